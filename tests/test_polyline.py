"""Properties of the host-side polyline helpers (``drivee2e_jax.polyline``),
with shapely as the oracle for lengths and positions along a line."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from drivee2e_jax import geometry
from drivee2e_jax.polyline import (
    arc_length,
    dedupe_polyline,
    densify_polyline,
    polyline_heading,
    polyline_length,
    resample_at_fractions,
    resample_polyline,
    wrap_angle,
)

finite = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)
angles = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
coords = st.floats(-200.0, 200.0, allow_nan=False, allow_infinity=False)
polylines = st.lists(st.tuples(coords, coords), min_size=2, max_size=12).map(lambda p: np.array(p, np.float64))
spacings = st.floats(0.1, 20.0, allow_nan=False)


def _x_monotone(p: np.ndarray) -> np.ndarray:
    """A simple (never self-touching) polyline from ``p``: x made strictly increasing."""
    q = p.copy()
    q[:, 0] = np.cumsum(np.abs(q[:, 0]) + 0.01)
    return q


# --------------------------------------------------------------------------
# wrap_angle
# --------------------------------------------------------------------------


@settings(max_examples=300, deadline=None)
@given(angles)
def test_wrap_angle_range_and_same_direction(a):
    w = float(wrap_angle(a))
    assert -math.pi < w <= math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


@settings(max_examples=300, deadline=None)
@given(angles)
def test_wrap_angle_is_idempotent_within_rounding(a):
    w = wrap_angle(a)
    assert abs(float(wrap_angle(w)) - float(w)) <= 4 * np.spacing(math.pi)


def test_wrap_angle_edges_go_to_plus_pi():
    edges = np.array([math.pi, -math.pi, 3 * math.pi, -3 * math.pi, np.nextafter(math.pi, 4.0),
                      np.nextafter(-math.pi, -4.0)])
    w = wrap_angle(edges)
    assert np.all(w > -math.pi) and np.all(w <= math.pi)
    assert w[0] == math.pi and w[1] == math.pi and w[2] == math.pi and w[3] == math.pi
    assert wrap_angle(0.0) == 0.0 and wrap_angle(np.zeros((2, 3))).shape == (2, 3)


@settings(max_examples=200, deadline=None)
@given(st.floats(-50.0, 50.0, allow_nan=False))
def test_wrap_angle_matches_the_in_jit_geometry_wrap(a):
    ours = float(wrap_angle(a))
    jit = float(geometry.wrap_angle(np.float32(a)))
    # same convention: equal up to float32 rounding (both ends map to +pi)
    assert abs(ours - jit) < 1e-5 or abs(abs(ours - jit) - 2 * math.pi) < 1e-5 and abs(abs(ours) - math.pi) < 1e-5


# --------------------------------------------------------------------------
# lengths and headings
# --------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(polylines)
def test_length_and_arc_match_shapely(p):
    s = arc_length(p)
    assert s[0] == 0.0 and np.all(np.diff(s) >= 0.0) and s.shape == (len(p),)
    assert math.isclose(polyline_length(p), s[-1], rel_tol=1e-12, abs_tol=1e-9)
    assert math.isclose(polyline_length(p), shapely.LineString(p).length, rel_tol=1e-9, abs_tol=1e-9)


def test_length_of_fewer_than_two_points_is_zero():
    assert polyline_length(np.zeros((0, 2))) == 0.0
    assert polyline_length(np.array([[1.0, 2.0]])) == 0.0


def test_heading_of_first_and_last_segment_and_over_a_distance():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [1.0, 5.0]])
    assert polyline_heading(p) == 0.0
    assert polyline_heading(p, at_end=True) == pytest.approx(math.pi / 2)
    # the chord over the first 2 m ends at (1, 1)
    assert polyline_heading(p, over_m=2.0) == pytest.approx(math.pi / 4)
    assert polyline_heading(p, at_end=True, over_m=2.0) == pytest.approx(math.pi / 2)
    assert polyline_heading(np.ones((3, 2)), over_m=2.0) == 0.0


# --------------------------------------------------------------------------
# resampling
# --------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(polylines, spacings, st.booleans())
def test_resample_keeps_ends_spacing_and_stays_on_the_line(p, spacing, importer_mode):
    kw = dict(dedupe_tol=0.0, count_slack=0.0) if importer_mode else {}
    length = polyline_length(p)
    assume(length > 1e-3)
    q = resample_polyline(p, spacing, **kw)
    assert np.array_equal(q[0], p[0]) and np.array_equal(q[-1], p[-1])
    assert len(q) >= 2
    steps = np.linalg.norm(np.diff(q, axis=0), axis=1)
    assert steps.max() <= spacing + 1e-6
    line = shapely.LineString(p)
    assert max(line.distance(shapely.Point(x)) for x in q) < 1e-6
    assert len(q) - 1 >= math.ceil(length / spacing - 1e-6)


@settings(max_examples=200, deadline=None)
@given(polylines, spacings)
def test_resample_spaces_evenly_along_a_simple_line(p, spacing):
    p = _x_monotone(p)
    q = resample_polyline(p, spacing)
    line = shapely.LineString(p)
    along = np.array([line.project(shapely.Point(x)) for x in q])
    length = polyline_length(p)
    assert np.allclose(np.diff(along), length / (len(q) - 1), atol=1e-6 * max(1.0, length))


@settings(max_examples=100, deadline=None)
@given(polylines, spacings)
def test_resample_never_lengthens_the_polyline(p, spacing):
    assert polyline_length(resample_polyline(p, spacing)) <= polyline_length(p) + 1e-9


def test_resample_counts_and_degenerate_inputs():
    p = np.array([[0.0, 0.0], [10.0, 0.0]])
    assert len(resample_polyline(p, 2.0)) == 6
    assert len(resample_polyline(p, 3.0)) == 5  # 10 / 3 -> 4 steps of 2.5 m
    # a hair over a multiple adds no point by default (count_slack), one without it
    q = np.array([[0.0, 0.0], [10.0 + 1e-12, 0.0]])
    assert len(resample_polyline(q, 2.0)) == 6
    assert len(resample_polyline(q, 2.0, count_slack=0.0)) == 7
    assert resample_polyline(np.array([[1.0, 2.0]]), 1.0).shape == (1, 2)
    same = resample_polyline(np.array([[1.0, 2.0], [1.0, 2.0]]), 1.0)
    assert np.array_equal(same, [[1.0, 2.0], [1.0, 2.0]])
    # extra columns are ignored
    assert resample_polyline(np.array([[0.0, 0.0, 5.0], [4.0, 0.0, 5.0]]), 1.0).shape == (5, 2)


def test_dedupe_keeps_first_and_exact_last():
    p = np.array([[0.0, 0.0], [0.0, 1e-9], [1.0, 0.0], [1.0, 1e-7]])
    d = dedupe_polyline(p)
    assert np.array_equal(d, [[0.0, 0.0], [1.0, 1e-7]])


@settings(max_examples=100, deadline=None)
@given(polylines, st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8))
def test_points_at_fractions_match_shapely_interpolate(p, frac):
    assume(polyline_length(p) > 1e-3)
    q = resample_at_fractions(p, np.array(frac))
    line = shapely.LineString(p)
    for f, x in zip(frac, q):
        want = line.interpolate(f, normalized=True)
        assert math.hypot(x[0] - want.x, x[1] - want.y) < 1e-6


@settings(max_examples=200, deadline=None)
@given(polylines, st.floats(0.2, 5.0))
def test_densify_fixed_step_with_exact_last_point(p, step):
    xy, arc = densify_polyline(p, step)
    assert np.array_equal(xy[-1], p[-1]) and arc[0] == 0.0
    assert np.allclose(arc, arc_length(xy))
    assert np.all(np.diff(arc) <= step + 1e-6)  # chords never longer than the step
    assume(polyline_length(p) > 1e-6)
    line = shapely.LineString(p)
    assert max(line.distance(shapely.Point(x)) for x in xy) < 1e-6


@settings(max_examples=200, deadline=None)
@given(polylines, st.floats(0.2, 5.0))
def test_densify_steps_exactly_along_a_simple_line(p, step):
    p = _x_monotone(p)
    xy, _ = densify_polyline(p, step)
    line = shapely.LineString(p)
    along = np.diff([line.project(shapely.Point(x)) for x in xy])
    assert np.allclose(along[:-1], step, atol=1e-6)  # every step but the last is exact ...
    assert 0.0 < along[-1] <= step + 1e-6  # ... the last is no longer


def test_densify_repeats_and_empty():
    xy, arc = densify_polyline(np.zeros((0, 2)), 1.0)
    assert xy.shape == (0, 2) and arc.shape == (0,)
    xy, arc = densify_polyline(np.array([[1.0, 1.0], [1.0, 1.0]]), 1.0)
    assert xy.shape == (1, 2) and arc.tolist() == [0.0]
