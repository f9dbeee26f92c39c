"""Gymnasium environments over a suite split (numpy in, numpy out).

* ``DriveE2EVectorEnv(suite, split, num_envs)``: a ``gymnasium.vector.VectorEnv``
  stepping ``num_envs`` episodes as one jitted, vmapped program
  (``envs.functional``); autoreset mode SAME_STEP.
* ``DriveE2EEnv(suite, split)``: one environment (``num_envs`` = 1 underneath)
  for code that wants a ``gymnasium.Env``; ``check_env`` passes on it.

Both are registered with Gymnasium as ``drivee2e_jax/DriveE2E-v0``::

    env = gymnasium.make("drivee2e_jax/DriveE2E-v0", suite="twin15", split="train")
    envs = gymnasium.make_vec("drivee2e_jax/DriveE2E-v0", num_envs=8,
                              vectorization_mode="vector_entry_point", suite="twin15")

Spaces (docs/envs.md): the observation is a ``spaces.Dict`` of ``Box`` es, one
per vector field of ``types.Observation`` (ego, gps, compass, route,
route_valid, command, agents, agents_category, agents_valid, lanes,
lanes_valid, signal_state, signal_distance, speed_limit, plus bev / lidar when
``SimConfig.sensors`` turns them on; never ``privileged``). The action is
``Box(3,)`` [throttle 0..1, brake 0..1, steer -1..1] (``action="controls"``,
default) or ``Box(K, 2)`` ego-frame waypoints, metres, ``waypoint_dt`` apart
(``action="waypoints"``). Out-of-range actions are clipped by the simulator
and counted as ``invalid_action``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from drivee2e_jax import compile_cache
from drivee2e_jax.envs.functional import DriveEnv, EnvParams, EnvState, RewardConfig, make_params
from drivee2e_jax.sim import SimConfig
from drivee2e_jax.types import Category, Command, SignalState

ENV_ID = "drivee2e_jax/DriveE2E-v0"

#: Bounds of the float observation fields (finite, so check_env is quiet). Values
#: outside are clipped (they do not occur on real scenarios).
FLOAT_BOUND = 1.0e4
GPS_BOUND = 1.0e7
#: Bounds of the waypoint action, metres (ego frame).
WAYPOINT_BOUND = 100.0

#: (low, high) of the integer observation fields.
_INT_BOUNDS = {
    "command": (int(Command.VOID), max(int(c) for c in Command)),
    "agents_category": (-1, max(int(c) for c in Category)),
    "signal_state": (0, max(int(s) for s in SignalState)),
    "bev": (0, 2**31 - 1),
}

_ENV = DriveEnv()


# --------------------------------------------------------------------------
# The jitted program shared by every instance (compiled once per shape)
# --------------------------------------------------------------------------


def vector_observation(obs) -> dict[str, Any]:
    """The ``types.Observation`` fields the Gymnasium spaces carry: every
    array field but ``privileged`` (sensors that are off, None, are left out;
    the ``sensors`` dict's entries appear under their own names)."""
    out = {}
    for f in dataclasses.fields(obs):
        v = getattr(obs, f.name)
        if f.name == "privileged" or v is None:
            continue
        if isinstance(v, dict):
            out.update({k: x for k, x in v.items() if x is not None})
        else:
            out[f.name] = v
    return out


def _advance_one(key, state: EnvState, action, params: EnvParams, reset, index):
    """Step one environment, then start a new episode where it ended or where
    ``reset`` asks (row ``index``; -1 = drawn uniformly)."""
    k_step, k_reset, k_index = jax.random.split(key, 3)
    obs_st, st, reward, done, info = _ENV.step(k_step, state, action, params)
    drawn = jax.random.randint(k_index, (), 0, params.num_scenarios)
    obs_re, s_re = _ENV.reset(k_reset, params, jnp.where(index >= 0, index, drawn))
    s_re = s_re.replace(episode=jnp.where(reset, 0, st.episode + 1), total_steps=jnp.where(reset, 0, st.total_steps))
    go = reset | done
    pick = lambda a, b: jnp.where(go, a, b)
    state = jax.tree_util.tree_map(pick, s_re, st)
    obs = jax.tree_util.tree_map(pick, vector_observation(obs_re), vector_observation(obs_st))
    return obs, state, reward, done & ~reset, info, vector_observation(obs_st)


_ADVANCE = jax.jit(jax.vmap(_advance_one, in_axes=(0, 0, 0, None, 0, 0)))


def _shape_state(params: EnvParams):
    """A zero ``EnvState`` with the right structure (the input of the first reset)."""
    shapes = jax.eval_shape(_ENV.reset, jax.random.PRNGKey(0), params, 0)
    return jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), shapes[1])


def _box(name: str, shape, dtype) -> spaces.Box:
    dtype = np.dtype(dtype)
    if dtype == np.bool_:
        return spaces.Box(low=0, high=1, shape=shape, dtype=np.bool_)
    if np.issubdtype(dtype, np.integer):
        lo, hi = _INT_BOUNDS.get(name, (np.iinfo(dtype).min, np.iinfo(dtype).max))
        return spaces.Box(low=lo, high=hi, shape=shape, dtype=dtype)
    bound = GPS_BOUND if name == "gps" else FLOAT_BOUND
    return spaces.Box(low=-bound, high=bound, shape=shape, dtype=dtype)


def observation_space(params: EnvParams) -> spaces.Dict:
    """The single-environment observation space of ``params`` (no compilation)."""
    obs, _ = jax.eval_shape(_ENV.reset, jax.random.PRNGKey(0), params, 0)
    return spaces.Dict({k: _box(k, tuple(v.shape), v.dtype) for k, v in vector_observation(obs).items()})


def action_space(action: str = "controls", num_waypoints: int = 4) -> spaces.Box:
    """Box(3,) [throttle, brake, steer] or Box(num_waypoints, 2) waypoints."""
    if action == "controls":
        return spaces.Box(low=np.array([0.0, 0.0, -1.0], np.float32), high=np.array([1.0, 1.0, 1.0], np.float32),
                          dtype=np.float32)
    if action == "waypoints":
        return spaces.Box(low=-WAYPOINT_BOUND, high=WAYPOINT_BOUND, shape=(num_waypoints, 2), dtype=np.float32)
    raise ValueError(f"action must be 'controls' or 'waypoints', got {action!r}")


def _to_numpy_obs(obs: dict, space: spaces.Dict) -> dict[str, np.ndarray]:
    out = {}
    for k, sub in space.spaces.items():
        a = np.array(obs[k], dtype=sub.dtype)  # a fresh copy
        if sub.dtype != np.bool_:
            a = np.clip(a, sub.low, sub.high).astype(sub.dtype)
        out[k] = a
    return out


def _flat_info(info: dict) -> dict[str, np.ndarray]:
    """jax info -> numpy (the nested ``episode`` dict kept nested)."""
    return {k: (_flat_info(v) if isinstance(v, dict) else np.array(v)) for k, v in info.items()}


def _masked(info: dict, mask: np.ndarray) -> dict:
    """Gymnasium vector info: ``key`` (zero where not set) + ``_key`` mask."""
    out = {}
    for k, v in info.items():
        if isinstance(v, dict):
            out[k] = _masked(v, mask)
        else:
            m = mask.reshape(mask.shape + (1,) * (v.ndim - 1))
            out[k] = np.where(m, v, np.zeros_like(v))
        out[f"_{k}"] = mask.copy()
    return out


# --------------------------------------------------------------------------
# Vector environment
# --------------------------------------------------------------------------


class DriveE2EVectorEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` closed-loop episodes on a suite split, stepped together.

    Args:
      suite: suite name or folder, ``scenario.Suite`` or ``PackedBatch``.
      split: the split the episodes are drawn from (uniformly; None = all).
      num_envs: environments stepped in one call.
      config: ``SimConfig``; reward: ``RewardConfig`` (see ``envs.functional``).
      action: "controls" (default) or "waypoints".
      num_waypoints: K of the waypoint action.
      limit: only the first ``limit`` scenarios of the split.
      params: a prebuilt ``functional.EnvParams`` (then suite/split/config/reward/limit are ignored).

    Autoreset: SAME_STEP. When an episode ends, ``step`` returns the first
    observation of the next episode; ``info["final_obs"]`` (object array,
    mask ``_final_obs``) holds the last observation of the finished one and
    ``info["final_info"]`` its step info. ``info["scores"]`` (mask
    ``_scores``) has the finished episode's route_completion, driving_score,
    infraction_score (%), success, status (``metrics.driving_score.Status``),
    return, length, scenario_index. Every other info key is set for every
    environment each step (its ``_key`` mask all True).

    ``reset(seed=..., options={"index": i or [i, ...]})`` starts episodes on
    the given scenario rows (-1 = drawn).
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, suite="twin15", split: str | None = "train", num_envs: int = 1, *,
                 config: SimConfig | None = None, reward: RewardConfig | None = None, action: str = "controls",
                 num_waypoints: int = 4, limit: int | None = None, params: EnvParams | None = None):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        # JAX's persistent compilation cache, as every drivee2e command uses it:
        # a new process takes the env's compiled step from disk instead of
        # compiling it again (DRIVEE2E_JAX_CACHE=off turns it off).
        compile_cache.enable()
        self.params = params if params is not None else make_params(suite, split, config=config, reward=reward,
                                                                     limit=limit)
        self.num_envs = int(num_envs)
        self.action_type = action
        self.render_mode = None
        self.single_observation_space = observation_space(self.params)
        self.single_action_space = action_space(action, num_waypoints)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._state: EnvState | None = None
        self._key = None

    def _keys(self):
        self._key, sub = jax.random.split(self._key)
        return jax.random.split(sub, self.num_envs)

    def _run(self, actions, reset, index):
        return _ADVANCE(self._keys(), self._state, jnp.asarray(actions, jnp.float32), self.params,
                        jnp.asarray(reset), jnp.asarray(index, jnp.int32))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._key = jax.random.PRNGKey(int(self.np_random.integers(2**31 - 1)))
        index = np.full(self.num_envs, -1, np.int64)
        if options and options.get("index") is not None:
            index[:] = np.asarray(options["index"], np.int64)
            if np.any(index >= self.params.num_scenarios):
                raise ValueError(f"options['index']: rows {index.tolist()} of a {self.params.num_scenarios}-scenario split")
        if self._state is None:
            self._state = _shape_state(self.params)
            self._state = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (self.num_envs, *a.shape)), self._state)
        zeros = np.zeros(self.action_space.shape, np.float32)
        obs, self._state, _, _, _, _ = self._run(zeros, np.ones(self.num_envs, bool), index)
        index = np.asarray(self._state.index)
        info = {"scenario_index": index.astype(np.int64), "_scenario_index": np.ones(self.num_envs, bool)}
        return _to_numpy_obs(obs, self.single_observation_space), info

    def step(self, actions):
        if self._state is None:
            raise RuntimeError("DriveE2EVectorEnv.step before reset")
        actions = np.asarray(actions, np.float32).reshape(self.action_space.shape)
        prev_index = np.asarray(self._state.index)
        obs, self._state, reward, done, info, final = self._run(actions, np.zeros(self.num_envs, bool),
                                                                np.full(self.num_envs, -1))
        obs = _to_numpy_obs(obs, self.single_observation_space)
        done = np.array(done)
        raw = _flat_info(info)
        terminated = raw["terminated"] & done
        truncated = raw["truncated"] & done
        episode = raw.pop("scores")
        all_envs = np.ones(self.num_envs, bool)
        out = _masked(raw, all_envs)
        out["scenario_index"] = prev_index.astype(np.int64)
        out["_scenario_index"] = all_envs.copy()
        if done.any():
            out.update(_masked({"scores": episode}, done))
            final_np = _to_numpy_obs(final, self.single_observation_space)
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done):
                final_obs[i] = {k: np.array(v[i]) for k, v in final_np.items()}
            out["final_obs"], out["_final_obs"] = final_obs, done.copy()
            step_info = {**raw, "scores": episode, "scenario_index": prev_index.astype(np.int64)}
            out["final_info"], out["_final_info"] = _masked(step_info, done), done.copy()
        return obs, np.array(reward, np.float64), terminated, truncated, out

    def close_extras(self, **kwargs):
        self._state = None


# --------------------------------------------------------------------------
# Single environment
# --------------------------------------------------------------------------


class DriveE2EEnv(gymnasium.Env):
    """One closed-loop episode at a time (a ``DriveE2EVectorEnv`` with one
    environment underneath). Arguments as ``DriveE2EVectorEnv`` but
    ``num_envs``. After ``terminated`` / ``truncated`` call ``reset``.

    ``info`` of ``step``: the step facts (Python scalars) and, on the last
    step, ``info["scores"]`` with the episode's RC / DS / status.
    """

    metadata = {"render_modes": []}

    def __init__(self, suite="twin15", split: str | None = "train", *, config: SimConfig | None = None,
                 reward: RewardConfig | None = None, action: str = "controls", num_waypoints: int = 4,
                 limit: int | None = None, params: EnvParams | None = None):
        self.vec = DriveE2EVectorEnv(suite, split, 1, config=config, reward=reward, action=action,
                                     num_waypoints=num_waypoints, limit=limit, params=params)
        self.observation_space = self.vec.single_observation_space
        self.action_space = self.vec.single_action_space
        self.render_mode = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.vec._np_random = self.np_random  # one generator: seeding this env seeds the batch
        obs, info = self.vec.reset(options=options)
        return {k: np.array(v[0]) for k, v in obs.items()}, {"scenario_index": int(info["scenario_index"][0])}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.vec.step(np.asarray(action, np.float32)[None])
        done = bool(terminated[0] or truncated[0])
        if done:
            obs = info["final_obs"][0]
        else:
            obs = {k: np.array(v[0]) for k, v in obs.items()}
        out = {k: v[0].item() for k, v in info.items()
               if not k.startswith("_") and k not in ("final_obs", "final_info", "scores")}
        if done:
            out["scores"] = {k: v[0].item() for k, v in info["scores"].items() if not k.startswith("_")}
        return obs, float(reward[0]), bool(terminated[0]), bool(truncated[0]), out

    def close(self):
        self.vec.close()


if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="drivee2e_jax.envs.gym:DriveE2EEnv",
                       vector_entry_point="drivee2e_jax.envs.gym:DriveE2EVectorEnv")


__all__ = ["ENV_ID", "DriveE2EEnv", "DriveE2EVectorEnv", "action_space", "observation_space", "vector_observation"]
