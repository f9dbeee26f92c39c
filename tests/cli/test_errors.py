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


def _raised(exc: BaseException) -> BaseException:
    """``exc`` raised once (it carries a traceback), from a cause."""
    try:
        try:
            raise KeyError("the cause")
        except KeyError as cause:
            raise exc from cause
    except BaseException as e:  # noqa: BLE001
        return e


@pytest.mark.parametrize("case", ["drivee2e", "json", "bug"])
def test_debug_prints_the_traceback_and_keeps_the_exit_code(capsys, case):
    """--debug used to re-raise: Python's exit code 1 for every error, and a
    policy's own frames (the cause) only when Python printed the chain."""
    exc, code, line = CASES[case]
    assert common.run(_raising(_raised(exc)), argparse.Namespace(), debug=True) == code
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):") and "KeyError: 'the cause'" in err
    assert "The above exception was the direct cause of the following exception" in err
    assert err.splitlines()[-1].startswith(line), err


def test_debug_lets_ctrl_c_through():
    with pytest.raises(KeyboardInterrupt):
        common.run(_raising(KeyboardInterrupt()), argparse.Namespace(), debug=True)


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
    assert code == 2 and line.startswith(f"drivee2e: error: {meta}: unreadable checkpoint metadata (line 1 column 11: "
                                         "expected a number with at most 4300 digits"), line


# ------------------------------------------------------------- --debug: the policy's own frames, the same exit code


HOST_POLICY = """\
import numpy as np

from drivee2e_jax.hostapi import Controls, HostPolicy


class P(HostPolicy):
    name = "hp"
    action_type = "controls"
    observation_fields = ("ego",)

    def act(self, obs, state):
        raise ValueError("no route")  # HERE


policy = P()
"""


def _bench_twice(tmp_path, capsys, policy: Path) -> tuple[int, str, int, str]:
    """(exit code, stderr) of one bench of ``policy`` without and with --debug."""
    out = []
    for extra in ([], ["--debug"]):
        code = main(["bench", "--suite", "tiny", "--split", "val", "--policy", str(policy), "--limit", "1",
                     "--no-progress", "--out", str(tmp_path / f"out{len(out)}"), *extra])
        out += [code, capsys.readouterr().err]
    return tuple(out)


@pytest.mark.parametrize("kind", ["jax", "host"])
def test_debug_shows_the_policys_own_frame_and_keeps_the_exit_code(tmp_path, capsys, kind):
    """The issue: --debug showed framework frames but not the policy's own
    traceback, and changed the exit code (2 -> 1: Python's for a raise)."""
    if kind == "jax":
        policy, line_no = _policy_file(tmp_path, 'raise ValueError("no route")  # HERE\n')
    else:
        policy = tmp_path / "my_host_policy.py"
        policy.write_text(HOST_POLICY)
        line_no = next(i + 1 for i, s in enumerate(HOST_POLICY.splitlines()) if s.endswith("# HERE"))
    code, err, debug_code, debug_err = _bench_twice(tmp_path, capsys, policy)
    line = _one_error_line(err)
    assert code == 2 and f"raised ValueError: no route at {policy}:{line_no}" in line, line  # file:line without --debug
    assert debug_code == code, debug_err[-3000:]
    assert f'File "{policy}", line {line_no}, in act' in debug_err, debug_err[-3000:]
    assert 'raise ValueError("no route")  # HERE' in debug_err
    assert debug_err.rstrip().splitlines()[-1] == line  # the same one line closes it
