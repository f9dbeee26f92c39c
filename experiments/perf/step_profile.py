"""Where the closed-loop step spends its time, by simulator function (never a unit test).

    python experiments/perf/step_profile.py                 # state_obs, B = 800
    python experiments/perf/step_profile.py --config state_idm --batch 200

Wraps the step's parts (``infractions.*``, the observation's parts,
``replay.agents_at``, the episode update, the reactive agents) in
``jax.named_scope`` at run time, compiles the ``experiments/perf/run.py``
rollout afresh (both compile caches off, so the scopes are traced), runs three
chunks under ``jax.profiler.trace`` and sums XLA's per-op times by the
innermost two scopes named in each op's metadata. Shares are what to read:
the absolute ms include the profiler's overhead, and on a loaded machine the
other processes' (compare shares of one run only).
"""

from __future__ import annotations

import argparse
import collections
import functools
import glob
import gzip
import json
import os
import re
import sys
import tempfile
from pathlib import Path

os.environ["DRIVEE2E_LOWERED_CACHE"] = "off"
os.environ["DRIVEE2E_JAX_CACHE"] = "off"
sys.path.insert(0, str(Path(__file__).resolve().parent))

PREFIX = "SCOPE_"


def _scope(module, name: str, label: str | None = None) -> None:
    f = getattr(module, name)

    @functools.wraps(f)
    def wrapped(*args, **kwargs):
        import jax

        with jax.named_scope(PREFIX + (label or name)):
            return f(*args, **kwargs)

    setattr(module, name, wrapped)


def instrument() -> None:
    """Name the step's parts (module attributes looked up at call time)."""
    from drivee2e_jax import infractions, reactive, replay
    from drivee2e_jax import sim as simulator
    from drivee2e_jax.metrics import episode
    from drivee2e_jax.observe import vector

    for name in ("nearest_rows", "agent_contacts", "red_light_crossing", "lane_status", "ego_lanes",
                 "drivable_excess", "collision_type", "background_speed", "lane_invasion", "layout_contact",
                 "front_distance", "logged_overlap_exempt"):
        _scope(infractions, name)
    for name in ("route_ahead", "command_ahead", "nearest_agents", "lanes_near", "next_signal"):
        _scope(vector, name, "observe." + name)
    _scope(simulator, "observe", "observe")
    _scope(simulator, "_lane_rows")
    _scope(replay, "agents_at")
    _scope(replay, "signals_at")
    _scope(episode, "update", "episode.update")
    for name in ("step", "leaders"):
        _scope(reactive, name, "idm." + name)
    _scope(simulator.Simulator, "_privileged", "privileged")
    _scope(simulator.Simulator, "to_controls", "to_controls")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", choices=("state_only", "state_obs", "state_idm"), default="state_obs")
    ap.add_argument("--batch", type=int, default=800)
    ap.add_argument("--suite", default="twin15")
    args = ap.parse_args(argv)
    instrument()
    import jax
    import run as perf_run

    from drivee2e_jax.sim import SimConfig

    chunk = 10
    config = SimConfig(agents="idm") if args.config == "state_idm" else None
    ro, scn = perf_run._setup(args.suite, args.batch, chunk, reads_obs=args.config == "state_obs", config=config)
    keys = jax.random.split(jax.random.PRNGKey(0), args.batch)
    carry = ro.init(scn, keys)
    hlo = ro.advance.lower(scn, carry).compile().as_text()
    carry, _ = ro.advance(scn, carry)
    jax.block_until_ready(carry)
    rounds = 3
    with tempfile.TemporaryDirectory() as d:
        with jax.profiler.trace(d):
            for _ in range(rounds):
                carry, _ = ro.advance(scn, carry)
            jax.block_until_ready(carry)
        trace = sorted(glob.glob(d + "/**/*.trace.json.gz", recursive=True))[-1]
        events = json.load(gzip.open(trace))["traceEvents"]
    op_name = {m.group(1): m.group(2) for m in re.finditer(r'%([\w.\-]+) = [^\n]*?op_name="([^"]+)"', hlo)}
    by_scope: collections.Counter = collections.Counter()
    for e in events:
        if e.get("ph") != "X" or e.get("name") not in op_name:
            continue
        scopes = re.findall(PREFIX + r"([\w.]+)", op_name[e["name"]])
        by_scope["/".join(scopes[:2]) if scopes else "(rest of the step)"] += e["dur"]
    total = sum(by_scope.values())
    steps = rounds * chunk
    print(f"{args.config}, B = {args.batch}: {total / 1e3 / steps:.1f} ms a step in XLA ops (profiled)")
    for name, us in by_scope.most_common():
        print(f"{100 * us / total:6.1f} %  {us / 1e3 / steps:8.2f} ms  {name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
