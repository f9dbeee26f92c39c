"""The packed cache on disk, JAX-free: key, paths, JSON sidecar, raw npz members.

A packed suite is kept as ``<cache>/suites/<name>-<source>-<key16>.npz``
(``np.savez``, uncompressed, one array per ``sizes.LEAVES`` name) plus a
``.json`` sidecar: ``{"format", "key", "suite", "schema_version",
"pack_format", "npz_bytes", "sizes", "categories", "meta"}`` (``meta`` is
``SuiteMeta.to_json()``, ``categories`` agent category -> number of tracks).
Both files are written atomically, the npz first, so a sidecar always
describes a complete npz.

Nothing here imports JAX: ``drivee2e suite info`` answers from the sidecar
alone (``read_sidecar``) in a fraction of a second. Turning the npz members
into a ``PackedBatch`` (and back) is ``scenario.suite_arrays``.
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import mmap
import re
import struct
import zipfile
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_jax.files import atomic_write, cache_dir, read_json
from drivee2e_jax.records import SCHEMA_VERSION
from drivee2e_jax.scenario.meta import SuiteMeta

__all__ = ["CACHE_FORMAT", "PACK_FORMAT", "Sidecar", "cache_key", "cache_paths", "read_sidecar", "read_npz",
           "write_cache"]

log = logging.getLogger("drivee2e.cache")

#: Layout version of the cache files (bump to orphan old caches).
CACHE_FORMAT = 1

#: Version of the packed-array semantics (``scenario.pack`` re-exports it);
#: bump it when they change so that on-disk packed caches are rebuilt. It
#: lives here so that the cache key is computed without importing ``pack``
#: (which imports JAX).
PACK_FORMAT = 5  # 2: obstacle footprints have their own vertex count; 3: map.lane_polygons, map.drivable_edges;
# 4: positions in a local frame per map (meta.origin); 5: a lane's own polygon (LaneRecord.polygon) moves with it


def cache_key(source_parts: Mapping[str, Any], name: str) -> str:
    """Hex sha256 of everything a packed suite depends on: the cache, pack and
    schema formats, the suite ``name`` and the source's ``source_parts``
    (generator version and seed, or the folder's file paths/sizes/mtimes)."""
    parts = {"cache": CACHE_FORMAT, "pack": PACK_FORMAT, "schema": SCHEMA_VERSION, "name": name, **source_parts}
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()


def cache_paths(name: str, source_id: str, key: str) -> tuple[Path, Path] | None:
    """(npz, sidecar) paths of a packed suite; None when caching is off
    (``$DRIVEE2E_CACHE=off``)."""
    root = cache_dir()
    if root is None:
        return None
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", name)[:40]
    stem = root / "suites" / f"{safe}-{source_id}-{key[:16]}"
    return stem.with_suffix(".npz"), stem.with_suffix(".json")


@dataclass(frozen=True)
class Sidecar:
    """A valid sidecar: the suite's ``meta`` (B rows), ``categories`` (agent
    category -> number of tracks) and the ``npz`` it describes, whose size in
    bytes (``npz_bytes``) matched when it was read."""

    meta: SuiteMeta
    categories: dict[str, int]
    npz: Path
    npz_bytes: int


def read_sidecar(npz: Path, side: Path, key: str) -> Sidecar | None:
    """The sidecar at ``side`` if it is for ``key`` and its npz is there with
    the recorded size; None otherwise (a defect is logged: the caller rebuilds)."""
    try:
        head = read_json(side)
        if head.get("format") != CACHE_FORMAT or head.get("key") != key:
            return None
        meta = SuiteMeta.from_json(head["meta"])
        categories = {str(k): int(v) for k, v in head["categories"].items()}
        if not npz.is_file() or npz.stat().st_size != int(head["npz_bytes"]):
            raise ValueError(f"{npz.name} is missing or has the wrong size")
        return Sidecar(meta, categories, npz, int(head["npz_bytes"]))
    except FileNotFoundError:
        return None
    except Exception as e:  # noqa: BLE001 - any defect means "rebuild"
        log.warning("drivee2e: packed cache %s is unusable (%s: %s); rebuilding", side, type(e).__name__, e)
        return None


def read_npz(path: Path) -> dict[str, np.ndarray]:
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


def write_cache(paths: tuple[Path, Path], key: str, name: str, flat: Mapping[str, np.ndarray],
                sizes: Mapping[str, int], meta: SuiteMeta, categories: Mapping[str, int]) -> None:
    """Write the npz (``flat``: leaf name -> (B, ...) array) and then its
    sidecar, atomically; remove older entries of the same suite and source.
    A failure to write is logged, never raised (the suite works uncached)."""
    npz, side = paths
    try:
        npz.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(npz, lambda fh: np.savez(fh, **flat), binary=True)
        head = {"format": CACHE_FORMAT, "key": key, "suite": name, "schema_version": SCHEMA_VERSION,
                "pack_format": PACK_FORMAT, "npz_bytes": npz.stat().st_size,
                "sizes": dict(sizes), "categories": dict(categories), "meta": meta.to_json()}
        atomic_write(side, lambda fh: fh.write(json.dumps(head, separators=(",", ":")).encode()), binary=True)
        prefix = npz.stem.rsplit("-", 1)[0]
        for old in npz.parent.glob(f"{prefix}-*"):
            if old.stem != npz.stem and old.suffix in (".npz", ".json"):
                old.unlink(missing_ok=True)
    except OSError as e:
        log.warning("drivee2e: could not write the packed cache %s (%s); continuing without it", npz, e)
