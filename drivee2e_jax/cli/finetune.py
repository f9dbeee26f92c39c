"""`drivee2e finetune`: fine-tune an imitation checkpoint through the differentiable simulator."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli.common import add_command

EPILOG = """\
examples:
  drivee2e finetune --init runs/ad_mlp --split train --out runs/finetune/ad_mlp
  drivee2e finetune --init runs/ad_mlp --out runs/finetune/ad_mlp --resume
  drivee2e finetune --init runs/ad_mlp --out runs/finetune/ad_mlp_rl --steps 200 --horizon 20 --batch 8 --weights red_light=5
  drivee2e bench --split val --policy ad_mlp:checkpoint=runs/finetune/ad_mlp,name=ad_mlp_ft

Each step drives a pool of --batch episodes --horizon steps further with the
current policy (on-policy states) and backpropagates the loss (soft collision,
route deviation, comfort, imitation relabelled at the on-policy states) through the
rollout (docs/finetuning.md). Writes RUN/config.json, RUN/log.jsonl and an
Orbax checkpoint every --ckpt-every steps in RUN/checkpoints/<step>
(checkpoint 0 = the --init parameters). The run loads like a `drivee2e train`
run: --policy <model>:checkpoint=RUN, `drivee2e trend RUN`. --init takes a
`drivee2e train` run of ad_mlp or vector_transformer.
"""


def add_parser(subparsers) -> None:
    p = add_command(subparsers, "finetune", help="fine-tune a checkpoint closed-loop through the simulator",
                    description="Closed-loop fine-tuning: truncated backpropagation through short, batched, "
                    "jitted rollouts of the differentiable simulator, the policy's parameters the only trainable "
                    "thing; Optax AdamW, Orbax checkpoints, JSON-lines log.", epilog=EPILOG)
    p.add_argument("--init", required=True, help="imitation run folder or checkpoint (drivee2e train --out)")
    p.add_argument("--out", type=Path, required=True, help="run folder")
    p.add_argument("--suite", default="twin15", help="suite name or folder (default: twin15)")
    p.add_argument("--split", default="train", help="split driven (default: train)")
    p.add_argument("--steps", type=int, default=400, help="optimiser steps (default: 400)")
    p.add_argument("--horizon", type=int, default=30, help="simulated steps per segment, BPTT length (default: 30)")
    p.add_argument("--batch", type=int, default=16, help="episodes in the pool (default: 16)")
    p.add_argument("--lr", type=float, default=5e-5, help="peak learning rate (default: 5e-5)")
    p.add_argument("--warmup-steps", type=int, default=20, help="linear warmup steps (default: 20)")
    p.add_argument("--reset-prob", type=float, default=0.1,
                   help="chance per step that an unfinished episode restarts (default: 0.1)")
    p.add_argument("--weights", default="",
                   help="loss weights as k=v,... over collision, route, comfort, imitation, red_light "
                   "(default: collision=10,route=1,comfort=0.01,imitation=1,red_light=0)")
    p.add_argument("--no-straight-through", action="store_true",
                   help="use the controller's own (mostly zero) longitudinal gradient")
    p.add_argument("--obs-gradient", action="store_true",
                   help="also backpropagate through the observation of the new pose (explodes; see docs)")
    p.add_argument("--seed", type=int, default=0, help="pool seed (default: 0)")
    p.add_argument("--log-every", type=int, default=5, help="steps between log lines (default: 5)")
    p.add_argument("--ckpt-every", type=int, default=100, help="steps between checkpoints (default: 100)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--force", action="store_true", help="discard an existing run in --out (only one holding nothing but a run's files)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def parse_weights(text: str):
    """``LossWeights`` from "k=v,..." (unnamed terms keep their defaults)."""
    import dataclasses

    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.train.finetune import LossWeights

    names = [f.name for f in dataclasses.fields(LossWeights)]
    kw = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        k, sep, v = item.partition("=")
        if not sep or k.strip() not in names:
            raise DriveE2EError(f"--weights: bad item {item!r} (expected k=v with k in {', '.join(names)})")
        try:
            kw[k.strip()] = float(v)
        except ValueError as e:
            raise DriveE2EError(f"--weights: {k}={v!r} is not a number") from e
    return LossWeights(**kw)


def run(args) -> int:
    from drivee2e_jax.progress import progress_bars
    from drivee2e_jax.train.finetune import FinetuneConfig, finetune

    cfg = FinetuneConfig(
        init=str(args.init), suite=args.suite, split=args.split, steps=args.steps, horizon=args.horizon,
        batch=args.batch, lr=args.lr, warmup_steps=args.warmup_steps, reset_prob=args.reset_prob,
        weights=parse_weights(args.weights), straight_through=not args.no_straight_through,
        obs_gradient=args.obs_gradient, seed=args.seed,
        log_every=args.log_every, ckpt_every=args.ckpt_every,
    )
    with progress_bars(not args.no_progress) as bars:
        res = finetune(cfg, args.out, resume=args.resume, force=args.force, progress=bars)
    print(f"checkpoints in {args.out / 'checkpoints'}: {len(res['checkpoints'])}")
    return 0
