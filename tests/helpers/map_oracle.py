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
  "ego in multiple lanes").

``compare`` lines these up with what the step produced (the trace's
``facts.*`` timelines and the row's DAC columns). Used by
``experiments/oracles/map_facts.py`` and the tests.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import LineString, Polygon

#: nuPlan's drivable_area_compliance ``max_violation_threshold``, m (from its
#: config, written here again so the oracle does not read the module under test).
NUPLAN_DAC_M = 0.3
#: Per-instant agreement of the excess, m (float32 corners against float64).
EXCESS_TOL_M = 0.01


def lane_polygon(lane) -> Polygon:
    """A lane's area: left boundary + reversed right boundary where the record
    has both, else the centreline buffered by width / 2 with flat ends."""
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


def episode_oracle(trace, map_record) -> dict:
    """Oracle facts of one trace at instants 1..n (the states after each active step)."""
    corners = ego_corners(trace.ego_xy[1:], trace.ego_yaw[1:], float(trace.ego_size[0]), float(trace.ego_size[1]))
    excess = corner_excess(drivable_area(map_record), corners)
    lanes = [lane_polygon(ln) for ln in map_record.lanes if len(ln.centerline) >= 2]
    return {"excess": excess, "multi_lane": multi_lane(lanes, corners),
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
    }
    row = trace.row or {}
    for col in ("nuplan_drivable_area_compliance", "navsim_dac"):
        if col in row and row[col] is not None:
            out[col] = float(row[col])
    return out
