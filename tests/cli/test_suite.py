"""`drivee2e suite ...` end to end, in-process via main(argv) and once as a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import types as pytypes

import pytest

from drivee2e_jax import cli
from drivee2e_jax.scenario import suite as suite_mod


@pytest.fixture
def fake_twin15(monkeypatch):
    mod = pytypes.ModuleType("drivee2e_jax.scenario.twin15")
    mod.VERSION = "test-1"

    def generate(seed=0):
        from tests.helpers.tiny_suite import build_tiny_suite

        rec = build_tiny_suite()
        rec.name, rec.meta = "twin15", {"seed": seed}
        return rec

    mod.generate = generate
    monkeypatch.setitem(sys.modules, "drivee2e_jax.scenario.twin15", mod)
    monkeypatch.setattr(suite_mod, "_GENERATED", {})
    return mod


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_info_json_is_one_object(capsys, tiny_suite_dir, drivee2e_cache):
    code, out, err = run(capsys, "suite", "info", str(tiny_suite_dir), "--json")
    assert code == 0, err
    info = json.loads(out)  # exactly one JSON document on stdout
    assert info["num_scenarios"] == 4
    assert info["splits"] == {"train": 2, "val": 1, "test": 1}
    assert info["behaviors"]["LFT"] == 1
    assert info["intersections"] == 2
    assert info["categories"]["cyclist"] == 2


def test_info_tables(capsys, tiny_suite_dir, drivee2e_cache):
    code, out, _ = run(capsys, "suite", "info", str(tiny_suite_dir))
    assert code == 0
    for text in ("4 scenarios, 2 maps, 2 intersections", "split", "behaviour", "intersection",
                 "agent category", "weather", "time of day", "pedestrian"):
        assert text in out
    assert any(line.split()[:2] == ["train", "2"] for line in out.splitlines())


def test_validate_ok(capsys, tiny_suite_dir):
    code, out, _ = run(capsys, "suite", "validate", str(tiny_suite_dir))
    assert (code, out.strip()) == (0, "OK: 4 scenarios, 2 maps")


def test_validate_notes_lane_polygon_fallbacks(capsys, tiny_suite_dir):
    p = tiny_suite_dir / "maps" / "m_cross.json"
    obj = json.loads(p.read_text())
    obj["drivable_areas"] = []
    lane = obj["lanes"][0]
    lane["left_boundary"] = [[x, y + 1.0] for x, y in lane["centerline"]]
    lane["right_boundary"] = [[x, y - 1.0] for x, y in lane["centerline"]]
    (x0, y0), (x1, y1) = obj["lanes"][1]["centerline"][0], obj["lanes"][1]["centerline"][-1]
    obj["lanes"][1]["polygon"] = [[x0, y0 - 1.0], [x1, y1 - 1.0], [x1, y1 + 1.0], [x0, y0 + 1.0]]
    p.write_text(json.dumps(obj))
    code, out, err = run(capsys, "suite", "validate", str(tiny_suite_dir))
    assert (code, out.strip()) == (0, "OK: 4 scenarios, 2 maps")
    n = len(obj["lanes"])
    assert (f"note: map m_cross: no drivable_areas; drivable-area compliance uses the union of its lane "
            f"polygons (1 the lane's own polygon, 1 from boundaries, {n - 2} from centreline ± width/2)") \
        in err.splitlines()
    ids = ", ".join(str(ln["id"]) for ln in obj["lanes"][2:])
    assert (f"note: map m_cross: lanes {ids} have no polygon nor left/right_boundary; their polygons are the "
            f"centreline ± width/2") in err.splitlines()
    assert "m_tee" not in err  # it has drivable areas and no boundaries at all


def test_validate_refuses_a_self_intersecting_lane_polygon(capsys, tiny_suite_dir):
    p = tiny_suite_dir / "maps" / "m_cross.json"
    obj = json.loads(p.read_text())
    obj["lanes"][0]["polygon"] = [[0, 0], [4, 4], [4, 0], [0, 3]]  # a bow tie
    p.write_text(json.dumps(obj))
    code, out, err = run(capsys, "suite", "validate", str(tiny_suite_dir))
    assert code != 0
    line = next((ln for ln in (out + err).splitlines() if "lanes[0].polygon" in ln), out + err)
    assert "expected a simple ring" in line and "Self-intersection" in line, line
    assert "Traceback" not in err


def test_validate_lists_every_problem(capsys, tiny_suite_dir):
    for name, old, new in (("s_val", '"fog"', '"smog"'), ("s_test", '"STP"', '"XYZ"')):
        p = tiny_suite_dir / "scenarios" / f"{name}.json"
        p.write_text(p.read_text().replace(old, new))
    code, out, err = run(capsys, "suite", "validate", str(tiny_suite_dir))
    assert code == 1
    lines = out.strip().splitlines()
    assert len(lines) == 2  # an invalid label is not reported again as disagreeing with suite.json
    assert "scenarios/s_val.json: weather: expected one of clear, cloudy, rain, fog, got 'smog'" in lines
    assert any(line.startswith("scenarios/s_test.json: behavior: expected one of COV") for line in lines)
    assert "2 problems" in err


def test_bad_suite_name_is_one_line_exit_2(capsys, drivee2e_cache):
    code, out, err = run(capsys, "suite", "info", "twin16")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith("drivee2e: error: unknown suite 'twin16'")
    assert "Traceback" not in err


def test_debug_shows_the_exception(capsys, drivee2e_cache):
    code, out, err = run(capsys, "suite", "info", "twin16", "--debug")
    assert code == 2 and out == ""  # the exit code of the run without --debug
    assert err.startswith("Traceback (most recent call last):") and "DriveE2EError: unknown suite 'twin16'" in err
    assert err.splitlines()[-1].startswith("drivee2e: error: unknown suite 'twin16'")


def test_validate_missing_folder(capsys, tmp_path):
    code, _, err = run(capsys, "suite", "validate", str(tmp_path / "nope"))
    assert code == 2 and "does not exist" in err and err.count("\n") == 1


def test_generate_writes_and_refuses_without_force(capsys, tmp_path, fake_twin15, drivee2e_cache):
    out_dir = tmp_path / "gen"
    code, out, err = run(capsys, "suite", "generate", "--out", str(out_dir), "--seed", "3")
    assert code == 0, err
    assert "wrote 4 scenarios, 2 maps" in out
    assert json.loads((out_dir / "suite.json").read_text())["meta"] == {"seed": 3}
    code, _, err = run(capsys, "suite", "generate", "--out", str(out_dir))
    assert code == 2 and "not empty" in err and "--force" in err
    code, _, err = run(capsys, "suite", "generate", "--out", str(out_dir), "--force")
    assert code == 0, err
    code, out, _ = run(capsys, "suite", "validate", str(out_dir))
    assert code == 0 and out.startswith("OK: 4 scenarios")


def test_generate_unknown_builtin(capsys, tmp_path):
    code, _, err = run(capsys, "suite", "generate", "--name", "nope", "--out", str(tmp_path / "x"))
    assert code == 2 and "unknown built-in suite 'nope'; expected one of: twin15" in err


@pytest.mark.parametrize("argv", [["--help"], ["suite", "--help"], ["suite", "generate", "--help"],
                                  ["suite", "info", "--help"], ["suite", "validate", "--help"]])
def test_help_has_description_and_example(capsys, argv):
    code, out, _ = run(capsys, *argv)
    assert code == 0
    assert "example" in out and "drivee2e suite" in out
    assert out.count("\n") > 8


def test_usage_errors_exit_2(capsys):
    code, _, err = run(capsys, "suite")
    assert code == 2 and "required" in err
    code, _, err = run(capsys)
    assert code == 2


def test_missing_or_broken_subcommand_modules_do_not_break_the_others(capsys, monkeypatch, tiny_suite_dir,
                                                                      drivee2e_cache):
    broken = pytypes.ModuleType("drivee2e_jax.cli.broken")  # no add_parser: AttributeError
    monkeypatch.setitem(sys.modules, "drivee2e_jax.cli.broken", broken)
    monkeypatch.setattr(cli, "SUBCOMMANDS", cli.SUBCOMMANDS + ("not_written_yet", "broken"))
    code, out, _ = run(capsys, "--help")
    assert code == 0 and "suite" in out and "broken" in out and "not_written_yet" not in out
    code, out, _ = run(capsys, "suite", "validate", str(tiny_suite_dir))
    assert code == 0
    code, _, err = run(capsys, "broken")
    assert code == 2 and err.startswith("drivee2e: error: subcommand 'broken' is unavailable")


def test_subprocess_one_line_error_without_traceback(tmp_path):
    env = dict(os.environ, DRIVEE2E_CACHE=str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, "-m", "drivee2e_jax.cli", "suite", "info", "no_such_suite"],
                          capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert proc.stderr.strip().splitlines() == [
        "drivee2e: error: unknown suite 'no_such_suite'; expected a built-in suite name (twin15, tiny) "
        "or the path of a suite folder"
    ]


def test_a_repeated_key_is_a_problem_naming_file_and_key(capsys, tiny_suite_dir):
    p = tiny_suite_dir / "scenarios" / "s_val.json"
    p.write_text(p.read_text().replace('"ego_track_id":', '"ego_track_id":4,"ego_track_id":', 1))
    code, out, err = run(capsys, "suite", "validate", str(tiny_suite_dir))
    assert code == 1
    assert out.strip() == "scenarios/s_val.json: expected each key once per object, got duplicate key 'ego_track_id'"
