"""Suites larger than memory: time and peak memory of a streamed evaluation vs suite size.

    python experiments/perf/large_suite.py --suite suites/twin15_800 --suite suites/twin15_8k \\
        --suite suites/twin15_80k --out /tmp/large_suite [--in-memory suites/twin15_800] [--plot docs/img/large_suite.png]

Each suite folder (``drivee2e suite generate --scenarios N --out DIR``) is
evaluated in a FRESH process with ``log_replay`` over every scenario of
every split, streamed in shards of ``--shard-size`` (``eval.stream`` over
``scenario.stream.shards``: the next shard read and packed in a thread, a
shard's rows computed in a thread while the next one steps). Per suite it
records: scenarios, the simulated scenario-steps and valid agent-steps
(agents valid in the log at each simulated step, the ego included), wall
time in all (reading + packing + compiling + stepping + rows), compile
time, peak resident memory of the process (``ru_maxrss``), and the
scenario-steps/s. The result rows are written to ``<out>/<suite>.rows.jsonl``
as each shard finishes (nothing accumulates in memory), the figures to
``<out>/<suite>.json``; a suite already measured there is skipped
(resumable; ``--force`` to redo).

``--tile SRC K OUT`` writes OUT: the suite folder SRC with every scenario
K times, copy r under the id ``<id>_r<r>`` (its file and suite.json entry;
the same split, behaviour and intersection), the maps and ``pack_sizes``
unchanged. It makes a suite of 80,000 scenario files from the 8,000
generated ones in minutes, where generating 80,000 takes ~75 min of both
cores here; the streamed evaluation does the same work per scenario file
either way (each copy is read, validated, packed and stepped).

``--in-memory DIR`` also evaluates DIR in one batch (``evaluate`` on
``load_suite(DIR).pack(None)``), in a fresh process, and checks that its
rows equal the streamed rows (statuses, events and every column but
``eval_time_s``; floats to 1e-6 relative).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path


def _measure_stream(folder: Path, shard_size: int, rows_path: Path) -> dict:
    import numpy as np

    from drivee2e_jax.eval.stream import evaluate_stream
    from drivee2e_jax.policy import load_policy, resolve_policy_path
    from drivee2e_jax.scenario.stream import SuiteIndex, shards

    t0 = time.perf_counter()
    index = SuiteIndex.open(folder)
    n = len(index)
    counted = {"agent_steps": 0, "scenario_steps": 0, "agents_mean": 0.0}

    def counting(it):
        for rows, packed in it:
            valid = np.asarray(packed.scenario.tracks.valid)[:, :, 1:]
            counted["agent_steps"] += int(valid.sum())
            counted["scenario_steps"] += int(valid.shape[0] * valid.shape[2])
            counted["agents_mean"] += float(valid.any(axis=2).sum())
            yield rows, packed

    tmp = rows_path.with_suffix(".tmp")
    with tmp.open("w") as fh:
        def write(rows, events):
            for r in rows:
                fh.write(json.dumps({**r, "events": events.get(r["scenario_id"], [])}) + "\n")

        res = evaluate_stream(load_policy(resolve_policy_path("log_replay")),
                              counting(shards(index, None, shard_size)), n, keep_rows=False, on_shard=write)
    os.replace(tmp, rows_path)
    wall = time.perf_counter() - t0
    return {"suite": folder.name, "mode": "stream", "shard_size": shard_size, "scenarios": n,
            "agent_rows": int(index.sizes.as_dict().get("agents", 0)) if hasattr(index.sizes, "as_dict") else None,
            "mean_agents": round(counted["agents_mean"] / n, 2), "simulated_steps": res.steps,
            "scenario_steps": counted["scenario_steps"],  # scenarios x the padded log steps (T - 1)
            "agent_steps": counted["agent_steps"], "wall_s": round(wall, 2), "compile_s": round(res.compile_s, 2),
            "scenario_steps_per_s": round(counted["scenario_steps"] / wall),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            "warnings": res.warnings}


def _measure_in_memory(folder: Path, rows_path: Path) -> dict:
    from drivee2e_jax.eval.closedloop import evaluate
    from drivee2e_jax.policy import load_policy, resolve_policy_path
    from drivee2e_jax.scenario import load_suite

    t0 = time.perf_counter()
    packed = load_suite(folder).pack(None)
    res = evaluate(load_policy(resolve_policy_path("log_replay")), packed, None)
    with rows_path.open("w") as fh:
        for r in res.rows:
            fh.write(json.dumps({**r, "events": res.events.get(r["scenario_id"], [])}) + "\n")
    wall = time.perf_counter() - t0
    return {"suite": folder.name, "mode": "in_memory", "scenarios": len(packed), "wall_s": round(wall, 2),
            "compile_s": round(res.compile_s, 2),
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}


def _same_rows(a_path: Path, b_path: Path) -> str:
    """'' when the two row files agree (every column but eval_time_s; floats to 1e-6 relative), else the first difference."""
    a = [json.loads(x) for x in a_path.read_text().splitlines()]
    b = [json.loads(x) for x in b_path.read_text().splitlines()]
    if [r["scenario_id"] for r in a] != [r["scenario_id"] for r in b]:
        return "different scenarios or order"
    for ra, rb in zip(a, b):
        for k in ra.keys() | rb.keys():
            if k == "eval_time_s":
                continue
            va, vb = ra.get(k), rb.get(k)
            if isinstance(va, float) and isinstance(vb, float):
                if abs(va - vb) > 1e-6 * max(abs(va), abs(vb), 1e-9):
                    return f"{ra['scenario_id']}: {k} {va} vs {vb}"
            elif va != vb:
                return f"{ra['scenario_id']}: {k} {va!r} vs {vb!r}"
    return ""


def tile(src: Path, k: int, out: Path) -> None:
    """``out`` = ``src`` with every scenario ``k`` times (see the module docstring)."""
    head = json.loads((src / "suite.json").read_text())
    if out.exists():
        raise SystemExit(f"--tile: {out} exists; expected a new folder")
    tmp = out.parent / f".{out.name}.tmp"
    (tmp / "scenarios").mkdir(parents=True, exist_ok=True)
    (tmp / "maps").mkdir(exist_ok=True)
    for m in (src / "maps").glob("*.json"):
        (tmp / "maps" / m.name).write_bytes(m.read_bytes())
    entries = []
    for r in range(k):
        for e in head["scenarios"]:
            sid = e["id"]
            new = f"{sid}_r{r}"
            data = (src / "scenarios" / f"{sid}.json").read_bytes()
            old_key = f'"scenario_id":"{sid}"'.encode()
            if data.count(old_key) != 1:
                raise SystemExit(f"--tile: {sid}.json: expected one {old_key.decode()}")
            (tmp / "scenarios" / f"{new}.json").write_bytes(data.replace(old_key, f'"scenario_id":"{new}"'.encode()))
            entries.append({**e, "id": new})
    meta = {**head["meta"], "num_scenarios": len(entries),
            "tiled": {"from": str(src), "copies": k, "ids": "<id>_r<copy>"}}
    head = {**head, "name": f"{head['name']}-tiled{k}", "meta": meta, "scenarios": entries}
    (tmp / "suite.json").write_text(json.dumps(head, separators=(",", ":")))
    os.replace(tmp, out)


def _child(args) -> int:
    folder = Path(args._one)
    out = Path(args.out)
    if args._mode == "stream":
        row = _measure_stream(folder, args.shard_size, out / f"{folder.name}.rows.jsonl")
    else:
        row = _measure_in_memory(folder, out / f"{folder.name}.in_memory.rows.jsonl")
    print(json.dumps(row), flush=True)
    return 0


def _run_child(folder: Path, mode: str, args) -> dict:
    cmd = [sys.executable, __file__, "--_one", str(folder), "--_mode", mode, "--out", str(args.out),
           "--shard-size", str(args.shard_size)]
    load = os.getloadavg()[0]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"{folder} ({mode}) failed: {proc.stderr.strip()[-2000:]}")
    row = json.loads(proc.stdout.strip().splitlines()[-1])
    row["load_1min_before"] = round(load, 2)
    return row


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted((r for r in rows if r["mode"] == "stream"), key=lambda r: r["scenarios"])
    n = [r["scenarios"] for r in rows]
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    after = [r["wall_s"] - r["compile_s"] for r in rows]  # after the first shard's read + compile + first chunk
    ax[0].loglog(n, [r["wall_s"] for r in rows], "o-", label="in all")
    ax[0].loglog(n, after, "s-", label="after the first shard's compile")
    ax[0].loglog(n, [after[-1] * k / n[-1] for k in n], "--", color="grey", label="linear (through the largest)")
    ax[0].set(xlabel="scenarios", ylabel="wall time, s (read + pack + step + rows)")
    ax[0].legend()
    ax[1].semilogx(n, [r["peak_rss_mb"] / 1024 for r in rows], "o-")
    ax[1].axhline(6.0, color="red", ls=":", label="6 GB bound")
    ax[1].set(xlabel="scenarios", ylabel="peak resident memory, GB", ylim=(0, 7))
    ax[1].legend()
    ax[2].loglog([r["agent_steps"] for r in rows], [r["wall_s"] for r in rows], "o-")
    ax[2].loglog([r["scenario_steps"] for r in rows], [r["wall_s"] for r in rows], "s-")
    ax[2].legend(["vs valid agent-steps", "vs scenario-steps"])
    ax[2].set(xlabel="simulated steps", ylabel="wall time, s")
    fig.suptitle(f"log_replay streamed in shards of {rows[0].get('shard_size')} (twin15 generator, 2-core CPU)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--suite", action="append", default=[], type=Path, help="suite folder (repeatable)")
    ap.add_argument("--out", type=Path, default=None, help="folder for the figures and the rows")
    ap.add_argument("--shard-size", type=int, default=800)
    ap.add_argument("--in-memory", type=Path, default=None, help="also evaluate this folder in one batch and compare")
    ap.add_argument("--plot", type=Path, default=None, help="write the curves here (PNG)")
    ap.add_argument("--force", action="store_true", help="re-measure suites already measured in --out")
    ap.add_argument("--tile", nargs=3, metavar=("SRC", "K", "OUT"), default=None,
                    help="write OUT = suite folder SRC with every scenario K times under new ids, then exit")
    ap.add_argument("--_one", help=argparse.SUPPRESS)
    ap.add_argument("--_mode", default="stream", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args._one:
        return _child(args)
    if args.tile:
        tile(Path(args.tile[0]), int(args.tile[1]), Path(args.tile[2]))
        return 0
    if args.out is None:
        ap.error("--out is required")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    jobs = [(f, "stream") for f in args.suite] + ([(args.in_memory, "in_memory")] if args.in_memory else [])
    for folder, mode in jobs:
        done = args.out / f"{folder.name}.{mode}.json"
        if done.is_file() and not args.force:
            row = json.loads(done.read_text())
        else:
            row = _run_child(folder, mode, args)
            done.write_text(json.dumps(row, indent=1))
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.in_memory:
        diff = _same_rows(args.out / f"{args.in_memory.name}.rows.jsonl",
                          args.out / f"{args.in_memory.name}.in_memory.rows.jsonl")
        print(json.dumps({"in_memory_equals_stream": not diff, "first_difference": diff or None}), flush=True)
    if args.plot:
        _plot(rows, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
