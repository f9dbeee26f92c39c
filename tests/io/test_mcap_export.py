"""MCAP export: read the file back with the mcap reader; every channel, count and schema."""

from __future__ import annotations

import base64
import io
import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from drivee2e_jax.cli import main
from drivee2e_jax.eval import traces as episodes
from drivee2e_jax.eval.bench import BenchConfig, run_bench
from drivee2e_jax.io import mcap_export as mx
from drivee2e_jax.observe.bev import BevConfig
from drivee2e_jax.observe.lidar import LidarConfig
from drivee2e_jax.observe.sensors import SensorConfig

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "scenarios" / "examples" / "tiny"
SMALL_SENSORS = SensorConfig(bev=BevConfig(height=32, width=32, resolution=1.0), lidar=LidarConfig(channels=4, azimuth_bins=32))
PER_STEP = ("tf", "scene", "bev", "lidar", "metrics")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("mcap") / "run"
    cfg = BenchConfig(suite=str(TINY), split="train", policies=(str(REPO / "drivee2e_jax" / "zoo" / "constant_velocity.py"),), out=out,
                      limit=2, progress=False)
    run_bench(cfg, print_fn=lambda s: None)
    return out


@pytest.fixture(scope="module")
def exported(run_dir, tmp_path_factory):
    traces = episodes.trace_episodes(run_dir, sensor_config=SMALL_SENSORS)
    path = mx.write_mcap(traces, tmp_path_factory.mktemp("mcap_out") / "episodes.mcap")
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        messages = [(schema.name, json.loads(schema.data), ch.topic, msg) for schema, ch, msg in reader.iter_messages()]
    return traces, path, summary, messages


def _check(value, schema: dict, where: str) -> None:
    """A small JSON Schema check: types, enum consts, nested objects and arrays.
    Foxglove's schemas list no `required`; every field they declare must be
    in our messages, and no undeclared field may appear."""
    if "oneOf" in schema:
        assert value in [o["const"] for o in schema["oneOf"]], where
        return
    kinds = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
    ok = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None),
          "integer": int, "number": (int, float)}
    assert any(isinstance(value, ok[k]) and not (k in ("integer", "number") and isinstance(value, bool))
               for k in kinds), f"{where}: {type(value).__name__} is not {kinds}"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        assert value >= schema.get("minimum", -np.inf) and value <= schema.get("maximum", np.inf), where
    if isinstance(value, dict):
        props = schema["properties"]
        assert set(value) == set(props), f"{where}: fields {sorted(set(value) ^ set(props))}"
        for k, v in value.items():
            _check(v, props[k], f"{where}.{k}")
    if isinstance(value, list) and "items" in schema:
        for i, v in enumerate(value):
            _check(v, schema["items"], f"{where}[{i}]")


def test_every_channel_schema_and_message_count(exported):
    traces, _, summary, messages = exported
    assert len(traces) == 2
    channels = {c.topic: (summary.schemas[c.schema_id].name, c.message_encoding) for c in summary.channels.values()}
    counts = {c.topic: summary.statistics.channel_message_counts[i] for i, c in summary.channels.items()}
    want = {}
    for t in traces:
        p = f"/{t.scenario_id}"
        want.update({f"{p}/tf": "foxglove.FrameTransform", f"{p}/scene": "foxglove.SceneUpdate",
                     f"{p}/map": "foxglove.SceneUpdate", f"{p}/bev": "foxglove.CompressedImage",
                     f"{p}/lidar": "foxglove.PointCloud", f"{p}/metrics": "drivee2e.EpisodeMetrics",
                     f"{p}/infractions": "foxglove.Log"})
        for name in PER_STEP:
            assert counts[f"{p}/{name}"] == t.num_steps
        assert counts[f"{p}/map"] == 1
        assert counts[f"{p}/infractions"] == len(t.events) > 0
    assert {k: v[0] for k, v in channels.items()} == want
    assert {v[1] for v in channels.values()} == {"json"}
    assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
    assert len(messages) == sum(counts.values())
    assert sum(counts[f"/{t.scenario_id}/{n}"] for t in traces for n in PER_STEP) == len(PER_STEP) * sum(
        t.num_steps for t in traces)


def test_payloads_validate_against_their_schemas(exported):
    _, _, _, messages = exported
    seen = set()
    for name, schema, topic, msg in messages:
        assert schema["title"] == name
        payload = json.loads(msg.data)
        _check(payload, schema, topic)
        stamp = payload["timestamp"] if "timestamp" in payload else payload["entities"][0]["timestamp"]
        assert stamp["sec"] * 10**9 + stamp["nsec"] == msg.log_time
        seen.add(name)
    assert seen == {"foxglove.FrameTransform", "foxglove.SceneUpdate", "foxglove.CompressedImage",
                    "foxglove.PointCloud", "foxglove.Log", "drivee2e.EpisodeMetrics"}


def test_payloads_carry_the_trace(exported):
    traces, _, _, messages = exported
    offsets = mx.episode_offsets(traces)
    assert offsets[1] > offsets[0] + traces[0].times[-1] * 1e9  # episodes one after another
    from PIL import Image

    for t, off in zip(traces, offsets):
        p = f"/{t.scenario_id}"
        by = {}
        for _, _, topic, msg in messages:
            by.setdefault(topic, []).append(msg)
        tf = [json.loads(m.data) for m in by[f"{p}/tf"]]
        np.testing.assert_allclose([[d["translation"]["x"], d["translation"]["y"]] for d in tf], t.ego_xy, atol=1e-5)
        yaw = [2 * np.arctan2(d["rotation"]["z"], d["rotation"]["w"]) for d in tf]
        np.testing.assert_allclose(np.angle(np.exp(1j * (np.array(yaw) - t.ego_yaw))), 0, atol=1e-5)
        assert [m.log_time for m in by[f"{p}/tf"]] == [off + int(round(x * 1e9)) for x in t.times]
        k = t.num_steps // 2
        # LiDAR: the packed points decode to the trace's valid returns.
        pc = json.loads(by[f"{p}/lidar"][k].data)
        pts = np.frombuffer(base64.b64decode(pc["data"]), mx._POINT_DTYPE)
        ok = t.lidar_valid[k]
        np.testing.assert_array_equal(np.stack([pts["x"], pts["y"], pts["z"]], 1), t.lidar_points[k][ok])
        np.testing.assert_array_equal(pts["class"], t.lidar_class[k][ok])
        # BEV: the PNG decodes to the colour picture of the trace's channels.
        img = json.loads(by[f"{p}/bev"][k].data)
        rgb = np.asarray(Image.open(io.BytesIO(base64.b64decode(img["data"]))).convert("RGB"))
        np.testing.assert_array_equal(rgb, episodes.bev_rgb(t.bev, k))
        assert t.bev["ego"][k].any()
        # Scene: one cube per valid agent; metrics: the timeline values.
        scene = json.loads(by[f"{p}/scene"][k].data)
        agents = next(e for e in scene["entities"] if e["id"] == "agents")
        assert len(agents["cubes"]) == int(t.agents.valid[k].sum())
        plan = next(e for e in scene["entities"] if e["id"] == "plan")["lines"][0]["points"]
        np.testing.assert_allclose([[q["x"], q["y"]] for q in plan[1:]], t.plan_xy[k], atol=1e-5)
        met = json.loads(by[f"{p}/metrics"][-1].data)
        assert met["route_completion"] == pytest.approx(float(t.timeline["route_completion"][-1]))
        logs = [json.loads(m.data)["message"] for m in by[f"{p}/infractions"]]
        assert [s.split(" at ")[0] for s in logs] == [e["type"] for e in sorted(t.events, key=lambda e: e["t"])]


def test_cli_exports_and_refuses_to_overwrite(run_dir, tmp_path, capsys):
    out = tmp_path / "one.mcap"
    assert main(["export-mcap", str(run_dir), "--scenario", "s_left", "--out", str(out), "--no-sensors"]) == 0
    assert "1 episode(s) of constant_velocity" in capsys.readouterr().out
    with out.open("rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert topics == {f"/s_left/{n}" for n in ("tf", "scene", "map", "metrics", "infractions")}
    before = out.read_bytes()
    assert main(["export-mcap", str(run_dir), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "exists; use --force" in err and err.count("\n") == 1
    assert out.read_bytes() == before


@pytest.mark.parametrize("args, message", [
    (["--scenario", "nope"], "--scenario nope: not in this run (2 scenarios: s_straight, s_left)"),
    (["--policy", "expert"], "--policy expert: not in"),
])
def test_cli_errors_are_one_line(run_dir, tmp_path, capsys, args, message):
    out = tmp_path / "x.mcap"
    assert main(["export-mcap", str(run_dir), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not out.exists() and not list(tmp_path.glob(".x.mcap*"))


def test_cli_rejects_a_folder_that_is_not_a_run(tmp_path, capsys):
    assert main(["export-mcap", str(tmp_path), "--out", str(tmp_path / "x.mcap")]) == 2
    assert "not a drivee2e results folder" in capsys.readouterr().err
