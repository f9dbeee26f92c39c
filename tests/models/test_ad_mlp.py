"""drivee2e_jax/zoo/ad_mlp.py: loads a checkpoint; its act is pure and jit/vmap-compatible."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import base
from drivee2e_jax.policy import load_policy
from drivee2e_jax.train.dataset import DemoDataset
from drivee2e_jax.types import Waypoints

POLICY = Path(__file__).resolve().parents[2] / "drivee2e_jax" / "zoo" / "ad_mlp.py"


def test_needs_a_checkpoint(monkeypatch, tmp_path):
    monkeypatch.delenv("DRIVEE2E_AD_MLP_CHECKPOINT", raising=False)
    monkeypatch.setenv("DRIVEE2E_ZOO_WEIGHTS", str(tmp_path))  # no bundled weights either
    with pytest.raises(DriveE2EError, match="checkpoint=.*DRIVEE2E_AD_MLP_CHECKPOINT"):
        load_policy(POLICY)


def test_act_is_pure_and_jit_vmap_compatible(tiny_run, tiny_demos):
    pol = load_policy(POLICY, checkpoint=str(tiny_run))
    assert pol.action_type == "waypoints" and pol.waypoint_dt == 0.5 and pol.name == "ad_mlp"
    obs = jax.tree_util.tree_map(jnp.asarray, DemoDataset(tiny_demos).first().obs)
    params = pol.init(jax.random.PRNGKey(0), obs)
    st = pol.initial_state(obs)
    key = jax.random.PRNGKey(1)
    a1, s1 = pol.act(params, obs, st, key)
    a2, s2 = pol.act(params, obs, st, key)
    assert isinstance(a1, Waypoints) and a1.xy.shape == (6, 2)
    np.testing.assert_array_equal(a1.xy, a2.xy)
    aj, sj = jax.jit(pol.act)(params, obs, st, key)
    np.testing.assert_allclose(aj.xy, a1.xy, rtol=1e-5, atol=1e-5)
    jax.tree_util.tree_map(np.testing.assert_array_equal, sj, s1)
    batched = jax.tree_util.tree_map(lambda a: jnp.stack([a, a, a]), (obs, st))
    av, _ = jax.jit(jax.vmap(pol.act, in_axes=(None, 0, 0, None)))(params, *batched, key)
    assert av.xy.shape == (3, 6, 2)
    np.testing.assert_allclose(av.xy[2], a1.xy, rtol=1e-5, atol=1e-5)


def test_history_is_pushed_every_half_second(tiny_demos):
    obs = jax.tree_util.tree_map(jnp.asarray, DemoDataset(tiny_demos).first().obs)
    h = base.empty_history(obs)
    times = []
    for k in range(12):  # 0.1 s control steps
        t = jnp.float32(0.1 * k)
        o = obs.replace(privileged=obs.privileged.replace(ego=obs.privileged.ego.replace(t=t)))
        h = base.push_history(h, o)
    times = np.asarray(h.t)[np.asarray(h.valid)]
    np.testing.assert_allclose(times, [0.0, 0.5, 1.0], atol=1e-5)


def test_fused_rule_follows_tcp():
    from drivee2e_jax.types import Controls

    traj = Controls(throttle=jnp.float32(0.5), brake=jnp.float32(0.0), steer=jnp.float32(0.0))
    ctrl = Controls(throttle=jnp.float32(1.0), brake=jnp.float32(0.2), steer=jnp.float32(0.5))
    straight = base.fuse_controls(traj, ctrl)
    np.testing.assert_allclose([straight.throttle, straight.brake, straight.steer], [0.65, 0.2, 0.15], atol=1e-6)
    turning = base.fuse_controls(traj.replace(steer=jnp.float32(0.4)), ctrl)
    np.testing.assert_allclose([turning.throttle, turning.steer], [0.75, 0.47], atol=1e-6)  # 0.85 capped at 0.75


class _Scripted:
    """A stand-in Model whose output is its ``params``: (waypoints, controls)."""

    name = "scripted"
    required_sensors = ()
    waypoint_dt = 0.5
    num_waypoints = 4

    def apply(self, params, obs):
        from drivee2e_jax.types import Controls

        wps, c = params
        return base.ModelOutput(waypoints=wps, controls=Controls(throttle=c[0], brake=c[1], steer=c[2]))


def test_fused_mode_keeps_tcps_20_frame_turning_memory(tiny_demos):
    """TCP's agent leads with the control branch once more than 10 of the last
    20 fused steers exceeded 0.1; a Python deque oracle of ``tcp_agent.py``
    step by step, while the memoryless rule would switch at once."""
    from collections import deque

    from drivee2e_jax import controller as ctl

    obs = jax.tree_util.tree_map(jnp.asarray, DemoDataset(tiny_demos).first().obs)
    pol = base.ModelPolicy(_Scripted(), params=None, mode="fused")
    act = jax.jit(pol.act)
    st, cst = pol.initial_state(obs), ctl.init_controller_state(pol.controller)
    straight = jnp.stack([5.0 * jnp.arange(1, 5), jnp.zeros(4)], -1)
    left = jnp.array([[5.0, 0.8], [10.0, 3.0], [14.5, 6.5], [18.5, 11.0]])
    last, status, switched_late = deque(maxlen=20), 0, 0
    for k in range(60):
        turn_phase = 5 <= k < 35
        wps = left if turn_phase else straight
        ctrl = jnp.array([0.4, 0.0, 0.6 if turn_phase else 0.0], jnp.float32)
        a, st = act((wps, ctrl), obs, st, None)
        traj, cst = ctl.waypoints_to_controls(wps, obs.ego[0], cst, pol.controller)
        w = 0.7 if status else 0.3  # weight of the control branch
        want = np.clip(w * float(ctrl[2]) + (1 - w) * float(traj.steer), -1, 1)
        np.testing.assert_allclose(float(a.steer), want, atol=1e-5, err_msg=f"step {k}")
        switched_late += int(bool(abs(float(traj.steer)) > 0.1) != bool(status))
        last.append(abs(float(a.steer)))
        status = int(sum(s > 0.1 for s in last) > 10)
    assert switched_late > 10  # the memory matters: the memoryless rule differs on many steps
