"""The suite generator: plan every scenario, simulate them in batches,
cut and verify the logs, retry the misses with fresh randomness;
``generate`` returns the suite in memory, ``generate_to`` streams it into a
suite folder block by block (suites larger than memory).

Every scenario's outcome depends only on ``(seed, its index, attempt)``,
never on which other scenarios share its batch, so the work can be split
between processes (and a subset regenerated) with identical results.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import sys
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.progress import ProgressFn
from drivee2e_jax.records import ScenarioRecord, SuiteRecord
from drivee2e_jax.scenario.schema import SuiteWriter

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
#: Scenario indices generated (and held in memory) at a time by ``generate_to``.
BLOCK = 800
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


def _check_num_scenarios(num_scenarios) -> int:
    if isinstance(num_scenarios, bool) or not isinstance(num_scenarios, (int, np.integer)) \
            or num_scenarios < NUM_SCENARIOS or num_scenarios % NUM_SCENARIOS:
        raise DriveE2EError(f"twin15: num_scenarios: expected a positive multiple of {NUM_SCENARIOS}, "
                            f"got {num_scenarios!r}")
    return int(num_scenarios)


def suite_name(num_scenarios: int = NUM_SCENARIOS) -> str:
    """``"twin15"`` for the 800-scenario suite, ``"twin15x<k>"`` for ``k * 800``
    scenarios (so results, caches and folders of different sizes never share a name)."""
    k = _check_num_scenarios(num_scenarios) // NUM_SCENARIOS
    return "twin15" if k == 1 else f"twin15x{k}"


def plan_suite(seed: int, num_scenarios: int = NUM_SCENARIOS) -> list[Meta]:
    """Split, label, intersection, weather and time of day of every scenario
    index (no traffic simulated; ~0.1 s per 800 scenarios)."""
    n = _check_num_scenarios(num_scenarios)
    return assign(np.random.default_rng([seed, 15]), capable(build_tables()), len(SPECS), n // NUM_SCENARIOS)


def _select(scenarios, num_scenarios: int) -> list[int]:
    if scenarios is None:
        return list(range(num_scenarios))
    todo = sorted(set(int(i) for i in scenarios))
    bad = [i for i in todo if not 0 <= i < num_scenarios]
    if bad:
        raise DriveE2EError(f"twin15: scenarios: expected indices in 0..{num_scenarios - 1}, got {bad[0]}")
    return todo


def _generate_some(seed: int, metas: list[Meta], todo: list[int], workers: int | None) -> tuple[list[ScenarioRecord], dict]:
    """Records of the indices ``todo`` (in that order) and their statistics
    (``_stats``). Every record depends only on ``(seed, index, metas)``."""
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
    stats = {
        "scenarios": len(scen), "agents_sum": int(agents.sum()), "agents_max": int(agents.max()),
        "attempts_total": int(attempts.sum()), "attempts_max": int(attempts.max()),
        "moved_intersection": int(sum(o.moved for o in outs)), "misses": dict(misses),
        "removed_total": int(removed[:, 0].sum()), "removed_max": int(removed[:, 0].max()),
        "removed_near_ego": int(removed[:, 1].sum()),
        "traffic_model": dict(sum((o.sim_stats for o in outs), Counter())),
    }
    return scen, stats


def suite_meta(seed: int, num_scenarios: int, blocks: list[dict]) -> dict:
    """suite.json's ``meta`` from the statistics of one or more blocks of
    ``_generate_some`` (sums, maxima and the mean over all of them)."""
    def total(key):
        return sum(b[key] for b in blocks)

    def most(key):
        return max(b[key] for b in blocks)

    def counts(key):
        return dict(sorted(sum((Counter(b[key]) for b in blocks), Counter()).items()))

    meta = {"generator": "drivee2e_jax.scenario.twin15", "seed": int(seed)}
    if num_scenarios != NUM_SCENARIOS:
        meta["num_scenarios"] = int(num_scenarios)
    meta.update({
        "description": "procedural stand-in for DriveE2E: 15 signalised intersections, rule-based traffic logs",
        "dt": 0.1,
        "num_steps": 201,
        # an exact integer sum over an exact count: the same float as numpy's mean
        "agents_per_scenario": {"mean": round(total("agents_sum") / total("scenarios"), 2),
                                "max": most("agents_max")},
        "attempts": {"total": total("attempts_total"), "max": most("attempts_max"),
                     "moved_intersection": total("moved_intersection")},
        "misses": counts("misses"),
        "removed_overlap_agents": {"total": total("removed_total"), "max_per_scenario": most("removed_max"),
                                   "near_ego": total("removed_near_ego")},
        "traffic_model": counts("traffic_model"),
    })
    return meta


def _maps() -> dict:
    return {sp.map_id: build_layout(sp.map_id).map for sp in SPECS}


def generate(seed: int = 0, version: str = "1", scenarios=None, workers: int | None = None,
             num_scenarios: int = NUM_SCENARIOS) -> SuiteRecord:
    """The suite (see the package docstring), all in memory; ``scenarios``
    limits it to some indices (the others are left out), ``workers`` sets how
    many processes share the work (default: 2 when there are 2 cores)."""
    metas = plan_suite(seed, num_scenarios)
    todo = _select(scenarios, num_scenarios)
    scen, stats = _generate_some(seed, metas, todo, workers)
    return SuiteRecord(name=suite_name(num_scenarios), version=version, maps=_maps(), scenarios=scen,
                       meta=suite_meta(seed, num_scenarios, [stats]))


def generate_to(path, seed: int = 0, version: str = "1", *, num_scenarios: int = NUM_SCENARIOS, scenarios=None,
                workers: int | None = None, block: int = BLOCK, overwrite: bool = False,
                progress: ProgressFn | None = None) -> Path:
    """Generate the suite straight into the suite folder ``path``, ``block``
    scenario indices at a time (bounded memory: one block of records, ~0.7 GB
    RSS for 800), each block validated, written and freed before the next.

    ``suite.json`` comes last, its meta accumulated over the blocks plus
    ``pack_sizes`` (``schema.SuiteWriter``). A killed run leaves
    ``.<name>.partial`` next to ``path``; the same call (same seed, version,
    num_scenarios, scenarios, block) resumes after the blocks it finished.
    Block ``b`` holds indices ``b*block .. (b+1)*block - 1``; for
    ``num_scenarios=800`` (one block) every file is the one
    ``write_suite(generate(seed), path)`` writes, and suite.json differs
    only by ``meta["pack_sizes"]``.
    """
    if isinstance(block, bool) or not isinstance(block, int) or block < 1:
        raise DriveE2EError(f"twin15: block: expected an integer >= 1, got {block!r}")
    metas = plan_suite(seed, num_scenarios)
    todo = _select(scenarios, num_scenarios)
    blocks: dict[int, list[int]] = {}
    for i in todo:
        blocks.setdefault(i // block, []).append(i)
    key = {"generator": "drivee2e_jax.scenario.twin15", "version": str(version), "seed": int(seed),
           "num_scenarios": int(num_scenarios), "block": block,
           "scenarios": None if scenarios is None else hashlib.sha256(json.dumps(todo).encode()).hexdigest()}
    name = suite_name(num_scenarios)
    writer = SuiteWriter(path, name=name, version=str(version), maps=_maps(), key=key, overwrite=overwrite)
    try:
        done = sum(len(ix) for b, ix in blocks.items() if writer.done(b))
        if progress is not None:
            progress(f"generating {name}", done, len(todo), {})
        for b, indices in blocks.items():
            if writer.done(b):
                continue
            scen, stats = _generate_some(seed, metas, indices, workers)
            writer.write_block(b, scen, stats)
            del scen
            done += len(indices)
            if progress is not None:
                progress(f"generating {name}", done, len(todo), {})
        return writer.finish(lambda stats: suite_meta(seed, num_scenarios, stats))
    finally:
        writer.close()
