"""The guarded JSON reader: every way ``json.loads`` fails is one BadJSON line
naming the file, the place and what was expected."""

from __future__ import annotations

import sys

import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.jsonfile import BadJSON, parse_json, read_json

LIMIT = sys.get_int_max_str_digits()


def test_values_are_json_values(tmp_path):
    f = tmp_path / "a.json"
    f.write_text('{"x": [1, 2.5, null, true], "big": ' + "9" * 30 + ', "nan": NaN}')
    got = read_json(f)
    assert got["x"] == [1, 2.5, None, True] and got["big"] == int("9" * 30) and got["nan"] != got["nan"]


def test_a_number_longer_than_python_converts_is_one_line(tmp_path):
    """The user's report: a 5001-digit integer raised ValueError deep inside json."""
    f = tmp_path / "scenario.json"
    f.write_text('{\n "num_steps": ' + "7" * 5001 + "\n}")
    with pytest.raises(BadJSON) as err:
        read_json(f)
    e = err.value
    assert isinstance(e, DriveE2EError) and "\n" not in str(e)
    assert str(e).startswith(f"{f}: line 2 column 15: expected a number with at most {LIMIT} digits")
    assert f"got a number with more than {LIMIT} digits (5001)" in str(e)
    assert (e.where, e.got) == ("line 2 column 15", f"a number with more than {LIMIT} digits (5001)")
    assert str(e) == f"{f}: {e.detail}" and e.detail.startswith("line 2 column 15: expected a number with at most")


def test_nesting_deeper_than_the_recursion_limit_is_one_line():
    with pytest.raises(BadJSON, match=r"^suite.json: expected valid JSON, got arrays / objects nested too deep"):
        parse_json("[" * 200_000 + "]" * 200_000, "suite.json")


def test_invalid_json_and_non_utf8_name_the_place():
    with pytest.raises(BadJSON, match=r"^x.json: line 2 column 1: expected valid JSON, got Expecting value"):
        parse_json(b'{"a":\n}', "x.json")
    with pytest.raises(BadJSON, match=r"^x.json: expected UTF-8 text, got byte 2 undecodable"):
        parse_json(b'"a\xff"', "x.json")


def test_a_missing_file_is_left_to_the_caller(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_json(tmp_path / "nope.json")
