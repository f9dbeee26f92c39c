"""Lanelets (a lane as a pair of bounds) -> ``MapRecord``: shared by the
Lanelet2, CommonRoad and OpenDRIVE importers (host side, numpy + shapely).

A :class:`Lanelet` is one lane between a left and a right bound polyline, both
ordered in driving direction. :func:`assemble_map` turns a list of them (plus
crosswalk polygons and stop-line polylines) into a ``MapRecord``:

* **Centreline** = midline of the two bounds: both are resampled at the same
  arc-length *fractions* and averaged, then simplified (5 cm tolerance).
  **Width** = mean distance between the paired bound points.
* **Successors**: the ones the format gives, else inferred from geometry by
  ``common.infer_successors`` over the vehicle lanes: B follows A when B's
  centreline starts within :data:`SUCCESSOR_TOL_M` of A's end and the headings
  there differ by < 45 deg.
* **Connector** lanes (junction interiors): the ones the format marks, else
  inferred: a lane whose centreline crosses another lane's centreline away from
  both ends (turning paths cross), or that starts where another lane starts
  and ends > 2 m away heading > 30 deg differently (a fork at a junction
  entry; a turn pocket added alongside its lane stays a driving lane).
* **Boundaries**: every distinct bound whose marking is not ``none``.
* **Stop lines**: a stop-line polyline is split per lane: one
  ``StopLineRecord`` for each non-connector vehicle lane whose centreline
  (extended 1.5 m at its end) crosses it more than 0.5 m after the lane's
  start, spanning that lane's width at the crossing.
* **Drivable area**: union of the vehicle lanes' polygons, closed over
  0.5 m gaps, simplified (0.2 m); holes are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from drivee2e_jax.polyline import arc_length, polyline_heading, resample_at_fractions, wrap_angle
from drivee2e_jax.records import BoundaryRecord, LaneRecord, MapRecord, StopLineRecord
from drivee2e_jax.scenario.importers.maps import infer_successors

__all__ = [
    "Lanelet",
    "StopLineSpec",
    "orient_bounds",
    "midline",
    "simplify",
    "assemble_map",
]

#: Lane types that carry vehicles (get drivable area, stop lines, successors).
VEHICLE_TYPES = ("driving", "turn_pocket", "connector")
#: Successor gap tolerance, m (Lanelet2 maps such as SinD's leave ~1 m "gap" lanelets).
SUCCESSOR_TOL_M = 1.5


@dataclass
class Lanelet:
    """One lane between two bounds, both (n, 2) / (m, 2) m in driving direction.

    ``successors`` None = infer from geometry; ``connector`` None = infer.
    ``speed_limit`` in m/s (None: the LaneRecord default). ``markings_guessed``:
    the format gave no markings and the importer guessed them; a connector's
    guessed markings become ``none`` (junction interiors are unpainted).
    """

    id: int
    left: np.ndarray
    right: np.ndarray
    left_marking: str = "dashed"
    right_marking: str = "dashed"
    type: str = "driving"
    speed_limit: float | None = None
    successors: list[int] | None = None
    connector: bool | None = None
    name: str = ""
    markings_guessed: bool = False  # markings inferred by the format, not read: unpainted ("none") in a junction


@dataclass
class StopLineSpec:
    """A stop-line polyline (n, 2) m guarded by ``signal_group`` (-1: none);
    ``lanes``: the lanelet ids it is known to stop (None: find by geometry)."""

    points: np.ndarray
    signal_group: int = -1
    lanes: list[int] | None = None


# --------------------------------------------------------------------------
# Polyline helpers
# --------------------------------------------------------------------------


def orient_bounds(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Put both bounds in one direction, with ``left`` on the left of travel.

    Returns (left, right, flipped): the right bound is reversed when it runs
    against the left one; then both are reversed (``flipped`` True) when the
    left bound lies on the right of that direction. Formats that guarantee the
    orientation need not call this.
    """
    left = np.asarray(left, np.float64)
    right = np.asarray(right, np.float64)
    same = np.linalg.norm(left[0] - right[0]) + np.linalg.norm(left[-1] - right[-1])
    opposite = np.linalg.norm(left[0] - right[-1]) + np.linalg.norm(left[-1] - right[0])
    if opposite < same:
        right = right[::-1]
    mid = midline(left, right, 2)
    d = mid[-1] - mid[0]
    off = resample_at_fractions(left, np.array([0.5]))[0] - resample_at_fractions(right, np.array([0.5]))[0]
    flipped = bool(d[0] * off[1] - d[1] * off[0] < 0.0)
    if flipped:
        left, right = right[::-1], left[::-1]
    return left, right, flipped


def midline(left: np.ndarray, right: np.ndarray, n: int | None = None, spacing: float = 1.0) -> np.ndarray:
    """Midline (n, 2) of two bounds in the same direction, paired by arc-length
    fraction; ``n`` defaults to one point per ``spacing`` m (at least the
    larger bound's point count)."""
    if n is None:
        length = max(arc_length(np.asarray(left))[-1], arc_length(np.asarray(right))[-1])
        n = max(len(left), len(right), int(math.ceil(length / spacing)) + 1, 2)
    frac = np.linspace(0.0, 1.0, n)
    return 0.5 * (resample_at_fractions(left, frac) + resample_at_fractions(right, frac))


def _end_heading(xy: np.ndarray) -> float:
    """Heading over the last 2 m of a centreline (steadier than its last segment)."""
    return polyline_heading(xy, at_end=True, over_m=2.0)


def simplify(xy: np.ndarray, tol: float = 0.05) -> np.ndarray:
    """Douglas-Peucker simplification (keeps both ends); (k, 2)."""
    xy = np.asarray(xy, np.float64)
    if len(xy) <= 2:
        return xy
    keep = np.asarray(shapely.LineString(xy).simplify(tol, preserve_topology=False).coords)
    return keep if len(keep) >= 2 else xy[[0, -1]]


# --------------------------------------------------------------------------
# Assembly
# --------------------------------------------------------------------------


@dataclass
class _Lane:
    src: Lanelet
    center: np.ndarray
    width: float
    connector: bool = False


def _build_lane(ll: Lanelet) -> _Lane:
    n = max(len(ll.left), len(ll.right), 2)
    length = max(arc_length(ll.left)[-1], arc_length(ll.right)[-1])
    n = max(n, int(math.ceil(length / 1.0)) + 1)
    frac = np.linspace(0.0, 1.0, n)
    lp, rp = resample_at_fractions(ll.left, frac), resample_at_fractions(ll.right, frac)
    center = simplify(0.5 * (lp + rp))
    width = float(np.mean(np.linalg.norm(lp - rp, axis=1)))
    return _Lane(src=ll, center=center, width=width)


def _infer_connectors(lanes: list[_Lane]) -> None:
    veh = [ln for ln in lanes if ln.src.type in VEHICLE_TYPES]
    lines = [shapely.LineString(ln.center) for ln in veh]
    tree = shapely.STRtree(lines)
    for i, a in enumerate(veh):
        if a.src.connector is not None:
            a.connector = bool(a.src.connector)
            continue
        ends = shapely.MultiPoint([a.center[0], a.center[-1]])
        for j in tree.query(lines[i]):
            if j == i:
                continue
            b = veh[j]
            same_start = np.linalg.norm(a.center[0] - b.center[0]) < 0.5
            turn = abs(float(wrap_angle(_end_heading(a.center) - _end_heading(b.center))))
            if same_start and np.linalg.norm(a.center[-1] - b.center[-1]) > 2.0 and turn > math.radians(30.0):
                a.connector = True  # paths that part at a junction entry (not a lane added alongside)
                break
            if same_start or np.linalg.norm(a.center[-1] - b.center[-1]) < 0.5:
                continue  # a merge onto one exit lane is not a crossing
            hit = lines[i].intersection(lines[j])
            if hit.is_empty:
                continue
            far = ends.union(shapely.MultiPoint([b.center[0], b.center[-1]])).buffer(0.5)
            if not hit.difference(far).is_empty:
                a.connector = True
                break


def _boundary_key(pts: np.ndarray) -> tuple:
    a, b = np.round(pts[0], 1), np.round(pts[-1], 1)
    lo, hi = sorted([tuple(a), tuple(b)])
    return (lo, hi, len(pts), round(float(arc_length(pts)[-1]), 1))


def _boundaries(lanes: list[_Lane], extra: list[BoundaryRecord]) -> list[BoundaryRecord]:
    out: list[BoundaryRecord] = []
    seen: set = set()
    cands = [(ln.src.left, ln.src.left_marking) for ln in lanes]
    cands += [(ln.src.right, ln.src.right_marking) for ln in lanes]
    cands += [(b.points, b.marking) for b in extra]
    for pts, marking in cands:
        pts = simplify(np.asarray(pts, np.float64))
        if marking == "none" or len(pts) < 2:
            continue
        key = _boundary_key(pts)
        if key in seen:
            continue
        seen.add(key)
        out.append(BoundaryRecord(points=pts, marking=marking))
    return out


def _stop_lines(specs: list[StopLineSpec], lanes: list[_Lane]) -> list[StopLineRecord]:
    out: list[StopLineRecord] = []
    veh = [ln for ln in lanes if ln.src.type in VEHICLE_TYPES and not ln.connector]
    for spec in specs:
        line = shapely.LineString(np.asarray(spec.points, np.float64))
        for ln in veh:
            if spec.lanes is not None and ln.src.id not in spec.lanes:
                continue
            c = ln.center
            h = _end_heading(c)
            ext = np.vstack([c, c[-1] + 1.5 * np.array([math.cos(h), math.sin(h)])])
            hit = shapely.LineString(ext).intersection(line)
            if hit.is_empty:
                continue
            p = np.asarray(hit.geoms[0].coords[0] if hasattr(hit, "geoms") else hit.coords[0])
            proj = shapely.LineString(ext).project(shapely.Point(p))
            if proj < 0.5:
                continue  # the line is where this lane starts: it stops the lane before, not this one
            q = shapely.LineString(ext).interpolate(min(proj + 0.5, shapely.LineString(ext).length))
            r = shapely.LineString(ext).interpolate(max(proj - 0.5, 0.0))
            d = np.array(q.coords[0]) - np.array(r.coords[0])
            nrm = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-9)
            pts = np.stack([p - nrm * ln.width / 2, p + nrm * ln.width / 2])
            out.append(StopLineRecord(id=len(out), points=pts, lane_id=ln.src.id, signal_group=spec.signal_group))
    return out


def _drivable(lanes: list[_Lane]) -> list[np.ndarray]:
    polys = []
    for ln in lanes:
        if ln.src.type not in VEHICLE_TYPES:
            continue
        ring = np.vstack([ln.src.left, ln.src.right[::-1]])
        p = shapely.Polygon(ring)
        if not p.is_valid:
            p = shapely.make_valid(p)
        polys.append(p.buffer(0))
    if not polys:
        return []
    area = shapely.union_all(polys).buffer(0.5, join_style="mitre").buffer(-0.5, join_style="mitre")
    area = area.simplify(0.2)
    geoms = getattr(area, "geoms", [area])
    out = []
    for g in geoms:
        if g.geom_type != "Polygon" or g.area < 1.0:
            continue
        ring = shapely.Polygon(g.exterior)
        ring = shapely.geometry.polygon.orient(ring, 1.0)
        out.append(np.asarray(ring.exterior.coords)[:-1])
    return out


def assemble_map(map_id: str, lanelets: list[Lanelet], *, crosswalks: list[np.ndarray] = (),
                 stop_lines: list[StopLineSpec] = (), extra_boundaries: list[BoundaryRecord] = (),
                 meta: dict | None = None) -> MapRecord:
    """Lanelets + crosswalk polygons + stop-line polylines -> one MapRecord
    (rules in the module docstring). Lane ids are the lanelet ids."""
    lanes = [_build_lane(ll) for ll in lanelets]
    _infer_connectors(lanes)
    records = []
    for ln in lanes:  # (boundaries are collected below, after connector markings are settled)
        ltype = ln.src.type
        if ltype in ("driving", "turn_pocket") and ln.connector:
            ltype = "connector"
        kw = {} if ln.src.speed_limit is None else {"speed_limit": float(ln.src.speed_limit)}
        if ltype == "connector" and ln.src.markings_guessed:
            ln.src.left_marking = ln.src.right_marking = "none"
        records.append(LaneRecord(id=int(ln.src.id), centerline=ln.center, width=ln.width, type=ltype,
                                  successors=[int(s) for s in dict.fromkeys(ln.src.successors or [])],
                                  left_marking=ln.src.left_marking, right_marking=ln.src.right_marking,
                                  left_boundary=np.asarray(ln.src.left, np.float64),
                                  right_boundary=np.asarray(ln.src.right, np.float64), **kw))
    if any(ln.src.successors is None for ln in lanes):  # a lane graph by geometry where the format has none
        infer_successors([r for r in records if r.type in VEHICLE_TYPES], tol_m=SUCCESSOR_TOL_M)
        for ln, rec in zip(lanes, records):
            if ln.src.successors is not None:
                rec.successors = [int(s) for s in dict.fromkeys(ln.src.successors)]
    for ln, rec in zip(lanes, records):
        ln.connector = rec.type == "connector"
    return MapRecord(
        map_id=map_id,
        lanes=records,
        boundaries=_boundaries(lanes, list(extra_boundaries)),
        crosswalks=[np.asarray(c, np.float64) for c in crosswalks],
        stop_lines=_stop_lines(list(stop_lines), lanes),
        drivable_areas=_drivable(lanes),
        meta=dict(meta or {}),
    )
