"""``evaluate(policy, suite, split)`` (exported as ``drivee2e_jax.evaluate``): one policy, one split, one batched rollout.

Returns per-scenario records (the columns of ``io.results``) and the
infraction events with time and location, plus timing. Host-side glue around
``rollout.Rollout`` and ``metrics.episode.finalize``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import hostbridge, testing
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.results import event_key
from drivee2e_jax.metrics import abilities, finegrained, navsim, nuplan
from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.observe import sensors
from drivee2e_jax.observe.bev import bev_label
from drivee2e_jax.rollout import (
    ControlTiming,
    LogReplay,
    Rollout,
    balanced_chunk,
    episode_results,
    longest_episode,
    shard_rollout_inputs,
)
from drivee2e_jax.sim import SimConfig, Simulator


@dataclasses.dataclass
class EvalResult:
    """What one evaluation produced.

    Attributes:
      rows: one dict per scenario (see ``io.results.BASE_COLUMNS`` + counts).
      events: scenario id -> list of infraction events {type, t, x, y, ...}.
      logs: the stacked ``StepLog`` (numpy, (B, T_sim, ...)).
      compile_s: seconds spent compiling (first call) .
      wall_s: seconds of the rollout after compilation.
      steps: simulated steps executed (max over the batch).
      warnings: one line each about results that may be meaningless (episodes
        with non-finite actions, maps without lanes); the CLI prints them.
    """

    rows: list[dict]
    events: dict[str, list[dict]]
    logs: Any
    compile_s: float
    wall_s: float
    steps: int
    warnings: list[str] = dataclasses.field(default_factory=list)


def evaluate(
    policy,
    suite,
    split: str | None = "val",
    *,
    params=None,
    config: SimConfig | None = None,
    timing: ControlTiming | None = None,
    seed: int = 0,
    seeds: Sequence[int] | None = None,
    limit: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    chunk: int = 50,
    maps: dict | None = None,
    devices: Sequence | None = None,
    shard: Sequence[int] | None = None,
) -> EvalResult:
    """Roll ``policy`` out on every scenario of ``suite``'s ``split`` at once.

    Args:
      policy: a ``policy.Policy``.
      suite: a ``scenario.Suite`` (``load_suite(...)``) or a ``PackedBatch``.
      split: split name; ``None`` = every scenario.
      params: policy parameters (``policy.init`` is called when None).
      progress: ``progress(done_steps, total_steps)`` after every chunk.
      chunk: at most this many steps per compiled chunk; the chunks are
        evened out over the longest episode (``rollout.balanced_chunk``).
      maps: {map_id: MapRecord}, needed for the BEV when ``suite`` is a
        ``PackedBatch`` (a ``Suite`` provides its own).
      seeds: repetitions in ONE rollout: the batch is tiled ``len(seeds)``
        times and repetition r's scenarios get the keys
        ``evaluate(seed=seeds[r])`` would give them, so its rows equal that
        call's (tested); rows carry ``repetition`` = r and events are keyed
        ``io.results.event_key(row)``. ``params`` are initialised once, from
        ``seeds[0]`` (pass ``params=`` if a policy's init depends on the key).
      devices: the batch is split over these (default: this process's
        ``jax.local_devices()``), padded with copies of a real scenario to a
        multiple of their number; padding rows are dropped, never scored.
      shard: evaluate only these rows of the split (after ``limit``), each
        with the PRNG key the whole split's run gives it, so the rows equal
        that run's (``distributed.process_shard``: one process's part).

    Sensors: ``config.sensors`` plus every sensor the policy lists in
    ``required_sensors`` (``with_policy_sensors``).

    Before the rollout compiles, a JAX policy is traced once on the first
    scenario's initial observation (``begin_rollout``): a policy that raises,
    returns the wrong action or state, or branches on a traced value is a
    one-line DriveE2EError naming its file and line instead of a JAX
    traceback. ``compile_s`` counts the reset, that check and the first chunk.
    """
    policy = hostbridge.wrap(policy)
    packed = suite.pack(split) if hasattr(suite, "pack") else suite
    if limit is not None:
        packed = packed.select(np.arange(min(limit, len(packed))))
    n_split = len(packed)
    index = np.arange(n_split) if shard is None else np.asarray(shard, np.int64)
    if shard is not None:
        packed = packed.select(index)
    n_scn = len(packed)
    if seeds is not None:
        seeds = [int(s) for s in seeds]
        seed = seeds[0]
        packed = packed.select(np.tile(np.arange(n_scn), len(seeds)))
    cfg = with_policy_sensors(config or SimConfig(), policy)
    if cfg.sensors.needs_raster and maps is None:
        if not hasattr(suite, "maps"):
            raise ValueError("evaluate: the BEV needs the suite's maps: pass maps= with a PackedBatch")
        maps = suite.maps
    assets = sensors.build_assets(packed, cfg.sensors, maps)
    batch, meta = device_batch(packed)
    sim = Simulator(cfg)
    key = jax.random.PRNGKey(seed)
    if hostbridge.is_host(policy):  # one host call per step for the whole batch, on one device
        devices = devices or jax.local_devices()[:1]
    b = int(batch.ego_index.shape[0])
    total = longest_episode(sim, batch)
    chunk = balanced_chunk(total, chunk, (timing or ControlTiming()).control_every)

    t0 = time.perf_counter()
    keys = _scenario_keys(key, n_split, index) if seeds is None else _repetition_keys(seeds, n_split, index)
    run_batch, keys, run_assets = shard_rollout_inputs(batch, keys, assets, devices)
    ro = Rollout(sim, policy, None, timing=timing, chunk=chunk, assets=run_assets)
    carry = begin_rollout(ro, run_batch, keys, key, meta, params)
    carry, first = ro.advance(run_batch, carry)
    jax.block_until_ready(carry)
    hostbridge.raise_if_failed(policy)
    compile_s = time.perf_counter() - t0  # includes one chunk of stepping

    t1 = time.perf_counter()
    logs = [_head(first, b)]
    steps = chunk
    if progress:
        progress(min(steps, total), total)
    while steps < total and not bool(np.all(np.asarray(carry.sim.episode.done))):
        carry, log = ro.advance(run_batch, carry)
        hostbridge.raise_if_failed(policy)
        logs.append(_head(log, b))
        steps += chunk
        if progress:
            progress(min(steps, total), total)
    results = _head(episode_results(sim, carry.sim.episode, run_batch.route), b)
    wall_s = time.perf_counter() - t1
    limit_kmh = _route_mean(_head(carry.sim.ctx.speed_limit, b), np.asarray(batch.route.valid)) * 3.6
    stacked = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=1), *logs)
    per_scn = (compile_s + wall_s) / max(b, 1)
    reps = None if seeds is None else np.repeat(np.arange(len(seeds)), n_scn)
    rows, events = _rows_and_events(policy.name, meta, batch, results, stacked, sim.config, per_scn, limit_kmh, reps)
    _add_closed_loop_scores(rows, stacked, batch, sim, run_batch, total, chunk)
    warnings = [*nonfinite_warning(_head(carry.nonfinite, b), policy.action_type),
                *lane_free_warning(np.asarray(batch.map.lanes.valid), meta.scenario_id)]
    return EvalResult(rows=rows, events=events, logs=stacked, compile_s=compile_s, wall_s=wall_s,
                      steps=min(steps, total), warnings=warnings)


def _add_closed_loop_scores(rows, logs, batch, sim: Simulator, run_batch, total: int, chunk: int) -> None:
    """Under the ``nuplan`` / ``navsim`` presets, add that benchmark's score
    and sub-metric columns to each row (``metrics.nuplan``, ``metrics.navsim``).

    NAVSIM's human filter and its progress reference need the logged ego
    driven through the same simulator: one more rollout of ``LogReplay``
    (sensors off) on the same scenarios."""
    preset = sim.config.score.name
    if preset not in ("nuplan", "navsim"):
        return
    scn = jax.tree_util.tree_map(np.asarray, batch)
    human = None
    if preset == "navsim":
        hsim = Simulator(dataclasses.replace(sim.config, sensors=sensors.SensorConfig()))
        _, human = Rollout(hsim, LogReplay(), None, chunk=chunk).run(run_batch, jax.random.PRNGKey(0), max_steps=total)
        human = _head(human, len(rows))
    plan_dt = sim.config.controller.waypoint_dt
    for i, row in enumerate(rows):
        one = lambda tree, i=i: jax.tree_util.tree_map(lambda a: a[i], tree)  # noqa: E731
        if preset == "nuplan":
            cols = nuplan.episode_columns(one(logs), one(scn), sim.config.dt)
        else:
            log_i = one(logs)
            cols = navsim.episode_columns(log_i, one(scn), sim.config.dt, human=one(human), plans=log_i.plan,
                                          plan_dt=plan_dt)
        row.update({k: round(float(v), 6) for k, v in cols.items()})


#: What the simulator does with a non-finite action (``sim.Simulator.to_controls``).
REPAIRED = {"controls": "replaced by a full brake: throttle 0, brake 1, steer 0",
            "waypoints": "NaN / inf waypoint coordinates replaced by 0, the ego's own position"}


def nonfinite_warning(steps, action_type: str) -> list[str]:
    """[one line] when some episode applied a non-finite action, else [].
    ``steps``: (B,) int steps per episode whose action held a NaN / inf."""
    steps = np.asarray(steps)
    bad = int(np.count_nonzero(steps))
    if not bad:
        return []
    return [f"{bad} of {len(steps)} episodes had non-finite actions ({int(steps.sum())} steps in all; "
            f"{REPAIRED.get(action_type, 'repaired')}); results may be meaningless"]


def lane_free_warning(lanes_valid, scenario_ids, shown: int = 5) -> list[str]:
    """[one line] naming the scenarios whose map has no lanes, else [].
    ``lanes_valid``: (B, L, ...) bool; ``scenario_ids``: (B,) (repetitions repeat ids)."""
    valid = np.asarray(lanes_valid).reshape(len(scenario_ids), -1)
    ids = list(dict.fromkeys(str(s) for s, ok in zip(scenario_ids, valid.any(axis=1)) if not ok))
    if not ids:
        return []
    more = ", ..." if len(ids) > shown else ""
    return [f"{len(ids)} scenario(s) have a map with no lanes ({', '.join(ids[:shown])}{more}): every step counts "
            f"as off-lane and the route has no lane to follow; their scores are meaningless"]


def device_batch(packed, limit: int | None = None):
    """(Scenario batch as device arrays, meta table), cut to the first ``limit`` scenarios."""
    batch, meta = packed.scenario, packed.meta
    if limit is not None:
        batch = jax.tree_util.tree_map(lambda a: a[:limit], batch)
        meta = meta.select(np.arange(min(limit, len(meta))))
    return jax.device_put(batch), meta


def with_policy_sensors(config: SimConfig, policy) -> SimConfig:
    """``config`` with the sensors ``policy.required_sensors`` lists turned on
    (at ``config.sensors``' sizes, else the policy's ``sensor_config`` sizes,
    else the defaults); others as configured.

    A policy whose ``sensor_config`` fixes a sensor's size (a model policy:
    the BEV of its training data) refuses a ``config`` that sets another
    size for it: a one-line DriveE2EError, not a silently different input.
    """

    required = tuple(getattr(policy, "required_sensors", ()) or ())
    if not required:
        return config
    own = getattr(policy, "sensor_config", None)
    chosen = config.sensors
    for name in required:
        fixed = None if own is None else own.get(name)
        configured = config.sensors.get(name)
        if fixed is None or configured == fixed:
            continue
        if configured is not None:
            size = bev_label if name == "bev" else repr
            raise DriveE2EError(f"policy {getattr(policy, 'name', '?')!r}: SimConfig.sensors.{name} is {size(configured)} "
                                f"but the policy was trained on {size(fixed)}; leave it unset or set that one")
        chosen = chosen.with_sensor(name, fixed)
    want = set(required) | set(config.sensors.enabled)
    return dataclasses.replace(config, sensors=sensors.SensorConfig.for_policy(tuple(want), chosen))


def begin_rollout(ro: Rollout, batch, keys, key, meta, params=None, *, init: bool = True):
    """Reset ``batch`` (``ro.reset``) and return the rollout's first carry.

    With ``init`` (the first batch of a run) ``ro.params`` is set to
    ``params``, or ``policy.init(key, obs)`` when None, on row 0's initial
    observation (``Start.first_obs``, reset with row 0's own key), and a JAX
    policy is checked on that observation first (``testing.checked_params``):
    a policy that raises, returns the wrong action or state, or branches on a
    traced value is a one-line DriveE2EError naming its file and line, not a
    JAX traceback. A host policy is started (``hostbridge.begin``) on the
    batch's rows. One compiled reset serves both the parameters and the
    rollout (before, a second reset of one scenario was compiled for them).

    ``batch``: the (possibly sharded) device ``Scenario`` batch, (B, ...);
    ``keys``: (B, 2) per-scenario keys; ``key``: the run's key (``init``'s);
    ``meta``: the batch's ``SuiteMeta`` (at least its real rows).
    """
    policy = ro.policy
    sid = str(meta.scenario_id[0])
    try:
        started = ro.reset(batch, keys)
    except DriveE2EError:
        raise
    except Exception as e:  # noqa: BLE001 - a policy's initial_state fails inside the compiled reset
        _raise_initial_state_problem(ro, batch, key, sid, e)
        raise
    if init:
        if hostbridge.is_host(policy):
            ro.params = policy.init(key, started.first_obs) if params is None else params
        else:
            ro.params = testing.checked_params(policy, started.first_obs, key, params,
                                               where=f"on scenario {sid}'s first observation")
    hostbridge.begin(policy, meta, batch, lambda: jax.tree_util.tree_map(lambda a: a[None], started.first_obs))
    return ro.start(started, batch)


def _raise_initial_state_problem(ro: Rollout, batch, key, sid: str, error: Exception) -> None:
    """The one-line DriveE2EError for a policy whose ``initial_state`` broke
    ``ro.reset``'s tracing (found again, abstractly, on the first scenario);
    returns when the policy is not the cause."""
    first = jax.tree_util.tree_map(lambda a: a[0], batch)
    assets = ro.assets if ro.assets is None else ro.assets.replace(map_index=ro.assets.map_index[0])
    try:
        _, obs = jax.eval_shape(ro.sim.reset, key, first, assets)
    except Exception:  # noqa: BLE001 - the simulator itself fails: the original error stands
        return
    report = testing.check_initial_state(ro.policy, obs, where=f"on scenario {sid}'s first observation")
    if report:  # --debug: the policy's own frames (found again abstractly), else the compiled reset's
        raise DriveE2EError(report[0].message) from (report[0].cause or error)


def init_params(policy, sim: Simulator, batch, key, assets=None):
    """``policy.init(key, obs)`` on the first scenario's initial observation
    (reset with ``key``): parameters for a rollout of ``batch`` (a device
    ``Scenario`` batch, (B, ...)) under ``sim``, for scripts that build a
    ``Rollout`` themselves; ``assets``: the batch's ``SensorAssets`` when a
    sensor is on. ``evaluate`` uses ``begin_rollout`` instead."""
    obs = jax.tree_util.tree_map(lambda a: a[0], first_observation(sim, batch, key, assets))
    return policy.init(key, obs)


def first_observation(sim: Simulator, batch, key, assets=None):
    """The initial observation of ``batch``'s first scenario, with a leading
    batch axis of 1 (what a host policy sees for a one-scenario batch)."""
    first = jax.tree_util.tree_map(lambda a: a[0], batch)
    first_assets = None if assets is None else assets.replace(map_index=assets.map_index[0])
    _, obs = jax.jit(sim.reset)(key, first, first_assets)
    return jax.tree_util.tree_map(lambda a: a[None], obs)


def _route_mean(values, valid):
    """(B,) mean of (B, R) per-route-point values over the valid points."""
    return np.where(valid, values, 0.0).sum(axis=1) / np.maximum(valid.sum(axis=1), 1)


def _scenario_keys(key, n_split: int, index):
    """(len(index), 2) keys of rows ``index`` of an ``n_split``-scenario split:
    ``split(key, n_split)[index]``, so a shard's rows get the whole run's keys."""
    return jax.random.split(key, n_split)[np.asarray(index)]


def _repetition_keys(seeds: Sequence[int], n_split: int, index):
    """(len(seeds) * len(index), 2) per-scenario keys: repetition r's block is
    ``_scenario_keys(PRNGKey(seeds[r]), n_split, index)``."""
    return jnp.concatenate([_scenario_keys(jax.random.PRNGKey(s), n_split, index) for s in seeds])


def _head(tree, n: int):
    """``tree`` as numpy with only its first ``n`` rows (drops the padding rows of a sharded batch)."""
    return jax.tree_util.tree_map(lambda a: np.asarray(a)[:n], tree)


def _rows_and_events(name, meta, batch, res, logs, cfg: SimConfig, eval_s_per_scenario, limit_kmh, reps=None):
    rows, events = [], {}
    route_len = np.asarray(batch.route.length)
    fine_rows = finegrained.batch_columns(
        logs,
        route_length_m=route_len,
        route_completion_pct=np.asarray(res.route_completion),
        dt_s=cfg.dt,
        min_speed_pct=np.asarray(res.min_speed_pct),
        min_speed_valid=np.asarray(res.min_speed_valid),
        bm_scores=True,
    )
    # Bench2Drive's Traffic_Signs junction credit needs where each route enters its junction (1 m points).
    valid = np.asarray(batch.route.valid)
    junction = abilities.first_junction_index(np.asarray(batch.route.command), valid)
    for i, (m, fine) in enumerate(zip(meta.rows(), fine_rows)):
        counts = {k: int(v[i]) for k, v in ep.counts_dict(res).items()}
        log_i = jax.tree_util.tree_map(lambda a, i=i: a[i], logs)
        row = {
            "policy": name,
            "scenario_id": m["scenario_id"],
            "split": m["split"],
            "intersection_id": m["intersection_id"],
            "behavior": m["behavior"],
            "weather": m["weather"],
            "time_of_day": m["time_of_day"],
            "route_length_m": round(float(route_len[i]), 3),
            "route_speed_limit_kmh": round(float(limit_kmh[i]), 2),
            "route_junction_index": int(junction[i]),
            "route_waypoints": int(valid[i].sum()),
            "route_completion": float(res.route_completion[i]),
            "infraction_score": float(res.infraction_score[i]),
            "driving_score": float(res.driving_score[i]),
            "success": bool(res.success[i]),
            "status": ep.status_name(int(res.status[i])),
            # Both collision views side by side (``ScoreConfig.collision_mode`` picks the headline above).
            "driving_score_all": float(res.driving_score_all[i]),
            "infraction_score_all": float(res.infraction_score_all[i]),
            "success_all": bool(res.success_all[i]),
            "driving_score_at_fault": float(res.driving_score_at_fault[i]),
            "infraction_score_at_fault": float(res.infraction_score_at_fault[i]),
            "success_at_fault": bool(res.success_at_fault[i]),
            "outside_route_lanes_pct": round(float(res.outside_lanes_pct[i]), 3),
            "outside_route_lanes_m": round(float(res.outside_lanes_m[i]), 3),
            "episode_s": round(float(res.episode_s[i]), 3),
            "eval_time_s": round(eval_s_per_scenario, 4),
            **counts,
            # Undefined values (NaN) are null in JSON and empty in CSV.
            **{k: (round(v, 4) if np.isfinite(v) else None) for k, v in fine.items()},
        }
        if reps is not None:
            row["repetition"] = int(reps[i])
        rows.append(row)
        events[event_key(row)] = events_to_world(ep.extract_events(log_i), meta.origin[i])
    return rows, events


def events_to_world(events: list[dict], origin) -> list[dict]:
    """``events`` (``metrics.episode.extract_events``: x, y in the packed
    local frame) with x, y in the world frame: plus ``origin`` ((2,) float64,
    the row's ``meta.origin``), rounded to mm like the local ones."""
    ox, oy = (float(v) for v in np.asarray(origin, np.float64).reshape(2))
    if ox == 0.0 and oy == 0.0:
        return events
    return [{**e, "x": round(e["x"] + ox, 3), "y": round(e["y"] + oy, 3)} if "x" in e else e for e in events]
