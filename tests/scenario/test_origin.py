"""Per-map origins (``scenario.origin``): packing re-centres a large world
frame before the float32 cast, so a scene in UTM-sized coordinates simulates
as it does near (0, 0); validation bounds world positions.

The closed-loop check runs the hand-built road scenes (``tests.helpers.sim_scenarios``:
a clean drive, a car, a pedestrian and a pole in the way) under ``log_replay``
and the ``nuplan`` preset, once as built and once moved by (4e6, 5e5) m (a
UTM northing / easting), and compares every per-step fact of the ``StepLog``
and every row column (collisions, drivable-area excess, the comfort columns).
Without the origin the moved copy is packed at float32 spacing 0.5 m / 0.03 m
and its rows differ (measured on the code before this module: mean longitudinal
jerk 17.16 instead of 1.70 m/s^3, the pole hit once instead of twice).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import evaluate, events_to_world
from drivee2e_jax.metrics.driving_score import score_preset
from drivee2e_jax.observe.bev import BevConfig
from drivee2e_jax.observe.sensors import SensorConfig, build_assets
from drivee2e_jax.policy import load_policy, resolve_policy_path
from drivee2e_jax.records import MapRecord, ScenarioRecord, SuiteRecord
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.scenario.origin import ORIGIN_GRID, POSITION_BOUND, map_origin
from drivee2e_jax.scenario.pack import pack, unpack
from drivee2e_jax.scenario.schema import write_suite
from drivee2e_jax.scenario.validate import validate_records
from drivee2e_jax.sim import SimConfig
from tests.helpers import sim_scenarios as ss

UTM = np.array([4e6, 5e5])  # a UTM-sized northing / easting, m

#: leaves holding world positions (the ones packing re-centres)
XY_LEAVES = ("tracks.xy", "map.lanes.xy", "map.lane_polygons.xy", "map.boundaries.xy", "map.crosswalks.xy",
             "map.stop_lines", "map.drivable.xy", "map.obstacles.xy", "map.drivable_edges", "route.xy")


def _move(a, d):
    return None if a is None else np.asarray(a, np.float64) + d


def moved_map(m: MapRecord, d) -> MapRecord:
    """``m`` translated by ``d`` (2,) m; ``map_id`` kept (a scenario names it).

    Written apart from ``origin.translate_map`` on purpose: moving the input with
    the function under test would hide a field both forget (a lane's ``polygon``
    did, before e10cc32)."""
    return dataclasses.replace(
        m,
        lanes=[dataclasses.replace(ln, centerline=_move(ln.centerline, d), left_boundary=_move(ln.left_boundary, d),
                                   right_boundary=_move(ln.right_boundary, d), polygon=_move(ln.polygon, d))
               for ln in m.lanes],
        boundaries=[dataclasses.replace(b, points=_move(b.points, d)) for b in m.boundaries],
        crosswalks=[_move(p, d) for p in m.crosswalks],
        stop_lines=[dataclasses.replace(s, points=_move(s.points, d)) for s in m.stop_lines],
        drivable_areas=[_move(p, d) for p in m.drivable_areas],
        obstacles=[dataclasses.replace(o, polygon=_move(o.polygon, d)) for o in m.obstacles],
    )


def moved_scenario(s: ScenarioRecord, d) -> ScenarioRecord:
    r = s.route
    return dataclasses.replace(
        s, tracks=[dataclasses.replace(t, xy=_move(t.xy, d)) for t in s.tracks],
        route=dataclasses.replace(r, waypoints=_move(r.waypoints, d), source=_move(r.source, d),
                                  destination=_move(r.destination, d)))


def _with_own_polygon(m: MapRecord) -> MapRecord:
    """``m`` with its first lane carrying its own area ring (``LaneRecord.polygon``, as
    ScenarioNet's lanes do): the ring must move with the origin like every other position."""
    ln = m.lanes[0]
    c, hw = np.asarray(ln.centerline, np.float64), 0.5 * float(ln.width)
    t = (c[-1] - c[0]) / np.linalg.norm(c[-1] - c[0])
    n = np.array([-t[1], t[0]]) * hw
    ring = np.stack([c[0] - n, c[-1] - n, c[-1] + n, c[0] + n])
    return dataclasses.replace(m, lanes=[dataclasses.replace(ln, polygon=ring), *m.lanes[1:]])


def scenes():
    """The road scenes with an ego at 8.7 m/s on y = -1.6: neither its steps (0.87 m) nor its
    lane offset are multiples of float32's spacing at (4e6, 5e5) (0.5 m, 1/32 m), so without
    the origin the moved ego is quantised (at 10 m/s on y = -1.75 it happens to be exact)."""
    maps = {m.map_id: _with_own_polygon(m) for m in (ss.road_map(), ss.road_map(obstacle=True))}
    ego = ss.ego_track(speed=8.7, y=-1.6)
    scns = [ss.scenario("clean", [ego, ss.parked(5, 30.0, y=1.75)]), ss.scenario("car_ahead", [ego, ss.parked(5, 0.0)]),
            ss.scenario("ped", [ego, ss.parked(7, 20.0, category="pedestrian", size=(0.6, 0.6, 1.7))]),
            ss.scenario("pole", [ego], map_id="road_obst")]
    return maps, scns


def packed_pair(d):
    maps, scns = scenes()
    return pack(scns, maps), pack([moved_scenario(s, d) for s in scns], {k: moved_map(m, d) for k, m in maps.items()})


# --------------------------------------------------------------------------
# Packing
# --------------------------------------------------------------------------


def test_origin_is_the_map_centre_rounded_to_the_grid():
    maps, scns = scenes()
    road = maps["road"]  # x in [-80, 80], y in [-3.5, 3.5]: centred on (0, 0)
    assert map_origin(road).tolist() == [0.0, 0.0] and not np.signbit(map_origin(road)).any()
    assert map_origin(moved_map(road, UTM)).tolist() == UTM.tolist()
    # 499 m off still rounds to 0; 501 m to the next kilometre; a half-grid offset rounds to even.
    assert map_origin(moved_map(road, (499.0, -501.0))).tolist() == [0.0, -ORIGIN_GRID]
    # A map with no geometry takes the ego start it is given.
    assert map_origin(MapRecord("empty", []), (UTM[0] + 1234.0, UTM[1])).tolist() == [4001000.0, 5e5]


def test_a_moved_scene_packs_to_the_same_local_arrays():
    near, far = packed_pair(UTM)
    np.testing.assert_array_equal(near.meta.origin, 0.0)
    np.testing.assert_array_equal(far.meta.origin, np.tile(UTM, (len(far), 1)))
    a, b = flatten_scenario(near.scenario), flatten_scenario(far.scenario)
    for k in a:  # the offset is a multiple of the grid: local positions are bit for bit the same
        np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)
    # An offset off the grid leaves local positions shifted by the remainder, at float32
    # precision of the local magnitude (~1e-5 m here), never of 4e6 m (0.5 m).
    off = UTM + (123.456, -77.7)
    _, odd = packed_pair(off)
    np.testing.assert_array_equal(odd.meta.origin[0], UTM)
    f = flatten_scenario(odd.scenario)
    for k in XY_LEAVES:
        valid = np.abs(np.asarray(a[k])) > 0  # padding stays 0
        shift = np.tile((123.456, -77.7), np.asarray(a[k]).shape[-1] // 2)
        got = np.asarray(f[k], np.float64) - shift
        np.testing.assert_allclose(got[valid], np.asarray(a[k], np.float64)[valid], atol=5e-5, err_msg=k)
    # Headings, velocities, sizes, arc lengths do not depend on the frame.
    for k in ("tracks.yaw", "tracks.vel", "tracks.size", "route.arc", "route.length", "map.lane_width"):
        np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(f[k]), err_msg=k)


def test_unpack_returns_world_positions():
    _, far = packed_pair(UTM + (123.25, -77.5))
    maps, scns = scenes()
    back = unpack(far)
    for s, r in zip(scns, back):
        ego = next(t for t in r.tracks if t.track_id == s.ego_track_id)
        want = next(t for t in s.tracks if t.track_id == s.ego_track_id).xy + UTM + (123.25, -77.5)
        np.testing.assert_allclose(ego.xy, want, atol=1e-4)  # float32 of ~150 m local, not of 4e6 m
        np.testing.assert_allclose(r.route.waypoints[[0, -1]], s.route.waypoints[[0, -1]] + UTM + (123.25, -77.5),
                                   atol=1e-4)


def test_events_to_world_adds_the_origin():
    ev = [{"type": "collisions_vehicle", "t": 1.0, "x": 1.5, "y": -2.25}, {"type": "timeout", "t": 2.0}]
    assert events_to_world(ev, (0.0, 0.0)) is ev
    got = events_to_world(ev, UTM)
    assert (got[0]["x"], got[0]["y"]) == (4000001.5, 499997.75) and got[1] == ev[1]


# --------------------------------------------------------------------------
# Closed loop: the same facts and metrics far from (0, 0)
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def runs():
    near, far = packed_pair(UTM)
    pol = load_policy(resolve_policy_path("log_replay"))
    cfg = SimConfig(score=score_preset("nuplan"))
    return evaluate(pol, near, None, config=cfg), evaluate(pol, far, None, config=cfg)


def test_far_scene_gives_the_same_step_facts(runs):
    near, far = runs
    a, b = leaves(near.logs), leaves(far.logs)
    assert a.keys() == b.keys() and len(a) > 20
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_far_scene_gives_the_same_rows_and_world_events(runs):
    near, far = runs
    # what this checks is not vacuous: the scenes collide, leave nothing undriven, and are scored for comfort
    by = {r["scenario_id"]: r for r in near.rows}
    assert by["car_ahead"]["collisions_vehicle"] >= 1 and by["ped"]["collisions_pedestrian"] >= 1
    assert by["pole"]["collisions_layout"] >= 1 and "nuplan_ego_is_comfortable" in by["clean"]
    for ra, rb in zip(near.rows, far.rows):
        for k in ra:
            if k != "eval_time_s":
                assert ra[k] == rb[k] or (ra[k] != ra[k] and rb[k] != rb[k]), (ra["scenario_id"], k, ra[k], rb[k])
    for sid, evs in near.events.items():
        assert len(evs) == len(far.events[sid]) and evs, sid
        for e, f in zip(evs, far.events[sid]):
            assert (f["x"], f["y"]) == pytest.approx((e["x"] + UTM[0], e["y"] + UTM[1]), abs=1e-6)


def leaves(tree) -> dict:
    """Leaf path -> numpy array of a pytree (the StepLog)."""
    return {jax.tree_util.keystr(p): np.asarray(v) for p, v in jax.tree_util.tree_leaves_with_path(tree)}


# --------------------------------------------------------------------------
# Validation: a physical bound on world positions
# --------------------------------------------------------------------------


@pytest.mark.parametrize(("where", "field"), [
    ("scenario", "tracks[0].x[3]"), ("scenario", "route.waypoints[1]"), ("map", "lanes[0].centerline[0]"),
    ("map", "obstacles[0].polygon[0]"), ("map", "stop_lines[0].points[0]"),
])
def test_positions_beyond_the_bound_are_refused_naming_file_and_field(where, field):
    maps, scns = scenes()
    s, m = scns[3], maps["road_obst"]
    bad = 1.5 * POSITION_BOUND
    if where == "scenario":
        if field.startswith("tracks"):
            xy = s.tracks[0].xy.copy()
            xy[3, 0] = bad
            s = dataclasses.replace(s, tracks=[dataclasses.replace(s.tracks[0], xy=xy), *s.tracks[1:]])
        else:
            wp = s.route.waypoints.copy()
            wp[1, 1] = -bad
            s = dataclasses.replace(s, route=dataclasses.replace(s.route, waypoints=wp))
    else:
        d = np.zeros(2)
        if field.startswith("lanes"):
            cl = m.lanes[0].centerline.copy()
            cl[0, 1] = bad
            m = dataclasses.replace(m, lanes=[dataclasses.replace(m.lanes[0], centerline=cl), *m.lanes[1:]])
        elif field.startswith("obstacles"):
            m = dataclasses.replace(m, obstacles=[dataclasses.replace(m.obstacles[0], polygon=m.obstacles[0].polygon
                                                                      + (bad, 0.0))])
        else:
            m = moved_map(m, d)
            m = dataclasses.replace(m, stop_lines=[dataclasses.replace(m.stop_lines[0],
                                                                       points=m.stop_lines[0].points + (0.0, 1e37))])
    problems = validate_records(SuiteRecord("s", "1", {m.map_id: m}, [s]))
    file = f"scenarios/{s.scenario_id}.json" if where == "scenario" else f"maps/{m.map_id}.json"
    hits = [p for p in problems if p.file == file and p.field == field]
    assert len(problems) == 1 and hits, [str(p) for p in problems]
    assert "|value| <= 1e+07 m" in hits[0].expected


def test_utm_positions_are_accepted_and_a_bad_one_stops_the_write(tmp_path):
    maps, scns = scenes()
    far = SuiteRecord("far", "1", {k: moved_map(m, UTM * (2.4, 19.9)) for k, m in maps.items()},  # northing 9.95e6
                      [moved_scenario(s, UTM * (2.4, 19.9)) for s in scns])
    assert validate_records(far) == []
    xy = far.scenarios[0].tracks[0].xy.copy()
    xy[0] = (1e37, 0.0)  # inside float32, outside any planar frame
    bad = dataclasses.replace(far, scenarios=[dataclasses.replace(
        far.scenarios[0], tracks=[dataclasses.replace(far.scenarios[0].tracks[0], xy=xy),
                                  *far.scenarios[0].tracks[1:]]), *far.scenarios[1:]])
    with pytest.raises(DriveE2EError) as e:
        write_suite(bad, tmp_path / "bad")
    msg = str(e.value)
    assert "scenarios/clean.json" in msg and "tracks[0].x[0]" in msg and "1e+37" in msg and "\n" not in msg.strip()


def test_bev_rasters_are_placed_in_the_local_frame():
    """The BEV's static rasters are drawn from the world MapRecords: ``build_assets``
    shifts each by the packed origin, so the moved scene's table equals the unmoved one's."""
    maps, _ = scenes()
    near, far = packed_pair(UTM)
    cfg = SensorConfig(bev=BevConfig())
    a = build_assets(near, cfg, maps)
    b = build_assets(far, cfg, {k: moved_map(m, UTM) for k, m in maps.items()})
    assert a.raster.map_ids == b.raster.map_ids
    np.testing.assert_array_equal(np.asarray(a.raster.origin), np.asarray(b.raster.origin))
    np.testing.assert_array_equal(np.asarray(a.raster.words), np.asarray(b.raster.words))
    np.testing.assert_array_equal(a.map_index, b.map_index)
    assert np.abs(np.asarray(b.raster.origin)).max() < 100  # local, not 4e6
