"""The model registry: name -> module ``drivee2e_jax/models/<name>.py``.

Modules are imported by name on first use, so one missing or broken model does
not break the others (``get_model`` raises a one-line DriveE2EError instead).
A new model = one module with ``make_model(**config)`` + one line in ``MODELS``.
"""

from __future__ import annotations

import importlib

from drivee2e_jax.errors import DriveE2EError

#: Registry name -> module under ``drivee2e_jax.models``.
MODELS = {
    "ad_mlp": "ad_mlp",
    "tcp": "tcp",
    "vector_mlp": "vector_mlp",
    "vector_transformer": "vector_transformer",
}


def get_model(name: str, **config):
    """The model ``name`` built with ``config`` (its ``make_model(**config)``)."""
    if name not in MODELS:
        raise DriveE2EError(f"--model {name}: unknown model (expected one of {', '.join(MODELS)})")
    try:
        module = importlib.import_module(f"drivee2e_jax.models.{MODELS[name]}")
    except ModuleNotFoundError as e:
        raise DriveE2EError(f"model {name!r}: drivee2e_jax/models/{MODELS[name]}.py is not available ({e})") from e
    if not hasattr(module, "make_model"):
        raise DriveE2EError(f"drivee2e_jax/models/{MODELS[name]}.py: defines no make_model(**config)")
    try:
        return module.make_model(**config)
    except TypeError as e:
        raise DriveE2EError(f"model {name!r}: bad config {config}: {e}") from e
