"""Host-side aggregation: B2D-01 merge and global statistics, LB-10 (when its
routes are available), and hand-built checks of every rule.

``check_b2d01_aggregation`` and ``check_lb10`` take case dicts and are shared
with ``test_metric_cases.py``.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from drivee2e_jax.metrics.aggregate import (
    DRIVEE2E_ABILITIES,
    RouteResult,
    b2d_efficiency,
    b2d_merge,
    drivee2e_ability,
    drivee2e_merge,
    lb_global,
    records_from_scores,
)
from drivee2e_jax.metrics.driving_score import ScoreConfig, outcome_from_events


def sibling(name: str):
    """Import a sibling test module by path (no package, no conftest needed)."""
    key = f"_drivee2e_metrics_tests_{name}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, Path(__file__).with_name(f"{name}.py"))
        mod = importlib.util.module_from_spec(spec)
        sys.modules[key] = mod
        spec.loader.exec_module(mod)
    return sys.modules[key]


def stack(scores):
    return jax.tree_util.tree_map(lambda *a: np.stack(a), *scores)


# ---------------------------------------------------------------------------
# B2D-01: merge and global statistics
# ---------------------------------------------------------------------------


def b2d01_records(case: dict) -> list[RouteResult]:
    ds = sibling("test_driving_score")
    scores = ds.check_b2d01_routes(case)
    routes = [r for r, _ in ds.b2d01_outcomes(case)]
    return records_from_scores(
        stack(scores),
        [r["route_id"] for r in routes],
        [r["route_length_m"] for r in routes],
        categories=[r["scenario_type"] for r in routes],
    )


def check_b2d01_aggregation(case: dict) -> None:
    exp, tol = case["expected"], case["tolerance"]["abs"]
    records = b2d01_records(case)
    merged = b2d_merge(records, planned_routes=case["input"]["benchmark_total_routes"])
    assert merged["driving score"] == pytest.approx(exp["driving_score"], abs=tol)
    assert merged["success rate"] == pytest.approx(exp["success_rate_fraction"], abs=tol)
    assert merged["success"] == exp["success_per_route"]
    per_km = lb_global(records, planned_routes=len(case["input"]["routes"]))["infractions"]
    want = exp["global_infractions_per_km_b2d_statistics_manager"]
    assert per_km.keys() == want.keys()
    for k, v in want.items():
        assert per_km[k] == pytest.approx(v, abs=tol), k


def test_b2d01_merge_and_global():
    check_b2d01_aggregation(sibling("test_driving_score").subset_case("B2D-01"))


def test_b2d_efficiency_on_b2d01():
    records = b2d01_records(sibling("test_driving_score").subset_case("B2D-01"))
    # Routes with min-speed entries: (120 + 95.5) / 2, 100, 60 (1500 ignored), 80.
    assert b2d_efficiency(records) == pytest.approx((107.75 + 100 + 60 + 80) / 4, abs=1e-12)
    bad = RouteResult("r", 1.0, 100, 1, 100, "Completed", {"min_speed_infractions": 1}, min_speed_pct=(1500.0,))
    with pytest.raises(ZeroDivisionError, match="exceeds 1000"):
        b2d_efficiency([bad])


# ---------------------------------------------------------------------------
# LB-10: global aggregation over LB-01 .. LB-09
# ---------------------------------------------------------------------------

LB10_ROUTES = [f"LB-0{i}" for i in range(1, 10)]


def lb_records(cases_by_id: dict, cfg: ScoreConfig) -> list[RouteResult]:
    ds = sibling("test_driving_score")
    records = []
    for cid in LB10_ROUTES:
        inp = cases_by_id[cid]["input"]
        s = ds.score64(outcome_from_events(inp["events"], route_timeout=inp["route_timeout"], checkpoints=4), cfg)
        records.extend(records_from_scores(stack([s]), [cid], [inp["route_length_m"]]))
    return records


def check_lb10(case: dict, cases_by_id: dict) -> None:
    missing = [c for c in LB10_ROUTES if c not in cases_by_id]
    if missing:
        pytest.skip(f"LB-10 aggregates LB-01..LB-09; {', '.join(missing)} not in metric_cases.json")
    exp, tol = case["expected"], case["tolerance"]["abs"]
    records = lb_records(cases_by_id, ScoreConfig.lb20())
    for planned in case["input"]["planned_total_routes"]:
        g, want = lb_global(records, planned), exp[f"planned_{planned}"]
        for k, v in want["scores_mean"].items():
            assert g["scores_mean"][k] == pytest.approx(v, abs=tol), (planned, k)
        for k, v in want["scores_std_dev"].items():
            assert g["scores_std_dev"][k] == pytest.approx(v, abs=1e-9), (planned, k)
        for k, v in want["infractions_per_km"].items():
            assert g["infractions"][k] == pytest.approx(v, abs=1e-9), (planned, k)
        if "status" in want:
            assert g["status"] == want["status"]
        if "total_length_m" in want:
            assert g["meta"]["total_length"] == pytest.approx(want["total_length_m"], abs=tol)
    v21 = case.get("variant_lb21_expected", {}).get("planned_9_scores_mean")
    if v21:
        g = lb_global(lb_records(cases_by_id, ScoreConfig.lb21()), 9)
        for k, v in v21.items():
            assert g["scores_mean"][k] == pytest.approx(v, abs=tol), k


# ---------------------------------------------------------------------------
# Hand-built LB 2.0 global statistics
# ---------------------------------------------------------------------------


def _two_routes():
    r1 = RouteResult("RouteScenario_1_rep0", 1000.0, 100.0, 1.0, 100.0, "Perfect")
    r2 = RouteResult(
        "RouteScenario_2_rep0", 500.0, 50.0, 0.6, 30.0, "Failed - Agent got blocked",
        {"collisions_vehicle": 1, "vehicle_blocked": 1, "outside_route_lanes": 1}, outside_lanes_m=25.0,
    )
    return [r1, r2]


def test_lb_global_means_std_per_km():
    g = lb_global(_two_routes(), planned_routes=3)  # one planned route missing: counts 0
    assert g["scores_mean"] == {"score_composed": 43.333333, "score_route": 50.0, "score_penalty": 0.533333}
    std_ds = math.sqrt(((100 - 43.333333) ** 2 + (30 - 43.333333) ** 2) / 2)
    assert g["scores_std_dev"]["score_composed"] == round(std_ds, 3) == 41.164
    assert g["scores_std_dev"]["score_route"] == round(math.sqrt((50**2 + 0**2) / 2), 3)
    assert g["km_driven"] == pytest.approx(1.25)
    assert g["infractions"]["collisions_vehicle"] == 0.8 and g["infractions"]["vehicle_blocked"] == 0.8
    assert g["infractions"]["outside_route_lanes"] == 0.025  # km off-lane, not per km
    assert g["infractions"]["red_light"] == 0.0
    assert g["status"] == "Failed"
    assert g["meta"]["exceptions"] == [("RouteScenario_2_rep0", "Failed - Agent got blocked")]
    assert g["meta"]["total_length"] == 1500.0


def test_lb_global_single_route_floor_and_status():
    r = RouteResult("x", 100.0, 0.0, 0.5, 0.0, "Failed", {"collisions_pedestrian": 1})
    g = lb_global([r], planned_routes=1)
    assert g["scores_std_dev"] == {"score_composed": 0, "score_route": 0, "score_penalty": 0}
    assert g["km_driven"] == 0.001 and g["infractions"]["collisions_pedestrian"] == 1000.0
    ok = [
        RouteResult("a", 10, 100, 1, 100, "Perfect"),
        RouteResult("b", 10, 100, 0.9, 90, "Completed", {"red_light": 1}),
    ]
    assert lb_global(ok, 2)["status"] == "Completed"
    assert lb_global(ok[:1], 2)["status"] == "Perfect"
    with pytest.raises(ValueError, match="planned_routes"):
        lb_global(ok, 0)


# ---------------------------------------------------------------------------
# DriveE2E merge and abilities
# ---------------------------------------------------------------------------


def _rec(cat, success, ds=100.0):
    if success:
        return RouteResult(f"{cat}", 50.0, 100.0, ds / 100, ds, "Completed", {"min_speed_infractions": 1}, category=cat)
    blocked = {"vehicle_blocked": 1}
    return RouteResult(f"{cat}", 50.0, 40.0, 1.0, 40.0, "Failed - Agent got blocked", blocked, category=cat)


def test_drivee2e_merge_and_ability():
    recs = [_rec("COV", True), _rec("COV", True, ds=60.0), _rec("UT", False), _rec("STR", True), _rec("XYZ", True)]
    m = drivee2e_merge(recs, route_nums=175)
    assert m["driving score"] == pytest.approx((100 + 60 + 40 + 100 + 100) / 175)
    assert m["success rate"] == pytest.approx(4 / 175 * 100) and m["success num"] == 4
    assert drivee2e_merge([], 175)["driving score"] == 0.0
    ab = drivee2e_ability(recs)
    assert ab["COV"] == pytest.approx(100 * 2 / 32) and ab["STR"] == pytest.approx(100 / 33)
    assert ab["UT"] == 0.0 and ab["IPC"] == 0
    assert ab["mean"] == pytest.approx(sum(ab[a] for a in DRIVEE2E_ABILITIES) / 8)
    own = drivee2e_ability(recs, counts={a: 2 for a in DRIVEE2E_ABILITIES})
    assert own["COV"] == 100.0


def test_records_from_scores_roundtrip():
    ds = sibling("test_driving_score")
    events = [
        [{"type": "ROUTE_COMPLETION", "route_completed": 100}, {"type": "MIN_SPEED_INFRACTION", "percentage": 80.0}],
        [{"type": "ROUTE_COMPLETION", "route_completed": 30.0}, {"type": "ROUTE_DEVIATION"},
         {"type": "OUTSIDE_ROUTE_LANES_INFRACTION", "percentage": 10.0, "distance": 12.3456}],
    ]
    scores = [ds.score64(outcome_from_events(e, checkpoints=4), ScoreConfig.lb20()) for e in events]
    recs = records_from_scores(stack(scores), ["a", "b"], [123.45678, 200.0], categories=["RT", "LFT"])
    assert recs[0].status == "Completed" and recs[0].success and recs[0].min_speed_pct == (80.0,)
    assert recs[0].route_length_m == 123.457 and recs[0].category == "RT"
    assert recs[1].status == "Failed - Agent deviated from the route" and not recs[1].success
    assert recs[1].infractions == {"outside_route_lanes": 1, "route_dev": 1}
    assert recs[1].outside_lanes_m == 12.346 and recs[1].num_infractions == 2
    with pytest.raises(ValueError, match="route ids"):
        records_from_scores(stack(scores), ["a"], [1.0])
