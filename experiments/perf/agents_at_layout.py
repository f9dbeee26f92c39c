"""``replay.agents_at`` from agent-major (A, T) tracks against time-major (T, A) ones
(never a unit test): CPU ms of one call at B = 800 on random tracks, and of the transpose.

    python experiments/perf/agents_at_layout.py

docs/performance.md, "Map facts from the map's polygons" (re-measured 2026-11-29).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import replay


def bench(name, f, *args) -> None:
    g = jax.jit(jax.vmap(f))
    jax.block_until_ready(g(*args))
    best = float("inf")
    for _ in range(10):
        c0 = time.process_time()
        jax.block_until_ready(g(*args))
        best = min(best, time.process_time() - c0)
    print(f"{name:28s} {best * 1e3:8.2f} ms CPU", flush=True)


def main() -> None:
    b, a, t_len = 800, 104, 208
    rng = np.random.default_rng(0)
    xy = jnp.asarray(rng.normal(size=(b, a, t_len, 2)).astype(np.float32))
    yaw = jnp.asarray(rng.normal(size=(b, a, t_len)).astype(np.float32))
    vel = jnp.asarray(rng.normal(size=(b, a, t_len, 2)).astype(np.float32))
    valid = jnp.asarray(rng.random((b, a, t_len)) > 0.1)
    t = jnp.full((b,), 5.0, jnp.float32)

    def agent_major(xy, yaw, vel, valid, t):
        return jax.vmap(replay._interp_one, in_axes=(0, 0, 0, 0, None, None))(xy, yaw, vel, valid, t, 0.1)

    def time_major(xy_t, yaw_t, vel_t, valid_t, t):
        k, r, _, _, _ = replay._time_index(t, 0.1, xy_t.shape[0])
        two = lambda x: jax.lax.dynamic_slice_in_dim(x, k, 2, axis=0)  # noqa: E731
        x, y, v, ok = two(xy_t), two(yaw_t), two(vel_t), two(valid_t)
        return x[0] + r * (x[1] - x[0]), y[0] + r * (y[1] - y[0]), v[0] + r * (v[1] - v[0]), ok[0] & ok[1]

    def transpose(xy, yaw, vel, valid):
        return xy.transpose(1, 0, 2), yaw.T, vel.transpose(1, 0, 2), valid.T

    bench("agents_at, (A, T) tracks", agent_major, xy, yaw, vel, valid, t)
    bench("same from (T, A) tracks", time_major, *transpose(xy, yaw, vel, valid), t)
    bench("transpose (A, T) -> (T, A)", transpose, xy, yaw, vel, valid)


if __name__ == "__main__":
    main()
