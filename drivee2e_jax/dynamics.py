"""Kinematic bicycle for the ego: controls -> motion, and its inverse.

The reference point is the box centre (half-way along the wheelbase), so the
centre moves at the slip angle ``beta = atan(lr / L * tan(delta))`` off the
heading, with ``lr = L / 2``. With the steer angle and the acceleration held
over a step, the centre follows a circular arc of curvature
``kappa = sin(beta) / lr`` whatever the speed profile, so ``step`` integrates
the arc exactly (heading advances by ``kappa * s`` for a travelled distance
``s``; the chord points along the mid-step heading plus ``beta``). That is
what makes ``inverse`` a closed form and the round trip exact to float
rounding, at any ``dt``.

Longitudinal model (CARLA-like): net acceleration
``throttle * max_accel - brake * max_decel - drag(v)`` with
``drag(v) = drag_const + drag_quad * v**2`` evaluated at the step's start
speed. Speed is clipped to ``[0, max_speed]`` inside the step (the distance
integral accounts for the moment the clip is hit): no reversing, and braking
stops at 0. A standing car does not creep: the throttle must beat
``drag_const`` first (rolling resistance acts like static friction).

Everything is unbatched, jit/vmap/grad friendly: no sqrt or atan2 at points
the ego reaches (speed 0, zero steer), so gradients stay finite.

The simulator does not call these functions directly: it goes through a
``DynamicsModel`` (``SimConfig.dynamics_model``, default
``KinematicBicycle()``, the model of this module). Another ego model is a
frozen, hashable class with the same three methods (``initial_state``,
``step``, ``inverse``), registered in ``DYNAMICS_MODELS``.
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, Protocol, runtime_checkable

import jax.numpy as jnp
from flax import struct

from drivee2e_jax import geometry
from drivee2e_jax.types import Controls, EgoState

Array = jnp.ndarray


@struct.dataclass
class BicycleParams:
    """Vehicle parameters (frozen and hashable: pass as a jit static argument
    or as a pytree of scalars, e.g. to vmap over vehicles).

    Attributes:
      wheelbase:      m (a mid-size car; CARLA's Lincoln MKZ is ~2.9 m).
      max_steer:      rad, front-wheel angle at steer = +-1 (35 deg).
      max_accel:      m/s^2 at throttle 1 (before drag).
      max_decel:      m/s^2 at brake 1 (before drag).
      max_speed:      m/s.
      drag_const:     m/s^2, rolling resistance (applies while moving, holds a
                      standing car).
      drag_quad:      1/m, aerodynamic drag coefficient: ``drag_quad * v**2``
                      m/s^2 (0.625 m/s^2 at 25 m/s).
      max_steer_rate: rad/s limit on the steer angle change; ``inf`` = off.
    """

    wheelbase: float = 2.9
    max_steer: float = 0.61
    max_accel: float = 3.5
    max_decel: float = 8.0
    max_speed: float = 25.0
    drag_const: float = 0.2
    drag_quad: float = 0.001
    max_steer_rate: float = float("inf")

    @property
    def lr(self) -> float:
        """Distance from the rear axle to the reference point (box centre), m."""
        return 0.5 * self.wheelbase


def drag(speed: Array, params: BicycleParams) -> Array:
    """() m/s^2 resistance deceleration at ``speed`` (>= 0)."""
    return params.drag_const + params.drag_quad * speed**2


def controls_to_accel_steer(
    controls: Controls, speed: Array, params: BicycleParams
) -> tuple[Array, Array]:
    """CARLA-style mapping of controls to (net accel m/s^2, steer angle rad).

    throttle, brake are clipped to [0, 1] and steer to [-1, 1] (+1 = left);
    accel includes ``drag(speed)`` and may be negative at speed 0 (the step
    clips the speed, not the acceleration).
    """
    throttle = jnp.clip(controls.throttle, 0.0, 1.0)
    brake = jnp.clip(controls.brake, 0.0, 1.0)
    accel = throttle * params.max_accel - brake * params.max_decel - drag(speed, params)
    return accel, jnp.clip(controls.steer, -1.0, 1.0) * params.max_steer


def _sinc(x: Array) -> Array:
    """sin(x)/x with a smooth, NaN-free value and gradient at 0."""
    small = jnp.abs(x) < 1e-3
    xs = jnp.where(small, 1.0, x)
    return jnp.where(small, 1.0 - x**2 / 6.0, jnp.sin(xs) / xs)


def _distance(v0: Array, accel: Array, dt: Array, v_max: float) -> tuple[Array, Array]:
    """Distance travelled and end speed over ``dt`` at constant ``accel``,
    speed clipped to [0, v_max] from the moment it hits a bound."""
    v1 = jnp.clip(v0 + accel * dt, 0.0, v_max)
    moving = jnp.abs(accel) > 1e-6
    a_safe = jnp.where(moving, accel, 1.0)
    t_clip = jnp.where(moving, jnp.clip((v1 - v0) / a_safe, 0.0, dt), dt)
    s = v0 * t_clip + 0.5 * accel * t_clip**2 + v1 * (dt - t_clip)
    return jnp.maximum(s, 0.0), v1


def _arc_pose(xy: Array, yaw: Array, s: Array, beta: Array, lr: float):
    """Pose after travelling ``s`` along the arc that leaves ``xy`` at heading
    ``yaw + beta`` with curvature sin(beta)/lr. Returns (xy, yaw, dyaw)."""
    dyaw = s * jnp.sin(beta) / lr
    chord = s * _sinc(0.5 * dyaw)
    direction = yaw + beta + 0.5 * dyaw
    return xy + chord * jnp.stack([jnp.cos(direction), jnp.sin(direction)]), yaw + dyaw, dyaw


def step(ego: EgoState, controls: Controls, dt: Array, params: BicycleParams) -> EgoState:
    """Advance the ego by ``dt`` s under ``controls`` held constant.

    Returns the new EgoState with ``accel`` the realised mean acceleration
    ((v1 - v0) / dt, so 0 for a car held at rest), ``steer`` the applied
    front-wheel angle, ``yaw_rate`` the mean over the step, ``yaw`` wrapped to
    (-pi, pi], ``t`` advanced by ``dt``.
    """
    v0 = jnp.clip(ego.speed, 0.0, None)
    accel, steer_cmd = controls_to_accel_steer(controls, v0, params)
    max_dsteer = params.max_steer_rate * dt
    steer = jnp.clip(steer_cmd, ego.steer - max_dsteer, ego.steer + max_dsteer)
    s, v1 = _distance(v0, accel, dt, params.max_speed)
    beta = jnp.arctan(0.5 * jnp.tan(steer))  # lr / L = 1/2
    xy, yaw, dyaw = _arc_pose(ego.xy, ego.yaw, s, beta, params.lr)
    return EgoState(
        xy=xy,
        yaw=geometry.wrap_angle(yaw),
        speed=v1,
        accel=(v1 - v0) / dt,
        steer=steer,
        yaw_rate=dyaw / dt,
        t=ego.t + dt,
    )


def _accel_for_distance(v0: Array, s: Array, dt: Array, v_max: float) -> Array:
    """Net constant acceleration that travels ``s`` m in ``dt`` from speed
    ``v0`` under the speed clip of ``_distance`` (inverse of it).

    Three regimes: no clip (s = v0 dt + a dt^2/2); stopping inside the step
    (s < v0 dt / 2: a = -v0^2 / 2s); reaching v_max inside the step
    (s > (v0 + v_max) dt / 2). Unreachable distances saturate.
    """
    a_free = 2.0 * (s - v0 * dt) / dt**2
    a_stop = -(v0**2) / (2.0 * jnp.maximum(s, 1e-6))
    gap = jnp.maximum(v_max * dt - s, 1e-6)
    a_top = (v_max - v0) ** 2 / (2.0 * gap)
    return jnp.where(
        s < 0.5 * v0 * dt, a_stop, jnp.where(s > 0.5 * (v0 + v_max) * dt, a_top, a_free)
    )


def inverse(
    ego: EgoState, next_xy: Array, next_yaw: Array, dt: Array, params: BicycleParams
) -> Controls:
    """Controls that carry ``ego`` to the logged next pose in one ``dt`` step.

    The one-step reachable set is two-dimensional (distance, curvature) while
    a pose has three numbers, so we match the POSITION exactly (when within
    the limits) and let the heading follow the model. Matching the position
    gives replay feedback: an error left by one step is corrected by the next,
    whereas matching the logged heading change would integrate every
    inconsistency of the log (noise, a yaw that is the path tangent rather
    than the body heading) into a position drift. On a log the model could
    have produced, position and heading are both reproduced.

    The arc through the chord (dx, dy) in the ego frame leaving at slip angle
    beta satisfies ``tan(beta) = 2 lr dy / (d^2 + 2 lr dx)`` (closed form of
    "chord direction = beta + half the heading change"); the travelled arc
    length follows from the chord and the heading change.

    ``next_yaw`` is part of the pose-complete signature but not needed by this
    model: the heading is the consequence of matching the position. Chords of
    a few millimetres (a standing or creeping car, where position noise
    dominates the direction) blend towards holding the current steer. A
    standing target holds the brake. The steer-rate limit is not inverted.

    Args:
      ego: current EgoState.  next_xy: (2,) m.  next_yaw: () rad.  dt: () s.

    Returns:
      Controls with throttle, brake in [0, 1] (never both > 0), steer in [-1, 1].
    """
    del next_yaw  # see above: the heading follows from the position
    lr = params.lr
    v0 = jnp.clip(ego.speed, 0.0, None)
    dx, dy = geometry.to_frame(next_xy, ego.xy, ego.yaw)
    d2 = dx**2 + dy**2
    # Position branch: slip angle of the arc through the chord.
    den = d2 + 2.0 * lr * dx
    num = 2.0 * lr * dy
    ok = (jnp.abs(num) + jnp.abs(den)) > 1e-12
    beta_pos = jnp.arctan2(jnp.where(ok, num, 0.0), jnp.where(ok, den, 1.0))
    beta_max = jnp.arctan(0.5 * jnp.tan(params.max_steer))
    beta_pos = jnp.clip(beta_pos, -beta_max, beta_max)
    # Arc length from the chord: dyaw = 2 (theta - beta) with theta the chord
    # direction, and s = d / sinc(dyaw / 2). Going backwards is impossible:
    # only the forward component of the chord counts then.
    d = geometry.safe_norm(jnp.stack([dx, dy]))
    cb, sb = jnp.cos(beta_pos), jnp.sin(beta_pos)
    moved = d2 > 1e-12
    half_turn = jnp.arctan2(jnp.where(moved, dy * cb - dx * sb, 0.0),
                            jnp.where(moved, dx * cb + dy * sb, 1.0))
    s = jnp.where(dx > 0, d / _sinc(half_turn), 0.0)
    # A chord of a few mm carries no usable direction (position noise, or a
    # standing car) and the steer barely moves the pose: keep the current one.
    beta_prev = jnp.arctan(0.5 * jnp.tan(ego.steer))
    w = d2 / (d2 + 0.005**2)
    beta = w * beta_pos + (1.0 - w) * beta_prev
    steer = jnp.arctan(2.0 * jnp.tan(beta)) / params.max_steer  # tan(delta) = L/lr tan(beta)

    accel_net = _accel_for_distance(v0, s, dt, params.max_speed)
    accel_cmd = accel_net + drag(v0, params)
    hold = (v0 < 1e-3) & (s < 1e-4)  # standing target: keep the brake on
    throttle = jnp.where(hold, 0.0, jnp.clip(accel_cmd / params.max_accel, 0.0, 1.0))
    brake = jnp.where(hold, 1.0, jnp.clip(-accel_cmd / params.max_decel, 0.0, 1.0))
    return Controls(throttle=throttle, brake=brake, steer=jnp.clip(steer, -1.0, 1.0))


def ego_from_log(xy: Array, yaw: Array, vel: Array, t: Array) -> EgoState:
    """Initial EgoState from one log sample: ``xy (2,)`` m, ``yaw ()`` rad,
    ``vel (2,)`` world-frame m/s, ``t ()`` s. Speed is the velocity projected
    on the heading, clipped at 0 (a reversing log sample starts at rest);
    accel, steer and yaw_rate start at 0."""
    heading = jnp.stack([jnp.cos(yaw), jnp.sin(yaw)])
    zero = jnp.zeros((), jnp.float32)
    return EgoState(
        xy=jnp.asarray(xy, jnp.float32),
        yaw=jnp.asarray(yaw, jnp.float32),
        speed=jnp.maximum(jnp.dot(vel, heading), 0.0).astype(jnp.float32),
        accel=zero,
        steer=zero,
        yaw_rate=zero,
        t=jnp.asarray(t, jnp.float32),
    )


# --------------------------------------------------------------------------
# The model protocol the simulator goes through
# --------------------------------------------------------------------------


@runtime_checkable
class DynamicsModel(Protocol):
    """An ego vehicle model: what ``sim.Simulator`` needs of the ego's motion.

    Implementations are frozen and hashable (they sit in the jit-static
    ``SimConfig``) and hold no arrays; vehicle parameters come separately as
    ``params`` (``SimConfig.dynamics``; for the bicycle a ``BicycleParams``).
    The waypoint controller reads the same ``params`` as
    ``ControllerParams.vehicle`` (``wheelbase``, ``max_steer``,
    ``max_accel``, ``max_decel``, ``drag_const``, ``drag_quad``), so a
    model's params must provide those fields for waypoint policies.
    Every method is unbatched, pure and jit/vmap friendly.

    Attributes:
      name: registry name (``DYNAMICS_MODELS``).
    """

    name: ClassVar[str]

    def initial_state(self, xy: Array, yaw: Array, vel: Array, t: Array) -> EgoState:
        """Ego state at reset from one log sample: ``xy (2,)`` m, ``yaw ()``
        rad, ``vel (2,)`` world-frame m/s, ``t ()`` s."""
        ...

    def step(self, ego: EgoState, controls: Controls, dt: Array, params: Any) -> EgoState:
        """The ego after ``dt`` s under ``controls`` (throttle, brake [0, 1],
        steer [-1, 1], already sanitised) held constant. ``accel``,
        ``steer`` (front-wheel angle, rad) and ``yaw_rate`` are the
        realised values of the step, ``yaw`` wrapped to (-pi, pi]."""
        ...

    def inverse(self, ego: EgoState, next_xy: Array, next_yaw: Array, dt: Array, params: Any) -> Controls:
        """Controls that carry ``ego`` to the logged next pose (``next_xy``
        (2,) m, ``next_yaw`` () rad) in one ``dt`` step: the log-derived
        reference action (``types.Privileged.log_controls``)."""
        ...


@dataclasses.dataclass(frozen=True)
class KinematicBicycle:
    """The kinematic bicycle of this module as a ``DynamicsModel`` (the
    default ``SimConfig.dynamics_model``); ``params`` is a ``BicycleParams``.
    Stateless: every instance is equal and hashes alike."""

    name: ClassVar[str] = "kinematic_bicycle"

    def initial_state(self, xy: Array, yaw: Array, vel: Array, t: Array) -> EgoState:
        return ego_from_log(xy, yaw, vel, t)

    def step(self, ego: EgoState, controls: Controls, dt: Array, params: BicycleParams) -> EgoState:
        return step(ego, controls, dt, params)

    def inverse(self, ego: EgoState, next_xy: Array, next_yaw: Array, dt: Array, params: BicycleParams) -> Controls:
        return inverse(ego, next_xy, next_yaw, dt, params)


#: Dynamics models by name.
DYNAMICS_MODELS: dict[str, DynamicsModel] = {KinematicBicycle.name: KinematicBicycle()}


def get_dynamics_model(name: str) -> DynamicsModel:
    """The registered model called ``name``; ValueError listing the names otherwise."""
    if name not in DYNAMICS_MODELS:
        raise ValueError(f"unknown dynamics model {name!r}; expected one of {', '.join(DYNAMICS_MODELS)}")
    return DYNAMICS_MODELS[name]
