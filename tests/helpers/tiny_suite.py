"""The tiny hand-built suite of the shared fixtures (2 maps, 4 scenarios).

``build_tiny_suite()`` returns a fresh ``SuiteRecord``: maps ``m_cross`` and
``m_tee``; scenarios ``s_straight`` / ``s_left`` (train), ``s_val`` (val),
``s_test`` (test). ``drivee2e_jax/scenario/examples/tiny`` is this suite written out
(``tests/e2e/test_examples.py`` checks it stays so).
"""

from __future__ import annotations

import numpy as np

from drivee2e_jax.records import (
    BoundaryRecord,
    LaneRecord,
    MapRecord,
    ObstacleRecord,
    RouteRecord,
    ScenarioRecord,
    SignalPhase,
    StopLineRecord,
    SuiteRecord,
    TrackRecord,
)

DT = 0.1
STEPS = 50


def _line(a, b, n=2):
    return np.linspace(a, b, n)


def _left_arc(n=7):
    """Quarter circle from (-12, -1.75) heading east to (1.75, 12) heading north."""
    r = 13.75
    ang = np.linspace(-np.pi / 2, 0.0, n)
    return np.stack([-12.0 + r * np.cos(ang), -1.75 + r + r * np.sin(ang)], axis=1)


def _square(x0, y0, x1, y1):
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def _cross_map() -> MapRecord:
    lanes = [
        LaneRecord(1, _line((-60, -1.75), (-12, -1.75), 5), successors=[2, 3], right_marking="road_edge"),
        LaneRecord(2, _line((-12, -1.75), (12, -1.75), 3), type="connector", successors=[4]),
        LaneRecord(3, _left_arc(), type="connector", successors=[5], left_marking="none", right_marking="none"),
        LaneRecord(4, _line((12, -1.75), (60, -1.75), 4), speed_limit=16.7),
        LaneRecord(5, _line((1.75, 12), (1.75, 60), 4), width=3.25),
    ]
    return MapRecord(
        map_id="m_cross",
        lanes=lanes,
        boundaries=[BoundaryRecord(_line((-60, -3.5), (-12, -3.5), 3), "road_edge"),
                    BoundaryRecord(_line((-60, 0.0), (-12, 0.0), 2), "double_solid")],
        crosswalks=[_square(-12, -7, -8, 7)],
        stop_lines=[StopLineRecord(0, np.array([[-12.0, -3.5], [-12.0, 0.0]]), lane_id=1, signal_group=0),
                    StopLineRecord(1, np.array([[0.0, 12.0], [3.5, 12.0]]), lane_id=-1, signal_group=1),
                    StopLineRecord(2, np.array([[12.0, 0.0], [12.0, 3.5]]), lane_id=4, signal_group=-1)],
        drivable_areas=[_square(-60, -10, 60, 10), _square(-10, -60, 10, 60)],
        obstacles=[ObstacleRecord(_square(20, 20, 40, 40), 12.0),
                   ObstacleRecord(np.array([[15.0, -15.0], [16.0, -15.0], [15.5, -14.0]]), 5.0, kind="signal_pole")],
        signal_plan=[SignalPhase(20.0, [0]), SignalPhase(15.0, [1], yellow_duration=2.5, all_red=1.0)],
        meta={"legs": 4, "skew_deg": 0.0},
    )


def _tee_map() -> MapRecord:
    # No connector lanes: commands come from the route's curvature alone.
    return MapRecord(
        map_id="m_tee",
        lanes=[LaneRecord(10, _line((0, -60), (0, -10), 6), successors=[11]),
               LaneRecord(11, _line((0, -10), (0, 40), 6), type="driving")],
        stop_lines=[StopLineRecord(0, np.array([[-1.75, -10.0], [1.75, -10.0]]), lane_id=10, signal_group=0)],
        drivable_areas=[_square(-5, -60, 5, 40)],
    )


def _track(tid, cat, k, xy, yaw, size=(4.5, 1.9, 1.5), vel=None, visible=None, quality=None):
    k = np.asarray(k)
    return TrackRecord(track_id=tid, category=cat, size=np.array(size, float), t=k * DT,
                       xy=np.asarray(xy, float), yaw=np.asarray(yaw, float),
                       vel=None if vel is None else np.asarray(vel, float),
                       visible=visible, quality=quality)


def _straight() -> ScenarioRecord:
    k = np.arange(STEPS)
    ego_x = -40.0 + 10.0 * k * DT
    ego = _track(7, "car", k, np.stack([ego_x, np.full(STEPS, -1.75)], 1), np.zeros(STEPS),
                 vel=np.tile([10.0, 0.0], (STEPS, 1)))
    k2 = np.arange(30)
    car = _track(3, "truck", k2, np.stack([-55 + 8 * k2 * DT, np.full(30, -1.75)], 1), np.zeros(30),
                 size=(9.0, 2.5, 3.5))
    k3 = np.arange(10, 41, 2)
    n3 = len(k3)
    ped = _track(12, "pedestrian", k3, np.stack([np.full(n3, -10.0), -6 + 0.14 * (k3 - 10)], 1),
                 np.full(n3, np.pi / 2), size=(0.6, 0.6, 1.7),
                 visible=np.arange(n3) % 3 != 0, quality=np.arange(n3) % 5 != 1)
    return ScenarioRecord(
        scenario_id="s_straight", split="train", intersection_id="i0", map_id="m_cross", behavior="STR",
        weather="clear", time_of_day="day", ego_track_id=7,
        route=RouteRecord(np.array([[-40.0, -1.75], [0.0, -1.75], [40.0, -1.75]]),
                          np.array([-40.0, -1.75]), np.array([40.0, -1.75])),
        dt=DT, num_steps=STEPS, tracks=[car, ped, ego],
        signals={0: np.full(STEPS, 3, np.int8), 1: np.full(STEPS, 1, np.int8)},
    )


def _left() -> ScenarioRecord:
    path = np.concatenate([_line((-30, -1.75), (-12, -1.75), 4)[:-1], _left_arc(), _line((1.75, 12), (1.75, 30), 3)[1:]])
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.r_[0, np.cumsum(seg)]
    k = np.arange(STEPS)
    q = np.minimum(8.0 * k * DT, s[-1])
    xy = np.stack([np.interp(q, s, path[:, 0]), np.interp(q, s, path[:, 1])], 1)
    d = np.gradient(xy, axis=0)
    yaw = np.arctan2(d[:, 1], d[:, 0])
    yaw[::7] += 2 * np.pi  # out of (-pi, pi]: packing wraps it
    ego = _track(2, "car", k, xy, yaw)
    cyc = _track(5, "cyclist", np.arange(5, 45), np.stack([np.full(40, 3.0), np.linspace(-40, 0, 40)], 1),
                 np.full(40, np.pi / 2), size=(1.8, 0.7, 1.6), vel=np.tile([0.0, 10.0], (40, 1)))
    sig0 = np.r_[np.full(20, 3), np.full(10, 2), np.full(20, 1)].astype(np.int8)
    return ScenarioRecord(
        scenario_id="s_left", split="train", intersection_id="i0", map_id="m_cross", behavior="LFT",
        weather="rain", time_of_day="night", ego_track_id=2,
        route=RouteRecord(path, path[0].copy(), path[-1].copy()),
        dt=DT, num_steps=STEPS, tracks=[ego, cyc], signals={0: sig0, 1: np.full(STEPS, 1, np.int8)},
    )


def _tee() -> ScenarioRecord:
    n = 30
    k = np.arange(n)
    # a gentle S: straight, then a 90-degree right bend, then straight
    path = np.array([[0.0, -50.0], [0.0, -20.0], [3.0, -12.0], [10.0, -8.0], [30.0, -8.0]])
    ego = _track(1, "van", k, np.stack([np.zeros(n), -50 + 6 * k * DT], 1), np.full(n, np.pi / 2))
    moto = _track(4, "motorcycle", k, np.stack([np.full(n, 1.0), -40 + 9 * k * DT], 1), np.full(n, np.pi / 2),
                  size=(2.1, 0.8, 1.4))
    return ScenarioRecord(
        scenario_id="s_val", split="val", intersection_id="i1", map_id="m_tee", behavior="COV",
        weather="fog", time_of_day="dusk", ego_track_id=1,
        route=RouteRecord(path, path[0].copy(), path[-1].copy()),
        dt=DT, num_steps=n, tracks=[moto, ego], signals={0: np.full(n, 3, np.int8)},
    )


def _stop() -> ScenarioRecord:
    k = np.arange(STEPS)
    ego = _track(0, "car", k, np.stack([np.full(STEPS, -14.0), np.full(STEPS, -1.75)], 1), np.zeros(STEPS))
    others = [
        _track(9, "bus", k[:20], np.stack([np.full(20, 1.75), 30 - 5 * k[:20] * DT], 1), np.full(20, -np.pi / 2),
               size=(12.0, 2.5, 3.2)),
        _track(11, "tricycle", k[25:], np.stack([np.full(25, 5.0), np.linspace(-20, 20, 25)], 1),
               np.full(25, np.pi / 2), size=(2.5, 1.2, 1.8)),
        _track(8, "cyclist", [3], [[0.0, 0.0]], [1.0], size=(1.8, 0.7, 1.6)),
    ]
    return ScenarioRecord(
        scenario_id="s_test", split="test", intersection_id="i0", map_id="m_cross", behavior="STP",
        weather="cloudy", time_of_day="day", ego_track_id=0,
        route=RouteRecord(np.array([[-20.0, -1.75], [-14.0, -1.75], [20.0, -1.75]]),
                          np.array([-20.0, -1.75]), np.array([20.0, -1.75])),
        dt=DT, num_steps=STEPS, tracks=[ego, *others], signals={0: np.full(STEPS, 1, np.int8)},
    )


def build_tiny_suite() -> SuiteRecord:
    maps = {m.map_id: m for m in (_cross_map(), _tee_map())}
    return SuiteRecord(name="tiny", version="1.0", maps=maps,
                       scenarios=[_straight(), _left(), _tee(), _stop()], meta={"purpose": "tests"})
