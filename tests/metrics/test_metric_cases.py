"""Every worked case of ``shared/reference/metric_cases.json`` through the
project's own metric functions (the ones the simulator uses).

The shared folder sits beside the repository and is absent in a plain clone;
then this module is skipped and ``metric_cases_subset.json`` (a verbatim copy
of the reproduced cases, exercised by test_criteria / test_driving_score /
test_aggregate) keeps the core assertions running.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.helpers.metric_cases import aggregate as aggregate_cases
from tests.helpers.metric_cases import behavior as behavior_cases
from tests.helpers.metric_cases import comfort as comfort_cases
from tests.helpers.metric_cases import criteria as criteria_cases
from tests.helpers.metric_cases import driving_score as driving_score_cases
from tests.helpers.metric_cases import openloop as openloop_cases

CASES_PATH = Path(__file__).resolve().parents[2] / ".." / "shared" / "reference" / "metric_cases.json"
SUBSET_PATH = Path(__file__).resolve().parents[1] / "data" / "metric_cases_subset.json"

if not CASES_PATH.is_file():
    pytest.skip("../shared/reference not present (plain clone)", allow_module_level=True)

CASES = json.loads(CASES_PATH.read_text())["cases"]
BY_ID = {c["id"]: c for c in CASES}


def run_case(case: dict) -> None:
    family = case["family"]
    if family == "lb20_route_score":
        driving_score_cases.check_lb_route_case(case)
    elif family == "lb20_global_aggregation":
        aggregate_cases.check_lb10(case, BY_ID)
    elif family == "lb20_route_completion":
        criteria_cases.run_cr01(case)
    elif family == "min_speed_checkpoints":
        criteria_cases.run_cr02(case)
    elif family == "collision_dedup":
        criteria_cases.run_cr06(case)
    elif family == "b2d_route_score_and_merge":
        aggregate_cases.check_b2d01_aggregation(case)  # includes the per-route checks
    elif family == "b2d_comfort":
        comfort_cases.check_b2d03(case)
    elif family == "behavior_metrics":
        behavior_cases.check_bm01(case)
    elif family == "openloop_L2":
        openloop_cases.check_ol01(case)
    elif family == "openloop_collision_uniad":
        openloop_cases.check_ol04(case)
    else:
        pytest.fail(f"{case['id']}: no driver for case family {family!r}")


@pytest.mark.parametrize("case_id", list(BY_ID))
def test_metric_case(case_id):
    run_case(BY_ID[case_id])


def test_subset_is_a_verbatim_copy():
    """The plain-clone fixture must not drift from the shared cases."""
    subset = json.loads(SUBSET_PATH.read_text())["cases"]
    assert subset, "empty subset"
    for case in subset:
        assert case == BY_ID[case["id"]], case["id"]
