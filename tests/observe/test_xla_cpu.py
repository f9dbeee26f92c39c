"""``observe.xla_cpu.materialize``: the same values on every platform.

On CPU it is a sum with a zero slice (a reduction XLA:CPU does not fuse into
its consumers); lowered for any other platform it must be the value itself
behind an ``optimization_barrier``, with no CPU-only trick left in the program.
The non-CPU branch is checked by lowering for GPU / TPU on this CPU machine
(no device needed) and by running that branch here.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.observe import xla_cpu


def _fn(x):
    return xla_cpu.materialize(jnp.sin(x)) * 2.0


@pytest.mark.parametrize("platform", ["cuda", "rocm", "tpu"])
def test_non_cpu_lowering_is_a_barrier_without_the_reduction(platform):
    x = jnp.linspace(-3.0, 3.0, 12).reshape(4, 3)
    text = jax.jit(jax.vmap(_fn)).trace(x).lower(lowering_platforms=(platform,)).as_text()
    assert "optimization_barrier" in text
    assert "stablehlo.reduce" not in text


def test_cpu_lowering_keeps_the_reduction_and_no_barrier():
    x = jnp.linspace(-3.0, 3.0, 12).reshape(4, 3)
    text = jax.jit(jax.vmap(_fn)).trace(x).lower(lowering_platforms=("cpu",)).as_text()
    assert "stablehlo.reduce" in text
    assert "optimization_barrier" not in text
    compiled = jax.jit(jax.vmap(_fn)).lower(x).compile().as_text()
    assert "conditional" not in compiled  # the one-platform switch is gone before fusion


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.int32, jnp.uint32, jnp.bool_])
def test_both_branches_return_the_same_values_and_dtype(dtype):
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(5, 7)) * 100).astype(dtype)
    cpu, other = jax.jit(xla_cpu._reduce_copy)(x), jax.jit(xla_cpu._barrier)(x)
    assert cpu.dtype == other.dtype == xla_cpu.materialize(x).dtype
    np.testing.assert_array_equal(np.asarray(cpu), np.asarray(other))
    np.testing.assert_array_equal(np.asarray(xla_cpu.materialize(x)), np.asarray(x).astype(cpu.dtype))


def test_non_cpu_branch_runs_and_differentiates(monkeypatch):
    """The default (non-CPU) branch forced on this machine: ``platform_dependent``
    replaced by its default, as a GPU lowering picks it."""
    monkeypatch.setattr(xla_cpu.jax.lax, "platform_dependent", lambda *a, default, **_: default(*a))
    x = jnp.linspace(-3.0, 3.0, 12)
    np.testing.assert_array_equal(np.asarray(jax.jit(_fn)(x)), np.asarray(jnp.sin(x) * 2.0))
    g = jax.grad(lambda v: jnp.sum(_fn(v)))(x)
    np.testing.assert_allclose(np.asarray(g), np.asarray(2.0 * jnp.cos(x)), rtol=1e-6)
