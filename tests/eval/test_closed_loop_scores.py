"""The ``nuplan`` / ``navsim`` presets' columns in ``eval.closedloop.evaluate`` rows.

On the packaged ``tiny`` suite under ``log_replay``: every ``metrics.nuplan.COLUMNS``
/ ``metrics.navsim.COLUMNS`` column is present and in [0, 1], each headline
score is its sub-metrics combined as the references do, NAVSIM's human
filter makes the logged ego score EPDMS 1, and the ``paper`` preset adds none
of these columns. One evaluation (one compile) per preset, shared by the module.
"""

from __future__ import annotations

import math

import pytest

from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.metrics import navsim, nuplan
from drivee2e_jax.metrics.driving_score import score_preset
from drivee2e_jax.policy import load_policy, resolve_policy_path
from drivee2e_jax.scenario.suite import load_suite
from drivee2e_jax.sim import SimConfig


@pytest.fixture(scope="module")
def rows():
    suite = load_suite("tiny")
    policy = load_policy(resolve_policy_path("log_replay"))
    return {p: evaluate(policy, suite, split=None, config=SimConfig(score=score_preset(p))).rows
            for p in ("paper", "nuplan", "navsim")}


@pytest.mark.parametrize(("preset", "columns"), [("nuplan", nuplan.COLUMNS), ("navsim", navsim.COLUMNS)])
def test_preset_rows_carry_every_column_in_unit_range(rows, preset, columns):
    assert len(rows[preset]) == 4
    for r in rows[preset]:
        for c in columns:
            assert c in r, (r["scenario_id"], c)
            assert isinstance(r[c], float) and 0.0 <= r[c] <= 1.0, (r["scenario_id"], c, r[c])
        # The headline criteria stay the paper's (RC / DS comparable across presets).
        assert "driving_score" in r and "route_completion" in r


def test_nuplan_score_is_multipliers_times_weighted_average(rows):
    """nuPlan ``WeightedAverageMetricAggregator._compute_scenario_score``
    (nuplan/planning/metrics/aggregator/weighted_average_metric_aggregator.py): product of the
    multiplier metrics times the weighted mean (5 progress, 5 TTC, 4 speed limit, 2 comfort)."""
    assert dict(nuplan.WEIGHTS) == {
        "nuplan_ego_progress_along_expert_route": 5.0, "nuplan_time_to_collision_within_bound": 5.0,
        "nuplan_speed_limit_compliance": 4.0, "nuplan_ego_is_comfortable": 2.0}
    for r in rows["nuplan"]:
        mult = math.prod(r[c] for c in nuplan.MULTIPLIERS)
        avg = sum(w * r[c] for c, w in nuplan.WEIGHTS.items()) / 16.0
        assert r["nuplan_score"] == pytest.approx(mult * avg, abs=1e-5), r["scenario_id"]
    # log_replay is not at fault for the pedestrian walking into its side in s_straight.
    straight = {r["scenario_id"]: r for r in rows["nuplan"]}["s_straight"]
    assert straight["nuplan_no_ego_at_fault_collisions"] == 1.0


def test_navsim_epdms_formula_and_human_filter(rows):
    """EPDMS = NC * DAC * DDC * TLC * (5 EP + 5 TTC + 2 LK + 2 HC + 2 EC) / 16 (navsim
    pdm_scorer.py ``PDMScorerConfig``, run_pdm_score ``compute_final_scores``); the logged
    ego driven by ``log_replay`` is the human itself, so every column where it scores 0 counts 1
    (navsim/evaluate/pdm_score.py ``pdm_score_from_interpolated_trajectory``): EPDMS 1."""
    for r in rows["navsim"]:
        mult = math.prod(r[f"navsim_{c}"] for c in navsim.MULTIPLIERS)
        avg = sum(w * r[f"navsim_{c}"] for c, w in navsim.WEIGHTS.items()) / 16.0
        assert r["epdms"] == pytest.approx(mult * avg, abs=1e-5), r["scenario_id"]
        assert r["epdms"] == 1.0, r["scenario_id"]


def test_paper_rows_have_no_benchmark_columns(rows):
    extra = set(nuplan.COLUMNS) | set(navsim.COLUMNS)
    for r in rows["paper"]:
        assert not extra & r.keys(), r["scenario_id"]
    # ... while the other columns are the same set.
    assert set(rows["nuplan"][0]) - set(rows["paper"][0]) == set(nuplan.COLUMNS)
    assert set(rows["navsim"][0]) - set(rows["paper"][0]) == set(navsim.COLUMNS)
