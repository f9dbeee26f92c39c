"""Per-tick infraction facts not covered through whole episodes in test_sim."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point

from drivee2e_jax import geometry as geo
from drivee2e_jax import infractions as inf
from drivee2e_jax.dynamics import ego_from_log
from drivee2e_jax.types import Marking

LW = jnp.array([4.6, 2.0])


def _ego(x, y, yaw):
    return ego_from_log(jnp.array([x, y]), jnp.asarray(yaw), jnp.zeros(2), jnp.zeros(()))


def _lines(*polys, n=8):
    """Pad polylines to (M, n, 2) + point masks."""
    xy = np.zeros((len(polys), n, 2), np.float32)
    pv = np.zeros((len(polys), n), bool)
    for i, p in enumerate(polys):
        xy[i, : len(p)] = p
        pv[i, : len(p)] = True
    return jnp.asarray(xy), jnp.asarray(pv)


DASHED_Y0 = np.array([[-50.0, 0.0], [0.0, 0.0], [50.0, 0.0]])
EDGE_Y5 = np.array([[-50.0, 5.0], [50.0, 5.0]])

@jax.jit
def invasion(prev, ego, lw, xy, pv, valid, marking):
    return inf.lane_invasion(prev, ego, lw, inf.marking_segments(xy, pv, valid, marking))


def _call(prev, ego, polys, markings, valid=None):
    xy, pv = _lines(*polys)
    valid = jnp.ones(len(polys), bool) if valid is None else jnp.asarray(valid)
    hit, mark = invasion(prev, ego, LW, xy, pv, valid, jnp.asarray(markings, jnp.int32))
    return bool(hit), int(mark)


def test_driving_along_a_lane_invades_nothing():
    assert _call(_ego(0, -1.75, 0.0), _ego(1.5, -1.75, 0.0), [DASHED_Y0], [Marking.DASHED]) == (False, Marking.NONE)


def test_a_corner_crossing_a_dashed_line_is_an_invasion():
    # Ego drifting left: its left corners move from y = -0.1 to y = +0.3.
    assert _call(_ego(0, -1.1, 0.0), _ego(1.0, -0.7, 0.0), [DASHED_Y0], [Marking.DASHED]) == (True, Marking.DASHED)


def test_strictest_marking_is_reported_and_road_edges_do_not_count():
    solid_y0 = DASHED_Y0.copy()
    prev, ego = _ego(0, -1.1, 0.0), _ego(1.0, -0.7, 0.0)
    assert _call(prev, ego, [DASHED_Y0, solid_y0], [Marking.DASHED, Marking.SOLID]) == (True, Marking.SOLID)
    assert _call(prev, ego, [DASHED_Y0], [Marking.ROAD_EDGE])[0] is False
    assert _call(prev, ego, [DASHED_Y0], [Marking.NONE])[0] is False
    assert _call(prev, ego, [DASHED_Y0], [Marking.DASHED], valid=[False])[0] is False
    # A kerb far away changes nothing.
    assert _call(prev, ego, [DASHED_Y0, EDGE_Y5], [Marking.DASHED, Marking.ROAD_EDGE]) == (True, Marking.DASHED)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-3, 3), st.floats(-3, 3), st.floats(-np.pi, np.pi),
    st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.floats(-0.3, 0.3),
    st.floats(-4, 4), st.floats(-4, 4), st.floats(-np.pi, np.pi),
)
def test_matches_shapely_corner_paths(x, y, yaw, dx, dy, dyaw, lx, ly, lang):
    """Oracle: some corner's straight path crosses the marking segment (shapely)."""
    a = np.array([lx, ly]) - 6 * np.array([np.cos(lang), np.sin(lang)])
    b = np.array([lx, ly]) + 6 * np.array([np.cos(lang), np.sin(lang)])
    prev, ego = _ego(x, y, yaw), _ego(x + dx, y + dy, yaw + dyaw)
    c0 = np.asarray(geo.box_corners(prev.xy, prev.yaw, LW[0], LW[1]))
    c1 = np.asarray(geo.box_corners(ego.xy, ego.yaw, LW[0], LW[1]))
    line = LineString([a, b])
    paths = [LineString([p, q]) for p, q in zip(c0, c1)]
    # Proper crossings only: skip near-touching cases (float32 vs float64).
    ends = [Point(c) for c in (*c0, *c1)]
    if any(line.distance(e) < 1e-3 for e in ends) or any(p.distance(Point(e)) < 1e-3 for p in paths for e in (a, b)):
        return
    want = any(p.crosses(line) for p in paths)
    got, _ = _call(prev, ego, [np.stack([a, b])], [Marking.SOLID])
    assert got == want
