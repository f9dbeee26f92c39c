"""The RL study (issue 21): PPO from scratch and PPO fine-tuning of the imitation transformer.

    python experiments/rl/run.py --out results/rl --runs runs/rl --init runs/baselines/vector_transformer
    python experiments/rl/run.py --out results/rl --runs runs/rl --init ... --minutes ppo_scratch=120,ppo_ft=40
    python experiments/rl/run.py --out /tmp/rl-smoke --runs /tmp/rl-runs --init RUN --smoke   # minutes, not hours

1. **Train** each run of ``RUNS`` below (from scratch; fine-tuning; the
   fine-tuning with gamma 0.999) with ``drivee2e rl`` (fixed
   hyperparameters, one seed) for its training-time budget (``--minutes``;
   ``drivee2e rl --time-limit``). A run stopped by its budget or interrupted
   continues with ``--resume`` (exactly: the checkpoint holds the environments
   and the RNG); a run that has used its budget or all its env steps is skipped.
2. **Curves**: ``drivee2e trend RUN --split val`` scores every checkpoint
   closed-loop (SR, DS) and open-loop on twin15 val (reused on a rerun);
   ``OUT/curves.png`` plots the training episodes' DS and return (rolling mean
   over updates, from ``RUN/log.jsonl``) and the val DS of the checkpoints,
   against env steps and against training minutes.
3. **Evaluate** the last checkpoint of each run next to the imitation
   transformer (``--init``) in one ``drivee2e bench --open-loop`` folder
   (``OUT/bench-val``; resumes), and write ``OUT/table4.md|csv`` and
   ``OUT/per_behaviour.md|csv`` with ``experiments/baselines/run.py``'s
   tabulation, plus ``OUT/provenance.json`` (commands, env steps, minutes).

Results and the reading: docs/results.md ("Reinforcement learning").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "baselines"))

import run as baselines  # noqa: E402  (experiments/baselines/run.py: the tabulation)

from drivee2e_jax.errors import DriveE2EError  # noqa: E402
from drivee2e_jax.files import atomic_write_json  # noqa: E402
from drivee2e_jax.models import checkpoint as ckpt  # noqa: E402

#: name -> (uses --init, drivee2e rl flags, default training minutes). One seed each.
RUNS = {
    "ppo_scratch": (False, ["--env-steps", "50000000", "--epochs", "2", "--lr", "3e-4", "--init-log-std", "-0.5",
                            "--ckpt-every", "50"], 40.0),
    "ppo_ft": (True, ["--env-steps", "3000000", "--critic-warmup", "10", "--lr", "1e-5", "--critic-lr", "3e-4",
                      "--epochs", "2", "--init-log-std", "-1.2", "--ckpt-every", "50"], 40.0),
    # ppo_ft with gamma 0.999: at 0.99 per 0.1 s step, progress delayed 20 s by a red light is
    # discounted to 0.13, far more than the red light's penalty costs (ppo_ft lost its STP stops).
    "ppo_ft_g999": (True, ["--env-steps", "3000000", "--critic-warmup", "10", "--lr", "1e-5", "--critic-lr", "3e-4",
                           "--epochs", "2", "--init-log-std", "-1.2", "--ckpt-every", "50", "--gamma", "0.999"], 25.0),
    # From scratch with the MLP actor (models/vector_mlp.py): ~10x the transformer's env steps per second
    # (VmapAutoResetWrapper, a cheap learner); two waypoints (only wp0 / wp1 set the controller's speed, so
    # the other four only add noise to the gradient) and an initial straight-ahead plan at 5 m/s.
    "ppo_scratch_mlp": (False, ["--model", "vector_mlp", "--model-config", "init_speed=5,num_waypoints=2",
                                "--envs", "256", "--rollout-steps", "32", "--epochs", "4", "--minibatches", "4",
                                "--lr", "3e-4", "--init-log-std", "-0.5", "--env-steps", "100000000",
                                "--ckpt-every", "100"], 60.0),
}
SMOKE = ["--envs", "8", "--rollout-steps", "8", "--minibatches", "2", "--ckpt-every", "2", "--limit", "8",
         "--env-steps", "256"]


def trained_minutes(run_dir: Path) -> float:
    """Training minutes of a run, summed over its resumed segments (``time``
    restarts at 0 in each process)."""
    f = run_dir / "log.jsonl"
    if not f.is_file():
        return 0.0
    total, last, prev = 0.0, 0.0, -1.0
    for line in f.read_text().splitlines():
        if not line.strip():
            continue
        t = float(json.loads(line).get("time", 0.0))
        if t < prev:
            total, last = total + last, 0.0
        prev, last = t, t
    return (total + last) / 60.0


def rl_command(name: str, runs: Path, init: Path | None, minutes: float, smoke: bool, resume: bool) -> list[str]:
    uses_init, flags, _ = RUNS[name]
    cmd = ["drivee2e", "rl", "--out", str(runs / name), "--no-progress", *flags]
    if uses_init:
        cmd += ["--init", str(init)]
    if smoke:
        cmd += SMOKE
    cmd += ["--time-limit", f"{minutes:.3f}"]
    return cmd + (["--resume"] if resume else [])


def _run(cmd: list[str], log_file: Path) -> None:
    log_file.parent.mkdir(parents=True, exist_ok=True)
    with open(log_file, "a", encoding="utf-8") as f:
        f.write(f"$ {' '.join(cmd)}\n")
        f.flush()
        code = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, check=False).returncode
    if code:
        raise DriveE2EError(f"{' '.join(cmd[:3])} failed with exit code {code}; see {log_file}")


def train(name: str, args, log) -> dict:
    run_dir = args.runs / name
    budget = args.minutes.get(name, RUNS[name][2])
    done_min = trained_minutes(run_dir)
    ckpts = ckpt.list_checkpoints(run_dir)
    finished = bool(ckpts) and _finished(run_dir)
    if finished or done_min >= budget:
        log(f"[rl {name}] {run_dir}: {done_min:.1f} of {budget:.0f} min trained{', all env steps done' if finished else ''}; skipped")
    else:
        cmd = rl_command(name, args.runs, args.init, budget - done_min, args.smoke, resume=bool(ckpts))
        log(f"[rl {name}] {' '.join(cmd)}")
        _run(cmd, args.out / "logs" / f"rl-{name}.log")
    last = ckpt.read_meta(ckpt.list_checkpoints(run_dir)[-1])
    return {"command": " ".join(rl_command(name, args.runs, args.init, budget, args.smoke, False)),
            "train_min": round(trained_minutes(run_dir), 2), "env_steps": last.get("env_steps"),
            "updates": last.get("step")}


def _finished(run_dir: Path) -> bool:
    cfg = json.loads((run_dir / "config.json").read_text())["ppo"]
    per_update = cfg["num_envs"] * cfg["rollout_steps"]
    total = -(-cfg["total_env_steps"] // per_update)
    return int(ckpt.read_meta(ckpt.list_checkpoints(run_dir)[-1])["step"]) >= total


def trend(name: str, args, log) -> list[dict]:
    out = args.out / f"trend-{name}"
    cmd = ["drivee2e", "trend", str(args.runs / name), "--split", "val", "--out", str(out)]
    if args.smoke:
        cmd += ["--limit", "4"]
    log(f"[trend {name}] {' '.join(cmd)}")
    _run(cmd, args.out / "logs" / f"trend-{name}.log")
    rows = [json.loads(p.read_text()) for p in sorted((out / "checkpoints").glob("*.json"))]
    return sorted(rows, key=lambda r: r["epoch"])


def run_model(run_dir: Path) -> str:
    """The model a PPO run trains (its ``config.json``): the zoo file that loads it."""
    return json.loads((run_dir / "config.json").read_text())["model"]


def bench(args, names: list[str], log) -> Path:
    bdir = args.out / "bench-val"
    cmd = ["drivee2e", "bench", "--split", "val", "--open-loop", "--no-progress", "--out", str(bdir),
           "--policy", f"vector_transformer:checkpoint={args.init},name=vector_transformer"]
    for n in names:
        cmd += ["--policy", f"{run_model(args.runs / n)}:checkpoint={args.runs / n},name={n}"]
    if args.smoke:
        cmd += ["--limit", "4"]
    log(f"[eval] {' '.join(cmd)}")
    _run(cmd, args.out / "logs" / "bench-val.log")
    return bdir


def _rolling(xs: list[float], k: int = 20) -> list[float]:
    out, acc = [], []
    for x in xs:
        acc = (acc + [x])[-k:]
        vals = [v for v in acc if v is not None]
        out.append(sum(vals) / len(vals) if vals else float("nan"))
    return out


def plot_curves(args, names: list[str], trends: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    for n in names:
        rows = [json.loads(ln) for ln in (args.runs / n / "log.jsonl").read_text().splitlines() if ln.strip()]
        steps = [r["env_steps"] / 1e6 for r in rows]
        minutes, off, prev = [], 0.0, -1.0
        for r in rows:  # training minutes across resumed segments
            if r["time"] < prev:
                off += prev
            prev = r["time"]
            minutes.append((off + r["time"]) / 60.0)
        for row, x in ((0, steps), (1, minutes)):
            axes[row, 0].plot(x, _rolling([r.get("episode_ds") for r in rows]), label=n)
            axes[row, 1].plot(x, _rolling([r.get("episode_return") for r in rows]), label=n)
        t = trends.get(n, [])
        if t:
            axes[0, 2].plot([(r.get("env_steps") or 0) / 1e6 for r in t], [r["driving_score"] for r in t], "o-", label=n)
            per_update = {r["update"]: m for r, m in zip(rows, minutes, strict=True)}
            axes[1, 2].plot([per_update.get(r["epoch"], 0.0) for r in t], [r["driving_score"] for r in t], "o-", label=n)
    for row, xl in ((0, "env steps (millions, log scale)"), (1, "training minutes")):
        for col, yl in ((0, "train episodes: DS (rolling mean)"), (1, "train episodes: return, m"), (2, "val DS (checkpoints)")):
            ax = axes[row, col]
            if row == 0:  # the runs span 0.3 M to tens of millions of env steps
                ax.set_xscale("log")
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.suptitle("PPO on twin15 (train episodes are stochastic; val DS is the deterministic policy)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def parse_minutes(text: str) -> dict:
    out = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        k, sep, v = item.partition("=")
        if not sep or k not in RUNS:
            raise DriveE2EError(f"--minutes: bad item {item!r} (expected NAME=MIN with NAME in {', '.join(RUNS)})")
        try:
            out[k] = float(v)
        except ValueError as e:
            raise DriveE2EError(f"--minutes: {k}={v!r} is not a number") from e
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--out", type=Path, required=True, help="tables, curves and logs folder")
    ap.add_argument("--runs", type=Path, default=Path("runs/rl"), help="PPO run folders (default: runs/rl)")
    ap.add_argument("--init", type=Path, required=True, help="the imitation vector_transformer run (drivee2e train)")
    ap.add_argument("--runs-to-do", default=",".join(RUNS), help=f"comma-separated (default: {','.join(RUNS)})")
    ap.add_argument("--minutes", type=parse_minutes, default={},
                    help="training minutes per run, NAME=MIN,... (default: " + ",".join(f"{k}={v[2]:.0f}" for k, v in RUNS.items()) + ")")
    ap.add_argument("--smoke", action="store_true", help="8 environments x 8 steps on 8 scenarios; trend and bench on 4")
    ap.add_argument("--eval-only", action="store_true", help="do not train; curves and tables of the existing runs")
    try:
        args = ap.parse_args(argv)
        names = [n for n in (s.strip() for s in args.runs_to_do.split(",")) if n]
        bad = [n for n in names if n not in RUNS]
        if bad:
            raise DriveE2EError(f"--runs-to-do: unknown run(s) {', '.join(bad)} (expected some of {', '.join(RUNS)})")
        ckpt.resolve(args.init)
        args.out.mkdir(parents=True, exist_ok=True)
        log = lambda s: print(time.strftime("%H:%M:%S"), s, flush=True)
        training = {n: (train(n, args, log) if not args.eval_only else {}) for n in names}
        trends = {n: trend(n, args, log) for n in names}
        plot_curves(args, names, trends, args.out / "curves.png")
        bdir = bench(args, names, log)
        t4, beh = baselines.build_tables(
            bdir, [("vector_transformer", "vector_transformer")] + [(n, run_model(args.runs / n)) for n in names], {})
        baselines.write_tables(args.out, t4, beh)
        atomic_write_json(args.out / "provenance.json", {"runs": training, "init": str(args.init),
                                                        "trend_last": {n: t[-1] if t else None for n, t in trends.items()}})
        print((args.out / "table4.md").read_text())
        return 0
    except DriveE2EError as e:
        print(f"rl: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
