"""The main job: evaluate several policies on one suite split, write and print results.

``run_bench(BenchConfig(...))`` is what ``drivee2e bench`` calls. Each policy
is one batched rollout over the whole split; finished policies are saved
atomically and skipped when the run is resumed.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

from drivee2e_jax import hostbridge
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval import distributed
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.eval.leaderboard import write_leaderboard_results
from drivee2e_jax.eval.openloop import evaluate_openloop
from drivee2e_jax.eval.report import write_report
from drivee2e_jax.eval.results import RunDir, event_key
from drivee2e_jax.eval.runspec import RunSpec
from drivee2e_jax.eval.summary import OPEN_LOOP_COLUMNS, finite, format_tables, summarize
from drivee2e_jax.eval.tasks import add_task_success
from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.policy import load_policy
from drivee2e_jax.progress import StepBar


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """One benchmark run (CLI flags map one to one).

    Attributes:
      suite: suite name or folder.  split: split name.
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
      coordinator / num_processes / process_id: several processes
        (``distributed.initialize``; None = env or one process): each rolls
        out its part of the scenarios, process 0 gathers and writes.
    """

    suite: str = "twin15"
    split: str = "val"
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
    coordinator: str | None = None
    num_processes: int | None = None
    process_id: int | None = None

    def run_spec(self) -> RunSpec:
        """The requested ``RunSpec`` of this run (``run.json`` once resolved).
        Raises DriveE2EError for a bad limit, repetitions, task or variant."""
        return RunSpec(
            suite=self.suite, split=self.split, preset=self.preset, dt=self.dt, control_every=self.control_every,
            latency=self.latency, seed=self.seed, open_loop=self.open_loop, task=self.task,
            repetitions=self.repetitions, limit=self.limit, gps_noise_std=self.gps_noise_std,
            compass_noise_std=self.compass_noise_std, variant=self.variant,
        )


def run_bench(cfg: BenchConfig, print_fn: Callable[[str], None] = print) -> dict:
    """Run, write ``results/<run>/`` and print the tables. Returns the summary
    ({} on processes other than 0, which write and print nothing)."""

    multi = distributed.initialize(cfg.coordinator, cfg.num_processes, cfg.process_id)  # before any JAX work
    if not distributed.is_root():
        print_fn = _silent

    spec = cfg.run_spec()  # checks limit, repetitions, task, variant
    task = spec.task_spec()
    suite = spec.load_suite()
    run_batch = spec.batch(suite)
    packed, variant = run_batch.packed, run_batch.variant
    if variant is not None:
        print_fn(variant.summary())
    policy_kwargs = cfg.policy_kwargs or tuple({} for _ in cfg.policies)
    policy_names = cfg.policy_names or tuple("" for _ in cfg.policies)
    if not len(policy_kwargs) == len(policy_names) == len(cfg.policies):
        raise DriveE2EError("BenchConfig: policy_kwargs / policy_names need one entry per policy")
    policies = [_named(load_policy(p, **kw), n) for p, kw, n in zip(cfg.policies, policy_kwargs, policy_names)]
    names = [p.name for p in policies]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise DriveE2EError(f"two policies are named {sorted(dup)[0]!r}; policy names must be unique in a run")
    sim_cfg = spec.sim_config()
    timing = spec.timing()

    out = cfg.out or spec.default_out()
    spec = spec.resolve(suite, run_batch)
    run_info = spec.to_json()  # run.json
    run, done = distributed.on_root(lambda: RunDir(out, run_info, force=cfg.force), lambda r: [n for n in names if r.done(n)])
    shard = distributed.process_shard(run_info["num_scenarios"]) if multi else None
    if multi and run_info["num_scenarios"] < distributed.process_count():
        raise DriveE2EError(f"{run_info['num_scenarios']} scenarios for {distributed.process_count()} processes: "
                            "use at most one process per scenario")
    print_fn(f"suite {suite.name} v{suite.version}, split {cfg.split}: {run_info['num_scenarios']} scenarios -> {out}")

    for pol, path, kwargs in zip(policies, cfg.policies, policy_kwargs):
        if pol.name in done:
            if run is not None:
                print_fn(f"[{pol.name}] already done in {run.policy_file(pol.name)} (resumed; --force to redo)")
            continue
        # All repetitions in one rollout (the batch tiled, keys as separate seeds would give).
        seeds = spec.repetition_seeds()
        label = pol.name if seeds is None else f"{pol.name} x{cfg.repetitions} reps"
        bar = StepBar(label, cfg.progress and run is not None)
        res = evaluate(
            pol, packed, None, config=sim_cfg, timing=timing, seed=cfg.seed, seeds=seeds, limit=cfg.limit,
            progress=bar.update, maps=suite.maps if "bev" in getattr(pol, "required_sensors", ()) else None,
            shard=shard,
        )
        bar.close()
        res = distributed.gather_result(res)  # every process's rows (no-op in one process)
        if cfg.open_loop and run is not None:
            _add_open_loop(pol, packed, res.rows, sim_cfg, cfg, print_fn, suite)
        add_task_success(task, res.rows)
        events = {event_key(r): res.events[event_key(r)] for r in res.rows}
        timing_info = {"compile_s": res.compile_s, "wall_s": res.wall_s, "steps": res.steps}
        print_fn(
            f"[{label}] {len(res.rows)} episodes, {res.steps} steps: compile+first chunk {res.compile_s:.1f} s, "
            f"rollout {res.wall_s:.1f} s"
        )
        extra = {"policy_path": str(path), **timing_info, "runs": [timing_info]}
        if run is not None:
            run.save_policy(pol.name, res.rows, events, {**extra, "policy_kwargs": kwargs} if kwargs else extra)
    for pol in policies:  # host policies: release what they hold (a remote policy's connection)
        if hostbridge.is_host(pol):
            pol.close()

    if run is None:  # not process 0: process 0 writes the results
        return {}
    policy_data = {n: run.load_policy(n) for n in names}
    rows_by_policy = {n: d["rows"] for n, d in policy_data.items()}
    for pol in policies:  # leaderboard/<policy>.json: a CARLA LB 2.0 / Bench2Drive results.json per agent
        d = policy_data[pol.name]
        write_leaderboard_results(out / "leaderboard" / run.policy_file(pol.name).name, d["rows"], d["events"],
                                  run_info, pol)
    summary = summarize(rows_by_policy, run_info)
    run.write_tables(names, summary, ep.COUNT_COLUMNS)
    print_fn("")
    print_fn(format_tables(summary))

    report = write_report(out)
    print_fn(f"\nper-scenario results: {out / 'scenarios.csv'}, summary: {out / 'summary.json'}, report: {report}, "
             f"leaderboard / Bench2Drive results.json: {out / 'leaderboard'}/<policy>.json")
    return summary


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


def _add_open_loop(pol, packed, rows: list[dict], sim_cfg, cfg: BenchConfig, print_fn, suite) -> None:
    """Add the open-loop columns to ``rows`` (null for a controls policy)."""

    if pol.action_type != "waypoints":
        print_fn(f"[{pol.name}] open-loop metrics need future waypoints; this policy outputs controls (columns left empty)")
        for r in rows:
            r.update({c: None for c in OPEN_LOOP_COLUMNS})
        return

    t0 = time.perf_counter()
    maps = suite.maps if "bev" in getattr(pol, "required_sensors", ()) else None
    ol = evaluate_openloop(pol, packed, config=sim_cfg, seed=cfg.seed, limit=cfg.limit, maps=maps)
    for r in rows:
        got = ol[r["scenario_id"]]
        r.update({c: (got[c] if finite(got[c]) else None) for c in OPEN_LOOP_COLUMNS})
    print_fn(f"[{pol.name}] open-loop on the logged demonstrations: {time.perf_counter() - t0:.1f} s")
