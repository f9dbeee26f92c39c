"""Fine-grained per-episode columns from a simulated episode log (host side).

``episode_columns`` turns one episode's ``StepLog`` (numpy, ``(T, ...)``,
only the steps where the episode was ``active`` are used) into the columns a
results row carries besides the leaderboard scores:

* Behavior Metrics (``behavior.episode_behavior``, the paper's definitions by
  default, the tool code's with ``definition="code"``): lane-centre
  deviation, effective / completed distance, average speed, the paper's
  signed speed-change "jerk", collisions and lane invasions per km, share of
  time per front-distance bucket;
* a physical longitudinal jerk (mean |da/dt|, m/s^3) — the paper's eq. (2)
  telescopes to (v_end - v_0) / T and says little about comfort;
* Bench2Drive smoothness (``comfort``: % of 20-step chunks within its
  acceleration / jerk / yaw-rate bounds) and the route's efficiency (mean
  ego / traffic speed ratio over its min-speed checkpoints, values > 1000 %
  ignored as B2D does; NaN without checkpoints).

``COLUMNS`` lists them in CSV order; ``SUMMARY_COLUMNS`` those averaged in
the run summary.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from drivee2e_jax.metrics import behavior, comfort

#: Behavior Metrics columns kept in results rows (paper definitions).
BM_COLUMNS = (
    "position_deviation_mean_m",
    "effective_completed_distance_m",
    "completed_distance_m",
    "average_speed_kmh",
    "longitudinal_jerk_mps",
    "collisions_per_km",
    "lane_invasions",
    "lane_invasions_per_km",
    "front_time_pct_great",
    "front_time_pct_medium",
    "front_time_pct_short",
    "front_time_pct_dangerous",
)
#: All fine-grained columns, in CSV order.
COLUMNS = BM_COLUMNS + ("jerk_lon_mean_mps3", "smoothness_pct", "efficiency_pct")
#: Columns averaged over scenarios in ``summary.json`` (NaN rows skipped).
SUMMARY_COLUMNS = (
    "position_deviation_mean_m",
    "average_speed_kmh",
    "jerk_lon_mean_mps3",
    "lane_invasions_per_km",
    "front_time_pct_dangerous",
    "smoothness_pct",
)
#: Marking crossings closer in time than this are one lane invasion, s (the
#: front corners cross first, the rear ones about a car length later).
INVASION_MERGE_S = 1.5
#: Min-speed percentages above this are ignored (Bench2Drive's efficiency).
EFFICIENCY_MAX_PCT = 1000.0


def episode_columns(
    log,
    *,
    route_length_m: float,
    route_completion_pct: float,
    dt_s: float,
    min_speed_pct=(),
    definition: Literal["paper", "code"] = "paper",
) -> dict[str, float]:
    """The fine-grained columns of one episode.

    Args:
      log: one episode's ``sim.StepLog`` as numpy arrays with a leading time
        axis (``xy (T, 2)``, ``speed (T,)``, ``active (T,)``, ``facts``, ``events``).
      route_length_m: m.  route_completion_pct: RC, %.  dt_s: sim step, s.
      min_speed_pct: the episode's closed min-speed checkpoint values, %.
      definition: Behavior Metrics definitions, "paper" (default) or "code".

    Returns: ``{column: value}`` for every name in ``COLUMNS`` (floats; NaN
    where undefined, e.g. lane deviation when no aligned lane was ever near).
    """
    act = np.flatnonzero(np.asarray(log.active))
    if len(act) == 0:
        return {c: math.nan for c in COLUMNS}
    xy = np.asarray(log.xy)[act].astype(np.float64)
    yaw = np.asarray(log.yaw)[act].astype(np.float64)
    speed = np.asarray(log.speed)[act].astype(np.float64)
    accel = np.asarray(log.accel)[act].astype(np.float64)
    offset = np.asarray(log.facts.lane_offset)[act].astype(np.float64)
    front = np.asarray(log.facts.front_distance)[act].astype(np.float64)
    collisions = np.flatnonzero(np.asarray(log.events.collision)[act])
    invasions = _distinct_crossings(np.flatnonzero(np.asarray(log.facts.lane_invasion)[act]), dt_s)
    # Steps with no aligned lane in reach have no lane centre: excluded below.
    finite = np.isfinite(offset)
    bm = behavior.episode_behavior(
        xy, speed, dt_s, np.where(finite, offset, 0.0), front, collisions, invasions,
        route_length_m, route_completion_pct, definition=definition,
    )
    out = {c: float(bm[c]) for c in BM_COLUMNS}
    out["position_deviation_mean_m"] = float(offset[finite].mean()) if finite.any() else math.nan
    out["jerk_lon_mean_mps3"] = float(np.abs(np.diff(accel)).mean() / dt_s) if len(accel) > 1 else 0.0
    out["smoothness_pct"] = _smoothness_pct(xy, yaw, speed, dt_s)
    kept = [float(v) for v in min_speed_pct if not float(v) > EFFICIENCY_MAX_PCT]
    out["efficiency_pct"] = float(np.mean(kept)) if kept else math.nan
    return out


def _distinct_crossings(steps: np.ndarray, dt_s: float) -> np.ndarray:
    """Steps starting a lane invasion: the first crossing tick after a pause
    longer than ``INVASION_MERGE_S`` (each box corner crosses on its own tick)."""
    if len(steps) == 0:
        return steps
    gap = np.diff(steps, prepend=-np.inf) * dt_s
    return steps[gap > INVASION_MERGE_S]


def _smoothness_pct(xy, yaw, speed, dt_s) -> float:
    """Bench2Drive smoothness of the episode, % of passing chunks (NaN if < 3 steps)."""
    if len(xy) < 3:
        return math.nan
    f = comfort.b2d_frames_from_episode(xy, yaw, speed, dt_s)
    frac = comfort.b2d_route_smoothness(f["accel_xy"], f["forward_xy"], f["right_xy"], f["yaw_rate"], delta_s=dt_s)
    return 100.0 * frac
