"""eval.results: the results-folder contract (lock, fingerprints, resume rules, provenance) without rollouts."""

from __future__ import annotations

import json

import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.results import (
    RESULTS_FOLDER,
    RunDir,
    check_policy_current,
    check_run_current,
    git_state,
    policy_fingerprint,
    policy_provenance,
    run_differences,
    run_fingerprint,
    run_provenance,
    stored_path,
)
from drivee2e_jax.policy import resolve_policy_path

INFO = {"suite": "s", "split": "val", "num_scenarios": 1, "dt": 0.1,
        "fingerprint": {"suite_sha256": "aa", "drivee2e_version": "1"}}
ROW = {"policy": "a", "scenario_id": "x", "status": "Perfect", "driving_score": 100.0}


def _finish(run: RunDir, name: str) -> None:
    run.save_policy(name, [{**ROW, "policy": name}], {"x": []}, {})


def _policy(tmp_path, text="policy = None\n"):
    f = tmp_path / "pol.py"
    f.write_text(text)
    return f


def test_a_finished_policy_resumes_only_with_the_same_fingerprint(tmp_path):
    f = _policy(tmp_path)
    fp = policy_fingerprint(f, {})
    with RunDir(tmp_path / "r", INFO, policies={"a": fp}) as run:
        assert not run.done("a")
        _finish(run, "a")
    with RunDir(tmp_path / "r", INFO, policies={"a": policy_fingerprint(f, {})}) as run:
        assert run.done("a")
    f.write_text("policy = None  # edited\n")
    with pytest.raises(DriveE2EError) as e:
        RunDir(tmp_path / "r", INFO, policies={"a": policy_fingerprint(f, {})})
    msg = str(e.value)
    assert msg.startswith("[a] ") and "(changed: the policy file's content)" in msg and "--force" in msg
    f.write_text("policy = None\n")
    with pytest.raises(DriveE2EError, match=r"\(changed: its make_policy arguments\)"):
        RunDir(tmp_path / "r", INFO, policies={"a": policy_fingerprint(f, {"gain": 2})})
    with RunDir(tmp_path / "r", INFO, force=True, policies={"a": policy_fingerprint(f, {})}) as run:
        assert not run.done("a") and run.finished() == []  # --force starts over


def test_a_checkpoint_argument_is_fingerprinted_by_content(tmp_path):
    ckpt = tmp_path / "ckpt"
    ckpt.mkdir()
    (ckpt / "w.bin").write_bytes(b"1")
    f = _policy(tmp_path)
    fp = policy_fingerprint(f, {"checkpoint": str(ckpt), "gain": 1})
    assert set(fp["files_sha256"]) == {"checkpoint"} and fp["kwargs"] == {"checkpoint": str(ckpt), "gain": 1}
    (ckpt / "w.bin").write_bytes(b"2")
    assert policy_fingerprint(f, {"checkpoint": str(ckpt), "gain": 1}) != fp
    with RunDir(tmp_path / "r", INFO, policies={"a": fp}) as run:
        _finish(run, "a")
    with pytest.raises(DriveE2EError, match=r"\[a\] .*\(changed: the files its arguments name \(checkpoint\)\)"):
        RunDir(tmp_path / "r", INFO, policies={"a": policy_fingerprint(f, {"checkpoint": str(ckpt), "gain": 1})})
    prov = policy_provenance(f, {"checkpoint": str(ckpt)}, fp, tmp_path)
    assert prov["policy"] == "pol.py" and prov["files"]["checkpoint"]["path"] == "ckpt"  # relative to the folder


def test_a_remote_policy_is_never_resumed(tmp_path):
    fp = policy_fingerprint("remote://127.0.0.1:5555", {}, remote_name="srv")
    assert fp == {"remote": "remote://127.0.0.1:5555", "server_name": "srv"}
    with RunDir(tmp_path / "r", INFO, policies={"srv": None}) as run:
        _finish(run, "srv")
    with RunDir(tmp_path / "r", INFO, policies={"srv": None}) as run:
        assert not run.done("srv") and run.finished() == ["srv"]


def test_a_different_run_or_an_older_folder_is_refused_in_one_line(tmp_path):
    with RunDir(tmp_path / "r", INFO) as run:
        _finish(run, "a")
    changed = {**INFO, "fingerprint": {**INFO["fingerprint"], "suite_sha256": "bb"}}
    with pytest.raises(DriveE2EError, match=r"different run \(differs in fingerprint.suite_sha256\); use --force"):
        RunDir(tmp_path / "r", changed)
    old = {k: v for k, v in INFO.items() if k != "fingerprint"}
    (tmp_path / "r" / "run.json").write_text(json.dumps(old))
    with pytest.raises(DriveE2EError, match="written by an older drivee2e version .*use --force"):
        RunDir(tmp_path / "r", INFO)
    assert run_differences({**INFO, "provenance": {"time_utc": "x"}}, INFO) == []  # provenance is not compared


def test_a_corrupt_policy_file_is_one_line_naming_it(tmp_path):
    with RunDir(tmp_path / "r", INFO) as run:
        _finish(run, "a")
    f = tmp_path / "r" / "policies" / "a.json"
    f.write_text(f.read_text()[:25])  # truncated
    with pytest.raises(DriveE2EError) as e:
        RunDir(tmp_path / "r", INFO, policies={"a": {}})
    assert str(e.value).startswith(f"{f} is corrupt (") and str(e.value).endswith("delete it or use --force")
    f.write_text("[]")
    with pytest.raises(DriveE2EError, match="is corrupt"):
        RunDir(tmp_path / "r", INFO)


def test_tables_list_every_policy_file_this_runs_first(tmp_path):
    for names in (["b", "c"], ["z", "a"]):
        with RunDir(tmp_path / "r", INFO) as run:
            for n in names:
                _finish(run, n)
    with RunDir(tmp_path / "r", INFO) as run:
        assert run.finished(["z", "c"]) == ["z", "c", "a", "b"]
        run.write_tables(run.finished(["z", "c"]), {}, ())
    got = json.loads((tmp_path / "r" / "scenarios.json").read_text())
    assert [r["policy"] for r in got] == ["z", "c", "a", "b"]


def test_a_second_writer_is_refused_and_what_a_failed_run_created_is_removed(tmp_path):
    out = tmp_path / "r"
    run = RunDir(out, INFO)
    with pytest.raises(DriveE2EError, match=r"in use by another run \(pid \d+ on .*\); wait for it .* --out"):
        RunDir(out, INFO)
    run.close()
    assert not out.exists()  # nothing finished: the folder it created is gone
    out.mkdir()
    RunDir(out, INFO).close()
    assert out.is_dir() and list(out.iterdir()) == []  # an empty folder given: left empty
    (out / "notes.txt").write_text("mine")
    with pytest.raises(DriveE2EError, match="not a drivee2e results folder"):
        RunDir(out, INFO)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]  # refused before the lock: untouched


def test_stray_temp_files_are_removed_under_the_lock(tmp_path):
    with RunDir(tmp_path / "r", INFO) as run:
        _finish(run, "a")
    stray = [tmp_path / "r" / "policies" / ".a.json.k2j4h5g6.tmp", tmp_path / "r" / ".summary.json.abcd1234.tmp"]
    for s in stray:
        s.write_text("{")
    with RunDir(tmp_path / "r", INFO):
        assert not any(s.exists() for s in stray)


def test_provenance_records_portable_paths(tmp_path):
    expert = resolve_policy_path("expert")
    assert stored_path(expert, tmp_path) == "expert"  # a zoo policy by name, not the site-packages path
    inside = tmp_path / "pol" / "p.py"
    assert stored_path(inside, tmp_path) == "pol/p.py"
    assert stored_path("/elsewhere/p.py", tmp_path) == "/elsewhere/p.py"
    prov = run_provenance(tmp_path, str(tmp_path / "suites" / "s"), {"backend": "cpu"})
    assert {"drivee2e_version", "time_utc", "command", "suite", "backend"} <= set(prov)
    assert prov["suite"] == str(tmp_path / "suites" / "s")  # not a folder (yet): as given
    assert git_state(tmp_path / "not_a_checkout" / "drivee2e_jax") == {}


def test_a_later_policy_whose_name_shares_a_file_is_refused(tmp_path):
    """'x/y' wrote policies/x_y.json; a later run's 'x_y' must not overwrite (and silently drop) it."""
    fp = policy_fingerprint(_policy(tmp_path), {})
    with RunDir(tmp_path / "r", INFO, policies={"x/y": fp}) as run:
        _finish(run, "x/y")
    with pytest.raises(DriveE2EError, match=r"\[x_y\] its result file .*x_y.json already holds policy 'x/y'"):
        RunDir(tmp_path / "r", INFO, policies={"x_y": fp})
    with RunDir(tmp_path / "r", INFO, policies={"x/y": fp}) as run:  # the original still resumes
        assert run.done("x/y")


def test_force_never_deletes_files_drivee2e_did_not_write(tmp_path):
    out = tmp_path / "mine"
    (out / "plots").mkdir(parents=True)
    for name in ("report.md", "summary.json", "plots/fig.png"):
        (out / name).write_text("the user's")
    for force in (False, True):
        with pytest.raises(DriveE2EError) as e:
            RunDir(out, INFO, force=force)
        msg = str(e.value)
        assert msg.startswith(f"{out}: not a drivee2e results folder (no run.json; holds plots/fig.png, report.md, "
                              "summary.json)") and "\n" not in msg
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "plots", "plots/fig.png", "report.md", "summary.json"]  # untouched, not even a lock file
    assert all(p.read_text() == "the user's" for p in out.rglob("*") if p.is_file())

    run = tmp_path / "r"  # a results folder the user added a file to
    with RunDir(run, INFO) as r:
        _finish(r, "a")
    (run / "plots").mkdir()
    (run / "plots" / "fig.png").write_text("the user's")
    with RunDir(run, INFO) as r:  # resuming deletes nothing: allowed
        assert r.finished() == ["a"]
    with pytest.raises(DriveE2EError, match=rf"^{run}: holds files drivee2e did not write \(plots/fig.png\); "
                                            r"--force redoes only"):
        RunDir(run, INFO, force=True)
    assert (run / "plots" / "fig.png").read_text() == "the user's" and (run / "policies" / "a.json").is_file()
    (run / "plots" / "fig.png").unlink()
    for name in ("plots/comfort.png", "leaderboard/a.json", "report.md", "scenarios.csv"):  # what drivee2e writes
        assert RESULTS_FOLDER.owns(name)
    with RunDir(run, INFO, force=True) as r:  # drivee2e's own files: redone
        assert r.finished() == []


def test_a_module_the_policy_imports_from_its_folder_is_fingerprinted(tmp_path):
    pkg = tmp_path / "mine"
    (pkg / "lib").mkdir(parents=True)
    pol = pkg / "pol.py"
    pol.write_text("import os\nimport helper\nfrom lib import tune\npolicy = None\n")
    (pkg / "helper.py").write_text("GAIN = 1\nimport pol  # a cycle\n")
    (pkg / "lib" / "__init__.py").write_text("")
    (pkg / "lib" / "tune.py").write_text("def f():\n    from . import deep\n")  # relative, inside a function
    (pkg / "lib" / "deep.py").write_text("K = 1\n")
    (pkg / "unused.py").write_text("")
    fp = policy_fingerprint(pol, {})
    assert sorted(fp["modules_sha256"]) == ["helper.py", "lib/__init__.py", "lib/deep.py", "lib/tune.py"]
    assert "modules_sha256" not in policy_fingerprint(_policy(tmp_path), {})  # none: older fingerprints still match
    with RunDir(tmp_path / "r", INFO, policies={"a": fp}) as run:
        _finish(run, "a")
    (pkg / "unused.py").write_text("x = 2\n")
    with RunDir(tmp_path / "r", INFO, policies={"a": policy_fingerprint(pol, {})}) as run:
        assert run.done("a")  # a file the policy does not import changes nothing
    (pkg / "lib" / "deep.py").write_text("K = 2\n")  # two imports away
    with pytest.raises(DriveE2EError) as e:
        RunDir(tmp_path / "r", INFO, policies={"a": policy_fingerprint(pol, {})})
    msg = str(e.value)
    assert msg.startswith("[a] ") and "(changed: the modules it imports from its folder (lib/deep.py))" in msg
    assert "--force" in msg and "\n" not in msg
    with RunDir(tmp_path / "r", INFO, force=True, policies={"a": policy_fingerprint(pol, {})}) as run:
        assert not run.done("a")  # --force redoes it


def test_a_reader_refuses_results_whose_inputs_changed(tmp_path):
    fp = INFO["fingerprint"]
    check_run_current(tmp_path, INFO, fp)
    with pytest.raises(DriveE2EError, match=rf"^{tmp_path}: stale results: the suite's scenarios \(a scenario, map "
                                            r"or suite.json file edited, or the suite regenerated\) changed since "
                                            r"`drivee2e bench` wrote them \(differs in fingerprint.suite_sha256\)"):
        check_run_current(tmp_path, INFO, {**fp, "suite_sha256": "bb"})
    with pytest.raises(DriveE2EError, match="written by an older drivee2e version"):
        check_run_current(tmp_path, {"suite": "s"}, fp)
    assert set(run_fingerprint(suite_sha256="aa")) == {"suite_sha256", "drivee2e_version"}
    pol = _policy(tmp_path)
    data = {"fingerprint": policy_fingerprint(pol, {})}
    check_policy_current(tmp_path, "a", data, policy_fingerprint(pol, {}))
    pol.write_text("policy = None  # edited\n")
    with pytest.raises(DriveE2EError, match=r"^\[a\] .*stale results: .*\(changed: the policy file's content\)"):
        check_policy_current(tmp_path, "a", data, policy_fingerprint(pol, {}))


def test_a_repeated_key_in_run_json_is_refused_naming_it(tmp_path):
    with RunDir(tmp_path / "r", INFO) as run:
        _finish(run, "a")
    meta = tmp_path / "r" / "run.json"
    meta.write_text(meta.read_text().replace('"split": "val",', '"split": "val", "split": "test",'))
    with pytest.raises(DriveE2EError, match=rf"^{meta}: expected each key once per object, got duplicate key 'split'; use --force"):
        RunDir(tmp_path / "r", INFO)
