"""Hand-built scenarios with known outcomes for simulator tests.

A straight two-lane road along +x (eastbound lane centre y = -1.75, westbound
y = +1.75), a stop line at x = 0 guarding the eastbound lane. The ego logs a
constant 10 m/s drive from x = -40 to x = +40 (8 s) in a 10 s log.
"""

from __future__ import annotations

import numpy as np

from drivee2e_jax.records import (
    LaneRecord,
    MapRecord,
    ObstacleRecord,
    RouteRecord,
    ScenarioRecord,
    StopLineRecord,
    TrackRecord,
)
from drivee2e_jax.scenario.pack import pack

DT = 0.1
STEPS = 101  # 10 s
EGO_SPEED = 10.0


def road_map(obstacle: bool = False) -> MapRecord:
    east = LaneRecord(1, np.stack([np.linspace(-80, 80, 33), np.full(33, -1.75)], 1), width=3.5)
    west = LaneRecord(2, np.stack([np.linspace(80, -80, 33), np.full(33, 1.75)], 1), width=3.5)
    obstacles = [ObstacleRecord(np.array([[10.0, -3.0], [12.0, -3.0], [12.0, -1.0], [10.0, -1.0]]), 3.0, "pole")] if obstacle else []
    return MapRecord(
        map_id="road" + ("_obst" if obstacle else ""),
        lanes=[east, west],
        stop_lines=[StopLineRecord(0, np.array([[0.0, -3.5], [0.0, 0.0]]), lane_id=1, signal_group=0)],
        drivable_areas=[np.array([[-80.0, -3.5], [80.0, -3.5], [80.0, 3.5], [-80.0, 3.5]])],
        obstacles=obstacles,
    )


def ego_track(speed: float = EGO_SPEED, y: float = -1.75) -> TrackRecord:
    n = int(8.0 / DT) + 1
    k = np.arange(n)
    x = -40.0 + speed * k * DT
    return TrackRecord(
        track_id=1, category="car", size=np.array([4.6, 1.9, 1.5]), t=np.round(k * DT, 6),
        xy=np.stack([x, np.full(n, y)], 1), yaw=np.zeros(n), vel=np.tile([speed, 0.0], (n, 1)),
    )


def parked(track_id: int, x: float, y: float = -1.75, category: str = "car", size=(4.5, 1.9, 1.5)) -> TrackRecord:
    k = np.arange(STEPS)
    return TrackRecord(
        track_id=track_id, category=category, size=np.array(size, float), t=np.round(k * DT, 6),
        xy=np.tile([x, y], (STEPS, 1)), yaw=np.zeros(STEPS), vel=np.zeros((STEPS, 2)),
    )


def scenario(sid: str, tracks, signal: int = 3, map_id: str = "road", behavior: str = "STR") -> ScenarioRecord:
    route = np.array([[-40.0, -1.75], [40.0, -1.75]])
    return ScenarioRecord(
        scenario_id=sid, split="val", intersection_id="road", map_id=map_id, behavior=behavior,
        weather="clear", time_of_day="day", ego_track_id=1,
        route=RouteRecord(route, route[0].copy(), route[-1].copy()),
        dt=DT, num_steps=STEPS, tracks=list(tracks), signals={0: np.full(STEPS, signal, np.int8)},
    )


def build(scenarios, maps=None):
    maps = maps or {m.map_id: m for m in (road_map(), road_map(obstacle=True))}
    return pack(list(scenarios), maps)


def clean():
    return scenario("clean", [ego_track(), parked(5, 30.0, y=1.75)])


def blocked_by_car():
    """A parked car on the route at x = 0: log replay drives through it."""
    return scenario("car_ahead", [ego_track(), parked(5, 0.0)])


def red_light():
    return scenario("red", [ego_track()], signal=1)


def pedestrian_ahead():
    return scenario("ped", [ego_track(), parked(7, 20.0, category="pedestrian", size=(0.6, 0.6, 1.7))])


def obstacle_ahead():
    return scenario("pole", [ego_track()], map_id="road_obst")
