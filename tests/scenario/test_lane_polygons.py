"""Lane area polygons against shapely (independent oracle)."""

import numpy as np
import pytest

shapely = pytest.importorskip("shapely")
from shapely.geometry import LineString, Polygon  # noqa: E402

from drivee2e_jax.records import LaneRecord  # noqa: E402
from drivee2e_jax.scenario.lane_polygons import lane_polygon, lane_polygon_source, signed_area  # noqa: E402


def _arc(radius: float, sweep: float, n: int) -> np.ndarray:
    a = np.linspace(0.0, sweep, n)
    return np.stack([radius * np.sin(a), radius - radius * np.cos(a)], axis=1)


@pytest.mark.parametrize("centerline", [
    np.stack([np.linspace(0, 40, 9), np.zeros(9)], axis=1),
    _arc(20.0, np.pi / 2, 25),
    _arc(6.0, np.pi, 40),  # tight U-turn
])
def test_centerline_polygon_matches_flat_buffer(centerline):
    width = 3.5
    poly = lane_polygon(LaneRecord(id=0, centerline=centerline, width=width))
    shp = Polygon(poly)
    ref = LineString(centerline).buffer(width / 2, cap_style="flat")
    assert shp.is_valid
    assert signed_area(poly) > 0  # counter-clockwise
    assert abs(shp.area - ref.area) / ref.area < 0.01
    assert shp.symmetric_difference(ref).area / ref.area < 0.02


def test_boundaries_used_exactly():
    cl = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 1.0]])
    left = np.array([[0.0, 2.0], [10.0, 2.1], [20.0, 3.0]])
    right = np.array([[0.0, -1.5], [5.0, -1.6], [20.0, -1.0]])
    lane = LaneRecord(id=1, centerline=cl, width=3.5, left_boundary=left, right_boundary=right)
    assert lane_polygon_source(lane) == "boundaries"
    poly = lane_polygon(lane)
    np.testing.assert_allclose(poly, np.concatenate([right, left[::-1]]))
    assert Polygon(poly).is_valid and signed_area(poly) > 0
    # one boundary only -> fallback
    assert lane_polygon_source(LaneRecord(id=2, centerline=cl, left_boundary=left)) == "centerline"


def test_packed_polygon_is_capped_and_close():
    from drivee2e_jax.scenario.lane_polygons import MAX_VERTICES, packed_lane_polygon

    cl = _arc(30.0, np.pi, 200)  # 400 ring vertices before simplification
    lane = LaneRecord(id=0, centerline=cl, width=3.5)
    full, capped = Polygon(lane_polygon(lane)), Polygon(packed_lane_polygon(lane))
    assert len(lane_polygon(lane)) > MAX_VERTICES >= len(packed_lane_polygon(lane))
    assert capped.is_valid and capped.exterior.is_ccw
    # a 94 m half-circle in <= 64 vertices: chords of ~3 m, sagitta ~4 cm on each side
    assert full.symmetric_difference(capped).area / full.area < 0.02
