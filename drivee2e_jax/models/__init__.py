"""Trainable baselines (Flax Linen) behind ``models.base.Model``.

Each model module ``drivee2e_jax/models/<name>.py`` exposes
``make_model(**config) -> Model``; ``MODELS`` maps registry names to those
modules, imported lazily so one missing or broken model does not break the
others (``get_model`` raises a one-line DriveE2EError instead).
"""

from __future__ import annotations

from drivee2e_jax.models.registry import MODELS, get_model

__all__ = ["MODELS", "get_model"]
