"""`constant_velocity`: the classic open-loop planning baseline.

Extrapolates the ego's current speed and yaw rate (``Observation.ego``) for
6 x 0.5 s: the waypoints lie on the circular arc (a straight line at zero yaw
rate) the ego would follow if neither changed. No privileged input.

In closed loop the waypoints go through the simulator's waypoint controller
(PID + drag feed-forward on the spacing of the first two points = the current
speed, pure pursuit on the arc), so it holds its speed and curvature and
never brakes for anything: a lower bound for reactive driving, a strong baseline for open-loop
L2 (as ST-P3 / AD-MLP showed on nuScenes). A standing ego stays standing.
"""

import jax.numpy as jnp

from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Waypoints


def arc_waypoints(speed, yaw_rate, times):
    """Ego-frame positions (len(times), 2), m, after ``times`` s at constant
    ``speed`` (m/s, >= 0) and ``yaw_rate`` (rad/s, + = left).

    x = v t sin(a) / a, y = v t (1 - cos a) / a with a = yaw_rate t, written
    with ``sinc`` so zero yaw rate is exact and differentiable.
    """
    s = speed * times
    a = yaw_rate * times
    x = s * jnp.sinc(a / jnp.pi)
    y = s * (0.5 * a) * jnp.sinc(a / (2.0 * jnp.pi)) ** 2
    return jnp.stack([x, y], axis=-1)


class ConstantVelocity(StatelessPolicy):
    name = "constant_velocity"
    action_type = "waypoints"
    waypoint_dt = 0.5

    def __init__(self, num_waypoints: int = 6):
        self.num_waypoints = int(num_waypoints)

    def act(self, params, obs, policy_state, key):
        speed = jnp.maximum(obs.ego[0], 0.0)
        yaw_rate = obs.ego[2]
        times = self.waypoint_dt * jnp.arange(1, self.num_waypoints + 1, dtype=jnp.float32)
        xy = arc_waypoints(speed, yaw_rate, times).astype(jnp.float32)
        return Waypoints(xy=xy), policy_state


policy = ConstantVelocity()
