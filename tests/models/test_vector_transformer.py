"""The vector-scene transformer (``models/vector_transformer.py``,
``drivee2e_jax/zoo/vector_transformer.py``): shapes, purity, padding and order
invariance, training on a fixed batch, the policy in ``evaluate``."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax import SimConfig
from drivee2e_jax.models import vector_transformer as vt
from drivee2e_jax.scenario import load_suite

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny"
CONFIG = dict(dim=32, heads=4, layers=2)


@pytest.fixture(scope="module")
def model():
    return vt.make_model(**CONFIG)


@pytest.fixture(scope="module")
def batch(tiny_demos):
    """Every demonstration of the tiny train split as one batch (``conftest.tiny_demos``)."""
    from drivee2e_jax.train.dataset import DemoDataset

    ds = DemoDataset(tiny_demos)
    return jax.tree_util.tree_map(jnp.asarray, next(ds.batches(len(ds))))


@pytest.fixture(scope="module")
def params(model, batch):
    return jax.jit(model.init)(jax.random.PRNGKey(0), first(batch.obs))


@pytest.fixture(scope="module")
def apply(model):
    return jax.jit(model.apply)


def first(tree, i=0):
    return jax.tree_util.tree_map(lambda a: a[i], tree)


def test_shapes_and_loss(model, batch, params, apply):
    obs = first(batch.obs)
    out = apply(params, obs)
    assert out.waypoints.shape == (6, 2) and out.waypoints.dtype == jnp.float32 and out.controls is None
    loss, metrics = jax.jit(model.loss)(params, obs, first(batch.target))
    assert np.isfinite(loss) and np.isclose(loss, metrics["l1"]) and metrics["l2"] >= 0
    n = sum(x.size for x in jax.tree_util.tree_leaves(params))
    assert 10_000 < n < 200_000, n


def test_apply_is_pure_and_vmaps(batch, params, apply, model):
    batched = jax.jit(jax.vmap(model.apply, in_axes=(None, 0)))(params, batch.obs)
    for i in (0, len(batch.target.command) - 1):
        np.testing.assert_allclose(batched.waypoints[i], apply(params, first(batch.obs, i)).waypoints,
                                   rtol=1e-4, atol=1e-4)
    np.testing.assert_array_equal(apply(params, first(batch.obs)).waypoints, apply(params, first(batch.obs)).waypoints)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), sample=st.integers(0, 3))
def test_padded_tokens_and_token_order_do_not_change_the_output(batch, params, apply, seed, sample):
    obs = first(batch.obs, sample)
    rng = np.random.default_rng(seed)
    ref = np.asarray(apply(params, obs).waypoints)
    # Garbage in every padded agent slot and every invalid lane point.
    av = np.asarray(obs.agents_valid)
    agents = np.where(av[:, None], np.asarray(obs.agents), rng.normal(0, 30, obs.agents.shape)).astype(np.float32)
    cats = np.where(av, np.asarray(obs.agents_category), rng.integers(0, 8, av.shape)).astype(np.int32)
    lv = np.asarray(obs.lanes_valid)
    lanes = np.where(lv[..., None], np.asarray(obs.lanes), rng.normal(0, 30, obs.lanes.shape)).astype(np.float32)
    noisy = obs.replace(agents=jnp.asarray(agents), agents_category=jnp.asarray(cats), lanes=jnp.asarray(lanes))
    np.testing.assert_allclose(apply(params, noisy).waypoints, ref, rtol=1e-4, atol=1e-4)
    # Agents and lanes are sets: shuffling them changes nothing.
    pa, pl = rng.permutation(av.shape[0]), rng.permutation(lv.shape[0])
    shuffled = noisy.replace(agents=noisy.agents[pa], agents_category=noisy.agents_category[pa],
                             agents_valid=obs.agents_valid[pa], lanes=noisy.lanes[pl], lanes_valid=obs.lanes_valid[pl])
    np.testing.assert_allclose(apply(params, shuffled).waypoints, ref, rtol=1e-4, atol=1e-4)


def test_a_valid_agent_does_change_the_output(batch, params, apply):
    obs = first(batch.obs)
    moved = obs.replace(agents=obs.agents.at[0].set(jnp.array([6.0, 0.0, 1.0, 0.0, 0.0, 0.0, 4.5, 1.9])),
                        agents_valid=obs.agents_valid.at[0].set(True), agents_category=obs.agents_category.at[0].set(0))
    assert not np.allclose(apply(params, moved).waypoints, apply(params, obs).waypoints, atol=1e-4)


def test_a_few_adam_steps_decrease_the_loss(model, batch):
    from tests.helpers.training import fit

    start, end, _ = fit(model, batch)
    assert end < 0.5 * start, (start, end)


def test_policy_file_restores_a_checkpoint_and_runs_in_evaluate(model, batch, params, apply, tmp_path):
    from drivee2e_jax.eval.closedloop import evaluate
    from drivee2e_jax.models import checkpoint
    from drivee2e_jax.policy import load_policy

    checkpoint.save(tmp_path, 3, {"params": params}, {"model": "vector_transformer", "model_config": CONFIG})
    pol = load_policy(REPO / "drivee2e_jax" / "zoo" / "vector_transformer.py", checkpoint=tmp_path)
    assert (pol.name, pol.action_type, pol.model) == ("vector_transformer", "waypoints", model)
    np.testing.assert_allclose(apply(pol.params, first(batch.obs)).waypoints, apply(params, first(batch.obs)).waypoints)
    res = evaluate(pol, load_suite(TINY), None, limit=2, config=SimConfig(max_episode_s=1.0))
    assert len(res.rows) == 2 and all(r["policy"] == "vector_transformer" for r in res.rows)
    assert np.isfinite(res.logs.xy).all()
