"""The checkpoint-trend study on a 2-checkpoint tiny run."""

import csv
from pathlib import Path

from drivee2e_jax.train.trend import COLUMNS, run_trend

TINY = Path(__file__).resolve().parents[2] / "drivee2e_jax" / "scenario" / "examples" / "tiny"


def test_trend_writes_csv_and_plot(tiny_run, tmp_path):
    msgs = []
    rows = run_trend(tiny_run, tmp_path, suite=str(TINY), split="train", limit=1, print_fn=msgs.append)
    assert [r["epoch"] for r in rows] == [1, 2]
    with open(tmp_path / "trend.csv") as f:
        table = list(csv.DictReader(f))
    assert tuple(table[0]) == COLUMNS and len(table) == 2 and table[0]["num_scenarios"] == "1"
    for r in table:
        assert 0.0 <= float(r["driving_score"]) <= 100.0 and 0.0 <= float(r["success_rate"]) <= 100.0
        assert float(r["l2_2s"]) >= 0.0 and int(r["openloop_samples"]) > 0
    assert (tmp_path / "trend.png").stat().st_size > 1000
    # Resumable: a rerun reuses the rows.
    again = run_trend(tiny_run, tmp_path, suite=str(TINY), split="train", limit=1, print_fn=msgs.append)
    assert again == rows and sum("reused" in m for m in msgs) == 2


def test_a_policy_shorter_than_the_open_loop_horizon_gets_empty_open_loop_columns():
    from drivee2e_jax.models import base
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.train.trend import evaluate_checkpoint

    policy = base.policy_from_checkpoint("vector_mlp", None, "traj", num_waypoints=2)   # 1 s: a PPO actor's
    packed = load_suite(TINY).pack("train")
    row = evaluate_checkpoint(policy, None, packed, None, limit=1, seed=0)
    assert row["l2_1s"] is None and row["openloop_samples"] is None
    assert 0.0 <= row["driving_score"] <= 100.0 and row["num_scenarios"] == 1


def test_trend_refuses_an_out_folder_holding_other_files(tmp_path):
    import pytest

    from drivee2e_jax.errors import DriveE2EError

    out = tmp_path / "trend"
    out.mkdir()
    (out / "trend.csv").write_text("the user's table")
    (out / "draft.txt").write_text("the user's")
    with pytest.raises(DriveE2EError, match=rf"^{out}: holds files drivee2e did not write \(draft.txt\)"):
        run_trend(tmp_path / "no-run", out)
    assert (out / "trend.csv").read_text() == "the user's table"


def test_a_rerun_with_other_inputs_evaluates_again_instead_of_reusing(tiny_run, tmp_path):
    """Issue 39 (results never lie): a stored checkpoint row is reused only
    for the same inputs; another --limit, a retrained checkpoint or a row
    without recorded inputs is evaluated again and says why."""
    import json
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    out = tmp_path / "trend"
    msgs = []
    first = run_trend(run, out, suite=str(TINY), split="train", limit=1, print_fn=msgs.append)
    assert all(r["num_scenarios"] == 1 for r in first)
    msgs.clear()
    wider = run_trend(run, out, suite=str(TINY), split="train", limit=2, print_fn=msgs.append)
    assert all(r["num_scenarios"] == 2 for r in wider), wider  # before: the 1-scenario rows came back
    assert sum("evaluated again" in m and "limit" in m and "suite_sha256" in m for m in msgs) == 2, msgs
    # a checkpoint retrained in place: its files changed
    params = next(p for p in sorted((run / "checkpoints" / "2").rglob("*")) if p.is_file() and p.suffix != ".json")
    params.write_bytes(params.read_bytes() + b" ")
    msgs.clear()
    try:
        run_trend(run, out, suite=str(TINY), split="train", limit=2, print_fn=msgs.append)
    except Exception:  # noqa: BLE001 - the edited file may no longer load; what matters is it was not reused
        pass
    assert any(m.startswith("[epoch 2] evaluated again") and "checkpoint_sha256" in m for m in msgs), msgs
    assert any(m.startswith("[epoch 1] reused") for m in msgs), msgs
    # a row from before inputs were recorded
    row_file = out / "checkpoints" / "1.json"
    row = json.loads(row_file.read_text())
    del row["inputs"]
    row_file.write_text(json.dumps(row))
    msgs.clear()
    try:
        run_trend(run, out, suite=str(TINY), split="train", limit=2, print_fn=msgs.append)
    except Exception:  # noqa: BLE001 - epoch 2's edited checkpoint
        pass
    assert any(m.startswith("[epoch 1] evaluated again") and "records no inputs" in m for m in msgs), msgs
