"""Suites larger than memory: a suite folder read shard by shard.

``SuiteIndex.open(folder)`` reads suite.json and maps/ only (no scenario
file): ids, splits, behaviours, intersections and the ``PackSizes`` every
shard is packed at. ``shards(index, split, shard_size)`` then yields the
split as ``(rows, PackedBatch)`` pairs in order, each scenario file read and
validated exactly as ``schema.read_suite`` does, while a background thread
reads and packs the next shard(s). At most ``prefetch + 1`` shards are alive
at a time (the one the caller holds and ``prefetch`` being read or waiting),
so memory does not grow with the suite.

Packing sizes come from ``suite.json``'s ``meta["pack_sizes"]`` (written by
``schema.SuiteWriter``, e.g. ``drivee2e suite generate --scenarios N``);
a folder without them (written by ``write_suite`` or an importer) costs one
pre-pass over its scenario files at ``open`` (each file read, validated and
dropped; the needs kept). Either way the sizes are those ``pack`` fits for
the whole suite, so a shard equals the rows of the in-memory batch:
``load_suite(folder).pack(split).select(rows)``, leaf for leaf, with the
same ``SuiteMeta`` (``index`` = row in the suite).

The records are host data (numpy); ``PackedBatch`` itself holds a
``types.Scenario`` pytree, so this module imports JAX (through ``pack``)
but never touches a device.
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import SPLITS, MapRecord, ScenarioRecord
from drivee2e_jax.scenario.batch import PackedBatch
from drivee2e_jax.scenario.pack import pack
from drivee2e_jax.scenario.routes import densify_route
from drivee2e_jax.scenario.schema import read_head, read_scenario
from drivee2e_jax.scenario.sizes import PackSizes, record_needs

__all__ = ["SuiteIndex", "shards"]


@dataclass(frozen=True)
class SuiteIndex:
    """What a suite folder holds, without its scenario files.

    Attributes:
      folder: the suite folder (resolved).
      name, version: from suite.json.
      meta: suite.json's ``meta`` object.
      ids, splits, behaviors, intersections: (N,) numpy str, one per
        scenario in suite.json order (row i = ``Scenario.index`` i).
      maps: {map_id: MapRecord} (all of maps/, validated).
      sizes: the PackSizes every shard is packed at (see the module docstring).
      sizes_from: ``"suite.json"`` or ``"pre-pass"`` (where ``sizes`` came from).
    """

    folder: Path
    name: str
    version: str
    meta: dict = field(repr=False)
    ids: np.ndarray = field(repr=False)
    splits: np.ndarray = field(repr=False)
    behaviors: np.ndarray = field(repr=False)
    intersections: np.ndarray = field(repr=False)
    maps: dict[str, MapRecord] = field(repr=False)
    sizes: PackSizes = field(repr=False)
    sizes_from: str = "suite.json"

    @classmethod
    def open(cls, folder: str | os.PathLike) -> SuiteIndex:
        """Read ``folder``'s suite.json and maps (validated as ``read_suite``
        does: DriveE2EError naming the first problem). Without
        ``meta["pack_sizes"]`` every scenario file is read once for the sizes."""
        folder = Path(folder).expanduser().resolve()
        header, entries, maps = read_head(folder)
        meta = dict(header.get("meta") or {})
        ids = np.array([e["id"] for e in entries], dtype=str)
        on_disk = {p.stem for p in (folder / "scenarios").glob("*.json")} if (folder / "scenarios").is_dir() else set()
        unlisted = sorted(on_disk - set(ids.tolist()))
        if unlisted:
            raise DriveE2EError(f"{folder / 'scenarios' / (unlisted[0] + '.json')}: expected to be listed in "
                                f"suite.json (nothing is silently dropped), got not listed"
                                + (f" (and {len(unlisted) - 1} more)" if len(unlisted) > 1 else ""))
        if "pack_sizes" in meta:
            sizes, source = _sizes_from_meta(meta["pack_sizes"], folder), "suite.json"
        else:
            sizes, source = _pre_pass(folder, entries, maps), "pre-pass"
        return cls(folder=folder, name=str(header["name"]), version=str(header["version"]), meta=meta, ids=ids,
                   splits=np.array([e["split"] for e in entries], dtype=str),
                   behaviors=np.array([e["behavior"] for e in entries], dtype=str),
                   intersections=np.array([e["intersection_id"] for e in entries], dtype=str),
                   maps=maps, sizes=sizes, sizes_from=source)

    def __len__(self) -> int:
        return len(self.ids)

    def split_counts(self) -> dict[str, int]:
        """Non-empty split name -> number of scenarios, in SPLITS order."""
        return {s: int(n) for s in SPLITS if (n := int((self.splits == s).sum()))}

    def rows(self, split: str | None) -> np.ndarray:
        """(n,) int64 suite rows of ``split`` (all rows for None), in suite
        order; DriveE2EError for an unknown or empty split, naming the others."""
        if split is None:
            return np.arange(len(self), dtype=np.int64)
        available = ", ".join(f"{s} ({n})" for s, n in self.split_counts().items()) or "none"
        if split not in SPLITS:
            raise DriveE2EError(f"unknown split {split!r} for suite {self.name!r}; expected one of: {available}")
        rows = np.flatnonzero(self.splits == split).astype(np.int64)
        if len(rows) == 0:
            raise DriveE2EError(f"split {split!r} of suite {self.name!r} is empty; available splits: {available}")
        return rows

    def read(self, row: int) -> ScenarioRecord:
        """The ScenarioRecord of suite row ``row``, read and validated as
        ``read_suite`` does (DriveE2EError naming the file and the field)."""
        row = int(row)
        entry = {"id": str(self.ids[row]), "split": str(self.splits[row]), "behavior": str(self.behaviors[row]),
                 "intersection_id": str(self.intersections[row]), "row": row}
        return read_scenario(self.folder, entry, list(self.maps))

    def pack_rows(self, rows: np.ndarray, sizes: PackSizes | None = None, *,
                  stop: threading.Event | None = None) -> PackedBatch:
        """Suite rows ``rows`` read and packed at ``sizes`` (default
        ``self.sizes``); ``stop`` set: give up between two files (_Stopped)."""
        records = []
        for r in rows:
            if stop is not None and stop.is_set():
                raise _Stopped
            records.append(self.read(r))
        return pack(records, self.maps, sizes or self.sizes, index=np.asarray(rows, dtype=np.int64))


class _Stopped(Exception):
    """The consumer went away: the reading thread ends early."""


def _sizes_from_meta(obj, folder: Path) -> PackSizes:
    fields = set(PackSizes.MULTIPLE)
    if not isinstance(obj, dict) or set(obj) != fields:
        got = sorted(obj) if isinstance(obj, dict) else type(obj).__name__
        raise DriveE2EError(f"{folder / 'suite.json'}: meta.pack_sizes: expected an object with keys "
                            f"{', '.join(sorted(fields))}, got {got}")
    try:
        return PackSizes(**obj)
    except DriveE2EError as e:
        raise DriveE2EError(f"{folder / 'suite.json'}: meta.pack_sizes: {e}") from None


def _pre_pass(folder: Path, entries: list[dict], maps: dict[str, MapRecord]) -> PackSizes:
    """The sizes ``pack`` fits for the whole suite, one file in memory at a time."""
    best = {k: 0 for k in PackSizes.MULTIPLE}
    used_maps: set[str] = set()
    for e in entries:
        s = read_scenario(folder, e, list(maps))
        if s.map_id not in used_maps:
            used_maps.add(s.map_id)
            for k, (n, _) in record_needs([s], maps, [densify_route(s.route.waypoints)[0]]).items():
                best[k] = max(best[k], n)
        else:
            best["agents"] = max(best["agents"], len(s.tracks))
            best["steps"] = max(best["steps"], int(s.num_steps))
            best["route"] = max(best["route"], len(densify_route(s.route.waypoints)[0]))
    return PackSizes.rounded(best)


class _Failed:
    def __init__(self, error: BaseException):
        self.error = error


_DONE = object()


def shards(index: SuiteIndex, split: str | None, shard_size: int, *, sizes: PackSizes | None = None,
           prefetch: int = 1) -> Iterator[tuple[np.ndarray, PackedBatch]]:
    """The scenarios of ``split`` (None = all) as consecutive shards.

    Yields ``(rows, batch)`` in order: ``rows`` (n,) int64 are the positions
    of the shard's scenarios within the split (0.., as in
    ``Suite.pack(split).select(rows)``), ``batch`` their PackedBatch, every
    one packed at ``sizes`` (default ``index.sizes``; a record that does not
    fit is a DriveE2EError naming it), ``meta.index`` = suite rows. The last
    shard may be shorter.

    Bad arguments and an unknown or empty split raise DriveE2EError at the
    call. With ``prefetch >= 1`` a background thread reads and packs up to
    ``prefetch`` shards ahead while the caller works on the current one (it
    overlaps with work that releases the GIL: XLA computations, file I/O);
    an exception there (a malformed file: one line naming the file and the
    field) is raised in the caller, at the shard it belongs to.
    ``prefetch=0`` reads each shard when asked for. Closing the iterator
    early (``break``, ``close()``) stops the thread before its next file.
    """
    if isinstance(shard_size, bool) or not isinstance(shard_size, (int, np.integer)) or shard_size < 1:
        raise DriveE2EError(f"shard_size: expected an integer >= 1, got {shard_size!r}")
    if isinstance(prefetch, bool) or not isinstance(prefetch, (int, np.integer)) or prefetch < 0:
        raise DriveE2EError(f"prefetch: expected an integer >= 0, got {prefetch!r}")
    suite_rows = index.rows(split)  # an unknown or empty split fails here, before any reading
    return _iterate(index, suite_rows, int(shard_size), sizes or index.sizes, int(prefetch))


def _iterate(index: SuiteIndex, suite_rows: np.ndarray, shard_size: int, sizes: PackSizes,
             prefetch: int) -> Iterator[tuple[np.ndarray, PackedBatch]]:
    starts = range(0, len(suite_rows), shard_size)

    def make(start: int, stop: threading.Event | None = None) -> tuple[np.ndarray, PackedBatch]:
        pos = np.arange(start, min(start + shard_size, len(suite_rows)), dtype=np.int64)
        return pos, index.pack_rows(suite_rows[pos], sizes, stop=stop)

    if prefetch == 0:
        for start in starts:
            yield make(start)
        return

    out: queue.Queue = queue.Queue()
    slots = threading.Semaphore(prefetch)  # shards read ahead and not yet handed over
    stop = threading.Event()

    def work() -> None:
        try:
            for start in starts:
                while not slots.acquire(timeout=0.1):
                    if stop.is_set():
                        return
                if stop.is_set():
                    return
                out.put(make(start, stop))
        except _Stopped:
            pass
        except BaseException as e:  # noqa: BLE001 - handed to the caller, raised there
            out.put(_Failed(e))
        finally:
            out.put(_DONE)

    thread = threading.Thread(target=work, name="drivee2e-shards", daemon=True)
    thread.start()
    try:
        while True:
            item = out.get()
            if item is _DONE:
                return
            if isinstance(item, _Failed):
                raise item.error
            slots.release()  # the caller now holds this shard: the thread may read the next
            yield item
            del item
    finally:
        stop.set()  # the thread stops before its next file
        thread.join()
