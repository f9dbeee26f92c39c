"""The map facts of an episode recomputed on the host with shapely: the oracle.

Independent of the simulator's packing and of its in-``jit`` geometry: it
reads the suite's own ``MapRecord`` (drivable polygons, lanes with their
boundaries or centreline and width) and the re-simulated ego poses of an
``eval.traces.EpisodeTrace``, and answers per instant

* ``excess``: the largest distance of an ego corner outside the union of the
  map's drivable polygons (shapely ``distance``; 0 inside) -- the input of
  nuPlan's ``drivable_area_compliance`` (fails at >= 0.3 m) and NAVSIM's DAC
  (fails at > 0);
* ``multi_lane``: no single lane polygon covers all four corners (nuPlan's
  "ego in multiple lanes");
* ``oncoming``: the ego centre's travel against the lane holding it, when no
  lane holding it runs its way (nuPlan's ``driving_direction_compliance``
  input), and that metric's score over 1 s windows.

``compare`` lines these up with what the step produced (the trace's
``facts.*`` timelines and the row's DAC columns). Used by
``experiments/oracles/map_facts.py`` and the tests.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import LineString, Point, Polygon

#: nuPlan's drivable_area_compliance ``max_violation_threshold``, m (from its
#: config, written here again so the oracle does not read the module under test).
NUPLAN_DAC_M = 0.3
#: Per-instant agreement of the excess, m (float32 corners against float64).
EXCESS_TOL_M = 0.01
#: nuPlan driving_direction_compliance: thresholds (m) and window (s), from its config.
DIRECTION_M = (2.0, 6.0)
DIRECTION_WINDOW_S = 1.0


def lane_polygon(lane) -> Polygon:
    """A lane's area: its own ring where the record has one; left boundary +
    reversed right boundary where it has both, else the centreline buffered by
    width / 2 with flat ends."""
    own = getattr(lane, "polygon", None)
    if own is not None and len(own) >= 3:
        return shapely.make_valid(Polygon(np.asarray(own, float)[:, :2]))
    left, right = getattr(lane, "left_boundary", None), getattr(lane, "right_boundary", None)
    if left is not None and right is not None and len(left) >= 2 and len(right) >= 2:
        ring = np.concatenate([np.asarray(left, float), np.asarray(right, float)[::-1]])
        return shapely.make_valid(Polygon(ring))
    return LineString(np.asarray(lane.centerline, float)).buffer(0.5 * float(lane.width), cap_style="flat")


def drivable_area(map_record):
    """The union of the map's drivable polygons; of its lane polygons when it has none; None without either."""
    if map_record.drivable_areas:
        return shapely.union_all([shapely.make_valid(Polygon(np.asarray(p, float))) for p in map_record.drivable_areas])
    lanes = [ln for ln in map_record.lanes if len(ln.centerline) >= 2]
    return shapely.union_all([lane_polygon(ln) for ln in lanes]) if lanes else None


def ego_corners(xy, yaw, length: float, width: float) -> np.ndarray:
    """(T, 4, 2) box corners (FL, FR, RR, RL order irrelevant here), m."""
    xy, yaw = np.asarray(xy, float), np.asarray(yaw, float)
    f = np.stack([np.cos(yaw), np.sin(yaw)], -1)[:, None]
    left = np.stack([-np.sin(yaw), np.cos(yaw)], -1)[:, None]
    sx = np.array([1, 1, -1, -1])[None, :, None] * 0.5 * length
    sy = np.array([1, -1, -1, 1])[None, :, None] * 0.5 * width
    return xy[:, None] + sx * f + sy * left


def corner_excess(area, corners: np.ndarray) -> np.ndarray:
    """(T,) largest corner distance outside ``area``, m (0 without an area)."""
    if area is None:
        return np.zeros(corners.shape[0])
    pts = shapely.points(corners.reshape(-1, 2))
    return shapely.distance(area, pts).reshape(corners.shape[:2]).max(axis=1)


def multi_lane(lanes: list[Polygon], corners: np.ndarray) -> np.ndarray:
    """(T,) bool: no single lane polygon covers all four corners."""
    if not lanes:
        return np.ones(corners.shape[0], bool)
    pts = shapely.points(corners.reshape(-1, 2))
    held = np.stack([shapely.covers(lp, pts).reshape(corners.shape[:2]).all(axis=1) for lp in lanes])
    return ~held.any(axis=0)


def oncoming_travel(xy, yaw, lanes: list, lines: list) -> np.ndarray:
    """(n,) m travel of the ego centre against the lane holding it, for each
    step xy[k-1] -> xy[k] (k = 1..n): 0 unless a lane polygon holds xy[k] and
    none of those holding it runs within 90 deg of the heading; then the
    backward travel along the first holding lane's direction at that point."""
    xy, yaw = np.asarray(xy, float), np.asarray(yaw, float)
    out = np.zeros(len(xy) - 1)
    for k in range(1, len(xy)):
        p = Point(xy[k])
        heading = np.array([np.cos(yaw[k]), np.sin(yaw[k])])
        tangents = []
        for lp, line in zip(lanes, lines):
            if lp.covers(p):
                s = line.project(p)
                a, b = line.interpolate(max(s - 0.05, 0.0)), line.interpolate(min(s + 0.05, line.length))
                t = np.array([b.x - a.x, b.y - a.y])
                tangents.append(t / max(np.linalg.norm(t), 1e-9))
        if tangents and not any(t @ heading >= 0 for t in tangents):
            out[k - 1] = max(0.0, -float((xy[k] - xy[k - 1]) @ tangents[0]))
    return out


#: A worst window this close to a threshold (m) is borderline: the lane's
#: direction at a point (float32 nearest segment vs a shapely chord) may tip it.
DIRECTION_BORDER_M = 0.05


def direction_compliance(oncoming: np.ndarray, dt: float) -> tuple[float, float]:
    """nuPlan's ``DrivingDirectionComplianceStatistics``: the largest travel
    against the lanes over any window of int(1 s / dt) + 1 samples:
    < 2 m -> 1, < 6 m -> 0.5, else 0. Returns (score, that largest travel m)."""
    n = int(round(DIRECTION_WINDOW_S / dt))
    worst = max((oncoming[max(0, i - n): i + 1].sum() for i in range(len(oncoming))), default=0.0)
    return (1.0 if worst < DIRECTION_M[0] else (0.5 if worst < DIRECTION_M[1] else 0.0)), float(worst)


#: NAVSIM lane keeping (pdm_scorer.yaml): deviation limit (m) and window (s).
LK_DEVIATION_M = 0.5
LK_WINDOW_S = 2.0
#: Per-instant agreement of the LK deviation, m (float32 nearest segment against shapely).
LK_TOL_M = 0.01
#: NAVSIM takes the first of equally aligned lanes in its map order; both sides here take
#: the nearest centreline among lanes whose direction cosine is within this of the best.
LK_ALIGN_TIE = 1e-3


def lk_deviation(xy, yaw, lanes: list, lines: list, connector: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per point of ``xy`` (n, 2): the centre's distance to the centreline of
    the lane polygon holding it with the lowest heading error (NAVSIM's
    starting-lane rule; ``Point.distance(linestring)``; ties within
    ``LK_ALIGN_TIE``: the nearest of them), else to the nearest
    centreline; whether a holding lane exists; whether a connector holds it
    (NAVSIM's INTERSECTION layer, skipped by LK). Returns three (n,) arrays."""
    xy, yaw = np.asarray(xy, float), np.asarray(yaw, float)
    dev, held, junction = np.zeros(len(xy)), np.zeros(len(xy), bool), np.zeros(len(xy), bool)
    for k in range(len(xy)):
        p = Point(xy[k])
        heading = np.array([np.cos(yaw[k]), np.sin(yaw[k])])
        holding = []  # (alignment, distance)
        for lp, line, conn in zip(lanes, lines, connector):
            if not lp.covers(p):
                continue
            junction[k] |= conn
            s = line.project(p)
            a, b = line.interpolate(max(s - 0.05, 0.0)), line.interpolate(min(s + 0.05, line.length))
            t = np.array([b.x - a.x, b.y - a.y])
            holding.append((float(t @ heading) / max(np.linalg.norm(t), 1e-9), p.distance(line)))
        held[k] = bool(holding)
        if holding:  # equally aligned lanes (within LK_ALIGN_TIE): the nearest centreline
            best = max(al for al, _ in holding)
            dev[k] = min(d for al, d in holding if al >= best - LK_ALIGN_TIE)
        else:
            dev[k] = min((ln.distance(p) for ln in lines), default=np.inf)
    return dev, held, junction


def lane_keeping(dev: np.ndarray, junction: np.ndarray, dt: float) -> float:
    """NAVSIM ``_calculate_lane_keeping``: 0 once the deviation exceeds 0.5 m on
    ceil(2 s / dt) consecutive states, junction states skipped (no reset)."""
    need, run = int(np.ceil(LK_WINDOW_S / dt - 1e-9)), 0
    for d, j in zip(dev, junction):
        if j:
            continue
        run = run + 1 if d > LK_DEVIATION_M else 0
        if run >= need:
            return 0.0
    return 1.0


def episode_oracle(trace, map_record) -> dict:
    """Oracle facts of one trace at instants 1..n (the states after each active step)."""
    corners = ego_corners(trace.ego_xy[1:], trace.ego_yaw[1:], float(trace.ego_size[0]), float(trace.ego_size[1]))
    excess = corner_excess(drivable_area(map_record), corners)
    records = [ln for ln in map_record.lanes if len(ln.centerline) >= 2]
    lanes = [lane_polygon(ln) for ln in records]
    lines = [LineString(np.asarray(ln.centerline, float)) for ln in records]
    oncoming = oncoming_travel(trace.ego_xy, trace.ego_yaw, lanes, lines)
    direction, worst = direction_compliance(oncoming, float(trace.dt))
    dev, held, junction = lk_deviation(trace.ego_xy[1:], trace.ego_yaw[1:], lanes, lines,
                                       [ln.type == "connector" for ln in records])
    return {"lk_deviation": dev, "lk_held": held, "lk_junction": junction,
            "lk": lane_keeping(dev, junction, float(trace.dt)),
            "excess": excess, "multi_lane": multi_lane(lanes, corners), "oncoming": oncoming,
            "direction": direction, "direction_borderline": bool(min(abs(worst - t) for t in DIRECTION_M)
                                                                  < DIRECTION_BORDER_M),
            "dac_nuplan_fail": bool(np.any(excess >= NUPLAN_DAC_M)), "dac_navsim_fail": bool(np.any(excess > 0.0))}


def compare(trace, oracle: dict) -> dict:
    """What the step produced against ``oracle`` (``episode_oracle``), one episode.

    Keys: ``dac_nuplan`` / ``dac_navsim`` (sim fails?, oracle fails?),
    ``excess_max`` (sim, oracle) m, ``excess_agree`` fraction of instants within
    ``EXCESS_TOL_M`` (or on the same side of 0 / 0.3 m), ``multi_lane_agree``
    fraction of instants with the same answer, and the row's own DAC columns
    where the preset wrote them (``nuplan_drivable_area_compliance``, ``navsim_dac``).
    """
    sim = np.asarray(trace.timeline["facts.drivable_excess_m"][1:], float)
    orc = oracle["excess"]
    close = np.abs(sim - orc) <= EXCESS_TOL_M
    same_side = ((sim > 0) == (orc > 0)) & ((sim >= NUPLAN_DAC_M) == (orc >= NUPLAN_DAC_M))
    ml = np.asarray(trace.timeline["facts.multi_lane"][1:], bool)
    out = {
        "dac_nuplan": (bool(np.any(sim >= NUPLAN_DAC_M)), oracle["dac_nuplan_fail"]),
        "dac_navsim": (bool(np.any(sim > 0.0)), oracle["dac_navsim_fail"]),
        "excess_max": (float(sim.max(initial=0.0)), float(orc.max(initial=0.0))),
        "excess_agree": float(np.mean(close | same_side)) if len(sim) else 1.0,
        "multi_lane_agree": float(np.mean(ml == oracle["multi_lane"])) if len(ml) else 1.0,
        "multi_lane_steps": (int(ml.sum()), int(oracle["multi_lane"].sum())),
        "lanes_overflow_steps": int(np.sum(trace.timeline.get("facts.lanes_overflow", np.zeros(1))[1:])),
    }
    lk = trace.timeline.get("facts.navsim.lane_offset")
    if lk is not None:
        lk = np.asarray(lk[1:], float)
        orc_lk, held = oracle["lk_deviation"], oracle["lk_held"]
        # where a lane holds the centre the values must match; elsewhere both only need to exceed 0.5 m
        ok = np.where(held, np.abs(lk - orc_lk) <= LK_TOL_M, (lk > LK_DEVIATION_M) == (orc_lk > LK_DEVIATION_M))
        out["lk_instant_agree"] = float(np.mean(ok)) if len(ok) else 1.0
        out["lk_worst_gap_m"] = float(np.max(np.abs(lk - orc_lk)[held], initial=0.0))
        out["lk_worst_gap_step"] = int(np.argmax(np.where(held, np.abs(lk - orc_lk), -1.0))) + 1 if held.any() else -1
        # The row's navsim_lk is human-filtered (1 where the logged ego fails LK too), so the
        # step's own LK is NAVSIM's rule on the step's deviations and junction flags.
        junction = np.asarray(trace.timeline["facts.navsim.in_junction"][1:], bool)
        out["lk"] = (lane_keeping(lk, junction, float(trace.dt)), oracle["lk"])
    row = trace.row or {}
    if row.get("navsim_lk") is not None:
        out["navsim_lk"] = float(row["navsim_lk"])
    if row.get("nuplan_driving_direction_compliance") is not None:
        out["direction"] = (float(row["nuplan_driving_direction_compliance"]), oracle["direction"])
        out["direction_borderline"] = oracle["direction_borderline"]
    for col in ("nuplan_drivable_area_compliance", "navsim_dac"):
        if col in row and row[col] is not None:
            out[col] = float(row[col])
    return out
