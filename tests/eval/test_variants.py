"""scenario.variants: visibility along the logged ego run, filtered variants, mask cache, `bench --variant`.

The scene (every agent moves with the ego, so the geometry holds for the
whole log): the ego drives east along y = 0; a bus 12 m ahead hides a car
25 m ahead; a 10 m high wall along y in [4, 6] hides a car and a pedestrian
north of it; a car follows 12 m behind in plain sight. Twin scenarios
without the wall / without the bus show the hidden agents are in the
cameras' view otherwise (the oracle is the geometry, not the code).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.eval import variants
from drivee2e_jax.observe.camera import CameraConfig, CameraRigConfig
from drivee2e_jax.records import (
    LaneRecord,
    MapRecord,
    ObstacleRecord,
    RouteRecord,
    ScenarioRecord,
    SuiteRecord,
    TrackRecord,
)
from drivee2e_jax.scenario.filters import filter_invisible, filter_invisible_packed
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.scenario.pack import pack
from drivee2e_jax.scenario.suite import Suite

DT, STEPS, SPEED = 0.1, 20, 5.0
RIG = CameraRigConfig(cameras=(CameraConfig("front", (1.7, 0.0, 1.5), 0.0, 70.0, 16, 9),
                               CameraConfig("back", (-1.0, 0.0, 1.5), 180.0, 110.0, 16, 9)))
CFG = variants.VisibilityConfig(rig=RIG, block=64)
EGO, BUS, CAR_BEHIND_BUS, CAR_BEHIND_WALL, PED_BEHIND_WALL, CAR_FOLLOWING = 1, 2, 3, 4, 5, 6
#: (track id, category, offset from the ego (m), size l/w/h)
AGENTS = [
    (EGO, "car", (0.0, 0.0), (4.5, 1.9, 1.5)),
    (BUS, "bus", (12.0, 0.0), (12.0, 2.5, 3.5)),
    (CAR_BEHIND_BUS, "car", (25.0, 0.0), (4.5, 1.9, 1.5)),
    (CAR_BEHIND_WALL, "car", (30.0, 12.0), (4.5, 1.9, 1.5)),
    (PED_BEHIND_WALL, "pedestrian", (20.0, 9.0), (0.6, 0.6, 1.7)),
    (CAR_FOLLOWING, "car", (-12.0, 0.0), (4.5, 1.9, 1.5)),
]


def _map(wall: bool) -> MapRecord:
    lane = LaneRecord(1, np.stack([np.linspace(-60, 100, 17), np.zeros(17)], 1), width=3.5)
    walls = [ObstacleRecord(np.array([[-60.0, 4.0], [100.0, 4.0], [100.0, 6.0], [-60.0, 6.0]]), 10.0)]
    return MapRecord(map_id="wall" if wall else "open", lanes=[lane],
                     drivable_areas=[np.array([[-60.0, -4.0], [100.0, -4.0], [100.0, 4.0], [-60.0, 4.0]])],
                     obstacles=walls if wall else [])


def _scenario(sid: str, wall: bool = True, without: tuple[int, ...] = (), split: str = "val") -> ScenarioRecord:
    k = np.arange(STEPS)
    ego_x = SPEED * k * DT
    tracks = [TrackRecord(tid, cat, np.array(size, float), k * DT,
                          np.stack([ego_x + dx, np.full(STEPS, dy)], 1), np.zeros(STEPS), np.tile([SPEED, 0.0], (STEPS, 1)))
              for tid, cat, (dx, dy), size in AGENTS if tid not in without]
    route = RouteRecord(np.array([[0.0, 0.0], [ego_x[-1], 0.0]]), np.array([0.0, 0.0]), np.array([ego_x[-1], 0.0]))
    return ScenarioRecord(sid, split, "i0", "wall" if wall else "open", "STR", "clear", "day", EGO, route, DT, STEPS,
                          tracks)


def _suite() -> SuiteRecord:
    scns = [_scenario("occluded"), _scenario("no_wall", wall=False), _scenario("no_bus", without=(BUS,)),
            _scenario("train_twin", split="train")]
    return SuiteRecord("walls", "1", {m.map_id: m for m in (_map(True), _map(False))}, scns)


@pytest.fixture(scope="module")
def suite():
    return Suite.from_records(_suite())


@pytest.fixture(scope="module")
def seen(suite):
    """{scenario id: {track id: visible at every step}} of the val split (one masks computation)."""
    batch = suite.pack("val")
    vis = variants.reference_visibility(batch, CFG)
    ids = np.asarray(batch.scenario.tracks.track_id)
    return {sid: {int(t): bool(vis[b, a, :STEPS].all()) for a, t in enumerate(ids[b]) if t >= 0}
            for b, sid in enumerate(batch.meta.scenario_id)}


def test_reference_visibility_follows_the_geometry(seen):
    hidden = {CAR_BEHIND_BUS, CAR_BEHIND_WALL, PED_BEHIND_WALL}
    assert seen["occluded"] == {EGO: False, BUS: True, **{t: False for t in hidden}, CAR_FOLLOWING: True}
    # not vacuous: without the wall / the bus the same agents are in view all along
    assert seen["no_wall"][CAR_BEHIND_WALL] and seen["no_wall"][PED_BEHIND_WALL]
    assert not seen["no_wall"][CAR_BEHIND_BUS]
    assert seen["no_bus"][CAR_BEHIND_BUS] and not seen["no_bus"][CAR_BEHIND_WALL]


def _assert_same(got, want):
    """Two packed batches hold the same arrays and meta table."""
    a, b = flatten_scenario(got.scenario), flatten_scenario(want.scenario)
    for k in b:
        np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)
    for k, v in want.meta.columns().items():
        np.testing.assert_array_equal(getattr(got.meta, k), v, err_msg=k)


def _track_ids(batch):
    ids = np.asarray(batch.scenario.tracks.track_id)
    return {sid: sorted(int(t) for t in ids[b] if t >= 0) for b, sid in enumerate(batch.meta.scenario_id)}


def test_variants_remove_the_hidden_agents_and_keep_the_visible(suite, seen, drivee2e_cache):
    complete = suite.pack("val")
    same = variants.suite_variant(suite, "val", "complete", CFG)
    _assert_same(same.batch, complete)
    assert same.record == {} and same.removed == 0 and same.agents == 5 + 5 + 4

    veh = variants.suite_variant(suite, "val", "visible_vehicles", CFG)
    assert veh.record["removed"] == {"occluded": [CAR_BEHIND_BUS, CAR_BEHIND_WALL], "no_wall": [CAR_BEHIND_BUS],
                                     "no_bus": [CAR_BEHIND_WALL]}
    assert _track_ids(veh.batch)["occluded"] == [EGO, BUS, PED_BEHIND_WALL, CAR_FOLLOWING]
    assert veh.by_category["car"] == (4, 9) and veh.by_category["pedestrian"] == (0, 3)
    assert veh.batch.sizes == complete.sizes and list(veh.batch.meta.num_agents) == [4, 5, 4]
    assert "removed 4 of 14 non-ego agents" in veh.summary()

    every = variants.suite_variant(suite, "val", "visible_all", CFG)
    assert every.record["removed"]["occluded"] == [CAR_BEHIND_BUS, CAR_BEHIND_WALL, PED_BEHIND_WALL]
    assert every.removed == 6 and every.by_category["pedestrian"] == (2, 3)

    # the packed filter is bit for bit the records filter packed with the same sizes
    for name, var in (("visible_vehicles", veh), ("visible_all", every)):
        rec = variants.variant_records(suite, "val", name, CFG)
        assert rec.meta["filters"][-1] == var.record
        _assert_same(var.batch, pack(rec.scenarios, rec.maps, sizes=complete.sizes, index=complete.meta.index))


def test_masks_are_cached_and_reused(suite, drivee2e_cache, monkeypatch):
    calls = []
    real = variants.reference_visibility

    def counting(*a, **kw):
        calls.append(1)
        return real(*a, **kw)

    monkeypatch.setattr(variants, "reference_visibility", counting)
    first = variants.suite_variant(suite, "val", "visible_all", CFG)
    files = list((drivee2e_cache / "visibility").glob("walls-val-*.npz"))
    assert len(calls) == 1 and len(files) == 1
    again = variants.suite_variant(suite, "val", "visible_vehicles", CFG)  # same masks, other variant
    assert len(calls) == 1 and again.record["removed_tracks"] == 4 and first.record["removed_tracks"] == 6
    # another sensor config is another key; a corrupt file is recomputed, never trusted
    files[0].write_bytes(b"not a zip")
    variants.suite_variant(suite, "val", "visible_all", CFG)
    assert len(calls) == 2
    monkeypatch.setenv("DRIVEE2E_CACHE", "off")
    variants.suite_variant(suite, "val", "visible_all", CFG)
    assert len(calls) == 3


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), density=st.floats(0.0, 0.2), cats=st.sampled_from(["vehicles", "all"]))
def test_packed_filter_equals_the_records_filter(seed, density, cats):
    """Random sparse masks on the tiny suite: both filters drop the same tracks and pack identically."""
    from tests.helpers.tiny_suite import build_tiny_suite

    rec = build_tiny_suite()
    batch = pack(rec.scenarios, rec.maps)
    shape = np.asarray(batch.scenario.tracks.valid).shape
    vis = np.random.default_rng(seed).random(shape) < density
    got, record = filter_invisible_packed(batch, vis, cats)
    out = filter_invisible(rec, {s.scenario_id: vis[b] for b, s in enumerate(rec.scenarios)}, cats)
    assert record == out.meta["filters"][-1]
    _assert_same(got, pack(out.scenarios, out.maps, sizes=batch.sizes))


def test_unknown_variant_is_one_line(capsys, tmp_path):
    from drivee2e_jax.cli import main

    with pytest.raises(Exception, match="unknown variant; expected one of complete, visible_vehicles, visible_all"):
        variants.check_variant("bogus")
    rc = main(["bench", "--suite", str(tmp_path / "nowhere"), "--variant", "bogus", "--no-progress"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--variant 'bogus'" in err[0] and "visible_all" in err[0]


def test_bench_variant_runs_log_replay_and_records_it(tmp_path, capsys, monkeypatch, drivee2e_cache):
    """The CLI on a filtered variant of the road suite of tests/cli/test_bench.py (same shapes: its
    compiled rollout is reused). The camera model is stubbed (tested above): no
    agent is ever seen, so visible_all removes the parked car the logged ego
    drives through, and log_replay's DS there goes from 60 to 100."""
    from drivee2e_jax.cli import main
    from drivee2e_jax.scenario.schema import write_suite
    from tests.helpers import sim_scenarios as ss

    maps = {m.map_id: m for m in (ss.road_map(), ss.road_map(obstacle=True))}
    folder = write_suite(SuiteRecord("road3", "1", maps, [ss.clean(), ss.blocked_by_car(), ss.red_light()]),
                         tmp_path / "road3")
    monkeypatch.setattr(variants, "reference_visibility",
                        lambda batch, cfg, progress=None: np.zeros(np.asarray(batch.scenario.tracks.valid).shape, bool))
    out = tmp_path / "run"
    rc = main(["bench", "--suite", str(folder), "--variant", "visible_all", "--policy", "log_replay",
               "--out", str(out), "--no-progress"])
    printed = capsys.readouterr().out
    assert rc == 0 and "variant visible_all: removed 2 of 2 non-ego agents (100.0 %)" in printed
    run = json.loads((out / "run.json").read_text())
    assert run["variant"] == "visible_all" and run["variant_removed"]["car"] == [2, 2]
    rows = {r["scenario_id"]: r for r in json.loads((out / "policies" / "log_replay.json").read_text())["rows"]}
    assert rows["car_ahead"]["driving_score"] == pytest.approx(100.0) and rows["car_ahead"]["collisions_vehicle"] == 0
