"""The suite generator: plan every scenario, simulate them in batches,
cut and verify the logs, retry the misses with fresh randomness.

Every scenario's outcome depends only on ``(seed, its index, attempt)``,
never on which other scenarios share its batch, so the work can be split
between processes (and a subset regenerated) with identical results.
"""

from __future__ import annotations

import multiprocessing
import os
import sys
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field

import numpy as np

from drivee2e_jax.records import ScenarioRecord, SuiteRecord

from .assemble import scenario_record
from .egoplan import capable
from .labels import FINISH_MARGIN, LOG_STEPS, Miss, cut
from .layout import build_layout
from .plan import SIM_STEPS, WARMUP_STEPS, Plan, make_plan
from .scenarios import NUM_SCENARIOS, Meta, assign
from .specs import SPECS
from .tables import build_tables
from .traffic import Agents, simulate

MAX_ATTEMPTS = 24
#: After this many misses a scenario may move to another intersection that
#: can produce its label (keeps the exact label counts; all intersections
#: keep their place in every split, they only lose or gain a few).
MOVE_AFTER = 8
BATCH = 400  # scenarios simulated together (bounds the log memory)
#: Share of the scenarios the parent keeps when a second process helps (the
#: parent also merges the helper's records at the end).
PARENT_SHARE = 0.48


@dataclass
class _Outcome:
    records: dict[int, ScenarioRecord] = field(default_factory=dict)
    misses: Counter = field(default_factory=Counter)
    sim_stats: Counter = field(default_factory=Counter)
    attempts: dict[int, int] = field(default_factory=dict)
    removed: dict[int, tuple[int, int]] = field(default_factory=dict)
    moved: int = 0
    failed: list[int] = field(default_factory=list)


def _simulate(tab, plans: list[Plan]):
    sizes = [len(p.agents["path"]) for p in plans]
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    cat = {k: np.concatenate([p.agents[k] for p in plans]) for k in plans[0].agents}
    scen = np.repeat(np.arange(len(plans)), sizes)
    ag = Agents(scen, cat["path"], cat["t_spawn"], cat["length"], cat["width"], cat["v_des"], cat["a_max"],
                cat["b_comf"], cat["t_head"], cat["s0"], cat["ego"])
    inter = np.array([p.inter for p in plans])
    offset = np.array([p.offset for p in plans])
    ego_path = cat["path"][first]
    s_end = tab.path_j1[ego_path] + np.array([p.d_after for p in plans])
    res = simulate(tab, inter, offset, ag, SIM_STEPS, WARMUP_STEPS, (first, s_end, FINISH_MARGIN, LOG_STEPS + 20))
    return res, first, sizes


def _run(seed: int, metas: list[Meta], todo: list[int]) -> _Outcome:
    """Generate the scenarios ``todo`` (indices into ``metas``)."""
    tab = build_tables()
    groups = {sp.map_id: sorted({g.id for g in build_layout(sp.map_id).signals.groups}) for sp in SPECS}
    out = _Outcome()
    for attempt in range(MAX_ATTEMPTS):
        if not todo:
            break
        if attempt == MOVE_AFTER:
            caps = capable(tab)
            for i in todo:
                metas[i].inter = int(np.random.default_rng([seed, i, 999]).choice(sorted(caps[metas[i].label])))
                out.moved += 1
        failed = []
        for b0 in range(0, len(todo), BATCH):
            plans, rngs, idx = [], [], []
            for i in todo[b0:b0 + BATCH]:
                m = metas[i]
                rng = np.random.default_rng([seed, i, attempt])
                plan = make_plan(rng, tab, i, m.inter, m.label, m.time_of_day)
                out.attempts[i] = attempt + 1
                if plan is None:
                    out.misses["no signal timing fits"] += 1
                    failed.append(i)
                    continue
                plans.append(plan), rngs.append(rng), idx.append(i)
            if not plans:
                continue
            res, first, sizes = _simulate(tab, plans)
            out.sim_stats.update({k: v for k, v in res.stats.items() if isinstance(v, int)})
            for j, (plan, rng, i, f, n) in enumerate(zip(plans, rngs, idx, first, sizes)):
                try:
                    c = cut(rng, tab, plan, np.arange(f, f + n), res, scen_row=j)
                except Miss as e:
                    out.misses[str(e)] += 1
                    failed.append(i)
                    continue
                m = metas[i]
                mid = SPECS[m.inter].map_id
                out.records[i] = scenario_record(plan, c, m.scenario_id, m.split, m.weather, mid, groups[mid])
                out.removed[i] = (c.removed, c.removed_near_ego)
            del res
        todo = sorted(failed)
    out.failed = todo
    return out


def _jax_backend_live() -> bool:
    """Whether JAX has started its backend (and with it its thread pools)."""

    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge  # noqa: PLC0415 - only once JAX is loaded: never import it here

        return bool(getattr(xla_bridge, "_backends", {}))
    except Exception:  # noqa: BLE001 - private API moved: assume live, stay safe
        return True


def _default_workers() -> int:
    env = os.environ.get("DRIVEE2E_TWIN15_WORKERS", "").strip()
    if env:
        return max(1, int(env))
    # Forking a process whose JAX runtime threads are running can deadlock
    # the child (JAX warns about it), so fork only before JAX has started.
    if _jax_backend_live():
        return 1
    return 2 if (os.cpu_count() or 1) >= 2 else 1


def generate(seed: int = 0, version: str = "1", scenarios=None, workers: int | None = None) -> SuiteRecord:
    """The suite (see the package docstring); ``scenarios`` limits it to
    some indices (the others are left out), ``workers`` sets how many
    processes share the work (default: 2 when there are 2 cores)."""
    tab = build_tables()
    maps = {sp.map_id: build_layout(sp.map_id).map for sp in SPECS}
    metas = assign(np.random.default_rng([seed, 15]), capable(tab), len(SPECS))
    todo = list(range(NUM_SCENARIOS)) if scenarios is None else sorted(set(int(i) for i in scenarios))
    workers = _default_workers() if workers is None else max(1, int(workers))
    if workers > 1 and len(todo) >= 200 and "fork" in multiprocessing.get_all_start_methods():
        # a helper process takes every other scenario beyond the parent's share
        k = int(round(len(todo) * (1 - PARENT_SHARE)))
        helper_part = todo[1::2][:k]
        mine = sorted(set(todo) - set(helper_part))
        # fork: the helper inherits the built tables and needs no import of
        # the caller's __main__ (spawn would re-run an unguarded script). It
        # runs numpy only, so threads a parent may have started are moot.
        ctx = multiprocessing.get_context("fork")
        try:
            with ProcessPoolExecutor(1, mp_context=ctx) as ex:
                fut = ex.submit(_run, seed, metas, helper_part)
                outs = [_run(seed, metas, mine), fut.result()]
        except (OSError, RuntimeError, BrokenProcessPool):  # no subprocesses here: do it all ourselves
            outs = [_run(seed, metas, todo)]
    else:
        outs = [_run(seed, metas, todo)]
    failed = sorted(i for o in outs for i in o.failed)
    misses = sum((o.misses for o in outs), Counter())
    if failed:
        m = metas[failed[0]]
        raise RuntimeError(f"twin15: {len(failed)} scenarios found no valid log after {MAX_ATTEMPTS} attempts "
                           f"(e.g. {m.scenario_id} {m.label}); misses: {dict(misses)}")
    records = {i: r for o in outs for i, r in o.records.items()}
    scen = [records[i] for i in todo]
    attempts = np.array([a for o in outs for a in o.attempts.values()])
    removed = np.array([r for o in outs for r in o.removed.values()]).reshape(-1, 2)
    agents = np.array([len(r.tracks) for r in scen])
    meta = {
        "generator": "drivee2e_jax.scenario.twin15",
        "seed": int(seed),
        "description": "procedural stand-in for DriveE2E: 15 signalised intersections, rule-based traffic logs",
        "dt": 0.1,
        "num_steps": 201,
        "agents_per_scenario": {"mean": round(float(agents.mean()), 2), "max": int(agents.max())},
        "attempts": {"total": int(attempts.sum()), "max": int(attempts.max()),
                     "moved_intersection": int(sum(o.moved for o in outs))},
        "misses": dict(sorted(misses.items())),
        "removed_overlap_agents": {"total": int(removed[:, 0].sum()), "max_per_scenario": int(removed[:, 0].max()),
                                   "near_ego": int(removed[:, 1].sum())},
        "traffic_model": dict(sorted(sum((o.sim_stats for o in outs), Counter()).items())),
    }
    return SuiteRecord(name="twin15", version=version, maps=maps, scenarios=scen, meta=meta)
