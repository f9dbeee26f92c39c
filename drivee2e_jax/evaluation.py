"""``evaluate(policy, suite, split)`` (exported as ``drivee2e_jax.evaluate``): one policy, one split, one batched rollout.

Returns per-scenario records (the columns of ``io.results``) and the
infraction events with time and location, plus timing. Host-side glue around
``rollout.Rollout`` and ``metrics.episode.finalize``.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.metrics import finegrained
from drivee2e_jax.observe import sensors
from drivee2e_jax.rollout import ControlTiming, Rollout
from drivee2e_jax.sim import Simulator, SimConfig


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
    """

    rows: list[dict]
    events: dict[str, list[dict]]
    logs: Any
    compile_s: float
    wall_s: float
    steps: int


def evaluate(
    policy,
    suite,
    split: str | None = "val",
    *,
    params=None,
    config: SimConfig | None = None,
    timing: ControlTiming | None = None,
    seed: int = 0,
    limit: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    chunk: int = 50,
    maps: dict | None = None,
) -> EvalResult:
    """Roll ``policy`` out on every scenario of ``suite``'s ``split`` at once.

    Args:
      policy: a ``policy.Policy``.
      suite: a ``scenario.Suite`` (``load_suite(...)``) or a ``PackedBatch``.
      split: split name; ``None`` = every scenario.
      params: policy parameters (``policy.init`` is called when None).
      progress: ``progress(done_steps, total_steps)`` after every chunk.
      maps: {map_id: MapRecord}, needed for the BEV when ``suite`` is a
        ``PackedBatch`` (a ``Suite`` provides its own).

    Sensors: ``config.sensors`` plus every sensor the policy lists in
    ``required_sensors`` (``with_policy_sensors``).
    """
    packed = suite.pack(split) if hasattr(suite, "pack") else suite
    if limit is not None:
        packed = packed.select(np.arange(min(limit, len(packed))))
    cfg = with_policy_sensors(config or SimConfig(), policy)
    if cfg.sensors.bev is not None and maps is None:
        if not hasattr(suite, "maps"):
            raise ValueError("evaluate: the BEV needs the suite's maps: pass maps= with a PackedBatch")
        maps = suite.maps
    assets = sensors.build_assets(packed, cfg.sensors, maps)
    batch, meta = device_batch(packed)
    sim = Simulator(cfg)
    key = jax.random.PRNGKey(seed)
    if params is None:
        params = _init_params(policy, sim, batch, key, assets)
    ro = Rollout(sim, policy, params, timing=timing, chunk=chunk, assets=assets)
    b = int(batch.ego_index.shape[0])
    total = int(np.max(np.asarray(jax.vmap(sim.episode_steps)(batch))))

    t0 = time.perf_counter()
    keys = jax.random.split(key, b)
    carry = ro.init(batch, keys)
    carry, first = ro.advance(batch, carry)
    jax.block_until_ready(carry)
    compile_s = time.perf_counter() - t0  # includes one chunk of stepping

    t1 = time.perf_counter()
    logs = [jax.tree_util.tree_map(np.asarray, first)]
    steps = chunk
    if progress:
        progress(min(steps, total), total)
    while steps < total and not bool(np.all(np.asarray(carry.sim.episode.done))):
        carry, log = ro.advance(batch, carry)
        logs.append(jax.tree_util.tree_map(np.asarray, log))
        steps += chunk
        if progress:
            progress(min(steps, total), total)
    results = jax.tree_util.tree_map(np.asarray, jax.vmap(ep.finalize, in_axes=(0, 0, None))(
        carry.sim.episode, batch.route, sim.config.score
    ))
    wall_s = time.perf_counter() - t1
    limit_kmh = _route_mean(np.asarray(carry.sim.ctx.speed_limit), np.asarray(batch.route.valid)) * 3.6
    stacked = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=1), *logs)
    per_scn = (compile_s + wall_s) / max(b, 1)
    rows, events = _rows_and_events(policy.name, meta, batch, results, stacked, sim.config, per_scn, limit_kmh)
    return EvalResult(rows=rows, events=events, logs=stacked, compile_s=compile_s, wall_s=wall_s, steps=min(steps, total))


def device_batch(packed, limit: int | None = None):
    """(Scenario batch as device arrays, meta table), cut to the first ``limit`` scenarios."""
    batch, meta = packed.scenario, packed.meta
    if limit is not None:
        batch = jax.tree_util.tree_map(lambda a: a[:limit], batch)
        meta = meta.select(np.arange(min(limit, len(meta))))
    return jax.tree_util.tree_map(jnp.asarray, batch), meta


def with_policy_sensors(config: SimConfig, policy) -> SimConfig:
    """``config`` with the sensors ``policy.required_sensors`` lists turned on
    (at ``config.sensors``' sizes, else the defaults); others as configured."""
    required = tuple(getattr(policy, "required_sensors", ()) or ())
    if not required:
        return config
    want = set(required) | set(config.sensors.enabled)
    return dataclasses.replace(config, sensors=sensors.SensorConfig.for_policy(tuple(want), config.sensors))


def _init_params(policy, sim: Simulator, batch, key, assets=None):
    """``policy.init`` on the first scenario's initial observation."""
    first = jax.tree_util.tree_map(lambda a: a[0], batch)
    first_assets = None if assets is None else assets.replace(map_index=assets.map_index[0])
    _, obs = jax.jit(sim.reset)(key, first, first_assets)
    return policy.init(key, obs)


def _route_mean(values, valid):
    """(B,) mean of (B, R) per-route-point values over the valid points."""
    return np.where(valid, values, 0.0).sum(axis=1) / np.maximum(valid.sum(axis=1), 1)


def _rows_and_events(name, meta, batch, res, logs, cfg: SimConfig, eval_s_per_scenario, limit_kmh):
    rows, events = [], {}
    route_len = np.asarray(batch.route.length)
    fine_rows = finegrained.batch_columns(
        logs,
        route_length_m=route_len,
        route_completion_pct=np.asarray(res.route_completion),
        dt_s=cfg.dt,
        min_speed_pct=np.asarray(res.min_speed_pct),
        min_speed_valid=np.asarray(res.min_speed_valid),
    )
    for i, (m, fine) in enumerate(zip(meta.rows(), fine_rows)):
        counts = {k: int(v[i]) for k, v in ep.counts_dict(res).items()}
        log_i = jax.tree_util.tree_map(lambda a: a[i], logs)
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
            "route_completion": float(res.route_completion[i]),
            "infraction_score": float(res.infraction_score[i]),
            "driving_score": float(res.driving_score[i]),
            "success": bool(res.success[i]),
            "status": ep.status_name(int(res.status[i])),
            "outside_route_lanes_pct": round(float(res.outside_lanes_pct[i]), 3),
            "outside_route_lanes_m": round(float(res.outside_lanes_m[i]), 3),
            "episode_s": round(float(res.episode_s[i]), 3),
            "eval_time_s": round(eval_s_per_scenario, 4),
            **counts,
            # Undefined values (NaN) are null in JSON and empty in CSV.
            **{k: (round(v, 4) if np.isfinite(v) else None) for k, v in fine.items()},
        }
        rows.append(row)
        events[m["scenario_id"]] = ep.extract_events(log_i)
    return rows, events
