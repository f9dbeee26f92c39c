"""At-fault collision attribution through whole episodes (``metrics.episode``).

The packaged ``tiny`` suite under ``log_replay``: in ``s_straight`` a pedestrian
walks into the side of the logged ego (``active_lateral``, the ego in its own
lane: not at fault by nuPlan's ``classify_at_fault_collisions``,
nuplan/planning/metrics/evaluation_metrics/common/no_ego_at_fault_collisions.py).
Three evaluations (one compile each), and one of ``expert``, are shared by the
module.
"""

from __future__ import annotations

import dataclasses

import pytest

from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.metrics.driving_score import score_preset
from drivee2e_jax.policy import load_policy, resolve_policy_path
from drivee2e_jax.scenario.suite import load_suite
from drivee2e_jax.sim import SimConfig
from drivee2e_jax.types import COLLISION_TYPE_NAMES

COLLISION_EVENTS = ("collisions_pedestrian", "collisions_vehicle", "collisions_layout")
#: LB 2.0 pedestrian-collision coefficient (``driving_score.PENALTIES``).
PEDESTRIAN_PENALTY = 0.5


@pytest.fixture(scope="module")
def runs():
    suite = load_suite("tiny")
    policy = load_policy(resolve_policy_path("log_replay"))
    paper = score_preset("paper")
    cfgs = {"all": paper, "at_fault": dataclasses.replace(paper, collision_mode="at_fault"),
            "vru": dataclasses.replace(paper, vru_at_fault=True)}
    out = {k: evaluate(policy, suite, split=None, config=SimConfig(score=c)) for k, c in cfgs.items()}
    # The expert too (its at-fault DS is never below its DS; on tiny it drives into a pedestrian: at fault).
    out["expert"] = evaluate(load_policy(resolve_policy_path("expert")), suite, split=None,
                             config=SimConfig(score=paper))
    return out


def _rows(out):
    return {r["scenario_id"]: r for r in out.rows}


def _collisions(out):
    return [(sid, e) for sid, evs in out.events.items() for e in evs if e["type"] in COLLISION_EVENTS]


def test_pedestrian_side_contact_is_not_at_fault(runs):
    out = runs["all"]
    (sid, ev), = _collisions(out)
    assert sid == "s_straight" and ev["type"] == "collisions_pedestrian" and ev["other_category"] == "pedestrian"
    assert (ev["collision_type"], ev["at_fault"]) == ("active_lateral", False)
    row = _rows(out)["s_straight"]
    assert (row["collisions_pedestrian"], row["collisions_at_fault"]) == (1, 0)
    # Same route completion, one pedestrian penalty (x 0.5) only in the "all" view.
    assert row["driving_score_at_fault"] > row["driving_score_all"]
    assert row["driving_score_all"] == pytest.approx(PEDESTRIAN_PENALTY * row["driving_score_at_fault"], abs=1e-4)
    assert row["infraction_score_all"] == pytest.approx(PEDESTRIAN_PENALTY)
    assert row["infraction_score_at_fault"] == pytest.approx(1.0)


def test_at_fault_view_never_below_all_view(runs):
    for out in runs.values():
        for r in out.rows:
            assert r["driving_score_at_fault"] >= r["driving_score_all"], r["scenario_id"]
            assert r["infraction_score_at_fault"] >= r["infraction_score_all"], r["scenario_id"]
            assert r["success_at_fault"] or not r["success_all"], r["scenario_id"]


def test_collision_mode_picks_the_headline(runs):
    for r in runs["all"].rows:  # the paper's protocol: every collision counts
        assert (r["driving_score"], r["success"]) == (r["driving_score_all"], r["success_all"])
    for r in runs["at_fault"].rows:
        assert (r["driving_score"], r["success"]) == (r["driving_score_at_fault"], r["success_at_fault"])
    # Both views are the same numbers whichever is the headline; the event is still recorded.
    a, f = _rows(runs["all"]), _rows(runs["at_fault"])
    for sid in a:
        for k in ("driving_score_all", "driving_score_at_fault", "collisions_pedestrian"):
            assert a[sid][k] == f[sid][k], (sid, k)
    assert f["s_straight"]["driving_score"] > a["s_straight"]["driving_score"]


def test_every_collision_event_is_attributed(runs):
    for out in runs.values():
        for _, ev in _collisions(out):
            assert ev["collision_type"] in (*COLLISION_TYPE_NAMES, "static")
            assert isinstance(ev["at_fault"], bool)
            if ev["collision_type"] == "static":
                assert ev["at_fault"]  # a layout contact is always the ego's


def test_vru_at_fault_makes_the_pedestrian_contact_at_fault(runs):
    out = runs["vru"]
    (_, ev), = _collisions(out)
    assert (ev["collision_type"], ev["at_fault"]) == ("active_lateral", True)  # the type is unchanged
    row = _rows(out)["s_straight"]
    assert row["collisions_at_fault"] == 1
    assert row["driving_score_at_fault"] == row["driving_score_all"] == _rows(runs["all"])["s_straight"]["driving_score_all"]
