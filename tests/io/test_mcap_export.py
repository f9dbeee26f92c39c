"""MCAP export: read the file back with the mcap reader and check every channel, count and message
against the schemas Foxglove publishes (the ``foxglove-schemas-protobuf`` classes, and the
FileDescriptorSet each schema record carries, as a reader that has only the file would)."""

from __future__ import annotations

import importlib
import io
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from google.protobuf import descriptor_pool, message_factory
from google.protobuf.descriptor_pb2 import FileDescriptorProto, FileDescriptorSet
from mcap.reader import make_reader

from drivee2e_jax.cli import main
from drivee2e_jax.cli.export_mcap import EPILOG
from drivee2e_jax.eval import traces as episodes
from drivee2e_jax.eval.bench import BenchConfig, run_bench
from drivee2e_jax.io import mcap_export as mx
from drivee2e_jax.io.foxglove_schemas import to_ns
from drivee2e_jax.observe.bev import BevConfig
from drivee2e_jax.observe.lidar import LidarConfig
from drivee2e_jax.observe.sensors import SensorConfig
from drivee2e_jax.scenario.suite import load_suite

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny"
SMALL_SENSORS = SensorConfig(bev=BevConfig(height=32, width=32, resolution=1.0), lidar=LidarConfig(channels=4, azimuth_bins=32))
PER_STEP = ("tf", "origin", "scene", "bev", "lidar", "metrics")
FOXGLOVE = {"foxglove.FrameTransform", "foxglove.SceneUpdate", "foxglove.CompressedImage", "foxglove.PointCloud",
            "foxglove.Log"}


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
        messages = list(reader.iter_messages())
    return traces, path, summary, messages


def _by_topic(messages) -> dict:
    out = {}
    for _, ch, msg in messages:
        out.setdefault(ch.topic, []).append(msg)
    return out


# --------------------------------------------------------------------------
# Validation against the published schemas
# --------------------------------------------------------------------------


def official_class(schema_name: str):
    """The class foxglove-schemas-protobuf publishes for ``foxglove.<Name>`` (looked up by name, not via mx)."""
    pkg, name = schema_name.split(".")
    assert pkg == "foxglove", schema_name
    return getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)


def class_from_record(schema):
    """The class a reader with only the file builds: the schema record's FileDescriptorSet, in a fresh pool."""
    pool = descriptor_pool.DescriptorPool()
    for f in FileDescriptorSet.FromString(schema.data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def parse_exactly(cls, data: bytes):
    """Parse ``data`` with ``cls``; every byte must belong to a field the schema defines."""
    msg = cls.FromString(data)
    known = cls()
    known.CopyFrom(msg)
    known.DiscardUnknownFields()
    assert known.SerializeToString() == data, f"{cls.DESCRIPTOR.full_name}: fields the schema does not define"
    return msg


def _walk(msg):
    """Every message in ``msg``'s tree, ``msg`` first."""
    yield msg
    for fd, value in msg.ListFields():
        if fd.message_type is not None:
            for v in value if fd.is_repeated else [value]:
                yield from _walk(v)


def check_foxglove_rules(msg, log_time: int, where: str) -> None:
    """What Foxglove's schema docs ask beyond types: stamps, one of color/colors, unit quaternions,
    colours in [0, 1], packed point layout, a PNG image, entity ids and lifetimes."""
    if "timestamp" in msg.DESCRIPTOR.fields_by_name:
        assert to_ns(msg.timestamp) == log_time, where
    for m in _walk(msg):
        kind = m.DESCRIPTOR.full_name
        if kind == "foxglove.SceneEntity":
            assert m.id and m.frame_id == "map" and to_ns(m.timestamp) == log_time and to_ns(m.lifetime) > 0, where
        elif kind == "foxglove.LinePrimitive":
            assert m.HasField("color") or len(m.colors) == len(m.points) > 0, f"{where}: no color/colors"
            assert m.thickness > 0 and m.type in (0, 1, 2) and all(i < len(m.points) for i in m.indices), where
        elif kind == "foxglove.Quaternion":
            assert math.isclose(m.x**2 + m.y**2 + m.z**2 + m.w**2, 1.0, abs_tol=1e-9), where
        elif kind == "foxglove.Color":
            assert all(0 <= c <= 1 for c in (m.r, m.g, m.b, m.a)), where
        elif kind == "foxglove.PointCloud":
            names = {f.name for f in m.fields}
            assert len(names & {"x", "y", "z"}) >= 2 and len(m.data) % m.point_stride == 0, where
            assert all(f.offset < m.point_stride and f.type != 0 for f in m.fields), where
        elif kind == "foxglove.CompressedImage":
            assert m.format == "png" and m.data.startswith(b"\x89PNG\r\n\x1a\n") and m.frame_id, where
        elif kind == "foxglove.Log":
            assert m.level == m.WARNING and m.message and m.name, where


def check_json(value, schema: dict, where: str) -> None:
    """A small JSON Schema check of our metrics message: types, bounds, required, no extra fields."""
    kinds = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
    ok = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None),
          "integer": int, "number": (int, float)}
    assert any(isinstance(value, ok[k]) and not (k in ("integer", "number") and isinstance(value, bool))
               for k in kinds), f"{where}: {type(value).__name__} is not {kinds}"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        assert schema.get("minimum", -np.inf) <= value <= schema.get("maximum", np.inf), where
    if isinstance(value, dict):
        props = schema["properties"]
        assert set(schema["required"]) <= set(value) <= set(props), f"{where}: fields {sorted(set(value) ^ set(props))}"
        for k, v in value.items():
            check_json(v, props[k], f"{where}.{k}")


def test_every_channel_schema_and_message_count(exported):
    traces, _, summary, messages = exported
    assert len(traces) == 2
    channels = {c.topic: (summary.schemas[c.schema_id], c.message_encoding) for c in summary.channels.values()}
    counts = {c.topic: summary.statistics.channel_message_counts[i] for i, c in summary.channels.items()}
    want = {}
    for t in traces:
        p = f"/{t.scenario_id}"
        want.update({f"{p}/tf": "foxglove.FrameTransform", f"{p}/origin": "foxglove.FrameTransform",
                     f"{p}/scene": "foxglove.SceneUpdate",
                     f"{p}/map": "foxglove.SceneUpdate", f"{p}/bev": "foxglove.CompressedImage",
                     f"{p}/lidar": "foxglove.PointCloud", f"{p}/metrics": "drivee2e.EpisodeMetrics",
                     f"{p}/infractions": "foxglove.Log"})
        for name in PER_STEP:
            assert counts[f"{p}/{name}"] == t.num_steps
        assert counts[f"{p}/map"] == 1
        assert counts[f"{p}/infractions"] == len(t.events) > 0
    assert {k: v[0].name for k, v in channels.items()} == want
    for schema, encoding in channels.values():
        is_foxglove = schema.name in FOXGLOVE
        assert (schema.encoding, encoding) == (("protobuf", "protobuf") if is_foxglove else ("jsonschema", "json"))
    assert len(summary.schemas) == len(FOXGLOVE) + 1  # one record per schema, shared by the episodes
    assert len(messages) == sum(counts.values())
    assert sum(counts[f"/{t.scenario_id}/{n}"] for t in traces for n in PER_STEP) == len(PER_STEP) * sum(
        t.num_steps for t in traces)


def test_schema_records_are_the_published_descriptors(exported):
    """Each protobuf schema record holds Foxglove's own .proto files, byte for byte."""
    _, _, summary, _ = exported
    for schema in summary.schemas.values():
        if schema.encoding != "protobuf":
            continue
        files = {f.name: f for f in FileDescriptorSet.FromString(schema.data).file}
        published = official_class(schema.name).DESCRIPTOR.file
        todo = [published]
        while todo:
            fd = todo.pop()
            want = FileDescriptorProto()
            fd.CopyToProto(want)
            assert files.pop(fd.name) == want, f"{schema.name}: {fd.name} differs from the published file"
            todo += [d for d in fd.dependencies if d.name in files]
        assert not files, f"{schema.name}: files that are not its dependencies: {sorted(files)}"
        assert class_from_record(schema).DESCRIPTOR.full_name == schema.name


def test_every_message_parses_with_the_published_schema(exported):
    _, _, _, messages = exported
    from_record = {}
    seen = set()
    for schema, ch, msg in messages:
        where = f"{ch.topic}#{msg.sequence}"
        assert msg.log_time == msg.publish_time, where
        if schema.encoding == "protobuf":
            parsed = parse_exactly(official_class(schema.name), msg.data)
            cls = from_record.setdefault(schema.id, class_from_record(schema))
            assert parse_exactly(cls, msg.data).SerializeToString() == parsed.SerializeToString(), where
            check_foxglove_rules(parsed, msg.log_time, where)
        else:
            payload = json.loads(msg.data)
            check_json(payload, json.loads(schema.data), where)
            assert payload["timestamp"]["sec"] * 10**9 + payload["timestamp"]["nsec"] == msg.log_time, where
        seen.add(schema.name)
    assert seen == FOXGLOVE | {mx.METRICS_SCHEMA_NAME}


def test_a_message_with_an_undefined_field_fails_the_check():
    """The exactness check can fail: bytes of a field number Log does not define are caught."""
    cls = official_class("foxglove.Log")
    good = cls(message="x").SerializeToString()
    parse_exactly(cls, good)
    with pytest.raises(AssertionError, match="does not define"):
        parse_exactly(cls, good + b"\xa8\x06\x01")  # field 101, varint 1


def test_timestamps_are_integer_ns_on_the_dt_grid(exported):
    traces, _, summary, messages = exported
    by = _by_topic(messages)
    offsets = mx.episode_offsets(traces)
    assert offsets == [int(m.metadata["offset_ns"]) for m in _metadata(exported[1])]
    for t, off in zip(traces, offsets):
        dt_ns = mx.step_ns(t.dt)
        assert dt_ns == 100_000_000
        grid = [off + k * dt_ns for k in range(t.num_steps)]
        for name in PER_STEP:
            assert [m.log_time for m in by[f"/{t.scenario_id}/{name}"]] == grid, name
        met = [json.loads(m.data) for m in by[f"/{t.scenario_id}/metrics"]]
        assert [d["t"] for d in met] == [k / 10 for k in range(t.num_steps)]  # 4.1, not 4.099999905
    t0 = traces[0]
    assert t0.num_steps > 41
    assert by[f"/{t0.scenario_id}/tf"][41].log_time == offsets[0] + 4_100_000_000
    assert offsets[1] == offsets[0] + (t0.num_steps - 1) * 100_000_000 + mx.EPISODE_GAP_NS
    for t, off in zip(traces, offsets):  # an event at t s is stamped at step round(t / dt)
        logs = by[f"/{t.scenario_id}/infractions"]
        want = sorted(off + round(float(e["t"]) * 10) * 100_000_000 for e in t.events)
        assert [m.log_time for m in logs] == want


def _metadata(path: Path) -> list:
    with path.open("rb") as f:
        return [m for m in make_reader(f).iter_metadata() if m.name == "drivee2e.episode"]


def test_step_stamps_come_from_the_step_index_not_float_times():
    tr = SimpleNamespace(dt=0.1, num_steps=50)
    stamps = mx.episode_stamps(tr, 7_000_000_000)
    assert stamps[41] == 7_000_000_000 + 4_100_000_000 and all(type(s) is int for s in stamps)
    assert mx.episode_offsets([tr, tr]) == [0, 49 * 100_000_000 + mx.EPISODE_GAP_NS]
    assert mx.step_ns(0.05) == 50_000_000
    assert mx.event_step({"t": float(np.float32(4.1))}, 0.1, 50) == 41
    assert mx.event_step({"t": 99.0}, 0.1, 50) == 49 and mx.event_step({"t": -1.0}, 0.1, 50) == 0


def test_payloads_carry_the_trace(exported):
    traces, _, _, messages = exported
    by = _by_topic(messages)
    log, scene_update, image, cloud = (official_class(f"foxglove.{n}") for n in ("Log", "SceneUpdate", "CompressedImage",
                                                                                 "PointCloud"))
    transform = official_class("foxglove.FrameTransform")
    from PIL import Image

    for t in traces:
        p = f"/{t.scenario_id}"
        tf = [transform.FromString(m.data) for m in by[f"{p}/tf"]]
        assert {(d.parent_frame_id, d.child_frame_id) for d in tf} == {("map", "ego")}
        # world -> map carries the scenario's origin at every step (map -> ego: the local ego pose).
        placed = [transform.FromString(m.data) for m in by[f"{p}/origin"]]
        assert {(d.parent_frame_id, d.child_frame_id) for d in placed} == {("world", "map")}
        assert {(d.translation.x, d.translation.y) for d in placed} == {tuple(float(v) for v in t.origin)}
        np.testing.assert_allclose([[d.translation.x, d.translation.y] for d in tf], t.ego_xy, atol=1e-5)
        yaw = [2 * np.arctan2(d.rotation.z, d.rotation.w) for d in tf]
        np.testing.assert_allclose(np.angle(np.exp(1j * (np.array(yaw) - t.ego_yaw))), 0, atol=1e-5)
        k = t.num_steps // 2
        # LiDAR: the packed points decode to the trace's valid returns.
        pc = cloud.FromString(by[f"{p}/lidar"][k].data)
        pts = np.frombuffer(pc.data, mx._POINT_DTYPE)
        assert pc.point_stride == mx._POINT_DTYPE.itemsize == 13
        assert [(f.name, f.offset, f.type) for f in pc.fields] == [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("class", 12, 1)]
        ok = t.lidar_valid[k]
        np.testing.assert_array_equal(np.stack([pts["x"], pts["y"], pts["z"]], 1), t.lidar_points[k][ok])
        np.testing.assert_array_equal(pts["class"], t.lidar_class[k][ok])
        # BEV: the PNG decodes to the colour picture of the trace's channels.
        img = image.FromString(by[f"{p}/bev"][k].data)
        rgb = np.asarray(Image.open(io.BytesIO(img.data)).convert("RGB"))
        np.testing.assert_array_equal(rgb, episodes.bev_rgb(t.bev, k))
        assert t.bev["ego"][k].any()
        # Scene: one cube per valid agent, the plan; the map: one entity per layer, for the whole episode.
        scene = scene_update.FromString(by[f"{p}/scene"][k].data)
        ents = {e.id: e for e in scene.entities}
        assert len(ents["agents"].cubes) == int(t.agents.valid[k].sum())
        assert ents["ego"].cubes[0].size.x == pytest.approx(float(t.ego_size[0]))
        plan = ents["plan"].lines[0].points
        np.testing.assert_allclose([[q.x, q.y] for q in plan[1:]], t.plan_xy[k], atol=1e-5)
        (map_msg,) = by[f"{p}/map"]
        layers = {e.id: e for e in scene_update.FromString(map_msg.data).entities}
        assert set(layers) == {"drivable", "lanes", "boundaries", "crosswalks", "stop_lines", "obstacles", "route"}
        assert len(layers["lanes"].lines) == len(t.map.lanes)
        assert to_ns(layers["route"].lifetime) == t.num_steps * mx.step_ns(t.dt)
        np.testing.assert_allclose([[q.x, q.y] for q in layers["route"].lines[0].points], t.route_xy, atol=1e-9)
        met = json.loads(by[f"{p}/metrics"][-1].data)
        assert met["route_completion"] == pytest.approx(float(t.timeline["route_completion"][-1]))
        logs = [log.FromString(m.data).message for m in by[f"{p}/infractions"]]
        assert [s.split(" at ")[0] for s in logs] == [e["type"] for e in sorted(t.events, key=lambda e: e["t"])]


def test_help_examples_name_what_bench_writes_by_default():
    """The --help examples read results/twin15-val (bench's default --out for --split val) and name
    scenarios among the first 5 of twin15's val split, so they run after `drivee2e bench --split val --limit 5`."""
    lines = [ln.split() for ln in EPILOG.splitlines() if ln.strip().startswith("drivee2e export-mcap")]
    assert len(lines) >= 2 and {ln[2] for ln in lines} == {"results/twin15-val"}
    named = {ln[i + 1] for ln in lines for i, a in enumerate(ln) if a == "--scenario"}
    suite = load_suite("twin15")
    first_val = {str(suite.meta.scenario_id[i]) for i in suite.split_rows("val")[:5]}
    assert named and named <= first_val, sorted(named - first_val)


def test_cli_exports_and_refuses_to_overwrite(run_dir, tmp_path, capsys):
    out = tmp_path / "one.mcap"
    assert main(["export-mcap", str(run_dir), "--scenario", "s_left", "--out", str(out), "--no-sensors"]) == 0
    assert "1 episode(s) of constant_velocity" in capsys.readouterr().out
    with out.open("rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert topics == {f"/s_left/{n}" for n in ("tf", "origin", "scene", "map", "metrics", "infractions")}
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


def test_collision_event_log_names_type_and_fault_and_metadata_carries_both_ds():
    tr = SimpleNamespace(scenario_id="s0", policy="p", num_steps=10, driving_score=60.0, stored_driving_score=60.0,
                         row={"driving_score_all": 60.0, "driving_score_at_fault": 100.0, "collisions_at_fault": 0})
    ev = {"type": "collisions_vehicle", "t": 1.5, "x": 1.0, "collision_type": "active_rear", "at_fault": False}
    msg = mx.infraction_log(tr, ev, 0).message
    assert msg.startswith("collisions_vehicle at t=1.5 s [active_rear, not at fault] (")
    assert "collision_type=active_rear" in msg and "at_fault=False" in msg
    lay = {"type": "collisions_layout", "t": 2.0, "collision_type": "static", "at_fault": True}
    assert mx.infraction_log(tr, lay, 0).message.startswith("collisions_layout at t=2.0 s [static, at fault] (")
    assert mx.infraction_log(tr, {"type": "red_light", "t": 1.0}, 0).message.startswith("red_light at t=1.0 s")
    md = mx.episode_metadata(tr, 5)
    assert (md["driving_score_all"], md["driving_score_at_fault"], md["collisions_at_fault"]) == (
        "60.0000", "100.0000", "0")
    assert all(isinstance(v, str) for v in md.values()) and md["offset_ns"] == "5"
    old = mx.episode_metadata(SimpleNamespace(**{**vars(tr), "row": {"driving_score": 60.0}}), 0)
    assert "driving_score_all" not in old and old["driving_score"] == "60.0000"


def test_map_frame_sits_at_the_scenario_origin():
    """Entities live in ``map`` (the local frame the simulator computes in); ``world`` -> ``map``
    carries the packed ``meta.origin`` in float64, so a UTM scene keeps its world coordinates."""
    tr = SimpleNamespace(scenario_id="s0", policy="p", num_steps=10, driving_score=60.0, stored_driving_score=60.0,
                         row={}, origin=np.array([4000000.0, 512345.5]))
    tf = mx.map_transform(tr, 7)
    assert (tf.parent_frame_id, tf.child_frame_id) == ("world", "map") and to_ns(tf.timestamp) == 7
    assert (tf.translation.x, tf.translation.y, tf.translation.z) == (4000000.0, 512345.5, 0.0)
    assert (tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w) == (0.0, 0.0, 0.0, 1.0)
    md = mx.episode_metadata(tr, 0)
    assert (float(md["origin_x"]), float(md["origin_y"])) == (4000000.0, 512345.5)
