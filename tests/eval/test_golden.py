"""The reference policies' per-scenario results on twin15 val, against stored values.

``tests/data/golden_twin15_val.json.gz`` holds every row and infraction event
of ``drivee2e bench --split val --policy log_replay --policy expert --policy
stop --policy constant_velocity`` as recorded before the layer restructuring
(341d779). Refactors and speed work must reproduce them: the same statuses,
successes and events, float columns within 1e-6 relative (issue 22 allows
1e-4; nothing here should move at all).
"""

from __future__ import annotations

import gzip
import json
import math
from pathlib import Path

import pytest

from drivee2e_jax.eval.bench import BenchConfig, run_bench
from drivee2e_jax.policy import resolve_policy_path

GOLDEN = Path(__file__).resolve().parents[1] / "data" / "golden_twin15_val.json.gz"
POLICIES = ("log_replay", "expert", "stop", "constant_velocity")
#: Wall-clock columns: the only ones allowed to differ.
TIMING = {"eval_time_s"}


def _same(a, b) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or isinstance(a, str) or isinstance(b, str) or a is None or b is None:
        return a == b
    if isinstance(a, int) and isinstance(b, int):
        return a == b
    return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-9)


def _diff_row(want: dict, got: dict, new_columns_ok: bool = False) -> list[str]:
    """Differences of one stored record; with ``new_columns_ok`` a column the
    stored record lacks (a metric added since) is not one: every stored
    column must still be there with its stored value."""
    keys = (set(want) if new_columns_ok else set(want) | set(got)) - TIMING
    return [f"{k}: stored {want.get(k)!r}, now {got.get(k)!r}" for k in sorted(keys)
            if k not in want or k not in got or not _same(want[k], got[k])]


def _diff_events(want: list[dict], got: list[dict]) -> list[str]:
    if len(want) != len(got):
        return [f"{len(want)} events stored, {len(got)} now: {[e['type'] for e in got]}"]
    # Fields added to events since (a collision's type and fault) are allowed; every stored one must match.
    return [f"event {i}: {d}" for i, (w, g) in enumerate(zip(want, got)) for d in _diff_row(w, g, new_columns_ok=True)]


@pytest.mark.slow
def test_reference_policies_reproduce_the_stored_twin15_val_results(tmp_path):
    golden = json.loads(gzip.decompress(GOLDEN.read_bytes()))["policies"]
    out = tmp_path / "golden"
    cfg = BenchConfig(split="val", policies=tuple(str(resolve_policy_path(p)) for p in POLICIES), out=out,
                      progress=False)
    run_bench(cfg, print_fn=lambda _line: None)
    problems = []
    for name in POLICIES:
        got = json.loads((out / "policies" / f"{name}.json").read_text())
        want = golden[name]
        assert [r["scenario_id"] for r in got["rows"]] == [r["scenario_id"] for r in want["rows"]], name
        for w, g in zip(want["rows"], got["rows"]):
            problems += [f"{name} {w['scenario_id']} {d}" for d in _diff_row(w, g, new_columns_ok=True)]
        assert set(got["events"]) == set(want["events"]), name
        for sid, events in want["events"].items():
            problems += [f"{name} {sid} {d}" for d in _diff_events(events, got["events"][sid])]
    assert not problems, f"{len(problems)} differences, first: " + "; ".join(problems[:10])
