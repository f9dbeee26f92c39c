"""BEV raster micro-benchmark (never a unit test).

    python experiments/perf/bev.py                 # twin15 maps, readable table
    python experiments/perf/bev.py --quick         # tiny test maps, fewer configs
    python experiments/perf/bev.py --json          # one JSON object per line

Measures ``render_bev`` under ``jit(vmap(...))`` inside a ``lax.scan`` over
``--steps`` steps (as the rollout runs it: XLA reuses the step's buffers, so
no per-call allocation of the (B, H, W, C) output is timed), for both outputs:
``packed`` (``render_bev_packed``, (H, W) int32) and ``float``
(``render_bev``, (H, W, C) float32). Each step moves
every ego, renders the BEV of all B scenarios and sums every output element
(the stand-in consumer). Scenes: ego poses on random drivable-area points of
the maps, A = 2K agents (all eight categories, realistic sizes) scattered within 40 m, 64 route
points ahead. Reports compile seconds, scenario-steps/s, microseconds per
scenario-step (wall, best of ``--reps``), CPU microseconds per scenario-step
(process CPU time over all threads: less sensitive to other load), the
1-minute load average and ``os.cpu_count()``. On a shared machine the wall
numbers are noisy: run it alone when you can.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
SIZES = {0: (4.5, 1.9), 1: (9.0, 2.5), 2: (12.0, 2.6), 3: (5.0, 2.0), 4: (2.1, 0.8), 5: (2.5, 1.2),
         6: (0.6, 0.6), 7: (1.8, 0.7)}


def _maps(quick: bool):
    if quick:
        sys.path.insert(0, str(ROOT))
        from tests.helpers.tiny_suite import build_tiny_suite

        return build_tiny_suite().maps
    import drivee2e_jax as de

    return de.load_suite("twin15").records.maps


def _scenes(table, maps, batch: int, agents: int, route_points: int, seed: int = 0):
    import shapely

    rng = np.random.default_rng(seed)
    records = [maps[mid] for mid in table.map_ids]
    mi = rng.integers(0, len(records), batch)
    ego = np.zeros((batch, 2))
    for b, m in enumerate(mi):
        area = shapely.union_all([shapely.Polygon(p) for p in records[m].drivable_areas])
        lo, hi = np.array(area.bounds[:2]), np.array(area.bounds[2:])
        while True:
            p = rng.uniform(lo, hi)
            if area.contains(shapely.Point(p)):
                ego[b] = p
                break
    yaw = rng.uniform(-np.pi, np.pi, batch)
    axy = ego[:, None] + rng.uniform(-40, 40, (batch, agents, 2))
    cat = rng.integers(0, 8, (batch, agents))
    size = np.array([SIZES[int(c)] + (1.5,) for c in cat.ravel()]).reshape(batch, agents, 3)
    fwd = np.stack([np.cos(yaw), np.sin(yaw)], -1)
    route = ego[:, None] + fwd[:, None] * np.arange(route_points)[None, :, None]
    f32 = np.float32
    return dict(ego_xy=ego.astype(f32), ego_yaw=yaw.astype(f32), agents_xy=axy.astype(f32),
                agents_yaw=rng.uniform(-np.pi, np.pi, (batch, agents)).astype(f32),
                agents_size=size.astype(f32), agents_category=cat.astype(np.int32),
                agents_valid=rng.random((batch, agents)) < 0.9,
                stop_state=rng.integers(0, 4, (batch, 32)).astype(np.int32),
                route_xy=route.astype(f32), route_valid=np.ones((batch, route_points), bool),
                map_index=mi.astype(np.int32))


def measure(table, maps, batch: int, size: int, k: int, steps: int, reps: int, channels=None,
            output: str = "float", overrides: dict | None = None) -> dict:
    import jax
    import jax.numpy as jnp

    from drivee2e_jax.observe.bev import BevConfig, render_bev, render_bev_packed

    render = render_bev if output == "float" else render_bev_packed
    kw = {} if channels is None else {"channels": tuple(channels)}
    cfg = BevConfig(height=size, width=size, num_agents=k, **kw, **(overrides or {}))
    scenes = {n: jnp.asarray(v) for n, v in _scenes(table, maps, batch, 2 * k, 64).items()}
    tab = jax.device_put(table)

    def one(s, shift):
        return render(**{**s, "ego_xy": s["ego_xy"] + shift, "route_xy": s["route_xy"] + shift},
                          ego_lw=jnp.array([4.5, 1.9]), table=tab, cfg=cfg)

    @jax.jit
    def run(s):
        def step(acc, i):
            bev = jax.vmap(one, in_axes=(0, None))(s, 0.5 * i)
            # Read EVERY output element (a strided sample would let XLA skip
            # most of the work; a barrier is stripped by XLA:CPU).
            return acc + bev.sum().astype(jnp.float32), None

        return jax.lax.scan(step, jnp.zeros(()), jnp.arange(steps, dtype=jnp.float32))[0]

    t0 = time.perf_counter()
    compiled = run.lower(scenes).compile()
    compile_s = time.perf_counter() - t0
    compiled(scenes).block_until_ready()
    best = best_cpu = np.inf
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        compiled(scenes).block_until_ready()
        best = min(best, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    n = batch * steps
    return {"bench": "bev", "output": output, "batch": batch, "size": f"{size}x{size}", "k": k,
            "channels": len(cfg.channel_names),
            "steps": steps, "compile_s": round(compile_s, 2), "scenario_steps_per_s": round(n / best, 1),
            "us_per_scenario_step": round(best / n * 1e6, 1),
            "cpu_us_per_scenario_step": round(best_cpu / n * 1e6, 1), "cpu_count": os.cpu_count(),
            "load_avg_1min": round(os.getloadavg()[0], 2)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="tiny test maps, B=64, sizes 64/128, K 16/32")
    ap.add_argument("--json", action="store_true", help="one JSON object per line")
    ap.add_argument("--batch", type=int, nargs="*", default=None)
    ap.add_argument("--size", type=int, nargs="*", default=None)
    ap.add_argument("--k", type=int, nargs="*", default=None)
    ap.add_argument("--steps", type=int, default=10, help="scan steps per timed call")
    ap.add_argument("--reps", type=int, default=3, help="timed calls (best is reported)")
    ap.add_argument("--channels", nargs="*", default=None, help="BEV channel subset (default: all defaults)")
    ap.add_argument("--output", nargs="*", default=["packed", "float"], choices=["packed", "float"],
                    help="render_bev_packed (H, W) int32 and/or render_bev (H, W, C) float32")
    ap.add_argument("--set", nargs="*", default=[], metavar="FIELD=INT",
                    help="BevConfig integer overrides, e.g. tile=4 agents_per_tile=2")
    args = ap.parse_args(argv)
    overrides = {kv.split("=")[0]: int(kv.split("=")[1]) for kv in args.set}
    batches = args.batch or ([64] if args.quick else [64, 800])
    sizes = args.size or ([64, 128] if args.quick else [64, 128, 256])
    ks = args.k or ([16, 32] if args.quick else [16, 32, 64])

    from drivee2e_jax.observe.raster import rasterize_maps

    maps = _maps(args.quick)
    t0 = time.perf_counter()
    table = rasterize_maps(maps)
    raster_s = time.perf_counter() - t0
    if not args.json:
        print(f"rasterised {len(table.map_ids)} maps in {raster_s:.1f} s: table {table.words.shape} "
              f"{table.nbytes / 2**20:.1f} MiB; cpu_count={os.cpu_count()}")
        print(f"{'output':>7} {'B':>5} {'size':>8} {'K':>3} {'C':>3} {'compile s':>9} {'steps/s':>10} "
              f"{'us/scen-step':>12} "
              f"{'cpu us':>8} {'load':>5}")
    grid = [(b, size, k, out) for b in batches for size in sizes for k in ks for out in args.output]
    for b, size, k, output in grid:
        row = measure(table, maps, b, size, k, args.steps, args.reps, args.channels, output, overrides)
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print(f"{output:>7} {b:>5} {row['size']:>8} {k:>3} {row['channels']:>3} {row['compile_s']:>9} "
                  f"{row['scenario_steps_per_s']:>10} {row['us_per_scenario_step']:>12} "
                  f"{row['cpu_us_per_scenario_step']:>8} {row['load_avg_1min']:>5}", flush=True)

if __name__ == "__main__":
    main()
