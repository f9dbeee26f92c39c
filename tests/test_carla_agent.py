"""CARLA-leaderboard-style agents as host policies (``drivee2e_jax.carla_agent``):
the ``input_data`` an agent gets for its sensor list (keys, shapes, frames,
units), sensors without a counterpart, the steer sign, the global plan, and
the example agent of docs/examples driving twin15 routes."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drivee2e_jax import carla_agent, hostapi
from drivee2e_jax.carla_agent import AutonomousAgent, CarlaAgentPolicy, RoadOption, VehicleControl
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.observe import bev as bev_mod
from drivee2e_jax.observe import lidar as lidar_mod
from drivee2e_jax.policy import load_policy
from drivee2e_jax.scenario import load_suite
from tests.helpers.host_policies import NO_JAX

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "docs" / "examples" / "carla_style_agent.py"

SENSORS = [
    {"type": "sensor.other.gnss", "x": -1.4, "y": 0.0, "z": 0.0, "id": "GPS"},
    {"type": "sensor.other.imu", "x": -1.4, "y": 0.0, "z": 0.0, "roll": 0.0, "pitch": 0.0, "yaw": 0.0, "id": "IMU"},
    {"type": "sensor.speedometer", "reading_frequency": 20, "id": "SPEED"},
    {"type": "sensor.lidar.ray_cast", "x": 1.3, "y": 0.0, "z": 2.5, "roll": 0.0, "pitch": 0.0, "yaw": 0.0,
     "id": "LIDAR"},
    {"type": "sensor.drivee2e.bev", "id": "BEV"},
    {"type": "sensor.drivee2e.observation", "id": "OBS"},
]


def make_agent_class(specs, steer=0.25):
    class Recorder(AutonomousAgent):
        def setup(self, path_to_conf_file):
            self.config, self.seen = path_to_conf_file, []

        def sensors(self):
            return [dict(s) for s in specs]

        def run_step(self, input_data, timestamp):
            self.seen.append((input_data, timestamp))
            return VehicleControl(throttle=0.5, steer=steer, brake=0.0)

    return Recorder


def fake_obs(b=2, p=10, k=4, m=3, q=5, h=8, w=6, c=64, z=360) -> hostapi.Observation:
    rng = np.random.default_rng(0)
    f32 = np.float32
    ego = hostapi.EgoState(xy=rng.normal(size=(b, 2)).astype(f32), yaw=np.zeros(b, f32), speed=np.full(b, 5, f32),
                           accel=np.zeros(b, f32), steer=np.zeros(b, f32), yaw_rate=np.zeros(b, f32),
                           t=np.arange(b, dtype=f32) + 1.5)
    zb = np.zeros(b, f32)
    priv = hostapi.Privileged(ego=ego, log_next_xy=np.zeros((b, 2), f32), log_next_yaw=zb, log_valid=np.ones(b, bool),
                              log_controls=hostapi.Controls(throttle=zb, brake=zb, steer=zb))
    route = np.stack([2.0 * (1 + np.arange(p)), np.zeros(p)], -1).astype(f32)
    lidar = np.full((b, c, z), 85.0, f32)
    lidar[:, 40, 90] = 10.0  # one return, to the ego's left
    return hostapi.Observation(
        ego=np.tile(np.array([5.0, 1.0, 0.2, 0.0], f32), (b, 1)), gps=np.array([[100.0, 50.0], [-20.0, 7.0]], f32)[:b],
        compass=np.array([0.0, np.pi / 2], f32)[:b], route=np.tile(route, (b, 1, 1)), route_valid=np.ones((b, p), bool),
        command=np.full(b, 4, np.int32), agents=np.zeros((b, k, 8), f32), agents_category=np.zeros((b, k), np.int32),
        agents_valid=np.zeros((b, k), bool), lanes=np.zeros((b, m, q, 2), f32), lanes_valid=np.zeros((b, m, q), bool),
        signal_state=np.zeros(b, np.int32), signal_distance=np.full(b, 1e3, f32), speed_limit=np.full(b, 13.9, f32),
        privileged=priv, bev=np.full((b, h, w), 0b101, np.int32), lidar=lidar)


def test_defaults_agree_with_the_observe_package():
    cfg = lidar_mod.LidarConfig()
    assert carla_agent.LIDAR_ELEVATION_DEG == (cfg.elevation_min_deg, cfg.elevation_max_deg)
    assert carla_agent.LIDAR_MOUNT == cfg.mount_xyz and carla_agent.LIDAR_MAX_RANGE == cfg.max_range
    assert carla_agent.BEV_CHANNELS == len(bev_mod.DEFAULT_CHANNELS)
    bits = np.array([[0b1011, 0], [1 << 13, 7]], np.int32)
    np.testing.assert_array_equal(carla_agent.unpack_bev(bits, 14), np.asarray(bev_mod.unpack_bits(bits, 14)))


def test_input_data_keys_shapes_and_units():
    pol = CarlaAgentPolicy(make_agent_class(SENSORS), "conf.yaml")
    assert pol.required_sensors == ("bev", "lidar") and pol.action_type == "controls"
    obs = fake_obs()
    state = pol.reset([{"scenario_id": "a"}, {"scenario_id": "b"}])
    assert [a.config for a in state.agents] == ["conf.yaml"] * 2
    for _step in range(2):
        action, state = pol.act(obs, state)
    assert isinstance(action, hostapi.Controls) and action.steer.shape == (2,)
    for b, agent in enumerate(state.agents):
        data, ts = agent.seen[-1]
        assert set(data) == {s["id"] for s in SENSORS}
        assert all(frame == 1 for frame, _ in data.values()) and ts == pytest.approx(b + 1.5)
        gps, imu = data["GPS"][1], data["IMU"][1]
        assert gps.shape == (3,) and gps.dtype == np.float64 and imu.shape == (7,)
        # GNSS: the sensor 1.4 m behind the ego centre, in CARLA's world (y = -north)
        yaw = float(obs.compass[b])
        sensor_xy = obs.gps[b] - 1.4 * np.array([math.cos(yaw), math.sin(yaw)])
        np.testing.assert_allclose(carla_agent.gps_to_location(gps[0], gps[1]), [sensor_xy[0], -sensor_xy[1]],
                                   atol=1e-4)
        # IMU: accel x, centripetal to the left = negative y (CARLA y right), gravity, gyro z = -yaw rate, compass
        np.testing.assert_allclose(imu[:6], [1.0, -5.0 * 0.2, 9.81, 0.0, 0.0, -0.2], rtol=1e-6)
        assert imu[6] == pytest.approx(np.mod(np.pi / 2 - yaw, 2 * np.pi))
        assert data["SPEED"][1] == {"speed": 5.0}
        pts = data["LIDAR"][1]
        assert pts.shape == (1, 4) and pts.dtype == np.float32
        bev = data["BEV"][1]
        assert bev.shape == (8, 6, 14) and bev[..., 0].all() and bev[..., 2].all() and not bev[..., 1].any()
        o = data["OBS"][1]
        assert "privileged" not in o and o["agents"].shape == (4, 8) and o["speed_limit"] == pytest.approx(13.9)
    assert obs.compass[0] == 0.0 and state.agents[0].seen[-1][0]["IMU"][1][6] == pytest.approx(np.pi / 2)  # east


def test_lidar_points_in_the_requested_carla_frame():
    rng = np.full((64, 360), 85.0, np.float32)
    rng[40, 90] = 10.0  # channel 40, azimuth 90 deg: to the ego's LEFT
    el = math.radians(np.linspace(-30.0, 10.0, 64)[40])
    ego = np.array([0.0, 10 * math.cos(el), 1.84 + 10 * math.sin(el)])  # ego frame, y left
    pts = carla_agent.lidar_points(rng, {"x": 1.3, "y": 0.0, "z": 2.5})
    np.testing.assert_allclose(pts[0, :3], [ego[0] - 1.3, -ego[1], ego[2] - 2.5], atol=1e-4)  # CARLA y right
    assert pts[0, 1] < 0 and 0 < pts[0, 3] < 1
    # a sensor yawed 90 deg to the LEFT (CARLA yaw -90) sees that point straight ahead
    turned = carla_agent.lidar_points(rng, {"x": 0.0, "y": 0.0, "z": 1.84, "yaw": -90.0})
    np.testing.assert_allclose(turned[0, :3], [10 * math.cos(el), 0.0, 10 * math.sin(el)], atol=1e-4)
    assert carla_agent.lidar_points(np.full((64, 360), 85.0), {}).shape == (0, 4)


def test_rgb_camera_is_a_one_line_error_naming_the_sensor():
    specs = [*SENSORS[:1], {"type": "sensor.camera.rgb", "x": 0.8, "z": 1.6, "width": 320, "height": 160,
                            "fov": 70, "id": "CAM_FRONT"}]
    with pytest.raises(DriveE2EError) as err:
        CarlaAgentPolicy(make_agent_class(specs))
    msg = str(err.value)
    assert "\n" not in msg and "'CAM_FRONT'" in msg and "sensor.camera.rgb" in msg
    assert "sensor.other.gnss" in msg and "sensor.lidar.ray_cast" in msg and "fill_missing" in msg
    pol = CarlaAgentPolicy(make_agent_class(specs), fill_missing="zeros")
    state = pol.reset([{}])
    pol.act(fake_obs(b=1), state)
    img = state.agents[0].seen[0][0]["CAM_FRONT"][1]
    assert img.shape == (160, 320, 4) and img.dtype == np.uint8 and not img.any()
    with pytest.raises(DriveE2EError, match="'HD'.*sensor.opendrive_map"):
        CarlaAgentPolicy(make_agent_class([{"type": "sensor.opendrive_map", "id": "HD"}]), fill_missing="zeros")


def test_steer_sign_and_brakes():
    # CARLA: +steer = right; drivee2e Controls.steer: +1 = full left
    assert carla_agent.control_to_row(VehicleControl(throttle=0.3, steer=0.5, brake=0.1), "x") == (0.3, 0.1, -0.5)
    assert carla_agent.control_to_row(VehicleControl(throttle=0.3, steer=-0.2, hand_brake=True), "x") == (0.0, 1.0, 0.2)
    assert carla_agent.control_to_row(VehicleControl(throttle=0.3, reverse=True), "x")[:2] == (0.0, 1.0)
    pol = CarlaAgentPolicy(make_agent_class(SENSORS[:3], steer=0.25))
    action, _ = pol.act(fake_obs(), pol.reset([{}, {}]))
    np.testing.assert_array_equal(action.steer, [-0.25, -0.25])
    np.testing.assert_array_equal(action.throttle, [0.5, 0.5])
    with pytest.raises(DriveE2EError, match="scenario row 0, step 0: run_step returned dict"):
        bad = make_agent_class(SENSORS[:1])
        bad.run_step = lambda self, data, ts: {"steer": 0.0}
        p = CarlaAgentPolicy(bad)
        p.act(fake_obs(b=1), p.reset([{}]))


def test_global_plan_from_meta_and_from_the_observation():
    pol = CarlaAgentPolicy(make_agent_class(SENSORS[:3]))
    xy = np.stack([np.arange(120.0), np.full(120, 5.0)], -1)  # 120 m east along y = 5 (north)
    cmd = [4] * 60 + [1] * 20 + [4] * 40
    state = pol.reset([{"route_xy": xy.tolist(), "route_command": cmd}])
    agent = state.agents[0]
    assert len(agent._plan_gps_HACK) == 120
    world = agent._global_plan_world_coord
    assert [o for _, o in world][:3] == [RoadOption.LANEFOLLOW, RoadOption.LANEFOLLOW, RoadOption.LEFT]
    t0 = world[0][0]
    assert (t0.location.x, t0.location.y, t0.rotation.yaw) == pytest.approx((0.0, -5.0, 0.0))
    g = agent._global_plan[-1][0]
    np.testing.assert_allclose(carla_agent.gps_to_location(g["lat"], g["lon"]), [119.0, -5.0], atol=1e-6)
    # no route in meta (a served policy): built from obs.route and grown in place
    state = pol.reset([{}, {}])
    obs = fake_obs()
    pol.act(obs, state)
    plan = state.agents[0]._plan_gps_HACK
    first = len(plan)
    assert first == 11  # the ego + 10 points ahead
    moved = hostapi.Observation(**{**{f: getattr(obs, f) for f in hostapi.field_names(hostapi.Observation)},
                                   "gps": obs.gps + np.array([[4.0, 0.0], [0.0, 4.0]], np.float32)})
    pol.act(moved, state)
    assert state.agents[0]._plan_gps_HACK is plan and len(plan) == first + 2


def test_module_imports_no_jax():
    program = NO_JAX + "import drivee2e_jax.carla_agent\nprint('ok', 'jax' in sys.modules and sys.modules['jax'] is not None)\n"
    out = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("ok False")


def test_example_agent_drives_twin15_routes():
    res = evaluate(load_policy(EXAMPLE), load_suite("twin15"), "val", limit=4)
    rows = res.rows
    assert len(rows) == 4 and all(r["invalid_action"] == 0 for r in rows)  # finite controls every step
    rc = [r["route_completion"] for r in rows]
    ds = [r["driving_score"] for r in rows]
    print("carla_style_agent twin15 val[:4] RC", rc, "DS", ds)
    assert max(rc) == pytest.approx(100.0) and np.mean(rc) > 50.0


def test_example_agent_without_a_route_in_meta_builds_its_plan_from_the_observation():
    """A served policy gets no route in its meta rows: the plan grows from obs.route."""
    pol = load_policy(EXAMPLE)
    pol.wants_route = False
    rows = evaluate(pol, load_suite("twin15"), "val", limit=2).rows
    assert all(r["invalid_action"] == 0 for r in rows) and max(r["route_completion"] for r in rows) == pytest.approx(100.0)


def test_from_file_uses_the_leaderboard_entry_point(tmp_path):
    pol = CarlaAgentPolicy.from_file(EXAMPLE, "cfg")
    assert pol.agent_class.__name__ == "RuleAgent" and pol.config == "cfg"
    assert [s["id"] for s in pol.specs] == ["GPS", "IMU", "SPEED", "OBS"] and pol.required_sensors == ()
    bad = tmp_path / "no_entry.py"
    bad.write_text("x = 1\n")
    with pytest.raises(DriveE2EError, match="get_entry_point"):
        CarlaAgentPolicy.from_file(bad)
