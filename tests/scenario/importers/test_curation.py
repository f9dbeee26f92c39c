"""scenario.curation on hand-built scenarios with known defects (each check must fire, and only there)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.records import LaneRecord, MapRecord, RouteRecord, ScenarioRecord, TrackRecord
from drivee2e_jax.scenario import curation
from drivee2e_jax.scenario.importers.common import ImportOptions, windowed_scenarios
from drivee2e_jax.scenario.routes import build_route

DT = 0.1
N = 50


def lane_map() -> MapRecord:
    xs = np.linspace(-100, 100, 21)
    return MapRecord("m", [LaneRecord(1, np.stack([xs, np.zeros_like(xs)], 1), width=3.5)])


def trk(tid, xy, cat="car", k=None, yaw=None, size=(4.5, 1.9, 1.5), visible=None) -> TrackRecord:
    xy = np.asarray(xy, float)
    k = np.arange(len(xy)) if k is None else np.asarray(k)
    yaw = np.zeros(len(xy)) if yaw is None else np.asarray(yaw, float)
    return TrackRecord(tid, cat, np.array(size, float), k * DT, xy, yaw, visible=visible)


def line(x0, x1, n, y=0.0):
    return np.stack([np.linspace(x0, x1, n), np.full(n, y)], 1)


def scen(tracks, route=None) -> ScenarioRecord:
    ego = tracks[0]
    route = route or RouteRecord(ego.xy.copy(), ego.xy[0].copy(), ego.xy[-1].copy())
    return ScenarioRecord("s1", "test", "i", "m", "STR", "clear", "day", ego.track_id, route, DT, N, tracks)


def clean_ego():
    return trk(0, line(-30, 0, N))  # 30 m at ~6 m/s along the lane


def test_clean_scenario_has_no_findings():
    s = scen([clean_ego(), trk(1, line(-60, -40, N)), trk(2, line(5, 5, N, y=8.0), cat="pedestrian")])
    assert curation.curate_scenario(s, lane_map()) == []


def test_completeness_gap_and_partial_ego():
    k = np.r_[np.arange(0, 10), np.arange(15, 20)]
    s = scen([trk(0, line(-30, -10, 40)), trk(3, line(-60, -50, len(k)), k=k)])
    f = curation.check_completeness(s)
    gap = [x for x in f if x.track_id == 3]
    assert len(gap) == 1 and gap[0].t == pytest.approx(1.0) and "gap of 5 steps (0.5 s) until t=1.5 s" in gap[0].message
    ego = [x for x in f if x.track_id == 0]
    assert len(ego) == 1 and "ego covers steps 0..39; expected 0..49" in ego[0].message
    assert "s1: track 3 t=1.0 s: completeness: gap" in str(gap[0])


def test_completeness_respects_a_slower_sampling_stride():
    k = np.r_[np.arange(0, 20, 2), np.arange(26, 40, 2)]  # every 2nd step, then a 6-step hole
    f = curation.check_completeness(scen([clean_ego(), trk(3, line(-60, -50, len(k)), k=k)]))
    assert len(f) == 1 and f[0].t == pytest.approx(1.9) and "gap of 7 steps" in f[0].message


def test_completeness_invisible_ego():
    vis = np.ones(N, bool)
    vis[7] = False
    f = curation.check_completeness(scen([trk(0, line(-30, 0, N), visible=vis)]))
    assert len(f) == 1 and f[0].t == pytest.approx(0.7) and "not visible at 1 steps" in f[0].message


def test_plausibility_teleport_is_a_speed_and_acceleration_finding():
    xy = line(-30, 0, N)
    xy[25:] += [40.0, 0.0]  # an identity switch: 40 m jump between two samples
    f = curation.check_plausibility(scen([clean_ego(), trk(4, xy)]))
    assert {x.track_id for x in f} == {4}
    speed = [x for x in f if "speed" in x.message]
    assert len(speed) == 1 and speed[0].t == pytest.approx(2.4) and "car speed 206.1 m/s > 45 m/s for 2 steps" in speed[0].message  # (40 + 2 * 30/49) / 0.2
    assert any("acceleration" in x.message for x in f)


def test_plausibility_bounds_are_per_category():
    walk = trk(5, line(0, 7 * (N - 1) * DT, N, y=10.0), cat="pedestrian")  # 7 m/s: too fast on foot
    drive = trk(6, line(0, 7 * (N - 1) * DT, N, y=20.0), cat="car")      # 7 m/s: fine for a car
    f = curation.check_plausibility(scen([clean_ego(), walk, drive]))
    assert [x.track_id for x in f] == [5] and "pedestrian speed 7.0 m/s > 6 m/s" in f[0].message


def test_plausibility_yaw_rate_only_when_moving_and_not_for_pedestrians():
    spin = np.arange(N) * 0.5  # 5 rad/s
    moving = trk(7, line(-60, -30, N), yaw=spin)
    standing = trk(8, np.tile([[50.0, 9.0]], (N, 1)), yaw=spin)
    walker = trk(9, line(0, 5, N, y=12.0), cat="pedestrian", yaw=spin)
    f = curation.check_plausibility(scen([clean_ego(), moving, standing, walker]))
    assert [x.track_id for x in f] == [7] and "yaw rate 5.0 rad/s > 1.5 rad/s" in f[0].message


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 30.0), st.floats(-3.0, 3.0))
def test_kinematics_of_constant_acceleration(v0, a):
    """Property: the speed/acceleration stencils are exact for 1-D constant acceleration (while moving forward)."""
    t = np.arange(N) * DT
    if v0 + a * t[-1] < 0.5:
        return
    x = v0 * t + 0.5 * a * t * t
    tt, v, acc, _ = curation.track_kinematics(trk(0, np.stack([x, np.zeros(N)], 1)), DT)
    np.testing.assert_allclose(tt, t)
    ok = ~np.isnan(v)
    np.testing.assert_allclose(v[ok], (v0 + a * t)[ok], atol=1e-9)
    ok = ~np.isnan(acc)
    assert ok.sum() > 0
    np.testing.assert_allclose(acc[ok], a, atol=1e-7)


def test_route_too_short_and_off_lane():
    f = curation.check_route(scen([trk(0, line(-10, 0, N))]), lane_map())
    assert len(f) == 1 and "route is 10.0 m long; expected >= 20 m" in f[0].message
    # 60 m route: the middle 20 m swing 5 m off the lane centre (width 3.5: off beyond 2.25 m)
    xy = line(-30, 30, N)
    xy[15:35, 1] = 5.0
    f = curation.check_route(scen([trk(0, xy)]), lane_map())
    assert len(f) == 1 and f[0].check == "route" and "leaves the lanes" in f[0].message
    assert f[0].t == pytest.approx(1.5, abs=0.2)
    # the wrong way down the lane is off lane too (direction > 120 deg from the lane's)
    f = curation.check_route(scen([trk(0, line(30, -30, N))]), lane_map())
    assert len(f) == 1 and "from 0 m to 60 m" in f[0].message
    assert curation.route_problems(scen([trk(0, line(30, -30, N))]).route, lane_map())


def test_route_lane_match_offsets():
    pts = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.2], [3.0, 2.3]])
    lane, off = curation.route_lane_match(pts, lane_map())
    assert lane.tolist() == [0, 0, 0, -1]  # 2.2 m <= 3.5 / 2 + 0.5, 2.3 m is not
    np.testing.assert_allclose(off[:3], [0.0, 1.0, 2.2])
    assert math.isinf(off[3])


def test_overlap_of_the_ego_box():
    ego = clean_ego()
    ahead = trk(10, ego.xy + [3.0, 0.0])  # 3 m ahead: boxes 4.5 m long overlap
    beside = trk(11, ego.xy + [0.0, 2.5])  # 2.5 m to the side: 1.9 m wide boxes do not
    f = curation.check_overlaps(scen([ego, ahead, beside]))
    assert [(x.track_id, x.t) for x in f] == [(10, 0.0)]


def test_curate_suite_runs_over_every_scenario(tiny_suite):
    findings = curation.curate_suite(tiny_suite)
    assert all(f.scenario_id in {s.scenario_id for s in tiny_suite.scenarios} for f in findings)
    assert findings == curation.curate_suite(tiny_suite)  # deterministic


def test_fair_test_refuses_an_ego_that_barely_moves():
    standing = trk(0, np.tile([[5.0, 0.0]], (N, 1)) + np.random.default_rng(0).normal(0, 0.05, (N, 2)))  # jitter only
    s = scen([standing], route=build_route(standing))
    assert curation.ego_travel_m(s) < 1.0
    (why,) = curation.fair_test_problems(s)
    assert why.startswith("the logged ego travels 0.") and f">= {curation.MIN_EGO_TRAVEL_M:g} m" in why
    short = trk(0, line(0, curation.MIN_EGO_TRAVEL_M - 0.5, N))
    assert curation.fair_test_problems(scen([short], route=build_route(short)))
    ok = trk(0, line(0, curation.MIN_EGO_TRAVEL_M + 0.5, N))
    assert curation.ego_travel_m(scen([ok], route=build_route(ok))) == pytest.approx(curation.MIN_EGO_TRAVEL_M + 0.5)
    assert curation.fair_test_problems(scen([ok], route=build_route(ok))) == []


def test_importer_skips_an_unfair_window_with_the_reason():
    # 10 s log: the ego stands for 5 s, then drives 30 m; a 5 s window each.
    n = 100
    x = np.where(np.arange(n) < 50, 0.0, (np.arange(n) - 49) * 0.6)
    ego = trk(0, np.stack([x, np.zeros(n)], 1))
    skipped, notes = [], []
    out = windowed_scenarios("rec", lane_map(), [ego], 0, DT, n, ImportOptions(window_s=5.0), "rec.csv", skipped, notes)
    assert [s.scenario_id for s in out] == ["rec_w01"]
    (sk,) = skipped
    assert sk.source == "rec.csv window 0-5 s"
    assert sk.reason == ("not a fair closed-loop test (ego track 0): the logged ego travels 0.0 m; "
                         f"expected >= {curation.MIN_EGO_TRAVEL_M:g} m (a shorter route tests no driving)")
