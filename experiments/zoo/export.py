"""Export a training checkpoint as the policy zoo's bundled weights.

Writes ``<NAME>.npz`` (the model parameters only, float32) and ``<NAME>.json``
(model, config, mode, sha256, where it came from, how it was trained, its
twin15 val scores) into ``drivee2e_jax/zoo/weights/`` (or ``--out``), a thin
CLI over ``drivee2e_jax.models.bundled.export_bundled``; docs/baselines.md,
"Policy zoo". Example::

    python experiments/zoo/export.py runs/vt vector_transformer --mode traj \\
        --training "drivee2e train --model vector_transformer --data data/demos --out runs/vt --epochs 20" \\
        --data data/demos --epochs 20 \\
        --val-ds 61.2 --val-sr 31.5 --val-rc 80.1 \\
        --measured-with "drivee2e bench --policy vector_transformer --split val"

Measure the val numbers with the checkpoint first (``drivee2e bench --policy
NAME:checkpoint=RUN --split val``), or export without them (``val`` null),
bench the bundled policy, and export again with them: the npz bytes (and so
its sha256) do not change.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models.bundled import MODES, export_bundled

PACKAGE_WEIGHTS = Path(__file__).resolve().parents[2] / "drivee2e_jax" / "zoo" / "weights"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="experiments/zoo/export.py", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("run", help="a training run folder, its checkpoints/ or one checkpoints/<epoch> (the last epoch "
                   "of a run folder is taken)")
    p.add_argument("name", help="the zoo name: vector_transformer, vector_transformer_ft, ppo, ad_mlp, tcp, "
                   "tcp_traj, tcp_ctrl (or your own)")
    p.add_argument("--mode", required=True, choices=MODES,
                   help="how the zoo drives the model: traj (waypoints), ctrl (control head), fused (TCP's blend)")
    p.add_argument("--out", type=Path, default=PACKAGE_WEIGHTS,
                   help=f"folder to write NAME.npz + NAME.json into (default: {PACKAGE_WEIGHTS})")
    p.add_argument("--training", default=None, help="the command that trained the checkpoint")
    p.add_argument("--data", default=None, help="the data it was trained on (dataset folder, suite / split)")
    p.add_argument("--epochs", type=int, default=None, help="epochs trained")
    p.add_argument("--steps", type=int, default=None, help="optimiser / PPO update steps trained")
    p.add_argument("--val-ds", type=float, default=None, help="twin15 val driving score (0-100)")
    p.add_argument("--val-sr", type=float, default=None, help="twin15 val success rate (%%)")
    p.add_argument("--val-rc", type=float, default=None, help="twin15 val route completion (0-100)")
    p.add_argument("--variant", action="append", default=[], metavar="NAME=DS,SR,RC",
                   help="val scores of another zoo name that drives these weights in another mode (repeatable; "
                   "e.g. --variant tcp_traj=47.12,31.0,55.28 on the tcp pair)")
    p.add_argument("--measured-with", default=None,
                   help="the bench command the val numbers came from (default: drivee2e bench --policy NAME "
                   "--split val, when --val-* are given)")
    return p.parse_args(argv)


def info_of(args: argparse.Namespace) -> dict:
    """The ``info`` argument of ``export_bundled`` from the command line."""
    vals = (args.val_ds, args.val_sr, args.val_rc)
    if any(v is not None for v in vals) and not all(v is not None for v in vals):
        raise DriveE2EError("--val-ds, --val-sr and --val-rc go together (all three or none)")
    val = None if vals[0] is None else dict(zip(("driving_score", "success_rate", "route_completion"), vals))
    measured = args.measured_with or (f"drivee2e bench --policy {args.name} --split val" if val else None)
    training = {"command": args.training, "data": args.data, "epochs": args.epochs, "steps": args.steps}
    variants = {}
    for text in args.variant:
        name, _, nums = text.partition("=")
        parts = nums.split(",")
        try:
            variants[name.strip()] = dict(zip(("driving_score", "success_rate", "route_completion"),
                                              map(float, parts), strict=True))
        except ValueError:
            raise DriveE2EError(f"--variant {text!r}: expected NAME=DS,SR,RC (three numbers)") from None
    return {"mode": args.mode, "training": training, "val": val, "measured_with": measured, "variants": variants}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        npz, jpath = export_bundled(args.run, args.name, args.out, info_of(args))
    except DriveE2EError as e:
        print(f"export.py: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {npz} ({npz.stat().st_size:,} bytes) and {jpath}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
