"""nuPlan closed-loop score (``drivee2e_jax.metrics.nuplan``): every sub-metric
on hand-built inputs whose answers follow nuplan-devkit's code (file and
function named per test), TTC also against a shapely transcription of
nuPlan's projection loop, and the CLS on a worked episode."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.metrics import nuplan
from drivee2e_jax.types import Category
from tests.helpers import lanes as lane_helpers
from tests.helpers.nuplan_cases import (
    agents,
    ego_state,
    fake_log,
    fake_scenario,
    shapely_ttc,
    straight_lanes,
)

EGO_LW = (4.0, 2.0)
NO_LANE = (jnp.zeros(1, bool), jnp.array([[1.0, 0.0]]))  # no lane polygon holds the ego


@jax.jit
def _tick(prev_xy, ego, ag, size, wide):
    return nuplan.tick(prev_xy, ego, jnp.asarray(EGO_LW, jnp.float32), ag, size, *NO_LANE, wide_view=wide)


def _ttc(ego, rows, sizes, wide=False):
    ag = agents(rows)
    size = jnp.asarray([[ln, w, 1.5] for ln, w in sizes], jnp.float32)
    out = _tick(ego.xy, ego, ag, size, jnp.asarray(wide))
    return float(out.ttc_s)


# --- time_to_collision_within_bound.py: _compute_time_to_collision_at_timestamp ---


def test_ttc_head_on_exact_step():
    # Gap between the fronts 30 - 2 - 2.25 = 25.75 m, closing 10 + 5 = 15 m/s:
    # contact at 1.717 s, first projected sample overlapping is k = 18 -> 1.8 s.
    ego = ego_state(0.0, 0.0, 0.0, 10.0)
    rows, sizes = [(30.0, 0.5, math.pi, 5.0)], [(4.5, 1.8)]
    got = _ttc(ego, rows, sizes)
    assert got == pytest.approx(1.8, abs=1e-5)
    assert got == pytest.approx(shapely_ttc((0, 0, 0, 10), EGO_LW, [(30, 0.5, math.pi, 5, 4.5, 1.8)]), abs=1e-5)


def test_ttc_beyond_horizon_is_inf():
    # Contact would need 46.75 / 15 = 3.1 s > the last sample 2.9 s.
    assert _ttc(ego_state(0, 0, 0, 10), [(51.0, 0.0, math.pi, 5.0)], [(4.5, 1.8)]) == math.inf
    assert shapely_ttc((0, 0, 0, 10), EGO_LW, [(51, 0, math.pi, 5, 4.5, 1.8)]) == math.inf


def test_ttc_stopped_ego_not_evaluated():
    # compute_time_to_collision: ego speed <= 5e-3 m/s -> default inf.
    assert _ttc(ego_state(0, 0, 0, 0.004), [(8.0, 0.0, math.pi, 5.0)], [(4.5, 1.8)]) == math.inf
    # just above: gap 8 - 4.25 = 3.75 m closing at 5.006 m/s -> 0.749 s -> sample 0.8 s
    assert _ttc(ego_state(0, 0, 0, 0.006), [(8.0, 0.0, math.pi, 5.0)], [(4.5, 1.8)]) == pytest.approx(0.8, abs=1e-6)


def test_ttc_track_behind_never_counts():
    # Faster car 15 m behind in the same lane: is_agent_behind (angle 180 > 150 deg),
    # so not projected, even with the lateral view open.
    rows, sizes = [(-15.0, 0.0, 0.0, 15.0)], [(4.5, 1.8)]
    assert shapely_ttc((0, 0, 0, 5), EGO_LW, [(-15, 0, 0, 15, 4.5, 1.8)]) < 3.0  # it would hit
    assert _ttc(ego_state(0, 0, 0, 5), rows, sizes) == math.inf
    assert _ttc(ego_state(0, 0, 0, 5), rows, sizes, wide=True) == math.inf


def test_ttc_lateral_track_only_with_wide_view():
    # Crossing car at relative angle ~62 deg from the rear axle (-1.45, 0): not
    # ahead (< 30 deg), not behind; counted only while the ego is between
    # lanes / off route objects / in an intersection.
    rows, sizes = [(5.0, -12.0, math.pi / 2, 6.0)], [(4.5, 1.8)]
    ego = ego_state(0, 0, 0, 2.0)
    want = shapely_ttc((0, 0, 0, 2), EGO_LW, [(5, -12, math.pi / 2, 6, 4.5, 1.8)])
    assert 0.0 < want < 3.0
    assert _ttc(ego, rows, sizes) == math.inf
    assert _ttc(ego, rows, sizes, wide=True) == pytest.approx(want, abs=1e-5)


def test_ttc_track_already_in_contact_is_excluded():
    # extract_tracks_info_excluding_collided_tracks: collided tracks are dropped.
    ego = ego_state(0, 0, 0, 5.0)
    assert _ttc(ego, [(3.0, 0.0, math.pi, 5.0)], [(4.5, 1.8)]) == math.inf
    # ... while the second, not yet touching car ahead still counts: gap 20 - 4.25, closing 5 m/s -> 3.15 s;
    # at 10 m/s closing -> 1.575 -> 1.6 s.
    got = _ttc(ego, [(3.0, 0.0, math.pi, 5.0), (20.0, 0.0, math.pi, 5.0)], [(4.5, 1.8), (4.5, 1.8)])
    assert got == pytest.approx(1.6, abs=1e-5)


def test_ttc_score_rules():
    # TimeToCollisionStatistics.compute: within bound iff 0.95 < ttc at every sample.
    speed = np.full(3, 5.0)
    none = np.zeros(3, bool)
    assert nuplan.ttc_score([np.inf, 1.0, 2.0], speed, none) == 1.0
    assert nuplan.ttc_score([np.inf, 0.9, 2.0], speed, none) == 0.0
    assert nuplan.ttc_score([np.inf, 0.9, 2.0], [5.0, 0.004, 5.0], none) == 1.0  # stopped: not evaluated
    assert nuplan.ttc_score([np.inf] * 3, speed, np.array([False, True, False])) == 0.0  # at-fault tick -> 0


# --- driving_direction_compliance.py: _extract_metric + compute ---


def test_oncoming_travel_on_lanes():
    xy, _, _, _ = straight_lanes([(0.0, 1), (3.5, -1)])
    lmap = lane_helpers.lane_map(list(np.asarray(xy)))

    def onc(x, y, yaw, px, py):
        ego = ego_state(x, y, yaw, 5.0)
        el = lane_helpers.ego_lanes(ego, EGO_LW, lmap)
        return float(nuplan.oncoming_travel(jnp.array([px, py]), ego, el.centre_in, el.tangent))

    assert onc(0.0, 0.0, math.pi, 1.0, 0.0) == pytest.approx(1.0)  # wrong way on the +x lane
    assert onc(1.0, 0.0, 0.0, 0.0, 0.0) == 0.0  # with the lane
    assert onc(0.0, 3.5, math.pi, 1.0, 3.5) == 0.0  # on the -x lane going -x
    assert onc(0.0, 1.75, math.pi, 1.0, 1.75) == 0.0  # on both: a lane runs its way
    assert onc(0.0, 0.5, 0.0, -1.0, 0.5) == 0.0
    assert onc(2.0, 3.0, 0.0, 0.5, 3.0) == pytest.approx(1.5)  # +x on the -x lane
    assert onc(0.0, 9.0, math.pi, 1.0, 9.0) == 0.0  # on no lane: no direction


@pytest.mark.parametrize(("total", "want"), [(1.9, 1.0), (4.0, 0.5), (7.0, 0.0)])
def test_direction_windows(total, want):
    # 10 Hz -> n_horizon = int(1e6 / 1e5) = 10; windows of 11 samples. The travel is spread over 10 ticks.
    t = 0.1 * np.arange(1, 31)
    x = np.zeros(30)
    x[5:15] = total / 10
    assert nuplan.direction_score(x, t) == want


def test_direction_window_length():
    # 0.25 m per tick for 40 ticks: any 11-sample window holds 2.75 m -> 0.5 (not 10 m -> 0).
    t = 0.1 * np.arange(1, 41)
    assert nuplan.direction_score(np.full(40, 0.25), t) == 0.5
    # 0.19 m per tick: 11 * 0.19 = 2.09 >= 2 -> 0.5; 0.18 -> 1.98 -> 1.
    assert nuplan.direction_score(np.full(40, 0.19), t) == 0.5
    assert nuplan.direction_score(np.full(40, 0.18), t) == 1.0


# --- no_ego_at_fault_collisions.py: find_new_collisions, classify_at_fault_collisions, compute_score ---


def _coll(hits, layout):
    n = len(layout)
    hit = np.zeros(n, bool)
    tid = np.full(n, -1)
    cat = np.zeros(n, int)
    fault = np.zeros(n, bool)
    for i, (track, category, f) in hits.items():
        hit[i], tid[i], cat[i], fault[i] = True, track, category, f
    return nuplan.collision_score(*nuplan.collision_counts(hit, tid, cat, fault, np.asarray(layout, bool)))


def test_collision_multiplier():
    quiet = [0] * 6
    assert _coll({}, quiet) == 1.0
    assert _coll({2: (7, Category.PEDESTRIAN, True)}, quiet) == 0.0  # 1 VRU, threshold 0
    assert _coll({2: (7, Category.CYCLIST, True)}, quiet) == 0.0
    assert _coll({2: (7, Category.CAR, True)}, quiet) == 0.0  # 1 vehicle, threshold 0
    assert _coll({}, [0, 1, 1, 0, 0, 0]) == 0.5  # 1 object: 1 - 1/2
    assert _coll({}, [0, 1, 0, 1, 1, 0]) == 0.0  # 2 objects: 1 - 2/2
    assert _coll({2: (7, Category.CAR, False)}, quiet) == 1.0  # not at fault
    # the same track counts once, with its FIRST contact's fault
    assert _coll({2: (7, Category.CAR, False), 3: (7, Category.CAR, True)}, quiet) == 1.0
    assert nuplan.collision_counts([1, 1, 1], [7, 7, 8], [6, 6, 0], [1, 1, 1], [0, 0, 0]) == (1, 1, 0)


# --- drivable_area_compliance.py: is_corner_far_from_drivable_area (>= 0.3 m) ---


def test_drivable_area():
    assert nuplan.drivable_score([0.0, 0.29, 0.1]) == 1.0
    assert nuplan.drivable_score([0.0, 0.31]) == 0.0
    assert nuplan.drivable_score([]) == 1.0


# --- ego_progress_along_expert_route.py: compute; ego_is_making_progress.py ---


def test_progress_ratio():
    assert nuplan.progress_ratio(10.0, 20.0) == 0.5
    assert nuplan.progress_ratio(30.0, 20.0) == 1.0  # saturated at 1
    assert nuplan.progress_ratio(1.0, 1.5) == 1.0  # both below 2 m: 2 / 2
    assert nuplan.progress_ratio(-1.9, 20.0) == 0.1  # max(-1.9, 2) / 20
    assert nuplan.progress_ratio(-2.1, 20.0) == 0.0  # below -2 m
    assert nuplan.route_arc([[3.2, 0.7], [-1.0, 0.0]], [[0, 0], [1, 0], [2, 0], [5, 0]], [1, 1, 1, 1]) == \
        pytest.approx([3.2, 0.0])


# --- speed_limit_compliance.py: _compute_violation_metric_score ---


def test_speed_limit_arithmetic():
    # 11 samples 0.1 s apart: duration 1.0 s, mean dt 0.1 s. 5 ticks 2.23 m/s over:
    # 1 - 5 * 2.23 * 0.1 / (2.23 * 1.0) = 0.5.
    t = 0.1 * np.arange(1, 12)
    speed = np.full(11, 12.0)
    lim = np.where(np.arange(11) < 5, 12.0 - 2.23, 13.0)
    assert nuplan.speed_limit_score(speed, lim, t) == pytest.approx(0.5)
    assert nuplan.speed_limit_score(speed, np.where(np.arange(11) < 5, 0.0, 13.0), t) == 1.0  # no limit known
    assert nuplan.speed_limit_score(speed, np.full(11, 12.0 - 4.46), t) == 0.0  # clipped at 0
    assert nuplan.speed_limit_score([20.0], [1.0], [0.1]) == 1.0  # zero duration


# --- ego_is_comfortable.py + state_extractors.py (extract_ego_acceleration / jerk / yaw_rate) ---


def _comfort(lon, yaw, t, lat=None):
    return nuplan.comfort_score(lon, np.zeros_like(lon) if lat is None else lat, yaw, t)


@pytest.mark.parametrize(("lon", "want"), [(2.39, 1.0), (2.41, 0.0), (-4.04, 1.0), (-4.06, 0.0)])
def test_comfort_lon_acc_bounds(lon, want):
    # SG smoothing keeps a constant exactly; bounds strict.
    t = 0.1 * np.arange(1, 21)
    assert _comfort(np.full(20, lon), np.zeros(20), t) == want


@pytest.mark.parametrize(("lat", "want"), [(4.88, 1.0), (4.90, 0.0)])
def test_comfort_lat_acc_bounds(lat, want):
    t = 0.1 * np.arange(1, 21)
    assert _comfort(np.zeros(20), np.zeros(20), t, lat=np.full(20, lat)) == want


@pytest.mark.parametrize(("jerk", "want"), [(4.0, 1.0), (4.2, 0.0)])
def test_comfort_lon_jerk_bounds(jerk, want):
    # 7 samples: acc window min(8, 7) = 7 (odd) and jerk window 7 both fit the whole
    # (linear) signal, so the SG 1st derivative is exactly j; a < 0 throughout, so the
    # magnitude jerk is -j (inside 8.37).
    t = 0.1 * np.arange(0, 7)
    acc = -3.5 + jerk * t
    sig = nuplan.comfort_signals(acc, np.zeros(7), np.zeros(7), t)
    assert np.allclose(sig["lon_jerk"], jerk) and np.allclose(sig["jerk"], -jerk)
    assert _comfort(acc, np.zeros(7), t) == want


def test_comfort_even_acc_window_shifts_half_a_sample():
    # extract_ego_acceleration's window 8 is even: scipy evaluates the fit half a sample
    # late inside the signal (the ends come from the interp fit, unshifted), so a ramp
    # a = j t smooths to j (t + dt / 2) in the interior and its jerk is no longer constant.
    t = 0.1 * np.arange(0, 20)
    sig = nuplan.comfort_signals(4.0 * t - 3.5, np.zeros(20), np.zeros(20), t)
    assert np.allclose(sig["lon_acc"][4:-4], 4.0 * (t[4:-4] + 0.05) - 3.5)
    assert np.allclose(sig["lon_acc"][:4], 4.0 * t[:4] - 3.5)
    assert sig["lon_jerk"].max() > 4.13  # a steady 4 m/s^3 ramp fails nuPlan's lon-jerk bound


@pytest.mark.parametrize(("rate", "want"), [(0.94, 1.0), (0.96, 0.0)])
def test_comfort_yaw_rate_bounds(rate, want):
    t = 0.1 * np.arange(0, 20)
    yaw = np.angle(np.exp(1j * rate * t))  # wrapped, then phase_unwrap-ped
    assert _comfort(np.zeros(20), yaw, t) == want


@pytest.mark.parametrize(("acc", "want"), [(1.92, 1.0), (1.94, 0.0)])
def test_comfort_yaw_acc_bounds(acc, want):
    # heading = acc t^2 / 2 over 5 samples: SG (window 5, order 3) 2nd derivative = acc exactly;
    # the yaw rate stays <= 1.94 * 0.4 = 0.78.
    t = 0.1 * np.arange(0, 5)
    sig = nuplan.comfort_signals(np.zeros(5), np.zeros(5), 0.5 * acc * t**2, t)
    assert np.allclose(sig["yaw_acc"], acc)
    assert _comfort(np.zeros(5), 0.5 * acc * t**2, t) == want


# --- weighted_average_metric_aggregator.py: _compute_scenario_score on a worked episode ---


def _episode(**kw):
    # Ego: 11 active steps at 0.1 s (t = 0.1 ... 1.1) from x = 0 to x = 10 m, 2 steps after the end.
    # Expert (logged ego): x = 20 k / 11 at step k -> 20 m at t = 1.1 s. Progress ratio 10 / 20 = 0.5.
    speed = 10.0 / 1.1
    lim = np.where(np.arange(11) < 5, speed - 2.23, 30.0)  # speed-limit score 0.5 (as above)
    log = fake_log(11, 2, 0.1, x_end=10.0, speed=speed, speed_limit=lim, **kw)
    return nuplan.episode_columns(log, fake_scenario(20.0 * np.arange(16) / 11, 0.1), 0.1)


def test_episode_worked_case_clean():
    cols = _episode(drivable_excess=0.29)
    assert tuple(cols) == nuplan.COLUMNS
    want = {
        "nuplan_no_ego_at_fault_collisions": 1.0, "nuplan_drivable_area_compliance": 1.0,
        "nuplan_ego_is_making_progress": 1.0, "nuplan_driving_direction_compliance": 1.0,
        "nuplan_ego_progress_along_expert_route": 0.5, "nuplan_time_to_collision_within_bound": 1.0,
        "nuplan_speed_limit_compliance": 0.5, "nuplan_ego_is_comfortable": 1.0,
    }
    for k, v in want.items():
        assert cols[k] == pytest.approx(v, abs=1e-9), k
    # (5 * 0.5 + 5 * 1 + 4 * 0.5 + 2 * 1) / 16 = 11.5 / 16
    assert cols["nuplan_score"] == pytest.approx(11.5 / 16)


def test_episode_worked_case_layout_contact():
    # One layout contact (ticks 5-6): objects 1 -> 0.5, and the new at-fault collision sets
    # that tick's TTC to 0 -> ttc 0. Score 0.5 * (2.5 + 0 + 2 + 2) / 16.
    layout = np.zeros(11)
    layout[5:7] = 1
    cols = _episode(layout_hit=layout, oncoming=np.r_[np.zeros(6), np.full(5, 0.8)])
    assert cols["nuplan_no_ego_at_fault_collisions"] == 0.5
    assert cols["nuplan_time_to_collision_within_bound"] == 0.0
    assert cols["nuplan_driving_direction_compliance"] == 0.5  # 4 m against the lanes within 1 s
    assert cols["nuplan_score"] == pytest.approx(0.5 * 0.5 * 6.5 / 16)


def test_episode_multipliers_zero_the_score():
    assert _episode(drivable_excess=0.31)["nuplan_score"] == 0.0
    # ego stuck at the start: progress max(0, 2) / 20 = 0.1 < 0.2 -> not making progress
    log = fake_log(11, 0, 0.1, x_end=0.0, speed=0.0, speed_limit=30.0)
    cols = nuplan.episode_columns(log, fake_scenario(20.0 * np.arange(16) / 11, 0.1), 0.1)
    assert cols["nuplan_ego_progress_along_expert_route"] == pytest.approx(0.1)
    assert cols["nuplan_ego_is_making_progress"] == 0.0
    assert cols["nuplan_score"] == 0.0


def test_episode_needs_the_nuplan_ticks():
    log = fake_log(3, 0, 0.1, x_end=1.0, speed=3.0, speed_limit=30.0)
    log.facts.nuplan = None
    with pytest.raises(ValueError, match="nuplan preset"):
        nuplan.episode_columns(log, fake_scenario(np.arange(5.0), 0.1), 0.1)


def test_combine_default_weight_for_unlisted_metric():
    """nuplan-devkit ``nuplan/planning/metrics/aggregator/weighted_average_metric_aggregator.py``,
    ``WeightedAverageMetricAggregator._compute_scenario_score`` / ``_get_metric_weight``: every
    scored column takes part; a metric missing from ``metric_weights`` gets ``metric_weights['default']``
    (1.0 in ``closed_loop_reactive_agents_weighted_average.yaml``); None values and ``score`` are skipped.

    Worked case: multipliers 1, 0.5, 1, 1 -> factor 0.5; weighted part
    (5*1 + 5*0 + 4*1 + 2*1 + 1*0 [unlisted, default 1.0]) / (5+5+4+2+1) = 11/17.
    """
    cols = {
        "nuplan_no_ego_at_fault_collisions": 1.0,
        "nuplan_drivable_area_compliance": 0.5,
        "nuplan_ego_is_making_progress": 1.0,
        "nuplan_driving_direction_compliance": 1.0,
        "nuplan_ego_progress_along_expert_route": 1.0,
        "nuplan_time_to_collision_within_bound": 0.0,
        "nuplan_speed_limit_compliance": 1.0,
        "nuplan_ego_is_comfortable": 1.0,
        "nuplan_unlisted_metric": 0.0,
        "nuplan_none_metric": None,
        "nuplan_score": 123.0,
    }
    assert nuplan.DEFAULT_WEIGHT == 1.0
    assert nuplan.combine(cols) == pytest.approx(0.5 * 11.0 / 17.0, abs=1e-12)
    without = {k: v for k, v in cols.items() if k != "nuplan_unlisted_metric"}
    assert nuplan.combine(without) == pytest.approx(0.5 * 11.0 / 16.0, abs=1e-12)


def test_static_obstacle_contact_while_ego_stopped_is_not_at_fault():
    """nuplan-devkit ``nuplan/planning/metrics/utils/collision_utils.py``, ``get_collision_type``:
    ego speed <= stopped_speed_threshold (5e-2 m/s) -> STOPPED_EGO_COLLISION, which
    ``no_ego_at_fault_collisions.py`` (``classify_at_fault_collisions``) never counts; a static
    object hit by a moving ego is STOPPED_TRACK_COLLISION, at fault, an object collision. The
    type is fixed at the first contact tick (``find_new_collisions`` registers the token then).

    Worked case (NAVSIM's ``no_at_fault_collision`` applies the same rule): contact 1 starts while
    the ego stands (0.0 m/s) and speeds up while touching -> not counted; contact 2 starts at
    2 m/s -> one object collision; with the ego stopped at both contacts none counts (score 1).
    """
    n = 8
    no_agent = (np.zeros(n, bool), np.zeros(n, int), np.zeros(n, int), np.zeros(n, bool))
    lay = np.array([0, 1, 1, 0, 0, 1, 1, 0], bool)
    speed = np.array([0.0, 0.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0])
    assert nuplan.collision_counts(*no_agent, lay, speed) == (0, 0, 1)
    stopped = np.where(lay, 0.01, 1.0)
    assert nuplan.collision_counts(*no_agent, lay, stopped) == (0, 0, 0)
    assert nuplan.collision_score(*nuplan.collision_counts(*no_agent, lay, stopped)) == 1.0
    ticks = nuplan._first_fault_ticks(no_agent[0], no_agent[1], no_agent[3], lay, speed)
    assert np.flatnonzero(ticks).tolist() == [5]


# --- issue 35 item 4 / 8: TTC over every reachable track and obstacle, collision bookkeeping ---


def _obstacles(polys):
    """(O, V) Polylines of convex polygons (vertex lists, padded to 6)."""
    from drivee2e_jax.types import Polylines

    xy = np.zeros((len(polys), 6, 2), np.float32)
    pv = np.zeros((len(polys), 6), bool)
    for i, p in enumerate(polys):
        xy[i, : len(p)] = p
        pv[i, : len(p)] = True
    return Polylines(xy=jnp.asarray(xy), point_valid=jnp.asarray(pv), valid=jnp.ones(len(polys), bool))


@jax.jit
def _tick_full(ego, ag, size, ob_xy, ob_pv, ob_valid, collided, ob_collided):
    from drivee2e_jax import geometry
    from drivee2e_jax.types import Polylines

    obs = Polylines(xy=ob_xy, point_valid=ob_pv, valid=ob_valid)
    sat = jax.vmap(geometry.polygon_sat)(obs.xy, obs.point_valid & obs.valid[:, None])
    return nuplan.tick(ego.xy, ego, jnp.asarray(EGO_LW, jnp.float32), ag, size, *NO_LANE, collided=collided,
                       obstacles=sat, discs=nuplan.obstacle_discs(obs), obstacle_collided=ob_collided)


def _square(cx, cy, h):
    return [(cx - h, cy - h), (cx + h, cy - h), (cx + h, cy + h), (cx - h, cy + h)]


def test_ttc_reaches_past_the_16_nearest_and_static_objects():
    """nuplan-devkit ``time_to_collision_within_bound.py``:
    ``extract_tracks_info_excluding_collided_tracks`` keeps EVERY tracked object
    (``observation.tracked_objects``, static objects included, a non-``Agent`` at
    speed 0) that is ahead of the rear axle (or not behind in the wide view), and
    ``_compute_time_to_collision_at_timestamp`` projects all of them.

    Worked case, ego (0, 0) heading +x at 10 m/s, 4 x 2 m:
    * 20 parked cars 6-25 m BEHIND the ego (the 16 nearest agents; behind: never projected);
    * an oncoming car at x = 60 m, 20 m/s: gap 60 - 2 - 2.25 = 55.75 m at 30 m/s
      -> 1.858 s -> first overlapping sample 1.9 s. It is the 21st nearest, so the
      old "16 nearest" view (``infractions.nearest_rows``) never projected it (TTC inf);
    * alone, a 2 x 2 m static box centred 20.5 m ahead: gap 20.5 - 2 - 1 = 17.5 m at
      10 m/s -> 1.75 s -> sample 1.8 s (never projected before: TTC inf).
    Both against the shapely transcription of nuPlan's loop.
    """
    ego = ego_state(0.0, 0.0, 0.0, 10.0)
    parked = [(-6.0 - i, 3.0 * (i % 2) - 1.5, 0.0, 0.0) for i in range(20)]
    rows = [*parked, (60.0, 0.0, math.pi, 20.0)]
    size = jnp.asarray([[4.5, 1.8, 1.5]] * len(rows), jnp.float32)
    ag = agents(rows)
    from drivee2e_jax import infractions

    near, _ = infractions.nearest_rows(ego, ag)
    assert len(rows) - 1 not in np.asarray(near).tolist()  # the old view missed the oncoming car
    far = _obstacles([_square(500.0, 500.0, 1.0)])
    none_a, none_o = jnp.zeros(len(rows), bool), jnp.zeros(1, bool)
    out = _tick_full(ego, ag, size, far.xy, far.point_valid, far.valid, none_a, none_o)
    want = shapely_ttc((0, 0, 0, 10), EGO_LW, [(*r, 4.5, 1.8) for r in rows])
    assert want == pytest.approx(1.9)
    assert float(out.ttc_s) == pytest.approx(want, abs=1e-5)
    assert int(out.ttc_reachable) == 1 and not bool(out.ttc_overflow)

    box = _square(20.5, 0.0, 1.0)
    ob = _obstacles([box])
    lone = agents([(-30.0, 0.0, 0.0, 0.0)])
    out = _tick_full(ego, lone, size[:1], ob.xy, ob.point_valid, ob.valid, jnp.zeros(1, bool), none_o)
    want = shapely_ttc((0, 0, 0, 10), EGO_LW, [], statics=[box])
    assert want == pytest.approx(1.8)
    assert float(out.ttc_s) == pytest.approx(want, abs=1e-5)
    # A static object already touched earlier in the episode is excluded (collided_track_ids).
    out = _tick_full(ego, lone, size[:1], ob.xy, ob.point_valid, ob.valid, jnp.zeros(1, bool), jnp.ones(1, bool))
    assert float(out.ttc_s) == math.inf


def test_ttc_culling_keeps_every_reachable_track_and_flags_overflow():
    """The culling (``nuplan.ttc_candidates``) keeps every track whose closest
    approach passes the reach bound; 20 oncoming 1 x 1 m boxes in a file ahead
    (x = 30.3, 32.3, ..., 68.3 m, 10 m/s; ego 15 m/s: all reach it within 2.9 s)
    qualify (> 16): ``ttc_overflow`` says so, and the TTC is still the first
    hit (the earliest possible contacts are kept first): gap 30.3 - 2 - 0.5 =
    27.8 m at 25 m/s -> 1.112 s -> sample 1.2 s. Oracle: shapely nuPlan loop."""
    ego = ego_state(0.0, 0.0, 0.0, 15.0)
    rows = [(68.3 - 2.0 * i, 0.0, math.pi, 10.0) for i in range(20)]
    size = jnp.asarray([[1.0, 1.0, 1.5]] * 20, jnp.float32)
    far = _obstacles([_square(500.0, 500.0, 1.0)])
    out = _tick_full(ego, agents(rows), size, far.xy, far.point_valid, far.valid, jnp.zeros(20, bool),
                     jnp.zeros(1, bool))
    assert int(out.ttc_reachable) == 20 and bool(out.ttc_overflow)
    want = shapely_ttc((0, 0, 0, 15), EGO_LW, [(*r, 1.0, 1.0) for r in rows])
    assert want == pytest.approx(1.2)
    assert float(out.ttc_s) == pytest.approx(want, abs=1e-5)


def test_ttc_keeps_excluding_a_collided_track():
    """nuplan-devkit ``time_to_collision_within_bound.py``,
    ``extract_tracks_info_excluding_collided_tracks``: ``collided_track_ids`` is a
    union over the timestamps so far, so a track stays excluded after the
    contact ends. Worked case: a car touched earlier, now 10 m ahead and
    oncoming at 5 m/s (gap 10 - 4.25 = 5.75 m at 15 m/s -> 0.383 s -> 0.4 s):
    without memory (not touching now) TTC 0.4; with the memory, inf.
    The memory: ``nuplan.remember`` ORs each tick's contacts."""
    ego = ego_state(0.0, 0.0, 0.0, 10.0)
    rows = [(10.0, 0.0, math.pi, 5.0)]
    size = jnp.asarray([[4.5, 1.8, 1.5]], jnp.float32)
    far = _obstacles([_square(500.0, 500.0, 1.0)])
    args = (ego, agents(rows), size, far.xy, far.point_valid, far.valid)
    assert float(_tick_full(*args, jnp.zeros(1, bool), jnp.zeros(1, bool)).ttc_s) == pytest.approx(0.4, abs=1e-5)
    assert shapely_ttc((0, 0, 0, 10), EGO_LW, [(*rows[0], 4.5, 1.8)]) == pytest.approx(0.4)
    mem = nuplan.init_memory(3, 2)
    mem = nuplan.remember(mem, jnp.array([2, 0]), jnp.array([True, False]), jnp.array([False, True]))
    mem = nuplan.remember(mem, jnp.array([2, 0]), jnp.array([False, False]), jnp.array([False, False]))
    assert np.asarray(mem.agents).tolist() == [False, False, True]
    assert np.asarray(mem.obstacles).tolist() == [False, True]
    assert float(_tick_full(*args, jnp.ones(1, bool), jnp.zeros(1, bool)).ttc_s) == math.inf


def test_two_tracks_hit_at_once_count_each():
    """nuplan-devkit ``no_ego_at_fault_collisions.py``, ``find_new_collisions``: every
    tracked object overlapping the ego at a timestamp is registered and classified
    (``_get_collision_type``). Worked case at tick 2: car 7 (nearest, rear-ending
    the ego: ACTIVE_REAR, not at fault) and car 8 (the ego's front on it: at
    fault) both touch. Keeping only the nearest contact counted nothing (score
    1); nuPlan counts car 8 (vehicles 1 -> score 0) and that tick's TTC is 0.
    A pedestrian and a car first hit at fault together count one each."""
    n = 4
    hit = np.zeros((n, 2), bool)
    hit[2:] = True
    tid = np.tile([7, 8], (n, 1))
    cat = np.zeros((n, 2), int)
    fault = np.zeros((n, 2), bool)
    fault[2:, 1] = True
    lay = np.zeros((n, 1), bool)
    speed = np.full(n, 5.0)
    assert nuplan.collision_counts(hit, tid, cat, fault, lay, speed) == (0, 1, 0)
    assert nuplan.collision_counts(hit[:, 0], tid[:, 0], cat[:, 0], fault[:, 0], lay[:, 0], speed) == (0, 0, 0)
    assert np.flatnonzero(nuplan._first_fault_ticks(hit, tid, fault, lay, speed)).tolist() == [2]
    cat2 = np.tile([int(Category.PEDESTRIAN), 0], (n, 1))
    both = np.broadcast_to(hit & True, (n, 2)).copy()
    assert nuplan.collision_counts(both, tid, cat2, both, lay, speed) == (1, 1, 0)


def test_static_obstacle_counts_once_per_episode():
    """nuplan-devkit ``no_ego_at_fault_collisions.py``: ``find_new_collisions`` skips a
    token in ``collided_track_ids``, so touching the same static object again
    (the ego backs off and rolls on into it) is no new collision; a second
    object is. Worked case (ego at 2 m/s): obstacle 0 touched at ticks 1-2 and
    again 5-6, obstacle 1 at tick 8 -> objects 2 (score 1 - 2/2 = 0); without
    identity (rising edges of ``layout_hit``) this counted 3. Obstacle 0 first
    touched while the ego stood (STOPPED_EGO) and re-touched moving: 0."""
    n = 10
    lay = np.zeros((n, 2), bool)
    lay[[1, 2, 5, 6], 0] = True
    lay[8, 1] = True
    speed = np.full(n, 2.0)
    none = (np.zeros(n, bool), np.zeros(n, int), np.zeros(n, int), np.zeros(n, bool))
    assert nuplan.collision_counts(*none, lay, speed) == (0, 0, 2)
    assert nuplan.collision_counts(*none, lay.any(1), speed) == (0, 0, 3)
    assert np.flatnonzero(nuplan._first_fault_ticks(*none[:2], none[3], lay, speed)).tolist() == [1, 8]
    stood = np.where(np.arange(n) == 1, 0.0, 2.0)
    assert nuplan.collision_counts(*none, lay[:, :1], stood) == (0, 0, 0)
