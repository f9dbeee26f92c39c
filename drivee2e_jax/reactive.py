"""Reactive IDM agents (``--agents idm``): logged vehicles that yield.

In plain log replay (``replay.py``) no agent reacts to the ego. Here, as in
nuPlan's reactive setting, every logged VEHICLE (car, truck, bus, van,
motorcycle, tricycle) keeps its LOGGED PATH (the polyline through its valid
logged positions) but its speed along that path follows the Intelligent
Driver Model, reacting to the ego and to the other agents. Pedestrians,
cyclists, static vehicles (never faster than ``STATIC_SPEED`` in the log) and
the ego's own track row replay the log exactly (``replay.agents_at``).

The faithfulness rule: an IDM agent is never AHEAD of its logged position,
``s(t) <= s_log(t)`` (``s`` arc length along the logged path). An
unobstructed agent therefore replays its log exactly (position, heading and
velocity are the replayed ones); only a leader makes it lag, and a lagging
agent catches up with IDM's free-road acceleration until it meets its log
again, where its speed snaps to the logged speed (the position stays
continuous). Per step, with ``a_int = -a (s*/gap)^2`` the leader term:

* on its log:  ``v' = v_log(t+dt) + a_int dt``, ``s' = s_log(t+dt) + (v' - v_log(t+dt)) dt / 2``
  (the log plays IDM's free-road part, so the log's own accelerations,
  which may exceed ``a``, do not make an unobstructed agent lag);
* lagging:     ``v' = v + (a (1 - (v/v0)^delta) + a_int) dt`` (plain IDM),
  ``s' = s + (v + v') dt / 2``;
* then ``v' >= 0``, ``s'`` clipped to ``[s, s_log(t+dt)]`` and to
  ``s + max(gap, 0)`` (never into the leader).

Agents the log does not show at ``t`` (not yet appeared, gone, a gap) follow
the log (``s = s_log``, ``v`` = logged speed) and are invalid exactly when the
log says so.

Leader: the nearest valid object (the ego box or another agent) on the
agent's OWN PATH ahead: its logged path, continued past its end along the
lane holding that end and the lane's first successor (``leader_paths``,
once per episode). An object leads when its box, measured across the path,
reaches within the agent's half width (+ ``lateral_margin``, default 0) of
the path; the gap is the arc distance to its foot point minus both half
extents along the path; the leader's speed is its velocity along the path
(``leaders``). nuPlan does the same with the agent's route along lanes
buffered by its half width (``nuplan/planning/simulation/observation/idm/
idm_agent_manager.py`` ``IDMAgentManager.propagate_agents``); until issue 35
this was a straight band along the agent's heading, which finds cars in
other lanes on a curve and misses the car ahead on it.

IDM itself follows Waymax ``waymax/agents/waypoint_following_agent.py``
``IDMRoutePolicy._get_accel`` (defaults s0 2 m, T 2 s, a 2 m/s^2, b 4 m/s^2,
delta 4; ``s* = s0 + max(0, v T + v dv / (2 sqrt(a b)))``; minimum gap 0.1 m)
and nuPlan ``nuplan/planning/simulation/observation/idm/idm_policy.py``
``IDMPolicy.idm_model`` (forward Euler on progress and velocity).

Desired speed ``v0``: the brief's "larger of the logged speed at t and the
max logged speed" is the max logged speed (the first never exceeds the
second); we use ``v0 = v0_scale * max(max logged speed, v0_min)`` with
``v0_scale = 1.2``: at ``v0`` equal to the logged cruise speed a lagging
agent's free-road acceleration vanishes as it reaches that speed and it
never catches up; 20 % headroom lets it close the lag in bounded time, and
the ``s <= s_log`` cap keeps it from overshooting. ``v0`` is constant per
episode and computed once (``init``), so it lives in ``IDMState``.

Measuring drift from the log (ego replaying its log): ``drift(scenario, dt,
num_steps)`` returns the mean / max position error over valid reactive
agent-steps (host function, one scenario).

Unbatched: one scenario; ``jax.vmap`` over scenarios.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
from flax import struct

from drivee2e_jax import replay
from drivee2e_jax.geometry import wrap_angle
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import Category, Polylines, Scenario, Tracks

Array = jnp.ndarray

#: Categories driven by IDM; pedestrians and cyclists replay the log.
REACTIVE_CATEGORIES = (
    int(Category.CAR), int(Category.TRUCK), int(Category.BUS), int(Category.VAN),
    int(Category.MOTORCYCLE), int(Category.TRICYCLE),
)
#: m/s; a vehicle never faster than this in its log is static and replays it
#: (Waymax ``waypoint_following_agent.py`` ``_STATIC_SPEED_THRESHOLD``).
STATIC_SPEED = 1.0
#: m; smallest gap fed to IDM (Waymax ``_MINIMUM_LEAD_DISTANCE``).
MIN_GAP = 0.1


@dataclasses.dataclass(frozen=True)
class IDMParams:
    """IDM parameters (hashable: static under jit).

    Attributes:
      s0: minimum gap, m.
      time_headway: desired time headway T, s.
      accel: maximum acceleration a, m/s^2.
      decel: comfortable deceleration b (positive), m/s^2.
      delta: acceleration exponent.
      lateral_margin: m added to the agent's half width when testing whether an
        object's box reaches its path (``leaders``); 0 as nuPlan.
      v0_scale: desired speed / max logged speed (catch-up headroom).
      v0_min: m/s floor of the desired speed (keeps v / v0 finite).
    """

    s0: float = 2.0
    time_headway: float = 2.0
    accel: float = 2.0
    decel: float = 4.0
    delta: float = 4.0
    lateral_margin: float = 0.0
    v0_scale: float = 1.2
    v0_min: float = 1.0


@struct.dataclass
class IDMState:
    """IDM agents' longitudinal state.

    Attributes:
      s:  (A,) float32 arc position along the agent's logged path, m.
      v:  (A,) float32 speed along it, m/s (>= 0).
      v0: (A,) float32 desired speed, m/s (constant over the episode).
      active: (A,) bool rows driven by IDM (``reactive_mask``; constant).
      on_log: (A,) bool the agent sits exactly on its log (``s = s_log(t)``,
        ``v`` = logged speed) and replays it; a flag rather than a float
        comparison, so float32 time round-off never makes an agent "lag".
      k: (A,) int32 the logged-path segment [k, k + 1] holding ``s``
        (``arc[k] <= s``); k0: (A,) int32 the last valid sample at or before
        k (where the segment starts when k falls in a gap). Tracked
        incrementally (``advance_segment``), so placing an agent costs a few
        gathers instead of a search over the whole log.
      agents: ``replay.AgentStates`` (A, ...) of every row at the state's
        time (``agents_at`` of this state; kept so a step computes the
        agents once: the simulator reads them from here).
    """

    s: Array
    v: Array
    v0: Array
    active: Array
    on_log: Array
    k: Array
    k0: Array
    agents: AgentStates


# --------------------------------------------------------------------------
# The logged path
# --------------------------------------------------------------------------


def path_arc(tracks: Tracks) -> Array:
    """(A, T) float32 cumulative arc length (m) of each agent's valid logged
    positions at every log step.

    Segment k -> k+1 has the length from the last valid sample at or before k
    to sample k+1 when k+1 is valid, else 0: invalid samples carry the arc,
    leading invalid samples have arc 0. Non-decreasing; precompute once per
    scenario.
    """
    num_steps = tracks.xy.shape[-2]
    start = _last_valid(tracks.valid)  # (A, T)
    p0 = jnp.take_along_axis(tracks.xy, start[..., None], axis=-2)[:, :-1]
    seg = jnp.linalg.norm(tracks.xy[:, 1:] - p0, axis=-1)
    seg = jnp.where(tracks.valid[:, 1:], seg, 0.0)
    zero = jnp.zeros(seg.shape[:-1] + (1,), seg.dtype)
    arc = jnp.concatenate([zero, jnp.cumsum(seg, axis=-1)], axis=-1)
    return arc[:, :num_steps].astype(jnp.float32)


def _last_valid(valid: Array) -> Array:
    """(A, T) int32 index of the last valid sample at or before each step (the
    first valid one before the first; 0 for an agent never valid)."""
    num_steps = valid.shape[-1]
    idx = jnp.where(valid, jnp.arange(num_steps), -1)
    last = jax.lax.cummax(idx, axis=idx.ndim - 1)
    first = jnp.argmax(valid, axis=-1)[..., None]
    return jnp.where(last < 0, first, last).astype(jnp.int32)


def arc_at(arc: Array, t: Array, dt_log: Array) -> Array:
    """(A,) logged arc position s_log(t), m: ``arc`` (A, T) interpolated
    linearly in time, held at the ends."""
    num_steps = arc.shape[-1]
    u = t / dt_log
    k = jnp.clip(jnp.floor(u), 0, max(num_steps - 2, 0)).astype(jnp.int32)
    k1 = jnp.minimum(k + 1, num_steps - 1)
    r = jnp.clip(u - k, 0.0, 1.0)
    return arc[:, k] + r * (arc[:, k1] - arc[:, k])


#: Log samples a path segment may advance in one step (``advance_segment``).
#: A lagging agent moves at most ``v0 dt`` per step; it crosses more than 8
#: samples only where the log crawled (samples < v0 dt / 8 apart: < 0.19 m at
#: 15 m/s and 0.1 s) and then reaches its true segment over the next steps
#: (placed at the window's end meanwhile). 8 rather than 16: a third of the
#: IDM step's cost went into this window's gathers.
SEGMENT_WINDOW = 8


def time_segment(t: Array, dt_log: Array, num_steps: int) -> Array:
    """() int32 the log interval [k, k + 1] holding time ``t`` (clipped to [0, T - 2])."""
    return jnp.clip(jnp.floor(t / dt_log + 1e-4), 0, max(num_steps - 2, 0)).astype(jnp.int32)


def advance_segment(k: Array, k0: Array, s: Array, arc: Array, valid: Array) -> tuple[Array, Array]:
    """(k, k0) moved forward to the segment holding arc ``s`` (A,), looking at
    most ``SEGMENT_WINDOW`` samples past ``k``: ``arc`` (A, T) is
    non-decreasing, so the samples with ``arc <= s`` in the window are a
    prefix; ``k0`` becomes the last valid one of them (or stays)."""
    num_steps = arc.shape[-1]
    win = k[:, None] + 1 + jnp.arange(SEGMENT_WINDOW)  # (A, W) candidate segment starts
    idx = jnp.minimum(win, num_steps - 1)
    passed = (win <= num_steps - 2) & (jnp.take_along_axis(arc, idx, axis=-1) <= s[:, None])
    k_new = k + passed.sum(axis=-1, dtype=jnp.int32)
    valid_w = jnp.take_along_axis(valid, idx, axis=-1)
    k0_new = jnp.maximum(k0, jnp.max(jnp.where(passed & valid_w, win, -1), axis=-1))
    return k_new.astype(jnp.int32), k0_new.astype(jnp.int32)


def _pose_on_segment(xy, yaw, valid, arc, s, k, k0):
    """One agent: xy (T,2), yaw (T,), valid (T,), arc (T,), s (), segment k
    and its valid start k0 (``IDMState``) -> (xy (2,), yaw ()) at arc s on the
    logged path. In a gap (k invalid) the arc does not grow, so the segment
    starts at the last valid sample k0."""
    k1 = k + 1
    p0, y0 = xy[k0], yaw[k0]
    p1 = jnp.where(valid[k1], xy[k1], p0)
    y1 = jnp.where(valid[k1], yaw[k1], y0)
    d = arc[k1] - arc[k]
    r = jnp.where(d > 0, (s - arc[k]) / jnp.where(d > 0, d, 1.0), 0.0)
    r = jnp.clip(r, 0.0, 1.0)
    return p0 + r * (p1 - p0), wrap_angle(y0 + r * wrap_angle(y1 - y0))


# --------------------------------------------------------------------------
# Which agents react
# --------------------------------------------------------------------------


def reactive_mask(tracks: Tracks, ego_index: Array) -> Array:
    """(A,) bool: rows driven by IDM (moving vehicles, not the ego row)."""
    vehicle = jnp.isin(tracks.category, jnp.asarray(REACTIVE_CATEGORIES))
    speed = jnp.where(tracks.valid, jnp.linalg.norm(tracks.vel, axis=-1), 0.0)
    moving = speed.max(axis=-1) > STATIC_SPEED
    not_ego = jnp.arange(tracks.category.shape[0]) != ego_index
    return vehicle & moving & not_ego


def desired_speed(tracks: Tracks, params: IDMParams) -> Array:
    """(A,) float32 IDM desired speed v0, m/s: ``v0_scale * max(max logged
    speed, v0_min)`` (module docstring: why not the plain max)."""
    speed = jnp.where(tracks.valid, jnp.linalg.norm(tracks.vel, axis=-1), 0.0)
    return (params.v0_scale * jnp.maximum(speed.max(axis=-1), params.v0_min)).astype(jnp.float32)


def init(tracks: Tracks, dt_log: Array, params: IDMParams = IDMParams(), *, ego_index: Array) -> IDMState:
    """State at t = 0 from the log: ``s = 0`` (the path starts at the first
    valid sample), ``v`` the logged speed at t = 0 (0 if not yet valid), the
    per-episode constants ``v0`` and ``active``."""
    log = replay.agents_at(tracks, jnp.zeros((), jnp.float32), dt_log)
    v = jnp.where(log.valid, jnp.linalg.norm(log.vel, axis=-1), 0.0)
    s = jnp.zeros(tracks.category.shape, jnp.float32)
    first = jnp.argmax(tracks.valid, axis=-1).astype(jnp.int32)
    return IDMState(s=s, v=v.astype(jnp.float32), v0=desired_speed(tracks, params),
                    active=reactive_mask(tracks, ego_index), on_log=jnp.ones(s.shape, bool),
                    k=jnp.zeros(s.shape, jnp.int32), k0=first, agents=log)


# --------------------------------------------------------------------------
# Poses, leaders, one step
# --------------------------------------------------------------------------


def agents_at(state: IDMState, tracks: Tracks, arc: Array, t: Array, dt_log: Array) -> AgentStates:
    """All agents at time ``t`` (s): lagging IDM agents at arc ``state.s`` on
    their logged path (heading interpolated from the logged yaw of the two
    path samples, velocity ``v * heading``); every other row (on-log IDM
    agents, pedestrians, cyclists, statics, the ego row) exactly
    ``replay.agents_at``. ``valid`` is the log's validity at ``t`` (the ego
    row included: mask it as ``Simulator.agents`` does).

    Args:
      arc: (A, T) ``path_arc(tracks)``.
    """
    return _placed(state, tracks, arc, replay.agents_at(tracks, t, dt_log))


def _placed(state: IDMState, tracks: Tracks, arc: Array, log: AgentStates) -> AgentStates:
    """``agents_at`` given the log's agents at that time (``log``)."""
    lagging = state.active & ~state.on_log
    xy, yaw = jax.vmap(_pose_on_segment)(tracks.xy, tracks.yaw, tracks.valid, arc, state.s, state.k, state.k0)
    vel = state.v[:, None] * jnp.stack([jnp.cos(yaw), jnp.sin(yaw)], axis=-1)
    return AgentStates(
        xy=jnp.where(lagging[:, None], xy, log.xy),
        yaw=jnp.where(lagging, yaw, log.yaw),
        vel=jnp.where(lagging[:, None], vel, log.vel),
        valid=log.valid,
    )


#: Points of a leader path (``leader_paths``): ``PATH_POINTS +
#: EXTENSION_POINTS``, evenly spaced over the logged path and its extension.
PATH_POINTS = 40
#: m; the smallest spacing of those points (longer paths are spaced wider).
PATH_DS = 4.0
#: The extension past the end of the logged path, along the map's lanes:
#: ``EXTENSION_POINTS`` points ``EXTENSION_DS`` m apart (32 m).
EXTENSION_POINTS = 8
EXTENSION_DS = 4.0
#: Path segments searched for a leader ahead of an agent each step: at least
#: ``LEADER_WINDOW * PATH_DS`` = 48 m, minus the part of the first segment
#: already behind the agent. IDM's leader term ``-a (s*/gap)^2`` at 48 m is
#: -0.9 m/s^2 for an agent at 15 m/s behind a stopped leader (s* = 32 m).
LEADER_WINDOW = 12
#: Objects per agent tried as its leader each step: those nearest to the
#: points of its path window (``leaders``).
LEADER_CANDIDATES = 8
#: A lane continues an agent's path when the path's end lies within its half
#: width plus this margin (m) of the centreline and their headings differ by
#: less than ``LANE_HEADING_COS`` (cos 45 deg).
LANE_MARGIN = 1.0
LANE_HEADING_COS = 0.7071


@struct.dataclass
class LeaderPaths:
    """Each agent's path ahead, for finding its leader (``leader_paths``).

    Attributes:
      xy:  (A, P, 2) float32 points, m: the logged path resampled by arc
           length (``PATH_POINTS``), then ``EXTENSION_POINTS`` along the lane
           that continues it and that lane's first successor (straight on
           along the final heading where no lane does).
      arc: (A, P) float32 arc position of each point on the agent's path, m,
           in ``path_arc``'s coordinate (so ``arc - s`` is distance ahead).
    """

    xy: Array
    arc: Array


def _resample(points: Array, arc: Array, at: Array) -> Array:
    """Points (N, 2) with non-decreasing arc (N,) at arc positions ``at`` (K,)."""
    return jnp.stack([jnp.interp(at, arc, points[:, 0]), jnp.interp(at, arc, points[:, 1])], axis=-1)


def _lane_extension(end: Array, heading: Array, lanes: Polylines, lane_width: Array,
                    successors: Array) -> tuple[Array, Array]:
    """``EXTENSION_POINTS`` points (K, 2) continuing a path that ends at
    ``end`` (2,) heading ``heading`` () along the lane that holds it and that
    lane's first successor, and their distances from ``end`` along that
    chain (K,), m. Straight on along ``heading`` where no lane matches."""
    a, b = lanes.xy[:, :-1], lanes.xy[:, 1:]  # (L, N-1, 2)
    seg_ok = lanes.point_valid[:, :-1] & lanes.point_valid[:, 1:] & lanes.valid[:, None]
    d = b - a
    len2 = jnp.sum(d * d, axis=-1)
    t = jnp.clip(jnp.sum((end - a) * d, axis=-1) / jnp.where(len2 > 0, len2, 1.0), 0.0, 1.0)
    foot = a + t[..., None] * d
    dist = jnp.linalg.norm(end - foot, axis=-1)
    along = jnp.sum(d * jnp.stack([jnp.cos(heading), jnp.sin(heading)]), axis=-1)
    ok = seg_ok & (len2 > 0) & (along >= LANE_HEADING_COS * jnp.sqrt(len2)) & (
        dist <= 0.5 * lane_width[:, None] + LANE_MARGIN)
    score = jnp.where(ok, dist, jnp.inf).reshape(-1)
    best = jnp.argmin(score)
    found = jnp.isfinite(score[best])
    n_seg = a.shape[1]
    lane, k = best // n_seg, best % n_seg
    succ = successors[lane, 0]
    has_succ = succ >= 0
    succ = jnp.maximum(succ, 0)
    n = lanes.xy.shape[1]
    # The chain: the foot point, lane points after segment k, successor points.
    pts = jnp.concatenate([foot[lane, k][None], lanes.xy[lane], lanes.xy[succ]], axis=0)
    valid = jnp.concatenate([jnp.ones((1,), bool), lanes.point_valid[lane] & (jnp.arange(n) > k),
                             lanes.point_valid[succ] & lanes.valid[succ] & has_succ])
    pts = jnp.take_along_axis(pts, _last_valid(valid[None])[0][:, None], axis=0)
    seg = jnp.linalg.norm(jnp.diff(pts, axis=0), axis=-1)
    chain_arc = jnp.concatenate([jnp.zeros((1,)), jnp.cumsum(seg)])
    at = EXTENSION_DS * (1.0 + jnp.arange(EXTENSION_POINTS, dtype=jnp.float32))
    on_lane = _resample(pts, chain_arc, jnp.minimum(at, chain_arc[-1]))
    straight = end + at[:, None] * jnp.stack([jnp.cos(heading), jnp.sin(heading)])
    lead_in = jnp.linalg.norm(foot[lane, k] - end)
    return (jnp.where(found, on_lane, straight),
            jnp.where(found, lead_in + jnp.minimum(at, chain_arc[-1]), at))


def leader_paths(tracks: Tracks, arc: Array, lanes: Polylines | None = None, lane_width: Array | None = None,
                 successors: Array | None = None) -> LeaderPaths:
    """Each agent's path ahead (``LeaderPaths``), computed once per episode.

    The logged path (through the valid logged positions, ``path_arc``'s arc
    coordinate), continued for ``EXTENSION_POINTS * EXTENSION_DS`` m past its
    end along the lane that holds the end (heading within 45 deg, within
    half its width + 1 m of the centreline) and that lane's first successor
    (straight on without a map, ``lanes`` None, or a matching lane), is
    resampled at ``PATH_POINTS + EXTENSION_POINTS`` points spaced
    ``max(PATH_DS, length / (points - 1))`` apart (chords: the path's end
    corner may be cut by a few cm). An agent never drives past its
    logged path; the extension lets it see a leader standing just beyond it.

    Args:
      tracks: the log (A, T); arc: (A, T) ``path_arc(tracks)``.
      lanes: Polylines (L, N) centrelines; lane_width (L,) m; successors (L, K) int32.
    """
    last = _last_valid(tracks.valid)  # (A, T)
    filled = jnp.take_along_axis(tracks.xy, last[..., None], axis=-2)
    total = arc[:, -1]
    end = filled[:, -1]
    heading = jnp.take_along_axis(tracks.yaw, last[:, -1:], axis=-1)[:, 0]
    if lanes is None:
        step = EXTENSION_DS * (1.0 + jnp.arange(EXTENSION_POINTS, dtype=jnp.float32))
        ext = end[:, None] + step[None, :, None] * jnp.stack([jnp.cos(heading), jnp.sin(heading)], -1)[:, None]
        ext_arc = jnp.broadcast_to(step, (end.shape[0], EXTENSION_POINTS))
    else:  # one agent at a time: the (A, L, N) distances of all at once are large under a batch vmap
        ext, ext_arc = jax.lax.map(lambda eh: _lane_extension(eh[0], eh[1], lanes, lane_width, successors),
                                   (end, heading))
    # One arc coordinate: the log up to ``total``, then the extension (from
    # the path's end); every point evenly spaced over both, so a short path
    # does not spend points the window would have to skip.
    chain = jnp.concatenate([end[:, None], ext], axis=1)
    chain_arc = jnp.concatenate([jnp.zeros_like(total)[:, None], ext_arc], axis=1)
    num = PATH_POINTS + EXTENSION_POINTS
    length = total + chain_arc[:, -1]
    ds = jnp.maximum(PATH_DS, length / (num - 1))
    at = jnp.minimum(jnp.arange(num, dtype=jnp.float32)[None] * ds[:, None], length[:, None])
    on_log = jax.vmap(_resample)(filled, arc, jnp.minimum(at, total[:, None]))
    beyond = jax.vmap(_resample)(chain, chain_arc, jnp.maximum(at - total[:, None], 0.0))
    xy = jnp.where((at <= total[:, None])[..., None], on_log, beyond)
    return LeaderPaths(xy=xy.astype(jnp.float32), arc=at.astype(jnp.float32))


def leader_reach(seg_len: Array, lw: Array, obj_lw: Array, lateral_margin: float) -> Array:
    """(A, M) m: how far from the nearest of the window points 0, 3, 6, ...
    (``leaders``) an object's centre can be and still lead agent i: half the
    longest group of 3 window segments (``seg_len`` (A, W) m; every point of
    the window is that close to one of those points along the path) plus the
    agent's half width (``lw`` (A, 2) m) plus ``lateral_margin`` plus half
    the object's diagonal (``obj_lw`` (M, 2) m: the most its box reaches
    across any path), plus 1 mm for float round-off. A bound, not a test:
    every object that leads is within it."""
    groups = seg_len.reshape(seg_len.shape[0], -1, 3).sum(axis=-1)  # (A, W / 3)
    half_diag = 0.5 * jnp.sqrt(obj_lw[:, 0] ** 2 + obj_lw[:, 1] ** 2)
    return (0.5 * groups.max(axis=-1) + 0.5 * lw[:, 1] + lateral_margin + 1e-3)[:, None] + half_diag[None, :]


def leaders(s: Array, lw: Array, paths: LeaderPaths, obj_xy: Array, obj_yaw: Array, obj_vel: Array,
            obj_lw: Array, obj_valid: Array, self_index: Array, lateral_margin: float) -> tuple[Array, Array, Array]:
    """Nearest object ahead on each agent's own path.

    An object leads agent i when its box, projected on the path's normal at
    its foot point, reaches within ``w_i / 2 + lateral_margin`` of the path
    (the object's half extent across the path counts its heading: a car
    crossing the path reaches ``l / 2`` across it) and its foot point lies
    ahead of the agent's arc position ``s``, within the ``LEADER_WINDOW``
    path segments ahead. The gap is the arc distance to the foot point minus
    ``l_i / 2`` and the object's half extent along the path; the leader's
    speed is its velocity along the path there.

    Args:
      s: (A,) the agents' arc positions, m; lw (A, 2) their length, width, m.
      paths: ``leader_paths`` (A, P).
      obj_xy (M, 2), obj_yaw (M,), obj_vel (M, 2), obj_lw (M, 2), obj_valid (M,): objects.
      self_index: (A,) int32 row of each agent among the objects (-1: none).
      lateral_margin: m added to the agent's half width.

    Returns:
      (has_leader (A,) bool, gap (A,) m bumper to bumper (inf if none; may be
      negative when boxes overlap), leader speed along the path (A,) m/s).
    """
    num_points = paths.arc.shape[-1]
    first = jnp.clip(jnp.sum(paths.arc <= s[:, None], axis=-1) - 1, 0, num_points - 2)  # segment holding s
    idx = jnp.minimum(first[:, None] + jnp.arange(LEADER_WINDOW + 1), num_points - 1)  # (A, W+1)
    pts = jnp.take_along_axis(paths.xy, idx[..., None], axis=1)
    parc = jnp.take_along_axis(paths.arc, idx, axis=1)
    a, d = pts[:, :-1], pts[:, 1:] - pts[:, :-1]  # (A, W, 2)
    a_arc, d_arc = parc[:, :-1], parc[:, 1:] - parc[:, :-1]
    seg_len = jnp.linalg.norm(d, axis=-1)
    ux = jnp.where(seg_len > 0, d[..., 0] / jnp.where(seg_len > 0, seg_len, 1.0), 1.0)
    uy = jnp.where(seg_len > 0, d[..., 1] / jnp.where(seg_len > 0, seg_len, 1.0), 0.0)
    not_self = jnp.arange(obj_xy.shape[0])[None, :] != self_index[:, None]
    usable = obj_valid[None, :] & not_self  # (A, M)
    # Candidates: the LEADER_CANDIDATES objects nearest to every third point
    # of the window that can lead at all, so the exact projection below runs
    # on (A, W, K) instead of (A, W, M). Every point of the window lies
    # within half a group's length (3 segments) of one of those 5 points, and
    # an object's box reaches at most half its diagonal across the path; an
    # object farther than that plus the agent's half width from every one
    # of them is on no segment (``leader_reach``), so ranking only the rest
    # makes the K exactly the exhaustive (A, W, M) search's result whenever
    # at most K objects are in reach (tests/test_reactive.py checks it on
    # twin15). The 5 distances are a running minimum of (A, M) arrays: the
    # same values as a min over an (A, 5, M) axis, 2-3x faster on XLA CPU.
    ox, oy = obj_xy[None, :, 0], obj_xy[None, :, 1]
    d2 = None
    for c in range(0, LEADER_WINDOW + 1, 3):
        e = (ox - pts[:, c, 0:1]) ** 2 + (oy - pts[:, c, 1:2]) ** 2
        d2 = e if d2 is None else jnp.minimum(d2, e)
    reach = leader_reach(seg_len, lw, obj_lw, lateral_margin)  # (A, M) m
    in_reach = usable & (d2 <= jnp.where(reach >= 0.0, reach * reach, -1.0))
    k = min(LEADER_CANDIDATES, obj_xy.shape[0])
    _, cand_idx = jax.lax.top_k(jnp.where(in_reach, -d2, -jnp.inf), k)  # (A, K)
    # One gather of every candidate attribute (five separate ones cost more).
    feat = jnp.concatenate([obj_xy, jnp.cos(obj_yaw)[:, None], jnp.sin(obj_yaw)[:, None], obj_vel, obj_lw], axis=-1)
    c_feat = feat[cand_idx]  # (A, K, 8)
    c_xy, c_vel, c_lw = c_feat[..., 0:2], c_feat[..., 4:6], c_feat[..., 6:8]
    cy, sy = c_feat[:, None, :, 2], c_feat[:, None, :, 3]
    c_ok = jnp.take_along_axis(in_reach, cand_idx, axis=1)
    # (A, W, K): every candidate against every segment of the window.
    rx = c_xy[:, None, :, 0] - a[..., 0:1]
    ry = c_xy[:, None, :, 1] - a[..., 1:2]
    along = ux[..., None] * rx + uy[..., None] * ry
    t = jnp.clip(along, 0.0, seg_len[..., None])
    lat = jnp.sqrt((rx - t * ux[..., None]) ** 2 + (ry - t * uy[..., None]) ** 2)
    cos_rel = jnp.abs(ux[..., None] * cy + uy[..., None] * sy)
    sin_rel = jnp.abs(ux[..., None] * sy - uy[..., None] * cy)
    half_across = 0.5 * (sin_rel * c_lw[:, None, :, 0] + cos_rel * c_lw[:, None, :, 1])
    half_along = 0.5 * (cos_rel * c_lw[:, None, :, 0] + sin_rel * c_lw[:, None, :, 1])
    foot = a_arc[..., None] + d_arc[..., None] * t / jnp.where(seg_len > 0, seg_len, 1.0)[..., None]
    cand = (c_ok[:, None, :] & (foot > s[:, None, None])
            & (lat <= 0.5 * lw[:, 1, None, None] + lateral_margin + half_across))
    gap = jnp.where(cand, foot - s[:, None, None] - 0.5 * lw[:, 0, None, None] - half_along, jnp.inf)
    g = jnp.min(gap, axis=(1, 2))
    # The nearest one's speed without an argmin + gather (slow on CPU): the
    # smallest speed along the path among the (ties of the) nearest.
    v_path = ux[..., None] * c_vel[:, None, :, 0] + uy[..., None] * c_vel[:, None, :, 1]
    v_lead = jnp.min(jnp.where(gap == g[:, None, None], v_path, jnp.inf), axis=(1, 2))
    has = jnp.isfinite(g)
    return has, g, jnp.where(has, v_lead, 0.0)


def idm_interaction(v: Array, gap: Array, v_lead: Array, has_leader: Array, params: IDMParams) -> Array:
    """(A,) leader term of IDM's acceleration, ``-a (s*/gap)^2`` (<= 0, m/s^2;
    0 without a leader), Waymax ``IDMRoutePolicy._get_accel``."""
    s_star = params.s0 + jnp.maximum(
        0.0, v * params.time_headway + v * (v - v_lead) / (2.0 * (params.accel * params.decel) ** 0.5))
    g = jnp.maximum(jnp.where(has_leader, gap, 1.0), MIN_GAP)
    return jnp.where(has_leader, -params.accel * (s_star / g) ** 2, 0.0)


def step(state: IDMState, tracks: Tracks, arc: Array, paths: LeaderPaths, t: Array, dt: float | Array,
         dt_log: Array, ego_xy: Array, ego_yaw: Array, ego_speed: Array, ego_lw: Array,
         params: IDMParams = IDMParams(), *, ego_index: Array) -> IDMState:
    """Advance the IDM agents from ``t`` to ``t + dt`` (module docstring).

    Args:
      state: IDMState at t.
      tracks: the log; arc: (A, T) ``path_arc(tracks)``; paths: ``leader_paths``.
      t: () s; dt: sim step, s; dt_log: () log step, s.
      ego_xy (2,) m, ego_yaw () rad, ego_speed () m/s, ego_lw (2,) length,
        width m: the simulated ego box (a leader like any agent).
      params: IDMParams (static).
      ego_index: () int32 the ego's row in ``tracks`` (never an IDM agent nor
        an obstacle: the simulated ego box stands for it).

    Returns:
      IDMState at t + dt.
    """
    now = state.agents  # = agents_at(state, tracks, arc, t, dt_log)
    nxt = replay.agents_at(tracks, t + dt, dt_log)
    s_log1 = arc_at(arc, t + dt, dt_log)
    v_log1 = jnp.where(nxt.valid, jnp.linalg.norm(nxt.vel, axis=-1), 0.0)
    on_log = state.on_log

    num = tracks.category.shape[0]
    ego_vel = ego_speed * jnp.stack([jnp.cos(ego_yaw), jnp.sin(ego_yaw)])
    obj_xy = jnp.concatenate([now.xy, ego_xy[None]], axis=0)
    obj_vel = jnp.concatenate([now.vel, ego_vel[None]], axis=0)
    obj_yaw = jnp.concatenate([now.yaw, jnp.reshape(ego_yaw, (1,))], axis=0)
    lw = tracks.size[:, :2]
    obj_lw = jnp.concatenate([lw, jnp.reshape(ego_lw, (1, 2))], axis=0)
    not_ego = jnp.arange(num) != ego_index
    obj_valid = jnp.concatenate([now.valid & not_ego, jnp.ones((1,), bool)])
    has, gap, v_lead = leaders(state.s, lw, paths, obj_xy, obj_yaw, obj_vel, obj_lw, obj_valid,
                               jnp.arange(num), params.lateral_margin)

    v = state.v
    a_int = idm_interaction(v, gap, v_lead, has, params)
    a_free = params.accel * (1.0 - (v / state.v0) ** params.delta)
    v_idm = jnp.maximum(jnp.where(on_log, v_log1, v + a_free * dt) + a_int * dt, 0.0)
    s_idm = jnp.where(on_log, s_log1 + 0.5 * (v_idm - v_log1) * dt, state.s + 0.5 * (v + v_idm) * dt)
    s_idm = jnp.where(has, jnp.minimum(s_idm, state.s + jnp.maximum(gap, 0.0)), s_idm)
    s_new = jnp.clip(s_idm, state.s, jnp.maximum(s_log1, state.s))
    follow_log = ~state.active | ~now.valid | ~nxt.valid
    reached = (s_idm >= s_log1) | follow_log
    s_new = jnp.where(reached, s_log1, s_new)
    v_new = jnp.where(reached, v_log1, v_idm)
    # The segment holding the new s: an agent on its log at t starts the
    # search from t's log interval (valid there, or it follows the log).
    kt = time_segment(t, dt_log, arc.shape[-1])
    k, k0 = advance_segment(jnp.where(on_log, kt, state.k), jnp.where(on_log, kt, state.k0), s_new, arc,
                            tracks.valid)
    new = state.replace(s=s_new.astype(jnp.float32), v=v_new.astype(jnp.float32), on_log=reached, k=k, k0=k0)
    return new.replace(agents=_placed(new, tracks, arc, nxt))


# --------------------------------------------------------------------------
# Host-side check: how far the agents drift from their logs
# --------------------------------------------------------------------------


#: m; where ``drift_errors`` puts the logged ego box while its log shows no ego.
ABSENT_XY = 1e6


def drift_errors(scenario: Scenario, dt: float, num_steps: int, params: IDMParams = IDMParams()):
    """Per-step position error (m) of every agent against its log with the ego
    REPLAYING its log (its logged box is the ego box): one unbatched scenario,
    pure (``jax.vmap`` it). Returns (err (N, A), mask (N, A) reactive agents
    valid in the log, lagging (N, A) not on their log)."""
    tracks = scenario.tracks
    ego = scenario.ego_index
    arc = path_arc(tracks)
    paths = leader_paths(tracks, arc, scenario.map.lanes, scenario.map.lane_width, scenario.map.lane_successors)
    ego_lw = tracks.size[ego, :2]
    state0 = init(tracks, scenario.dt_log, params, ego_index=ego)

    def body(state, k):
        t = k.astype(jnp.float32) * dt
        e = replay.ego_log_at(tracks, ego, t, scenario.dt_log)
        # Where the ego's log has ended (or not begun) the logged ego is
        # absent: its box goes far away (``ego_log_at`` gives zeros there,
        # which would be a phantom ego at the map's origin).
        e = e.replace(xy=jnp.where(e.valid, e.xy, ABSENT_XY))
        log = replay.agents_at(tracks, t, scenario.dt_log)
        err = jnp.linalg.norm(state.agents.xy - log.xy, axis=-1)
        mask = state.active & log.valid
        lagging = ~state.on_log
        state = step(state, tracks, arc, paths, t, dt, scenario.dt_log, e.xy, e.yaw, jnp.linalg.norm(e.vel), ego_lw, params,
                     ego_index=ego)
        return state, (jnp.where(mask, err, 0.0), mask, lagging)

    return jax.lax.scan(body, state0, jnp.arange(num_steps))[1]


def drift(scenario: Scenario, dt: float, num_steps: int, params: IDMParams = IDMParams()) -> dict[str, float]:
    """Mean / max position error (m) of the IDM agents against their logs over
    all valid reactive agent-steps, with the ego replaying its log
    (``drift_errors``). ``scenario``: one scenario or a batch (leading axis,
    numpy or JAX leaves); host function, one compiled call.

    Returns {"mean_m", "max_m", "lagging_frac", "agent_steps"}.
    """
    scenario = jax.device_put(scenario)
    fn = functools.partial(drift_errors, dt=dt, num_steps=num_steps, params=params)
    if scenario.tracks.xy.ndim == 4:
        fn = jax.vmap(fn)
    err, mask, lag = jax.device_get(jax.jit(fn)(scenario))
    n = int(mask.sum())
    return {
        "mean_m": float(err.sum() / max(n, 1)),
        "max_m": float(err.max()) if err.size else 0.0,
        "lagging_frac": float((lag & mask).sum() / max(n, 1)),
        "agent_steps": float(n),
    }
