"""Vector observation pieces that are not covered through the simulator tests."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.observe.vector import route_speed_limits
from drivee2e_jax.types import Route


def _polyline(x0, x1, y, n=41):
    return np.stack([np.linspace(x0, x1, n), np.full(n, y)], 1).astype(np.float32)


def test_route_speed_limit_follows_the_aligned_lane_under_the_route():
    # Route eastbound along y = -1.75 from x = -20 to 20. Lanes: the eastbound
    # lane is split at x = 0 into a 10 m/s and a 15 m/s part; a westbound lane
    # at y = +1.75 (closer to nothing, but opposite) has 30 m/s and must never count.
    xs = np.arange(-20.0, 21.0, 1.0, dtype=np.float32)
    route = Route(
        xy=jnp.stack([xs, np.full_like(xs, -1.75)], 1),
        arc=jnp.asarray(xs + 20.0),
        command=jnp.zeros(xs.shape, jnp.int32),
        valid=jnp.ones(xs.shape, bool),
        length=jnp.asarray(40.0),
    )
    lanes = np.stack([_polyline(-40, 0, -1.75), _polyline(0, 40, -1.75), _polyline(40, -40, -1.0)])
    limits = route_speed_limits(
        route, jnp.asarray(lanes), jnp.ones(lanes.shape[:2], bool), jnp.ones(3, bool), jnp.array([10.0, 15.0, 30.0])
    )
    limits = np.asarray(limits)
    assert limits.shape == (41,)
    np.testing.assert_allclose(limits[xs < -0.5], 10.0)
    np.testing.assert_allclose(limits[xs > 0.5], 15.0)


def test_route_speed_limit_without_aligned_lane_takes_the_highest_candidate():
    xs = np.arange(0.0, 10.0, 1.0, dtype=np.float32)
    route = Route(
        xy=jnp.stack([xs, np.zeros_like(xs)], 1),
        arc=jnp.asarray(xs),
        command=jnp.zeros(xs.shape, jnp.int32),
        valid=jnp.ones(xs.shape, bool),
        length=jnp.asarray(9.0),
    )
    # Only a northbound lane (perpendicular) nearby, plus an invalid row.
    lanes = np.stack([np.stack([np.full(11, 5.0), np.linspace(-5, 5, 11)], 1), np.zeros((11, 2))]).astype(np.float32)
    limits = route_speed_limits(
        route, jnp.asarray(lanes), jnp.ones((2, 11), bool), jnp.array([True, False]), jnp.array([8.0, 99.0])
    )
    assert np.asarray(limits) == pytest.approx(np.full(10, 8.0))
