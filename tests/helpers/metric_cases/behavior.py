"""Worked case BM-01 of Behavior Metrics (``drivee2e_jax.metrics.behavior``)
through ``bm_code_metrics``, from a case dict of ``metric_cases.json``."""

from __future__ import annotations

import math

import numpy as np

from drivee2e_jax.metrics.behavior import bm_code_metrics

R2 = math.sqrt(2.0)


def assert_close(got, want, tol: dict, what: str) -> None:
    rel, abs_ = tol.get("rel", 0.0), tol.get("abs", 0.0)
    ok = math.isclose(float(got), float(want), rel_tol=rel, abs_tol=abs_)
    assert ok, f"{what}: got {got!r}, want {want!r} ({tol})"


def bm01_inputs(case: dict) -> dict:
    """The arrays BM-01's ``input`` describes (45-degree road, 101 poses)."""
    inp = case["input"]
    k = np.arange(401)
    waypoints = np.stack([100 + 0.5 * k / R2, 50 + 0.5 * k / R2], axis=1)
    i = np.arange(101)
    off = np.where(i < 60, 0.3, np.where(i < 80, 1.5, 0.3))
    poses = np.stack([100 + i / R2 - off / R2, 50 + i / R2 + off / R2], axis=1)
    speed = np.r_[0.0, np.full(50, 10.0), np.full(50, 8.0)]
    controls = [[s["throttle"], s["steer"], s["brake"]] for s in inp["vehicle_status"]]
    return dict(
        map_waypoints_xy=waypoints, pose_xy=poses, pose_time_s=0.1 * i, speed_mps=speed, controls=controls,
        collision_time_s=[e["Time"] for e in inp["collision_events"]],
        lane_invasion_time_s=[e["Time"] for e in inp["lane_invasion_events"]],
    )


def check_bm01(case: dict) -> None:
    """Every expected key of BM-01 through ``bm_code_metrics``, within the case tolerance."""
    assert case["id"] == "BM-01" and case["family"] == "behavior_metrics"
    got = bm_code_metrics(**bm01_inputs(case))
    for key, want in case["expected"].items():
        assert key in got, f"BM-01: missing {key}"
        assert_close(got[key], want, case["tolerance"], f"BM-01 {key}")
