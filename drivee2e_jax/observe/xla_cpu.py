"""Helpers that steer XLA:CPU's fusion (shared by the sensors).

XLA:CPU fuses a cheap-looking producer into EVERY consumer element, and it
strips ``optimization_barrier`` before fusion: a per-object value (a box's
cos / sin) read by every (object, ray) or (pixel, box) pair is then
recomputed for each pair. A reduction is never fused into its consumers.
"""

from __future__ import annotations

import jax.numpy as jnp


def materialize(x):
    """``x``, computed once into a buffer (a sum with a zero slice: a
    reduction, which XLA never fuses into its consumers)."""
    return jnp.sum(jnp.stack([x, jnp.zeros_like(x)]), axis=0)
