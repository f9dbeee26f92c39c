"""The TCP-like baseline (``models/tcp.py``, ``policies/tcp*.py``): shapes,
purity, the BEV input, training on a fixed batch, the policy in ``evaluate``."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax import SimConfig, Simulator
from drivee2e_jax.models import base, tcp
from drivee2e_jax.observe import sensors
from drivee2e_jax.observe.bev import unpack_bits
from drivee2e_jax.scenario import load_suite
from tests.helpers.training import first, fit

REPO = Path(__file__).resolve().parents[2]
POLICIES = REPO / "drivee2e_jax" / "zoo"
TINY = REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny"
#: Small and fast: a 32 x 32 BEV at 2 m/px (the default extent) and a slim net.
CONFIG = dict(bev_size=32, bev_resolution=2.0, conv_features=(8, 16, 16, 16), hidden=64, gru_hidden=32)


def demo_batch(sensor_config: sensors.SensorConfig, records: int = 4):
    """A fixed training batch from the tiny example suite (4 scenarios):
    ``log_replay`` demonstrations recorded every 0.5 s for 2 s by
    ``train.dataset.make_recorder``, as one ``Sample`` with a leading axis."""
    from drivee2e_jax.train.dataset import DatasetConfig, make_recorder

    suite = load_suite(TINY)
    packed = suite.pack(None)
    assets = sensors.build_assets(packed, sensor_config, suite.maps)
    sim = Simulator(SimConfig(sensors=sensor_config))
    record = make_recorder(sim, DatasetConfig(), records, sensors.assets_axes(assets))
    scn = jax.tree_util.tree_map(jnp.asarray, packed.scenario)
    samples, keep = record(scn, jax.random.split(jax.random.PRNGKey(0), len(packed)), assets)
    keep = np.asarray(keep).reshape(-1)
    return jax.tree_util.tree_map(lambda x: x.reshape((-1,) + x.shape[2:])[keep], samples)


@pytest.fixture(scope="module")
def model():
    return tcp.make_model(**CONFIG)


@pytest.fixture(scope="module")
def batch(model):
    return demo_batch(model.sensor_config)


def test_shapes_ranges_and_loss(model, batch):
    obs = first(batch.obs)
    assert obs.bev.shape == (32, 32)
    params = jax.jit(model.init)(jax.random.PRNGKey(0), obs)
    out = jax.jit(model.apply)(params, obs)
    assert out.waypoints.shape == (6, 2) and out.waypoints.dtype == jnp.float32
    c = base.controls_vector(out.controls)
    assert 0 <= c[0] <= 1 and 0 <= c[1] <= 1 and -1 <= c[2] <= 1
    loss, metrics = jax.jit(model.loss)(params, obs, first(batch.target))
    assert np.isfinite(loss) and set(metrics) == {"l1", "l2", "ctrl_l1"}
    assert np.isclose(loss, metrics["l1"] + metrics["ctrl_l1"], rtol=1e-5)


def test_apply_is_pure_and_vmaps(model, batch):
    params = jax.jit(model.init)(jax.random.PRNGKey(0), first(batch.obs))
    batched = jax.jit(jax.vmap(model.apply, in_axes=(None, 0)))(params, batch.obs)
    for i in (0, len(batch.target.command) - 1):
        one = jax.jit(model.apply)(params, jax.tree_util.tree_map(lambda a, i=i: a[i], batch.obs))
        np.testing.assert_allclose(batched.waypoints[i], one.waypoints, rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(batched.controls.steer[i], one.controls.steer, rtol=1e-4, atol=1e-5)
    again = jax.jit(jax.vmap(model.apply, in_axes=(None, 0)))(params, batch.obs)
    np.testing.assert_array_equal(batched.waypoints, again.waypoints)


def test_bev_image_max_pools_a_finer_bev(model):
    rng = np.random.default_rng(0)
    coarse = rng.integers(0, 2**14, size=(32, 32), dtype=np.int32)
    fine = np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)
    fine[::2, ::2] = 0  # one fine pixel of four off: the max still sees the others
    np.testing.assert_array_equal(tcp.bev_image(jnp.asarray(fine), model.bev), unpack_bits(jnp.asarray(coarse), 14))
    with pytest.raises(ValueError, match="not a multiple"):
        tcp.bev_image(jnp.zeros((48, 48), jnp.int32), model.bev)


def test_the_bev_and_the_target_point_matter(model, batch):
    obs = first(batch.obs)
    params = jax.jit(model.init)(jax.random.PRNGKey(0), obs)
    apply = jax.jit(model.apply)
    out = apply(params, obs)
    blank = apply(params, obs.replace(bev=jnp.zeros_like(obs.bev)))
    turned = apply(params, obs.replace(route=obs.route[:, ::-1]))
    assert not np.allclose(out.waypoints, blank.waypoints)
    assert not np.allclose(out.waypoints, turned.waypoints)
    assert np.allclose(tcp.target_point(obs.route, jnp.zeros_like(obs.route_valid)), 0.0)
    assert np.allclose(tcp.target_point(obs.route, obs.route_valid), obs.route[int(obs.route_valid.sum()) - 1])


def test_a_few_adam_steps_decrease_the_loss(model, batch):
    start, end, _ = fit(model, batch)
    assert end < 0.5 * start, (start, end)


def test_policy_files_name_the_source_rows_and_run_in_evaluate(model, batch, tmp_path):
    from drivee2e_jax.eval.closedloop import evaluate
    from drivee2e_jax.models import checkpoint
    from drivee2e_jax.policy import load_policy

    params = jax.jit(model.init)(jax.random.PRNGKey(0), first(batch.obs))
    checkpoint.save(tmp_path, 1, {"params": params}, {"model": "tcp", "model_config": CONFIG})
    pols = {f: load_policy(POLICIES / f"{f}.py", checkpoint=tmp_path) for f in ("tcp", "tcp_traj", "tcp_ctrl")}
    assert {f: (p.name, p.mode, p.action_type) for f, p in pols.items()} == {
        "tcp": ("tcp", "fused", "controls"), "tcp_traj": ("tcp_traj", "traj", "waypoints"),
        "tcp_ctrl": ("tcp_ctrl", "ctrl", "controls")}
    # The restored parameters drive like the saved ones.
    obs = first(batch.obs)
    apply = jax.jit(model.apply)
    np.testing.assert_allclose(apply(pols["tcp_traj"].params, obs).waypoints, apply(params, obs).waypoints, rtol=1e-5)

    res = evaluate(pols["tcp"], load_suite(TINY), None, limit=2,
                   config=SimConfig(sensors=model.sensor_config, max_episode_s=1.0))
    assert len(res.rows) == 2 and all(r["policy"] == "tcp" for r in res.rows)
    assert np.isfinite(res.logs.xy).all() and np.isfinite(res.logs.throttle).all()
