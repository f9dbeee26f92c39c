"""Plot a training run's JSON-lines log (``RUN/log.jsonl``).

    python experiments/training/plot_log.py runs/ad_mlp [--out runs/ad_mlp/loss.png]

Left: the loss per logged step (and per-epoch means); right: the learning
rate. Metrics other than the loss (e.g. ``l2``) are drawn on the left too.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def read_log(run: Path) -> tuple[list[dict], list[dict]]:
    """(step rows, epoch rows) of ``run/log.jsonl``."""
    f = run / "log.jsonl"
    if not f.is_file():
        sys.exit(f"plot_log: {f}: no training log")
    rows = [json.loads(ln) for ln in f.read_text().splitlines() if ln.strip()]
    return [r for r in rows if "event" not in r], [r for r in rows if r.get("event") == "epoch"]


def plot(run: Path, out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from drivee2e_jax.files import atomic_write

    steps, epochs = read_log(run)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    x = [r["step"] for r in steps]
    a.plot(x, [r["loss"] for r in steps], lw=1, label="loss")
    for k in sorted({k for r in steps for k in r.get("metrics", {})} - {"l1"}):
        a.plot(x, [r["metrics"].get(k) for r in steps], lw=1, alpha=0.7, label=k)
    a.plot([r["step"] for r in epochs], [r["loss"] for r in epochs], "o", color="k", label="epoch mean loss")
    a.set_yscale("log")
    a.set_xlabel("step")
    a.legend(fontsize=8)
    a.grid(alpha=0.3)
    b.plot(x, [r["lr"] for r in steps])
    b.set_xlabel("step")
    b.set_ylabel("learning rate")
    b.grid(alpha=0.3)
    fig.suptitle(str(run))
    fig.tight_layout()
    atomic_write(out, lambda f: fig.savefig(f, format="png", dpi=110), binary=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Plot RUN/log.jsonl (loss and learning rate).")
    p.add_argument("run", type=Path, help="training run folder")
    p.add_argument("--out", type=Path, default=None, help="png path (default: RUN/loss.png)")
    args = p.parse_args(argv)
    print(plot(args.run, args.out or args.run / "loss.png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
