"""drivee2e view: --force never overwrites what the player did not write, and a stale results folder is refused (issue 39 items 2, 4)."""

from __future__ import annotations

import json
import shutil

from drivee2e_jax.cli import main
from drivee2e_jax.policy import resolve_policy_path


def _run(capsys, *args) -> tuple[int, list[str]]:
    code = main(list(args))
    return code, capsys.readouterr().err.strip().splitlines()


def test_force_never_overwrites_a_page_or_files_drivee2e_did_not_write(tmp_path, capsys):
    results = tmp_path / "results"
    results.mkdir()
    page = tmp_path / "p.html"
    page.write_text("<html>the user's page</html>")
    code, err = _run(capsys, "view", str(results), "--out", str(page), "--force")
    assert code == 2 and len(err) == 1 and err[0].startswith(f"drivee2e: error: {page}: not a player page drivee2e wrote")
    assert page.read_text() == "<html>the user's page</html>"
    page.unlink()
    files = tmp_path / "p_files"
    (files / "episodes").mkdir(parents=True)
    (files / "episodes" / "e00000.js").write_text("drivee2e_data(...)")
    (files / "episodes" / "notes.txt").write_text("the user's")
    code, err = _run(capsys, "view", str(results), "--out", str(page), "--force")
    assert code == 2 and len(err) == 1
    assert f"{files}: holds files drivee2e did not write (episodes/notes.txt)" in err[0]
    assert (files / "episodes" / "notes.txt").exists() and (files / "episodes" / "e00000.js").exists()

    mcap = tmp_path / "a.mcap"
    mcap.write_bytes(b"the user's recording")
    code, err = _run(capsys, "export-mcap", str(results), "--out", str(mcap), "--force")
    assert code == 2 and len(err) == 1 and err[0].startswith(f"drivee2e: error: {mcap}: not a MCAP file drivee2e wrote")
    assert mcap.read_bytes() == b"the user's recording"


def test_view_and_export_refuse_results_whose_suite_or_policy_changed(suite_dir, tmp_path, capsys, monkeypatch):
    """The fingerprints bench checks on resume, checked by the readers before
    they re-simulate or write anything: an edited scenario, policy file or a
    module the policy imports from its folder."""
    monkeypatch.setenv("DRIVEE2E_CACHE", str(tmp_path / "cache"))
    suite = shutil.copytree(suite_dir, tmp_path / "suite")
    pol = tmp_path / "policy" / "stop.py"
    pol.parent.mkdir()
    pol.write_text("import helper  # noqa: F401\n" + resolve_policy_path("stop").read_text())
    helper = pol.parent / "helper.py"
    helper.write_text("GAIN = 1\n")
    monkeypatch.syspath_prepend(str(pol.parent))
    out = tmp_path / "run"
    assert main(["bench", "--suite", str(suite), "--out", str(out), "--no-progress", "--limit", "1",
                 "--policy", str(pol)]) == 0
    capsys.readouterr()
    page, mcap = tmp_path / "p.html", tmp_path / "a.mcap"

    def readers() -> list[str]:
        lines = []
        for args in (["view", str(out), "--out", str(page), "--no-sensors", "--no-progress"],
                     ["export-mcap", str(out), "--out", str(mcap), "--no-sensors"]):
            code, err = _run(capsys, *args)
            assert code == 2 and len(err) == 1, err
            lines.append(err[0])
        assert not page.exists() and not (tmp_path / "p_files").exists() and not mcap.exists()  # nothing written
        return lines

    first = json.loads((out / "policies" / "stop.json").read_text())["rows"][0]["scenario_id"]
    scn = suite / "scenarios" / f"{first}.json"
    original = scn.read_text()
    data = json.loads(original)
    data["tracks"][0]["size"][0] += 0.5  # one agent's length
    scn.write_text(json.dumps(data))
    for line in readers():
        assert line.startswith(f"drivee2e: error: {out}: stale results: the suite's scenarios (")
        assert "(differs in fingerprint.suite_sha256)" in line and "--force" in line
    scn.write_text(original)

    helper.write_text("GAIN = 2\n")
    for line in readers():
        assert line.startswith(f"drivee2e: error: [stop] {out}: stale results: the policy changed")
        assert "(changed: the modules it imports from its folder (helper.py))" in line
    helper.write_text("GAIN = 1\n")
    pol.write_text(pol.read_text() + "# tuned\n")
    for line in readers():
        assert "(changed: the policy file's content)" in line
