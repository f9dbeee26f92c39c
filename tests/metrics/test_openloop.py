"""Open-loop planning metrics (METRICS.md §5): the worked cases OL-01 / OL-04
and hand-built checks of ``drivee2e_jax.metrics.openloop``.

``check_ol01(case)`` / ``check_ol04(case)`` take a case dict of
``shared/reference/metric_cases.json`` and assert its expected values; the
shared case runner calls them too (``tests/helpers/metric_cases/openloop.py``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, event, given, settings
from hypothesis import strategies as st

from tests.helpers.metric_cases import subset_case
from tests.helpers.metric_cases.openloop import check_ol01, check_ol04

try:
    from shapely.geometry import Polygon
except ImportError:  # pragma: no cover - the oracle test is skipped
    Polygon = None

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.metrics import openloop as olm

_load_case = subset_case


def test_ol01_case():
    check_ol01(_load_case("OL-01"))


def test_ol04_case():
    check_ol04(_load_case("OL-04"))


# --------------------------------------------------------------------------
# Hand-built: L2 conventions
# --------------------------------------------------------------------------

T6 = 0.5 * np.arange(1, 7, dtype=np.float32)


def _straight(speed=5.0, n=1):
    xy = np.stack([speed * T6, np.zeros(6, np.float32)], -1)
    return np.broadcast_to(xy, (n, 6, 2)).copy()


def test_perfect_prediction_has_zero_l2():
    gt = _straight(n=3)
    res = olm.l2_metrics(gt, gt)
    for k in ("per_step", "uniad", "stp3"):
        np.testing.assert_array_equal(np.asarray(res[k]), 0.0)
    np.testing.assert_array_equal(np.asarray(olm.vad_l2(gt, gt)), 0.0)
    # The zero-distance gradient is finite (safe sqrt).
    g = jax.grad(lambda p: olm.l2_per_step(p, jnp.asarray(gt)).sum())(jnp.asarray(gt))
    assert np.all(np.isfinite(np.asarray(g)))


def test_constant_lateral_offset_is_one_metre_in_every_convention():
    gt = _straight(n=4)
    pred = gt + np.array([0.0, 1.0], np.float32)
    res = olm.l2_metrics(pred, gt)
    np.testing.assert_allclose(np.asarray(res["per_step"]), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(res["uniad"]), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(res["stp3"]), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(olm.vad_l2(pred, gt)), 1.0, atol=1e-6)


def test_uniad_mask_gives_zero_but_sample_counts():
    gt = _straight(n=2)
    pred = gt + np.array([[[0.0, 1.0]], [[0.0, 3.0]]], np.float32)  # 1 m and 3 m off
    mask = np.ones((2, 6), bool)
    mask[1, 5] = False  # second sample's 3 s point is not logged
    res = olm.l2_metrics(pred, gt, mask)
    np.testing.assert_allclose(np.asarray(res["per_step"]), [2, 2, 2, 2, 2, 0.5], atol=1e-6)
    np.testing.assert_allclose(np.asarray(res["uniad"]), [2, 2, 0.5], atol=1e-6)
    # VAD drops the sample instead (fut_valid_flag).
    np.testing.assert_allclose(np.asarray(olm.vad_l2(pred, gt, mask.all(-1))), 1.0, atol=1e-6)


def test_sample_valid_and_empty():
    v = np.array([[1.0] * 6, [3.0] * 6])
    np.testing.assert_allclose(np.asarray(olm.sample_mean(v, np.array([True, False]))), 1.0)
    assert np.all(np.isnan(np.asarray(olm.sample_mean(v, np.array([False, False])))))


def test_conventions_index_rules_and_errors():
    per_step = jnp.arange(1.0, 7.0)
    np.testing.assert_allclose(np.asarray(olm.uniad_convention(per_step)), [2, 4, 6])
    np.testing.assert_allclose(np.asarray(olm.stp3_convention(per_step)), [1.5, 2.5, 3.5])
    assert olm.horizon_steps() == (2, 4, 6)
    with pytest.raises(DriveE2EError, match="3 s"):
        olm.uniad_convention(jnp.ones(4))  # 3 s needs 6 steps
    with pytest.raises(DriveE2EError):
        olm.horizon_steps((1,), 0.4)


# --------------------------------------------------------------------------
# Hand-built: UniAD raster rules
# --------------------------------------------------------------------------


def test_uniad_footprint_is_32_cells():
    r, c = olm.FOOTPRINT_ROWS, olm.FOOTPRINT_COLS
    assert r.shape == (32,)
    assert (r.min(), r.max(), c.min(), c.max()) == (97, 104, 98, 101)
    assert len({(int(a), int(b)) for a, b in zip(r, c)}) == 32


def test_uniad_point_and_box_index_rules():
    traj = jnp.array([[0.0, 15.0], [0.0, -50.0], [0.0, -50.5], [2.0, 0.0]])
    r, c, inside = olm.uniad_point_cells(traj)
    np.testing.assert_array_equal(np.asarray(r), [129, 0, 0, 99])  # trunc(-0.5) = 0: still inside
    np.testing.assert_array_equal(np.asarray(c), [99, 99, 99, 103])
    np.testing.assert_array_equal(np.asarray(inside), [True, True, False, True])
    rows, cols = olm.uniad_box_cells(jnp.array([[0.0, 12.5], [0.0, 500.0], [-0.3, -0.3]]))
    assert int(rows[0].min()) == 122 and int(rows[0].max()) == 129
    assert int(rows[1].min()) == 199  # far away: clipped onto the border row
    # trunc toward zero: -0.6 + 97 = 96.4 -> 96; cols -0.6 + 98 = 97.4 -> 97
    assert int(rows[2].min()) == 96 and int(cols[2].min()) == 97


def test_uniad_box_far_away_hits_the_border_row():
    occ = np.zeros((6, 200, 200), bool)
    occ[:, 199, 99] = True
    far = jnp.tile(jnp.array([[0.0, 500.0]]), (6, 1))
    assert bool(olm.uniad_box_collisions(far, occ).all())
    assert not bool(olm.uniad_point_collisions(far, occ).any())


def test_uniad_gt_collision_excludes_step():
    occ = np.zeros((1, 6, 200, 200), bool)
    occ[0, :, 125:131, 95:106] = True
    pred = _straight(speed=5.0)  # in UniAD coordinates x lateral, y forward: swap
    pred = pred[..., ::-1].copy()
    gt_same = pred.copy()
    rates = olm.uniad_collision_rates(pred, gt_same, occ)
    np.testing.assert_array_equal(np.asarray(rates["obj_box_col"]["per_step"]), 0.0)
    np.testing.assert_array_equal(np.asarray(rates["obj_col"]["per_step"]), 0.0)
    gt_clear = gt_same + np.array([5.0, 0.0], np.float32)
    rates = olm.uniad_collision_rates(pred, gt_clear, occ)
    np.testing.assert_array_equal(np.asarray(rates["obj_box_col"]["per_step"]), [0, 0, 0, 0, 1, 1])


def test_ego_to_uniad():
    np.testing.assert_allclose(np.asarray(olm.ego_to_uniad(jnp.array([[10.0, 2.0]]))), [[-2.0, 10.0]])


# --------------------------------------------------------------------------
# Hand-built: box-based collision (the project's default)
# --------------------------------------------------------------------------

EGO_LW = jnp.array([4.6, 1.9])


def _parked(x, y=0.0, h=6, lw=(4.5, 1.9)):
    """One parked agent at (x, y), heading 0, plus a padded invalid agent."""
    xy = jnp.tile(jnp.array([[[x, y], [0.0, 0.0]]]), (h, 1, 1))
    yaw = jnp.zeros((h, 2))
    lws = jnp.array([lw, [4.5, 1.9]])
    valid = jnp.tile(jnp.array([[True, False]]), (h, 1))
    return xy, yaw, lws, valid


def test_waypoint_headings():
    xy = jnp.array([[0.0, 0.0], [0.01, 0.0], [1.01, 1.0], [1.01, 1.0], [1.01, 2.0], [1.01, 2.0]])
    h = np.asarray(olm.waypoint_headings(xy))
    np.testing.assert_allclose(h, [0.0, 0.0, np.pi / 4, np.pi / 4, np.pi / 2, np.pi / 2], atol=1e-6)
    np.testing.assert_allclose(np.asarray(olm.waypoint_headings(jnp.array([[0.0, -3.0]]))), [-np.pi / 2], atol=1e-6)


def test_driving_through_a_parked_car_counts():
    a_xy, a_yaw, a_lw, a_valid = _parked(10.0)
    pred = jnp.asarray(_straight(5.0)[0])  # 2.5 .. 15 m
    gt_stop = jnp.tile(jnp.array([[1.0, 0.0]]), (6, 1))  # the log stops short
    counted, gt_col = olm.openloop_box_collisions(pred, gt_stop, EGO_LW, a_xy, a_yaw, a_lw, a_valid)
    # overlap while |x - 10| < (4.6 + 4.5) / 2 = 4.55: x = 7.5, 10, 12.5
    np.testing.assert_array_equal(np.asarray(counted), [0, 0, 1, 1, 1, 0])
    assert not bool(gt_col.any())
    # The same path in the log: every such step is the log's own collision -> 0.
    counted2, gt_col2 = olm.openloop_box_collisions(pred, pred, EGO_LW, a_xy, a_yaw, a_lw, a_valid)
    assert not bool(counted2.any()) and bool(gt_col2.any())
    # An invalid GT step is never a GT collision.
    mask = jnp.array([True, True, True, True, False, True])
    counted3, _ = olm.openloop_box_collisions(pred, pred, EGO_LW, a_xy, a_yaw, a_lw, a_valid, gt_mask=mask)
    np.testing.assert_array_equal(np.asarray(counted3), [0, 0, 0, 0, 1, 0])
    # Rates: two samples, one colliding at steps 3..5 -> 0.5 there.
    rates = olm.collision_rates(jnp.stack([counted, counted2]))
    np.testing.assert_allclose(np.asarray(rates["per_step"]), [0, 0, 0.5, 0.5, 0.5, 0])
    np.testing.assert_allclose(np.asarray(rates["uniad"]), [0, 0.5, 0])
    np.testing.assert_allclose(np.asarray(rates["stp3"]), [0, 0.25, 0.25])


def test_perfect_prediction_never_collides():
    a_xy, a_yaw, a_lw, a_valid = _parked(7.0, y=0.5)
    gt = jnp.asarray(_straight(5.0)[0])
    counted, gt_col = olm.openloop_box_collisions(gt, gt, EGO_LW, a_xy, a_yaw, a_lw, a_valid)
    assert bool(gt_col.any()) and not bool(counted.any())


def test_invalid_agent_and_touching_do_not_count():
    a_xy, a_yaw, a_lw, _ = _parked(10.0)
    pred = jnp.asarray(_straight(5.0)[0])
    none_valid = jnp.zeros((6, 2), bool)
    assert not bool(olm.box_collisions(pred, EGO_LW, a_xy, a_yaw, a_lw, none_valid).any())
    # Bumper to bumper: the ego (x = 5, half length 2.3) and the agent (x = 9.55, half 2.25) touch.
    touch = jnp.tile(jnp.array([[5.0, 0.0]]), (6, 1))
    a_xy2, a_yaw2, a_lw2, a_valid2 = _parked(9.55)
    assert not bool(olm.box_collisions(touch, EGO_LW, a_xy2, a_yaw2, a_lw2, a_valid2).any())


# The oracle: shapely polygons of the same boxes (corners computed here in
# float64, independently of geometry.box_corners).
def _poly(xy, yaw, lw):
    c, s_ = np.cos(yaw), np.sin(yaw)
    hl, hw = 0.5 * lw[0], 0.5 * lw[1]
    local = np.array([[hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw]])
    rot = np.array([[c, -s_], [s_, c]])
    return Polygon(local @ rot.T + np.asarray(xy, np.float64))


_box_jit = jax.jit(lambda p, lw, axy, ayaw, alw, off: olm.box_collisions(
    p[None], lw, axy[None, None], ayaw[None, None], alw[None], jnp.ones((1, 1), bool), center_offset=off
)[0], static_argnums=5)

coord = st.floats(-8.0, 8.0, allow_nan=False)
length = st.floats(0.5, 6.0, allow_nan=False)


@pytest.mark.skipif(Polygon is None, reason="shapely (the oracle) is not installed")
@settings(max_examples=150, deadline=None)
@given(px=coord, py=coord, ax=coord, ay=coord, ayaw=st.floats(-3.2, 3.2, allow_nan=False),
       el=length, ew=length, al=length, aw=length, off=st.sampled_from([0.0, 0.5]))
def test_box_collision_matches_shapely(px, py, ax, ay, ayaw, el, ew, al, aw, off):
    p = np.array([px, py], np.float32)
    assume(np.hypot(px, py) > 0.1)  # a heading exists (not the "keep previous" rule)
    yaw = float(np.arctan2(p[1], p[0]))
    centre = p.astype(np.float64) + off * np.array([np.cos(yaw), np.sin(yaw)])
    ego = _poly(centre, yaw, (el, ew))
    agent = _poly((ax, ay), ayaw, (al, aw))
    # Skip near-touching configurations, where the tolerance decides.
    if ego.buffer(-2e-3, join_style=2).intersects(agent.buffer(-2e-3, join_style=2)):
        want = True
    elif not ego.buffer(2e-3, join_style=2).intersects(agent):
        want = False
    else:
        assume(False)
    event(f"overlap={want}")
    got = _box_jit(jnp.asarray(p), jnp.array([el, ew], jnp.float32), jnp.array([ax, ay], jnp.float32),
                   jnp.float32(ayaw), jnp.array([al, aw], jnp.float32), off)
    assert bool(got) == want


# ---------------------------------------------------------------------------
# VAD's raster (metric_stp3.PlanningMetric): row flip and the point-cell quirk
# ---------------------------------------------------------------------------


def vad_case() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Three samples (pred, gt (3, 6, 2) in VAD's frame, x lateral / y forward; occupancy
    (3, 6, 200, 200) in VAD's image layout, forward = up). A: an obstacle ahead (rows 66-72)
    that the box reaches at y = 12.5 and 15, plus one cell (19, 49) hit by the point quirk at
    y = 15; GT 5 m to the side. B: the same with GT = pred (every hit excluded). C: clipping
    (y = +-60 onto rows 0 / 199), trunc at a box edge (y = 2.3: rows 91..98, so row 98 hits and
    row 99 does not) and trunc toward zero of a point row ((24.875 - 25) / 0.5 = -0.25 -> row 0)."""
    ys = np.array([2.5, 5.0, 7.5, 10.0, 12.5, 15.0], np.float32)
    a = np.stack([np.zeros(6, np.float32), ys], -1)
    c = np.stack([np.zeros(6, np.float32), np.array([60.0, -60.0, 2.3, 2.3, 25.0, 2.3], np.float32)], -1)
    pred = np.stack([a, a, c])
    gt = np.stack([a + [5.0, 0.0], a, c + [30.0, 0.0]]).astype(np.float32)
    occ = np.zeros((3, 6, 200, 200), bool)
    occ[:2, :, 66:73, 95:106] = True
    occ[:2, 5, 19, 49] = True
    occ[2, 0, 0, 95:106] = True
    occ[2, 1, 199, 95:106] = True
    occ[2, 2, 98, 95:106] = True
    occ[2, 3, 99, 95:106] = True
    occ[2, 4, 0, 49] = True
    return pred, gt, occ


#: VAD ``PlanningMetric.evaluate_coll`` on ``vad_case`` (obj_coll_sum, obj_box_coll_sum), EXECUTED.
VAD_OBJ_COL_SUM = [0, 0, 0, 0, 1, 1]
VAD_OBJ_BOX_COL_SUM = [1, 1, 1, 0, 1, 1]


def test_vad_raster_collisions_match_vads_planning_metric():
    """Expected sums by EXECUTING hustvl/VAD@1688c4b ``projects/mmdet3d_plugin/VAD/planner/metric_stp3.py``
    ``PlanningMetric.evaluate_coll`` (torch, float32 inputs; ``skimage.draw.polygon`` replaced by the
    cells strictly inside the axis-aligned footprint, rows 97..104 x cols 98..101 as METRICS.md §5;
    cv2 / nuscenes / plotting stubbed). By hand: A's box hits at steps 5, 6 and its point cell
    (trunc(19.75), trunc(49.75)) = (19, 49) at step 6; C's box hits at steps 1-3, its point at step 5.
    VAD's per-sample ``obj_box_coll.mean()`` over steps 1..2k, averaged over the 3 samples, is the
    ST-P3 value of the per-step rates."""
    pred, gt, occ = vad_case()
    rates = olm.raster_collision_rates(pred, gt, occ, convention="vad")
    np.testing.assert_allclose(np.asarray(rates["obj_col"]["per_step"]), np.array(VAD_OBJ_COL_SUM) / 3, atol=1e-7)
    np.testing.assert_allclose(np.asarray(rates["obj_box_col"]["per_step"]), np.array(VAD_OBJ_BOX_COL_SUM) / 3,
                               atol=1e-7)
    per_sample = np.asarray(olm.raster_collisions(pred, gt, occ, "vad")["obj_box_col"], float)  # (3, 6)
    vad_style = [per_sample[:, :n].mean(axis=1).mean() for n in (2, 4, 6)]
    np.testing.assert_allclose(np.asarray(rates["obj_box_col"]["stp3"]), vad_style, atol=1e-7)
    np.testing.assert_allclose(np.asarray(rates["obj_box_col"]["stp3"]), [1 / 3, 0.25, 5 / 18], atol=1e-7)


def test_vad_and_uniad_rasters_differ_by_the_row_flip():
    rows_v, cols_v = olm.vad_box_cells(jnp.array([[0.0, 0.0], [0.0, 12.5]]))
    rows_u, cols_u = olm.uniad_box_cells(jnp.array([[0.0, 0.0], [0.0, 12.5]]))
    assert (int(rows_v[0].min()), int(rows_v[0].max())) == (96, 103)  # trunc(200 - r), r = 97..104
    assert (int(rows_v[1].min()), int(rows_v[1].max())) == (71, 78)
    assert (int(rows_u[1].min()), int(rows_u[1].max())) == (122, 129)
    np.testing.assert_array_equal(np.asarray(cols_v), np.asarray(cols_u))
    r, c, inside = olm.vad_point_cells(jnp.array([[0.0, 0.0], [0.0, 60.0]]))
    assert (int(r[0]), int(c[0]), bool(inside[0])) == (49, 49, True)  # the ~25 m offset: not the centre 99/100
    assert not bool(inside[1])
    with pytest.raises(DriveE2EError, match="convention"):
        olm.raster_collisions(jnp.zeros((6, 2)), jnp.zeros((6, 2)), jnp.zeros((6, 200, 200)), "stp3")
