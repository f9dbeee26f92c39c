"""Oriented-box overlap checks on logged tracks (numpy, host side).

``find_overlaps`` tests every pair of agents of one scenario at every step
with the separating axis theorem, after a broad phase on bounding circles
so the cost stays near-linear in agents: used by the generator to drop the
rare overlapping agent and by the tests over the whole suite.
"""

from __future__ import annotations

import warnings

import numpy as np

CHUNK = 20  # steps per broad-phase bounding box


def corners(xy: np.ndarray, yaw: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """(..., 4, 2) box corners (counter-clockwise from front-left)."""
    c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
    hl, hw = (length / 2)[..., None], (width / 2)[..., None]
    lx = np.array([1.0, -1.0, -1.0, 1.0]) * hl
    ly = np.array([1.0, 1.0, -1.0, -1.0]) * hw
    return np.stack([xy[..., :1] + c * lx - s * ly, xy[..., 1:] + s * lx + c * ly], axis=-1)


def sat_overlap(c1: np.ndarray, c2: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """(...) bool: boxes with corners c1, c2 (..., 4, 2) share interior."""
    e1 = c1[..., 1, :] - c1[..., 0, :]
    e2 = c1[..., 3, :] - c1[..., 0, :]
    f1 = c2[..., 1, :] - c2[..., 0, :]
    f2 = c2[..., 3, :] - c2[..., 0, :]
    sep = np.zeros(c1.shape[:-2], bool)
    for ax in (e1, e2, f1, f2):
        p1 = np.einsum("...kd,...d->...k", c1, ax)
        p2 = np.einsum("...kd,...d->...k", c2, ax)
        scale = np.sqrt((ax * ax).sum(-1))
        sep |= (p1.max(-1) - p2.min(-1) <= eps * scale) | (p2.max(-1) - p1.min(-1) <= eps * scale)
    return ~sep


def find_overlaps(xy: np.ndarray, yaw: np.ndarray, size: np.ndarray, valid: np.ndarray,
                  inflate: np.ndarray | None = None) -> np.ndarray:
    """Overlapping (i, j, t) triples (i < j) of one scenario.

    Args:
      xy: (A, T, 2) box centres; yaw: (A, T); size: (A, >=2) length, width;
      valid: (A, T) bool; inflate: (A,) metres added on every side of an
        agent's box (e.g. 0.5 for the ego: a 0.5 m clearance check).
    Returns:
      (K, 3) int array.
    """
    A = xy.shape[0]
    if A < 2:
        return np.zeros((0, 3), np.int64)
    infl = np.zeros(A) if inflate is None else np.asarray(inflate, float)
    length = size[:, 0] + 2 * infl
    width = size[:, 1] + 2 * infl
    rad = 0.5 * np.hypot(length, width)
    # broad phase: bounding boxes per chunk of steps, then circles per step
    T = xy.shape[1]
    nc = -(-T // CHUNK)
    pad = nc * CHUNK - T
    big = np.where(valid[..., None], xy, np.nan)
    big = np.pad(big, ((0, 0), (0, pad), (0, 0)), constant_values=np.nan).reshape(A, nc, CHUNK, 2)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN chunks
        lo = np.nanmin(big, axis=2) - rad[:, None, None]
        hi = np.nanmax(big, axis=2) + rad[:, None, None]
    ii, jj = np.triu_indices(A, 1)
    touch = np.all(lo[ii] <= hi[jj], axis=-1) & np.all(lo[jj] <= hi[ii], axis=-1)  # NaN compares False
    pi, ci = np.nonzero(touch)
    if not len(pi):
        return np.zeros((0, 3), np.int64)
    a, b = ii[pi], jj[pi]
    t = (ci[:, None] * CHUNK + np.arange(CHUNK)[None, :]).ravel()
    a, b = np.repeat(a, CHUNK), np.repeat(b, CHUNK)
    ok = t < T
    a, b, t = a[ok], b[ok], t[ok]
    near = valid[a, t] & valid[b, t] & (((xy[a, t] - xy[b, t]) ** 2).sum(-1) < (rad[a] + rad[b]) ** 2)
    a, b, t = a[near], b[near], t[near]
    if not len(a):
        return np.zeros((0, 3), np.int64)
    c1 = corners(xy[a, t], yaw[a, t], length[a], width[a])
    c2 = corners(xy[b, t], yaw[b, t], length[b], width[b])
    hit = sat_overlap(c1, c2)
    return np.stack([a[hit], b[hit], t[hit]], axis=1)
