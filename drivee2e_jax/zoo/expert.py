"""`expert`: a rule-based route follower (privileged only in seeing signals).

* Lateral: pure pursuit on the route points ahead (lookahead grows with speed).
* Longitudinal: IDM towards the lane's speed limit, lowered for route
  curvature, on the
  nearest obstacle in its path corridor: agents now inside the corridor ahead,
  agents predicted (constant velocity, up to 2.5 s) to enter it (crossing
  pedestrians, cyclists, cross traffic), and a red (or yellow it can still stop
  for) stop line on the route.

It never uses the logged ego future. Replayed agents do not react to it, so a
trailing logged vehicle can still hit it when it brakes earlier than the log's
ego did; the bench reports such cases per scenario.
"""

from __future__ import annotations

import jax.numpy as jnp

from drivee2e_jax.dynamics import BicycleParams
from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls, SignalState

A_LAT = 2.0  # comfortable lateral acceleration for curve speed, m/s^2
IDM_A = 2.0  # max acceleration, m/s^2
IDM_B = 3.0  # comfortable deceleration, m/s^2
IDM_S0 = 2.5  # jam distance, m
IDM_T = 1.2  # time headway, s
HORIZONS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5)  # prediction times, s
EGO_HALF_LEN = 2.4
EGO_HALF_WIDTH = 1.0


def _path_coords(points, route, route_valid):
    """Arc position along and lateral distance from the route polyline.

    points: (..., 2) ego frame; route: (P, 2) ego-frame route points (the ego at
    the origin is prepended). Returns (arc, lateral) with the same lead shape.
    """
    poly = jnp.concatenate([jnp.zeros((1, 2)), route], axis=0)
    pv = jnp.concatenate([jnp.ones((1,), bool), route_valid])
    a, b = poly[:-1], poly[1:]
    seg_ok = pv[:-1] & pv[1:]
    ab = b - a
    seg_len = jnp.linalg.norm(ab, axis=-1)
    cum = jnp.concatenate([jnp.zeros((1,)), jnp.cumsum(seg_len)])[:-1]
    p = points[..., None, :]
    u = jnp.clip(jnp.sum((p - a) * ab, -1) / jnp.maximum(seg_len**2, 1e-6), 0.0, 1.0)
    foot = a + u[..., None] * ab
    d = jnp.linalg.norm(p - foot, axis=-1)
    d = jnp.where(seg_ok, d, jnp.inf)
    i = jnp.argmin(d, axis=-1)
    arc = jnp.take_along_axis(cum + u * seg_len, i[..., None], -1)[..., 0]
    lat = jnp.take_along_axis(d, i[..., None], -1)[..., 0]
    return arc, lat


def _curve_speed(route, route_valid, v_max):
    """``v_max`` lowered for the sharpest heading change over the route ahead."""
    d = route[1:] - route[:-1]
    h = jnp.arctan2(d[:, 1], d[:, 0])
    dh = jnp.abs(jnp.angle(jnp.exp(1j * (h[1:] - h[:-1]))))
    ds = jnp.maximum(jnp.linalg.norm(d[1:], axis=-1), 0.5)
    ok = route_valid[2:]
    kappa = jnp.max(jnp.where(ok, dh / ds, 0.0))
    return jnp.minimum(v_max, jnp.sqrt(A_LAT / jnp.maximum(kappa, 1e-3)))


def _idm(v, v0, gap, dv):
    s_star = IDM_S0 + jnp.maximum(0.0, v * IDM_T + v * dv / (2.0 * jnp.sqrt(IDM_A * IDM_B)))
    free = 1.0 - (v / jnp.maximum(v0, 0.1)) ** 4
    return IDM_A * (free - (s_star / jnp.maximum(gap, 0.1)) ** 2)


class Expert(StatelessPolicy):
    name = "expert"
    action_type = "controls"

    def __init__(self, params: BicycleParams | None = None):
        self.params = params or BicycleParams()

    def act(self, params, obs, policy_state, key):
        v = obs.ego[0]
        route, rvalid = obs.route, obs.route_valid
        v0 = _curve_speed(route, rvalid, obs.speed_limit)

        # Agents now and predicted, in path coordinates.
        ag = obs.agents  # x, y, cos, sin, vx, vy, length, width
        t = jnp.asarray(HORIZONS)
        pos = ag[None, :, 0:2] + t[:, None, None] * ag[None, :, 4:6]  # (H, K, 2)
        arc, lat = _path_coords(pos, route, rvalid)
        half_w = 0.5 * ag[None, :, 7]
        half_l = 0.5 * ag[None, :, 6]
        # Agents now behind the ego's centre are followers: braking for their
        # predicted (overtaking) positions would only stop the ego in their way.
        now_ahead = obs.agents_valid & (ag[:, 0] > 0.0)
        in_path = (lat < EGO_HALF_WIDTH + half_w + 0.6) & (arc > 0.0) & now_ahead[None]
        # Beside or behind the ego front: not an obstacle to brake for.
        ahead = ag[None, :, 0] + t[:, None] * ag[None, :, 4] > EGO_HALF_LEN * 0.5
        gap = jnp.where(in_path & ahead, arc - EGO_HALF_LEN - half_l, jnp.inf)
        # Leader speed along the path: current agents use their forward speed;
        # predicted entries are treated as standing where they will be.
        v_lead = jnp.where(t[:, None] == 0.0, jnp.maximum(ag[None, :, 4], 0.0), 0.0)
        gap_flat, vl_flat = gap.reshape(-1), v_lead.reshape(-1)
        j = jnp.argmin(gap_flat)
        agent_gap, agent_v = gap_flat[j], vl_flat[j]

        # Signal: stop for red; for yellow when a comfortable stop is possible.
        d_stop = obs.signal_distance - EGO_HALF_LEN - 0.5
        can_stop = d_stop > v * v / (2.0 * IDM_B)
        must_stop = (obs.signal_state == SignalState.RED) | ((obs.signal_state == SignalState.YELLOW) & can_stop)
        must_stop = must_stop & (obs.signal_distance > 0.0)
        sig_gap = jnp.where(must_stop, jnp.maximum(d_stop, 0.05) + IDM_S0, jnp.inf)

        use_sig = sig_gap < agent_gap
        gap = jnp.where(use_sig, sig_gap, agent_gap)
        v_l = jnp.where(use_sig, 0.0, agent_v)
        acc_free = IDM_A * (1.0 - (v / jnp.maximum(v0, 0.1)) ** 4)
        acc = jnp.where(jnp.isfinite(gap), _idm(v, v0, gap, v - v_l), acc_free)
        # Hold the brake at standstill when something is close ahead.
        hold = (v < 0.3) & (gap < IDM_S0 + 1.0)
        throttle = jnp.clip(acc / self.params.max_accel, 0.0, 1.0)
        brake = jnp.where(hold, 1.0, jnp.clip(-acc / self.params.max_decel, 0.0, 1.0))
        throttle = jnp.where(hold, 0.0, throttle)

        # Pure pursuit on the route.
        ld = jnp.clip(3.0 + 0.6 * v, 4.0, 12.0)
        dist = jnp.linalg.norm(route, axis=-1)
        k = jnp.argmin(jnp.where(rvalid, jnp.abs(dist - ld), jnp.inf))
        target = jnp.where(rvalid.any(), route[k], jnp.array([ld, 0.0]))
        alpha = jnp.arctan2(target[1], target[0])
        delta = jnp.arctan2(2.0 * self.params.wheelbase * jnp.sin(alpha), jnp.maximum(jnp.linalg.norm(target), 1.0))
        steer = jnp.clip(delta / self.params.max_steer, -1.0, 1.0)
        return Controls(throttle=throttle, brake=brake, steer=steer), policy_state


policy = Expert()
