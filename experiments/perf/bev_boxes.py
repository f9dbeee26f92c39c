"""Where the BEV's box drawing goes: the route (never a unit test).

    python experiments/perf/bev_boxes.py
    python experiments/perf/bev_boxes.py --batch 64 --reps 50

B smooth routes of 96 points 1 m apart through the view (the rollout's route
window), drawn as ``BevConfig()``'s 47 route boxes (every 2nd point) under
``jit(vmap(...))``. Prints process CPU microseconds per scenario (best of
``--reps``) for the whole ``draw_route`` and for its pieces: the row spans,
the spans + 32-column word masks + OR over boxes, the per-pixel unpack, the
masks and the OR (one reduction, and the log-depth tree it replaced) from
given inputs, and masks + OR with and without
``xla_cpu.materialize`` on the masks (as ``bev._draw_boxes_bits`` does).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax.observe import bev

CFG = bev.BevConfig()


def _masks(first, last):
    """``bev.span_masks`` of every box (the route's boxes are all drawn)."""
    return bev.span_masks(first, last, jnp.ones(first.shape[:1], bool), CFG.width)


def _or(m):
    """The OR over boxes of (NW, N, H) masks, as ``bev._draw_boxes_bits`` does it."""
    return jax.lax.reduce(m, jnp.uint32(0), jax.lax.bitwise_or, (1,))


def _or_tree(m):
    """The same as a log-depth tree of elementwise ORs (the code before 2026-11-28)."""
    m = jnp.moveaxis(m, 1, 0)
    while m.shape[0] > 1:
        if m.shape[0] % 2:
            m = jnp.concatenate([m, jnp.zeros_like(m[:1])])
        m = m[: m.shape[0] // 2] | m[m.shape[0] // 2:]
    return m[0]


def _spans(ego_xy, ego_yaw, route_xy):
    xy, yaw, lw, _ = bev.route_boxes(ego_xy, ego_yaw, route_xy, jnp.ones(route_xy.shape[:1], bool), CFG)
    return bev.box_row_spans(xy, jnp.cos(yaw), jnp.sin(yaw), 0.5 * lw, CFG)


def _unpack(planes):
    bit = jnp.arange(32, dtype=jnp.uint32)
    return ((planes.T[:, :, None] >> bit) & 1).astype(jnp.int32).reshape(CFG.height, CFG.width)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--reps", type=int, default=20)
    args = ap.parse_args()
    b = args.batch
    rng = np.random.default_rng(0)
    t = np.arange(CFG.route_points, dtype=np.float32) - CFG.route_behind
    ang = rng.uniform(-0.03, 0.03, (b, 1)).astype(np.float32) * t
    route = np.stack([np.cumsum(np.cos(ang), 1), np.cumsum(np.sin(ang), 1)], -1).astype(np.float32) - CFG.route_behind
    ego_xy = rng.uniform(-1, 1, (b, 2)).astype(np.float32)
    ego_yaw = rng.uniform(-0.2, 0.2, b).astype(np.float32)
    valid = np.ones(route.shape[:2], bool)

    def cpu_us(f, *xs):
        f = jax.jit(jax.vmap(f))
        jax.block_until_ready(f(*xs))
        best = float("inf")
        for _ in range(args.reps):
            c = time.process_time()
            jax.block_until_ready(f(*xs))
            best = min(best, time.process_time() - c)
        return round(best / b * 1e6, 1)

    first, last = jax.jit(jax.vmap(_spans))(ego_xy, ego_yaw, route)
    masks = jax.jit(jax.vmap(_masks))(first, last)
    planes = jax.jit(jax.vmap(_or))(masks)
    row = {
        "draw_route": cpu_us(lambda e, y, r, v: bev.draw_route(e, y, r, v, CFG, packed=True), ego_xy, ego_yaw, route,
                             valid),
        "spans": cpu_us(lambda e, y, r: sum(x.sum() for x in _spans(e, y, r)), ego_xy, ego_yaw, route),
        "spans_masks_or": cpu_us(lambda e, y, r: _or(bev._materialize(_masks(*_spans(e, y, r)))), ego_xy, ego_yaw,
                                 route),
        "unpack": cpu_us(_unpack, planes),
        "masks_from_spans": cpu_us(_masks, first, last),
        "or_from_masks": cpu_us(_or, masks),
        "or_tree_from_masks": cpu_us(_or_tree, masks),
        "masks_or_materialised": cpu_us(lambda lo, hi: _or(bev._materialize(_masks(lo, hi))), first, last),
        "masks_or_not_materialised": cpu_us(lambda lo, hi: _or(_masks(lo, hi)), first, last),
        "batch": b,
        "boxes": int(first.shape[1]),
        "load_avg_1min": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(row))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
