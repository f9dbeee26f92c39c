"""Log replay at continuous time: agent states and signal states at any ``t``.

The log is sampled at ``t_k = k * dt_log``; the simulator may step at any
``dt`` (e.g. 0.05 s on a 0.1 s log). Agent states are interpolated linearly
between the two neighbouring samples (yaw the short way round the circle);
signal states are piecewise constant (the most recent sample).

Float tolerance: a simulator that accumulates ``t += dt`` in float32 drifts
by up to ~3e-3 log steps over 800 steps, so ``t / dt_log`` within ``SNAP``
(1e-2) steps of an integer counts as that sample for VALIDITY and for the
signal state (an agent's last valid sample stays valid, a light does not
switch late). Values snap only within ``EXACT`` (1e-4) steps, where they are
bit-exact samples (``t = 0.30000001`` at ``dt_log = 0.1`` is sample 3);
elsewhere they are the continuous interpolation. The value snap moves values
by at most 1e-4 of a step and keeps derivatives: ``d state / d t`` is the
slope of the interval, so states are differentiable w.r.t. ``t`` and the log.

Unbatched: one scenario; ``agents_at`` maps over the agents itself.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from drivee2e_jax.geometry import wrap_angle
from drivee2e_jax.types import Signals, Tracks

Array = jnp.ndarray

#: Tolerance, in log steps, for "t lands on a sample" (validity, signals).
SNAP = 1e-2
#: Tolerance, in log steps, within which values are exactly the sample.
EXACT = 1e-4


@struct.dataclass
class AgentStates:
    """Replayed agents at one instant.

    Attributes:
      xy:    (A, 2) float32 box centre, m.
      yaw:   (A,) float32 heading in (-pi, pi], rad.
      vel:   (A, 2) float32 world-frame velocity, m/s.
      valid: (A,) bool, both neighbouring log samples valid (or the sample
        itself when t lands on one) and t inside the log.
    """

    xy: Array
    yaw: Array
    vel: Array
    valid: Array


def _time_index(t: Array, dt_log: Array, num_steps: int):
    """Locate ``t`` on the log grid.

    Returns (k, r, base_next, on_sample, inside): interval [k, k+1] with k in
    [0, T-2]; the value is ``sample(base) + r * (sample(k+1) - sample(k))``
    with base = k+1 if ``base_next`` else k. ``on_sample``: t is within SNAP
    of sample ``k + base_next``. Off-sample, r is the interpolation weight
    (clipped to [0, 1] so out-of-log times hold the end sample); within EXACT
    of a sample r is exactly 0 in value but keeps d r / d t = 1 / dt_log.
    """
    u = t / dt_log
    k_near = jnp.round(u)
    on_sample = jnp.abs(u - k_near) <= SNAP
    exact = jnp.abs(u - k_near) <= EXACT
    k = jnp.where(on_sample, k_near, jnp.floor(u))
    k = jnp.clip(k, 0, max(num_steps - 2, 0))
    base_next = on_sample & (k_near == k + 1)
    r = u - (k + base_next)
    r = jnp.where(exact, r - jax.lax.stop_gradient(r), r)
    r = jnp.where(on_sample, r, jnp.clip(r, 0.0, 1.0))
    inside = (u >= -SNAP) & (u <= (num_steps - 1) + SNAP)
    return k.astype(jnp.int32), r, base_next, on_sample, inside


def _interp_one(xy, yaw, vel, valid, t, dt_log):
    """One agent: xy (T,2), yaw (T,), vel (T,2), valid (T,) -> state at t."""
    num_steps = xy.shape[0]
    k, r, base_next, on_sample, inside = _time_index(t, dt_log, num_steps)
    k1 = jnp.minimum(k + 1, num_steps - 1)
    v0, v1 = valid[k], valid[k1]
    # A padded neighbour must not leak into the value (nor its gradient).
    xy1 = jnp.where(v1, xy[k1], xy[k])
    yaw1 = jnp.where(v1, yaw[k1], yaw[k])
    vel1 = jnp.where(v1, vel[k1], vel[k])
    xy0 = jnp.where(v0, xy[k], xy1)
    yaw0 = jnp.where(v0, yaw[k], yaw1)
    vel0 = jnp.where(v0, vel[k], vel1)
    state_xy = jnp.where(base_next, xy1, xy0) + r * (xy1 - xy0)
    state_yaw = wrap_angle(jnp.where(base_next, yaw1, yaw0) + r * wrap_angle(yaw1 - yaw0))
    state_vel = jnp.where(base_next, vel1, vel0) + r * (vel1 - vel0)
    # On a sample only that sample's validity counts.
    ok = jnp.where(on_sample, jnp.where(base_next, v1, v0), v0 & v1) & inside
    return state_xy, state_yaw, state_vel, ok


def agents_at(tracks: Tracks, t: Array, dt_log: Array) -> AgentStates:
    """All logged agents at time ``t`` (s) on a log of step ``dt_log`` (s).

    Linear interpolation between samples floor(t / dt_log) and the next; yaw
    the short way round. Invalid outside [0, (T-1) dt_log] or when a needed
    sample is invalid (the values are then still finite: the valid
    neighbour's, or garbage-free padding). Exact at sample times.
    """
    xy, yaw, vel, ok = jax.vmap(_interp_one, in_axes=(0, 0, 0, 0, None, None))(
        tracks.xy, tracks.yaw, tracks.vel, tracks.valid, t, dt_log
    )
    return AgentStates(xy=xy, yaw=yaw, vel=vel, valid=ok)


def ego_log_at(tracks: Tracks, ego_index: Array, t: Array, dt_log: Array) -> AgentStates:
    """The logged state of one agent (the ego) at ``t``: an AgentStates with
    unbatched fields xy (2,), yaw (), vel (2,), valid ()."""
    xy, yaw, vel, ok = _interp_one(
        tracks.xy[ego_index], tracks.yaw[ego_index], tracks.vel[ego_index],
        tracks.valid[ego_index], t, dt_log,
    )
    return AgentStates(xy=xy, yaw=yaw, vel=vel, valid=ok)


def signals_at(signals: Signals, t: Array, dt_log: Array) -> Array:
    """(S,) int32 signal states at ``t``: the most recent log sample at or
    before t (within ``SNAP`` steps), clamped to the first / last sample."""
    num_steps = signals.state.shape[-1]
    k = jnp.floor(t / dt_log + SNAP)
    k = jnp.clip(k, 0, num_steps - 1).astype(jnp.int32)
    return signals.state[:, k].astype(jnp.int32)
