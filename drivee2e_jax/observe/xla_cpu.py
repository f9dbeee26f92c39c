"""Helpers that steer XLA:CPU's fusion (shared by the sensors).

XLA:CPU fuses a cheap-looking producer into EVERY consumer element, and it
strips ``optimization_barrier`` before fusion: a per-object value (a box's
cos / sin) read by every (object, ray) or (pixel, box) pair is then
recomputed for each pair. A reduction is never fused into its consumers.

It is not free: the producer is fused INTO the reduction, whose loop can run
it slower than the vectorised loop it would otherwise get (JAX 0.10.2: 32-
column masks of 47 route boxes + their OR, 25.6 CPU-us per scenario
materialised against 9.8 not; ``experiments/perf/bev_boxes.py``). Every
site in the sensors pays in place (docs/performance.md, "The sensor floor
against today's step"), but a new site is worth measuring in the whole
sensor (``experiments/perf/sweep_parts.py``), not only in isolation: the
two can disagree.

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
