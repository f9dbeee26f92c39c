"""Where a cold compile of the state-only rollout goes (never a unit test).

    python experiments/perf/compile_parts.py                 # B = 800, chunk 25
    python experiments/perf/compile_parts.py --batch 64 --threads

For ``run.py``'s state-only rollout (``log_replay``, twin15): the seconds
spent tracing + lowering (``init``'s two programs together, then ``advance``)
and compiling (XLA) each of the three programs a run compiles (``reset``,
``start``, ``advance``), with the process CPU seconds of
each compile (XLA:CPU compiles a program's kernels on several threads). The
persistent compilation cache and the lowered-program store are off, so every
figure is cold. ``--threads``: compile the three lowered programs in parallel
threads instead, and print the wall time of that one step.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=800)
    ap.add_argument("--chunk", type=int, default=25)
    ap.add_argument("--threads", action="store_true", help="compile the three programs in parallel threads")
    args = ap.parse_args()
    os.environ["DRIVEE2E_LOWERED_CACHE"] = "off"
    os.environ.pop("DRIVEE2E_PERSISTENT_CACHE", None)
    import jax

    jax.config.update("jax_enable_compilation_cache", False)
    from run import _setup

    ro, scn = _setup("twin15", args.batch, args.chunk)
    keys = jax.random.split(jax.random.PRNGKey(0), args.batch)
    row: dict = {"batch": args.batch, "chunk": args.chunk}
    t = time.perf_counter()
    reset, start = ro.lower_init(scn, keys)
    row["init_lower_s"] = time.perf_counter() - t
    t = time.perf_counter()
    advance = ro.advance.lower(scn, start.out_info)
    row["advance_lower_s"] = time.perf_counter() - t
    programs = {"reset": reset, "start": start, "advance": advance}
    if args.threads:
        t = time.perf_counter()
        with ThreadPoolExecutor(len(programs)) as pool:
            for f in [pool.submit(p.compile) for p in programs.values()]:
                f.result()
        row["compile_threads_s"] = time.perf_counter() - t
    else:
        for name, program in programs.items():
            t, c = time.perf_counter(), time.process_time()
            program.compile()
            row[f"{name}_compile_s"] = time.perf_counter() - t
            row[f"{name}_compile_cpu_s"] = time.process_time() - c
    row["load_avg_1min"] = os.getloadavg()[0]
    print(json.dumps({k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
