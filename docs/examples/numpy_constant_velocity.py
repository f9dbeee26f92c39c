"""constant_velocity as a host policy, in numpy: the smallest example of a policy
that runs outside JAX (the same could call PyTorch, ONNX Runtime, ...).

    drivee2e bench --policy docs/examples/numpy_constant_velocity.py --policy constant_velocity

It gives the same per-scenario results as the JAX reference policy
``drivee2e_jax/zoo/constant_velocity.py`` (tests/test_hostbridge.py checks it): the
host policy receives the observation of every scenario at once (numpy, leading
batch axis B) and returns B actions.
"""

import numpy as np

from drivee2e_jax.hostapi import HostPolicy, Waypoints


class NumpyConstantVelocity(HostPolicy):
    name = "np_constant_velocity"
    action_type = "waypoints"
    waypoint_dt = 0.5  # s between waypoints
    num_waypoints = 6
    observation_fields = ("ego",)  # all it reads: the simulator skips the rest (lanes, agents, ...)

    def reset(self, meta):
        return None  # stateless: nothing to remember between steps

    def act(self, obs, state):
        # obs.ego: (B, 4) = speed m/s, acceleration m/s^2, yaw rate rad/s, steer rad (drivee2e_jax.types.Observation)
        speed = np.maximum(obs.ego[:, 0], np.float32(0.0))[:, None]  # (B, 1)
        yaw_rate = obs.ego[:, 2][:, None]
        times = np.float32(self.waypoint_dt) * np.arange(1, self.num_waypoints + 1, dtype=np.float32)[None]  # (1, K)
        s, a = speed * times, yaw_rate * times  # arc length m, heading change rad: (B, K)
        x = s * np.sinc(a / np.float32(np.pi))  # the circular arc at constant speed and yaw rate
        y = s * (np.float32(0.5) * a) * np.sinc(a / np.float32(2.0 * np.pi)) ** 2
        return Waypoints(xy=np.stack([x, y], axis=-1).astype(np.float32)), state  # (B, K, 2), ego frame, m


policy = NumpyConstantVelocity()
