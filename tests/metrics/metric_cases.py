"""The worked metric cases the tests reproduce, from the verbatim subset of
``shared/reference/metric_cases.json`` kept beside this file (so they run in
a plain clone; ``test_metric_cases`` checks the copy against the shared file
when it is present)."""

from __future__ import annotations

import json
from pathlib import Path

SUBSET = Path(__file__).resolve().parent / "metric_cases_subset.json"


def subset_case(case_id: str) -> dict:
    """One case by id (``LB-01``, ``BM-01`` ...)."""
    return {c["id"]: c for c in json.loads(SUBSET.read_text())["cases"]}[case_id]
