"""The array half of a ``Suite`` (imports JAX): pack records, and turn the
packed cache's npz into a ``PackedBatch`` and back.

``scenario.suite`` loads this module only when a batch is needed (packing a
cold cache, ``Suite.pack``), so that ``Suite.info`` / ``meta`` / ``splits``
served from the cache's sidecar (``scenario.cache``) never import JAX.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from drivee2e_jax import types
from drivee2e_jax.records import CATEGORIES, SuiteRecord
from drivee2e_jax.scenario.batch import PackedBatch, bucket, resize
from drivee2e_jax.scenario.cache import Sidecar, read_npz, write_cache
from drivee2e_jax.scenario.flat import flatten_scenario, unflatten_scenario
from drivee2e_jax.scenario.pack import pack
from drivee2e_jax.scenario.sizes import LEAVES

__all__ = ["build", "load_batch", "save_batch", "category_counts", "bucket", "resize"]

log = logging.getLogger("drivee2e.cache")


def category_counts(batch: PackedBatch) -> dict[str, int]:
    """Agent category name (``records.CATEGORIES`` order) -> number of valid tracks."""
    tr = batch.scenario.tracks
    cats = np.asarray(tr.category)[np.asarray(tr.valid).any(axis=-1)]
    counts = np.bincount(cats, minlength=len(CATEGORIES))
    return {c: int(counts[int(types.Category[c.upper()])]) for c in CATEGORIES}


def build(records: SuiteRecord) -> tuple[PackedBatch, dict[str, int]]:
    """The whole suite packed (leaves read-only, as when memory-mapped from
    the cache) and its category counts."""
    batch = pack(records.scenarios, records.maps)
    for leaf in flatten_scenario(batch.scenario).values():
        leaf.flags.writeable = False
    return batch, category_counts(batch)


def load_batch(sidecar: Sidecar) -> PackedBatch | None:
    """The cached batch the sidecar describes (memory-mapped, every member
    CRC-checked and matched against ``LEAVES`` and the meta); None when
    anything is off (logged: the caller rebuilds)."""
    npz = sidecar.npz
    try:
        if npz.stat().st_size != sidecar.npz_bytes:
            raise ValueError("size changed since the sidecar was written")
        flat = read_npz(npz)
        for k, (axes, dtype, _) in LEAVES.items():
            a = flat[k]
            if a.dtype != np.dtype(dtype) or a.ndim != 1 + len(axes) or a.shape[0] != len(sidecar.meta):
                raise ValueError(f"{k}: dtype {a.dtype} shape {a.shape} does not match the pack format")
        scenario = unflatten_scenario(flat).validate()
        if sidecar.meta.stop_line_group.shape[1] != scenario.map.stop_lines.shape[1]:
            raise ValueError("meta.stop_line_group does not match the stop lines")
        return PackedBatch(scenario, sidecar.meta)
    except Exception as e:  # noqa: BLE001 - any defect means "rebuild"
        log.warning("drivee2e: packed cache %s is unusable (%s: %s); rebuilding", npz, type(e).__name__, e)
        return None


def save_batch(paths: tuple[Path, Path], key: str, name: str, batch: PackedBatch,
               categories: dict[str, int]) -> None:
    """Write ``batch`` to the packed cache at ``paths`` (``cache.write_cache``)."""
    flat = {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}
    write_cache(paths, key, name, flat, batch.sizes.as_dict(), batch.meta, categories)
