"""Small training helpers shared by the model tests (``tests/models``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax


def first(tree):
    return jax.tree_util.tree_map(lambda a: a[0], tree)


def fit(model, batch, steps: int = 40, lr: float = 3e-3):
    """(initial loss, final loss, params) after ``steps`` Adam steps on ``batch``."""
    params = jax.jit(model.init)(jax.random.PRNGKey(1), first(batch.obs))
    opt = optax.adam(lr)

    def batch_loss(p):
        return jnp.mean(jax.vmap(model.loss, in_axes=(None, 0, 0))(p, batch.obs, batch.target)[0])

    @jax.jit
    def step(p, s):
        loss, g = jax.value_and_grad(batch_loss)(p)
        u, s = opt.update(g, s, p)
        return optax.apply_updates(p, u), s, loss

    state, losses = opt.init(params), []
    for _ in range(steps):
        params, state, loss = step(params, state)
        losses.append(float(loss))
    return losses[0], float(jax.jit(batch_loss)(params)), params
