"""Behavior Metrics [BM] fine-grained metrics of one episode (host-side numpy).

Definitions: ``shared/reference/METRICS.md`` section 4 and the BM paper
(``shared/seeds/001_*.txt``: eq. 1 mean position deviation, eq. 2 longitudinal
jerk, distance-to-front buckets as a share of time).

* ``bm_code_metrics`` reproduces BM's code (JdeRobot/BehaviorMetrics
  ``utils/metrics_carla.py`` at noetic-devel a4bfa13) on BM's own inputs: map
  waypoints every 0.5 m, odometry poses, speedometer, vehicle_status controls,
  collision and lane-invasion events. Keys and units are BM's (speeds km/h).
* ``episode_behavior`` gives the project's definitions for a simulated
  episode: the paper's by default, ``definition="code"`` adds the code's
  variants (per-km divisions, |dv| in km/h, distance-weighted front buckets,
  BM's event de-duplication).

Everything here is a pure function of one episode; arrays are already trimmed
to the episode's active steps. Nothing runs under ``jit``.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from drivee2e_jax.polyline import polyline_length

#: BM map waypoints are generated every 0.5 m; each covered one adds 0.5 m.
WAYPOINT_SPACING_M = 0.5
#: A pose contributes to the position deviation iff its nearest waypoint is closer (strict).
DEVIATION_MAX_M = 100.0
#: A pose's nearest waypoint is "covered" iff closer than this (strict).
COVERED_MAX_M = 1.0
#: A collision / lane invasion counts iff its pose is farther than this from the previous event's pose.
EVENT_MIN_GAP_M = 1.0
#: ... and, for lane invasions, later than this after the previous event (strict).
LANE_INVASION_MIN_GAP_S = 0.5
#: Lap counting skips this many poses at the start and after each lap.
LAP_SKIP_POSES = 50
#: A pose closer than this to the starting point closes a lap.
LAP_RADIUS_M = 0.5
#: Distance-to-front buckets (name, low exclusive, high); "great" excludes 50 m,
#: the others include their upper bound; "dangerous" has no lower bound.
FRONT_BUCKETS = (("great", 20.0, 50.0), ("medium", 15.0, 20.0), ("short", 6.0, 15.0), ("dangerous", -np.inf, 6.0))

KMH_PER_MPS = 3.6

#: ``constants.CARLA_INFRACTION_PENALTIES`` (BM's driving score factors per event).
BM_PENALTIES = {"collision_walker": 0.5, "collision_vehicle": 0.6, "collision_static": 0.65, "wrong_turn": 0.7,
                "time_out": 0.7, "red_light": 0.7}
#: ``test_suite_manager_carla.py`` termination codes: 1 success, 2 wrong turn, 3 time out. The suite
#: manager initialises the code to 3 and never changes it, so every run is scored as a time-out.
BM_TERMINATION_SUCCESS, BM_TERMINATION_WRONG_TURN, BM_TERMINATION_TIME_OUT = 1, 2, 3


# ---------------------------------------------------------------------------
# Shared pieces
# ---------------------------------------------------------------------------


def _as(name: str, fn: str, a, shape: tuple) -> np.ndarray:
    """float64 array with shape checked against ``shape`` (None = any size)."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, arr.shape)):
        want = "(" + ", ".join("n" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ValueError(f"{fn}: {name} must have shape {want}, got {arr.shape}")
    return arr


def nearest_waypoints(points_xy, waypoints_xy, *, block_elems: int = 2_000_000) -> tuple[np.ndarray, np.ndarray]:
    """Nearest waypoint of every point, by brute force in memory-bounded blocks.

    Args:
      points_xy: (T, 2) m.
      waypoints_xy: (N, 2) m, N >= 1.
      block_elems: at most this many point-waypoint distances held at once.

    Returns:
      (index (T,) int, distance (T,) m); ties go to the lowest index, as BM's
      strict ``<`` scan does.
    """
    p = _as("points_xy", "nearest_waypoints", points_xy, (None, 2))
    w = _as("waypoints_xy", "nearest_waypoints", waypoints_xy, (None, 2))
    if len(w) == 0:
        raise ValueError("nearest_waypoints: waypoints_xy is empty")
    idx = np.zeros(len(p), dtype=np.int64)
    dist = np.zeros(len(p))
    step = max(1, block_elems // len(w))
    for s in range(0, len(p), step):
        d = np.sqrt(((w[None, :, :] - p[s : s + step, None, :]) ** 2).sum(-1))
        idx[s : s + step] = d.argmin(axis=1)
        dist[s : s + step] = d[np.arange(len(d)), idx[s : s + step]]
    return idx, dist


def distinct_events(event_xy, event_time_s=None, *, min_gap_m: float = EVENT_MIN_GAP_M,
                    min_gap_s: float | None = None, first_ref_xy=(0.0, 0.0),
                    first_ref_time_s: float = 0.0) -> np.ndarray:
    """BM's event de-duplication: which events count.

    An event counts iff its pose is more than ``min_gap_m`` from the previous
    event's pose and (if ``min_gap_s`` is given) it is more than ``min_gap_s``
    after the previous event; "previous" is the previous event whether it
    counted or not. BM compares the first event with the pose (0, 0) and the
    time 0 (its defaults); ``first_ref_xy=None`` counts the first event always.

    Args:
      event_xy: (E, 2) m, the pose matched to each event, in event order.
      event_time_s: (E,) s, needed only with ``min_gap_s``.

    Returns:
      (E,) bool.
    """
    xy = _as("event_xy", "distinct_events", event_xy, (None, 2))
    t = None
    if min_gap_s is not None:
        if event_time_s is None:
            raise ValueError("distinct_events: min_gap_s needs event_time_s")
        t = _as("event_time_s", "distinct_events", event_time_s, (len(xy),))
    keep = np.zeros(len(xy), dtype=bool)
    if len(xy) == 0:
        return keep
    if first_ref_xy is None:
        prev_xy = np.full(2, np.inf)
        prev_t = -np.inf
    else:
        prev_xy = np.asarray(first_ref_xy, dtype=np.float64)
        prev_t = first_ref_time_s
    for e in range(len(xy)):
        far = np.sqrt(((prev_xy - xy[e]) ** 2).sum()) > min_gap_m
        late = True if t is None else (t[e] - prev_t) > min_gap_s
        keep[e] = bool(far and late)
        prev_xy = xy[e]
        if t is not None:
            prev_t = t[e]
    return keep


def _per_km(value: float, km: float, *, zero_if_zero: bool) -> float:
    """value / km; 0 for a zero count when ``zero_if_zero`` (BM's rule for
    counts); NaN when km = 0 (BM divides by zero there)."""
    if zero_if_zero and value == 0:
        return 0.0
    return float(value / km) if km > 0 else float("nan")


def _abs_diff_from_rest(x: np.ndarray) -> np.ndarray:
    """|x_i - x_{i-1}| per row with x_{-1} = 0 (BM's "suddenness" steps)."""
    prev = np.concatenate([np.zeros_like(x[:1]), x[:-1]], axis=0)
    d = x - prev
    return np.sqrt((d**2).sum(-1)) if d.ndim == 2 else np.abs(d)


def _front_bucket_masks(d: np.ndarray) -> dict[str, np.ndarray]:
    return {name: (d > lo) & ((d < hi) if name == "great" else (d <= hi)) for name, lo, hi in FRONT_BUCKETS}


def front_distance_buckets(ego_xy, front_distance_m) -> dict[str, float]:
    """BM code's distance-to-front buckets (``get_distance_other_vehicle``).

    For each step i >= 1 the ego displacement |p_i - p_{i-1}| is added to the
    bucket of d_i: great 20 < d < 50, medium 15 < d <= 20, short ("close" in
    BM) 6 < d <= 15, dangerous d <= 6; d >= 50 (or inf, nothing ahead) is not
    counted.

    Args:
      ego_xy: (T, 2) m.
      front_distance_m: (T,) m, distance to the front vehicle (inf if none).

    Returns:
      ``front_distance_m_<bucket>`` (m driven in the bucket),
      ``front_distance_m_total`` (m counted) and ``front_distance_pct_<bucket>``
      (% of the counted distance, 0 when nothing was counted, as BM).
    """
    xy = _as("ego_xy", "front_distance_buckets", ego_xy, (None, 2))
    d = _as("front_distance_m", "front_distance_buckets", front_distance_m, (len(xy),))
    step = np.sqrt((np.diff(xy, axis=0) ** 2).sum(-1))
    masks = _front_bucket_masks(d[1:])
    metres = {name: float(step[m].sum()) for name, m in masks.items()}
    total = sum(metres.values())
    out = {f"front_distance_m_{k}": v for k, v in metres.items()}
    out["front_distance_m_total"] = total
    out.update({f"front_distance_pct_{k}": (100.0 * v / total if total else 0.0) for k, v in metres.items()})
    return out


def front_time_shares(front_distance_m) -> dict[str, float]:
    """Paper's distance-to-front metric: % of the episode's steps in each bucket.

    Buckets as ``FRONT_BUCKETS`` (great 20-50, medium 15-20, short 6-15,
    dangerous 0-6 m; boundaries as BM's code). The denominator is every step,
    so the shares sum to the % of time with a vehicle within 50 m.

    Args:
      front_distance_m: (T,) m, inf if nothing ahead; T >= 1.

    Returns:
      ``front_time_pct_<bucket>`` in %.
    """
    d = _as("front_distance_m", "front_time_shares", front_distance_m, (None,))
    if len(d) == 0:
        raise ValueError("front_time_shares: front_distance_m is empty")
    return {f"front_time_pct_{k}": 100.0 * float(m.mean()) for k, m in _front_bucket_masks(d).items()}


# ---------------------------------------------------------------------------
# BM code, on BM's inputs
# ---------------------------------------------------------------------------


def _completed_laps(xy: np.ndarray) -> int:
    """``get_completed_laps``: after skipping 50 poses, a pose within 0.5 m of
    the first pose is a lap, and the skip restarts."""
    skip, laps = LAP_SKIP_POSES, 0
    for p in xy:
        if skip > 0:
            skip -= 1
        elif np.sqrt(((xy[0] - p) ** 2).sum()) < LAP_RADIUS_M:
            laps += 1
            skip = LAP_SKIP_POSES
    return laps


def _deviation_and_coverage(xy: np.ndarray, waypoints: np.ndarray) -> tuple[np.ndarray, int]:
    """Distances < 100 m to the nearest waypoint, and the number of covered
    waypoints (nearest, < 1 m, x AND y both differ from the last covered)."""
    idx, dist = nearest_waypoints(xy, waypoints)
    valid = dist < DEVIATION_MAX_M
    covered: list[np.ndarray] = []
    for i in np.flatnonzero(valid & (dist < COVERED_MAX_M)):
        wp = waypoints[idx[i]]
        if not covered or (covered[-1][0] != wp[0] and covered[-1][1] != wp[1]):
            covered.append(wp)
    return dist[valid], len(covered)


def bm_code_metrics(map_waypoints_xy, pose_xy, pose_time_s, speed_mps, controls, collision_time_s=(),
                    lane_invasion_time_s=(), front_xy=None) -> dict[str, float]:
    """Behavior Metrics' code definitions (METRICS.md section 4) on BM's inputs.

    Poses must be in the waypoints' frame: BM mirrors x or y for some CARLA
    towns (ROS vs CARLA axes); that plumbing is the caller's (Town05 = none).
    Each event is matched to the pose with the nearest timestamp (first on
    ties, as pandas ``idxmin``).

    Args:
      map_waypoints_xy: (N, 2) m, waypoints every 0.5 m over the whole map.
      pose_xy: (T, 2) m, ego odometry, T >= 2.
      pose_time_s: (T,) s, pose timestamps.
      speed_mps: (S,) m/s, speedometer samples (S >= 1, independent of T).
      controls: (K, 3) vehicle_status [throttle, steer, brake], K >= 1.
      collision_time_s: (C,) s, collision event times.
      lane_invasion_time_s: (L,) s, lane-invasion event times.
      front_xy: optional (T, 2) m, the front vehicle's poses
        (``follow_lane_traffic``); adds the front-distance buckets.

    Returns:
      BM's keys: ``completed_distance`` (m, pose polyline), ``average_speed``,
      ``max_speed``, ``min_speed`` (km/h), ``suddenness_distance_speed``
      (mean |dv| km/h, v_{-1} = 0), ``suddenness_distance_control_commands``,
      ``_throttle``, ``_steer``, ``_brake_command`` (mean step norm, previous
      command starts at 0), ``collisions``, ``lane_invasions`` (de-duplicated
      counts), ``effective_completed_distance`` (m, 0.5 x covered waypoints),
      ``position_deviation_mean`` / ``_total_err`` (m), the ``*_per_km``
      divisions by the effective km (counts: 0 when the count is 0; NaN
      where BM would divide by zero), ``completed_laps``; with ``front_xy``
      also ``front_distance_m_*`` / ``front_distance_pct_*``.
    """
    fn = "bm_code_metrics"
    wps = _as("map_waypoints_xy", fn, map_waypoints_xy, (None, 2))
    xy = _as("pose_xy", fn, pose_xy, (None, 2))
    if len(xy) < 2:
        raise ValueError(f"{fn}: pose_xy needs >= 2 poses (BM returns no metrics otherwise), got {len(xy)}")
    t = _as("pose_time_s", fn, pose_time_s, (len(xy),))
    v = _as("speed_mps", fn, speed_mps, (None,))
    u = _as("controls", fn, controls, (None, 3))
    if len(v) == 0 or len(u) == 0:
        raise ValueError(f"{fn}: speed_mps and controls need >= 1 sample, got {len(v)} and {len(u)}")
    tc = _as("collision_time_s", fn, collision_time_s, (None,))
    tl = _as("lane_invasion_time_s", fn, lane_invasion_time_s, (None,))

    out: dict[str, float] = {"completed_distance": polyline_length(xy)}

    kmh = v * KMH_PER_MPS
    out["average_speed"] = float(kmh.sum() / len(kmh))
    out["suddenness_distance_speed"] = float(_abs_diff_from_rest(kmh).mean())
    out["max_speed"] = float(kmh.max())
    out["min_speed"] = float(kmh.min())

    out["suddenness_distance_control_commands"] = float(_abs_diff_from_rest(u).mean())
    for j, name in enumerate(("throttle", "steer", "brake_command")):
        out[f"suddenness_distance_{name}"] = float(_abs_diff_from_rest(u[:, j]).mean())

    def match(te):
        return np.abs(t[None, :] - te[:, None]).argmin(axis=1) if len(te) else np.zeros(0, dtype=np.int64)

    out["collisions"] = int(distinct_events(xy[match(tc)]).sum())
    out["lane_invasions"] = int(distinct_events(xy[match(tl)], tl, min_gap_s=LANE_INVASION_MIN_GAP_S).sum())

    dists, n_covered = _deviation_and_coverage(xy, wps)
    eff_m = WAYPOINT_SPACING_M * n_covered
    km = eff_m / 1000.0
    out["effective_completed_distance"] = eff_m
    out["position_deviation_mean"] = float(dists.sum() / len(dists)) if len(dists) else float("nan")
    out["position_deviation_total_err"] = float(dists.sum())
    out["position_deviation_mean_per_km"] = _per_km(out["position_deviation_mean"], km, zero_if_zero=False)
    out["collisions_per_km"] = _per_km(out["collisions"], km, zero_if_zero=True)
    out["lane_invasions_per_km"] = _per_km(out["lane_invasions"], km, zero_if_zero=True)
    # BM's key is singular ("command") here, plural without the suffix.
    out["suddenness_distance_control_command_per_km"] = _per_km(
        out["suddenness_distance_control_commands"], km, zero_if_zero=False)
    for name in ("throttle", "steer", "brake_command", "speed"):
        out[f"suddenness_distance_{name}_per_km"] = _per_km(out[f"suddenness_distance_{name}"], km, zero_if_zero=False)
    out["completed_laps"] = _completed_laps(xy)

    if front_xy is not None:
        fxy = _as("front_xy", fn, front_xy, (len(xy), 2))
        out.update(front_distance_buckets(xy, np.sqrt(((xy - fxy) ** 2).sum(-1))))
    return out


# ---------------------------------------------------------------------------
# Route completion and driving score (controller_carla.py)
# ---------------------------------------------------------------------------


def bm_route_completion(effective_completed_distance_m: float, route_length_m: float) -> float:
    """BM route completion: effective completed distance / route length, a fraction.

    ``controller_carla.stop_recording_metrics``; not clipped (a route whose
    covered waypoints exceed its nominal length scores > 1). NaN for a route
    of length 0 (BM would divide by zero).
    """
    if not route_length_m > 0:
        return float("nan")
    return float(effective_completed_distance_m) / float(route_length_m)


def bm_collision_class(actor_type_id: str) -> str:
    """BM's class of a collided actor from its CARLA ``type_id``: the prefix
    before the first dot, ``vehicle`` / ``walker``, anything else ``static``."""
    prefix = actor_type_id.split(".")[0]
    return prefix if prefix in ("vehicle", "walker") else "static"


def bm_driving_score(route_completion: float, collisions_vehicle: int = 0, collisions_static: int = 0,
                     collisions_walker: int = 0, red_lights: int = 0,
                     termination_code: int = BM_TERMINATION_TIME_OUT) -> float:
    """BM driving score (``controller_carla.stop_recording_metrics``).

    ``RC * 0.6^veh * 0.65^static * 0.5^walker * 0.7^red * 0.7^wrong_turn *
    0.7^time_out``, where wrong_turn = 1 iff ``termination_code`` is 2 and
    time_out = 1 iff it is 3. The default 3 is what ``test_suite_manager_carla``
    always passes (METRICS.md section 4), so every run carries the 0.7 factor.

    Args:
      route_completion: BM route completion, a fraction (``bm_route_completion``).
      collisions_*: de-duplicated collision counts by ``bm_collision_class``.
      red_lights: the brain's red-light counter.
      termination_code: 1 success, 2 wrong turn, 3 time out (None-like values: no factor).

    Returns: the score, same unit as ``route_completion`` (a fraction).
    """
    p = BM_PENALTIES
    wrong_turn = int(termination_code == BM_TERMINATION_WRONG_TURN)
    time_out = int(termination_code == BM_TERMINATION_TIME_OUT)
    return float(route_completion * p["collision_vehicle"] ** collisions_vehicle
                 * p["collision_static"] ** collisions_static * p["collision_walker"] ** collisions_walker
                 * p["red_light"] ** red_lights * p["wrong_turn"] ** wrong_turn * p["time_out"] ** time_out)


# ---------------------------------------------------------------------------
# Project definitions for a simulated episode
# ---------------------------------------------------------------------------


def _steps(name: str, steps, n: int) -> np.ndarray:
    s = np.asarray(steps, dtype=np.int64).reshape(-1)
    if s.size and (s.min() < 0 or s.max() >= n):
        raise ValueError(f"episode_behavior: {name} must index the episode's {n} steps, got {s.min()}..{s.max()}")
    return s


def episode_behavior(xy, speed_mps, dt_s: float, lane_offset_m, front_distance_m, collision_steps,
                     lane_invasion_steps, route_length_m: float, route_completion_pct: float, *,
                     definition: Literal["paper", "code"] = "paper") -> dict[str, float]:
    """BM fine-grained metrics of one simulated episode.

    Args:
      xy: (T, 2) m, ego positions, T >= 1.
      speed_mps: (T,) m/s.
      dt_s: step length, s (times lane-invasion events for the code's 0.5 s rule).
      lane_offset_m: (T,) m, distance (sign ignored) to the centre of the lane
        being traversed.
      front_distance_m: (T,) m, distance to the vehicle ahead, inf if none.
      collision_steps, lane_invasion_steps: step indices of the events, in
        time order.
      route_length_m: route length, m.
      route_completion_pct: route completion RC, %.
      definition: "paper" (default) or "code".

    Returns (both definitions):
      ``completed_distance_m`` (polyline length of ``xy``);
      ``effective_completed_distance_m`` = RC/100 x route length (route
      progress stands in for BM's covered 0.5 m waypoints: both count only
      distance made along the lane);
      ``average_speed_kmh``;
      ``position_deviation_mean_m`` (paper eq. 1: plain mean |offset|);
      ``longitudinal_jerk_mps`` (paper eq. 2: mean *signed* speed change per
      step, m/s; telescopes to (v_last - v_0)/(T - 1), 0 when T = 1);
      ``collisions``, ``lane_invasions`` (counts) and ``collisions_per_km``,
      ``lane_invasions_per_km`` (count / effective km; 0 for no events, NaN
      for events with no effective distance);
      ``front_time_pct_{great,medium,short,dangerous}`` (paper: % of time).

    ``definition="code"`` adds BM code's variants:
      ``position_deviation_total_err_m`` and ``position_deviation_mean_per_km``
      (MPD / effective km, m/km); ``suddenness_distance_speed_kmh`` (mean
      |v_i - v_{i-1}| in km/h with v_{-1} = 0, so a run that starts moving
      scores v_0 x 3.6 / T even at constant speed; BM runs start at rest) and
      ``suddenness_distance_speed_per_km``; ``max_speed_kmh``,
      ``min_speed_kmh``; the distance-weighted ``front_distance_m_*`` /
      ``front_distance_pct_*`` (see ``front_distance_buckets``); and events
      de-duplicated as BM (> 1 m from the previous event's pose, lane
      invasions also > 0.5 s after it) except that the first event always
      counts (BM compares it with the world origin and t = 0, an artefact of
      its frames). BM's nearest-waypoint-of-any-lane deviation needs the map:
      see ``bm_code_metrics``; here both definitions use ``lane_offset_m``.
    """
    fn = "episode_behavior"
    if definition not in ("paper", "code"):
        raise ValueError(f"{fn}: definition must be 'paper' or 'code', got {definition!r}")
    p = _as("xy", fn, xy, (None, 2))
    n = len(p)
    if n == 0:
        raise ValueError(f"{fn}: empty episode")
    v = _as("speed_mps", fn, speed_mps, (n,))
    off = np.abs(_as("lane_offset_m", fn, lane_offset_m, (n,)))
    front = _as("front_distance_m", fn, front_distance_m, (n,))
    cs = _steps("collision_steps", collision_steps, n)
    ls = _steps("lane_invasion_steps", lane_invasion_steps, n)
    if not dt_s > 0 or not route_length_m >= 0:
        raise ValueError(f"{fn}: need dt_s > 0 and route_length_m >= 0, got {dt_s} and {route_length_m}")

    eff_m = float(route_completion_pct) / 100.0 * float(route_length_m)
    km = eff_m / 1000.0
    if definition == "code":
        n_col = int(distinct_events(p[cs], first_ref_xy=None).sum())
        n_inv = int(distinct_events(p[ls], ls * dt_s, min_gap_s=LANE_INVASION_MIN_GAP_S, first_ref_xy=None).sum())
    else:
        n_col, n_inv = len(cs), len(ls)

    out: dict[str, float] = {
        "completed_distance_m": polyline_length(p),
        "effective_completed_distance_m": eff_m,
        "average_speed_kmh": float(v.mean() * KMH_PER_MPS),
        "position_deviation_mean_m": float(off.mean()),
        "longitudinal_jerk_mps": float(np.diff(v).mean()) if n > 1 else 0.0,
        "collisions": n_col,
        "collisions_per_km": _per_km(n_col, km, zero_if_zero=True),
        "lane_invasions": n_inv,
        "lane_invasions_per_km": _per_km(n_inv, km, zero_if_zero=True),
    }
    out.update(front_time_shares(front))
    if definition == "code":
        kmh = v * KMH_PER_MPS
        out["position_deviation_total_err_m"] = float(off.sum())
        out["position_deviation_mean_per_km"] = _per_km(out["position_deviation_mean_m"], km, zero_if_zero=False)
        out["suddenness_distance_speed_kmh"] = float(_abs_diff_from_rest(kmh).mean())
        out["suddenness_distance_speed_per_km"] = _per_km(out["suddenness_distance_speed_kmh"], km, zero_if_zero=False)
        out["max_speed_kmh"] = float(kmh.max())
        out["min_speed_kmh"] = float(kmh.min())
        out.update(front_distance_buckets(p, front))
    return out


__all__ = [
    "BM_PENALTIES",
    "FRONT_BUCKETS",
    "bm_code_metrics",
    "bm_collision_class",
    "bm_driving_score",
    "bm_route_completion",
    "distinct_events",
    "episode_behavior",
    "front_distance_buckets",
    "front_time_shares",
    "nearest_waypoints",
]
