"""`drivee2e trend`: open-loop vs closed-loop metrics across a training run's checkpoints."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli.common import add_command

EPILOG = """\
examples:
  drivee2e trend runs/ad_mlp --split val --out results/trend-ad_mlp
  drivee2e trend runs/ad_mlp --split val --limit 20 --out results/trend-quick

For every checkpoint RUN/checkpoints/<epoch>: open-loop L2 at 1 s / 2 s
(ST-P3 convention; *_uniad columns: the value at k s) and the open-loop
collision rate on the split's logged demonstrations, and closed-loop SR / DS
on the same split. Writes DIR/trend.csv, DIR/trend.png (open loop left,
closed loop right) and DIR/checkpoints/<epoch>.json; a rerun reuses the
checkpoints already evaluated (delete DIR/checkpoints/<epoch>.json to redo one).
"""


def add_parser(subparsers) -> None:
    p = add_command(subparsers, "trend", help="open- vs closed-loop metrics across a run's checkpoints",
                    description="Evaluate every checkpoint of a training run open-loop (L2, collision rate) and "
                    "closed-loop (SR, DS) on one split: the source paper's Figure 5.", epilog=EPILOG)
    p.add_argument("run", type=Path, help="training run folder (drivee2e train --out)")
    p.add_argument("--split", default="val", help="split (default: val)")
    p.add_argument("--suite", default=None, help="suite name or folder (default: the run dataset's suite)")
    p.add_argument("--limit", type=int, default=None, help="only the first N scenarios of the split")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed (default: 0)")
    p.add_argument("--mode", default="traj", choices=("traj", "ctrl", "fused"),
                   help="policy output used closed-loop (default: traj)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.set_defaults(func=run)


def run(args) -> int:
    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.train.trend import run_trend

    if args.limit is not None and args.limit < 1:
        raise DriveE2EError(f"--limit must be >= 1, got {args.limit}")
    rows = run_trend(args.run, args.out, suite=args.suite, split=args.split, limit=args.limit, seed=args.seed,
                     mode=args.mode)
    print(f"{len(rows)} checkpoints -> {args.out / 'trend.csv'}, {args.out / 'trend.png'}")
    return 0

