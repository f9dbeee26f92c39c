"""evaluate(): a broken JAX policy is one line naming its file and line before
anything compiles; episodes with NaN actions and maps without lanes come back
as EvalResult.warnings instead of silently scored."""

from __future__ import annotations

import textwrap

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import evaluate, lane_free_warning, nonfinite_warning
from drivee2e_jax.policy import load_policy
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.scenario.batch import PackedBatch
from drivee2e_jax.testing import TINY_SUITE

HEADER = """\
import jax.numpy as jnp

from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls


def z():
    return jnp.zeros((), jnp.float32)


class P(StatelessPolicy):
    name = "p"
"""


def _policy(tmp_path, body: str):
    path = tmp_path / "my_policy.py"
    path.write_text(HEADER + textwrap.indent(textwrap.dedent(body), "    ") + "\n\npolicy = P()\n")
    return path, load_policy(path)


@pytest.fixture(scope="module")
def packed():
    return load_suite(str(TINY_SUITE)).pack(None)


def test_policy_branching_on_a_traced_value_is_one_line_with_its_line(tmp_path, packed):
    path, pol = _policy(tmp_path, """\
        def act(self, params, obs, state, key):
            if obs.ego[0] > -1.0:
                return Controls(throttle=z(), brake=z(), steer=z()), state
            return Controls(throttle=z(), brake=z() + 1, steer=z()), state
    """)
    line = path.read_text().splitlines().index("        if obs.ego[0] > -1.0:") + 1
    with pytest.raises(DriveE2EError) as e:
        evaluate(pol, packed.select([0]), None)
    msg = str(e.value)
    assert msg.startswith(f"{path}: act(params, obs, state, key) branches on a traced value (Python if/while/bool "
                          f"on an array) at {path}:{line}; use jnp.where or jax.lax.cond"), msg
    assert f"scenario {packed.meta.scenario_id[0]}'s first observation" in msg and "\n" not in msg


@pytest.mark.parametrize("body, expected", [
    ("""\
        def initial_state(self, obs):
            if obs.ego[0] > -1.0:
                return {"n": jnp.zeros(())}
            return {"n": jnp.ones(())}
    """, "initial_state(obs) branches on a traced value (Python if/while/bool on an array) at {path}:{line}; "
        "use jnp.where or jax.lax.cond "
        "(traced on scenario s_straight's first observation)"),
    ("""\
        def initial_state(self, obs):
            return {"name": "history"}
    """, "initial_state returned a state with a str 'history' at ['name'], expected arrays only"),
], ids=["branches", "str_leaf"])
def test_a_broken_initial_state_is_one_line_although_it_is_traced_in_the_reset(tmp_path, packed, body, expected):
    """``initial_state`` is traced inside the compiled batch reset (``Rollout.reset``),
    before the params exist: its failure is still the checker's one line."""
    path, pol = _policy(tmp_path, textwrap.dedent(body) + textwrap.dedent("""\
        def act(self, params, obs, state, key):
            return Controls(throttle=z(), brake=z(), steer=z()), state
    """))
    with pytest.raises(DriveE2EError) as e:
        evaluate(pol, packed.select([0]), None)
    msg = str(e.value)
    lines = path.read_text().splitlines()
    line = lines.index("        if obs.ego[0] > -1.0:") + 1 if "        if obs.ego[0] > -1.0:" in lines else None
    assert msg.startswith(f"{path}: ") and expected.format(path=path, line=line) in msg and "\n" not in msg, msg


def test_nan_actions_and_a_lane_free_map_are_warned_about(tmp_path, packed):
    """The user's report: an all-NaN policy scores DS > 0 and nothing says so;
    a map without lanes gives 100 % off-lane silently."""
    _, pol = _policy(tmp_path, """\
        def act(self, params, obs, state, key):
            n = jnp.full((), jnp.nan, jnp.float32)
            return Controls(throttle=n, brake=n, steer=n), state
    """)
    two = packed.select([0, 1])
    valid, points = (np.asarray(a).copy() for a in (two.scenario.map.lanes.valid, two.scenario.map.lanes.point_valid))
    valid[1], points[1] = False, False  # scenario 1's map loses its lanes
    lanes = two.scenario.map.lanes.replace(valid=valid, point_valid=points)
    two = PackedBatch(two.scenario.replace(map=two.scenario.map.replace(lanes=lanes)), two.meta)
    res = evaluate(pol, two, None, chunk=100)
    assert any(r["driving_score"] > 0 for r in res.rows)  # what the user saw: a score for NaN actions
    nan_line = next(w for w in res.warnings if "non-finite" in w)
    steps = [r["invalid_action"] for r in res.rows]  # every running step was repaired
    assert nan_line == (f"2 of 2 episodes had non-finite actions ({sum(steps)} steps in all; replaced by a full "
                        f"brake: throttle 0, brake 1, steer 0); results may be meaningless")
    lane_line = next(w for w in res.warnings if "no lanes" in w)
    assert lane_line.startswith(f"1 scenario(s) have a map with no lanes ({two.meta.scenario_id[1]}): ")


def test_a_working_policy_gets_no_warnings(packed):
    assert nonfinite_warning(np.zeros(3, np.int32), "controls") == []
    valid = np.asarray(packed.scenario.map.lanes.valid)
    assert valid.any(axis=1).all() and lane_free_warning(valid, packed.meta.scenario_id) == []


def test_warning_lines_count_and_cut():
    (line,) = nonfinite_warning(np.array([0, 3, 0, 1]), "waypoints")
    assert line.startswith("2 of 4 episodes had non-finite actions (4 steps in all; NaN / inf waypoint")
    valid = np.ones((8, 2, 3), bool)
    valid[1:] = False
    ids = np.array([f"s{i}" for i in range(4)] * 2)  # two repetitions of 4 scenarios
    (line,) = lane_free_warning(valid, ids, shown=2)
    assert line.startswith("4 scenario(s) have a map with no lanes (s1, s2, ...): ")


def test_host_policy_raising_is_one_line_with_its_line(tmp_path, packed):
    path = tmp_path / "host_policy.py"
    path.write_text(textwrap.dedent("""\
        from drivee2e_jax.hostapi import HostPolicy


        class P(HostPolicy):
            name = "host"
            action_type = "waypoints"
            waypoint_dt = 0.5

            def reset(self, meta):
                return None

            def act(self, obs, state):
                raise RuntimeError("CUDA out of memory")  # HERE


        policy = P()
    """))
    line = next(i + 1 for i, s in enumerate(path.read_text().splitlines()) if s.endswith("# HERE"))
    with pytest.raises(DriveE2EError) as e:
        evaluate(load_policy(path), packed.select([0]), None)
    msg = str(e.value)
    assert msg == (f"{path}, probing the number of waypoints: act raised RuntimeError: CUDA out of memory at "
                   f"{path}:{line}")
