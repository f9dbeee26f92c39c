"""Waypoint action path: ego-frame waypoints -> CARLA-style controls.

Longitudinal control is TCP's PID (Wu et al. 2022, ``TCP/model.py
control_pid``; the same rule as TransFuser) plus our drag feed-forward:

* TCP's: the desired speed is read from the spacing of the first two
  waypoints; a PID with a moving-window integral drives the throttle on the
  speed error clipped to ``clip_delta``; the controller brakes fully when the
  desired speed is below ``brake_speed`` or the ego is faster than
  ``brake_ratio`` times the desired speed. Gains and thresholds are TCP's.
* Ours (``feedforward=True``, the default): the throttle
  ``drag(target) / max_accel`` that cancels our bicycle's resistance
  (``dynamics.drag``) at the desired speed is added to the PID output, and
  the error is clipped to ``[-clip_delta, clip_delta]`` instead of TCP's
  ``[0, clip_delta]``. Why: TCP's PID only pushes while the ego is slower
  than the plan, so a plan at the ego's current speed (what a constant-
  velocity extrapolation or a learned planner consistent with its input
  speed predicts) gives ~0 throttle and the car coasts down under drag
  (~0.3 m/s^2 at 11 m/s: 41 -> 27 km/h in 12 s). With the feed-forward the
  plan's speed is an equilibrium; the two-sided error lets the PID take the
  throttle back below the feed-forward after an overshoot, which TCP leaves
  to drag, and drag is exactly what the feed-forward cancels.
  ``feedforward=False`` is TCP's rule unchanged (for ablations).

Lateral control is pure pursuit on our bicycle's rear axle (instead of TCP's
angle PID, whose gains are tuned to CARLA's steering response): aim at the
point ``lookahead`` metres along the waypoint polyline (ego origin first,
extrapolated past the last waypoint) and command the front-wheel angle whose
rear-axle arc passes through it. On an exact kinematic bicycle this tracks
circles without steady-state error and needs no integrator.

Both use ``params.vehicle`` (the Simulator sets it to ``SimConfig.dynamics``,
the parameters of its ``dynamics.DynamicsModel``): the bicycle's drag law and
geometry, whichever model moves the ego.
Unbatched and jit-friendly; the brake decision is a hard switch (as in TCP),
so the controls are not differentiable through it.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import struct

from drivee2e_jax.dynamics import BicycleParams, drag
from drivee2e_jax.types import Controls

Array = jnp.ndarray


@struct.dataclass
class ControllerParams:
    """Waypoint controller settings (frozen, hashable).

    Attributes:
      kp, ki, kd:     longitudinal PID gains on the speed error (TCP values).
      window:         PID integral window, steps (static: sets a shape).
      clip_delta:     m/s, the speed error fed to the PID is clipped to
                      [-clip_delta, clip_delta] with the feed-forward, to
                      [0, clip_delta] without it (TCP: overshoot is left to
                      drag and the brake rule).
      feedforward:    add the throttle drag(target) / max_accel that holds
                      the desired speed on ``vehicle`` (ours; static).
                      False = TCP's PID exactly.
      max_throttle:   upper throttle limit.
      brake_speed:    m/s, desired speeds below this brake fully.
      brake_ratio:    brake fully when speed > brake_ratio * desired speed.
      waypoint_dt:    s between consecutive waypoints (and from the ego to the
                      first one).
      lookahead_time: s, pure-pursuit lookahead = lookahead_time * speed ...
      lookahead_min, lookahead_max: ... clipped to these, m. Equal to
                      waypoint_dt by default, so between 4 and 16 m/s the aim
                      point is the first waypoint itself: aiming between sparse
                      waypoints would cut the chord (0.6 s doubled the
                      closed-loop error on a 25 m radius curve).
      vehicle:        the bicycle whose drag the feed-forward cancels and whose
                      geometry the pursuit inverts.
    """

    kp: float = 5.0
    ki: float = 0.5
    kd: float = 1.0
    window: int = struct.field(pytree_node=False, default=40)
    clip_delta: float = 0.25
    feedforward: bool = struct.field(pytree_node=False, default=True)
    max_throttle: float = 0.75
    brake_speed: float = 0.4
    brake_ratio: float = 1.1
    waypoint_dt: float = 0.5
    lookahead_time: float = 0.5
    lookahead_min: float = 2.0
    lookahead_max: float = 8.0
    vehicle: BicycleParams = BicycleParams()


@struct.dataclass
class ControllerState:
    """PID memory.

    Attributes:
      errors: (window,) float32 last speed errors fed to the PID, oldest
        first (m/s); starts at zeros, as TCP's deque does.
    """

    errors: Array


def init_controller_state(params: ControllerParams | None = None) -> ControllerState:
    """A fresh ControllerState (zero error history); ``params`` default: ``ControllerParams()``."""
    params = ControllerParams() if params is None else params
    return ControllerState(errors=jnp.zeros((params.window,), jnp.float32))


def desired_speed(waypoints_xy: Array, params: ControllerParams) -> Array:
    """() m/s: |wp1 - wp0| / waypoint_dt (TCP's 2 * |wp1 - wp0| at 2 Hz)."""
    step = waypoints_xy[1] - waypoints_xy[0]
    sq = jnp.sum(step**2)
    ok = sq > 1e-12
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0) / params.waypoint_dt


def lookahead_point(waypoints_xy: Array, distance: Array) -> Array:
    """(2,) point ``distance`` m along the polyline [ego origin, wp0, wp1, ...],
    extrapolated along the last non-degenerate segment past the end; the
    origin if every waypoint sits on the ego."""
    pts = jnp.concatenate([jnp.zeros((1, 2)), waypoints_xy])
    seg = pts[1:] - pts[:-1]
    sq = jnp.sum(seg**2, axis=-1)
    ok = sq > 1e-12
    seg_len = jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)
    cum = jnp.concatenate([jnp.zeros(1), jnp.cumsum(seg_len)])  # (K+1,)
    k = jnp.arange(seg.shape[0])
    # The segment holding `distance`; past the end: the last real segment.
    last = jnp.max(jnp.where(ok, k, -1))
    inside = ok & (cum[:-1] <= distance) & (distance < cum[1:])
    i = jnp.where(jnp.any(inside), jnp.argmax(inside), jnp.maximum(last, 0))
    t = (distance - cum[i]) / jnp.where(ok[i], seg_len[i], 1.0)
    return jnp.where(last >= 0, pts[i] + t * seg[i], jnp.zeros(2))


def pursuit_steer(waypoints_xy: Array, speed: Array, params: ControllerParams) -> Array:
    """() steer command of pure pursuit, NOT clipped to [-1, 1] (smooth in
    the waypoints): from the rear axle (lr behind the box centre) the arc
    through the aim point ``lookahead`` m along the plan has curvature
    2 y / d^2, and tan(delta) = L k; returned as delta / max_steer."""
    veh = params.vehicle
    lookahead = jnp.clip(params.lookahead_time * speed, params.lookahead_min, params.lookahead_max)
    aim = lookahead_point(waypoints_xy, lookahead)
    x_rear, y = aim[0] + veh.lr, aim[1]
    curvature = 2.0 * y / (x_rear**2 + y**2)
    return jnp.arctan(veh.wheelbase * curvature) / veh.max_steer


def waypoints_to_controls(
    waypoints_xy: Array, speed: Array, state: ControllerState, params: ControllerParams
) -> tuple[Controls, ControllerState]:
    """Controls that follow ``waypoints_xy (K, 2)`` (ego frame, m, x forward, y
    left, ``params.waypoint_dt`` apart, K >= 2) at ego ``speed`` (m/s).

    Returns (Controls, new ControllerState).
    """
    target = desired_speed(waypoints_xy, params)

    veh = params.vehicle

    # Longitudinal: TCP's clipped-error PID with a moving-window integral, on
    # top of the throttle that cancels drag at the desired speed (ours).
    lowest = -params.clip_delta if params.feedforward else 0.0
    error = jnp.clip(target - speed, lowest, params.clip_delta)
    errors = jnp.concatenate([state.errors[1:], error[None]])
    pid = params.kp * error + params.ki * jnp.mean(errors) + params.kd * (errors[-1] - errors[-2])
    hold = drag(target, veh) / veh.max_accel if params.feedforward else 0.0
    brake = (target < params.brake_speed) | (speed > params.brake_ratio * target)
    throttle = jnp.where(brake, 0.0, jnp.clip(hold + pid, 0.0, params.max_throttle))

    steer = jnp.clip(pursuit_steer(waypoints_xy, speed, params), -1.0, 1.0)

    controls = Controls(
        throttle=throttle.astype(jnp.float32),
        brake=brake.astype(jnp.float32),
        steer=steer.astype(jnp.float32),
    )
    return controls, ControllerState(errors=errors)
