"""Road surface and what stands beside it: drivable-area polygons,
crosswalks, and static obstacles (corner buildings, signal poles, lamp
poles), all footprints convex and kept clear of the drivable area.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Polygon

from drivee2e_jax.records import ObstacleRecord

from .curves import line_intersection, polygon_ccw
from .legs import SIDEWALK, Corner, Leg

#: Minimum clearance between an obstacle and the drivable area, m.
OBSTACLE_CLEARANCE = 0.8


def crosswalk_polygon(leg: Leg) -> np.ndarray:
    d0, d1 = leg.crosswalk_span
    return polygon_ccw(np.stack([leg.point(d0, -leg.w_out), leg.point(d1, -leg.w_out),
                                 leg.point(d1, leg.w_in), leg.point(d0, leg.w_in)]))


def junction_polygon(legs: list[Leg], corners: list[Corner]) -> np.ndarray:
    """The junction box: leg mouths joined by the rounded kerbs (a simple,
    generally non-convex polygon)."""
    pts = []
    for leg, c in zip(legs, corners):
        pts += [leg.point(leg.r, -leg.w_out), leg.point(leg.r, leg.w_in)]
        if c.arc is not None:
            pts += list(c.arc)
    return polygon_ccw(np.asarray(pts))


def leg_polygon(leg: Leg) -> np.ndarray:
    """The leg's road surface from the junction box to the map edge."""
    d = np.linspace(leg.d_stop, leg.d_end, 41)
    kerb = leg.point(d, leg.kerb_in(d))
    pts = [leg.point(leg.r, -leg.w_out), leg.point(leg.d_end, -leg.w_out)]
    pts += list(kerb[::-1]) + [leg.point(leg.r, leg.w_in)]
    poly = np.asarray(pts)
    keep = np.ones(len(poly), bool)
    # drop collinear points (straight kerbs) so the polygon stays small
    for i in range(1, len(poly) - 1):
        u, v = poly[i] - poly[i - 1], poly[i + 1] - poly[i]
        if abs(u[0] * v[1] - u[1] * v[0]) < 1e-6:
            keep[i] = False
    return polygon_ccw(poly[keep])


def _square(center: np.ndarray, half: float, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    loc = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    return center + loc @ np.array([[c, s], [-s, c]])


def build_obstacles(legs: list[Leg], corners: list[Corner], drivable: list[np.ndarray]) -> list[ObstacleRecord]:
    road = shapely.union_all([Polygon(p) for p in drivable]).buffer(OBSTACLE_CLEARANCE)
    out: list[ObstacleRecord] = []
    for k, c in enumerate(corners):
        a, b = legs[c.a], legs[c.b]
        if c.arc is not None:
            # a block in the corner wedge, behind the sidewalks of both legs
            x = line_intersection((a.w_in + SIDEWALK) * a.n, a.u, -(b.w_out + SIDEWALK) * b.n, b.u)
            la, lb = 16.0 + 3.0 * (k % 3), 14.0 + 4.0 * ((k + 1) % 3)
            poly = np.stack([x, x + la * a.u, x + la * a.u + lb * b.u, x + lb * b.u])
            bis = a.u + b.u
            bis /= np.linalg.norm(bis)
        else:
            # a straight kerb (a T's through side): a block facing the junction
            pa, pb = a.point(a.r, a.w_in), b.point(b.r, -b.w_out)
            along = (pb - pa) / max(np.linalg.norm(pb - pa), 1e-9)
            out_n = np.array([along[1], -along[0]])
            if out_n @ (pa + pb) < 0:
                out_n = -out_n
            mid = (pa + pb) / 2 + SIDEWALK * out_n
            poly = np.stack([mid - 14 * along, mid + 14 * along,
                             mid + 14 * along + 12 * out_n, mid - 14 * along + 12 * out_n])
            bis = out_n
        for _ in range(40):  # push outwards until clear of the road
            if not Polygon(poly).intersects(road) and Polygon(poly).distance(road) >= SIDEWALK - 2.0:
                break
            poly = poly + bis
        out.append(ObstacleRecord(polygon_ccw(poly), height=float(9.0 + 6.0 * (k % 4)), kind="building"))
    for leg in legs:
        # a signal pole on each side of the stop line
        for o in (leg.w_in + 1.2, -(leg.w_out + 1.2)):
            out.append(ObstacleRecord(_square(leg.point(leg.d_stop + 0.8, o), 0.2, leg.theta), 6.0, "signal_pole"))
        # lamp poles along both kerbs
        for d in np.arange(leg.d_stop + 18.0, leg.d_end - 4.0, 30.0):
            for o in (float(leg.kerb_in(d)) + 1.0, -(leg.w_out + 1.0)):
                out.append(ObstacleRecord(_square(leg.point(d, o), 0.15, leg.theta), 8.0, "pole"))
    keep = [o for o in out if not Polygon(o.polygon).intersects(road)]
    return keep
