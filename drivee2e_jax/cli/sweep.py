"""`drivee2e sweep`: run every combination of an experiment config (experiments/*.toml)."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli.common import add_command

EPILOG = """\
examples:
  drivee2e sweep experiments/smoke.toml                 # tiny: 1 run, 2 policies x 2 repetitions
  drivee2e sweep experiments/baselines.toml --dry-run   # list the runs and whether each is complete
  drivee2e sweep experiments/smoke.toml --out results/sweeps/smoke-2 --no-progress   # elsewhere, quietly

A run is one suite x split x variant x task x [sim] combination, evaluated
like `drivee2e bench` (all policies; the repetitions of a policy in one
batched rollout) into OUT/runs/<run-id>/. OUT/combined.csv and combined.md
compare the policies side by side. Rerunning resumes: complete runs and
finished policies are skipped; a changed config is refused unless --force
(which starts over). The config format is documented in docs/sweeps.md.
"""


def add_parser(subparsers) -> None:
    p = add_command(
        subparsers, "sweep",
        help="run an experiment config: every policy on every suite/split/variant/setting",
        description="Run every combination of an experiment config (experiments/*.toml): one bench results folder "
        "per run, resumable after interruption, plus combined tables comparing the policies.",
        epilog=EPILOG,
    )
    p.add_argument("config", type=Path, help="experiment config (.toml)")
    p.add_argument("--out", type=Path, default=None,
                   help="sweep folder (default: [sweep] out, else results/sweeps/<name>)")
    p.add_argument("--force", action="store_true", help="start over: redo every run, even under a changed config (only a folder holding nothing but the sweep's files)")
    p.add_argument("--dry-run", action="store_true", help="list the runs (and which are complete); run nothing")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    from drivee2e_jax.sweep.config import load_config, out_dir, with_out
    from drivee2e_jax.sweep.runner import expand, is_complete, policy_paths, run_sweep

    cfg = with_out(load_config(args.config), args.out)
    if args.dry_run:
        runs = expand(cfg)
        out = out_dir(cfg)
        paths = policy_paths(cfg)
        print(f"sweep {cfg.sweep.name}: {len(runs)} run(s) x {len(cfg.policies)} policies x "
              f"{cfg.repetitions.count} repetitions -> {out}")
        print("policies: " + ", ".join(f"{p.name or Path(path).stem} ({path})" for p, path in zip(cfg.policies, paths)))
        for r in runs:
            state = "complete" if is_complete(out / "runs" / r.run_id) else "to run"
            print(f"  {r.run_id:<40} {state}")
        return 0
    run_sweep(cfg, force=args.force, progress=not args.no_progress)
    return 0
