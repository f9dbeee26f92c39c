"""Trained weights shipped inside the package: the policy zoo's bundled files.

A zoo name (``drivee2e bench --policy vector_transformer``) with no
``checkpoint=RUN`` loads ``drivee2e_jax/zoo/weights/<name>.npz`` +
``<name>.json`` when they are there (``zoo/*.py``). Layout::

    <name>.npz    the model parameters only (no optimiser state): one float32
                  array per leaf of the params pytree, keyed by the '/'-joined
                  path of nested dict keys ("params/Dense_0/kernel"); a zip
                  written with sorted keys and fixed timestamps, so exporting
                  the same checkpoint twice gives the same bytes
    <name>.json   {"name", "model", "model_config", "mode" ("traj" / "ctrl" /
                  "fused"), "format": 1, "sha256" (of the npz), "source"
                  (checkpoint folder + epoch), "training" (command, data,
                  epochs / steps), "val" ({"driving_score", "success_rate",
                  "route_completion"} or null), "measured_with" (the bench
                  command), "data_bev" (the BEV the training data was rendered
                  at, or null), "n_params"}

Loading needs numpy only (this module imports no JAX); ``export_bundled``
reads an Orbax checkpoint and imports ``models.checkpoint`` (JAX, Orbax)
when called. The weights folder is ``DRIVEE2E_ZOO_WEIGHTS`` when set (tests,
private zoos), else the package's ``zoo/weights/``.
"""

from __future__ import annotations

import io
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import atomic_write, atomic_write_json, sha256_file
from drivee2e_jax.jsonfile import BadJSON, read_json
from drivee2e_jax.policy import ZOO_WEIGHTS_ENV, zoo_weights_dir

#: Environment variable naming another weights folder (overrides the package's).
WEIGHTS_ENV = ZOO_WEIGHTS_ENV
FORMAT = 1
MODES = ("traj", "ctrl", "fused")
#: Keys of ``val`` (twin15 val, ``drivee2e bench``'s aggregate columns).
VAL_KEYS = ("driving_score", "success_rate", "route_completion")
_NAME = re.compile(r"^[a-z][a-z0-9_]*$")
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


def weights_dir(root: str | Path | None = None) -> Path:
    """The folder holding bundled weights: ``root`` when given, else
    ``$DRIVEE2E_ZOO_WEIGHTS``, else ``drivee2e_jax/zoo/weights/`` of the
    installed package."""
    return Path(root) if root is not None else zoo_weights_dir()


def bundled_paths(name: str, root: str | Path | None = None) -> tuple[Path, Path]:
    """(``<name>.npz``, ``<name>.json``) in ``weights_dir(root)``."""
    d = weights_dir(root)
    return d / f"{name}.npz", d / f"{name}.json"


def has_bundled(name: str, root: str | Path | None = None) -> bool:
    """Whether weights of ``name`` are bundled (either file of the pair
    present; ``load_bundled`` then says if the other is missing)."""
    return any(p.is_file() for p in bundled_paths(name, root))


def flatten_params(tree: Any, where: str = "params") -> dict[str, np.ndarray]:
    """Nested dicts of arrays -> {"a/b/c": float32 array}. Raises
    DriveE2EError on a leaf that is not a floating array, an empty dict, or a
    key that is empty or holds '/' (the flat keys could not be split back)."""
    flat: dict[str, np.ndarray] = {}

    def walk(node, path):
        if isinstance(node, dict) or (hasattr(node, "keys") and hasattr(node, "items")):  # dict, FrozenDict
            if not node:
                raise DriveE2EError(f"{where}: empty dict at {'/'.join(path) or 'the root'} (cannot be bundled)")
            for k, v in node.items():
                if not isinstance(k, str) or not k or "/" in k:
                    raise DriveE2EError(f"{where}: key {k!r} under {'/'.join(path) or 'the root'} "
                                        "(expected a non-empty string without '/')")
                walk(v, (*path, k))
            return
        arr = np.asarray(node)
        if not np.issubdtype(arr.dtype, np.floating):
            raise DriveE2EError(f"{where}: leaf {'/'.join(path)} is {arr.dtype}, expected floating-point parameters")
        flat["/".join(path)] = arr.astype(np.float32)

    walk(tree, ())
    return flat


def unflatten_params(flat: dict[str, np.ndarray]) -> dict:
    """Inverse of ``flatten_params``: {"a/b/c": x} -> {"a": {"b": {"c": x}}}."""
    tree: dict = {}
    for key in sorted(flat):
        *heads, leaf = key.split("/")
        node = tree
        for h in heads:
            node = node.setdefault(h, {})
        node[leaf] = flat[key]
    return tree


def write_npz(path: Path, flat: dict[str, np.ndarray]) -> None:
    """``flat`` as an ``np.load``-able .npz (deflated, sorted keys, fixed
    timestamps: the same arrays give the same bytes), written atomically."""

    def write(f):
        with zipfile.ZipFile(f, "w", compression=zipfile.ZIP_DEFLATED) as z:
            for key in sorted(flat):
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(flat[key]), allow_pickle=False)
                info = zipfile.ZipInfo(f"{key}.npy", date_time=_ZIP_TIME)
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                z.writestr(info, buf.getvalue())

    atomic_write(path, write, binary=True)


def read_info(name: str, root: str | Path | None = None) -> dict:
    """The checked ``<name>.json`` of a bundled pair. Raises DriveE2EError
    (one line, naming the file) when it is missing, not JSON, of another
    format, or lacks a field."""
    _, jpath = bundled_paths(name, root)
    try:
        info = read_json(jpath)
    except BadJSON as e:
        raise DriveE2EError(f"{jpath}: unreadable bundled weights' metadata ({e.detail})") from e
    except FileNotFoundError as e:
        raise DriveE2EError(f"{jpath}: bundled weights' metadata missing (export with experiments/zoo/export.py)") from e
    except OSError as e:
        raise DriveE2EError(f"{jpath}: unreadable bundled weights' metadata ({' '.join(str(e).split())})") from e
    if not isinstance(info, dict):
        raise DriveE2EError(f"{jpath}: expected a JSON object, got {type(info).__name__}")
    if info.get("format") != FORMAT:
        raise DriveE2EError(f"{jpath}: format {info.get('format')!r}, expected {FORMAT}")
    for key, kind in (("name", str), ("model", str), ("model_config", dict), ("mode", str), ("sha256", str)):
        if not isinstance(info.get(key), kind):
            raise DriveE2EError(f"{jpath}: field {key!r} missing or not a {kind.__name__}")
    if info["name"] != name:
        raise DriveE2EError(f"{jpath}: field 'name' is {info['name']!r}, expected {name!r}")
    if info["mode"] not in MODES:
        raise DriveE2EError(f"{jpath}: field 'mode' is {info['mode']!r}, expected one of {', '.join(MODES)}")
    return info


def load_bundled(name: str, root: str | Path | None = None) -> tuple[str, dict, dict]:
    """(model name, model_config, params) of the bundled weights ``name``:
    params as nested dicts of float32 numpy arrays, the structure the model's
    ``init`` gives. The npz's sha256 must match the json's. Raises
    DriveE2EError (one line, naming the file) on a missing file, bad json,
    a sha256 mismatch or an unreadable npz."""
    npz, jpath = bundled_paths(name, root)
    info = read_info(name, root)
    if not npz.is_file():
        raise DriveE2EError(f"{npz}: bundled weights missing (its metadata {jpath.name} is there)")
    digest = sha256_file(npz)
    if digest != info["sha256"]:
        raise DriveE2EError(f"{npz}: sha256 {digest[:12]}... does not match {info['sha256'][:12]}... recorded in "
                            f"{jpath.name} (a corrupted or replaced file: export the pair again)")
    try:
        with np.load(npz, allow_pickle=False) as z:
            flat = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile) as e:
        raise DriveE2EError(f"{npz}: unreadable bundled weights ({' '.join(str(e).split())})") from e
    if not flat:
        raise DriveE2EError(f"{npz}: holds no arrays")
    return info["model"], dict(info["model_config"]), unflatten_params(flat)


def _check_val(val: Any, where: str = "info['val']") -> dict | None:
    if val is None:
        return None
    if not isinstance(val, dict) or set(val) != set(VAL_KEYS):
        raise DriveE2EError(f"{where}: expected null or {{{', '.join(VAL_KEYS)}}}, got {val!r}")
    try:
        return {k: float(val[k]) for k in VAL_KEYS}
    except (TypeError, ValueError) as e:
        raise DriveE2EError(f"{where}: expected numbers, got {val!r}") from e


def _check_variants(variants: Any) -> dict:
    """{zoo name: val} of the other zoo names that drive the same weights in
    another mode (``tcp_traj`` / ``tcp_ctrl`` on the ``tcp`` pair)."""
    if variants is None:
        return {}
    if not isinstance(variants, dict):
        raise DriveE2EError(f"info['variants']: expected {{zoo name: val}}, got {variants!r}")
    for name in variants:
        if not isinstance(name, str) or not _NAME.match(name):
            raise DriveE2EError(f"info['variants']: name {name!r}: expected lower-case letters, digits and '_'")
    return {n: _check_val(v, f"info['variants'][{n!r}]") for n, v in variants.items()}


def export_bundled(checkpoint_path: str | Path, name: str, out_dir: str | Path, info: dict) -> tuple[Path, Path]:
    """Write ``out_dir/<name>.npz`` + ``<name>.json`` from a training
    checkpoint (a run folder, its ``checkpoints/`` or one
    ``checkpoints/<epoch>``; ``models.checkpoint.resolve``).

    Args:
      info: ``mode`` ("traj" / "ctrl" / "fused", required); ``training``
        (dict or text: command, data, epochs / steps), ``val`` (null or
        {driving_score, success_rate, route_completion}), ``measured_with``
        (the bench command), optionally ``variants`` ({zoo name: val} for
        the names that drive these weights in another mode, e.g. ``tcp_traj``
        and ``tcp_ctrl`` on ``tcp``) and ``source`` (default: the resolved
        checkpoint folder and its epoch).
    Returns (npz path, json path). Raises DriveE2EError on a bad name, mode
    or val, or an unreadable checkpoint.
    """
    # Orbax + JAX (~2 s to import): only exporting reads a training checkpoint;
    # load_bundled (the zoo's path) stays numpy-only.
    from drivee2e_jax.models import checkpoint as ckpt  # noqa: PLC0415 - see the comment above

    if not _NAME.match(name):
        raise DriveE2EError(f"bundled weights name {name!r}: expected lower-case letters, digits and '_'")
    mode = info.get("mode")
    if mode not in MODES:
        raise DriveE2EError(f"info['mode'] is {mode!r}, expected one of {', '.join(MODES)}")
    val = _check_val(info.get("val"))  # every check before anything is written
    variants = _check_variants(info.get("variants"))
    path = ckpt.resolve(checkpoint_path)
    meta = ckpt.read_meta(path)
    if not isinstance(meta.get("model"), str):
        raise DriveE2EError(f"{path / ckpt.META}: no 'model' field (not a drivee2e training checkpoint)")
    flat = flatten_params(ckpt.restore(path)["params"], where=str(path))
    bev = ckpt.training_bev(meta)
    npz, jpath = bundled_paths(name, out_dir)
    write_npz(npz, flat)
    record = {
        "name": name,
        "model": meta["model"],
        "model_config": meta.get("model_config") or {},
        "mode": mode,
        "format": FORMAT,
        "sha256": sha256_file(npz),
        "n_params": int(sum(a.size for a in flat.values())),
        "source": info.get("source") or {"checkpoint": str(Path(path).resolve()), "epoch": meta.get("epoch")},
        "training": info.get("training"),
        "val": val,
        "measured_with": info.get("measured_with"),
        "variants": variants,
        "data_bev": None if bev is None else {"height": bev.height, "width": bev.width,
                                              "resolution": bev.resolution},
    }
    atomic_write_json(jpath, record)
    return npz, jpath
