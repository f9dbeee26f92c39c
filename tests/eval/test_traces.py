"""Episode traces: a tiny bench re-simulated must reproduce its stored results."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval import traces as episodes
from drivee2e_jax.eval.bench import BenchConfig, run_bench

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny"
#: One waypoint policy: the same bench as test_mcap_export (one compile, shared
#: through the persistent cache), and its plan exercises the world-frame transform.
POLICIES = ("constant_velocity",)
POLICY = POLICIES[0]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("episodes") / "run"
    cfg = BenchConfig(suite=str(TINY), split="train", policies=tuple(str(REPO / "drivee2e_jax" / "zoo" / f"{p}.py") for p in POLICIES),
                      out=out, limit=2, progress=False)
    run_bench(cfg, print_fn=lambda s: None)
    return out


@pytest.fixture(scope="module")
def traces(run_dir):
    return {p: episodes.trace_episodes(run_dir, p, sensors=()) for p in POLICIES}


def _records():
    from drivee2e_jax.scenario import load_suite

    return {s.scenario_id: s for s in load_suite(str(TINY)).records.scenarios}


def test_resimulation_reproduces_the_stored_driving_score(run_dir, traces):
    stored = json.loads((run_dir / "scenarios.json").read_text())
    for pol, trs in traces.items():
        rows = {r["scenario_id"]: r for r in stored if r["policy"] == pol}
        assert [t.scenario_id for t in trs] == list(rows)  # every scenario of the run, in run order
        for t in trs:
            assert t.reproduced
            assert t.driving_score == pytest.approx(rows[t.scenario_id]["driving_score"], abs=1e-4)
            assert t.row["driving_score"] == rows[t.scenario_id]["driving_score"]
            # The re-simulated events are the stored ones (type, time and place).
            assert [(e["type"], e["t"]) for e in t.resim_events] == [(e["type"], e["t"]) for e in t.events]
            assert t.events == rows[t.scenario_id]["events"]


def test_trace_starts_on_the_logged_ego_and_replays_the_agents(traces):
    recs = _records()
    for t in traces[POLICY]:
        rec = recs[t.scenario_id]
        ego = next(tr for tr in rec.tracks if tr.track_id == rec.ego_track_id)
        assert t.times[0] == 0.0
        np.testing.assert_allclose(t.ego_xy[0], ego.xy[0], atol=1e-4)
        assert abs(np.angle(np.exp(1j * (t.ego_yaw[0] - ego.yaw[0])))) < 1e-5
        # Every other agent sits at its logged pose whenever the log has a sample.
        by_id = {int(i): j for j, i in enumerate(t.agents.track_id)}
        others = [tr for tr in rec.tracks if tr.track_id != rec.ego_track_id]
        assert sorted(by_id) == sorted(tr.track_id for tr in others)
        for tr in others:
            j = by_id[tr.track_id]
            for k in (0, 20, t.num_steps - 1):
                at = np.flatnonzero(np.isclose(tr.t, t.times[k], atol=1e-6))
                assert bool(t.agents.valid[k, j]) == bool(len(at))
                if len(at):
                    np.testing.assert_allclose(t.agents.xy[k, j], tr.xy[at[0]], atol=1e-4)


def test_trace_shapes_and_time_axis(traces):
    for t in traces[POLICY]:
        n = t.num_steps
        np.testing.assert_allclose(t.times, t.dt * np.arange(n), atol=1e-5)
        assert t.ego_xy.shape == (n, 2) and t.controls.shape == (n, 3) and t.plan_xy.shape == (n, 6, 2)
        assert t.agents.xy.shape == (n, len(t.agents.track_id), 2)
        assert t.signals.shape == (n, len(t.map.stop_lines))
        assert all(v.shape == (n,) for v in t.timeline.values())
        assert {"speed", "route_completion", "facts.agent_hit", "events.collision"} <= set(t.timeline)
        assert t.timeline["route_completion"][-1] == pytest.approx(t.row["route_completion"], abs=1e-3)
        assert not t.plan_valid[-1] and t.plan_valid[:-1].all()
        assert t.bev is None and t.lidar_points is None
        assert len(t.map.lanes) > 0 and t.route_xy.shape[1] == 2


def test_waypoint_plan_is_in_the_world_frame(traces):
    """constant_velocity plans its first point 0.5 s ahead along its heading."""
    for t in traces[POLICY]:
        k = np.flatnonzero(t.plan_valid & (t.ego_speed > 1.0))
        assert len(k) > 5
        d = t.plan_xy[k, 0] - t.ego_xy[k]
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 0.5 * t.ego_speed[k], rtol=0.02, atol=0.02)
        heading = np.arctan2(d[:, 1], d[:, 0])
        err = np.angle(np.exp(1j * (heading - t.ego_yaw[k])))
        assert np.all(np.abs(err) < 0.05 + 0.25 * np.abs(t.ego_yaw_rate[k]))


def test_scenario_selection_and_errors(run_dir, traces):
    all_traces = traces
    one = episodes.trace_episodes(run_dir, POLICY, ["s_left"], sensors=())
    assert [t.scenario_id for t in one] == ["s_left"]
    np.testing.assert_array_equal(one[0].ego_xy, next(t for t in all_traces[POLICY] if t.scenario_id == "s_left").ego_xy)
    with pytest.raises(DriveE2EError, match=r"--scenario nope: not in this run \(2 scenarios: s_straight, s_left\)"):
        episodes.trace_episodes(run_dir, POLICY, ["nope"], sensors=())
    with pytest.raises(DriveE2EError, match="expected one of constant_velocity"):
        episodes.read_run(run_dir, "unknown")
    with pytest.raises(DriveE2EError, match="not a drivee2e results folder"):
        episodes.read_run(run_dir / "policies")
    with pytest.raises(DriveE2EError, match="unknown 'radar'"):
        episodes.default_sensor_config(("radar",))


def test_to_jsonable_is_strict_json(traces):
    t = traces[POLICY][0]
    d = episodes.to_jsonable(t)
    text = json.dumps(d, allow_nan=False)
    back = json.loads(text)
    assert len(back["times"]) == t.num_steps and len(back["agents"]["xy"]) == t.num_steps
    np.testing.assert_allclose(back["ego_xy"], t.ego_xy, atol=0.006)
    assert len(back["plan_xy"][0]) == t.plan_xy.shape[1]
    assert back["timeline"].keys() == t.timeline.keys()


@settings(deadline=None, max_examples=30)
@given(st.lists(st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32)), min_size=1, max_size=20),
       st.integers(0, 4))
def test_rounding_keeps_finite_values_and_nulls_the_rest(values, nd):
    a = np.asarray(values, np.float32)
    out = episodes._r(a, nd)
    json.dumps(out, allow_nan=False)
    for v, o in zip(a.astype(np.float64), out):
        if np.isfinite(np.round(v, nd)):
            assert o == pytest.approx(v, abs=0.5 * 10.0 ** -nd + 1e-9 * abs(v))
        else:
            assert o is None


def test_stream_renders_one_chunk_ahead_at_most(monkeypatch):
    """The stream holds at most two chunks of frames (the one being handed
    out and the next, rendering): a counting fake renderer over 7 episodes in
    chunks of 2 (the simulation and trace assembly faked too)."""
    log = []

    class FakeRenderer:
        bev_sim = None

        def __init__(self, sim_out, suite, packed, sensor_cfg, chunk, stride, lidar_stride):
            assert (chunk, stride, lidar_stride) == (2, 3, 5)

        def start(self, part):
            log.append(("start", tuple(part["rows"])))
            return tuple(part["rows"])

        def finish(self, part, started):
            assert started == tuple(part["rows"])
            log.append(("finish", started))
            return [f"frames {r}" for r in started]

    def fake_trace(run, packed, row, j, part, frames, stored, bev_cfg, sensor_cfg, stride, lidar_stride):
        assert frames[j] == f"frames {row}"
        log.append(("yield", row))
        return SimpleNamespace(row=row, reproduced=True)

    monkeypatch.setattr(episodes, "FrameRenderer", FakeRenderer)
    monkeypatch.setattr(episodes, "_simulate", lambda *a: {"rows": 7})
    monkeypatch.setattr(episodes, "_chunk", lambda sim_out, packed, rows, a, b: {"rows": rows[a:b]})
    monkeypatch.setattr(episodes, "_episode_trace", fake_trace)
    for name in ("_load_run_policy", "_run_settings", "stored_rows"):
        monkeypatch.setattr(episodes, name, lambda *a: {})
    packed = SimpleNamespace(meta=SimpleNamespace(scenario_id=[f"s{i}" for i in range(7)]))
    stream = episodes._stream(None, None, packed, np.arange(7), None, 2, 3, 5)
    assert log == [], "nothing runs before the first next()"
    assert [t.row for t in stream] == list(range(7))
    assert [e for e in log if e[0] == "yield"] == [("yield", r) for r in range(7)]
    held, peak = set(), 0
    for kind, what in log:
        if kind == "start":
            held.add(what)
        elif kind == "yield" and what % 2 == 1 or kind == "yield" and what == 6:
            held.discard(next(c for c in held if what in c))  # the chunk's last trace handed out
        peak = max(peak, len(held))
        if kind == "yield":
            later = [c for c in held if min(c) > what]
            assert len(later) <= 1, (what, held)  # never more than the next chunk rendered ahead
    assert peak == 2


def test_iter_traces_streams_the_same_traces(run_dir, traces):
    """``iter_traces`` in chunks of one gives ``trace_episodes``' traces, and
    simulates nothing before the first ``next()``."""
    stream = episodes.iter_traces(run_dir, POLICY, sensors=(), chunk_size=1)
    seen = list(stream)
    assert [t.scenario_id for t in seen] == [t.scenario_id for t in traces[POLICY]]
    for a, b in zip(seen, traces[POLICY]):
        assert a.reproduced
        np.testing.assert_array_equal(a.ego_xy, b.ego_xy)
        np.testing.assert_array_equal(a.agents.xy, b.agents.xy)


def test_strided_sensor_frames_are_the_full_frames_at_those_instants(run_dir):
    """``sensor_stride`` / ``lidar_stride`` keep exactly the stride-1 frames of
    instants 0, s, 2s, ... (the BEV bits and the LiDAR returns)."""
    kw = dict(sensors=("bev", "lidar"), limit=1, chunk_size=2)
    (full,) = episodes.iter_traces(run_dir, POLICY, **kw)
    (part,) = episodes.iter_traces(run_dir, POLICY, sensor_stride=3, lidar_stride=4, **kw)
    n = full.num_steps
    assert (part.sensor_stride, part.lidar_stride) == (3, 4) and part.num_steps == n
    assert isinstance(part.bev, episodes.PackedBev) and list(part.bev) == list(full.bev)
    np.testing.assert_array_equal(part.bev.bits, full.bev.bits[::3])
    assert part.bev.bits.shape[0] == -(-n // 3)
    for c in full.bev:
        np.testing.assert_array_equal(part.bev[c], full.bev[c][::3])
    np.testing.assert_array_equal(part.lidar_points, full.lidar_points[::4])
    np.testing.assert_array_equal(part.lidar_valid, full.lidar_valid[::4])
    with pytest.raises(DriveE2EError, match="chunk_size, sensor_stride and lidar_stride must be >= 1"):
        episodes.iter_traces(run_dir, POLICY, chunk_size=0)


def test_run_policies_and_scenarios(run_dir):
    assert episodes.run_policies(run_dir) == [POLICY]
    assert episodes.run_scenarios(run_dir, POLICY) == ["s_straight", "s_left"]


def test_a_moved_folder_finds_its_policy_by_the_recorded_portable_path(tmp_path):
    """policy_path is where the bench found the file; when that is gone (the
    folder moved, another installation) provenance.policy is used: a zoo name,
    or a path relative to the results folder."""
    from drivee2e_jax.eval.runspec import RunSpec

    spec = RunSpec(num_scenarios=1)
    zoo = episodes.RunRecord(path=tmp_path, info={}, policy="cv", spec=spec,
                             data={"policy_path": "/gone/constant_velocity.py",
                                   "provenance": {"policy": "constant_velocity"}})
    assert episodes._load_run_policy(zoo).name == "constant_velocity"
    (tmp_path / "mine.py").write_text("from drivee2e_jax.policy import load_policy, resolve_policy_path\n"
                                      "policy = load_policy(resolve_policy_path('stop'))\n")
    inside = episodes.RunRecord(path=tmp_path, info={}, policy="mine", spec=spec,
                                data={"policy_path": "/gone/mine.py", "provenance": {"policy": "mine.py"}})
    assert episodes._load_run_policy(inside).name == "stop"
    lost = episodes.RunRecord(path=tmp_path, info={}, policy="x", spec=spec,
                              data={"policy_path": "/gone/x.py", "provenance": {"policy": "/gone/x.py"}})
    with pytest.raises(DriveE2EError, match="/gone/x.py: the policy file of 'x'"):
        episodes._load_run_policy(lost)
