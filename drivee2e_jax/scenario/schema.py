"""The on-disk suite format: JSON read/write and validation of suite folders.

A suite folder::

    suite.json            {"name", "version", "schema_version", "meta",
                           "scenarios": [{"id", "split", "intersection_id", "behavior"}]}
    maps/<map_id>.json    one MapRecord
    scenarios/<id>.json   one ScenarioRecord

The JSON keys are the field names of ``scenario.records``, with two changes
that keep files compact: a track is stored column-wise (``t, x, y, yaw`` and
the optional ``vx, vy, visible, quality`` lists; velocity and flags are absent
when the record has none), and signal states are lists of ``SIGNAL_STATES``
indices (0 unknown, 1 red, 2 yellow, 3 green) keyed by signal group.
Flags are written as 0/1. Floats are rounded (1 mm, 1 mm/s, 1e-4 rad,
1e-4 s) and every file is written in a fixed layout, so the same suite always
gives the same bytes.

Validation collects *every* problem in a folder (:func:`validate_suite`), each
naming the file, the JSON path of the field (``tracks[3].yaw[17]``) and what
was expected. :func:`read_suite` raises one :class:`DriveE2EError` line for the
first problem and says how many more there are.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.progress import progress as progress_bar
from drivee2e_jax.records import (
    BEHAVIORS,
    CATEGORIES,
    LANE_TYPES,
    MARKINGS,
    SCHEMA_VERSION,
    SIGNAL_STATES,
    SPLITS,
    TIMES_OF_DAY,
    WEATHERS,
    BoundaryRecord,
    LaneRecord,
    MapRecord,
    ObstacleRecord,
    RouteRecord,
    ScenarioRecord,
    SignalPhase,
    StopLineRecord,
    SuiteRecord,
    TrackRecord,
)

__all__ = [
    "Problem",
    "read_suite",
    "write_suite",
    "validate_suite",
    "validate_records",
    "problems_error",
    "GRID_TOLERANCE_S",
]

#: A timestamp is "on the grid" when it is within this of some ``k * dt``.
GRID_TOLERANCE_S = 1e-3

#: Scenario and map ids become file names: keep them portable.
_SAFE_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]*$")
_SAFE_ID_TEXT = "an id of letters, digits, '_', '.', '-' (it names a file)"

# Decimal places per JSON key when writing (1 mm, 1 mm/s, 1e-4 rad, 1e-4 s).
_DECIMALS = {
    "t": 4, "x": 3, "y": 3, "yaw": 4, "vx": 3, "vy": 3, "size": 3,
    "waypoints": 3, "source": 3, "destination": 3,
    "centerline": 3, "width": 3, "speed_limit": 3, "points": 3, "polygon": 3,
    "height": 3, "crosswalks": 3, "drivable_areas": 3,
    "duration": 3, "yellow_duration": 3, "all_red": 3, "dt": 6,
}


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


def _short(value: Any, limit: int = 60) -> str:
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
    else:
        text = str(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _kind(value: Any) -> str:
    """The JSON type name of a value, for 'got' texts."""
    if value is None:
        return "null"
    if isinstance(value, (bool, np.bool_)):
        return f"boolean {_short(value)}"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return f"number {_short(value)}"
    if isinstance(value, str):
        return f"string {_short(value)}"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "a list"
    return type(value).__name__


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


# --------------------------------------------------------------------------
# The checker: typed getters that record problems instead of raising
# --------------------------------------------------------------------------


class _Checker:
    def __init__(self, file: str, problems: list[Problem]):
        self.file = file
        self.problems = problems

    def add(self, field: str, expected: str, got: str = "") -> None:
        self.problems.append(Problem(self.file, field, expected, got))

    def mark(self) -> int:
        return len(self.problems)

    def fields(self, obj: Any, path: str, required: tuple, optional: tuple = ()) -> bool:
        if not isinstance(obj, dict):
            self.add(path or "(top level)", "an object", _kind(obj))
            return False
        for key in required:
            if key not in obj:
                self.add(_join(path, key), "a value (the field is missing)")
        known = required + optional
        for key in obj:
            if key not in known:
                self.add(_join(path, str(key)), f"one of the known fields ({', '.join(known)})", "an unknown field")
        return True

    def string(self, obj: dict, key: str, path: str, choices: tuple | None = None,
               pattern: re.Pattern | None = None, default: Any = None) -> str | None:
        if key not in obj:
            return default
        v, p = obj[key], _join(path, key)
        if not isinstance(v, str):
            self.add(p, "a string" if choices is None else f"one of {', '.join(choices)}", _kind(v))
            return None
        if choices is not None and v not in choices:
            self.add(p, f"one of {', '.join(choices)}", _short(v))
            return None
        if pattern is not None and not pattern.match(v):
            self.add(p, _SAFE_ID_TEXT, _short(v))
            return None
        return v

    def integer(self, obj: dict, key: str, path: str, minimum: int | None = None,
                default: Any = None) -> int | None:
        if key not in obj:
            return default
        v, p = obj[key], _join(path, key)
        if not _is_int(v):
            self.add(p, "an integer", _kind(v))
            return None
        if minimum is not None and v < minimum:
            self.add(p, f"an integer >= {minimum}", str(v))
            return None
        return int(v)

    def number(self, obj: dict, key: str, path: str, minimum: float | None = None,
               positive: bool = False, default: Any = None) -> float | None:
        if key not in obj:
            return default
        v, p = obj[key], _join(path, key)
        if not _is_num(v):
            self.add(p, "a number", _kind(v))
            return None
        v = float(v)
        if not np.isfinite(v):
            self.add(p, "a finite number", _short(v))
            return None
        if positive and v <= 0:
            self.add(p, "a number > 0", _short(v))
            return None
        if minimum is not None and v < minimum:
            self.add(p, f"a number >= {minimum:g}", _short(v))
            return None
        return v

    def listing(self, obj: dict, key: str, path: str, default: Any = None) -> list | None:
        if key not in obj:
            return default
        v = obj[key]
        if not isinstance(v, (list, tuple)):
            self.add(_join(path, key), "a list", _kind(v))
            return None
        return list(v)

    def array(self, value: Any, path: str, cols: int | None = None, min_len: int = 0,
              length: int | None = None, minimum: float | None = None) -> np.ndarray | None:
        """A float array of shape (n,) or (n, cols), finite, checked elementwise."""
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
        finite = np.isfinite(a) if cols is None else np.isfinite(a).all(axis=1)
        if not finite.all():
            i = int(np.flatnonzero(~finite)[0])
            self.add(f"{path}[{i}]", "finite numbers", _short(value[i] if cols is None else list(np.asarray(a[i]).tolist())))
            return None
        if minimum is not None:
            low = a < minimum if cols is None else (a < minimum).any(axis=1)
            if low.any():
                i = int(np.flatnonzero(low)[0])
                self.add(f"{path}[{i}]", f"a number >= {minimum:g}", _short(float(np.min(a[i]))))
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
            self.add(path, "a list of true/false (or 0/1)", _kind(value))
            return None
        for i, v in enumerate(value):
            if not (isinstance(v, (bool, np.bool_)) or (_is_int(v) and v in (0, 1))):
                self.add(f"{path}[{i}]", "true/false (or 0/1)", _short(v))
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
            self.add(path, "a list of integers", _kind(value))
            return None
        for i, v in enumerate(value):
            if not _is_int(v):
                self.add(f"{path}[{i}]", choice_text or "an integer", _short(v))
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
        return path, want, _kind(value)
    if isinstance(value, np.ndarray):
        return path, want, f"array of shape {value.shape}"
    for i, v in enumerate(value):
        if cols is None:
            if not _is_num(v):
                return f"{path}[{i}]", "a number", _kind(v)
        else:
            if not isinstance(v, (list, tuple, np.ndarray)) or len(v) != cols:
                return f"{path}[{i}]", f"a list of {cols} numbers", _kind(v) if not isinstance(v, (list, tuple)) else f"{len(v)} values"
            for j, e in enumerate(v):
                if not _is_num(e):
                    return f"{path}[{i}][{j}]", "a number", _kind(e)
    return path, want, ""


# --------------------------------------------------------------------------
# Record checks on JSON-shaped objects (lists from files or numpy from records)
# --------------------------------------------------------------------------

_SUITE_REQ = ("name", "version", "schema_version", "scenarios")
_SUITE_OPT = ("meta",)
_ENTRY_REQ = ("id", "split", "intersection_id", "behavior")
_SCEN_REQ = ("scenario_id", "split", "intersection_id", "map_id", "behavior", "weather",
             "time_of_day", "ego_track_id", "dt", "num_steps", "route", "tracks")
_SCEN_OPT = ("schema_version", "signals")
_TRACK_REQ = ("track_id", "category", "size", "t", "x", "y", "yaw")
_TRACK_OPT = ("vx", "vy", "visible", "quality")
_ROUTE_REQ = ("waypoints", "source", "destination")
_MAP_REQ = ("map_id", "lanes")
_MAP_OPT = ("schema_version", "boundaries", "crosswalks", "stop_lines", "drivable_areas",
            "obstacles", "signal_plan", "meta")
_LANE_REQ = ("id", "centerline")
_LANE_OPT = ("width", "speed_limit", "type", "successors", "left_marking", "right_marking")
_SIGNAL_TEXT = "a signal state index: " + ", ".join(f"{i}={n}" for i, n in enumerate(SIGNAL_STATES))


def _check_schema_version(c: _Checker, obj: dict) -> None:
    if "schema_version" not in obj:
        return
    v = obj["schema_version"]
    if not _is_int(v) or v != SCHEMA_VERSION:
        c.add("schema_version", f"{SCHEMA_VERSION} (the schema version this drivee2e reads)", _short(v))


def _check_suite_json(obj: Any, c: _Checker) -> tuple[dict, list[dict]] | None:
    """Returns (header, entries) with entries [{id, split, intersection_id, behavior, row}]."""
    mark = c.mark()
    if not c.fields(obj, "", _SUITE_REQ, _SUITE_OPT):
        return None
    name = c.string(obj, "name", "")
    version = obj.get("version")
    if "version" in obj and not isinstance(version, str):
        if _is_num(version):
            version = str(version)
        else:
            c.add("version", "a string", _kind(version))
    _check_schema_version(c, obj)
    meta = obj.get("meta", {})
    if not isinstance(meta, dict):
        c.add("meta", "an object", _kind(meta))
    entries: list[dict] = []
    listed = c.listing(obj, "scenarios", "")
    seen: dict[str, int] = {}
    for i, e in enumerate(listed or []):
        p = f"scenarios[{i}]"
        m = c.mark()
        if not c.fields(e, p, _ENTRY_REQ):
            continue
        sid = c.string(e, "id", p, pattern=_SAFE_ID)
        split = c.string(e, "split", p, choices=SPLITS)
        inter = c.string(e, "intersection_id", p)
        beh = c.string(e, "behavior", p, choices=BEHAVIORS)
        if sid is not None and sid in seen:
            c.add(f"{p}.id", "a unique scenario id", f"{sid!r} (also scenarios[{seen[sid]}])")
            continue
        if sid is not None:
            seen[sid] = i
        if c.mark() == m:
            entries.append({"id": sid, "split": split, "intersection_id": inter, "behavior": beh, "row": i})
    if listed is not None and not listed:
        c.add("scenarios", "at least one scenario", "an empty list")
    if c.mark() > mark:
        return None
    return {"name": name, "version": version, "meta": meta}, entries


def _check_track(obj: Any, p: str, c: _Checker, dt: float | None, num_steps: int | None) -> TrackRecord | None:
    mark = c.mark()
    if not c.fields(obj, p, _TRACK_REQ, _TRACK_OPT):
        return None
    tid = c.integer(obj, "track_id", p)
    cat = c.string(obj, "category", p, choices=CATEGORIES)
    size = c.array(obj["size"], _join(p, "size"), length=3, minimum=0.0) if "size" in obj else None
    cols = {}
    for key in ("t", "x", "y", "yaw", "vx", "vy"):
        if key in obj:
            cols[key] = c.array(obj[key], _join(p, key))
    for key in ("visible", "quality"):
        if key in obj:
            cols[key] = c.flags(obj[key], _join(p, key))
    if ("vx" in obj) != ("vy" in obj):
        missing = "vy" if "vx" in obj else "vx"
        c.add(_join(p, missing), "vx and vy together (or neither)", "missing")
    t = cols.get("t")
    if t is not None:
        if len(t) == 0:
            c.add(_join(p, "t"), "at least one sample", "an empty list")
        for key, a in cols.items():
            if key != "t" and a is not None and len(a) != len(t):
                c.add(_join(p, key), f"{len(t)} values (as many as t)", f"{len(a)}")
        if dt is not None and num_steps is not None and len(t):
            _check_times(t, _join(p, "t"), c, dt, num_steps)
    if c.mark() > mark:
        return None
    vel = None if "vx" not in obj else np.stack([cols["vx"], cols["vy"]], axis=1)
    return TrackRecord(
        track_id=tid, category=cat, size=size, t=t, xy=np.stack([cols["x"], cols["y"]], axis=1),
        yaw=cols["yaw"], vel=vel, visible=cols.get("visible"), quality=cols.get("quality"),
    )


def _check_times(t: np.ndarray, p: str, c: _Checker, dt: float, num_steps: int) -> None:
    k = np.rint(t / dt)
    off = np.abs(t - k * dt) > GRID_TOLERANCE_S
    if off.any():
        i = int(np.flatnonzero(off)[0])
        c.add(f"{p}[{i}]", f"a multiple of dt={dt:g} s (within {GRID_TOLERANCE_S * 1e3:g} ms)", _short(t[i]))
        return
    if len(t) > 1:
        bad = np.diff(k) <= 0
        if bad.any():
            i = int(np.flatnonzero(bad)[0]) + 1
            c.add(f"{p}[{i}]", "increasing timestamps", f"{t[i]:.6g} after {t[i - 1]:.6g}")
            return
    if k[0] < 0:
        c.add(f"{p}[0]", "a time >= 0", _short(t[0]))
    if k[-1] >= num_steps:
        i = int(np.flatnonzero(k >= num_steps)[0])
        c.add(f"{p}[{i}]", f"a time <= {(num_steps - 1) * dt:.6g} s (num_steps={num_steps}, dt={dt:g})", _short(t[i]))


def _check_route(obj: Any, p: str, c: _Checker) -> RouteRecord | None:
    mark = c.mark()
    if not c.fields(obj, p, _ROUTE_REQ):
        return None
    wp = c.array(obj["waypoints"], _join(p, "waypoints"), cols=2, min_len=2) if "waypoints" in obj else None
    src = c.array(obj["source"], _join(p, "source"), length=2) if "source" in obj else None
    dst = c.array(obj["destination"], _join(p, "destination"), length=2) if "destination" in obj else None
    if c.mark() > mark:
        return None
    return RouteRecord(waypoints=wp, source=src, destination=dst)


def _check_scenario(obj: Any, c: _Checker) -> ScenarioRecord | None:
    mark = c.mark()
    if not c.fields(obj, "", _SCEN_REQ, _SCEN_OPT):
        return None
    _check_schema_version(c, obj)
    sid = c.string(obj, "scenario_id", "", pattern=_SAFE_ID)
    split = c.string(obj, "split", "", choices=SPLITS)
    inter = c.string(obj, "intersection_id", "")
    map_id = c.string(obj, "map_id", "", pattern=_SAFE_ID)
    beh = c.string(obj, "behavior", "", choices=BEHAVIORS)
    weather = c.string(obj, "weather", "", choices=WEATHERS)
    tod = c.string(obj, "time_of_day", "", choices=TIMES_OF_DAY)
    ego = c.integer(obj, "ego_track_id", "")
    dt = c.number(obj, "dt", "", positive=True)
    num_steps = c.integer(obj, "num_steps", "", minimum=1)
    route = _check_route(obj["route"], "route", c) if "route" in obj else None

    tracks: list[TrackRecord] = []
    seen: dict[int, int] = {}
    for i, tobj in enumerate(c.listing(obj, "tracks", "") or []):
        tr = _check_track(tobj, f"tracks[{i}]", c, dt, num_steps)
        if tr is None:
            continue
        if tr.track_id in seen:
            c.add(f"tracks[{i}].track_id", "a unique track id", f"{tr.track_id} (also tracks[{seen[tr.track_id]}])")
            continue
        seen[tr.track_id] = i
        tracks.append(tr)
    if "tracks" in obj and isinstance(obj["tracks"], list) and not obj["tracks"]:
        c.add("tracks", "at least one track (the ego)", "an empty list")
    raw_ids = {t["track_id"] for t in obj.get("tracks") or [] if isinstance(t, dict) and _is_int(t.get("track_id"))}
    if ego is not None and isinstance(obj.get("tracks"), list) and ego not in raw_ids:
        ids = sorted(raw_ids)
        shown = ", ".join(map(str, ids[:12])) + (", ..." if len(ids) > 12 else "")
        c.add("ego_track_id", f"one of the track ids ({shown})", str(ego))

    signals: dict[int, np.ndarray] = {}
    sig = obj.get("signals", {})
    if not isinstance(sig, dict):
        c.add("signals", "an object {signal group: [states]}", _kind(sig))
        sig = {}
    for key, states in sig.items():
        p = f'signals["{key}"]'
        try:
            group = int(key)
        except (TypeError, ValueError):
            c.add(p, "an integer signal group as key", _short(key))
            continue
        a = c.ints(states, p, choices=range(len(SIGNAL_STATES)), choice_text=_SIGNAL_TEXT)
        if a is None:
            continue
        if num_steps is not None and len(a) != num_steps:
            c.add(p, f"{num_steps} states (one per log step, num_steps)", f"{len(a)}")
            continue
        signals[group] = a.astype(np.int8)
    if c.mark() > mark:
        return None
    return ScenarioRecord(
        scenario_id=sid, split=split, intersection_id=inter, map_id=map_id, behavior=beh,
        weather=weather, time_of_day=tod, ego_track_id=ego, route=route, dt=dt,
        num_steps=num_steps, tracks=tracks, signals=signals,
    )


def _polygons(obj: dict, key: str, c: _Checker, min_len: int) -> list[np.ndarray]:
    out = []
    for i, poly in enumerate(c.listing(obj, key, "", default=[]) or []):
        a = c.array(poly, f"{key}[{i}]", cols=2, min_len=min_len)
        if a is not None:
            out.append(a)
    return out


def _check_map(obj: Any, c: _Checker) -> MapRecord | None:
    mark = c.mark()
    if not c.fields(obj, "", _MAP_REQ, _MAP_OPT):
        return None
    _check_schema_version(c, obj)
    map_id = c.string(obj, "map_id", "", pattern=_SAFE_ID)

    lanes: list[LaneRecord] = []
    lane_ids: dict[int, int] = {}
    successor_refs: list[tuple[str, int]] = []
    for i, lobj in enumerate(c.listing(obj, "lanes", "") or []):
        p = f"lanes[{i}]"
        m = c.mark()
        if not c.fields(lobj, p, _LANE_REQ, _LANE_OPT):
            continue
        lid = c.integer(lobj, "id", p)
        cl = c.array(lobj["centerline"], _join(p, "centerline"), cols=2, min_len=2) if "centerline" in lobj else None
        width = c.number(lobj, "width", p, minimum=0.0, default=LaneRecord.width)
        speed = c.number(lobj, "speed_limit", p, minimum=0.0, default=LaneRecord.speed_limit)
        ltype = c.string(lobj, "type", p, choices=LANE_TYPES, default=LaneRecord.type)
        succ = c.ints(lobj["successors"], _join(p, "successors")) if "successors" in lobj else np.zeros(0, np.int64)
        left = c.string(lobj, "left_marking", p, choices=MARKINGS, default=LaneRecord.left_marking)
        right = c.string(lobj, "right_marking", p, choices=MARKINGS, default=LaneRecord.right_marking)
        if lid is not None and lid in lane_ids:
            c.add(_join(p, "id"), "a unique lane id", f"{lid} (also lanes[{lane_ids[lid]}])")
            continue
        if lid is not None:
            lane_ids[lid] = i
        if c.mark() > m:
            continue
        successor_refs += [(f"{p}.successors[{j}]", int(s)) for j, s in enumerate(succ)]
        lanes.append(LaneRecord(id=lid, centerline=cl, width=width, speed_limit=speed, type=ltype,
                                successors=[int(s) for s in succ], left_marking=left, right_marking=right))
    ids_text = _ids_text(lane_ids)
    for p, s in successor_refs:
        if s not in lane_ids:
            c.add(p, f"a lane id of this map ({ids_text})", str(s))

    boundaries = []
    for i, bobj in enumerate(c.listing(obj, "boundaries", "", default=[]) or []):
        p = f"boundaries[{i}]"
        if not c.fields(bobj, p, ("points", "marking")):
            continue
        pts = c.array(bobj["points"], _join(p, "points"), cols=2, min_len=2) if "points" in bobj else None
        mk = c.string(bobj, "marking", p, choices=MARKINGS)
        if pts is not None and mk is not None:
            boundaries.append(BoundaryRecord(points=pts, marking=mk))

    crosswalks = _polygons(obj, "crosswalks", c, 3)
    drivable = _polygons(obj, "drivable_areas", c, 3)

    stop_lines = []
    stop_ids: dict[int, int] = {}
    for i, sobj in enumerate(c.listing(obj, "stop_lines", "", default=[]) or []):
        p = f"stop_lines[{i}]"
        m = c.mark()
        if not c.fields(sobj, p, ("id", "points", "lane_id", "signal_group")):
            continue
        sid = c.integer(sobj, "id", p)
        pts = c.array(sobj["points"], _join(p, "points"), cols=2, length=2) if "points" in sobj else None
        lane_id = c.integer(sobj, "lane_id", p)
        group = c.integer(sobj, "signal_group", p, minimum=-1)
        if lane_id is not None and lane_id != -1 and lane_id not in lane_ids:
            c.add(_join(p, "lane_id"), f"-1 or a lane id of this map ({ids_text})", str(lane_id))
        if sid is not None and sid in stop_ids:
            c.add(_join(p, "id"), "a unique stop line id", f"{sid} (also stop_lines[{stop_ids[sid]}])")
        elif sid is not None:
            stop_ids[sid] = i
        if c.mark() == m:
            stop_lines.append(StopLineRecord(id=sid, points=pts, lane_id=lane_id, signal_group=group))

    obstacles = []
    for i, oobj in enumerate(c.listing(obj, "obstacles", "", default=[]) or []):
        p = f"obstacles[{i}]"
        m = c.mark()
        if not c.fields(oobj, p, ("polygon", "height"), ("kind",)):
            continue
        poly = c.array(oobj["polygon"], _join(p, "polygon"), cols=2, min_len=3) if "polygon" in oobj else None
        height = c.number(oobj, "height", p, minimum=0.0)
        kind = c.string(oobj, "kind", p, default=ObstacleRecord.kind)
        if c.mark() == m:
            obstacles.append(ObstacleRecord(polygon=poly, height=height, kind=kind))

    plan = []
    for i, pobj in enumerate(c.listing(obj, "signal_plan", "", default=[]) or []):
        p = f"signal_plan[{i}]"
        m = c.mark()
        if not c.fields(pobj, p, ("duration", "green"), ("yellow_duration", "all_red")):
            continue
        dur = c.number(pobj, "duration", p, positive=True)
        green = c.ints(pobj["green"], _join(p, "green")) if "green" in pobj else None
        yellow = c.number(pobj, "yellow_duration", p, minimum=0.0, default=SignalPhase.yellow_duration)
        all_red = c.number(pobj, "all_red", p, minimum=0.0, default=SignalPhase.all_red)
        if c.mark() == m:
            plan.append(SignalPhase(duration=dur, green=[int(g) for g in green], yellow_duration=yellow, all_red=all_red))

    meta = obj.get("meta", {})
    if not isinstance(meta, dict):
        c.add("meta", "an object", _kind(meta))
    if c.mark() > mark:
        return None
    return MapRecord(map_id=map_id, lanes=lanes, boundaries=boundaries, crosswalks=crosswalks,
                     stop_lines=stop_lines, drivable_areas=drivable, obstacles=obstacles,
                     signal_plan=plan, meta=dict(meta))


def _ids_text(ids: Iterable[int], limit: int = 12) -> str:
    ids = sorted(ids)
    return ", ".join(map(str, ids[:limit])) + (", ..." if len(ids) > limit else "") if ids else "none"


def _check_cross(obj: Any, c: _Checker, entry: dict | None, map_ids: Iterable[str]) -> None:
    """Checks against other files: the scenario file says what suite.json
    says about it, and its map exists."""
    if not isinstance(obj, dict):
        return
    if entry is not None:
        for key, value in (("scenario_id", entry["id"]), ("split", entry["split"]),
                           ("intersection_id", entry["intersection_id"]), ("behavior", entry["behavior"])):
            got = obj.get(key)
            allowed = {"split": SPLITS, "behavior": BEHAVIORS}.get(key)
            if isinstance(got, str) and got != value and (allowed is None or got in allowed):
                c.add(key, f"{value!r} as listed in suite.json (scenarios[{entry['row']}])", repr(got))
    map_id = obj.get("map_id")
    map_ids = sorted(map_ids)
    if isinstance(map_id, str) and map_id not in map_ids:
        c.add("map_id", f"one of the suite's maps ({', '.join(map_ids) or 'none: maps/ is empty'})", repr(map_id))


# --------------------------------------------------------------------------
# Records -> JSON-shaped objects
# --------------------------------------------------------------------------


def _track_obj(tr: TrackRecord) -> dict:
    xy = np.asarray(tr.xy)
    x, y = (xy[:, 0], xy[:, 1]) if xy.ndim == 2 and xy.shape[1] == 2 else (xy, xy)
    out = {"track_id": tr.track_id, "category": tr.category, "size": np.asarray(tr.size),
           "t": np.asarray(tr.t), "x": x, "y": y, "yaw": np.asarray(tr.yaw)}
    if tr.vel is not None:
        vel = np.asarray(tr.vel)
        out["vx"], out["vy"] = (vel[:, 0], vel[:, 1]) if vel.ndim == 2 and vel.shape[1] == 2 else (vel, vel)
    if tr.visible is not None:
        out["visible"] = np.asarray(tr.visible)
    if tr.quality is not None:
        out["quality"] = np.asarray(tr.quality)
    return out


def _group_key(item: tuple) -> tuple:
    k = item[0]
    return (0, int(k), "") if _is_int(k) else (1, 0, str(k))


def _scenario_obj(s: ScenarioRecord) -> dict:
    r = s.route
    return {
        "schema_version": SCHEMA_VERSION,
        "scenario_id": s.scenario_id, "split": s.split, "intersection_id": s.intersection_id,
        "map_id": s.map_id, "behavior": s.behavior, "weather": s.weather, "time_of_day": s.time_of_day,
        "ego_track_id": s.ego_track_id, "dt": s.dt, "num_steps": s.num_steps,
        "route": {"waypoints": np.asarray(r.waypoints), "source": np.asarray(r.source),
                  "destination": np.asarray(r.destination)} if isinstance(r, RouteRecord) else r,
        "signals": {str(g): np.asarray(a) for g, a in sorted(s.signals.items(), key=_group_key)},
        "tracks": [_track_obj(t) for t in s.tracks],
    }


def _map_obj(m: MapRecord) -> dict:
    return {
        "schema_version": SCHEMA_VERSION,
        "map_id": m.map_id,
        "lanes": [{"id": ln.id, "centerline": np.asarray(ln.centerline), "width": ln.width,
                   "speed_limit": ln.speed_limit, "type": ln.type, "successors": list(ln.successors),
                   "left_marking": ln.left_marking, "right_marking": ln.right_marking} for ln in m.lanes],
        "boundaries": [{"points": np.asarray(b.points), "marking": b.marking} for b in m.boundaries],
        "crosswalks": [np.asarray(p) for p in m.crosswalks],
        "stop_lines": [{"id": s.id, "points": np.asarray(s.points), "lane_id": s.lane_id,
                        "signal_group": s.signal_group} for s in m.stop_lines],
        "drivable_areas": [np.asarray(p) for p in m.drivable_areas],
        "obstacles": [{"polygon": np.asarray(o.polygon), "height": o.height, "kind": o.kind} for o in m.obstacles],
        "signal_plan": [{"duration": p.duration, "green": list(p.green), "yellow_duration": p.yellow_duration,
                         "all_red": p.all_red} for p in m.signal_plan],
        "meta": m.meta,
    }


def _suite_obj(suite: SuiteRecord) -> dict:
    return {
        "name": suite.name, "version": suite.version, "schema_version": SCHEMA_VERSION,
        "meta": suite.meta,
        "scenarios": [{"id": s.scenario_id, "split": s.split, "intersection_id": s.intersection_id,
                       "behavior": s.behavior} for s in suite.scenarios],
    }


def _jsonify(v: Any, nd: int | None = None) -> Any:
    """Plain JSON values, floats rounded to ``nd`` places (-0.0 folded to 0.0)."""
    if isinstance(v, dict):
        return {str(k): _jsonify(x, _DECIMALS.get(str(k), nd)) for k, x in v.items()}
    if isinstance(v, np.ndarray):
        if v.dtype.kind == "b":
            return v.astype(np.int8).tolist()
        if v.dtype.kind == "f" and nd is not None:
            return (np.round(v.astype(np.float64), nd) + 0.0).tolist()
        return v.tolist()
    if isinstance(v, (list, tuple)):
        return [_jsonify(x, nd) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return (round(float(v), nd) + 0.0) if nd is not None else float(v)
    return v


def _dumps(obj: dict) -> str:
    """Fixed layout: one top-level key per line, one list-of-objects item per line."""
    def compact(v: Any) -> str:
        return json.dumps(v, separators=(",", ":"), ensure_ascii=False, allow_nan=False)

    lines = ["{"]
    items = list(obj.items())
    for i, (key, value) in enumerate(items):
        sep = "," if i < len(items) - 1 else ""
        if isinstance(value, list) and value and all(isinstance(e, dict) for e in value):
            lines.append(f" {json.dumps(key)}:[")
            lines += [f"  {compact(e)}{',' if j < len(value) - 1 else ''}" for j, e in enumerate(value)]
            lines.append(f" ]{sep}")
        else:
            lines.append(f" {json.dumps(key)}:{compact(value)}{sep}")
    lines.append("}")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------


def validate_records(suite: SuiteRecord) -> list[Problem]:
    """Every problem in an in-memory suite, named as in the folder it would
    be written to (``scenarios/<id>.json: tracks[2].t[5]: ...``)."""
    if not isinstance(suite, SuiteRecord):
        raise TypeError(f"expected a SuiteRecord, got {type(suite).__name__}")
    problems: list[Problem] = []
    _check_suite_json(_suite_obj(suite), _Checker("suite.json", problems))
    for key, m in suite.maps.items():
        c = _Checker(f"maps/{key}.json", problems)
        if _check_map(_map_obj(m), c) is not None and m.map_id != key:
            c.add("map_id", f"{key!r} (the key of SuiteRecord.maps)", repr(m.map_id))
    for s in suite.scenarios:
        c = _Checker(f"scenarios/{s.scenario_id}.json", problems)
        obj = _scenario_obj(s)
        _check_scenario(obj, c)
        _check_cross(obj, c, None, suite.maps)
    return problems


def write_suite(suite: SuiteRecord, path: str | os.PathLike, *, overwrite: bool = False,
                progress: bool = False) -> Path:
    """Write ``suite`` as a suite folder at ``path`` and return the path.

    The suite is validated first (a DriveE2EError names the first problem).
    The folder is built under a temporary name next to ``path`` and moved
    into place with ``os.replace``, so readers never see half a suite. An
    existing non-empty folder is refused unless ``overwrite=True``, and even
    then only a folder that holds a ``suite.json`` is replaced.
    """
    problems = validate_records(suite)
    if problems:
        err = problems_error(problems)
        raise DriveE2EError(f"cannot write suite {suite.name!r}: {err}")
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise DriveE2EError(f"{path} exists and is not a folder; expected a new or empty folder")
        if any(path.iterdir()):
            if not overwrite:
                raise DriveE2EError(f"{path} exists and is not empty; expected a new or empty folder "
                                    "(pass --force / overwrite=True to replace a suite folder)")
            if not (path / "suite.json").is_file():
                raise DriveE2EError(f"{path} is not a suite folder (no suite.json); refusing to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        (tmp / "maps").mkdir(parents=True)
        (tmp / "scenarios").mkdir()
        for key, m in suite.maps.items():
            (tmp / "maps" / f"{key}.json").write_text(_dumps(_jsonify(_map_obj(m))), encoding="utf-8")
        scenarios = suite.scenarios
        if progress:
            scenarios = progress_bar(scenarios, desc=f"writing {suite.name}", unit="scenario")
        for s in scenarios:
            (tmp / "scenarios" / f"{s.scenario_id}.json").write_text(_dumps(_jsonify(_scenario_obj(s))), encoding="utf-8")
        (tmp / "suite.json").write_text(_dumps(_jsonify(_suite_obj(suite))), encoding="utf-8")
        if path.exists():
            old = path.parent / f".{path.name}.old-{os.getpid()}"
            shutil.rmtree(old, ignore_errors=True)
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


_FAILED = object()


def _read_json(folder: Path, rel: str, problems: list[Problem]) -> Any:
    try:
        text = (folder / rel).read_text(encoding="utf-8")
    except FileNotFoundError:
        problems.append(Problem(rel, "", "a file", "missing"))
        return _FAILED
    except UnicodeDecodeError as e:
        problems.append(Problem(rel, "", "UTF-8 text", f"byte {e.start} undecodable"))
        return _FAILED
    except OSError as e:
        problems.append(Problem(rel, "", "a readable file", e.strerror or str(e)))
        return _FAILED
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        problems.append(Problem(rel, f"line {e.lineno} column {e.colno}", "valid JSON", e.msg))
        return _FAILED
    except RecursionError:
        problems.append(Problem(rel, "", "valid JSON", "nesting too deep"))
        return _FAILED


def _suite_folder(path: str | os.PathLike) -> Path:
    folder = Path(path).expanduser()
    if not folder.exists():
        raise DriveE2EError(f"suite folder {folder} does not exist; expected a folder with suite.json, maps/, scenarios/")
    if not folder.is_dir():
        raise DriveE2EError(f"{folder} is not a folder; expected a suite folder with suite.json, maps/, scenarios/")
    return folder


def _load(folder: Path, progress: bool) -> tuple[SuiteRecord | None, list[Problem]]:
    problems: list[Problem] = []
    if not (folder / "suite.json").is_file():
        problems.append(Problem("suite.json", "", "a suite.json file (is this a suite folder?)", "missing"))
        return None, problems
    head = _read_json(folder, "suite.json", problems)
    checked = None if head is _FAILED else _check_suite_json(head, _Checker("suite.json", problems))

    maps: dict[str, MapRecord] = {}
    map_stems = sorted(p.stem for p in (folder / "maps").glob("*.json")) if (folder / "maps").is_dir() else []
    for stem in map_stems:
        rel = f"maps/{stem}.json"
        obj = _read_json(folder, rel, problems)
        if obj is _FAILED:
            continue
        c = _Checker(rel, problems)
        m = _check_map(obj, c)
        if m is not None and m.map_id != stem:
            c.add("map_id", f"{stem!r} (the file name)", repr(m.map_id))
        elif m is not None:
            maps[stem] = m
    if checked is None:
        return None, problems
    header, entries = checked

    scen_dir = folder / "scenarios"
    on_disk = {p.stem for p in scen_dir.glob("*.json")} if scen_dir.is_dir() else set()
    scenarios: list[ScenarioRecord] = []
    todo = entries
    if progress:
        todo = progress_bar(entries, desc=f"reading {folder.name}", unit="scenario")
    for entry in todo:
        rel = f"scenarios/{entry['id']}.json"
        if entry["id"] not in on_disk:
            problems.append(Problem(rel, "", f"a file (listed in suite.json as scenarios[{entry['row']}])", "missing"))
            continue
        obj = _read_json(folder, rel, problems)
        if obj is _FAILED:
            continue
        c = _Checker(rel, problems)
        rec = _check_scenario(obj, c)
        _check_cross(obj, c, entry, map_stems)
        if rec is not None:
            scenarios.append(rec)
    listed = {e["id"] for e in entries}
    for stem in sorted(on_disk - listed):
        problems.append(Problem(f"scenarios/{stem}.json", "", "to be listed in suite.json (nothing is silently dropped)", "not listed"))
    if problems:
        return None, problems
    suite = SuiteRecord(name=header["name"], version=header["version"], maps=maps,
                        scenarios=scenarios, meta=dict(header["meta"]))
    return suite, problems


def validate_suite(path: str | os.PathLike, *, progress: bool = False) -> list[Problem]:
    """Every problem in the suite folder at ``path`` (empty list = valid).

    Raises DriveE2EError only when ``path`` is not a folder at all.
    """
    return _load(_suite_folder(path), progress)[1]


def read_suite(path: str | os.PathLike, *, progress: bool = False) -> SuiteRecord:
    """Read and validate the suite folder at ``path``.

    Raises DriveE2EError naming the first problem (file, field, expectation)
    and how many more there are.
    """
    folder = _suite_folder(path)
    suite, problems = _load(folder, progress)
    if problems:
        raise problems_error(problems, folder)
    return suite
