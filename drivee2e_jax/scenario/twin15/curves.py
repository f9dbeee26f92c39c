"""Host-side polyline helpers for the generator (numpy, float64, metres).

Only what building a map needs: unit vectors (arc length and uniform
resampling are ``drivee2e_jax.polyline``'s), Bezier and arc pieces, smoothing that keeps straight ends exact,
heading and curvature, and splitting long polylines for fixed-size packing.
"""

from __future__ import annotations

import numpy as np

from drivee2e_jax.polyline import arc_length, resample_polyline


def unit(angle_rad: float) -> np.ndarray:
    """(2,) unit vector at ``angle_rad`` CCW from +x."""
    return np.array([np.cos(angle_rad), np.sin(angle_rad)])


def rot90(v: np.ndarray) -> np.ndarray:
    """``v`` rotated by +90 degrees (counter-clockwise); works on (..., 2)."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def line(a: np.ndarray, b: np.ndarray, step: float = 0.25) -> np.ndarray:
    """Straight segment from a to b sampled at <= ``step``."""
    return resample_polyline(np.stack([np.asarray(a, float), np.asarray(b, float)]), step)


def bezier(p0, p1, p2, p3, n: int = 200) -> np.ndarray:
    """(n, 2) cubic Bezier curve through its four control points."""
    t = np.linspace(0.0, 1.0, n)[:, None]
    p0, p1, p2, p3 = (np.asarray(p, float) for p in (p0, p1, p2, p3))
    return ((1 - t) ** 3) * p0 + 3 * ((1 - t) ** 2) * t * p1 + 3 * (1 - t) * t * t * p2 + t ** 3 * p3


def arc(center: np.ndarray, radius: float, a0: float, a1: float, step: float = 0.25) -> np.ndarray:
    """Circular arc from angle a0 to a1 (rad; a1 < a0 runs clockwise)."""
    n = max(2, int(np.ceil(abs(a1 - a0) * radius / step)) + 1)
    ang = np.linspace(a0, a1, n)
    return np.asarray(center, float) + radius * np.stack([np.cos(ang), np.sin(ang)], axis=1)


def smooth(pts: np.ndarray, sigma: float, step: float = 0.25) -> np.ndarray:
    """Gaussian-smooth a polyline along its arc length (sigma in m).

    The ends are extended along their end tangents before filtering, so a
    polyline whose first and last ``3 * sigma`` metres are straight keeps its
    end points and end headings exactly (a linear function is a fixed point
    of the filter). Returns points ``step`` apart.
    """
    p = resample_polyline(pts, step)
    k = int(np.ceil(3 * sigma / step))
    d0 = p[1] - p[0]
    d1 = p[-1] - p[-2]
    head = p[0] - d0 * np.arange(k, 0, -1)[:, None]
    tail = p[-1] + d1 * np.arange(1, k + 1)[:, None]
    ext = np.concatenate([head, p, tail])
    x = np.arange(-k, k + 1) * step
    w = np.exp(-0.5 * (x / sigma) ** 2)
    w /= w.sum()
    out = np.stack([np.convolve(ext[:, 0], w, "valid"), np.convolve(ext[:, 1], w, "valid")], axis=1)
    out[0], out[-1] = pts[0], pts[-1]
    return resample_polyline(out, step)


def headings(pts: np.ndarray) -> np.ndarray:
    """(n,) unwrapped tangent heading of a densely sampled polyline, rad."""
    d = np.gradient(pts, axis=0)
    return np.unwrap(np.arctan2(d[:, 1], d[:, 0]))


def curvature(pts: np.ndarray) -> np.ndarray:
    """(n,) signed curvature (1/m, + = left) of a uniformly sampled polyline."""
    s = arc_length(pts)
    h = headings(pts)
    if len(s) < 3:
        return np.zeros(len(s))
    return np.gradient(h, s)


def chunk(pts: np.ndarray, max_points: int, overlap: int = 1) -> list[np.ndarray]:
    """Split a polyline into pieces of <= ``max_points`` sharing end points."""
    n = len(pts)
    if n <= max_points:
        return [pts]
    pieces, i = [], 0
    while i < n - 1:
        j = min(n, i + max_points)
        pieces.append(pts[i:j])
        i = j - overlap
    return pieces


def polygon_ccw(poly: np.ndarray) -> np.ndarray:
    """The polygon with counter-clockwise vertex order (shoelace sign)."""
    x, y = poly[:, 0], poly[:, 1]
    area2 = np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))
    return poly if area2 > 0 else poly[::-1].copy()


def line_intersection(p, d, q, e) -> np.ndarray | None:
    """Intersection of the lines p + t d and q + u e (None when parallel)."""
    m = np.array([[d[0], -e[0]], [d[1], -e[1]]])
    if abs(np.linalg.det(m)) < 1e-9:
        return None
    t, _ = np.linalg.solve(m, np.asarray(q, float) - np.asarray(p, float))
    return np.asarray(p, float) + t * np.asarray(d, float)
