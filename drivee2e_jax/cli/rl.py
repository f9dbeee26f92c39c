"""`drivee2e rl`: train a policy with PPO on the batched simulator (train/ppo.py)."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli.common import add_command

EPILOG = """\
examples:
  drivee2e rl --out runs/ppo --env-steps 2000000
  drivee2e rl --init runs/ad_mlp --out runs/ppo_ad_mlp --critic-warmup 10 --lr 1e-5 --critic-lr 3e-4
  drivee2e rl --init runs/ad_mlp --out runs/ppo_ad_mlp --critic-warmup 10 --lr 1e-5 --critic-lr 3e-4 --resume
  drivee2e rl --out runs/ppo_mlp --model ad_mlp --model-config hidden=64x64 --reward comfort=0.1,failure=0.2 --seed 1
  drivee2e rl --out runs/ppo_scratch --model vector_mlp --model-config init_speed=5,num_waypoints=2 --envs 256 --time-limit 60
  drivee2e bench --split val --policy vector_mlp:checkpoint=runs/ppo_scratch,name=ppo_scratch --limit 5
  drivee2e bench --split val --policy ad_mlp:checkpoint=runs/ppo_ad_mlp,name=ad_mlp_ppo --limit 5
  drivee2e trend runs/ppo_ad_mlp --split val --limit 5 --out results/trend-ppo

Each update drives --envs episodes --rollout-steps steps further with the
current stochastic policy (a Gaussian around the model's waypoints; a finished
episode restarts on a random scenario of --split), then runs --epochs passes of
--minibatches PPO minibatches over those samples: one compiled function, no
Python per simulated step. Reward: metres of route progress minus the
Leaderboard 2.0 penalties scaled by the route length (--reward overrides the
RewardConfig fields: progress, outside_lanes, penalty_scale_m,
collision_pedestrian, collision_vehicle, collision_layout, red_light, failure,
invalid_action, comfort, at_fault_only; docs/training.md). Without --init the model
(--model) starts from a random init; with --init it starts from an imitation
run (drivee2e train or finetune) and --critic-warmup updates first train only
the value network. Writes RUN/config.json, RUN/log.jsonl (one line per
update: env steps, episode return / RC / DS, losses, env-steps/s) and an Orbax
checkpoint every --ckpt-every updates in RUN/checkpoints/<update> (0 = the
initial actor), holding the environments and RNG too, so --resume continues
exactly as an uninterrupted run. The run loads like a drivee2e train run:
--policy <model>:checkpoint=RUN, drivee2e trend RUN.
"""


def add_parser(subparsers) -> None:
    p = add_command(subparsers, "rl", help="train a policy with PPO in the batched simulator",
                    description="Proximal Policy Optimization in pure JAX on the functional environment: "
                    "thousands of parallel closed-loop episodes, GAE, clipped objective, Optax Adam, Orbax "
                    "checkpoints, JSON-lines log, exact resume.", epilog=EPILOG)
    p.add_argument("--out", type=Path, required=True, help="run folder")
    p.add_argument("--init", default=None, help="imitation run folder or checkpoint to start from (default: random init)")
    p.add_argument("--model", default="vector_transformer",
                   help="model trained from scratch (ignored with --init): vector_transformer, vector_mlp (the "
                   "fast one: an MLP over the ego's past and the scene vector) or ad_mlp (default: vector_transformer)")
    p.add_argument("--model-config", default="",
                   help="the model's make_model arguments as k=v,... from scratch: vector_transformer dim, heads, "
                   "layers; vector_mlp / ad_mlp hidden=256x256, init_speed=M/S (the initial straight-ahead plan) "
                   "(default: the model's defaults)")
    p.add_argument("--suite", default="twin15", help="suite name or folder (default: twin15)")
    p.add_argument("--split", default="train", help="split the episodes are drawn from (default: train)")
    p.add_argument("--limit", type=int, default=None, help="use only the first N scenarios of the split")
    p.add_argument("--envs", type=int, default=64, help="parallel environments (default: 64)")
    p.add_argument("--rollout-steps", type=int, default=32, help="steps per environment per update (default: 32)")
    p.add_argument("--env-steps", type=int, default=1_000_000, help="total environment steps (default: 1000000)")
    p.add_argument("--epochs", type=int, default=4, help="PPO passes over each rollout (default: 4)")
    p.add_argument("--minibatches", type=int, default=4, help="minibatches per pass (default: 4)")
    p.add_argument("--lr", type=float, default=3e-4, help="Adam step size of the actor (default: 3e-4)")
    p.add_argument("--critic-lr", type=float, default=None, help="Adam step size of the critic (default: --lr)")
    p.add_argument("--gamma", type=float, default=0.99, help="discount per 0.1 s step (default: 0.99)")
    p.add_argument("--gae-lambda", type=float, default=0.95, help="GAE lambda (default: 0.95)")
    p.add_argument("--clip", type=float, default=0.2, help="PPO ratio clip (default: 0.2)")
    p.add_argument("--ent-coef", type=float, default=0.0, help="entropy bonus (default: 0)")
    p.add_argument("--vf-coef", type=float, default=0.5, help="value-loss weight (default: 0.5)")
    p.add_argument("--target-kl", type=float, default=0.05,
                   help="skip an update's remaining minibatches past 1.5 x this KL; 0 = never (default: 0.05)")
    p.add_argument("--init-log-std", type=float, default=-1.0,
                   help="initial log-std of each waypoint coordinate, log m (default: -1.0, i.e. 0.37 m)")
    p.add_argument("--critic-warmup", type=int, default=0, help="first updates that train only the critic (default: 0)")
    p.add_argument("--reward", default="", help="RewardConfig overrides as k=v,... (the fields are listed below)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (default: 0)")
    p.add_argument("--log-every", type=int, default=1, help="updates between log lines (default: 1)")
    p.add_argument("--ckpt-every", type=int, default=50, help="updates between checkpoints (default: 50)")
    p.add_argument("--time-limit", type=float, default=None, metavar="MIN",
                   help="stop with a checkpoint after this many minutes of training (--resume continues)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--force", action="store_true", help="discard an existing run in --out (only one holding nothing but a run's files)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def parse_kv(text: str, flag: str, fields: dict) -> dict:
    """{k: value} from "k=v,..."; ``fields`` maps each allowed key to its type."""
    from drivee2e_jax.errors import DriveE2EError

    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        k, sep, v = (s.strip() for s in item.partition("="))
        if not sep or k not in fields:
            raise DriveE2EError(f"{flag}: bad item {item!r} (expected k=v with k in {', '.join(sorted(fields))})")
        kind = fields[k]
        try:
            if kind is bool:
                if v.lower() not in ("true", "false", "1", "0"):
                    raise ValueError(v)
                out[k] = v.lower() in ("true", "1")
            else:
                out[k] = None if v.lower() == "none" else kind(v)
        except ValueError as e:
            raise DriveE2EError(f"{flag}: {k}={v!r} is not a {kind.__name__.strip('_')}") from e
    return out


def _widths(text: str) -> list[int]:
    """"128x128" -> [128, 128] (ad_mlp's hidden widths)."""
    return [int(w) for w in text.split("x")]


def run(args) -> int:
    import dataclasses

    from drivee2e_jax.envs.functional import RewardConfig
    from drivee2e_jax.progress import progress_bars
    from drivee2e_jax.train.ppo import PPOConfig, train

    reward_fields = {f.name: (bool if f.type in (bool, "bool") else float) for f in dataclasses.fields(RewardConfig)}
    model_fields = {"dim": int, "heads": int, "layers": int, "num_waypoints": int, "waypoint_dt": float,
                    "hidden": _widths, "init_speed": float}
    cfg = PPOConfig(
        suite=args.suite, split=args.split, model=args.model,
        model_config=parse_kv(args.model_config, "--model-config", model_fields),
        init=None if args.init is None else str(args.init), num_envs=args.envs, rollout_steps=args.rollout_steps,
        total_env_steps=args.env_steps, update_epochs=args.epochs, minibatches=args.minibatches, lr=args.lr,
        critic_lr=args.critic_lr,
        gamma=args.gamma, gae_lambda=args.gae_lambda, clip_eps=args.clip, vf_coef=args.vf_coef,
        ent_coef=args.ent_coef, target_kl=args.target_kl or None, init_log_std=args.init_log_std,
        critic_warmup_updates=args.critic_warmup, reward=parse_kv(args.reward, "--reward", reward_fields),
        limit=args.limit, seed=args.seed, log_every=args.log_every, ckpt_every=args.ckpt_every,
    )
    with progress_bars(not args.no_progress) as bars:
        res = train(cfg, args.out, resume=args.resume, force=args.force, progress=bars,
                    time_limit_s=None if args.time_limit is None else 60.0 * args.time_limit)
    last = res["last"]
    if last:
        episodes = (f"{last['episodes']} episodes ended, mean return {last['episode_return']:.1f} m, "
                    f"DS {last['episode_ds']:.1f}" if last.get("episodes") else "no episode ended")
        print(f"last update: {episodes}; {last['env_steps_per_s']:.0f} env-steps/s")
    print(f"checkpoints in {args.out / 'checkpoints'}: {len(res['checkpoints'])}")
    return 0
