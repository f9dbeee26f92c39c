"""`drivee2e bench` end to end on a small suite folder: files, tables, resume, errors."""

from __future__ import annotations

import csv
import json

import pytest

from drivee2e_jax.cli import main
from drivee2e_jax.records import SuiteRecord
from drivee2e_jax.scenario.schema import write_suite
from tests.helpers import sim_scenarios as ss

REQUIRED = ("policy", "scenario_id", "split", "intersection_id", "behavior", "route_completion", "infraction_score",
            "driving_score", "success", "status", "eval_time_s", "collisions_vehicle", "red_light")


@pytest.fixture(scope="module")
def suite_dir(tmp_path_factory):
    maps = {m.map_id: m for m in (ss.road_map(), ss.road_map(obstacle=True))}
    scns = [ss.clean(), ss.blocked_by_car(), ss.red_light()]
    return write_suite(SuiteRecord("road3", "1", maps, scns), tmp_path_factory.mktemp("suites") / "road3")


def _bench(suite_dir, out, *extra):
    return main(["bench", "--suite", str(suite_dir), "--out", str(out), "--no-progress",
                 "--policy", "log_replay", "--policy", "stop", *extra])


def test_bench_writes_tables_and_resumes(suite_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "run"
    assert _bench(suite_dir, out) == 0
    printed = capsys.readouterr().out
    assert "SR %" in printed and "log_replay" in printed and "SR % by behaviour" in printed
    rows = list(csv.DictReader((out / "scenarios.csv").open()))
    assert len(rows) == 6 and set(REQUIRED) <= set(rows[0])
    by = {(r["policy"], r["scenario_id"]): r for r in rows}
    assert by[("log_replay", "clean")]["status"] == "Perfect"
    assert float(by[("log_replay", "car_ahead")]["driving_score"]) == pytest.approx(60.0, abs=1e-3)
    detail = json.loads((out / "scenarios.json").read_text())
    ev = next(r for r in detail if r["policy"] == "log_replay" and r["scenario_id"] == "red")["events"]
    assert any(e["type"] == "red_light" and {"t", "x", "y"} <= set(e) for e in ev)
    summary = json.loads((out / "summary.json").read_text())
    lr = summary["policies"]["log_replay"]["overall"]
    assert lr["num_scenarios"] == 3 and lr["success_rate"] == pytest.approx(100 / 3, abs=1e-3)
    assert summary["policies"]["stop"]["overall"]["success_rate"] == 0.0

    # Resume: both policies are skipped, files stay identical.
    before = (out / "scenarios.csv").read_text()
    stamp = (out / "policies" / "log_replay.json").stat().st_mtime_ns
    assert _bench(suite_dir, out) == 0
    assert "already done" in capsys.readouterr().out
    assert (out / "policies" / "log_replay.json").stat().st_mtime_ns == stamp
    assert (out / "scenarios.csv").read_text() == before


def test_bench_refuses_a_different_run_without_force(suite_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "run"
    assert _bench(suite_dir, out, "--limit", "1") == 0
    capsys.readouterr()
    assert _bench(suite_dir, out, "--preset", "lb20", "--limit", "1") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different run" in err[0] and "preset" in err[0] and "Traceback" not in err[0]
    assert _bench(suite_dir, out, "--preset", "lb20", "--limit", "1", "--force") == 0


@pytest.mark.parametrize(
    "args, needle",
    [
        (["--policy", "no/such/policy.py"], "policy file not found"),
        (["--policy", "nonsense"], "not a file and not a reference policy"),
        (["--split", "train"], "split"),
        (["--control-every", "0"], "control_every"),
    ],
)
def test_bench_bad_input_is_one_line(suite_dir, tmp_path, capsys, monkeypatch, args, needle):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    rc = main(["bench", "--suite", str(suite_dir), "--out", str(tmp_path / "o"), "--no-progress", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and needle in err[0] and "Traceback" not in err[0]


def test_policy_file_without_policy(tmp_path, capsys, suite_dir, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    bad = tmp_path / "empty_policy.py"
    bad.write_text("x = 1\n")
    rc = main(["bench", "--suite", str(suite_dir), "--out", str(tmp_path / "o"), "--no-progress", "--policy", str(bad)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "defines neither `policy` nor `make_policy()`" in err and str(bad) in err


def test_open_loop_columns_fine_grained_metrics_and_report(suite_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "ol"
    assert main(["bench", "--suite", str(suite_dir), "--out", str(out), "--no-progress", "--open-loop",
                 "--policy", "constant_velocity", "--policy", "log_replay"]) == 0
    printed = capsys.readouterr().out
    assert "open-loop" in printed and "outputs controls" in printed and "fine-grained" in printed
    rows = list(csv.DictReader((out / "scenarios.csv").open()))
    for col in ("l2_1s_stp3", "l2_2s_stp3", "l2_3s_stp3", "l2_1s_uniad", "l2_2s_uniad", "l2_3s_uniad",
                "openloop_collision_rate", "position_deviation_mean_m", "lane_invasions_per_km", "smoothness_pct"):
        assert col in rows[0], col
    cv = {r["scenario_id"]: r for r in rows if r["policy"] == "constant_velocity"}
    lr = [r for r in rows if r["policy"] == "log_replay"]
    # The logged ego drives at a constant 10 m/s straight: constant velocity is exact.
    assert float(cv["clean"]["l2_3s_stp3"]) == pytest.approx(0.0, abs=0.05)
    assert all(r["l2_1s_stp3"] == "" for r in lr)  # a controls policy has no open-loop columns
    summary = json.loads((out / "summary.json").read_text())
    o = summary["policies"]["constant_velocity"]["overall"]
    assert o["openloop_samples"] > 0 and "l2_2s_uniad" in o and "smoothness_pct" in o
    report = (out / "report.md").read_text()
    assert "constant_velocity" in report and (out / "plots" / "sr_by_behavior.png").stat().st_size > 1000


def test_policy_spec_with_make_policy_arguments_and_a_result_name(tmp_path):
    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.policy import load_policy, parse_policy_spec

    f = tmp_path / "p.py"
    f.write_text(
        "from drivee2e_jax.policy import StatelessPolicy\n"
        "class P(StatelessPolicy):\n"
        "    def __init__(self, gain, tag):\n"
        "        self.gain, self.tag = gain, tag\n"
        "def make_policy(gain=1.0, tag='a'):\n"
        "    return P(gain, tag)\n"
    )
    path, kwargs, name = parse_policy_spec(f"{f}:gain=2.5,tag=runs/x,name=mine")
    assert (path, kwargs, name) == (f, {"gain": 2.5, "tag": "runs/x"}, "mine")  # JSON when it parses, else text
    pol = load_policy(path, **kwargs)
    assert (pol.gain, pol.tag) == (2.5, "runs/x")
    with pytest.raises(DriveE2EError, match="make_policy does not take"):
        load_policy(path, bogus=1)
    with pytest.raises(DriveE2EError, match="expected PATH:key=value"):
        parse_policy_spec(f"{f}:gain")
    plain = tmp_path / "plain.py"
    plain.write_text(f.read_text().replace("def make_policy(gain=1.0, tag='a'):\n    return P(gain, tag)\n",
                                           "policy = P(1.0, 'a')\n"))
    with pytest.raises(DriveE2EError, match="defines no make_policy"):
        load_policy(plain, gain=2.0)
