"""A functional JAX environment over a packed suite (gymnax / Jumanji style).

Everything is pure and jittable; batch environments with ``jax.vmap``::

    params = make_params("tiny", "train")
    env = AutoResetWrapper(DriveEnv())
    obs, state = env.reset(key, params)
    obs, state, reward, done, info = env.step(key, state, action, params)

* ``EnvParams``: the packed suite's ``Scenario`` batch (N, ...) on the device
  (and the sensors' map rasters when a BEV is on) plus the static
  ``SimConfig`` and ``RewardConfig`` (pytree metadata: static under ``jit``).
* ``EnvState``: the ``sim.SimState`` of the running episode, the scenario's
  row in ``params.scenarios`` and step / episode counters.
* ``DriveEnv.reset(key, params, index=None)`` draws a scenario uniformly from
  the suite (or takes row ``index``) and returns ``(obs, state)``.
* ``DriveEnv.step(key, state, action, params)`` returns
  ``(obs, state, reward, done, info)``. ``done`` = the episode ended;
  ``info["terminated"]`` (the route ended: completed, deviated, blocked,
  timed out) and ``info["truncated"]`` (cut by the time limit: end of the log
  or ``SimConfig.max_episode_s``) keep the two apart, and
  ``info["discount"]`` = 1 - terminated is what a value bootstrap multiplies.
  Stepping a finished episode (without ``AutoResetWrapper``) changes nothing
  and yields reward 0.
* ``AutoResetWrapper``: on ``done`` the next scenario is drawn and its first
  observation returned; the last observation of the finished episode is
  ``info["final_obs"]`` (Gymnasium's SAME_STEP autoreset).
* ``VmapAutoResetWrapper``: the same for a batch of environments (keys,
  states and actions with a leading B), resetting only the environments
  that ended instead of computing a reset for all of them and selecting
  (2.2x the vmapped wrapper's steps/s at B = 256, docs/performance.md).

Observations are ``types.Observation`` (including ``privileged``: ground truth
for reference policies and imitation targets, not for benchmark policies).
Actions are ``types.Controls``, ``types.Waypoints`` or a plain array: shape
(3,) = [throttle, brake, steer], shape (K, 2) = ego-frame waypoints.

Reward (``RewardConfig``, docs/envs.md): metres of route progress this step
minus Leaderboard-2.0 penalties for this step's events, scaled to metres.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.metrics.comfort import B2D_BOUNDS
from drivee2e_jax.metrics.driving_score import PENALTIES
from drivee2e_jax.observe import sensors
from drivee2e_jax.scenario import PackedBatch, load_suite
from drivee2e_jax.sim import SimConfig, SimState, Simulator, StepLog
from drivee2e_jax.types import CollisionClass, Controls, Observation, Scenario, Waypoints

_LB20 = {p.key: p.lb20 for p in PENALTIES}


# --------------------------------------------------------------------------
# Reward
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RewardConfig:
    """The step reward (frozen, hashable: static under ``jit``).

    ``reward = progress * (metres of route progress this step
                           - metres of it passed outside the route lanes)
               - scale * (sum over this step's events of their penalty)``

    where ``scale`` is ``penalty_scale_m`` or, when None, the scenario's route
    length. An event's penalty defaults to 1 - its Leaderboard 2.0 factor
    (``metrics.driving_score.PENALTIES``): pedestrian collision 0.5, vehicle
    collision 0.4, static collision 0.35, red light 0.3. With the defaults the
    return of a completed route is, to first order, route length x DS / 100:
    DS multiplies completion by one factor per event and by
    (1 - off-lane share) for driving outside the route lanes.

    Attributes:
      progress: reward per metre of route progress (the route-completion
        criterion's progress along the 1 m route points).
      outside_lanes: progress made outside the route lanes earns nothing
        (only when the score preset counts outside-route-lanes).
      penalty_scale_m: metres per unit penalty; None = the route's length.
      collision_pedestrian, collision_vehicle, collision_layout, red_light:
        penalty per counted event (a collision counts once per contact, as
        the leaderboard counts it; only criteria the score preset enables).
      failure: penalty when the route fails (deviation, blocked, route
        timeout); 0 by default: the lost completion is the leaderboard's
        penalty for it.
      invalid_action: penalty per step whose action was out of range or
        non-finite (clipped / replaced by a full brake by the simulator).
      at_fault_only: count a collision with an agent only when nuPlan's
        attribution (``infractions.at_fault``: the ego's front, a stopped
        agent, or a side contact while in several lanes / off the drivable
        area) puts it on the ego; contacts with the ego stopped and rear-end
        contacts, which non-reactive replay causes whenever the ego drives
        slower than the log, then cost nothing. Layout collisions always
        count. False by default (the leaderboard counts every collision).
      comfort: metres taken off per step whose ego motion leaves
        Bench2Drive's comfort bounds (``metrics.comfort.B2D_BOUNDS``:
        longitudinal acceleration in (-4.05, 2.40) m/s^2, lateral
        acceleration speed x yaw rate within 4.89 m/s^2, yaw rate within
        0.95 rad/s), as CaRL's comfort term; 0 (off) by default. Not scaled
        by the route length.
    """

    progress: float = 1.0
    outside_lanes: bool = True
    penalty_scale_m: float | None = None
    collision_pedestrian: float = 1.0 - _LB20["collisions_pedestrian"]
    collision_vehicle: float = 1.0 - _LB20["collisions_vehicle"]
    collision_layout: float = 1.0 - _LB20["collisions_layout"]
    red_light: float = 1.0 - _LB20["red_light"]
    failure: float = 0.0
    invalid_action: float = 0.0
    comfort: float = 0.0
    at_fault_only: bool = False

    def __call__(self, scenario: Scenario, prev: SimState, new: SimState, log: StepLog, config: SimConfig):
        """() float32 reward of the step ``prev`` -> ``new`` (``log`` its StepLog)."""
        route = scenario.route
        progress = ep.progress_arc(new.episode, route) - ep.progress_arc(prev.episode, route)
        if self.outside_lanes and config.score.outside_lanes:
            progress = progress - (new.episode.outside.wrong - prev.episode.outside.wrong)
        e = log.events
        cls = e.collision_class
        agent_hit = e.collision & log.facts.at_fault if self.at_fault_only else e.collision
        units = (
            self.collision_pedestrian * (agent_hit & (cls == CollisionClass.PEDESTRIAN))
            + self.collision_vehicle * (agent_hit & (cls == CollisionClass.VEHICLE))
            + self.collision_layout * (e.collision & (cls == CollisionClass.LAYOUT))
            + self.red_light * e.red_light
            + self.failure * (e.route_deviation | e.blocked | e.route_timeout)
            + self.invalid_action * (e.invalid_action & log.active)
        )
        scale = route.length if self.penalty_scale_m is None else self.penalty_scale_m
        reward = self.progress * progress - scale * units
        if self.comfort:
            reward = reward - self.comfort * (uncomfortable(new.ego) & log.active)
        return reward.astype(jnp.float32)


_BOUNDS = {k: (lo, hi) for k, lo, hi in B2D_BOUNDS}


def uncomfortable(ego) -> jnp.ndarray:
    """() bool: the ego's last step left Bench2Drive's comfort bounds
    (longitudinal / lateral acceleration, yaw rate; unsmoothed, per step)."""
    lat = ego.speed * ego.yaw_rate
    out = jnp.zeros((), bool)
    for name, x in (("lon_acc", ego.accel), ("lat_acc", lat), ("yaw_rate", ego.yaw_rate)):
        lo, hi = _BOUNDS[name]
        out = out | (x <= lo) | (x >= hi)
    return out


# --------------------------------------------------------------------------
# Params and state
# --------------------------------------------------------------------------


@struct.dataclass
class EnvParams:
    """What the environment steps in.

    Attributes:
      scenarios: ``types.Scenario`` with leading axis N (the packed suite split).
      assets: ``observe.sensors.SensorAssets`` of those scenarios (map rasters
        + (N,) map index) when a sensor needs them, else None.
      contexts: ``sim.SimContext`` (N, ...) of every scenario under ``config``,
        computed once by ``make_params`` (``with_contexts``): a reset then only
        gathers its row instead of deriving the per-episode constants again,
        which would otherwise dominate an ``AutoResetWrapper`` step (it resets
        every step, selecting where done). None: computed at each reset.
        Used only while ``config`` is the one it was computed for
        (``contexts_config``); recompute it (``with_contexts``) after
        changing ``config`` or ``scenarios``.
      config: ``sim.SimConfig`` (static).
      reward: the reward function (static): a ``RewardConfig`` or any hashable
        callable with its signature.
    """

    scenarios: Scenario
    assets: Any = None
    contexts: Any = None
    config: SimConfig = struct.field(pytree_node=False, default_factory=SimConfig)
    reward: Any = struct.field(pytree_node=False, default_factory=RewardConfig)
    contexts_config: SimConfig | None = struct.field(pytree_node=False, default=None)

    @property
    def num_scenarios(self) -> int:
        return int(self.scenarios.ego_index.shape[0])

    def with_contexts(self) -> EnvParams:
        """These params with ``contexts`` computed for ``config`` (one jitted, vmapped pass)."""
        return self.replace(contexts=_CONTEXTS(self.config, self.scenarios), contexts_config=self.config)


def _context_one(config: SimConfig, scenario: Scenario):
    state, _ = Simulator(config).reset(jax.random.PRNGKey(0), scenario)
    return state.ctx


_CONTEXTS = jax.jit(jax.vmap(_context_one, in_axes=(None, 0)), static_argnums=0)


@struct.dataclass
class EnvState:
    """One environment's state.

    Attributes:
      sim: ``sim.SimState`` of the running episode.
      index: () int32 the episode's row in ``params.scenarios``.
      step: () int32 steps taken in this episode.
      episode: () int32 episodes finished by this environment (AutoResetWrapper).
      total_steps: () int32 steps taken over all episodes.
      episode_return: () float32 sum of rewards of this episode so far.
    """

    sim: SimState
    index: jnp.ndarray
    step: jnp.ndarray
    episode: jnp.ndarray
    total_steps: jnp.ndarray
    episode_return: jnp.ndarray


def make_params(suite, split: str | None = "train", *, config: SimConfig | None = None,
                reward=None, limit: int | None = None, maps: dict | None = None) -> EnvParams:
    """``EnvParams`` of a suite split.

    Args:
      suite: a suite name (``"twin15"``) or folder, a ``scenario.Suite``, or a
        ``scenario.PackedBatch`` (then ``split`` is ignored).
      split: the split to pack; None = every scenario.
      config: ``SimConfig`` (default ``SimConfig()``).
      reward: ``RewardConfig`` (default) or a callable like it.
      limit: keep only the first ``limit`` scenarios.
      maps: {map_id: MapRecord} for the BEV when ``suite`` is a PackedBatch.
    """
    config = config or SimConfig()
    if isinstance(suite, PackedBatch):
        packed = suite
    else:
        suite = load_suite(suite)
        packed = suite.pack(split)
        if maps is None and config.sensors.needs_raster:
            maps = suite.maps
    if limit is not None:
        packed = packed.select(range(min(limit, len(packed))))
    if config.sensors.needs_raster and maps is None:
        raise ValueError("make_params: the BEV needs the suite's maps: pass maps= with a PackedBatch")
    assets = sensors.build_assets(packed, config.sensors, maps)
    if assets is not None:
        assets = jax.device_put(assets)
    scenarios = jax.device_put(packed.scenario)
    params = EnvParams(scenarios=scenarios, assets=assets, config=config,
                       reward=RewardConfig() if reward is None else reward)
    return params.with_contexts()


def as_action(action):
    """``Controls`` / ``Waypoints`` as they are; an array of shape (3,) as
    Controls [throttle, brake, steer]; shape (K, 2) as Waypoints."""
    if isinstance(action, Controls | Waypoints):
        return action
    a = jnp.asarray(action, jnp.float32)
    if a.ndim == 1 and a.shape[0] == 3:
        return Controls(throttle=a[0], brake=a[1], steer=a[2])
    if a.ndim == 2 and a.shape[1] == 2:
        return Waypoints(xy=a)
    raise ValueError(f"action: expected Controls, Waypoints, an array (3,) or (K, 2); got shape {a.shape}")


def _row(tree, index):
    return jax.tree_util.tree_map(lambda a: a[index], tree)


def _episode_info(res: ep.EpisodeResult, state: EnvState, done):
    """The finished episode's scores; NaN / -1 / False where ``done`` is False."""
    nan = jnp.float32(jnp.nan)
    f = lambda x: jnp.where(done, x.astype(jnp.float32), nan)
    return {
        "route_completion": f(res.route_completion),
        "driving_score": f(res.driving_score),
        "infraction_score": f(res.infraction_score),
        "success": done & res.success,
        "status": jnp.where(done, res.status, -1).astype(jnp.int32),
        "return": f(state.episode_return),
        "length": jnp.where(done, state.step, -1).astype(jnp.int32),
        "scenario_index": jnp.where(done, state.index, -1).astype(jnp.int32),
    }


# --------------------------------------------------------------------------
# The environment
# --------------------------------------------------------------------------


class DriveEnv:
    """The functional environment: no state of its own; every method is pure
    (jit / vmap them; vmap with ``in_axes=(0, 0, 0, None)`` to share params)."""

    def default_params(self, suite="tiny", split: str | None = "train", **kwargs) -> EnvParams:
        return make_params(suite, split, **kwargs)

    def scenario(self, state: EnvState, params: EnvParams) -> Scenario:
        """The running episode's scenario (one row of ``params.scenarios``)."""
        return _row(params.scenarios, state.index)

    def _assets(self, params: EnvParams, index):
        a = params.assets
        return None if a is None else a.replace(map_index=a.map_index[index])

    def reset(self, key, params: EnvParams, index=None) -> tuple[Observation, EnvState]:
        """A new episode on row ``index`` (None: drawn uniformly from ``key``)."""
        k_index, k_sim = jax.random.split(key)
        if index is None:
            index = jax.random.randint(k_index, (), 0, params.num_scenarios)
        index = jnp.asarray(index, jnp.int32)
        sim = Simulator(params.config)
        scenario, assets = _row(params.scenarios, index), self._assets(params, index)
        sim_state, obs = sim.reset(k_sim, scenario, assets)
        if params.contexts is not None and params.contexts_config == params.config:
            # The cached constants; under jit the reset's own ctx and
            # observation are then dead code and never computed.
            sim_state = sim_state.replace(ctx=_row(params.contexts, index))
            obs = sim.observe(scenario, sim_state, assets)
        zero = jnp.zeros((), jnp.int32)
        state = EnvState(sim=sim_state, index=index, step=zero, episode=zero, total_steps=zero,
                         episode_return=jnp.zeros((), jnp.float32))
        return obs, state

    def observe(self, state: EnvState, params: EnvParams) -> Observation:
        """The observation of ``state`` (what reset / step returned for it)."""
        sim = Simulator(params.config)
        return sim.observe(self.scenario(state, params), state.sim, self._assets(params, state.index))

    def step(self, key, state: EnvState, action, params: EnvParams):
        """One simulation step. ``key`` is unused here (the simulator's own
        noise key rides in the state); AutoResetWrapper draws the next
        scenario from it. Returns (obs, state, reward, done, info)."""
        del key
        sim = Simulator(params.config)
        scenario = self.scenario(state, params)
        active = ~state.sim.episode.done
        new_sim, obs, log = sim.step(scenario, state.sim, as_action(action), self._assets(params, state.index))
        reward = jnp.where(active, params.reward(scenario, state.sim, new_sim, log, params.config), 0.0)
        reward = reward.astype(jnp.float32)
        done = new_sim.episode.done
        truncated = done & new_sim.episode.truncated
        terminated = done & ~truncated
        inc = active.astype(jnp.int32)
        new = state.replace(sim=new_sim, step=state.step + inc, total_steps=state.total_steps + inc,
                            episode_return=state.episode_return + reward)
        result = ep.finalize(new_sim.episode, scenario.route, params.config.score)
        e, facts = log.events, log.facts
        cls = e.collision_class
        info = {
            # facts of this step (False / 0 for a step of a finished episode)
            "collision": e.collision,
            "collision_pedestrian": e.collision & (cls == CollisionClass.PEDESTRIAN),
            "collision_vehicle": e.collision & (cls == CollisionClass.VEHICLE),
            "collision_layout": e.collision & (cls == CollisionClass.LAYOUT),
            "red_light": e.red_light,
            "outside_lanes": facts.off_lane & active,
            "lane_invasion": facts.lane_invasion & active,
            "route_deviation": e.route_deviation,
            "blocked": e.blocked,
            "route_timeout": e.route_timeout,
            "completed": e.completed,
            "invalid_action": e.invalid_action & active,
            "route_completion": log.route_completion.astype(jnp.float32),
            "progress_m": (ep.progress_arc(new_sim.episode, scenario.route)
                           - ep.progress_arc(state.sim.episode, scenario.route)).astype(jnp.float32),
            "speed": log.speed.astype(jnp.float32),
            "terminated": terminated,
            "truncated": truncated,
            "discount": 1.0 - terminated.astype(jnp.float32),
            # the finished episode's leaderboard scores (NaN / -1 until done)
            "scores": _episode_info(result, new, done & active),
        }
        return obs, new, reward, done, info


def _where_done(done, new, old):
    """``new`` where ``done`` else ``old``, leaf by leaf; ``done`` is () for one
    environment or (B,) for a batch (broadcast over each leaf's trailing axes)."""
    return jax.tree_util.tree_map(
        lambda a, b: jnp.where(done.reshape(done.shape + (1,) * (a.ndim - done.ndim)), a, b), new, old)


def _next_episode(fresh: EnvState, finished: EnvState) -> EnvState:
    """A fresh episode's state carrying the finished one's counters (episodes, total steps)."""
    return fresh.replace(episode=finished.episode + 1, total_steps=finished.total_steps)


class AutoResetWrapper:
    """Starts the next episode when one ends, inside the same ``step``.

    On ``done`` the returned observation and state are those of a fresh
    episode on a scenario drawn (uniformly) from ``key``; the finished
    episode's last observation is ``info["final_obs"]``. ``reward``, ``done``
    and the rest of ``info`` are the finished step's. Both branches are
    computed and selected (``jnp.where``), so it jits and vmaps; the
    ``EnvState`` counters ``episode`` / ``total_steps`` carry over.
    """

    def __init__(self, env: DriveEnv | None = None):
        self.env = env or DriveEnv()

    def __getattr__(self, name):
        return getattr(self.env, name)

    def reset(self, key, params: EnvParams, index=None):
        return self.env.reset(key, params, index)

    def step(self, key, state: EnvState, action, params: EnvParams):
        k_step, k_reset = jax.random.split(key)
        obs_st, state_st, reward, done, info = self.env.step(k_step, state, action, params)
        obs_re, state_re = self.env.reset(k_reset, params)
        obs = _where_done(done, obs_re, obs_st)
        state = _where_done(done, _next_episode(state_re, state_st), state_st)
        info = {**info, "final_obs": obs_st}
        return obs, state, reward, done, info


class VmapAutoResetWrapper:
    """A batch of auto-resetting environments that resets only those that ended.

    ``step(keys, state, action, params)`` returns exactly what
    ``jax.vmap(AutoResetWrapper(env).step, in_axes=(0, 0, 0, None))`` returns
    (same keys, same draws, same scenarios and episode ends; floats equal up
    to the last bit, which XLA may round differently when it vectorises a
    reset of a few rows rather than of B), but without computing a reset for
    every environment in every step. The vmapped ``AutoResetWrapper`` must
    compute a fresh episode (the scenario's gathered rows, its cached
    constants, its first observation) for all B environments and select,
    which costs about as much as the step itself; here the environments that
    ended (found with ``jnp.nonzero``, at most ``max_resets`` of them) are
    reset and scattered back, and a step in which more than ``max_resets``
    ended takes the vmapped path (``lax.cond``), so ``max_resets`` changes
    the speed, never the result.

    Shapes: ``keys`` (B, 2) (one PRNG key per environment, as the vmapped
    wrapper takes them), ``state`` / ``action`` / outputs with a leading B.
    ``reset(keys, params)`` is the vmapped ``env.reset``.

    Args:
      env: the ``DriveEnv`` (default ``DriveEnv()``).
      max_resets: environments reset by gathering in one step (default 8:
        with episodes of ~100-200 steps a batch of 256 ends ~1-3 per step);
        0 = always the vmapped path.
    """

    def __init__(self, env: DriveEnv | None = None, max_resets: int = 8):
        if max_resets < 0:
            raise ValueError(f"VmapAutoResetWrapper: max_resets must be >= 0, got {max_resets}")
        self.env = env or DriveEnv()
        self.max_resets = int(max_resets)

    def reset(self, keys, params: EnvParams, index=None):
        """Batched ``env.reset``: keys (B, 2) -> (obs, state) with a leading B."""
        return jax.vmap(self.env.reset, in_axes=(0, None, None if index is None else 0))(keys, params, index)

    def step(self, keys, state: EnvState, action, params: EnvParams):
        split = jax.vmap(jax.random.split)(keys)
        k_step, k_reset = split[:, 0], split[:, 1]
        obs_st, state_st, reward, done, info = jax.vmap(self.env.step, in_axes=(0, 0, 0, None))(
            k_step, state, action, params)
        n = done.shape[0]

        def every():
            obs_re, state_re = self.reset(k_reset, params)
            return _where_done(done, obs_re, obs_st), _where_done(done, _next_episode(state_re, state_st), state_st)

        def ended_only():
            idx = jnp.nonzero(done, size=self.max_resets, fill_value=n)[0]   # n = no slot
            safe = jnp.minimum(idx, n - 1)
            obs_re, state_re = self.reset(k_reset[safe], params)
            state_re = _next_episode(state_re, _row(state_st, safe))
            put = lambda a, r: a.at[idx].set(r, mode="drop")
            return (jax.tree_util.tree_map(put, obs_st, obs_re),
                    jax.tree_util.tree_map(put, state_st, state_re))

        if self.max_resets == 0 or self.max_resets >= n:
            obs, state = every()
        else:
            obs, state = jax.lax.cond(jnp.sum(done) > self.max_resets, every, ended_only)
        info = {**info, "final_obs": obs_st}
        return obs, state, reward, done, info


__all__ = ["AutoResetWrapper", "DriveEnv", "EnvParams", "EnvState", "RewardConfig", "VmapAutoResetWrapper",
           "as_action", "make_params"]
