"""Packing records into padded batches: semantics, masks, sizes, round trip."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.batch import PackedBatch, SuiteMeta, bucket, padding_efficiency, resize
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.scenario.pack import pack, pack_buckets, unpack
from drivee2e_jax.scenario.routes import densify_route, route_commands
from drivee2e_jax.scenario.sizes import LEAVES, PackSizes

C = types.Command


@pytest.fixture
def packed(tiny_suite):
    return pack(tiny_suite.scenarios, tiny_suite.maps)


def _flat(batch):
    return {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}


def test_shapes_dtypes_and_sizes(packed, tiny_suite):
    s = packed.sizes
    assert isinstance(packed, PackedBatch) and len(packed) == 4
    assert s == PackSizes.fit(tiny_suite.scenarios, tiny_suite.maps)
    # maxima rounded up: 4 tracks -> 8 agents, 50 steps -> 56, 81 route points -> 96
    assert (s.agents, s.steps, s.lanes, s.route, s.stop_lines) == (8, 56, 8, 96, 4)
    for name, a in _flat(packed).items():
        axes, dtype, _ = LEAVES[name]
        shape = (4, *(getattr(s, x) if isinstance(x, str) else x for x in axes))
        assert a.shape == shape, name
        assert a.dtype == np.dtype(dtype), name
        assert isinstance(a, np.ndarray)
    packed.scenario.validate()


def test_ego_first_then_track_id(packed, tiny_suite):
    tid = _flat(packed)["tracks.track_id"]
    assert (np.asarray(packed.scenario.ego_index) == 0).all()
    assert tid[0, :4].tolist() == [7, 3, 12, -1]  # ego 7, then 3 < 12; padding -1
    assert tid[3, :5].tolist() == [0, 8, 9, 11, -1]
    for b, s in enumerate(tiny_suite.scenarios):
        assert tid[b, 0] == s.ego_track_id == packed.meta.ego_track_id[b]


def test_tracks_on_the_grid_with_masks(packed, tiny_suite):
    f = _flat(packed)
    ped = next(t for t in tiny_suite.scenarios[0].tracks if t.track_id == 12)
    k = np.rint(ped.t / 0.1).astype(int)
    row = 2
    assert f["tracks.valid"][0, row].nonzero()[0].tolist() == k.tolist()  # valid exactly at samples
    np.testing.assert_allclose(f["tracks.xy"][0, row, k], ped.xy, atol=1e-5)
    np.testing.assert_array_equal(f["tracks.visible"][0, row, k], ped.visible)
    np.testing.assert_array_equal(f["tracks.quality"][0, row, k], ped.quality)
    assert not f["tracks.visible"][0, row][~f["tracks.valid"][0, row]].any()
    # no velocity in the record: finite differences over the sample times
    np.testing.assert_allclose(f["tracks.vel"][0, row, k], np.gradient(ped.xy, ped.t, axis=0), atol=1e-5)
    assert f["tracks.category"][0, row] == types.Category.PEDESTRIAN
    np.testing.assert_allclose(f["tracks.size"][0, row], ped.size)
    # logged velocity is kept as given
    np.testing.assert_allclose(f["tracks.vel"][0, 0, :50], np.tile([10.0, 0.0], (50, 1)))
    # a single-sample track gets zero velocity
    assert f["tracks.valid"][3, 1].sum() == 1 and not f["tracks.vel"][3, 1].any()
    # padding rows and steps are empty
    assert not f["tracks.valid"][:, 4:].any()
    assert not f["tracks.valid"][0, :, 50:].any()
    assert f["num_steps"].tolist() == [50, 50, 30, 50]
    np.testing.assert_allclose(f["dt_log"], 0.1)
    assert f["index"].tolist() == [0, 1, 2, 3] == packed.meta.index.tolist()


def test_yaw_wrapped(packed, tiny_suite):
    yaw = _flat(packed)["tracks.yaw"][1, 0, :50]
    raw = tiny_suite.scenarios[1].tracks[0].yaw
    assert raw.max() > np.pi  # the fixture holds unwrapped angles
    assert (yaw > -np.pi - 1e-6).all() and (yaw <= np.pi + 1e-6).all()
    np.testing.assert_allclose(np.cos(yaw), np.cos(raw), atol=1e-5)
    np.testing.assert_allclose(np.sin(yaw), np.sin(raw), atol=1e-5)


def test_map_padding_and_indices(packed, tiny_suite):
    f = _flat(packed)
    m = tiny_suite.maps["m_cross"]
    b = 0
    for i, ln in enumerate(m.lanes):
        n = len(ln.centerline)
        assert f["map.lanes.point_valid"][b, i].tolist() == [True] * n + [False] * (8 - n)
        np.testing.assert_allclose(f["map.lanes.xy"][b, i, :n], ln.centerline, atol=1e-5)
    assert f["map.lanes.valid"][b].tolist() == [True] * 5 + [False] * 3
    # lane ids 1..5 sit in rows 0..4: successors are rows, -1 padded
    assert f["map.lane_successors"][b, 0].tolist() == [1, 2, -1, -1]
    assert f["map.lane_successors"][b, 5:].tolist() == [[-1] * 4] * 3
    assert f["map.lane_type"][b, 1] == types.LaneType.CONNECTOR
    assert f["map.lane_right_marking"][b, 0] == types.Marking.ROAD_EDGE
    assert f["map.boundary_marking"][b, :2].tolist() == [types.Marking.ROAD_EDGE, types.Marking.DOUBLE_SOLID]
    assert f["map.stop_line_lane"][b].tolist() == [0, -1, 3, -1]  # lane 1 -> row 0, lane 4 -> row 3
    assert f["map.stop_line_valid"][b].tolist() == [True, True, True, False]
    assert f["map.obstacles.point_valid"][b, 1].tolist() == [True, True, True, False]
    np.testing.assert_allclose(f["map.obstacle_height"][b, :2], [12.0, 5.0])
    assert f["map.drivable.valid"][b].tolist() == [True, True, False, False]
    # the tee map (scenario 2) has one lane pair and no crosswalks
    assert f["map.lanes.valid"][2].sum() == 2 and not f["map.crosswalks.valid"][2].any()


def test_signals_per_stop_line(packed):
    st_ = _flat(packed)["signals.state"]
    S = types.SignalState
    # scenario 0: group 0 green, group 1 red, stop line 2 unsignalised, row 3 padding
    assert (st_[0, 0, :50] == S.GREEN).all() and (st_[0, 1, :50] == S.RED).all()
    assert (st_[0, 2] == S.UNKNOWN).all() and (st_[0, 3] == S.UNKNOWN).all()
    # padded to T with the last state
    s1 = st_[1, 0]
    assert s1[:20].tolist() == [S.GREEN] * 20 and s1[20:30].tolist() == [S.YELLOW] * 10
    assert (s1[30:] == S.RED).all() and len(s1) == 56
    # scenario 3 has no group 1: UNKNOWN
    assert (st_[3, 1] == S.UNKNOWN).all()
    assert (st_[2, 0, :30] == S.GREEN).all() and (st_[2, 0, 30:] == S.GREEN).all()


def test_route_densified_to_one_metre(packed):
    f = _flat(packed)
    n = int(f["route.valid"][0].sum())
    assert n == 81  # 80 m straight route: 0, 1, ..., 80
    assert f["route.valid"][0].tolist() == [True] * n + [False] * (96 - n)  # valid prefix
    xy = f["route.xy"][0, :n]
    np.testing.assert_allclose(np.linalg.norm(np.diff(xy, axis=0), axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(f["route.arc"][0, :n], np.arange(n), atol=1e-4)
    assert f["route.length"][0] == pytest.approx(80.0)
    np.testing.assert_allclose(xy[-1], [40.0, -1.75])
    # padding repeats the last point, command VOID
    np.testing.assert_allclose(f["route.xy"][0, n:], np.tile(xy[-1], (96 - n, 1)))
    assert (f["route.command"][0, n:] == C.VOID).all()
    for b in range(4):
        m = int(f["route.valid"][b].sum())
        assert f["route.length"][b] == pytest.approx(f["route.arc"][b, m - 1])
        gaps = np.linalg.norm(np.diff(f["route.xy"][b, :m], axis=0), axis=1)
        assert (gaps <= 1.0 + 1e-5).all() and (gaps > 0).all()


def test_route_commands_from_junction_and_curvature(packed):
    f = _flat(packed)
    cmd = [f["route.command"][b][f["route.valid"][b]] for b in range(4)]
    # straight through the junction (connector lanes): STRAIGHT inside, LANEFOLLOW outside
    assert set(cmd[0].tolist()) == {C.LANEFOLLOW, C.STRAIGHT}
    assert cmd[0][0] == C.LANEFOLLOW and cmd[0][-1] == C.LANEFOLLOW
    assert cmd[0][40] == C.STRAIGHT  # x = 0, the junction centre
    # left turn through the junction
    assert set(cmd[1].tolist()) == {C.LANEFOLLOW, C.LEFT}
    # the tee map has no connector lanes: curvature finds the right bend
    assert set(cmd[2].tolist()) == {C.LANEFOLLOW, C.RIGHT}


def test_route_commands_unit():
    straight = np.stack([np.arange(50.0), np.zeros(50)], 1)
    assert (route_commands(straight) == C.LANEFOLLOW).all()
    # 90-degree left, radius 10 m, between straights
    ang = np.linspace(-np.pi / 2, 0, 16)
    arc = np.stack([10 * np.cos(ang), 10 + 10 * np.sin(ang)], 1)
    path = np.concatenate([np.stack([np.arange(-30.0, 0), np.zeros(30)], 1), arc,
                           np.stack([np.full(30, 10.0), np.arange(11.0, 41)], 1)])
    xy, _ = densify_route(path)
    cmd = route_commands(xy)
    assert C.LEFT in cmd and C.RIGHT not in cmd and cmd[0] == C.LANEFOLLOW and cmd[-1] == C.LANEFOLLOW
    mirrored = route_commands(xy * [1, -1])
    assert C.RIGHT in mirrored and C.LEFT not in mirrored
    # a junction that does not turn is STRAIGHT; a gentle 10-degree bend stays LANEFOLLOW
    inside = (straight[:, 0] > 20) & (straight[:, 0] < 30)
    assert (route_commands(straight, inside)[inside] == C.STRAIGHT).all()
    bend = np.stack([np.arange(100.0), np.r_[np.zeros(50), np.arange(50) * np.tan(np.radians(10))]], 1)
    assert (route_commands(densify_route(bend)[0]) == C.LANEFOLLOW).all()


def test_densify_keeps_last_point_and_drops_repeats():
    xy, arc = densify_route(np.array([[0, 0], [0, 0], [2.5, 0]]))
    np.testing.assert_allclose(xy, [[0, 0], [1, 0], [2, 0], [2.5, 0]])
    np.testing.assert_allclose(arc, [0, 1, 2, 2.5])
    xy, arc = densify_route(np.array([[1.0, 1.0], [1.0, 1.0]]))
    assert xy.shape == (1, 2) and arc.tolist() == [0.0]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-200, 200), st.floats(-200, 200)), min_size=2, max_size=12))
def test_densify_property(points):
    w = np.array(points, dtype=float)
    xy, arc = densify_route(w)
    # the first point, unless the whole polyline is shorter than the 1e-6 m a last piece is merged under
    # (Hypothesis found [(0, 0), (0, 6e-8)]: one point, the exact end)
    np.testing.assert_allclose(xy[0], w[0], atol=1e-6)
    np.testing.assert_allclose(xy[-1], w[-1])
    gaps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    assert (gaps <= 1.0 + 1e-9).all()
    np.testing.assert_allclose(arc, np.r_[0.0, np.cumsum(gaps)])
    total = np.linalg.norm(np.diff(w, axis=0), axis=1).sum()
    assert arc[-1] <= total + 1e-9  # chords never exceed the polyline
    assert len(xy) == (1 if total <= 1e-9 else int(np.ceil(total - 1e-6)) + 1)


def test_unpack_round_trip(packed, tiny_suite):
    back = unpack(packed)
    assert [r.scenario_id for r in back] == [s.scenario_id for s in tiny_suite.scenarios]
    for orig, rec in zip(tiny_suite.scenarios, back):
        for key in ("split", "intersection_id", "map_id", "behavior", "weather", "time_of_day",
                    "ego_track_id", "dt", "num_steps"):
            assert getattr(orig, key) == getattr(rec, key), key
        assert rec.tracks[0].track_id == orig.ego_track_id
        by_id = {t.track_id: t for t in rec.tracks}
        assert set(by_id) == {t.track_id for t in orig.tracks}
        for t in orig.tracks:
            u = by_id[t.track_id]
            assert u.category == t.category
            np.testing.assert_allclose(u.t, t.t, atol=1e-9)
            np.testing.assert_allclose(u.xy, t.xy, atol=1e-4)
            np.testing.assert_allclose(np.cos(u.yaw), np.cos(t.yaw), atol=1e-5)
            np.testing.assert_allclose(np.sin(u.yaw), np.sin(t.yaw), atol=1e-5)
            np.testing.assert_allclose(u.size, t.size, atol=1e-6)
            if t.vel is not None:
                np.testing.assert_allclose(u.vel, t.vel, atol=1e-4)
            for flag in ("visible", "quality"):
                want = getattr(t, flag)
                np.testing.assert_array_equal(getattr(u, flag), np.ones(len(t.t), bool) if want is None else want)
        # route: the dense 1 m points along the original waypoints
        dense, _ = densify_route(orig.route.waypoints)
        np.testing.assert_allclose(rec.route.waypoints, dense, atol=1e-4)
        np.testing.assert_allclose(rec.route.source, orig.route.source)
        np.testing.assert_allclose(rec.route.destination, orig.route.destination)
        for g, states in orig.signals.items():
            np.testing.assert_array_equal(rec.signals[g], states)
    # repacking the unpacked records gives the same arrays, except that the
    # route is re-densified along the dense chords (documented: not idempotent
    # at the corners of coarse waypoints)
    again = _flat(pack(back, tiny_suite.maps, packed.sizes))
    for k, v in _flat(packed).items():
        tol = 0.1 if k in ("route.xy", "route.arc", "route.length") else 2e-5
        np.testing.assert_allclose(again[k], v, atol=tol, err_msg=k)


def test_meta_table(packed):
    meta = packed.meta
    assert isinstance(meta, SuiteMeta) and len(meta) == 4
    rows = meta.rows()
    assert rows[2] == {"scenario_id": "s_val", "split": "val", "intersection_id": "i1", "map_id": "m_tee",
                       "behavior": "COV", "weather": "fog", "time_of_day": "dusk", "ego_track_id": 1,
                       "index": 2, "num_agents": 2, "num_steps": 30, "dt": 0.1}
    assert meta.to_dicts() == rows
    assert meta.count("split") == {"train": 2, "val": 1, "test": 1}
    again = SuiteMeta.from_json(meta.to_json())
    for k, v in meta.columns().items():
        np.testing.assert_array_equal(getattr(again, k), v)
    assert meta.select([3, 0]).scenario_id.tolist() == ["s_test", "s_straight"]


def test_explicit_sizes_overflow_is_an_error(tiny_suite):
    fit = PackSizes.fit(tiny_suite.scenarios, tiny_suite.maps)
    with pytest.raises(DriveE2EError, match=r"scenario 's_test' tracks: needs agents=4, more than PackSizes.agents=3"):
        pack(tiny_suite.scenarios, tiny_suite.maps, fit.replace(agents=3))
    with pytest.raises(DriveE2EError, match=r"map 'm_cross' lanes\[2\]\.centerline: needs points=7, more than PackSizes.points=2"):
        pack(tiny_suite.scenarios, tiny_suite.maps, fit.replace(points=2))
    with pytest.raises(DriveE2EError, match=r"scenario 's_straight' route at 1 m spacing: needs route=81"):
        pack(tiny_suite.scenarios, tiny_suite.maps, fit.replace(route=80))
    big = fit.replace(agents=16, steps=64)
    b = pack(tiny_suite.scenarios, tiny_suite.maps, big)
    assert b.sizes == big


def test_pack_sizes_checks():
    with pytest.raises(DriveE2EError, match="PackSizes.agents: expected an integer >= 1"):
        PackSizes.rounded({}).replace(agents=0)
    assert PackSizes.rounded({"agents": 9, "route": 17}).agents == 16
    assert PackSizes.rounded({"route": 17}).route == 32


def test_pack_errors_name_the_scenario(tiny_suite):
    with pytest.raises(DriveE2EError, match="nothing to pack"):
        pack([], tiny_suite.maps)
    s = tiny_suite.scenarios[2]
    s.map_id = "m_missing"
    with pytest.raises(DriveE2EError, match=r"scenario 's_val': map_id: expected one of the maps"):
        pack(tiny_suite.scenarios, tiny_suite.maps)


def test_resize_grow_and_shrink(packed):
    big = packed.sizes.replace(agents=24, steps=80, lanes=16, route=128, stop_lines=8)
    grown = resize(packed, big)
    assert grown.sizes == big
    f = _flat(grown)
    assert (f["tracks.track_id"][:, 8:] == -1).all()
    assert (f["signals.state"][1, 0, 50:] == types.SignalState.RED).all()  # last state carried
    assert (f["route.command"][:, 96:] == C.VOID).all()
    assert grown.meta.stop_line_group.shape == (4, 8)
    back = resize(grown, packed.sizes)
    for k, v in _flat(packed).items():
        np.testing.assert_array_equal(_flat(back)[k], v, err_msg=k)
    with pytest.raises(DriveE2EError, match=r"scenario 's_test': needs agents=4"):
        resize(packed, packed.sizes.replace(agents=3))
    assert unpack(grown)[1].signals[0].tolist() == unpack(packed)[1].signals[0].tolist()


def test_select_and_fit(packed):
    sub = packed.select([2])
    assert sub.meta.scenario_id.tolist() == ["s_val"] and np.asarray(sub.scenario.index).tolist() == [2]
    tight = sub.fit()
    assert (tight.sizes.agents, tight.sizes.steps, tight.sizes.lanes) == (8, 32, 8)
    assert unpack(tight)[0].tracks[0].xy.tolist() == unpack(sub)[0].tracks[0].xy.tolist()


def test_buckets_cover_every_row_once(tiny_suite):
    single = pack(tiny_suite.scenarios, tiny_suite.maps)
    buckets = pack_buckets(tiny_suite.scenarios, tiny_suite.maps, num_buckets=2)
    assert 1 <= len(buckets) <= 2
    idx = sorted(i for b in buckets for i in b.meta.index.tolist())
    assert idx == [0, 1, 2, 3]
    for b in buckets:
        assert np.asarray(b.scenario.index).tolist() == b.meta.index.tolist()
    assert padding_efficiency(buckets) >= padding_efficiency(single)
    assert len(bucket(single, 1)) == 1
    valid = sum(int(np.asarray(b.scenario.tracks.valid).sum()) for b in buckets)
    assert valid == int(np.asarray(single.scenario.tracks.valid).sum())


def test_padding_efficiency(packed):
    v = np.asarray(packed.scenario.tracks.valid)
    assert packed.padding_efficiency == pytest.approx(v.sum() / v.size)
    assert "padding_efficiency" in repr(packed)


def test_to_jax_and_jit(packed):
    import jax
    import jax.numpy as jnp

    sc = packed.to_jax()
    assert isinstance(sc.tracks.xy, jax.Array)
    n_valid = jax.jit(lambda s: jnp.sum(s.tracks.valid, axis=(1, 2)))(sc)
    assert np.asarray(n_valid).tolist() == np.asarray(packed.scenario.tracks.valid).sum(axis=(1, 2)).tolist()
    one = jax.tree_util.tree_map(lambda a: a[0], sc)
    assert one.tracks.xy.shape == (8, 56, 2)
    assert dataclasses.is_dataclass(one)


def test_lane_polygons_packed_per_lane_row(packed, tiny_suite):
    from shapely.geometry import Point, Polygon

    from drivee2e_jax.scenario.lane_polygons import packed_lane_polygon

    f = _flat(packed)
    m = tiny_suite.maps["m_cross"]
    b = 0
    assert f["map.lane_polygons.valid"][b].tolist() == f["map.lanes.valid"][b].tolist()
    for i, ln in enumerate(m.lanes):
        ref = packed_lane_polygon(ln)
        n = len(ref)
        assert f["map.lane_polygons.point_valid"][b, i].sum() == n
        xy = f["map.lane_polygons.xy"][b, i, :n].astype(np.float64)
        np.testing.assert_allclose(xy, ref, atol=1e-4)
        shp = Polygon(xy)
        assert shp.is_valid and shp.exterior.is_ccw
        mid = np.asarray(ln.centerline)[len(ln.centerline) // 2]
        assert shp.buffer(1e-3).contains(Point(mid))
    assert PackSizes.of(packed.scenario).lane_vertices == f["map.lane_polygons.xy"].shape[2]
