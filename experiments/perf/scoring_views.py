"""What the replay-robust scoring views cost: the state-only step with collision
attribution, nuPlan's / NAVSIM's per-tick facts and IDM agents, as ratios.

    python experiments/perf/scoring_views.py --batch 800 --steps 100
    python experiments/perf/scoring_views.py --batch 800 --baseline-src /tmp/before   # + a checkout before the change

Each configuration is the state-only closed loop (dynamics, replay, every
infraction and criterion, the vector observation) with the ``log_replay``
policy on the first B scenarios of the suite (cycled), timed in its own fresh
subprocess after compilation: ``paper`` (today's default: at-fault
attribution always on), ``nuplan`` (+ nuPlan's TTC and driving-direction
facts), ``navsim`` (+ NAVSIM's TTC, junction and direction facts), ``idm``
(paper scoring, IDM agents) and, with ``--baseline-src DIR``, ``before`` (the
same default rollout from another source tree, e.g. a ``git worktree`` of the
commit before attribution landed). Every configuration runs ``--rounds``
times, interleaved (before, paper, nuplan, navsim, idm, before, ...), and the
best wall of each is compared, so a machine whose speed drifts during the run
affects all alike. Prints scenario-steps/s per configuration and each ratio
to ``paper`` (and to ``before``), with the load average.

Budgets (issue "Scores that survive non-reactive replay"): attribution + TTC
<= 15 % over the state-only step; IDM agents <= 1.5x it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))  # run.py beside this file

import run as perf_run  # noqa: E402  (the state-only timing loop)

CONFIGS = ("paper", "nuplan", "navsim", "idm")


def measure(config: str, suite: str, batch: int, steps: int, chunk: int) -> dict:
    """Time one configuration in this process (``run.measure``: after a compile + warm-up chunk)."""
    from drivee2e_jax.metrics.driving_score import score_preset
    from drivee2e_jax.sim import SimConfig

    if config in ("before", "paper"):
        cfg = SimConfig()
    elif config == "idm":
        cfg = SimConfig(agents="idm")
    else:
        cfg = SimConfig(score=score_preset(config))
    m = perf_run.measure(suite, batch, chunk, steps, config=cfg)
    return {"config": config, "batch": batch, "steps": m["steps"], "wall_s": round(m["wall_s"], 3),
            "scenario_steps_per_s": round(m["scenario_steps_per_s"], 1), "load1": os.getloadavg()[0]}


def run_one(config: str, args) -> dict:
    """``measure`` in a fresh subprocess (its own compile, nothing shared), from
    ``--baseline-src`` for ``before``."""
    src = args.baseline_src if config == "before" else ROOT
    env = {**os.environ, "PYTHONPATH": str(src)}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--_one", config, "--suite", args.suite,
           "--batch", str(args.batch), "--steps", str(args.steps), "--chunk", str(args.chunk)]
    out = subprocess.run(cmd, env=env, cwd=src, capture_output=True, text=True, check=False)
    if out.returncode:
        raise SystemExit(f"scoring_views: {config} failed: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="example: python experiments/perf/scoring_views.py --batch 64 --steps 50 --rounds 1")
    ap.add_argument("--suite", default="twin15")
    ap.add_argument("--batch", type=int, default=800, help="scenarios stepped together (default 800)")
    ap.add_argument("--steps", type=int, default=100, help="timed steps (default 100)")
    ap.add_argument("--chunk", type=int, default=50, help="steps per compiled advance (default 50)")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds; the best of each is kept (default 2)")
    ap.add_argument("--configs", default=",".join(CONFIGS), help=f"comma-separated subset of {','.join(CONFIGS)}")
    ap.add_argument("--baseline-src", type=Path, default=None,
                    help="a source tree to time as 'before' (e.g. a git worktree of the previous commit)")
    ap.add_argument("--json", action="store_true", help="one JSON object per measurement")
    ap.add_argument("--_one", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args._one:
        print(json.dumps(measure(args._one, args.suite, args.batch, args.steps, args.chunk)))
        return 0
    configs = (["before"] if args.baseline_src else []) + [c for c in args.configs.split(",") if c]
    bad = [c for c in configs if c not in (*CONFIGS, "before")]
    if bad:
        raise SystemExit(f"scoring_views: --configs: unknown {bad}; expected a subset of {','.join(CONFIGS)}")
    best: dict[str, dict] = {}
    for r in range(args.rounds):
        for c in configs:
            m = run_one(c, args)
            m["round"] = r
            if args.json:
                print(json.dumps(m), flush=True)
            if c not in best or m["wall_s"] < best[c]["wall_s"]:
                best[c] = m
    print(f"B = {args.batch}, {best[configs[0]]['steps']} steps, best of {args.rounds} interleaved rounds, "
          f"{os.cpu_count()} cores")
    print(f"{'config':<8} {'scenario-steps/s':>17} {'vs paper':>9} {'vs before':>10} {'load1':>6}")
    for c in configs:
        m = best[c]
        vs = lambda ref, m=m: f"{best[ref]['wall_s'] / m['wall_s']:.3f}x" if ref in best else "-"  # noqa: E731
        print(f"{c:<8} {m['scenario_steps_per_s']:>17,.0f} {vs('paper'):>9} {vs('before'):>10} {m['load1']:>6.1f}")
    print("(ratios are speeds: < 1 means slower than the reference)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
