"""A rule-based agent written in the CARLA leaderboard's style, run as a host policy.

    drivee2e bench --policy docs/examples/carla_style_agent.py

The agent class is ordinary CARLA Leaderboard 2.0 / Bench2Drive agent code;
only the two imports below differ (docs/leaderboard_agents.md). It navigates
with GNSS + IMU + speedometer along the dense global plan (pure pursuit on a
speed-dependent look-ahead point, PI speed control) and, standing in for a
camera perception stack, reads the drivee2e observation sensor for the next
traffic light and the vehicles ahead (it stops for red and yellow lights and
keeps a gap to the lead vehicle).
"""

import math

import numpy as np

from drivee2e_jax import carla_agent as autonomous_agent  # was: from leaderboard.autoagents import autonomous_agent
from drivee2e_jax.carla_agent import CarlaAgentPolicy, carla, gps_to_location  # was: import carla

WHEELBASE, MAX_STEER = 2.9, 0.61  # m, rad at |steer| = 1 (drivee2e's default bicycle)
RED, YELLOW = 1, 2  # drivee2e_jax.types.SignalState


def get_entry_point():
    return "RuleAgent"


class RuleAgent(autonomous_agent.AutonomousAgent):
    def setup(self, path_to_conf_file):
        self.track = autonomous_agent.Track.SENSORS
        self.cruise = 8.0  # m/s
        self.route, self.index, self.integral = None, 0, 0.0

    def sensors(self):
        return [
            {"type": "sensor.other.gnss", "x": 0.0, "y": 0.0, "z": 0.0, "id": "GPS"},
            {"type": "sensor.other.imu", "x": 0.0, "y": 0.0, "z": 0.0, "roll": 0.0, "pitch": 0.0, "yaw": 0.0,
             "id": "IMU"},
            {"type": "sensor.speedometer", "reading_frequency": 20, "id": "SPEED"},
            {"type": "sensor.drivee2e.observation", "id": "OBS"},  # not CARLA: signals and agents
        ]

    def _init(self):
        # the dense GPS route (Bench2Drive keeps it as _plan_gps_HACK), as CARLA world x, y
        plan = self._plan_gps_HACK or self._global_plan
        self.route = np.array([gps_to_location(p["lat"], p["lon"]) for p, _ in plan])
        self.commands = [int(c) for _, c in plan]

    def run_step(self, input_data, timestamp):
        if self.route is None or len(self.route) < len(self._plan_gps_HACK or ()):  # first step, or a grown plan
            self._init()
        lat, lon, _ = input_data["GPS"][1]
        pos = gps_to_location(lat, lon)  # CARLA world x, y (y points south)
        compass = input_data["IMU"][1][-1]  # clockwise from north
        speed = input_data["SPEED"][1]["speed"]
        forward = np.array([math.sin(compass), -math.cos(compass)])
        right = np.array([math.cos(compass), math.sin(compass)])

        # progress along the route: the nearest point in a window ahead
        window = self.route[self.index:self.index + 40]
        self.index += int(np.argmin(np.linalg.norm(window - pos, axis=1)))
        lookahead = float(np.clip(1.0 * speed, 4.0, 12.0))
        ahead = np.linalg.norm(self.route[self.index:] - pos, axis=1)
        far = np.nonzero(ahead >= lookahead)[0]
        target = self.route[self.index + (far[0] if len(far) else len(ahead) - 1)]
        d = target - pos
        x, y_right = float(d @ forward), float(d @ right)
        angle = math.atan2(2.0 * WHEELBASE * y_right, max(x * x + y_right * y_right, 1.0))
        steer = float(np.clip(angle / MAX_STEER, -1.0, 1.0))  # CARLA sign: + = right

        # desired speed: cruise, slower in turns, stop for lights and lead vehicles
        obs = input_data["OBS"][1]
        turning = any(c in (1, 2) for c in self.commands[self.index:self.index + 15])
        desired = min(self.cruise, float(obs["speed_limit"]), 5.0 if turning else self.cruise)
        light, dist = int(obs["signal_state"]), float(obs["signal_distance"])
        if light == RED or (light == YELLOW and dist - 3.0 > speed * speed / (2.0 * 3.0)):  # go on yellow if too close
            desired = min(desired, math.sqrt(max(2.0 * 2.5 * (dist - 3.0), 0.0)))
        agents, valid = obs["agents"], obs["agents_valid"]  # ego frame: x forward, y left, m
        lead = valid & (agents[:, 0] > 0.0) & (np.abs(agents[:, 1]) < 2.0)
        if lead.any():
            gap = float(agents[lead, 0].min()) - 7.0
            desired = min(desired, math.sqrt(max(2.0 * 2.5 * gap, 0.0)))

        error = desired - speed
        self.integral = float(np.clip(self.integral + 0.1 * error, -2.0, 2.0))
        control = carla.VehicleControl()
        control.steer = steer
        if desired < 0.3 or error < -1.5:
            control.throttle, control.brake = 0.0, 1.0 if desired < 0.3 else 0.5
        else:
            control.throttle = float(np.clip(0.4 * error + 0.1 * self.integral + 0.25, 0.0, 0.8))
        return control


def make_policy(config: str = "", fill_missing=None):
    return CarlaAgentPolicy(RuleAgent, config, name="carla_rule_agent", fill_missing=fill_missing)
