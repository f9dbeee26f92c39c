"""`drivee2e bench --shard-size N`: a suite folder streamed shard by shard
(or an in-memory suite cut in shards) writes the same per-scenario results as
the one-batch run, resumes, and refuses what it cannot combine with in one
line."""

from __future__ import annotations

import csv
import json

import pytest

from drivee2e_jax.cli import main
from drivee2e_jax.eval import bench as bench_mod
from tests.helpers.road3 import bench as _bench


def _rows(out):
    rows = list(csv.DictReader((out / "scenarios.csv").open()))
    for r in rows:
        r.pop("eval_time_s", None)  # timing.json holds it since issue 39 (a shard's time, not the split's)
    return rows


def _events(out):
    return {(r["policy"], r["scenario_id"]): r["events"] for r in json.loads((out / "scenarios.json").read_text())}


def test_streamed_folder_equals_the_one_batch_run_and_resumes(suite_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    assert _bench(suite_dir, tmp_path / "whole") == 0
    assert _bench(suite_dir, tmp_path / "streamed", "--shard-size", "2") == 0
    printed = capsys.readouterr().out
    assert "3 scenarios in shards of 2" in printed
    assert _rows(tmp_path / "streamed") == _rows(tmp_path / "whole")
    assert _events(tmp_path / "streamed") == _events(tmp_path / "whole")
    info = json.loads((tmp_path / "streamed" / "run.json").read_text())
    assert set(info["fingerprint"]) == {"suite_files_sha256", "drivee2e_version"}
    assert _bench(suite_dir, tmp_path / "streamed", "--shard-size", "2") == 0
    assert "already done" in capsys.readouterr().out
    # --limit ends inside a shard: the first two scenarios only
    assert _bench(suite_dir, tmp_path / "limited", "--shard-size", "2", "--limit", "2") == 0
    assert [r["scenario_id"] for r in _rows(tmp_path / "limited")][:2] == [r["scenario_id"] for r in
                                                                           _rows(tmp_path / "whole")][:2]
    assert len(_rows(tmp_path / "limited")) == 4


def test_in_memory_suite_cut_in_shards_equals_the_one_batch_run(suite_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(bench_mod, "_streams_folder", lambda cfg: False)  # as for a built-in suite
    assert _bench(suite_dir, tmp_path / "whole") == 0
    assert _bench(suite_dir, tmp_path / "cut", "--shard-size", "1") == 0
    assert _rows(tmp_path / "cut") == _rows(tmp_path / "whole")
    info = json.loads((tmp_path / "cut" / "run.json").read_text())
    assert set(info["fingerprint"]) == {"suite_sha256", "drivee2e_version"}


@pytest.mark.parametrize("args, needle", [
    (["--shard-size", "0"], "--shard-size must be >= 1, got 0"),
    (["--shard-size", "2", "--open-loop"], "does not combine with --open-loop"),
    (["--shard-size", "2", "--repetitions", "2"], "does not combine with --repetitions 2"),
    (["--shard-size", "2", "--task", "lane_following"], "--task lane_following filters the whole split"),
])
def test_streamed_bad_combinations_are_one_line(suite_dir, tmp_path, capsys, monkeypatch, args, needle):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    rc = main(["bench", "--suite", str(suite_dir), "--out", str(tmp_path / "o"), "--no-progress", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and needle in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "o").exists()
