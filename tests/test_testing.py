"""testing: the policy conformance check passes every reference policy and
catches each way of breaking the contract with one line naming the file."""

from __future__ import annotations

import textwrap

import jax
import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import device_batch, first_observation
from drivee2e_jax.policy import load_policy, reference_policy_dir
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.sim import Simulator
from drivee2e_jax.testing import (
    TINY_SUITE,
    Problem,
    check_policy,
    check_policy_file,
    check_traceable,
    checked_params,
)

#: Small and shared: every check below reuses one set of observations.
SMALL = {"batch": 2, "steps": 2}
REPO = reference_policy_dir().parents[1]

JAX_HEADER = """\
import time

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls, Waypoints


def z(dtype=jnp.float32):
    return jnp.zeros((), dtype)


class Base(StatelessPolicy):
    name = "bad"
    action_type = "controls"
"""

HOST_HEADER = """\
import numpy as np

from drivee2e_jax.hostapi import Controls, HostPolicy, Waypoints


class Base(HostPolicy):
    name = "bad_host"
    action_type = "controls"

    def reset(self, meta):
        return {"n": len(meta)}

    def brake(self, b):
        z = np.zeros(b, np.float32)
        return Controls(throttle=z, brake=np.ones(b, np.float32), steer=z)
"""


def _write(tmp_path, header: str, body: str, name: str = "bad_policy.py"):
    path = tmp_path / name
    path.write_text(header + "\n\n" + textwrap.dedent(body) + "\npolicy = P()\n")
    return path


def _assert_one_line_naming(report, path) -> None:
    assert report, "expected problems"
    for p in report:
        assert isinstance(p, Problem)
        assert "\n" not in p.message and p.message.startswith(f"{path}: "), p.message


# --------------------------------------------------------------------------
# Conformant policies
# --------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["log_replay", "expert", "stop", "constant_velocity"])
def test_reference_policies_conform(name):
    report = check_policy_file(REPO / "drivee2e_jax" / "zoo" / f"{name}.py", **SMALL)
    assert report.ok, [str(p) for p in report]
    assert report.summary.startswith(f"{name}: JAX policy, ")
    assert ("Waypoints xy (6, 2) float32" if name == "constant_velocity" else "Controls") in report.summary


def test_model_policy_with_random_init_conforms():
    from drivee2e_jax.models.base import policy_from_checkpoint

    report = check_policy(policy_from_checkpoint("ad_mlp", None, "traj"), source="drivee2e_jax/zoo/ad_mlp.py", **SMALL)
    assert report.ok, [str(p) for p in report]
    assert "Waypoints xy (6, 2) float32" in report.summary and "state: 7 leaves" in report.summary


def test_host_example_conforms():
    report = check_policy_file(REPO / "docs" / "examples" / "numpy_constant_velocity.py", **SMALL)
    assert report.ok, [str(p) for p in report]
    assert report.summary.startswith("np_constant_velocity: host policy, Waypoints xy (B, 6, 2) float32")


def test_suite_by_path_and_spec_arguments(tmp_path):
    path = _write(tmp_path, JAX_HEADER, """\
        class P(Base):
            def __init__(self, throttle=0.0):
                self.throttle = float(throttle)

            def act(self, params, obs, state, key):
                return Controls(throttle=z() + self.throttle, brake=z(), steer=z()), state

        def make_policy(throttle=0.0):
            return P(throttle)
    """)
    report = check_policy_file(f"{path}:throttle=0.5,name=half", suite=TINY_SUITE, **SMALL)
    assert report.ok and report.summary.startswith("half: JAX policy"), list(report)


def test_unloadable_files_raise_one_line(tmp_path):
    with pytest.raises(DriveE2EError, match="policy file not found"):
        check_policy_file(tmp_path / "missing.py")
    broken = tmp_path / "broken.py"
    broken.write_text("import no_such_module_xyz\n")
    with pytest.raises(DriveE2EError, match="importing the policy failed"):
        check_policy_file(broken)


# --------------------------------------------------------------------------
# Broken JAX policies: each caught, one line naming the file
# --------------------------------------------------------------------------

JAX_CASES = {
    "wrong_action_type": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Waypoints(xy=jnp.zeros((4, 2), jnp.float32)), state
     """, "action", "act returned a Waypoints action (step 0, scenario"),
    "wrong_shape": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=jnp.zeros((1,), jnp.float32), brake=z(), steer=z()), state
     """, "action", "action Controls.throttle has shape (1,)"),
    "waypoints_wrong_shape": ("""\
        class P(Base):
            action_type = "waypoints"
            num_waypoints = 4

            def act(self, params, obs, state, key):
                return Waypoints(xy=jnp.zeros((3, 2), jnp.float32)), state
     """, "action", "has 3 waypoints (shape (3, 2), step 0"),
    "float64": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=np.zeros((), np.float64), brake=z(), steer=z()), state
     """, "action", "action Controls.throttle has dtype float64"),
    "int": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(jnp.int32), steer=z()), state
     """, "action", "action Controls.brake has dtype int32"),
    "dict_action": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return {"throttle": z(), "brake": z(), "steer": z()}, state
     """, "action", "act returned a dict with keys [throttle, brake, steer] as the action"),
    "not_a_pair": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z())
     """, "act", "expected a pair (action, policy_state)"),
    "nan": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=z() * jnp.nan, brake=z(), steer=z()), state
     """, "finite", "act returned a non-finite action: Controls.throttle holds nan"),
    "numpy_random": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=z() + np.random.rand(), brake=z(), steer=z()), state
     """, "determinism", "act is not deterministic"),
    "time": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                time.sleep(0.002)  # two calls >= 2000 us apart: different microsecond readings
                clock = (time.perf_counter_ns() // 1000) % 1_000_000 / 1e6
                return Controls(throttle=z(), brake=z(), steer=z() + clock), state
     """, "determinism", "draw randomness from `key`"),
    "python_if": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                if obs.ego[0] > -1.0:
                    return Controls(throttle=z(), brake=z(), steer=z()), state
                return Controls(throttle=z(), brake=z() + 1, steer=z()), state
     """, "jit", "act fails under jax.jit: Python control flow or conversion on a traced value at "),
    "state_forgotten": ("""\
        class P(Base):
            def initial_state(self, obs):
                return {"count": jnp.zeros((), jnp.int32)}

            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z()), None
     """, "state", "act changed the policy state's structure (step 0, scenario"),
    "state_reshaped": ("""\
        class P(Base):
            def initial_state(self, obs):
                return {"history": jnp.zeros((3, 2), jnp.float32)}

            def act(self, params, obs, state, key):
                h = jnp.concatenate([state["history"], obs.gps[None]])
                return Controls(throttle=z(), brake=z(), steer=z()), {"history": h}
     """, "state", "act changed the policy state at ['history'] (step 0, scenario"),
    "act_raises": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                raise RuntimeError("boom")
     """, "act", "act(params, obs, state, key) raised RuntimeError: boom at "),
    "bad_attributes": ("""\
        class P(Base):
            name = ""
            action_type = "steering"

            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z()), state
     """, "attributes", "action_type is 'steering', expected 'controls' or 'waypoints'"),
    "bad_waypoint_dt": ("""\
        class P(Base):
            action_type = "waypoints"
            waypoint_dt = 0

            def act(self, params, obs, state, key):
                return Waypoints(xy=jnp.zeros((4, 2), jnp.float32)), state
     """, "attributes", "waypoint_dt is 0, expected a positive number of seconds"),
    "unknown_sensor": ("""\
        class P(Base):
            required_sensors = ("sonar",)

            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z()), state
     """, "attributes", "required_sensors names the unknown sensor 'sonar'"),
}


@pytest.mark.parametrize("case", list(JAX_CASES))
def test_broken_jax_policy_is_caught(tmp_path, case):
    body, check, text = JAX_CASES[case]
    path = _write(tmp_path, JAX_HEADER, body)
    report = check_policy_file(path, **SMALL)
    _assert_one_line_naming(report, path)
    hits = [p for p in report if p.check == check and text in p.message]
    assert hits, [str(p) for p in report]


def test_randomness_from_the_key_is_fine(tmp_path):
    """Sampling with `key` is deterministic for a fixed key, and under vmap
    each scenario gets its own key."""
    path = _write(tmp_path, JAX_HEADER, """\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=jax.random.uniform(key), brake=z(), steer=z()), state
    """)
    report = check_policy_file(path, **SMALL)
    assert report.ok, [str(p) for p in report]


# --------------------------------------------------------------------------
# Broken host policies
# --------------------------------------------------------------------------

HOST_CASES = {
    "wrong_batch_size": ("""\
        class P(Base):
            def act(self, obs, state):
                return self.brake(obs.batch_size + 1), state
     """, "action", "has batch size 3 (shape (3,)), expected 2"),
    "wrong_type": ("""\
        class P(Base):
            def act(self, obs, state):
                return Waypoints(xy=np.zeros((obs.batch_size, 4, 2), np.float32)), state
     """, "action", "a Waypoints action, but the policy's action_type is 'controls'"),
    "dict_action": ("""\
        class P(Base):
            def act(self, obs, state):
                b = obs.batch_size
                return {"throttle": np.zeros(b), "brake": np.zeros(b), "steer": np.zeros(b)}, state
     """, "action", "the action is a dict with keys [throttle, brake, steer]"),
    "reset_raises": ("""\
        class P(Base):
            def reset(self, meta):
                raise KeyError("weights")

            def act(self, obs, state):
                return self.brake(obs.batch_size), state
     """, "reset", "reset(meta) raised KeyError: 'weights'"),
    "act_raises": ("""\
        class P(Base):
            def act(self, obs, state):
                raise ValueError("no GPU")
     """, "act", "act(obs, state) raised ValueError: no GPU at "),
    "no_state": ("""\
        class P(Base):
            def act(self, obs, state):
                return self.brake(obs.batch_size)
     """, "action", "expected a pair (action, state)"),
    "state_forgotten": ("""\
        class P(Base):
            def act(self, obs, state):
                return self.brake(obs.batch_size), None
     """, "state", "act returned the state None (step 0)"),
    "nan": ("""\
        class P(Base):
            def act(self, obs, state):
                a = self.brake(obs.batch_size)
                a.brake[1] = np.nan
                return a, state
     """, "finite", "Controls.brake holds nan (step 0, scenario"),
    "nondeterministic": ("""\
        class P(Base):
            def act(self, obs, state):
                a = self.brake(obs.batch_size)
                return Controls(throttle=np.random.rand(obs.batch_size), brake=a.brake, steer=a.steer), state
     """, "determinism", "two fresh reset(meta) + act(obs) on the same observation give different actions"),
}


@pytest.mark.parametrize("case", list(HOST_CASES))
def test_broken_host_policy_is_caught(tmp_path, case):
    body, check, text = HOST_CASES[case]
    path = _write(tmp_path, HOST_HEADER, body)
    report = check_policy_file(path, **SMALL)
    _assert_one_line_naming(report, path)
    hits = [p for p in report if p.check == check and text in p.message]
    assert hits, [str(p) for p in report]


# --------------------------------------------------------------------------
# check_traceable / checked_params: evaluate's abstract check before compiling
# --------------------------------------------------------------------------

#: body, then the text of the one problem; "{at}" is "<file>:<line of the # HERE comment>".
TRACE_CASES = {
    "act_raises": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                raise ValueError("no lane ahead")  # HERE
     """, "act(params, obs, state, key) raised ValueError: no lane ahead at {at} (traced on the probe)"),
    "python_if": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                if obs.ego[0] > 1.0:  # HERE
                    return Controls(throttle=z(), brake=z(), steer=z()), state
                return Controls(throttle=z(), brake=z() + 1, steer=z()), state
     """, "act(params, obs, state, key) branches on a traced value (Python if/while/bool on an array) at {at}; "
          "use jnp.where or jax.lax.cond (traced on the probe)"),
    "int_of_array": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                k = int(obs.ego[0])  # HERE
                return Controls(throttle=z() + k, brake=z(), steer=z()), state
     """, "act(params, obs, state, key) uses a traced value where a concrete one is needed (int() / float(), a "
          "shape or a Python index computed from an array) at {at}"),
    "dict_action": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return {"throttle": z(), "brake": z(), "steer": z()}, state
     """, "act returned a dict with keys [brake, steer, throttle] as the action (traced on the probe), expected "
          "drivee2e_jax.types.Controls(throttle, brake, steer) of float32 scalars"),
    "wrong_shape": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=jnp.zeros((2,), jnp.float32), brake=z(), steer=z()), state
     """, "action Controls.throttle has shape (2,) (traced on the probe), expected ()"),
    "not_a_pair": ("""\
        class P(Base):
            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z())
     """, "act returned a drivee2e_jax.types.Controls (traced on the probe), expected a pair (action, policy_state)"),
    "state_forgotten": ("""\
        class P(Base):
            def initial_state(self, obs):
                return {"n": jnp.zeros((), jnp.int32)}

            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z()), None
     """, "act changed the policy state's structure (traced on the probe): initial_state gave PyTreeDef({{'n': *}}), "
          "act returned None"),
    "state_other_structure": ("""\
        class P(Base):
            def initial_state(self, obs):
                return {"n": jnp.zeros((), jnp.int32)}

            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z()), (state["n"], state["n"])
     """, "act returned PyTreeDef((*, *))"),
    "initial_state_raises": ("""\
        class P(Base):
            def initial_state(self, obs):
                raise KeyError("history")  # HERE
     """, "initial_state(obs) raised KeyError: 'history' at {at} (traced on the probe)"),
    "init_raises": ("""\
        class P(Base):
            def init(self, key, obs):
                raise FileNotFoundError("weights.npz")  # HERE

            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z()), state
     """, "init(key, obs) raised FileNotFoundError: weights.npz at {at} (on the probe)"),
    "params_not_arrays": ("""\
        class P(Base):
            def init(self, key, obs):
                return {"w": jnp.ones(3), "note": "v2"}

            def act(self, params, obs, state, key):
                return Controls(throttle=z(), brake=z(), steer=z()), state
     """, "init(key, obs) returned params with a str 'v2' at ['note'], expected a pytree of arrays"),
}


@pytest.fixture(scope="module")
def probe_obs():
    """One scenario's observation of the tiny suite (no batch axis)."""
    batch, _ = device_batch(load_suite(str(TINY_SUITE)).pack(None), limit=1)
    obs = first_observation(Simulator(), batch, jax.random.PRNGKey(0))
    return jax.tree_util.tree_map(lambda a: a[0], obs), jax.random.PRNGKey(1)


@pytest.mark.parametrize("case", list(TRACE_CASES))
def test_checked_params_is_one_line_naming_file_and_line(tmp_path, probe_obs, case):
    body, text = TRACE_CASES[case]
    path = _write(tmp_path, JAX_HEADER, body)
    lines = path.read_text().splitlines()
    at = next((f"{path}:{i + 1}" for i, s in enumerate(lines) if s.endswith("# HERE")), None)
    obs, key = probe_obs
    with pytest.raises(DriveE2EError) as e:
        checked_params(load_policy(path), obs, key, where="on the probe")
    msg = str(e.value)
    assert msg.startswith(f"{path}: ") and "\n" not in msg and "Traceback" not in msg
    assert text.format(at=at) in msg, msg


def test_checked_params_passes_good_policies_and_keeps_given_params(probe_obs):
    obs, key = probe_obs
    for name in ("expert", "log_replay", "constant_velocity"):
        pol = load_policy(reference_policy_dir() / f"{name}.py")
        assert check_traceable(pol, obs, None, key).ok
    given = {"w": np.ones(2, np.float32)}
    assert checked_params(pol, obs, key, given) is given


def test_default_steps_catch_a_failure_after_the_warm_up(tmp_path):
    from drivee2e_jax.cli import build_parser
    from drivee2e_jax.testing import DEFAULT_STEPS, check_policy_file

    path = tmp_path / "late.py"
    path.write_text(textwrap.dedent("""
        import numpy as np
        from drivee2e_jax.hostapi import Controls, HostPolicy


        class Late(HostPolicy):
            name = "late"
            action_type = "controls"
            observation_fields = ("route",)

            def reset(self, meta):
                return 0

            def act(self, obs, state):
                if state == 3:  # after a 3-call warm-up (the old default missed it)
                    raise RuntimeError("buffer full")
                z = np.zeros(obs.route.shape[0], np.float32)
                return Controls(throttle=z, steer=z, brake=z), state + 1


        policy = Late()
    """))
    report = check_policy_file(path, suite="tiny", batch=2)
    assert not report.ok
    assert any("buffer full" in str(p) and "step 3" in str(p) for p in report), [str(p) for p in report]
    assert build_parser().parse_args(["check-policy", "x.py"]).steps == DEFAULT_STEPS
