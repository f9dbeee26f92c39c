"""Fine-grained per-episode columns from a StepLog (hand-built logs, numpy only)."""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
import pytest

from drivee2e_jax.metrics.finegrained import COLUMNS, episode_columns

DT = 0.1

# Pytrees shaped like ``sim.StepLog`` (the fields the columns read).
Log = namedtuple("Log", "xy yaw speed accel active facts events")
Facts = namedtuple("Facts", "lane_offset front_distance lane_invasion")
Events = namedtuple("Events", "collision")


def fake_log(t=60, speed=10.0, accel=None, offset=0.2, front=np.inf, invasions=(), collisions=(), active=None):
    x = speed * DT * np.arange(1, t + 1)
    return Log(
        xy=np.stack([x, np.zeros(t)], 1),
        yaw=np.zeros(t),
        speed=np.full(t, speed),
        accel=np.zeros(t) if accel is None else np.asarray(accel, float),
        active=np.ones(t, bool) if active is None else np.asarray(active),
        facts=Facts(
            lane_offset=np.broadcast_to(np.asarray(offset, float), (t,)).copy(),
            front_distance=np.broadcast_to(np.asarray(front, float), (t,)).copy(),
            lane_invasion=np.isin(np.arange(t), invasions),
        ),
        events=Events(collision=np.isin(np.arange(t), collisions)),
    )


def cols(log, **kw):
    kw = {"route_length_m": 100.0, "route_completion_pct": 60.0, "dt_s": DT, **kw}
    return episode_columns(log, **kw)


def test_every_column_and_a_clean_constant_speed_drive():
    c = cols(fake_log())
    assert set(c) == set(COLUMNS)
    assert c["jerk_lon_mean_mps3"] == 0.0 and c["longitudinal_jerk_mps"] == 0.0
    assert c["position_deviation_mean_m"] == pytest.approx(0.2)
    assert c["average_speed_kmh"] == pytest.approx(36.0)
    assert c["smoothness_pct"] == 100.0
    assert c["lane_invasions"] == 0 and c["collisions_per_km"] == 0.0
    assert math.isnan(c["efficiency_pct"])


def test_steps_without_an_aligned_lane_are_left_out_of_the_deviation():
    off = np.full(60, 0.4)
    off[:30] = np.inf
    assert cols(fake_log(offset=off))["position_deviation_mean_m"] == pytest.approx(0.4)
    assert math.isnan(cols(fake_log(offset=np.inf))["position_deviation_mean_m"])


def test_corner_crossings_of_one_lane_change_are_one_invasion():
    # Front corners cross at step 10, rear ones 5 steps later; a second change at 40.
    c = cols(fake_log(invasions=(10, 15, 40)))
    assert c["lane_invasions"] == 2
    assert c["lane_invasions_per_km"] == pytest.approx(2 / 0.06)


def test_jerk_is_the_mean_rate_of_change_of_acceleration():
    accel = np.where(np.arange(60) % 2 == 0, 1.0, -1.0)  # flips by 2 m/s^2 every 0.1 s
    assert cols(fake_log(accel=accel))["jerk_lon_mean_mps3"] == pytest.approx(20.0)


def test_only_active_steps_count_and_an_empty_episode_is_all_nan():
    active = np.arange(60) < 20
    c = cols(fake_log(front=10.0, active=active))
    assert c["front_time_pct_short"] == pytest.approx(100.0)
    assert c["completed_distance_m"] == pytest.approx(19 * 1.0)
    assert all(math.isnan(v) for v in cols(fake_log(active=np.zeros(60, bool))).values())


def test_efficiency_is_the_mean_checkpoint_ratio_ignoring_over_1000():
    assert cols(fake_log(), min_speed_pct=[80.0, 120.0, 5000.0])["efficiency_pct"] == pytest.approx(100.0)


def test_batched_smoothness_equals_the_per_episode_b2d_path():
    """Episodes of different active lengths (prefixes of T) in one batch give
    what B2D's per-route functions give on each episode's own frames."""
    from drivee2e_jax.metrics import comfort
    from drivee2e_jax.metrics.finegrained import smoothness_pct

    rng = np.random.default_rng(0)
    b, t = 7, 95
    yaw = np.cumsum(rng.normal(0, 0.02, (b, t)), axis=1) + 3.1  # crosses +-pi for some
    speed = np.clip(8 + np.cumsum(rng.normal(0, 0.15, (b, t)), axis=1), 0, None)
    speed[3, 40:50] += 6.0  # a harsh chunk
    n = np.array([95, 80, 61, 41, 20, 7, 2])
    got = smoothness_pct(yaw, speed, n, DT)
    for i in range(b):
        if n[i] < 3:
            assert math.isnan(got[i])
            continue
        f = comfort.b2d_frames_from_episode(np.zeros((n[i], 2)), yaw[i, : n[i]], speed[i, : n[i]], DT)
        want = 100 * comfort.b2d_route_smoothness(f["accel_xy"], f["forward_xy"], f["right_xy"], f["yaw_rate"])
        assert got[i] == pytest.approx(want), i
    assert got[3] < 100.0


def test_batch_columns_match_one_episode_at_a_time():
    from drivee2e_jax.metrics.finegrained import batch_columns

    logs = [fake_log(speed=s, offset=o, invasions=inv, active=np.arange(60) < n)
            for s, o, inv, n in ((10.0, 0.2, (), 60), (5.0, 0.5, (3, 30), 45), (12.0, 0.1, (50,), 12))]
    stacked = Log(*(np.stack(x) for x in zip(*[(lg.xy, lg.yaw, lg.speed, lg.accel, lg.active) for lg in logs])),
                  facts=Facts(*(np.stack(x) for x in zip(*[lg.facts for lg in logs]))),
                  events=Events(np.stack([lg.events.collision for lg in logs])))
    ms = np.array([[50.0, 80.0], [2000.0, 40.0], [0.0, 0.0]])
    mv = np.array([[True, True], [True, True], [False, False]])
    rows = batch_columns(stacked, route_length_m=np.array([100.0, 80.0, 50.0]),
                         route_completion_pct=np.array([60.0, 30.0, 10.0]), dt_s=DT,
                         min_speed_pct=ms, min_speed_valid=mv)
    for i, lg in enumerate(logs):
        one = episode_columns(lg, route_length_m=[100.0, 80.0, 50.0][i], route_completion_pct=[60.0, 30.0, 10.0][i],
                              dt_s=DT, min_speed_pct=ms[i][mv[i]])
        assert rows[i].keys() == one.keys()
        for k in one:
            assert rows[i][k] == pytest.approx(one[k], nan_ok=True), (i, k)
    assert rows[0]["efficiency_pct"] == pytest.approx(65.0)
    assert rows[1]["efficiency_pct"] == pytest.approx(40.0)  # > 1000 % ignored, as B2D
    assert math.isnan(rows[2]["efficiency_pct"])


def test_bm_score_columns_count_collisions_by_class_and_red_lights():
    """By hand: RC 60 % of 100 m -> effective 60 m -> BM RC 0.6; a vehicle and a pedestrian
    collision and one red light, with the time-out factor: 0.6 * 0.6 * 0.5 * 0.7 * 0.7.
    The "code" definition drops the pedestrian hit 0.5 m after the vehicle one (BM's 1 m rule)."""
    from drivee2e_jax.metrics.finegrained import BM_SCORE_COLUMNS
    from drivee2e_jax.types import CollisionClass

    base = fake_log(collisions=(10, 40))
    cls = np.full(60, -1)
    cls[10], cls[40] = int(CollisionClass.VEHICLE), int(CollisionClass.PEDESTRIAN)
    red = np.isin(np.arange(60), (20,))
    log = base._replace(events=namedtuple("Ev", "collision collision_class red_light")(
        base.events.collision, cls, red))
    c = cols(log, bm_scores=True)
    assert set(c) == set(COLUMNS) | set(BM_SCORE_COLUMNS)
    assert c["bm_route_completion"] == pytest.approx(0.6)
    assert c["bm_driving_score"] == pytest.approx(0.6 * 0.6 * 0.5 * 0.7 * 0.7)
    only_car = log._replace(events=log.events._replace(collision=np.isin(np.arange(60), (10,))))
    assert cols(only_car, bm_scores=True)["bm_driving_score"] == pytest.approx(0.6 * 0.6 * 0.7 * 0.7)
    near = log._replace(xy=np.where(np.arange(60)[:, None] == 40, log.xy[10] + [0.5, 0.0], log.xy))
    assert cols(near, bm_scores=True, definition="code")["bm_driving_score"] == pytest.approx(0.6 * 0.6 * 0.7 * 0.7)
    assert cols(near, bm_scores=True)["bm_driving_score"] == pytest.approx(0.6 * 0.6 * 0.5 * 0.7 * 0.7)
    assert "bm_driving_score" not in cols(base)  # opt-in: the default rows keep their columns
