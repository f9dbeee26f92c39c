"""evaluate_stream: a split evaluated shard by shard gives the rows and
events of one in-memory evaluate over the whole split (the same PRNG key per
scenario, the same compiled step), for every shard size, with the last shard
padded; rows can be consumed as they come; an empty source is one line."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.eval.stream import evaluate_stream, shards_of
from drivee2e_jax.metrics.driving_score import score_preset
from drivee2e_jax.policy import load_policy, resolve_policy_path
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.sim import SimConfig
from drivee2e_jax.testing import TINY_SUITE


@pytest.fixture(scope="module")
def packed():
    return load_suite(str(TINY_SUITE)).pack(None)


def _same_rows(a: list[dict], b: list[dict]) -> None:
    assert [r["scenario_id"] for r in a] == [r["scenario_id"] for r in b]
    for ra, rb in zip(a, b):
        assert ra.keys() == rb.keys()
        for k in ra:
            if k == "eval_time_s":  # the shard's time per scenario, not the split's
                continue
            va, vb = ra[k], rb[k]
            if isinstance(va, float) and isinstance(vb, float):
                assert va == pytest.approx(vb, rel=1e-6, abs=1e-9), (ra["scenario_id"], k)
            else:
                assert va == vb, (ra["scenario_id"], k, va, vb)


@pytest.mark.parametrize("size", [1, 3])
def test_stream_equals_in_memory(packed, size):
    pol = load_policy(resolve_policy_path("expert"))
    whole = evaluate(pol, packed, None, seed=3)
    got = evaluate_stream(pol, shards_of(packed, size), len(packed), seed=3)
    _same_rows(whole.rows, got.rows)
    assert got.events == whole.events
    assert got.logs is None and got.steps == whole.steps


def test_stream_under_a_preset_and_consumed_as_it_comes(packed):
    pol = load_policy(resolve_policy_path("expert"))
    cfg = SimConfig(score=score_preset("nuplan"))
    whole = evaluate(pol, packed, None, config=cfg)
    seen: list[list[dict]] = []
    events: dict = {}
    done: list[int] = []
    got = evaluate_stream(pol, shards_of(packed, 3), len(packed), config=cfg, keep_rows=False,
                          on_shard=lambda rows, ev: (seen.append(rows), events.update(ev)),
                          progress=lambda d, n: done.append(d))
    assert got.rows == [] and got.events == {}
    assert [[r["scenario_id"] for r in rows] for rows in seen] == [list(packed.meta.scenario_id[:3]),
                                                                   list(packed.meta.scenario_id[3:])]
    assert done == [3, len(packed)]
    assert "nuplan_score" in whole.rows[0]
    _same_rows(whole.rows, [r for rows in seen for r in rows])
    assert events == whole.events


def test_empty_source_and_bad_shard_size(packed):
    pol = load_policy(resolve_policy_path("stop"))
    with pytest.raises(DriveE2EError, match="no shards"):
        evaluate_stream(pol, iter(()), 0)
    with pytest.raises(DriveE2EError, match="shard size must be >= 1"):
        list(shards_of(packed, 0))
    with pytest.raises(DriveE2EError, match="row indices"):
        evaluate_stream(pol, [(np.arange(2), packed.select([0]))], len(packed))
