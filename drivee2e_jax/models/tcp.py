"""TCP-like baseline: BEV + ego state + command -> trajectory and control heads.

After Wu et al. 2022 ("Trajectory-guided Control Prediction", TCP), with the
front camera replaced by the simulator's BEV raster (no expert-feature
distillation, as the DriveE2E paper trains it). One sample:

* ``bev`` (H, W) int32 bit-packed (``observe.bev``), unpacked to C float
  channels; a BEV larger than ``TcpConfig.bev`` by an integer factor (e.g. the
  default 128 x 128 at 0.5 m/px) is max-pooled down to it, so one set of
  parameters drives with either;
* measurements: speed (``ego[0]``), the route command (one-hot, VOID
  included) and the target point = the farthest valid route point ahead
  (<= 20 m with the default ``ObsConfig``), ego frame.

Network: a 4-layer strided CNN (flattened, so it keeps where things are) and
a measurement MLP -> a joint feature ->

* trajectory head: TCP's GRU decoder, K steps, each fed the previous
  waypoint and the target point, emitting a displacement (K waypoints,
  ``waypoint_dt`` apart);
* control head: an MLP -> throttle (sigmoid), brake (sigmoid), steer (tanh).

Loss: ``traj_weight`` x masked L1 on the waypoints (``base.waypoint_l1``) +
``ctrl_weight`` x mean L1 on [throttle, brake, steer] vs the controls that
reproduce the log. The three policy modes (``base.as_policy``) are the
source's rows: ``fused`` = TCP (situation-based fusion, ``base.fuse_controls``),
``traj`` = TCP-traj (waypoints -> the simulator's PID + pure pursuit),
``ctrl`` = TCP-ctr (the control head alone).

Size and cost: see ``docs/baselines.md`` (``python -m drivee2e_jax.models.tcp``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import flax.linen as nn
import jax
import jax.numpy as jnp

from drivee2e_jax.models import base
from drivee2e_jax.models.registry import get_model
from drivee2e_jax.observe import sensors
from drivee2e_jax.observe.bev import BevConfig, unpack_bits
from drivee2e_jax.observe.sensors import SensorConfig
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.sim import SimConfig, Simulator
from drivee2e_jax.types import Controls

#: Command one-hot width: ``types.Command`` -1 (VOID) .. 6.
NUM_COMMANDS = 8
#: Input scales: positions / 20 m, speed / 10 m/s; a GRU step's output is
#: scaled to metres per 0.5 s at 10 m/s.
POS_SCALE = 0.05
SPEED_SCALE = 0.1
STEP_SCALE = 5.0

#: The BEV TCP is sized for: 64 x 64 at 1 m/px (48 m ahead, 16 m behind, 32 m
#: each side, as the default 128 x 128 at 0.5 m/px, at a quarter of its cost).
TCP_BEV = BevConfig(height=64, width=64, resolution=1.0)


def command_onehot(command: jnp.ndarray) -> jnp.ndarray:
    """(8,) float32 one-hot of a ``types.Command`` (() int32, -1..6)."""
    return jax.nn.one_hot(jnp.clip(command + 1, 0, NUM_COMMANDS - 1), NUM_COMMANDS, dtype=jnp.float32)


def target_point(route: jnp.ndarray, route_valid: jnp.ndarray) -> jnp.ndarray:
    """(2,) the farthest valid point of ``route (P, 2)`` (ego frame, m); the
    origin when none is valid (route finished)."""
    i = jnp.maximum(jnp.sum(route_valid) - 1, 0)
    return jnp.where(route_valid.any(), route[i], 0.0).astype(jnp.float32)


def bev_image(bev: jnp.ndarray, cfg: BevConfig) -> jnp.ndarray:
    """(h, w, C) float32 image of the packed ``bev (H, W)`` at ``cfg``'s size.

    H, W must be integer multiples of ``cfg.height, cfg.width``; larger BEVs
    are max-pooled (a thing occupying any fine pixel occupies the coarse one),
    as a bitwise OR of the packed words before unpacking (C times cheaper).
    """
    h, w = bev.shape
    if h % cfg.height or w % cfg.width:
        raise ValueError(f"TCP: observed BEV {h}x{w} is not a multiple of the model's {cfg.height}x{cfg.width}")
    fh, fw = h // cfg.height, w // cfg.width
    if fh > 1 or fw > 1:
        blocks = bev.reshape(cfg.height, fh, cfg.width, fw)
        bev = jax.lax.reduce(blocks, jnp.zeros((), bev.dtype), jax.lax.bitwise_or, (1, 3))
    return unpack_bits(bev, len(cfg.channels))


class TcpNet(nn.Module):
    """(h, w, C) image + (10,) measurements -> ((K, 2) waypoints m, (3,) controls)."""

    conv_features: tuple[int, ...]
    hidden: int
    gru_hidden: int
    num_waypoints: int

    @nn.compact
    def __call__(self, img, speed, command, target):
        x = img
        for f in self.conv_features:
            x = nn.relu(nn.Conv(f, (3, 3), strides=2)(x))
        x = nn.relu(nn.Dense(self.hidden)(x.reshape(-1)))
        meas = jnp.concatenate([speed[None] * SPEED_SCALE, command_onehot(command), target * POS_SCALE])
        m = nn.relu(nn.Dense(64)(nn.relu(nn.Dense(64)(meas))))
        j = nn.relu(nn.Dense(self.hidden)(jnp.concatenate([x, m])))

        # Trajectory head: TCP's GRU roll-out towards the target point.
        h = nn.Dense(self.gru_hidden)(j)
        cell = nn.GRUCell(self.gru_hidden)
        out = nn.Dense(2)
        wp, wps = jnp.zeros(2), []
        for _ in range(self.num_waypoints):
            h, _ = cell(h, jnp.concatenate([wp * POS_SCALE, target * POS_SCALE]))
            wp = wp + STEP_SCALE * out(h)
            wps.append(wp)

        c = nn.Dense(3)(nn.relu(nn.Dense(self.hidden // 2)(j)))
        controls = jnp.stack([nn.sigmoid(c[0]), nn.sigmoid(c[1]), jnp.tanh(c[2])])
        return jnp.stack(wps), controls


@dataclasses.dataclass(frozen=True)
class TCP:
    """The TCP-like baseline (a ``models.base.Model``).

    Attributes:
      bev: the BEV the network is sized for (``TCP_BEV``); the simulator must
        render it or an integer multiple of it (``sensor_config``).
      conv_features: channels of the stride-2 3x3 convolutions.
      hidden: width of the joint feature.
      gru_hidden: GRU state width of the trajectory head.
      num_waypoints: K predicted points, ``waypoint_dt`` s apart.
      traj_weight, ctrl_weight: loss weights of the two heads.
    """

    bev: BevConfig = TCP_BEV
    conv_features: tuple[int, ...] = (16, 32, 32, 64)
    hidden: int = 256
    gru_hidden: int = 64
    num_waypoints: int = 6
    waypoint_dt: float = 0.5
    traj_weight: float = 1.0
    ctrl_weight: float = 1.0
    name = "tcp"
    required_sensors: tuple[str, ...] = ("bev",)

    @property
    def net(self) -> TcpNet:
        return TcpNet(conv_features=tuple(self.conv_features), hidden=self.hidden, gru_hidden=self.gru_hidden,
                      num_waypoints=self.num_waypoints)

    @property
    def sensor_config(self):
        """``observe.sensors.SensorConfig`` rendering the BEV this model is sized for."""

        return SensorConfig(bev=self.bev)

    def _inputs(self, obs):
        if obs.bev is None:
            raise ValueError("TCP needs obs.bev: enable the BEV (required_sensors = ('bev',))")
        return (bev_image(obs.bev, self.bev), obs.ego[0].astype(jnp.float32), obs.command,
                target_point(obs.route, obs.route_valid))

    def init(self, key, obs):
        return self.net.init(key, *self._inputs(obs))

    def apply(self, params, obs) -> base.ModelOutput:
        wps, c = self.net.apply(params, *self._inputs(obs))
        return base.ModelOutput(waypoints=wps, controls=Controls(throttle=c[0], brake=c[1], steer=c[2]))

    def loss(self, params, obs, target: base.Target):
        out = self.apply(params, obs)
        l1 = base.waypoint_l1(out.waypoints, target)
        ctrl = jnp.mean(jnp.abs(base.controls_vector(out.controls) - target.controls))
        total = self.traj_weight * l1 + self.ctrl_weight * ctrl
        return total, {"l1": l1, "l2": base.waypoint_l2(out.waypoints, target), "ctrl_l1": ctrl}


def make_model(bev_size: int = 64, bev_resolution: float = 1.0, conv_features=(16, 32, 32, 64), hidden: int = 256,
               gru_hidden: int = 64, num_waypoints: int = 6, waypoint_dt: float = 0.5, traj_weight: float = 1.0,
               ctrl_weight: float = 1.0) -> TCP:
    """A ``TCP`` with a square ``bev_size`` px BEV at ``bev_resolution`` m/px."""
    bev = dataclasses.replace(TCP_BEV, height=int(bev_size), width=int(bev_size), resolution=float(bev_resolution))
    return TCP(bev=bev, conv_features=tuple(int(f) for f in conv_features), hidden=int(hidden),
               gru_hidden=int(gru_hidden), num_waypoints=int(num_waypoints), waypoint_dt=float(waypoint_dt),
               traj_weight=float(traj_weight), ctrl_weight=float(ctrl_weight))


def inference_cost(model, obs, batch: int = 200, repeats: int = 20) -> dict:
    """Parameter count and per-sample cost of ``jit(vmap(model.apply))`` over
    ``batch`` copies of ``obs`` (host timing: wall and process CPU time, us)."""

    params = jax.jit(model.init)(jax.random.PRNGKey(0), obs)
    many = jax.jit(jax.vmap(model.apply, in_axes=(None, 0)))
    obs_b = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (batch,) + jnp.shape(a)), obs)
    jax.block_until_ready(many(params, obs_b))
    w0, c0 = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        jax.block_until_ready(many(params, obs_b))
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    return {"model": model.name, "parameters": int(sum(x.size for x in jax.tree_util.tree_leaves(params))),
            "batch": batch, "wall_us_per_sample": 1e6 * wall / (repeats * batch),
            "cpu_us_per_sample": 1e6 * cpu / (repeats * batch)}


def example_observation(sensor_config=None, suite: str = "tiny"):
    """A ``HistoryObservation`` at the reset of ``suite``'s first scenario,
    with the sensors of ``sensor_config`` (host helper for measurements)."""

    sensor_config = sensor_config or sensors.SensorConfig()
    s = load_suite(suite)
    packed = s.pack(None).select(jnp.arange(1))
    assets = sensors.build_assets(packed, sensor_config, s.maps)
    first = jax.tree_util.tree_map(lambda a: jnp.asarray(a[0]), packed.scenario)
    one = None if assets is None else assets.replace(map_index=assets.map_index[0])
    _, obs = jax.jit(Simulator(SimConfig(sensors=sensor_config)).reset)(jax.random.PRNGKey(0), first, one)
    return base.with_history(obs, base.push_history(base.empty_history(obs), obs))


def main(argv=None) -> None:
    """``python -m drivee2e_jax.models.tcp [--bev-size 64 128] [--model tcp vector_transformer]``:
    parameters and inference cost per sample (JSON lines)."""

    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("--model", nargs="+", default=["tcp", "vector_transformer"])
    p.add_argument("--bev-size", type=int, nargs="+", default=[64],
                   help="rendered BEV sizes (px, same 64 m extent) fed to the default TCP")
    p.add_argument("--batch", type=int, default=200)
    a = p.parse_args(argv)
    for name in a.model:
        model = get_model(name)
        for size in a.bev_size if name == "tcp" else [None]:
            bev = None if size is None else dataclasses.replace(model.bev, height=size, width=size,
                                                                 resolution=64.0 / size)
            obs = example_observation(SensorConfig(bev=bev))
            print(json.dumps({**inference_cost(model, obs, a.batch), "bev": None if obs.bev is None
                              else list(obs.bev.shape)}), flush=True)


if __name__ == "__main__":
    main()
