"""Problems of a suite and the checker that collects them.

``Problem(file, field, expected, got)`` is one thing wrong in a suite;
``problems_error`` turns a list into one DriveE2EError line. ``Checker``
holds typed getters over JSON-shaped objects that record a Problem instead
of raising (``validate`` uses them); ``short``, ``json_kind``, ``is_int``,
``is_num``, ``join_path`` are the small helpers of its texts.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.origin import POSITION_BOUND, POSITION_TEXT

__all__ = [
    "SAFE_ID", "SAFE_ID_TEXT", "INT32_RANGE", "FLOAT32_MAX", "Problem", "problems_error", "Checker", "short", "json_kind", "is_int", "is_num",
    "join_path",
]

#: Integers are packed as int32 (``scenario.sizes.LEAVES``: num_steps, track ids,
#: signal groups); a value outside this range is refused, naming the range.
INT32_RANGE = (-(2**31), 2**31 - 1)
#: Every float is simulated as float32: a larger magnitude becomes inf.
FLOAT32_MAX = float(np.finfo(np.float32).max)
FLOAT32_TEXT = f"|value| <= {FLOAT32_MAX:.6g}, the float32 range the simulator computes in"

#: Scenario and map ids become file names: keep them portable.
SAFE_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")
SAFE_ID_TEXT = "an id of letters, digits, '_', '.', '-' (it names a file)"


# --------------------------------------------------------------------------
# Problems
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class Problem:
    """One thing wrong in a suite.

    Attributes:
      file:     path of the file relative to the suite folder (``scenarios/x.json``).
      field:    JSON path inside the file (``tracks[3].yaw[17]``); "" for the whole file.
      expected: what the field should be.
      got:      what it is (short), "" when not useful.
    """

    file: str
    field: str
    expected: str
    got: str = ""

    def __str__(self) -> str:
        where = f"{self.file}: {self.field}" if self.field else self.file
        got = f", got {self.got}" if self.got else ""
        return f"{where}: expected {self.expected}{got}"


def problems_error(problems: list[Problem], folder: str | os.PathLike | None = None) -> DriveE2EError:
    """One DriveE2EError line for a non-empty problem list: the first problem
    (its file under ``folder``) plus how many more there are."""
    first = problems[0]
    if folder is not None:
        first = Problem(f"{Path(folder) / first.file}", first.field, first.expected, first.got)
    more = ""
    if len(problems) > 1:
        target = f" {folder}" if folder is not None else ""
        more = f" (and {len(problems) - 1} more; run `drivee2e suite validate{target}`)"
    return DriveE2EError(f"{first}{more}")


def short(value: Any, limit: int = 60) -> str:
    if isinstance(value, str):
        text = repr(value)
    elif isinstance(value, (float, np.floating)):
        text = f"{float(value):.6g}"
    elif isinstance(value, (list, dict, tuple)):
        text = type(value).__name__ + (f" of {len(value)}" if hasattr(value, "__len__") else "")
    elif value is None:
        text = "null"
    elif isinstance(value, (bool, np.bool_)):
        text = "true" if value else "false"
    elif isinstance(value, int) and abs(value) >= 10**limit:  # str() of a 5000-digit int raises
        text = f"an integer of about {int((abs(value).bit_length() - 1) * 0.30103) + 1} digits"
    else:
        text = str(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def json_kind(value: Any) -> str:
    """The JSON type name of a value, for 'got' texts."""
    if value is None:
        return "null"
    if isinstance(value, (bool, np.bool_)):
        return f"boolean {short(value)}"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return f"number {short(value)}"
    if isinstance(value, str):
        return f"string {short(value)}"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "a list"
    return type(value).__name__


def is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def is_num(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def join_path(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


# --------------------------------------------------------------------------
# The checker: typed getters that record problems instead of raising
# --------------------------------------------------------------------------


class Checker:
    def __init__(self, file: str, problems: list[Problem]):
        self.file = file
        self.problems = problems

    def add(self, field: str, expected: str, got: str = "") -> None:
        self.problems.append(Problem(self.file, field, expected, got))

    def mark(self) -> int:
        return len(self.problems)

    def fields(self, obj: Any, path: str, required: tuple, optional: tuple = ()) -> bool:
        if not isinstance(obj, dict):
            self.add(path or "(top level)", "an object", json_kind(obj))
            return False
        for key in required:
            if key not in obj:
                self.add(join_path(path, key), "a value (the field is missing)")
        known = required + optional
        for key in obj:
            if key not in known:
                self.add(join_path(path, str(key)), f"one of the known fields ({', '.join(known)})", "an unknown field")
        return True

    def string(self, obj: dict, key: str, path: str, choices: tuple | None = None,
               pattern: re.Pattern | None = None, default: Any = None) -> str | None:
        if key not in obj:
            return default
        v, p = obj[key], join_path(path, key)
        if not isinstance(v, str):
            self.add(p, "a string" if choices is None else f"one of {', '.join(choices)}", json_kind(v))
            return None
        if choices is not None and v not in choices:
            self.add(p, f"one of {', '.join(choices)}", short(v))
            return None
        if pattern is not None and not pattern.match(v):
            self.add(p, SAFE_ID_TEXT, short(v))
            return None
        return v

    def integer(self, obj: dict, key: str, path: str, minimum: int | None = None,
                default: Any = None) -> int | None:
        if key not in obj:
            return default
        v, p = obj[key], join_path(path, key)
        low, high = INT32_RANGE
        low = low if minimum is None else max(low, minimum)
        if isinstance(v, (float, np.floating)) and np.isfinite(v) and float(v).is_integer() and not low <= v <= high:
            self.add(p, f"an integer in [{low}, {high}]", short(v))  # orjson reads integers beyond 64 bits as floats
            return None
        if not is_int(v):
            self.add(p, "an integer", json_kind(v))
            return None
        if not low <= v <= high:  # num_steps etc. are packed as int32: a 401-digit one overflowed numpy
            self.add(p, f"an integer in [{low}, {high}]", short(v))
            return None
        return int(v)

    def number(self, obj: dict, key: str, path: str, minimum: float | None = None,
               positive: bool = False, default: Any = None) -> float | None:
        if key not in obj:
            return default
        v, p = obj[key], join_path(path, key)
        if not is_num(v):
            self.add(p, "a number", json_kind(v))
            return None
        if is_int(v) and abs(v) > FLOAT32_MAX:  # float() of a 401-digit integer raises OverflowError
            self.add(p, f"a finite number, {FLOAT32_TEXT}", short(v))
            return None
        v = float(v)
        if not np.isfinite(v) or abs(v) > FLOAT32_MAX:
            self.add(p, f"a finite number, {FLOAT32_TEXT}", short(v))
            return None
        if positive and v <= 0:
            self.add(p, "a number > 0", short(v))
            return None
        if minimum is not None and v < minimum:
            self.add(p, f"a number >= {minimum:g}", short(v))
            return None
        return v

    def listing(self, obj: dict, key: str, path: str, default: Any = None) -> list | None:
        if key not in obj:
            return default
        v = obj[key]
        if not isinstance(v, (list, tuple)):
            self.add(join_path(path, key), "a list", json_kind(v))
            return None
        return list(v)

    def array(self, value: Any, path: str, cols: int | None = None, min_len: int = 0,
              length: int | None = None, minimum: float | None = None,
              position: bool = False) -> np.ndarray | None:
        """A float array of shape (n,) or (n, cols), finite, checked elementwise;
        ``position``: world coordinates, each within ``POSITION_BOUND`` m."""
        a = _as_numeric(value)
        if a is None or (a.ndim != (1 if cols is None else 2) and a.size > 0) or (
            cols is not None and a.ndim == 2 and a.shape[1] != cols
        ):
            want = ("a list of numbers" if cols is None else
                    "a list of [x, y] pairs" if cols == 2 else f"a list of {cols}-number lists")
            self.add(*_locate_bad(value, path, cols, want))
            return None
        if a.size == 0:
            a = a.reshape((0,) if cols is None else (0, cols))
        a = a.astype(np.float64, copy=False)
        if length is not None and len(a) != length:
            self.add(path, f"{length} numbers" if cols is None else f"{length} points", f"{len(a)}")
            return None
        if len(a) < min_len:
            self.add(path, f"at least {min_len} {'values' if cols is None else 'points'}", f"{len(a)}")
            return None
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(a) & (np.abs(a) <= FLOAT32_MAX)  # a position of 1e308 is inf in float32
        finite = ok if cols is None else ok.all(axis=1)
        if not finite.all():
            i = int(np.flatnonzero(~finite)[0])
            got = short(value[i]) if cols is None else "[" + ", ".join(short(float(x)) for x in a[i]) + "]"
            self.add(f"{path}[{i}]", f"finite numbers, {FLOAT32_TEXT}", got)
            return None
        if position:
            far = np.abs(a) > POSITION_BOUND if cols is None else (np.abs(a) > POSITION_BOUND).any(axis=1)
            if far.any():
                i = int(np.flatnonzero(far)[0])
                got = short(float(a[i])) if cols is None else "[" + ", ".join(short(float(x)) for x in a[i]) + "]"
                self.add(f"{path}[{i}]", POSITION_TEXT, got)
                return None
        if minimum is not None:
            low = a < minimum if cols is None else (a < minimum).any(axis=1)
            if low.any():
                i = int(np.flatnonzero(low)[0])
                self.add(f"{path}[{i}]", f"a number >= {minimum:g}", short(float(np.min(a[i]))))
                return None
        return a

    def flags(self, value: Any, path: str) -> np.ndarray | None:
        """A bool array given as true/false or 0/1."""
        try:
            a = np.asarray(value)
        except (TypeError, ValueError):
            a = None
        if a is not None and a.ndim == 1 and (a.dtype.kind == "b" or a.size == 0):
            return a.astype(bool)
        if a is not None and a.ndim == 1 and a.dtype.kind in "iu" and 0 <= a.min() and a.max() <= 1:
            return a.astype(bool)
        if not isinstance(value, (list, tuple, np.ndarray)):
            self.add(path, "a list of true/false (or 0/1)", json_kind(value))
            return None
        for i, v in enumerate(value):
            if not (isinstance(v, (bool, np.bool_)) or (is_int(v) and v in (0, 1))):
                self.add(f"{path}[{i}]", "true/false (or 0/1)", short(v))
                return None
        self.add(path, "a flat list of true/false (or 0/1)")
        return None

    def ints(self, value: Any, path: str, choices: range | None = None,
             choice_text: str = "") -> np.ndarray | None:
        """An int array (JSON integers only), optionally each in ``choices``."""
        try:
            a = np.asarray(value)
        except (TypeError, ValueError):
            a = None
        ok = a is not None and a.ndim == 1 and (a.dtype.kind in "iu" or a.size == 0)
        if ok and choices is not None and a.size and not ((a >= choices.start) & (a < choices.stop)).all():
            i = int(np.flatnonzero((a < choices.start) | (a >= choices.stop))[0])
            self.add(f"{path}[{i}]", choice_text or f"an integer in [{choices.start}, {choices.stop})", str(a[i]))
            return None
        if ok:
            return a.astype(np.int64)
        if not isinstance(value, (list, tuple, np.ndarray)):
            self.add(path, "a list of integers", json_kind(value))
            return None
        for i, v in enumerate(value):
            integral = is_int(v) or (isinstance(v, (float, np.floating)) and np.isfinite(v) and float(v).is_integer())
            if integral and not -(2**63) <= v < 2**63:  # numpy keeps it as an object; orjson reads it as a float
                self.add(f"{path}[{i}]", choice_text or f"an integer in [{-(2**63)}, {2**63 - 1}]", short(v))
                return None
            if not is_int(v):
                self.add(f"{path}[{i}]", choice_text or "an integer", short(v))
                return None
        self.add(path, "a flat list of integers")
        return None


def _as_numeric(value: Any) -> np.ndarray | None:
    if isinstance(value, (str, bytes, dict)) or value is None:
        return None
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):
        return None
    if a.size == 0 and a.dtype.kind in "fiuO":
        return a.astype(np.float64) if a.dtype.kind != "O" else np.zeros((0,))
    if a.dtype.kind not in "fiu":
        return None
    return a


def _locate_bad(value: Any, path: str, cols: int | None, want: str) -> tuple[str, str, str]:
    """(field, expected, got) for the first element that spoils an array."""
    if not isinstance(value, (list, tuple, np.ndarray)):
        return path, want, json_kind(value)
    if isinstance(value, np.ndarray):
        return path, want, f"array of shape {value.shape}"
    for i, v in enumerate(value):
        if cols is None:
            if not is_num(v):
                return f"{path}[{i}]", "a number", json_kind(v)
            if is_int(v) and abs(v) > FLOAT32_MAX:  # numpy keeps a 401-digit integer as an object
                return f"{path}[{i}]", f"a finite number, {FLOAT32_TEXT}", short(v)
        else:
            if not isinstance(v, (list, tuple, np.ndarray)) or len(v) != cols:
                return f"{path}[{i}]", f"a list of {cols} numbers", json_kind(v) if not isinstance(v, (list, tuple)) else f"{len(v)} values"
            for j, e in enumerate(v):
                if not is_num(e):
                    return f"{path}[{i}][{j}]", "a number", json_kind(e)
                if is_int(e) and abs(e) > FLOAT32_MAX:
                    return f"{path}[{i}][{j}]", f"a finite number, {FLOAT32_TEXT}", short(e)
    return path, want, ""
