"""The open-loop driver (``drivee2e_jax.eval.openloop``) and the constant-velocity
baseline on hand-built scenarios (``tests/helpers/sim_scenarios.py``): straight 10 m/s logs.

One compiled program for the module: the policy under test is the
constant-velocity file wrapped with a lateral offset taken from ``params``, so
the exact baseline (offset 0) and a wrong policy (offset 3.5 m) reuse the same
executable.
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax import controller as ctl
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.openloop import evaluate_openloop, resample_waypoints
from drivee2e_jax.policy import StatelessPolicy, load_policy
from drivee2e_jax.types import Waypoints
from tests.helpers import sim_scenarios as ss

POLICIES = Path(__file__).resolve().parents[2] / "drivee2e_jax" / "zoo"
KEYS = ("l2_1s_stp3", "l2_2s_stp3", "l2_3s_stp3", "l2_1s_uniad", "l2_2s_uniad", "l2_3s_uniad",
        "openloop_collision_rate", "openloop_samples")
L2_KEYS = KEYS[:6]


@pytest.fixture(scope="module")
def cv():
    return load_policy(POLICIES / "constant_velocity.py")


class Offset(StatelessPolicy):
    """``base``'s waypoints shifted left by ``params["dy"]`` m."""

    name = "offset"
    action_type = "waypoints"

    def __init__(self, base):
        self.base = base
        self.waypoint_dt = base.waypoint_dt

    def init(self, key, obs):
        return {"dy": jnp.zeros((), jnp.float32)}

    def act(self, params, obs, policy_state, key):
        wp, state = self.base.act(None, obs, policy_state, key)
        return Waypoints(xy=wp.xy + jnp.stack([jnp.zeros(()), params["dy"]])), state


@pytest.fixture(scope="module")
def results(cv):
    batch = ss.build([ss.clean(), ss.blocked_by_car()])
    pol = Offset(cv)
    exact = evaluate_openloop(pol, batch, params={"dy": jnp.float32(0.0)})
    wrong = evaluate_openloop(pol, batch, params={"dy": jnp.float32(3.5)})
    return exact, wrong


def test_keys_and_samples(results):
    for res in results:
        assert set(res) == {"clean", "car_ahead"}
        for row in res.values():
            assert set(KEYS) <= set(row)
            # 2 Hz queries whose 3 s future lies inside the 8 s ego log: t = 0 .. 5 s.
            assert row["openloop_samples"] == 11
            assert row["openloop_log_deviation_m"] < 1e-3  # the replayed ego is on its log


def test_constant_velocity_is_exact_on_a_constant_speed_log(results):
    exact, _ = results
    for row in exact.values():
        for k in L2_KEYS:
            assert row[k] == pytest.approx(0.0, abs=1e-3), k
        assert row["openloop_collision_rate"] == 0.0


def test_log_collision_steps_are_excluded(results):
    exact, _ = results
    # The log drives through the parked car: those steps are the log's own
    # collisions and add 0 even though the prediction collides there too.
    assert exact["car_ahead"]["openloop_gt_collision_steps"] > 0
    assert exact["car_ahead"]["openloop_collision_rate"] == 0.0
    assert exact["clean"]["openloop_gt_collision_steps"] == 0


def test_wrong_policy_has_positive_l2_and_collides(results):
    _, wrong = results
    for row in wrong.values():
        for k in L2_KEYS:
            assert row[k] == pytest.approx(3.5, abs=1e-3), k
    # 3.5 m left is the westbound lane, where a car is parked at x = 30.
    assert wrong["clean"]["openloop_collision_rate"] > 0.0


def test_controls_policy_is_rejected():
    log_replay = load_policy(POLICIES / "log_replay.py")
    with pytest.raises(DriveE2EError, match="waypoint policy"):
        evaluate_openloop(log_replay, ss.build([ss.clean()]))


def test_bad_arguments_are_rejected(cv):
    batch = ss.build([ss.clean()])
    with pytest.raises(DriveE2EError, match="every"):
        evaluate_openloop(cv, batch, every=0)
    with pytest.raises(DriveE2EError, match="horizon"):
        evaluate_openloop(cv, batch, horizon=0)


def test_resample_waypoints():
    t = 0.25 * np.arange(1, 13, dtype=np.float32)
    xy = jnp.asarray(np.stack([4.0 * t, t**2], -1))
    out = np.asarray(resample_waypoints(xy, 0.25, 6, 0.5))
    np.testing.assert_allclose(out, np.asarray(xy)[1::2], atol=1e-6)
    # Coarser source: linear in time between points, from the origin.
    out = np.asarray(resample_waypoints(jnp.array([[2.0, 0.0], [4.0, 2.0]]), 1.0, 4, 0.5))
    np.testing.assert_allclose(out, [[1, 0], [2, 0], [3, 1], [4, 2]], atol=1e-6)


def test_constant_velocity_arc_and_controller(cv):
    mod = sys.modules[type(cv).__module__]
    v, w = 10.0, 0.5
    t = 0.5 * jnp.arange(1, 7)
    xy = np.asarray(mod.arc_waypoints(v, w, t))
    r = v / w  # circle of radius 20 m centred (0, 20)
    np.testing.assert_allclose(np.hypot(xy[:, 0], xy[:, 1] - r), r, atol=1e-4)
    chord = np.hypot(*np.diff(np.r_[[[0, 0]], xy], axis=0).T)
    np.testing.assert_allclose(chord, 2 * r * np.sin(w * 0.5 / 2), rtol=1e-5)  # equal 0.5 s chords
    straight = np.asarray(mod.arc_waypoints(v, 0.0, t))
    np.testing.assert_allclose(straight, np.stack([v * np.asarray(t), np.zeros(6)], -1), atol=1e-6)
    # Closed loop: the waypoint controller keeps the speed (no brake) and steers left.
    params = ctl.ControllerParams()
    controls, _ = ctl.waypoints_to_controls(jnp.asarray(xy), jnp.float32(v), ctl.init_controller_state(params), params)
    assert float(controls.brake) == 0.0 and float(controls.steer) > 0.0


class BevCount(StatelessPolicy):
    """Waypoints 5 m apart straight ahead; reads ``obs.bev``, so it fails to
    trace when the open-loop driver does not render the BEV."""

    name = "bev_count"
    action_type = "waypoints"
    waypoint_dt = 0.5
    required_sensors = ("bev",)

    def act(self, params, obs, policy_state, key):
        seen = jnp.sum(obs.bev != 0).astype(jnp.float32)
        x = (5.0 + 0.0 * seen) * jnp.arange(1, 7, dtype=jnp.float32)
        return Waypoints(xy=jnp.stack([x, jnp.zeros_like(x)], axis=-1)), policy_state


def test_a_bev_policy_is_scored_open_loop_with_its_sensors_rendered():
    from drivee2e_jax.scenario import load_suite

    suite = load_suite(POLICIES.parents[1] / "drivee2e_jax" / "scenario" / "examples" / "tiny")
    packed = suite.pack("train")
    with pytest.raises(DriveE2EError, match="maps"):
        evaluate_openloop(BevCount(), packed, limit=1)
    got = evaluate_openloop(BevCount(), packed, limit=1, maps=suite.maps)
    (only,) = got.values()
    assert only["openloop_samples"] > 0
    assert all(np.isfinite(only[k]) for k in L2_KEYS)
