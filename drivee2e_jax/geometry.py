"""Planar geometry: frames, oriented boxes, polygons, segments, polylines.

Every function is pure JAX and written for ONE item (one point, one box, one
polygon); callers ``jax.vmap``. Padded inputs carry a ``valid`` mask and
invalid entries never influence a result. World frame: x east, y north, yaw
counter-clockwise from +x, metres and radians. A *local* (ego) frame has x
forward and y left.

Conventions shared by the predicates (all within a tolerance ``eps`` in m):

* boxes / polygons *overlap* only when they share interior: touching edges or
  corners are NOT an overlap (a car parked bumper-to-bumper does not collide);
* segments *intersect* when the closed segments share a point: touching at an
  end point, a T-junction or a collinear overlap all count (a stop line touched
  by the ego's tail counts as crossed);
* a point is *in* a polygon by the even-odd crossing rule; points exactly on
  the boundary may go either way.

Gradients: distances use a zero-safe norm, so gradients are finite (zero at
the exact degenerate point) rather than NaN; min/argmin selections are
piecewise smooth.

Ray casting (LiDAR-like range sensing against boxes and polygon edges) will
live here too, as ``ray_segment_distance`` / ``ray_box_distance`` built on the
same segment algebra; it arrives with the sensor issue.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

Array = jnp.ndarray

#: Default tolerance of the boolean predicates, m. float32 world coordinates
#: of a few hundred metres carry ~1e-5 m of rounding, so stay well above it.
EPS = 1e-4

_TINY = 1e-12  # squared-length floor below which a vector counts as zero


# --------------------------------------------------------------------------
# Angles and frames
# --------------------------------------------------------------------------


def wrap_angle(a: Array) -> Array:
    """Wrap angles to (-pi, pi]. Elementwise; derivative 1 everywhere."""
    two_pi = 2.0 * jnp.pi
    return a + two_pi * jnp.floor((jnp.pi - a) / two_pi)


def rotate(v: Array, yaw: Array) -> Array:
    """Rotate vectors ``v (..., 2)`` counter-clockwise by ``yaw`` (rad, broadcast
    against ``v[..., 0]``)."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    x, y = v[..., 0], v[..., 1]
    return jnp.stack([c * x - s * y, s * x + c * y], axis=-1)


def to_frame(points: Array, origin: Array, yaw: Array) -> Array:
    """World points ``(..., 2)`` -> the local frame at ``origin (2,)`` with
    heading ``yaw`` (x forward, y left)."""
    return rotate(points - origin, -yaw)


def from_frame(points: Array, origin: Array, yaw: Array) -> Array:
    """Local points ``(..., 2)`` (x forward, y left) of the frame at ``origin``
    with heading ``yaw`` -> world points ``(..., 2)``. Inverse of ``to_frame``."""
    return rotate(points, yaw) + origin


def cross2(a: Array, b: Array) -> Array:
    """z of the 2-D cross product a x b, (..., 2) x (..., 2) -> (...)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def dot(a: Array, b: Array) -> Array:
    """Dot product over the last axis, (..., n) x (..., n) -> (...).

    For 2-vectors written as ``a0 b0 + a1 b1``: XLA:CPU runs a sum over a
    trailing axis of 2 as an element-by-element reduction, ~4x slower over
    batched rows (docs/performance.md)."""
    if jnp.shape(a)[-1:] == (2,) and jnp.shape(b)[-1:] == (2,):
        return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]
    return jnp.sum(a * b, axis=-1)


def safe_norm(v: Array) -> Array:
    """|v| with a zero (not NaN) gradient at v = 0."""
    sq = dot(v, v)
    ok = sq > _TINY
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)


def row_norms(v: Array) -> Array:
    """``(...,)`` lengths of the 2-vectors ``v (..., 2)``: ``sqrt(dot(v, v))``, the
    plane form (``jnp.linalg.norm(v, axis=-1)`` reduces a trailing axis of 2).
    No gradient guard at 0: use ``safe_norm`` where one is differentiated."""
    return jnp.sqrt(dot(v, v))


def _unit(v: Array) -> tuple[Array, Array]:
    """(v / |v|, nonzero); zero vectors map to (1, 0) so callers can mask them."""
    n = safe_norm(v)
    ok = n > jnp.sqrt(_TINY)
    u = jnp.where(ok[..., None], v / jnp.where(ok, n, 1.0)[..., None], jnp.array([1.0, 0.0]))
    return u, ok


# --------------------------------------------------------------------------
# Oriented boxes (SAT)
# --------------------------------------------------------------------------


def box_corners(xy: Array, yaw: Array, length: Array, width: Array) -> Array:
    """Corners ``(4, 2)`` of a box centred at ``xy (2,)`` with heading ``yaw``,
    counter-clockwise from the front-right corner (FR, FL, RL, RR)."""
    hl, hw = 0.5 * length, 0.5 * width
    local = jnp.stack(
        [jnp.stack([hl, -hw]), jnp.stack([hl, hw]), jnp.stack([-hl, hw]), jnp.stack([-hl, -hw])]
    )
    return from_frame(local, xy, yaw)


def _box_axes(yaw: Array) -> Array:
    """(2, 2) unit axes of a box: forward, left."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    return jnp.stack([jnp.stack([c, s]), jnp.stack([-s, c])])


def _box_radius(axes_n: Array, yaw: Array, lw: Array) -> Array:
    """Half-extent of a box (heading ``yaw``, ``lw`` = length, width) projected
    on unit axes ``axes_n (k, 2)`` -> (k,)."""
    cos, sin = jnp.cos(yaw), jnp.sin(yaw)
    # Multiply-adds rather than small matmuls (slow when batched on XLA:CPU).
    along = axes_n[..., 0] * cos + axes_n[..., 1] * sin
    across = -axes_n[..., 0] * sin + axes_n[..., 1] * cos
    return 0.5 * (jnp.abs(along) * lw[0] + jnp.abs(across) * lw[1])


def box_penetration(
    xy_a: Array, yaw_a: Array, lw_a: Array, xy_b: Array, yaw_b: Array, lw_b: Array
) -> Array:
    """Signed overlap depth of two oriented boxes, m.

    The minimum over the four separating-axis candidates of the projected
    overlap. Positive: the boxes overlap and this is the shortest translation
    separating them. Non-positive: they are apart and ``-value`` is a lower
    bound of the gap (exact when the closest features are parallel edges).
    Piecewise smooth, so usable as a soft collision penalty.

    Args:
      xy_a, xy_b: (2,) box centres, m.  yaw_a, yaw_b: () headings, rad.
      lw_a, lw_b: (2,) length, width, m (a ``Tracks.size[:2]`` row works).
    """
    axes = jnp.concatenate([_box_axes(yaw_a), _box_axes(yaw_b)])  # (4, 2)
    d = xy_b - xy_a
    centre_gap = jnp.abs(axes[..., 0] * d[0] + axes[..., 1] * d[1])
    overlap = _box_radius(axes, yaw_a, lw_a) + _box_radius(axes, yaw_b, lw_b) - centre_gap
    return jnp.min(overlap)


def boxes_overlap(
    xy_a: Array,
    yaw_a: Array,
    lw_a: Array,
    xy_b: Array,
    yaw_b: Array,
    lw_b: Array,
    eps: float = EPS,
) -> Array:
    """() bool: the two oriented boxes share interior (depth > ``eps`` m);
    touching edges do not count. Arguments as ``box_penetration``."""
    return box_penetration(xy_a, yaw_a, lw_a, xy_b, yaw_b, lw_b) > eps


def segment_box_intersect(p: Array, q: Array, xy: Array, yaw: Array, lw: Array) -> Array:
    """() bool: the segment ``p``-``q`` ((2,) each, m) touches the oriented box
    (centre ``xy`` (2,), heading ``yaw``, ``lw`` = length, width) -- shapely's
    ``LineString.intersects(Polygon)``: an endpoint inside or an edge crossed.

    Liang-Barsky clipping of the segment in the box frame: the parameter range
    [0, 1] is cut by each slab ``|x| <= l/2``, ``|y| <= w/2``; it intersects
    when the range stays non-empty.
    """
    a = to_frame(p[None], xy, yaw)[0]
    d = to_frame(q[None], xy, yaw)[0] - a
    half = 0.5 * lw[:2]
    lo, hi = jnp.zeros(()), jnp.ones(())
    for k in range(2):
        parallel = jnp.abs(d[k]) < _TINY
        inv = 1.0 / jnp.where(parallel, 1.0, d[k])
        t1, t2 = (-half[k] - a[k]) * inv, (half[k] - a[k]) * inv
        lo = jnp.where(parallel, lo, jnp.maximum(lo, jnp.minimum(t1, t2)))
        hi = jnp.where(parallel, hi, jnp.minimum(hi, jnp.maximum(t1, t2)))
        # A segment parallel to a slab misses unless it runs inside it.
        hi = jnp.where(parallel & (jnp.abs(a[k]) > half[k]), -1.0, hi)
    return lo <= hi


# --------------------------------------------------------------------------
# Padded polygons
# --------------------------------------------------------------------------


def closed_edges(poly: Array, valid: Array) -> tuple[Array, Array, Array]:
    """Edges of a padded polygon, closed, skipping invalid vertices.

    Each invalid vertex is replaced by the previous valid one (cyclically), so
    edge i runs from vertex i to vertex i+1 (mod V) and edges touching padding
    collapse to zero length. Works for any validity pattern, not only prefixes.

    Returns (start (V,2), end (V,2), edge_valid (V,)) with edge_valid False for
    the zero-length edges.
    """
    n = poly.shape[0]
    idx = jnp.arange(n)
    last_valid = jnp.max(jnp.where(valid, idx, -1))
    fill = jax.lax.cummax(jnp.where(valid, idx, -1))
    fill = jnp.where(fill < 0, last_valid, fill)
    fill = jnp.maximum(fill, 0)  # all-invalid polygon: every edge degenerate
    pts = poly[fill]
    start, end = pts, jnp.roll(pts, -1, axis=0)
    edge_valid = (fill != jnp.roll(fill, -1)) & jnp.any(valid)
    return start, end, edge_valid


def point_in_polygon(p: Array, poly: Array, poly_valid: Array) -> Array:
    """() bool: ``p (2,)`` inside the padded polygon ``poly (V, 2)`` (even-odd
    crossing rule; simple non-convex polygons fine; implicitly closed;
    ``poly_valid (V,)`` masks padding). False with fewer than 3 valid vertices.
    """
    a, b, ok = closed_edges(poly, poly_valid)
    straddles = (a[:, 1] > p[1]) != (b[:, 1] > p[1])
    dy = jnp.where(straddles, b[:, 1] - a[:, 1], 1.0)
    x_cross = a[:, 0] + (p[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / dy
    crossings = straddles & ok & (p[0] < x_cross)
    return (jnp.sum(crossings) % 2) == 1


def convex_polygon_box_penetration(
    poly: Array, poly_valid: Array, xy: Array, yaw: Array, lw: Array
) -> Array:
    """Signed SAT overlap depth (m) of a padded convex polygon and a box.

    Args:
      poly: (V, 2) vertices (either winding), m.  poly_valid: (V,) bool.
      xy: (2,) box centre, m.  yaw: () rad.  lw: (2,) length, width, m.

    Returns () float: > 0 overlap depth, <= 0 apart (``-value`` bounds the gap
    from below). ``-inf`` when the polygon has no valid vertex. Degenerate
    polygons (a segment, a point) are handled as their convex hull.
    """
    a, b, ok = closed_edges(poly, poly_valid)
    normals, nonzero = _unit(jnp.stack([-(b - a)[:, 1], (b - a)[:, 0]], axis=-1))
    axes = jnp.concatenate([normals, _box_axes(yaw)])  # (V + 2, 2)
    axis_ok = jnp.concatenate([ok & nonzero, jnp.array([True, True])])
    proj = poly @ axes.T  # (V, V + 2)
    hi = jnp.max(jnp.where(poly_valid[:, None], proj, -jnp.inf), axis=0)
    lo = jnp.min(jnp.where(poly_valid[:, None], proj, jnp.inf), axis=0)
    c = axes @ xy
    r = _box_radius(axes, yaw, lw)
    overlap = jnp.minimum(hi - (c - r), (c + r) - lo)
    depth = jnp.min(jnp.where(axis_ok, overlap, jnp.inf))
    return jnp.where(jnp.any(poly_valid), depth, -jnp.inf)


def convex_polygon_box_overlap(
    poly: Array, poly_valid: Array, xy: Array, yaw: Array, lw: Array, eps: float = EPS
) -> Array:
    """() bool: a padded convex polygon (static obstacle footprint) and a box
    share interior (SAT depth > ``eps`` m). Arguments as
    ``convex_polygon_box_penetration``."""
    return convex_polygon_box_penetration(poly, poly_valid, xy, yaw, lw) > eps


@struct.dataclass
class PolygonSAT:
    """A static convex polygon's separating-axis data, computed once.

    The polygon's projections onto its own edge normals never change, so a
    simulator precomputes them at reset and each step only projects the box
    (cost O(V) instead of O(V^2) per polygon).

    Attributes:
      normals: (V, 2) unit edge normals.  normal_ok: (V,) bool usable axes.
      lo, hi:  (V,) polygon extent along each normal, m.
      poly:    (V, 2) vertices.  valid: (V,) bool.  any: () bool.
    """

    normals: Array
    normal_ok: Array
    lo: Array
    hi: Array
    poly: Array
    valid: Array
    any: Array


def polygon_sat(poly: Array, poly_valid: Array) -> PolygonSAT:
    """Precompute ``PolygonSAT`` for a padded convex polygon (V, 2)."""
    a, b, ok = closed_edges(poly, poly_valid)
    normals, nonzero = _unit(jnp.stack([-(b - a)[:, 1], (b - a)[:, 0]], axis=-1))
    proj = poly @ normals.T  # (V, V)
    hi = jnp.max(jnp.where(poly_valid[:, None], proj, -jnp.inf), axis=0)
    lo = jnp.min(jnp.where(poly_valid[:, None], proj, jnp.inf), axis=0)
    return PolygonSAT(normals=normals, normal_ok=ok & nonzero, lo=lo, hi=hi, poly=poly, valid=poly_valid,
                      any=jnp.any(poly_valid))


def polygon_sat_box_penetration(sat: PolygonSAT, xy: Array, yaw: Array, lw: Array) -> Array:
    """Same value as ``convex_polygon_box_penetration`` from precomputed data."""
    # Explicit multiply-adds: tiny batched matmuls are slow on XLA:CPU.
    n = sat.normals
    c = n[:, 0] * xy[0] + n[:, 1] * xy[1]
    r = _box_radius(n, yaw, lw)
    over_poly = jnp.minimum(sat.hi - (c - r), (c + r) - sat.lo)
    cos, sin = jnp.cos(yaw), jnp.sin(yaw)
    px, py = sat.poly[:, 0], sat.poly[:, 1]
    over_box = []
    # The vertices on each box axis as one plane per axis (a (V, 2) stack
    # reduced over V is an element-by-element loop on XLA:CPU).
    for proj, cb, rb in ((px * cos + py * sin, xy[0] * cos + xy[1] * sin, 0.5 * lw[0]),
                         (-px * sin + py * cos, -xy[0] * sin + xy[1] * cos, 0.5 * lw[1])):
        hi = jnp.max(jnp.where(sat.valid, proj, -jnp.inf))
        lo = jnp.min(jnp.where(sat.valid, proj, jnp.inf))
        over_box.append(jnp.minimum(hi - (cb - rb), (cb + rb) - lo))  # rb: a box's radius on its own axis
    depth = jnp.minimum(jnp.min(jnp.where(sat.normal_ok, over_poly, jnp.inf)),
                        jnp.minimum(over_box[0], over_box[1]))
    return jnp.where(sat.any, depth, -jnp.inf)


# --------------------------------------------------------------------------
# Segments
# --------------------------------------------------------------------------


def point_segment_distance(p: Array, a: Array, b: Array) -> Array:
    """() distance (m) from ``p (2,)`` to the closed segment ``a``-``b``."""
    d = b - a
    t = jnp.clip(dot(p - a, d) / jnp.maximum(dot(d, d), _TINY), 0.0, 1.0)
    return safe_norm(p - (a + t * d))


def segment_distance(p1: Array, p2: Array, q1: Array, q2: Array) -> Array:
    """() distance (m) between closed segments p1-p2 and q1-q2 (0 if they cross)."""
    cross = (cross2(q2 - q1, p1 - q1) * cross2(q2 - q1, p2 - q1) < 0) & (
        cross2(p2 - p1, q1 - p1) * cross2(p2 - p1, q2 - p1) < 0
    )
    d = jnp.min(
        jnp.stack(
            [
                point_segment_distance(p1, q1, q2),
                point_segment_distance(p2, q1, q2),
                point_segment_distance(q1, p1, p2),
                point_segment_distance(q2, p1, p2),
            ]
        )
    )
    return jnp.where(cross, 0.0, d)


def segments_intersect(p1: Array, p2: Array, q1: Array, q2: Array, eps: float = EPS) -> Array:
    """() bool: the closed segments p1-p2 and q1-q2 (each (2,)) share a point,
    within ``eps`` m: proper crossings, touching end points, T-junctions and
    collinear overlaps all count (segment distance <= eps)."""
    return segment_distance(p1, p2, q1, q2) <= eps


# --------------------------------------------------------------------------
# Polylines
# --------------------------------------------------------------------------


@struct.dataclass
class Projection:
    """The foot point of a point on a padded polyline.

    Attributes:
      distance: () m, unsigned distance to the polyline (+inf if no valid point).
      lateral:  () m, signed offset perpendicular to the foot segment's
        direction, + = left of the driving direction. Equal to +-distance when
        the foot lies inside a segment; beyond the end points it is the offset
        from the extended end segment (Frenet-like); 0 for a one-point polyline.
      arc:      () m, arc length of the foot point from the first valid point
        (invalid gaps contribute nothing).
      segment:  () int32, index i of the foot segment (points i, i+1), or of
        the lone point; -1 if no valid point.
      heading:  () rad, direction of the foot segment (0 for a lone point).
      valid:    () bool, the polyline has a valid point.
    """

    distance: Array
    lateral: Array
    arc: Array
    segment: Array
    heading: Array
    valid: Array


def project_to_polyline(p: Array, xy: Array, valid: Array) -> Projection:
    """Project ``p (2,)`` on the padded polyline ``xy (N, 2)``, ``valid (N,)``.

    Segment i (points i, i+1) counts iff both ends are valid. A valid point
    with no valid segment after it (a lone point, or the polyline end) is a
    candidate on its own, so a single-point polyline projects onto that point.
    Ties go to the lower index.
    """
    a = xy
    seg_ok = valid[:-1] & valid[1:]
    b = jnp.concatenate([jnp.where(seg_ok[:, None], xy[1:], xy[:-1]), xy[-1:]])  # (N, 2)
    d = b - a
    seg_len = safe_norm(d)
    t = jnp.clip(dot(p - a, d) / jnp.maximum(dot(d, d), _TINY), 0.0, 1.0)
    foot = a + t[:, None] * d
    dist = safe_norm(p - foot)
    i = jnp.argmin(jnp.where(valid, dist, jnp.inf))

    cum = jnp.concatenate([jnp.zeros(1), jnp.cumsum(seg_len[:-1])])
    tangent, _ = _unit(d[i])
    any_valid = jnp.any(valid)
    return Projection(
        distance=jnp.where(any_valid, dist[i], jnp.inf),
        lateral=cross2(tangent, p - a[i]) * (seg_len[i] > 0),
        arc=cum[i] + t[i] * seg_len[i],
        segment=jnp.where(any_valid, i, -1).astype(jnp.int32),
        heading=jnp.arctan2(tangent[1], tangent[0]),
        valid=any_valid,
    )


def nearest_vertex(p: Array, xy: Array, valid: Array) -> tuple[Array, Array]:
    """(index, squared distance) of the valid vertex of ``xy (N, 2)`` nearest
    ``p (2,)`` (the lowest index on a tie; index 0 and inf when none is valid).

    The squared distance is the plane-form ``dot`` (see there): ~4x faster than
    a sum over the trailing axis of 2 on the (B, lanes, points) arrays of the
    per-step lane tests (docs/performance.md)."""
    d = xy - p
    d2 = jnp.where(valid, dot(d, d), jnp.inf)
    j = jnp.argmin(d2)
    return j, d2[j]


def nearest_segment(p: Array, xy: Array, valid: Array, *, with_vertex: bool = False):
    """Fast (distance, heading) of ``p`` to a DENSELY sampled padded polyline.

    Finds the nearest valid vertex (``nearest_vertex``), then projects onto its
    two adjacent segments only: O(N) cheap squared distances instead of N full
    segment projections. Equal to ``project_to_polyline``'s distance whenever
    the true foot lies on a segment adjacent to the nearest vertex, which holds
    for polylines sampled much finer than their radius of curvature and the
    point's distance (lanes at <= 2 m spacing, queried within a few metres).
    Returns (inf, 0) for a polyline without a valid point; with
    ``with_vertex`` also the nearest vertex's index (a third output).
    """
    n = xy.shape[0]
    j, d2j = nearest_vertex(p, xy, valid)
    lo = jnp.clip(j - 1, 0, n - 2)
    best_d, best_dab = jnp.inf, jnp.zeros(2, xy.dtype)
    for k in (lo, lo + 1):  # segments (k, k + 1) around the vertex
        k = jnp.minimum(k, n - 2)
        a, b = xy[k], xy[k + 1]
        ok = valid[k] & valid[k + 1]
        dab = b - a
        t = jnp.clip(dot(p - a, dab) / jnp.maximum(dot(dab, dab), _TINY), 0.0, 1.0)
        dist = jnp.where(ok, safe_norm(p - (a + t * dab)), jnp.inf)
        better = dist < best_d
        best_dab = jnp.where(better, dab, best_dab)
        best_d = jnp.where(better, dist, best_d)
    best_h = jnp.arctan2(best_dab[1], best_dab[0])  # one arctan2, of the winning segment
    # A lone valid point (no valid segment): its own distance.
    lone = ~jnp.isfinite(best_d) & valid[j]
    best_d = jnp.where(lone, jnp.sqrt(d2j), best_d)
    if with_vertex:
        return best_d, best_h, j
    return best_d, best_h


def distance_to_polylines(
    p: Array, xy: Array, point_valid: Array, valid: Array
) -> tuple[Array, Array]:
    """Nearest of a padded set of polylines.

    Args:
      p: (2,) point, m.  xy: (P, N, 2).  point_valid: (P, N).  valid: (P,).

    Returns:
      (distance () m, +inf if none; index () int32 of the nearest polyline, -1
      if none).
    """
    proj = jax.vmap(project_to_polyline, in_axes=(None, 0, 0))(p, xy, point_valid)
    ok = valid & proj.valid
    dist = jnp.where(ok, proj.distance, jnp.inf)
    i = jnp.argmin(dist)
    return dist[i], jnp.where(jnp.any(ok), i, -1).astype(jnp.int32)


# --------------------------------------------------------------------------
# Rays (2-D ray casting; the sensors in ``observe/raycast.py`` build on these)
# --------------------------------------------------------------------------


def ray_segment_distance(origin: Array, direction: Array, a: Array, b: Array) -> Array:
    """() distance t > 0 (m) at which the ray ``origin + t * direction`` first
    meets the closed segment ``a``-``b``; +inf if it misses.

    Args:
      origin: (2,) m.  direction: (2,) UNIT vector.  a, b: (2,) end points, m.

    A ray parallel to the segment (including collinear) counts as a miss (a
    measure-zero case). Differentiable in all arguments away from the end
    points; the gradient is zero on a miss.
    """
    e, w = b - a, a - origin
    return segment_entry(e, w, cross2(w, e), direction)


def segment_entry(e: Array, w: Array, w_x_e: Array, direction: Array) -> Array:
    """``ray_segment_distance`` from the per-segment terms ``e = b - a``,
    ``w = a - origin`` (each (..., 2)) and ``w_x_e = cross(w, e)``, so a caller
    casting many rays at one segment computes them once (observe/raycast.py)."""
    den = cross2(direction, e)
    ok = jnp.abs(den) > _TINY
    den = jnp.where(ok, den, 1.0)
    t = w_x_e / den
    s = cross2(w, direction) / den
    hit = ok & (t > 0.0) & (s >= 0.0) & (s <= 1.0)
    return jnp.where(hit, t, jnp.inf)


def ray_box_distance(origin: Array, direction: Array, xy: Array, yaw: Array, lw: Array) -> Array:
    """() entry distance t > 0 (m) of the ray ``origin + t * direction`` into an
    oriented box (slab method); +inf if the ray misses it or starts inside it.

    Args:
      origin: (2,) m.  direction: (2,) UNIT vector.  xy: (2,) box centre, m.
      yaw: () box heading, rad.  lw: (2,) length, width, m.

    Differentiable in the box pose and the ray away from the box's corners
    (the entry face switches there); the gradient is zero on a miss.
    """
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    p = origin - xy
    ox, oy = c * p[0] + s * p[1], -s * p[0] + c * p[1]
    dx, dy = c * direction[0] + s * direction[1], -s * direction[0] + c * direction[1]
    return slab_entry(ox, oy, dx, dy, 0.5 * lw[0], 0.5 * lw[1])


def slab_entry(ox: Array, oy: Array, dx: Array, dy: Array, hl: Array, hw: Array) -> Array:
    """Entry distance t > 0 (m; +inf on a miss or from inside) of the ray
    ``(ox, oy) + t (dx, dy)`` into the axis-aligned box ``|x| <= hl, |y| <= hw``,
    all in the box frame (any broadcastable shapes). ``ray_box_distance`` and
    the LiDAR's per-box hoisted version (observe/raycast.py) both end here."""
    # A ray parallel to a slab: a tiny signed denominator turns the slab into
    # (-huge, +huge) when the origin lies between its planes, a miss otherwise.
    dx = jnp.where(jnp.abs(dx) < 1e-12, jnp.where(dx < 0, -1e-12, 1e-12), dx)
    dy = jnp.where(jnp.abs(dy) < 1e-12, jnp.where(dy < 0, -1e-12, 1e-12), dy)
    tx1, tx2 = (-hl - ox) / dx, (hl - ox) / dx
    ty1, ty2 = (-hw - oy) / dy, (hw - oy) / dy
    t_near = jnp.maximum(jnp.minimum(tx1, tx2), jnp.minimum(ty1, ty2))
    t_far = jnp.minimum(jnp.maximum(tx1, tx2), jnp.maximum(ty1, ty2))
    hit = (t_near <= t_far) & (t_near > 0.0)
    return jnp.where(hit, t_near, jnp.inf)
