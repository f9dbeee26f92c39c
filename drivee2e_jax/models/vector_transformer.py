"""Vector-scene transformer: nearest agents + lane polylines + route -> waypoints.

The vectorised-planner family of VAD (Jiang et al. 2023) without perception:
the scene arrives as vectors (``observe.vector``), each becomes one token,
a few self-attention layers mix them and a planning query reads K waypoints.
One sample (``HistoryObservation``):

* agent tokens (K_a = ``ObsConfig.num_agents``): relative pose, velocity,
  size (``obs.agents``) + category one-hot; masked by ``agents_valid``;
* lane tokens (M = 16 lanes near the route): each polyline's points (x, y and
  the direction to the next point) through a shared point MLP, max-pooled over
  its valid points (PointNet); masked where no point is valid;
* one route token: the route points ahead (``obs.route``) as a polyline,
  encoded the same way by its own PointNet;
* one ego token: speed, accel, yaw rate, steer, command one-hot, next signal
  state one-hot and distance, speed limit.

Each kind adds its own learned type embedding. ``layers`` pre-LayerNorm
self-attention blocks (``flax.linen.MultiHeadDotProductAttention``) with key
padding masks, then a learned planning query cross-attends to the tokens and
an MLP emits K per-step displacements (cumulated into waypoints). Padded
tokens never receive attention weight (their logits are masked to -inf
before the softmax), so the output does not depend on what padding holds,
and it does not depend on the order of the agents or of the lanes.

Loss: masked L1 to the logged future (``base.waypoint_l1``).
Size and cost: see ``docs/baselines.md``
(``python -m drivee2e_jax.models.vector_transformer``).
"""

from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax.models import base
from drivee2e_jax.models.tcp import POS_SCALE, SPEED_SCALE, STEP_SCALE, command_onehot
from drivee2e_jax.observe.vector import NO_SIGNAL_DISTANCE
from drivee2e_jax.types import Category, SignalState

#: Agent feature scales: x, y / 20 m, cos, sin, vx, vy / 10 m/s, length, width / 5 m.
_AGENT_SCALE = np.array([POS_SCALE, POS_SCALE, 1.0, 1.0, SPEED_SCALE, SPEED_SCALE, 0.2, 0.2], np.float32)
_NUM_CATEGORIES = len(Category)
_NUM_SIGNALS = len(SignalState)
_NEG = -1e9  # max-pool fill for invalid points


def polyline_points(xy: jnp.ndarray, valid: jnp.ndarray) -> jnp.ndarray:
    """(..., N, 4) per-point features of polylines ``xy (..., N, 2)`` (m, ego
    frame): scaled x, y and the scaled step to the next valid point (0 at the
    last one)."""
    nxt = jnp.concatenate([xy[..., 1:, :], xy[..., -1:, :]], axis=-2)
    nxt_ok = jnp.concatenate([valid[..., 1:], jnp.zeros_like(valid[..., -1:])], axis=-1)
    step = jnp.where((valid & nxt_ok)[..., None], nxt - xy, 0.0)
    return jnp.concatenate([xy, step], axis=-1) * POS_SCALE


class PointNet(nn.Module):
    """(N, F) points + (N,) valid -> (d,) max-pooled polyline embedding (0 if
    no point is valid)."""

    dim: int

    @nn.compact
    def __call__(self, pts, valid):
        h = nn.Dense(self.dim)(nn.relu(nn.Dense(self.dim)(pts)))
        pooled = jnp.max(jnp.where(valid[:, None], h, _NEG), axis=0)
        return jnp.where(valid.any(), pooled, 0.0)


class Block(nn.Module):
    """Pre-LN attention + MLP residual block; ``mask (Nq, Nk)`` bool."""

    dim: int
    heads: int

    @nn.compact
    def __call__(self, q, kv, mask):
        att = nn.MultiHeadDotProductAttention(num_heads=self.heads, qkv_features=self.dim)
        x = q + att(nn.LayerNorm()(q), nn.LayerNorm()(kv), mask=mask[None])
        return x + nn.Dense(self.dim)(nn.relu(nn.Dense(2 * self.dim)(nn.LayerNorm()(x))))


class VectorNet(nn.Module):
    """Tokens -> (K, 2) waypoints, m."""

    dim: int
    heads: int
    layers: int
    num_waypoints: int

    @nn.compact
    def __call__(self, agents, agents_valid, lane_pts, lanes_valid, lane_point_valid, route_pts, route_valid, ego):
        d = self.dim
        mlp = lambda x, name: nn.Dense(d, name=f"{name}_out")(nn.relu(nn.Dense(d, name=f"{name}_in")(x)))  # noqa: E731
        lane_net = PointNet(d, name="lane_pointnet")
        tokens = jnp.concatenate([
            mlp(ego, "ego")[None],
            PointNet(d, name="route_pointnet")(route_pts, route_valid)[None],
            mlp(agents, "agent"),
            jax.vmap(lane_net)(lane_pts, lane_point_valid),
        ])
        kinds = jnp.concatenate([jnp.array([0, 1]), jnp.full(agents.shape[0], 2), jnp.full(lane_pts.shape[0], 3)])
        tokens = tokens + nn.Embed(4, d, name="type_embedding")(kinds)
        valid = jnp.concatenate([jnp.ones(1, bool), route_valid.any()[None], agents_valid, lanes_valid])
        mask = valid[None, :] & valid[:, None]
        mask = mask | jnp.eye(valid.shape[0], dtype=bool)  # a padded query still attends to itself
        for i in range(self.layers):
            tokens = Block(d, self.heads, name=f"self_{i}")(tokens, tokens, mask)
        query = self.param("plan_query", nn.initializers.normal(0.02), (1, d))
        plan = Block(d, self.heads, name="plan")(query, tokens, valid[None, :])
        steps = nn.Dense(2 * self.num_waypoints)(nn.relu(nn.Dense(d)(nn.LayerNorm()(plan[0]))))
        return jnp.cumsum(STEP_SCALE * steps.reshape(self.num_waypoints, 2), axis=0)


def inputs(obs) -> dict:
    """The network's inputs of one ``Observation`` (scaled; see the module docstring)."""
    cat = jax.nn.one_hot(obs.agents_category, _NUM_CATEGORIES, dtype=jnp.float32)  # -1 (padding) -> zeros
    agents = jnp.concatenate([obs.agents * _AGENT_SCALE, cat], axis=-1)
    ego = jnp.concatenate([
        obs.ego.astype(jnp.float32) * jnp.array([SPEED_SCALE, 0.2, 1.0, 1.0]),
        command_onehot(obs.command),
        jax.nn.one_hot(obs.signal_state, _NUM_SIGNALS, dtype=jnp.float32),
        jnp.minimum(obs.signal_distance, 100.0)[None] / 100.0,
        (obs.signal_distance >= NO_SIGNAL_DISTANCE)[None].astype(jnp.float32),
        obs.speed_limit[None] * SPEED_SCALE,
    ])
    return dict(
        agents=agents, agents_valid=obs.agents_valid,
        lane_pts=polyline_points(obs.lanes, obs.lanes_valid), lanes_valid=obs.lanes_valid.any(axis=-1),
        lane_point_valid=obs.lanes_valid,
        route_pts=polyline_points(obs.route, obs.route_valid), route_valid=obs.route_valid, ego=ego,
    )


@dataclasses.dataclass(frozen=True)
class VectorTransformer:
    """The vector-scene transformer baseline (a ``models.base.Model``).

    Attributes:
      dim: token width.  heads: attention heads.  layers: self-attention blocks.
      num_waypoints: K predicted points, ``waypoint_dt`` s apart.
    """

    dim: int = 64
    heads: int = 4
    layers: int = 2
    num_waypoints: int = 6
    waypoint_dt: float = 0.5
    name = "vector_transformer"
    required_sensors: tuple[str, ...] = ()

    @property
    def net(self) -> VectorNet:
        return VectorNet(dim=self.dim, heads=self.heads, layers=self.layers, num_waypoints=self.num_waypoints)

    def init(self, key, obs):
        return self.net.init(key, **inputs(obs))

    def apply(self, params, obs) -> base.ModelOutput:
        return base.ModelOutput(waypoints=self.net.apply(params, **inputs(obs)))

    def loss(self, params, obs, target: base.Target):
        pred = self.apply(params, obs).waypoints
        l1 = base.waypoint_l1(pred, target)
        return l1, {"l1": l1, "l2": base.waypoint_l2(pred, target)}


def make_model(dim: int = 64, heads: int = 4, layers: int = 2, num_waypoints: int = 6,
               waypoint_dt: float = 0.5) -> VectorTransformer:
    if dim % heads:
        raise ValueError(f"vector_transformer: dim ({dim}) must be a multiple of heads ({heads})")
    return VectorTransformer(dim=int(dim), heads=int(heads), layers=int(layers), num_waypoints=int(num_waypoints),
                             waypoint_dt=float(waypoint_dt))
