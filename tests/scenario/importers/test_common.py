"""importers.common on hand-built tracks: resampling and gaps, route building,
ego selection, behaviour inference, categories, windows, writing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import LaneRecord, MapRecord, ScenarioRecord, TrackRecord
from drivee2e_jax.scenario.importers import common
from drivee2e_jax.scenario.importers.common import ImportOptions, ImportResult, RawTrack
from drivee2e_jax.scenario.routes import LOG_ROUTE_SPACING_M, ROUTE_END_MARGIN_M
from drivee2e_jax.scenario.schema import read_suite

DT = 0.1


def straight_map(length=200.0) -> MapRecord:
    """One eastbound lane along y = 0 and one westbound at y = 3.5, plus a left-turn lane."""
    xs = np.linspace(-length / 2, length / 2, 41)
    east = LaneRecord(id=1, centerline=np.stack([xs, np.zeros_like(xs)], 1))
    west = LaneRecord(id=2, centerline=np.stack([xs[::-1], np.full_like(xs, 3.5)], 1))
    ang = np.linspace(-np.pi / 2, 0, 10)
    turn = LaneRecord(id=3, centerline=np.stack([20 * np.cos(ang), 20 + 20 * np.sin(ang)], 1))
    north = LaneRecord(id=4, centerline=np.stack([np.full(10, 20.0), np.linspace(20, 100, 10)], 1))
    return MapRecord(map_id="m", lanes=[east, west, turn, north])


def track(tid, xy, cat="car", t=None, yaw=None, visible=None) -> TrackRecord:
    xy = np.asarray(xy, float)
    n = len(xy)
    t = np.arange(n) * DT if t is None else np.asarray(t, float)
    if yaw is None:
        d = np.gradient(xy, axis=0) if n > 1 else np.zeros((1, 2))
        yaw = np.arctan2(d[:, 1], d[:, 0])
    return TrackRecord(track_id=tid, category=cat, size=np.array([4.5, 1.9, 1.5]), t=t, xy=xy, yaw=np.asarray(yaw),
                       visible=visible)


def line(x0, x1, n, y=0.0):
    return np.stack([np.linspace(x0, x1, n), np.full(n, y)], 1)


# ---------------------------------------------------------------- resampling


def test_resample_on_grid_is_a_copy_and_off_grid_is_interpolated():
    t = np.array([0.0, 0.1, 0.2, 0.3])
    r = common.resample(t, np.array([0.0, 1.0, 2.0, 3.0]), DT, 10)
    assert r.k.tolist() == [0, 1, 2, 3] and r.values[:, 0].tolist() == [0, 1, 2, 3]
    assert not r.interpolated.any() and r.gaps == []
    # a 10 Hz source with a 0.05 s offset: every grid value is the midpoint of its neighbours
    r = common.resample(t + 0.05, np.array([0.0, 1.0, 2.0, 3.0]), DT, 10)
    assert r.k.tolist() == [1, 2, 3]
    np.testing.assert_allclose(r.values[:, 0], [0.5, 1.5, 2.5])
    assert r.interpolated.all()


def test_resample_never_interpolates_across_a_gap():
    t = np.array([0.0, 0.1, 0.2, 0.7, 0.8])
    r = common.resample(t, t * 10, DT, 20)
    assert r.k.tolist() == [0, 1, 2, 7, 8]
    assert r.gaps == [(0.2, 0.7)]
    # a larger tolerance (a 2 Hz source) bridges it, and says the samples are interpolated
    r = common.resample(t, t * 10, DT, 20, max_gap_s=0.6)
    assert r.k.tolist() == list(range(9)) and r.gaps == []
    np.testing.assert_allclose(r.values[:, 0], np.arange(9), atol=1e-9)
    assert r.interpolated.tolist() == [False, False, False, True, True, True, True, False, False]


def test_resample_angles_take_the_short_way_round():
    t = np.array([0.0, 0.2])
    r = common.resample(t, np.array([[math.pi - 0.1], [-math.pi + 0.1]]), DT, 3, max_gap_s=0.3, angles=(0,))
    assert abs(abs(r.values[1, 0]) - math.pi) < 1e-9  # through pi, not through 0


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 0.099), st.floats(0.5, 5.0), st.floats(-3.0, 3.0))
def test_resample_reproduces_linear_motion(offset, rate_hz, speed):
    """Property: a linear motion sampled at any rate/offset resamples to the exact line on the grid."""
    t = offset + np.arange(0, 3.0, 1.0 / rate_hz)
    r = common.resample(t, speed * t, DT, 40, max_gap_s=1.0 / rate_hz + 1e-6)
    grid = r.k * DT
    assert np.all(grid >= t[0] - 1e-3) and np.all(grid <= t[-1] + 1e-3)
    np.testing.assert_allclose(r.values[:, 0], speed * np.clip(grid, t[0], t[-1]), atol=1e-9)
    assert len(r.k) == len(np.unique(r.k))


def test_resample_track_keeps_flags_sizes_and_drops_empty():
    raw = RawTrack("a", "car", np.array([0.0, 0.1, 0.2]), line(0, 2, 3), np.zeros(3),
                   np.array([[4.0, 2.0, 1.5], [4.2, 2.0, 1.5], [4.4, 2.0, 1.5]]),
                   vel=np.ones((3, 2)), visible=np.array([True, False, True]))
    tr, r = common.resample_track(raw, 7, DT, 10)
    assert tr.track_id == 7 and tr.visible.tolist() == [True, False, True]
    np.testing.assert_allclose(tr.size, [4.2, 2.0, 1.5])
    np.testing.assert_allclose(tr.vel, np.ones((3, 2)))
    raw_late = RawTrack("b", "car", np.array([5.0]), np.zeros((1, 2)), np.zeros(1), np.ones(3))
    assert common.resample_track(raw_late, 1, DT, 10) == (None, None)


def test_convert_tracks_reports_empty_and_uncovered_tracks():
    raws = [RawTrack("ego", "car", np.arange(5) * DT, line(0, 4, 5), np.zeros(5), np.ones(3)),
            RawTrack("empty", "car", np.zeros(0), np.zeros((0, 2)), np.zeros(0), np.ones(3)),
            RawTrack("late", "car", np.array([9.0]), np.zeros((1, 2)), np.zeros(1), np.ones(3))]
    conv = common.convert_tracks(raws, "ego", DT, 5, "f.bin")
    assert [t.track_id for t in conv.tracks] == [0]
    reasons = sorted(s.reason.split(" (")[0].split(" on ")[0] for s in conv.skipped)
    assert reasons == ["empty track", "no sample"]
    assert conv.ids.table() == {0: "ego", 1: "empty", 2: "late"}


# ---------------------------------------------------------------- categories, markings, geometry


def test_map_category_reports_unknown_and_unusable():
    table = {"vehicle": "car", "static": None}
    assert common.map_category("vehicle", table, "f") == ("car", None)
    cat, skip = common.map_category("static", table, "f track 3")
    assert cat is None and "static" in skip.reason and skip.source == "f track 3"
    cat, skip = common.map_category("spaceship", table, "f")
    assert cat is None and "unknown category 'spaceship'" in skip.reason
    with pytest.raises(DriveE2EError, match="x.json: lanes\\[2\\]: unknown lane marking 'PURPLE'"):
        common.map_marking("PURPLE", {"SOLID": "solid"}, "x.json: lanes[2]")


def test_box_polygon_is_ccw_with_the_right_area():
    p = common.box_polygon(np.array([1.0, 2.0]), 0.7, 4.0, 2.0)
    x, y = p[:, 0], p[:, 1]
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    assert area == pytest.approx(8.0)
    np.testing.assert_allclose(p.mean(0), [1.0, 2.0])


def test_static_obstacle_only_for_objects_that_stay():
    still = RawTrack("c", "car", np.arange(3) * DT, np.array([[0, 0], [0.05, 0], [0, 0.05]]), np.zeros(3),
                     np.array([0.5, 0.5, 1.0]))
    ob = common.static_obstacle(still, "cone")
    assert ob.kind == "cone" and ob.polygon.shape == (4, 2) and ob.height == 1.0
    moving = RawTrack("c", "car", np.arange(3) * DT, line(0, 3, 3), np.zeros(3), np.ones(3))
    assert common.static_obstacle(moving, "cone") is None


def test_infer_successors_and_crop():
    m = straight_map()
    for ln in m.lanes:
        ln.successors = []
    # lane 1 ends at x=100; add one starting there and one starting there but pointing back
    m.lanes.append(LaneRecord(id=5, centerline=line(100, 150, 5)))
    m.lanes.append(LaneRecord(id=6, centerline=line(100, 50, 5, y=0.3)))
    common.infer_successors(m.lanes)
    lanes = {ln.id: ln for ln in m.lanes}
    assert lanes[1].successors == [5]
    assert lanes[3].successors == [4]
    assert [ln.id for ln in common.crop_map(m, np.array([[130.0, 0.0]]), 25.0).lanes] == [5]  # lane 1 ends 30 m away
    cropped = common.crop_map(m, np.array([[130.0, 0.0]]), 31.0)
    assert sorted(ln.id for ln in cropped.lanes) == [1, 2, 5, 6]
    kept = {ln.id: ln for ln in cropped.lanes}
    assert kept[1].successors == [5] and m.lanes[0].successors == [5]  # the original is untouched
    m.lanes[2].successors = [4]
    assert all(s in kept for ln in cropped.lanes for s in ln.successors)


# ---------------------------------------------------------------- routes and ego selection


def test_build_route_keeps_exact_start_ends_short_of_the_log_and_spacing():
    xy = line(0, 50.05, 1002)  # 5 cm steps
    r = common.build_route(track(0, xy))
    np.testing.assert_allclose(r.source, xy[0])
    np.testing.assert_allclose(r.destination, xy[-1])
    np.testing.assert_allclose(r.waypoints[0], xy[0])
    # The route ends ROUTE_END_MARGIN_M before the logged end, so a perfect replay passes its last point.
    np.testing.assert_allclose(r.waypoints[-1], xy[-1] - [ROUTE_END_MARGIN_M, 0.0], atol=1e-9)
    gaps = np.linalg.norm(np.diff(r.waypoints, axis=0), axis=1)
    assert gaps[:-1].min() >= LOG_ROUTE_SPACING_M - 1e-9 and gaps.max() < 2 * LOG_ROUTE_SPACING_M
    standing = common.build_route(track(0, np.zeros((5, 2))))
    assert standing.waypoints.shape == (2, 2)


def test_route_heading_change_signs():
    ang = np.linspace(-np.pi / 2, 0, 30)
    left = np.stack([20 * np.cos(ang), 20 + 20 * np.sin(ang)], 1)
    assert math.degrees(common.route_heading_change(left)) == pytest.approx(90, abs=5)
    assert math.degrees(common.route_heading_change(left * [1, -1])) == pytest.approx(-90, abs=5)
    jitter = np.random.default_rng(0).normal(0, 0.02, (50, 2))  # a standing vehicle
    assert common.route_heading_change(jitter) == 0.0


def test_select_ego_follows_the_curation_rules():
    m = straight_map()
    n = 50
    tracks = [
        track(1, line(-40, 0, n)),                        # 40 m east in its lane: candidate
        track(2, line(-40, 10, n)),                       # 50 m: the longest, but leaves after step 40
        track(3, line(-60, -20, n), cat="pedestrian"),    # not a vehicle
        track(4, line(-40, -38, n)),                      # barely moves
        track(5, line(40, -20, n)),                       # 60 m westbound in the eastbound lane: off its lanes
        track(6, line(-40, 10, n, y=0.0), visible=np.r_[np.ones(n - 1, bool), False]),
    ]
    tracks[1] = track(2, line(-40, 10, 40))
    ego, reasons = common.select_ego(tracks, m, n, DT)
    assert ego.track_id == 1
    assert "present at 40 of 50" in reasons[2]
    assert "moves 2.0 m" in reasons[4]
    assert "leaves the lanes" in reasons[5]
    assert "not visible" in reasons[6]
    assert 3 not in reasons
    none, _ = common.select_ego(tracks[2:], m, n, DT)
    assert none is None


def _glitched(tid, x0, x1, n, at=25, jump_m=1.5):
    """A car driving east along y = 0 whose position jumps ``jump_m`` ahead at one step (an annotation glitch)."""
    xy = line(x0, x1, n)
    xy[at, 0] += jump_m
    return track(tid, xy, yaw=np.zeros(n))


def test_select_ego_passes_over_candidates_with_implausible_motion():
    m = straight_map()
    n = 50
    spiky, clean = _glitched(1, -40, 10, n), track(2, line(-40, 0, n))  # the glitched one has the longer path
    ego, reasons = common.select_ego([spiky, clean], m, n, DT)
    assert ego.track_id == 2
    assert reasons[1].startswith(common.PLAUSIBILITY_PREFIX + "car acceleration")
    assert "m/s^2 > 12 m/s^2" in reasons[1] and "at t=2." in reasons[1]
    # through windowed_scenarios: the note names the candidate passed over, by its source id too
    skipped, notes = [], []
    out = common.windowed_scenarios("x", m, [spiky, clean], None, DT, n, ImportOptions(), "f", skipped, notes,
                                    source_ids={1: "veh-a", 2: "veh-b"})
    assert [s.ego_track_id for s in out] == [2] and not skipped
    chosen = next(x for x in notes if "ego chosen automatically" in x)
    assert "track 2 (source veh-b)" in chosen
    assert "candidates passed over: track 1 (source veh-a): implausible motion: car acceleration" in chosen
    # no clean candidate left: the window is skipped, naming the near miss first and how to force it
    out = common.windowed_scenarios("x", m, [track(3, line(-40, -38, n)), spiky], None, DT, n, ImportOptions(), "f",
                                    skipped, notes, source_ids={1: "veh-a", 3: "veh-c"})
    assert out == []
    assert skipped[-1].reason.startswith("no vehicle qualifies as ego (1 (source veh-a): implausible motion: ")
    assert "3 (source veh-c): moves 2.0 m" in skipped[-1].reason
    assert skipped[-1].reason.endswith("; --ego SOURCE_ID uses one anyway")


# ---------------------------------------------------------------- behaviour


def _scenario(tracks, ego_id=0):
    ego = next(t for t in tracks if t.track_id == ego_id)
    return ScenarioRecord("s", "test", "i", "m", "STR", "clear", "day", ego_id, common.build_route(ego), DT,
                          len(ego.t), tracks)


def test_infer_behavior_turns():
    m = straight_map()
    ang = np.linspace(-np.pi / 2, 0, 60)
    left = np.stack([20 * np.cos(ang), 20 + 20 * np.sin(ang)], 1)
    assert common.infer_behavior(_scenario([track(0, line(-30, 30, 60))]), m)[0] == "STR"
    assert common.infer_behavior(_scenario([track(0, left)]), m)[0] == "LFT"
    assert common.infer_behavior(_scenario([track(0, left * [1, -1])]), m)[0] == "RT"
    u = np.concatenate([line(-30, 0, 30), np.stack([3 * np.sin(np.linspace(0, np.pi, 20)),
                                                     1.75 - 1.75 * np.cos(np.linspace(0, np.pi, 20))], 1),
                        line(0, -30, 30, y=3.5)])
    assert common.infer_behavior(_scenario([track(0, u)]), m)[0] == "UT"


def test_infer_behavior_stop_and_go():
    xy = np.concatenate([line(-30, -20, 20), np.tile([[-20.0, 0.0]], (15, 1)), line(-20, 0, 20)])
    label, why = common.infer_behavior(_scenario([track(0, xy)]), straight_map())
    assert label == "STP" and "stopped" in why
    # a stop at the very end (no driving on) is not STP
    xy = np.concatenate([line(-30, -20, 20), np.tile([[-20.0, 0.0]], (15, 1))])
    assert common.infer_behavior(_scenario([track(0, xy)]), straight_map())[0] == "STR"


def test_infer_behavior_pedestrian_on_crossing_and_crossing_vehicle():
    m = straight_map()
    m.crosswalks = [np.array([[0.0, -2.0], [4.0, -2.0], [4.0, 6.0], [0.0, 6.0]])]
    ego = track(0, line(-30, 30, 60))
    ped = track(9, np.tile([[2.0, 4.0]], (60, 1)), cat="pedestrian")
    assert common.infer_behavior(_scenario([ego, ped]), m)[0] == "IPC"
    ped_off = track(9, np.tile([[2.0, 9.0]], (60, 1)), cat="pedestrian")
    assert common.infer_behavior(_scenario([ego, ped_off]), m)[0] == "STR"
    m.crosswalks = []
    # a vehicle crosses x = 10 northbound at step 25, when the ego (1 m/step from -30) is at x = -5: 15 m before
    cross = track(5, np.stack([np.full(60, 10.0), np.linspace(-25, 35, 60)], 1))
    assert common.infer_behavior(_scenario([ego, cross]), m)[0] == "COV"
    # the same vehicle crossing after the ego has passed: no conflict
    late = track(5, np.stack([np.full(60, -25.0), np.linspace(-25, 35, 60)], 1))
    assert common.infer_behavior(_scenario([ego, late]), m)[0] == "STR"


# ---------------------------------------------------------------- windows, scenarios, writing


def test_windows_and_cut():
    assert common.windows(100, DT, None) == [(0, 100)]
    assert common.windows(100, DT, 3.0) == [(0, 30), (30, 60), (60, 90)]  # the 1 s rest is dropped
    assert common.windows(110, DT, 5.0) == [(0, 50), (50, 100)]
    tr = track(1, line(0, 9.9, 100))
    cut = common.cut_window([tr, track(2, line(0, 1, 5))], 30, 60, DT)
    assert len(cut) == 1
    np.testing.assert_allclose(cut[0].t, np.arange(30) * DT)
    np.testing.assert_allclose(cut[0].xy[0], [3.0, 0.0])


def test_windowed_scenarios_skip_windows_without_the_ego():
    m = straight_map()
    ego = track(0, line(-50, 49, 100))
    short = track(0, line(-50, 0, 70))
    skipped, notes = [], []
    out = common.windowed_scenarios("x", m, [ego], 0, DT, 100, ImportOptions(window_s=5.0), "f", skipped, notes)
    assert [s.scenario_id for s in out] == ["x_w00", "x_w01"] and all(s.num_steps == 50 for s in out)
    out = common.windowed_scenarios("x", m, [short], 0, DT, 100, ImportOptions(window_s=5.0), "f", skipped, notes)
    assert [s.scenario_id for s in out] == ["x_w00"]
    assert "present at 20 of 50 steps" in skipped[-1].reason and "window 5-10 s" in skipped[-1].source
    out = common.windowed_scenarios("x", m, [ego], 0, DT, 100, ImportOptions(window_s=5.0, max_scenarios=1), "f",
                                    skipped, notes)
    assert len(out) == 1


def test_windowed_scenarios_cut_signals_per_window():
    m = straight_map()
    ego = track(0, line(-50, 49, 100))
    full = {3: (np.arange(100) % 4).astype(np.int8), 1: np.full(100, 2, np.int8)}
    as_function = lambda t: {g: v[np.rint(t / DT).astype(int)] for g, v in full.items()}  # noqa: E731
    for source in (full, as_function):
        out = common.windowed_scenarios("x", m, [ego], 0, DT, 100, ImportOptions(window_s=3.0), "f", [], [],
                                        signals=source)
        assert [s.scenario_id for s in out] == ["x_w00", "x_w01", "x_w02"]
        for s, k0 in zip(out, (0, 30, 60)):
            assert sorted(s.signals) == [1, 3] and s.signals[3].dtype == np.int8
            np.testing.assert_array_equal(s.signals[3], full[3][k0:k0 + 30])
            np.testing.assert_array_equal(s.signals[1], 2)
    none = common.windowed_scenarios("x", m, [ego], 0, DT, 100, ImportOptions(), "f", [], [])
    assert none[0].signals == {}
    with pytest.raises(ValueError, match=r"signals\[3\]: expected 100 states"):
        common.windowed_scenarios("x", m, [ego], 0, DT, 100, ImportOptions(), "f", [], [], signals={3: full[3][:50]})


def test_static_or_skip():
    still = RawTrack("c", "car", np.arange(5) * DT, np.zeros((5, 2)), np.zeros(5), np.array([0.5, 0.5, 1.0]))
    moving = RawTrack("c", "car", np.arange(5) * DT, line(0, 4, 5), np.zeros(5), np.array([0.5, 0.5, 1.0]))
    own = common.Skipped("f track c", "category 'CONE' has no agent category (not a road user)")
    assert common.static_or_skip(still, "cone", own, "category 'CONE'").kind == "cone"
    assert common.static_or_skip(still, None, own, "category 'CONE'") is own
    moved = common.static_or_skip(moving, "cone", own, "category 'CONE'")
    assert moved == common.Skipped("f track c", "category 'CONE' moves; no agent category for it")


def test_write_result_error_names_the_first_skipped_item(tmp_path):
    res = ImportResult({}, [], [common.Skipped("a.xml", "no dynamic obstacle with a usable trajectory, so no ego"),
                                common.Skipped("b.xml", "other")], [])
    with pytest.raises(DriveE2EError) as e:
        common.write_result(res, tmp_path / "empty", name="t")
    assert str(e.value) == (f"nothing to write to {tmp_path / 'empty'}: no scenario could be imported (2 items "
                            "skipped; first: a.xml: no dynamic obstacle with a usable trajectory, so no ego)")
    with pytest.raises(DriveE2EError, match=r"imported \(0 items skipped\)$"):
        common.write_result(ImportResult({}, [], [], []), tmp_path / "empty", name="t")


def test_parse_xml_errors(tmp_path):
    ok = tmp_path / "ok.xml"
    ok.write_text("<osm><node id='1'/></osm>")
    assert common.parse_xml(ok, "OSM", "osm").tag == "osm"
    for text, needle in (("<osm><node", "expected well-formed OSM XML, got a parse error"),
                         ("<map/>", "expected an <osm> root element, got <map>")):
        ok.write_text(text)
        with pytest.raises(DriveE2EError, match=needle):
            common.parse_xml(ok, "OSM", "osm")
    with pytest.raises(DriveE2EError, match="missing.xml: expected a readable OSM file"):
        common.parse_xml(tmp_path / "missing.xml", "OSM", "osm")


def test_write_result_refuses_non_empty_and_writes_valid_suite(tmp_path):
    m = straight_map()
    s, _ = common.make_scenario("a/b c", m, [track(0, line(-50, 0, 50))], 0, DT, 50, ImportOptions(split="val"))
    assert s.scenario_id == "a_b_c" and s.split == "val"
    res = ImportResult(maps={"m": m}, scenarios=[s], skipped=[], notes=[], meta={"source": "test"})
    out = tmp_path / "suite"
    common.write_result(res, out, name="t")
    back = read_suite(out)
    assert [x.scenario_id for x in back.scenarios] == ["a_b_c"] and back.meta["source"] == "test"
    with pytest.raises(DriveE2EError, match="not empty"):
        common.write_result(res, out, name="t")
    common.write_result(res, out, name="t", force=True)
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "x.txt").write_text("x")
    with pytest.raises(DriveE2EError, match="no suite.json"):
        common.write_result(res, junk, name="t", force=True)
    with pytest.raises(DriveE2EError, match="no scenario could be imported"):
        common.write_result(ImportResult({}, [], [], []), tmp_path / "empty", name="t")


def test_import_options_are_checked():
    with pytest.raises(DriveE2EError, match="--split"):
        ImportOptions(split="dev")
    with pytest.raises(DriveE2EError, match="--max-scenarios"):
        ImportOptions(max_scenarios=0)
    with pytest.raises(DriveE2EError, match="--window-s"):
        ImportOptions(window_s=-1)


def test_merge_results_rejects_duplicate_ids():
    m = straight_map()
    s, _ = common.make_scenario("a", m, [track(0, line(-50, 0, 50))], 0, DT, 50, ImportOptions())
    r1 = ImportResult({"m": m}, [s], [], ["n1"], {"track_ids": {"a": {}}})
    r2 = ImportResult({"m": m}, [], [common.Skipped("f", "why")], ["n2"], {"track_ids": {"b": {}}})
    merged = common.merge_results([r1, r2])
    assert len(merged.scenarios) == 1 and merged.notes == ["n1", "n2"] and set(merged.meta["track_ids"]) == {"a", "b"}
    with pytest.raises(DriveE2EError, match="comes from two inputs"):
        common.merge_results([r1, r1])


def test_read_table_errors(tmp_path):
    pa = pytest.importorskip("pyarrow", reason="the import extra (pyarrow) is not installed")
    import pyarrow.parquet as pq

    p = tmp_path / "x.parquet"
    pq.write_table(pa.table({"a": [1, 2], "b": ["x", "y"]}), p)
    cols = common.read_table(p, ["a", "b"])
    assert cols["a"].tolist() == [1, 2] and cols["b"].tolist() == ["x", "y"]
    with pytest.raises(DriveE2EError, match="x.parquet: missing column 'c'"):
        common.read_table(p, ["a", "c"])
    bad = tmp_path / "bad.parquet"
    bad.write_text("not parquet")
    with pytest.raises(DriveE2EError, match="bad.parquet: not a readable Parquet file"):
        common.read_table(bad, ["a"])
