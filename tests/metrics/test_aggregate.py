"""Host-side aggregation: B2D-01 merge and global statistics, LB-10 (when its
routes are available), and hand-built checks of every rule.

``check_b2d01_aggregation`` and ``check_lb10`` take case dicts; they live in
``tests/helpers/metric_cases/aggregate.py``, shared with ``test_metric_cases.py``.
"""

from __future__ import annotations

import math

import pytest

from drivee2e_jax.metrics.aggregate import (
    DRIVEE2E_ABILITIES,
    RouteResult,
    b2d_efficiency,
    drivee2e_ability,
    drivee2e_merge,
    lb_global,
    records_from_scores,
)
from drivee2e_jax.metrics.driving_score import ScoreConfig, outcome_from_events
from tests.helpers.metric_cases import driving_score as driving_score_cases
from tests.helpers.metric_cases import subset_case
from tests.helpers.metric_cases.aggregate import b2d01_records, check_b2d01_aggregation, stack

# ---------------------------------------------------------------------------
# B2D-01: merge and global statistics
# ---------------------------------------------------------------------------


def test_b2d01_merge_and_global():
    check_b2d01_aggregation(subset_case("B2D-01"))


def test_b2d_efficiency_on_b2d01():
    records = b2d01_records(subset_case("B2D-01"))
    # Routes with min-speed entries: (120 + 95.5) / 2, 100, 60 (1500 ignored), 80.
    assert b2d_efficiency(records) == pytest.approx((107.75 + 100 + 60 + 80) / 4, abs=1e-12)
    bad = RouteResult("r", 1.0, 100, 1, 100, "Completed", {"min_speed_infractions": 1}, min_speed_pct=(1500.0,))
    with pytest.raises(ZeroDivisionError, match="exceeds 1000"):
        b2d_efficiency([bad])


# ---------------------------------------------------------------------------
# LB-10: global aggregation over LB-01 .. LB-09
# ---------------------------------------------------------------------------

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
    ds = driving_score_cases
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
