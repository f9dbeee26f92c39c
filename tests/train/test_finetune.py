"""Closed-loop fine-tuning (train/finetune.py): the straight-through controller,
the soft collision cost, real gradients through the rollout, the run folder."""

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import Polygon

from drivee2e_jax import controller as ctl
from drivee2e_jax import geometry
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import checkpoint as ckpt
from drivee2e_jax.models.registry import get_model
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.sim import Simulator
from drivee2e_jax.train import finetune as ft
from drivee2e_jax.types import EgoState

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny"
CTL = ctl.ControllerParams()
H = 8  # BPTT horizon of the tests


# --------------------------------------------------------------------------
# Straight-through controller
# --------------------------------------------------------------------------

_st = jax.jit(ft.st_controls, static_argnums=3)
_exact = jax.jit(ctl.waypoints_to_controls, static_argnums=3)


def _throttle_minus_brake(wp, speed):
    c, _ = ft.st_controls(wp, speed, ctl.init_controller_state(CTL), CTL)
    return c.throttle - c.brake


_grad_tb = jax.jit(jax.grad(_throttle_minus_brake))


@settings(max_examples=40, deadline=None)
@given(
    step=st.floats(0.5, 8.0), lateral=st.floats(-3.0, 3.0), speed=st.floats(0.0, 15.0),
    err=st.lists(st.floats(0.0, 0.25), min_size=CTL.window, max_size=CTL.window),
)
def test_st_controls_forward_is_the_controller_and_backward_is_informative(step, lateral, speed, err):
    k = jnp.arange(1, 7, dtype=jnp.float32)[:, None]
    wp = jnp.concatenate([k * step, k**2 * lateral / 36.0], axis=1)
    state = ctl.ControllerState(errors=jnp.asarray(err, jnp.float32))
    got, gs = _st(wp, jnp.float32(speed), state, CTL)
    want, ws = _exact(wp, jnp.float32(speed), state, CTL)
    for a, b in zip(jax.tree_util.tree_leaves((got, gs)), jax.tree_util.tree_leaves((want, ws))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Spacing the waypoints further apart asks for more speed: d(throttle - brake)
    # / d(spacing) > 0 even where the exact controller brakes (zero gradient).
    g = _grad_tb(wp, jnp.float32(speed))
    assert float(g[1, 0] - g[0, 0]) > 0


# --------------------------------------------------------------------------
# Soft collision cost
# --------------------------------------------------------------------------


def _ego(x, y, yaw):
    z = jnp.zeros((), jnp.float32)
    return EgoState(xy=jnp.array([x, y], jnp.float32), yaw=jnp.float32(yaw), speed=z, accel=z, steer=z, yaw_rate=z, t=z)


def _one_agent(x, y, yaw):
    return AgentStates(xy=jnp.array([[x, y]], jnp.float32), yaw=jnp.array([yaw], jnp.float32),
                       vel=jnp.zeros((1, 2), jnp.float32), valid=jnp.ones((1,), bool))


_LW = jnp.array([4.5, 1.9], jnp.float32)
_SIZE = jnp.array([[4.0, 1.8, 1.5]], jnp.float32)
_cost = jax.jit(jax.value_and_grad(
    lambda xy, yaw, agents: ft.soft_collision(_ego(xy[0], xy[1], yaw), _LW, agents, _SIZE, 0.5, 0.2)))


def _poly(x, y, yaw, lw):
    return Polygon(np.asarray(geometry.box_corners(jnp.array([x, y]), jnp.float32(yaw), lw[0], lw[1])))


@settings(max_examples=40, deadline=None)
@given(x=st.floats(-8, 8), y=st.floats(-5, 5), yaw=st.floats(-3.1, 3.1), ayaw=st.floats(-3.1, 3.1))
def test_soft_collision_against_shapely(x, y, yaw, ayaw):
    agents = _one_agent(x, y, ayaw)
    cost, g = _cost(jnp.zeros(2, jnp.float32), jnp.float32(yaw), agents)
    ego_poly, agent_poly = _poly(0.0, 0.0, yaw, _LW), _poly(x, y, ayaw, _SIZE[0, :2])
    assert np.isfinite(float(cost)) and np.all(np.isfinite(np.asarray(g)))
    if ego_poly.intersection(agent_poly).area > 1e-3:
        assert float(cost) >= 0.5 - 1e-4  # at least the margin when overlapping
        # Moving the ego down the gradient lowers the cost (unless the boxes sit
        # exactly symmetric, where the SAT depth has a zero subgradient).
        if float(jnp.linalg.norm(g)) > 1e-3:
            step = -0.05 * g / jnp.linalg.norm(g)
            assert float(_cost(step, jnp.float32(yaw), agents)[0]) < float(cost)
    elif ego_poly.distance(agent_poly) > 0.5 + 3 * 0.2 + np.hypot(2.25, 0.95):
        # Far apart (beyond margin + 3 widths, and the SAT bound's slack): ~0.
        assert float(cost) < 0.2 * np.log1p(np.exp(-3.0)) + 1e-6
    invalid = agents.replace(valid=jnp.zeros((1,), bool))
    assert float(_cost(jnp.zeros(2, jnp.float32), jnp.float32(yaw), invalid)[0]) == 0.0


# --------------------------------------------------------------------------
# Gradients through the rollout (tiny suite, tiny AD-MLP)
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny():
    """(model, tuner, scenarios, params, carry, grad_fn): the tiny suite's
    train split (2 scenarios) driven by a random AD-MLP (hidden 16), with the
    full gradient (``obs_gradient``: through the observation too, so that it
    is the true derivative). The programs are the very ones ``finetune``
    compiles for the run test below (same config), so the persistent
    compilation cache serves them once."""
    from drivee2e_jax.models import base
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.sim import SimConfig

    scenarios = jax.device_put(load_suite(TINY, cache=False).pack("train").scenario)
    model = get_model("ad_mlp", hidden=(16,))
    tuner = ft.FineTuner(model, Simulator(SimConfig()), ft.FinetuneConfig(horizon=H, batch=2, obs_gradient=True))
    idx = np.arange(2)
    carry = ft.make_reset(tuner)(scenarios, idx, jax.random.split(jax.random.PRNGKey(0), 2))
    obs0 = jax.tree_util.tree_map(lambda a: a[0], carry.obs)
    params = model.init(jax.random.PRNGKey(1), base.with_history(obs0, base.push_history(base.empty_history(obs0), obs0)))
    # Larger weights than the init: waypoints far from zero, so the car moves
    # and the controller is not parked on its brake rule.
    params = jax.tree_util.tree_map(lambda a: a * 1.5, params)
    grad_fn = ft.make_grad_fn(tuner)
    w = tuner.weight_vector()
    return model, tuner, scenarios, params, carry, lambda p, st, w=w: grad_fn(p, scenarios, idx, carry, jnp.float32(st), w)


def test_gradient_matches_finite_differences(tiny):
    """Exact controller derivative (st = 0): the autodiff directional
    derivative of the closed-loop loss equals central finite differences.
    The imitation term is left out: its label is a stop-gradient function of
    the pose (a constant target by design, not part of the derivative)."""
    _, tuner, _, params, _, grad0 = tiny
    w = tuner.weight_vector().at[ft.TERMS.index("imitation")].set(0.0)
    grad = lambda p, st: grad0(p, st, w)
    (loss, (terms, _)), g = grad(params, 0.0)
    assert np.isfinite(float(loss)) and float(terms["active"]) == 2 * H
    leaves, tree = jax.tree_util.tree_flatten(params)
    keys = jax.random.split(jax.random.PRNGKey(3), len(leaves))
    v = jax.tree_util.tree_unflatten(tree, [jax.random.normal(k, a.shape) for k, a in zip(keys, leaves)])
    analytic = sum(float(jnp.vdot(a, b)) for a, b in zip(jax.tree_util.tree_leaves(g), jax.tree_util.tree_leaves(v)))
    eps = 1e-4  # the loss curves within ~1e-2 (8 steps of closed loop); float32 noise ~1e-3 here
    f = lambda s: float(grad(jax.tree_util.tree_map(lambda p, d: p + s * d, params, v), 0.0)[0][0])
    numeric = (f(eps) - f(-eps)) / (2 * eps)
    assert np.isfinite(analytic) and abs(analytic) > 1e-2
    assert analytic == pytest.approx(numeric, rel=0.1, abs=2e-3)


def test_loss_decreases_on_a_fixed_batch(tiny):
    """Straight-through gradients (st = 1): a few Adam steps from the same
    start states lower the closed-loop loss (the gradient is real and useful)."""
    import optax

    _, _, _, params, _, grad = tiny
    opt = optax.adam(3e-3)
    @jax.jit
    def update(p, s, g):
        u, s = opt.update(g, s, p)
        return optax.apply_updates(p, u), s

    state = opt.init(params)
    first = float(grad(params, 1.0)[0][0])
    for _ in range(15):
        _, g = grad(params, 1.0)
        assert np.isfinite(float(optax.global_norm(g))) and float(optax.global_norm(g)) > 0
        params, state = update(params, state, g)
    final = float(grad(params, 1.0)[0][0])
    assert final < 0.8 * first


# --------------------------------------------------------------------------
# The run folder and the CLI
# --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def init_run(tmp_path_factory, tiny):
    """A fake imitation run: an AD-MLP (hidden 16) checkpoint with random params."""
    params = tiny[3]
    out = tmp_path_factory.mktemp("il")
    (out / "config.json").write_text(json.dumps({"model": "ad_mlp", "model_config": {"hidden": [16]}, "data": ""}))
    ckpt.save(out, 1, {"params": params, "opt_state": {}, "step": np.int64(1)},
              {"model": "ad_mlp", "model_config": {"hidden": [16]}, "step": 1})
    return out


def test_finetune_run_folder_resume_and_policy(init_run, tmp_path, drivee2e_cache):
    from drivee2e_jax.cli import main
    from drivee2e_jax.policy import load_policy

    out = tmp_path / "ft"
    argv = ["finetune", "--init", str(init_run), "--suite", str(TINY), "--out", str(out), "--steps", "3",
            "--horizon", str(H), "--batch", "2", "--ckpt-every", "2", "--log-every", "1", "--no-progress",
            "--obs-gradient"]
    assert main(argv) == 0
    assert [p.name for p in ckpt.list_checkpoints(out)] == ["0", "2", "3"]
    rows = [json.loads(ln) for ln in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [1, 2, 3]
    assert set(rows[0]["terms"]) == set(ft.TERMS) and all(np.isfinite(r["grad_norm"]) for r in rows)
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["model"] == "ad_mlp" and cfg["finetune"]["horizon"] == H
    # Checkpoint 0 holds the imitation parameters; the last one moved away from them.
    p0, p3, il = (ckpt.load_params(x) for x in (out / "checkpoints" / "0", out, init_run))
    jax.tree_util.tree_map(np.testing.assert_array_equal, p0, il)
    assert any(not np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(p3), jax.tree_util.tree_leaves(il)))
    # The run drives like any imitation run.
    pol = load_policy(REPO / "drivee2e_jax" / "zoo" / "ad_mlp.py", checkpoint=str(out))
    jax.tree_util.tree_map(np.testing.assert_array_equal, pol.params, p3)
    # No silent overwrite; --resume continues to a larger --steps.
    with pytest.raises(DriveE2EError, match="already exists"):
        ft.finetune(dataclasses.replace(_cfg_of(out)), out)
    assert main(argv + ["--resume"]) == 0  # already at 3 steps: nothing to do
    assert main(["finetune", "--init", str(init_run), "--out", str(out), "--weights", "speed=1"]) == 2


def test_parse_weights():
    from drivee2e_jax.cli.finetune import parse_weights

    assert parse_weights("collision=2, comfort=0") == ft.LossWeights(collision=2.0, comfort=0.0)
    assert parse_weights("") == ft.LossWeights()
    for bad in ("speed=1", "collision", "collision=x", "route=-1"):
        with pytest.raises(DriveE2EError, match="weight"):
            parse_weights(bad)


def _cfg_of(out):
    d = json.loads((out / "config.json").read_text())["finetune"]
    d["weights"] = ft.LossWeights(**d["weights"])
    return ft.FinetuneConfig(**d)
