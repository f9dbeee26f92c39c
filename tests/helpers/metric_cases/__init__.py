"""The worked metric cases the tests reproduce, from the verbatim subset of
``shared/reference/metric_cases.json`` kept in ``tests/data`` (so they run in
a plain clone; ``test_metric_cases`` checks the copy against the shared file
when it is present).

The modules of this package check one family of cases each through the
project's metric functions, mirroring ``drivee2e_jax/metrics``: each
``check_*`` / ``run_*`` takes a case dict of ``metric_cases.json`` and
asserts its expected values. ``tests/metrics/test_<module>.py`` runs them on
the subset, ``tests/metrics/test_metric_cases.py`` on the full shared file."""

from __future__ import annotations

import json
from pathlib import Path

SUBSET = Path(__file__).resolve().parents[2] / "data" / "metric_cases_subset.json"


def subset_case(case_id: str) -> dict:
    """One case by id (``LB-01``, ``BM-01`` ...)."""
    return {c["id"]: c for c in json.loads(SUBSET.read_text())["cases"]}[case_id]
