"""`drivee2e train`: imitation-train a baseline on a demonstration dataset."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli.common import add_command

EPILOG = """\
examples:
  drivee2e train --model ad_mlp --data data/demos-train --epochs 3 --out runs/ad_mlp
  drivee2e train --model ad_mlp --data data/demos-train --epochs 3 --out runs/ad_mlp --resume
  drivee2e train --model ad_mlp --model-config '{"hidden": [64, 64]}' --data data/demos-train --out runs/small

Writes RUN/config.json, RUN/log.jsonl (plot it with
experiments/training/plot_log.py RUN) and an Orbax checkpoint per epoch in
RUN/checkpoints/<epoch>. --resume continues from the last epoch (the config
must be unchanged). Drive with a checkpoint: `drivee2e bench --policy
<model>:checkpoint=RUN`; study checkpoints with `drivee2e trend RUN`.
"""


def add_parser(subparsers) -> None:
    p = add_command(subparsers, "train", help="imitation-train a baseline (Optax + Orbax checkpoints)",
                    description="Train a registered model on recorded demonstrations: AdamW with a warmup-cosine "
                    "schedule, one checkpoint per epoch, JSON-lines log.", epilog=EPILOG)
    p.add_argument("--model", required=True, help="model name (drivee2e_jax.models.MODELS: ad_mlp, tcp, vector_mlp, vector_transformer)")
    p.add_argument("--model-config", default="{}", help="JSON object of model options (default: {})")
    p.add_argument("--data", type=Path, required=True, help="dataset folder (drivee2e dataset build)")
    p.add_argument("--out", type=Path, required=True, help="run folder")
    p.add_argument("--epochs", type=int, default=3, help="epochs (default: 3)")
    p.add_argument("--batch-size", type=int, default=256, help="samples per step (default: 256)")
    p.add_argument("--lr", type=float, default=1e-3, help="peak learning rate (default: 1e-3)")
    p.add_argument("--warmup-steps", type=int, default=50, help="linear warmup steps (default: 50)")
    p.add_argument("--weight-decay", type=float, default=1e-4, help="AdamW weight decay (default: 1e-4)")
    p.add_argument("--seed", type=int, default=0, help="init and shuffle seed (default: 0)")
    p.add_argument("--log-every", type=int, default=10, help="steps between log lines (default: 10)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last epoch")
    p.add_argument("--force", action="store_true", help="discard an existing run in --out (only one holding nothing but a run's files)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.files import loads_json
    from drivee2e_jax.progress import progress_bars
    from drivee2e_jax.train.loop import TrainConfig, train

    try:
        model_cfg = loads_json(args.model_config)
    except ValueError as e:
        raise DriveE2EError(f"--model-config: not JSON ({e})") from e
    if not isinstance(model_cfg, dict):
        raise DriveE2EError("--model-config: expected a JSON object like '{\"hidden\": [64, 64]}'")
    cfg = TrainConfig(
        model=args.model, model_config=tuple(sorted((k, _freeze(v)) for k, v in model_cfg.items())),
        data=str(args.data), epochs=args.epochs, batch_size=args.batch_size, lr=args.lr,
        warmup_steps=args.warmup_steps, weight_decay=args.weight_decay, seed=args.seed, log_every=args.log_every,
    )
    with progress_bars(not args.no_progress) as bars:
        res = train(cfg, args.out, resume=args.resume, force=args.force, progress=bars)
    print(f"trained {cfg.model}: {res['steps']} steps, last loss {res['loss']:.4f}, {res['wall_s']:.1f} s; "
          f"checkpoints in {args.out / 'checkpoints'}")
    return 0


def _freeze(v):
    return tuple(_freeze(x) for x in v) if isinstance(v, list) else v
