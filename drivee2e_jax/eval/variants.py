"""Occlusion-filtered suite variants (the source's Table 6).

A recorded scenario carries every agent the infrastructure sensors tracked,
including ones the ego's own cameras never saw. A *variant* re-evaluates the
same scenarios (same ego, same route) with those agents removed:

* ``complete``: the scenarios as recorded (nothing removed);
* ``visible_vehicles``: agents never visible from the ego's cameras removed,
  vehicles only (cars, trucks, buses, vans, motorcycles, tricycles);
  pedestrians and cyclists are kept (``filters.KEPT_WHEN_VEHICLES``);
* ``visible_all``: every never-visible agent removed, whatever its category.

"Visible" is decided along the **reference run** (``log_replay``: the ego
on its logged poses), at every log step: an agent is visible at step k if
it is the first hit of at least one pixel of the surround camera rig
(``observe.visibility.camera_visible``, ``VisibilityConfig``) with the ego
at its logged pose of step k and every agent at its logged sample of step
k. The masks are computed for a packed batch in blocks of scenarios x steps
(one jitted vmap over both, one compilation) and cached under
``$DRIVEE2E_CACHE/visibility/`` (``files.cache_dir``), keyed by a digest of
the arrays they depend on (tracks, ego, obstacles) and the sensor config:
a second run of the same variant never recomputes them.

    from drivee2e_jax.eval.variants import suite_variant
    var = suite_variant(load_suite("twin15"), "val", "visible_vehicles")
    evaluate(policy, var.batch, None)
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
import re
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import atomic_write, cache_dir
from drivee2e_jax.observe import camera, raycast, visibility
from drivee2e_jax.records import CATEGORIES, SuiteRecord
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.scenario.batch import PackedBatch
from drivee2e_jax.scenario.filters import filter_invisible, filter_invisible_packed
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.scenario.suite import load_suite

__all__ = ["VARIANTS", "VisibilityConfig", "Variant", "check_variant", "reference_visibility",
           "cached_visibility", "apply_variant", "suite_variant", "variant_records"]

log = logging.getLogger("drivee2e.cache")

#: Variant names (module docstring), ``complete`` first.
VARIANTS = ("complete", "visible_vehicles", "visible_all")
#: ``filters.filter_invisible`` categories of each filtered variant.
_CATEGORIES = {"visible_vehicles": "vehicles", "visible_all": "all"}
#: Bump when the mask semantics change (orphans old cache files).
MASK_FORMAT = 1
#: Leaves the masks depend on (part of the cache key).
_KEY_LEAVES = ("tracks.xy", "tracks.yaw", "tracks.size", "tracks.category", "tracks.valid", "ego_index",
               "num_steps", "map.obstacles.xy", "map.obstacles.point_valid", "map.obstacles.valid",
               "map.obstacle_height")


@dataclasses.dataclass(frozen=True)
class VisibilityConfig:
    """The sensor model of the reference run (static under jit).

    Attributes:
      rig: the cameras (default: six surround 64 x 36 cameras, 100 m).
      scene: which objects the ray casts consider (default: as the
        simulator's sensors: the 32 nearest agents and 8 nearest obstacles
        within 100 m; an agent outside them at a step is not seen then).
      block: scenario-steps per jitted call (bounds memory; not in the key).
    """

    rig: camera.CameraRigConfig = camera.CameraRigConfig()
    scene: raycast.SceneConfig = raycast.SceneConfig()
    block: int = 256

    def key(self) -> str:
        return repr((self.rig, self.scene))


def check_variant(name: str) -> str:
    """``name`` if it is a variant, else a one-line DriveE2EError listing them."""
    if name not in VARIANTS:
        raise DriveE2EError(f"--variant {name!r}: unknown variant; expected one of {', '.join(VARIANTS)}")
    return name


# --------------------------------------------------------------------------
# Visibility along the logged ego run
# --------------------------------------------------------------------------


def _visible_at(scenario: types.Scenario, k: jnp.ndarray, cfg: VisibilityConfig) -> jnp.ndarray:
    """(A,) bool: agents the cameras see at log step ``k`` (one scenario,
    ego on its logged pose); False where the ego or the agent has no sample."""
    tr, ego, m = scenario.tracks, scenario.ego_index, scenario.map
    agents = AgentStates(xy=tr.xy[:, k], yaw=tr.yaw[:, k], vel=tr.vel[:, k], valid=tr.valid[:, k])
    ego_xy, ego_yaw = tr.xy[ego, k], tr.yaw[ego, k]
    scene = raycast.select_scene(ego_xy, agents, tr.size, tr.category, m.obstacles, m.obstacle_height,
                                 cfg.scene, exclude=ego)
    seen = visibility.camera_visible(scene, ego_xy, ego_yaw, tr.xy.shape[0], cfg.rig)
    return seen & tr.valid[:, k] & tr.valid[ego, k]


@functools.partial(jax.jit, static_argnames="cfg")
def _block(scenarios: types.Scenario, steps: jnp.ndarray, cfg: VisibilityConfig) -> jnp.ndarray:
    """(S, A, Tb) masks of S scenarios at the Tb steps ``steps``."""
    per_step = jax.vmap(_visible_at, in_axes=(None, 0, None), out_axes=1)
    return jax.vmap(per_step, in_axes=(0, None, None))(scenarios, steps, cfg)


def reference_visibility(batch: PackedBatch, cfg: VisibilityConfig = VisibilityConfig(),
                         progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """(B, A, T) bool: agent row a of scenario b is visible from the ego's
    cameras at log step k of the reference run (module docstring).

    Blocks of ``s`` scenarios x ``tb`` steps (``s * tb <= cfg.block``) share
    one compilation; the last blocks are padded by repetition.
    ``progress(done, total)`` after each block (scenario-steps).
    """
    b, a, t = batch.scenario.tracks.valid.shape
    tb = min(t, max(1, cfg.block))
    s = max(1, min(b, cfg.block // tb))
    out = np.zeros((b, a, t), bool)
    total, done = b * t, 0
    for i in range(0, b, s):
        rows = np.minimum(np.arange(i, i + s), b - 1)
        chunk = jax.tree_util.tree_map(lambda x, rows=rows: jnp.asarray(np.asarray(x)[rows]), batch.scenario)
        n = min(s, b - i)
        for j in range(0, t, tb):
            steps = np.minimum(np.arange(j, j + tb), t - 1)
            got = np.asarray(_block(chunk, jnp.asarray(steps, jnp.int32), cfg))
            m = min(tb, t - j)
            out[i:i + n, :, j:j + m] = got[:n, :, :m]
            done += n * m
            if progress is not None:
                progress(done, total)
    return out


def _digest(batch: PackedBatch, cfg: VisibilityConfig) -> str:
    flat = flatten_scenario(batch.scenario)
    h = hashlib.sha256(json.dumps({"format": MASK_FORMAT, "sensor": cfg.key()}).encode())
    for k in _KEY_LEAVES:
        a = np.ascontiguousarray(np.asarray(flat[k]))
        h.update(f"{k}{a.dtype}{a.shape}".encode())
        h.update(a.data)
    return h.hexdigest()


def cached_visibility(batch: PackedBatch, label: str, cfg: VisibilityConfig = VisibilityConfig(),
                      progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """``reference_visibility(batch, cfg)``, from / to the mask cache.

    The cache file is ``<cache_dir>/visibility/<label>-<digest>.npz``
    (``label`` names it for people, e.g. ``twin15-val``; the digest covers the
    batch's tracks, ego, obstacles and ``cfg``), written atomically; with
    caching off (``DRIVEE2E_CACHE=off``) the masks are always computed. A
    cache file that does not match is recomputed and replaced.
    """

    root = cache_dir()
    key = _digest(batch, cfg)
    shape = batch.scenario.tracks.valid.shape
    path = None
    if root is not None:
        path = root / "visibility" / f"{re.sub(r'[^A-Za-z0-9_.-]', '_', label)[:60]}-{key[:16]}.npz"
        try:
            with np.load(path) as z:
                if str(z["key"]) == key and z["visible"].shape == shape and z["visible"].dtype == bool:
                    return z["visible"]
            log.warning("drivee2e: visibility cache %s does not match; recomputing", path)
        except FileNotFoundError:
            pass
        except Exception as e:  # noqa: BLE001 - any defect means "recompute"
            log.warning("drivee2e: visibility cache %s is unusable (%s: %s); recomputing", path, type(e).__name__, e)
    visible = reference_visibility(batch, cfg, progress)
    if path is not None:
        try:
            atomic_write(path, lambda f: np.savez_compressed(f, key=np.array(key), visible=visible), binary=True)
        except OSError as e:
            log.warning("drivee2e: could not write the visibility cache %s (%s)", path, e)
    return visible


# --------------------------------------------------------------------------
# Variants
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Variant:
    """A suite split as one variant.

    Attributes:
      name: one of ``VARIANTS``.
      batch: the packed batch to evaluate (same padded sizes and scenario
        rows as the complete one; removed agents are padding).
      record: the filter record (``filters.filter_invisible``: categories,
        removed_tracks, removed {scenario_id: [track ids]}); {} for complete.
      by_category: category -> (removed, non-ego agents in the complete batch).
    """

    name: str
    batch: PackedBatch
    record: dict
    by_category: dict[str, tuple[int, int]]

    @property
    def removed(self) -> int:
        return sum(r for r, _ in self.by_category.values())

    @property
    def agents(self) -> int:
        return sum(n for _, n in self.by_category.values())

    def summary(self) -> str:
        """One line: how many agents were removed, per category."""
        pct = 100.0 * self.removed / max(self.agents, 1)
        cats = ", ".join(f"{c} {r}/{n}" for c, (r, n) in self.by_category.items() if n)
        return (f"variant {self.name}: removed {self.removed} of {self.agents} non-ego agents ({pct:.1f} %) "
                f"in {len(self.record.get('removed', {}))} of {len(self.batch)} scenarios; by category: {cats}")


def _other_agents(batch: PackedBatch) -> np.ndarray:
    """(B, A) bool: rows holding a non-ego agent."""
    tr = batch.scenario.tracks
    present = np.asarray(tr.valid).any(-1)
    present[np.arange(len(batch)), np.asarray(batch.scenario.ego_index)] = False
    return present


def _by_category(complete: PackedBatch, filtered: PackedBatch) -> dict[str, tuple[int, int]]:
    def counts(batch):
        cat = np.asarray(batch.scenario.tracks.category)[_other_agents(batch)]
        return np.bincount(cat, minlength=len(CATEGORIES))

    before, after = counts(complete), counts(filtered)
    return {c: (int(before[i] - after[i]), int(before[i]))
            for c in CATEGORIES for i in [int(types.Category[c.upper()])]}


def apply_variant(batch: PackedBatch, name: str, label: str = "batch", cfg: VisibilityConfig = VisibilityConfig(),
                  progress: Callable[[int, int], None] | None = None) -> Variant:
    """``batch`` as variant ``name`` (``complete``: unchanged, no masks
    computed). ``label`` names the mask cache file (``cached_visibility``)."""
    check_variant(name)
    if name == "complete":
        filtered, record = batch, {}
    else:
        visible = cached_visibility(batch, label, cfg, progress)
        filtered, record = filter_invisible_packed(batch, visible, _CATEGORIES[name])
    return Variant(name, filtered, record, _by_category(batch, filtered))


def suite_variant(suite, split: str | None, name: str, cfg: VisibilityConfig = VisibilityConfig(),
                  progress: Callable[[int, int], None] | None = None) -> Variant:
    """Split ``split`` of ``suite`` (a ``Suite``, name or folder) as variant ``name``."""

    check_variant(name)
    suite = load_suite(suite)
    return apply_variant(suite.pack(split), name, f"{suite.name}-{split or 'all'}", cfg, progress)


def variant_records(suite, split: str | None, name: str, cfg: VisibilityConfig = VisibilityConfig()) -> SuiteRecord:
    """The records of ``split`` as variant ``name`` (``filters.filter_invisible``
    with the same cached masks), e.g. to write a variant suite folder with
    ``schema.write_suite``. Needs the suite's records (twin15 generates them)."""

    check_variant(name)
    suite = load_suite(suite)
    batch = suite.pack(split)
    ids = set(batch.meta.scenario_id.tolist())
    rec = suite.records
    rec = dataclasses.replace(rec, scenarios=[s for s in rec.scenarios if s.scenario_id in ids])
    if name == "complete":
        return rec
    visible = cached_visibility(batch, f"{suite.name}-{split or 'all'}", cfg)
    masks = {str(sid): visible[i] for i, sid in enumerate(batch.meta.scenario_id)}
    return filter_invisible(rec, masks, _CATEGORIES[name])
