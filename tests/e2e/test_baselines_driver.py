"""experiments/baselines/run.py: table assembly from synthetic bench results,
training-state bookkeeping, commands and argument errors (no JAX work)."""

from __future__ import annotations

import csv
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "experiments" / "baselines" / "run.py"


def _load():
    spec = importlib.util.spec_from_file_location("baselines_run", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["baselines_run"] = mod
    spec.loader.exec_module(mod)
    return mod


run = _load()

GROUPS = ("COV", "IPC", "UT", "STP")


def _row(policy, i, behavior, ds, rc, is_, success, coll, length, eval_s, ol=None):
    """A per-scenario bench row; ``ol`` = (l2_1, l2_2, l2_3, coll_rate, samples) or None."""
    row = {
        "policy": policy, "scenario_id": f"s{i:03d}", "split": "val", "intersection_id": "i0",
        "behavior": behavior, "weather": "clear", "time_of_day": "day", "route_length_m": length,
        "route_completion": rc, "infraction_score": is_, "driving_score": ds, "success": success,
        # success in the source's sense: Completed and no infraction entry
        "status": "Completed" if success or coll else "Failed - Agent deviated from the route",
        "episode_s": 10.0, "eval_time_s": eval_s, "collisions_vehicle": coll,
        "outside_route_lanes_pct": 0.0,
    }
    keys = ("l2_1s_stp3", "l2_2s_stp3", "l2_3s_stp3", "openloop_collision_rate", "openloop_samples")
    row.update(dict(zip(keys, ol)) if ol else {k: None for k in keys})
    return row


def _write_policy(bdir: Path, name: str, rows: list[dict], compile_s=3.0, wall_s=5.0):
    (bdir / "policies").mkdir(parents=True, exist_ok=True)
    (bdir / "policies" / f"{name}.json").write_text(
        json.dumps({"policy": name, "rows": rows, "events": {}, "compile_s": compile_s, "wall_s": wall_s}))


def _synthetic(draw_ds, draw_success, draw_coll, draw_l2, draw_samples, n):
    rows = []
    for i in range(n):
        ol = (draw_l2[i], 2 * draw_l2[i] + 0.1, 3 * draw_l2[i] + 0.2, 0.01 * (i % 3), draw_samples[i])
        rows.append(_row("m", i, GROUPS[i % len(GROUPS)], draw_ds[i], 50.0 + i % 7, 0.5 + 0.01 * (i % 5),
                         draw_success[i] and not draw_coll[i], draw_coll[i], 100.0 + 10 * i, 0.25, ol))
    return rows


@settings(deadline=None, max_examples=25)
@given(st.data())
def test_table4_and_behaviour_rows_match_oracle(tmp_path_factory, data):
    n = data.draw(st.integers(4, 12))
    ds = data.draw(st.lists(st.floats(0, 100), min_size=n, max_size=n))
    ok = data.draw(st.lists(st.booleans(), min_size=n, max_size=n))
    coll = data.draw(st.lists(st.integers(0, 2), min_size=n, max_size=n))
    l2 = data.draw(st.lists(st.floats(0.01, 5), min_size=n, max_size=n))
    samples = data.draw(st.lists(st.integers(1, 30), min_size=n, max_size=n))
    rows = _synthetic(ds, ok, coll, l2, samples, n)
    bdir = tmp_path_factory.mktemp("bench")
    _write_policy(bdir, "m", rows, compile_s=4.0, wall_s=6.0)
    stop_rows = [_row("stop", i, GROUPS[i % 2], 4.0 + i, 4.0 + i, 1.0, False, 0, 80.0, 0.1) for i in range(3)]
    _write_policy(bdir, "stop", stop_rows)
    training = {"ad_mlp": {"epochs": 7, "train_loop_s": 123.0}}
    t4, beh = run.build_tables(bdir, [("m", "ad_mlp"), ("stop", None)], training)

    # Oracle: plain means / sample-weighted means over the rows.
    success = np.array([o and not c for o, c in zip(ok, coll)])
    w = np.array(samples, float)
    l2_1 = np.sum(np.array(l2) * w) / w.sum()
    l2_2 = np.sum((2 * np.array(l2) + 0.1) * w) / w.sum()
    km = sum((100.0 + 10 * i) / 1000 * (50.0 + i % 7) / 100 for i in range(n))
    m = t4[0]
    assert m["policy"] == "m" and m["model"] == "ad_mlp" and m["train_epochs"] == 7
    assert m["train_min"] == pytest.approx(123.0 / 60, abs=0.01)
    assert m["driving_score"] == pytest.approx(np.mean(ds), abs=1e-3)
    assert m["success_rate"] == pytest.approx(100 * success.mean(), abs=1e-3)
    assert m["route_completion"] == pytest.approx(np.mean([50.0 + i % 7 for i in range(n)]), abs=1e-3)
    assert m["infraction_score"] == pytest.approx(np.mean([0.5 + 0.01 * (i % 5) for i in range(n)]), abs=1e-3)
    assert m["collisions_per_km"] == pytest.approx(sum(coll) / km, abs=2e-3)
    assert m["l2_1s"] == pytest.approx(l2_1, abs=1e-3)
    assert m["l2_2s"] == pytest.approx(l2_2, abs=1e-3)
    assert m["l2_avg"] == pytest.approx((l2_1 + l2_2) / 2, abs=2e-3)  # the source's Avg. = mean of 1 s and 2 s
    coll_rate = np.sum(np.array([0.01 * (i % 3) for i in range(n)]) * w) / w.sum()
    assert m["openloop_collision_pct"] == pytest.approx(100 * coll_rate, abs=0.02)
    assert m["eval_s_per_scene"] == pytest.approx(0.25)
    assert (m["compile_s"], m["rollout_s"], m["num_scenarios"]) == (4.0, 6.0, n)
    assert m["rollout_s_per_scene"] == pytest.approx(6.0 / n, abs=1e-4)
    s = t4[1]
    assert s["model"] == "reference" and s["l2_1s"] is None and s["l2_avg"] is None and s["train_min"] is None
    assert s["driving_score"] == pytest.approx(5.0) and s["success_rate"] == 0.0

    # Per behaviour: the source's group order, means over each group's rows.
    got = {(r["policy"], r["behavior"]): r for r in beh}
    assert [r["behavior"] for r in beh if r["policy"] == "m"] == [g for g in run.BEHAVIOURS if g in GROUPS[:n]]
    for g in GROUPS:
        idx = [i for i in range(n) if GROUPS[i % len(GROUPS)] == g]
        r = got[("m", g)]
        assert r["num_scenarios"] == len(idx)
        assert r["driving_score"] == pytest.approx(np.mean([ds[i] for i in idx]), abs=1e-3)
        assert r["success_rate"] == pytest.approx(100 * success[idx].mean(), abs=1e-3)
    assert got[("stop", "COV")]["driving_score"] == pytest.approx((4.0 + 6.0) / 2)
    assert ("stop", "UT") not in got


def test_written_tables_round_trip(tmp_path):
    rows = [_row("m", i, g, ds, 80.0, 1.0, True, 0, 200.0, 0.5, (0.2, 0.6, 1.0, 0.0, 10))
            for i, (g, ds) in enumerate([("COV", 90.0), ("COV", 70.0), ("STP", 40.0)])]
    _write_policy(tmp_path / "b", "m", rows)
    t4, beh = run.build_tables(tmp_path / "b", [("m", "tcp")], {"tcp": {"epochs": 3, "train_loop_s": 90.0}})
    run.write_tables(tmp_path, t4, beh)
    with open(tmp_path / "table4.csv") as f:
        (r,) = list(csv.DictReader(f))
    assert float(r["l2_avg"]) == pytest.approx(0.4) and float(r["driving_score"]) == pytest.approx(200 / 3, abs=1e-3)
    assert float(r["train_min"]) == pytest.approx(1.5) and r["train_epochs"] == "3"
    md = (tmp_path / "table4.md").read_text()
    assert "| m | tcp | 3 | 1.5 | 0.200 | 0.600 | 0.400 | 0.00 | 100.0 | 66.67 | 80.00 | 1.000 | 0.00 | 0.500 | 1.667 |" in md
    pb = (tmp_path / "per_behaviour.md").read_text()
    assert "| SR % | COV (2) | STP (1) |" in pb and "| m | 80.00 | 40.00 |" in pb
    with open(tmp_path / "per_behaviour.csv") as f:
        got = {(d["policy"], d["behavior"]): float(d["driving_score"]) for d in csv.DictReader(f)}
    assert got == {("m", "COV"): 80.0, ("m", "STP"): 40.0}
    assert not list(tmp_path.glob(".*.tmp"))  # atomic writes leave no temp files


def test_train_time_sums_resumed_segments(tmp_path):
    log = tmp_path / "log.jsonl"
    lines = [{"step": 1, "time": 5.0}, {"event": "epoch", "epoch": 1, "time": 40.0},
             {"event": "epoch", "epoch": 2, "time": 80.0},
             {"step": 91, "time": 3.0}, {"event": "epoch", "epoch": 3, "time": 50.0}]  # resumed: time restarts
    log.write_text("".join(json.dumps(x) + "\n" for x in lines))
    assert run.train_time_s(log) == pytest.approx(130.0)
    assert np.isnan(run.train_time_s(tmp_path / "missing.jsonl"))


def test_train_state(tmp_path):
    d = tmp_path / "tcp"
    assert run.train_state(d, 3) == "new"
    d.mkdir()
    (d / "config.json").write_text(json.dumps({"epochs": 3}))
    assert run.train_state(d, 3) == "resume"
    for e in (1, 2, 3):
        (d / "checkpoints" / str(e)).mkdir(parents=True)
    assert run.train_state(d, 3) == "done" and run.epochs_done(d) == 3
    with pytest.raises(run.DriveE2EError, match="run of 3 epochs exists, 5 requested"):
        run.train_state(d, 5)


def test_commands(tmp_path):
    cfg = run.parse_args(["--out", str(tmp_path / "o"), "--runs", "R", "--models", "tcp,ad_mlp",
                          "--epochs", "tcp=2", "--references", "expert"])
    assert cfg.epochs == {"tcp": 2, "ad_mlp": 20} and cfg.references == ("stop", "constant_velocity", "expert")
    cmd = run.train_command(cfg, "tcp", resume=True)
    assert cmd[:3] == ["drivee2e", "train", "--model"] and cmd[3] == "tcp"
    assert cmd[cmd.index("--epochs") + 1] == "2" and cmd[cmd.index("--out") + 1] == str(Path("R") / "tcp")
    assert cmd[-1] == "--resume" and cmd[cmd.index("--data") + 1].endswith("demos-train-bev")
    b = run.bench_command(cfg)
    assert "--open-loop" in b and b[b.index("--split") + 1] == "val"
    specs = [b[i + 1] for i, a in enumerate(b) if a == "--policy"]
    assert [s.rsplit("name=", 1)[-1] for s in specs[:4]] == ["tcp", "tcp_traj", "tcp_ctrl", "ad_mlp"]
    assert all(f"checkpoint={Path('R') / 'tcp'}," in s for s in specs[:3])
    assert specs[4:] == ["stop", "constant_velocity", "expert"]


def test_evaluation_skipped_when_every_policy_is_done(tmp_path):
    cfg = run.parse_args(["--out", str(tmp_path), "--models", "ad_mlp"])
    bdir = run.bench_dir(cfg)
    for name in ("ad_mlp", "stop", "constant_velocity"):
        _write_policy(bdir, name, [])
    (bdir / "summary.json").write_text("{}")
    said = []
    assert run.evaluate_all(cfg, said.append) is None and "skipped" in said[0]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--models", "ad_mlp,resnet"], "--models: unknown model 'resnet'"),
        (["--epochs", "tcp=zero"], "--epochs: tcp: expected a positive integer"),
        (["--epochs", "bogus=3"], "--epochs: expected MODEL=N"),
        (["--references", "oracle"], "--references: unknown reference policy 'oracle'"),
        (["--models", "ad_mlp", "--data", "ad_mlp=MISSING"], "MISSING: demonstrations for ad_mlp not found"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, argv, message):
    argv = [a.replace("MISSING", str(tmp_path / "nope")) for a in argv]
    code = run.main(["--out", str(tmp_path / "out"), "--runs", str(tmp_path / "runs"), *argv])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("baselines: error: ") and err.count("\n") == 1
    assert message.replace("MISSING", str(tmp_path / "nope")) in err


@pytest.mark.slow
def test_end_to_end_on_the_tiny_suite(tiny_run, tmp_path):
    """--eval-only on the tiny suite's val split with a 2-epoch AD-MLP run: one
    real `drivee2e bench --open-loop` subprocess, tables from its rows, and a
    rerun that skips the evaluation. Slow (three policies compile in a
    subprocess: ~100 s on the loaded 2-core machine), hence the marker."""
    import shutil

    runs = tmp_path / "runs"
    shutil.copytree(tiny_run, runs / "ad_mlp")
    out = tmp_path / "out"
    argv = ["--out", str(out), "--runs", str(runs), "--models", "ad_mlp", "--epochs", "ad_mlp=2",
            "--suite", str(REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny"), "--eval-only"]
    assert run.main(argv) == 0
    with open(out / "table4.csv") as f:
        t4 = {r["policy"]: r for r in csv.DictReader(f)}
    assert list(t4) == ["ad_mlp", "stop", "constant_velocity"]
    assert t4["ad_mlp"]["train_epochs"] == "2" and t4["stop"]["model"] == "reference"
    summary = json.loads((out / "bench-val" / "summary.json").read_text())
    for name, r in t4.items():
        assert float(r["driving_score"]) == pytest.approx(summary["policies"][name]["overall"]["driving_score"])
    evals = (out / "evaluations.jsonl").read_text().splitlines()
    assert len(evals) == 1 and "sha256" in json.loads(evals[0])["controller"]
    assert run.main(argv) == 0 and len((out / "evaluations.jsonl").read_text().splitlines()) == 1
