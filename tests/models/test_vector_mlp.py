"""The vector MLP (``models/vector_mlp.py``): AD-MLP's network over the ego's
past plus a flat vector of the scene; the PPO critic reads the same vector."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.models import ad_mlp, vector_mlp
from drivee2e_jax.models.registry import get_model


@pytest.fixture(scope="module")
def batch(tiny_demos):
    from drivee2e_jax.train.dataset import DemoDataset

    ds = DemoDataset(tiny_demos)
    return jax.tree_util.tree_map(jnp.asarray, next(ds.batches(len(ds))))


def first(tree, i=0):
    return jax.tree_util.tree_map(lambda a: a[i], tree)


def test_shapes_and_size(batch):
    model = get_model("vector_mlp")
    obs = first(batch.obs)
    assert vector_mlp.scene_features(obs).shape == (4 + 2 * obs.route.shape[0] + 8 * obs.agents.shape[0] + 18,)
    assert vector_mlp.features(obs).shape == (ad_mlp.features(obs).shape[0] + vector_mlp.scene_features(obs).shape[0],)
    params = model.init(jax.random.PRNGKey(0), obs)
    assert sum(a.size for a in jax.tree_util.tree_leaves(params)) == 130_060
    out = jax.vmap(model.apply, in_axes=(None, 0))(params, batch.obs)
    assert out.waypoints.shape == (len(batch.obs.ego), 6, 2) and bool(jnp.isfinite(out.waypoints).all())


def test_it_sees_the_scene_and_ad_mlp_does_not(batch):
    obs = first(batch.obs)
    lead = jnp.array([6.0, 0.0, 1.0, 0.0, 0.0, 0.0, 4.5, 1.9])
    moved = obs.replace(agents=obs.agents.at[0].set(lead), agents_valid=obs.agents_valid.at[0].set(True))
    red = obs.replace(signal_state=jnp.asarray(1 - obs.signal_state, obs.signal_state.dtype))
    for name, sees in (("vector_mlp", True), ("ad_mlp", False)):
        model = get_model(name)
        params = model.init(jax.random.PRNGKey(0), obs)
        base_wp = model.apply(params, obs).waypoints
        for changed in (moved, red):
            differs = not np.allclose(model.apply(params, changed).waypoints, base_wp, atol=1e-6)
            assert differs == sees, name


def test_a_few_adam_steps_decrease_the_loss(batch):
    from tests.helpers.training import fit

    start, end, _ = fit(get_model("vector_mlp", hidden=(64, 64)), batch)
    assert end < 0.5 * start, (start, end)


@pytest.mark.parametrize("name", ["ad_mlp", "vector_mlp"])
def test_init_speed_starts_from_a_straight_plan_at_that_speed(batch, name):
    obs = first(batch.obs)
    model = get_model(name, init_speed=5.0)
    params = model.init(jax.random.PRNGKey(0), obs)
    last = max((k for k in params["params"] if k.startswith("Dense_")), key=lambda k: int(k.split("_")[1]))
    np.testing.assert_array_equal(params["params"][last]["bias"], np.tile([2.5, 0.0], 6))   # 5 m/s x 0.5 s
    zeroed = jax.tree_util.tree_map(lambda a: a, params)
    zeroed["params"][last]["kernel"] = jnp.zeros_like(params["params"][last]["kernel"])
    np.testing.assert_allclose(model.apply(zeroed, obs).waypoints, np.stack([2.5 * np.arange(1, 7), np.zeros(6)], 1))
    default = get_model(name).init(jax.random.PRNGKey(0), obs)
    assert not np.any(default["params"][last]["bias"])
