"""Host policies in the rollout (``hostbridge``): numpy re-implementations of
reference policies give the JAX policies' per-scenario rows; errors inside a
host policy are one line naming its file and the step; NaN is counted per
scenario; remote policies run end to end."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from drivee2e_jax import hostbridge
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.bench import BenchConfig, run_bench
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.eval.openloop import evaluate_openloop
from drivee2e_jax.eval.traces import trace_episodes
from drivee2e_jax.policy import load_policy, resolve_policy_path
from drivee2e_jax.scenario import load_suite
from tests.helpers.host_policies import serve_policy

REPO = Path(__file__).resolve().parents[1]
LIMIT = 12  # twin15 val scenarios per rollout: a mix of behaviours, collisions and red lights

NP_LOG_REPLAY = '''
import os

import numpy as np
from drivee2e_jax.hostapi import Controls, HostPolicy

class NumpyLogReplay(HostPolicy):
    name = "np_log_replay"
    action_type = "controls"

    def __init__(self, fail_at=-1, mode="raise", nan_rows=(), die_at=-1):
        self.fail_at, self.mode, self.nan_rows, self.die_at = fail_at, mode, tuple(nan_rows), die_at

    def reset(self, meta):
        return {"step": 0, "ids": [m["scenario_id"] for m in meta]}

    def act(self, obs, state):
        c = obs.privileged.log_controls
        if state["step"] == self.die_at:  # the serving process dies mid-run
            os._exit(3)
        if state["step"] == self.fail_at:
            if self.mode == "raise":
                raise RuntimeError("kaboom")
            if self.mode == "dict":
                return {"throttle": c.throttle, "brake": c.brake, "steer": c.steer}, state
            if self.mode == "shape":
                return Controls(throttle=c.throttle[:, None], brake=c.brake, steer=c.steer), state
            if self.mode == "nostate":
                return Controls(throttle=c.throttle, brake=c.brake, steer=c.steer)
        ok = np.asarray(obs.privileged.log_valid)  # past the end of the log: hold still, as rollout.LogReplay
        throttle = np.where(ok, c.throttle, 0.0).astype(np.float32)
        throttle[list(self.nan_rows)] = np.nan
        state = {**state, "step": state["step"] + 1}
        brake, steer = np.where(ok, c.brake, 1.0).astype(np.float32), np.where(ok, c.steer, 0.0).astype(np.float32)
        return Controls(throttle=throttle, brake=brake, steer=steer), state

def make_policy(**kwargs):
    return NumpyLogReplay(**kwargs)
'''

#: Wall-clock and naming columns, the only ones allowed to differ.
SKIP = {"policy", "eval_time_s"}


@pytest.fixture(scope="module")
def twin15():
    return load_suite("twin15")


@pytest.fixture(scope="module")
def np_log_replay(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("host") / "np_log_replay.py"
    path.write_text(NP_LOG_REPLAY)
    return path


@pytest.fixture(scope="module")
def jax_log_replay(twin15):
    return evaluate(load_policy(resolve_policy_path("log_replay")), twin15, "val", limit=LIMIT)


def _same_rows(a, b, rel=0.0):
    assert [r["scenario_id"] for r in a.rows] == [r["scenario_id"] for r in b.rows]
    for ra, rb in zip(a.rows, b.rows):
        for k in set(ra) | set(rb):
            if k in SKIP:
                continue
            va, vb = ra.get(k), rb.get(k)
            if isinstance(va, float) and isinstance(vb, float) and rel:
                assert math.isclose(va, vb, rel_tol=rel, abs_tol=1e-9), (ra["scenario_id"], k, va, vb)
            else:
                assert va == vb, (ra["scenario_id"], k, va, vb)
    assert a.events == b.events


def test_numpy_log_replay_host_policy_equals_the_jax_one(twin15, np_log_replay, jax_log_replay):
    host = load_policy(np_log_replay)
    assert hostbridge.is_host(host) and host.source == str(np_log_replay)
    _same_rows(evaluate(host, twin15, "val", limit=LIMIT), jax_log_replay)


def test_numpy_constant_velocity_host_policy_equals_the_jax_one(twin15):
    example = load_policy(REPO / "docs" / "examples" / "numpy_constant_velocity.py")
    jax_cv = evaluate(load_policy(resolve_policy_path("constant_velocity")), twin15, "val", limit=LIMIT)
    # np.sinc and jnp.sinc may differ in the last float32 bit; nothing visible downstream.
    _same_rows(evaluate(example, twin15, "val", limit=LIMIT), jax_cv, rel=1e-5)


def test_a_host_policy_under_control_every_and_latency_equals_the_jax_one(twin15, np_log_replay):
    """The bridge's host loop knows the control steps on the host (the episodes
    step in lockstep) and holds / delays the action as the scan does for a JAX
    policy: the same rows with a query every 3 steps and 2 steps of latency."""
    from drivee2e_jax.rollout import ControlTiming

    timing = ControlTiming(control_every=3, latency=2)
    jax_rows = evaluate(load_policy(resolve_policy_path("log_replay")), twin15, "val", limit=4, timing=timing)
    _same_rows(evaluate(load_policy(np_log_replay), twin15, "val", limit=4, timing=timing), jax_rows)


def test_undeclared_number_of_waypoints_is_probed(twin15, tmp_path):
    src = (REPO / "docs" / "examples" / "numpy_constant_velocity.py").read_text()
    path = tmp_path / "cv_undeclared.py"
    path.write_text(src.replace("    num_waypoints = 6\n", "").replace("self.num_waypoints + 1", "7"))
    pol = load_policy(path)
    assert pol.num_waypoints is None
    res = evaluate(pol, twin15, "val", limit=2)
    assert len(res.rows) == 2 and hostbridge.wrap(pol).action_type == "waypoints"


@pytest.mark.parametrize("mode, expected", [
    ("raise", "act raised RuntimeError: kaboom"),
    ("dict", "the action is a dict"),
    ("shape", "has shape (2, 1), expected (2,)"),
    ("nostate", "expected a pair (action, state)"),
])
def test_a_failing_host_policy_is_one_line_naming_its_file_and_step(twin15, np_log_replay, mode, expected):
    pol = load_policy(np_log_replay, fail_at=3, mode=mode)
    with pytest.raises(DriveE2EError) as err:
        evaluate(pol, twin15, "val", limit=2)
    msg = str(err.value)
    assert "\n" not in msg and str(np_log_replay) in msg and "step 3" in msg and expected in msg, msg


def test_nan_actions_are_counted_per_scenario_and_poison_no_other(twin15, np_log_replay, jax_log_replay):
    res = evaluate(load_policy(np_log_replay, nan_rows=[1]), twin15, "val", limit=LIMIT)
    assert res.rows[1]["invalid_action"] > 0
    for i in range(LIMIT):
        if i != 1:
            assert res.rows[i]["driving_score"] == jax_log_replay.rows[i]["driving_score"]
            assert res.rows[i]["invalid_action"] == 0


def test_bench_runs_a_remote_policy_and_resumes_after_the_server_dies(np_log_replay, tmp_path):
    out = tmp_path / "results"
    reference = str(resolve_policy_path("log_replay"))
    with serve_policy(f"{np_log_replay}:die_at=5", tmp_path) as server:
        cfg = BenchConfig(split="val", limit=4, policies=(reference, server.remote), policy_names=("", "remote_lr"),
                          out=out, progress=False)
        with pytest.raises(DriveE2EError) as err:
            run_bench(cfg, print_fn=lambda _line: None)
    msg = str(err.value)
    assert server.address.removeprefix("tcp://") in msg and "step 5" in msg and "\n" not in msg, msg
    done = out / "policies" / "log_replay.json"
    assert done.exists() and not (out / "policies" / "remote_lr.json").exists()  # finished policies are kept
    mtime = done.stat().st_mtime_ns
    with serve_policy(str(np_log_replay), tmp_path) as server:  # a new server: the run resumes
        cfg = BenchConfig(split="val", limit=4, policies=(reference, server.remote), policy_names=("", "remote_lr"),
                          out=out, progress=False)
        summary = run_bench(cfg, print_fn=lambda _line: None)
    assert done.stat().st_mtime_ns == mtime
    overall = summary["policies"]
    for key in ("driving_score", "success_rate", "route_completion"):
        assert overall["remote_lr"]["overall"][key] == overall["log_replay"]["overall"][key], key


def test_open_loop_scores_a_host_waypoint_policy_like_the_jax_one(twin15):
    packed = twin15.pack("val")
    host = evaluate_openloop(load_policy(REPO / "docs" / "examples" / "numpy_constant_velocity.py"), packed, limit=4)
    jax_cv = evaluate_openloop(load_policy(resolve_policy_path("constant_velocity")), packed, limit=4)
    assert host.keys() == jax_cv.keys()
    for sid, want in jax_cv.items():
        for k, v in want.items():
            got = host[sid][k]
            assert (got == v) or math.isclose(got, v, rel_tol=1e-5, abs_tol=1e-7), (sid, k, got, v)


def test_view_and_mcap_resimulate_a_host_policy_run(np_log_replay, tmp_path):
    out = tmp_path / "results"
    cfg = BenchConfig(split="val", limit=3, policies=(str(np_log_replay),), out=out, progress=False, open_loop=True)
    run_bench(cfg, print_fn=lambda _line: None)
    traces = trace_episodes(out, "np_log_replay", sensors=())
    assert len(traces) == 3 and all(t.reproduced for t in traces)
    assert (out / "leaderboard" / "np_log_replay.json").exists()


FIELDS_PROBE = '''
import numpy as np
from drivee2e_jax.hostapi import Controls, HostPolicy

SEEN = []

class Probe(HostPolicy):
    name = "fields_probe"
    action_type = "controls"
    observation_fields = ("ego", "route")

    def act(self, obs, state):
        SEEN.append({f: getattr(obs, f) is None for f in ("ego", "route", "lanes", "agents", "privileged")})
        b = obs.ego.shape[0]
        return Controls(throttle=np.zeros(b, np.float32), brake=np.ones(b, np.float32), steer=np.zeros(b, np.float32)), state

policy = Probe()
'''


def test_observation_fields_send_only_what_the_policy_reads(twin15, tmp_path):
    path = tmp_path / "fields_probe.py"
    path.write_text(FIELDS_PROBE)
    pol = load_policy(path)
    evaluate(pol, twin15, "val", limit=2)
    seen = __import__("sys").modules[type(pol).__module__].SEEN
    assert seen and all(s == {"ego": False, "route": False, "lanes": True, "agents": True, "privileged": True}
                        for s in seen)
    bad = tmp_path / "bad_fields.py"
    bad.write_text(FIELDS_PROBE.replace('("ego", "route")', '("ego", "radar")'))
    with pytest.raises(DriveE2EError, match="observation_fields is"):
        load_policy(bad)


ROUTE_ONLY = '''
import numpy as np
from drivee2e_jax.hostapi import Controls, HostPolicy


class RouteOnly(HostPolicy):
    name = "route_only"
    action_type = "controls"
    observation_fields = ("route",)  # like docs/host_policies.md: no "ego"

    def __init__(self, log):
        self.log = log

    def reset(self, meta):
        return None

    def act(self, obs, state):
        b = obs.batch_size  # from the fields it observes (no ego)
        with open(self.log, "a") as f:
            f.write(f"{obs.ego is None} {b}\\n")
        z = np.zeros(b, np.float32)
        return Controls(throttle=z, steer=z, brake=np.ones(b, np.float32)), state


def make_policy(log):
    return RouteOnly(log)
'''


def test_a_host_policy_that_does_not_observe_ego_runs_in_check_policy_and_bench(tmp_path):
    from drivee2e_jax.testing import check_policy_file

    path, log = tmp_path / "route_only.py", tmp_path / "seen.txt"
    path.write_text(ROUTE_ONLY)
    report = check_policy_file(f"{path}:log={log}", suite="tiny", batch=2, steps=2)
    assert report.ok, list(report)
    seen = log.read_text().split("\n")[:-1]
    assert seen and all(line == "True 2" for line in seen)  # check-policy showed what bench sends: no ego
    log.unlink()
    result = evaluate(load_policy(f"{path}:log={log}"), load_suite("tiny"), "train", limit=2)
    assert len(result.rows) == 2
    seen = log.read_text().split("\n")[:-1]
    assert seen and all(line == "True 2" for line in seen)
    # served: the server takes the batch size from the fields that arrive
    log.unlink()
    with serve_policy(f"{path}:log={log}", tmp_path) as server:
        remote = evaluate(load_policy(server.remote), load_suite("tiny"), "train", limit=2)
    skip = {"policy", "eval_time_s"}
    assert [{k: v for k, v in r.items() if k not in skip} for r in remote.rows] == \
        [{k: v for k, v in r.items() if k not in skip} for r in result.rows]
    seen = log.read_text().split("\n")[:-1]
    assert seen and all(line == "True 2" for line in seen)


def test_a_host_policy_calling_sys_exit_is_one_line_naming_its_file_and_line(tmp_path):
    import types

    import numpy as np

    from drivee2e_jax import hostapi

    path = tmp_path / "exiter.py"
    path.write_text("import sys\nfrom drivee2e_jax.hostapi import HostPolicy\n\n\nclass P(HostPolicy):\n"
                    "    name = 'exiter'\n    action_type = 'controls'\n    observation_fields = ('route',)\n\n"
                    "    def reset(self, meta):\n        return None\n\n    def act(self, obs, state):\n"
                    "        sys.exit(3)\n\n\npolicy = P()\n")
    bridge = hostbridge.wrap(load_policy(path))
    bridge.begin([{"scenario_id": "a"}, {"scenario_id": "b"}])
    obs = types.SimpleNamespace(**{f: None for f in hostapi.field_names(hostapi.Observation)})
    obs.route = np.zeros((2, 5, 2), np.float32)
    action = bridge._host_act(obs)  # no SystemExit escapes: the rollout brakes, the failure is kept
    assert np.shape(action.brake) == (2,)
    assert bridge.failure == f"{path}, step 0: act called sys.exit(3) at {path}:14"


_TWO_RUNS = """
import json, sys
from drivee2e_jax import compile_cache
compile_cache.enable()
import jax
compiled = [0.0]
def on_duration(event, seconds, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        compiled[0] += seconds
jax.monitoring.register_event_duration_secs_listener(on_duration)
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.policy import load_policy
from drivee2e_jax.scenario import load_suite
evaluate(load_policy(sys.argv[1]), load_suite("twin15"), "val", limit=2)
print(json.dumps(compiled[0]))
"""


def test_a_second_process_takes_a_host_policy_rollout_from_the_compile_cache(tmp_path):
    """Issue 39 item 9: JAX never stores a program holding a host callback, so
    the bridge runs compiled segments around the host call instead; a second
    process finds every large program in the persistent cache (and the
    lowered store) and compiles almost nothing."""
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "DRIVEE2E_JAX_CACHE": str(tmp_path / "jax")}
    policy = str(REPO / "docs" / "examples" / "numpy_constant_velocity.py")
    seconds = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", _TWO_RUNS, policy], env=env, cwd=REPO, capture_output=True,
                             text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
        seconds.append(json.loads(out.stdout.strip().splitlines()[-1]))
    first, second = seconds
    assert first > 2.0, seconds  # the rollout was compiled (XLA seconds of the first process)
    assert second < 0.25 * first, seconds  # before the segments: ~the first's (the scan with its callback)
