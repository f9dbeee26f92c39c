"""geometry.py against shapely 2 as the independent oracle, plus jit/vmap/grad.

Inputs are drawn as float32-representable numbers so that the float32 JAX code
and float64 shapely see the same geometry; a thin tolerance band around the
touching configurations (where the two legitimately disagree) is excluded.
"""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from hypothesis import assume, event, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point, Polygon

from drivee2e_jax import geometry as geo


def f32(lo, hi):
    """float32-representable floats in [lo, hi] (bounds rounded to float32)."""
    return st.floats(float(np.float32(lo)), float(np.float32(hi)), width=32)


V_MAX = 10  # padded vertex count of the property tests (one compile each)
BAND = 1e-3  # m: ambiguity band excluded from oracle comparisons
SETTINGS = settings(max_examples=150, deadline=None)

coord = f32(-20.0, 20.0)
angle = f32(-3.14159, 3.14159)
side = f32(0.3, 6.0)

# Compiled once per module: hypothesis calls them hundreds of times.
_overlap = jax.jit(geo.boxes_overlap)
_penetration = jax.jit(geo.box_penetration)
_poly_overlap = jax.jit(geo.convex_polygon_box_overlap)
_pip = jax.jit(geo.point_in_polygon)
_seg = jax.jit(geo.segments_intersect)
_project = jax.jit(geo.project_to_polyline)
_seg_dist = jax.jit(geo.segment_distance)


def _shapely_box(xy, yaw, lw):
    return Polygon(np.asarray(geo.box_corners(jnp.array(xy), yaw, lw[0], lw[1]), np.float64))


def _pad(points, v_max, fill=0.0):
    points = np.asarray(points, np.float32)
    n = len(points)
    out = np.full((v_max, 2), fill, np.float32)
    out[:n] = points
    valid = np.zeros(v_max, bool)
    valid[:n] = True
    return jnp.array(out), jnp.array(valid)


@st.composite
def star_polygon(draw, n_min=3, n_max=9):
    """A simple (star-shaped around its centre) polygon, CCW."""
    n = draw(st.integers(n_min, n_max))
    cx, cy = draw(coord), draw(coord)
    angles = sorted(draw(st.lists(f32(0.0, 6.28318), min_size=n, max_size=n, unique=True)))
    assume(min(np.diff(angles + [angles[0] + 2 * math.pi])) > 0.05)
    radii = draw(st.lists(f32(1.0, 8.0), min_size=n, max_size=n))
    pts = [(cx + r * math.cos(a), cy + r * math.sin(a)) for a, r in zip(angles, radii)]
    return np.asarray(pts, np.float32)


# --------------------------------------------------------------------------
# Angles and frames
# --------------------------------------------------------------------------


def test_wrap_angle_range_and_values():
    a = jnp.array([0.0, math.pi, -math.pi, 3 * math.pi, -3 * math.pi, 7.0, -7.0, 1e-3])
    w = geo.wrap_angle(a)
    assert bool(jnp.all((w > -math.pi) & (w <= math.pi + 1e-6)))
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-5)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-5)
    assert float(geo.wrap_angle(jnp.float32(math.pi))) == pytest.approx(math.pi)
    assert float(geo.wrap_angle(jnp.float32(0.25))) == 0.25  # small angles untouched


@SETTINGS
@given(coord, coord, angle, coord, coord)
def test_frame_round_trip(ox, oy, yaw, px, py):
    origin = jnp.array([ox, oy])
    p = jnp.array([[px, py], [0.0, 0.0]])
    local = geo.to_frame(p, origin, yaw)
    np.testing.assert_allclose(geo.from_frame(local, origin, yaw), p, atol=1e-4)
    np.testing.assert_allclose(jnp.linalg.norm(local[0]), jnp.linalg.norm(p[0] - origin), atol=1e-4)


def test_to_frame_axes():
    origin = jnp.array([1.0, 2.0])
    yaw = jnp.float32(math.pi / 2)  # facing north
    # A point north of the origin is straight ahead; east is to the right.
    np.testing.assert_allclose(geo.to_frame(jnp.array([1.0, 5.0]), origin, yaw), [3.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(geo.to_frame(jnp.array([4.0, 2.0]), origin, yaw), [0.0, -3.0], atol=1e-6)


def test_box_corners_ccw():
    c = np.asarray(geo.box_corners(jnp.array([0.0, 0.0]), 0.0, 4.0, 2.0))
    np.testing.assert_allclose(c, [[2, -1], [2, 1], [-2, 1], [-2, -1]])
    assert Polygon(c).exterior.is_ccw


# --------------------------------------------------------------------------
# Boxes
# --------------------------------------------------------------------------


@SETTINGS
@given(coord, coord, angle, side, side, coord, coord, angle, side, side)
def test_boxes_overlap_vs_shapely(ax, ay, ayaw, al, aw, bx, by, byaw, bl, bw):
    # Pull b near a so that both outcomes are frequent.
    bx, by = ax + bx / 3.0, ay + by / 3.0
    a, b = (jnp.array([ax, ay]), ayaw, jnp.array([al, aw])), (jnp.array([bx, by]), byaw, jnp.array([bl, bw]))
    pa, pb = _shapely_box(*a), _shapely_box(*b)
    sure_in = pa.buffer(-BAND, join_style="mitre").intersects(pb)
    sure_out = pa.distance(pb) > BAND
    assume(sure_in or sure_out)
    event("overlap" if sure_in else "apart")
    assert bool(_overlap(*a, *b)) == sure_in
    depth = float(_penetration(*a, *b))
    assert (depth > 0) == sure_in
    if sure_out:  # -depth is a lower bound of the gap
        assert -depth <= pa.distance(pb) + 1e-4


def test_boxes_touching_is_not_overlap():
    lw = jnp.array([4.0, 2.0])
    a = (jnp.array([0.0, 0.0]), 0.0, lw)
    assert not bool(_overlap(*a, jnp.array([4.0, 0.0]), 0.0, lw))  # bumper to bumper
    assert not bool(_overlap(*a, jnp.array([4.0, 2.0]), 0.0, lw))  # corner to corner
    assert bool(_overlap(*a, jnp.array([3.9, 0.0]), 0.0, lw))
    np.testing.assert_allclose(_penetration(*a, jnp.array([3.9, 0.0]), 0.0, lw), 0.1, atol=1e-6)
    np.testing.assert_allclose(_penetration(*a, jnp.array([5.0, 0.0]), 0.0, lw), -1.0, atol=1e-6)


def test_box_penetration_grad_finite():
    def f(xa, ya, b):
        return geo.box_penetration(xa, ya, jnp.array([4.5, 1.9]), b[:2], b[2], jnp.array([4.0, 1.8]))

    cases = [
        (jnp.array([0.0, 0.0]), 0.0, jnp.array([3.0, 0.5, 0.0])),  # aligned: degenerate axes
        (jnp.array([0.0, 0.0]), 0.3, jnp.array([3.0, 0.5, 1.2])),
        (jnp.array([0.0, 0.0]), 0.0, jnp.array([0.0, 0.0, 0.0])),  # coincident
        (jnp.array([1.0, 2.0]), -2.0, jnp.array([9.0, 0.5, 0.7])),  # apart
    ]
    g = jax.jit(jax.grad(f, argnums=(0, 1, 2)))
    for case in cases:
        for leaf in jax.tree_util.tree_leaves(g(*case)):
            assert bool(jnp.all(jnp.isfinite(leaf)))
    # Separating the boxes along x: d depth / d x_b = -1.
    gb = g(*cases[0])[2]
    np.testing.assert_allclose(gb[:2], [-1.0, 0.0], atol=1e-6)


def test_boxes_jit_vmap():
    xy = jnp.array([[0.0, 0.0], [3.0, 0.0], [10.0, 0.0]])
    yaw = jnp.zeros(3)
    lw = jnp.tile(jnp.array([4.0, 2.0]), (3, 1))
    pair = jax.vmap(jax.vmap(geo.boxes_overlap, (None, None, None, 0, 0, 0)), (0, 0, 0, None, None, None))
    m = jax.jit(pair)(xy, yaw, lw, xy, yaw, lw)
    chex.assert_shape(m, (3, 3))
    np.testing.assert_array_equal(m, [[1, 1, 0], [1, 1, 0], [0, 0, 1]])


# --------------------------------------------------------------------------
# Polygons
# --------------------------------------------------------------------------


@SETTINGS
@given(star_polygon(), coord, coord)
def test_point_in_polygon_vs_shapely(poly, px, py):
    pts, valid = _pad(poly, V_MAX, fill=123.0)  # one shape: one compile
    shp = Polygon(poly.astype(np.float64))
    assume(shp.is_valid)
    p = Point(px / 2.0 + poly[:, 0].mean(), py / 2.0 + poly[:, 1].mean())
    assume(shp.exterior.distance(p) > BAND)
    event("inside" if shp.contains(p) else "outside")
    assert bool(_pip(jnp.array([p.x, p.y], jnp.float32), pts, valid)) == shp.contains(p)


def test_point_in_polygon_padding_anywhere_and_nonconvex():
    # A U shape (non-convex) with padding between vertices: padding is skipped.
    u = np.array([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]], np.float32)
    pts = np.zeros((12, 2), np.float32)
    valid = np.zeros(12, bool)
    slots = [0, 2, 3, 5, 6, 8, 9, 11]
    pts[slots], valid[slots] = u, True
    pts[~valid] = 50.0  # garbage
    inside = [(0.5, 2.5), (2.5, 2.5), (1.5, 0.5)]
    outside = [(1.5, 2.0), (4.0, 1.0), (-0.5, 0.5), (50.0, 50.0)]
    f = jax.jit(geo.point_in_polygon)
    for p in inside:
        assert bool(f(jnp.array(p), pts, valid)), p
    for p in outside:
        assert not bool(f(jnp.array(p), pts, valid)), p
    assert not bool(f(jnp.array([0.5, 0.5]), pts, np.zeros(12, bool)))


@SETTINGS
@given(star_polygon(n_max=7), coord, coord, angle, side, side, st.booleans())
def test_convex_polygon_box_overlap_vs_shapely(poly, bx, by, yaw, bl, bw, clockwise):
    hull = shapely.convex_hull(shapely.MultiPoint(poly.astype(np.float64)))
    ring = np.asarray(hull.exterior.coords, np.float32)[:-1]
    if clockwise:
        ring = ring[::-1]  # either winding
    pts, valid = _pad(ring, V_MAX, fill=-77.0)
    xy = jnp.array([poly[:, 0].mean() + bx / 2.0, poly[:, 1].mean() + by / 2.0], jnp.float32)
    lw = jnp.array([bl, bw])
    shp_hull = Polygon(ring.astype(np.float64))
    box = _shapely_box(xy, yaw, lw)
    sure_in = shp_hull.buffer(-BAND, join_style="mitre").intersects(box)
    sure_out = shp_hull.distance(box) > BAND
    assume(sure_in or sure_out)
    event("overlap" if sure_in else "apart")
    assert bool(_poly_overlap(pts, valid, xy, yaw, lw)) == sure_in


def test_convex_polygon_degenerate_cases():
    lw = jnp.array([4.0, 2.0])
    origin = jnp.zeros(2)
    seg, seg_valid = _pad([[0.0, -5.0], [0.0, 5.0]], 5)  # a wall through the box
    assert bool(_poly_overlap(seg, seg_valid, origin, 0.0, lw))
    assert not bool(_poly_overlap(seg, seg_valid, jnp.array([3.0, 0.0]), 0.0, lw))
    point, point_valid = _pad([[0.5, 0.5]], 4)
    assert bool(_poly_overlap(point, point_valid, origin, 0.3, lw))
    empty = jnp.zeros(4, bool)
    assert not bool(_poly_overlap(point, empty, origin, 0.0, lw))


# --------------------------------------------------------------------------
# Segments
# --------------------------------------------------------------------------


@SETTINGS
@given(coord, coord, coord, coord, coord, coord, coord, coord)
def test_segments_intersect_vs_shapely(a, b, c, d, e, f, g, h):
    p1, p2 = np.array([a, b], np.float32), np.array([c, d], np.float32)
    q1, q2 = np.array([e, f], np.float32) / 2, np.array([g, h], np.float32) / 2
    lp, lq = LineString([p1, p2]), LineString([q1, q2])
    hit, dist = lp.intersects(lq), lp.distance(lq)
    assume(hit or dist > BAND)  # near misses are the tolerance band
    assume(lp.length > BAND and lq.length > BAND)
    args = [jnp.array(v) for v in (p1, p2, q1, q2)]
    event("intersect" if hit else "apart")
    assert bool(_seg(*args)) == hit
    np.testing.assert_allclose(float(_seg_dist(*args)), 0.0 if hit else dist, atol=1e-4)


def test_segments_touching_convention():
    s = lambda *pts: bool(_seg(*(jnp.array(p, jnp.float32) for p in pts)))
    assert s([0, 0], [2, 0], [2, 0], [3, 1])  # shared end point
    assert s([0, 0], [2, 0], [1, 0], [1, 5])  # T-junction
    assert s([0, 0], [2, 0], [1, 0], [3, 0])  # collinear overlap
    assert s([0, 0], [2, 2], [0, 2], [2, 0])  # proper crossing
    assert not s([0, 0], [2, 0], [3, 0], [4, 0])  # collinear, apart
    assert not s([0, 0], [2, 0], [1, 0.01], [1, 5])


# --------------------------------------------------------------------------
# Polylines
# --------------------------------------------------------------------------

polyline = st.lists(st.tuples(coord, coord), min_size=2, max_size=7)


@SETTINGS
@given(polyline, coord, coord)
def test_projection_vs_shapely(points, px, py):
    pts_np = np.asarray(points, np.float32)
    line = LineString(pts_np.astype(np.float64))
    assume(line.length > 0.1)
    pts, valid = _pad(pts_np, V_MAX, fill=999.0)
    p = np.array([px, py], np.float32)
    proj = _project(jnp.array(p), pts, valid)
    dist = line.distance(Point(p))
    np.testing.assert_allclose(float(proj.distance), dist, atol=2e-4)
    assert bool(proj.valid)
    # The foot point is at arc length `arc` along the line.
    foot = line.interpolate(float(proj.arc))
    np.testing.assert_allclose(foot.distance(Point(p)), dist, atol=2e-3)
    assert 0 <= int(proj.segment) < len(pts_np)
    # |lateral| = distance whenever the foot is inside its segment.
    a, b = pts_np[int(proj.segment)], pts_np[min(int(proj.segment) + 1, len(pts_np) - 1)]
    if LineString([a, b]).length > 1e-3:
        t = np.dot(p - a, b - a) / np.dot(b - a, b - a)
        if 1e-3 < t < 1 - 1e-3:
            np.testing.assert_allclose(abs(float(proj.lateral)), dist, atol=2e-4)


def test_projection_signs_arc_heading():
    pts, valid = _pad([[0, 0], [10, 0], [10, 10]], 6)
    proj = _project(jnp.array([4.0, 1.5]), pts, valid)
    np.testing.assert_allclose([proj.distance, proj.lateral, proj.arc, proj.heading], [1.5, 1.5, 4.0, 0.0], atol=1e-6)
    assert int(proj.segment) == 0
    proj = _project(jnp.array([12.0, 4.0]), pts, valid)  # right of the north leg
    np.testing.assert_allclose([proj.distance, proj.lateral, proj.arc, proj.heading], [2.0, -2.0, 14.0, math.pi / 2], atol=1e-6)
    # Beyond the end: Frenet-like lateral off the extended last segment.
    proj = _project(jnp.array([9.0, 12.0]), pts, valid)
    np.testing.assert_allclose([proj.arc, proj.lateral], [20.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(proj.distance, math.sqrt(5.0), atol=1e-6)


def test_projection_single_point_and_empty():
    pts, valid = _pad([[3.0, 4.0]], 5, fill=-1.0)
    proj = _project(jnp.zeros(2), pts, valid)
    np.testing.assert_allclose([proj.distance, proj.arc, proj.lateral], [5.0, 0.0, 0.0], atol=1e-6)
    assert int(proj.segment) == 0 and bool(proj.valid)
    proj = _project(jnp.zeros(2), pts, jnp.zeros(5, bool))
    assert not bool(proj.valid) and np.isinf(float(proj.distance)) and int(proj.segment) == -1


def test_projection_skips_invalid_gaps():
    # Points 0,1 valid, 2 invalid, 3,4 valid: no segment bridges the gap.
    pts = jnp.array([[0.0, 0.0], [1.0, 0.0], [2.0, 5.0], [3.0, 0.0], [4.0, 0.0]])
    valid = jnp.array([True, True, False, True, True])
    proj = _project(jnp.array([2.0, 0.0]), pts, valid)
    np.testing.assert_allclose(proj.distance, 1.0, atol=1e-6)


def test_projection_grad_finite():
    pts, valid = _pad([[0, 0], [10, 0], [10, 10]], 6)

    def f(p, xy):
        proj = geo.project_to_polyline(p, xy, valid)
        return proj.distance + proj.lateral + proj.arc + proj.heading

    g = jax.jit(jax.grad(f, argnums=(0, 1)))
    for p in ([4.0, 1.5], [4.0, 0.0], [10.0, 0.0], [12.0, 12.0], [0.0, 0.0], [-3.0, 0.0]):
        for leaf in g(jnp.array(p), pts):
            assert bool(jnp.all(jnp.isfinite(leaf))), p
    one, one_valid = _pad([[3.0, 4.0]], 3)
    gp = jax.grad(lambda p: _project(p, one, one_valid).distance)(jnp.array([3.0, 4.0]))
    assert bool(jnp.all(jnp.isfinite(gp)))


def test_distance_to_polylines():
    xy = jnp.array([[[0, 0], [10, 0], [0, 0]], [[0, 5], [10, 5], [20, 5]], [[0, 1], [10, 1], [0, 0]]], jnp.float32)
    point_valid = jnp.array([[1, 1, 0], [1, 1, 1], [1, 1, 0]], bool)
    valid = jnp.array([True, True, False])  # the closest one is padding
    f = jax.jit(geo.distance_to_polylines)
    d, i = f(jnp.array([5.0, 1.5]), xy, point_valid, valid)
    np.testing.assert_allclose(d, 1.5, atol=1e-6)
    assert int(i) == 0
    d, i = f(jnp.array([5.0, 4.0]), xy, point_valid, valid)
    assert int(i) == 1
    d, i = f(jnp.array([5.0, 4.0]), xy, point_valid, jnp.zeros(3, bool))
    assert np.isinf(float(d)) and int(i) == -1
    # Batched over points.
    ds, _ = jax.vmap(f, (0, None, None, None))(jnp.array([[5.0, 1.5], [5.0, 4.0]]), xy, point_valid, valid)
    chex.assert_shape(ds, (2,))


def test_precomputed_polygon_sat_matches_direct_sat():
    """The per-episode precomputation gives the same depth as the direct SAT."""
    from drivee2e_jax.geometry import convex_polygon_box_penetration, polygon_sat, polygon_sat_box_penetration

    rng = np.random.default_rng(0)
    for _ in range(50):
        ang = np.sort(rng.uniform(0, 2 * np.pi, 6))
        poly = np.stack([np.cos(ang), np.sin(ang)], 1) * rng.uniform(1, 4) + rng.uniform(-3, 3, 2)
        poly = np.concatenate([poly, np.zeros((4, 2))])  # padded
        valid = np.arange(10) < 6
        xy, yaw, lw = rng.uniform(-4, 4, 2), rng.uniform(-np.pi, np.pi), np.array([4.5, 1.9])
        want = convex_polygon_box_penetration(jnp.asarray(poly), jnp.asarray(valid), jnp.asarray(xy), yaw, jnp.asarray(lw))
        got = polygon_sat_box_penetration(polygon_sat(jnp.asarray(poly), jnp.asarray(valid)), jnp.asarray(xy), yaw, jnp.asarray(lw))
        np.testing.assert_allclose(float(got), float(want), rtol=1e-5, atol=1e-5)


def test_nearest_segment_matches_full_projection_on_dense_polylines():
    """On a lane sampled at 2 m, the fast projection equals the exact one."""
    from drivee2e_jax.geometry import nearest_segment, project_to_polyline

    rng = np.random.default_rng(1)
    for radius in (8.0, 15.0, 40.0):  # U-turn-tight to gentle curve
        s = np.arange(0, min(60.0, np.pi * radius), 2.0)  # at most a U-turn
        ang = s / radius
        xy = np.stack([radius * np.sin(ang), radius * (1 - np.cos(ang))], 1)
        xy = np.concatenate([xy, np.zeros((6, 2))])
        valid = np.arange(len(xy)) < len(s)
        for _ in range(40):
            k = rng.integers(0, len(s))
            p = xy[k] + rng.uniform(-3, 3, 2)
            want = project_to_polyline(jnp.asarray(p), jnp.asarray(xy), jnp.asarray(valid))
            d, h = nearest_segment(jnp.asarray(p), jnp.asarray(xy), jnp.asarray(valid))
            np.testing.assert_allclose(float(d), float(want.distance), atol=1e-4)
            assert abs(math.remainder(float(h) - float(want.heading), 2 * math.pi)) < 1e-4 or float(d) < 1e-3


def test_nearest_vertex_and_plane_forms_match_numpy():
    """``nearest_vertex`` (lowest index on ties, invalid vertices skipped), ``row_norms``,
    the 2-vector ``dot`` and ``dot(v, v)`` (all written from x / y planes for XLA:CPU) against
    float64 numpy on random rows; ``nearest_segment(with_vertex=True)`` hands back that vertex."""
    rng = np.random.default_rng(7)
    xy = rng.uniform(-20, 20, (64, 2)).astype(np.float32)
    xy[10] = xy[3]  # a tie: the lower index wins
    valid = rng.random(64) > 0.2
    valid[3] = valid[10] = True
    for p in (xy[3], rng.uniform(-20, 20, 2).astype(np.float32)):
        j, d2 = geo.nearest_vertex(jnp.asarray(p), jnp.asarray(xy), jnp.asarray(valid))
        ref = np.where(valid, ((xy.astype(np.float64) - p) ** 2).sum(-1), np.inf)
        assert int(j) == int(np.argmin(ref))
        np.testing.assert_allclose(float(d2), ref.min(), rtol=1e-5, atol=1e-6)
        _, _, jv = geo.nearest_segment(jnp.asarray(p), jnp.asarray(xy), jnp.asarray(valid), with_vertex=True)
        assert int(jv) == int(j)
    j, d2 = geo.nearest_vertex(jnp.zeros(2), jnp.asarray(xy), jnp.zeros(64, bool))
    assert int(j) == 0 and np.isinf(float(d2))
    v, w = rng.normal(size=(5, 3, 2)), rng.normal(size=(5, 3, 2))
    np.testing.assert_allclose(np.asarray(geo.dot(jnp.asarray(v), jnp.asarray(v))), (v**2).sum(-1), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(geo.row_norms(jnp.asarray(v))), np.linalg.norm(v, axis=-1), rtol=1e-5)
    np.testing.assert_allclose(np.asarray(geo.dot(jnp.asarray(v), jnp.asarray(w))), (v * w).sum(-1), rtol=1e-5,
                               atol=1e-6)
    u, z = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))  # other lengths keep the plain sum
    np.testing.assert_allclose(np.asarray(geo.dot(jnp.asarray(u), jnp.asarray(z))), (u * z).sum(-1), rtol=1e-5,
                               atol=1e-6)


# --------------------------------------------------------------------------
# Segment vs oriented box (nuPlan's front-bumper test)
# --------------------------------------------------------------------------

_seg_box = jax.jit(jax.vmap(geo.segment_box_intersect))


def test_segment_box_intersect_vs_shapely_random():
    """Oracle: shapely ``LineString.intersects(Polygon)``, the test nuPlan's ``_get_collision_type``
    (no_ego_at_fault_collisions.py) applies to the ego's front edge. 400 seeded segment/box pairs
    around each other; pairs within ``BAND`` of touching are excluded (float32 vs float64)."""
    rng = np.random.default_rng(7)
    n = 400
    xy = rng.uniform(-2, 2, (n, 2)).astype(np.float32)
    yaw = rng.uniform(-np.pi, np.pi, n).astype(np.float32)
    lw = rng.uniform(0.5, 6.0, (n, 2)).astype(np.float32)
    p = rng.uniform(-6, 6, (n, 2)).astype(np.float32)
    q = (p + rng.uniform(-8, 8, (n, 2))).astype(np.float32)
    got = np.asarray(_seg_box(jnp.asarray(p), jnp.asarray(q), jnp.asarray(xy), jnp.asarray(yaw), jnp.asarray(lw)))
    compared = hits = 0
    for i in range(n):
        box = _shapely_box(xy[i], yaw[i], lw[i])
        line = LineString([p[i].astype(np.float64), q[i].astype(np.float64)])
        if line.distance(box) < BAND and line.intersection(box).length < BAND:
            continue  # touching: either answer is right
        want = line.intersects(box)
        assert bool(got[i]) == want, (p[i], q[i], xy[i], yaw[i], lw[i])
        compared += 1
        hits += want
    assert compared > 380 and 0.2 * compared < hits < 0.8 * compared  # both outcomes well represented


def test_segment_box_intersect_special_cases():
    one = jax.jit(geo.segment_box_intersect)
    box = (jnp.zeros(2), jnp.float32(0.0), jnp.array([4.0, 2.0]))  # x in [-2, 2], y in [-1, 1]

    def hit(p, q, xy=box[0], yaw=box[1], lw=box[2]):
        return bool(one(jnp.array(p, jnp.float32), jnp.array(q, jnp.float32), xy, yaw, lw))

    assert hit([-0.5, 0.0], [0.5, 0.0])  # wholly inside: no edge crossed
    assert hit([-3.0, 0.5], [3.0, 0.5])  # parallel to x, inside the y slab
    assert not hit([-3.0, 1.5], [3.0, 1.5])  # parallel to x, outside the y slab
    assert hit([1.5, -3.0], [1.5, 3.0])  # parallel to y, through
    assert not hit([2.5, -3.0], [2.5, 3.0])
    assert hit([0.3, 0.2], [0.3, 0.2])  # a point inside
    assert not hit([3.0, 0.0], [3.0, 0.0])  # a point outside
    assert not hit([3.0, 0.0], [5.0, 0.0])  # on the axis but short of the box
    assert not hit([1.5, 2.5], [3.5, 0.5])  # diagonal x + y = 4 passing the corner (2, 1) outside
    assert hit([0.5, 2.0], [2.5, 0.0])  # diagonal cutting the corner (x + y = 2.5 < 3)
    # Rotated 90 deg about (10, 0): the box spans x in [9, 11], y in [-2, 2].
    rot = dict(xy=jnp.array([10.0, 0.0]), yaw=jnp.float32(np.pi / 2))
    assert hit([8.0, 1.8], [12.0, 1.8], **rot)
    assert not hit([8.0, 2.2], [12.0, 2.2], **rot)
