"""Drivable-area excess against shapely: the map's polygons as they are.

``scenario.drivable.drivable_edges`` flattens the boundary of the union of a
map's drivable polygons (or of its lane areas); ``infractions.area_distance``
answers, inside ``jit``, how far a point lies outside that area. The oracle is
shapely's ``distance`` to the union of the same polygons.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point, Polygon

from drivee2e_jax import geometry as geo
from drivee2e_jax import infractions as inf
from drivee2e_jax.dynamics import ego_from_log
from drivee2e_jax.records import LaneRecord, MapRecord
from drivee2e_jax.scenario.drivable import DrivableSource, drivable_edges, drivable_union
from tests.helpers import lanes as lane_helpers

# A road: an L-shaped non-convex junction and a leg overlapping it.
JUNCTION = np.array([[0, 0], [30, 0], [30, 10], [10, 10], [10, 30], [0, 30]], float)
LEG = np.array([[25, 2], [60, 2], [60, 8], [25, 8]], float)


def _map(polys=(JUNCTION, LEG), lanes=()):
    return MapRecord(map_id="m", lanes=list(lanes), drivable_areas=[np.asarray(p) for p in polys])


_dist = jax.jit(inf.area_distance)


def _check(m, pts, tol=2e-3):
    edges, _ = drivable_edges(m)
    union, _ = drivable_union(m)
    got = np.asarray(_dist(jnp.asarray(pts, jnp.float32), jnp.asarray(edges, jnp.float32),
                           jnp.ones(len(edges), bool)))
    want = np.array([union.distance(Point(p)) for p in pts])
    np.testing.assert_allclose(got, want, atol=tol)
    return got, want


def test_union_of_overlapping_polygons_is_one_area():
    m = _map()
    edges, source = drivable_edges(m)
    assert source == DrivableSource.POLYGONS
    # The leg's end inside the junction is not a boundary: a point there is inside.
    got, _ = _check(m, np.array([[27.0, 5.0], [5.0, 25.0], [20.0, 20.0], [45.0, 12.0], [-3.0, -4.0]]))
    assert got[0] == 0 and got[1] == 0
    assert got[2] == pytest.approx(10.0, abs=1e-3)  # in the L's notch: 10 m to either arm
    assert got[3] == pytest.approx(4.0, abs=1e-3) and got[4] == pytest.approx(5.0, abs=1e-3)
    assert not np.any(np.isclose(edges[:, [0, 2]], 25.0))  # the leg's end inside the junction is gone


def test_a_hole_is_off_the_area():
    # A hole cannot be given as one simple polygon; the union of four makes one.
    m = _map(polys=(np.array([[80, 0], [120, 0], [120, 10], [80, 10]]), np.array([[80, 30], [120, 30], [120, 40], [80, 40]]),
                    np.array([[80, 0], [90, 0], [90, 40], [80, 40]]), np.array([[110, 0], [120, 0], [120, 40], [110, 40]])))
    union, _ = drivable_union(m)
    assert len(union.interiors) == 1
    got, _ = _check(m, np.array([[100.0, 20.0], [85.0, 20.0], [100.0, 12.0]]))
    assert got[0] == pytest.approx(10.0, abs=1e-3)
    assert got[1] == 0 and got[2] == pytest.approx(2.0, abs=1e-3)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-20, 140), st.floats(-20, 50)), min_size=1, max_size=30))
def test_matches_shapely_anywhere(pts):
    _check(_map(polys=(JUNCTION, LEG, np.array([[80, 0], [120, 0], [100, 40]]))), np.array(pts))


def test_lanes_are_the_area_when_the_map_has_no_polygons():
    arc = np.stack([20 * np.sin(np.linspace(0, np.pi / 2, 30)), 20 - 20 * np.cos(np.linspace(0, np.pi / 2, 30))], 1)
    lanes = [LaneRecord(id=1, centerline=arc, width=3.5),
             LaneRecord(id=2, centerline=np.array([[20.0, 20.0], [20.0, 60.0]]), width=3.5)]
    m = MapRecord(map_id="l", lanes=lanes)
    edges, source = drivable_edges(m)
    assert source == DrivableSource.LANES and len(edges) > 0
    union, _ = drivable_union(m)
    want_area = LineString(arc).buffer(1.75, cap_style="flat").union(
        LineString([[20, 20], [20, 60]]).buffer(1.75, cap_style="flat")).area
    assert union.area == pytest.approx(want_area, rel=1e-3)
    # On the curve, 1.5 m off the centreline: inside; 2.5 m off: 0.75 m out.
    n = np.array([-np.sin(np.pi / 4), np.cos(np.pi / 4)])  # left normal at the middle of the arc
    mid = np.array([20 * np.sin(np.pi / 4), 20 - 20 * np.cos(np.pi / 4)])
    got, _ = _check(m, np.array([mid + 1.5 * n, mid - 2.5 * n]), tol=0.02)
    assert got[0] == 0 and got[1] == pytest.approx(0.75, abs=0.02)


def test_no_area_is_not_judged():
    m = MapRecord(map_id="n", lanes=[])
    edges, source = drivable_edges(m)
    assert source == DrivableSource.NONE and edges.shape == (0, 4)
    d = inf.area_distance(jnp.zeros((2, 2)), jnp.zeros((4, 4)), jnp.zeros(4, bool))
    np.testing.assert_array_equal(np.asarray(d), 0.0)


def test_drivable_excess_is_the_farthest_corner():
    m = _map()
    edges, _ = drivable_edges(m)
    md = type("M", (), {})()
    md.drivable_edges = jnp.asarray(edges, jnp.float32)
    md.drivable_edges_valid = jnp.ones(len(edges), bool)
    # A 4 x 2 m car at x = 45, heading +x, 1.5 m over the leg's north edge (y = 8).
    ego = ego_from_log(jnp.array([45.0, 8.5]), jnp.asarray(0.0), jnp.zeros(2), jnp.zeros(()))
    got = float(inf.drivable_excess(ego, jnp.array([4.0, 2.0]), md))
    union, _ = drivable_union(m)
    corners = shapely.points([[43, 9.5], [47, 9.5], [43, 7.5], [47, 7.5]])
    assert got == pytest.approx(max(union.distance(c) for c in corners), abs=1e-4)
    assert got == pytest.approx(1.5, abs=1e-4)


# --------------------------------------------------------------------------
# Lane polygons: which lanes hold the ego's points
# --------------------------------------------------------------------------


def _arc_lane(r, w=3.5, n=24):
    """A quarter-circle lane of centre radius r about the origin, as a polygon."""
    a = np.linspace(0, np.pi / 2, n)
    outer = np.stack([(r + w / 2) * np.cos(a), (r + w / 2) * np.sin(a)], 1)
    inner = np.stack([(r - w / 2) * np.cos(a), (r - w / 2) * np.sin(a)], 1)[::-1]
    return np.concatenate([outer, inner])


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 90.0), st.floats(-3.0, 3.0), st.floats(-1.0, 1.0))
def test_lane_hits_match_shapely_on_curved_lanes(deg, off, dyaw):
    lanes = [_arc_lane(10.0), _arc_lane(13.5), np.array([[-50, -1.75], [50, -1.75], [50, 1.75], [-50, 1.75]])]
    poly = lane_helpers.polylines(lanes, 64)
    a = np.radians(deg)
    centre = np.array([(10.0 + off) * np.cos(a), (10.0 + off) * np.sin(a)])
    yaw = a + np.pi / 2 + dyaw
    ego = ego_from_log(jnp.asarray(centre, jnp.float32), jnp.asarray(yaw, jnp.float32), jnp.zeros(2), jnp.zeros(()))
    corners = np.asarray(geo.box_corners(ego.xy, ego.yaw, 4.6, 2.0))
    pts = np.concatenate([corners, centre[None]])
    index = inf.lane_index(poly)
    hits = inf.lane_hits(jnp.asarray(pts, jnp.float32), index)
    rows = np.asarray(hits.rows)
    got = np.zeros((len(pts), len(lanes)), bool)
    for j, r in enumerate(rows):
        if r >= 0:
            got[:, r] = np.asarray(hits.inside)[:, j]
    want = np.array([[Polygon(lp).contains(Point(p)) for lp in lanes] for p in pts])
    # Points within 1 mm of an edge may go either way (float32 vs float64).
    near_edge = np.array([[Polygon(lp).exterior.distance(Point(p)) < 1e-3 for lp in lanes] for p in pts])
    assert np.all((got == want) | near_edge)
    assert not bool(hits.overflow)
