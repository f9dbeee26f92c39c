"""Helpers that steer XLA:CPU's fusion (shared by the sensors).

XLA:CPU fuses a cheap-looking producer into EVERY consumer element, and it
strips ``optimization_barrier`` before fusion: a per-object value (a box's
cos / sin) read by every (object, ray) or (pixel, box) pair is then
recomputed for each pair. A reduction is never fused into its consumers.

Other backends: ``materialize`` is chosen per lowering platform
(``jax.lax.platform_dependent``): the reduction trick on CPU, a plain
``optimization_barrier`` (the value itself, no extra buffer or pass)
elsewhere, e.g. on GPU, where XLA honours the barrier and fuses on its own
terms.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def _reduce_copy(x):
    """The XLA:CPU form: a sum with a zero slice (a reduction, which XLA:CPU
    never fuses into its consumers). Same values as ``x`` except that -0.0
    becomes +0.0; a bool ``x`` comes back as int32 (``jnp.sum``)."""
    return jnp.sum(jnp.stack([x, jnp.zeros_like(x)]), axis=0)


def _barrier(x):
    """Any other backend: ``x`` itself behind an ``optimization_barrier``,
    in the dtype ``_reduce_copy`` would return (bool -> int32)."""
    if x.dtype == jnp.bool_:
        x = x.astype(jnp.int32)
    return jax.lax.optimization_barrier(x)


def materialize(x):
    """``x``, computed once into a buffer: ``_reduce_copy`` when lowered for
    CPU, ``_barrier`` for any other platform (chosen at lowering time; a
    program lowered for one platform holds only that branch)."""
    return jax.lax.platform_dependent(x, cpu=_reduce_copy, default=_barrier)
