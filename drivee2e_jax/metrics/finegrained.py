"""Fine-grained per-episode columns from a simulated episode log (host side).

``batch_columns`` turns a batch of episodes' ``StepLog`` (numpy,
``(B, T, ...)``, only the steps where an episode was ``active`` are used)
into the columns a results row carries besides the leaderboard scores
(``episode_columns`` does one episode):

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
  ignored as B2D does; NaN without checkpoints);
* with ``bm_scores=True``, ``BM_SCORE_COLUMNS``: Behavior Metrics' route
  completion (effective distance / route length, a fraction) and driving
  score (``behavior.bm_driving_score``: the episode's collisions by class
  and red lights, with the time-out factor every BM run receives).

``COLUMNS`` lists them in CSV order; ``SUMMARY_COLUMNS`` those averaged in
the run summary.
"""

from __future__ import annotations

import math
from typing import Literal

import jax
import numpy as np

from drivee2e_jax.metrics import behavior, comfort
from drivee2e_jax.types import CollisionClass

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
#: Behavior Metrics route completion (fraction) and driving score (``bm_scores=True``).
BM_SCORE_COLUMNS = ("bm_route_completion", "bm_driving_score")
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
    bm_scores: bool = False,
) -> dict[str, float]:
    """The fine-grained columns of one episode (``batch_columns`` with B = 1).

    Args:
      log: one episode's ``sim.StepLog`` as numpy arrays with a leading time
        axis (``xy (T, 2)``, ``speed (T,)``, ``active (T,)``, ``facts``, ``events``).
      route_length_m: m.  route_completion_pct: RC, %.  dt_s: sim step, s.
      min_speed_pct: the episode's closed min-speed checkpoint values, %.
      definition: Behavior Metrics definitions, "paper" (default) or "code".
      bm_scores: add ``BM_SCORE_COLUMNS`` (reads ``events.collision_class``
        and ``events.red_light`` too).

    Returns: ``{column: value}`` for every name in ``COLUMNS`` (floats; NaN
    where undefined, e.g. lane deviation when no aligned lane was ever near).
    """
    ms = np.asarray(min_speed_pct, dtype=np.float64).reshape(1, -1)
    return batch_columns(
        _map(lambda a: np.asarray(a)[None], log),
        route_length_m=np.array([route_length_m]),
        route_completion_pct=np.array([route_completion_pct]),
        dt_s=dt_s,
        min_speed_pct=ms,
        min_speed_valid=np.ones(ms.shape, bool),
        definition=definition,
        bm_scores=bm_scores,
    )[0]


def batch_columns(
    logs,
    *,
    route_length_m,
    route_completion_pct,
    dt_s: float,
    min_speed_pct,
    min_speed_valid,
    definition: Literal["paper", "code"] = "paper",
    bm_scores: bool = False,
) -> list[dict[str, float]]:
    """The fine-grained columns of a batch of episodes.

    The reductions over time are numpy array operations over the whole batch
    (one batched Savitzky-Golay pass for every smoothness chunk of every
    episode); only the event lists of Behavior Metrics are per episode.

    Args:
      logs: ``sim.StepLog`` as numpy arrays with leading (B, T) axes; an
        episode's ``active`` steps are a prefix (it runs until it is done).
      route_length_m: (B,) m.  route_completion_pct: (B,) %.  dt_s: step, s.
      min_speed_pct: (B, Q) min-speed checkpoint values, %; min_speed_valid (B, Q) bool.
      definition: Behavior Metrics definitions, "paper" (default) or "code".
      bm_scores: also ``BM_SCORE_COLUMNS`` (see ``bm_score_columns``).

    Returns: one ``{column: value}`` dict per episode (``COLUMNS``, plus
    ``BM_SCORE_COLUMNS`` with ``bm_scores``; NaN where undefined).
    """
    active = np.asarray(logs.active, bool)
    n_act = active.sum(axis=1)
    xy = np.asarray(logs.xy, np.float64)
    yaw = np.asarray(logs.yaw, np.float64)
    speed = np.asarray(logs.speed, np.float64)
    accel = np.asarray(logs.accel, np.float64)
    offset = np.abs(np.asarray(logs.facts.lane_offset, np.float64))
    front = np.asarray(logs.facts.front_distance, np.float64)
    collision = np.asarray(logs.events.collision, bool)
    invasion = np.asarray(logs.facts.lane_invasion, bool)

    smooth = smoothness_pct(yaw, speed, n_act, dt_s)
    # Steps with no aligned lane in reach have no lane centre: left out.
    lane_ok = active & np.isfinite(offset)
    n_lane = lane_ok.sum(axis=1)
    deviation = np.where(lane_ok, offset, 0.0).sum(axis=1) / np.maximum(n_lane, 1)
    jerk_steps = np.abs(np.diff(accel, axis=1)) * (active[:, 1:])
    jerk = jerk_steps.sum(axis=1) / np.maximum(n_act - 1, 1) / dt_s
    ms = np.where(np.asarray(min_speed_valid) & ~(np.asarray(min_speed_pct) > EFFICIENCY_MAX_PCT),
                  np.asarray(min_speed_pct, np.float64), np.nan)

    out = []
    names = COLUMNS + (BM_SCORE_COLUMNS if bm_scores else ())
    for i, n in enumerate(n_act):
        if n == 0:
            out.append({c: math.nan for c in names})
            continue
        invasions = _distinct_crossings(np.flatnonzero(invasion[i, :n]), dt_s)
        bm = behavior.episode_behavior(
            xy[i, :n], speed[i, :n], dt_s, np.where(lane_ok[i, :n], offset[i, :n], 0.0), front[i, :n],
            np.flatnonzero(collision[i, :n]), invasions, float(route_length_m[i]), float(route_completion_pct[i]),
            definition=definition,
        )
        row = {c: float(bm[c]) for c in BM_COLUMNS}
        row["position_deviation_mean_m"] = float(deviation[i]) if n_lane[i] else math.nan
        row["jerk_lon_mean_mps3"] = float(jerk[i])
        row["smoothness_pct"] = float(smooth[i])
        kept = ms[i][np.isfinite(ms[i])]
        row["efficiency_pct"] = float(kept.mean()) if len(kept) else math.nan
        if bm_scores:
            row.update(bm_score_columns(
                xy[i, :n], collision[i, :n], np.asarray(logs.events.collision_class)[i, :n],
                np.asarray(logs.events.red_light, bool)[i, :n], bm["effective_completed_distance_m"],
                float(route_length_m[i]), definition))
        out.append(row)
    return out


#: ``CollisionClass`` -> the ``behavior.bm_driving_score`` count it adds to (BM: by the
#: actor's type prefix; anything neither vehicle nor walker is "static").
_BM_CLASS = {int(CollisionClass.VEHICLE): "collisions_vehicle", int(CollisionClass.PEDESTRIAN): "collisions_walker",
             int(CollisionClass.LAYOUT): "collisions_static", int(CollisionClass.OTHER): "collisions_static"}


def bm_score_columns(xy, collision, collision_class, red_light, effective_m: float, route_length_m: float,
                     definition: Literal["paper", "code"] = "paper") -> dict[str, float]:
    """Behavior Metrics route completion and driving score of one episode.

    Args:
      xy: (T, 2) m, the episode's active steps.
      collision: (T,) bool, a collision counted at that step (leaderboard rules).
      collision_class: (T,) int ``CollisionClass`` of it.
      red_light: (T,) bool, a red light run at that step.
      effective_m: effective completed distance, m (``episode_behavior``).
      route_length_m: m.
      definition: "code" keeps only the collisions BM's de-duplication keeps
        (> 1 m from the previous one; the first always), as the fine-grained
        collision count does; "paper" all counted ones.

    Returns: ``bm_route_completion`` (fraction) and ``bm_driving_score``
    (fraction; ``behavior.bm_driving_score`` with termination code 3, the
    time-out every BM run is scored with; no wrong-turn detection here).
    """
    steps = np.flatnonzero(collision)
    if definition == "code":
        steps = steps[behavior.distinct_events(xy[steps], first_ref_xy=None)]
    counts = {"collisions_vehicle": 0, "collisions_walker": 0, "collisions_static": 0}
    for c in np.asarray(collision_class)[steps]:
        counts[_BM_CLASS.get(int(c), "collisions_static")] += 1
    rc = behavior.bm_route_completion(effective_m, route_length_m)
    ds = behavior.bm_driving_score(rc, red_lights=int(np.count_nonzero(red_light)), **counts)
    return {"bm_route_completion": rc, "bm_driving_score": ds}


def smoothness_pct(yaw, speed, n_active, dt_s: float, chunk: int = comfort.B2D_CHUNK) -> np.ndarray:
    """Bench2Drive smoothness of a batch of episodes, % of passing chunks.

    Each episode's first ``n_active`` frames are turned into B2D's per-frame
    signals as ``comfort.b2d_frames_from_episode`` does (``np.gradient``:
    central differences inside, one-sided at both ends of the active prefix)
    and judged as ``comfort.b2d_route_smoothness``: every complete
    ``chunk``-frame chunk of every episode goes through one batched
    Savitzky-Golay pass; an episode of <= ``chunk`` frames is judged whole.

    Args:
      yaw: (B, T) rad.  speed: (B, T) m/s.  n_active: (B,) int frames.

    Returns: (B,) float64 %, NaN for episodes of fewer than 3 frames.
    """
    b, t = yaw.shape
    n = np.asarray(n_active, np.int64)
    rows = np.arange(b)
    fwd = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)  # (B, T, 2)
    vel = speed[..., None] * fwd
    uyaw = np.unwrap(yaw, axis=1)
    if t > 1:
        accel = np.gradient(vel, dt_s, axis=1)
        rate = np.gradient(uyaw, dt_s, axis=1)
        # np.gradient is one-sided at the array's end; an episode's last
        # active frame needs the same one-sided difference.
        last, prev = np.clip(n - 1, 0, t - 1), np.clip(n - 2, 0, t - 1)
        accel[rows, last] = (vel[rows, last] - vel[rows, prev]) / dt_s
        rate[rows, last] = (uyaw[rows, last] - uyaw[rows, prev]) / dt_s
    else:
        accel, rate = np.zeros_like(vel), np.zeros_like(uyaw)
    right = np.stack([fwd[..., 1], -fwd[..., 0]], axis=-1)
    out = np.full(b, np.nan)

    long = n > chunk
    if long.any():
        c = t // chunk
        cut = lambda x: x[long, : c * chunk].reshape((int(long.sum()), c, chunk) + x.shape[2:])  # noqa: E731
        ok = np.arange(c)[None, :] < (n[long] // chunk)[:, None]  # (B_long, c) complete chunks
        sig = comfort.chunk_signals(cut(accel)[ok], cut(fwd)[ok], cut(right)[ok], cut(rate)[ok], dt_s)
        passed = np.logical_and.reduce(list(comfort.chunk_checks(sig).values()))  # (chunks,)
        per_episode = np.zeros(ok.shape)
        per_episode[ok] = passed
        out[long] = 100.0 * per_episode.sum(axis=1) / ok.sum(axis=1)
    for i in np.flatnonzero((n >= 3) & ~long):  # short episodes: judged whole, own SG window
        m = n[i]
        out[i] = 100.0 * comfort.b2d_route_smoothness(accel[i, :m], fwd[i, :m], right[i, :m], rate[i, :m],
                                                      chunk=chunk, delta_s=dt_s)
    return out


def _map(fn, tree):
    """``fn`` on every array leaf of a log (namespace / struct dataclass)."""

    return jax.tree_util.tree_map(fn, tree)


def _distinct_crossings(steps: np.ndarray, dt_s: float) -> np.ndarray:
    """Steps starting a lane invasion: the first crossing tick after a pause
    longer than ``INVASION_MERGE_S`` (each box corner crosses on its own tick)."""
    if len(steps) == 0:
        return steps
    gap = np.diff(steps, prepend=-np.inf) * dt_s
    return steps[gap > INVASION_MERGE_S]
