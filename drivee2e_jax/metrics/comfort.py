"""Bench2Drive comfortness/smoothness (host-side numpy).

Definitions: ``shared/reference/METRICS.md`` section 2 ("Comfortness/
smoothness", "Efficiency"), from Bench2Drive 0.0.4
``tools/efficiency_smoothness_benchmark.py``.

* Savitzky-Golay smoothing is ``scipy.signal.savgol_filter`` itself, as
  B2D calls it (default ``mode="interp"``: the ``window // 2`` samples at each
  end come from the polynomial fitted to the first / last window), along the
  last axis so a batch of chunks is filtered in one call. scipy comes with
  JAX (a dependency of ``jax``).
* ``b2d_comfort_checks`` / ``b2d_route_smoothness`` / ``b2d_smoothness``:
  the six bounds on one chunk, the fraction of passing 20-frame chunks of a
  route, the mean over routes.
* ``b2d_frames_from_episode``: a simulated episode as B2D's per-frame signals.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.signal import savgol_filter

#: Strict bounds (low, high) of every smoothed signal [B2D]; units m/s^2,
#: m/s^3, rad/s (B2D calls the smoothed yaw rate "yaw acc", bound 1.93).
B2D_BOUNDS = (
    ("lon_acc", -4.05, 2.40),
    ("lat_acc", -4.89, 4.89),
    ("magnitude_jerk", -8.37, 8.37),
    ("lon_jerk", -4.13, 4.13),
    ("yaw_acc", -1.93, 1.93),
    ("yaw_rate", -0.95, 0.95),
)
#: B2D's Savitzky-Golay window (clipped to the signal length), order and
#: derivative spacing (s), and its chunk length (frames).
B2D_WINDOW = 7
B2D_POLYORDER = 2
B2D_DELTA_S = 0.1
B2D_CHUNK = 20


def _phase_unwrap(a: np.ndarray) -> np.ndarray:
    """B2D's ``_phase_unwrap`` along the last axis (applied there to the yaw
    *rate*): remove 2*pi jumps between successive samples (numpy's
    round-half-even, as B2D)."""
    adj = np.zeros_like(a)
    adj[..., 1:] = np.cumsum(np.round(np.diff(a, axis=-1) / (2.0 * np.pi)), axis=-1)
    return a - 2.0 * np.pi * adj


def _xy(name: str, a, n: int | None) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 2 or (n is not None and len(arr) != n):
        raise ValueError(f"b2d comfort: {name} must have shape (n, 2) or (n, 3) with n = {n}, got {arr.shape}")
    return arr[:, :2]


def chunk_signals(a, f, r, wz, delta_s: float) -> dict[str, np.ndarray]:
    """``b2d_comfort_signals`` on a batch of chunks: ``a, f, r`` (..., n, 2),
    ``wz`` (..., n); returns (..., n) arrays."""
    n = wz.shape[-1]
    w = min(B2D_WINDOW, n)
    if not B2D_POLYORDER < w:
        raise ValueError(f"b2d comfort: needs >= {B2D_POLYORDER + 1} frames (SG order {B2D_POLYORDER}), got {n}")

    def sg(x, deriv=0):
        return savgol_filter(x, w, B2D_POLYORDER, deriv=deriv, delta=delta_s, mode="interp", axis=-1)

    yaw = sg(_phase_unwrap(wz))
    lon = sg((a * f).sum(-1))
    mag = sg(np.hypot(a[..., 0], a[..., 1]))
    return {
        "lon_acc": lon,
        "lat_acc": sg((a * r).sum(-1)),
        "magnitude_jerk": sg(mag, deriv=1),
        "lon_jerk": sg(lon, deriv=1),
        "yaw_acc": yaw,
        "yaw_rate": yaw,
    }


def chunk_checks(sig: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """{bound name: (...) bool} every frame of the chunk strictly inside (NaN fails)."""
    return {k: np.all((sig[k] > lo) & (sig[k] < hi), axis=-1) for k, lo, hi in B2D_BOUNDS}


def b2d_comfort_signals(accel_xy, forward_xy, right_xy, yaw_rate, *,
                        delta_s: float = B2D_DELTA_S) -> dict[str, np.ndarray]:
    """B2D's smoothed signals of one chunk (``compute_comfort_metric``).

    lon/lat acc = 2-D acceleration . forward / right vector, magnitude = |2-D
    acc|, yaw rate phase-unwrapped; each Savitzky-Golay smoothed (window
    min(7, n), order 2); jerks = SG first derivative (spacing ``delta_s``) of
    the *smoothed* lon acc / magnitude; "yaw_acc" is just the smoothed yaw
    rate (B2D's quirk).

    Args:
      accel_xy: (n, 2|3) m/s^2, world-frame acceleration (z ignored).
      forward_xy, right_xy: (n, 2|3) unit vectors (z ignored).
      yaw_rate: (n,) angular velocity about z, in the unit the caller scores
        (CARLA gives deg/s; the bounds are meant as rad/s).
      delta_s: derivative spacing, s (B2D fixes 0.1).

    Returns:
      dict of (n,) arrays keyed as ``B2D_BOUNDS``.
    """
    wz = np.asarray(yaw_rate, dtype=np.float64).reshape(-1)
    n = len(wz)
    a, f, r = (_xy(k, v, n) for k, v in (("accel_xy", accel_xy), ("forward_xy", forward_xy), ("right_xy", right_xy)))
    return chunk_signals(a, f, r, wz, delta_s)


def b2d_comfort_checks(accel_xy, forward_xy, right_xy, yaw_rate, *, delta_s: float = B2D_DELTA_S) -> dict[str, bool]:
    """Which of B2D's six bounds hold (strictly, at every frame) for one chunk.

    Args: as ``b2d_comfort_signals``.

    Returns:
      {signal name: bool}; the chunk passes iff all are True (NaN fails).
    """
    sig = b2d_comfort_signals(accel_xy, forward_xy, right_xy, yaw_rate, delta_s=delta_s)
    return {k: bool(v) for k, v in chunk_checks(sig).items()}


def b2d_route_smoothness(accel_xy, forward_xy, right_xy, yaw_rate, *, chunk: int = B2D_CHUNK,
                         delta_s: float = B2D_DELTA_S) -> float:
    """B2D smoothness of one route (``seg_compute_comfort_metric``).

    Routes with <= ``chunk`` frames are judged whole (1.0 or 0.0); longer ones
    are cut into chunks of ``chunk`` frames, a trailing partial chunk is
    dropped, and the value is the fraction of chunks passing every bound.
    All chunks are filtered at once (one batched Savitzky-Golay pass).

    Args:
      accel_xy, forward_xy, right_xy: (n, 2|3), see ``b2d_comfort_signals``.
      yaw_rate: (n,).
      chunk: frames per chunk (B2D: 20).
      delta_s: derivative spacing, s.

    Returns:
      fraction in [0, 1]. Raises ValueError for n < 3 (B2D raises too).
    """
    wz = np.asarray(yaw_rate, dtype=np.float64).reshape(-1)
    n = len(wz)
    a, f, r = (_xy(k, v, n) for k, v in (("accel_xy", accel_xy), ("forward_xy", forward_xy), ("right_xy", right_xy)))
    m = n if n <= chunk else (n // chunk) * chunk
    c = 1 if n <= chunk else n // chunk
    cut = lambda x: x[:m].reshape((c, m // c) + x.shape[1:])  # noqa: E731 - (chunks, frames, ...)
    sig = chunk_signals(cut(a), cut(f), cut(r), cut(wz), delta_s)
    passed = np.logical_and.reduce(list(chunk_checks(sig).values()))
    return float(passed.mean())


def b2d_smoothness(route_values: Sequence[float]) -> float:
    """B2D driving smoothness: mean of the per-route values (NaN for no
    routes, where B2D divides by zero)."""
    v = [float(x) for x in route_values]
    return sum(v) / len(v) if v else float("nan")


def b2d_frames_from_episode(xy, yaw_rad, speed_mps, dt_s: float, *,
                            carla_deg_per_s: bool = False) -> dict[str, np.ndarray]:
    """A simulated episode as B2D's per-frame signals (one frame per step).

    velocity = speed * [cos yaw, sin yaw]; 2-D acceleration and yaw rate are
    its / the unwrapped yaw's finite differences (``np.gradient``: central
    inside, one-sided at the ends; zeros for a 1-step episode). Forward =
    [cos, sin], right = [sin, -cos] (right of travel with yaw counter-clockwise
    from +x; only the sign of lat acc depends on it and its bound is
    symmetric).

    Args:
      xy: (T, 2) m (kept as ``location``; B2D records but never uses it).
      yaw_rad: (T,) rad.
      speed_mps: (T,) m/s.
      dt_s: step, s.
      carla_deg_per_s: give the yaw rate in deg/s as CARLA's angular velocity
        (reproduces B2D literally, whose rad/s bounds then bind at 0.95 deg/s);
        default rad/s, the unit the bounds are meant in.

    Returns:
      ``location`` (T, 2), ``accel_xy`` (T, 2) m/s^2, ``forward_xy``,
      ``right_xy`` (T, 2), ``yaw_rate`` (T,) rad/s (deg/s if asked).
    """
    p = np.asarray(xy, dtype=np.float64)
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    v = np.asarray(speed_mps, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or yaw.shape != (len(p),) or v.shape != (len(p),) or len(p) == 0:
        raise ValueError(f"b2d_frames_from_episode: need xy (T, 2), yaw (T,), speed (T,) with T >= 1, "
                         f"got {p.shape}, {yaw.shape}, {v.shape}")
    if not dt_s > 0:
        raise ValueError(f"b2d_frames_from_episode: dt_s must be > 0, got {dt_s}")
    fwd = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)
    if len(p) > 1:
        accel = np.gradient(v[:, None] * fwd, dt_s, axis=0)
        rate = np.gradient(np.unwrap(yaw), dt_s)
    else:
        accel, rate = np.zeros((1, 2)), np.zeros(1)
    return {
        "location": p,
        "accel_xy": accel,
        "forward_xy": fwd,
        "right_xy": np.stack([fwd[:, 1], -fwd[:, 0]], axis=-1),
        "yaw_rate": np.degrees(rate) if carla_deg_per_s else rate,
    }


__all__ = [
    "B2D_BOUNDS",
    "b2d_comfort_checks",
    "b2d_comfort_signals",
    "b2d_frames_from_episode",
    "b2d_route_smoothness",
    "b2d_smoothness",
    "chunk_checks",
    "chunk_signals",
]
