"""Suite folders: JSON round trip, determinism, atomic writes, validation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import SuiteRecord
from drivee2e_jax.scenario.problems import Problem
from drivee2e_jax.scenario.schema import read_suite, validate_suite, write_suite
from drivee2e_jax.scenario.validate import validate_records


def _files(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*.json"))}


def _tracks_by_id(rec):
    return {t.track_id: t for t in rec.tracks}


# --------------------------------------------------------------------------
# write / read
# --------------------------------------------------------------------------


def test_round_trip_reproduces_records(tiny_suite, tiny_suite_dir):
    back = read_suite(tiny_suite_dir)
    assert isinstance(back, SuiteRecord)
    assert (back.name, back.version, back.meta) == (tiny_suite.name, tiny_suite.version, tiny_suite.meta)
    assert set(back.maps) == set(tiny_suite.maps)
    assert [s.scenario_id for s in back.scenarios] == [s.scenario_id for s in tiny_suite.scenarios]
    for a, b in zip(tiny_suite.scenarios, back.scenarios):
        for key in ("split", "intersection_id", "map_id", "behavior", "weather", "time_of_day",
                    "ego_track_id", "dt", "num_steps"):
            assert getattr(a, key) == getattr(b, key), key
        np.testing.assert_allclose(a.route.waypoints, b.route.waypoints, atol=5e-4)
        assert set(a.signals) == set(b.signals)
        for g in a.signals:
            np.testing.assert_array_equal(a.signals[g], b.signals[g])
        ta, tb = _tracks_by_id(a), _tracks_by_id(b)
        assert list(ta) == list(tb)  # order kept on disk
        for tid in ta:
            x, y = ta[tid], tb[tid]
            assert x.category == y.category
            np.testing.assert_allclose(x.t, y.t, atol=5e-5)
            np.testing.assert_allclose(x.xy, y.xy, atol=5e-4)
            np.testing.assert_allclose(x.yaw, y.yaw, atol=5e-5)
            np.testing.assert_allclose(x.size, y.size, atol=5e-4)
            assert (x.vel is None) == (y.vel is None)
            if x.vel is not None:
                np.testing.assert_allclose(x.vel, y.vel, atol=5e-4)
            for flag in ("visible", "quality"):
                fx, fy = getattr(x, flag), getattr(y, flag)
                assert (fx is None) == (fy is None)
                if fx is not None:
                    np.testing.assert_array_equal(fx, fy)
    m0, m1 = tiny_suite.maps["m_cross"], back.maps["m_cross"]
    assert [ln.successors for ln in m0.lanes] == [ln.successors for ln in m1.lanes]
    assert [(s.id, s.lane_id, s.signal_group) for s in m0.stop_lines] == \
        [(s.id, s.lane_id, s.signal_group) for s in m1.stop_lines]
    assert [o.kind for o in m0.obstacles] == [o.kind for o in m1.obstacles]
    assert m0.signal_plan == m1.signal_plan
    assert m0.meta == m1.meta


def test_writes_are_byte_deterministic_and_compact(tiny_suite, tmp_path):
    a = write_suite(tiny_suite, tmp_path / "a")
    b = write_suite(read_suite(a), tmp_path / "b")  # a read-back suite writes the same bytes
    assert _files(a) == _files(b)
    text = (a / "scenarios" / "s_left.json").read_text()
    assert "-0.0," not in text and "NaN" not in text
    obj = json.loads(text)
    xs = obj["tracks"][0]["x"]
    assert all(round(v, 3) == v for v in xs)  # 1 mm
    assert all(round(v, 4) == v for v in obj["tracks"][0]["yaw"])  # 1e-4 rad
    assert "vx" not in obj["tracks"][0] and "vx" in obj["tracks"][1]  # velocity only when the record has it
    assert set(obj) >= {"scenario_id", "route", "tracks", "signals", "schema_version"}
    head = json.loads((a / "suite.json").read_text())
    assert head["schema_version"] == 1
    assert head["scenarios"][0] == {"id": "s_straight", "split": "train", "intersection_id": "i0", "behavior": "STR"}


def test_write_refuses_non_empty_folder_and_replaces_only_suites(tiny_suite, tmp_path):
    out = write_suite(tiny_suite, tmp_path / "s")
    with pytest.raises(DriveE2EError, match="not empty"):
        write_suite(tiny_suite, out)
    tiny_suite.name = "renamed"
    write_suite(tiny_suite, out, overwrite=True)
    assert read_suite(out).name == "renamed"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]  # no temp folders left behind

    other = tmp_path / "not_a_suite"
    other.mkdir()
    (other / "precious.txt").write_text("keep me")
    with pytest.raises(DriveE2EError, match="not a suite folder"):
        write_suite(tiny_suite, other, overwrite=True)
    assert (other / "precious.txt").read_text() == "keep me"

    empty = tmp_path / "empty"
    empty.mkdir()
    write_suite(tiny_suite, empty)
    assert (empty / "suite.json").is_file()


def test_write_refuses_invalid_records(tiny_suite, tmp_path):
    tiny_suite.scenarios[0].weather = "snow"
    with pytest.raises(DriveE2EError, match=r"scenarios/s_straight.json: weather: expected one of clear"):
        write_suite(tiny_suite, tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def test_validate_records_names_virtual_files(tiny_suite):
    tiny_suite.scenarios[1].tracks[0].t = tiny_suite.scenarios[1].tracks[0].t + 0.03
    tiny_suite.maps["m_tee"].lanes[0].successors = [42]
    problems = validate_records(tiny_suite)
    texts = [str(p) for p in problems]
    assert any(t.startswith("scenarios/s_left.json: tracks[0].t[0]: expected a multiple of dt") for t in texts)
    assert any(t.startswith("maps/m_tee.json: lanes[0].successors[0]: expected a lane id") for t in texts)


def test_valid_suite_has_no_problems(tiny_suite_dir):
    assert validate_suite(tiny_suite_dir) == []


# --------------------------------------------------------------------------
# Validation: every kind of problem, each naming file and field
# --------------------------------------------------------------------------


def test_lane_boundaries_round_trip_and_stay_optional(tiny_suite, tmp_path):
    import copy

    suite = copy.deepcopy(tiny_suite)
    lane = suite.maps["m_cross"].lanes[0]
    cl = np.asarray(lane.centerline, float)
    lane.left_boundary, lane.right_boundary = cl + [0.0, 1.75], cl - [0.0, 1.75]
    other = suite.maps["m_cross"].lanes[1]
    (x0, y0), (x1, y1) = np.asarray(other.centerline, float)[[0, -1]]
    other.polygon = np.array([[x0, y0 - 1.5], [x1, y1 - 1.5], [x1, y1 + 1.5], [x0, y0 + 1.5]])
    write_suite(suite, tmp_path / "s")
    obj = json.loads((tmp_path / "s" / M).read_text())
    assert "left_boundary" in obj["lanes"][0] and "left_boundary" not in obj["lanes"][1]
    assert "polygon" in obj["lanes"][1] and all("polygon" not in o for i, o in enumerate(obj["lanes"]) if i != 1)
    back = read_suite(tmp_path / "s").maps["m_cross"].lanes
    np.testing.assert_allclose(back[0].left_boundary, lane.left_boundary, atol=5e-4)
    np.testing.assert_allclose(back[0].right_boundary, lane.right_boundary, atol=5e-4)
    assert back[1].left_boundary is None and back[1].right_boundary is None
    np.testing.assert_allclose(back[1].polygon, other.polygon, atol=5e-4)
    assert back[0].polygon is None


def _edit(folder, rel, fn):
    path = folder / rel
    obj = json.loads(path.read_text())
    fn(obj)
    path.write_text(json.dumps(obj))  # NaN is written as the (non-standard) NaN token


def _set(path, value):
    def fn(obj):
        *head, last = path
        for k in head:
            obj = obj[k]
        obj[last] = value

    return fn


def _delete(key):
    return lambda obj: obj.pop(key)


S = "scenarios/s_straight.json"
M = "maps/m_cross.json"

CASES = {
    "missing field": (S, _delete("weather"), "weather", "field is missing"),
    "unknown field": (S, _set(["wether"], "clear"), "wether", "one of the known fields (scenario_id, split,"),
    "wrong type": (S, _set(["num_steps"], "50"), "num_steps", "an integer"),
    "unknown category": (S, _set(["tracks", 0, "category"], "lorry"), "tracks[0].category",
                         "one of car, truck, bus, van, motorcycle, tricycle, pedestrian, cyclist"),
    "unknown behavior": (S, _set(["behavior"], "ZIG"), "behavior", "one of COV, IPC, UT, YLW, STR, LFT, RT, STP"),
    "unknown split": (S, _set(["split"], "dev"), "split", "one of train, val, test"),
    "unknown weather": (S, _set(["weather"], "snow"), "weather", "one of clear, cloudy, rain, fog"),
    "unknown time of day": (S, _set(["time_of_day"], "noon"), "time_of_day", "one of day, dusk, night"),
    "unknown lane type": (M, _set(["lanes", 0, "type"], "highway"), "lanes[0].type",
                          "one of driving, turn_pocket, connector, bike, parking"),
    "unknown marking": (M, _set(["boundaries", 1, "marking"], "zigzag"), "boundaries[1].marking",
                        "one of none, dashed, solid, double_solid, road_edge"),
    "unknown signal state": (S, lambda o: o["signals"]["0"].__setitem__(3, 7), 'signals["0"][3]', "3=green"),
    "length mismatch": (S, lambda o: o["tracks"][0]["yaw"].pop(), "tracks[0].yaw", "(as many as t)"),
    "non-finite": (S, _set(["tracks", 0, "x", 2], math.nan), "tracks[0].x[2]", "finite"),
    "off the dt grid": (S, _set(["tracks", 0, "t", 1], 0.1234), "tracks[0].t[1]", "multiple of dt=0.1"),
    "non-increasing": (S, _set(["tracks", 0, "t", 2], 0.1), "tracks[0].t[2]", "increasing timestamps"),
    "beyond num_steps": (S, _set(["tracks", 2, "t", 49], 5.0), "tracks[2].t[49]", "num_steps=50"),
    "ego not a track": (S, _set(["ego_track_id"], 999), "ego_track_id", "one of the track ids (3, 7, 12)"),
    "map not in suite": (S, _set(["map_id"], "m_nowhere"), "map_id", "one of the suite's maps (m_cross, m_tee)"),
    "successor missing": (M, _set(["lanes", 0, "successors"], [2, 99]), "lanes[0].successors[1]",
                          "a lane id of this map (1, 2, 3, 4, 5)"),
    "stop line lane missing": (M, _set(["stop_lines", 0, "lane_id"], 77), "stop_lines[0].lane_id",
                               "-1 or a lane id of this map"),
    "signal length": (S, _set(["signals", "0"], [3, 3, 3]), 'signals["0"]', "50 states"),
    "negative size": (S, _set(["tracks", 0, "size", 1], -1.0), "tracks[0].size[1]", ">= 0"),
    "zero ego size": (S, _set(["tracks", 2, "size"], [0, 0, 0]), "tracks[2].size", "length and width >= 0.1 m"),
    "thin agent": (S, _set(["tracks", 0, "size"], [4.5, 0.01, 1.5]), "tracks[0].size", "length and width >= 0.1 m"),
    "map without lanes": (M, _set(["lanes"], []), "lanes", "at least one lane"),
    "negative lane width": (M, _set(["lanes", 2, "width"], -3.0), "lanes[2].width", ">= 0"),
    "short route": (S, _set(["route", "waypoints"], [[0.0, 0.0]]), "route.waypoints", "at least 2 points"),
    "duplicate track ids": (S, _set(["tracks", 1, "track_id"], 3), "tracks[1].track_id", "a unique track id"),
    "duplicate scenario ids": ("suite.json", _set(["scenarios", 1, "id"], "s_straight"), "scenarios[1].id",
                               "a unique scenario id"),
    "schema version": ("suite.json", _set(["schema_version"], 99), "schema_version", "1 (the schema version"),
    "vx without vy": ("scenarios/s_left.json", lambda o: o["tracks"][1].pop("vy"), "tracks[1].vy",
                      "vx and vy together"),
    "bad flag": (S, _set(["tracks", 1, "visible", 0], 2), "tracks[1].visible[0]", "true/false (or 0/1)"),
    "polygon too small": (M, _set(["crosswalks", 0], [[0, 0], [1, 1]]), "crosswalks[0]", "at least 3 points"),
    "point not a pair": (M, _set(["lanes", 1, "centerline", 1], [1.0]), "lanes[1].centerline[1]",
                         "a list of 2 numbers"),
    "boundary point not a pair": (M, _set(["lanes", 1, "left_boundary"], [[0.0, 1.0], [1.0]]),
                                  "lanes[1].left_boundary[1]", "a list of 2 numbers"),
    "short boundary": (M, _set(["lanes", 0, "right_boundary"], [[0.0, 0.0]]), "lanes[0].right_boundary",
                       "at least 2 points"),
    "map id not file name": (M, _set(["map_id"], "m_other"), "map_id", "'m_cross' (the file name)"),
    "disagrees with suite.json": (S, _set(["behavior"], "LFT"), "behavior", "'STR' as listed in suite.json"),
    "non-positive dt": (S, _set(["dt"], 0.0), "dt", "a number > 0"),
    # integers packed as int32, floats simulated as float32: out of range is refused, naming the range
    # (a 401-digit num_steps raised OverflowError; a 1e308 position became inf in float32 unnoticed)
    "num_steps beyond int32": (S, _set(["num_steps"], int("9" * 401)), "num_steps", "an integer in [1, 2147483647]"),
    "num_steps 1e20": (S, _set(["num_steps"], 10**20), "num_steps", "an integer in [1, 2147483647]"),
    "track id beyond int32": (S, _set(["tracks", 0, "track_id"], 2**40), "tracks[0].track_id",
                              "an integer in [-2147483648, 2147483647]"),
    "signal group beyond int32": (M, _set(["stop_lines", 0, "signal_group"], -(2**31) - 1), "stop_lines[0].signal_group",
                                  "an integer in [-1, 2147483647]"),
    "successor beyond int64": (M, _set(["lanes", 0, "successors"], [2, 2**70]), "lanes[0].successors[1]",
                               "an integer in [-9223372036854775808, 9223372036854775807]"),
    "position beyond float32": (S, _set(["tracks", 0, "x", 2], 1e308), "tracks[0].x[2]", "float32 range"),
    "integer position beyond float32": (S, _set(["tracks", 0, "y", 2], int("9" * 401)), "tracks[0].y[2]",
                                        "float32 range"),
    "route point beyond float32": (S, _set(["route", "waypoints", 1], [0.0, -5e38]), "route.waypoints[1]",
                                   "float32 range"),
    "lane width beyond float32": (M, _set(["lanes", 0, "width"], 1e39), "lanes[0].width", "float32 range"),
    # positions within float32 but beyond any planar frame (scenario.origin.POSITION_BOUND)
    "position beyond 1e7 m": (S, _set(["tracks", 0, "x", 2], 1e37), "tracks[0].x[2]", "|value| <= 1e+07 m"),
    "lane point beyond 1e7 m": (M, _set(["lanes", 0, "centerline", 0], [0.0, -2e7]), "lanes[0].centerline[0]",
                                "|value| <= 1e+07 m"),
    "dt as a 401-digit integer": (S, _set(["dt"], int("9" * 401)), "dt", "float32 range"),
    "signal group key beyond int32": (S, lambda o: o["signals"].__setitem__("9" * 12, o["signals"].pop("0")),
                                      f'signals["{"9" * 12}"]', "an integer signal group in [-2147483648, 2147483647]"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_problem_names_file_field_and_expectation(tiny_suite_dir, case):
    rel, mutate, field, expected = CASES[case]
    _edit(tiny_suite_dir, rel, mutate)
    problems = validate_suite(tiny_suite_dir)
    hits = [p for p in problems if p.file == rel and p.field == field and expected in p.expected]
    assert hits, f"no {rel}: {field}: ...{expected}... in {[str(p) for p in problems]}"
    with pytest.raises(DriveE2EError) as err:
        read_suite(tiny_suite_dir)
    msg = str(err.value)
    assert "\n" not in msg
    first = problems[0]
    assert f"{first.file}: {first.field}" in msg and first.expected in msg
    if len(problems) > 1:
        assert f"(and {len(problems) - 1} more; run `drivee2e suite validate" in msg


def test_zero_size_names_track_id_and_ego(tiny_suite_dir):
    _edit(tiny_suite_dir, S, _set(["tracks", 0, "size"], [0, 0, 0]))
    _edit(tiny_suite_dir, S, _set(["tracks", 2, "size"], [0.05, 2.0, 0.0]))
    ego = json.loads((tiny_suite_dir / S).read_text())["ego_track_id"]
    got = {p.field: p.got for p in validate_suite(tiny_suite_dir) if p.file == S}
    assert ego == 7  # tracks[2]
    assert got["tracks[0].size"] == "[0, 0, 0] (track_id 3, an agent)"
    assert got["tracks[2].size"] == "[0.05, 2, 0] (track_id 7, the ego)"


def test_height_zero_and_small_real_sizes_stay_valid(tiny_suite_dir):
    _edit(tiny_suite_dir, S, _set(["tracks", 2, "size"], [0.1, 0.1, 0.0]))  # the bound itself, unknown height
    assert validate_suite(tiny_suite_dir) == []


def test_records_with_a_lane_free_map_name_the_scenario(tiny_suite):
    tiny_suite.maps["m_cross"].lanes = []
    users = sorted(s.scenario_id for s in tiny_suite.scenarios if s.map_id == "m_cross")
    problems = validate_records(tiny_suite)
    assert any(p.file == "maps/m_cross.json" and p.field == "lanes" for p in problems)
    named = sorted(p.file for p in problems if p.field == "map_id" and "has no lanes" in p.got)
    assert users and named == [f"scenarios/{s}.json" for s in users]


def test_unparsable_json_reports_line_and_column(tiny_suite_dir):
    path = tiny_suite_dir / S
    path.write_text('{\n "scenario_id": "s_straight",\n "split": \n}')
    (p,) = validate_suite(tiny_suite_dir)
    assert p.file == S and p.field == "line 4 column 1" and p.expected == "valid JSON"
    with pytest.raises(DriveE2EError, match=r"s_straight.json: line 4 column 1: expected valid JSON"):
        read_suite(tiny_suite_dir)


def test_a_number_longer_than_python_converts_names_the_file_and_place(tiny_suite_dir):
    """The user's report: a 5001-digit integer raised ValueError deep inside json
    ("unexpected; rerun with --debug")."""
    path = tiny_suite_dir / S
    path.write_text(path.read_text().replace('"num_steps":', '"num_steps": ' + "9" * 5001 + ', "x":', 1))
    (p,) = validate_suite(tiny_suite_dir)
    assert p.file == S and p.field.startswith("line ") and "a number with at most 4300 digits" in p.expected
    assert p.got == "a number with more than 4300 digits (5001)"
    with pytest.raises(DriveE2EError, match=r"s_straight.json: line \d+ column \d+: expected a number with at most "
                                            r"4300 digits .*, got a number with more than 4300 digits"):
        read_suite(tiny_suite_dir)


def test_listed_scenario_file_missing_and_unlisted_file(tiny_suite_dir):
    (tiny_suite_dir / "scenarios" / "s_val.json").rename(tiny_suite_dir / "scenarios" / "s_extra.json")
    problems = {p.file: p for p in validate_suite(tiny_suite_dir)}
    assert "listed in suite.json as scenarios[2]" in problems["scenarios/s_val.json"].expected
    assert problems["scenarios/s_val.json"].got == "missing"
    assert "listed in suite.json" in problems["scenarios/s_extra.json"].expected


def test_all_problems_are_collected(tiny_suite_dir):
    _edit(tiny_suite_dir, S, _set(["weather"], "snow"))
    _edit(tiny_suite_dir, S, _set(["tracks", 0, "x", 0], math.inf))
    _edit(tiny_suite_dir, "scenarios/s_val.json", _set(["time_of_day"], "noon"))
    _edit(tiny_suite_dir, M, _set(["lanes", 0, "successors"], [55]))
    problems = validate_suite(tiny_suite_dir)
    assert len(problems) == 4
    assert {p.file for p in problems} == {S, "scenarios/s_val.json", M}
    with pytest.raises(DriveE2EError, match=r"\(and 3 more; run `drivee2e suite validate "):
        read_suite(tiny_suite_dir)


def test_not_a_suite_folder(tmp_path):
    with pytest.raises(DriveE2EError, match="does not exist"):
        read_suite(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    (p,) = validate_suite(tmp_path / "empty")
    assert p.file == "suite.json" and "suite.json file" in p.expected


def test_problem_str():
    assert str(Problem("a.json", "x[1]", "a number", "null")) == "a.json: x[1]: expected a number, got null"
    assert str(Problem("a.json", "", "a file")) == "a.json: expected a file"


def test_force_replaces_only_a_folder_of_suite_files(tiny_suite, tmp_path):
    out = write_suite(tiny_suite, tmp_path / "s")
    (out / "README.md").write_text("the user's notes")
    with pytest.raises(DriveE2EError, match=rf"^{out}: holds files drivee2e did not write \(README.md\)"):
        write_suite(tiny_suite, out, overwrite=True)
    assert (out / "README.md").read_text() == "the user's notes" and (out / "suite.json").is_file()


def test_a_repeated_key_is_a_problem_naming_file_and_key(tiny_suite_dir):
    p = tiny_suite_dir / "scenarios" / "s_val.json"
    text = p.read_text()
    p.write_text(text.replace('"ego_track_id":', '"ego_track_id":4,"ego_track_id":', 1))
    problems = validate_suite(tiny_suite_dir)
    assert [str(x) for x in problems] == [
        "scenarios/s_val.json: expected each key once per object, got duplicate key 'ego_track_id'"]
    with pytest.raises(DriveE2EError, match=r"scenarios/s_val.json: expected each key once per object, got "
                                            r"duplicate key 'ego_track_id'"):
        read_suite(tiny_suite_dir)
    p.write_text(text)
    s = tiny_suite_dir / "suite.json"
    s.write_text(s.read_text().replace('"name":', '"name":"x","name":', 1))
    assert [str(x) for x in validate_suite(tiny_suite_dir)] == [
        "suite.json: expected each key once per object, got duplicate key 'name'"]
