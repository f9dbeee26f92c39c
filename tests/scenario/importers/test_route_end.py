"""An imported route ends ``routes.ROUTE_END_MARGIN_M`` before the logged ego's
last position, so that replaying the log passes its last point (LB counts a
route point only once the ego is strictly ahead of it)."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_jax.polyline import polyline_length
from drivee2e_jax.records import TrackRecord
from drivee2e_jax.scenario.routes import LOG_ROUTE_SPACING_M, ROUTE_END_MARGIN_M, build_route


def _track(xy):
    xy = np.asarray(xy, float)
    n = len(xy)
    return TrackRecord(0, "car", np.array([4.5, 1.9, 1.5]), np.arange(n) * 0.1, xy, np.zeros(n))


def test_route_stops_the_margin_short_of_the_logged_end_along_the_path():
    xy = np.stack([np.linspace(0, 50.05, 1002), np.zeros(1002)], 1)
    r = build_route(_track(xy))
    np.testing.assert_allclose(r.source, xy[0])
    np.testing.assert_allclose(r.destination, xy[-1])  # the logged end
    np.testing.assert_allclose(r.waypoints[0], xy[0])
    np.testing.assert_allclose(r.waypoints[-1], xy[-1] - [ROUTE_END_MARGIN_M, 0.0], atol=1e-9)
    assert polyline_length(r.waypoints) == pytest.approx(50.05 - ROUTE_END_MARGIN_M)
    gaps = np.linalg.norm(np.diff(r.waypoints, axis=0), axis=1)
    assert gaps[:-1].min() >= LOG_ROUTE_SPACING_M - 1e-9 and gaps.max() < 2 * LOG_ROUTE_SPACING_M


def test_the_logged_end_lies_strictly_ahead_of_the_last_point_on_a_turn():
    a = np.linspace(-np.pi / 2, 0.0, 200)  # a quarter circle of radius 20 m, left turn
    xy = np.stack([20 * np.cos(a), 20 + 20 * np.sin(a)], 1)
    r = build_route(_track(xy))
    fwd = r.waypoints[-1] - r.waypoints[-2]
    assert np.dot(xy[-1] - r.waypoints[-1], fwd / np.linalg.norm(fwd)) == pytest.approx(ROUTE_END_MARGIN_M, abs=1e-6)


def test_a_path_not_longer_than_the_margin_is_kept_whole():
    r = build_route(_track([[0.0, 0.0], [0.2, 0.0], [0.4, 0.0]]))
    np.testing.assert_allclose(r.waypoints[[0, -1]], [[0.0, 0.0], [0.4, 0.0]])
    assert build_route(_track(np.zeros((5, 2)))).waypoints.shape == (2, 2)
