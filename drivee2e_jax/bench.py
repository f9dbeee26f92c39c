"""The main job: evaluate several policies on one suite split, write and print results.

``run_bench(BenchConfig(...))`` is what ``drivee2e bench`` calls. Each policy
is one batched rollout over the whole split; finished policies are saved
atomically and skipped when the run is resumed.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Callable

import numpy as np

from drivee2e_jax.io.results import RunDir, event_key
from drivee2e_jax.metrics import episode as ep


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


def run_bench(cfg: BenchConfig, print_fn: Callable[[str], None] = print) -> dict:
    """Run, write ``results/<run>/`` and print the tables. Returns the summary
    ({} on processes other than 0, which write and print nothing)."""
    from drivee2e_jax import distributed

    multi = distributed.initialize(cfg.coordinator, cfg.num_processes, cfg.process_id)  # before any JAX work
    if not distributed.is_root():
        print_fn = _silent
    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.evaluation import evaluate
    from drivee2e_jax.policy import load_policy
    from drivee2e_jax.rollout import ControlTiming
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.scenario.variants import apply_variant, check_variant
    from drivee2e_jax.sim import SimConfig, score_preset
    from drivee2e_jax.tasks import add_task_success, apply_task, get_task

    if cfg.limit is not None and cfg.limit < 1:
        raise DriveE2EError(f"--limit must be >= 1, got {cfg.limit}")
    if cfg.repetitions < 1:
        raise DriveE2EError(f"--repetitions must be >= 1, got {cfg.repetitions}")
    task = get_task(cfg.task)
    check_variant(cfg.variant)
    suite = load_suite(cfg.suite)
    packed = apply_task(task, suite.pack(cfg.split))
    variant = None
    if cfg.variant != "complete":  # masks only for the scenarios run
        rows = np.arange(min(len(packed), cfg.limit or len(packed)))
        variant = apply_variant(packed.select(rows), cfg.variant, f"{suite.name}-{cfg.split}{_task_tag(task)}")
        packed = variant.batch
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
    try:
        sim_cfg = SimConfig(dt=cfg.dt, score=score_preset(cfg.preset), obs=_obs_config(cfg))
        timing = ControlTiming(cfg.control_every, cfg.latency)
    except ValueError as e:
        raise DriveE2EError(str(e)) from e

    suite_tag = Path(cfg.suite).name if Path(cfg.suite).exists() else cfg.suite
    variant_tag = "" if variant is None else f"-{cfg.variant}"
    out = cfg.out or Path("results") / f"{suite_tag}-{cfg.split}{_task_tag(task)}{variant_tag}"
    run_info = {
        "suite": cfg.suite,
        "suite_version": suite.version,
        "split": cfg.split,
        "num_scenarios": min(len(packed.meta), cfg.limit or len(packed.meta)),
        "preset": cfg.preset,
        "dt": cfg.dt,
        "control_every": cfg.control_every,
        "latency": cfg.latency,
        "seed": cfg.seed,
        "open_loop": cfg.open_loop,
        "task": task.name,
        "repetitions": cfg.repetitions,
    }
    if cfg.gps_noise_std or cfg.compass_noise_std:  # recorded only when used: older run.json stay resumable
        run_info.update(gps_noise_std=cfg.gps_noise_std, compass_noise_std=cfg.compass_noise_std)
    if variant is not None:  # recorded only when used: older run.json stay resumable
        run_info.update(variant=cfg.variant, variant_removed={c: list(v) for c, v in variant.by_category.items()})
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
        seeds = None if cfg.repetitions == 1 else [cfg.seed + rep for rep in range(cfg.repetitions)]
        label = pol.name if seeds is None else f"{pol.name} x{cfg.repetitions} reps"
        bar = _progress_bar(label, cfg.progress and run is not None)
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

    if run is None:  # not process 0: process 0 writes the results
        return {}
    rows_by_policy = {n: run.load_policy(n)["rows"] for n in names}
    summary = summarize(rows_by_policy, run_info)
    run.write_tables(names, summary, ep.COUNT_COLUMNS)
    print_fn("")
    print_fn(format_tables(summary))
    from drivee2e_jax.io.report import write_report

    report = write_report(out)
    print_fn(f"\nper-scenario results: {out / 'scenarios.csv'}, summary: {out / 'summary.json'}, report: {report}")
    return summary


def _silent(_line: str) -> None:
    """``print_fn`` of processes other than 0."""


def _task_tag(task) -> str:
    return "" if task.name == "route_navigation" else f"-{task.name}"


def _named(pol, name: str):
    """``pol`` under the result name ``name`` ("" = unchanged)."""
    if not name or name == pol.name:
        return pol
    if dataclasses.is_dataclass(pol) and "name" in {f.name for f in dataclasses.fields(pol)}:
        return dataclasses.replace(pol, name=name)
    pol.name = name  # a fresh object per load_policy call: nothing else sees it
    return pol


def _obs_config(cfg: BenchConfig):
    """The default ``ObsConfig`` with the run's observation noise."""
    from drivee2e_jax.observe.vector import ObsConfig

    return dataclasses.replace(ObsConfig(), gps_noise_std=cfg.gps_noise_std, compass_noise_std=cfg.compass_noise_std)


#: Per-scenario open-loop columns (``openloop.evaluate_openloop``).
OPEN_LOOP_COLUMNS = (
    "l2_1s_stp3", "l2_2s_stp3", "l2_3s_stp3", "l2_1s_uniad", "l2_2s_uniad", "l2_3s_uniad",
    "openloop_collision_rate", "openloop_samples",
)


def _add_open_loop(pol, packed, rows: list[dict], sim_cfg, cfg: BenchConfig, print_fn, suite) -> None:
    """Add the open-loop columns to ``rows`` (null for a controls policy)."""
    import time

    if pol.action_type != "waypoints":
        print_fn(f"[{pol.name}] open-loop metrics need future waypoints; this policy outputs controls (columns left empty)")
        for r in rows:
            r.update({c: None for c in OPEN_LOOP_COLUMNS})
        return
    from drivee2e_jax.openloop import evaluate_openloop

    t0 = time.perf_counter()
    maps = suite.maps if "bev" in getattr(pol, "required_sensors", ()) else None
    ol = evaluate_openloop(pol, packed, config=sim_cfg, seed=cfg.seed, limit=cfg.limit, maps=maps)
    for r in rows:
        got = ol[r["scenario_id"]]
        r.update({c: (got[c] if _finite(got[c]) else None) for c in OPEN_LOOP_COLUMNS})
    print_fn(f"[{pol.name}] open-loop on the logged demonstrations: {time.perf_counter() - t0:.1f} s")


def _open_loop_means(rows: list[dict]) -> dict:
    """Pooled open-loop values: per-scenario values weighted by their samples."""
    use = [r for r in rows if r.get("openloop_samples")]
    if not use:
        return {}
    w = np.array([r["openloop_samples"] for r in use], float)
    out = {"openloop_samples": int(w.sum())}
    for c in OPEN_LOOP_COLUMNS[:-1]:
        v = np.array([r[c] if _finite(r.get(c)) else np.nan for r in use], float)
        ok = np.isfinite(v)
        if ok.any():
            out[c] = round(float(np.sum(v[ok] * w[ok]) / np.sum(w[ok])), 4)
    return out


class _progress_bar:
    """tqdm over simulated steps; a no-op when disabled."""

    def __init__(self, name: str, enabled: bool):
        self.bar = None
        self.last = 0
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=None, desc=f"{name:>12}", unit="step", leave=True, dynamic_ncols=True)

    def update(self, done: int, total: int) -> None:
        if self.bar is None:
            return
        if self.bar.total != total:
            self.bar.total = total
        self.bar.update(done - self.last)
        self.last = done

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def summarize(rows_by_policy: dict[str, list[dict]], run_info: dict) -> dict:
    """Aggregates per policy, and per behaviour group / intersection / weather."""
    out = {"run": run_info, "policies": {}}
    for name, rows in rows_by_policy.items():
        out["policies"][name] = {
            "overall": summary_of(rows),
            "by_behavior": _group(rows, "behavior"),
            "by_intersection": _group(rows, "intersection_id"),
            "by_weather": _group(rows, "weather"),
        }
    return out


def summary_of(rows: list[dict], brief: bool = False) -> dict:
    """SR / DS / RC / IS over ``rows`` plus LB 2.0 per-km infraction rates.

    SR and DS follow DriveE2E's merge (sum over the scenarios run / their
    number; SR in %); per-km rates follow LB 2.0's global statistics.
    """
    from drivee2e_jax.metrics.aggregate import RouteResult, b2d_efficiency, drivee2e_merge, lb_global
    from drivee2e_jax.metrics.driving_score import INFRACTION_KEYS

    if not rows:
        return {"num_scenarios": 0}
    recs = [
        RouteResult(
            route_id=r["scenario_id"],
            route_length_m=r["route_length_m"],
            score_route=r["route_completion"],
            score_penalty=r["infraction_score"],
            score_composed=r["driving_score"],
            status=r["status"],
            infractions={k: r[k] for k in INFRACTION_KEYS if r.get(k)},
            outside_lanes_m=r.get("outside_route_lanes_m", 0.0),
            # The route's mean checkpoint ratio: B2D efficiency averages these.
            min_speed_pct=(float(r["efficiency_pct"]),) if _finite(r.get("efficiency_pct")) else (),
            category=r["behavior"],
        )
        for r in rows
    ]
    merged = drivee2e_merge(recs, route_nums=len(recs))
    out = {
        "num_scenarios": len(rows),
        "success_rate": round(merged["success rate"], 4),
        "driving_score": round(merged["driving score"], 4),
        "route_completion": round(float(np.mean([r["route_completion"] for r in rows])), 4),
    }
    if "task_success" in rows[0]:
        out["task_success_rate"] = round(100.0 * float(np.mean([bool(r["task_success"]) for r in rows])), 4)
    if brief:
        return out
    out["abilities"] = ability_scores(rows)
    g = lb_global(recs, planned_routes=len(recs))
    per_km = g["infractions"]
    collisions = sum(per_km[k] for k in ("collisions_pedestrian", "collisions_vehicle", "collisions_layout"))
    out.update(
        {
            "infraction_score": round(float(np.mean([r["infraction_score"] for r in rows])), 4),
            "driving_score_std": g["scores_std_dev"]["score_composed"],
            "km_driven": round(g["km_driven"], 4),
            "collisions_per_km": round(collisions, 3),
            "red_light_per_km": per_km["red_light"],
            "infractions_per_km": per_km,
            "outside_route_lanes_pct": round(float(np.mean([r.get("outside_route_lanes_pct", 0) for r in rows])), 3),
            "statuses": _counts(r["status"] for r in rows),
            "eval_time_s": round(float(np.mean([r["eval_time_s"] for r in rows])), 4),
            "episode_s": round(float(np.mean([r["episode_s"] for r in rows])), 3),
            "invalid_action_steps": int(sum(r.get("invalid_action", 0) for r in rows)),
        }
    )
    out.update(_fine_means(rows))
    out.update(_open_loop_means(rows))
    if any(r.min_speed_pct for r in recs):
        out["efficiency_pct"] = round(b2d_efficiency(recs), 4)
    return out


#: Bench2Drive's five abilities mapped onto the source's behaviour groups
#: (B2D maps its own scenario types; ours is a judgement from the labels'
#: meaning, docs/metrics.md): Merging = entering or crossing a conflicting
#: stream (competing vehicles, left and right turns); Emergency_Brake =
#: something may appear in the path (pedestrians / cyclists, competing
#: vehicles); Give_Way = yielding (pedestrians / cyclists, unprotected left
#: turns, U-turns); Traffic_Signs = obeying signals (red-light stops, yellow
#: passes, straight through on the signal); Overtaking has no group here.
ABILITIES = {
    "Merging": ("COV", "LFT", "RT"),
    "Overtaking": (),
    "Emergency_Brake": ("IPC", "COV"),
    "Give_Way": ("IPC", "LFT", "UT"),
    "Traffic_Signs": ("STP", "YLW", "STR"),
}


def ability_scores(rows: list[dict]) -> dict:
    """Bench2Drive multi-ability success rates (%), by ``ABILITIES``.

    Per ability: successes / scenarios of its behaviour groups (B2D's
    ``ability_benchmark``, same success test as SR); abilities without a
    scenario are left out; ``mean`` averages the abilities present (B2D
    averages its five). Returns {} when no row has a mapped group.
    """
    out = {}
    for ability, groups in ABILITIES.items():
        sel = [r for r in rows if r["behavior"] in groups]
        if sel:
            out[ability] = round(100.0 * float(np.mean([bool(r["success"]) for r in sel])), 4)
    if out:
        out["mean"] = round(float(np.mean(list(out.values()))), 4)
    return out


def _finite(v) -> bool:
    # "" = a blank CSV cell (rows read back by io.report.load_rows: an all-blank column stays text)
    return v is not None and v != "" and not math.isnan(float(v))


def _fine_means(rows: list[dict]) -> dict:
    """Means of the fine-grained columns over scenarios (NaN rows skipped)."""
    from drivee2e_jax.metrics.finegrained import SUMMARY_COLUMNS

    out = {}
    for c in SUMMARY_COLUMNS:
        vals = [float(r[c]) for r in rows if _finite(r.get(c))]
        if vals:
            out[c] = round(float(np.mean(vals)), 4)
    return out


def _counts(values) -> dict:
    out: dict = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return dict(sorted(out.items()))


def _group(rows, key):
    groups: dict = {}
    for r in rows:
        groups.setdefault(r[key], []).append(r)
    return {g: summary_of(rs, brief=True) for g, rs in sorted(groups.items())}


BEHAVIOR_ORDER = ("COV", "IPC", "UT", "YLW", "STR", "LFT", "RT", "STP")


def format_tables(summary: dict) -> str:
    """The two tables printed at the end of a run (plain text)."""
    pols = summary["policies"]
    nw = max(18, *(len(n) + 2 for n in pols))  # name column width
    lines = []
    task = summary["run"].get("task", "route_navigation")
    with_task = task != "route_navigation"
    head = f"{'policy':<{nw}}{'SR %':>7}{'DS':>8}{'RC':>8}{'IS':>7}{'coll/km':>9}{'red/km':>8}{'offlane%':>9}{'t/scn s':>9}"
    head += f"{'task SR%':>10}" if with_task else ""
    title = "Closed-loop results (mean over scenarios)" + (f", task {task}" if with_task else "")
    lines += [title, head, "-" * len(head)]
    for name, s in pols.items():
        o = s["overall"]
        lines.append(
            f"{name:<{nw}}{o['success_rate']:>7.1f}{o['driving_score']:>8.2f}{o['route_completion']:>8.2f}"
            f"{o['infraction_score']:>7.3f}{o['collisions_per_km']:>9.3f}{o['red_light_per_km']:>8.3f}"
            f"{o['outside_route_lanes_pct']:>9.2f}{o['eval_time_s']:>9.3f}"
            + (f"{o.get('task_success_rate', float('nan')):>10.1f}" if with_task else "")
        )
    groups = [g for g in BEHAVIOR_ORDER if any(g in s["by_behavior"] for s in pols.values())]
    head = f"{'SR % by behaviour':<{nw}}" + "".join(f"{g:>7}" for g in groups)
    lines += ["", head, "-" * len(head)]
    for name, s in pols.items():
        cells = "".join(
            f"{s['by_behavior'][g]['success_rate']:>7.1f}" if g in s["by_behavior"] else f"{'-':>7}" for g in groups
        )
        lines.append(f"{name:<{nw}}{cells}")
    head = f"{'DS by behaviour':<{nw}}" + "".join(f"{g:>7}" for g in groups)
    lines += ["", head, "-" * len(head)]
    for name, s in pols.items():
        cells = "".join(
            f"{s['by_behavior'][g]['driving_score']:>7.1f}" if g in s["by_behavior"] else f"{'-':>7}" for g in groups
        )
        lines.append(f"{name:<{nw}}{cells}")
    names = [a for a in ABILITIES if any(a in s["overall"].get("abilities", {}) for s in pols.values())]
    if names:
        aw = max(len(a) for a in names) + 2
        head = f"{'B2D abilities SR %':<{nw}}" + "".join(f"{a:>{aw}}" for a in names) + f"{'mean':>8}"
        lines += ["", head, "-" * len(head)]
        for name, s in pols.items():
            ab = s["overall"].get("abilities", {})
            cells = "".join(f"{ab[a]:>{aw}.1f}" if a in ab else f"{'-':>{aw}}" for a in names)
            lines.append(f"{name:<{nw}}{cells}{ab.get('mean', float('nan')):>8.1f}")
    fine = (
        ("dev m", "position_deviation_mean_m", 8.3),
        ("km/h", "average_speed_kmh", 7.1),
        ("jerk", "jerk_lon_mean_mps3", 7.2),
        ("inv/km", "lane_invasions_per_km", 8.2),
        ("dang%", "front_time_pct_dangerous", 7.1),
        ("smooth%", "smoothness_pct", 9.1),
        ("eff%", "efficiency_pct", 7.1),
    )
    head = f"{'fine-grained':<{nw}}" + "".join(f"{h:>{int(w)}}" for h, _, w in fine)
    lines += ["", head, "-" * len(head)]
    for name, s in pols.items():
        o = s["overall"]
        cells = "".join(
            f"{o[k]:>{w}f}" if k in o else f"{'-':>{int(w)}}" for _, k, w in fine
        )
        lines.append(f"{name:<{nw}}{cells}")
    ol = [(name, s["overall"]) for name, s in pols.items() if "l2_1s_stp3" in s["overall"]]
    if ol:
        head = f"{'open-loop':<{nw}}" + "".join(
            f"{h:>9}" for h in ("L2@1s", "L2@2s", "L2@3s", "L2@1s*", "L2@2s*", "L2@3s*", "coll%")
        )
        lines += ["", head, "-" * len(head)]
        for name, o in ol:
            vals = [o.get(f"l2_{k}s_stp3") for k in (1, 2, 3)] + [o.get(f"l2_{k}s_uniad") for k in (1, 2, 3)]
            vals.append(100 * o["openloop_collision_rate"] if "openloop_collision_rate" in o else None)
            lines.append(f"{name:<{nw}}" + "".join(f"{v:>9.3f}" if v is not None else f"{'-':>9}" for v in vals))
        lines.append("(L2 in m, ST-P3 convention = mean over steps up to t; * = UniAD convention = value at t)")
    n = summary["run"].get("num_scenarios")
    lines.append(f"\n(n = {n} scenarios per policy; group sizes in summary.json)")
    lines.append(
        "fine-grained: lane-centre deviation m, average speed km/h, longitudinal jerk m/s^3, lane invasions/km,"
        " % of time < 6 m behind a vehicle, Bench2Drive smoothness % and efficiency % (docs/metrics.md)"
    )
    return "\n".join(lines)

