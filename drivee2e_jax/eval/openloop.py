"""Open-loop evaluation of a waypoint policy on the reference demonstrations.

The ego follows its LOG (each step applies ``Observation.privileged.log_controls``,
the log-replay demonstration, which reproduces the logged positions), so the
policy's output never feeds back. Every ``every`` simulation steps the policy
under test is queried on the same observation a closed-loop run would give it,
and its ``Waypoints`` are compared with the logged future:

* ground truth: the logged ego positions at t + 0.5, ..., t + 3.0 s
  (``horizon`` x ``waypoint_dt``), in the frame of the ego at t (the frame the
  policy's waypoints are expressed in); steps where the log is invalid are
  masked;
* L2 per step (UniAD: masked steps give 0), reported in the UniAD (value at
  step 2/4/6) and ST-P3 (mean over steps 1..2k) conventions;
* collisions: the ego's oriented box at each predicted waypoint (heading from
  consecutive waypoints) against the LOGGED agents' boxes at that future time,
  a step where the logged ego itself collides adding 0
  (``metrics.openloop.openloop_box_collisions``).

One jitted, vmapped ``lax.scan`` over the packed batch: an outer scan over the
queries, each running ``every`` log-replay simulator steps inside, so the
policy runs only at query steps. Pure functions live in ``metrics.openloop``.

A sample counts while the episode is running (the simulator freezes a finished
episode) and the ego is logged at t; with ``full_future=True`` (default, VAD's
``fut_valid_flag``) its whole future must be logged too, otherwise masked
steps give 0 and the sample still counts (UniAD).

Suite-level values: every per-scenario value is a per-step sum divided by
``openloop_samples``, so the pooled value over scenarios is the
``openloop_samples``-weighted mean of the per-scenario values.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax import geometry, hostbridge, replay
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import device_batch, with_policy_sensors
from drivee2e_jax.metrics import openloop as olm
from drivee2e_jax.observe import sensors
from drivee2e_jax.rollout import longest_episode
from drivee2e_jax.sim import SimConfig, Simulator
from drivee2e_jax.types import Controls, Waypoints

#: Reported horizons, s.
SECONDS = (1, 2, 3)


class ShortHorizonError(DriveE2EError):
    """The policy's waypoints end before the open-loop horizon (e.g. a PPO
    actor with two waypoints): open-loop L2 is undefined for it. ``bench
    --open-loop`` and ``drivee2e trend`` leave its open-loop columns empty."""


@struct.dataclass
class OpenLoopFacts:
    """One policy query (one scenario); the driver stacks them (B, N, ...).

    Attributes:
      t:          () s, simulation time of the query.
      pred:       (H, 2) predicted positions resampled to ``waypoint_dt``, ego frame, m.
      gt:         (H, 2) logged future positions, ego frame at t, m.
      gt_mask:    (H,) bool, the log is valid at that future time.
      l2:         (H,) per-step L2 (masked steps 0), m.
      collision:  (H,) bool, the predicted box overlaps a logged agent and the
                  logged ego's box does not.
      gt_collision: (H,) bool, the logged ego's own box overlaps a logged agent.
      sample:     () bool, this query counts.
      deviation:  () m, distance of the simulated ego from its log at t.
    """

    t: jnp.ndarray
    pred: jnp.ndarray
    gt: jnp.ndarray
    gt_mask: jnp.ndarray
    l2: jnp.ndarray
    collision: jnp.ndarray
    gt_collision: jnp.ndarray
    sample: jnp.ndarray
    deviation: jnp.ndarray


@dataclasses.dataclass
class OpenLoopRun:
    """What ``collect_openloop`` produced.

    Attributes:
      facts: ``OpenLoopFacts`` with numpy leaves (B, N, ...).
      scenario_ids: B scenario ids, batch order.
      horizon, waypoint_dt: the ground-truth steps.
      compile_s: s to compile (reset + scan) including the first run.
      wall_s: s of a second, compiled run (0 if not measured).
    """

    facts: Any
    scenario_ids: list[str]
    horizon: int
    waypoint_dt: float
    compile_s: float
    wall_s: float = 0.0


def resample_waypoints(xy: jnp.ndarray, src_dt: float, horizon: int, dst_dt: float) -> jnp.ndarray:
    """Positions at ``dst_dt * (1..horizon)`` s from waypoints ``xy (K, 2)``
    ``src_dt`` s apart (the first at ``src_dt``; the ego origin at 0), linear
    in time. The caller guarantees ``K * src_dt >= horizon * dst_dt``.

    Returns (horizon, 2) m.
    """
    k = xy.shape[-2]
    if abs(src_dt - dst_dt) < 1e-9 and k >= horizon:
        return xy[..., :horizon, :]
    src_t = src_dt * jnp.arange(k + 1, dtype=jnp.float32)
    pts = jnp.concatenate([jnp.zeros((1, 2), xy.dtype), xy], axis=0)
    dst_t = dst_dt * jnp.arange(1, horizon + 1, dtype=jnp.float32)
    return jnp.stack([jnp.interp(dst_t, src_t, pts[:, 0]), jnp.interp(dst_t, src_t, pts[:, 1])], axis=-1)


def _check_args(policy, horizon, waypoint_dt, every):
    action_type = getattr(policy, "action_type", None)
    if action_type != "waypoints":
        name = getattr(policy, "name", type(policy).__name__)
        raise DriveE2EError(
            f"open-loop metrics need a waypoint policy (action_type 'waypoints'); "
            f"{name!r} has action_type {action_type!r}"
        )
    if not (isinstance(horizon, (int, np.integer)) and horizon >= 1):
        raise DriveE2EError(f"open-loop horizon must be an integer >= 1 step, got {horizon!r}")
    if not waypoint_dt > 0:
        raise DriveE2EError(f"open-loop waypoint_dt must be > 0 s, got {waypoint_dt!r}")
    if not (isinstance(every, (int, np.integer)) and every >= 1):
        raise DriveE2EError(f"open-loop query interval `every` must be an integer >= 1 step, got {every!r}")


_RESETS: dict = {}
_RUNNERS: dict = {}


def _cached(cache: dict, key, build):
    """``build()`` memoised on ``key`` (unhashable keys are not cached)."""
    try:
        hash(key)
    except TypeError:
        return build()
    if key not in cache:
        if len(cache) >= 8:
            cache.pop(next(iter(cache)))
        cache[key] = build()
    return cache[key]


def _make_runner(sim: Simulator, policy, horizon: int, waypoint_dt: float, every: int, n_queries: int,
                 policy_dt: float, full_future: bool, axes):
    """jit(vmap(one scenario)): (batch, sim states, obs, keys, sensor assets, params) -> OpenLoopFacts
    (B, N, ...); ``axes`` = ``sensors.assets_axes`` of the assets."""
    offsets = waypoint_dt * jnp.arange(1, horizon + 1, dtype=jnp.float32)

    def one(scenario, state, obs, key, assets, params):
        tracks = scenario.tracks
        ego_i = scenario.ego_index
        dt_log = scenario.dt_log
        ego_lw = tracks.size[ego_i, :2]
        agents_lw = tracks.size[:, :2]
        not_ego = jnp.arange(tracks.xy.shape[0]) != ego_i

        def query(state, obs, pstate, key):
            key, k_act = jax.random.split(key)
            action, pstate = policy.act(params, obs, pstate, k_act)
            pred = resample_waypoints(jnp.asarray(action.xy, jnp.float32), policy_dt, horizon, waypoint_dt)
            ego = state.ego
            times = ego.t + offsets
            now = replay.ego_log_at(tracks, ego_i, ego.t, dt_log)
            fut = jax.vmap(lambda tt: replay.ego_log_at(tracks, ego_i, tt, dt_log))(times)
            gt = geometry.to_frame(fut.xy, ego.xy, ego.yaw)
            agents = jax.vmap(lambda tt: replay.agents_at(tracks, tt, dt_log))(times)  # (H, A)
            a_xy = geometry.to_frame(agents.xy, ego.xy, ego.yaw)
            a_yaw = geometry.wrap_angle(agents.yaw - ego.yaw)
            a_valid = agents.valid & not_ego[None]
            counted, gt_col = olm.openloop_box_collisions(
                pred, gt, ego_lw, a_xy, a_yaw, agents_lw, a_valid, gt_mask=fut.valid
            )
            sample = ~state.episode.done & now.valid
            if full_future:
                sample = sample & jnp.all(fut.valid)
            facts = OpenLoopFacts(
                t=ego.t,
                pred=pred,
                gt=jnp.where(fut.valid[:, None], gt, 0.0),
                gt_mask=fut.valid,
                l2=olm.l2_per_step(pred, gt, fut.valid),
                collision=counted,
                gt_collision=gt_col,
                sample=sample,
                deviation=geometry.safe_norm(ego.xy - now.xy),
            )
            return facts, pstate, key

        def replay_step(carry, _):
            st, ob = carry
            c, ok = ob.privileged.log_controls, ob.privileged.log_valid
            action = Controls(
                throttle=jnp.where(ok, c.throttle, 0.0),
                brake=jnp.where(ok, c.brake, 1.0),
                steer=jnp.where(ok, c.steer, 0.0),
            )
            st, ob, _ = sim.step(scenario, st, action, assets)
            return (st, ob), None

        def outer(carry, _):
            st, ob, pstate, k = carry
            facts, pstate, k = query(st, ob, pstate, k)
            (st, ob), _ = jax.lax.scan(replay_step, (st, ob), None, length=every)
            return (st, ob, pstate, k), facts

        pstate = policy.initial_state(obs)
        _, facts = jax.lax.scan(outer, (state, obs, pstate, key), None, length=n_queries)
        return facts

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, 0, axes, None)))


def collect_openloop(
    policy,
    packed,
    *,
    params=None,
    config: SimConfig | None = None,
    seed: int = 0,
    limit: int | None = None,
    horizon: int = 6,
    waypoint_dt: float = 0.5,
    every: int = 5,
    full_future: bool = True,
    measure: bool = False,
    maps: dict | None = None,
) -> OpenLoopRun:
    """Run the open-loop replay and return the per-query facts (host numpy).

    Arguments as ``evaluate_openloop``; ``measure=True`` runs the compiled
    program a second time to time it without compilation.
    """
    policy = hostbridge.wrap(policy)  # a host policy: one host call per query for the whole batch
    _check_args(policy, horizon, waypoint_dt, every)
    if hasattr(packed, "pack"):
        raise DriveE2EError("evaluate_openloop expects a PackedBatch (e.g. suite.pack('val')), got a Suite")
    if limit is not None:
        packed = packed.select(np.arange(min(limit, len(packed))))
    # The sensors the policy declares are rendered from the replayed ego, as in closed loop.
    cfg = with_policy_sensors(config or SimConfig(), policy)
    if cfg.sensors.bev is not None and maps is None:
        raise DriveE2EError(f"open-loop scoring of {getattr(policy, 'name', '?')!r} renders its BEV: pass the "
                            "suite's maps (maps=suite.maps)")
    assets = sensors.build_assets(packed, cfg.sensors, maps)
    axes = sensors.assets_axes(assets)
    batch, meta = device_batch(packed)
    sim = Simulator(cfg)
    b = int(batch.ego_index.shape[0])
    key = jax.random.PRNGKey(seed)
    k_init, k_reset, k_run = jax.random.split(key, 3)

    t0 = time.perf_counter()
    reset = _cached(_RESETS, sim.config, lambda: jax.jit(jax.vmap(sim.reset, in_axes=(0, 0, axes))))
    states, obs = reset(jax.random.split(k_reset, b), batch, assets)
    obs0 = jax.tree_util.tree_map(lambda a: a[0], obs)
    hostbridge.begin(policy, meta, batch, lambda: jax.tree_util.tree_map(lambda a: a[:1], obs))
    if params is None:
        params = policy.init(k_init, obs0)

    # The action's structure and length, without running the policy.
    out = jax.eval_shape(lambda o: policy.act(params, o, policy.initial_state(o), k_init)[0], obs0)
    if not isinstance(out, Waypoints):
        raise DriveE2EError(
            f"open-loop metrics need a waypoint policy: {getattr(policy, 'name', '?')!r} returned "
            f"{type(out).__name__}, expected Waypoints"
        )
    if len(out.xy.shape) != 2 or out.xy.shape[-1] != 2:
        raise DriveE2EError(f"policy waypoints must have shape (K, 2), got {tuple(out.xy.shape)}")
    policy_dt = float(getattr(policy, "waypoint_dt", waypoint_dt))
    k = int(out.xy.shape[0])
    if not policy_dt > 0 or k * policy_dt < horizon * waypoint_dt - 1e-6:
        raise ShortHorizonError(
            f"policy waypoints cover {k} x {policy_dt} s, open-loop evaluation needs {horizon} x {waypoint_dt} s"
        )

    total = longest_episode(sim, batch)
    n_queries = max(1, math.ceil(total / every))
    run = _cached(
        _RUNNERS,
        (policy, sim.config, horizon, float(waypoint_dt), every, n_queries, policy_dt, bool(full_future)),
        lambda: _make_runner(sim, policy, horizon, float(waypoint_dt), every, n_queries, policy_dt, full_future, axes),
    )
    keys = jax.random.split(k_run, b)
    facts = run(batch, states, obs, keys, assets, params)
    hostbridge.raise_if_failed(policy)
    facts = jax.tree_util.tree_map(np.asarray, facts)
    compile_s = time.perf_counter() - t0
    wall_s = 0.0
    if measure:
        t1 = time.perf_counter()
        jax.block_until_ready(run(batch, states, obs, keys, assets, params))
        wall_s = time.perf_counter() - t1
    ids = [str(s) for s in meta.scenario_id.tolist()]
    return OpenLoopRun(facts=facts, scenario_ids=ids, horizon=horizon, waypoint_dt=float(waypoint_dt),
                       compile_s=compile_s, wall_s=wall_s)


def _at_seconds(per_step: np.ndarray, waypoint_dt: float, convention: str) -> dict[int, np.ndarray]:
    """k -> (B,) value at k s (NaN for horizons the steps do not cover)."""
    out = {}
    h = per_step.shape[-1]
    for s in SECONDS:
        try:
            (n,) = olm.horizon_steps((s,), waypoint_dt, h)
        except DriveE2EError:
            out[s] = np.full(per_step.shape[:-1], np.nan)
            continue
        fn = olm.uniad_convention if convention == "uniad" else olm.stp3_convention
        out[s] = np.asarray(fn(per_step, (s,), waypoint_dt))[..., 0]
    return out


def summarize(run: OpenLoopRun) -> dict[str, dict]:
    """Per-scenario open-loop metrics from ``collect_openloop``'s facts.

    Keys per scenario: ``l2_{1,2,3}s_{stp3,uniad}`` (m),
    ``openloop_collision_rate`` (fraction of (sample, future step) pairs whose
    predicted box overlaps a logged agent while the logged ego's does not =
    the ST-P3 value over the whole horizon), ``openloop_samples`` (queries
    that count), ``openloop_gt_collision_steps`` (future steps at which the
    logged ego itself overlaps a logged agent, over counted samples: a log
    check) and ``openloop_log_deviation_m`` (largest distance of the replayed
    ego from its log at a counted query). NaN when no query counts.
    """
    f = run.facts
    sample = np.asarray(f.sample, bool)
    l2 = np.asarray(olm.sample_mean(f.l2, sample))  # (B, H)
    col = np.asarray(olm.sample_mean(f.collision, sample))  # (B, H)
    l2_u = _at_seconds(l2, run.waypoint_dt, "uniad")
    l2_s = _at_seconds(l2, run.waypoint_dt, "stp3")
    n = sample.sum(axis=-1)
    gt_steps = np.sum(np.asarray(f.gt_collision, bool) & sample[..., None], axis=(-2, -1))
    dev = np.where(sample, np.asarray(f.deviation), -np.inf).max(axis=-1)
    out = {}
    for i, sid in enumerate(run.scenario_ids):
        row = {}
        for s in SECONDS:
            row[f"l2_{s}s_stp3"] = float(l2_s[s][i])
        for s in SECONDS:
            row[f"l2_{s}s_uniad"] = float(l2_u[s][i])
        row["openloop_collision_rate"] = float(np.mean(col[i])) if n[i] else float("nan")
        row["openloop_samples"] = int(n[i])
        row["openloop_gt_collision_steps"] = int(gt_steps[i])
        row["openloop_log_deviation_m"] = float(dev[i]) if n[i] else float("nan")
        out[sid] = row
    return out


def evaluate_openloop(
    policy,
    packed,
    *,
    params=None,
    config: SimConfig | None = None,
    seed: int = 0,
    limit: int | None = None,
    horizon: int = 6,
    waypoint_dt: float = 0.5,
    every: int = 5,
    full_future: bool = True,
    maps: dict | None = None,
) -> dict[str, dict]:
    """Open-loop metrics of a waypoint policy on the logged demonstrations.

    Args:
      policy: a ``policy.Policy`` with ``action_type == "waypoints"`` whose
        ``Waypoints.xy (K, 2)`` are ``policy.waypoint_dt`` s apart (resampled
        linearly in time to ``waypoint_dt``; they must cover the horizon).
      packed: a ``scenario.pack.PackedBatch`` (``suite.pack(split)``).
      params: policy parameters (``policy.init`` on the first observation when None).
      config: simulator settings (default ``SimConfig()``).
      seed: PRNG seed (observation noise, policy keys).
      limit: only the first ``limit`` scenarios.
      horizon: future steps compared (6), ``waypoint_dt`` s apart (0.5).
      every: query the policy every ``every`` simulation steps (5 x 0.1 s = 2 Hz).
      full_future: count only queries whose whole future is logged (VAD);
        False = UniAD's rule (masked steps give 0, the sample counts).
      maps: {map_id: MapRecord} (``suite.maps``), needed when the policy
        declares the BEV in ``required_sensors``; its sensors are rendered
        from the replayed ego as in closed loop.

    Returns scenario_id -> {"l2_1s_stp3", "l2_2s_stp3", "l2_3s_stp3",
    "l2_1s_uniad", "l2_2s_uniad", "l2_3s_uniad", "openloop_collision_rate",
    "openloop_samples", "openloop_gt_collision_steps",
    "openloop_log_deviation_m"} (see ``summarize``).

    Raises DriveE2EError for a controls policy, waypoints that do not cover
    the horizon, or bad arguments.
    """
    run = collect_openloop(policy, packed, params=params, config=config, seed=seed, limit=limit,
                           horizon=horizon, waypoint_dt=waypoint_dt, every=every, full_future=full_future, maps=maps)
    return summarize(run)
