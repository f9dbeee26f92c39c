"""Pooling the bit-packed BEV: unpack-to-float vs ``bev.pool_bits`` (never a unit test).

    python experiments/perf/bev_pool.py

B = 128 random (128, 128) words with 14 channel bits, each pooled into 8 x 8
cells per channel (the ``run.py`` MLP policy's BEV features) inside a
``lax.scan`` of 25 steps; prints process CPU microseconds per scenario-step
(best of 3) for ``float`` (``unpack_bits`` then mean), ``int`` (per-bit
integer sums), ``pool_bits`` (SWAR counting) and ``read`` (each word read
once: the floor), and checks that ``pool_bits`` equals the float pooling.
"""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax.observe.bev import pool_bits, unpack_bits

B, S, C = 128, 25, 14


def f_float(w):
    img = unpack_bits(w, C)
    h, ww, c = img.shape
    return img.reshape(8, h // 8, 8, ww // 8, c).mean(axis=(1, 3)).reshape(-1)


def f_int(w):
    x = w.reshape(8, 16, 8, 16)
    return (((x[..., None] >> jnp.arange(C, dtype=jnp.int32)) & 1).sum(axis=(1, 3)) / 256.0).reshape(-1)


def f_pool_bits(w):
    return pool_bits(w, C, 16, 16).reshape(-1)


def f_read(w):
    return w.astype(jnp.float32).reshape(-1)


def main():
    words = jnp.asarray(np.random.default_rng(0).integers(0, 2**C, (B, 128, 128)).astype(np.int32))
    for name, fn in [("float", f_float), ("int", f_int), ("pool_bits", f_pool_bits), ("read", f_read)]:
        def run(ws, fn=fn):
            def body(acc, i):
                return acc + jnp.sum(jax.vmap(fn)(ws + i)), None
            return jax.lax.scan(body, jnp.zeros(()), jnp.arange(S))[0]

        compiled = jax.jit(run).lower(words).compile()
        compiled(words).block_until_ready()
        best = float("inf")
        for _ in range(3):
            c0 = time.process_time()
            compiled(words).block_until_ready()
            best = min(best, time.process_time() - c0)
        print(f"{name:>10} {best / (B * S) * 1e6:8.1f} CPU-us per scenario-step  load {os.getloadavg()[0]:.2f}")
    a = jax.jit(jax.vmap(f_float))(words)
    b = jax.jit(jax.vmap(f_pool_bits))(words)
    print("pool_bits == float pooling:", bool(jnp.allclose(a, b)))


if __name__ == "__main__":
    main()
