"""dynamics.DynamicsModel: the bicycle satisfies it, SimConfig selects it, the
simulator goes through it (bit-identical to calling the bicycle directly)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax import dynamics as dyn
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.policy import load_policy
from drivee2e_jax.sim import SimConfig, Simulator
from drivee2e_jax.types import Controls, EgoState
from tests.helpers import sim_scenarios as ss

P = dyn.BicycleParams()
POLICIES = Path(__file__).resolve().parents[1] / "drivee2e_jax" / "zoo"


@dataclasses.dataclass(frozen=True)
class Delegating:
    """A model of its own class that delegates to the module functions."""

    name: ClassVar[str] = "delegating"

    def initial_state(self, xy, yaw, vel, t):
        return dyn.ego_from_log(xy, yaw, vel, t)

    def step(self, ego, controls, dt, params):
        return dyn.step(ego, controls, dt, params)

    def inverse(self, ego, next_xy, next_yaw, dt, params):
        return dyn.inverse(ego, next_xy, next_yaw, dt, params)


@dataclasses.dataclass(frozen=True)
class Parked(Delegating):
    """Never moves: only the clock advances."""

    name: ClassVar[str] = "parked"

    def step(self, ego, controls, dt, params):
        return ego.replace(t=ego.t + dt)


def _ego(x, y, yaw, speed, steer) -> EgoState:
    f = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    return EgoState(xy=f([x, y]), yaw=f(yaw), speed=f(speed), accel=f(0.0), steer=f(steer), yaw_rate=f(0.0), t=f(0.0))


def _same(a, b) -> None:
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_the_bicycle_is_a_registered_hashable_dynamics_model():
    model = dyn.KinematicBicycle()
    assert isinstance(model, dyn.DynamicsModel)
    assert isinstance(Delegating(), dyn.DynamicsModel)
    assert not isinstance(object(), dyn.DynamicsModel)
    assert model == dyn.KinematicBicycle() and hash(model) == hash(dyn.KinematicBicycle())
    assert dyn.get_dynamics_model("kinematic_bicycle") == model
    assert dyn.DYNAMICS_MODELS[model.name] == model
    with pytest.raises(ValueError, match="unknown dynamics model"):
        dyn.get_dynamics_model("unicycle")


def test_simconfig_defaults_to_the_bicycle_and_stays_hashable():
    cfg = SimConfig()
    assert cfg.dynamics_model == dyn.KinematicBicycle()
    assert SimConfig(dynamics_model=dyn.KinematicBicycle()) == cfg
    other = SimConfig(dynamics_model=Delegating())
    assert other != cfg and isinstance(hash(other), int)  # another model: another static config
    with pytest.raises(TypeError, match="DynamicsModel"):
        SimConfig(dynamics_model=object())


@settings(deadline=None, max_examples=25)
@given(
    x=st.floats(-50, 50), y=st.floats(-50, 50), yaw=st.floats(-3.1, 3.1), speed=st.floats(0, 20),
    steer=st.floats(-0.6, 0.6), throttle=st.floats(0, 1), brake=st.floats(0, 1), csteer=st.floats(-1, 1),
)
def test_the_bicycle_model_steps_and_inverts_exactly_as_the_functions(x, y, yaw, speed, steer, throttle, brake, csteer):
    model = dyn.KinematicBicycle()
    ego = _ego(x, y, yaw, speed, steer)
    c = Controls(jnp.float32(throttle), jnp.float32(brake), jnp.float32(csteer))
    _same(model.step(ego, c, 0.1, P), dyn.step(ego, c, 0.1, P))
    nxt = dyn.step(ego, c, 0.1, P)
    _same(model.inverse(ego, nxt.xy, nxt.yaw, 0.1, P), dyn.inverse(ego, nxt.xy, nxt.yaw, 0.1, P))
    xy, v = jnp.asarray([x, y], jnp.float32), jnp.asarray([speed, 0.0], jnp.float32)
    _same(model.initial_state(xy, jnp.float32(yaw), v, jnp.float32(0)), dyn.ego_from_log(xy, jnp.float32(yaw), v, jnp.float32(0)))


@pytest.fixture(scope="module")
def scenario():
    batch = ss.build([ss.clean()])
    return jax.tree_util.tree_map(lambda a: jnp.asarray(a[0]), batch.scenario)


def _run(cfg: SimConfig, scenario, n: int = 20):
    sim = Simulator(cfg)
    state, obs = jax.jit(sim.reset)(jax.random.PRNGKey(0), scenario)
    step = jax.jit(sim.step)
    out = [(state, obs)]
    c = Controls(jnp.float32(0.6), jnp.float32(0.0), jnp.float32(0.2))
    for _ in range(n):
        state, obs, log = step(scenario, state, c)
        out.append((state.replace(ctx=None), obs, log))
    return out


def test_a_simconfig_with_the_model_steps_identically(scenario):
    base = _run(SimConfig(), scenario)
    _same(_run(SimConfig(dynamics_model=dyn.KinematicBicycle()), scenario), base)
    _same(_run(SimConfig(dynamics_model=Delegating()), scenario), base)  # another class, same functions


def test_the_simulator_goes_through_the_model(scenario):
    out = _run(SimConfig(dynamics_model=Parked()), scenario, n=5)
    start = np.asarray(out[0][0].ego.xy)
    for state, _, log in out[1:]:
        np.testing.assert_array_equal(np.asarray(state.ego.xy), start)
        assert float(log.t) > 0


def test_evaluate_with_the_explicit_bicycle_gives_the_same_rows():
    """log_replay acts on the model's inverse (``Privileged.log_controls``)."""
    batch = ss.build([ss.clean(), ss.blocked_by_car()])
    pol = load_policy(POLICIES / "log_replay.py")
    a = evaluate(pol, batch, None, chunk=25)
    b = evaluate(pol, batch, None, config=SimConfig(dynamics_model=Delegating()), chunk=25)
    strip = lambda rows: [{k: v for k, v in r.items() if k != "eval_time_s"} for r in rows]  # noqa: E731
    assert strip(a.rows) == strip(b.rows)
    np.testing.assert_array_equal(np.asarray(a.logs.xy), np.asarray(b.logs.xy))
    np.testing.assert_array_equal(np.asarray(a.logs.throttle), np.asarray(b.logs.throttle))
