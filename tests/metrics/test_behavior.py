"""Behavior Metrics: BM-01 through ``bm_code_metrics``, BM's code quirks on
hand-built inputs, and the project's episode definitions on hand-built drives.

``check_bm01`` takes the case dict; it lives in
``tests/helpers/metric_cases/behavior.py``, shared with the case runner.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.metrics.behavior import (
    bm_code_metrics,
    bm_collision_class,
    bm_driving_score,
    bm_route_completion,
    distinct_events,
    episode_behavior,
    front_distance_buckets,
    front_time_shares,
    nearest_waypoints,
)
from tests.helpers.metric_cases import subset_case
from tests.helpers.metric_cases.behavior import assert_close, bm01_inputs, check_bm01

# ---------------------------------------------------------------------------
# BM-01
# ---------------------------------------------------------------------------


def test_bm01_shared_case():
    check_bm01(subset_case("BM-01"))


def test_bm01_numbers_by_hand():
    """BM-01's construction with the values derived from the definitions, so
    the reproduction is pinned even without the shared file."""
    case = {"input": {"vehicle_status": [{"throttle": 0.5, "steer": 0.0, "brake": 0.0},
                                         {"throttle": 0.5, "steer": 0.1, "brake": 0.0},
                                         {"throttle": 0.0, "steer": 0.1, "brake": 0.6},
                                         {"throttle": 0.3, "steer": -0.1, "brake": 0.0}],
                      "collision_events": [{"Time": 1.0}, {"Time": 1.05}, {"Time": 5.0}],
                      "lane_invasion_events": [{"Time": 2.0}, {"Time": 2.2}, {"Time": 3.0}, {"Time": 7.0}]}}
    got = bm_code_metrics(**bm01_inputs(case))
    mpd = (81 * 0.3 + 20 * 1.5) / 101
    want = {
        "completed_distance": 98 + 2 * math.sqrt(1 + 1.2**2),
        "average_speed": (50 * 36 + 50 * 28.8) / 101,
        "suddenness_distance_speed": (36 + 7.2) / 101,
        "suddenness_distance_control_commands":
            (0.5 + 0.1 + math.sqrt(0.25 + 0.36) + math.sqrt(0.09 + 0.04 + 0.36)) / 4,
        "collisions": 2, "lane_invasions": 3, "effective_completed_distance": 40.5,
        "position_deviation_mean": mpd, "position_deviation_mean_per_km": mpd / 0.0405,
        "collisions_per_km": 2 / 0.0405, "lane_invasions_per_km": 3 / 0.0405, "completed_laps": 0,
    }
    for key, w in want.items():
        assert_close(got[key], w, {"rel": 1e-9}, key)


# ---------------------------------------------------------------------------
# BM code quirks
# ---------------------------------------------------------------------------


def _line_inputs(n=11, **kw):
    """An x-axis road (waypoints every 0.5 m from x = 10) and poses 1 m apart."""
    x = 10 + np.arange(n, dtype=float)
    base = dict(map_waypoints_xy=np.stack([10 + 0.5 * np.arange(2 * n), np.zeros(2 * n)], 1),
                pose_xy=np.stack([x, np.full(n, 0.2)], 1), pose_time_s=0.1 * np.arange(n),
                speed_mps=np.full(n, 5.0), controls=[[0.2, 0.0, 0.0]])
    base.update(kw)
    return base


def test_axis_aligned_road_covers_only_the_first_waypoint():
    """Covered waypoints must differ in x AND y from the last one: on an
    axis-aligned road only the first is ever appended."""
    got = bm_code_metrics(**_line_inputs())
    assert got["effective_completed_distance"] == 0.5
    assert got["position_deviation_mean"] == pytest.approx(0.2)
    assert got["position_deviation_mean_per_km"] == pytest.approx(0.2 / 0.0005)


def test_deviation_ignores_poses_100m_away_and_nan_without_any():
    inp = _line_inputs()
    inp["pose_xy"] = inp["pose_xy"].copy()
    inp["pose_xy"][3, 1] = 100.0  # exactly 100 m from the road: excluded (strict <)
    got = bm_code_metrics(**inp)
    assert got["position_deviation_total_err"] == pytest.approx(10 * 0.2)
    assert got["position_deviation_mean"] == pytest.approx(0.2)
    far = bm_code_metrics(**_line_inputs(pose_xy=np.stack([np.arange(11.0), np.full(11, 500.0)], 1)))
    assert math.isnan(far["position_deviation_mean"]) and far["effective_completed_distance"] == 0
    assert math.isnan(far["position_deviation_mean_per_km"]) and far["collisions_per_km"] == 0


def test_collision_dedup_against_previous_event_and_origin():
    xy = np.stack([np.arange(11.0) * 0.4, np.zeros(11)], 1)  # starts at the origin, 0.4 m per pose
    inp = _line_inputs(pose_xy=xy, collision_time_s=[0.0, 0.3, 0.6, 0.7])
    # pose 0 is the origin (not > 1 m from (0, 0)); 0.3 -> pose 3 (1.2 m): counts;
    # 0.6 -> pose 6 (1.2 m from pose 3): counts; 0.7 -> pose 7 (0.4 m): no.
    assert bm_code_metrics(**inp)["collisions"] == 2
    np.testing.assert_array_equal(distinct_events(xy[[0, 3, 6, 7]]), [False, True, True, False])
    np.testing.assert_array_equal(distinct_events(xy[[0, 3, 6, 7]], first_ref_xy=None), [True, True, True, False])


def test_lane_invasions_need_distance_and_half_a_second():
    xy = np.stack([10 + np.arange(101.0) * 2.0, np.zeros(101)], 1)  # 2 m per pose, 0.1 s per pose
    inp = _line_inputs(n=101, pose_xy=xy, lane_invasion_time_s=[0.5, 0.6, 1.2, 1.71, 1.75])
    # 0.5: not > 0.5 s after t = 0; 0.6: 0.1 s after; 1.2: 0.6 s after 0.6 -> counts;
    # 1.71: 0.51 s after, 10 m away -> counts; 1.75 matches pose 17 like 1.71 (0 m away): no.
    assert bm_code_metrics(**inp)["lane_invasions"] == 2


def test_events_match_the_pose_with_the_nearest_timestamp_first_on_ties():
    t = np.array([0.0, 1.0, 2.0, 3.0])
    xy = np.array([[5.0, 0.0], [7.0, 0.0], [9.0, 0.0], [11.0, 0.0]])
    inp = _line_inputs(n=4, pose_xy=xy, pose_time_s=t, collision_time_s=[1.5, 1.5])
    # both match pose 1 (tie 1.0 / 2.0 -> first); the second is 0 m away -> not counted
    assert bm_code_metrics(**inp)["collisions"] == 1
    inp["collision_time_s"] = [1.5, 1.6]  # second -> pose 2, 2 m away
    assert bm_code_metrics(**inp)["collisions"] == 2


def test_completed_laps_skip_50_poses_then_count_returns_to_start():
    ang = np.linspace(0, 4 * np.pi, 161)  # two laps of a circle, 80 poses each
    xy = 20 * np.stack([np.cos(ang), np.sin(ang)], 1)
    n = len(xy)
    got = bm_code_metrics(**_line_inputs(n=n, pose_xy=xy, pose_time_s=0.1 * np.arange(n)))
    assert got["completed_laps"] == 2
    short = bm_code_metrics(**_line_inputs(n=40, pose_xy=np.zeros((40, 2)), pose_time_s=0.1 * np.arange(40)))
    assert short["completed_laps"] == 0  # within the first 50 poses nothing counts


def test_speed_and_control_suddenness_start_from_rest():
    got = bm_code_metrics(**_line_inputs(speed_mps=[5.0, 5.0, 5.0, 5.0], controls=[[0.0, 0.2, 0.0], [0.0, 0.2, 0.0]]))
    assert got["suddenness_distance_speed"] == pytest.approx(18.0 / 4)  # only 0 -> 18 km/h
    assert got["average_speed"] == pytest.approx(18.0) and got["max_speed"] == got["min_speed"]
    assert got["suddenness_distance_steer"] == pytest.approx(0.1)
    assert got["suddenness_distance_control_commands"] == pytest.approx(0.1)


def test_bm_front_vehicle_buckets_weight_ego_displacement():
    n = 5
    ego = np.stack([np.arange(n) * 2.0, np.zeros(n)], 1)
    front = ego + np.array([[0, 0], [30, 0], [18, 0], [10, 0], [3, 0]], dtype=float)
    got = bm_code_metrics(**_line_inputs(n=n, pose_xy=ego, pose_time_s=0.1 * np.arange(n), front_xy=front))
    for name in ("great", "medium", "short", "dangerous"):
        assert got[f"front_distance_m_{name}"] == pytest.approx(2.0)
        assert got[f"front_distance_pct_{name}"] == pytest.approx(25.0)


def test_nearest_waypoints_blocks_do_not_change_the_answer():
    rng = np.random.default_rng(3)
    pts, wps = rng.uniform(-50, 50, (37, 2)), rng.uniform(-50, 50, (53, 2))
    i1, d1 = nearest_waypoints(pts, wps)
    i2, d2 = nearest_waypoints(pts, wps, block_elems=60)
    np.testing.assert_array_equal(i1, i2)
    np.testing.assert_array_equal(d1, d2)
    np.testing.assert_allclose(d1, np.linalg.norm(pts[:, None] - wps[None], axis=-1).min(1))


def test_bm_code_metrics_rejects_bad_shapes():
    with pytest.raises(ValueError, match="pose_xy must have shape"):
        bm_code_metrics(**_line_inputs(pose_xy=np.zeros((11, 3))))
    with pytest.raises(ValueError, match="controls"):
        bm_code_metrics(**_line_inputs(controls=np.zeros((0, 3))))


# ---------------------------------------------------------------------------
# Project definitions on simulated episodes
# ---------------------------------------------------------------------------


def straight_drive(n=50, speed=10.0, dt=0.1, offset=0.0, front=np.inf):
    x = speed * dt * np.arange(n)
    return dict(xy=np.stack([x, np.full(n, offset)], 1), speed_mps=np.full(n, speed), dt_s=dt,
                lane_offset_m=np.full(n, offset), front_distance_m=np.full(n, front),
                collision_steps=[], lane_invasion_steps=[], route_length_m=100.0, route_completion_pct=49.0)


def test_constant_speed_straight_drive_has_zero_jerk():
    ep = straight_drive()
    paper = episode_behavior(**ep)
    assert paper["longitudinal_jerk_mps"] == 0.0
    assert paper["average_speed_kmh"] == pytest.approx(36.0)
    assert paper["completed_distance_m"] == pytest.approx(49.0)
    code = episode_behavior(**ep, definition="code")
    # the code's |dv| starts from rest: the initial 36 km/h counts once
    assert code["suddenness_distance_speed_kmh"] == pytest.approx(36.0 / 50)
    assert code["max_speed_kmh"] == code["min_speed_kmh"] == pytest.approx(36.0)


def test_signed_jerk_telescopes_and_abs_jerk_does_not():
    ep = straight_drive(n=5)
    ep["speed_mps"] = np.array([10.0, 12.0, 10.0, 12.0, 10.0])
    paper = episode_behavior(**ep, definition="code")
    assert paper["longitudinal_jerk_mps"] == pytest.approx(0.0, abs=1e-12)
    assert paper["suddenness_distance_speed_kmh"] == pytest.approx((36 + 4 * 7.2) / 5)


def test_centreline_drive_has_zero_deviation_and_offset_is_unsigned():
    assert episode_behavior(**straight_drive())["position_deviation_mean_m"] == 0.0
    ep = straight_drive(n=4)
    ep["lane_offset_m"] = np.array([0.5, -0.5, 1.0, -1.0])
    got = episode_behavior(**ep, definition="code")
    assert got["position_deviation_mean_m"] == pytest.approx(0.75)
    assert got["position_deviation_total_err_m"] == pytest.approx(3.0)


def test_parked_car_10m_ahead_is_short_distance_all_the_time():
    ep = straight_drive(n=30, speed=0.0, front=10.0)
    got = episode_behavior(**ep, definition="code")
    assert got["front_time_pct_short"] == 100.0
    assert got["front_time_pct_great"] == got["front_time_pct_medium"] == got["front_time_pct_dangerous"] == 0.0
    # the code weights by distance driven: a stopped ego counts nothing
    assert got["front_distance_m_total"] == 0.0 and got["front_distance_pct_short"] == 0.0
    moving = episode_behavior(**straight_drive(n=30, front=10.0), definition="code")
    assert moving["front_distance_pct_short"] == 100.0
    assert moving["front_distance_m_short"] == pytest.approx(29.0)


def test_front_bucket_boundaries():
    d = np.array([50.0, 49.999, 20.0, 20.001, 15.0, 15.001, 6.0, 6.001, 0.0, -1.0, np.inf, 100.0])
    got = front_time_shares(d)
    n = len(d)
    assert got["front_time_pct_great"] == pytest.approx(100 * 2 / n)  # 49.999, 20.001
    assert got["front_time_pct_medium"] == pytest.approx(100 * 2 / n)  # 20, 15.001
    assert got["front_time_pct_short"] == pytest.approx(100 * 2 / n)  # 15, 6.001
    assert got["front_time_pct_dangerous"] == pytest.approx(100 * 3 / n)  # 6, 0, -1
    # distance-weighted: step i >= 1 weighs |p_i - p_{i-1}| = 1 m, by d_i
    xy = np.stack([np.arange(n, dtype=float), np.zeros(n)], 1)
    dist = front_distance_buckets(xy, d)
    assert dist["front_distance_m_great"] == 2.0 and dist["front_distance_m_medium"] == 2.0
    assert dist["front_distance_m_short"] == 2.0 and dist["front_distance_m_dangerous"] == 3.0
    assert dist["front_distance_m_total"] == 9.0  # d_0 = 50 is never weighed; inf, 100 not counted
    assert dist["front_distance_pct_dangerous"] == pytest.approx(100 * 3 / 9)


def test_per_km_normalisation_uses_route_progress():
    ep = straight_drive()
    ep.update(route_length_m=2000.0, route_completion_pct=50.0, collision_steps=[5, 30, 45],
              lane_invasion_steps=[10], lane_offset_m=np.full(50, 0.4))
    got = episode_behavior(**ep, definition="code")
    assert got["effective_completed_distance_m"] == pytest.approx(1000.0)
    assert got["collisions_per_km"] == pytest.approx(3.0)
    assert got["lane_invasions_per_km"] == pytest.approx(1.0)
    assert got["position_deviation_mean_per_km"] == pytest.approx(0.4)
    assert got["suddenness_distance_speed_per_km"] == pytest.approx(36.0 / 50)
    ep["route_completion_pct"] = 25.0
    half = episode_behavior(**ep, definition="code")
    assert half["collisions_per_km"] == pytest.approx(6.0)
    assert half["position_deviation_mean_per_km"] == pytest.approx(0.8)
    assert "position_deviation_mean_per_km" not in episode_behavior(**ep)  # paper: plain mean only


def test_per_km_zero_events_is_zero_and_events_without_distance_nan():
    ep = straight_drive()
    ep["route_completion_pct"] = 0.0
    got = episode_behavior(**ep)
    assert got["collisions_per_km"] == 0.0 and got["lane_invasions_per_km"] == 0.0
    ep["collision_steps"] = [3]
    assert math.isnan(episode_behavior(**ep)["collisions_per_km"])


def test_code_definition_deduplicates_events_as_bm():
    ep = straight_drive()  # 1 m per step, 0.1 s per step
    ep.update(collision_steps=[10, 11, 20], lane_invasion_steps=[0, 3, 9])
    paper = episode_behavior(**ep)
    code = episode_behavior(**ep, definition="code")
    assert paper["collisions"] == 3 and paper["lane_invasions"] == 3
    # collisions: step 11 is 1 m (not > 1 m) after step 10. Lane invasions: the
    # first always counts (not compared with t = 0 / the origin), step 3 is
    # only 0.3 s later, step 9 is 0.6 s and 6 m after step 3.
    assert code["collisions"] == 2 and code["lane_invasions"] == 2


def test_episode_behavior_rejects_bad_inputs():
    ep = straight_drive()
    with pytest.raises(ValueError, match="speed_mps must have shape"):
        episode_behavior(**{**ep, "speed_mps": np.zeros(3)})
    with pytest.raises(ValueError, match="collision_steps must index"):
        episode_behavior(**{**ep, "collision_steps": [50]})
    with pytest.raises(ValueError, match="definition"):
        episode_behavior(**ep, definition="codes")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0, 40), min_size=2, max_size=40),
       st.lists(st.one_of(st.floats(-5, 80), st.just(math.inf)), min_size=40, max_size=40))
def test_properties_signed_jerk_and_time_shares(speeds, fronts):
    n = len(speeds)
    ep = straight_drive(n=n)
    ep.update(speed_mps=np.array(speeds), front_distance_m=np.array(fronts[:n]))
    got = episode_behavior(**ep)
    assert got["longitudinal_jerk_mps"] == pytest.approx((speeds[-1] - speeds[0]) / (n - 1), abs=1e-9)
    share = sum(got[f"front_time_pct_{k}"] for k in ("great", "medium", "short", "dangerous"))
    assert share == pytest.approx(100.0 * np.mean(np.array(fronts[:n]) < 50))


# ---------------------------------------------------------------------------
# Route completion and driving score (controller_carla.py)
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(("eff_m", "length_m", "actor_types", "red", "code", "want_rc", "want_ds"), [
    # BM-01's effective distance (40.5 m) on a 100 m route; its two collisions a car and a pedestrian.
    (40.5, 100.0, ("vehicle.tesla.model3", "walker.pedestrian.0001"), 1, 3, 0.405, 0.059534999999999984),
    # A bicycle is a vehicle; static.* and traffic.* are "static"; termination 2 = wrong turn.
    (40.5, 100.0, ("vehicle.bh.crossbike", "static.prop.streetbarrier", "traffic.traffic_light"), 0, 2,
     0.405, 0.07186725000000001),
    # Success (code 1): no time-out factor; RC is not clipped at 1.
    (250.0, 200.0, (), 2, 1, 1.25, 0.6124999999999999),
])
def test_bm_route_completion_and_driving_score_match_controller_carla(eff_m, length_m, actor_types, red, code,
                                                                      want_rc, want_ds):
    """Expected values by EXECUTING JdeRobot/BehaviorMetrics@a4bfa13
    ``utils/controller_carla.py`` ``ControllerCarla.stop_recording_metrics`` (ROS, CARLA and the
    bag reading stubbed: ``metrics_carla.get_metrics`` returned the effective distance and the
    collided actor ids, ``world.get_actor`` actors with the given ``type_id``). By hand, row 1:
    0.405 * 0.6 * 0.5 * 0.7 (red) * 0.7 (time out) = 0.059535."""
    rc = bm_route_completion(eff_m, length_m)
    classes = [bm_collision_class(t) for t in actor_types]
    ds = bm_driving_score(rc, collisions_vehicle=classes.count("vehicle"), collisions_static=classes.count("static"),
                          collisions_walker=classes.count("walker"), red_lights=red, termination_code=code)
    assert rc == pytest.approx(want_rc, rel=1e-12)
    assert ds == pytest.approx(want_ds, rel=1e-12)


def test_bm_driving_score_defaults_to_the_time_out_every_run_gets():
    assert bm_driving_score(1.0) == pytest.approx(0.7)
    assert bm_driving_score(1.0, termination_code=None) == 1.0
    assert math.isnan(bm_route_completion(10.0, 0.0))
