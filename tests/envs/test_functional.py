"""The functional JAX environment (drivee2e_jax.envs.functional) on the tiny example suite.

One compiled program serves the module: 4 environments under ``jit`` /
``vmap`` / ``lax.scan`` with ``AutoResetWrapper`` for 1,000 steps; envs 0-1
drive a uniformly random policy, envs 2-3 the reference ``log_replay`` policy
file (its actions from ``obs.privileged.log_controls``). The log-replay
episodes must score exactly what the benchmark's own evaluation gives.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.envs.functional import (
    AutoResetWrapper,
    DriveEnv,
    RewardConfig,
    VmapAutoResetWrapper,
    as_action,
    make_params,
)
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.metrics.driving_score import STATUS_NAMES
from drivee2e_jax.policy import load_policy, resolve_policy_path
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.types import Controls, Waypoints

TINY = Path(__file__).resolve().parents[2] / "drivee2e_jax" / "scenario" / "examples" / "tiny"
STEPS = 1000
NUM_ENVS = 4
LOG_REPLAY = np.array([False, False, True, True])


@pytest.fixture(scope="module")
def params():
    return make_params(TINY, "train")


@pytest.fixture(scope="module")
def log_replay():
    return load_policy(resolve_policy_path("log_replay"))


@pytest.fixture(scope="module")
def rollout(params, log_replay):
    """(final state, per-step outputs (T, B, ...) as numpy) of the module's run."""
    env = AutoResetWrapper(DriveEnv())
    use_log = jnp.asarray(LOG_REPLAY)

    def run(key, params):
        k_reset, k_run = jax.random.split(key)
        first = jnp.arange(NUM_ENVS, dtype=jnp.int32) % params.num_scenarios
        obs, state = jax.vmap(env.reset, in_axes=(0, None, 0))(jax.random.split(k_reset, NUM_ENVS), params, first)

        def body(carry, key):
            obs, state = carry
            k_act, k_step = jax.random.split(key)
            lo, hi = jnp.array([0.0, 0.0, -1.0]), jnp.array([1.0, 1.0, 1.0])
            random = jax.random.uniform(k_act, (NUM_ENVS, 3), minval=lo, maxval=hi)
            logged, _ = jax.vmap(lambda o: log_replay.act(None, o, None, k_act))(obs)
            logged = jnp.stack([logged.throttle, logged.brake, logged.steer], axis=-1)
            action = jnp.where(use_log[:, None], logged, random)
            obs, state, reward, done, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k_step, NUM_ENVS), state, action, params)
            floats = [x for x in jax.tree_util.tree_leaves((obs, info["final_obs"]))
                      if jnp.issubdtype(x.dtype, jnp.floating)]
            finite = jnp.stack([jnp.all(jnp.isfinite(x), axis=tuple(range(1, x.ndim))) for x in floats]).all(0)
            out = {"reward": reward, "done": done, "finite": finite, "index": state.index,
                   **{k: info[k] for k in ("terminated", "truncated", "discount", "progress_m", "route_completion")},
                   **{f"episode_{k}": v for k, v in info["scores"].items()}}
            return (obs, state), out

        (_, state), out = jax.lax.scan(body, (obs, state), jax.random.split(k_run, STEPS))
        return state, out

    state, out = jax.jit(run)(jax.random.PRNGKey(0), params)
    return jax.tree_util.tree_map(np.asarray, state), jax.tree_util.tree_map(np.asarray, out)


def test_random_policy_runs_1000_steps_with_auto_reset(rollout, params):
    state, out = rollout
    assert out["reward"].shape == (STEPS, NUM_ENVS)
    assert out["finite"].all(), "every observation (and final observation) is finite"
    assert np.isfinite(out["reward"]).all()
    done = out["done"]
    # Tiny logs are 5 s (49 steps): about 20 episodes per environment.
    assert (done.sum(0) >= 15).all(), done.sum(0)
    np.testing.assert_array_equal(state.episode, done.sum(0))
    np.testing.assert_array_equal(state.total_steps, STEPS)
    # termination and truncation are exclusive and make up `done`
    np.testing.assert_array_equal(out["terminated"] | out["truncated"], done)
    assert not (out["terminated"] & out["truncated"]).any()
    np.testing.assert_array_equal(out["discount"], 1.0 - out["terminated"])
    # scores only where an episode ended
    assert np.isfinite(out["episode_driving_score"][done]).all()
    assert np.isnan(out["episode_driving_score"][~done]).all()
    assert (out["episode_status"][~done] == -1).all()
    assert ((out["episode_driving_score"][done] >= 0) & (out["episode_driving_score"][done] <= 100)).all()
    # episodes of both scenarios are drawn
    assert set(out["episode_scenario_index"][done].tolist()) == {0, 1}
    # episode lengths add up to the steps of finished episodes; return = sum of rewards
    for b in range(NUM_ENVS):
        ends = np.flatnonzero(done[:, b])
        assert out["episode_length"][ends, b].sum() == ends[-1] + 1
        np.testing.assert_allclose(out["episode_return"][ends[0], b], out["reward"][: ends[0] + 1, b].sum(), rtol=1e-5,
                                   atol=1e-3)


def test_log_replay_episodes_score_as_the_benchmark_evaluation(rollout, log_replay):
    _, out = rollout
    res = evaluate(log_replay, load_suite(TINY), "train")
    oracle = {i: row for i, row in enumerate(res.rows)}
    done = out["done"]
    checked = set()
    for b in np.flatnonzero(LOG_REPLAY):
        for t in np.flatnonzero(done[:, b]):
            i = int(out["episode_scenario_index"][t, b])
            row = oracle[i]
            assert out["episode_route_completion"][t, b] == pytest.approx(row["route_completion"], abs=1e-3)
            assert out["episode_driving_score"][t, b] == pytest.approx(row["driving_score"], abs=1e-3)
            assert STATUS_NAMES[int(out["episode_status"][t, b])] == row["status"]
            checked.add(i)
    assert checked == set(oracle), "log replay ran on every scenario of the split"


def test_reward_is_route_progress_minus_penalties(rollout, params):
    """Reward = metres of route progress - penalties (which only ever subtract);
    over a log-replay episode the progress adds up to RC% of the route length
    (to the 1 m route spacing) and the penalties to the LB 2.0 share of it."""
    _, out = rollout
    assert (out["progress_m"] - out["reward"] >= -1e-4).all()
    assert (out["progress_m"] >= 0).all()
    length = np.asarray(params.scenarios.route.length).astype(float)
    done = out["done"]
    for b in np.flatnonzero(LOG_REPLAY):
        ends = np.flatnonzero(done[:, b])
        for start, end in zip(np.r_[0, ends[:-1] + 1], ends):
            i = int(out["episode_scenario_index"][end, b])
            progress = out["progress_m"][start:end + 1, b].sum()
            rc = out["episode_route_completion"][end, b]
            assert progress == pytest.approx(rc / 100 * length[i], abs=1.5)
            # penalty units x route length; IS = product of (1 - units) per event
            penalty = progress - out["episode_return"][end, b]
            infraction = out["episode_infraction_score"][end, b]
            assert penalty == pytest.approx((1 - infraction) * length[i], abs=1.5 + 1e-3 * float(length[i]))
    assert RewardConfig().collision_vehicle == pytest.approx(0.4)
    assert RewardConfig().collision_pedestrian == pytest.approx(0.5)


def test_as_action():
    assert isinstance(as_action(Controls(jnp.float32(0), jnp.float32(1), jnp.float32(0))), Controls)
    c = as_action(jnp.array([0.25, 0.0, -0.5]))
    assert isinstance(c, Controls) and float(c.steer) == -0.5
    assert isinstance(as_action(jnp.zeros((4, 2))), Waypoints)
    with pytest.raises(ValueError, match="action"):
        as_action(jnp.zeros(5))


def test_cached_contexts_reset_equals_a_fresh_reset(params):
    """make_params caches each scenario's per-episode constants; a reset that
    uses them gives exactly the observation and state of one that derives them."""
    assert params.contexts is not None and params.contexts_config == params.config
    reset = jax.jit(DriveEnv().reset)
    key = jax.random.PRNGKey(3)
    cached = reset(key, params, 1)
    fresh = reset(key, params.replace(contexts=None), 1)
    for a, b in zip(jax.tree_util.tree_leaves(cached), jax.tree_util.tree_leaves(fresh), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("max_resets", [1, 3])
def test_vmap_auto_reset_equals_the_vmapped_wrapper(params, max_resets):
    """Resetting only the environments that ended (gathered, at most
    ``max_resets`` per step, else the vmapped path) gives the vmapped
    AutoResetWrapper's outputs and states, step for step (integers and
    booleans exactly, floats to float32 rounding)."""
    n, steps = 8, 150
    offset = jnp.array([0, 0, 0, 0, 9, 17, 17, 30])   # steps each environment starts into its episode
    ref_env, env = AutoResetWrapper(DriveEnv()), VmapAutoResetWrapper(DriveEnv(), max_resets=max_resets)
    ref_step = jax.vmap(ref_env.step, in_axes=(0, 0, 0, None))
    full_throttle = jnp.tile(jnp.array([1.0, 0.0, 0.0]), (n, 1))

    def run(step_fn, key):
        k_reset, k_run = jax.random.split(key)
        obs, state = jax.vmap(ref_env.reset, in_axes=(0, None))(jax.random.split(k_reset, n), params)

        def preroll(carry, k):
            obs, state, t = carry
            obs2, state2, *_ = ref_step(jax.random.split(jax.random.PRNGKey(9), n), state, full_throttle, params)
            go = offset > t
            pick = lambda a, b: jnp.where(go.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)
            return (jax.tree_util.tree_map(pick, obs2, obs), jax.tree_util.tree_map(pick, state2, state), t + 1), None

        (obs, state, _), _ = jax.lax.scan(preroll, (obs, state, 0), None, 30)

        def body(carry, key):
            obs, state = carry
            k_act, k_step = jax.random.split(key)
            action = jax.random.uniform(k_act, (n, 3), minval=jnp.array([0.0, 0.0, -0.3]), maxval=jnp.array([1.0, 0.3, 0.3]))
            obs, state, reward, done, info = step_fn(jax.random.split(k_step, n), state, action, params)
            return (obs, state), (obs, reward, done, info)

        return jax.lax.scan(body, (obs, state), jax.random.split(k_run, steps))

    key = jax.random.PRNGKey(3)
    ref = jax.jit(lambda k: run(ref_step, k))(key)
    got = jax.jit(lambda k: run(env.step, k))(key)
    ends = np.asarray(ref[1][2]).sum(1)
    # both paths ran: steps where a few ended (gathered) and where more did (vmapped)
    assert ((ends >= 1) & (ends <= max_resets)).sum() >= 5, np.bincount(ends)
    assert (ends > max_resets).any(), np.bincount(ends)
    flat_ref, tree_ref = jax.tree_util.tree_flatten(ref)
    flat_got, tree_got = jax.tree_util.tree_flatten(got)
    assert tree_ref == tree_got
    for a, b in zip(flat_ref, flat_got, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if np.issubdtype(a.dtype, np.floating):
            # XLA:CPU vectorises a reset of K rows and one of B rows
            # differently, so sin / cos may round the last bit differently
            np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-5)
        else:
            np.testing.assert_array_equal(b, a)


def test_vmap_auto_reset_rejects_negative_max_resets():
    with pytest.raises(ValueError, match="max_resets"):
        VmapAutoResetWrapper(max_resets=-1)


def test_at_fault_only_drops_the_penalty_of_contacts_that_are_not_the_egos_fault(params):
    from drivee2e_jax.sim import Simulator
    from drivee2e_jax.types import CollisionClass

    env = DriveEnv()
    # Reset and step compiled: run op by op they took ~40 s of the suite.
    _, state = jax.jit(env.reset)(jax.random.PRNGKey(0), params, 0)
    scenario = env.scenario(state, params)
    sim = Simulator(params.config)
    new, _, log = jax.jit(sim.step)(scenario, state.sim, Controls(throttle=0.5, brake=0.0, steer=0.0))
    hit = log.replace(events=log.events.replace(collision=jnp.bool_(True),
                                                collision_class=jnp.int32(CollisionClass.VEHICLE)))
    penalty = float(scenario.route.length) * RewardConfig().collision_vehicle
    for at_fault in (False, True):
        step = hit.replace(facts=hit.facts.replace(at_fault=jnp.bool_(at_fault)))
        clean = float(RewardConfig()(scenario, state.sim, new, log, params.config))
        every = float(RewardConfig()(scenario, state.sim, new, step, params.config))
        only = float(RewardConfig(at_fault_only=True)(scenario, state.sim, new, step, params.config))
        assert every == pytest.approx(clean - penalty, rel=1e-5)
        assert only == pytest.approx(every if at_fault else clean, rel=1e-5)
    layout = hit.replace(events=hit.events.replace(collision_class=jnp.int32(CollisionClass.LAYOUT)))
    assert float(RewardConfig(at_fault_only=True)(scenario, state.sim, new, layout, params.config)) == pytest.approx(
        clean - float(scenario.route.length) * RewardConfig().collision_layout, rel=1e-5)
