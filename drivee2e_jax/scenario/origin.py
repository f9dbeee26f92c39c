"""The per-map origin that packing subtracts from world positions (no JAX).

The simulator computes in float32, whose spacing at a coordinate ``x`` is
about ``|x| * 1.2e-7``: 0.5 m at a UTM northing of 4e6 m, 0.24 mm at 2 km,
15 um at 128 m. Sources in a geo-referenced or city frame (UTM Lanelet2 /
OpenDRIVE / CommonRoad maps, ScenarioNet and nuPlan city frames, AV2 city
frames) would lose collisions, drivable-area and comfort geometry to that
quantisation, so ``scenario.pack`` re-centres every scenario on its map's
**origin** before casting to float32:

* ``map_origin(m)``: the centre of the map's bounding box (every lane
  centreline and boundary, road boundary, crosswalk, drivable area, stop line
  and obstacle), rounded to the nearest multiple of ``ORIGIN_GRID`` (1 km) in
  float64. A map without geometry takes the ego's first logged position
  (rounded the same way) of the scenario being packed.
* The origin depends on the map alone, so every scenario of a map (and every
  shard of a streamed suite) shares one local frame and the host-rasterised
  BEV maps (``observe.raster``, world frame) line up with it by one offset.
* Rounding to 1 km leaves maps whose centre lies within 500 m of (0, 0) in
  their own frame, bit for bit: the built-in twin15 (|x|, |y| <= 140 m) and
  the example suites keep origin (0, 0). A map centred further out gets local
  coordinates within 500 m + half its extent of (0, 0).

``POSITION_BOUND`` is the physical bound validation puts on every world
position (``scenario.validate``): see its comment.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from drivee2e_jax.records import MapRecord, ScenarioRecord

__all__ = ["ORIGIN_GRID", "POSITION_BOUND", "POSITION_TEXT", "map_points", "map_origin", "round_origin",
           "ego_start", "translate_map", "translate_scenario"]

#: m; origins are multiples of this (a readable number, stable under small map edits).
ORIGIN_GRID = 1000.0
#: m; the largest |x| or |y| a world position may have. The largest planar
#: frames the importers accept are UTM (easting 0.17e6-0.83e6 m, northing
#: < 1e7 m: 0 at the equator to ~9.3e6 m at 84 deg N; the southern hemisphere's
#: false northing is 1e7 m) and the national grids / city frames of driving
#: datasets (< 1e7 m). A position beyond 1e7 m is no place on Earth in a planar
#: frame (ECEF, whose coordinates are 6.4e6 m from the Earth's centre, is not
#: planar and is not accepted either way): it is a unit or column mistake
#: (mm for m, a timestamp for x), or the float32 overflow guard's 1e37.
POSITION_BOUND = 1e7
POSITION_TEXT = (f"|value| <= {POSITION_BOUND:.0e} m (a planar world position: UTM and city frames "
                 "are within it)")


def map_points(m: MapRecord) -> np.ndarray:
    """(n, 2) float64: every point of the map's geometry (n may be 0)."""
    parts = [np.asarray(ln.centerline, np.float64).reshape(-1, 2) for ln in m.lanes]
    for ln in m.lanes:
        parts += [np.asarray(b, np.float64).reshape(-1, 2) for b in (ln.left_boundary, ln.right_boundary, ln.polygon)
                  if b is not None]
    parts += [np.asarray(b.points, np.float64).reshape(-1, 2) for b in m.boundaries]
    parts += [np.asarray(p, np.float64).reshape(-1, 2) for p in (*m.crosswalks, *m.drivable_areas)]
    parts += [np.asarray(s.points, np.float64).reshape(-1, 2) for s in m.stop_lines]
    parts += [np.asarray(o.polygon, np.float64).reshape(-1, 2) for o in m.obstacles]
    return np.concatenate(parts) if parts else np.zeros((0, 2))


def round_origin(xy) -> np.ndarray:
    """(2,) float64: ``xy`` rounded to the nearest multiple of ``ORIGIN_GRID``
    (+0.0, never -0.0)."""
    return np.round(np.asarray(xy, np.float64).reshape(2) / ORIGIN_GRID) * ORIGIN_GRID + 0.0


def ego_start(s: ScenarioRecord) -> np.ndarray | None:
    """(2,) float64 world position of the ego's first sample (None when the
    scenario has no such track: packing names that problem)."""
    for tr in s.tracks:
        if tr.track_id == s.ego_track_id and len(tr.t):
            return np.asarray(tr.xy, np.float64).reshape(-1, 2)[0]
    return None


def map_origin(m: MapRecord, fallback_xy=None) -> np.ndarray:
    """(2,) float64 world (x, y) of the map's local-frame origin, m (see the
    module docstring); ``fallback_xy`` (a scenario's ego start) is rounded
    instead when the map has no geometry (origin (0, 0) when None)."""
    pts = map_points(m)
    if len(pts):
        return round_origin(0.5 * (pts.min(0) + pts.max(0)))
    return round_origin((0.0, 0.0) if fallback_xy is None else fallback_xy)


def _moved(a, d: np.ndarray):
    return None if a is None else np.asarray(a, np.float64).reshape(-1, 2) + d


def translate_map(m: MapRecord, d) -> MapRecord:
    """``m`` with every position moved by ``d`` ((2,) m, float64): lane
    centrelines and edges, boundaries, crosswalks, stop lines, drivable areas,
    obstacles. ``m`` itself when ``d`` is (0, 0)."""
    d = np.asarray(d, np.float64).reshape(2)
    if not d.any():
        return m
    return dataclasses.replace(
        m,
        lanes=[dataclasses.replace(ln, centerline=_moved(ln.centerline, d), left_boundary=_moved(ln.left_boundary, d),
                                   right_boundary=_moved(ln.right_boundary, d), polygon=_moved(ln.polygon, d))
               for ln in m.lanes],
        boundaries=[dataclasses.replace(b, points=_moved(b.points, d)) for b in m.boundaries],
        crosswalks=[_moved(p, d) for p in m.crosswalks],
        stop_lines=[dataclasses.replace(s, points=_moved(s.points, d)) for s in m.stop_lines],
        drivable_areas=[_moved(p, d) for p in m.drivable_areas],
        obstacles=[dataclasses.replace(o, polygon=_moved(o.polygon, d)) for o in m.obstacles],
    )


def translate_scenario(s: ScenarioRecord, d) -> ScenarioRecord:
    """``s`` with its track positions and route (waypoints, source,
    destination) moved by ``d`` ((2,) m, float64); ``s`` itself when ``d`` is (0, 0)."""
    d = np.asarray(d, np.float64).reshape(2)
    if not d.any():
        return s
    r = s.route
    return dataclasses.replace(
        s, tracks=[dataclasses.replace(t, xy=_moved(t.xy, d)) for t in s.tracks],
        route=dataclasses.replace(r, waypoints=_moved(r.waypoints, d), source=_moved(r.source, d)[0],
                                  destination=_moved(r.destination, d)[0]))
