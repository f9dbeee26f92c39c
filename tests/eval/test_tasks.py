"""Behavior Metrics driving tasks: scenario filters, transforms, success rules."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.tasks import (
    LANE_DEVIATION_MAX_M,
    SPEED_BAND,
    TASKS,
    add_task_success,
    apply_task,
    get_task,
    logged_front_distance,
)
from drivee2e_jax.scenario.pack import pack
from drivee2e_jax.types import SignalState


@pytest.fixture
def packed(tiny_suite):
    return pack(tiny_suite.scenarios, tiny_suite.maps)


def _ids(p):
    return [m["scenario_id"] for m in p.meta.rows()]


def test_logged_front_distance_sees_the_motorcycle_ahead_not_the_truck_behind(packed):
    d = logged_front_distance(packed)
    ids = _ids(packed)
    tee = d[ids.index("s_val")]
    # Motorcycle 10 m ahead at t = 0, 1 m to the side, gaining 3 m/s on the ego.
    assert tee[0] == pytest.approx(np.hypot(10.0, 1.0), abs=1e-3)
    assert tee[10] == pytest.approx(np.hypot(13.0, 1.0), abs=1e-3)
    assert np.isinf(d[ids.index("s_straight")]).all()  # the truck is behind, the pedestrian is no vehicle


def test_driving_in_traffic_keeps_only_scenarios_with_a_vehicle_ahead(packed):
    sub = apply_task(get_task("driving_in_traffic"), packed)
    assert _ids(sub) == ["s_val"]


def test_lane_following_keeps_straight_routes_and_empties_the_roads(packed):
    sub = apply_task(get_task("lane_following"), packed)
    assert set(_ids(sub)) == {"s_straight", "s_test"}  # the left turn and the S-bend are out
    scn = sub.scenario
    valid = np.asarray(scn.tracks.valid)
    ego = np.asarray(scn.ego_index)
    for b in range(len(sub)):
        assert valid[b, ego[b]].any()
        assert not np.delete(valid[b], ego[b], axis=0).any()
    assert (np.asarray(scn.signals.state) == SignalState.UNKNOWN).all()
    # The input batch is not modified.
    assert np.asarray(packed.scenario.tracks.valid).sum() > valid.sum()


def test_route_navigation_is_every_scenario_unchanged(packed):
    assert apply_task(get_task("route_navigation"), packed) is packed


def test_success_rules_and_their_thresholds():
    base = {"success": True, "front_time_pct_dangerous": 0.0, "position_deviation_mean_m": 0.2,
            "average_speed_kmh": 45.0, "route_speed_limit_kmh": 50.0}
    rows = [dict(base), dict(base, front_time_pct_dangerous=1.5), dict(base, success=False),
            dict(base, position_deviation_mean_m=LANE_DEVIATION_MAX_M + 0.01),
            dict(base, average_speed_kmh=50.0 * SPEED_BAND[0] - 0.1),
            dict(base, average_speed_kmh=50.0 * SPEED_BAND[1] + 0.1),
            dict(base, position_deviation_mean_m=math.nan)]
    got = {}
    for name in TASKS:
        rs = [dict(r) for r in rows]
        add_task_success(get_task(name), rs)
        got[name] = [r["task_success"] for r in rs]
    assert got["route_navigation"] == [True, True, False, True, True, True, True]
    assert got["driving_in_traffic"] == [True, False, False, True, True, True, True]
    assert got["lane_following"] == [True, True, False, False, False, False, False]


def test_unknown_task_and_empty_selection_are_one_line_errors(packed):
    with pytest.raises(DriveE2EError, match="unknown task"):
        get_task("parking")
    only_left = packed.select([_ids(packed).index("s_left")])
    with pytest.raises(DriveE2EError, match="no scenario of this split qualifies"):
        apply_task(get_task("lane_following"), only_left)


def test_bench_with_a_task_writes_task_success_and_abilities(tiny_suite_dir, tmp_path):
    from drivee2e_jax.eval.bench import BenchConfig, run_bench
    from drivee2e_jax.policy import resolve_policy_path

    out = tmp_path / "run"
    cfg = BenchConfig(suite=str(tiny_suite_dir), split="train", policies=(str(resolve_policy_path("log_replay")),),
                      out=out, progress=False, task="lane_following", repetitions=2)
    printed = []
    summary = run_bench(cfg, print_fn=printed.append)
    rows = json.loads((out / "scenarios.json").read_text())
    assert {r["scenario_id"] for r in rows} == {"s_straight"}  # train split, straight routes only
    assert sorted(r["repetition"] for r in rows) == [0, 1]
    assert all("task_success" in r and "route_speed_limit_kmh" in r for r in rows)
    o = summary["policies"]["log_replay"]["overall"]
    # Traffic_Signs = SR plus B2D 0.0.4's junction credit (failed routes that got past their junction).
    assert "task_success_rate" in o and o["abilities_junction_credit"]
    assert 100 * o["abilities"]["Traffic_Signs"] >= o["success_rate"]
    assert any("task lane_following" in line for line in printed)


def test_ability_scores_pool_the_behaviour_groups_of_each_ability():
    from drivee2e_jax.eval.summary import ability_scores

    rows = [{"behavior": b, "success": s} for b, s in
            (("COV", True), ("LFT", False), ("RT", True), ("IPC", True), ("STP", False), ("UT", True))]
    ab = ability_scores(rows)  # fractions, B2D's ability table through the group -> scenario-type map
    assert ab["Merging"] == 1.0 and ab["Emergency_Brake"] == 1.0  # COV; IPC
    assert ab["Traffic_Signs"] == pytest.approx(4 / 6)  # every group, no junction data -> no credit
    assert "Overtaking" not in ab and "Give_Way" not in ab
    assert ab["mean"] == pytest.approx((1 + 1 + 4 / 6) / 3)
    assert ability_scores([{"behavior": "XXX", "success": True}]) == {}
