"""Evaluate a split shard by shard: suites larger than memory.

``evaluate_stream(policy, shards, n_split)`` runs the same compiled rollout
as ``closedloop.evaluate`` over a sequence of shards ``(rows, PackedBatch)``
(``rows``: the shard's positions in the split, so every scenario gets the
PRNG key the whole split's run gives it), and keeps only rows and events:
the step logs of a shard are reduced to its result rows and dropped. Peak
memory is therefore bounded by a few shards (the one stepping, the one
being packed by the shard reader's thread, the one whose rows are being
computed), whatever the split's size.

How the work overlaps on the host:

* the shard source (``shards_of`` for an in-memory ``PackedBatch``,
  ``scenario.stream.shards`` for a suite folder) may read and pack the next
  shard in a background thread while this one steps;
* a shard's result rows (fine-grained metrics in numpy, events, nuPlan /
  NAVSIM columns) are computed in one worker thread while the next shard
  steps (XLA and numpy release the GIL for their array work).

The rollout is compiled once: every shard is padded to the first shard's
size with copies of its row 0 (real scenarios, dropped before scoring), and
the chunk length is fixed from the first shard. Per-scenario results equal
``evaluate``'s on the whole split (tested: statuses and events identical,
float columns to 1e-6 relative); only ``eval_time_s`` is the shard's time
per scenario.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor

import jax
import numpy as np

from drivee2e_jax import hostbridge
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import (
    EvalResult,
    _add_closed_loop_scores,
    _head,
    _route_mean,
    _rows_and_events,
    _scenario_keys,
    begin_rollout,
    device_batch,
    lane_free_warning,
    nonfinite_warning,
    with_policy_sensors,
)
from drivee2e_jax.observe import sensors
from drivee2e_jax.rollout import (
    ControlTiming,
    Rollout,
    balanced_chunk,
    episode_results,
    longest_episode,
    pad_rows,
    shard_rollout_inputs,
)
from drivee2e_jax.sim import SimConfig, Simulator


def shards_of(packed, shard_size: int) -> Iterator[tuple[np.ndarray, object]]:
    """``(rows, packed.select(rows))`` for consecutive ``shard_size`` rows of an
    in-memory ``PackedBatch`` (the in-memory source of ``evaluate_stream``)."""
    if shard_size < 1:
        raise DriveE2EError(f"shard size must be >= 1, got {shard_size}")
    n = len(packed)
    for start in range(0, n, shard_size):
        rows = np.arange(start, min(start + shard_size, n), dtype=np.int64)
        yield rows, packed.select(rows)


def evaluate_stream(
    policy,
    shards: Iterable[tuple[np.ndarray, object]],
    n_split: int,
    *,
    params=None,
    config: SimConfig | None = None,
    timing: ControlTiming | None = None,
    seed: int = 0,
    chunk: int = 50,
    maps: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
    on_shard: Callable[[list[dict], dict], None] | None = None,
    keep_rows: bool = True,
) -> EvalResult:
    """Roll ``policy`` out over ``shards`` of an ``n_split``-scenario split.

    Args:
      shards: ``(rows, PackedBatch)`` pairs; ``rows`` (int64, (S,)) are the
        shard's positions in the split (its scenarios' PRNG keys are
        ``split(PRNGKey(seed), n_split)[rows]``, as in ``evaluate``). Every
        shard must be packed at the same sizes (one compiled program).
      n_split: scenarios in the whole split (for the keys and the progress).
      progress: ``progress(done_scenarios, n_split)`` after every shard.
      on_shard: ``on_shard(rows, events)`` with each finished shard's result
        rows and events (in shard order), e.g. to write them as they come.
      keep_rows: False = do not keep the rows in the result (``on_shard``
        consumes them): memory then does not grow with the split.
      Other arguments as ``closedloop.evaluate`` (repetitions, devices and
      process shards are not supported here).

    Returns an ``EvalResult`` with ``logs = None``; ``compile_s`` is the first
    shard's init + first chunk, ``wall_s`` everything after it, ``steps`` the
    most steps any shard ran.
    """
    policy = hostbridge.wrap(policy)
    cfg = with_policy_sensors(config or SimConfig(), policy)
    sim = Simulator(cfg)
    key = jax.random.PRNGKey(seed)
    every = (timing or ControlTiming()).control_every
    pool = ThreadPoolExecutor(1, thread_name_prefix="drivee2e-rows")
    pending: Future | None = None
    rows_out: list[dict] = []
    events_out: dict[str, list[dict]] = {}
    nonfinite_all: list[np.ndarray] = []  # (S,) per shard: steps with a non-finite action
    lane_free_ids: list[str] = []  # scenarios whose map has no lanes
    ro = None
    b0 = 0
    done = 0
    max_steps = 0
    compile_s = 0.0
    t_start = time.perf_counter()

    def collect(fut: Future | None) -> None:
        if fut is None:
            return
        rows, events = fut.result()
        if on_shard is not None:
            on_shard(rows, events)
        if keep_rows:
            rows_out.extend(rows)
            events_out.update(events)

    try:
        for rows, packed in shards:
            rows = np.asarray(rows, np.int64)
            if len(rows) != len(packed):
                raise DriveE2EError(f"shard of {len(packed)} scenarios came with {len(rows)} row indices")
            if cfg.sensors.needs_raster and maps is None:
                raise DriveE2EError("evaluate_stream: the BEV needs the suite's maps: pass maps=")
            t_shard = time.perf_counter()
            assets = sensors.build_assets(packed, cfg.sensors, maps)
            batch, meta = device_batch(packed)
            b = len(rows)
            keys = _scenario_keys(key, n_split, rows)
            first_shard = ro is None
            if first_shard:  # the first shard fixes the params, the chunk and the compiled batch size
                total0 = longest_episode(sim, batch)
                chunk = balanced_chunk(total0, chunk, every)
                b0 = b
            if not hostbridge.is_host(policy) and b < b0:  # the last shard: padded to the compiled size with
                batch, keys = pad_rows((batch, keys), b0)     # copies of its row 0 (a host policy's batch is the shard)
                if assets is not None:
                    assets = assets.replace(map_index=pad_rows(assets.map_index, b0))
            run_batch, run_keys, run_assets = shard_rollout_inputs(batch, keys, assets, jax.local_devices()[:1])
            if first_shard:
                ro = Rollout(sim, policy, None, timing=timing, chunk=chunk, assets=run_assets)
            ro.assets = run_assets
            total = longest_episode(sim, run_batch)
            carry = begin_rollout(ro, run_batch, run_keys, key, meta, params, init=first_shard)
            logs, steps = [], 0
            while steps < total:
                carry, log = ro.advance(run_batch, carry)
                hostbridge.raise_if_failed(policy)
                logs.append(_head(log, b))
                steps += chunk
                if compile_s == 0.0:
                    compile_s = time.perf_counter() - t_start
                if bool(np.all(np.asarray(carry.sim.episode.done))):
                    break
            max_steps = max(max_steps, min(steps, total))
            results = _head(episode_results(sim, carry.sim.episode, run_batch.route), b)
            limit_kmh = _route_mean(_head(carry.sim.ctx.speed_limit, b), np.asarray(packed.scenario.route.valid)) * 3.6
            nonfinite_all.append(_head(carry.nonfinite, b))
            lanes_ok = np.asarray(packed.scenario.map.lanes.valid).reshape(b, -1).any(axis=1)
            lane_free_ids.extend(str(s) for s, ok in zip(meta.scenario_id, lanes_ok) if not ok)
            per_scn = (time.perf_counter() - t_shard) / max(b, 1)
            collect(pending)  # the previous shard's rows, computed while this one stepped
            pending = pool.submit(_finish_shard, policy, meta, packed.scenario, results, logs, sim, run_batch,
                                  total, chunk, per_scn, limit_kmh)
            done += b
            if progress:
                progress(done, n_split)
        collect(pending)
        pending = None
    finally:
        if pending is not None:
            pending.cancel()
        pool.shutdown(wait=True)
    if ro is None:
        raise DriveE2EError("evaluate_stream: no shards (the split is empty)")
    warnings = [*nonfinite_warning(np.concatenate(nonfinite_all), policy.action_type),
                *(lane_free_warning(np.zeros((len(lane_free_ids), 1), bool), lane_free_ids) if lane_free_ids else [])]
    return EvalResult(rows=rows_out, events=events_out, logs=None, compile_s=compile_s,
                      wall_s=time.perf_counter() - t_start - compile_s, steps=max_steps, warnings=warnings)


def _finish_shard(policy, meta, scenario, results, logs, sim, run_batch, total, chunk, per_scn, limit_kmh):
    """(rows, events) of one stepped shard: ``closedloop``'s row code on its logs."""
    stacked = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=1), *logs)
    rows, events = _rows_and_events(policy.name, meta, scenario, results, stacked, sim.config, per_scn, limit_kmh)
    _add_closed_loop_scores(rows, stacked, scenario, sim, run_batch, total, chunk)
    return rows, events
