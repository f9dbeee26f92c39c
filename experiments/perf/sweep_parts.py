"""Where the time of the BEV + LiDAR sweep goes (never a unit test).

    python experiments/perf/sweep_parts.py --batch 128 --steps 25 --parts rollout:both rollout:none
    python experiments/perf/sweep_parts.py --parts observe:bev observe:lidar policy:both

Parts (each its own jitted program on the first ``--batch`` twin15 scenarios):

* ``rollout:<reads>``: ``Rollout.advance`` of ``--steps`` steps with the
  ``run.py`` MLP stand-in policy reading ``<reads>`` (``both``, ``bev``,
  ``lidar`` or ``none`` = ego features only, no sensor);
* ``observe:<reads>``: only ``Simulator.observe`` (the sensors + vector
  observation) and the policy's feature reduction, at the logged ego pose
  of ``--steps`` successive times (``lax.scan`` over time, ``vmap`` over
  scenarios, as in the rollout);
* ``policy:<reads>``: the MLP on a fixed observation, ``--steps`` times.

Reports the process CPU time and the wall time per scenario-step, the best of
``--reps`` runs after compilation (CPU time counts both cores when XLA uses
them; it is the less noisy number on a shared machine), the compile seconds
and the 1-minute load average.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _reads(name: str) -> tuple[str, ...]:
    return {"both": ("bev", "lidar"), "none": ()}.get(name, (name,))


def _setup(batch: int, reads, sensor_overrides: dict):
    import dataclasses

    import jax
    import jax.numpy as jnp
    import numpy as np
    from run import mlp_sensor_policy

    from drivee2e_jax.eval.closedloop import init_params, with_policy_sensors
    from drivee2e_jax.observe import sensors
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.sim import SimConfig, Simulator

    suite = load_suite("twin15")
    packed = suite.pack(None)
    packed = packed.select(np.arange(min(batch, len(packed))))
    pol = mlp_sensor_policy(reads=reads)
    cfg = with_policy_sensors(SimConfig(), pol)
    if sensor_overrides:
        cfg = dataclasses.replace(cfg, sensors=dataclasses.replace(cfg.sensors, **sensor_overrides))
    assets = sensors.build_assets(packed, cfg.sensors, suite.maps)
    scn = jax.tree_util.tree_map(jnp.asarray, packed.scenario)
    sim = Simulator(cfg)
    keys = jax.random.split(jax.random.PRNGKey(0), len(packed))
    params = init_params(pol, sim, scn, keys[0], assets)
    return sim, pol, params, scn, keys, assets


def _time(fn, args, reps: int):
    import jax

    t0 = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))
    best_wall = best_cpu = float("inf")
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(compiled(*args))
        best_wall = min(best_wall, time.perf_counter() - t0)
        best_cpu = min(best_cpu, time.process_time() - c0)
    return compile_s, best_wall, best_cpu


def measure(part: str, batch: int, steps: int, reps: int, sensor_overrides: dict) -> dict:
    import jax
    import jax.numpy as jnp

    from drivee2e_jax import replay
    from drivee2e_jax.observe import sensors
    from drivee2e_jax.rollout import Rollout

    kind, reads_name = part.split(":")
    reads = _reads(reads_name)
    sim, pol, params, scn, keys, assets = _setup(batch, reads, sensor_overrides)
    ax = sensors.assets_axes(assets)
    b = int(scn.ego_index.shape[0])
    if kind == "rollout":
        ro = Rollout(sim, pol, params, chunk=steps, assets=assets)
        carry = ro.init(scn, keys)
        fn = lambda s, c, a, p: jax.vmap(ro._advance_one, in_axes=(0, 0, ax, None))(s, c, a, p)[0]
        args = (scn, carry, assets, params)
    else:
        state0, obs0 = jax.jit(jax.vmap(sim.reset, in_axes=(0, 0, ax)))(keys, scn, assets)

        def at_log(s, st, i):
            # The ego on its logged pose at step i (a realistic scene).
            t = (i + 1).astype(jnp.float32) * sim.config.dt
            log = replay.ego_log_at(s.tracks, s.ego_index, t, s.dt_log)
            return st.replace(ego=st.ego.replace(xy=log.xy, yaw=log.yaw, t=t), step=i + 1)

        def one(s, st, a, i):
            return jnp.sum(pol.features(sim.observe(s, at_log(s, st, i), a)))

        if kind == "policy":
            def fn(o, p):
                def body(acc, i):
                    act, _ = jax.vmap(pol.act, in_axes=(None, 0, None, None))(p, o, None, jax.random.PRNGKey(0))
                    return acc + jnp.sum(act.throttle) + i, None
                return jax.lax.scan(body, jnp.zeros(()), jnp.arange(steps, dtype=jnp.float32))[0]
            args = (obs0, params)
        else:
            def fn(s, st, a):
                def body(acc, i):
                    return acc + jnp.sum(jax.vmap(one, in_axes=(0, 0, ax, None))(s, st, a, i)), None
                return jax.lax.scan(body, jnp.zeros(()), jnp.arange(steps))[0]
            args = (scn, state0, assets)
    compile_s, wall, cpu = _time(fn, args, reps)
    n = b * steps
    return {"part": part, "batch": b, "steps": steps, "compile_s": round(compile_s, 1),
            "cpu_us_per_scenario_step": round(cpu / n * 1e6, 1), "wall_us_per_scenario_step": round(wall / n * 1e6, 1),
            "overrides": {k: repr(v) for k, v in sensor_overrides.items()},
            "load_avg_1min": round(os.getloadavg()[0], 2), "cpu_count": os.cpu_count()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", nargs="+", default=["rollout:both", "rollout:none"])
    ap.add_argument("--batch", type=int, default=128)
    ap.add_argument("--steps", type=int, default=25)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--bev-channels", default=None, help="comma-separated BEV channel subset")
    ap.add_argument("--bev-set", nargs="*", default=[], metavar="FIELD=INT", help="BevConfig integer overrides")
    args = ap.parse_args(argv)
    over = {}
    if args.bev_channels or args.bev_set:
        import dataclasses

        from drivee2e_jax.observe.bev import BevConfig

        kw = {kv.split("=")[0]: int(kv.split("=")[1]) for kv in args.bev_set}
        if args.bev_channels:
            kw["channels"] = tuple(args.bev_channels.split(","))
        over["bev"] = dataclasses.replace(BevConfig(), **kw)
    for part in args.parts:
        print(json.dumps(measure(part, args.batch, args.steps, args.reps, over)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
