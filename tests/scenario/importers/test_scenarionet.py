"""ScenarioNet importer: the restricted unpickler, the shared nuScenes samples and tiny hand-written pickles."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import Polygon

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.importers import ImportOptions, load, scenarionet
from drivee2e_jax.scenario.importers.common import DEFAULT_SIZES
from drivee2e_jax.scenario.lane_polygons import lane_polygon, lane_polygon_source
from drivee2e_jax.scenario.validate import validate_records
from tests.helpers.importer_files import scenario_dict, write_pkl

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "nuscenes_scenarionet"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared real-data samples not found at {DATA}")


# ---------------------------------------------------------------- a tiny synthetic scenario
# (scenario_dict / write_pkl: tests/helpers/importer_files.py)


def test_tiny_scenario_converts(tmp_path):
    p = write_pkl(tmp_path / "sd_tiny.pkl", scenario_dict())
    r = load("scenarionet", [p], ImportOptions(split="val"))
    assert len(r.scenarios) == 1 and validate_records_ok(r)
    s = r.scenarios[0]
    assert s.scenario_id == "synthetic_tiny-1" and s.split == "val" and s.num_steps == 60 and s.ego_track_id == 0
    by_id = {r.meta["track_ids"][s.scenario_id][str(t.track_id)]: t for t in s.tracks}
    assert sorted(by_id) == ["car1", "ego", "ped"]
    assert by_id["car1"].category == "bus" and by_id["ped"].category == "pedestrian"
    np.testing.assert_allclose(by_id["ego"].size, [4.08, 1.73, 1.56])  # swapped: width > length
    np.testing.assert_allclose(by_id["ego"].xy[0], [-30 + scenarionet.EGO_CENTER_OFFSET_M, 0.0])
    np.testing.assert_allclose(by_id["car1"].xy[0], [-50.0, 0.0])  # other agents are not shifted
    reasons = {sk.source.split()[-1]: sk.reason for sk in r.skipped}
    assert "empty track" in reasons["ghost"] and "unknown category 'UFO'" in reasons["ufo"]
    m = r.maps[s.map_id]
    assert len(m.obstacles) == 1 and m.obstacles[0].kind == "cone"
    assert sorted(b.marking for b in m.boundaries) == ["road_edge", "solid"]
    assert len(m.crosswalks) == 1 and len(m.lanes) == 1 and m.lanes[0].width == pytest.approx(3.5)
    assert any("SPEED_BUMP x1" in n for n in r.notes) and any("swapped" in n for n in r.notes)


def test_lane_polygon_is_the_lane_area_and_a_bad_one_falls_back(tmp_path):
    """A lane's ``polygon`` (clockwise here) becomes its area as drawn; a bow tie is dropped with a note."""
    from drivee2e_jax.scenario.lane_polygons import signed_area

    d = scenario_dict()
    d["map_features"]["lane_a"]["polygon"] = np.array([[-60, 1.75], [60, 1.75], [60, -1.75], [-60, -1.75]])
    r = load("scenarionet", [write_pkl(tmp_path / "sd_cw.pkl", d)], ImportOptions())
    (ln,) = r.maps[r.scenarios[0].map_id].lanes
    assert lane_polygon_source(ln) == "polygon" and validate_records_ok(r)
    ring = lane_polygon(ln)
    assert signed_area(ring) == pytest.approx(120 * 3.5)  # made counter-clockwise, area kept
    assert sorted(map(tuple, ring)) == sorted(map(tuple, d["map_features"]["lane_a"]["polygon"].astype(float)))
    d["map_features"]["lane_a"]["polygon"] = np.array([[-60, -1.75], [60, 1.75], [60, -1.75], [-60, 1.0]])
    r = load("scenarionet", [write_pkl(tmp_path / "sd_bow.pkl", d)], ImportOptions())
    (ln,) = r.maps[r.scenarios[0].map_id].lanes
    assert ln.polygon is None and lane_polygon_source(ln) == "centerline"
    assert any("1 lane polygon(s) self-intersect or have no area" in n for n in r.notes)


def test_unstructured_lane_surface_is_a_connector(tmp_path):
    """ScenarioNet's nuScenes / nuPlan converters write junction connectors as LANE_SURFACE_UNSTRUCTURE."""
    d = scenario_dict()
    d["map_features"]["lane_a"]["type"] = "LANE_SURFACE_UNSTRUCTURE"
    r = load("scenarionet", [write_pkl(tmp_path / "sd_conn.pkl", d)], ImportOptions())
    assert [ln.type for ln in r.maps[r.scenarios[0].map_id].lanes] == ["connector"]


def test_zero_or_tiny_sizes_become_the_category_default(tmp_path):
    """Some conversions write 0 for an unknown size: such a box would never collide."""
    d = scenario_dict()
    d["tracks"]["car1"]["state"]["width"][:] = 0.0
    d["tracks"]["ped"]["state"]["length"][:] = 0.01
    r = load("scenarionet", [write_pkl(tmp_path / "sd_zero.pkl", d)], ImportOptions())
    s = r.scenarios[0]
    by_id = {r.meta["track_ids"][s.scenario_id][str(t.track_id)]: t for t in s.tracks}
    np.testing.assert_allclose(by_id["car1"].size, [11.0, DEFAULT_SIZES["bus"][1], 3.5])
    np.testing.assert_allclose(by_id["ped"].size, [DEFAULT_SIZES["pedestrian"][0], 0.7, 1.8])
    assert validate_records_ok(r)


def validate_records_ok(r) -> bool:
    from drivee2e_jax.records import SuiteRecord

    problems = validate_records(SuiteRecord("t", "1", r.maps, r.scenarios))
    assert problems == [], problems[:3]
    return True


def test_protocol_2_pickles_with_codecs_encode_load(tmp_path):
    p = write_pkl(tmp_path / "sd_p2.pkl", scenario_dict(), protocol=2)
    assert b"_codecs" in p.read_bytes()  # numpy arrays under protocol 2 go through _codecs.encode
    assert len(load("scenarionet", [p], ImportOptions()).scenarios) == 1


def test_two_hz_source_is_resampled_and_says_so(tmp_path):
    d = scenario_dict(n=13, dt=0.5)  # 6 s at 2 Hz
    t = np.arange(13) * 0.5
    d["tracks"]["car1"]["state"]["position"][:, 0] = -50 + 0.5 * t * t  # accelerating: no straight runs
    p = write_pkl(tmp_path / "sd_2hz.pkl", d)
    r = load("scenarionet", [p], ImportOptions())
    s = r.scenarios[0]
    assert s.num_steps == 61 and s.dt == pytest.approx(0.1)
    ego = next(t for t in s.tracks if t.track_id == 0)
    assert len(ego.t) == 61
    np.testing.assert_allclose(np.diff(ego.xy[:, 0]), 60 / 60, atol=1e-9)  # linear motion stays linear
    assert any("source step 0.5 s resampled to 0.1 s" in n for n in r.notes)
    assert any("interpolated between sparser keyframes" in n for n in r.notes) is False  # measured at 2 Hz


def test_bad_inputs_are_one_line_errors(tmp_path):
    d = scenario_dict()
    del d["tracks"]
    with pytest.raises(DriveE2EError, match=r"sd_a.pkl: missing field 'tracks'"):
        load("scenarionet", [write_pkl(tmp_path / "sd_a.pkl", d)], ImportOptions())
    d = scenario_dict()
    d["metadata"]["sdc_id"] = "nobody"
    with pytest.raises(DriveE2EError, match=r"sd_b.pkl: metadata.sdc_id 'nobody' is not a track id"):
        load("scenarionet", [write_pkl(tmp_path / "sd_b.pkl", d)], ImportOptions())
    d = scenario_dict()
    d["tracks"]["car1"]["state"]["position"] = d["tracks"]["car1"]["state"]["position"][:10]
    with pytest.raises(DriveE2EError, match=r"tracks\['car1'\].state.position: expected 60 rows"):
        load("scenarionet", [write_pkl(tmp_path / "sd_c.pkl", d)], ImportOptions())
    with pytest.raises(DriveE2EError, match="--ego 'zzz' is not a track id"):
        load("scenarionet", [write_pkl(tmp_path / "sd_d.pkl", scenario_dict())], ImportOptions(ego="zzz"))
    (tmp_path / "sd_e.pkl").write_bytes(b"garbage")
    with pytest.raises(DriveE2EError, match="sd_e.pkl: not a readable pickle"):
        load("scenarionet", [tmp_path / "sd_e.pkl"], ImportOptions())
    write_pkl(tmp_path / "sd_f.pkl", [1, 2, 3])
    with pytest.raises(DriveE2EError, match="expected a ScenarioNet scenario dict"):
        load("scenarionet", [tmp_path / "sd_f.pkl"], ImportOptions())
    with pytest.raises(DriveE2EError, match="expected a ScenarioNet .pkl"):
        load("scenarionet", [tmp_path / "sd_a.pkl"][:0] + [_touch(tmp_path / "x.txt")], ImportOptions())


def _touch(p: Path) -> Path:
    p.write_text("x")
    return p


class _Evil:
    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_malicious_pickle_is_refused_and_never_runs(tmp_path):
    marker = tmp_path / "pwned"
    d = scenario_dict()
    d["metadata"]["payload"] = _Evil(str(marker))
    p = write_pkl(tmp_path / "sd_evil.pkl", d)
    with pytest.raises(DriveE2EError) as e:
        load("scenarionet", [p], ImportOptions())
    msg = str(e.value)
    assert "sd_evil.pkl: refused to load global" in msg and ".system" in msg and "\n" not in msg
    assert not marker.exists()
    # the plain unpickler would have run it: the test can fail
    with open(p, "rb") as f:
        pickle.load(f)
    assert marker.exists()


class _HugeArray:
    """Unpickles as ``_reconstruct(ndarray, (10**15,), 'b')``: a 10^15-byte allocation."""

    def __reduce__(self):
        return (np.ndarray.__reduce__(np.zeros(0, np.int8))[0], (np.ndarray, (10**15,), b"b"))


class _HugeObjectArray:
    """An object array whose pickled state declares 10^14 slots but holds one item."""

    def __reduce__(self):
        fn, args, _ = np.ndarray.__reduce__(np.zeros(0, object))
        return (fn, args, (1, (10**14,), np.dtype("O"), False, [1]))


class _HugeBytearray:
    def __reduce__(self):
        return (bytearray, (10**15,))


@pytest.mark.parametrize("payload", [_HugeArray, _HugeObjectArray, _HugeBytearray])
@pytest.mark.parametrize("protocol", [2, 5])
def test_huge_declared_allocations_are_refused(tmp_path, payload, protocol):
    d = scenario_dict()
    d["metadata"]["payload"] = payload()
    p = tmp_path / "sd_huge.pkl"
    p.write_bytes(pickle.dumps(d, protocol=protocol))
    with pytest.raises(DriveE2EError) as e:
        scenarionet.safe_load(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: refused an array of shape (") and "x the file size" in msg and "\n" not in msg
    # the plain unpickler really asks for it: the test can fail
    with pytest.raises(MemoryError):
        pickle.loads(p.read_bytes())


def test_huge_opcode_length_is_refused_before_allocating(tmp_path):
    p = tmp_path / "sd_bytes8.pkl"
    p.write_bytes(b"\x80\x05\x8e" + (10**15).to_bytes(8, "little") + b"abc.")  # BINBYTES8 of 10^15 bytes
    with pytest.raises(MemoryError):
        pickle.loads(p.read_bytes())
    with pytest.raises(DriveE2EError, match=r"sd_bytes8.pkl: not a readable pickle \(ValueError: expected 10+ bytes"):
        scenarionet.safe_load(p)


def test_loaded_arrays_are_plain_ndarrays(tmp_path):
    p = write_pkl(tmp_path / "sd_plain.pkl", scenario_dict())
    raw = scenarionet.safe_load(p)
    pos = raw["tracks"]["ego"]["state"]["position"]
    assert type(pos) is np.ndarray
    np.testing.assert_array_equal(pos, pickle.loads(p.read_bytes())["tracks"]["ego"]["state"]["position"])


def _laughs(levels: int = 45) -> bytes:
    x: list = []
    for _ in range(levels):
        x = [x, x]  # every level points twice at the same list: 2**45 paths, ~300 bytes
    return pickle.dumps({"id": "a", "metadata": {"sdc_id": "1", "ts": x}, "tracks": {"1": {"state": {"position": x}}}},
                        protocol=2)


def test_billion_laughs_pickle_is_refused_quickly(tmp_path):
    import subprocess
    import sys
    import time

    p = tmp_path / "laughs.pkl"
    p.write_bytes(_laughs())
    assert len(p.read_bytes()) < 600
    code = ("import sys; from drivee2e_jax.scenario.importers import scenarionet\n"
            "try:\n    scenarionet.safe_load(sys.argv[1])\nexcept Exception as e:\n    print(e); sys.exit(2)\n")
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, timeout=60,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[3])})
    elapsed = time.perf_counter() - t0
    assert out.returncode == 2, out.stderr
    assert "billion laughs" in out.stdout and str(p) in out.stdout
    assert elapsed < 20  # includes interpreter + numpy start-up; the walk itself is milliseconds


def test_walk_is_linear_and_keeps_sharing(tmp_path):
    import time

    x: list = []
    for _ in range(20):  # 2**20 paths: accepted, but must cost ~20 visits, not a million
        x = [x, x]
    arr = np.arange(4.0)
    p = tmp_path / "shared.pkl"
    p.write_bytes(pickle.dumps({"a": x, "b": [arr, arr]}, protocol=2))
    t0 = time.perf_counter()
    raw = scenarionet.safe_load(p)
    assert time.perf_counter() - t0 < 0.5
    assert raw["a"][0] is raw["a"][1]
    assert type(raw["b"][0]) is np.ndarray and raw["b"][0] is raw["b"][1]


def test_too_deep_nesting_is_refused(tmp_path):
    x: list = []
    for _ in range(scenarionet.MAX_PICKLE_DEPTH + 5):
        x = [x]
    p = write_pkl(tmp_path / "deep.pkl", {"a": x})
    with pytest.raises(DriveE2EError, match="nested deeper than"):
        scenarionet.safe_load(p)


@pytest.mark.parametrize("payload", [
    ("builtins", "eval"), ("subprocess", "Popen"), ("numpy", "load"), ("numpy.lib.npyio", "load"),
])
def test_unpickler_refuses_other_globals(payload):
    import io

    with pytest.raises(DriveE2EError, match=f"refused to load global {payload[0]}.{payload[1]}"):
        scenarionet.SafeUnpickler(io.BytesIO(b""), source="x.pkl").find_class(*payload)


# ---------------------------------------------------------------- the shared nuScenes samples


@needs_data
def test_shared_nuscenes_samples_import():
    files = sorted(DATA.glob("sd_*.pkl"))
    assert len(files) == 2
    r = load("scenarionet", files, ImportOptions())
    assert validate_records_ok(r)
    assert [s.scenario_id for s in r.scenarios] == ["nuscenes_scene-0061", "nuscenes_scene-0103"]
    for f, s in zip(files, r.scenarios):
        raw = scenarionet.safe_load(f)
        assert s.num_steps == raw["length"]  # 191 / 196 steps at 0.1 s
        road_users = {k for k, t in raw["tracks"].items()
                      if t["type"] in ("VEHICLE", "PEDESTRIAN", "CYCLIST") and t["state"]["valid"].any()}
        assert len(s.tracks) == len(road_users)
        ego = next(t for t in s.tracks if t.track_id == s.ego_track_id)
        assert len(ego.t) == s.num_steps
        src = raw["tracks"]["ego"]["state"]
        shift = ego.xy - src["position"][:, :2]
        np.testing.assert_allclose(np.linalg.norm(shift, axis=1), scenarionet.EGO_CENTER_OFFSET_M, atol=1e-3)
        route_len = np.sum(np.linalg.norm(np.diff(s.route.waypoints, axis=0), axis=1))
        assert route_len > 80  # the README: ~92 m and ~119 m
        m = r.maps[s.map_id]
        assert any(ln.successors for ln in m.lanes)  # inferred from geometry
        # nuScenes lanes carry their polygon, lane connectors do not (ScenarioNet drops theirs)
        feats = {tuple(np.round(np.asarray(f["polyline"])[0, :2], 6)): f for f in raw["map_features"].values()
                 if str(f["type"]).startswith("LANE")}
        for ln in m.lanes:
            f = feats[tuple(np.round(ln.centerline[0], 6))]
            assert lane_polygon_source(ln) == ("polygon" if "polygon" in f else "centerline")
            # this (pre-69a3d7a) conversion types connectors LANE_SURFACE_STREET: no polygon = a connector
            assert ln.type == ("driving" if "polygon" in f else "connector")
            if "polygon" in f:
                assert Polygon(lane_polygon(ln)).equals(Polygon(np.asarray(f["polygon"])[:, :2]))
        assert {lane_polygon_source(ln) for ln in m.lanes} == {"polygon", "centerline"}
    assert any("% of moving agent samples lie exactly on straight" in n for n in r.notes)
    assert r.meta["interpolated_fraction"]["nuscenes_scene-0061"] > 0.5
