"""Ego choice and behaviour labels of recorded scenarios (see
``importers.common``): ``select_ego``, ``infer_behavior``. The label
thresholds are ``scenario.labels``'s, shared with the twin15 generator."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from shapely.geometry import LineString, Point, Polygon

from drivee2e_jax.polyline import arc_length, polyline_length, wrap_angle
from drivee2e_jax.records import MapRecord, ScenarioRecord, TrackRecord
from drivee2e_jax.scenario import curation
from drivee2e_jax.scenario.labels import (
    COV_AHEAD_M,
    COV_MIN_ANGLE,
    IPC_AHEAD_M,
    STOP_MIN_S,
    STOP_RESUME_M,
    STOP_SPEED_MPS,
    turn_label,
)
from drivee2e_jax.scenario.routes import build_route, route_heading_change

from .tracks import VEHICLES

__all__ = ["PLAUSIBILITY_PREFIX", "select_ego", "infer_behavior"]

#: How ``select_ego`` starts the reason of a candidate rejected for a plausibility finding.
PLAUSIBILITY_PREFIX = "implausible motion: "


def select_ego(tracks: Sequence[TrackRecord], map_rec: MapRecord, num_steps: int, dt: float,
               ) -> tuple[TrackRecord | None, dict[int, str]]:
    """Pick an ego by the curation rules of the source benchmarks (nuPlan /
    Waymo-style "ego candidate"): a vehicle (``VEHICLES``) present at every
    step of the window, visible at every step, whose logged path is at least
    ``curation.MIN_ROUTE_LENGTH_M`` long, gives a route that follows the
    lanes (``curation.route_problems`` finds nothing) and has no plausibility
    finding (``curation.track_plausibility``: speed, acceleration, yaw rate
    within the category's bounds; an annotation glitch in the ego's log would
    be replayed as the ego's own driving). Among candidates the longest path
    wins (ties: lowest track id). Returns the track (or None) and the reason
    each other vehicle was rejected; a candidate rejected only for
    plausibility has a reason starting with ``PLAUSIBILITY_PREFIX``."""

    reasons: dict[int, str] = {}
    best: tuple[float, int, TrackRecord] | None = None
    for tr in tracks:
        if tr.category not in VEHICLES:
            continue
        k = np.rint(np.asarray(tr.t) / dt).astype(int)
        if len(np.unique(k)) < num_steps or k.min() != 0:
            reasons[tr.track_id] = f"present at {len(np.unique(k))} of {num_steps} steps"
            continue
        if tr.visible is not None and not np.all(tr.visible):
            reasons[tr.track_id] = "not visible at every step"
            continue
        length = polyline_length(tr.xy)
        if length < curation.MIN_ROUTE_LENGTH_M:
            reasons[tr.track_id] = f"moves {length:.1f} m < {curation.MIN_ROUTE_LENGTH_M:g} m"
            continue
        bad = curation.route_problems(build_route(tr), map_rec)
        if bad:
            reasons[tr.track_id] = bad[0]
            continue
        found = curation.track_plausibility(tr, dt)
        if found:
            more = f" (+{len(found) - 1} more)" if len(found) > 1 else ""
            reasons[tr.track_id] = f"{PLAUSIBILITY_PREFIX}{found[0].message} at t={found[0].t:.1f} s{more}"
            continue
        key = (-length, tr.track_id, tr)
        if best is None or key[:2] < best[:2]:
            best = key
    return (best[2] if best else None), reasons


def _speeds(tr: TrackRecord, dt: float) -> np.ndarray:
    """Speeds from positions (not the source's velocity field, which some conversions leave at zero)."""
    if len(tr.t) < 2:
        return np.zeros(len(tr.t))
    return np.linalg.norm(np.gradient(tr.xy, tr.t, axis=0), axis=1)


def infer_behavior(scenario: ScenarioRecord, map_rec: MapRecord) -> tuple[str, str]:
    """The behaviour label of a recorded scenario and a one-line why.

    In this order (the first that holds wins):

    * YLW is never inferred (needs signal states, which the sources lack).
    * STP: the ego is stopped (< 0.1 m/s, from its positions) for >= 1 s and
      afterwards drives on >= 5 m (a stop-and-go at a junction or behind traffic).
    * IPC: a pedestrian or cyclist is inside a crosswalk polygon that the
      ego's path crosses, while the ego is within 25 m before or on it.
    * COV: another vehicle's path crosses the ego's path at > 30 deg, and the
      other vehicle passes the crossing point while the ego is within 25 m
      before it (it has not yet reached it).
    * else the turn label from the route's total heading change: > 150 deg
      UT; > 40 deg left LFT; > 40 deg right RT; otherwise STR.

    The test of each rule is host-side (shapely).
    """
    dt = scenario.dt
    ego = next(t for t in scenario.tracks if t.track_id == scenario.ego_track_id)
    speed = _speeds(ego, dt)
    stopped = speed < STOP_SPEED_MPS
    run = 0
    for i, s in enumerate(stopped):
        run = run + 1 if s else 0
        if run * dt >= STOP_MIN_S and polyline_length(ego.xy[i:]) >= STOP_RESUME_M:
            return "STP", f"ego stopped >= {STOP_MIN_S:g} s at t={ego.t[i]:.1f} s, then drove on"
    path = LineString(ego.xy) if len(ego.xy) >= 2 and polyline_length(ego.xy) > 0 else None
    if path is not None:
        arc_ego = arc_length(ego.xy)
        step_of = {int(round(t / dt)): i for i, t in enumerate(ego.t)}
        for cw in map_rec.crosswalks:
            poly = Polygon(cw)
            if not poly.is_valid or not path.intersects(poly):
                continue
            cross = path.intersection(poly)
            s_in = path.project(Point(cross.representative_point()))
            for tr in scenario.tracks:
                if tr.category not in ("pedestrian", "cyclist"):
                    continue
                for t, p in zip(tr.t, tr.xy):
                    i = step_of.get(int(round(t / dt)))
                    if i is None or not poly.contains(Point(p)):
                        continue
                    if -poly.length <= s_in - arc_ego[i] <= IPC_AHEAD_M:
                        return "IPC", f"{tr.category} {tr.track_id} on a crosswalk ahead of the ego at t={t:.1f} s"
        for tr in scenario.tracks:
            if tr.track_id == ego.track_id or tr.category not in VEHICLES or len(tr.xy) < 2:
                continue
            if polyline_length(tr.xy) < 1.0:
                continue
            other = LineString(tr.xy)
            hit = path.intersection(other)
            if hit.is_empty:
                continue
            pt = hit.representative_point() if hit.geom_type != "Point" else hit
            s_e, s_o = path.project(pt), other.project(pt)
            ie = int(np.clip(np.searchsorted(arc_ego, s_e), 1, len(ego.xy) - 1))
            arc_o = arc_length(tr.xy)
            io = int(np.clip(np.searchsorted(arc_o, s_o), 1, len(tr.xy) - 1))
            de, do = ego.xy[ie] - ego.xy[ie - 1], tr.xy[io] - tr.xy[io - 1]
            ang = abs(wrap_angle(math.atan2(de[1], de[0]) - math.atan2(do[1], do[0])))
            if min(ang, math.pi - ang) < COV_MIN_ANGLE:
                continue
            i_ego = step_of.get(int(round(tr.t[io] / dt)))
            if i_ego is not None and 0 < s_e - arc_ego[i_ego] <= COV_AHEAD_M:
                return "COV", f"vehicle {tr.track_id} crossed the ego's path ahead of it at t={tr.t[io]:.1f} s"
    turn = math.degrees(route_heading_change(scenario.route.waypoints))
    return turn_label(turn), f"heading change {turn:.0f} deg"
