"""Host-side (numpy, float64) angle and polyline helpers.

The one home of what the scenario builders, the importers, packing and the
host-side metrics need of plain polylines ``(n, 2)`` in metres. Nothing here
runs under ``jit``: the in-jit equivalents are in ``geometry`` (its
``wrap_angle`` has the same (-pi, pi] convention).

* ``wrap_angle(a)``: angles to (-pi, pi].
* ``arc_length(points) -> (n,)``: cumulative arc length, starting at 0.
* ``polyline_length(points) -> float``: total arc length (0 for < 2 points).
* ``polyline_heading(points, at_end=False) -> float``: heading of the first
  (or last) segment, rad.
* ``dedupe_polyline(points, tol)``: consecutive points closer than ``tol`` dropped.
* ``resample_polyline(points, spacing, ...)``: even arc-length spacing (the
  step is ``length / ceil(length / spacing)`` <= ``spacing``), both ends exact.
* ``resample_at_fractions(points, frac)``: points at arc-length fractions.
* ``densify_polyline(points, step) -> (xy, arc)``: a point every ``step`` m
  of arc, the last (shorter) piece ending at the exact last point.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "wrap_angle",
    "arc_length",
    "polyline_length",
    "polyline_heading",
    "dedupe_polyline",
    "resample_polyline",
    "resample_at_fractions",
    "densify_polyline",
]


def wrap_angle(a) -> np.ndarray:
    """Angles (any shape, rad) wrapped to (-pi, pi], as float64.

    ``pi - mod(pi - a, 2 pi)`` (the packed tracks' yaw since PACK_FORMAT 1),
    with -pi (``mod`` rounding up to 2 pi for ``a`` a hair above pi) mapped to pi.
    """
    w = np.pi - np.mod(np.pi - np.asarray(a, np.float64), 2.0 * np.pi)
    return np.where(w == -np.pi, np.pi, w)


def arc_length(points: np.ndarray) -> np.ndarray:
    """(n,) cumulative arc length of a polyline (n, 2), starting at 0."""
    p = np.asarray(points, np.float64)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def polyline_length(points: np.ndarray) -> float:
    """Arc length of a (n, 2) polyline, m (0 for fewer than two points)."""
    p = np.asarray(points, np.float64)
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(p) > 1 else 0.0


def polyline_heading(points: np.ndarray, at_end: bool = False, over_m: float | None = None) -> float:
    """Heading (rad, CCW from +x) at a polyline's start, or its end when ``at_end``.

    Of the first (last) segment by default (needs at least two points); with
    ``over_m`` of the chord over the first (last) ``over_m`` metres of arc
    (the whole polyline when shorter; 0 for a zero-length polyline).
    """
    p = np.asarray(points)
    if over_m is None:
        d = p[-1] - p[-2] if at_end else p[1] - p[0]
        return math.atan2(d[1], d[0])
    s = arc_length(p)
    if s[-1] <= 0:
        return 0.0
    if at_end:
        q = resample_at_fractions(p, np.array([max(0.0, 1.0 - over_m / s[-1]), 1.0]))
    else:
        q = resample_at_fractions(p, np.array([0.0, min(1.0, over_m / s[-1])]))
    d = q[1] - q[0]
    return math.atan2(d[1], d[0])


def dedupe_polyline(points: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Drop consecutive points closer than ``tol`` m; the first and the exact
    last point are kept."""
    pts = np.asarray(points, np.float64)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > tol])
    out = pts[keep]
    if np.linalg.norm(out[-1] - pts[-1]) > 0:
        out[-1] = pts[-1]
    return out


def resample_polyline(points: np.ndarray, spacing: float, *, dedupe_tol: float = 1e-6,
                      count_slack: float = 1e-9) -> np.ndarray:
    """A (m, 2) polyline at even arc-length spacing <= ``spacing`` m.

    ``m = max(2, ceil(length / spacing - count_slack) + 1)`` points, both ends
    exact. ``dedupe_tol`` > 0 first drops consecutive points closer than that
    (``dedupe_polyline``); ``count_slack`` keeps a length a hair over a
    multiple of ``spacing`` from adding a point (the importers pass 0 for
    both, as they always have). Fewer than two points come back as a copy; a
    zero-length polyline as its first point twice. Only the first two columns
    are used.
    """
    p = np.asarray(points, np.float64)[:, :2]
    if len(p) < 2:
        return p.copy()
    if dedupe_tol > 0:
        p = dedupe_polyline(p, dedupe_tol)
    s = arc_length(p)
    if s[-1] <= 0:
        return p[[0, -1]].copy()
    n = max(2, int(math.ceil(s[-1] / spacing - count_slack)) + 1)
    q = np.linspace(0.0, s[-1], n)
    out = np.stack([np.interp(q, s, p[:, 0]), np.interp(q, s, p[:, 1])], axis=1)
    out[0], out[-1] = p[0], p[-1]
    return out


def resample_at_fractions(points: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Points (k, 2) at arc-length fractions ``frac`` (k,) in [0, 1] of a
    polyline (n, 2); a zero-length polyline gives its first point k times."""
    xy = np.asarray(points, np.float64)
    s = arc_length(xy)
    if s[-1] <= 0.0:
        return np.repeat(xy[:1], len(frac), axis=0)
    q = np.asarray(frac) * s[-1]
    return np.stack([np.interp(q, s, xy[:, 0]), np.interp(q, s, xy[:, 1])], axis=1)


def densify_polyline(points: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """A point every ``step`` m of arc length, keeping the last point exactly
    (the last piece is <= ``step``; one shorter than 1e-6 m is merged into it).
    Runs of repeated points (< 1e-9 m apart) keep their last one first.

    Returns (xy (m, 2) float64, arc (m,) cumulative length of the result).
    """
    w = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(w) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    seg = np.linalg.norm(np.diff(w, axis=0), axis=1)
    w = w[np.r_[seg > 1e-9, True]]  # of a run of repeats keep the last (the exact end)
    if len(w) == 1:
        return w.copy(), np.zeros(1)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(w, axis=0), axis=1))]
    q = np.arange(0.0, s[-1], step)
    if s[-1] - q[-1] < 1e-6:
        q = q[:-1]
    q = np.r_[q, s[-1]]
    xy = np.stack([np.interp(q, s, w[:, 0]), np.interp(q, s, w[:, 1])], axis=1)
    xy[-1] = w[-1]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    return xy, arc
