"""Several processes (``jax.distributed`` on loopback) give the same per-scenario
results as one process; the scenario split over processes is contiguous and balanced."""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval import distributed


@settings(deadline=None, max_examples=50)
@given(n=st.integers(0, 200), count=st.integers(1, 17))
def test_process_shard_is_contiguous_balanced_and_covers_once(n, count):
    parts = [distributed.process_shard(n, i, count) for i in range(count)]
    assert [i for p in parts for i in p] == list(range(n))  # every scenario once, in order
    sizes = [len(p) for p in parts]
    assert max(sizes) - min(sizes) <= 1
    assert sizes == sorted(sizes, reverse=True)  # the larger parts come first


def test_process_shard_rejects_a_bad_process():
    with pytest.raises(ValueError):
        distributed.process_shard(10, 2, 2)


def test_initialize_without_coordinator_is_one_process_and_checks_its_arguments(monkeypatch):
    for env in (distributed.ENV_COORDINATOR, distributed.ENV_NUM_PROCESSES, distributed.ENV_PROCESS_ID):
        monkeypatch.delenv(env, raising=False)
    assert distributed.initialize() is False
    with pytest.raises(DriveE2EError, match="--coordinator"):
        distributed.initialize(num_processes=2, process_id=0)
    monkeypatch.setenv(distributed.ENV_NUM_PROCESSES, "two")
    with pytest.raises(DriveE2EError, match="DRIVEE2E_NUM_PROCESSES"):
        distributed.initialize()
    monkeypatch.setenv(distributed.ENV_NUM_PROCESSES, "2")
    with pytest.raises(DriveE2EError, match="0..1"):
        distributed.initialize("127.0.0.1:1", process_id=5)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _bench(suite: Path, out: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "drivee2e_jax.cli", "bench", "--suite", str(suite), "--split", "train",
            "--policy", "log_replay", "--policy", "expert", "--out", str(out), "--no-progress", *extra]


def _comparable(policy_file: Path) -> dict:
    data = json.loads(policy_file.read_text())
    return {"rows": [{k: v for k, v in r.items() if k != "eval_time_s"} for r in data["rows"]], "events": data["events"]}


def test_two_processes_on_loopback_match_one_process(tmp_path, tiny_suite, monkeypatch):
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.scenario.schema import write_suite

    # All four scenarios in one split, two per process: equal shapes, so process 1
    # reuses the programs process 0 wrote to the persistent compilation cache
    # (only process 0 writes it). Uneven parts: test_process_shard_*.
    tiny_suite.scenarios = [dataclasses.replace(s, split="train") for s in tiny_suite.scenarios]
    suite = write_suite(tiny_suite, tmp_path / "tiny")
    # The CLI enables the compile cache the session pinned in $DRIVEE2E_JAX_CACHE (conftest).
    env = dict(os.environ, JAX_PLATFORMS="cpu", DRIVEE2E_CACHE=str(tmp_path / "cache"))
    env.pop("XLA_FLAGS", None)
    env.pop(distributed.ENV_COORDINATOR, None)
    monkeypatch.setenv("DRIVEE2E_CACHE", env["DRIVEE2E_CACHE"])
    assert len(load_suite(suite).pack("train")) == 4  # packs the suite cache once, before the processes start

    coord = f"127.0.0.1:{_free_port()}"
    multi, single, other = tmp_path / "multi", tmp_path / "single", tmp_path / "process1"
    cmds = [
        _bench(suite, multi, "--coordinator", coord, "--num-processes", "2", "--process-id", "0"),
        _bench(suite, other, "--coordinator", coord, "--num-processes", "2", "--process-id", "1"),
        _bench(suite, single),
    ]
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for c in cmds]
    try:
        outs = [p.communicate(timeout=900) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    for p, (o, e) in zip(procs, outs):
        assert p.returncode == 0, (o + e)[-3000:]
    assert not other.exists()  # only process 0 writes
    assert "episodes" not in outs[1][0]  # and only process 0 prints
    for name in ("log_replay", "expert"):
        got, want = _comparable(multi / "policies" / f"{name}.json"), _comparable(single / "policies" / f"{name}.json")
        assert [r["scenario_id"] for r in want["rows"]] == ["s_straight", "s_left", "s_val", "s_test"]
        assert got == want
    assert (multi / "scenarios.csv").read_text().count("\n") == (single / "scenarios.csv").read_text().count("\n")
