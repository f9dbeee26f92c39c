"""The learned zoo policies' one loader: a checkpoint, else bundled weights.

Not a policy file (the leading ``_`` keeps it out of the zoo's names): the
policy files ``ad_mlp``, ``tcp*``, ``vector_transformer``,
``vector_transformer_ft`` and ``ppo`` import it.
"""

from __future__ import annotations

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import base
from drivee2e_jax.models import bundled as bw
from drivee2e_jax.models.checkpoint import bev_of_manifest


def bundled_name(names: tuple[str, ...]) -> str | None:
    """The first of ``names`` with bundled weights (``models.bundled``), or None."""
    return next((n for n in names if bw.has_bundled(n)), None)


def policy_from_bundled(bundle: str, model_name: str, mode: base.Mode, name: str | None = None,
                        **config) -> base.ModelPolicy:
    """``model_name`` driven in ``mode`` with the bundled weights ``bundle``:
    their ``model_config`` overrides ``config`` (as a checkpoint's does), their
    ``data_bev`` becomes the policy's BEV. Raises DriveE2EError (one line) on
    weights of another model or a bad / corrupted pair (``load_bundled``)."""
    stored_model, model_config, params = bw.load_bundled(bundle)
    _, jpath = bw.bundled_paths(bundle)
    if stored_model != model_name:
        raise DriveE2EError(f"{jpath}: weights of a {stored_model!r} model, expected {model_name!r}")
    data_bev = bw.read_info(bundle).get("data_bev")
    bev = bev_of_manifest({"sensors": ["bev"], "bev": data_bev}) if data_bev else None
    return base.policy_from_params(model_name, params, mode, name, bev=bev, origin=str(jpath),
                                   **{**config, **model_config})


def learned_policy(model_name: str, mode: base.Mode, name: str, checkpoint=None, *, bundles: tuple[str, ...] = (),
                   bundled: bool = True, required: bool = False, **config) -> base.ModelPolicy:
    """A zoo policy of ``model_name`` in ``mode``, named ``name``.

    Order: ``checkpoint`` (a run folder, ``checkpoints/`` or one
    ``checkpoints/<epoch>``; ``base.policy_from_checkpoint``); else the first
    of ``bundles`` (default ``(name,)``) with bundled weights, unless
    ``bundled`` is False; else a fresh random init (smoke tests only), or,
    with ``required``, a one-line DriveE2EError naming the missing file.
    """
    if checkpoint is not None:
        return base.policy_from_checkpoint(model_name, checkpoint, mode, name=name, **config)
    bundles = bundles or (name,)
    found = bundled_name(bundles) if bundled else None
    if found is not None:
        return policy_from_bundled(found, model_name, mode, name=name, **config)
    if required:
        npz, _ = bw.bundled_paths(bundles[0])
        raise DriveE2EError(f"{name}: no bundled weights ({npz} missing; set ${bw.WEIGHTS_ENV} to another folder) "
                            f"and no checkpoint (pass --policy {name}:checkpoint=RUN)")
    return base.policy_from_checkpoint(model_name, None, mode, name=name, **config)
