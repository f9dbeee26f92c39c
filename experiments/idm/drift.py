"""How far the IDM agents (``--agents idm``) drift from their logs.

The ego REPLAYS its log (its logged box is the ego box), every moving logged
vehicle follows ``drivee2e_jax.reactive``; the error is the distance of each
reactive agent from its logged position, over the valid reactive
agent-steps. A faithful reactive model drifts only where the ego or another
agent really stands in an agent's way; large drifts with the ego on its log
point to false leaders.

    python experiments/idm/drift.py [--suite twin15] [--split val] [--steps 200] [--limit N] [--worst 5]
        [--time-headway 2.0] [--lateral-margin 0.5]

Prints mean / median / p90 / p99 / max (m), the lagging fraction and the
scenarios with the largest drift (scenario, agent row, step, error).
"""

from __future__ import annotations

import argparse
import functools
import time

import jax
import numpy as np

from drivee2e_jax import reactive
from drivee2e_jax.scenario import load_suite


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--suite", default="twin15")
    ap.add_argument("--split", default="val")
    ap.add_argument("--steps", type=int, default=200, help="simulator steps (dt 0.1 s)")
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--chunk", type=int, default=50, help="scenarios per compiled call")
    ap.add_argument("--worst", type=int, default=5)
    ap.add_argument("--time-headway", type=float, default=reactive.IDMParams.time_headway, help="IDM T, s")
    ap.add_argument("--lateral-margin", type=float, default=reactive.IDMParams.lateral_margin,
                    help="m added to the agent's half width when looking for a leader")
    args = ap.parse_args(argv)

    packed = load_suite(args.suite).pack(args.split)
    n = min(len(packed), args.limit or len(packed))
    params = reactive.IDMParams(time_headway=args.time_headway, lateral_margin=args.lateral_margin)
    fn = jax.jit(jax.vmap(functools.partial(reactive.drift_errors, dt=0.1, num_steps=args.steps, params=params)))
    errs, masks, lags = [], [], []
    start = time.perf_counter()
    for lo in range(0, n, args.chunk):
        rows = np.arange(lo, min(lo + args.chunk, n))
        part = packed.select(rows)
        if len(rows) < args.chunk:  # one compiled shape: pad with the first row
            part = packed.select(np.concatenate([rows, np.full(args.chunk - len(rows), rows[0])]))
        e, m, g = jax.device_get(fn(part.to_jax()))
        errs.append(e[: len(rows)]), masks.append(m[: len(rows)]), lags.append(g[: len(rows)])
    err, mask, lag = (np.concatenate(x) for x in (errs, masks, lags))  # (S, N, A)
    vals = err[mask]
    print(f"{args.suite} {args.split}: {n} scenarios x {args.steps} steps, {vals.size:,} reactive agent-steps "
          f"({time.perf_counter() - start:.0f} s)")
    q = np.percentile(vals, [50, 90, 99])
    print(f"drift m: mean {vals.mean():.3f}  median {q[0]:.3f}  p90 {q[1]:.2f}  p99 {q[2]:.2f}  max {vals.max():.1f}  "
          f"lagging {100 * (lag & mask).sum() / max(mask.sum(), 1):.1f} % of agent-steps")
    ids = list(packed.meta.scenario_id[:n])
    worst = np.argsort(err.max(axis=(1, 2)))[::-1][: args.worst]
    for s in worst:
        k, a = np.unravel_index(np.argmax(err[s]), err[s].shape)
        print(f"  {ids[s]}: {err[s].max():6.1f} m (agent row {a}, step {k}); scenario mean {err[s][mask[s]].mean():.2f} m")


if __name__ == "__main__":
    main()
