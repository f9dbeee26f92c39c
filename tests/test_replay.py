"""replay.py: log interpolation at continuous time, validity, signals."""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import replay
from drivee2e_jax.types import Signals, Tracks

DT = jnp.float32(0.1)
A, T = 3, 6


def _tracks() -> Tracks:
    """Agent 0: moves +x at 10 m/s, yaw 179 deg -> -179 deg -> ... (wrapping).
    Agent 1: valid on steps 1..3 only, garbage elsewhere. Agent 2: padding."""
    k = np.arange(T, dtype=np.float32)
    xy = np.full((A, T, 2), 1e4, np.float32)
    xy[0, :, 0], xy[0, :, 1] = 10.0 * k * 0.1, 2.0
    xy[1, :, 0], xy[1, :, 1] = 5.0, k
    yaw = np.full((A, T), 9.0, np.float32)
    yaw[0] = np.deg2rad(179.0 + 2.0 * k)  # crosses 180 deg between steps 0 and 1
    yaw[0] = np.angle(np.exp(1j * yaw[0]))
    yaw[1] = 0.5
    vel = np.zeros((A, T, 2), np.float32)
    vel[0, :, 0] = 10.0 + k  # accelerating
    valid = np.zeros((A, T), bool)
    valid[0] = True
    valid[1, 1:4] = True
    return Tracks(
        xy=jnp.asarray(xy), yaw=jnp.asarray(yaw), vel=jnp.asarray(vel),
        size=jnp.ones((A, 3)), category=jnp.zeros(A, jnp.int32), valid=jnp.asarray(valid),
        visible=jnp.asarray(valid), quality=jnp.asarray(valid), track_id=jnp.arange(A, dtype=jnp.int32),
    )


_agents_at = jax.jit(replay.agents_at)


def test_exact_at_samples_with_float_noise():
    tracks = _tracks()
    for k in range(T):
        for t in (np.float32(k * 0.1), np.float32(k * 0.1) + np.float32(1e-7), np.float32(k * 0.1) - np.float32(1e-7)):
            s = _agents_at(tracks, jnp.float32(t), DT)
            np.testing.assert_array_equal(s.xy[0], tracks.xy[0, k])  # bit-exact
            np.testing.assert_array_equal(s.vel[0], tracks.vel[0, k])
            np.testing.assert_allclose(s.yaw[0], tracks.yaw[0, k], atol=1e-7)
            np.testing.assert_array_equal(s.valid, tracks.valid[:, k])
    # 0.30000001 with dt 0.1 is sample 3 (valid for agent 1) — both spellings.
    s = _agents_at(tracks, jnp.float32(0.30000001), jnp.float32(0.1))
    assert bool(s.valid[1])
    np.testing.assert_array_equal(s.xy[1], tracks.xy[1, 3])


def test_midpoint_interpolation_and_yaw_wrap():
    tracks = _tracks()
    s = _agents_at(tracks, jnp.float32(0.05), DT)
    np.testing.assert_allclose(s.xy[0], [0.5, 2.0], atol=1e-6)
    np.testing.assert_allclose(s.vel[0], [10.5, 0.0], atol=1e-6)
    # 179 deg -> -179 deg interpolates through 180 deg, not through 0.
    np.testing.assert_allclose(abs(float(s.yaw[0])), math.pi, atol=1e-5)
    s = _agents_at(tracks, jnp.float32(0.025), DT)
    np.testing.assert_allclose(float(s.yaw[0]), np.deg2rad(179.5), atol=1e-5)
    s = _agents_at(tracks, jnp.float32(0.075), DT)
    np.testing.assert_allclose(float(s.yaw[0]), np.deg2rad(-179.5), atol=1e-5)
    assert bool(jnp.all((s.yaw > -math.pi) & (s.yaw <= math.pi)))


def test_validity_edges():
    tracks = _tracks()
    at = lambda t: np.asarray(_agents_at(tracks, jnp.float32(t), DT).valid)
    np.testing.assert_array_equal(at(0.05), [True, False, False])  # agent 1 needs step 0
    np.testing.assert_array_equal(at(0.1), [True, True, False])  # exactly its first sample
    np.testing.assert_array_equal(at(0.25), [True, True, False])
    np.testing.assert_array_equal(at(0.3), [True, True, False])  # its last sample
    np.testing.assert_array_equal(at(0.35), [True, False, False])
    np.testing.assert_array_equal(at(0.5), [True, False, False])  # end of the log
    np.testing.assert_array_equal(at(0.5 + 1e-7), [True, False, False])
    np.testing.assert_array_equal(at(0.51), [False, False, False])
    np.testing.assert_array_equal(at(-0.01), [False, False, False])
    # A float32-accumulated time a little short of agent 1's last sample
    # (t += 0.05 drifts ~3e-3 steps over 800 steps) still finds it valid.
    np.testing.assert_array_equal(at(np.float32(0.3) - np.float32(3e-4)), [True, True, False])
    np.testing.assert_array_equal(at(np.float32(0.1) - np.float32(3e-4)), [True, True, False])
    np.testing.assert_array_equal(at(0.098), [True, False, False])
    # Invalid neighbours never leak garbage (1e4) into the values.
    s = _agents_at(tracks, jnp.float32(0.35), DT)
    np.testing.assert_allclose(s.xy[1], tracks.xy[1, 3])
    assert bool(jnp.all(jnp.abs(s.xy[:2]) < 1e4))


def test_values_continuous_across_snap_band():
    tracks = _tracks()
    times = jnp.float32(0.2) + jnp.linspace(-0.003, 0.003, 61, dtype=jnp.float32)
    xs = jax.vmap(lambda t: _agents_at(tracks, t, DT).xy[0, 0])(times)
    np.testing.assert_allclose(xs, 10.0 * times, atol=2e-5)  # no jump where the snaps switch


def test_sim_dt_finer_than_log():
    tracks = _tracks()
    times = jnp.arange(11, dtype=jnp.float32) * jnp.float32(0.05)  # sim at 20 Hz
    states = jax.jit(jax.vmap(replay.agents_at, (None, 0, None)))(tracks, times, DT)
    chex.assert_shape(states.xy, (11, A, 2))
    np.testing.assert_allclose(states.xy[:, 0, 0], 10.0 * times, atol=1e-5)
    assert bool(jnp.all(states.valid[:, 0]))


def test_gradients_finite():
    tracks = _tracks()

    def f(t, xy, yaw):
        s = replay.agents_at(tracks.replace(xy=xy, yaw=yaw), t, DT)
        return jnp.sum(jnp.where(s.valid[:, None], s.xy, 0.0)) + jnp.sum(jnp.where(s.valid, s.yaw, 0.0))

    g = jax.jit(jax.grad(f, argnums=(0, 1, 2)))
    for t in (0.0, 0.05, 0.1, 0.30000001, 0.37, 0.5, 0.7):
        for leaf in g(jnp.float32(t), tracks.xy, tracks.yaw):
            assert bool(jnp.all(jnp.isfinite(leaf))), t
    # d x / d t = 10 m/s for agent 0, also exactly on a sample.
    dx = jax.grad(lambda t: replay.agents_at(tracks, t, DT).xy[0, 0])
    for t in (0.05, 0.2, 0.2 + 1e-7):
        np.testing.assert_allclose(dx(jnp.float32(t)), 10.0, rtol=1e-4)
    gxy = g(jnp.float32(0.025), tracks.xy, tracks.yaw)[1]
    np.testing.assert_allclose(gxy[0, :2, 0], [0.75, 0.25], atol=1e-5)


def test_ego_log_at():
    tracks = _tracks()
    s = jax.jit(replay.ego_log_at)(tracks, jnp.int32(0), jnp.float32(0.15), DT)
    chex.assert_shape([s.xy, s.vel], (2,))
    chex.assert_shape([s.yaw, s.valid], ())
    full = replay.agents_at(tracks, jnp.float32(0.15), DT)
    np.testing.assert_allclose(s.xy, full.xy[0], atol=1e-6)


def test_signals_piecewise_constant():
    state = jnp.array([[0, 1, 1, 2, 3], [3, 3, 1, 1, 1]], jnp.int32)
    sig = Signals(state=state)
    f = jax.jit(replay.signals_at)
    expect = {0.0: [0, 3], 0.05: [0, 3], 0.098: [0, 3],
              0.0995: [1, 3],  # within SNAP (1e-2 steps) of sample 1: accumulated-t drift
              0.1: [1, 3], 0.30000001: [2, 1], 0.29999999: [2, 1], 0.35: [2, 1], 0.4: [3, 1], 7.0: [3, 1], -1.0: [0, 3]}
    for t, want in expect.items():
        got = f(sig, jnp.float32(t), DT)
        chex.assert_type(got, jnp.int32)
        np.testing.assert_array_equal(got, want, err_msg=str(t))


def test_single_step_log():
    tracks = jax.tree_util.tree_map(lambda x: x[:, :1] if x.ndim >= 2 and x.shape[1] == T else x, _tracks())
    s = replay.agents_at(tracks, jnp.float32(0.0), DT)
    np.testing.assert_array_equal(s.valid, [True, False, False])
    assert not bool(replay.agents_at(tracks, jnp.float32(0.05), DT).valid[0])
