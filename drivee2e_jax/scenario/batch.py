"""The packed batch container and what works on it without records.

* ``SuiteMeta``: the host-side table, one row per packed scenario (defined
  in the JAX-free ``scenario.meta``, re-exported here).
* ``PackedBatch(scenario, meta)``: a padded ``types.Scenario`` (numpy leaves,
  leading axis B) and its meta table; ``select``, ``resize``, ``fit``, ``to_jax``.
* ``padding_efficiency``, ``fit_sizes``, ``resize`` (re-pad), ``bucket``
  (split by (agents, steps) to cut padding waste).

Records -> batch is ``pack.pack``; batch -> records is ``pack.unpack``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.flat import flatten_scenario, unflatten_scenario
from drivee2e_jax.scenario.meta import META_2D, META_NUM, META_STR, SuiteMeta
from drivee2e_jax.scenario.sizes import LEAVES, PackSizes

__all__ = [
    "META_STR", "META_NUM", "META_2D", "SuiteMeta", "PackedBatch", "padding_efficiency", "fit_sizes", "resize",
    "bucket",
]

_UNKNOWN = int(types.SignalState.UNKNOWN)

# --------------------------------------------------------------------------
# Packed batch
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class PackedBatch:
    """A padded batch: ``scenario`` (types.Scenario, numpy leaves with leading
    axis B) and its host ``meta`` table (row i describes batch row i)."""

    scenario: types.Scenario
    meta: SuiteMeta

    def __len__(self) -> int:
        return len(self.meta)

    @property
    def sizes(self) -> PackSizes:
        return PackSizes.of(self.scenario)

    @property
    def padding_efficiency(self) -> float:
        return padding_efficiency(self)

    def select(self, rows: Sequence[int] | np.ndarray) -> PackedBatch:
        """The rows ``rows`` (a new batch, same padded sizes)."""
        rows = np.asarray(rows, dtype=np.int64)
        flat = {k: np.asarray(v)[rows] for k, v in flatten_scenario(self.scenario).items()}
        return PackedBatch(unflatten_scenario(flat).validate(), self.meta.select(rows))

    def resize(self, sizes: PackSizes) -> PackedBatch:
        return resize(self, sizes)

    def fit(self) -> PackedBatch:
        """This batch with the tightest (rounded) sizes that hold its rows."""
        return resize(self, fit_sizes(self))

    def to_jax(self) -> types.Scenario:
        """The scenario pytree as JAX arrays on the default device."""

        return jax.device_put(self.scenario)

    def __repr__(self) -> str:
        s = self.sizes
        return (f"PackedBatch(B={len(self)}, A={s.agents}, T={s.steps}, L={s.lanes}, R={s.route}, "
                f"padding_efficiency={self.padding_efficiency:.2f})")


def padding_efficiency(batches: PackedBatch | Iterable[PackedBatch]) -> float:
    """Valid agent-steps / padded agent-steps over one batch or several."""
    if isinstance(batches, PackedBatch):
        batches = [batches]
    valid = padded = 0
    for b in batches:
        v = np.asarray(b.scenario.tracks.valid)
        valid += int(v.sum())
        padded += v.size
    return valid / padded if padded else 0.0


# --------------------------------------------------------------------------
# resize / fit / buckets
# --------------------------------------------------------------------------


def _used(f: dict[str, np.ndarray], meta: SuiteMeta) -> dict[str, np.ndarray]:
    """Per size name: (B,) the count each row actually uses."""

    def last(mask, axis):  # 1 + index of the last True along ``axis`` (0 if none)
        m = mask.any(axis=tuple(i for i in range(1, mask.ndim) if i != axis)) if mask.ndim > 2 else mask
        n = m.shape[-1]
        return np.where(m.any(-1), n - np.argmax(m[..., ::-1], axis=-1), 0)

    agents = last(f["tracks.valid"], 1)
    steps = np.maximum(last(f["tracks.valid"], 2), f["num_steps"])
    return {
        "agents": agents,
        "steps": steps,
        "lanes": last(f["map.lanes.valid"], 1),
        "points": np.maximum(last(f["map.lanes.point_valid"], 2), last(f["map.boundaries.point_valid"], 2)),
        "boundaries": last(f["map.boundaries.valid"], 1),
        "crosswalks": last(f["map.crosswalks.valid"], 1),
        "vertices": np.maximum.reduce([last(f[f"map.{p}.point_valid"], 2) for p in ("crosswalks", "drivable")]),
        "obstacle_vertices": last(f["map.obstacles.point_valid"], 2),
        "lane_vertices": last(f["map.lane_polygons.point_valid"], 2),
        "stop_lines": last(f["map.stop_line_valid"], 1),
        "drivable": last(f["map.drivable.valid"], 1),
        "obstacles": last(f["map.obstacles.valid"], 1),
        "route": last(f["route.valid"], 1),
        "successors": last(f["map.lane_successors"] >= 0, 2),
        "drivable_edges": last(f["map.drivable_edges_valid"], 1),
    }


def fit_sizes(batch: PackedBatch) -> PackSizes:
    """The tightest rounded sizes that hold every row of ``batch``."""
    used = _used({k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}, batch.meta)
    return PackSizes.rounded({k: int(v.max(initial=0)) for k, v in used.items()})


def _pad_axis(a: np.ndarray, axis: int, new: int, pad: Any) -> np.ndarray:
    old = a.shape[axis]
    if new <= old:
        return np.take(a, np.arange(new), axis=axis)
    widths = [(0, 0)] * a.ndim
    widths[axis] = (0, new - old)
    if pad == "edge":
        return np.pad(a, widths, mode="edge")
    return np.pad(a, widths, mode="constant", constant_values=pad)


def resize(batch: PackedBatch, sizes: PackSizes) -> PackedBatch:
    """Re-pad a batch to ``sizes`` without its records: axes grow with the
    pad values of ``LEAVES`` and shrink only over padding (otherwise a
    DriveE2EError names the scenario and the size that is too small)."""
    old = batch.sizes
    if old == sizes:
        return batch
    f = {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}
    used = _used(f, batch.meta)
    for k, counts in used.items():
        limit = getattr(sizes, k)
        if limit < getattr(old, k) and (counts > limit).any():
            b = int(np.flatnonzero(counts > limit)[0])
            raise DriveE2EError(f"scenario {str(batch.meta.scenario_id[b])!r}: needs {k}={int(counts[b])}, "
                                f"more than PackSizes.{k}={limit} (records are never truncated; pass larger sizes)")
    out = {}
    for name, a in f.items():
        axes, _, pad = LEAVES[name]
        for ax, size_name in enumerate(axes, start=1):
            if not isinstance(size_name, str):
                continue
            p = pad
            if pad == "signal":
                p = "edge" if size_name == "steps" else _UNKNOWN
            a = _pad_axis(a, ax, getattr(sizes, size_name), p)
        out[name] = a
    meta = dataclasses.replace(batch.meta, stop_line_group=_pad_axis(batch.meta.stop_line_group, 1, sizes.stop_lines, -1))
    return PackedBatch(unflatten_scenario(out).validate(), meta)


def bucket(batch: PackedBatch, num_buckets: int = 4) -> list[PackedBatch]:
    """Split a batch into <= ``num_buckets`` batches by (agents, steps) so that
    padding waste stays small; each bucket is re-fitted to its rows.

    Rows are grouped by their rounded (agents, steps) need, the groups sorted
    by area, and the sorted list cut into contiguous buckets minimising the
    total padded agent-steps (exact dynamic programme over the cut points).
    Row order inside a bucket follows the input; ``meta.index`` maps back.
    """
    if num_buckets < 1:
        raise DriveE2EError(f"num_buckets: expected an integer >= 1, got {num_buckets}")
    f = {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}
    used = _used(f, batch.meta)
    ra = 8 * np.maximum(1, np.ceil(used["agents"] / 8)).astype(np.int64)
    rt = 8 * np.maximum(1, np.ceil(used["steps"] / 8)).astype(np.int64)
    keys = sorted(set(zip(ra.tolist(), rt.tolist())), key=lambda k: (k[0] * k[1], k))
    count = {k: 0 for k in keys}
    for k in zip(ra.tolist(), rt.tolist()):
        count[k] += 1
    m = len(keys)
    k_max = min(num_buckets, m)

    def cost(i, j):  # keys[i:j] in one bucket
        a = max(k[0] for k in keys[i:j])
        t = max(k[1] for k in keys[i:j])
        return a * t * sum(count[k] for k in keys[i:j])

    best = {(0, 0): (0, None)}
    for c in range(1, k_max + 1):
        for j in range(1, m + 1):
            cands = [(best[(c - 1, i)][0] + cost(i, j), i) for i in range(j) if (c - 1, i) in best]
            if cands:
                best[(c, j)] = min(cands)
    c = min((c for c in range(1, k_max + 1) if (c, m) in best), key=lambda c: best[(c, m)][0])
    cuts, j = [], m
    while c > 0:
        i = best[(c, j)][1]
        cuts.append((i, j))
        j, c = i, c - 1
    out = []
    row_key = list(zip(ra.tolist(), rt.tolist()))
    for i, j in reversed(cuts):
        members = set(keys[i:j])
        rows = [r for r, k in enumerate(row_key) if k in members]
        out.append(batch.select(rows).fit())
    return out
