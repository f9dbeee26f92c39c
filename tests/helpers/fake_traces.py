"""Hand-built episode traces for the player tests (no simulation): a straight
road, an ego at 8 m/s, a truck and a pedestrian, BEV and LiDAR frames."""

from __future__ import annotations

import numpy as np

from drivee2e_jax.eval.traces import AgentsTrace, EpisodeTrace, StaticMap

T, DT = 21, 0.1
BEV_CH = ("drivable", "route", "vehicle", "ego")


def fake_trace(sid="s0", map_id="m0", events=None, lidar_n=400, *, policy="expert", status="Completed", ds=60.0,
               behavior="STR"):
    """One T-instant episode; ``events`` default: a red light at t = 1.5 s."""
    rng = np.random.default_rng(0)
    t = np.arange(T) * DT
    ego_xy = np.stack([-20 + 8 * t, np.full(T, -1.75)], 1)
    ag_xy = rng.normal(0, 10, (T, 2, 2))
    ag_valid = np.ones((T, 2), bool)
    ag_valid[:5, 1] = False
    ag_valid[12, 1] = False
    bev = {c: np.zeros((T, 8, 8), bool) for c in BEV_CH}
    bev["drivable"][:] = True
    bev["ego"][:, 6, 4] = True
    bev["vehicle"][:, 1, 1] = True
    bev["ego"][:, 1, 1] = True  # the later channel wins
    pts = rng.uniform(-40, 40, (T, lidar_n, 3)).astype(np.float32)
    smap = StaticMap(
        lanes=[np.array([[-60.0, -1.75], [60.0, -1.75]])], lane_type=np.zeros(1, int),
        lane_speed_limit=np.full(1, 13.9), boundaries=[np.array([[-60.0, 0.0], [60.0, 0.0]])],
        boundary_marking=np.array([1]), crosswalks=[np.array([[-8.0, -7], [-4, -7], [-4, 7], [-8, 7]])],
        stop_lines=np.array([[[-12.0, -3.5], [-12.0, 0.0]]]), stop_line_row=np.array([0]),
        stop_line_lane=np.array([0]), drivable=[np.array([[-60.0, -10], [60, -10], [60, 10], [-60, 10]])],
        obstacles=[], obstacle_height=np.zeros(0),
    )
    return EpisodeTrace(
        scenario_id=sid, policy=policy, meta={"map_id": map_id, "behavior": behavior, "split": "val"},
        row={"driving_score": ds, "route_completion": 100.0, "status": status},
        dt=DT, times=t, ego_size=np.array([4.5, 1.9, 1.5]), ego_xy=ego_xy, ego_yaw=np.zeros(T),
        ego_speed=np.full(T, 8.0), ego_accel=np.zeros(T), ego_steer=np.zeros(T), ego_yaw_rate=np.zeros(T),
        controls=np.tile([0.5, 0.0, 0.1], (T, 1)), plan_xy=ego_xy[:, None, :] + np.array([[[2.0, 0], [4, 0]]]),
        plan_valid=np.arange(T) < T - 1,
        agents=AgentsTrace(track_id=np.array([3, 12]), category=np.array([1, 6]),
                           size=np.array([[9.0, 2.5, 3.5], [0.6, 0.6, 1.7]]), xy=ag_xy,
                           yaw=rng.uniform(-3, 3, (T, 2)), vel=np.zeros((T, 2, 2)), valid=ag_valid),
        signals=np.r_[np.full(10, 3), np.full(11, 1)][:, None], map=smap, route_xy=ego_xy,
        route_arc=8 * t, route_command=np.full(T, 4), route_length=16.0,
        timeline={"speed": np.full(T, 8.0), "route_completion": np.linspace(0, 100, T),
                  "facts.front_distance": np.full(T, np.inf), "facts.lane_offset": np.zeros(T)},
        events=events if events is not None else [{"type": "red_light", "t": 1.5, "x": -8.0, "y": -1.75}],
        resim_events=[], driving_score=ds, stored_driving_score=ds, reproduced=True,
        bev=bev, bev_resolution=0.5, lidar_points=pts, lidar_class=np.full((T, lidar_n), 4, np.int8),
        lidar_valid=np.ones((T, lidar_n), bool),
    )
