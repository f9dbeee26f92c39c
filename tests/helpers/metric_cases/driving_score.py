"""Worked cases of per-route scoring (``drivee2e_jax.metrics.driving_score``):
LB-01/02/04 and the per-route part of B2D-01, from a case dict of
``metric_cases.json`` through ``outcome_from_events`` and ``route_score``."""

from __future__ import annotations

import re

import jax
import numpy as np
import pytest

from drivee2e_jax.metrics.driving_score import (
    INFRACTION_KEYS,
    RouteOutcome,
    ScoreConfig,
    outcome_from_events,
    route_score,
    status_name,
)


def score64(outcome: RouteOutcome, cfg: ScoreConfig):
    """``route_score`` in float64 (the reference-exact path)."""
    with jax.enable_x64(True):
        s = route_score(outcome, cfg)
        return jax.tree_util.tree_map(np.asarray, s)


def counts_dict(score) -> dict:
    return {k: int(n) for k, n in zip(INFRACTION_KEYS, np.asarray(score.infractions)) if int(n)}


def check_lb_route_case(case: dict) -> None:
    """An ``lb20_route_score`` case: events -> RouteOutcome -> route_score."""
    inp, exp, tol = case["input"], case["expected"], case["tolerance"]["abs"]
    outcome = outcome_from_events(inp["events"], route_timeout=inp["route_timeout"], checkpoints=4)
    s = score64(outcome, ScoreConfig.lb20())
    assert float(s.route_completion) == pytest.approx(exp["RC"], abs=tol)
    assert float(s.infraction_penalty) == pytest.approx(exp["IS"], abs=tol)
    assert float(s.driving_score) == pytest.approx(exp["DS"], abs=tol)
    assert status_name(s.status) == exp["status"]
    assert int(s.num_infractions) == exp["num_infractions"]
    assert counts_dict(s) == exp["infraction_counts"]
    if "variant_lb21_expected" in case:
        v = case["variant_lb21_expected"]
        s21 = score64(outcome, ScoreConfig.lb21())
        assert float(s21.infraction_penalty) == pytest.approx(v["IS"], abs=tol)
        assert float(s21.driving_score) == pytest.approx(v["DS"], abs=tol)
        assert status_name(s21.status) == v["status"]


_B2D_SIMPLE = {"COLLISION_VEHICLE", "COLLISION_PEDESTRIAN", "COLLISION_STATIC", "TRAFFIC_LIGHT_INFRACTION",
               "STOP_INFRACTION", "VEHICLE_BLOCKED", "ROUTE_DEVIATION", "YIELD_TO_EMERGENCY_VEHICLE",
               "SCENARIO_TIMEOUT"}


def parse_b2d_event(text: str) -> dict:
    """Case notation -> event dict: "RC 70.0", "MIN_SPEED 95.5",
    "OUTSIDE_ROUTE_LANES 5.0 % (25 m)", or a bare TrafficEventType name."""
    if text.startswith("RC "):
        return {"type": "ROUTE_COMPLETION", "route_completed": float(text.split()[1])}
    if text.startswith("MIN_SPEED "):
        return {"type": "MIN_SPEED_INFRACTION", "percentage": float(text.split()[1])}
    m = re.fullmatch(r"OUTSIDE_ROUTE_LANES ([\d.]+) % \(([\d.]+) m\)", text)
    if m:
        return {"type": "OUTSIDE_ROUTE_LANES_INFRACTION", "percentage": float(m[1]), "distance": float(m[2])}
    if text in _B2D_SIMPLE:
        return {"type": text}
    raise ValueError(f"unknown B2D-01 event notation {text!r}")


def b2d01_outcomes(case: dict) -> list[tuple[dict, RouteOutcome]]:
    """(route dict, RouteOutcome) for every B2D-01 route that produced a record."""
    out = []
    for r in case["input"]["routes"]:
        if r.get("crashed"):
            continue
        events = [parse_b2d_event(e) for e in r["events"]]
        out.append((r, outcome_from_events(events, checkpoints=20)))
    return out


def check_b2d01_routes(case: dict) -> list:
    """Per-route DS / IS / status / success of B2D-01 with the b2d preset;
    returns the float64 scores (route order) for the aggregation checks."""
    exp, tol = case["expected"], case["tolerance"]["abs"]
    scores = [score64(o, ScoreConfig.b2d()) for _, o in b2d01_outcomes(case)]
    assert len(scores) == len(exp["per_route"])
    for s, want, ok in zip(scores, exp["per_route"], exp["success_per_route"]):
        assert float(s.driving_score) == pytest.approx(want["DS"], abs=tol)
        assert float(s.infraction_penalty) == pytest.approx(want["IS"], abs=tol)
        assert status_name(s.status) == want["status"]
        assert bool(s.success) == ok
    return scores
