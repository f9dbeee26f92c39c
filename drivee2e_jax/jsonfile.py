"""Reading the JSON files users hand drivee2e, guarded: a refusal is one line.

``json.loads`` fails in more ways than ``JSONDecodeError``: a number with
more than ``sys.get_int_max_str_digits()`` (4300) digits raises a plain
ValueError deep inside the decoder, and arrays nested deeper than Python's
recursion limit (a 200,000-deep ``[[[...]]]``) raise RecursionError; a file
that is not UTF-8 raises UnicodeDecodeError. :func:`parse_json` and
:func:`read_json` turn each into :class:`BadJSON`, a one-line
``DriveE2EError`` naming the file, the place and what was expected, whose
parts (``where``, ``expected``, ``got``) also serve callers that collect
problems (``scenario.schema``). An object that repeats a key is refused too
(``"ego_track_id": 1, "ego_track_id": 4`` would silently keep the last): the
parsing is ``files.loads_json``'s (orjson, 5x json's speed on a twin15
scenario file; the keys it parsed counted against the text's colons; the
standard library parses again on a mismatch or whatever orjson refuses, so
values and errors are json's), and this module turns its exceptions into
:class:`BadJSON`. Every reader of suite.json, scenario and map files,
results files and policy / config JSON goes through here
(``files.loads_json`` / ``read_json`` are the same parse without the
one-line messages, for drivee2e's own files).
"""

from __future__ import annotations

import json
import os
import re
import sys
from typing import Any

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import DuplicateKeyError, loads_json

__all__ = ["BadJSON", "parse_json", "read_json"]


class BadJSON(DriveE2EError):
    """A JSON file drivee2e cannot read. ``str``: ``NAME: [WHERE: ]expected
    EXPECTED, got GOT``; the parts are attributes (``where`` is "" or
    ``line L column C``)."""

    def __init__(self, name: str, where: str, expected: str, got: str):
        self.name, self.where, self.expected, self.got = str(name), where, expected, got
        super().__init__(f"{name}: {self.detail}")

    @property
    def reason(self) -> str:
        """``detail`` (the name ``files.JSONFileError`` gives it)."""
        return self.detail

    @property
    def detail(self) -> str:
        """The message without the file name: ``[WHERE: ]expected ..., got ...``
        (for callers that say what the file is: ``FILE: unreadable manifest (DETAIL)``)."""
        return f"{self.where + ': ' if self.where else ''}expected {self.expected}, got {self.got}"


def parse_json(data: bytes | bytearray | memoryview | str, name: str = "JSON text") -> Any:
    """The value of JSON ``data``; :class:`BadJSON` (naming ``name``) when it
    is not UTF-8, not JSON, holds a number with more digits than Python
    converts, or nests deeper than the decoder's recursion limit."""
    try:
        return loads_json(data)  # orjson, a repeated key an error; the standard library's values and errors
    except UnicodeDecodeError as e:
        raise BadJSON(name, "", "UTF-8 text", f"byte {e.start} undecodable ({e.reason})") from None
    except DuplicateKeyError as e:
        raise BadJSON(name, "", "each key once per object", f"duplicate key {e.key!r}") from None
    except json.JSONDecodeError as e:
        raise BadJSON(name, f"line {e.lineno} column {e.colno}", "valid JSON", e.msg) from None
    except RecursionError:
        raise BadJSON(name, "", "valid JSON", f"arrays / objects nested too deep to read (deeper than Python's "
                                              f"recursion limit, {sys.getrecursionlimit()})") from None
    except ValueError as e:  # "Exceeds the limit (4300 digits) for integer string conversion"
        digits = _long_number(data if isinstance(data, str) else bytes(data).decode("utf-8"))
        if digits is None:
            raise BadJSON(name, "", "valid JSON", str(e).split(";")[0]) from None
        limit, (line, col, n) = sys.get_int_max_str_digits(), digits
        raise BadJSON(name, f"line {line} column {col}",
                      f"a number with at most {limit} digits (Python's integer-string conversion limit)",
                      f"a number with more than {limit} digits ({n})") from None


def read_json(path: str | os.PathLike, name: str | None = None) -> Any:
    """The JSON value of the file ``path``; :class:`BadJSON` naming ``name``
    (default: the path) when it cannot be read as JSON. OSError (a missing or
    unreadable file) is left to the caller."""
    with open(path, "rb") as f:
        data = f.read()
    return parse_json(data, str(path) if name is None else name)


def _long_number(text: str) -> tuple[int, int, int] | None:
    """(line, column, digits) of the first run of digits longer than the
    int-string conversion limit, or None."""
    limit = sys.get_int_max_str_digits()
    if not limit:
        return None
    m = re.search(r"\d{" + str(limit + 1) + ",}", text)
    if m is None:
        return None
    line = text.count("\n", 0, m.start()) + 1
    col = m.start() - (text.rfind("\n", 0, m.start()) + 1) + 1
    return line, col, len(m.group())
