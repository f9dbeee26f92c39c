"""`drivee2e sweep`: config errors, the grid, batched repetitions, kill + resume, the notebook."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.sweep import expand, load_config, parse_config, run_sweep
from drivee2e_jax.sweep.config import SweepConfig, with_out

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "drivee2e_jax" / "scenario" / "examples" / "tiny"

#: A stochastic policy: its throttle comes from the step's PRNG key, so the
#: repetitions (seeds) differ and a wrong key assignment shows.
JITTER = '''
import jax
from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls


class Jitter(StatelessPolicy):
    name = "jitter"

    def act(self, params, obs, policy_state, key):
        u = jax.random.uniform(key, (3,))
        return Controls(throttle=u[0], brake=0.3 * u[1], steer=0.4 * (u[2] - 0.5)), policy_state


policy = Jitter()
'''


def _config_text(jitter: Path) -> str:
    return f"""
[sweep]
name = "t"

[[policies]]
path = "{jitter}"
name = "a"

[[policies]]
path = "{jitter}"
name = "b"

[data]
suites = ["{TINY}"]
splits = ["train"]
limit = 1

[repetitions]
count = 2
seed = 3
"""


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("sweepcfg")
    (d / "jitter.py").write_text(JITTER)
    path = d / "tiny.toml"
    path.write_text(_config_text(d / "jitter.py"))
    return path


def _load(tmp_path, text: str) -> SweepConfig:
    path = tmp_path / "x.toml"
    path.write_text(text)
    return load_config(path)


BASE = '[sweep]\nname = "x"\n[[policies]]\npath = "stop"\n'


@pytest.mark.parametrize(
    "extra, expect",
    [
        ("[sim]\ndtt = 0.1\n", "[sim] unknown key 'dtt' (expected one of: dt, preset,"),
        ("[repetitions]\ncount = \"two\"\n", "[repetitions] count: expected an integer, got 'two'"),
        ("[sim]\ndt = [0.1, \"x\"]\n", "[sim] dt: expected a number, got 'x'"),
        ("[sim]\nlatency = -1\n", "[sim] latency: must be >= 0, got -1"),
        ("[data]\ntasks = [\"flying\"]\n", "[data] tasks: unknown task 'flying'"),
        ("[outputs]\nmetrics = [\"speed\"]\n", "[outputs] metrics: unknown metric 'speed'"),
        ("[simm]\ndt = 0.1\n", "unknown table [simm]"),
        ("[[policies]]\nname = \"b\"\n", "[[policies]] #2 missing key 'path'"),
    ],
)
def test_config_errors_are_one_line_naming_file_table_key(tmp_path, extra, expect):
    with pytest.raises(DriveE2EError) as e:
        _load(tmp_path, BASE + extra)
    msg = str(e.value)
    assert msg.startswith(f"{tmp_path / 'x.toml'}: ") and expect in msg and "\n" not in msg


def test_config_empty_policies_and_cli_exit_code(tmp_path, capsys):
    with pytest.raises(DriveE2EError, match=r"\[\[policies\]\] is empty"):
        _load(tmp_path, 'policies = []\n[sweep]\nname = "x"\n')
    from drivee2e_jax.cli import main

    assert main(["sweep", str(tmp_path / "x.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("drivee2e: error:") and "[[policies]] is empty" in err and "\n" not in err


def test_config_scalars_become_tuples_and_round_trip_json():
    cfg = parse_config({"sweep": {"name": "g"}, "policies": [{"path": "stop", "kwargs": {"checkpoint": "c"}}],
                        "sim": {"dt": 0.05, "latency": [0, 2]}, "repetitions": {"count": 2}})
    assert cfg.sim.dt == (0.05,) and cfg.sim.latency == (0, 2) and cfg.sim.preset == ("paper",)
    assert cfg.policies[0].kwargs == {"checkpoint": "c"} and cfg.repetitions.count == 2
    assert json.loads(json.dumps(cfg.to_json())) == cfg.to_json()


def test_grid_expansion_every_combination_with_readable_ids():
    cfg = parse_config({
        "sweep": {"name": "g"}, "policies": [{"path": "stop"}],
        "data": {"suites": ["twin15", "some/dir/tiny"], "splits": ["val", "test"]},
        "sim": {"latency": [0, 1], "dt": 0.05},
    })
    runs = expand(cfg)
    assert len(runs) == 2 * 2 * 2
    assert len({r.run_id for r in runs}) == 8
    assert {(r.suite, r.split, r.latency) for r in runs} == {
        (s, sp, lat) for s in ("twin15", "some/dir/tiny") for sp in ("val", "test") for lat in (0, 1)}
    assert runs[0].run_id == "twin15-val-dt0.05" and runs[1].run_id == "twin15-val-dt0.05-lat1"
    assert runs[-1].run_id == "tiny-test-dt0.05-lat1" and all(r.dt == 0.05 for r in runs)
    dup = parse_config({"sweep": {"name": "g"}, "policies": [{"path": "stop"}],
                        "data": {"suites": ["a/tiny", "b/tiny"]}})
    with pytest.raises(DriveE2EError, match="share the folder runs/tiny-val"):
        expand(dup)


def test_batched_repetitions_equal_separate_evaluate_calls(tiny_config):
    from drivee2e_jax.eval.closedloop import evaluate
    from drivee2e_jax.metrics.driving_score import score_preset
    from drivee2e_jax.observe.vector import ObsConfig
    from drivee2e_jax.policy import load_policy
    from drivee2e_jax.rollout import ControlTiming
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.sim import SimConfig

    pol = load_policy(tiny_config.parent / "jitter.py")
    packed = load_suite(str(TINY)).pack("train")
    # The settings run_bench uses, so the sweep test below reuses these compiled programs.
    kw = dict(config=SimConfig(dt=0.1, score=score_preset("paper"), obs=ObsConfig()), timing=ControlTiming(1, 0),
              limit=1)
    batched = evaluate(pol, packed, None, seeds=[3, 4], **kw)
    separate = [evaluate(pol, packed, None, seed=s, **kw) for s in (3, 4)]
    assert [r["repetition"] for r in batched.rows] == [0, 1]
    skip = {"eval_time_s", "repetition"}
    for rep, res in enumerate(separate):
        got, want = batched.rows[rep], res.rows[0]
        assert set(got) - skip == set(want) - skip
        for k in set(want) - skip:
            if isinstance(want[k], float):
                assert got[k] == pytest.approx(want[k], rel=1e-5, abs=1e-6), k
            else:
                assert got[k] == want[k], k
        key = want["scenario_id"] if rep == 0 else f"{want['scenario_id']}#{rep}"
        assert batched.events[key] == res.events[want["scenario_id"]]
    # Non-vacuous: the two seeds drove differently.
    assert separate[0].rows[0]["completed_distance_m"] != separate[1].rows[0]["completed_distance_m"]


def _sweep_cmd(config: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "drivee2e_jax.cli", "sweep", str(config), "--out", str(out), "--no-progress"]


def _env() -> dict:
    """The test's environment: conftest pins ``DRIVEE2E_JAX_CACHE``, so the
    subprocess shares this session's compiled programs."""
    return dict(os.environ)


def test_sweep_killed_midway_resumes_without_redoing_work(tiny_config, tmp_path):
    out = tmp_path / "sweep"
    run_dir = out / "runs" / "tiny-train"
    first = run_dir / "policies" / "a.json"
    proc = subprocess.Popen(_sweep_cmd(tiny_config, out), cwd=ROOT, env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.time() + 600
    while not first.exists() and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    log = proc.communicate()[0]
    assert proc.returncode == -signal.SIGKILL, f"the sweep ended before it could be killed:\n{log[-2000:]}"
    assert first.exists() and not (run_dir / "bench.log").exists() and not (out / "combined.csv").exists()
    stamp = first.stat().st_mtime_ns

    done = subprocess.run(_sweep_cmd(tiny_config, out), cwd=ROOT, env=_env(), capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "[a] already done" in done.stdout and "[b x2 reps] 2 episodes" in done.stdout
    assert first.stat().st_mtime_ns == stamp  # the finished policy was not redone
    assert not list(out.rglob("*.tmp"))
    for f in out.rglob("*.json"):
        json.loads(f.read_text())  # no partial JSON anywhere

    # A third call skips the complete run; the tables equal an uninterrupted sweep's.
    again = subprocess.run(_sweep_cmd(tiny_config, out), cwd=ROOT, env=_env(), capture_output=True, text=True,
                           timeout=900)
    assert again.returncode == 0 and "tiny-train: complete, skipped" in again.stdout
    fresh = tmp_path / "fresh"
    rows = run_sweep(with_out(load_config(tiny_config), fresh), progress=False, print_fn=lambda s: None)
    assert (out / "combined.csv").read_text() == (fresh / "combined.csv").read_text()
    assert (out / "combined.md").read_text() == (fresh / "combined.md").read_text()
    by = {r["policy"]: r for r in rows}
    assert set(by) == {"a", "b"} and by["a"]["repetitions"] == 2 and math.isfinite(by["a"]["driving_score"])
    # Two instances of one file with the same seeds drive alike (one compiled program, from the cache).
    assert {k: v for k, v in by["a"].items() if k != "policy"} == {k: v for k, v in by["b"].items() if k != "policy"}

    # A changed config is refused in one line.
    changed = tiny_config.parent / "changed.toml"
    changed.write_text(tiny_config.read_text().replace("seed = 3", "seed = 4"))
    from drivee2e_jax.cli import main

    assert main(["sweep", str(changed), "--out", str(out), "--no-progress"]) == 2


def test_sweep_notebook_runs(tiny_config, tmp_path):
    env = dict(_env(), DRIVEE2E_SWEEP_CONFIG=str(tiny_config), DRIVEE2E_SWEEP_OUT=str(tmp_path / "nb"))
    proc = subprocess.run([sys.executable, str(ROOT / "notebooks" / "sweep.py")], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "tiny-train" in proc.stdout and "2 run x policy rows" in proc.stdout
    assert "## driving_score" in proc.stdout and "| tiny-train |" in proc.stdout


def test_a_second_sweep_on_a_locked_folder_is_refused_in_one_line(tiny_config, tmp_path):
    """Two sweeps on one folder would delete each other's temp files and
    interleave the combined tables: the second gets one line naming the holder
    and nothing of the folder changes."""
    from drivee2e_jax.files import lock_folder

    out = tmp_path / "locked"
    with lock_folder(out, command="drivee2e sweep first"):
        with pytest.raises(DriveE2EError, match=r"locked: in use by another run .*drivee2e sweep first.*--out"):
            run_sweep(with_out(load_config(tiny_config), out), progress=False, print_fn=lambda s: None)
    assert sorted(p.name for p in out.iterdir()) == [".lock"]


@pytest.mark.parametrize("extra, expect", [
    ("[sim]\ncollisions = [\"all\", \"some\"]\n",
     "[sim] collisions: unknown collision mode 'some' (expected one of: all, at_fault)"),
    ("[sim]\nagents = \"reactive\"\n", "[sim] agents: unknown agent model 'reactive' (expected one of: log, idm)"),
    ("[sim]\npreset = \"carla\"\n", "[sim] preset: unknown preset 'carla' (expected one of: paper,"),
])
def test_bad_collision_mode_agent_model_or_preset_is_one_line(tmp_path, extra, expect):
    with pytest.raises(DriveE2EError) as e:
        _load(tmp_path, BASE + extra)
    assert expect in str(e.value) and "\n" not in str(e.value)


def test_collisions_and_agents_are_grid_axes_passed_to_bench(tmp_path):
    from drivee2e_jax.sweep.runner import bench_config

    cfg = _load(tmp_path, BASE + '[sim]\ncollisions = ["all", "at_fault"]\nagents = ["log", "idm"]\n')
    runs = expand(cfg)
    assert [r.run_id for r in runs] == ["twin15-val", "twin15-val-agents_idm", "twin15-val-coll_at_fault",
                                        "twin15-val-coll_at_fault-agents_idm"]
    b = bench_config(cfg, runs[-1], tmp_path / "r")
    assert (b.collisions, b.agents) == ("at_fault", "idm")
    assert (b.run_spec().collisions, b.run_spec().agents) == ("at_fault", "idm")


def test_an_older_sweep_json_without_collisions_or_agents_still_resumes(tmp_path):
    from drivee2e_jax.sweep.runner import start

    cfg = _load(tmp_path, BASE)
    runs = expand(cfg)
    out = tmp_path / "out"
    out.mkdir()
    rec = cfg.to_json()
    for k in ("collisions", "agents"):
        del rec["sim"][k]
    (out / "sweep.json").write_text(json.dumps({"config": rec, "runs": [r.run_id for r in runs]}))
    start(out, cfg, runs, force=False)  # reads as all / log: the same config
    other = _load(tmp_path, BASE + '[sim]\nagents = "idm"\n')
    with pytest.raises(DriveE2EError, match=r"differs in sim\.agents"):
        start(out, other, expand(other), force=False)


def test_force_never_deletes_a_folder_drivee2e_did_not_write(tmp_path):
    """A sweep folder is recognised by sweep.json; --force redoes only its own files."""
    from drivee2e_jax.sweep.runner import DONE_FILE, check_own

    out = tmp_path / "mine"
    out.mkdir()
    (out / "combined.md").write_text("the user's")
    for force in (False, True):
        with pytest.raises(DriveE2EError, match=rf"^{out}: not a drivee2e sweep folder \(no sweep.json; holds "
                                                r"combined.md\)"):
            check_own(out, force)
    (out / "sweep.json").write_text("{}")
    run = out / "runs" / "tiny-val"
    (run / "policies").mkdir(parents=True)
    for name in ("run.json", "policies/stop.json", "summary.json", "plots/comfort.png", DONE_FILE, ".lock"):
        (run / name).parent.mkdir(parents=True, exist_ok=True)
        (run / name).write_text("{}")
    (out / "combined.md").write_text("| drivee2e's |")
    check_own(out, True)  # every file is a sweep's
    (run / "notes.txt").write_text("the user's")
    with pytest.raises(DriveE2EError, match=r"holds files drivee2e did not write \(runs/tiny-val/notes.txt\)"):
        check_own(out, True)
    check_own(out, False)  # resuming deletes nothing
