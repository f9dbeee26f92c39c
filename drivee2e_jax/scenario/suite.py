"""Suites: a named set of scenarios, loaded once and packed from a disk cache.

``load_suite("twin15")`` is the built-in generated suite; ``load_suite(path)``
reads a suite folder (``scenario.schema``). Either way the whole suite is
packed once (``scenario.pack``) and kept in a **packed cache** under
``$DRIVEE2E_CACHE`` (default ``~/.cache/drivee2e``; ``DRIVEE2E_CACHE=off``
disables it): ``suites/<name>-<source>-<key>.npz`` (np.savez, uncompressed,
one array per ``sizes.LEAVES`` name) plus a ``.json`` sidecar with the meta
table and category counts. The key hashes the suite name, the generator
``VERSION`` (built-in) or the files' paths/sizes/mtimes (folder), the schema
version and the pack format, so any change rebuilds. Both files are written
atomically. The npz is read back memory-mapped (no copy; a 0.5 GB suite loads
in ~0.3 s) with every member checked against its zip CRC; a cache that fails
any check (size, CRC, dtype, shape, meta) is rebuilt, never trusted.

Splits are rows of the cached full-suite batch: ``suite.pack("val")`` never
regenerates or re-reads records, and every split shares the suite's padded
sizes (one compilation serves all splits). ``.records`` is loaded only when
asked for.
"""

from __future__ import annotations

import hashlib
import importlib
import io
import json
import logging
import mmap
import os
import re
import struct
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import atomic_write, cache_dir
from drivee2e_jax.records import (
    BEHAVIORS,
    CATEGORIES,
    SCHEMA_VERSION,
    SPLITS,
    TIMES_OF_DAY,
    WEATHERS,
    SuiteRecord,
)
from drivee2e_jax.scenario import schema
from drivee2e_jax.scenario.batch import PackedBatch, SuiteMeta, bucket, resize
from drivee2e_jax.scenario.flat import flatten_scenario, unflatten_scenario
from drivee2e_jax.scenario.pack import PACK_FORMAT, pack
from drivee2e_jax.scenario.problems import Problem, problems_error
from drivee2e_jax.scenario.sizes import LEAVES, PackSizes
from drivee2e_jax.scenario.validate import validate_records

__all__ = ["Suite", "load_suite", "generate_suite", "BUILTIN_SUITES"]

log = logging.getLogger("drivee2e.cache")

#: Layout version of the cache files (bump to orphan old caches).
CACHE_FORMAT = 1

#: Built-in suites: name -> (generator module, seed). The module exposes
#: ``generate(seed=...) -> SuiteRecord`` and ``VERSION``.
BUILTIN_SUITES: dict[str, tuple[str, int]] = {"twin15": ("drivee2e_jax.scenario.twin15", 0)}

#: Example suites shipped as folders inside the package, accepted by name
#: (``drivee2e bench --suite tiny``): the four-scenario ``tiny`` suite, the
#: on-disk format by example (docs/suite_format.md).
EXAMPLE_SUITES: dict[str, Path] = {"tiny": Path(__file__).resolve().parent / "examples" / "tiny"}

_GENERATED: dict[tuple[str, int], SuiteRecord] = {}


# --------------------------------------------------------------------------
# Sources: where a suite's records come from
# --------------------------------------------------------------------------


class _Builtin:
    def __init__(self, name: str):
        self.name = name
        self.module_name, self.seed = BUILTIN_SUITES[name]
        self._module = None

    def module(self):
        if self._module is None:

            try:
                self._module = importlib.import_module(self.module_name)
            except ModuleNotFoundError as e:
                if e.name and self.module_name.startswith(e.name):
                    raise DriveE2EError(f"built-in suite {self.name!r} is not available: module "
                                        f"{self.module_name} is missing from this installation") from e
                raise
            missing = [n for n in ("generate", "VERSION") if not hasattr(self._module, n)]
            if missing:
                self._module = None
                raise DriveE2EError(f"built-in suite {self.name!r} is not available: module {self.module_name} "
                                    f"lacks {' and '.join(missing)}")
        return self._module

    @property
    def version(self) -> str:
        return str(self.module().VERSION)

    def key_parts(self) -> dict:
        return {"builtin": self.name, "version": self.version, "seed": self.seed}

    def source_id(self) -> str:
        return "builtin"

    def records(self) -> SuiteRecord:
        memo = (self.name, self.seed)
        if memo not in _GENERATED:
            rec = self.module().generate(seed=self.seed)
            problems = validate_records(rec)
            if problems:
                raise DriveE2EError(f"built-in suite {self.name!r} (generator {self.version}) produced an invalid "
                                    f"record: {problems_error(problems)}")
            _GENERATED[memo] = rec
        return _GENERATED[memo]


class _Folder:
    def __init__(self, path: Path):
        self.path = path.resolve()
        head_path = self.path / "suite.json"
        if not head_path.is_file():
            raise DriveE2EError(f"{path} is not a suite folder: expected a suite.json in it")
        try:
            head = json.loads(head_path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise problems_error(
                [Problem("suite.json", f"line {getattr(e, 'lineno', '?')} column {getattr(e, 'colno', '?')}",
                                "valid JSON", getattr(e, "msg", str(e)))], self.path) from None
        head = head if isinstance(head, dict) else {}
        self.name = str(head.get("name") or self.path.name)
        self.version = str(head.get("version", "?"))

    def key_parts(self) -> dict:
        files = [self.path / "suite.json"]
        for sub in ("maps", "scenarios"):
            if (self.path / sub).is_dir():
                files += sorted((self.path / sub).glob("*.json"))
        stats = []
        for f in files:
            st = f.stat()
            stats.append((str(f.relative_to(self.path)), st.st_size, st.st_mtime_ns))
        return {"folder": str(self.path), "files": stats}

    def source_id(self) -> str:
        return hashlib.sha256(str(self.path).encode()).hexdigest()[:8]

    def records(self) -> SuiteRecord:
        return schema.read_suite(self.path)


class _Memory:
    def __init__(self, records: SuiteRecord):
        self._records = records
        self.name, self.version = records.name, str(records.version)

    def records(self) -> SuiteRecord:
        return self._records


def generate_suite(name: str = "twin15", seed: int | None = None) -> SuiteRecord:
    """Run a built-in suite's generator (validated records; memoised per seed)."""
    if name not in BUILTIN_SUITES:
        raise DriveE2EError(f"unknown built-in suite {name!r}; expected one of: {', '.join(BUILTIN_SUITES)}")
    source = _Builtin(name)
    if seed is not None:
        source.seed = int(seed)
    return source.records()


# --------------------------------------------------------------------------
# The packed cache
# --------------------------------------------------------------------------


def _cache_paths(source, key: str) -> tuple[Path, Path] | None:
    root = cache_dir()
    if root is None or not hasattr(source, "key_parts"):
        return None
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", source.name)[:40]
    stem = root / "suites" / f"{safe}-{source.source_id()}-{key[:16]}"
    return stem.with_suffix(".npz"), stem.with_suffix(".json")


class _Packed:
    """The full suite: meta + category counts (sidecar) and the batch (npz, lazy)."""

    def __init__(self, meta: SuiteMeta, categories: dict[str, int], batch=None, npz: Path | None = None,
                 npz_bytes: int = 0):
        self.meta, self.categories, self._batch = meta, categories, batch
        self.npz, self.npz_bytes = npz, npz_bytes

    def batch(self) -> PackedBatch | None:
        if self._batch is None:
            self._batch = _load_npz(self.npz, self.npz_bytes, self.meta)
        return self._batch


def _load_sidecar(npz: Path, side: Path, key: str) -> _Packed | None:
    try:
        head = json.loads(side.read_text(encoding="utf-8"))
        if head.get("format") != CACHE_FORMAT or head.get("key") != key:
            return None
        meta = SuiteMeta.from_json(head["meta"])
        categories = {str(k): int(v) for k, v in head["categories"].items()}
        if not npz.is_file() or npz.stat().st_size != int(head["npz_bytes"]):
            raise ValueError(f"{npz.name} is missing or has the wrong size")
        return _Packed(meta, categories, npz=npz, npz_bytes=int(head["npz_bytes"]))
    except FileNotFoundError:
        return None
    except Exception as e:  # noqa: BLE001 - any defect means "rebuild"
        log.warning("drivee2e: packed cache %s is unusable (%s: %s); rebuilding", side, type(e).__name__, e)
        return None


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    """The members of an uncompressed ``.npz`` as read-only arrays over one
    memory map (no copy: a split only touches its own rows). Each member is
    checked against the CRC the zip directory holds; any defect raises."""
    with open(path, "rb") as fh:
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    view = memoryview(mm)
    out = {}
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            if info.compress_type != zipfile.ZIP_STORED or not info.filename.endswith(".npy"):
                raise ValueError(f"member {info.filename} is not a stored .npy")
            h = info.header_offset
            if bytes(view[h : h + 4]) != b"PK\x03\x04":
                raise ValueError(f"member {info.filename}: bad local header")
            n_name, n_extra = struct.unpack("<HH", view[h + 26 : h + 30])
            start = h + 30 + n_name + n_extra
            end = start + info.file_size
            if end > len(mm) or zlib.crc32(view[start:end]) != info.CRC:
                raise ValueError(f"member {info.filename}: CRC mismatch")
            fp = io.BytesIO(view[start : min(end, start + 65536)])
            version = np.lib.format.read_magic(fp)
            readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
            if version not in readers:
                raise ValueError(f"member {info.filename}: npy format {version} is not supported")
            shape, fortran, dtype = readers[version](fp)
            if dtype.hasobject:
                raise ValueError(f"member {info.filename}: object arrays are not allowed")
            out[info.filename[:-4]] = np.ndarray(shape, dtype, buffer=mm, offset=start + fp.tell(),
                                                 order="F" if fortran else "C")
    return out


def _load_npz(npz: Path, npz_bytes: int, meta: SuiteMeta) -> PackedBatch | None:
    try:
        if npz.stat().st_size != npz_bytes:
            raise ValueError("size changed since the sidecar was written")
        flat = _read_npz(npz)
        for k, (axes, dtype, _) in LEAVES.items():
            a = flat[k]
            if a.dtype != np.dtype(dtype) or a.ndim != 1 + len(axes) or a.shape[0] != len(meta):
                raise ValueError(f"{k}: dtype {a.dtype} shape {a.shape} does not match the pack format")
        scenario = unflatten_scenario(flat).validate()
        if meta.stop_line_group.shape[1] != scenario.map.stop_lines.shape[1]:
            raise ValueError("meta.stop_line_group does not match the stop lines")
        return PackedBatch(scenario, meta)
    except Exception as e:  # noqa: BLE001 - any defect means "rebuild"
        log.warning("drivee2e: packed cache %s is unusable (%s: %s); rebuilding", npz, type(e).__name__, e)
        return None


def _save(paths: tuple[Path, Path], key: str, name: str, batch: PackedBatch,
          categories: dict[str, int]) -> None:
    npz, side = paths
    try:
        npz.parent.mkdir(parents=True, exist_ok=True)
        flat = {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}
        atomic_write(npz, lambda fh: np.savez(fh, **flat), binary=True)
        head = {"format": CACHE_FORMAT, "key": key, "suite": name, "schema_version": SCHEMA_VERSION,
                "pack_format": PACK_FORMAT, "npz_bytes": npz.stat().st_size,
                "sizes": batch.sizes.as_dict(), "categories": categories, "meta": batch.meta.to_json()}
        atomic_write(side, lambda fh: fh.write(json.dumps(head, separators=(",", ":")).encode()), binary=True)
        prefix = npz.stem.rsplit("-", 1)[0]
        for old in npz.parent.glob(f"{prefix}-*"):
            if old.stem != npz.stem and old.suffix in (".npz", ".json"):
                old.unlink(missing_ok=True)
    except OSError as e:
        log.warning("drivee2e: could not write the packed cache %s (%s); continuing without it", npz, e)


def _category_counts(batch: PackedBatch) -> dict[str, int]:
    tr = batch.scenario.tracks
    cats = np.asarray(tr.category)[np.asarray(tr.valid).any(axis=-1)]
    counts = np.bincount(cats, minlength=len(CATEGORIES))
    return {c: int(counts[int(types.Category[c.upper()])]) for c in CATEGORIES}


# --------------------------------------------------------------------------
# Suite
# --------------------------------------------------------------------------


class Suite:
    """A scenario suite: metadata, splits and packed batches.

    Create with :func:`load_suite` (or ``Suite.from_records`` for an
    in-memory ``SuiteRecord``, which is never cached on disk).

    Attributes:
      name, version: from the generator or suite.json.
      records:  the SuiteRecord (loaded or generated on first access).
      meta:     SuiteMeta of the whole suite (row i = ``Scenario.index`` i).
      splits:   non-empty split name -> number of scenarios.
    """

    def __init__(self, source, *, cache: bool = True):
        self._source = source
        self._use_cache = cache
        self._records: SuiteRecord | None = None
        self._maps: dict | None = None
        self._packed: _Packed | None = None

    @classmethod
    def from_records(cls, records: SuiteRecord) -> Suite:
        problems = validate_records(records)
        if problems:
            raise problems_error(problems)
        suite = cls(_Memory(records), cache=False)
        suite._records = records
        return suite

    @property
    def name(self) -> str:
        return self._source.name

    @property
    def version(self) -> str:
        return self._source.version

    @property
    def records(self) -> SuiteRecord:
        if self._records is None:
            self._records = self._source.records()
        return self._records

    @property
    def maps(self) -> dict:
        """{map_id: MapRecord}. A built-in suite builds its maps without
        generating its traffic (the BEV's static layers need only these)."""
        if self._records is None and isinstance(self._source, _Builtin) and hasattr(self._source.module(), "maps"):
            if self._maps is None:
                self._maps = self._source.module().maps()
            return self._maps
        return self.records.maps

    def _cache_target(self) -> tuple[tuple[Path, Path] | None, str | None]:
        if not self._use_cache or not hasattr(self._source, "key_parts"):
            return None, None
        parts = {"cache": CACHE_FORMAT, "pack": PACK_FORMAT, "schema": SCHEMA_VERSION,
                 "name": self.name, **self._source.key_parts()}
        key = hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()
        return _cache_paths(self._source, key), key

    @property
    def ready(self) -> bool:
        """True when the packed suite is at hand (in memory or in a valid disk
        cache): using it will not generate or read records. Lets a CLI say
        "building the cache" before a long first load."""
        if self._packed is None:
            paths, key = self._cache_target()
            if paths is not None:
                self._packed = _load_sidecar(*paths, key)
        return self._packed is not None

    def _full(self) -> _Packed:
        if self._packed is None:
            paths, key = self._cache_target()
            packed = _load_sidecar(*paths, key) if paths is not None else None
            self._packed = packed or self._build(paths, key)
        return self._packed

    def _build(self, paths, key) -> _Packed:
        rec = self.records
        batch = pack(rec.scenarios, rec.maps)
        for leaf in flatten_scenario(batch.scenario).values():
            leaf.flags.writeable = False  # as when it comes memory-mapped from the cache
        categories = _category_counts(batch)
        if paths is not None:
            _save(paths, key, self.name, batch, categories)
        return _Packed(batch.meta, categories, batch)

    def _batch(self) -> PackedBatch:
        batch = self._full().batch()
        if batch is None:  # the npz went bad after its sidecar was read: rebuild
            self._packed = self._build(*self._cache_target())
            batch = self._packed.batch()
        return batch

    @property
    def meta(self) -> SuiteMeta:
        return self._full().meta

    @property
    def splits(self) -> dict[str, int]:
        counts = self.meta.count("split")
        return {s: counts[s] for s in SPLITS if counts.get(s)}

    def __len__(self) -> int:
        return len(self.meta)

    def split_rows(self, split: str | None) -> np.ndarray:
        """Rows of ``meta`` in ``split`` (all rows for None); DriveE2EError
        for an unknown or empty split, listing the available ones."""
        meta = self.meta
        if split is None:
            return np.arange(len(meta))
        available = ", ".join(f"{s} ({n})" for s, n in self.splits.items())
        if split not in SPLITS:
            raise DriveE2EError(f"unknown split {split!r} for suite {self.name!r}; expected one of: {available}")
        rows = np.flatnonzero(meta.split == split)
        if len(rows) == 0:
            raise DriveE2EError(f"split {split!r} of suite {self.name!r} is empty; available splits: {available}")
        return rows

    def pack(self, split: str | None = None, sizes: PackSizes | None = None) -> PackedBatch:
        """The padded batch of ``split`` (None = the whole suite).

        The whole-suite batch (``split=None``) is shared and read-only (it is
        memory-mapped from the cache); a split is a fresh copy of its rows.
        With ``sizes=None`` every split keeps the suite-wide padded sizes;
        otherwise the batch is re-padded to ``sizes`` (an error names a
        scenario that does not fit). ``Scenario.index`` / ``meta.index`` are
        rows of ``suite.meta``.
        """
        rows = self.split_rows(split)
        batch = self._batch()
        if split is not None:
            batch = batch.select(rows)
        return batch if sizes is None else resize(batch, sizes)

    def pack_buckets(self, split: str | None = None, num_buckets: int = 4) -> list[PackedBatch]:
        """``split`` as a few batches grouped by (agents, steps), each fitted."""
        return bucket(self.pack(split), num_buckets)

    def info(self) -> dict[str, Any]:
        """Counts for people and tools (``drivee2e suite info --json``)."""
        full = self._full()
        meta = full.meta

        def counts(column, labels):
            c = meta.count(column)
            return {k: c.get(k, 0) for k in labels}

        inter = dict(sorted(meta.count("intersection_id").items()))
        agents, steps = meta.num_agents, meta.num_steps
        return {
            "name": self.name,
            "version": self.version,
            "num_scenarios": len(meta),
            "num_maps": len(set(meta.map_id.tolist())),
            "splits": counts("split", SPLITS),
            "behaviors": counts("behavior", BEHAVIORS),
            "intersections": len(inter),
            "intersection_ids": inter,
            "categories": dict(full.categories),
            "weathers": counts("weather", WEATHERS),
            "times_of_day": counts("time_of_day", TIMES_OF_DAY),
            "agents_per_scenario": {"mean": round(float(agents.mean()), 2), "max": int(agents.max())},
            "steps_per_scenario": {"mean": round(float(steps.mean()), 2), "max": int(steps.max())},
        }

    def __repr__(self) -> str:
        return f"Suite({self.name!r}, version={self.version!r})"


def load_suite(name_or_path: str | os.PathLike | Suite, *, cache: bool = True) -> Suite:
    """A suite by built-in name (``"twin15"``; ``"tiny"``, ``EXAMPLE_SUITES``) or suite folder path.

    Loading is lazy: records are generated/read and packed on first use, and
    later loads come from the packed cache. Raises DriveE2EError for an
    unknown name or a missing folder.
    """
    if isinstance(name_or_path, Suite):
        return name_or_path
    text = os.fspath(name_or_path)
    if text in BUILTIN_SUITES:
        return Suite(_Builtin(text), cache=cache)
    path = EXAMPLE_SUITES.get(text) or Path(text).expanduser()
    if path.is_dir():
        return Suite(_Folder(path), cache=cache)
    if path.exists():
        raise DriveE2EError(f"{text} is a file; expected a suite folder (with suite.json) or a built-in suite "
                            f"name ({', '.join(BUILTIN_SUITES)})")
    if os.sep in text or text.startswith((".", "~")):
        raise DriveE2EError(f"suite folder {text} does not exist; expected a folder with suite.json, maps/, scenarios/")
    raise DriveE2EError(f"unknown suite {text!r}; expected a built-in suite name ({', '.join([*BUILTIN_SUITES, *EXAMPLE_SUITES])}) "
                        "or the path of a suite folder")
