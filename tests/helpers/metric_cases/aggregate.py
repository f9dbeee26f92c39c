"""Worked cases of host-side aggregation (``drivee2e_jax.metrics.aggregate``):
the B2D-01 merge and global statistics and LB-10 (over LB-01 .. LB-09), from
case dicts of ``metric_cases.json``."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from drivee2e_jax.metrics.aggregate import (
    RouteResult,
    b2d_merge,
    lb_global,
    records_from_scores,
)
from drivee2e_jax.metrics.driving_score import ScoreConfig, outcome_from_events
from tests.helpers.metric_cases import driving_score as driving_score_cases


def stack(scores):
    return jax.tree_util.tree_map(lambda *a: np.stack(a), *scores)


def b2d01_records(case: dict) -> list[RouteResult]:
    ds = driving_score_cases
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


LB10_ROUTES = [f"LB-0{i}" for i in range(1, 10)]


def lb_records(cases_by_id: dict, cfg: ScoreConfig) -> list[RouteResult]:
    ds = driving_score_cases
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
