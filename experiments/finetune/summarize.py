"""Tables for docs/finetuning.md: closed-loop results of IL vs fine-tuned policies
and the loss terms over a fine-tuning run.

Usage::

    python experiments/finetune/summarize.py results/finetune-val            # bench results
    python experiments/finetune/summarize.py --log runs/finetune/vt          # training log
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

RESULT_COLS = ("driving_score", "success_rate", "route_completion", "infraction_score", "collisions_per_km",
               "red_light_per_km", "outside_route_lanes_pct", "l2_1s_stp3", "l2_2s_stp3", "openloop_collision_rate")
COUNT_COLS = ("collisions_vehicle", "collisions_pedestrian", "collisions_cyclist_motorcycle", "collisions_layout",
              "red_light", "route_dev", "vehicle_blocked", "route_timeout")


def results_table(folder: Path) -> str:
    from drivee2e_jax.eval.summary import summary_of

    lines = ["| policy | " + " | ".join(RESULT_COLS) + " | " + " | ".join(COUNT_COLS) + " |",
             "|---" * (1 + len(RESULT_COLS) + len(COUNT_COLS)) + "|"]
    for f in sorted((folder / "policies").glob("*.json")):
        d = json.loads(f.read_text())
        s = summary_of(d["rows"])
        vals = [s.get(c) for c in RESULT_COLS]
        counts = [int(sum(bool(r.get(c)) for r in d["rows"])) for c in COUNT_COLS]  # scenarios with >= 1
        cell = lambda v: "-" if v is None else (f"{v:.3f}" if isinstance(v, float) else str(v))
        lines.append(f"| {d['policy']} | " + " | ".join(cell(v) for v in vals) + " | "
                     + " | ".join(map(str, counts)) + " |")
    return "\n".join(lines)


def paired(folder: Path, a: str, b: str) -> str:
    """Per-scenario DS differences b - a (same scenarios)."""
    rows = {f.stem: {r["scenario_id"]: r for r in json.loads(f.read_text())["rows"]}
            for f in (folder / "policies").glob("*.json")}
    if a not in rows or b not in rows:
        return ""
    ids = sorted(set(rows[a]) & set(rows[b]))
    d = np.array([rows[b][i]["driving_score"] - rows[a][i]["driving_score"] for i in ids])
    return (f"{b} - {a}: mean DS diff {d.mean():+.2f} (se {d.std(ddof=1) / np.sqrt(len(d)):.2f}, n={len(d)}); "
            f"better on {(d > 1e-6).sum()}, worse on {(d < -1e-6).sum()}, equal on {(np.abs(d) <= 1e-6).sum()}")


def log_table(run: Path, window: int = 50) -> str:
    rows = [json.loads(ln) for ln in (run / "log.jsonl").read_text().splitlines() if ln.strip()]
    terms = list(rows[0]["terms"])
    lines = ["| steps | loss | " + " | ".join(terms) + " | grad norm (median / max) |", "|---" * (3 + len(terms)) + "|"]
    last = rows[-1]["step"]
    for lo in range(0, last, window):
        w = [r for r in rows if lo < r["step"] <= lo + window]
        if not w:
            continue
        g = [r["grad_norm"] for r in w]
        lines.append(f"| {lo + 1}-{lo + window} | {np.mean([r['loss'] for r in w]):.3f} | "
                     + " | ".join(f"{np.mean([r['terms'][t] for r in w]):.4f}" for t in terms)
                     + f" | {np.median(g):.1f} / {np.max(g):.1f} |")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("results", nargs="?", type=Path)
    p.add_argument("--log", type=Path, help="a drivee2e finetune run folder")
    p.add_argument("--pair", nargs=2, metavar=("A", "B"), default=("vt_il", "vt_ft"))
    args = p.parse_args()
    if args.results:
        print(results_table(args.results))
        print(paired(args.results, *args.pair))
    if args.log:
        print(log_table(args.log))


if __name__ == "__main__":
    main()
