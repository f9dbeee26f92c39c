"""`drivee2e bench` end to end on a small suite folder: files, tables, resume, errors."""

from __future__ import annotations

import csv
import dataclasses
import json
import shutil
import subprocess
import sys

import pytest

from drivee2e_jax.cli import main
from drivee2e_jax.eval import bench as bench_mod
from drivee2e_jax.eval.runspec import RunSpec
from drivee2e_jax.files import sha256_file
from drivee2e_jax.policy import resolve_policy_path
from drivee2e_jax.records import SuiteRecord
from drivee2e_jax.scenario.schema import write_suite
from tests.helpers import sim_scenarios as ss
from tests.helpers.road3 import bench as _bench

REQUIRED = ("policy", "scenario_id", "split", "intersection_id", "behavior", "route_completion", "infraction_score",
            "driving_score", "success", "status", "collisions_vehicle", "red_light")


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

    # Provenance: the zoo policy by name with its file's sha256; versions, devices, command.
    info = json.loads((out / "run.json").read_text())
    assert set(info["fingerprint"]) == {"suite_sha256", "drivee2e_version"}
    assert {"drivee2e_version", "jax_version", "jaxlib_version", "backend", "device_kinds", "time_utc",
            "command"} <= set(info["provenance"])
    assert RunSpec.load(out).to_json() == {k: v for k, v in info.items() if k not in ("fingerprint", "provenance")}
    pol = json.loads((out / "policies" / "log_replay.json").read_text())
    assert pol["provenance"]["policy"] == "log_replay" and pol["warnings"] == []
    assert pol["provenance"]["policy_sha256"] == sha256_file(resolve_policy_path("log_replay"))

    # Resume: both policies are skipped, files stay identical; temp files of a killed run are removed.
    before = (out / "scenarios.csv").read_text()
    stamp = (out / "policies" / "log_replay.json").stat().st_mtime_ns
    stray = [out / "policies" / ".stop.json.x1y2z3w4.tmp", out / ".summary.json.a1b2c3d4.tmp"]
    for f in stray:
        f.write_text("{")
    assert _bench(suite_dir, out) == 0
    assert "already done" in capsys.readouterr().out
    assert (out / "policies" / "log_replay.json").stat().st_mtime_ns == stamp
    assert (out / "scenarios.csv").read_text() == before
    assert not any(f.exists() for f in stray)

    # A rerun naming a subset of the policies keeps the others in every table (this run's first).
    assert main(["bench", "--suite", str(suite_dir), "--out", str(out), "--no-progress", "--policy", "stop"]) == 0
    assert "also list 1 policies finished earlier" in capsys.readouterr().out
    rows = list(csv.DictReader((out / "scenarios.csv").open()))
    assert [r["policy"] for r in rows] == ["stop"] * 3 + ["log_replay"] * 3
    assert list(json.loads((out / "summary.json").read_text())["policies"]) == ["stop", "log_replay"]
    assert sorted(p.name for p in (out / "leaderboard").glob("*.json")) == ["log_replay.json", "stop.json"]
    assert "log_replay" in (out / "report.md").read_text()


#: Holds a results folder's lock, as a `drivee2e bench` running elsewhere would.
HOLDER = """
import sys, time
from drivee2e_jax.files import lock_folder
with lock_folder(sys.argv[1], command="drivee2e bench --policy expert --out RUN"):
    print("locked", flush=True)
    time.sleep(60)
"""


def test_a_second_run_of_a_busy_folder_stops_naming_the_first(suite_dir, tmp_path, capsys, monkeypatch):
    """Two benches with one --out at once both exited 0 with the last one's tables: now the second stops."""
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        assert _bench(suite_dir, out, "--limit", "1") == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"in use by another run (pid {proc.pid} on " in err[0]
        assert "drivee2e bench --policy expert --out RUN" in err[0] and "another --out" in err[0]
        assert [p.name for p in out.iterdir()] == [".lock"]  # the refused run wrote nothing
    finally:
        proc.kill()
        proc.wait()


def test_changed_suite_policy_or_a_corrupt_file_is_never_resumed(suite_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    suite = shutil.copytree(suite_dir, tmp_path / "suite")
    pol = tmp_path / "stop.py"
    pol.write_text(resolve_policy_path("stop").read_text())
    out = tmp_path / "run"

    def bench(*extra):
        code = main(["bench", "--suite", str(suite), "--out", str(out), "--no-progress", "--limit", "1",
                     "--policy", str(pol), *extra])
        got = capsys.readouterr()
        return code, got.err.strip().splitlines() or got.out

    assert bench()[0] == 0
    pol.write_text(pol.read_text() + "# tuned\n")
    code, err = bench()
    assert code == 2 and len(err) == 1 and err[0].startswith("drivee2e: error: [stop] ")
    assert "(changed: the policy file's content)" in err[0] and "--force" in err[0]
    pol.write_text(resolve_policy_path("stop").read_text())

    first = json.loads((out / "policies" / "stop.json").read_text())["rows"][0]["scenario_id"]
    scn = suite / "scenarios" / f"{first}.json"  # the scenario --limit 1 evaluates
    original = scn.read_text()
    data = json.loads(original)
    data["tracks"][0]["size"][0] += 0.5  # one agent's length
    scn.write_text(json.dumps(data))
    code, err = bench()
    assert code == 2 and len(err) == 1 and "differs in fingerprint.suite_sha256" in err[0] and "--force" in err[0]
    scn.write_text(original)  # same content again (new mtime): resumes
    code, printed = bench()
    assert code == 0 and "already done" in printed

    f = out / "policies" / "stop.json"
    f.write_text(f.read_text()[:100])  # truncated
    code, err = bench()
    assert code == 2 and err == [f"drivee2e: error: {f} is corrupt (" + err[0].split(" is corrupt (", 1)[1]]
    assert err[0].endswith("delete it or use --force")
    assert bench("--force")[0] == 0 and json.loads(f.read_text())["policy"] == "stop"


def test_a_run_failing_before_any_policy_finished_leaves_no_folder(suite_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    bad = tmp_path / "bad.py"
    bad.write_text("from drivee2e_jax.errors import DriveE2EError\n"
                   "from drivee2e_jax.policy import StatelessPolicy\n"
                   "class P(StatelessPolicy):\n"
                   "    name = 'bad'\n"
                   "    def init(self, key, obs):\n"
                   "        raise DriveE2EError('bad.py: no weights')\n"
                   "policy = P()\n")
    out = tmp_path / "run"
    assert main(["bench", "--suite", str(suite_dir), "--out", str(out), "--no-progress", "--policy", str(bad)]) == 2
    assert "no weights" in capsys.readouterr().err
    assert not out.exists()


def test_a_single_split_suite_is_picked_and_warnings_are_kept(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    maps = {m.map_id: m for m in (ss.road_map(),)}
    train = write_suite(SuiteRecord("tr", "1", maps, [dataclasses.replace(ss.clean(), split="train")]), tmp_path / "tr")

    real = bench_mod.evaluate

    def evaluate_warning(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), warnings=["all actions were NaN"])

    monkeypatch.setattr(bench_mod, "evaluate", evaluate_warning)
    out = tmp_path / "run"
    assert main(["bench", "--suite", str(train), "--out", str(out), "--no-progress", "--policy", "stop"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert "split train: the only non-empty split of suite tr (no --split given)" in printed
    assert "[stop] warning: all actions were NaN" in printed
    assert json.loads((out / "policies" / "stop.json").read_text())["warnings"] == ["all actions were NaN"]
    assert json.loads((out / "run.json").read_text())["split"] == "train"

    scns = [dataclasses.replace(ss.clean(), split="train"), dataclasses.replace(ss.red_light(), split="test")]
    two = write_suite(SuiteRecord("two", "1", maps, scns), tmp_path / "two")
    assert main(["bench", "--suite", str(two), "--out", str(tmp_path / "o2"), "--no-progress", "--policy", "stop"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["drivee2e: error: --split: suite two has no val split; name one of: train (1), test (1)"]


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
        (["--policy", "nonsense"], "not a file and not a policy of the zoo"),
        (["--split", "train"], "split 'train' of suite 'road3' is empty"),
        (["--control-every", "0"], "--control-every must be"),
        (["--dt", "inf"], "--dt must be a finite number"),
        (["--dt", "nan"], "--dt must be a finite number"),
        (["--dt", "1e6"], "--dt must be a finite number of seconds in (0, 1]"),
        (["--dt", "0"], "--dt must be"),
        (["--dt", "-1"], "--dt must be"),
        (["--dt", "0.2"], "--dt 0.2 exceeds the log step 0.1 s"),
        (["--seed", "-1"], "--seed must be"),
        (["--latency", "-2"], "--latency must be"),
    ],
)
def test_bench_bad_input_is_one_line_and_writes_nothing(suite_dir, tmp_path, capsys, monkeypatch, args, needle):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    rc = main(["bench", "--suite", str(suite_dir), "--out", str(tmp_path / "o"), "--no-progress", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and needle in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "o").exists()


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


def test_open_loop_leaves_waypoints_shorter_than_its_horizon_empty(suite_dir, tmp_path, capsys, monkeypatch):
    """A two-waypoint policy (1 s, e.g. a PPO actor) is scored closed-loop; its
    open-loop columns stay empty instead of failing the run."""
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "short"
    assert main(["bench", "--suite", str(suite_dir), "--out", str(out), "--no-progress", "--open-loop",
                 "--policy", "vector_mlp:num_waypoints=2"]) == 0
    printed = capsys.readouterr().out
    assert "no open-loop metrics: policy waypoints cover 2 x 0.5 s" in printed
    rows = list(csv.DictReader((out / "scenarios.csv").open()))
    assert rows and all(r["l2_1s_stp3"] == "" and r["driving_score"] != "" for r in rows)


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


@pytest.mark.parametrize("flag, value, want", [
    ("--collisions", "some", "drivee2e: error: --collisions: unknown collision mode 'some'; expected one of all, at_fault"),
    ("--agents", "carla", "drivee2e: error: --agents: unknown agent model 'carla'; expected one of log, idm"),
    ("--preset", "carla", "drivee2e: error: --preset: unknown scoring preset 'carla'; expected one of paper, "),
])
def test_bench_unknown_choice_is_one_line_listing_the_choices(suite_dir, tmp_path, capsys, flag, value, want):
    """Checked before the suite loads or anything is written."""
    out = tmp_path / "never"
    assert _bench(suite_dir, out, flag, value) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(want), err
    if flag == "--preset":
        assert "nuplan" in err[0] and "navsim" in err[0]
    assert not out.exists()


def test_bench_help_explains_collisions_agents_and_the_new_presets(capsys):
    assert main(["bench", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    for s in ("--collisions", "at_fault", "--agents", "idm", "nuplan", "navsim",
              "--preset nuplan --agents idm --collisions at_fault"):
        assert s in text, s


def test_bench_refuses_a_folder_of_another_collision_mode_or_agent_model(suite_dir, tmp_path, capsys, monkeypatch):
    """A folder of the default settings refuses --collisions at_fault or
    --agents idm in one line (the RunSpec keys differ)."""
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "run"
    assert _bench(suite_dir, out, "--limit", "1") == 0
    capsys.readouterr()
    for flags, key in ((["--collisions", "at_fault"], "collisions"), (["--agents", "idm"], "agents")):
        assert _bench(suite_dir, out, "--limit", "1", *flags) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "different run" in err[0] and key in err[0], err
    # refused before anything was written: the folder still holds the first run only
    # (--force clearing the old files: tests/eval/test_runspec.py)
    assert "collisions" not in json.loads((out / "run.json").read_text())
    rows = list(csv.DictReader((out / "scenarios.csv").open()))
    assert len(rows) == 2 and "driving_score_at_fault" in rows[0]


def test_two_identical_runs_give_byte_identical_tables(suite_dir, tmp_path, monkeypatch):
    """Wall-clock time stays out of scenarios.csv/.json (in timing.json), so determinism is a `cmp`."""
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    a, b = tmp_path / "a", tmp_path / "b"
    assert _bench(suite_dir, a) == 0 and _bench(suite_dir, b) == 0
    for name in ("scenarios.csv", "scenarios.json"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert "eval_time_s" not in (a / "scenarios.csv").read_text()
    timing = json.loads((a / "timing.json").read_text())["rows"]
    rows = list(csv.DictReader((a / "scenarios.csv").open()))
    assert [(t["policy"], t["scenario_id"]) for t in timing] == [(r["policy"], r["scenario_id"]) for r in rows]
    assert all(t["eval_time_s"] > 0 for t in timing)
    from drivee2e_jax.eval.report import load_rows

    cols, joined = load_rows(a / "scenarios.csv")  # the report and sweeps read the time back from timing.json
    assert "eval_time_s" in cols and all(r["eval_time_s"] > 0 for r in joined)


@pytest.mark.parametrize("a,b", [("x/y", "x_y"), ("a b", "a_b")])
def test_policy_names_sharing_a_result_file_are_refused(suite_dir, tmp_path, capsys, a, b):
    out = tmp_path / "run"
    rc = main(["bench", "--suite", str(suite_dir), "--out", str(out), "--no-progress",
               "--policy", f"log_replay:name={a}", "--policy", f"stop:name={b}"])
    err = capsys.readouterr().err
    assert rc != 0 and "map to the same result file" in err and "Traceback" not in err
    assert not (out / "policies").exists() or not list((out / "policies").glob("*.json"))


def test_force_never_deletes_a_folder_drivee2e_did_not_write(suite_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "mine"
    (out / "plots").mkdir(parents=True)
    mine = {"report.md": "# my report\n", "summary.json": '{"mine": 1}\n', "plots/fig.png": "png"}
    for name, text in mine.items():
        (out / name).write_text(text)
    for extra in ((), ("--force",)):
        assert _bench(suite_dir, out, "--limit", "1", *extra) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(
            f"drivee2e: error: {out}: not a drivee2e results folder (no run.json; holds plots/fig.png, report.md, "
            "summary.json)")
    assert {p.relative_to(out).as_posix(): p.read_text() for p in out.rglob("*") if p.is_file()} == mine
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == ["plots", *sorted(mine)]
