"""`drivee2e suite import` and the curation warnings of `drivee2e suite validate`, in-process via main(argv)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from drivee2e_jax import cli
from drivee2e_jax.scenario.schema import read_suite
from tests.helpers.importer_files import JUNCTION, interaction_csv, scenario_dict, write_pkl

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared real-data samples not found at {DATA}")


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_help_has_an_example(capsys):
    code, out, _ = run(capsys, "suite", "import", "--help")
    assert code == 0
    assert "examples:" in out and "drivee2e suite import argoverse2" in out and "--max-scenarios" in out


def _pickles(tmp_path, n=2):
    paths = []
    for i in range(n):
        d = scenario_dict()
        d["metadata"]["scenario_id"] = f"tiny-{i}"
        paths.append(write_pkl(tmp_path / f"sd_{i}.pkl", d))
    return paths


def test_import_prints_a_summary_and_writes_a_valid_suite(tmp_path, capsys):
    out = tmp_path / "suite"
    code, stdout, err = run(capsys, "suite", "import", "scenarionet", *_pickles(tmp_path), "--out", out, "--split", "val")
    assert code == 0, err
    assert "wrote 2 scenarios (STR 2), 2 maps" in stdout
    assert "skipped 4:" in stdout
    assert "2  empty track (no valid step)" in stdout and "unknown category 'UFO'" in stdout
    suite = read_suite(out)
    assert suite.name == "suite" and {s.split for s in suite.scenarios} == {"val"}
    code, stdout, err = run(capsys, "suite", "validate", out)
    assert code == 0 and "OK: 2 scenarios, 2 maps" in stdout


def test_max_scenarios_over_several_inputs(tmp_path, capsys):
    out = tmp_path / "one"
    code, stdout, _ = run(capsys, "suite", "import", "scenarionet", *_pickles(tmp_path, 3), "--out", out,
                          "--max-scenarios", "1", "--name", "just_one")
    assert code == 0 and "wrote 1 scenarios" in stdout
    assert read_suite(out).name == "just_one"


def test_errors_are_one_line_without_traceback(tmp_path, capsys):
    out = tmp_path / "suite"
    pk = _pickles(tmp_path, 1)
    assert run(capsys, "suite", "import", "scenarionet", *pk, "--out", out)[0] == 0
    code, stdout, err = run(capsys, "suite", "import", "scenarionet", *pk, "--out", out)
    assert code == 2 and "exists and is not empty" in err and "--force" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert run(capsys, "suite", "import", "scenarionet", *pk, "--out", out, "--force")[0] == 0
    bad = tmp_path / "sd_bad.pkl"
    bad.write_bytes(b"\x80\x04not a pickle")
    code, _, err = run(capsys, "suite", "import", "scenarionet", bad, "--out", tmp_path / "x")
    assert code == 2 and err.startswith("drivee2e: error: ") and "sd_bad.pkl" in err and len(err.splitlines()) == 1
    code, _, err = run(capsys, "suite", "import", "scenarionet", tmp_path / "missing.pkl", "--out", tmp_path / "y")
    assert code == 2 and "missing.pkl: no such file" in err
    code, _, err = run(capsys, "suite", "import", "scenarionet", *pk, "--out", tmp_path / "z", "--split", "dev")
    assert code == 2 and "--split: expected one of train, val, test" in err
    code, _, err = run(capsys, "suite", "import", "no-such-format", pk[0], "--out", tmp_path / "w")
    assert code == 2 and "invalid choice" in err
    assert not (tmp_path / "x").exists() and not (tmp_path / "z").exists()


def test_opendrive_map_and_tracks_stored_apart_load_together(tmp_path, capsys):
    """opendrive sets LOAD_ALL_PATHS_AT_ONCE: the CLI hands the .xodr and the track folder to one load()."""
    from drivee2e_jax.scenario.importers import opendrive

    assert opendrive.LOAD_ALL_PATHS_AT_ONCE
    xodr = tmp_path / "maps_elsewhere" / "junction.xodr"
    xodr.parent.mkdir()
    xodr.write_text(JUNCTION)
    lanes = {ln.id: ln for ln in opendrive.read_map(xodr)[0].lanes}
    rec = tmp_path / "data" / "recordings" / "rec"  # no .xodr in it, its parent or ../../maps/
    rec.mkdir(parents=True)
    interaction_csv(rec / "vehicle_tracks_000.csv", np.vstack([lanes[49].centerline, lanes[1049].centerline[1:]]))
    out = tmp_path / "od"
    code, stdout, err = run(capsys, "suite", "import", "opendrive", xodr, rec, "--out", out)
    assert code == 0, err
    assert "wrote 1 scenarios" in stdout
    suite = read_suite(out)
    assert [s.map_id for s in suite.scenarios] == ["junction"] and list(suite.maps) == ["junction"]
    # the same folder alone has no map to find (what a per-path load would have seen)
    code, _, err = run(capsys, "suite", "import", "opendrive", rec, "--out", tmp_path / "od2")
    assert code == 2 and "expected an .xodr map given with it" in err


@needs_data
def test_nothing_imported_names_the_first_skipped_item(tmp_path, capsys):
    """The SinD samples hold no vehicle tracks (Git LFS): the one-line error says so."""
    code, _, err = run(capsys, "suite", "import", "lanelet2-csv", DATA / "sind" / "Changchun", "--out", tmp_path / "o")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "no scenario could be imported (1 item skipped; first: " in err
    assert "no vehicle tracks, so no ego" in err and not (tmp_path / "o").exists()


def test_missing_pyarrow_names_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    monkeypatch.setitem(sys.modules, "pyarrow.feather", None)
    f = tmp_path / "scenario_x.parquet"
    f.write_bytes(b"PAR1")
    code, _, err = run(capsys, "suite", "import", "argoverse2", f, "--out", tmp_path / "o")
    assert code == 2 and "pip install 'drivee2e-jax[import]'" in err


def test_validate_prints_curation_warnings_and_strict_fails(tmp_path, capsys):
    d = scenario_dict()
    d["tracks"]["car1"]["state"]["position"][30:, 0] += 50.0  # a 50 m teleport: an identity switch
    out = tmp_path / "s"
    assert run(capsys, "suite", "import", "scenarionet", write_pkl(tmp_path / "sd_t.pkl", d), "--out", out)[0] == 0
    code, stdout, err = run(capsys, "suite", "validate", out)
    assert code == 0 and stdout.strip() == "OK: 1 scenarios, 1 maps"
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning: ")]
    assert warnings and all("synthetic_tiny-1: track" in w and "plausibility" in w for w in warnings)
    assert "t=2.9 s" in warnings[0] and "bus speed" in warnings[0]
    assert "curation finding" in err
    code, stdout, err = run(capsys, "suite", "validate", out, "--strict")
    assert code == 1 and "--strict" in err
    code, stdout, err = run(capsys, "suite", "validate", out, "--no-curation")
    assert code == 0 and "warning" not in err


@needs_data
@pytest.mark.parametrize("fmt,inputs,expected", [
    ("argoverse2", ["argoverse2"], 2),
    ("scenarionet", ["nuscenes_scenarionet/sd_nuscenes_v1.0-mini_scene-0061.pkl",
                     "nuscenes_scenarionet/sd_nuscenes_v1.0-mini_scene-0103.pkl"], 2),
])
def test_shared_samples_import_and_validate(tmp_path, capsys, fmt, inputs, expected):
    out = tmp_path / fmt
    code, stdout, err = run(capsys, "suite", "import", fmt, *[DATA / i for i in inputs], "--out", out)
    assert code == 0, err
    assert f"wrote {expected} scenarios" in stdout and "next: drivee2e suite validate" in stdout
    code, stdout, err = run(capsys, "suite", "validate", out)
    assert code == 0 and f"OK: {expected} scenarios, {expected} maps" in stdout
    suite = read_suite(out)
    for s in suite.scenarios:
        ego = next(t for t in s.tracks if t.track_id == s.ego_track_id)
        assert len(ego.t) == s.num_steps
        np.testing.assert_allclose(s.route.source, ego.xy[0], atol=1e-3)
        np.testing.assert_allclose(s.route.destination, ego.xy[-1], atol=1e-3)


def test_import_suite_api(tmp_path):
    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.scenario.importers import ImportOptions, import_suite

    pk = _pickles(tmp_path, 2)
    out = tmp_path / "api"
    r = import_suite("scenarionet", pk, out, ImportOptions(name="api_suite"))
    assert len(r.scenarios) == 2 and read_suite(out).name == "api_suite"
    with pytest.raises(DriveE2EError, match="not empty"):
        import_suite("scenarionet", pk, out, ImportOptions())
    assert len(import_suite("scenarionet", pk[:1], out, ImportOptions(), force=True).scenarios) == 1
    assert len(read_suite(out).scenarios) == 1
    with pytest.raises(DriveE2EError, match="unknown import format 'csv'"):
        import_suite("csv", pk, tmp_path / "b", ImportOptions())


@pytest.mark.parametrize("where, field", [
    (("tracks", "car1", "state", "position"), "tracks['car1'].state.position[5, 0]"),
    (("tracks", "ego", "state", "position"), "tracks['ego'].state.position[5, 0]"),
    (("map_features", "lane_a", "polyline"), "map_features['lane_a'].polyline[5, 0]"),
])
def test_a_position_beyond_float32_is_refused_naming_the_track_and_field(tmp_path, capsys, recwarn, where, field):
    """The user's report: a position of 1e308 spewed numpy overflow warnings, then a
    JSON ValueError ("Out of range float values") or an OverflowError, exit 1."""
    d = scenario_dict()
    obj = d
    for key in where:
        obj = obj[key]
    obj[5, 0] = 1e308
    pk = write_pkl(tmp_path / "sd_big.pkl", d)
    code, _, err = run(capsys, "suite", "import", "scenarionet", pk, "--out", tmp_path / "out")
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("drivee2e: error: ") and (
        f"{pk.name}: {field}: expected finite numbers with |value| <= 3.40282e+38 "
        "(the float32 range the simulator computes in), got 1e+308\n") in err, err
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in recwarn]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("value", [1e37, -2.5e7])
def test_a_position_beyond_any_planar_frame_is_refused_in_one_line(tmp_path, capsys, value):
    """Within float32 but no place on Earth in a planar frame (|x| > 1e7 m): the
    import stops before writing, naming the scenario file and field it would have
    been (every importer writes through ``validate_records``), exit 2."""
    d = scenario_dict()
    d["tracks"]["ego"]["state"]["position"][5, 0] = value
    pk = write_pkl(tmp_path / "sd_far.pkl", d)
    code, _, err = run(capsys, "suite", "import", "scenarionet", pk, "--out", tmp_path / "out")
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("drivee2e: error: cannot write suite 'out': scenarios/synthetic_tiny-1.json: "), err
    assert "|value| <= 1e+07 m" in err and f"{value:g}" in err, err  # the ego's route is checked before its track
    assert not (tmp_path / "out").exists()
