"""The main job: evaluate several policies on one suite split, write and print results.

``run_bench(BenchConfig(...))`` is what ``drivee2e bench`` calls. Each policy
is one batched rollout over the whole split; finished policies are saved
atomically and skipped when the run is resumed, if their fingerprints still
match (the results folder's rules: ``eval.results``).
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import jax
import numpy as np

from drivee2e_jax import hostbridge
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval import distributed
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.eval.leaderboard import write_leaderboard_results
from drivee2e_jax.eval.openloop import ShortHorizonError, evaluate_openloop
from drivee2e_jax.eval.report import write_report
from drivee2e_jax.eval.results import (
    RunDir,
    check_policy_file_names,
    event_key,
    policy_fingerprint,
    policy_provenance,
    run_fingerprint,
    run_provenance,
)
from drivee2e_jax.eval.runspec import RunSpec, batch_sha256, check_dt_against_logs, folder_fingerprint, pick_split
from drivee2e_jax.eval.stream import evaluate_stream, shards_of
from drivee2e_jax.eval.summary import OPEN_LOOP_COLUMNS, finite, format_tables, summarize
from drivee2e_jax.eval.tasks import add_task_success
from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.policy import load_policy
from drivee2e_jax.progress import StepBar
from drivee2e_jax.remote import is_remote_spec
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.scenario.stream import SuiteIndex
from drivee2e_jax.scenario.stream import shards as stream_shards


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """One benchmark run (CLI flags map one to one).

    Attributes:
      suite: suite name or folder.  split: split name; None = ``val`` when
        the suite has val scenarios, else its only non-empty split
        (``runspec.pick_split``).
      policies: policy file paths.  out: results folder (default results/<suite>-<split>).
      force: overwrite existing results.  preset: scoring rules.
      dt: sim step, s.  control_every / latency: control timing, steps.
      limit: only the first N scenarios.  seed: PRNG seed.  progress: show a bar.
      open_loop: also score waypoint policies open-loop on the logged
        demonstrations (L2 at 1/2/3 s in the ST-P3 and UniAD conventions,
        box collision rate with the logged agents), in the same sweep.
      task: Behavior Metrics driving task (``tasks.TASKS``): scenario
        filter + success rule; ``route_navigation`` = every scenario.
      repetitions: run each policy this many times with seeds seed,
        seed + 1, ...; rows carry a ``repetition`` column and the report
        gives mean +- std over repetitions. All repetitions of a policy run
        as one batched rollout (``evaluate(seeds=...)``).
      policy_kwargs: per policy, keyword arguments of its ``make_policy``
        (e.g. ``checkpoint``); () = none.  policy_names: per policy, the
        name in the results ("" = the policy's own); () = own names.
      gps_noise_std / compass_noise_std: observation noise, m / rad
        (``ObsConfig``); seeded per repetition.
      variant: suite variant (``scenario.variants.VARIANTS``): ``complete``,
        or agents never visible from the ego's cameras along the logged run
        removed (``visible_vehicles`` / ``visible_all``).
      collisions: which collisions count against IS / DS / SR
        (``metrics.driving_score.COLLISION_MODES``): ``all`` or ``at_fault`` (nuPlan's
        attribution); rows carry both either way.
      agents: the other agents (``sim.AGENT_MODELS``): ``log``
        (non-reactive replay) or ``idm`` (reactive IDM vehicles).
      coordinator / num_processes / process_id: several processes
        (``distributed.initialize``; None = env or one process): each rolls
        out its part of the scenarios, process 0 gathers and writes.
      shard_size: stream the split through the compiled rollout in shards of
        this many scenarios (``eval.stream``): a suite folder is then read
        shard by shard (``scenario.stream``), never whole, so memory does
        not grow with the suite; results equal the in-memory run's. None =
        one batch of the whole split.
    """

    suite: str = "twin15"
    split: str | None = "val"
    policies: tuple[str, ...] = ()
    out: Path | None = None
    force: bool = False
    preset: str = "paper"
    dt: float = 0.1
    control_every: int = 1
    latency: int = 0
    limit: int | None = None
    seed: int = 0
    progress: bool = True
    open_loop: bool = False
    task: str = "route_navigation"
    repetitions: int = 1
    policy_kwargs: tuple[dict, ...] = ()
    policy_names: tuple[str, ...] = ()
    gps_noise_std: float = 0.0
    compass_noise_std: float = 0.0
    variant: str = "complete"
    collisions: str = "all"
    agents: str = "log"
    coordinator: str | None = None
    num_processes: int | None = None
    process_id: int | None = None
    shard_size: int | None = None

    def run_spec(self) -> RunSpec:
        """The requested ``RunSpec`` of this run (``run.json`` once resolved;
        ``split`` None until ``run_bench`` picks one). Raises DriveE2EError
        for a bad dt, timing, seed, limit, repetitions, noise, task, variant,
        preset, collision mode or agent model."""
        return RunSpec(
            suite=self.suite, split=self.split, preset=self.preset, dt=self.dt, control_every=self.control_every,
            latency=self.latency, seed=self.seed, open_loop=self.open_loop, task=self.task,
            repetitions=self.repetitions, limit=self.limit, gps_noise_std=self.gps_noise_std,
            compass_noise_std=self.compass_noise_std, variant=self.variant, collisions=self.collisions,
            agents=self.agents,
        )


def run_bench(cfg: BenchConfig, print_fn: Callable[[str], None] = print) -> dict:
    """Run, write ``results/<run>/`` and print the tables. Returns the summary
    ({} on processes other than 0, which write and print nothing).

    Nothing is written to the results folder before every setting is checked,
    the suite packed and every policy loaded; the folder's rules (lock,
    fingerprints, resume, provenance) are ``eval.results``'."""

    multi = distributed.initialize(cfg.coordinator, cfg.num_processes, cfg.process_id)  # before any JAX work
    if not distributed.is_root():
        print_fn = _silent

    cfg.run_spec()  # checks dt, timing, seed, limit, repetitions, task, variant before the suite loads
    if cfg.shard_size is not None:
        check_streamable(cfg, multi)
        if _streams_folder(cfg):  # read shard by shard, never whole
            return _run_bench_folder_stream(cfg, print_fn)
    suite = load_suite(cfg.suite)
    if cfg.split is None:
        split, note = pick_split(suite.splits, f"suite {suite.name}")
        print_fn(note)
        cfg = dataclasses.replace(cfg, split=split)
    spec = cfg.run_spec()
    task = spec.task_spec()
    run_batch = spec.batch(suite)
    evaluated = run_batch.limited()  # the scenarios run: their log step bounds dt, their arrays are fingerprinted
    check_dt_against_logs(spec.dt, evaluated.meta)
    if run_batch.variant is not None:
        print_fn(run_batch.variant.summary())
    policies, fingerprints, policy_kwargs, names = _load_policies(cfg)
    spec.sim_config(), spec.timing()  # their errors too, before anything is written

    out = Path(cfg.out or spec.default_out())
    spec = spec.resolve(suite, run_batch)
    run_info = {**spec.to_json(),  # run.json: the spec + what resuming must also match
                "fingerprint": run_fingerprint(suite_sha256=batch_sha256(evaluated))}
    source = None if cfg.shard_size is None else _InMemoryShards(evaluated, cfg.shard_size)
    return _open_and_run(cfg, spec, run_info, out, suite.name, suite.version, run_batch, task, policies,
                         fingerprints, policy_kwargs, names, multi, print_fn, source, lambda: suite.maps)


def _streams_folder(cfg: BenchConfig) -> bool:
    """Whether a ``--shard-size`` run reads its suite folder shard by shard
    (a built-in suite is generated and packed in memory, then cut in shards)."""
    return Path(cfg.suite).is_dir()


def check_streamable(cfg: BenchConfig, multi: bool) -> None:
    """One-line DriveE2EError for ``--shard-size`` with what it does not support."""
    if cfg.shard_size < 1:
        raise DriveE2EError(f"--shard-size must be >= 1, got {cfg.shard_size}")
    flags = {"--open-loop": cfg.open_loop, f"--repetitions {cfg.repetitions}": cfg.repetitions != 1,
             f"--variant {cfg.variant}": cfg.variant != "complete", "several processes": multi}
    bad = [f for f, on in flags.items() if on]
    if bad:
        raise DriveE2EError(f"--shard-size streams one rollout over the split in shards and does not combine with "
                            f"{bad[0]}; drop --shard-size (in-memory run) or {bad[0]}")


class _InMemoryShards:
    """The shards of an in-memory run (a built-in suite): its evaluated batch cut in ``size`` rows."""

    def __init__(self, packed, size: int):
        self.packed, self.size = packed, size

    def shards(self):
        return shards_of(self.packed, self.size)


class _FolderShards:
    """The shards of a suite folder read shard by shard (``scenario.stream``):
    the split's first ``n`` rows (``--limit``), each shard checked against ``dt``."""

    def __init__(self, index, split: str, n: int, size: int, dt: float):
        self.index, self.split, self.n, self.size, self.dt = index, split, n, size, dt

    def shards(self):
        seen = 0
        for rows, packed in stream_shards(self.index, self.split, self.size):
            if seen >= self.n:
                return
            if seen + len(rows) > self.n:  # --limit ends inside this shard
                keep = np.arange(self.n - seen)
                rows, packed = rows[keep], packed.select(keep)
            check_dt_against_logs(self.dt, packed.meta)
            seen += len(rows)
            yield rows, packed


def _run_bench_folder_stream(cfg: BenchConfig, print_fn) -> dict:
    """``run_bench`` for ``--shard-size`` on a suite folder: the folder is never
    read whole (``scenario.stream``); the task filter is not available here."""
    index = SuiteIndex.open(cfg.suite)
    if cfg.task != "route_navigation":
        raise DriveE2EError(f"--task {cfg.task} filters the whole split in memory; it does not combine with "
                            "--shard-size on a suite folder")
    if cfg.split is None:
        split, note = pick_split(index.split_counts(), f"suite {index.name}")
        print_fn(note)
        cfg = dataclasses.replace(cfg, split=split)
    spec = cfg.run_spec()
    task = spec.task_spec()
    total = len(index.rows(spec.split))
    n = min(total, spec.limit or total)
    policies, fingerprints, policy_kwargs, names = _load_policies(cfg)
    spec.sim_config(), spec.timing()
    out = Path(cfg.out or spec.default_out())
    spec = dataclasses.replace(spec, suite_version=index.version, num_scenarios=n, variant_removed=None)
    run_info = {**spec.to_json(),
                "fingerprint": run_fingerprint(suite_files_sha256=folder_fingerprint(index, spec.split, n))}
    source = _FolderShards(index, spec.split, n, cfg.shard_size, spec.dt)
    return _open_and_run(cfg, spec, run_info, out, index.name, index.version, None, task, policies,
                         fingerprints, policy_kwargs, names, False, print_fn, source, lambda: index.maps)


def _load_policies(cfg: BenchConfig):
    """(policies under their result names, their fingerprints, kwargs, names); unique names."""
    policy_kwargs = cfg.policy_kwargs or tuple({} for _ in cfg.policies)
    policy_names = cfg.policy_names or tuple("" for _ in cfg.policies)
    if not len(policy_kwargs) == len(policy_names) == len(cfg.policies):
        raise DriveE2EError("BenchConfig: policy_kwargs / policy_names need one entry per policy")
    policies, fingerprints = [], []
    for p, kw, n in zip(cfg.policies, policy_kwargs, policy_names):
        pol = load_policy(p, **kw)
        fingerprints.append(policy_fingerprint(p, kw, remote_name=str(pol.name)))
        policies.append(_named(pol, n))
    names = [p.name for p in policies]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise DriveE2EError(f"two policies are named {sorted(dup)[0]!r}; policy names must be unique in a run")
    check_policy_file_names(names)
    return policies, fingerprints, policy_kwargs, names


def _open_and_run(cfg, spec, run_info, out, suite_name, suite_version, run_batch, task, policies, fingerprints,
                  policy_kwargs, names, multi, print_fn, source, maps_fn) -> dict:
    """Open the results folder, run every policy not done there, write the outputs."""
    resumable = {n: None if is_remote_spec(p) else fp for n, p, fp in zip(names, cfg.policies, fingerprints)}
    run, done = distributed.on_root(
        lambda: RunDir(out, run_info, force=cfg.force, policies=resumable,
                       provenance=run_provenance(out, cfg.suite, _jax_provenance())),
        lambda r: [n for n in names if r.done(n)])
    try:
        _run_policies(cfg, spec, run, done, out, suite_name, suite_version, run_batch, task, policies, fingerprints,
                      policy_kwargs, multi, print_fn, source, maps_fn)
        return {} if run is None else _write_outputs(run, policies, out, print_fn)  # process 0 writes
    finally:
        for pol in policies:  # host policies: release what they hold (a remote policy's connection)
            if hostbridge.is_host(pol):
                pol.close()
        if run is not None:
            run.close()


def _run_policies(cfg, spec, run, done, out, suite_name, suite_version, run_batch, task, policies, fingerprints,
                  policy_kwargs, multi, print_fn, source, maps_fn) -> None:
    """``run_bench`` once the folder is open: roll out every policy not
    ``done`` and save each (``run`` is None on processes other than 0).
    ``source``: the shards of a streamed run (None: ``run_batch`` in memory);
    ``maps_fn()``: the suite's maps (read only for a BEV policy)."""
    packed = None if run_batch is None else run_batch.packed
    sim_cfg, timing = spec.sim_config(), spec.timing()
    num = spec.num_scenarios
    shard = distributed.process_shard(num) if multi else None
    if multi and num < distributed.process_count():
        raise DriveE2EError(f"{num} scenarios for {distributed.process_count()} processes: "
                            "use at most one process per scenario")
    streamed = "" if source is None else f" in shards of {cfg.shard_size}"
    print_fn(f"suite {suite_name} v{suite_version}, split {spec.split}: {num} scenarios{streamed} -> {out}")

    for pol, path, kwargs, fp in zip(policies, cfg.policies, policy_kwargs, fingerprints):
        if pol.name in done:
            if run is not None:
                print_fn(f"[{pol.name}] already done in {run.policy_file(pol.name)} (resumed; --force to redo)")
            continue
        if run is not None and is_remote_spec(path) and pol.name in run.files:
            print_fn(f"[{pol.name}] remote policy: re-run (results of a remote policy are never resumed)")
        # All repetitions in one rollout (the batch tiled, keys as separate seeds would give).
        seeds = spec.repetition_seeds()
        label = pol.name if seeds is None else f"{pol.name} x{cfg.repetitions} reps"
        needs_maps = "bev" in getattr(pol, "required_sensors", ())
        if source is not None:
            bar = StepBar(label, cfg.progress and run is not None, unit="scenario")
            res = evaluate_stream(pol, source.shards(), num, config=sim_cfg, timing=timing, seed=cfg.seed,
                                  progress=bar.update, maps=maps_fn() if needs_maps else None)
        else:
            bar = StepBar(label, cfg.progress and run is not None)
            res = evaluate(
                pol, packed, None, config=sim_cfg, timing=timing, seed=cfg.seed, seeds=seeds, limit=cfg.limit,
                progress=bar.update, maps=maps_fn() if needs_maps else None, shard=shard,
            )
        bar.close()
        res = distributed.gather_result(res)  # every process's rows (no-op in one process)
        if cfg.open_loop and run is not None:
            _add_open_loop(pol, packed, res.rows, sim_cfg, cfg, print_fn, maps_fn)
        add_task_success(task, res.rows)
        events = {event_key(r): res.events[event_key(r)] for r in res.rows}
        timing_info = {"compile_s": res.compile_s, "wall_s": res.wall_s, "steps": res.steps}
        print_fn(
            f"[{label}] {len(res.rows)} episodes, {res.steps} steps: compile+first chunk {res.compile_s:.1f} s, "
            f"rollout {res.wall_s:.1f} s"
        )
        warnings = [str(w) for w in getattr(res, "warnings", ()) or ()]
        for w in warnings:
            print_fn(f"[{pol.name}] warning: {w}")
        if run is not None:
            extra = {"policy_path": str(path), **timing_info, "runs": [timing_info], "warnings": warnings,
                     "required_sensors": [str(s) for s in getattr(pol, "required_sensors", ())],
                     "provenance": policy_provenance(path, kwargs, fp, out)}
            run.save_policy(pol.name, res.rows, events, {**extra, "policy_kwargs": kwargs} if kwargs else extra)


def _write_outputs(run: RunDir, policies, out: Path, print_fn) -> dict:
    """Leaderboard files, tables, report and console tables of EVERY finished
    policy file in the folder (this run's policies first). Returns the summary."""
    run_info = run.info
    names = [p.name for p in policies]
    order = run.finished(names)  # every policy file of the folder: this run's first
    policy_data = {n: run.load_policy(n) for n in order}
    by_name = {p.name: p for p in policies}
    for n in order:  # leaderboard/<policy>.json: a CARLA LB 2.0 / Bench2Drive results.json per agent
        d = policy_data[n]
        pol = by_name.get(n) or SimpleNamespace(name=n, required_sensors=tuple(d.get("required_sensors") or ()))
        write_leaderboard_results(out / "leaderboard" / run.policy_file(n).name, d["rows"], d["events"], run_info, pol)
    summary = summarize({n: d["rows"] for n, d in policy_data.items()}, run_info)
    run.write_tables(order, summary, ep.COUNT_COLUMNS)
    others = [n for n in order if n not in by_name]
    if others:
        print_fn(f"the tables also list {len(others)} policies finished earlier in {out}: {', '.join(others)}")
    print_fn("")
    print_fn(format_tables(summary))

    report = write_report(out)
    print_fn(f"\nper-scenario results: {out / 'scenarios.csv'}, summary: {out / 'summary.json'}, report: {report}, "
             f"leaderboard / Bench2Drive results.json: {out / 'leaderboard'}/<policy>.json")
    return summary


def _jax_provenance() -> dict:
    """JAX's part of run.json's provenance: versions, backend, device kinds."""
    try:
        jaxlib_version = importlib.metadata.version("jaxlib")
    except importlib.metadata.PackageNotFoundError:
        jaxlib_version = "unknown"
    return {"jax_version": jax.__version__, "jaxlib_version": jaxlib_version, "backend": jax.default_backend(),
            "device_kinds": sorted({str(d.device_kind) for d in jax.devices()}),
            "process_count": jax.process_count()}


def _silent(_line: str) -> None:
    """``print_fn`` of processes other than 0."""


def _named(pol, name: str):
    """``pol`` under the result name ``name`` ("" = unchanged)."""
    if not name or name == pol.name:
        return pol
    if dataclasses.is_dataclass(pol) and "name" in {f.name for f in dataclasses.fields(pol)}:
        return dataclasses.replace(pol, name=name)
    pol.name = name  # a fresh object per load_policy call: nothing else sees it
    return pol


def _add_open_loop(pol, packed, rows: list[dict], sim_cfg, cfg: BenchConfig, print_fn, maps_fn) -> None:
    """Add the open-loop columns to ``rows`` (null for a controls policy and
    for waypoints shorter than the open-loop horizon)."""

    def left_empty(why: str) -> None:
        print_fn(f"[{pol.name}] {why} (columns left empty)")
        for r in rows:
            r.update(dict.fromkeys(OPEN_LOOP_COLUMNS))

    if pol.action_type != "waypoints":
        return left_empty("open-loop metrics need future waypoints; this policy outputs controls")
    t0 = time.perf_counter()
    maps = maps_fn() if "bev" in getattr(pol, "required_sensors", ()) else None
    try:
        ol = evaluate_openloop(pol, packed, config=sim_cfg, seed=cfg.seed, limit=cfg.limit, maps=maps)
    except ShortHorizonError as e:
        return left_empty(f"no open-loop metrics: {e}")
    for r in rows:
        got = ol[r["scenario_id"]]
        r.update({c: (got[c] if finite(got[c]) else None) for c in OPEN_LOOP_COLUMNS})
    print_fn(f"[{pol.name}] open-loop on the logged demonstrations: {time.perf_counter() - t0:.1f} s")
