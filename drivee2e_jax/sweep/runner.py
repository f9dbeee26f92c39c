"""Run a sweep: every combination of an experiment config, resumable, plus combined tables.

Layout of the sweep folder ``OUT/``::

    sweep.json              the config (resume checks it) and the run ids
    runs/<run-id>/          one ``bench`` results folder per run (io.results)
    runs/<run-id>/bench.log what ``run_bench`` printed; written last = the run is complete
    combined.csv / .md      one row per run x policy; policies side by side

A run is one suite x split x variant x task x sim-settings combination,
evaluated by ``bench.run_bench`` (all policies, the repetitions of each in one
batched rollout). Every file is written atomically; a rerun skips complete
runs, and ``run_bench`` skips the finished policies of an interrupted one.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.bench import BenchConfig, run_bench
from drivee2e_jax.eval.report import load_rows
from drivee2e_jax.eval.results import RESULTS_FOLDER, rows_to_csv
from drivee2e_jax.eval.summary import summary_of
from drivee2e_jax.files import (
    FolderLocked,
    ForeignFiles,
    OwnFolder,
    atomic_write_json,
    atomic_write_text,
    check_own_folder,
    lock_folder,
    remove_stray_temp_files,
)
from drivee2e_jax.jsonfile import BadJSON, read_json
from drivee2e_jax.policy import resolve_policy_path
from drivee2e_jax.progress import progress as progress_bar
from drivee2e_jax.sweep.config import SIM_KEYS_ADDED, SimSection, SweepConfig, out_dir

#: Marker of a complete run inside its folder.
DONE_FILE = "bench.log"
#: What a sweep folder holds: ``--force`` redoes only a folder with sweep.json
#: and no other files than these (``files.check_own_folder``).
SWEEP_FOLDER = OwnFolder("sweep", "sweep.json", ("sweep.json", "combined.csv", "combined.md", f"runs/*/{DONE_FILE}",
                                                 *RESULTS_FOLDER.nested("runs/*")))
#: Run-id parts for settings away from their default: field -> prefix.
ID_PREFIX = {"dt": "dt", "preset": "", "control_every": "ce", "latency": "lat", "gps_noise_std": "gps",
             "compass_noise_std": "compass", "collisions": "coll_", "agents": "agents_"}
#: Columns of combined.csv before the metrics.
RUN_COLUMNS = ("run_id", "suite", "split", "variant", "task", *ID_PREFIX, "policy", "repetitions", "num_scenarios")


@dataclasses.dataclass(frozen=True)
class Run:
    """One grid point: a ``run_bench`` call with every policy.

    Attributes:
      run_id: folder name under ``runs/`` (suite-split, then every setting off its default).
      suite, split, variant, task: the data.  dt (s), preset, control_every
      (steps), latency (steps), gps_noise_std (m), compass_noise_std (rad),
      collisions (``all`` / ``at_fault``), agents (``log`` / ``idm``): the simulator.
    """

    run_id: str
    suite: str
    split: str
    variant: str
    task: str
    dt: float
    preset: str
    control_every: int
    latency: int
    gps_noise_std: float
    compass_noise_std: float
    collisions: str = "all"
    agents: str = "log"


def expand(cfg: SweepConfig) -> list[Run]:
    """The runs of ``cfg``: suites x splits x variants x tasks x every [sim] list, in that order."""
    sim_keys = [f.name for f in dataclasses.fields(SimSection)]
    d = cfg.data
    axes = [d.suites, d.splits, d.variants, d.tasks] + [getattr(cfg.sim, k) for k in sim_keys]
    runs = []
    for suite, split, variant, task, *sim in itertools.product(*axes):
        settings = dict(zip(sim_keys, sim))
        runs.append(Run(_run_id(suite, split, variant, task, settings), suite, split, variant, task, **settings))
    ids = [r.run_id for r in runs]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise DriveE2EError(f"two runs would share the folder runs/{dup[0]} (two suites with one folder name?)")
    return runs


def _run_id(suite: str, split: str, variant: str, task: str, sim: dict) -> str:
    defaults = SimSection()
    parts = [Path(suite).name, split]
    parts += [variant] if variant != "complete" else []
    parts += [task] if task != "route_navigation" else []
    parts += [f"{ID_PREFIX[k]}{v:g}" if isinstance(v, float) else f"{ID_PREFIX[k]}{v}"
              for k, v in sim.items() if v != getattr(defaults, k)[0]]
    return "-".join(parts)


def bench_config(cfg: SweepConfig, run: Run, out: Path, *, force: bool = False, progress: bool = True):
    """The ``bench.BenchConfig`` of one run (policies resolved to files)."""

    extra = {}
    if "variant" in {f.name for f in dataclasses.fields(BenchConfig)}:
        extra["variant"] = run.variant
    elif run.variant != "complete":  # config.variant_names() prevents this
        raise DriveE2EError(f"variant {run.variant!r}: this bench has no suite variants")
    return BenchConfig(
        suite=run.suite, split=run.split, policies=tuple(str(p) for p in policy_paths(cfg)), out=out, force=force,
        preset=run.preset, dt=run.dt, control_every=run.control_every, latency=run.latency, limit=cfg.data.limit,
        seed=cfg.repetitions.seed, progress=progress, open_loop=cfg.outputs.open_loop, task=run.task,
        repetitions=cfg.repetitions.count, policy_kwargs=tuple(dict(p.kwargs) for p in cfg.policies),
        policy_names=tuple(p.name for p in cfg.policies), gps_noise_std=run.gps_noise_std,
        compass_noise_std=run.compass_noise_std, collisions=run.collisions, agents=run.agents, **extra,
    )


def policy_paths(cfg: SweepConfig) -> list[Path]:
    """Each ``[[policies]] path`` as a file (reference names resolved)."""

    out = []
    for i, p in enumerate(cfg.policies):
        try:
            out.append(resolve_policy_path(p.path))
        except DriveE2EError as e:
            raise DriveE2EError(f"[[policies]] #{i + 1} path: {e}") from None
    return out


def is_complete(run_dir: Path) -> bool:
    return (run_dir / DONE_FILE).is_file()


def run_sweep(cfg: SweepConfig, *, force: bool = False, progress: bool = True,
              print_fn: Callable[[str], None] = print) -> list[dict]:
    """Run every missing run of ``cfg``, then write the combined tables. Returns their rows."""

    out = out_dir(cfg)
    runs = expand(cfg)
    policy_paths(cfg)  # fail before anything is written
    check_own(out, force)  # before the lock: a folder refused gets no lock file
    try:
        with lock_folder(out, hint="wait for it to finish or use another --out"):  # one sweep per folder
            return _run_locked(out, cfg, runs, force, progress, print_fn)
    except FolderLocked as e:
        raise DriveE2EError(str(e)) from None


def _run_locked(out: Path, cfg: SweepConfig, runs: list[Run], force: bool, progress: bool,
                print_fn: Callable[[str], None]) -> list[dict]:
    """``run_sweep`` while holding the folder's lock."""
    start(out, cfg, runs, force)
    bar = progress_bar(total=len(runs), desc="sweep", unit="run", disable=None if progress else True, position=0)
    say = bar.write if progress else print_fn
    for i, run in enumerate(runs):
        folder = out / "runs" / run.run_id
        tag = f"[{i + 1}/{len(runs)}] {run.run_id}"
        if is_complete(folder):
            say(f"{tag}: complete, skipped (resumed)")
            bar.update(1)
            continue
        say(f"{tag}: running")
        log: list[str] = []

        def echo(line: str, log: list[str] = log) -> None:
            log.append(line)
            if line.startswith("["):  # per-policy lines; the tables go to the log and combined.md
                say(f"  {line}")

        run_bench(bench_config(cfg, run, folder, force=force, progress=progress), print_fn=echo)
        atomic_write_text(folder / DONE_FILE, "\n".join(log) + "\n")
        bar.update(1)
    bar.close()
    rows = combined_rows(cfg, runs, out)
    write_combined(out, rows, cfg)
    print_fn(f"{len(runs)} run(s) -> {out / 'runs'}; combined tables: {out / 'combined.csv'}, {out / 'combined.md'}")
    return rows


def start(out: Path, cfg: SweepConfig, runs: list[Run], force: bool) -> None:
    """Check ``out`` against ``cfg`` (resume) or reset it (``force``); clean what a killed sweep left."""
    meta = out / "sweep.json"
    record = {"config": cfg.to_json(), "runs": [r.run_id for r in runs]}
    check_own(out, force)
    if meta.exists() and not force:
        try:
            old = read_json(meta)
        except BadJSON as e:
            raise DriveE2EError(f"{e}; use --force to start over") from None
        old = with_added_sim_keys(old)
        if old.get("config") != record["config"]:
            diff = _diff(old.get("config") or {}, record["config"])
            raise DriveE2EError(f"{out}: holds a sweep with another config (differs in {diff}); "
                                "use --force to start over or --out for another folder")
    if force:
        for r in runs:
            (out / "runs" / r.run_id / DONE_FILE).unlink(missing_ok=True)
    remove_stray_temp_files(out)  # a killed sweep's (safe: this sweep holds the folder's lock)
    atomic_write_json(meta, record)


def check_own(out: Path, force: bool) -> None:
    """DriveE2EError (one line naming the files) unless ``out`` is new, empty
    or a sweep folder, and with ``force`` holds only a sweep's files
    (``SWEEP_FOLDER``): ``--force`` never deletes what drivee2e did not write."""
    try:
        check_own_folder(out, SWEEP_FOLDER, redo=force)
    except ForeignFiles as e:
        raise DriveE2EError(str(e)) from None


def with_added_sim_keys(record: dict) -> dict:
    """A ``sweep.json`` record with the ``[sim]`` keys added since it was
    written (``config.SIM_KEYS_ADDED``) at the value it stood for, so that an
    older sweep folder still resumes."""
    cfg = record.get("config") if isinstance(record, dict) else None
    if not isinstance(cfg, dict) or not isinstance(cfg.get("sim"), dict):
        return record
    return {**record, "config": {**cfg, "sim": {**SIM_KEYS_ADDED, **cfg["sim"]}}}


def _diff(old: dict, new: dict) -> str:
    """The ``table.key`` names whose values differ between two recorded configs."""
    keys = []
    for t in sorted(set(old) | set(new)):
        a, b = old.get(t), new.get(t)
        if isinstance(a, dict) and isinstance(b, dict):
            keys += [f"{t}.{k}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        elif a != b:
            keys.append(t)
    return ", ".join(keys)


def combined_rows(cfg: SweepConfig, runs: list[Run], out: Path) -> list[dict]:
    """One row per run x policy: the run's settings, then each metric's mean and std over repetitions."""

    rows = []
    for run in runs:
        folder = out / "runs" / run.run_id
        _, scn_rows = load_rows(folder / "scenarios.csv")
        policies = list(read_json(folder / "summary.json")["policies"])
        for pol in policies:
            mine = [r for r in scn_rows if r["policy"] == pol]
            by_rep: dict = {}
            for r in mine:
                by_rep.setdefault(r.get("repetition", 0), []).append(r)
            per_rep = [summary_of(rs) for rs in by_rep.values()]
            row = {**dataclasses.asdict(run), "policy": pol,
                   "repetitions": len(per_rep), "num_scenarios": per_rep[0]["num_scenarios"] if per_rep else 0}
            for m in cfg.outputs.metrics:
                vals = [s[m] for s in per_rep if s.get(m) is not None and math.isfinite(s[m])]
                row[m] = round(float(np.mean(vals)), 4) if vals else None
                row[f"{m}_std"] = round(float(np.std(vals, ddof=1)), 4) if len(vals) > 1 else None
            rows.append(row)
    return rows


def write_combined(out: Path, rows: list[dict], cfg: SweepConfig) -> None:
    """``combined.csv`` (every row) and ``combined.md`` (policies side by side per metric), atomically."""
    cols = list(RUN_COLUMNS) + [c for m in cfg.outputs.metrics for c in (m, f"{m}_std")]
    atomic_write_text(out / "combined.csv", rows_to_csv(rows, cols))
    atomic_write_text(out / "combined.md", combined_markdown(rows, cfg))


def combined_markdown(rows: list[dict], cfg: SweepConfig) -> str:
    """Per ``outputs.compare`` metric a runs x policies table, then every metric per run x policy."""
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    run_ids = list(dict.fromkeys(r["run_id"] for r in rows))
    by = {(r["run_id"], r["policy"]): r for r in rows}
    reps, seed = cfg.repetitions.count, cfg.repetitions.seed
    how = (f"mean ± sample std over {reps} repetitions (seeds {seed}..{seed + reps - 1})." if reps > 1
           else f"one repetition (seed {seed}).")
    lines = [f"# Sweep {cfg.sweep.name}", "", f"{len(run_ids)} run(s) x {len(policies)} policies; {how}"]
    for m in cfg.outputs.compare:
        lines += ["", f"## {m}", "", "| run | " + " | ".join(policies) + " |", "|---" * (len(policies) + 1) + "|"]
        for rid in run_ids:
            cells = [_cell(by.get((rid, p)), m) for p in policies]
            lines.append(f"| {rid} | " + " | ".join(cells) + " |")
    metrics = cfg.outputs.metrics
    lines += ["", "## All metrics", "", "| run | policy | n | " + " | ".join(metrics) + " |",
              "|---" * (len(metrics) + 3) + "|"]
    for r in rows:
        lines.append(f"| {r['run_id']} | {r['policy']} | {r['num_scenarios']} | "
                     + " | ".join(_cell(r, m) for m in metrics) + " |")
    return "\n".join(lines) + "\n"


def _cell(row: dict | None, metric: str) -> str:
    if row is None or row.get(metric) is None:
        return "–"
    std = row.get(f"{metric}_std")
    return f"{row[metric]:.2f}" + (f" ± {std:.2f}" if std is not None else "")
