"""The `drivee2e` CLI turns every error into one line on stderr with a non-zero
exit code; the traceback only with --debug."""

from __future__ import annotations

import argparse
import json
import re
import textwrap
from pathlib import Path

import pytest

from drivee2e_jax.cli import common, main
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.testing import TINY_SUITE


def _raising(exc: BaseException):
    def func(args):
        raise exc

    return func


def _json_error() -> json.JSONDecodeError:
    try:
        json.loads('{"a": 1,}')
    except json.JSONDecodeError as e:
        return e
    raise AssertionError("expected invalid JSON")


CASES = {
    "drivee2e": (DriveE2EError("suite.json: name: expected a string\ngot 3"), 2,
                 "drivee2e: error: suite.json: name: expected a string got 3"),
    "json": (_json_error(), 2, "drivee2e: error: invalid JSON: Expecting property name enclosed in double quotes"),
    "missing file": (FileNotFoundError(2, "No such file or directory", "runs/x.json"), 2,
                     "drivee2e: error: runs/x.json: No such file or directory"),
    "permission": (PermissionError(13, "Permission denied", "/results"), 2,
                   "drivee2e: error: /results: Permission denied"),
    "disk full": (OSError(28, "No space left on device"), 2, "drivee2e: error: [Errno 28] No space left on device"),
    "memory": (MemoryError(), 2, "drivee2e: error: out of memory (try fewer scenarios"),
    "interrupt": (KeyboardInterrupt(), 130, "drivee2e: interrupted"),
    "bug": (RuntimeError("shapes (3,) and (4,)\nin add"), 1,
            "drivee2e: error: RuntimeError: shapes (3,) and (4,) in add (unexpected; rerun with --debug for the "
            "traceback)"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_every_error_is_one_line_with_an_exit_code(capsys, case):
    exc, code, line = CASES[case]
    assert common.run(_raising(exc), argparse.Namespace(), debug=False) == code
    out = capsys.readouterr()
    assert out.out == "" and out.err.count("\n") == 1 and out.err.startswith(line), out.err
    assert "Traceback" not in out.err


def test_a_long_unexpected_error_is_cut():
    line = common.unexpected_message(ValueError("x" * 5000))
    assert len(line) < common.MAX_MESSAGE + 80
    assert line.endswith("xx... (unexpected; rerun with --debug for the traceback)")


@pytest.mark.parametrize("case", ["drivee2e", "interrupt", "bug"])
def test_debug_shows_the_traceback(case):
    exc = CASES[case][0]
    with pytest.raises(type(exc)):
        common.run(_raising(exc), argparse.Namespace(), debug=True)


POLICY = """\
import jax.numpy as jnp

from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls


class P(StatelessPolicy):
    name = "p"

    def act(self, params, obs, state, key):
        z = jnp.zeros((), jnp.float32)
{body}

policy = P()
"""


def _policy_file(tmp_path, body: str):
    """A policy file whose act ends with ``body``; (its path, the line of its ``# HERE``)."""
    path = tmp_path / "my_policy.py"
    path.write_text(POLICY.format(body=textwrap.indent(textwrap.dedent(body), " " * 8)))
    return path, next(i + 1 for i, s in enumerate(path.read_text().splitlines()) if s.endswith("# HERE"))


def test_bench_with_a_policy_branching_on_arrays_is_one_line(tmp_path, capsys):
    """The user's report: 35-100 lines of JAX traceback for a Python `if` on an array."""
    policy, line_no = _policy_file(tmp_path, """\
        if obs.ego[0] > 1.0:  # HERE
            return Controls(throttle=z, brake=z, steer=z), state
        return Controls(throttle=z, brake=z + 1, steer=z), state
    """)
    code = main(["bench", "--suite", str(TINY_SUITE), "--split", "val", "--policy", str(policy),
                 "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    (line,) = [s for s in err.splitlines() if s.startswith("drivee2e: error:")]
    assert line.startswith(f"drivee2e: error: {policy}: act(params, obs, state, key) branches on a traced value")
    assert f"at {policy}:{line_no}; use jnp.where or jax.lax.cond" in line


def test_check_policy_names_the_line(tmp_path, capsys):
    policy, line_no = _policy_file(tmp_path, """\
        raise ValueError("no route")  # HERE
    """)
    assert main(["check-policy", str(policy), "--batch", "1", "--steps", "1"]) == 1
    out = capsys.readouterr().out.strip()
    assert out.startswith(f"{policy}: act(params, obs, state, key) raised ValueError: no route at {policy}:{line_no} ")
    assert "\n" not in out


def test_the_error_line_is_not_glued_to_an_open_progress_bar(capsys):
    import sys

    from tqdm import tqdm

    bar = tqdm(total=10, desc="closed-loop", file=sys.stderr)
    bar.update(3)
    try:
        common.print_error("remote://127.0.0.1:5555, step 4: act raised ValueError: x at pol.py:9")
    finally:
        bar.close()
    err = capsys.readouterr().err
    lines = [seg for chunk in err.split("\n") for seg in chunk.split("\r")]
    assert any(seg.startswith("drivee2e: error: remote://") for seg in lines), repr(err)


# ------------------------------------------------------------- the users' reports: a file drivee2e cannot read
# (each ended in "unexpected; rerun with --debug" exit 1 or a traceback)


def _tiny_copy(tmp_path):
    import shutil

    return Path(shutil.copytree(TINY_SUITE, tmp_path / "suite"))


def _one_error_line(err: str) -> str:
    assert "Traceback" not in err, err
    (line,) = [s for s in err.splitlines() if s.startswith("drivee2e: error:")]
    return line


def test_bench_refuses_a_suite_json_nested_200000_deep(tmp_path, capsys):
    """`drivee2e suite validate` refused it; bench (suite._Folder) raised RecursionError."""
    suite = _tiny_copy(tmp_path)
    (suite / "suite.json").write_text("[" * 200_000 + "]" * 200_000)
    code = main(["bench", "--suite", str(suite), "--policy", "stop", "--limit", "1", "--no-progress",
                 "--out", str(tmp_path / "out")])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 2 and line.startswith(f"drivee2e: error: {suite.resolve()}/suite.json: expected valid JSON, got "
                                         "arrays / objects nested too deep to read"), line


def test_bench_refuses_a_5001_digit_number_in_a_scenario_file(tmp_path, capsys):
    suite = _tiny_copy(tmp_path)
    path = suite / "scenarios" / "s_val.json"
    path.write_text(path.read_text().replace('"num_steps":', '"num_steps":' + "9" * 5001 + ',"x":', 1))
    code = main(["bench", "--suite", str(suite), "--split", "val", "--policy", "stop", "--no-progress",
                 "--out", str(tmp_path / "out")])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 2 and line.startswith(f"drivee2e: error: {suite.resolve()}/scenarios/s_val.json: line "), line
    assert ": expected a number with at most 4300 digits" in line and "got a number with more than 4300 digits" in line

def test_bench_refuses_a_401_digit_num_steps_naming_its_range(tmp_path, capsys):
    """OverflowError when packed into numpy (int32)."""
    suite = _tiny_copy(tmp_path)
    path = suite / "scenarios" / "s_val.json"
    path.write_text(re.sub(r'"num_steps":\s*\d+', '"num_steps":' + "9" * 401, path.read_text(), count=1))
    code = main(["bench", "--suite", str(suite), "--split", "val", "--policy", "stop", "--no-progress",
                 "--out", str(tmp_path / "out")])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 2 and line == (f"drivee2e: error: {suite.resolve()}/scenarios/s_val.json: num_steps: expected an "
                                  "integer in [1, 2147483647], got an integer of about 401 digits"), line


def test_a_policy_checkpoint_json_with_a_5001_digit_number_is_one_line(tmp_path, capsys):
    """A policy's own JSON (the checkpoint's meta.json that ad_mlp:checkpoint= reads)."""
    meta = tmp_path / "run" / "checkpoints" / "1" / "meta.json"
    meta.parent.mkdir(parents=True)
    meta.write_text('{"epoch": ' + "9" * 5001 + "}")
    code = main(["bench", "--suite", str(TINY_SUITE), "--split", "val", "--policy", f"ad_mlp:checkpoint={meta.parent}",
                 "--no-progress", "--out", str(tmp_path / "out")])
    line = _one_error_line(capsys.readouterr().err)
    assert code == 2 and f"{meta}: line 1 column 11: expected a number with at most 4300 digits" in line, line

