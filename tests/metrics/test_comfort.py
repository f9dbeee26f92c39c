"""Bench2Drive smoothness: B2D-03 through the project's
functions, smoothed signals pinned on a fixed drive (recorded before the
project's own Savitzky-Golay copy gave way to ``scipy.signal.savgol_filter``),
the chunk pipeline against a transcription of B2D's scipy code, and simulated
drives.

``check_b2d03`` takes the case dict; it lives in
``tests/helpers/metric_cases/comfort.py``, shared with the case runner.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.metrics.comfort import (
    b2d_comfort_checks,
    b2d_comfort_signals,
    b2d_frames_from_episode,
    b2d_route_smoothness,
    b2d_smoothness,
)
from tests.helpers.metric_cases import subset_case
from tests.helpers.metric_cases.comfort import B2D03_ROUTES, check_b2d03, frames


def test_b2d03_shared_case():
    check_b2d03(subset_case("B2D-03"))


def test_b2d03_values_without_shared_file():
    got = [b2d_route_smoothness(*B2D03_ROUTES[r]()) for r in sorted(B2D03_ROUTES)]
    assert got == pytest.approx([1.0, 2 / 3, 1.0, 0.5, 0.0], abs=1e-12)
    assert b2d_smoothness(got) == pytest.approx(0.6333333333333333, abs=1e-12)
    # which bound fails: 3002's middle chunk on lon acc, 3004's first on yaw rate, 3005 on lat acc
    acc, f, r, wz = B2D03_ROUTES["3002"]()
    fails = [k for k, ok in b2d_comfort_checks(acc[20:40], f[20:40], r[20:40], wz[20:40]).items() if not ok]
    assert fails[0] == "lon_acc"
    acc, f, r, wz = B2D03_ROUTES["3004"]()
    fails = [k for k, ok in b2d_comfort_checks(acc[:20], f[:20], r[:20], wz[:20]).items() if not ok]
    assert fails == ["yaw_rate"]  # "yaw acc" is the smoothed rate: 1.2 < 1.93 never binds first
    assert [k for k, ok in b2d_comfort_checks(*B2D03_ROUTES["3005"]()).items() if not ok] == ["lat_acc"]


# ---------------------------------------------------------------------------
# Savitzky-Golay (scipy.signal.savgol_filter): outputs pinned before the switch
# ---------------------------------------------------------------------------


def fixed_drive(n=80):
    """A fixed, analytic 80-frame drive (0.1 s frames): weaving yaw, oscillating
    lon / lat acceleration with a slow ramp, a small fast yaw-rate ripple."""
    t = np.arange(n) * 0.1
    yaw = 0.4 * np.sin(0.7 * t)
    f = np.stack([np.cos(yaw), np.sin(yaw)], 1)
    r = np.stack([f[:, 1], -f[:, 0]], 1)
    acc = np.stack([2.5 * np.sin(1.3 * t) + 0.3 * t, 1.5 * np.cos(0.9 * t)], 1)
    wz = 0.28 * np.cos(0.7 * t) + 0.05 * np.sin(5.0 * t)
    return acc, f, r, wz


#: ``b2d_comfort_signals`` of ``fixed_drive()[:20]`` at frames 0, 2, 3, 10, 17, 19
#: (edges: mode "interp" polynomial fits; 10: interior window), recorded with the
#: project's own Savitzky-Golay copy before it was replaced by scipy's.
PINNED_20 = {
    "lon_acc": [-0.006733975956163721, 0.7905367164027292, 1.1570230518351858, 2.856659229880613,
                2.3710477343701895, 1.8843228948060695],
    "lat_acc": [-1.5026294686566404, -1.4313840999954266, -1.3536218691036317, -0.21143365059898178,
                0.8554516943338308, 0.9981727889051911],
    "magnitude_jerk": [0.647049447160957, 1.1697700619717715, 1.4311303693771784, 0.7321889877714285,
                       -1.6462632961750625, -2.2653500345304884],
    "lon_jerk": [4.238112012994426, 3.7839438419077207, 3.5568597563643682, 0.9016133067568006,
                 -2.0834119822095474, -2.8131863385216427],
    "yaw_rate": [0.27904262074714015, 0.31951955336867577, 0.3225090064614309, 0.16737213658297004,
                 0.14469842033047814, 0.061557444269273905],
}
#: The same for the first 5 frames only (window clipped to 5), every frame.
PINNED_5 = {
    "lon_acc": [-0.0014348198468321107, 0.39861788160553174, 0.7839042851155917, 1.1544243906833478,
                1.5101781983088],
    "lat_acc": [-1.5003797593742703, -1.4827065603728957, -1.434184896119951, -1.3548147666154362,
                -1.2445961718593517],
    "magnitude_jerk": [0.2246221663243183, 0.6913394304282227, 1.158056694532128, 1.624773958636034,
                       2.091491222739941],
    "lon_jerk": [4.0743585042351596, 3.9266955248121205, 3.779032545389081, 3.6313695659660423,
                 3.4837065865430055],
    "yaw_rate": [0.2793323452402981, 0.3046931154728616, 0.31911728132294515, 0.32260484279054874,
                 0.31515579987567244],
}


def test_smoothed_signals_equal_the_values_pinned_before_scipy():
    acc, f, r, wz = fixed_drive()
    sig = b2d_comfort_signals(acc[:20], f[:20], r[:20], wz[:20])
    for k, want in PINNED_20.items():
        np.testing.assert_allclose(sig[k][[0, 2, 3, 10, 17, 19]], want, rtol=1e-12, atol=1e-13, err_msg=k)
    np.testing.assert_array_equal(sig["yaw_acc"], sig["yaw_rate"])  # B2D's quirk
    sig = b2d_comfort_signals(acc[:5], f[:5], r[:5], wz[:5])
    for k, want in PINNED_5.items():
        np.testing.assert_allclose(sig[k], want, rtol=1e-12, atol=1e-13, err_msg=k)


def test_route_smoothness_and_failing_bounds_pinned_before_scipy():
    acc, f, r, wz = fixed_drive()
    assert b2d_route_smoothness(acc, f, r, wz) == 0.25  # 4 chunks, only frames 20..39 pass
    fails = [[k for k, ok in b2d_comfort_checks(acc[s:s + 20], f[s:s + 20], r[s:s + 20], wz[s:s + 20]).items()
              if not ok] for s in (0, 20, 40, 60)]
    assert fails == [["lon_acc", "lon_jerk"], [], ["lon_acc"], ["lon_acc"]]


def test_too_short_chunk_is_a_value_error():
    with pytest.raises(ValueError, match="frames"):
        b2d_comfort_signals(*(x[:2] for x in fixed_drive()))


# ---------------------------------------------------------------------------
# Chunk pipeline against B2D's own (scipy) code
# ---------------------------------------------------------------------------


def b2d_reference_signals(acc, ang, fwd, right):
    """Transcription of B2D 0.0.4 ``compute_comfort_metric`` (scipy savgol)."""
    from scipy.signal import savgol_filter as sg

    w = min(7, len(acc))
    a2, f2, r2 = acc[:, :2], fwd[:, :2], right[:, :2]
    z = ang[:, 2]
    adj = np.zeros_like(z)
    adj[1:] = np.cumsum(np.round(np.diff(z) / (2 * np.pi)))
    z = z - 2 * np.pi * adj
    lon = sg(np.einsum("ij,ij->i", a2, f2), polyorder=2, window_length=w)
    lat = sg(np.einsum("ij,ij->i", a2, r2), polyorder=2, window_length=w)
    mag = sg(np.hypot(a2[:, 0], a2[:, 1]), polyorder=2, window_length=w)
    yaw = sg(z, polyorder=2, window_length=w)
    return {
        "lon_acc": lon, "lat_acc": lat, "yaw_acc": yaw, "yaw_rate": yaw,
        "magnitude_jerk": sg(mag, polyorder=2, window_length=w, deriv=1, delta=0.1),
        "lon_jerk": sg(lon, polyorder=2, window_length=w, deriv=1, delta=0.1),
    }


@settings(max_examples=80, deadline=None)
@given(st.integers(3, 20), st.integers(0, 2**31 - 1), st.floats(0.1, 6.0))
def test_chunk_signals_equal_b2d_reference(n, seed, scale):
    pytest.importorskip("scipy.signal")
    rng = np.random.default_rng(seed)
    yaw = rng.uniform(-np.pi, np.pi, n)
    fwd = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(n)], 1)
    right = np.stack([-np.sin(yaw), np.cos(yaw), np.zeros(n)], 1)
    acc = np.c_[rng.normal(size=(n, 2)) * scale, np.zeros(n)]
    ang = np.c_[np.zeros((n, 2)), rng.normal(size=n) * scale * 2]  # large rates exercise the unwrap
    want = b2d_reference_signals(acc, ang, fwd, right)
    got = b2d_comfort_signals(acc, fwd, right, ang[:, 2])
    for k in want:
        np.testing.assert_allclose(got[k], want[k], rtol=1e-9, atol=1e-9, err_msg=k)


def test_yaw_rate_is_phase_unwrapped_like_b2d():
    acc, f, r, _ = frames(10)
    wz = np.where(np.arange(10) % 2, 0.1 + 2 * np.pi, 0.1)  # 2 pi jumps vanish
    sig = b2d_comfort_signals(acc, f, r, wz)
    np.testing.assert_allclose(sig["yaw_rate"], 0.1, atol=1e-12)


def test_short_routes_judged_whole_and_partial_chunk_dropped():
    acc, f, r, wz = frames(39, ax=(20, 38, -6.0))  # 39 frames: one chunk (0..19); 20..38 dropped
    assert b2d_route_smoothness(acc, f, r, wz) == 1.0
    acc, f, r, wz = frames(20, ax=(15, 19, -6.0))  # 20 frames: the whole route
    assert b2d_route_smoothness(acc, f, r, wz) == 0.0
    with pytest.raises(ValueError, match="frames"):
        b2d_route_smoothness(*frames(2))
    assert math.isnan(b2d_smoothness([]))


def test_bounds_are_strict():
    assert b2d_route_smoothness(*frames(20, ay=4.89)) == 0.0
    assert b2d_route_smoothness(*frames(20, ay=4.88)) == 1.0
    assert b2d_route_smoothness(*frames(20, yaw_rate=(0, 19, 0.95))) == 0.0
    assert b2d_route_smoothness(*frames(20, yaw_rate=(0, 19, 0.94))) == 1.0


# ---------------------------------------------------------------------------
# Simulated episodes
# ---------------------------------------------------------------------------


def episode(speed, yaw, dt=0.1):
    speed, yaw = np.asarray(speed, float), np.asarray(yaw, float)
    xy = np.cumsum(np.stack([speed * np.cos(yaw), speed * np.sin(yaw)], 1) * dt, axis=0)
    return b2d_frames_from_episode(xy, yaw, speed, dt)


def chunk_passes(fr, chunk=20):
    keys = ("accel_xy", "forward_xy", "right_xy", "yaw_rate")
    return [all(b2d_comfort_checks(*(fr[k][s : s + chunk] for k in keys)).values())
            for s in range(0, len(fr["yaw_rate"]) - chunk + 1, chunk)]


def test_straight_constant_speed_drive_passes_every_chunk():
    fr = episode(np.full(100, 12.0), np.full(100, 0.7))
    np.testing.assert_allclose(fr["accel_xy"], 0.0, atol=1e-12)
    np.testing.assert_allclose(fr["yaw_rate"], 0.0, atol=1e-12)
    assert chunk_passes(fr) == [True] * 5
    assert b2d_route_smoothness(fr["accel_xy"], fr["forward_xy"], fr["right_xy"], fr["yaw_rate"]) == 1.0


def test_harsh_brake_fails_its_chunks_only():
    n, dt = 100, 0.1
    v = np.full(n, 12.0)
    v[30:40] = 12.0 - 8.0 * dt * np.arange(1, 11)  # -8 m/s^2 over steps 30..39, reaching 4 m/s
    v[40:] = 4.0
    fr = episode(v, np.zeros(n), dt)
    assert fr["accel_xy"][31:39, 0] == pytest.approx(-8.0)
    assert chunk_passes(fr) == [True, False, True, True, True]  # the brake lies in chunk 1 (steps 20..39)
    v[40:45] = 4.0 - 0.8 * np.arange(1, 6)  # keep braking to 0 at step 44: now chunk 2 fails too
    v[45:] = 0.0
    assert chunk_passes(episode(v, np.zeros(n), dt)) == [True, False, False, True, True]
    checks = b2d_comfort_checks(*(fr[k][20:40] for k in ("accel_xy", "forward_xy", "right_xy", "yaw_rate")))
    assert not checks["lon_acc"] and not checks["lon_jerk"]


def test_constant_turn_yaw_rate_across_the_pi_seam():
    n = 60
    yaw = np.angle(np.exp(1j * (3.0 + 0.05 * np.arange(n))))  # wraps past +pi
    fr = episode(np.full(n, 5.0), yaw)
    np.testing.assert_allclose(fr["yaw_rate"], 0.5, atol=1e-9)
    # centripetal 5 m/s * 0.5 rad/s = 2.5 m/s^2 to the left: lat acc (right vector) = -2.5
    lat = (fr["accel_xy"][1:-1] * fr["right_xy"][1:-1]).sum(-1)
    np.testing.assert_allclose(lat, -2.5, rtol=2e-3)
    assert chunk_passes(fr) == [True] * 3
    deg = b2d_frames_from_episode(fr["location"], yaw, np.full(n, 5.0), 0.1, carla_deg_per_s=True)
    np.testing.assert_allclose(deg["yaw_rate"], np.degrees(0.5), atol=1e-7)
    assert chunk_passes(deg) == [False] * 3  # CARLA's deg/s against rad/s bounds


def test_frames_reject_bad_shapes():
    with pytest.raises(ValueError, match="b2d_frames_from_episode"):
        b2d_frames_from_episode(np.zeros((5, 2)), np.zeros(4), np.zeros(5), 0.1)
