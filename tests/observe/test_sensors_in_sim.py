"""Sensors inside the rollout: a policy declares them, evaluate turns them on."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax import SimConfig, Simulator
from drivee2e_jax.eval.closedloop import evaluate, with_policy_sensors
from drivee2e_jax.observe import sensors
from drivee2e_jax.observe.bev import BevConfig, unpack_bits
from drivee2e_jax.observe.lidar import LidarConfig
from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.scenario import Suite
from drivee2e_jax.scenario.pack import pack
from drivee2e_jax.types import Controls

SMALL = sensors.SensorConfig(bev=BevConfig(height=32, width=32, resolution=1.0, num_agents=8),
                             lidar=LidarConfig(channels=4, azimuth_bins=36))


class ReplayWithSensors(StatelessPolicy):
    """Drives like log_replay; touches the sensors so they are computed."""

    name = "replay_sensors"
    required_sensors = ("bev", "lidar")

    def act(self, params, obs, policy_state, key):
        c = obs.privileged.log_controls
        used = 0.0 * (obs.bev.sum() + obs.lidar.sum())
        ok = obs.privileged.log_valid
        return Controls(throttle=jnp.where(ok, c.throttle, 0.0) + used, brake=jnp.where(ok, c.brake, 1.0),
                        steer=jnp.where(ok, c.steer, 0.0)), policy_state


def test_for_policy_turns_on_only_what_is_asked():
    cfg = with_policy_sensors(SimConfig(sensors=SMALL), ReplayWithSensors())
    assert cfg.sensors.enabled == ("bev", "lidar") and cfg.sensors.bev.height == 32
    assert sensors.SensorConfig.for_policy(("lidar",)).enabled == ("lidar",)
    assert with_policy_sensors(SimConfig(), StatelessPolicy()).sensors.enabled == ()
    with pytest.raises(ValueError, match="unknown 'camera'"):
        sensors.SensorConfig.for_policy(("camera",))


def test_reset_renders_the_enabled_sensors_from_the_ego_state(tiny_suite):
    packed = pack(tiny_suite.scenarios, tiny_suite.maps)
    assets = sensors.build_assets(packed, SMALL, tiny_suite.maps)
    sim = Simulator(SimConfig(sensors=SMALL))
    scn = jax.tree_util.tree_map(jnp.asarray, packed.scenario)
    keys = jax.random.split(jax.random.PRNGKey(0), len(packed))
    _, obs = jax.jit(jax.vmap(sim.reset, in_axes=(0, 0, sensors.assets_axes(assets))))(keys, scn, assets)
    assert obs.bev.shape == (len(packed), 32, 32) and obs.bev.dtype == jnp.int32
    assert obs.lidar.shape == (len(packed), 4, 36)
    img = np.asarray(unpack_bits(obs.bev, len(SMALL.bev.channels)))
    ego = img[..., SMALL.bev.channels.index("ego")]
    drivable = img[..., SMALL.bev.channels.index("drivable")]
    assert (ego.sum(axis=(1, 2)) > 0).all()  # the ego box is drawn in every scenario
    assert (drivable.sum(axis=(1, 2)) > 0).all()  # it stands on a map
    lid = np.asarray(obs.lidar)
    assert (lid[:, 0] < 85.0).any()  # the lowest beam (-30 deg) hits the ground
    assert np.isfinite(lid).all()


def test_a_sensor_policy_drives_exactly_like_log_replay(tiny_suite):
    from drivee2e_jax.policy import load_policy, resolve_policy_path

    suite = Suite.from_records(tiny_suite)
    cfg = SimConfig(sensors=SMALL)
    with_sensors = evaluate(ReplayWithSensors(), suite, None, config=cfg)
    plain = evaluate(load_policy(resolve_policy_path("log_replay")), suite, None)
    for a, b in zip(with_sensors.rows, plain.rows):
        assert a["scenario_id"] == b["scenario_id"]
        assert a["driving_score"] == b["driving_score"] and a["route_completion"] == b["route_completion"]


def test_bev_without_assets_is_a_clear_error(tiny_suite):
    packed = pack(tiny_suite.scenarios, tiny_suite.maps)
    sim = Simulator(SimConfig(sensors=dataclasses.replace(SMALL, lidar=None)))
    first = jax.tree_util.tree_map(lambda a: jnp.asarray(a[0]), packed.scenario)
    with pytest.raises(ValueError, match="no SensorAssets"):
        jax.jit(sim.reset)(jax.random.PRNGKey(0), first)  # traced only: op by op the reset ran ~15 s first
