"""The built-in ``twin15`` suite: structure, maps, plausibility of every log,
the ego's log and its behaviour label, determinism.

The suite is generated once per session (``suite`` fixture, ~10-20 s on 2
cores); every check runs over all 800 scenarios. The label and overlap
checks here are written independently of the generator's own checks.
"""

from __future__ import annotations

import hashlib
from collections import Counter

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Polygon

from drivee2e_jax.records import (
    BEHAVIORS,
    CATEGORIES,
    MARKINGS,
    SIGNAL_STATES,
    TIMES_OF_DAY,
    WEATHERS,
)
from drivee2e_jax.scenario import twin15
from drivee2e_jax.scenario.twin15.boxes import corners, sat_overlap

PER_200 = {"COV": 36, "IPC": 34, "UT": 5, "YLW": 17, "STR": 36, "LFT": 26, "RT": 24, "STP": 22}
RED, YELLOW, GREEN = (SIGNAL_STATES.index(s) for s in ("red", "yellow", "green"))
VEHICLES = {"car", "truck", "bus", "van", "motorcycle", "tricycle"}
SIZE_RANGE = {  # plausible (length, width, height) bounds, m
    "car": ((3.5, 5.5), (1.5, 2.1), (1.2, 2.0)), "van": ((4.0, 6.5), (1.7, 2.2), (1.7, 2.8)),
    "truck": ((6.0, 12.0), (2.1, 2.6), (2.5, 4.0)), "bus": ((9.0, 13.0), (2.4, 2.6), (2.8, 3.8)),
    "motorcycle": ((1.5, 2.5), (0.6, 1.0), (1.0, 1.7)), "tricycle": ((2.2, 3.5), (1.0, 1.6), (1.3, 2.2)),
    "pedestrian": ((0.3, 0.8), (0.3, 0.8), (1.3, 2.0)), "cyclist": ((1.5, 2.0), (0.5, 0.8), (1.4, 2.0)),
}


@pytest.fixture(scope="session")
def suite():
    return twin15.generate(0)


@pytest.fixture(scope="session")
def scenarios(suite):
    """Per scenario: the record, its map and dense (A, T) track arrays."""
    out = []
    for s in suite.scenarios:
        A, T = len(s.tracks), s.num_steps
        xy = np.zeros((A, T, 2))
        yaw = np.zeros((A, T))
        vel = np.zeros((A, T, 2))
        valid = np.zeros((A, T), bool)
        size = np.zeros((A, 3))
        for a, tr in enumerate(s.tracks):
            k = np.rint(tr.t / s.dt).astype(int)
            xy[a, k], yaw[a, k], vel[a, k], valid[a, k] = tr.xy, tr.yaw, tr.vel, True
            size[a] = tr.size
        cats = np.array([tr.category for tr in s.tracks])
        ego = [tr.track_id for tr in s.tracks].index(s.ego_track_id)
        out.append({"rec": s, "map": suite.maps[s.map_id], "xy": xy, "yaw": yaw, "vel": vel, "valid": valid,
                    "size": size, "cat": cats, "ego": ego})
    return out


def _suite_hash(suite) -> str:
    h = hashlib.sha256()
    for s in suite.scenarios:
        h.update(s.scenario_id.encode())
        for tr in s.tracks:
            for a in (tr.t, tr.xy, tr.yaw, tr.vel, tr.size):
                h.update(np.ascontiguousarray(a).tobytes())
        for g in sorted(s.signals):
            h.update(s.signals[g].tobytes())
        h.update(s.route.waypoints.tobytes())
    return h.hexdigest()


# --------------------------------------------------------------------------
# structure
# --------------------------------------------------------------------------


def test_public_api():
    assert isinstance(twin15.VERSION, str) and twin15.VERSION == "1"
    assert callable(twin15.generate)


def test_ids_splits_and_label_counts(suite):
    sc = suite.scenarios
    assert suite.name == "twin15" and suite.version == twin15.VERSION
    assert [s.scenario_id for s in sc] == [f"twin15_{i:04d}" for i in range(800)]
    splits = Counter(s.split for s in sc)
    assert splits == {"train": 400, "val": 200, "test": 200}
    for split, scale in (("train", 2), ("val", 1), ("test", 1)):
        got = Counter(s.behavior for s in sc if s.split == split)
        assert got == {b: n * scale for b, n in PER_200.items()}, split
        assert {s.intersection_id for s in sc if s.split == split} == {f"I{i:02d}" for i in range(1, 16)}
    assert sorted(suite.maps) == [f"I{i:02d}" for i in range(1, 16)]
    for s in sc:
        assert s.map_id == s.intersection_id and s.behavior in BEHAVIORS
        assert s.dt == 0.1 and s.num_steps == 201


def test_weather_and_time_of_day_mix(suite):
    w = Counter(s.weather for s in suite.scenarios)
    t = Counter(s.time_of_day for s in suite.scenarios)
    assert set(w) == set(WEATHERS) and set(t) == set(TIMES_OF_DAY)
    assert w.most_common(1)[0][0] == "clear" and t.most_common(1)[0][0] == "day"
    assert min(w.values()) >= 20 and min(t.values()) >= 60


def test_records_pass_schema_validation(suite):
    from drivee2e_jax.scenario.validate import validate_records

    problems = validate_records(suite)
    assert not problems, problems[:5]


def test_categories_and_sizes(scenarios):
    seen = Counter()
    for sc in scenarios:
        for tr in sc["rec"].tracks:
            seen[tr.category] += 1
            for (lo, hi), x in zip(SIZE_RANGE[tr.category], tr.size):
                assert lo <= x <= hi, (sc["rec"].scenario_id, tr.track_id, tr.category, tr.size)
    assert set(seen) == set(CATEGORIES)
    assert seen["car"] == max(seen.values())
    n = np.array([len(sc["rec"].tracks) for sc in scenarios])
    assert 20 <= n.mean() <= 80 and n.max() <= 128


# --------------------------------------------------------------------------
# maps
# --------------------------------------------------------------------------


def test_fifteen_different_intersections(suite):
    metas = [m.meta for m in suite.maps.values()]
    assert Counter(m["legs"] for m in metas).keys() == {3, 4, 5}
    assert sum(m["skew_deg"] >= 10 for m in metas) >= 5
    lanes = [n for m in metas for n in m["lanes_in"]]
    assert set(lanes) == {1, 2, 3, 4}
    assert any(any(m["left_pockets"]) for m in metas) and any(any(m["right_pockets"]) for m in metas)
    assert sum(bool(m["u_turn_legs"]) for m in metas) >= 3
    shapes = {(m["legs"], tuple(m["leg_angles_deg"]), tuple(m["lanes_in"]), tuple(m["lanes_out"]),
               tuple(m["left_pockets"]), tuple(m["right_pockets"])) for m in metas}
    assert len(shapes) == 15


@pytest.mark.parametrize("map_id", [f"I{i:02d}" for i in range(1, 16)])
def test_map_geometry(suite, map_id):
    m = suite.maps[map_id]
    assert m.map_id == map_id
    ids = {ln.id for ln in m.lanes}
    road = shapely.union_all([Polygon(p) for p in m.drivable_areas])
    assert all(Polygon(p).is_valid for p in m.drivable_areas)
    cover = road.buffer(0.05)
    for ln in m.lanes:
        c = ln.centerline
        assert 2 <= len(c) <= 64
        assert np.linalg.norm(np.diff(c, axis=0), axis=1).max() <= 2.0 + 1e-6
        assert set(ln.successors) <= ids
        assert cover.contains(LineString(c)), (map_id, ln.id, ln.type)
    by_id = {ln.id: ln for ln in m.lanes}
    conn = [ln for ln in m.lanes if ln.type == "connector"]
    assert conn and all(len(ln.successors) == 1 and by_id[ln.successors[0]].type != "connector" for ln in conn)
    entries = {ln.id for ln in m.lanes if any(by_id[s].type == "connector" for s in ln.successors)}
    # one stop line per entry lane, across its end
    assert sorted(sl.lane_id for sl in m.stop_lines) == sorted(entries)
    groups = {int(g) for g in m.meta["signal_groups"]}
    plan_groups = {g for ph in m.signal_plan for g in ph.green}
    assert plan_groups == groups
    for sl in m.stop_lines:
        assert sl.signal_group in groups or sl.signal_group == -1
        end = by_id[sl.lane_id].centerline[-1]
        assert LineString(sl.points).distance(shapely.Point(end)) < 1e-6
    assert {b.marking for b in m.boundaries} <= set(MARKINGS)
    assert {"road_edge", "solid"} <= {b.marking for b in m.boundaries}
    assert all(2 <= len(b.points) <= 64 for b in m.boundaries)
    assert m.crosswalks and all(Polygon(c).is_valid for c in m.crosswalks)
    assert m.obstacles and {o.kind for o in m.obstacles} >= {"building", "signal_pole", "pole"}
    for o in m.obstacles:
        poly = Polygon(o.polygon)
        assert poly.is_valid and abs(poly.convex_hull.area - poly.area) < 1e-6  # convex
        assert not poly.intersects(road) and o.height > 0


def test_all_movements_exist(suite):
    turns = [t for m in suite.maps.values() for t in m.meta["turn_angles_deg"].values()]
    assert any(-130 < t < -60 for t in turns) and any(abs(t) >= 170 for t in turns)  # rights, U-turns
    assert any(abs(t) < 20 for t in turns) and any(60 < t < 130 for t in turns)  # straights, lefts
    assert {"dashed", "double_solid"} <= {b.marking for m in suite.maps.values() for b in m.boundaries}


# --------------------------------------------------------------------------
# logs
# --------------------------------------------------------------------------


def test_tracks_on_the_time_grid(scenarios):
    for sc in scenarios:
        s = sc["rec"]
        assert len({tr.track_id for tr in s.tracks}) == len(s.tracks)
        for tr in s.tracks:
            k = np.rint(tr.t / s.dt).astype(int)
            np.testing.assert_array_equal(tr.t, np.round(k * s.dt, 6))
            assert k[0] >= 0 and k[-1] < s.num_steps and np.all(np.diff(k) == 1)
            assert tr.vel is not None and tr.vel.shape == (len(k), 2)
            assert tr.visible.all() and tr.quality.all()


def test_signals_cover_every_group(scenarios):
    for sc in scenarios:
        s, m = sc["rec"], sc["map"]
        assert set(s.signals) == {int(g) for g in m.meta["signal_groups"]}
        for a in s.signals.values():
            assert a.dtype == np.int8 and a.shape == (201,) and set(np.unique(a)) <= {RED, YELLOW, GREEN}


def test_speed_acceleration_and_yaw_rate(scenarios):
    for sc in scenarios:
        dt = sc["rec"].dt
        speed = np.linalg.norm(sc["vel"], axis=-1)
        v = sc["valid"]
        for cat, vmax in (("pedestrian", 3.0), ("cyclist", 9.0)):
            m = sc["cat"] == cat
            assert (speed[m][v[m]] <= vmax).all()
        veh = np.isin(sc["cat"], list(VEHICLES))
        assert (speed[veh][v[veh]] <= 22.0).all()
        both = v[:, 1:] & v[:, :-1]
        acc = np.abs(np.diff(speed, axis=1)) / dt
        assert (acc[veh][both[veh]] <= 6.0 + 1e-6).all(), sc["rec"].scenario_id
        dyaw = np.abs((np.diff(sc["yaw"], axis=1) + np.pi) % (2 * np.pi) - np.pi) / dt
        moving = both & (speed[:, 1:] > 1.0) & veh[:, None]
        assert (dyaw[moving] <= 1.2).all(), sc["rec"].scenario_id
        # the logged velocity points along the logged heading
        dirn = np.stack([np.cos(sc["yaw"]), np.sin(sc["yaw"])], -1)
        assert (np.abs((sc["vel"] * dirn).sum(-1) - speed)[v] < 1e-6).all()


def _box_polys(xy, yaw, length, width):
    """(..., 4, 2) corners, written independently of the generator's."""
    c, s = np.cos(yaw), np.sin(yaw)
    f = np.stack([c, s], -1)[..., None, :]
    l_ = np.stack([-s, c], -1)[..., None, :]
    sx = np.array([0.5, -0.5, -0.5, 0.5])[:, None]
    sy = np.array([0.5, 0.5, -0.5, -0.5])[:, None]
    return xy[..., None, :] + sx * length[..., None, None] * f + sy * width[..., None, None] * l_


def _sat(p, q):
    """(...) bool: convex quads p, q (..., 4, 2) share interior (gap > 1 mm separates)."""
    sep = np.zeros(p.shape[:-2], bool)
    for poly in (p, q):
        for i in range(2):
            e = poly[..., i + 1, :] - poly[..., i, :]
            n = np.stack([-e[..., 1], e[..., 0]], -1)
            n = n / np.linalg.norm(n, axis=-1, keepdims=True)
            pp, qq = (p * n[..., None, :]).sum(-1), (q * n[..., None, :]).sum(-1)
            sep |= (pp.max(-1) < qq.min(-1) + 1e-3) | (qq.max(-1) < pp.min(-1) + 1e-3)
    return ~sep


def test_no_two_boxes_overlap_and_the_ego_keeps_half_a_metre(scenarios):
    for sc in scenarios:
        A = len(sc["cat"])
        grow = np.zeros(A)
        grow[sc["ego"]] = 0.5 - 1e-3  # the ego's box grown by its required clearance
        length, width = sc["size"][:, 0] + 2 * grow, sc["size"][:, 1] + 2 * grow
        rad = 0.5 * np.hypot(length, width)
        # broad phase: bounding boxes of whole tracks, then circles per step
        big = np.where(sc["valid"][..., None], sc["xy"], np.nan)
        lo = np.nanmin(big, axis=1) - rad[:, None]
        hi = np.nanmax(big, axis=1) + rad[:, None]
        i, j = np.triu_indices(A, 1)
        keep = np.all(lo[i] <= hi[j], axis=1) & np.all(lo[j] <= hi[i], axis=1)
        i, j = i[keep], j[keep]
        both = sc["valid"][i] & sc["valid"][j]
        near = both & (np.linalg.norm(sc["xy"][i] - sc["xy"][j], axis=-1) < (rad[i] + rad[j])[:, None])
        p, t = np.nonzero(near)
        a, b = i[p], j[p]
        hit = _sat(_box_polys(sc["xy"][a, t], sc["yaw"][a, t], length[a], width[a]),
                   _box_polys(sc["xy"][b, t], sc["yaw"][b, t], length[b], width[b]))
        assert not hit.any(), (sc["rec"].scenario_id, a[hit][:3], b[hit][:3], t[hit][:3])


# --------------------------------------------------------------------------
# the ego
# --------------------------------------------------------------------------


def _crossing(sc):
    """(step, stop line) where the ego's centre path crosses a stop line."""
    e = sc["ego"]
    k = np.flatnonzero(sc["valid"][e])
    path = LineString(sc["xy"][e, k])
    for sl in sc["map"].stop_lines:
        seg = LineString(sl.points)
        if path.intersects(seg):
            d = np.array([seg.distance(shapely.Point(p)) for p in sc["xy"][e, k]])
            front = sc["xy"][e, k] + 0.5 * sc["size"][e, 0] * np.stack(
                [np.cos(sc["yaw"][e, k]), np.sin(sc["yaw"][e, k])], -1)
            # first step the front bumper is past the line (its side flips)
            a, b = sl.points
            n = np.array([-(b - a)[1], (b - a)[0]])
            side = (front - a) @ n
            flip = np.flatnonzero(np.sign(side) != np.sign(side[0]))
            return int(k[flip[0]] if len(flip) else k[np.argmin(d)]), sl
    return None, None


def test_ego_log(scenarios):
    road_cache = {}
    for sc in scenarios:
        s, e = sc["rec"], sc["ego"]
        assert s.tracks[e].category == "car"
        k = np.flatnonzero(sc["valid"][e])
        assert k[0] == 0 and np.all(np.diff(k) == 1)
        assert k[-1] <= s.num_steps - 1 - 20, s.scenario_id  # ends >= 2 s before the log
        xy = sc["xy"][e, k]
        r = s.route
        np.testing.assert_array_equal(r.waypoints[0], xy[0])
        np.testing.assert_array_equal(r.waypoints[-1], xy[-1])
        np.testing.assert_array_equal(r.source, xy[0])
        np.testing.assert_array_equal(r.destination, xy[-1])
        gaps = np.linalg.norm(np.diff(r.waypoints, axis=0), axis=1)
        assert gaps.max() <= 2.0 + 1e-9 and gaps.sum() >= 40.0, s.scenario_id
        # on the road all along, through the junction, and >= 15 m past it
        road = road_cache.setdefault(s.map_id, shapely.union_all([Polygon(p) for p in sc["map"].drivable_areas]))
        box = _box_polys(xy, sc["yaw"][e, k], np.full(len(k), sc["size"][e, 0]), np.full(len(k), sc["size"][e, 1]))
        assert shapely.contains_xy(road, box[..., 0].ravel(), box[..., 1].ravel()).all(), s.scenario_id
        # every motor vehicle stays on the road too
        veh = np.isin(sc["cat"], list(VEHICLES))
        pts = sc["xy"][veh][sc["valid"][veh]]
        assert shapely.contains_xy(road, pts[:, 0], pts[:, 1]).all(), s.scenario_id
        box = Polygon(sc["map"].drivable_areas[0])  # the junction box
        inside = shapely.contains_xy(box, xy[:, 0], xy[:, 1])
        assert inside.any() and not inside[-1]
        last_in = np.flatnonzero(inside)[-1]
        assert np.linalg.norm(np.diff(xy[last_in:], axis=0), axis=1).sum() >= 15.0
        # never past a stop line on red
        step, sl = _crossing(sc)
        assert step is not None, s.scenario_id
        if sl.signal_group >= 0:
            assert s.signals[sl.signal_group][step] != RED, s.scenario_id


def test_behaviour_labels_hold_in_the_logs(scenarios):
    for sc in scenarios:
        s, e = sc["rec"], sc["ego"]
        k = np.flatnonzero(sc["valid"][e])
        yaw = np.unwrap(sc["yaw"][e, k])
        turn = np.rad2deg(yaw[-1] - yaw[0])
        step, sl = _crossing(sc)
        state = GREEN if sl.signal_group < 0 else s.signals[sl.signal_group][step]
        speed = np.linalg.norm(sc["vel"][e, k], axis=-1)
        lab = s.behavior
        if lab in ("STR", "LFT", "RT", "UT"):
            got = "UT" if turn > 150 else "LFT" if turn > 40 else "RT" if turn < -40 else "STR"
            assert got == lab and state == GREEN, (s.scenario_id, turn, state)
        elif lab == "YLW":
            assert state == YELLOW, s.scenario_id
        elif lab == "STP":
            line = LineString(sl.points)
            near = np.array([line.distance(shapely.Point(p)) for p in sc["xy"][e, k]]) < 3.0 + sc["size"][e, 0] / 2
            red = s.signals[sl.signal_group][k] == RED
            assert (near & red & (speed < 0.1) & (k < step)).any() and state == GREEN, s.scenario_id
        elif lab == "COV":
            # another vehicle from a different approach inside the junction
            # (box and crosswalks, up to the stop lines) while the ego is at
            # its stop line or inside
            m = sc["map"]
            box = shapely.union_all([Polygon(m.drivable_areas[0])] + [Polygon(c) for c in m.crosswalks]).buffer(2.0)
            ego_xy = sc["xy"][e]
            ego_at = sc["valid"][e] & (shapely.contains_xy(box, ego_xy[:, 0], ego_xy[:, 1]) |
                                       (np.array([LineString(sl.points).distance(shapely.Point(p)) for p in ego_xy])
                                        < 2.0 + sc["size"][e, 0] / 2))
            ok = False
            for a in np.flatnonzero(np.isin(sc["cat"], list(VEHICLES))):
                if a == e:
                    continue
                ka = np.flatnonzero(sc["valid"][a])
                heading = np.unwrap(sc["yaw"][a, ka])
                a_in = shapely.contains_xy(box, sc["xy"][a, :, 0], sc["xy"][a, :, 1]) & sc["valid"][a]
                other_approach = abs((np.rad2deg(heading[0] - yaw[0]) + 180) % 360 - 180) > 30
                if other_approach and (a_in & ego_at).any():
                    ok = True
                    break
            assert ok, s.scenario_id
        elif lab == "IPC":
            ego_line = LineString(sc["xy"][e, k])
            hit = False
            for cw in sc["map"].crosswalks:
                poly = Polygon(cw)
                if not ego_line.intersects(poly):
                    continue
                dist = np.array([poly.distance(shapely.Point(p)) for p in sc["xy"][e]])
                reached = np.maximum.accumulate(np.where(sc["valid"][e], dist < 1e-9, False))
                close = sc["valid"][e] & (dist <= 30.0) & ~(reached & (dist > 0))  # before / on it
                for a in np.flatnonzero(np.isin(sc["cat"], ["pedestrian", "cyclist"])):
                    on = shapely.contains_xy(poly, sc["xy"][a, :, 0], sc["xy"][a, :, 1]) & sc["valid"][a]
                    if (on & close).any():
                        hit = True
                        break
                if hit:
                    break
            assert hit, s.scenario_id


# --------------------------------------------------------------------------
# determinism and helpers
# --------------------------------------------------------------------------

SUBSET = list(range(0, 800, 53))


def test_deterministic_and_seeded(suite):
    a = twin15.generate(0, scenarios=SUBSET, workers=1)
    b = twin15.generate(0, scenarios=SUBSET, workers=1)
    assert _suite_hash(a) == _suite_hash(b)
    full = type(suite)(suite.name, suite.version, suite.maps, [suite.scenarios[i] for i in SUBSET])
    assert _suite_hash(a) == _suite_hash(full)  # a subset comes out exactly as in the whole suite
    c = twin15.generate(1, scenarios=SUBSET, workers=1)
    assert _suite_hash(c) != _suite_hash(a)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-6, 6), min_size=10, max_size=10))
def test_box_overlap_matches_shapely(v):
    x1, y1, a1, l1, w1, x2, y2, a2, l2, w2 = v
    l1, w1, l2, w2 = (abs(z) + 0.2 for z in (l1, w1, l2, w2))
    c1 = corners(np.array([[x1, y1]]), np.array([a1]), np.array([l1]), np.array([w1]))[0]
    c2 = corners(np.array([[x2, y2]]), np.array([a2]), np.array([l2]), np.array([w2]))[0]
    p1, p2 = Polygon(c1), Polygon(c2)
    inter = p1.intersection(p2).area
    got = bool(sat_overlap(c1[None], c2[None])[0])
    if inter > 1e-6:
        assert got
    elif p1.distance(p2) > 1e-6:
        assert not got
