"""Flat dotted-path views of nested dataclasses (the packed ``types.Scenario``).

``flatten_dataclass(obj) -> {"a.b": leaf}`` and its inverse
``unflatten_dataclass(cls, flat)``; ``flatten_scenario`` /
``unflatten_scenario`` for ``types.Scenario`` (its leaf names are those of
``sizes.LEAVES``). Used by packing, the packed cache, filters and datasets.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Any

from drivee2e_jax import types

__all__ = ["flatten_dataclass", "unflatten_dataclass", "flatten_scenario", "unflatten_scenario"]


def flatten_dataclass(obj) -> dict[str, Any]:
    """{"a.b": leaf, ...}: every leaf of a nest of dataclasses, by dotted path."""
    out = {}

    def walk(o, prefix):
        for f in dataclasses.fields(o):
            v = getattr(o, f.name)
            if dataclasses.is_dataclass(v):
                walk(v, f"{prefix}{f.name}.")
            else:
                out[f"{prefix}{f.name}"] = v

    walk(obj, "")
    return out


def unflatten_dataclass(cls, flat: dict[str, Any], *, optional: bool = False):
    """Inverse of :func:`flatten_dataclass` for the dataclass ``cls`` (nested
    dataclass fields by their type hints). ``optional``: a missing leaf is
    None instead of a KeyError."""

    def build(klass, prefix):
        kwargs = {}
        for name, hint in typing.get_type_hints(klass).items():
            if dataclasses.is_dataclass(hint):
                kwargs[name] = build(hint, f"{prefix}{name}.")
            else:
                key = f"{prefix}{name}"
                kwargs[name] = flat.get(key) if optional else flat[key]
        return klass(**kwargs)

    return build(cls, "")


def flatten_scenario(scenario: types.Scenario) -> dict[str, Any]:
    """{"tracks.xy": leaf, ...} for every leaf (the names of ``LEAVES``)."""
    return flatten_dataclass(scenario)


def unflatten_scenario(flat: dict[str, Any]) -> types.Scenario:
    """Inverse of :func:`flatten_scenario`."""
    return unflatten_dataclass(types.Scenario, flat)
