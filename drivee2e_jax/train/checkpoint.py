"""Orbax checkpoints of a training run: one per epoch, resumable.

Layout::

    RUN/checkpoints/<epoch>/state/      Orbax StandardCheckpointer: {"params", "opt_state", "step"}
    RUN/checkpoints/<epoch>/meta.json   epoch, step, model, config, data digest (written last:
                                        a checkpoint without it is incomplete and ignored)

``load_params`` accepts a run folder (its last epoch), its ``checkpoints/``
folder, or one ``checkpoints/<epoch>``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import jax
import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.io.results import atomic_write_json

META = "meta.json"


def _checkpointer():
    import orbax.checkpoint as ocp

    return ocp.StandardCheckpointer()


def checkpoint_dir(run_dir: str | Path, epoch: int) -> Path:
    return Path(run_dir) / "checkpoints" / str(int(epoch))


def save(run_dir: str | Path, epoch: int, state: dict, meta: dict) -> Path:
    """Write ``state`` (a pytree: params, opt_state, step) and ``meta`` (JSON)
    as the checkpoint of ``epoch``; returns its folder. Overwrites an
    incomplete or existing checkpoint of the same epoch."""
    import shutil

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
        return json.loads(f.read_text())
    except (OSError, ValueError) as e:
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
    import orbax.checkpoint as ocp

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
