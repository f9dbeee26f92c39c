"""AD-MLP: future waypoints from the ego's own past and state only.

After Zhai et al. 2023 ("Rethinking the open-loop evaluation of end-to-end
autonomous driving in nuScenes"): an MLP that sees no scene at all, only the
ego's recent past, its current dynamics and the route command, and still
scores well open-loop. Inputs (``HistoryObservation``), one sample:

* ``history`` (8, 7): 4 s of past at 0.5 s, current ego frame (x, y,
  cos/sin dyaw, speed, accel, yaw rate), masked;
* ``ego`` (4,): speed, accel, yaw rate, steer now;
* ``command``: one-hot of ``types.Command`` (8 values, VOID included).

Output: K = 6 waypoints 0.5 s apart as cumulative per-step displacements
(a monotone, smooth parameterisation). Loss: masked L1 to the logged future
(``base.waypoint_l1``); metric: mean L2.

Size and cost (default hidden (128, 128); measured with
``python experiments/perf/ad_mlp_cost.py data/demos-train`` on this shared
2-core CPU under load ~12, so noisy): 26,892 parameters; a jitted ``apply``
of one sample 0.42 ms (mostly dispatch), a vmapped batch of 256 1.26 ms
(~5 us per sample). Inside the rollout it is negligible next to the simulator.
"""

from __future__ import annotations

import dataclasses

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax.models import base

#: Input scales: positions / 10 m, speeds / 10 m/s, accel / 5 m/s^2.
_HIST_SCALE = np.array([0.1, 0.1, 1.0, 1.0, 0.1, 0.2, 1.0], np.float32)
_EGO_SCALE = np.array([0.1, 0.2, 1.0, 1.0], np.float32)
_NUM_COMMANDS = 8  # Command -1..6


class ADMLPNet(nn.Module):
    """MLP: (F,) features -> (K, 2) waypoints (cumulated displacements, m)."""

    hidden: tuple[int, ...]
    num_waypoints: int
    init_step: float = 0.0   # initial bias of each forward displacement (m)

    @nn.compact
    def __call__(self, x):
        for width in self.hidden:
            x = nn.relu(nn.Dense(width)(x))
        bias = jnp.tile(jnp.array([self.init_step, 0.0], jnp.float32), self.num_waypoints)
        out = nn.Dense(self.num_waypoints * 2, bias_init=lambda key, shape, dtype=jnp.float32: bias.astype(dtype))
        steps = out(x).reshape(self.num_waypoints, 2)
        return jnp.cumsum(steps, axis=0)


def features(obs: base.HistoryObservation) -> jnp.ndarray:
    """(8 * 7 + 4 + 8,) float32 AD-MLP input of one sample (scaled)."""
    hist = obs.history * _HIST_SCALE
    cmd = jax.nn.one_hot(jnp.clip(obs.command + 1, 0, _NUM_COMMANDS - 1), _NUM_COMMANDS)
    return jnp.concatenate([hist.reshape(-1), obs.ego.astype(jnp.float32) * _EGO_SCALE, cmd]).astype(jnp.float32)


@dataclasses.dataclass(frozen=True)
class ADMLP:
    """The AD-MLP baseline (a ``models.base.Model``).

    Attributes:
      hidden: widths of the hidden layers.
      num_waypoints: K predicted points, ``waypoint_dt`` s apart.
      init_speed: m/s; the output bias starts as a straight-ahead plan at
        this speed (0: the usual zero bias). Only the initialisation: a
        random network then plans roughly "drive on" instead of "stand
        still", which is what PPO from scratch needs to find any progress
        reward (``docs/training.md``); imitation learns the bias anyway.
    """

    hidden: tuple[int, ...] = (128, 128)
    num_waypoints: int = 6
    waypoint_dt: float = 0.5
    init_speed: float = 0.0
    name = "ad_mlp"
    required_sensors: tuple[str, ...] = ()

    @property
    def net(self) -> ADMLPNet:
        return ADMLPNet(hidden=tuple(self.hidden), num_waypoints=self.num_waypoints,
                        init_step=self.init_speed * self.waypoint_dt)

    def features(self, obs) -> jnp.ndarray:
        """The network's input of one sample (module ``features``)."""
        return features(obs)

    def init(self, key, obs):
        return self.net.init(key, self.features(obs))

    def apply(self, params, obs) -> base.ModelOutput:
        return base.ModelOutput(waypoints=self.net.apply(params, self.features(obs)))

    def loss(self, params, obs, target: base.Target):
        pred = self.apply(params, obs).waypoints
        l1 = base.waypoint_l1(pred, target)
        return l1, {"l1": l1, "l2": base.waypoint_l2(pred, target)}


def make_model(hidden=(128, 128), num_waypoints: int = 6, waypoint_dt: float = 0.5, init_speed: float = 0.0) -> ADMLP:
    return ADMLP(hidden=tuple(int(h) for h in hidden), num_waypoints=int(num_waypoints), waypoint_dt=float(waypoint_dt),
                 init_speed=float(init_speed))
