"""`drivee2e view` on a results folder whose files are not what `drivee2e bench`
writes: one line naming the file and what was expected (it was an
AttributeError / KeyError, "unexpected; rerun with --debug")."""

from __future__ import annotations

import json

import pytest

from drivee2e_jax.cli import main

EXPECTED = ('a corrupt results file: expected a JSON object with "policy" and "rows" (a list of scenario rows '
            'with "scenario_id"), as `drivee2e bench` writes it, got ')


def _results(tmp_path, policy_file: str, summary: str | None = None):
    """A results folder: a valid run.json, ``policies/stop.json`` = ``policy_file``."""
    run = tmp_path / "results"
    (run / "policies").mkdir(parents=True)
    (run / "run.json").write_text(json.dumps({"suite": "tiny", "split": "val", "dt": 0.1}))
    (run / "policies" / "stop.json").write_text(policy_file)
    if summary is not None:
        (run / "summary.json").write_text(summary)
    return run


@pytest.mark.parametrize("content, got", [
    ("[]", "an empty list"),
    ('{"policy": "stop", "events": {}}', 'an object without "rows"'),
    ('{"policy": "stop", "rows": {"s_val": {}}}', '"rows" an object'),
    ('{"policy": "stop", "rows": [{"status": "Perfect"}]}', "rows[0] without scenario_id"),
    ('{"policy": "stop", "rows": [3]}', "rows[0] a number"),
])
def test_a_corrupt_policy_file_is_one_line_naming_it(tmp_path, capsys, content, got):
    run = _results(tmp_path, content)
    code = main(["view", str(run), "--out", str(tmp_path / "p.html"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1, err
    assert err == (f"drivee2e: error: {run / 'policies' / 'stop.json'}: {EXPECTED}{got}; "
                   "rerun `drivee2e bench` for this policy\n")


@pytest.mark.parametrize("summary, got", [("[]", "an empty list"), ('{"policies": []}', "an empty list")])
def test_a_corrupt_summary_is_one_line_naming_it(tmp_path, capsys, summary, got):
    run = _results(tmp_path, '{"policy": "stop", "rows": [], "events": {}}', summary)
    code = main(["view", str(run), "--out", str(tmp_path / "p.html"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err == (f"drivee2e: error: {run / 'summary.json'}: a corrupt results file: expected a JSON "
                                 'object whose "policies" is an object (policy name -> summary), as `drivee2e bench` '
                                 f"writes it, got {got}\n"), err


def test_a_policy_file_that_is_not_json_names_the_place(tmp_path, capsys):
    run = _results(tmp_path, '{"policy": "stop", "rows": [' + "[" * 200_000)
    code = main(["view", str(run), "--out", str(tmp_path / "p.html"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"drivee2e: error: {run / 'policies' / 'stop.json'}: expected valid JSON, "
                                        "got arrays / objects nested too deep"), err
