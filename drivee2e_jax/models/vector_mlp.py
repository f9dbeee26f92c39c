"""Vector-MLP: AD-MLP's network over the ego's past AND a flat vector of the scene.

The cheapest model that sees the world: AD-MLP (``models/ad_mlp.py``) sees
only the ego, so it cannot stop for a light or a lead vehicle; the vector
transformer sees everything through attention, which makes its backward
pass the bulk of a PPO update on a CPU (docs/performance.md, "PPO training
throughput"). This model concatenates AD-MLP's input with ``scene_features``
(one observation as a flat vector, the same vector the PPO critic reads) and
runs an MLP: what PPO from scratch trains at simulator speed. Inputs
(``HistoryObservation``, one sample):

* AD-MLP's: ``history`` (8, 7), ``ego`` (4,), the route command one-hot (8,);
* ``scene_features`` (170,): ego state, the route points ahead (10 x 2), the
  nearest agents (16 x 8; 0 where invalid), command and next-signal one-hots,
  the distance to that stop line (capped at 100 m), the speed limit.

Output: K = 6 waypoints 0.5 s apart as cumulated per-step displacements (m),
as AD-MLP. Default hidden (256, 256): 130,060 parameters. Loss (imitation): masked L1 to the
logged future (``base.waypoint_l1``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from drivee2e_jax.models import ad_mlp, base
from drivee2e_jax.types import Observation

#: Positions / 20 m, speeds / 10 m/s.
_POS, _SPEED = 1.0 / 20.0, 1.0 / 10.0


def scene_features(obs: Observation) -> jnp.ndarray:
    """(F,) float32 flat vector of ONE observation (scaled; 0 where invalid).

    Ego [speed, accel, yaw rate, steer]; the route points ahead (P x 2); the
    nearest agents (A x 8); the route command and the next signal's state as
    one-hots (8 each); the distance to that stop line (capped at 100 m, / 100);
    the speed limit (/ 10 m/s). F = 4 + 2 P + 8 A + 18 (170 with the default
    P = 10 route points and A = 16 agents).
    """
    ego = obs.ego * jnp.array([_SPEED, 0.2, 1.0, 1.0], jnp.float32)
    route = jnp.where(obs.route_valid[:, None], obs.route * _POS, 0.0).reshape(-1)
    scale = jnp.array([_POS, _POS, 1.0, 1.0, _SPEED, _SPEED, 0.2, 0.2], jnp.float32)
    agents = jnp.where(obs.agents_valid[:, None], obs.agents * scale, 0.0).reshape(-1)
    command = jax.nn.one_hot(obs.command, 8, dtype=jnp.float32)
    signal = jax.nn.one_hot(obs.signal_state, 8, dtype=jnp.float32)
    dist = jnp.minimum(obs.signal_distance, 100.0)[None] / 100.0
    return jnp.concatenate([ego, route, agents, command, signal, dist,
                            obs.speed_limit[None] * _SPEED]).astype(jnp.float32)


def features(obs: base.HistoryObservation) -> jnp.ndarray:
    """AD-MLP's input followed by ``scene_features`` (one sample)."""
    return jnp.concatenate([ad_mlp.features(obs), scene_features(obs)])


@dataclasses.dataclass(frozen=True)
class VectorMLP(ad_mlp.ADMLP):
    """AD-MLP's network over ``features`` (a ``models.base.Model``).

    Attributes:
      hidden: widths of the hidden layers.
      num_waypoints: K predicted points, ``waypoint_dt`` s apart.
      init_speed: m/s, the initial straight-ahead plan (``ad_mlp.ADMLP``).
    """

    hidden: tuple[int, ...] = (256, 256)
    name = "vector_mlp"

    def features(self, obs) -> jnp.ndarray:
        return features(obs)


def make_model(hidden=(256, 256), num_waypoints: int = 6, waypoint_dt: float = 0.5,
               init_speed: float = 0.0) -> VectorMLP:
    return VectorMLP(hidden=tuple(int(h) for h in hidden), num_waypoints=int(num_waypoints),
                     waypoint_dt=float(waypoint_dt), init_speed=float(init_speed))
