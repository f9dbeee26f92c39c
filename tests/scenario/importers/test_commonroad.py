"""CommonRoad importer: the two NGSIM samples (2018b, 2020a), traffic-light
cycles, tiny hand-written files for edge cases, one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.importers import commonroad as cr
from drivee2e_jax.scenario.importers.common import ImportOptions, write_result
from drivee2e_jax.scenario.schema import validate_suite

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "commonroad_ngsim"
LANKER = DATA / "USA_Lanker-1_1_T-1.xml"
PEACH = DATA / "USA_Peach-4_8_T-1.xml"


def _need_data():
    if not PEACH.is_file():
        pytest.skip(f"shared CommonRoad samples not found at {DATA} (the repo's ../shared/data)")


def test_light_cycle_semantics():
    cyc = [(400, 3), (30, 2), (570, 1)]  # green 400, yellow 30, red 570 steps; cycle 1000
    got = cr.light_states(cyc, 590, np.array([0, 19, 20, 589, 590, 989, 990, 1019, 1020]))
    # (k - 590) mod 1000: 410 yellow, 429 yellow, 430 red, 999 red, 0 green, 399 green, 400 yellow, 429, 430 red
    assert got.tolist() == [2, 2, 1, 1, 3, 3, 2, 2, 1]


def test_samples_import_validate_and_keep_what_is_there(tmp_path):
    _need_data()
    res = cr.load([DATA], ImportOptions())
    # every Peachtree vehicle long enough to drive has an acceleration spike (NGSIM noise): no automatic ego
    assert [s.scenario_id for s in res.scenarios] == ["USA_Lanker-1_1_T-1"]
    why = next(sk.reason for sk in res.skipped if sk.source == str(PEACH))
    assert why.startswith("no vehicle qualifies as ego (5 (source 564): implausible motion: car acceleration")
    assert "7 (source 569): implausible motion: car acceleration 20.6 m/s^2 > 12 m/s^2 for 4 steps at t=1.3 s" in why
    assert why.endswith("--ego SOURCE_ID uses one anyway")
    forced = cr.load([PEACH], ImportOptions(ego="569"))  # the vehicle that was picked before the rule
    res.scenarios += forced.scenarios
    by_id = {s.scenario_id: s for s in res.scenarios}
    lank, peach = by_id["USA_Lanker-1_1_T-1"], by_id["USA_Peach-4_8_T-1"]
    assert (len(lank.tracks), lank.num_steps, lank.dt) == (24, 41, 0.1)
    assert (len(peach.tracks), peach.num_steps) == (9, 61)
    assert all(t.category == "car" for s in res.scenarios for t in s.tracks)
    ml, mp = res.maps["USA_Lanker-1_1_T-1"], res.maps["USA_Peach-4_8_T-1"]
    assert len(ml.lanes) == 91 and len(mp.lanes) == 79
    assert not ml.stop_lines and len(mp.stop_lines) == 13  # 13 lanelets with <stopLine>
    assert {s.signal_group for s in mp.stop_lines} == {43918, 43919, 43920, 43921}
    assert sorted(peach.signals) == [43918, 43919, 43920, 43921] and not lank.signals
    # timeOffset 590 of a 1000-step cycle: yellow for 20 steps, then red; offset 1090: red
    assert peach.signals[43918][:20].tolist() == [2] * 20 and set(peach.signals[43918][20:].tolist()) == {1}
    assert set(peach.signals[43919].tolist()) == {1}
    # the intersection's successorsLeft/Right/Straight are connectors, with unmarked bounds where guessed
    assert sum(ln.type == "connector" for ln in mp.lanes) >= 12
    # 2020a line markings are read; 2018b has none, guessed from adjacency
    marks = {m for ln in mp.lanes for m in (ln.left_marking, ln.right_marking)}
    assert {"dashed", "solid"} <= marks
    # speed limits: 2018b <speedLimit>, 2020a the R2-1 sign value
    assert ml.lanes[0].speed_limit == pytest.approx(13.4112)
    assert mp.lanes[0].speed_limit == pytest.approx(15.6464)
    # the ego is a recorded obstacle present over the whole log; the planning problem is kept in meta
    for s in res.scenarios:
        ego = next(t for t in s.tracks if t.track_id == s.ego_track_id)
        assert len(ego.t) == s.num_steps
    assert res.meta["planning_problems"]["USA_Peach-4_8_T-1"][0]["goals"] == [{"lanelets": [43616, 43482, 43474, 43478]}]
    write_result(res, tmp_path / "s", name="cr")
    assert validate_suite(tmp_path / "s") == []


def test_ego_option_names_an_obstacle():
    _need_data()
    res = cr.load([LANKER], ImportOptions(ego="1216"))
    s = res.scenarios[0]
    assert s.ego_track_id == 0 and res.meta["track_ids"]["USA_Lanker-1_1_T-1"]["0"] == "1216"
    with pytest.raises(DriveE2EError, match="--ego '42': expected a dynamic obstacle id"):
        cr.load([LANKER], ImportOptions(ego="42"))


# --------------------------------------------------------------------------
# Tiny hand-written files
# --------------------------------------------------------------------------


def _bound(tag, pts, marking=None):
    p = "".join(f"<point><x>{x}</x><y>{y}</y></point>" for x, y in pts)
    m = f"<lineMarking>{marking}</lineMarking>" if marking else ""
    return f"<{tag}>{p}{m}</{tag}>"


def _state(tag, k, x, y, yaw=0.0, v=8.0):
    return (f"<{tag}><position><point><x>{x}</x><y>{y}</y></point></position>"
            f"<orientation><exact>{yaw}</exact></orientation><time><exact>{k}</exact></time>"
            f"<velocity><exact>{v}</exact></velocity></{tag}>")


def tiny(version="2020a", step="0.1", extra_obstacle="", lanelet_extra="", car_states=None):
    """Two lanelets along +x (0..40, 40..80), one car at 8 m/s on them for 5 s."""
    la = (f'<lanelet id="1">{_bound("leftBound", [(0, 3.5), (40, 3.5)], "solid")}'
          f'{_bound("rightBound", [(0, 0), (40, 0)], "dashed")}<successor ref="2"/>'
          f'<stopLine><lineMarking>solid</lineMarking></stopLine>{lanelet_extra}</lanelet>')
    lb = (f'<lanelet id="2">{_bound("leftBound", [(40, 3.5), (80, 3.5)])}'
          f'{_bound("rightBound", [(40, 0), (80, 0)])}<predecessor ref="1"/></lanelet>')
    if car_states is None:
        car_states = _state("initialState", 0, 2.0, 1.75) + "<trajectory>" + "".join(
            _state("state", k, 2.0 + 0.8 * k, 1.75) for k in range(1, 51)) + "</trajectory>"
    if version == "2018b":
        car = (f'<obstacle id="10"><role>dynamic</role><type>car</type><shape><rectangle><length>4.5</length>'
               f'<width>1.8</width></rectangle></shape>{car_states}</obstacle>')
    else:
        car = (f'<dynamicObstacle id="10"><type>car</type><shape><rectangle><length>4.5</length>'
               f'<width>1.8</width></rectangle></shape>{car_states}</dynamicObstacle>')
    step_attr = f' timeStepSize="{step}"' if step is not None else ""
    return (f'<?xml version="1.0"?><commonRoad benchmarkID="T-1" commonRoadVersion="{version}"{step_attr}>'
            f"{la}{lb}{car}{extra_obstacle}</commonRoad>")


def _write(tmp_path, text, name="t.xml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("version", ["2018b", "2020a"])
def test_tiny_file_both_versions(tmp_path, version):
    ped = ('<dynamicObstacle id="11"><type>spaceship</type><shape><circle><radius>0.3</radius></circle></shape>'
           + _state("initialState", 0, 50, -3) + "</dynamicObstacle>")
    parked = ('<staticObstacle id="12"><type>parkedVehicle</type><shape><rectangle><length>4</length>'
              '<width>2</width></rectangle></shape>' + _state("initialState", 0, 60, -5) + "</staticObstacle>")
    res = cr.load([_write(tmp_path, tiny(version, extra_obstacle=ped + parked))], ImportOptions())
    assert len(res.scenarios) == 1
    s = res.scenarios[0]
    m = res.maps["T-1"]
    assert s.num_steps == 51 and s.behavior == "STR"
    ego = s.tracks[0]
    np.testing.assert_allclose(ego.xy[-1], [42.0, 1.75])
    np.testing.assert_allclose(ego.vel[0], [8.0, 0.0])
    assert [ln.id for ln in m.lanes] == [1, 2] and m.lanes[0].successors == [2]
    assert (m.lanes[0].left_marking, m.lanes[0].right_marking) == ("solid", "dashed")
    assert m.lanes[1].left_marking == "road_edge"  # no lineMarking, nothing adjacent
    assert len(m.stop_lines) == 1 and m.stop_lines[0].signal_group == -1 and m.stop_lines[0].lane_id == 1
    np.testing.assert_allclose(sorted(m.stop_lines[0].points[:, 0]), [40.0, 40.0])  # the lanelet's end
    assert any("spaceship" in k.reason for k in res.skipped)
    assert len(m.obstacles) == 1 and m.obstacles[0].kind == "parkedVehicle"


def test_tiny_interval_values_and_coarse_step(tmp_path):
    states = ("<initialState><position><point><x>2</x><y>1.75</y></point></position>"
              "<orientation><intervalStart>-0.1</intervalStart><intervalEnd>0.1</intervalEnd></orientation>"
              "<time><exact>0</exact></time></initialState><trajectory>"
              + "".join(_state("state", k, 2.0 + 4.0 * k, 1.75) for k in range(1, 11)) + "</trajectory>")
    res = cr.load([_write(tmp_path, tiny(step="0.5", car_states=states))], ImportOptions())
    s = res.scenarios[0]
    assert s.dt == 0.1 and s.num_steps == 51  # 0.5 s states resampled onto the 0.1 s grid
    ego = s.tracks[0]
    np.testing.assert_allclose(ego.xy[:6, 0], [2.0, 2.8, 3.6, 4.4, 5.2, 6.0])
    assert ego.vel is None  # the initial state has no velocity: speeds come from positions when packed


def test_no_dynamic_obstacles_is_skipped(tmp_path):
    text = tiny()
    text = text[:text.index("<dynamicObstacle")] + "</commonRoad>"
    res = cr.load([_write(tmp_path, text)], ImportOptions())
    assert res.scenarios == [] and "no dynamic obstacle" in res.skipped[0].reason


@pytest.mark.parametrize("text, needle", [
    ("<commonRoad><lanelet", "well-formed CommonRoad XML"),
    ("<osm/>", "<commonRoad> root"),
    (tiny(step=None), "<commonRoad timeStepSize>: expected a positive number"),
    (tiny(step="-1"), "timeStepSize>: expected a positive number"),
    (tiny().replace('<lanelet id="2">', '<lanelet id="two">'), "lanelet[1]: expected an integer 'id'"),
    (tiny().replace("<x>80</x><y>3.5</y>", "<x>80</x>"), "lanelet id=2/leftBound/point[1]/y: expected a number element"),
    (tiny().replace("<point><x>40</x><y>3.5</y></point><lineMarking>solid", "<lineMarking>solid", 1),
     "lanelet id=1/leftBound: expected at least 2 <point>s"),
    (tiny().replace('<lineMarking>dashed</lineMarking>', '<lineMarking>wavy</lineMarking>'),
     "lanelet id=1/rightBound/lineMarking: expected one of"),
    (tiny(car_states=_state("initialState", 0, 1, 1).replace("<position><point><x>1</x><y>1</y></point></position>", "")),
     "obstacle id=10/initialState/position: expected a <position>"),
    (tiny(car_states=_state("initialState", 0, 1, 1) + "<trajectory>" + _state("state", 0, 2, 1) + "</trajectory>"),
     "obstacle id=10/trajectory/state[0]/time: expected increasing time steps"),
    (tiny(car_states=_state("initialState", 0, 1, 1).replace("<exact>0.0</exact>", "<exact>north</exact>")),
     "obstacle id=10/initialState/orientation/exact: expected a number"),
])
def test_bad_files_one_line_errors(tmp_path, text, needle):
    p = _write(tmp_path, text)
    with pytest.raises(DriveE2EError) as e:
        cr.load([p], ImportOptions())
    msg = str(e.value)
    assert str(p) in msg and needle in msg and "\n" not in msg


def test_empty_folder(tmp_path):
    with pytest.raises(DriveE2EError, match="expected CommonRoad .xml files"):
        cr.load([tmp_path], ImportOptions())


def test_sample_lanes_keep_their_bounds():
    from shapely.geometry import Point, Polygon

    from drivee2e_jax.scenario.lane_polygons import lane_polygon, lane_polygon_source

    _need_data()
    m = cr.load([LANKER], ImportOptions()).maps["USA_Lanker-1_1_T-1"]
    assert {lane_polygon_source(ln) for ln in m.lanes} == {"boundaries"}
    shp = [Polygon(lane_polygon(ln)) for ln in m.lanes]
    assert all(s.is_valid for s in shp)
    assert all(s.buffer(1e-3).contains(Point(q)) for s, ln in zip(shp, m.lanes) for q in ln.centerline)
