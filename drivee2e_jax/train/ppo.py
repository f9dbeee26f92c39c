"""PPO in pure JAX on the batched functional environment (``envs.functional``).

Proximal Policy Optimization (Schulman et al. 2017) with the details that make
it work in practice (Huang et al. 2022, "The 37 implementation details"):
clipped surrogate objective, GAE(gamma, lambda) advantages normalised per
minibatch, a separate value network, an entropy bonus, several epochs of
shuffled minibatches per rollout, global-norm gradient clipping, Adam (Optax).

One ``update`` = collect ``rollout_steps`` steps of ``num_envs`` environments
(``VmapAutoResetWrapper``: an episode that ends starts again on a random
scenario of the split; only the environments that ended are reset) with
``lax.scan``, then the PPO epochs over those ``num_envs * rollout_steps`` samples: ONE jitted function, no Python per step.

Policy (actor). A registered imitation model (``models.base.Model``, "traj"
mode: the vector transformer by default) gives the MEAN of a diagonal Gaussian
over its K ego-frame waypoints (K x 2, m); a learned state-independent
log-std (K, 2) is the exploration. **Why waypoints and not controls:** the
imitation baselines emit waypoints, so fine-tuning starts from exactly the
imitation policy with no new head, and the simulator's PID + pure pursuit
turns them into controls as it does at benchmark time: the deterministic
policy scored by ``drivee2e bench`` is the Gaussian's mean, the very network
trained here, loaded like any ``drivee2e train`` checkpoint.

Value (critic). An MLP over a flat vector of the observation (``features``:
ego state, route ahead, nearest agents, next signal, speed limit) plus the
fraction of the episode's time left and the route metres left (an asymmetric
critic: the policy never reads those two). The time left makes the time limit
part of the state (Pardo et al. 2018), so every ``done`` -- route ended or log
ended -- is terminal for the bootstrap.

Reward: ``envs.functional.RewardConfig`` (route progress in metres minus the
Leaderboard 2.0 penalties, scaled by route length; optional comfort term),
docs/training.md.

Run folder (``train``; loadable like a ``drivee2e train`` run:
``--policy vector_transformer:checkpoint=RUN``, ``drivee2e trend RUN``)::

    RUN/config.json           model, model_config, init, the PPOConfig
    RUN/log.jsonl             one line per logged update: env_steps, returns, episode RC/DS, losses, env-steps/s
    RUN/checkpoints/<update>/ params (the actor = the model's parameters), critic, log_std,
                              opt_state, step and the whole runner state (environments, RNG):
                              ``--resume`` continues exactly as an uninterrupted run would
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from drivee2e_jax.envs.functional import (
    DriveEnv,
    EnvParams,
    EnvState,
    RewardConfig,
    VmapAutoResetWrapper,
    make_params,
)
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import atomic_write_json
from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.models import base
from drivee2e_jax.models import checkpoint as ckpt
from drivee2e_jax.models.registry import get_model
from drivee2e_jax.models.vector_mlp import scene_features
from drivee2e_jax.progress import ProgressFn
from drivee2e_jax.rollout import episode_lengths
from drivee2e_jax.sim import Simulator
from drivee2e_jax.train.finetune import load_init
from drivee2e_jax.train.loop import check_run_dir, trim_log
from drivee2e_jax.types import Observation, Waypoints

_LOG_2PI = math.log(2.0 * math.pi)


# --------------------------------------------------------------------------
# Config
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """A PPO run (``drivee2e rl`` flags in brackets).

    Attributes:
      suite, split: what the environments draw their episodes from [--suite, --split].
      model: registry name of the actor (``models.MODELS``; vector-observation
        models: vector_transformer, ad_mlp) [--model]; ignored with ``init``.
      model_config: the model's ``make_model`` arguments (from scratch).
      init: an imitation run / checkpoint to start the actor from (its model
        and config are used) [--init]; None = random init ("from scratch").
      num_envs: parallel environments B [--envs].
      rollout_steps: steps T collected per environment per update [--rollout-steps].
      total_env_steps: stop after this many environment steps (rounded up to
        whole updates of B x T) [--env-steps].
      update_epochs, minibatches: passes over each rollout, and minibatches per pass.
      lr: Adam step size of the actor and its log-std [--lr].
      critic_lr: Adam step size of the critic; None = ``lr`` [--critic-lr].
      max_grad_norm: global-norm clip, of the actor's and of the critic's gradient apart.
      gamma, gae_lambda: discount per 0.1 s step and GAE lambda.
      clip_eps: PPO ratio clip. vf_coef: value-loss weight. ent_coef: entropy bonus.
      target_kl: an update's remaining minibatches are skipped once a
        minibatch's approximate KL to the rollout policy exceeds 1.5 x this
        (Stable-Baselines3's early stop); None = never [--target-kl].
      init_log_std: initial log-std of every waypoint coordinate, log m
        (-1.0: 0.37 m) [--init-log-std].
      critic_hidden: the value MLP's hidden widths.
      reward_scale: rewards are multiplied by this before GAE and the value
        loss (returns of ~100 m become ~10: the critic's output layer starts
        at 0); the optimal policy is unchanged, logged returns are unscaled.
      critic_warmup_updates: updates at the start that train only the critic
        (the actor's gradient is zeroed): a fresh critic first learns the
        imitation policy's values before they steer it [--critic-warmup].
      reward: ``RewardConfig`` field overrides, e.g. {"comfort": 0.1} [--reward k=v,...].
      limit: use only the first ``limit`` scenarios of the split (tests).
      seed: every random draw of the run [--seed].
      log_every, ckpt_every: updates between log lines / checkpoints.
    """

    suite: str = "twin15"
    split: str = "train"
    model: str = "vector_transformer"
    model_config: dict = dataclasses.field(default_factory=dict)
    init: str | None = None
    num_envs: int = 64
    rollout_steps: int = 32
    total_env_steps: int = 1_000_000
    update_epochs: int = 4
    minibatches: int = 4
    lr: float = 3e-4
    critic_lr: float | None = None
    max_grad_norm: float = 0.5
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    vf_coef: float = 0.5
    ent_coef: float = 0.0
    target_kl: float | None = 0.05
    init_log_std: float = -1.0
    critic_hidden: tuple[int, ...] = (256, 256)
    reward_scale: float = 0.1
    critic_warmup_updates: int = 0
    reward: dict = dataclasses.field(default_factory=dict)
    limit: int | None = None
    seed: int = 0
    log_every: int = 1
    ckpt_every: int = 50

    def __post_init__(self):
        for name in ("num_envs", "rollout_steps", "total_env_steps", "update_epochs", "minibatches",
                     "log_every", "ckpt_every"):
            if int(getattr(self, name)) < 1:
                raise DriveE2EError(f"ppo: {name} must be >= 1, got {getattr(self, name)}")
        if (self.num_envs * self.rollout_steps) % self.minibatches:
            raise DriveE2EError(f"ppo: minibatches ({self.minibatches}) must divide envs x rollout steps "
                                f"({self.num_envs} x {self.rollout_steps})")
        if not 0.0 <= self.gamma <= 1.0 or not 0.0 <= self.gae_lambda <= 1.0:
            raise DriveE2EError(f"ppo: gamma and gae_lambda must lie in [0, 1], got {self.gamma}, {self.gae_lambda}")
        fields = {f.name for f in dataclasses.fields(RewardConfig)}
        bad = sorted(set(self.reward) - fields)
        if bad:
            raise DriveE2EError(f"ppo: unknown reward field(s) {', '.join(bad)} (expected some of {', '.join(sorted(fields))})")

    @property
    def batch_size(self) -> int:
        return self.num_envs * self.rollout_steps

    @property
    def num_updates(self) -> int:
        return -(-self.total_env_steps // self.batch_size)

    def reward_config(self) -> RewardConfig:
        return RewardConfig(**self.reward)

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["critic_hidden"] = list(self.critic_hidden)
        return d


# --------------------------------------------------------------------------
# Critic
# --------------------------------------------------------------------------

def features(obs: Observation, extra: jnp.ndarray) -> jnp.ndarray:
    """(F,) float32 critic input of ONE observation.

    ``models.vector_mlp.scene_features(obs)`` (ego state, the route points
    ahead, the nearest agents, command and next-signal one-hots, the distance
    to that stop line, the speed limit) followed by ``extra`` = (2,)
    [fraction of the episode's steps still to go (1 at reset, 0 at the last
    step), route metres still to drive / 100] (``PPO._extra``): what the
    return depends on most and the observation does not hold. The critic
    only trains the actor; the policy never reads ``extra``.
    """
    return jnp.concatenate([scene_features(obs), jnp.asarray(extra, jnp.float32).reshape(-1)]).astype(jnp.float32)


class Critic(nn.Module):
    """The value MLP: ``features`` (F,) -> () value (return units: metres)."""

    hidden: tuple[int, ...] = (256, 256)

    @nn.compact
    def __call__(self, x):
        for w in self.hidden:
            x = nn.tanh(nn.Dense(w)(x))
        return nn.Dense(1, kernel_init=nn.initializers.zeros)(x)[..., 0]


# --------------------------------------------------------------------------
# Gaussian over waypoints
# --------------------------------------------------------------------------


def log_prob(action, mean, log_std):
    """() log density of ``action`` (K, 2) under N(mean, exp(log_std)^2) (diagonal)."""
    z = (action - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z * z - log_std - 0.5 * _LOG_2PI)


def entropy(log_std):
    """() entropy of the diagonal Gaussian."""
    return jnp.sum(log_std + 0.5 * (1.0 + _LOG_2PI))


# --------------------------------------------------------------------------
# GAE
# --------------------------------------------------------------------------


def gae(rewards, values, dones, last_value, gamma: float, lam: float):
    """Generalised advantage estimates.

    Args:
      rewards, values, dones: (T, B) reward of step t, value of the state it
        was taken in, and whether the episode ended at step t.
      last_value: (B,) value of the state after the last step.
    Returns (advantages, returns), each (T, B).
    """

    def body(carry, x):
        adv_next, v_next = carry
        r, v, d = x
        nonterminal = 1.0 - d.astype(jnp.float32)
        delta = r + gamma * v_next * nonterminal - v
        adv = delta + gamma * lam * nonterminal * adv_next
        return (adv, v), adv

    _, adv = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), (rewards, values, dones), reverse=True)
    return adv, adv + values


# --------------------------------------------------------------------------
# The trainer
# --------------------------------------------------------------------------


@struct.dataclass
class Runner:
    """Everything that carries from one update to the next (a pytree)."""

    params: Any            # {"actor", "critic", "log_std"}
    opt_state: Any
    env_state: EnvState    # (B, ...)
    history: base.EgoHistory  # (B, ...) the actor's ego history
    obs: Observation       # (B, ...) the current observations
    key: jnp.ndarray
    update: jnp.ndarray    # () int32 updates done


class PPO:
    """The PPO learner for ``model`` on the environments of ``env_params``.

    ``init(key, actor_params=None)`` -> Runner; ``update(runner)`` -> (runner,
    metrics): one jitted collect + learn. ``policy_params(runner)`` are the
    model's parameters (the deterministic policy = the Gaussian's mean).
    """

    def __init__(self, model, env_params: EnvParams, cfg: PPOConfig):
        if getattr(model, "required_sensors", ()):
            raise DriveE2EError(f"ppo: model {model.name!r} needs sensors {list(model.required_sensors)}; "
                                "PPO trains vector-observation models (vector_transformer, vector_mlp, ad_mlp)")
        self.model, self.env_params, self.cfg = model, env_params, cfg
        self.env = VmapAutoResetWrapper(DriveEnv())
        self.critic = Critic(tuple(cfg.critic_hidden))
        # Actor (with its log-std) and critic each get their own clip and step
        # size: the value loss (in squared metres) would otherwise dominate a
        # shared global-norm clip, and fine-tuning wants a small actor step
        # with a critic that learns fast.
        group = lambda lr: optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), optax.adam(lr, eps=1e-5))
        critic_lr = cfg.lr if cfg.critic_lr is None else cfg.critic_lr
        self.opt = optax.multi_transform({"actor": group(cfg.lr), "critic": group(critic_lr)},
                                         {"actor": "actor", "critic": "critic", "log_std": "actor"})
        sim = Simulator(env_params.config)
        self._episode_steps = episode_lengths(sim, env_params.scenarios)
        self.update = jax.jit(self._update)
        # One compiled program: run op by op, the reset of the environments
        # and the model's init compiled ~1,000 small programs (~45 s on a CPU).
        self._init = jax.jit(self._init_runner)

    # -- pieces ------------------------------------------------------------

    def _extra(self, state: EnvState):
        """(2,) [time left as a fraction of the episode, route metres left / 100]."""
        total = self._episode_steps[state.index].astype(jnp.float32)
        time_left = jnp.clip(1.0 - state.step.astype(jnp.float32) / jnp.maximum(total, 1.0), 0.0, 1.0)
        route = jax.tree_util.tree_map(lambda a: a[state.index], self.env_params.scenarios.route)
        left = jnp.maximum(route.length - ep.progress_arc(state.sim.episode, route), 0.0) / 100.0
        return jnp.stack([time_left, left]).astype(jnp.float32)

    def _mean(self, actor, hobs):
        return self.model.apply(actor, hobs).waypoints.astype(jnp.float32)

    def _value(self, critic, obs, state):
        return self.critic.apply(critic, features(obs, self._extra(state)))

    def init(self, key, actor_params=None) -> Runner:
        """A fresh runner: environments reset, critic initialised, the actor
        ``actor_params`` (None: the model's random init)."""
        return self._init(key, actor_params)

    def _init_runner(self, key, actor_params) -> Runner:
        cfg = self.cfg
        k_env, k_actor, k_critic, key = jax.random.split(key, 4)
        obs, env_state = self.env.reset(jax.random.split(k_env, cfg.num_envs), self.env_params)
        history = jax.vmap(base.empty_history)(obs)
        obs0 = jax.tree_util.tree_map(lambda a: a[0], obs)
        if actor_params is None:
            actor_params = self.model.init(k_actor, base.with_history(obs0, base.push_history(base.empty_history(obs0), obs0)))
        state0 = jax.tree_util.tree_map(lambda a: a[0], env_state)
        critic = self.critic.init(k_critic, features(obs0, self._extra(state0)))
        log_std = jnp.full((self.model.num_waypoints, 2), cfg.init_log_std, jnp.float32)
        params = {"actor": actor_params, "critic": critic, "log_std": log_std}
        return Runner(params=params, opt_state=self.opt.init(params), env_state=env_state, history=history,
                      obs=obs, key=key, update=jnp.zeros((), jnp.int32))

    def _act_one(self, params, obs, history, state, key):
        hist = base.push_history(history, obs)
        hobs = base.with_history(obs, hist)
        mean = self._mean(params["actor"], hobs)
        action = mean + jnp.exp(params["log_std"]) * jax.random.normal(key, mean.shape)
        logp = log_prob(action, mean, params["log_std"])
        extra = self._extra(state)
        value = self.critic.apply(params["critic"], features(obs, extra))
        return hobs.replace(privileged=None), hist, action, logp, value, extra

    def _collect(self, runner: Runner):
        cfg, params = self.cfg, runner.params

        def step(carry, _):
            env_state, history, obs, key = carry
            key, k_act, k_env = jax.random.split(key, 3)
            hobs, hist, action, logp, value, extra = jax.vmap(self._act_one, in_axes=(None, 0, 0, 0, 0))(
                params, obs, history, env_state, jax.random.split(k_act, cfg.num_envs))
            obs2, env_state2, reward, done, info = self.env.step(
                jax.random.split(k_env, cfg.num_envs), env_state, Waypoints(xy=action), self.env_params)
            fresh = jax.vmap(base.empty_history)(obs2)
            hist2 = jax.tree_util.tree_map(
                lambda a, b: jnp.where(done.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), fresh, hist)
            sample = {"hobs": hobs, "extra": extra, "action": action, "logp": logp, "value": value,
                      "reward": reward, "done": done}
            scores = info["scores"]
            stats = {"done": done, "return": scores["return"], "driving_score": scores["driving_score"],
                     "route_completion": scores["route_completion"], "success": scores["success"],
                     "length": scores["length"], "collision": info["collision"], "red_light": info["red_light"],
                     "speed": info["speed"]}
            return (env_state2, hist2, obs2, key), (sample, stats)

        carry = (runner.env_state, runner.history, runner.obs, runner.key)
        (env_state, history, obs, key), (traj, stats) = jax.lax.scan(step, carry, None, cfg.rollout_steps)
        last_value = jax.vmap(self._value, in_axes=(None, 0, 0))(params["critic"], obs, env_state)
        runner = runner.replace(env_state=env_state, history=history, obs=obs, key=key)
        return runner, traj, stats, last_value

    def _loss(self, params, mb, actor_on):
        cfg = self.cfg
        actor = jax.tree_util.tree_map(
            lambda p: jnp.where(actor_on, p, jax.lax.stop_gradient(p)), params["actor"])
        mean = jax.vmap(self._mean, in_axes=(None, 0))(actor, mb["hobs"])
        log_std = jnp.where(actor_on, params["log_std"], jax.lax.stop_gradient(params["log_std"]))
        logp = jax.vmap(log_prob, in_axes=(0, 0, None))(mb["action"], mean, log_std)
        feats = jax.vmap(features)(mb["hobs"], mb["extra"])
        value = self.critic.apply(params["critic"], feats)
        adv = mb["adv"]
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        log_ratio = logp - mb["logp"]
        ratio = jnp.exp(log_ratio)
        pg = -jnp.mean(jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - cfg.clip_eps, 1.0 + cfg.clip_eps) * adv))
        v_loss = 0.5 * jnp.mean(jnp.square(value - mb["ret"]))
        ent = entropy(log_std)
        total = actor_on * (pg - cfg.ent_coef * ent) + cfg.vf_coef * v_loss
        aux = {"pg_loss": pg, "value_loss": v_loss, "entropy": ent,
               "approx_kl": jnp.mean((ratio - 1.0) - log_ratio),
               "clip_frac": jnp.mean((jnp.abs(ratio - 1.0) > cfg.clip_eps).astype(jnp.float32))}
        return total, aux

    def _learn(self, runner: Runner, traj, last_value):
        cfg = self.cfg
        rewards = traj["reward"] * cfg.reward_scale
        adv, ret = gae(rewards, traj["value"], traj["done"], last_value, cfg.gamma, cfg.gae_lambda)
        data = {"hobs": traj["hobs"], "extra": traj["extra"], "action": traj["action"],
                "logp": traj["logp"], "adv": adv, "ret": ret}
        n = cfg.batch_size
        data = jax.tree_util.tree_map(lambda a: a.reshape((n,) + a.shape[2:]), data)
        actor_on = (runner.update >= cfg.critic_warmup_updates).astype(jnp.float32)
        grad_fn = jax.value_and_grad(self._loss, has_aux=True)

        max_kl = jnp.inf if cfg.target_kl is None else 1.5 * cfg.target_kl

        def minibatch(carry, mb):
            params, opt_state, stopped = carry
            (_, aux), grads = grad_fn(params, mb, actor_on)
            stopped = stopped | (aux["approx_kl"] > max_kl)
            updates, new_opt = self.opt.update(grads, opt_state, params)
            keep = lambda new, old: jax.tree_util.tree_map(lambda a, b: jnp.where(stopped, b, a), new, old)
            params = keep(optax.apply_updates(params, updates), params)
            return (params, keep(new_opt, opt_state), stopped), {**aux, "applied": 1.0 - stopped}

        def epoch(carry, key):
            perm = jax.random.permutation(key, n)
            mbs = jax.tree_util.tree_map(
                lambda a: a[perm].reshape((cfg.minibatches, n // cfg.minibatches) + a.shape[1:]), data)
            return jax.lax.scan(minibatch, carry, mbs)

        key, k = jax.random.split(runner.key)
        (params, opt_state, _), aux = jax.lax.scan(epoch, (runner.params, runner.opt_state, jnp.zeros((), bool)),
                                                   jax.random.split(k, cfg.update_epochs))
        var = jnp.var(ret)
        explained = 1.0 - jnp.var(ret - traj["value"]) / jnp.maximum(var, 1e-8)
        metrics = {k: jnp.mean(v) for k, v in aux.items()}
        metrics.update(explained_variance=explained, advantage_mean=jnp.mean(adv),
                       std=jnp.mean(jnp.exp(params["log_std"])))
        return runner.replace(params=params, opt_state=opt_state, key=key), metrics

    def _update(self, runner: Runner):
        runner, traj, stats, last_value = self._collect(runner)
        runner, metrics = self._learn(runner, traj, last_value)
        done = stats["done"]
        n_done = jnp.sum(done)

        def mean_done(x):
            total = jnp.sum(jnp.where(done, jnp.nan_to_num(x.astype(jnp.float32)), 0.0))
            return jnp.where(n_done > 0, total / jnp.maximum(n_done, 1), jnp.nan)  # NaN: no episode ended

        metrics.update(
            reward=jnp.mean(traj["reward"]), episodes=n_done,
            episode_return=mean_done(stats["return"]), episode_ds=mean_done(stats["driving_score"]),
            episode_rc=mean_done(stats["route_completion"]), episode_success=mean_done(stats["success"]),
            episode_length=mean_done(stats["length"]),
            collisions=jnp.sum(stats["collision"]), red_lights=jnp.sum(stats["red_light"]),
            speed=jnp.mean(stats["speed"]))
        return runner.replace(update=runner.update + 1), metrics

    @staticmethod
    def policy_params(runner: Runner):
        """The model's parameters (the deterministic policy)."""
        return runner.params["actor"]


# --------------------------------------------------------------------------
# Run folder
# --------------------------------------------------------------------------


def _state_of(runner: Runner) -> dict:
    """The checkpoint pytree: ``params`` are the model's own (so a PPO run
    loads like an imitation run); the rest restores the runner exactly."""
    rest = jax.tree_util.tree_leaves((runner.env_state, runner.history, runner.obs, runner.key))
    return {"params": runner.params["actor"], "critic": runner.params["critic"],
            "log_std": runner.params["log_std"], "opt_state": runner.opt_state,
            "step": np.int64(runner.update), "runner": {str(i): a for i, a in enumerate(rest)}}


def _runner_of(state: dict, like: Runner) -> Runner:
    treedef = jax.tree_util.tree_structure((like.env_state, like.history, like.obs, like.key))
    leaves = jax.device_put([state["runner"][str(i)] for i in range(treedef.num_leaves)])
    env_state, history, obs, key = jax.tree_util.tree_unflatten(treedef, leaves)
    params = jax.device_put({"actor": state["params"], "critic": state["critic"], "log_std": state["log_std"]})
    return Runner(params=params, opt_state=jax.device_put(state["opt_state"]),
                  env_state=env_state, history=history, obs=obs, key=key,
                  update=jnp.asarray(int(state["step"]), jnp.int32))


def _model_and_init(cfg: PPOConfig):
    if cfg.init is None:
        model = get_model(cfg.model, **cfg.model_config)
        return model, None, cfg.model, dict(cfg.model_config)
    model, params, meta = load_init(cfg.init)
    return model, params, meta["model"], meta.get("model_config", {})


def _log_row(update: int, cfg: PPOConfig, metrics: dict, wall: float, sps: float) -> dict:
    row = {"update": update, "step": update, "env_steps": update * cfg.batch_size, "time": round(wall, 3),
           "env_steps_per_s": round(sps, 1)}
    for k, v in metrics.items():
        v = float(v)
        row[k] = v if math.isfinite(v) else None  # null: e.g. no episode ended in this update
    row["episodes"] = int(metrics["episodes"])
    return row


def train(cfg: PPOConfig, out: str | Path, *, resume: bool = False, force: bool = False,
          progress: ProgressFn | None = None, print_fn: Callable[[str], None] = print,
          env_params: EnvParams | None = None, model=None, time_limit_s: float | None = None) -> dict:
    """Run PPO per ``cfg``, writing the run folder ``out`` (module docstring).

    ``progress("ppo", env_steps, total_env_steps, {...})`` after every update.
    ``time_limit_s``: stop (with a checkpoint) after the update that passes
    this many seconds of this call; ``resume=True`` continues the run later.
    ``env_params`` / ``model`` replace the suite split / registry model (tests).
    Returns {"updates", "env_steps", "wall_s", "env_steps_per_s", "checkpoints", "last"}.
    """
    out = Path(out)
    if model is None:
        model, init_params, model_name, model_config = _model_and_init(cfg)
    else:
        init_params, model_name, model_config = None, model.name, {}
    cfg_json = json.loads(json.dumps({"model": model_name, "model_config": model_config, "data": "",
                                      "ppo": cfg.to_json()}))
    check_run_dir(out, cfg_json, resume, force)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "config.json", cfg_json)
    if env_params is None:
        env_params = make_params(cfg.suite, cfg.split, reward=cfg.reward_config(), limit=cfg.limit)
    ppo = PPO(model, env_params, cfg)
    runner = ppo.init(jax.random.PRNGKey(cfg.seed), init_params)
    ck_meta = {"model": model_name, "model_config": model_config, "config": cfg_json,
               "init": None if cfg.init is None else str(cfg.init), "algorithm": "ppo"}
    done = ckpt.list_checkpoints(out)
    if done:
        state = ckpt.restore(done[-1], _state_of(runner))
        runner = _runner_of(state, runner)
        trim_log(out / "log.jsonl", int(runner.update))
        print_fn(f"resuming {out} from update {int(runner.update)}")
    else:
        ckpt.save(out, 0, _state_of(runner), {**ck_meta, "step": 0, "env_steps": 0,
                                              "note": "the initial actor (before PPO)"})

    total = cfg.num_updates
    t0 = time.perf_counter()
    last: dict = {}
    u = int(runner.update)
    with open(out / "log.jsonl", "a", encoding="utf-8") as log:
        while u < total:
            t = time.perf_counter()
            runner, metrics = ppo.update(runner)
            metrics = jax.device_get(metrics)
            u = int(runner.update)
            dt = time.perf_counter() - t
            if not all(math.isfinite(float(metrics[k])) for k in ("pg_loss", "value_loss")):
                raise DriveE2EError(f"ppo: the loss became non-finite at update {u} (lower --lr?)")
            last = _log_row(u, cfg, metrics, time.perf_counter() - t0, cfg.batch_size / dt)
            if progress is not None:
                progress("ppo", u * cfg.batch_size, total * cfg.batch_size,
                         {"ret": f"{metrics['episode_return']:.1f}", "DS": f"{metrics['episode_ds']:.1f}",
                          "sps": f"{last['env_steps_per_s']:.0f}"})
            if u % cfg.log_every == 0 or u == 1 or u == total:
                log.write(json.dumps(last) + "\n")
                log.flush()
            out_of_time = time_limit_s is not None and time.perf_counter() - t0 > time_limit_s
            if u % cfg.ckpt_every == 0 or u == total or out_of_time:
                ckpt.save(out, u, _state_of(runner), {**ck_meta, "step": u, "env_steps": u * cfg.batch_size})
            if out_of_time and u < total:
                print_fn(f"ppo: time limit of {time_limit_s:.0f} s reached at update {u} of {total} (--resume continues)")
                break
    wall = time.perf_counter() - t0
    steps = u * cfg.batch_size
    print_fn(f"ppo {model_name}: {u} updates, {steps} env steps, {wall:.1f} s -> {out}")
    return {"updates": u, "env_steps": steps, "wall_s": wall,
            "env_steps_per_s": last.get("env_steps_per_s", float("nan")),
            "checkpoints": [str(p) for p in ckpt.list_checkpoints(out)], "last": last}


__all__ = ["PPO", "Critic", "PPOConfig", "Runner", "entropy", "features", "gae", "log_prob", "train"]
