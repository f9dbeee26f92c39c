"""Host-side suite variants: drop agents the ego's sensors never see.

A recorded scenario carries every annotated agent, including ones hidden
behind buildings for the whole log. A suite *variant* without them asks a
policy only about what it could perceive, and packs smaller. The masks come
from outside (the sensor model's per-step visibility, e.g. ``observe``);
nothing here runs under ``jit`` and the input suite is not changed.

Mask alignment
--------------
``visible[scenario_id]`` is a ``(A, T)`` bool array in the row order of the
packed tracks (``pack.track_order``, the order of ``tracks.*`` in a
``PackedBatch``): row 0 is the ego, rows ``1..n-1`` the other tracks by
ascending ``track_id``; column ``k`` is log step ``k`` (``t = k * dt``).
Padded masks are accepted: ``A`` may exceed the scenario's track count and
``T`` its ``num_steps`` (the extra rows and columns, which a packed batch pads
to the suite's largest scenario, are ignored). A True at a step where the
track has no sample counts for nothing (only sampled steps can be seen).

    from drivee2e_jax.scenario.filters import filter_invisible
    variant = filter_invisible(suite_records, {s_id: mask, ...}, categories="vehicles")

``filter_invisible_packed`` does the same to a packed batch (one (B, A, T)
mask in the batch's own rows) and returns exactly what packing the filtered
records with the same sizes gives: kept rows move up, freed rows are padding.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Literal

import numpy as np

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import CATEGORIES, ScenarioRecord, SuiteRecord
from drivee2e_jax.scenario.batch import PackedBatch
from drivee2e_jax.scenario.flat import flatten_scenario, unflatten_scenario
from drivee2e_jax.scenario.pack import track_order
from drivee2e_jax.scenario.sizes import LEAVES

__all__ = ["FILTER_CATEGORIES", "KEPT_WHEN_VEHICLES", "filter_invisible", "filter_invisible_packed",
           "never_visible", "removable_categories"]

#: Which agents ``filter_invisible`` may remove.
FILTER_CATEGORIES = ("vehicles", "all")
#: With ``categories="vehicles"`` these are kept even when never visible
#: (vulnerable road users: a policy should not learn that an unseen one is absent).
KEPT_WHEN_VEHICLES = ("pedestrian", "cyclist")


def never_visible(s: ScenarioRecord, mask: np.ndarray) -> list[int]:
    """Track ids of ``s`` (other than the ego) with no visible sampled step in
    ``mask`` (aligned as the module docstring says)."""
    order = track_order(s)
    m = np.asarray(mask)
    if m.ndim != 2 or m.shape[0] < len(order) or m.shape[1] < s.num_steps:
        raise DriveE2EError(f"scenario {s.scenario_id!r}: visibility mask: expected shape (>= {len(order)} tracks, "
                            f">= {s.num_steps} steps) in the packed track order, got {m.shape}")
    if m.dtype != bool:
        raise DriveE2EError(f"scenario {s.scenario_id!r}: visibility mask: expected dtype bool, got {m.dtype}")
    out = []
    for row, tr in enumerate(order[1:], start=1):
        k = np.rint(np.asarray(tr.t, np.float64) / s.dt).astype(np.int64)
        k = k[(k >= 0) & (k < s.num_steps)]
        if not m[row, k].any():
            out.append(int(tr.track_id))
    return out


def filter_invisible(suite: SuiteRecord, visible: Mapping[str, np.ndarray],
                     categories: Literal["vehicles", "all"] = "vehicles") -> SuiteRecord:
    """A copy of ``suite`` without the non-ego agents never visible over their scenario.

    Args:
      suite: the suite (not modified).
      visible: scenario id -> (A, T) bool mask, one per scenario of the suite
        (alignment: module docstring).
      categories: ``"vehicles"`` removes invisible agents of every category
        except :data:`KEPT_WHEN_VEHICLES`; ``"all"`` removes every invisible
        agent. The ego is never removed.

    Returns:
      A new SuiteRecord (maps shared, scenarios copied) whose ``meta["filters"]``
      list gains ``{"filter": "invisible", "categories", "removed_tracks",
      "removed": {scenario_id: [track ids]}}`` (scenarios with nothing removed
      are left out of ``removed``).
    """
    removable = removable_categories(categories)
    ids = {s.scenario_id for s in suite.scenarios}
    missing = [s.scenario_id for s in suite.scenarios if s.scenario_id not in visible]
    if missing:
        raise DriveE2EError(f"visible: no mask for scenario {missing[0]!r} ({len(missing)} missing); "
                            "expected one per scenario of the suite")
    extra = sorted(set(visible) - ids)
    if extra:
        raise DriveE2EError(f"visible: scenario {extra[0]!r} is not in suite {suite.name!r}")
    scenarios, removed = [], {}
    for s in suite.scenarios:
        unseen = set(never_visible(s, visible[s.scenario_id]))
        drop = {tr.track_id for tr in s.tracks if tr.track_id in unseen and tr.category in removable}
        if drop:
            removed[s.scenario_id] = sorted(drop)
        scenarios.append(replace(s, tracks=[tr for tr in s.tracks if tr.track_id not in drop]))
    meta = dict(suite.meta)
    meta["filters"] = [*meta.get("filters", []), _filter_record(categories, removed)]
    return replace(suite, scenarios=scenarios, meta=meta)


def removable_categories(categories: str) -> tuple[str, ...]:
    """The category names ``filter_invisible(..., categories)`` may remove."""
    if categories not in FILTER_CATEGORIES:
        raise DriveE2EError(f"categories: expected one of {', '.join(FILTER_CATEGORIES)}, got {categories!r}")
    return tuple(c for c in CATEGORIES if categories == "all" or c not in KEPT_WHEN_VEHICLES)


def _filter_record(categories: str, removed: dict[str, list[int]]) -> dict:
    return {"filter": "invisible", "categories": categories,
            "removed_tracks": sum(len(v) for v in removed.values()), "removed": removed}


def filter_invisible_packed(batch: PackedBatch, visible: np.ndarray,
                            categories: Literal["vehicles", "all"] = "vehicles") -> tuple[PackedBatch, dict]:
    """``filter_invisible`` on a packed batch.

    Args:
      batch: the batch (not modified).
      visible: (B, A, T) bool in the batch's rows and padded sizes (row b,
        agent row a, log step k); only steps where the agent is valid count.
      categories: as for ``filter_invisible``.

    Returns:
      (the filtered batch, same padded sizes and meta except ``num_agents``:
      kept agent rows keep their order and move up, freed rows become
      padding, bit for bit what ``pack`` of the filtered records gives;
      the filter record of ``filter_invisible``'s ``meta["filters"]``).
    """
    codes = [int(types.Category[c.upper()]) for c in removable_categories(categories)]
    flat = {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}
    valid = flat["tracks.valid"]
    vis = np.asarray(visible)
    if vis.shape != valid.shape or vis.dtype != bool:
        raise DriveE2EError(f"visible: expected a bool array of shape {valid.shape} (batch, agents, steps), "
                            f"got {vis.dtype} {vis.shape}")
    b, a = valid.shape[:2]
    ego = flat["ego_index"].astype(np.int64)
    drop = valid.any(-1) & ~(vis & valid).any(-1) & np.isin(flat["tracks.category"], codes)
    drop[np.arange(b), ego] = False
    order = np.argsort(drop, axis=1, kind="stable")  # kept rows first (in order), dropped rows last
    freed = np.arange(a)[None, :] >= (a - drop.sum(1))[:, None]
    for name, (_axes, _, pad) in LEAVES.items():
        if name.startswith("tracks."):
            leaf = flat[name]
            idx = order.reshape(order.shape + (1,) * (leaf.ndim - 2))
            leaf = np.take_along_axis(leaf, idx, axis=1)
            leaf[freed] = pad
            flat[name] = leaf
    flat["ego_index"] = np.argmax(order == ego[:, None], axis=1).astype(flat["ego_index"].dtype)
    track_id = np.asarray(batch.scenario.tracks.track_id)
    removed = {str(sid): sorted(int(t) for t in track_id[i][drop[i]])
               for i, sid in enumerate(batch.meta.scenario_id) if drop[i].any()}
    meta = replace(batch.meta, num_agents=(batch.meta.num_agents - drop.sum(1)).astype(batch.meta.num_agents.dtype))
    return PackedBatch(unflatten_scenario(flat).validate(), meta), _filter_record(categories, removed)
