"""Driving tasks as in Behavior Metrics (``drivee2e bench --task``).

Behavior Metrics evaluates three tasks (its paper, sec. 2.1 and "Successful
experiments"): *lane following* (stay in the lane, no other traffic),
*driving in traffic* (follow the lane among other vehicles at a safe
distance) and *route navigation* (drive between goal points obeying lights
and signs; it combines the other two). Here each task is a **scenario filter**,
an optional **scenario transform** and a **success rule** on the per-scenario
results row, with the thresholds below:

``route_navigation`` (default)
    Every scenario, unchanged. Success = the leaderboard's (the route
    completed without collisions or traffic violations; the ``--preset``).

``driving_in_traffic``
    Scenarios whose *logged* ego has a vehicle ahead in its lane corridor
    within ``TRAFFIC_FRONT_M`` = 50 m (the end of BM's "great" bucket) for at
    least ``TRAFFIC_MIN_S`` = 1 s of the log. Unchanged otherwise (signals
    kept: the logged traffic obeys them). Success = leaderboard success and
    never in BM's dangerous front-distance bucket (0-6 m):
    ``front_time_pct_dangerous == 0``.

``lane_following``
    Scenarios whose route has no turn command (every route point
    ``LANEFOLLOW`` / ``STRAIGHT`` / ``VOID``), with every non-ego agent removed
    and the signals switched off (``UNKNOWN``: lights belong to route
    navigation). Success = leaderboard success, mean lane-centre deviation
    ``<= LANE_DEVIATION_MAX_M`` = 0.5 m, and the average speed within
    ``SPEED_BAND`` = [0.7, 1.1] x the route's mean speed limit (BM: "drives
    at a constant speed" near its target; ours is the lane speed limit the
    expert cruises at).

The rows gain a ``task_success`` column; summaries a ``task_success_rate``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import infractions, replay
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.batch import PackedBatch
from drivee2e_jax.types import Category, Command, EgoState, SignalState

#: driving_in_traffic: a logged vehicle ahead within this distance, m ...
TRAFFIC_FRONT_M = 50.0
#: ... for at least this long, s.
TRAFFIC_MIN_S = 1.0
#: lane_following: mean |lane-centre offset| at most this, m.
LANE_DEVIATION_MAX_M = 0.5
#: lane_following: average speed / route speed limit must lie in this band.
SPEED_BAND = (0.7, 1.1)


@dataclasses.dataclass(frozen=True)
class Task:
    """One driving task.

    Attributes:
      name: the ``--task`` value.
      description: one line for ``--help`` and the report.
      select: ``select(packed) -> (B,) bool`` scenarios the task applies to.
      prepare: ``prepare(packed) -> packed`` the scenarios as the task runs them.
      success: ``success(row) -> bool`` on a per-scenario results row.
    """

    name: str
    description: str
    select: Callable
    prepare: Callable
    success: Callable


def _finite(v) -> bool:
    return v is not None and not math.isnan(float(v))


def _all(packed) -> np.ndarray:
    return np.ones(len(packed), bool)


def _same(packed):
    return packed


def logged_front_distance(packed) -> np.ndarray:
    """(B, T) m: distance from the LOGGED ego to the nearest vehicle ahead in
    its lane corridor (``infractions.front_distance``), inf where none or
    where the ego is not logged."""

    def one(scn):
        tr = scn.tracks
        i = scn.ego_index
        lw = tr.size[i, :2]
        not_ego = jnp.arange(tr.xy.shape[0]) != i
        # Pedestrians are not "front vehicles".
        vehicle = tr.category != Category.PEDESTRIAN

        def at(k):
            t = k.astype(jnp.float32) * scn.dt_log
            agents = replay.agents_at(tr, t, scn.dt_log)
            agents = agents.replace(valid=agents.valid & not_ego & vehicle)
            z = jnp.zeros((), jnp.float32)
            ego = EgoState(xy=tr.xy[i, k], yaw=tr.yaw[i, k], speed=z, accel=z, steer=z, yaw_rate=z, t=t)
            d = infractions.front_distance(ego, lw, agents, tr.size)
            return jnp.where(tr.valid[i, k], d, jnp.inf)

        return jax.vmap(at)(jnp.arange(tr.xy.shape[1]))

    return np.asarray(jax.jit(jax.vmap(one))(jax.device_put(packed.scenario)))


def _in_traffic(packed) -> np.ndarray:
    d = logged_front_distance(packed)
    dt = np.asarray(packed.scenario.dt_log)
    return (d <= TRAFFIC_FRONT_M).sum(axis=1) * dt >= TRAFFIC_MIN_S - 1e-6


def _no_turns(packed) -> np.ndarray:
    route = packed.scenario.route
    cmd = np.asarray(route.command)
    ok = np.isin(cmd, [Command.LANEFOLLOW, Command.STRAIGHT, Command.VOID]) | ~np.asarray(route.valid)
    return ok.all(axis=1)


def _empty_roads(packed):
    """Non-ego agents removed, signals off."""

    scn = packed.scenario
    a = np.asarray(scn.tracks.valid).shape[1]
    ego = np.arange(a)[None, :] == np.asarray(scn.ego_index)[:, None]  # (B, A)
    keep = lambda x: np.where(ego[:, :, None], x, False)  # noqa: E731 - per (B, A, T)
    tracks = scn.tracks.replace(valid=keep(np.asarray(scn.tracks.valid)),
                                visible=keep(np.asarray(scn.tracks.visible)))
    signals = scn.signals.replace(state=np.full_like(np.asarray(scn.signals.state), SignalState.UNKNOWN))
    return PackedBatch(scn.replace(tracks=tracks, signals=signals), packed.meta)


def _lane_following_success(row: dict) -> bool:
    limit = row.get("route_speed_limit_kmh")
    speed = row.get("average_speed_kmh")
    dev = row.get("position_deviation_mean_m")
    if not (row["success"] and _finite(limit) and _finite(speed) and _finite(dev)) or not float(limit) > 0:
        return False
    ratio = float(speed) / float(limit)
    return float(dev) <= LANE_DEVIATION_MAX_M and SPEED_BAND[0] <= ratio <= SPEED_BAND[1]


def _traffic_success(row: dict) -> bool:
    dangerous = row.get("front_time_pct_dangerous")
    return bool(row["success"]) and _finite(dangerous) and float(dangerous) == 0.0


TASKS: dict[str, Task] = {
    t.name: t
    for t in (
        Task("route_navigation", "reach the destination along the route (leaderboard success)",
             _all, _same, lambda row: bool(row["success"])),
        Task("driving_in_traffic", "follow the lane among the logged vehicles; never closer than 6 m to the one ahead",
             _in_traffic, _same, _traffic_success),
        Task("lane_following", "no other agents, no signals: stay near the lane centre at a steady speed",
             _no_turns, _empty_roads, _lane_following_success),
    )
}


def get_task(name: str) -> Task:
    """The task called ``name``; a one-line DriveE2EError for an unknown one."""
    if name not in TASKS:
        raise DriveE2EError(f"--task {name!r}: unknown task (expected one of {', '.join(TASKS)})")
    return TASKS[name]


def apply_task(task: Task, packed):
    """The scenarios of ``packed`` the task applies to, prepared for it.

    Raises DriveE2EError when no scenario qualifies.
    """
    rows = np.flatnonzero(task.select(packed))
    if len(rows) == 0:
        raise DriveE2EError(f"--task {task.name}: no scenario of this split qualifies ({task.description})")
    sub = packed if len(rows) == len(packed) else packed.select(rows)
    return task.prepare(sub)


def add_task_success(task: Task, rows: list[dict]) -> None:
    """Adds the ``task_success`` column to every results row (in place)."""
    for r in rows:
        r["task_success"] = bool(task.success(r))
