"""Orbax checkpoints of a training run: one per epoch, resumable.

Layout::

    RUN/checkpoints/<epoch>/state/      Orbax StandardCheckpointer: {"params", "opt_state", "step"}
    RUN/checkpoints/<epoch>/meta.json   epoch, step, model, config, data digest (written last:
                                        a checkpoint without it is incomplete and ignored)

``load_params`` accepts a run folder (its last epoch), its ``checkpoints/``
folder, or one ``checkpoints/<epoch>``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import shutil
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import atomic_write_json, loads_json
from drivee2e_jax.jsonfile import BadJSON, read_json
from drivee2e_jax.observe.bev import BevConfig

META = "meta.json"
#: A demonstrations dataset folder's manifest (``train.dataset``) and its format.
DATA_MANIFEST = "manifest.json"
DATA_FORMAT = 1
#: The BEV of datasets whose manifest predates recording it.
DEFAULT_BEV = BevConfig()


def _checkpointer():
    return ocp.StandardCheckpointer()


def checkpoint_dir(run_dir: str | Path, epoch: int) -> Path:
    return Path(run_dir) / "checkpoints" / str(int(epoch))


def save(run_dir: str | Path, epoch: int, state: dict, meta: dict) -> Path:
    """Write ``state`` (a pytree: params, opt_state, step) and ``meta`` (JSON)
    as the checkpoint of ``epoch``; returns its folder. Overwrites an
    incomplete or existing checkpoint of the same epoch."""

    d = checkpoint_dir(run_dir, epoch).resolve()
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    ck = _checkpointer()
    ck.save(d / "state", jax.tree_util.tree_map(np.asarray, state))
    ck.wait_until_finished()
    atomic_write_json(d / META, {**meta, "epoch": int(epoch)})
    return d


def list_checkpoints(run_dir: str | Path) -> list[Path]:
    """Complete checkpoint folders of a run, by epoch."""
    root = Path(run_dir) / "checkpoints"
    if not root.is_dir():
        return []
    eps = sorted(int(p.name) for p in root.iterdir() if p.name.isdigit() and (p / META).is_file())
    return [root / str(e) for e in eps]


def read_meta(ckpt: str | Path) -> dict:
    f = Path(ckpt) / META
    try:
        return read_json(f)
    except BadJSON as e:  # the guarded reader: names the file, the place and what was expected
        raise DriveE2EError(f"{f}: unreadable checkpoint metadata ({e.detail})") from e
    except OSError as e:
        raise DriveE2EError(f"{f}: unreadable checkpoint metadata ({e})") from e


def restore(ckpt: str | Path, target: Any = None) -> dict:
    """The state pytree of checkpoint folder ``ckpt``; with ``target`` (a pytree
    of the same structure, e.g. fresh params + opt state) the result has its
    structure, else plain dicts / arrays."""
    d = Path(ckpt).resolve()
    if not (d / "state").is_dir():
        raise DriveE2EError(f"{ckpt}: not a checkpoint folder (expected state/ and {META} inside)")
    ck = _checkpointer()
    if target is None:
        return ck.restore(d / "state")
    abstract = jax.tree_util.tree_map(ocp.utils.to_shape_dtype_struct, jax.tree_util.tree_map(np.asarray, target))
    return ck.restore(d / "state", abstract)


def resolve(path: str | Path) -> Path:
    """One checkpoint folder from a run folder, ``checkpoints/`` or a checkpoint."""
    p = Path(path)
    if (p / META).is_file():
        return p
    for root in (p, p.parent if p.name == "checkpoints" else None):
        if root is not None:
            found = list_checkpoints(root)
            if found:
                return found[-1]
    raise DriveE2EError(f"{path}: no checkpoint found (expected a run folder, its checkpoints/ or checkpoints/<epoch>)")


def load_params(path: str | Path):
    """The model parameters stored at ``path`` (see ``resolve``)."""
    return restore(resolve(path))["params"]


def bev_of_manifest(manifest: dict) -> BevConfig | None:
    """The BEV a dataset was rendered at (None: no BEV); manifests from before
    the size was recorded used the default 128 x 128 at 0.5 m/px."""
    if "bev" not in manifest.get("sensors", ()):
        return None
    b = manifest.get("bev") or {}
    return dataclasses.replace(DEFAULT_BEV, height=int(b.get("height", DEFAULT_BEV.height)),
                               width=int(b.get("width", DEFAULT_BEV.width)),
                               resolution=float(b.get("resolution", DEFAULT_BEV.resolution)))


def training_bev(meta: dict) -> BevConfig | None:
    """The BEV the training data of a checkpoint (its ``meta.json``) was
    rendered at: ``meta["data_bev"]`` (the manifest's ``"bev"``) when the
    training loop stored one, else the manifest of ``meta["config"]["data"]``
    when that folder still holds the data trained on (same digest); None when
    unknown or without a BEV."""
    if meta.get("data_bev"):
        return bev_of_manifest({"sensors": ["bev"], "bev": meta["data_bev"]})
    data = (meta.get("config") or {}).get("data")
    if not data:
        return None
    try:
        raw = (Path(data) / DATA_MANIFEST).read_bytes()
        manifest = loads_json(raw)
    except (OSError, ValueError):
        return None
    if not isinstance(manifest, dict) or manifest.get("format") != DATA_FORMAT:
        return None
    if meta.get("data_digest") not in (None, hashlib.sha256(raw).hexdigest()):
        return None
    return bev_of_manifest(manifest)
