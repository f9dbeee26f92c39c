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

The pieces: ``problems`` (Problem, the checker), ``validate`` (the checks,
``validate_records``), ``encode`` (records -> JSON objects and bytes); this
module reads, writes and validates folders.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.progress import progress as progress_bar
from drivee2e_jax.records import MapRecord, ScenarioRecord, SuiteRecord
from drivee2e_jax.scenario.encode import dumps, jsonify, map_obj, scenario_obj, suite_obj
from drivee2e_jax.scenario.problems import Checker, Problem, problems_error
from drivee2e_jax.scenario.validate import check_cross, check_map, check_scenario, check_suite_json, validate_records

__all__ = ["read_suite", "write_suite", "validate_suite"]


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
            (tmp / "maps" / f"{key}.json").write_text(dumps(jsonify(map_obj(m))), encoding="utf-8")
        scenarios = suite.scenarios
        if progress:
            scenarios = progress_bar(scenarios, desc=f"writing {suite.name}", unit="scenario")
        for s in scenarios:
            (tmp / "scenarios" / f"{s.scenario_id}.json").write_text(dumps(jsonify(scenario_obj(s))), encoding="utf-8")
        (tmp / "suite.json").write_text(dumps(jsonify(suite_obj(suite))), encoding="utf-8")
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
    checked = None if head is _FAILED else check_suite_json(head, Checker("suite.json", problems))

    maps: dict[str, MapRecord] = {}
    map_stems = sorted(p.stem for p in (folder / "maps").glob("*.json")) if (folder / "maps").is_dir() else []
    for stem in map_stems:
        rel = f"maps/{stem}.json"
        obj = _read_json(folder, rel, problems)
        if obj is _FAILED:
            continue
        c = Checker(rel, problems)
        m = check_map(obj, c)
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
        c = Checker(rel, problems)
        rec = check_scenario(obj, c)
        check_cross(obj, c, entry, map_stems)
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
