"""Replay-artifact study: how many failed episodes are artefacts of non-reactive replay?

Under log replay nobody yields: a policy that brakes correctly can be hit from
behind by a logged follower, and the paper's protocol counts that collision.
This study evaluates every policy on one split under three views

  (a) ``all``       every collision with a logged agent counts (the paper);
  (b) ``at_fault``  only the collisions nuPlan's attribution puts on the ego
                    (the same rollout as (a): both views are columns of it);
  (c) ``idm``       logged vehicles react with IDM (``--agents idm``), every
                    collision counts,

and reports the share of episodes failed under (a) that pass under (b) or (c)
-- failures that are replay artefacts -- overall and per behaviour group, as
markdown and CSV tables and a bar plot.

    python experiments/replay_artifacts/run.py --out results/replay_artifacts
    python experiments/replay_artifacts/run.py --out results/replay_artifacts \\
        --policy vector_transformer:checkpoint=runs/vector_transformer,name=vector_transformer
    python experiments/replay_artifacts/run.py --out /tmp/smoke --limit 8      # smoke run

Resumable: each view is one ``drivee2e bench`` results folder
(``OUT/bench-log``, ``OUT/bench-idm``) and bench skips the policies it already
finished with the same inputs. Writes ``OUT/artifacts.md``, ``OUT/artifacts.csv``,
``OUT/per_behaviour.csv``, ``OUT/collisions.csv`` (collisions by nuPlan type
and fault), ``OUT/artifacts.png`` and ``OUT/provenance.json``
(commands, wall time per view).

Bad input (a policy bench rejects, an unknown suite or split) prints bench's
one-line error and exits with its code.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))  # `python experiments/replay_artifacts/run.py` without an install

from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from drivee2e_jax.eval.results import read_policy_file, rows_to_csv  # noqa: E402
from drivee2e_jax.eval.summary import BEHAVIOR_ORDER  # noqa: E402
from drivee2e_jax.files import atomic_write_json, atomic_write_text  # noqa: E402

#: Policies shipped by name evaluated by default (trained ones come with --policy).
REFERENCES = ("log_replay", "expert", "constant_velocity", "stop")
#: bench folder per agent model.
VIEWS = {"log": "bench-log", "idm": "bench-idm"}


def bench(out: Path, agents: str, args, policies: list[str]) -> tuple[list[str], float]:
    """Run (or resume) ``drivee2e bench`` for one agent model; (command, seconds)."""
    cmd = [sys.executable, "-m", "drivee2e_jax.cli", "bench", "--suite", args.suite, "--split", args.split,
           "--out", str(out / VIEWS[agents]), "--agents", agents, "--collisions", "all", "--no-progress"]
    if args.limit:
        cmd += ["--limit", str(args.limit)]
    for p in policies:
        cmd += ["--policy", p]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=REPO)
    if proc.returncode:
        sys.exit(proc.returncode)
    return cmd, time.perf_counter() - t0


def load_rows(folder: Path) -> tuple[dict[str, dict[str, dict]], dict[str, list[dict]]]:
    """({policy: {scenario_id: row}}, {policy: [collision event, ...]}) of a bench results folder."""
    rows, collisions = {}, {}
    for f in sorted((folder / "policies").glob("*.json")):
        data = read_policy_file(f)
        pol = str(data["policy"])
        rows[pol] = {r["scenario_id"]: r for r in data["rows"] if r.get("repetition", 0) == 0}
        collisions[pol] = [e for evs in data["events"].values() for e in evs if e["type"].startswith("collisions_")]
    return rows, collisions


#: Collision types in the breakdown table (``types.COLLISION_TYPE_NAMES`` + static layout).
COLLISION_TYPES = ("stopped_ego", "stopped_track", "active_front", "active_rear", "active_lateral", "static")


def collision_breakdown(collisions: dict[str, list[dict]]) -> list[dict]:
    """Per policy: counted collision events under (a) by nuPlan type, and how many were at fault."""
    out = []
    for pol, evs in collisions.items():
        row = {"policy": pol, "collisions": len(evs), "at_fault": sum(bool(e.get("at_fault")) for e in evs)}
        row.update({k: sum(e.get("collision_type") == k for e in evs) for k in COLLISION_TYPES})
        out.append(row)
    return out


def artifact_counts(log_rows: dict[str, dict], idm_rows: dict[str, dict], ids) -> dict:
    """Counts over scenario ids ``ids``: failed under (a), of those passing under (b), (c), either."""
    failed = [s for s in ids if not log_rows[s]["success_all"]]
    b = [s for s in failed if log_rows[s]["success_at_fault"]]
    c = [s for s in failed if s in idm_rows and idm_rows[s]["success"]]
    either = sorted(set(b) | set(c))
    n = len(ids)
    pct = lambda k: round(100.0 * k / len(failed), 1) if failed else None  # noqa: E731
    mean = lambda rows, key: round(sum(float(rows[s][key]) for s in ids) / n, 2) if n else None  # noqa: E731
    return {
        "episodes": n,
        "failed_all": len(failed),
        "pass_at_fault": len(b),
        "pass_idm": len(c),
        "artifacts": len(either),
        "artifacts_pct_of_failed": pct(len(either)),
        "at_fault_pct_of_failed": pct(len(b)),
        "idm_pct_of_failed": pct(len(c)),
        "sr_all": round(100.0 * (n - len(failed)) / n, 1) if n else None,
        "sr_at_fault": round(100.0 * sum(bool(log_rows[s]["success_at_fault"]) for s in ids) / n, 1) if n else None,
        "sr_idm": round(100.0 * sum(bool(idm_rows[s]["success"]) for s in ids if s in idm_rows) / n, 1) if n else None,
        "ds_all": mean(log_rows, "driving_score_all"),
        "ds_at_fault": mean(log_rows, "driving_score_at_fault"),
        "ds_idm": mean(idm_rows, "driving_score") if set(ids) <= set(idm_rows) else None,
    }


def tables(log: dict, idm: dict) -> tuple[list[dict], list[dict]]:
    """(overall rows, per-behaviour rows), one per policy (x behaviour)."""
    overall, per_beh = [], []
    for pol, rows in log.items():
        ids = sorted(rows)
        overall.append({"policy": pol, **artifact_counts(rows, idm.get(pol, {}), ids)})
        for beh in BEHAVIOR_ORDER:
            sel = [s for s in ids if rows[s]["behavior"] == beh]
            if sel:
                per_beh.append({"policy": pol, "behavior": beh, **artifact_counts(rows, idm.get(pol, {}), sel)})
    return overall, per_beh


def _fmt(v) -> str:
    return "-" if v is None else str(v)


def markdown(overall: list[dict], per_beh: list[dict], breakdown: list[dict]) -> str:
    cols = ("policy", "episodes", "failed_all", "pass_at_fault", "pass_idm", "artifacts", "artifacts_pct_of_failed",
            "sr_all", "sr_at_fault", "sr_idm", "ds_all", "ds_at_fault", "ds_idm")
    head = ("policy", "episodes", "failed (a)", "pass (b) at-fault", "pass (c) IDM", "artefacts (b or c)",
            "artefacts % of failed", "SR (a)", "SR (b)", "SR (c)", "DS (a)", "DS (b)", "DS (c)")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(_fmt(r[c]) for c in cols) + " |" for r in overall]
    lines += ["", "Artefacts as % of the failed episodes, per behaviour group (failed under (a) / episodes):", ""]
    pols = [r["policy"] for r in overall]
    behs = [b for b in BEHAVIOR_ORDER if any(r["behavior"] == b for r in per_beh)]
    lines += ["| policy | " + " | ".join(behs) + " |", "|" + "---|" * (len(behs) + 1)]
    for p in pols:
        cells = []
        for b in behs:
            r = next((x for x in per_beh if x["policy"] == p and x["behavior"] == b), None)
            cells.append("-" if r is None else f"{_fmt(r['artifacts_pct_of_failed'])} ({r['failed_all']}/{r['episodes']})")
        lines.append(f"| {p} | " + " | ".join(cells) + " |")
    lines += ["", "Collisions counted under (a), by nuPlan type (static = layout), and how many were at fault:", ""]
    cols = ("collisions", "at_fault", *COLLISION_TYPES)
    lines += ["| policy | " + " | ".join(c.replace("_", " ") for c in cols) + " |", "|" + "---|" * (len(cols) + 1)]
    lines += [f"| {r['policy']} | " + " | ".join(str(r[c]) for c in cols) + " |" for r in breakdown]
    return "\n".join(lines) + "\n"


def plot(overall: list[dict], path: Path) -> None:
    """Stacked bars per policy: failed episodes under (a), split into artefacts and real failures."""
    fig = Figure(figsize=(7.5, 3.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    names = [r["policy"] for r in overall]
    b_only = [r["pass_at_fault"] for r in overall]
    c_extra = [r["artifacts"] - r["pass_at_fault"] for r in overall]
    real = [r["failed_all"] - r["artifacts"] for r in overall]
    x = range(len(names))
    ax.bar(x, real, color="#7f7f7f", label="fails in every view")
    ax.bar(x, b_only, bottom=real, color="#1f77b4", label="passes when only at-fault collisions count (b)")
    ax.bar(x, c_extra, bottom=[a + b for a, b in zip(real, b_only)], color="#ff7f0e",
           label="passes with IDM agents (c), not under (b)")
    ax.set_xticks(list(x), names, rotation=20, ha="right")
    ax.set_ylabel("failed episodes under (a)")
    ax.legend(fontsize=8, frameon=False, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="example: python experiments/replay_artifacts/run.py --out /tmp/ra --limit 8")
    ap.add_argument("--out", type=Path, required=True, help="study folder (resumable)")
    ap.add_argument("--suite", default="twin15")
    ap.add_argument("--split", default="val")
    ap.add_argument("--limit", type=int, default=None, help="first N scenarios only (smoke runs)")
    ap.add_argument("--policy", action="append", default=[],
                    help="extra policy spec as bench takes it (repeatable), e.g. a trained checkpoint")
    ap.add_argument("--references", default=",".join(REFERENCES),
                    help=f"comma-separated policies shipped by name (default {','.join(REFERENCES)})")
    args = ap.parse_args(argv)
    policies = [p for p in args.references.split(",") if p] + list(args.policy)
    args.out.mkdir(parents=True, exist_ok=True)
    prov = {"policies": policies, "views": {}}
    for agents in VIEWS:
        cmd, secs = bench(args.out, agents, args, policies)
        prov["views"][agents] = {"command": " ".join(cmd[1:]), "wall_s": round(secs, 1)}
    (log, collisions), (idm, _) = load_rows(args.out / VIEWS["log"]), load_rows(args.out / VIEWS["idm"])
    overall, per_beh = tables(log, idm)
    breakdown = collision_breakdown(collisions)
    atomic_write_text(args.out / "artifacts.md", markdown(overall, per_beh, breakdown))
    atomic_write_text(args.out / "artifacts.csv", rows_to_csv(overall, list(overall[0])))
    atomic_write_text(args.out / "per_behaviour.csv", rows_to_csv(per_beh, list(per_beh[0])))
    plot(overall, args.out / "artifacts.png")
    atomic_write_json(args.out / "provenance.json", prov)
    atomic_write_text(args.out / "collisions.csv", rows_to_csv(breakdown, list(breakdown[0])))
    print(markdown(overall, per_beh, breakdown))
    print(json.dumps(prov["views"], indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
