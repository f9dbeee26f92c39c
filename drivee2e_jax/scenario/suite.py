"""Suites: a named set of scenarios, loaded once and packed from a disk cache.

``load_suite("twin15")`` is the built-in generated suite; ``load_suite(path)``
reads a suite folder (``scenario.schema``). Either way the whole suite is
packed once (``scenario.pack``) and kept in a **packed cache** under
``$DRIVEE2E_CACHE`` (default ``~/.cache/drivee2e``; ``DRIVEE2E_CACHE=off``
disables it): ``suites/<name>-<source>-<key>.npz`` (np.savez, uncompressed,
one array per ``sizes.LEAVES`` name) plus a ``.json`` sidecar with the meta
table and category counts (``scenario.cache``). The key hashes the suite
name, the generator ``VERSION`` (built-in) or the files' paths/sizes/mtimes
(folder), the schema version and the pack format, so any change rebuilds.
Both files are written atomically. The npz is read back memory-mapped (no
copy; a 0.5 GB suite loads in ~0.3 s) with every member checked against its
zip CRC; a cache that fails any check (size, CRC, dtype, shape, meta) is
rebuilt, never trusted.

This module imports no JAX: ``name``, ``version``, ``ready``, ``meta``,
``splits`` and ``info()`` of a suite whose cache is warm come from the
sidecar (a built-in generator's ``VERSION`` is read from its source), and
``scenario.suite_arrays`` (packing, the batch; JAX) is loaded only when a
batch is needed or the cache is cold.

Splits are rows of the cached full-suite batch: ``suite.pack("val")`` never
regenerates or re-reads records, and every split shares the suite's padded
sizes (one compilation serves all splits). ``.records`` is loaded only when
asked for.
"""

from __future__ import annotations

import ast
import hashlib
import importlib
import importlib.util
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import loads_json
from drivee2e_jax.records import BEHAVIORS, SPLITS, TIMES_OF_DAY, WEATHERS, SuiteRecord
from drivee2e_jax.scenario import schema
from drivee2e_jax.scenario.cache import CACHE_FORMAT as CACHE_FORMAT  # re-exported: it was defined here
from drivee2e_jax.scenario.cache import Sidecar, cache_key, cache_paths, read_sidecar
from drivee2e_jax.scenario.meta import SuiteMeta
from drivee2e_jax.scenario.problems import Problem, problems_error
from drivee2e_jax.scenario.validate import validate_records

if TYPE_CHECKING:
    from drivee2e_jax.scenario.batch import PackedBatch
    from drivee2e_jax.scenario.sizes import PackSizes

__all__ = ["Suite", "load_suite", "generate_suite", "BUILTIN_SUITES"]

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
        if self._module is None and self.module_name not in sys.modules:
            declared = _declared_version(self.module_name)
            if declared is not None:
                return declared
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


def _declared_version(module_name: str) -> str | None:
    """``VERSION`` as the generator module's source assigns it, read without
    importing the module; None unless it is one top-level ``VERSION = <str or
    int literal>`` that nothing else in the file rebinds (then the caller
    imports the module). The cache key needs only this, and importing twin15
    runs its whole generator's imports, JAX included (~0.9 s)."""
    try:
        spec = importlib.util.find_spec(module_name)
        origin = Path(spec.origin) if spec is not None and spec.origin else None
        if origin is None or origin.suffix != ".py":
            return None
        tree = ast.parse(origin.read_bytes(), filename=str(origin))
    except (ImportError, ValueError, OSError, SyntaxError):
        return None
    binds = [n for n in ast.walk(tree)
             if (isinstance(n, ast.Name) and n.id == "VERSION" and not isinstance(n.ctx, ast.Load))
             or (isinstance(n, ast.alias) and (n.asname or n.name) in ("VERSION", "*"))
             or (isinstance(n, (ast.Global, ast.Nonlocal)) and "VERSION" in n.names)]
    top = [n for n in tree.body if isinstance(n, (ast.Assign, ast.AnnAssign)) and n.value is not None
           and any(isinstance(t, ast.Name) and t.id == "VERSION" for t in (n.targets if isinstance(n, ast.Assign) else [n.target]))]
    if len(binds) != 1 or len(top) != 1:
        return None
    value = top[0].value
    if not isinstance(value, ast.Constant) or type(value.value) not in (str, int):
        return None
    return str(value.value)


class _Folder:
    def __init__(self, path: Path):
        self.path = path.resolve()
        head_path = self.path / "suite.json"
        if not head_path.is_file():
            raise DriveE2EError(f"{path} is not a suite folder: expected a suite.json in it")
        try:
            head = loads_json(head_path.read_bytes())
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


def _arrays():
    """``scenario.suite_arrays``, the JAX half (packing, the npz <-> PackedBatch)."""
    from drivee2e_jax.scenario import suite_arrays  # noqa: PLC0415 - it imports JAX (~1 s): only when a batch is needed, so that info / meta / splits from the sidecar stay JAX-free

    return suite_arrays


class _Packed:
    """The full suite: meta + category counts (sidecar) and the batch (npz, lazy)."""

    def __init__(self, meta: SuiteMeta, categories: dict[str, int], batch: PackedBatch | None = None,
                 sidecar: Sidecar | None = None):
        self.meta, self.categories, self._batch, self.sidecar = meta, categories, batch, sidecar

    @classmethod
    def of(cls, sidecar: Sidecar | None) -> _Packed | None:
        return None if sidecar is None else cls(sidecar.meta, sidecar.categories, sidecar=sidecar)

    def batch(self) -> PackedBatch | None:
        if self._batch is None and self.sidecar is not None:
            self._batch = _arrays().load_batch(self.sidecar)
        return self._batch


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
        key = cache_key(self._source.key_parts(), self.name)
        return cache_paths(self._source.name, self._source.source_id(), key), key

    @property
    def ready(self) -> bool:
        """True when the packed suite is at hand (in memory or in a valid disk
        cache): using it will not generate or read records. Lets a CLI say
        "building the cache" before a long first load."""
        if self._packed is None:
            paths, key = self._cache_target()
            if paths is not None:
                self._packed = _Packed.of(read_sidecar(*paths, key))
        return self._packed is not None

    def _full(self) -> _Packed:
        if self._packed is None:
            paths, key = self._cache_target()
            packed = _Packed.of(read_sidecar(*paths, key)) if paths is not None else None
            self._packed = packed or self._build(paths, key)
        return self._packed

    def _build(self, paths, key) -> _Packed:
        arrays = _arrays()
        batch, categories = arrays.build(self.records)
        if paths is not None:
            arrays.save_batch(paths, key, self.name, batch, categories)
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
        return batch if sizes is None else _arrays().resize(batch, sizes)

    def pack_buckets(self, split: str | None = None, num_buckets: int = 4) -> list[PackedBatch]:
        """``split`` as a few batches grouped by (agents, steps), each fitted."""
        return _arrays().bucket(self.pack(split), num_buckets)

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
