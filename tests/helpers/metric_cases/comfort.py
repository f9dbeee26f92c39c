"""Worked case B2D-03 of Bench2Drive smoothness (``drivee2e_jax.metrics.comfort``)
through the project's functions, from a case dict of ``metric_cases.json``."""

from __future__ import annotations

import math

import numpy as np

from drivee2e_jax.metrics.comfort import (
    b2d_route_smoothness,
    b2d_smoothness,
)


def frames(n, ax=None, ay=0.0, yaw_rate=None):
    """B2D-03's frame layout: acceleration [ax, ay, 0], angular velocity
    [0, 0, yaw_rate], forward [1, 0, 0], right [0, 1, 0]; ``ax`` / ``yaw_rate``
    as (first, last, value) frame spans."""
    acc = np.zeros((n, 3))
    acc[:, 1] = ay
    wz = np.zeros(n)
    if ax:
        acc[ax[0] : ax[1] + 1, 0] = ax[2]
    if yaw_rate:
        wz[yaw_rate[0] : yaw_rate[1] + 1] = yaw_rate[2]
    return acc, np.tile([1.0, 0.0, 0.0], (n, 1)), np.tile([0.0, 1.0, 0.0], (n, 1)), wz


#: B2D-03's routes as its ``input.routes`` describes them.
B2D03_ROUTES = {
    "3001": lambda: frames(60),
    "3002": lambda: frames(60, ax=(22, 31, -6.0)),
    "3003": lambda: frames(15),
    "3004": lambda: frames(45, yaw_rate=(0, 19, 1.2)),
    "3005": lambda: frames(20, ay=5.0),
}


def check_b2d03(case: dict) -> None:
    """Per-route smoothness and the overall mean of B2D-03, within its tolerance."""
    assert case["id"] == "B2D-03" and case["family"] == "b2d_comfort"
    tol = case["tolerance"]
    want = case["expected"]["per_route"]
    assert set(want) == set(B2D03_ROUTES) == set(case["input"]["routes"])
    got = {rid: b2d_route_smoothness(*B2D03_ROUTES[rid]()) for rid in want}
    for rid in want:
        ok = math.isclose(got[rid], want[rid], rel_tol=tol.get("rel", 0.0), abs_tol=tol.get("abs", 0.0))
        assert ok, (rid, got[rid], want[rid])
    overall = b2d_smoothness([got[rid] for rid in want])
    assert math.isclose(overall, case["expected"]["driving_smoothness"], rel_tol=tol.get("rel", 0.0),
                        abs_tol=tol.get("abs", 0.0)), overall
