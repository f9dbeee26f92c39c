"""Scaling of the closed-loop rollout over local devices and over processes (never a unit test).

    python experiments/perf/scaling.py                      # table
    python experiments/perf/scaling.py --json               # one JSON object per configuration
    python experiments/perf/scaling.py --devices 1 2 4 --processes 2 --scenarios 64 --repeats 5

Each configuration runs in fresh subprocesses with the ``expert`` policy on
the first ``--scenarios`` scenarios of twin15 ``val``:

* ``devices N``: one process, ``XLA_FLAGS=--xla_force_host_platform_device_count=N``,
  the batch padded and split over the N host devices (``rollout.shard_rollout_inputs``,
  what ``evaluate`` does);
* ``processes P``: P processes joined with ``jax.distributed`` on loopback,
  each rolling out its ``distributed.process_shard`` on its one device.

After compiling (init + one chunk), ``--repeats`` times ``--chunks`` chunks of
``--chunk`` steps are timed; the wall of a repeat is the slowest process's.
Throughput = scenarios x steps / wall (scenario-steps/s); reported as min /
median over repeats. Forced host devices share the machine's cores, so N
devices beyond the core count only oversubscribe them.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def child(args) -> None:
    """One process of one configuration: print its timings as JSON."""
    from drivee2e_jax import compile_cache, distributed

    compile_cache.enable()  # compile time is not measured; reruns load it
    if args.num_processes > 1:
        distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    import jax
    import numpy as np

    from drivee2e_jax.eval.closedloop import device_batch, init_params
    from drivee2e_jax.policy import load_policy
    from drivee2e_jax.rollout import Rollout, shard_rollout_inputs
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.sim import SimConfig, Simulator

    packed = load_suite("twin15").pack("val")
    packed = packed.select(np.arange(min(args.scenarios, len(packed))))
    shard = distributed.process_shard(len(packed))
    batch, _ = device_batch(packed.select(np.asarray(shard)))
    sim = Simulator(SimConfig())
    pol = load_policy(ROOT / "drivee2e_jax" / "zoo" / "expert.py")
    key = jax.random.PRNGKey(0)
    params = init_params(pol, sim, batch, key)
    run_batch, keys, _ = shard_rollout_inputs(batch, jax.random.split(key, len(shard)), None)
    ro = Rollout(sim, pol, params, chunk=args.chunk)
    t0 = time.perf_counter()
    carry, _ = ro.advance(run_batch, ro.init(run_batch, keys))
    jax.block_until_ready(carry)
    compile_s = time.perf_counter() - t0
    walls = []
    for _ in range(args.repeats):
        distributed.allgather_json(0)  # start each repeat together
        t = time.perf_counter()
        for _ in range(args.chunks):
            carry, _ = ro.advance(run_batch, carry)
        jax.block_until_ready(carry)
        walls.append(time.perf_counter() - t)
    walls = distributed.allgather_json(walls)
    if distributed.is_root():
        print(json.dumps({"scenarios": len(packed), "devices_per_process": len(jax.local_devices()),
                          "compile_s": round(compile_s, 2), "walls": [max(w) for w in zip(*walls)]}))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_config(kind: str, n: int, args) -> dict:
    base = [sys.executable, __file__, "--child", "--scenarios", str(args.scenarios), "--chunk", str(args.chunk),
            "--chunks", str(args.chunks), "--repeats", str(args.repeats)]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    if kind == "devices":
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={n}"
        cmds = [base]
    else:
        env.pop("XLA_FLAGS", None)
        coord = f"127.0.0.1:{_free_port()}"
        cmds = [base + ["--coordinator", coord, "--num-processes", str(n), "--process-id", str(i)] for i in range(n)]
    procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for c in cmds]
    outs = [p.communicate() for p in procs]
    for p, (_, err) in zip(procs, outs):
        if p.returncode:
            raise SystemExit(f"{kind}={n} failed:\n{err[-3000:]}")
    got = json.loads(outs[0][0].strip().splitlines()[-1])
    import numpy as np

    steps = args.chunk * args.chunks
    tput = [got["scenarios"] * steps / w for w in got["walls"]]
    return {"config": f"{kind}={n}", "scenarios": got["scenarios"], "steps_per_repeat": steps,
            "compile_s": got["compile_s"], "wall_s_min": round(min(got["walls"]), 3),
            "wall_s_median": round(float(np.median(got["walls"])), 3),
            "scenario_steps_per_s_max": round(max(tput), 1), "scenario_steps_per_s_median": round(float(np.median(tput)), 1),
            "cores": os.cpu_count(), "load_avg_1min": round(os.getloadavg()[0], 2)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devices", type=int, nargs="*", default=[1, 2, 4], help="forced host device counts")
    ap.add_argument("--processes", type=int, nargs="*", default=[2], help="process counts (one device each)")
    ap.add_argument("--scenarios", type=int, default=64)
    ap.add_argument("--chunk", type=int, default=10, help="steps per compiled chunk")
    ap.add_argument("--chunks", type=int, default=3, help="chunks per timed repeat")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--coordinator", help=argparse.SUPPRESS)
    ap.add_argument("--num-processes", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--process-id", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        return child(args)
    configs = [("devices", n) for n in args.devices] + [("processes", n) for n in args.processes]
    shown = ("config", "scenarios", "steps_per_repeat", "compile_s", "wall_s_min", "wall_s_median",
             "scenario_steps_per_s_max", "scenario_steps_per_s_median", "load_avg_1min")
    if not args.json:
        print(" | ".join(shown))
    for kind, n in configs:
        r = run_config(kind, n, args)
        print(json.dumps(r) if args.json else " | ".join(str(r[k]) for k in shown), flush=True)

if __name__ == "__main__":
    main()
