"""Lane area polygons, built on the host (numpy; shapely only to simplify; no JAX).

A lane's area is a simple, counter-clockwise polygon (V, 2) in metres:

* ``"polygon"``: when the lane carries its own area ring (``LaneRecord.polygon``:
  nuScenes / nuPlan lane polygons through ScenarioNet), that ring, used exactly
  as given (closing point dropped, orientation made counter-clockwise);
* ``"boundaries"``: when the lane carries both ``left_boundary`` and
  ``right_boundary`` (polylines in the driving direction, left = left of
  travel), the polygon is the right boundary followed by the reversed left
  boundary (counter-clockwise for a lane driven along +x with its left edge at
  +y), used exactly as given;
* ``"centerline"``: otherwise the curved centreline offset by ± width/2 along
  per-vertex normals (bisector normals at interior vertices, mitre-limited so
  tight bends do not self-intersect).
"""

from __future__ import annotations

import numpy as np
from shapely.geometry import Polygon

from ..records import LaneRecord

__all__ = ["MAX_VERTICES", "MITRE_LIMIT", "SIMPLIFY_TOLERANCE", "lane_polygon", "lane_polygon_source",
           "map_notes", "offset_polyline", "packed_lane_polygon", "signed_area"]

# Largest mitre scale 1/cos(theta/2) at an interior vertex (a 120° turn); beyond
# it the offset is clipped so the edges of a tight bend cannot cross over.
MITRE_LIMIT = 2.0

#: Most vertices a packed lane polygon keeps (the simulator tests every one).
MAX_VERTICES = 64
#: First shapely ``simplify`` tolerance (m) for a polygon over MAX_VERTICES; grown 1.25x until it fits.
SIMPLIFY_TOLERANCE = 0.02


def signed_area(poly: np.ndarray) -> float:
    """Shoelace area of a closed ring (V, 2), m²; > 0 for counter-clockwise."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _dedupe(line: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Drop consecutive duplicate points of a polyline (n, 2)."""
    line = np.asarray(line, np.float64).reshape(-1, 2)
    if len(line) < 2:
        return line
    keep = np.concatenate([[True], np.linalg.norm(np.diff(line, axis=0), axis=1) > eps])
    return line[keep]


def offset_polyline(line: np.ndarray, offset: float) -> np.ndarray:
    """Offset a polyline (n, 2) by ``offset`` metres to its left (< 0: right).

    End vertices use their segment's normal; interior vertices use the bisector
    of the two adjacent segment normals, scaled by 1/cos(half turn angle) (the
    mitre) and clipped at ``MITRE_LIMIT``.  Returns (n, 2).
    """
    line = _dedupe(line)
    d = np.diff(line, axis=0)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    nrm = np.stack([-d[:, 1], d[:, 0]], axis=1)  # (n-1, 2) left normals
    vn = np.empty_like(line)
    vn[0], vn[-1] = nrm[0], nrm[-1]
    if len(line) > 2:
        b = nrm[:-1] + nrm[1:]
        bl = np.linalg.norm(b, axis=1, keepdims=True)
        b = np.where(bl > 1e-9, b / np.maximum(bl, 1e-12), nrm[:-1])
        cos_half = np.sum(b * nrm[:-1], axis=1, keepdims=True)
        vn[1:-1] = b / np.maximum(cos_half, 1.0 / MITRE_LIMIT)
    return line + offset * vn


def lane_polygon_source(lane: LaneRecord) -> str:
    """``"polygon"`` if the lane has its own area ring, ``"boundaries"`` if it has both
    boundary polylines, else ``"centerline"``."""
    if lane.polygon is not None and len(lane.polygon) >= 3:
        return "polygon"
    if (lane.left_boundary is not None and lane.right_boundary is not None
            and len(lane.left_boundary) >= 2 and len(lane.right_boundary) >= 2):
        return "boundaries"
    return "centerline"


def lane_polygon(lane: LaneRecord) -> np.ndarray:
    """The lane's area as a simple counter-clockwise polygon (V, 2), m, open ring.

    The lane's own ring when it has one, else from the boundaries when both are
    present (right boundary, then the left one reversed), else the centreline
    offset by ± width/2 (see ``offset_polyline``). The orientation is normalised
    to counter-clockwise by the shoelace sign.
    """
    source = lane_polygon_source(lane)
    if source == "polygon":
        ring = _dedupe(np.asarray(lane.polygon, np.float64)[:, :2])
        if len(ring) > 1 and np.allclose(ring[0], ring[-1]):
            ring = ring[:-1]
        return ring if signed_area(ring) >= 0 else ring[::-1]
    if source == "boundaries":
        left = _dedupe(lane.left_boundary)
        right = _dedupe(lane.right_boundary)
    else:
        cl = _dedupe(lane.centerline)
        half = 0.5 * float(lane.width)
        left = offset_polyline(cl, half)
        right = offset_polyline(cl, -half)
    ring = np.concatenate([right, left[::-1]], axis=0)
    ring = _dedupe(ring)
    if len(ring) > 1 and np.allclose(ring[0], ring[-1]):
        ring = ring[:-1]
    if signed_area(ring) < 0:
        ring = ring[::-1]
    return ring


def packed_lane_polygon(lane: LaneRecord, max_vertices: int = MAX_VERTICES) -> np.ndarray:
    """``lane_polygon(lane)`` with at most ``max_vertices`` vertices (V, 2), m.

    Over the cap the ring is simplified with shapely (topology-preserving,
    tolerance SIMPLIFY_TOLERANCE, grown by 1.25x until it fits); the result stays
    counter-clockwise and open.
    """
    ring = lane_polygon(lane)
    if len(ring) <= max_vertices:
        return ring
    shp, tol = Polygon(ring), SIMPLIFY_TOLERANCE
    while True:
        out = np.asarray(shp.simplify(tol, preserve_topology=True).exterior.coords)[:-1]
        if len(out) <= max_vertices:
            break
        tol *= 1.25
    if signed_area(out) < 0:
        out = out[::-1]
    return out


def map_notes(m) -> list[str]:
    """Informative lines (not problems) about a MapRecord's lane polygons.

    * no drivable_areas: drivable-area compliance falls back to the union of the
      lane polygons (with the count from boundaries vs centreline);
    * some but not all lanes have boundaries: the ids of the fallback lanes.
    """
    src = [lane_polygon_source(ln) for ln in m.lanes]
    npg, nb, nc = src.count("polygon"), src.count("boundaries"), src.count("centerline")
    out = []
    if not m.drivable_areas:
        own = f"{npg} the lane's own polygon, " if npg else ""
        out.append(f"map {m.map_id}: no drivable_areas; drivable-area compliance uses the union of its lane "
                   f"polygons ({own}{nb} from boundaries, {nc} from centreline ± width/2)")
    if (nb or npg) and nc:
        ids = [ln.id for ln, s in zip(m.lanes, src) if s == "centerline"]
        shown = ", ".join(str(i) for i in ids[:10]) + (f", ... ({len(ids)} in all)" if len(ids) > 10 else "")
        out.append(f"map {m.map_id}: lanes {shown} have no polygon nor left/right_boundary; their polygons are "
                   f"the centreline ± width/2")
    return out
