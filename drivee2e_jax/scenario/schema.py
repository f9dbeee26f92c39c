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

import fcntl
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import ForeignFiles, OwnFolder, check_own_folder, read_json
from drivee2e_jax.jsonfile import BadJSON, parse_json
from drivee2e_jax.progress import progress as progress_bar
from drivee2e_jax.records import SCHEMA_VERSION, MapRecord, ScenarioRecord, SuiteRecord
from drivee2e_jax.scenario.encode import dumps, jsonify, map_obj, scenario_obj, suite_obj
from drivee2e_jax.scenario.problems import Checker, Problem, problems_error
from drivee2e_jax.scenario.validate import check_cross, check_map, check_scenario, check_suite_json, validate_records

__all__ = ["read_suite", "write_suite", "validate_suite", "SuiteWriter", "read_head", "read_scenario"]


#: What a suite folder holds: ``overwrite`` (``--force``) replaces only a
#: folder with suite.json and no other files than these.
SUITE_FOLDER = OwnFolder("suite", "suite.json", ("suite.json", "maps/*.json", "scenarios/*.json"))


def write_suite(suite: SuiteRecord, path: str | os.PathLike, *, overwrite: bool = False,
                progress: bool = False) -> Path:
    """Write ``suite`` as a suite folder at ``path`` and return the path.

    The suite is validated first (a DriveE2EError names the first problem).
    The folder is built under a temporary name next to ``path`` and moved
    into place with ``os.replace``, so readers never see half a suite. An
    existing non-empty folder is refused unless ``overwrite=True``, and even
    then only a folder that holds a ``suite.json`` and nothing but a suite's
    files (``SUITE_FOLDER``) is replaced.
    """
    problems = validate_records(suite)
    if problems:
        err = problems_error(problems)
        raise DriveE2EError(f"cannot write suite {suite.name!r}: {err}")
    path = _check_target(Path(path), overwrite)
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
        _move_into_place(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


def _check_target(path: Path, overwrite: bool) -> Path:
    """``path`` if a suite may be written there (new, empty, or with
    ``overwrite`` a suite folder); DriveE2EError otherwise."""
    if path.exists():
        if not path.is_dir():
            raise DriveE2EError(f"{path} exists and is not a folder; expected a new or empty folder")
        if any(path.iterdir()):
            if not overwrite:
                raise DriveE2EError(f"{path} exists and is not empty; expected a new or empty folder "
                                    "(pass --force / overwrite=True to replace a suite folder)")
            if not (path / "suite.json").is_file():
                raise DriveE2EError(f"{path} is not a suite folder (no suite.json); refusing to replace it")
            try:  # replacing the folder deletes it whole: only a suite's own files may be there
                check_own_folder(path, SUITE_FOLDER, redo=True)
            except ForeignFiles as e:
                raise DriveE2EError(str(e)) from None
    return path


def _move_into_place(tmp: Path, path: Path) -> None:
    if path.exists():
        old = path.parent / f".{path.name}.old-{os.getpid()}"
        shutil.rmtree(old, ignore_errors=True)
        os.replace(path, old)
        os.replace(tmp, path)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, path)


def _write_atomic(path: Path, text: str) -> None:
    part = path.with_name(path.name + ".part")
    part.write_text(text, encoding="utf-8")
    os.replace(part, path)


def _entry(s: ScenarioRecord) -> dict:
    """A scenario's line in suite.json (as ``encode.suite_obj`` writes it)."""
    return {"id": s.scenario_id, "split": s.split, "intersection_id": s.intersection_id, "behavior": s.behavior}


class SuiteWriter:
    """Writes a suite folder block by block, for suites larger than memory.

    ::

        w = SuiteWriter(path, name=..., version=..., maps=..., key={...})
        try:
            for b, records in enumerate(blocks):   # any block numbers, written in any order
                if not w.done(b):
                    w.write_block(b, records(), stats={...})
            w.finish(lambda stats: {...})          # meta from the blocks' stats, in block order
        finally:
            w.close()

    Every block is validated like ``write_suite`` validates a suite
    (``validate_records``) and its files written before the call returns;
    the caller frees the records. ``finish`` writes ``suite.json`` (the
    scenarios in block order, ``meta["pack_sizes"]``: the ``PackSizes`` that
    ``pack`` fits for the whole suite, the elementwise maximum over blocks)
    and moves the folder into place with ``os.replace``, with the refusal
    rules of ``write_suite`` (``overwrite`` = ``--force``).

    Resuming: the folder is built in ``.<name>.partial`` next to ``path``,
    with ``resume.json`` (``key``: whatever identifies the generation, e.g.
    generator, seed, N) and ``blocks/<b>.json`` (a block's suite.json lines,
    stats and pack sizes, written after all its scenario files). A new
    writer with the same ``key`` keeps the blocks finished there
    (``done(b)``); a different ``key`` discards the folder. A lock (flock)
    refuses a second writer on the same folder at the same time.
    """

    def __init__(self, path: str | os.PathLike, *, name: str, version: str, maps: dict[str, MapRecord],
                 key: dict, overwrite: bool = False):
        self.path = _check_target(Path(path), overwrite)
        self.name, self.version, self.maps, self.overwrite = name, str(version), maps, overwrite
        problems: list[Problem] = []
        for k, m in maps.items():
            c = Checker(f"maps/{k}.json", problems)
            if check_map(map_obj(m), c) is not None and m.map_id != k:
                c.add("map_id", f"{k!r} (the key of the maps)", repr(m.map_id))
        if problems:
            raise DriveE2EError(f"cannot write suite {name!r}: {problems_error(problems)}")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = self.path.parent / f".{self.path.name}.partial"
        state = {"name": name, "version": self.version, "schema_version": SCHEMA_VERSION, "key": jsonify(key)}
        old = None
        try:
            old = read_json(self.tmp / "resume.json")
        except (OSError, ValueError):
            pass
        self._lock = None
        if old != state:
            self._take_lock()  # never wipe a folder another writer is filling
            shutil.rmtree(self.tmp, ignore_errors=True)
            self.close()
            self.tmp.mkdir()
            _write_atomic(self.tmp / "resume.json", json.dumps(state, sort_keys=True))
        self._take_lock()
        for sub in ("maps", "scenarios", "blocks"):
            (self.tmp / sub).mkdir(exist_ok=True)
        for k, m in maps.items():
            (self.tmp / "maps" / f"{k}.json").write_text(dumps(jsonify(map_obj(m))), encoding="utf-8")

    def _take_lock(self) -> None:
        if self._lock is not None or not self.tmp.is_dir():
            return
        fd = os.open(self.tmp, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise DriveE2EError(f"{self.tmp} is being written by another process; expected one writer per "
                                "suite folder") from None
        self._lock = fd

    def close(self) -> None:
        """Release the lock (the partial folder stays for a resume)."""
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None

    def _block_file(self, block: int) -> Path:
        return self.tmp / "blocks" / f"{int(block):06d}.json"

    def done(self, block: int) -> bool:
        """Whether block ``block`` is already written (by this or an earlier run)."""
        return self._block_file(block).is_file()

    def write_block(self, block: int, scenarios: list[ScenarioRecord], stats: dict | None = None) -> None:
        """Validate and write one block of records (``stats``: any JSON
        object, handed back to ``finish``'s meta function)."""
        if not scenarios:
            raise DriveE2EError(f"block {block}: expected at least one scenario")
        part = SuiteRecord(name=self.name, version=self.version, maps=self.maps, scenarios=scenarios, meta={})
        problems = validate_records(part)
        if problems:
            raise DriveE2EError(f"cannot write suite {self.name!r}: {problems_error(problems)}")
        # deferred: sizes imports JAX (types); reading and validating suites stays JAX-free
        from drivee2e_jax.scenario.sizes import PackSizes  # noqa: PLC0415

        sizes = PackSizes.fit(scenarios, self.maps).as_dict()
        for s in scenarios:
            (self.tmp / "scenarios" / f"{s.scenario_id}.json").write_text(dumps(jsonify(scenario_obj(s))),
                                                                            encoding="utf-8")
        mark = {"entries": [_entry(s) for s in scenarios], "stats": jsonify(stats or {}), "pack_sizes": sizes}
        _write_atomic(self._block_file(block), json.dumps(mark, separators=(",", ":")))

    def finish(self, meta: dict | Callable[[list[dict]], dict]) -> Path:
        """Write suite.json (``meta``, or ``meta(stats of every block, in
        block order)``, plus ``pack_sizes``) and move the folder into place."""
        marks = [read_json(p) for p in sorted((self.tmp / "blocks").glob("*.json"))]
        if not marks:
            raise DriveE2EError(f"cannot write suite {self.name!r}: no block was written")
        entries = [e for m in marks for e in m["entries"]]
        meta = dict(meta([m["stats"] for m in marks]) if callable(meta) else meta)
        sizes = {k: max(m["pack_sizes"][k] for m in marks) for k in marks[0]["pack_sizes"]}
        meta["pack_sizes"] = sizes
        head = {"name": self.name, "version": self.version, "schema_version": SCHEMA_VERSION,
                "meta": meta, "scenarios": entries}
        problems: list[Problem] = []
        check_suite_json(jsonify(head), Checker("suite.json", problems))
        listed = {e["id"] for e in entries}
        for stem in sorted({p.stem for p in (self.tmp / "scenarios").glob("*.json")} - listed):
            problems.append(Problem(f"scenarios/{stem}.json", "", "to be listed in suite.json (a block written "
                                    "twice with other ids?)", "not listed"))
        if problems:
            raise DriveE2EError(f"cannot write suite {self.name!r}: {problems_error(problems)}")
        _check_target(self.path, self.overwrite)
        (self.tmp / "suite.json").write_text(dumps(jsonify(head)), encoding="utf-8")
        (self.tmp / "resume.json").unlink()
        shutil.rmtree(self.tmp / "blocks")
        self.close()
        _move_into_place(self.tmp, self.path)
        return self.path


_FAILED = object()


def _read_json(folder: Path, rel: str, problems: list[Problem]) -> Any:
    """``folder / rel`` parsed by the guarded reader (``jsonfile``): a file
    that is missing, unreadable or not JSON drivee2e can read (not UTF-8, a
    number with more than 4300 digits, nesting too deep) is a Problem."""
    try:
        data = (folder / rel).read_bytes()
    except FileNotFoundError:
        problems.append(Problem(rel, "", "a file", "missing"))
        return _FAILED
    except OSError as e:
        problems.append(Problem(rel, "", "a readable file", e.strerror or str(e)))
        return _FAILED
    try:
        return parse_json(data, rel)
    except BadJSON as e:
        problems.append(Problem(rel, e.where, e.expected, e.got))
        return _FAILED


def _suite_folder(path: str | os.PathLike) -> Path:
    folder = Path(path).expanduser()
    if not folder.exists():
        raise DriveE2EError(f"suite folder {folder} does not exist; expected a folder with suite.json, maps/, scenarios/")
    if not folder.is_dir():
        raise DriveE2EError(f"{folder} is not a folder; expected a suite folder with suite.json, maps/, scenarios/")
    return folder


def _load_head(folder: Path, problems: list[Problem]) -> tuple[tuple[dict, list[dict]] | None, dict[str, MapRecord], list[str]]:
    """suite.json checked (header, entries) or None, the maps, the map file stems."""
    if not (folder / "suite.json").is_file():
        problems.append(Problem("suite.json", "", "a suite.json file (is this a suite folder?)", "missing"))
        return None, {}, []
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
    return checked, maps, map_stems


def _load_scenario(folder: Path, entry: dict, map_stems: list[str], on_disk: set[str] | None,
                   problems: list[Problem]) -> ScenarioRecord | None:
    """The scenario file of a suite.json entry, read and checked (None and
    ``problems`` extended when it has any); ``on_disk``: the scenario file
    stems (None: look the file up)."""
    rel = f"scenarios/{entry['id']}.json"
    present = entry["id"] in on_disk if on_disk is not None else (folder / rel).is_file()
    if not present:
        problems.append(Problem(rel, "", f"a file (listed in suite.json as scenarios[{entry['row']}])", "missing"))
        return None
    obj = _read_json(folder, rel, problems)
    if obj is _FAILED:
        return None
    mark = len(problems)
    c = Checker(rel, problems)
    rec = check_scenario(obj, c)
    check_cross(obj, c, entry, map_stems)
    return rec if len(problems) == mark else None


def _load(folder: Path, progress: bool) -> tuple[SuiteRecord | None, list[Problem]]:
    problems: list[Problem] = []
    checked, maps, map_stems = _load_head(folder, problems)
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
        rec = _load_scenario(folder, entry, map_stems, on_disk, problems)
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


def read_head(path: str | os.PathLike) -> tuple[dict, list[dict], dict[str, MapRecord]]:
    """suite.json and the maps of the suite folder at ``path``, validated as
    ``read_suite`` validates them, without reading any scenario file.

    Returns ``(header, entries, maps)``: header {name, version, meta, ...},
    entries [{id, split, intersection_id, behavior, row}] in suite.json order,
    maps {map_id: MapRecord}. Raises DriveE2EError naming the first problem.
    """
    folder = _suite_folder(path)
    problems: list[Problem] = []
    checked, maps, _ = _load_head(folder, problems)
    if problems or checked is None:
        raise problems_error(problems, folder)
    header, entries = checked
    return header, entries, maps


def read_scenario(path: str | os.PathLike, entry: dict, map_ids: list[str]) -> ScenarioRecord:
    """One scenario file of a suite folder (``entry``: its line of
    ``read_head``'s entries), read and validated exactly as ``read_suite``
    does (map_ids: the suite's map ids). Raises DriveE2EError naming the
    file, the field and what was expected."""
    folder = Path(path)
    problems: list[Problem] = []
    rec = _load_scenario(folder, entry, sorted(map_ids), None, problems)
    if problems or rec is None:
        raise problems_error(problems, folder)
    return rec


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
