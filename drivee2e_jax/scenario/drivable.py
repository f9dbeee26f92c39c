"""The drivable area of a map as one flat list of boundary edges (host, shapely).

The simulator judges drivable-area compliance (nuPlan's DAC, NAVSIM's DAC,
nuPlan's at-fault rule for lateral contacts) by the distance of each ego
corner outside the drivable area (``infractions.drivable_excess``). That test
runs inside ``jit`` for every tick, so the area is prepared here once per map:
the UNION of the map's drivable polygons is computed with shapely and its
boundary (every exterior and interior ring) is flattened into edges. Inside
``jit`` a point is then inside the area iff a ray from it crosses an odd number
of those edges, and its distance to the area is its distance to the nearest
edge -- exact for any union of simple polygons, holes included, with no
padding of overlapping polygons (twin15: 60-90 edges instead of 8 x 100
padded polygon vertices).

Sources, in order (``DrivableSource``):

* ``POLYGONS``: the map's ``drivable_areas`` (nuPlan's DRIVABLE_AREA layer,
  Argoverse 2 drivable areas, twin15's road surface).
* ``LANES``: a map without drivable polygons falls back to the union of its
  lane polygons (from the lanes' left/right boundaries where the source has
  them, else the curved centreline +- width / 2); ``suite validate`` says so.
* ``NONE``: no area geometry at all (no polygons, no lanes): drivable-area
  compliance is not judged (``drivable_excess_m`` stays 0).
"""

from __future__ import annotations

import enum

import numpy as np
import shapely
from shapely.geometry import Polygon

from drivee2e_jax.records import LaneRecord, MapRecord
from drivee2e_jax.scenario.lane_polygons import lane_polygon

__all__ = ["DrivableSource", "drivable_edges", "drivable_union", "lane_area"]

#: Vertices closer than this to the line through their neighbours are dropped
#: from the union's rings (m): exact to well below the 0.3 m / 0 m thresholds.
SIMPLIFY_TOLERANCE_M = 1e-3


class DrivableSource(enum.IntEnum):
    """Where a packed map's drivable area came from (``MapData.drivable_source``)."""

    NONE = 0
    POLYGONS = 1
    LANES = 2


def lane_area(lane: LaneRecord):
    """A shapely polygon of one lane's area (``scenario.lane_polygons.lane_polygon``:
    its left/right boundaries where the record has them, else the curved
    centreline +- width / 2)."""
    return shapely.make_valid(Polygon(lane_polygon(lane)))


def drivable_union(m: MapRecord):
    """(shapely geometry or None, ``DrivableSource``): the union of the map's
    drivable polygons, else of its lane areas, else None."""
    if m.drivable_areas:
        parts = [shapely.make_valid(Polygon(np.asarray(p, float).reshape(-1, 2))) for p in m.drivable_areas]
        return shapely.union_all(parts), DrivableSource.POLYGONS
    lanes = [ln for ln in m.lanes if len(ln.centerline) >= 2 and ln.width > 0]
    if lanes:
        return shapely.union_all([lane_area(ln) for ln in lanes]), DrivableSource.LANES
    return None, DrivableSource.NONE


def _rings(geom):
    """Every polygon ring (exterior and interiors) of a shapely geometry."""
    polys = [g for g in shapely.get_parts(geom) if isinstance(g, Polygon) and not g.is_empty]
    for g in shapely.get_parts(geom):  # a GeometryCollection from make_valid: its polygonal parts
        if not isinstance(g, Polygon) and hasattr(g, "geoms"):
            polys += [h for h in g.geoms if isinstance(h, Polygon) and not h.is_empty]
    for p in polys:
        yield p.exterior
        yield from p.interiors


def drivable_edges(m: MapRecord) -> tuple[np.ndarray, DrivableSource]:
    """(D, 4) float64 edges [ax, ay, bx, by] of the drivable area's boundary, m,
    and where the area came from (``drivable_union``)."""
    geom, source = drivable_union(m)
    edges = np.zeros((0, 4))
    if geom is not None and not geom.is_empty:
        geom = geom.simplify(SIMPLIFY_TOLERANCE_M, preserve_topology=True)
        rows = []
        for ring in _rings(geom):
            c = np.asarray(ring.coords, float)[:, :2]
            if len(c) >= 4:  # closed: first == last
                rows.append(np.concatenate([c[:-1], c[1:]], axis=1))
        if rows:
            edges = np.concatenate(rows)
    return edges, source
