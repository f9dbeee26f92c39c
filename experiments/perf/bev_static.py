"""The BEV's static-layer sampler alone: row-major vs tiled raster table (never a unit test).

    python experiments/perf/bev_static.py --batch 128 --steps 25 --reps 7

``bev.sample_static`` on the tiled ``RasterTable`` ("tiled") against the
sampler as committed before 2026-11-27 on the row-major words ("rowmajor",
``tests/observe/test_bev_static_rule._frozen``): ``jit(vmap)`` over ``--batch``
ego poses on random twin15 drivable points, ``lax.scan`` over ``--steps``
steps (each moves and turns every ego a little), the table passed as an
argument (as in the rollout). Checks that both read the same words, then
alternates the two ``--reps`` times; prints the best and median process
CPU-us (and best wall-us) per scenario-step and the 1-minute load.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--steps", type=int, default=25)
    ap.add_argument("--reps", type=int, default=7)
    args = ap.parse_args(argv)

    import jax
    import jax.numpy as jnp
    import numpy as np
    from bev import _maps, _scenes

    from drivee2e_jax.observe.bev import BevConfig, sample_static
    from drivee2e_jax.observe.raster import rasterize_maps
    from tests.observe.test_bev_static_rule import _frozen

    maps = _maps(False)
    tiled = rasterize_maps(maps)
    rowmajor = tiled.replace(words=tiled.pixels())
    sc = _scenes(tiled, maps, args.batch, 4, 8)
    cfg = BevConfig()
    poses = tuple(jnp.asarray(sc[k]) for k in ("ego_xy", "ego_yaw", "map_index"))
    variants = {"rowmajor": (_frozen, jax.device_put(rowmajor)), "tiled": (sample_static, jax.device_put(tiled))}

    def program(f):
        def run(exy, eyaw, mi, tab):
            def step(acc, i):
                w = jax.vmap(lambda a, b, c: f(a + 0.5 * i, b + 0.01 * i, tab, c, cfg))(exy, eyaw, mi)
                return acc + jnp.sum(w), None
            return jax.lax.scan(step, jnp.zeros((), jnp.int32), jnp.arange(args.steps, dtype=jnp.float32))[0]
        return run

    compiled, words = {}, {}
    for name, (f, tab) in variants.items():
        compiled[name] = jax.jit(program(f)).lower(*poses, tab).compile()
        words[name] = np.asarray(jax.jit(jax.vmap(lambda a, b, c, t, f=f: f(a, b, t, c, cfg),
                                                  in_axes=(0, 0, 0, None)))(*poses, tab))
    assert (words["rowmajor"] == words["tiled"]).all(), "the tiled sampler read other words"
    times = {name: [] for name in variants}
    n = args.batch * args.steps
    for _ in range(args.reps):
        for name, (_, tab) in variants.items():
            compiled[name](*poses, tab).block_until_ready()
            t0, c0 = time.perf_counter(), time.process_time()
            compiled[name](*poses, tab).block_until_ready()
            times[name].append(((time.process_time() - c0) / n * 1e6, (time.perf_counter() - t0) / n * 1e6))
    for name, t in times.items():
        cpu = sorted(x[0] for x in t)
        print(json.dumps({"table": name, "cpu_us_best": round(cpu[0], 1), "cpu_us_median": round(cpu[len(cpu) // 2], 1),
                          "wall_us_best": round(min(x[1] for x in t), 1), "batch": args.batch, "steps": args.steps,
                          "load_avg_1min": round(os.getloadavg()[0], 2)}), flush=True)


if __name__ == "__main__":
    main()
