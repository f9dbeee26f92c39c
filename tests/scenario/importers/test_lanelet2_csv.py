"""Lanelet2 OSM + drone CSV importer: projection oracles, the SinD samples,
a tiny hand-written recording end to end, and one-line errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.importers import lanelet2_csv as lc
from drivee2e_jax.scenario.importers.common import ImportOptions, write_result
from drivee2e_jax.scenario.importers.lanelet2 import load_map, marking_of, utm_projector
from drivee2e_jax.scenario.schema import validate_suite

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"
SIND = DATA / "sind"


def _need_sind():
    if not (SIND / "Tianjin" / "map_relink_law_save.osm").is_file():
        pytest.skip(f"shared SinD samples not found at {SIND} (the repo's ../shared/data)")


# --------------------------------------------------------------------------
# Projection
# --------------------------------------------------------------------------


def test_utm_known_value_equator():
    # (0 N, 0 E) is E = 166021.4431 m, N = 0 in UTM zone 31 (central meridian 3 E, E0 = 500 km)
    xy = utm_projector(0.0, 3.0)(np.array([0.0]), np.array([0.0]))[0]
    np.testing.assert_allclose(xy, [166021.4431 - 500000.0, 0.0], atol=2e-3)


def test_utm_northing_on_central_meridian_is_scaled_meridian_arc():
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    proj = utm_projector(0.0, 3.0)
    for lat in (0.01, 12.5, 47.0):
        arc = integrate.quad(lambda p: a * (1 - e2) / (1 - e2 * math.sin(p) ** 2) ** 1.5, 0, math.radians(lat),
                             epsabs=1e-9)[0]
        xy = proj(np.array([lat]), np.array([3.0]))[0]
        assert xy[0] == pytest.approx(0.0, abs=1e-6)
        assert xy[1] == pytest.approx(0.9996 * arc, abs=1e-3)


def test_marking_of_tags():
    assert marking_of({"type": "curbstone", "subtype": "low"}) == "road_edge"
    assert marking_of({"type": "line_thin", "subtype": "dashed"}) == "dashed"
    assert marking_of({"type": "line_thick", "subtype": "solid_solid"}) == "double_solid"
    assert marking_of({"type": "line_thin"}) == "solid"
    assert marking_of({"type": "virtual"}) == "none"
    assert marking_of({"type": "fancy_paint"}) is None


# --------------------------------------------------------------------------
# The SinD maps
# --------------------------------------------------------------------------


def test_tianjin_map_lanes_crosswalks_stop_lines_lights():
    _need_sind()
    m, notes = load_map(SIND / "Tianjin" / "map_relink_law_save.osm", "tj")
    assert len(m.lanes) == 62 and len(m.crosswalks) == 4  # 66 lanelets, 4 of them crosswalks
    assert {s.signal_group for s in m.stop_lines} == {2, 4, 6, 8}  # 'Traffic light 2/4/6/8'
    lanes = {ln.id: ln for ln in m.lanes}
    import shapely

    for s in m.stop_lines:  # each stop line lies across the last metres of a driving (approach) lane
        ln = lanes[s.lane_id]
        assert ln.type == "driving"
        mid = shapely.Point(s.points.mean(axis=0))
        line = shapely.LineString(ln.centerline)
        assert line.distance(mid) < 0.05 or np.linalg.norm(ln.centerline[-1] - s.points.mean(axis=0)) < 1.6
        assert line.length - line.project(mid) < 10.0
        assert np.linalg.norm(s.points[1] - s.points[0]) == pytest.approx(ln.width)
    for ln in m.lanes:  # successors start where their predecessor ends
        for sid in ln.successors:
            assert np.linalg.norm(lanes[sid].centerline[0] - ln.centerline[-1]) < 1.5
    assert sum(ln.type == "connector" for ln in m.lanes) >= 16  # the turning and crossing paths
    assert all(2.0 < ln.width < 10.0 for ln in m.lanes)
    # right-hand traffic: on the west approach (x < 0) eastbound lanes lie south of westbound ones
    west = [ln for ln in m.lanes if ln.centerline[:, 0].max() < 0]
    east_y = [ln.centerline[:, 1].mean() for ln in west if ln.centerline[-1, 0] > ln.centerline[0, 0]]
    west_y = [ln.centerline[:, 1].mean() for ln in west if ln.centerline[-1, 0] < ln.centerline[0, 0]]
    assert east_y and west_y and max(east_y) < min(west_y)


def test_changchun_map_and_pedestrians_in_its_frame():
    _need_sind()
    m, _ = load_map(SIND / "Changchun" / "Changchun_Pudong.osm", "cc")
    assert len(m.lanes) == 37 and not m.crosswalks
    assert m.stop_lines and all(s.signal_group == -1 for s in m.stop_lines)  # no regulatory elements
    raws, skipped, _ = lc.read_tracks(SIND / "Changchun" / "changchun_pudong_507_009" / "Ped_smoothed_tracks.csv")
    assert len(raws) == 49 and not skipped and all(r.category == "pedestrian" for r in raws)
    pts = np.vstack([r.xy for r in raws])
    allc = np.vstack([ln.centerline for ln in m.lanes])
    lo, hi = allc.min(0) - 5, allc.max(0) + 5
    inside = np.all((pts >= lo) & (pts <= hi), axis=1)
    assert inside.mean() > 0.99


def test_sind_samples_have_no_vehicle_tracks_and_say_so():
    _need_sind()
    res = lc.load([SIND / "Changchun"], ImportOptions())
    assert list(res.maps) == ["Changchun_Pudong"] and res.scenarios == []
    assert len(res.skipped) == 1 and "no vehicle tracks" in res.skipped[0].reason
    assert "Veh_smoothed_tracks.csv" in res.skipped[0].reason
    res = lc.load([SIND / "Tianjin" / "8_2_1"], ImportOptions())
    assert res.scenarios == [] and "lists 611 vehicles" in res.skipped[0].reason
    with pytest.raises(DriveE2EError, match="no scenario could be imported"):
        write_result(res, Path("/nonexistent/never_written"), name="x")


def test_sind_light_csv():
    _need_sind()
    t, groups = lc.read_signal_events(SIND / "Tianjin" / "8_2_1" / "TrafficLight_8_2_1.csv")
    assert sorted(groups) == list(range(1, 9)) and len(t) == 122 and np.all(np.diff(t) >= 0)
    # first row (t < 0): light 1 green, light 2 red
    st = {g: lc.signal_states(t, s, np.array([0.0])) for g, s in groups.items()}
    assert st[1][0] == 3 and st[2][0] == 1


def test_signal_states_hold_until_next_change():
    times = np.array([1000.0, 2000.0])
    states = np.array([1, 3], np.int8)
    got = lc.signal_states(times, states, np.array([0.0, 999.0, 1000.0, 1999.0, 2000.0, 9e9]))
    assert got.tolist() == [0, 0, 1, 1, 3, 3]


# --------------------------------------------------------------------------
# A tiny recording end to end
# --------------------------------------------------------------------------


def _node(i, x, y):
    return f'<node id="{i}" lat="0" lon="0"><tag k="local_x" v="{x}"/><tag k="local_y" v="{y}"/></node>'


def _way(i, nodes, **tags):
    t = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
    return f'<way id="{i}">' + "".join(f'<nd ref="{n}"/>' for n in nodes) + t + "</way>"


def _rel(i, members, **tags):
    t = "".join(f'<tag k="{k}" v="{v}"/>' for k, v in tags.items())
    m = "".join(f'<member type="way" ref="{r}" role="{role}"/>' for r, role in members)
    return f'<relation id="{i}">{m}{t}</relation>'


def tiny_osm(reverse_right: bool = False, light_without_line: bool = False) -> str:
    """Two lanelets along +x (y 0..3.5), a crosswalk at x 20..24, a stop line at x = 0
    guarded by 'Traffic light 3'. Local metric coordinates (local_x/local_y)."""
    nodes = [_node(1, -60, 3.5), _node(2, 0, 3.5), _node(3, 60, 3.5), _node(4, -60, 0), _node(5, 0, 0),
             _node(6, 60, 0), _node(7, 20, -2), _node(8, 20, 6), _node(9, 24, -2), _node(10, 24, 6),
             _node(11, 0, 0), _node(12, 0, 3.5), _node(13, -2, -3), _node(14, -2, -2)]
    right_a = [5, 4] if reverse_right else [4, 5]
    ways = [_way(101, [1, 2], type="line_thin", subtype="solid"), _way(102, [2, 3], type="line_thin", subtype="dashed"),
            _way(103, right_a, type="curbstone"), _way(104, [5, 6], type="curbstone"),
            _way(105, [7, 8], type="zebra_marking"), _way(106, [9, 10], type="zebra_marking"),
            _way(107, [11, 12], type="stop_line"), _way(108, [13, 14], type="traffic_light", name="Traffic light 3")]
    if light_without_line:  # the lanelet names the light; the light has no stop line drawn
        return tiny_osm(reverse_right).replace(
            '<member type="way" ref="107" role="ref_line"/>', "").replace(
            '<member type="way" ref="103" role="right"/>',
            '<member type="way" ref="103" role="right"/><member type="relation" ref="204" role="regulatory_element"/>', 1)
    rels = [_rel(201, [(101, "left"), (103, "right")], type="lanelet", subtype="road"),
            _rel(202, [(102, "left"), (104, "right")], type="lanelet", subtype="road"),
            _rel(203, [(105, "left"), (106, "right")], type="lanelet", subtype="crosswalk"),
            _rel(204, [(107, "ref_line"), (108, "refers")], type="regulatory_element", subtype="traffic_light")]
    return '<?xml version="1.0"?>\n<osm version="0.6">' + "".join(nodes + ways + rels) + "</osm>\n"


def _vehicle_csv(path: Path) -> None:
    rows = ["track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,width"]
    for f in range(200):  # car 1: x -50 -> 49.5 at 5 m/s on the lane centre
        rows.append(f"1,{f},{f * 100},car,{-50 + 0.5 * f:.2f},1.75,5.0,0.0,0.0,4.6,1.9")
    for f in range(50, 60):  # a parked truck, 1 s
        rows.append(f"2,{f},{f * 100},truck,40.0,-6.0,0.0,0.0,0.0,8.0,2.5")
    rows.append("3,5,500,tram,10.0,-10.0,0,0,0,20,2.5")  # not a category we know
    path.write_text("\n".join(rows) + "\n")


def _ped_csv(path: Path) -> None:
    rows = ["track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy"]
    for f in range(80):  # crosses the crosswalk at 1 m/s, t 0..7.9 s
        rows.append(f"P1,{f},{f * 100},pedestrian/bicycle,22.0,{-2 + 0.1 * f:.2f},0.0,1.0")
    path.write_text("\n".join(rows) + "\n")


def _lights_csv(path: Path) -> None:
    path.write_text("RawFrameID,timestamp(ms),Traffic light 3\n-30,-1000,0\n60,2000.0,1\n")


@pytest.fixture
def tiny_recording(tmp_path) -> Path:
    rec = tmp_path / "loc" / "rec_a"
    rec.mkdir(parents=True)
    (tmp_path / "loc" / "tiny.osm").write_text(tiny_osm())
    _vehicle_csv(rec / "vehicle_tracks_000.csv")
    _ped_csv(rec / "pedestrian_tracks_000.csv")
    _lights_csv(rec / "Traffic_Lights.csv")
    return rec


def test_tiny_map(tmp_path):
    p = tmp_path / "t.osm"
    p.write_text(tiny_osm())
    m, _ = load_map(p, "t")
    lanes = {ln.id: ln for ln in m.lanes}
    assert set(lanes) == {201, 202} and lanes[201].successors == [202]
    np.testing.assert_allclose(lanes[201].centerline[[0, -1]], [[-60, 1.75], [0, 1.75]])
    assert lanes[201].width == pytest.approx(3.5)
    assert (lanes[201].left_marking, lanes[201].right_marking) == ("solid", "road_edge")
    assert (lanes[202].left_marking, lanes[202].right_marking) == ("dashed", "road_edge")
    assert len(m.crosswalks) == 1 and len(m.stop_lines) == 1
    sl = m.stop_lines[0]
    assert (sl.lane_id, sl.signal_group) == (201, 3)
    np.testing.assert_allclose(sorted(sl.points[:, 1]), [0.0, 3.5], atol=1e-6)
    # a right way drawn backwards gives the same lane
    p.write_text(tiny_osm(reverse_right=True))
    m2, _ = load_map(p, "t")
    np.testing.assert_allclose(m2.lanes[0].centerline, m.lanes[0].centerline)


def test_light_without_stop_line_stops_its_lanelets_at_their_end(tmp_path):
    p = tmp_path / "t.osm"
    text = tiny_osm(light_without_line=True).replace('<way id="107"><nd ref="11"/><nd ref="12"/><tag k="type" v="stop_line"/></way>', "")
    assert "ref_line" not in text and 'type="stop_line"' not in text
    p.write_text(text)
    m, _ = load_map(p, "t")
    assert [(s.lane_id, s.signal_group) for s in m.stop_lines] == [(201, 3)]
    np.testing.assert_allclose(m.stop_lines[0].points.mean(axis=0), [0.0, 1.75], atol=1e-9)


def test_tiny_recording_end_to_end(tiny_recording, tmp_path):
    res = lc.load([tiny_recording], ImportOptions())
    assert len(res.scenarios) == 1
    s = res.scenarios[0]
    assert s.scenario_id == "rec_a_000" and s.num_steps == 200 and s.behavior == "STR"
    ids = res.meta["track_ids"]["rec_a_000"]
    assert ids[str(s.ego_track_id)] == "1"  # the only car long enough: auto-selected ego
    cats = {ids[str(t.track_id)]: t.category for t in s.tracks}
    assert cats == {"1": "car", "2": "truck", "P1": "pedestrian"}
    assert any("tram" in k.reason for k in res.skipped)
    # light 3 is red until 2.0 s, then green; unknown never (a state before the recording exists)
    sig = s.signals[3]
    assert sig[:20].tolist() == [1] * 20 and set(sig[20:].tolist()) == {3}
    ped = next(t for t in s.tracks if t.category == "pedestrian")
    np.testing.assert_allclose(ped.yaw, math.pi / 2, atol=1e-6)  # direction of motion
    out = tmp_path / "suite"
    write_result(res, out, name="tiny")
    assert validate_suite(out) == []


def test_ego_option_and_windows(tiny_recording):
    res = lc.load([tiny_recording], ImportOptions(window_s=10.0, ego="1"))
    assert [s.scenario_id for s in res.scenarios] == ["rec_a_000_w00", "rec_a_000_w01"]
    assert all(s.ego_track_id == 0 for s in res.scenarios)
    w1 = res.scenarios[1]
    assert set(w1.signals[3].tolist()) == {3}  # the second window is all green
    with pytest.raises(DriveE2EError, match="--ego 'nope'"):
        lc.load([tiny_recording], ImportOptions(ego="nope"))


def test_single_csv_file_input_and_empty_tracks(tiny_recording):
    res = lc.load([tiny_recording / "pedestrian_tracks_000.csv"], ImportOptions())
    # the file names the recording: both of its CSVs are read
    assert len(res.scenarios) == 1
    (tiny_recording / "vehicle_tracks_000.csv").write_text("track_id,frame_id,timestamp_ms,agent_type,x,y\n")
    res = lc.load([tiny_recording], ImportOptions())
    assert res.scenarios == [] and any("no track rows" in k.reason for k in res.skipped)
    assert any("no vehicle tracks" in k.reason for k in res.skipped)


@pytest.mark.parametrize("header, row, needle", [
    ("track_id,frame_id,agent_type,x,y", "1,0,car,0,0", "missing column 'timestamp_ms'"),
    ("track_id,frame_id,timestamp_ms,agent_type,x,y", "1,0,abc,car,0,0", "line 2, column 'timestamp_ms': expected a number"),
    ("track_id,frame_id,timestamp_ms,agent_type,x,y", "1,0,0,car", "line 2: expected 6 fields"),
])
def test_bad_csv_one_line_errors(tiny_recording, header, row, needle):
    p = tiny_recording / "vehicle_tracks_000.csv"
    p.write_text(f"{header}\n{row}\n")
    with pytest.raises(DriveE2EError) as e:
        lc.load([tiny_recording], ImportOptions())
    assert str(p) in str(e.value) and needle in str(e.value) and "\n" not in str(e.value)


def test_lfs_pointer_is_named(tiny_recording):
    (tiny_recording / "vehicle_tracks_000.csv").unlink()
    (tiny_recording / "pedestrian_tracks_000.csv").unlink()
    (tiny_recording / "Veh_smoothed_tracks.csv").write_text(
        "version https://git-lfs.github.com/spec/v1\noid sha256:abc\nsize 130000000\n")
    res = lc.load([tiny_recording], ImportOptions())
    assert res.scenarios == [] and "Git LFS pointer" in res.skipped[0].reason


@pytest.mark.parametrize("text, needle", [
    ("<osm><node id='1' lat='0'", "well-formed OSM XML"),
    ("<map/>", "an <osm> root"),
    ("<osm><node id='x' lat='0' lon='0'/></osm>", "<node>: expected an integer 'id'"),
    ("<osm><node id='1' lat='a' lon='0'/></osm>", "<node id=1>: expected numeric 'lat' and 'lon'"),
    ("<osm><node id='1' lat='0' lon='0'/><relation id='5'><member type='way' ref='9' role='left'/>"
     "<tag k='type' v='lanelet'/></relation></osm>", "<relation id=5> (lanelet): expected one 'left' and one 'right'"),
    ("<osm><node id='1' lat='0' lon='0'/><relation id='5'><member type='way' ref='9' role='left'/>"
     "<member type='way' ref='8' role='right'/><tag k='type' v='lanelet'/></relation></osm>",
     "relation 5 left: expected a way id present in the file, got 9"),
    ("<osm><node id='1' lat='0' lon='0'/></osm>", "expected at least one lanelet"),
])
def test_bad_osm_one_line_errors(tmp_path, text, needle):
    p = tmp_path / "bad.osm"
    p.write_text(text)
    with pytest.raises(DriveE2EError) as e:
        load_map(p, "bad")
    assert str(p) in str(e.value) and needle in str(e.value) and "\n" not in str(e.value)


def test_no_map_found(tmp_path):
    rec = tmp_path / "r"
    rec.mkdir()
    _vehicle_csv(rec / "vehicle_tracks_000.csv")
    with pytest.raises(DriveE2EError, match="expected a Lanelet2 .osm map"):
        lc.load([rec], ImportOptions())


# --------------------------------------------------------------------------
# SinD file format (synthetic tracks on the real Tianjin map and light log)
# --------------------------------------------------------------------------

_SIND_VEH = ("track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,yaw_rad,heading_rad,length,width,"
             "ax,ay,v_lon,v_lat,a_lon,a_lat")


def tianjin_path(m, group: int = 4) -> tuple[np.ndarray, float]:
    """A straight-on path from the start of a lane stopped by light ``group``
    through its junction: (points (n, 2), arc length of the stop line along it)."""
    import shapely

    lanes = {ln.id: ln for ln in m.lanes}
    stop = next(s for s in m.stop_lines if s.signal_group == group)
    chain = [lanes[stop.lane_id]]
    while chain[-1].successors and len(chain) < 4:
        h_end = lambda ln: math.atan2(*(ln.centerline[-1] - ln.centerline[-2])[::-1])  # noqa: E731
        nxt = [lanes[i] for i in chain[-1].successors]
        chain.append(min(nxt, key=lambda ln: abs(math.remainder(h_end(ln) - h_end(chain[0]), 2 * math.pi))))
    pts = np.vstack([chain[0].centerline] + [ln.centerline[1:] for ln in chain[1:]])
    line = shapely.LineString(pts)
    return pts, line.project(shapely.Point(stop.points.mean(axis=0)))


def write_sind_recording(folder: Path, m, speed: float = 5.0) -> None:
    """Veh/Ped_smoothed_tracks.csv in SinD's format: car 5 drives ``tianjin_path`` at
    ``speed`` from t = 0 (frames of 100.1 ms); car 9 waits at another stop line; P3 walks."""
    pts, _ = tianjin_path(m)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))]
    n = int((s[-1] - 1.0) / (speed * 0.1001))
    rows = [_SIND_VEH]
    for f in range(n):
        d = f * 0.1001 * speed
        x, y = np.interp(d, s, pts[:, 0]), np.interp(d, s, pts[:, 1])
        x2, y2 = np.interp(d + 0.3, s, pts[:, 0]), np.interp(d + 0.3, s, pts[:, 1])
        h = math.atan2(y2 - y, x2 - x)
        rows.append(f"5,{f},{f * 100.1:.4f},car,{x:.4f},{y:.4f},{speed * math.cos(h):.4f},{speed * math.sin(h):.4f},"
                    f"{h:.5f},{h:.5f},4.6,1.85,0,0,{speed},0,0,0")
    other = next(st for st in m.stop_lines if st.signal_group == 2)
    wx, wy = other.points.mean(axis=0) - 0.0
    lane = next(ln for ln in m.lanes if ln.id == other.lane_id)
    h = math.atan2(*(lane.centerline[-1] - lane.centerline[-2])[::-1])
    wx, wy = wx - 4.0 * math.cos(h), wy - 4.0 * math.sin(h)
    for f in range(n):
        rows.append(f"9,{f},{f * 100.1:.4f},car,{wx:.4f},{wy:.4f},0,0,{h:.5f},{h:.5f},4.4,1.8,0,0,0,0,0,0")
    (folder / "Veh_smoothed_tracks.csv").write_text("\n".join(rows) + "\n")
    cw = m.crosswalks[0]
    a, b = cw[0], cw[len(cw) // 2]
    rows = ["track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,ax,ay"]
    for f in range(0, 60):
        p = a + (b - a) * f / 60
        v = (b - a) / 6.0
        rows.append(f"P3,{f},{f * 100.1:.4f},pedestrian,{p[0]:.4f},{p[1]:.4f},{v[0]:.4f},{v[1]:.4f},0,0")
    (folder / "Ped_smoothed_tracks.csv").write_text("\n".join(rows) + "\n")


def test_sind_format_on_the_tianjin_map(tmp_path):
    _need_sind()
    import shutil

    loc = tmp_path / "Tianjin"
    rec = loc / "8_2_1"
    rec.mkdir(parents=True)
    shutil.copy(SIND / "Tianjin" / "map_relink_law_save.osm", loc)
    shutil.copy(SIND / "Tianjin" / "8_2_1" / "TrafficLight_8_2_1.csv", rec)
    m, _ = load_map(loc / "map_relink_law_save.osm", "map_relink_law_save")
    write_sind_recording(rec, m)
    res = lc.load([loc], ImportOptions())
    assert len(res.scenarios) == 1, res.skipped
    s = res.scenarios[0]
    ids = res.meta["track_ids"]["8_2_1"]
    assert ids[str(s.ego_track_id)] == "5"  # car 9 stands still: not an ego
    assert {ids[str(t.track_id)] for t in s.tracks} == {"5", "9", "P3"}
    assert sorted(s.signals) == list(range(1, 9))
    # the ego passes its stop line (light 4) while light 4 is green (0 .. 9.68 s of the log)
    pts, s_stop = tianjin_path(m)
    ego = next(t for t in s.tracks if t.track_id == s.ego_track_id)
    t_stop = s_stop / 5.0
    k = int(round(t_stop / s.dt))
    assert 0 < t_stop < 9.6 and s.signals[4][k] == 3 and s.signals[2][k] == 1
    # 100.1 ms frames resampled onto the 0.1 s grid: positions stay on the path
    import shapely

    assert shapely.LineString(pts).distance(shapely.MultiPoint(ego.xy)) < 1e-6
    assert max(shapely.LineString(pts).distance(shapely.Point(p)) for p in ego.xy) < 0.01
    out = tmp_path / "suite"
    write_result(res, out, name="sind")
    assert validate_suite(out) == []
