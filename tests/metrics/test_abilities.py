"""Bench2Drive multi-ability (``metrics.abilities``) against Bench2Drive's own
``tools/ability_benchmark.py``.

Two route sets: B2D-01 of ``metric_cases.json`` (its routes carry the 1 m
waypoint count and first junction waypoint the junction credit needs) and
``EDGE_ROUTES``, built to hit every rule (strict ``>`` of the junction test,
stop-sign and red-light vetoes, a type in two abilities, a crashed route).

Expected values were obtained by EXECUTING the reference code on the same
records: 0.0.4 = the verbatim copy in ``tests/data/third_party/bench2drive``,
run inside the test (``carla`` / the route planner replaced by stand-ins that
return the stated junction waypoint); 0.0.3 = Thinklab-SJTU/Bench2Drive@2645714
``tools/ability_benchmark.py`` (the file as of the v0.0.3 release c644989), run
once by hand with the same stand-ins plus a dummy CARLA client / server, its
``_ability.json`` copied into ``B2D01_V003`` / ``EDGE_V003``. Both agree with
the hand count in each test's comment.
"""

from __future__ import annotations

import json
import types
from pathlib import Path

import numpy as np
import pytest

from drivee2e_jax.metrics.abilities import (
    ABILITY_NAMES,
    B2D_ABILITIES,
    BEHAVIOR_SCENARIO_TYPES,
    AbilityRoute,
    b2d_abilities,
    first_junction_index,
    passes_junction,
    route_from_result,
    routes_from_rows,
)
from drivee2e_jax.metrics.aggregate import RouteResult
from drivee2e_jax.metrics.driving_score import INFRACTION_KEYS
from drivee2e_jax.types import Command
from tests.helpers.b2d_tools import load_b2d_tool
from tests.helpers.metric_cases import subset_case
from tests.helpers.metric_cases.aggregate import b2d01_records

#: (route id, scenario type, status, infraction counts, RC %, waypoints, first junction index 0-based);
#: status None = crashed (no record).
EDGE_ROUTES = (
    ("4001", "VanillaSignalizedTurnEncounterGreenLight", "Perfect", {}, 100.0, 100, 40),
    ("4002", "SignalizedJunctionLeftTurn", "Failed - Agent deviated from the route", {"route_dev": 1}, 50.0, 100, 40),
    ("4003", "VanillaNonSignalizedTurnEncounterStopsign", "Completed", {"stop_infraction": 1}, 100.0, 100, 10),
    ("4004", "VehicleTurningRoutePedestrian", "Failed - Agent got blocked",
     {"collisions_pedestrian": 1, "vehicle_blocked": 1}, 49.0, 100, 40),
    ("4005", "Accident", "Completed", {"min_speed_infractions": 2}, 100.0, 100, 40),
    ("4006", "InvadingTurn", "Failed", {"collisions_vehicle": 1}, 30.0, 100, 40),
    ("4007", "OppositeVehicleRunningRedLight", "Completed", {"red_light": 1}, 100.0, 120, 30),
    ("4008", "ParkedObstacle", None, {}, 0.0, 100, 40),
)
#: 0.0.3's ``_ability.json`` for EDGE_ROUTES and B2D-01 (executed, see the module docstring).
EDGE_V003 = {"Overtaking": 1.0, "Merging": 0.0, "Emergency_Brake": 0.0, "Give_Way": 0.0, "Traffic_Signs": 0.3,
             "mean": 0.26}
B2D01_V003 = {"Overtaking": 1.0, "Merging": 0.0, "Emergency_Brake": 0.0, "Give_Way": 0.0, "Traffic_Signs": 0.25,
              "mean": 0.25}


def edge_records() -> list[tuple[RouteResult | None, str, int, int]]:
    """(record or None, scenario type, waypoints, first junction index) per EDGE_ROUTES entry."""
    out = []
    for rid, typ, status, counts, rc, n, j in EDGE_ROUTES:
        rec = None if status is None else RouteResult(
            route_id=f"RouteScenario_{rid}_rep0", route_length_m=float(n), score_route=rc, score_penalty=1.0,
            score_composed=rc, status=status, infractions=counts, category=typ)
        out.append((rec, typ, n, j))
    return out


def b2d01_inputs() -> list[tuple[RouteResult | None, str, int | None, int | None]]:
    """B2D-01 through the project's route scoring, with the case's junction data."""
    case = subset_case("B2D-01")
    by_id = {r.route_id: r for r in b2d01_records(case)}
    out = []
    for route in case["input"]["routes"]:
        rec = None if route.get("crashed") else by_id[route["route_id"]]
        out.append((rec, route["scenario_type"], route.get("route_waypoints_1m"),
                    route.get("first_junction_waypoint_index_0based")))
    return out


def ours(inputs, version: str) -> dict:
    routes = [route_from_result(rec, j, n) for rec, _, n, j in inputs if rec is not None]
    return b2d_abilities(routes, version)


# ---------------------------------------------------------------------------
# Running Bench2Drive's tool on the same records
# ---------------------------------------------------------------------------


def b2d_record(rec: RouteResult) -> dict:
    """A results.json record as the leaderboard writes it (one message per infraction)."""
    return {"route_id": rec.route_id, "status": rec.status, "scores": {"score_route": rec.score_route},
            "infractions": {k: ["x"] * rec.count(k) for k in INFRACTION_KEYS}}


def write_inputs(folder: Path, inputs) -> tuple[Path, Path]:
    """Route XML and results.json for ``ability_benchmark.py``. Each route has two
    keypoints; the first carries (waypoints, junction index) for the stand-in planner."""
    xml = ["<routes>"]
    records = []
    for i, (rec, typ, n, j) in enumerate(inputs):
        rid = rec.route_id.split("_")[1] if rec is not None else f"9{i:03d}"
        xml.append(f'<route id="{rid}" town="Town01"><waypoints><position x="{n or 0}" y="{-1 if j is None else j}" '
                   f'z="0"/><position x="0" y="0" z="0"/></waypoints><scenarios><scenario type="{typ}"/>'
                   "</scenarios></route>")
        if rec is not None:
            records.append(b2d_record(rec))
    xml.append("</routes>")
    route_file, result_file = folder / "routes.xml", folder / "results.json"
    route_file.write_text("\n".join(xml))
    result_file.write_text(json.dumps({"_checkpoint": {"records": records}}))
    return route_file, result_file


class StandInPlanner:
    """``GlobalRoutePlanner`` stand-in: from keypoint (n, j) it traces n waypoints, the j-th in a junction."""

    def __init__(self, *_args):
        pass

    def trace_route(self, a, _b):
        n, j = int(a[0]), int(a[1])
        return [(types.SimpleNamespace(is_junction=i == j), None) for i in range(n)]


def load_b2d_004(monkeypatch):
    """The vendored (0.0.4) ``ability_benchmark`` module, imported with the stand-ins."""
    return load_b2d_tool("ability_benchmark", monkeypatch, planner=StandInPlanner)


def run_b2d_004(tmp_path: Path, monkeypatch, inputs) -> dict:
    """The vendored (0.0.4) ``ability_benchmark.main`` on ``inputs``; its ``_ability.json``."""
    mod = load_b2d_004(monkeypatch)
    monkeypatch.setattr(mod, "load_offline_map", lambda town, root: object())
    route_file, result_file = write_inputs(tmp_path, inputs)
    mod.main(types.SimpleNamespace(file=str(route_file), result_file=str(result_file)))
    out = json.loads((tmp_path / "results_ability.json").read_text())
    out.pop("crashed")
    return out


# ---------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------


def test_table_is_bench2drives(monkeypatch):
    assert ABILITY_NAMES == ("Overtaking", "Merging", "Emergency_Brake", "Give_Way", "Traffic_Signs")
    assert {k: list(v) for k, v in B2D_ABILITIES.items()} == load_b2d_004(monkeypatch).Ability
    assert set(BEHAVIOR_SCENARIO_TYPES.values()) <= set().union(*B2D_ABILITIES.values())


def test_b2d01_v004_matches_bench2drive(tmp_path, monkeypatch):
    """Hand count: Overtaking 3001 1/1; Merging 3003 0/1; Emergency_Brake 3002 0/1; Give_Way 3005 0/1;
    Traffic_Signs 3003, 3004 fail, 3003 passes the junction (0.70 > (101 + 8) / 200, no red light) -> 1/2;
    3006 crashed, skipped. Mean 1.5 / 5."""
    inputs = b2d01_inputs()
    want = {"Overtaking": 1.0, "Merging": 0.0, "Emergency_Brake": 0.0, "Give_Way": 0.0, "Traffic_Signs": 0.5,
            "mean": 0.3}
    got = ours(inputs, "0.0.4")
    assert got == pytest.approx(want, abs=1e-12)
    assert got == pytest.approx(run_b2d_004(tmp_path, monkeypatch, inputs), abs=1e-12)


def test_b2d01_v003_matches_bench2drive():
    """0.0.3 judges 3003 (passes) and 3004 (red light) again: Traffic_Signs (0 + 1) / (2 + 2)."""
    assert ours(b2d01_inputs(), "0.0.3") == pytest.approx(B2D01_V003, abs=1e-12)


def test_edge_routes_v004_matches_bench2drive(tmp_path, monkeypatch):
    """Traffic_Signs routes 4001 (success), 4002 (fails, 0.50 > (41 + 8) / 100: credit), 4003 (stop sign),
    4004 (0.49 is not > 0.49), 4007 (red light) -> 2/5; 4004 and 4007 are Emergency_Brake too (0/2);
    4005 succeeds with min-speed entries (Overtaking 1/1); 4008 crashed. Mean (1 + 0.4) / 5."""
    inputs = edge_records()
    want = {"Overtaking": 1.0, "Merging": 0.0, "Emergency_Brake": 0.0, "Give_Way": 0.0, "Traffic_Signs": 0.4,
            "mean": 0.28}
    got = ours(inputs, "0.0.4")
    assert got == pytest.approx(want, abs=1e-12)
    assert got == pytest.approx(run_b2d_004(tmp_path, monkeypatch, inputs), abs=1e-12)


def test_edge_routes_v003_matches_bench2drive():
    """0.0.3: the five Traffic_Signs routes are judged again (+5 routes); 4001 and 4002 pass -> (1 + 2) / 10."""
    assert ours(edge_records(), "0.0.3") == pytest.approx(EDGE_V003, abs=1e-12)


def test_junction_test_rules():
    r = AbilityRoute(("T_Junction",), False, route_completion_pct=50.0, first_junction_index=40, num_waypoints=100)
    assert passes_junction(r)
    assert not passes_junction(AbilityRoute(("T_Junction",), False, 49.0, 40, 100))  # 0.49 > 0.49 is false
    assert not passes_junction(AbilityRoute(("T_Junction",), False, 90.0, 40, 100, red_light_infractions=1))
    assert not passes_junction(AbilityRoute(("T_Junction",), False, 90.0, 40, 100, stop_infractions=1))
    with pytest.raises(ValueError, match="no junction waypoint"):
        passes_junction(AbilityRoute(("T_Junction",), False, 90.0, None, 100, route_id="r1"))
    assert not passes_junction(AbilityRoute(("T_Junction",), False, 90.0, None, 100), strict=False)


def test_empty_abilities_raise_or_are_skipped():
    routes = [AbilityRoute(("Accident",), True)]
    with pytest.raises(ZeroDivisionError, match="Merging"):
        b2d_abilities(routes)
    assert b2d_abilities(routes, skip_empty=True) == {"Overtaking": 1.0, "mean": 1.0}
    assert b2d_abilities([], skip_empty=True) == {}
    with pytest.raises(ValueError, match="version"):
        b2d_abilities(routes, "0.0.5", skip_empty=True)


def test_a_route_with_two_types_counts_once_per_ability():
    both = AbilityRoute(("Accident", "ParkedObstacle", "InvadingTurn"), True)
    got = b2d_abilities([both, AbilityRoute(("Accident",), False)], skip_empty=True, junction_credit=False)
    assert got["Overtaking"] == 0.5 and got["Give_Way"] == 1.0


def test_first_junction_index_on_packed_routes():
    lf, left, straight = int(Command.LANEFOLLOW), int(Command.LEFT), int(Command.STRAIGHT)
    cmd = np.array([[lf, lf, left, left, lf], [lf, straight, lf, lf, lf], [lf, lf, lf, lf, left]])
    valid = np.array([[1, 1, 1, 1, 1], [1, 1, 1, 1, 1], [1, 1, 1, 1, 0]], bool)
    assert first_junction_index(cmd, valid).tolist() == [2, 1, -1]


def test_routes_from_rows_maps_behaviour_groups():
    rows = [
        {"scenario_id": "a", "behavior": "STP", "success": False, "route_completion": 80.0, "red_light": 0,
         "route_junction_index": 30, "route_waypoints": 100},
        {"scenario_id": "b", "behavior": "COV", "success": True, "route_completion": 100.0, "red_light": 0},
        {"scenario_id": "c", "behavior": "XXX", "success": True, "route_completion": 100.0},
    ]
    a, b = routes_from_rows(rows)
    assert a.scenario_types == ("VanillaSignalizedTurnEncounterRedLight",) and a.first_junction_index == 30
    assert passes_junction(a)  # 0.8 > 39 / 100
    assert b.scenario_types == ("SignalizedJunctionLeftTurn",) and b.first_junction_index is None
