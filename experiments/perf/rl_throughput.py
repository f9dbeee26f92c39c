"""PPO training throughput against the state-only rollout, in one process (never a unit test).

    python experiments/perf/rl_throughput.py                        # vector_transformer, 64 envs x 32 steps
    python experiments/perf/rl_throughput.py --envs 256 --model ad_mlp --rounds 2 --json

Issue 21's target: training throughput (simulation + learner) >= 50 % of the
state-only rollout's scenario-steps/s measured in the same run. For each of
``--rounds`` interleaved rounds it times:

* ``state_only``: ``experiments/perf/run.py``'s state-only closed loop
  (``log_replay``, every infraction and criterion) at B = ``--envs``
  scenarios of twin15 train, over ``--steps`` steps;
* ``ppo``: ``--updates`` PPO updates (``train/ppo.py``: collect ``--envs`` x
  ``--rollout-steps`` steps with the model's stochastic policy, then the PPO
  epochs) after one compiled warm-up update; env-steps/s = envs x rollout
  steps x updates / wall;
* ``ppo_collect``: the collection alone (the policy's forward pass + the
  simulator), to split the cost between acting and learning.

Prints one line per measurement and the best-of ratio ppo / state_only.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import run as perf_run  # noqa: E402  (experiments/perf/run.py)


def ppo_rates(model_name: str, envs: int, rollout_steps: int, updates: int, suite: str, split: str,
              epochs: int = 4) -> dict:
    import jax

    from drivee2e_jax.envs.functional import make_params
    from drivee2e_jax.models.registry import get_model
    from drivee2e_jax.train import ppo

    cfg = ppo.PPOConfig(suite=suite, split=split, model=model_name, num_envs=envs, rollout_steps=rollout_steps,
                        update_epochs=epochs)
    learner = ppo.PPO(get_model(model_name), make_params(suite, split), cfg)
    runner = learner.init(jax.random.PRNGKey(0))
    t0 = time.perf_counter()
    runner, m = learner.update(runner)
    jax.block_until_ready(m)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(updates):
        runner, m = learner.update(runner)
    jax.block_until_ready(m)
    wall = time.perf_counter() - t0
    collect = jax.jit(learner._collect)
    jax.block_until_ready(collect(runner))
    t1 = time.perf_counter()
    for _ in range(updates):
        out = collect(runner)
        runner = out[0]
    jax.block_until_ready(out)
    wall_collect = time.perf_counter() - t1
    steps = envs * rollout_steps * updates
    return {"ppo_env_steps_per_s": steps / wall, "ppo_collect_env_steps_per_s": steps / wall_collect,
            "ppo_compile_s": compile_s, "ppo_wall_s": wall}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--model", default="vector_transformer", help="actor model (default: vector_transformer)")
    ap.add_argument("--envs", type=int, default=64, help="parallel environments = state-only batch (default: 64)")
    ap.add_argument("--rollout-steps", type=int, default=32, help="steps per environment per update (default: 32)")
    ap.add_argument("--updates", type=int, default=5, help="timed PPO updates per round (default: 5)")
    ap.add_argument("--epochs", type=int, default=4, help="PPO epochs per update (default: 4; the RL study uses 2)")
    ap.add_argument("--steps", type=int, default=160, help="timed state-only steps per round (default: 160)")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds (default: 2)")
    ap.add_argument("--suite", default="twin15")
    ap.add_argument("--split", default="train")
    ap.add_argument("--json", action="store_true", help="one JSON object per line")
    args = ap.parse_args(argv)
    perf_run._enable_persistent_cache()
    best: dict = {}
    for r in range(args.rounds):
        load = os.getloadavg()[0]
        so = perf_run.measure(args.suite, args.envs, 10, args.steps)
        pp = ppo_rates(args.model, args.envs, args.rollout_steps, args.updates, args.suite, args.split, args.epochs)
        row = {"round": r + 1, "envs": args.envs, "model": args.model, "epochs": args.epochs, "load_1m": round(load, 2),
               "state_only_scenario_steps_per_s": so["scenario_steps_per_s"], **pp}
        for k, v in row.items():
            if k.endswith("_per_s"):
                best[k] = max(best.get(k, 0.0), v)
        print(json.dumps(row) if args.json else
              f"round {r + 1}  B={args.envs}  state_only {so['scenario_steps_per_s']:,.0f}  "
              f"ppo {pp['ppo_env_steps_per_s']:,.0f}  ppo_collect {pp['ppo_collect_env_steps_per_s']:,.0f} "
              f"env-steps/s  (ppo compile {pp['ppo_compile_s']:.1f} s, load {load:.2f})", flush=True)
    ratio = best["ppo_env_steps_per_s"] / best["state_only_scenario_steps_per_s"]
    collect = best["ppo_collect_env_steps_per_s"] / best["state_only_scenario_steps_per_s"]
    print(json.dumps({"ratio_ppo_vs_state_only": ratio, "ratio_collect_vs_state_only": collect}) if args.json else
          f"best of {args.rounds}: ppo {ratio:.3f}x state-only, collection alone {collect:.3f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
