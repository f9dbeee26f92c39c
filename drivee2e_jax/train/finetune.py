"""Closed-loop fine-tuning: backpropagate through short simulator rollouts.

An imitation-trained waypoint model (``models.base.Model``, "traj" mode)
drives the ego in the very ``Simulator`` the benchmark scores with; a loss on
the states it reaches is differentiated through the chain model -> waypoint
controller -> kinematic bicycle -> next step's controls ... over ``horizon``
steps (truncated BPTT), and only the model's parameters are trained (Optax
AdamW). In the spirit of Urban Driver (Scheel et al. 2021, closed-loop
training in a differentiable log-replay simulator). Results, weights and
what did not work: docs/finetuning.md.

States are ON-POLICY: a pool of ``batch`` episodes is driven by the current
policy; each optimisation step continues every episode by ``horizon`` steps
from where the previous one left it (gradient cut at the segment start). An
episode that finishes, or is picked with probability ``reset_prob`` (to keep
the pool spread over episode times), restarts on a random scenario of the
split. The imitation model never saw these drifted states: that is the point.

Loss per simulated step (means over active steps and the pool), see
``step_losses`` and ``LossWeights``:

* ``collision``: softplus of the SAT penetration (``geometry.box_penetration``)
  plus a safety margin between the ego box and every replayed agent box;
* ``route``: Huber lateral distance to the route polyline;
* ``comfort``: squared acceleration and yaw rate;
* ``red_light``: softplus of the ego front's overshoot past a stop line the
  route crosses while it shows red (``red_light_cost``; off by default);
* ``imitation``: the imitation (L1 waypoint) loss at the on-policy state
  against the log's future from the nearest logged position
  (``relabelled_target``: DAgger with the log as expert), so it does not forget.

Gradient path: the simulator's step runs exactly (infractions, criteria,
observation) without gradient; the ego pose gets its gradient from the same
dynamics step (``SimConfig.dynamics_model.step``). The observation of the new pose is detached by default
(``obs_gradient``): the loss reaches the parameters through the controls and
the vehicle dynamics, not through the perception feedback loop.

The waypoint controller's brake rule is a hard switch and its PID error is
clipped, which would block the longitudinal gradient. ``st_controls`` (and
``FineTuner._controls``, where the weight ``st`` is an argument) keeps
the controller's exact output in the forward pass and routes the backward
pass through a smooth surrogate (straight-through), so a fine-tuned model is
driven at evaluation exactly as any other checkpoint.

Run folder (loadable by ``policies/<model>.py:checkpoint=RUN`` and
``drivee2e trend RUN``)::

    RUN/config.json            model, model_config, data (of the init run) + the FinetuneConfig
    RUN/log.jsonl              {"step", "loss", "terms", "grad_norm", "lr", "time", ...} per logged step
    RUN/checkpoints/<step>/    ``train.checkpoint``; checkpoint 0 = the imitation parameters
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from drivee2e_jax import controller as ctl
from drivee2e_jax import geometry, replay
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import atomic_write_json
from drivee2e_jax.models import base
from drivee2e_jax.models import checkpoint as ckpt
from drivee2e_jax.models.registry import get_model
from drivee2e_jax.progress import ProgressFn
from drivee2e_jax.rollout import episode_lengths
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.sim import SimConfig, SimState, Simulator, sanitize_controls
from drivee2e_jax.train.loop import check_run_dir, trim_log
from drivee2e_jax.types import Controls, EgoState, Scenario, SignalState

TERMS = ("collision", "route", "comfort", "imitation", "red_light")


# --------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """Weights of the per-step loss terms (``step_losses``); 0 turns one off."""

    collision: float = 10.0
    route: float = 1.0
    comfort: float = 0.01
    imitation: float = 1.0
    red_light: float = 0.0

    def __post_init__(self):
        for k, v in dataclasses.asdict(self).items():
            if not (v >= 0 and np.isfinite(v)):
                raise DriveE2EError(f"finetune: loss weight {k} must be a finite number >= 0, got {v}")


@dataclasses.dataclass(frozen=True)
class FinetuneConfig:
    """One fine-tuning run (``drivee2e finetune`` flags map one to one).

    Attributes:
      init: imitation run folder (or checkpoint) whose parameters start the run.
      suite, split: scenarios driven (train split by default).
      steps: optimiser steps.  horizon: simulated steps per segment (BPTT length).
      batch: episodes in the pool (rollouts per step).
      lr: peak learning rate (linear warmup over ``warmup_steps``, then cosine
        to ``lr * end_lr_ratio``).  grad_clip: global-norm clip.
      weight_decay: AdamW.  reset_prob: chance per step that an episode
        restarts on a new scenario even if unfinished.
      margin: collision safety margin, m.  softness: collision softplus width, m.
      weights: ``LossWeights``.  seed: pool / reset seed.
      straight_through: backward through ``smooth_controls`` (True) or the
        exact controller's own derivative (False: zero through the brake rule).
      obs_gradient: also backpropagate through the observation of the ego's
        new pose (the perception feedback). Off by default: with it the
        30-step gradient norm reached 1e5-1e7 (chaotic loop, docs/finetuning.md).
      log_every: steps between log lines.  ckpt_every: steps between checkpoints.
    """

    init: str = ""
    suite: str = "twin15"
    split: str = "train"
    steps: int = 400
    horizon: int = 30
    batch: int = 16
    lr: float = 5e-5
    warmup_steps: int = 20
    end_lr_ratio: float = 0.1
    grad_clip: float = 1.0
    weight_decay: float = 0.0
    reset_prob: float = 0.1
    margin: float = 0.5
    softness: float = 0.2
    weights: LossWeights = dataclasses.field(default_factory=LossWeights)
    seed: int = 0
    straight_through: bool = True
    obs_gradient: bool = False
    log_every: int = 5
    ckpt_every: int = 100

    def __post_init__(self):
        for name in ("steps", "horizon", "batch", "log_every", "ckpt_every"):
            if getattr(self, name) < 1:
                raise DriveE2EError(f"finetune: {name} must be >= 1, got {getattr(self, name)}")
        if not self.lr > 0:
            raise DriveE2EError(f"finetune: lr must be > 0, got {self.lr}")
        if not 0.0 <= self.reset_prob <= 1.0:
            raise DriveE2EError(f"finetune: reset_prob must be in [0, 1], got {self.reset_prob}")

    def to_json(self) -> dict:
        return dataclasses.asdict(self)


# --------------------------------------------------------------------------
# Straight-through waypoint controller (pure, one sample)
# --------------------------------------------------------------------------

#: Surrogate longitudinal response: d(net accel)/d(desired speed), 1/s, and
#: the softplus width of the throttle / brake split, m/s.
SURROGATE_GAIN = 2.0
SURROGATE_WIDTH = 0.5


def smooth_controls(waypoints_xy, speed, params: ctl.ControllerParams) -> Controls:
    """A smooth stand-in for ``controller.waypoints_to_controls`` (backward pass only).

    Throttle / brake ask for a net acceleration ``SURROGATE_GAIN * (v* - v)``
    (v* the controller's desired speed), split smoothly into throttle and
    brake; steer is the controller's pure pursuit (already differentiable).

    Args:
      waypoints_xy: (K, 2) ego frame, m.  speed: () m/s.
    """
    veh = params.vehicle
    step = waypoints_xy[1] - waypoints_xy[0]
    target = jnp.sqrt(jnp.sum(step**2) + 1e-6) / params.waypoint_dt
    u = (target - speed) / SURROGATE_WIDTH
    throttle = SURROGATE_GAIN * SURROGATE_WIDTH / veh.max_accel * jax.nn.softplus(u)
    brake = SURROGATE_GAIN * SURROGATE_WIDTH / veh.max_decel * jax.nn.softplus(-u)
    return Controls(throttle=throttle, brake=brake, steer=ctl.pursuit_steer(waypoints_xy, speed, params))


def straight_through(exact, smooth):
    """``exact`` in value, the gradient of ``smooth``."""
    return exact + (smooth - jax.lax.stop_gradient(smooth))


def st_controls(waypoints_xy, speed, state: ctl.ControllerState, params: ctl.ControllerParams):
    """``controller.waypoints_to_controls`` with a straight-through backward pass.

    Forward: exactly the simulator's controls. Backward: ``smooth_controls``.
    The speed enters the exact branch without gradient (the surrogate carries
    d/d speed). Returns (Controls, ControllerState).
    """
    exact, new_state = ctl.waypoints_to_controls(jax.lax.stop_gradient(waypoints_xy), jax.lax.stop_gradient(speed),
                                                 state, params)
    smooth = smooth_controls(waypoints_xy, speed, params)
    return jax.tree_util.tree_map(straight_through, exact, smooth), new_state


# --------------------------------------------------------------------------
# Loss terms (pure, one sample, one step)
# --------------------------------------------------------------------------


def soft_collision(ego: EgoState, ego_lw, agents: replay.AgentStates, size, margin: float, softness: float):
    """() sum over valid agents of ``softness * softplus((penetration + margin) / softness)``, m.

    ``penetration`` is the SAT overlap depth of the two boxes
    (``geometry.box_penetration``: > 0 overlapping, else minus a lower bound
    of the gap), so the cost is ~0 beyond ``margin`` and grows linearly with
    the overlap. Args: ego_lw (2,) m; agents (A,) replayed; size (A, 3) m.
    """
    pen = jax.vmap(geometry.box_penetration, in_axes=(None, None, None, 0, 0, 0))(
        ego.xy, ego.yaw, ego_lw, agents.xy, agents.yaw, size[:, :2])
    cost = softness * jax.nn.softplus((pen + margin) / softness)
    return jnp.sum(jnp.where(agents.valid, cost, 0.0))


def huber(x, delta: float = 1.0):
    """Huber of a non-negative distance ``x`` (quadratic below ``delta`` m)."""
    return jnp.where(x < delta, 0.5 * x**2, delta * (x - 0.5 * delta))


def red_light_cost(front_arc, prev_front_arc, stop_arc, signals, margin: float, softness: float):
    """() soft cost of the ego's front passing a red stop line, m.

    For every stop line the route crosses (``stop_arc (S,)`` route arc, inf if
    none) that shows red now (``signals (S,)`` ``SignalState``) and that the
    front had not passed at the previous step (``prev_front_arc``, no
    gradient): ``softness * softplus((front_arc - stop_arc + margin) / softness)``,
    ~0 when the front stays ``margin`` m behind the line.
    """
    armed = jnp.isfinite(stop_arc) & (signals == SignalState.RED) & (prev_front_arc < stop_arc)
    over = (front_arc - jnp.where(armed, stop_arc, 0.0) + margin) / softness
    return jnp.sum(jnp.where(armed, softness * jax.nn.softplus(over), 0.0))


def step_losses(scenario: Scenario, prev: EgoState, ego: EgoState, agents: replay.AgentStates, ego_lw, stop_arc,
                cfg: FinetuneConfig) -> dict:
    """The unweighted state loss terms after one step (see the module docstring).

    Args: scenario unbatched; prev / ego the EgoState before / after the step;
    agents the replayed (non-ego) agents at ``ego.t``; ego_lw (2,) m;
    stop_arc (S,) route arc of each stop line (``SimContext.stop_arc``).
    Returns {term: ()} without "imitation".
    """
    route = scenario.route
    proj = geometry.project_to_polyline(ego.xy, route.xy, route.valid)
    prev_arc = geometry.project_to_polyline(jax.lax.stop_gradient(prev.xy), route.xy, route.valid).arc
    signals = replay.signals_at(scenario.signals, ego.t, scenario.dt_log)
    half = 0.5 * ego_lw[0]
    red = red_light_cost(proj.arc + half, prev_arc + half, stop_arc, signals, cfg.margin, cfg.softness)
    dist = huber(proj.distance)
    return {
        "collision": soft_collision(ego, ego_lw, agents, scenario.tracks.size, cfg.margin, cfg.softness),
        "route": jnp.where(jnp.isfinite(dist), dist, 0.0),
        "comfort": ego.accel**2 + ego.yaw_rate**2,
        "red_light": jnp.where(proj.valid, red, 0.0),
    }


def nearest_log_time(scenario: Scenario, ego: EgoState):
    """() s, the log time at the foot of ``ego.xy`` on the logged ego path:
    where the demonstrator was when it stood where the ego stands now,
    whatever the clock says. Continuous in the pose (interpolated along the
    foot segment); a standing log resolves to the moment it arrived."""
    tr, i = scenario.tracks, scenario.ego_index
    proj = geometry.project_to_polyline(ego.xy, tr.xy[i], tr.valid[i])
    k = jnp.maximum(proj.segment, 0)
    k1 = jnp.minimum(k + 1, tr.xy.shape[1] - 1)
    seg = tr.xy[i, k1] - tr.xy[i, k]
    frac = jnp.clip(jnp.dot(ego.xy - tr.xy[i, k], seg) / jnp.maximum(jnp.dot(seg, seg), 1e-9), 0.0, 1.0)
    return (k.astype(jnp.float32) + frac) * scenario.dt_log


def relabelled_target(scenario: Scenario, ego: EgoState, obs, num_waypoints: int, dt: float) -> base.Target:
    """The imitation label at an on-policy state (no gradient): the log's
    future from ``nearest_log_time`` in the CURRENT ego frame, i.e. the way
    back onto the demonstration from here (DAgger with the log as expert).
    A same-clock label would ask a late ego to race to where the log is now."""
    ego_ = ego.replace(t=nearest_log_time(scenario, ego))
    return jax.lax.stop_gradient(base.targets_from_log(scenario, ego_, obs, num_waypoints, dt))


# --------------------------------------------------------------------------
# Rollout segment with gradients
# --------------------------------------------------------------------------


@struct.dataclass
class Carry:
    """One pool episode between segments.

    Attributes: sim (SimState), obs (Observation), history (base.EgoHistory),
    controller (ControllerState of the straight-through controller), key.
    """

    sim: SimState
    obs: Any
    history: base.EgoHistory
    controller: ctl.ControllerState
    key: jnp.ndarray


class FineTuner:
    """The differentiable closed loop of ``model`` in ``sim`` (pure methods, one sample).

    ``reset(scenario, key) -> Carry``; ``segment(params, scenario, carry) ->
    (loss, (terms, Carry))`` drives ``cfg.horizon`` steps; ``batch_loss`` is
    its mean over a pool (vmapped).
    """

    def __init__(self, model, sim: Simulator, cfg: FinetuneConfig):
        self.model, self.sim, self.cfg = model, sim, cfg
        self.ctl_params = dataclasses.replace(sim.config.controller, waypoint_dt=float(model.waypoint_dt))

    def reset(self, scenario: Scenario, key) -> Carry:
        k_reset, key = jax.random.split(key)
        state, obs = self.sim.reset(k_reset, scenario)
        return Carry(sim=state, obs=obs, history=base.empty_history(obs),
                     controller=ctl.init_controller_state(self.ctl_params), key=key)

    def _controls(self, wp, speed, cstate, st):
        """The controller's exact controls; their gradient is the surrogate's
        (``st`` = 1) or the controller's own (``st`` = 0), a traced weight so
        both share one compiled program."""
        exact, new_state = ctl.waypoints_to_controls(jax.lax.stop_gradient(wp), jax.lax.stop_gradient(speed), cstate,
                                                     self.ctl_params)
        own, own_state = ctl.waypoints_to_controls(wp, speed, cstate, self.ctl_params)
        smooth = smooth_controls(wp, speed, self.ctl_params)
        grad_of = lambda x: x - jax.lax.stop_gradient(x)
        controls = jax.tree_util.tree_map(lambda e, s_, o: e + st * grad_of(s_) + (1.0 - st) * grad_of(o),
                                          exact, smooth, own)
        # The PID memory carries the controller's own derivative (st = 0 only).
        new_state = jax.tree_util.tree_map(lambda e, o: e + (1.0 - st) * grad_of(o), new_state, own_state)
        return controls, new_state

    def _step(self, params, scenario: Scenario, c: Carry, st):
        cfg, sim = self.cfg, self.sim
        active = ~c.sim.episode.done
        obs = c.obs if cfg.obs_gradient else jax.lax.stop_gradient(c.obs)
        hist = base.push_history(c.history, obs)
        wp = self.model.apply(params, base.with_history(obs, hist)).waypoints
        target = relabelled_target(scenario, c.sim.ego, c.obs, wp.shape[0], self.model.waypoint_dt)
        controls, cstate = self._controls(wp, c.sim.ego.speed, c.controller, st)
        # The simulator's own step, exact and without gradient (infractions,
        # criteria, observation); the gradient takes the same dynamics step.
        state, new_obs, _ = sim.step(scenario, jax.lax.stop_gradient(c.sim), jax.lax.stop_gradient(controls))
        ego = sim.config.dynamics_model.step(c.sim.ego, sanitize_controls(controls)[0], sim.config.dt,
                                             sim.config.dynamics)
        ego = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), ego, c.sim.ego)
        state = state.replace(ego=jax.tree_util.tree_map(straight_through, state.ego, ego))
        if cfg.obs_gradient:  # the observation of the differentiable pose (same value)
            new_obs = sim.observe(scenario, state)
        terms = step_losses(scenario, c.sim.ego, state.ego, sim.agents(scenario, state.ego.t, state), state.ctx.ego_lw,
                            state.ctx.stop_arc, cfg)
        terms["imitation"] = base.waypoint_l1(wp, target)
        terms = {k: jnp.where(active, v, 0.0) for k, v in terms.items()}
        terms["active"] = active.astype(jnp.float32)
        return Carry(sim=state, obs=new_obs, history=hist, controller=cstate, key=c.key), terms

    def weight_vector(self) -> jnp.ndarray:
        """(len(TERMS),) float32 the config's loss weights, in ``TERMS`` order."""
        return jnp.array([getattr(self.cfg.weights, k) for k in TERMS], jnp.float32)

    def segment(self, params, scenario: Scenario, carry: Carry, st=1.0, weights=None):
        """() summed weighted loss over ``horizon`` steps, ({term: () sum}, Carry).
        ``st``: straight-through weight (see ``_controls``); ``weights``
        (len(TERMS),) loss weights (default: the config's), an argument so that
        changing them does not recompile."""

        def body(c, _):
            return self._step(params, scenario, c, st)

        carry, terms = jax.lax.scan(body, carry, None, length=self.cfg.horizon)
        sums = {k: jnp.sum(v) for k, v in terms.items()}
        w = self.weight_vector() if weights is None else weights
        loss = sum(w[i] * sums[k] for i, k in enumerate(TERMS))
        return loss, (sums, carry)

    def batch_loss(self, params, batch: Scenario, carry: Carry, st=1.0, weights=None):
        """Mean per active step over the pool: (loss, (terms, Carry))."""
        loss, (sums, carry) = jax.vmap(self.segment, in_axes=(None, 0, 0, None, None))(params, batch, carry, st,
                                                                                      weights)
        n = jnp.maximum(jnp.sum(sums["active"]), 1.0)
        terms = {k: jnp.sum(sums[k]) / n for k in TERMS}
        terms["active"] = n
        carry = jax.lax.stop_gradient(carry)
        return jnp.sum(loss) / n, (terms, carry)


# --------------------------------------------------------------------------
# Training loop (host)
# --------------------------------------------------------------------------


def make_optimizer(cfg: FinetuneConfig):
    """(AdamW with global-norm clipping, its schedule)."""
    warmup = min(cfg.warmup_steps, max(cfg.steps - 1, 0))
    schedule = optax.warmup_cosine_decay_schedule(0.0, cfg.lr, warmup, max(cfg.steps, warmup + 1),
                                                  end_value=cfg.lr * cfg.end_lr_ratio)
    opt = optax.chain(optax.clip_by_global_norm(cfg.grad_clip), optax.adamw(schedule, weight_decay=cfg.weight_decay))
    return opt, schedule


def _take(tree, idx):
    return jax.tree_util.tree_map(lambda a: a[idx], tree)


def make_grad_fn(tuner: FineTuner) -> Callable:
    """jit((params, scenarios, idx, carry, st, weights) -> ((loss, (terms, carry)), grads)):
    one segment on the pool rows ``idx (B,)`` of the device-resident split;
    ``st`` () float32 straight-through weight (1 = surrogate, 0 = exact);
    ``weights`` (len(TERMS),) float32 (``FineTuner.weight_vector``)."""

    def grad_fn(params, scenarios, idx, carry, st, weights):
        return jax.value_and_grad(tuner.batch_loss, has_aux=True)(params, _take(scenarios, idx), carry, st, weights)

    return jax.jit(grad_fn)


def make_update(opt) -> Callable:
    """jit((params, opt_state, grads) -> (params, opt_state, grad_norm))."""

    def update(params, opt_state, grads):
        updates, opt_state = opt.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, _global_norm(grads)

    return jax.jit(update)


def make_reset(tuner: FineTuner) -> Callable:
    """jit((scenarios, idx (B,), keys (B, 2)) -> Carry): fresh episodes on rows ``idx``."""
    return jax.jit(lambda scenarios, idx, keys: jax.vmap(tuner.reset)(_take(scenarios, idx), keys))


@jax.jit
def _merge(mask, fresh, carry):
    """``fresh`` where ``mask (B,)``, else ``carry``."""
    return jax.tree_util.tree_map(lambda a, b: jnp.where(mask.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), fresh, carry)


def load_init(init: str | Path):
    """(model, params, run config dict) of an imitation run / checkpoint."""

    path = ckpt.resolve(init)
    meta = ckpt.read_meta(path)
    if "model" not in meta:
        raise DriveE2EError(f"{path}/meta.json: no 'model' field (expected a drivee2e train checkpoint)")
    model = get_model(meta["model"], **meta.get("model_config", {}))
    if getattr(model, "required_sensors", ()):
        raise DriveE2EError(f"--init {init}: model {meta['model']!r} needs sensors {list(model.required_sensors)}; "
                            "fine-tuning supports vector-observation models (vector_transformer, ad_mlp)")
    return model, ckpt.load_params(path), meta


def finetune(cfg: FinetuneConfig, out: str | Path, *, resume: bool = False, force: bool = False,
             progress: ProgressFn | None = None, print_fn: Callable[[str], None] = print) -> dict:
    """Fine-tune ``cfg.init`` in closed loop on ``cfg.suite``/``cfg.split``; write ``out``.

    ``progress("finetune", step, steps, {"loss": ..., ...})`` after every step
    (``progress.ProgressFn``; the CLI draws a bar).

    Returns {"steps", "loss", "wall_s", "checkpoints"}.
    """

    out = Path(out)
    model, init_params, meta = load_init(cfg.init)
    data = meta.get("config", {}).get("data", "")
    cfg_json = json.loads(json.dumps({"model": meta["model"], "model_config": meta.get("model_config", {}),
                                      "data": data, "finetune": cfg.to_json()}))
    check_run_dir(out, cfg_json, resume, force)
    out.mkdir(parents=True, exist_ok=True)

    atomic_write_json(out / "config.json", cfg_json)

    packed = load_suite(cfg.suite).pack(cfg.split)
    scenarios = jax.device_put(packed.scenario)
    n_scen = len(packed)
    tuner = FineTuner(model, Simulator(SimConfig()), cfg)
    opt, schedule = make_optimizer(cfg)
    params, opt_state, step = init_params, opt.init(init_params), 0
    ck_meta = {"model": meta["model"], "model_config": meta.get("model_config", {}), "config": cfg_json,
               "init": str(cfg.init)}
    done = ckpt.list_checkpoints(out)
    if done:
        state = ckpt.restore(done[-1], {"params": params, "opt_state": opt_state, "step": np.int64(0)})
        params, opt_state, step = state["params"], state["opt_state"], int(state["step"])
        trim_log(out / "log.jsonl", step)
        print_fn(f"resuming {out} from step {step}")
    else:
        ckpt.save(out, 0, {"params": params, "opt_state": opt_state, "step": np.int64(0)},
                  {**ck_meta, "step": 0, "note": "the imitation parameters (before fine-tuning)"})

    grad_fn, update, reset = make_grad_fn(tuner), make_update(opt), make_reset(tuner)
    st = jnp.float32(1.0 if cfg.straight_through else 0.0)
    weights = tuner.weight_vector()
    rng = np.random.default_rng([cfg.seed, step])
    key = jax.random.PRNGKey(cfg.seed + 7919 * step)
    idx = rng.integers(0, n_scen, cfg.batch)
    key, k = jax.random.split(key)
    carry = reset(scenarios, idx, jax.random.split(k, cfg.batch))
    # The pool starts at t = 0 everywhere; the random restarts (reset_prob)
    # spread it over episode times within a few steps, at no extra rollout.
    max_steps = np.asarray(episode_lengths(tuner.sim, scenarios))

    t0 = time.perf_counter()
    loss = float("nan")
    with open(out / "log.jsonl", "a", encoding="utf-8") as log:
        while step < cfg.steps:
            (loss_value, (terms, carry)), grads = grad_fn(params, scenarios, idx, carry, st, weights)
            params, opt_state, gnorm = update(params, opt_state, grads)
            step += 1
            loss = float(loss_value)
            if not np.isfinite(loss):
                raise DriveE2EError(f"finetune: loss became {loss} at step {step} (lower --lr?)")
            # Restart finished episodes, those too close to their end for a
            # full segment, and a random few.
            sim_step = np.asarray(carry.sim.step)
            restart = (np.asarray(carry.sim.episode.done) | (sim_step + cfg.horizon > max_steps[idx])
                       | (rng.random(cfg.batch) < cfg.reset_prob))
            if restart.any():
                idx = np.where(restart, rng.integers(0, n_scen, cfg.batch), idx)
                key, k = jax.random.split(key)
                carry = _merge(restart, reset(scenarios, idx, jax.random.split(k, cfg.batch)), carry)
            if progress is not None:
                progress("finetune", step, cfg.steps,
                         {"loss": f"{loss:.3f}", **{k[:4]: f"{float(terms[k]):.3f}" for k in TERMS}})
            if step % cfg.log_every == 0 or step == 1:
                row = {"step": step, "loss": loss, "lr": float(schedule(step - 1)), "grad_norm": float(gnorm),
                       "terms": {k: float(terms[k]) for k in TERMS}, "active_steps": float(terms["active"]),
                       "restarts": int(restart.sum()), "time": round(time.perf_counter() - t0, 3)}
                log.write(json.dumps(row) + "\n")
                log.flush()
            if step % cfg.ckpt_every == 0 or step == cfg.steps:
                ckpt.save(out, step, {"params": params, "opt_state": opt_state, "step": np.int64(step)},
                          {**ck_meta, "step": step, "train_loss": loss})
    wall = time.perf_counter() - t0
    print_fn(f"fine-tuned {meta['model']}: {step} steps, last loss {loss:.4f}, {wall:.1f} s -> {out}")
    return {"steps": step, "loss": loss, "wall_s": wall, "checkpoints": [str(p) for p in ckpt.list_checkpoints(out)]}


def _global_norm(tree) -> jnp.ndarray:
    """() L2 norm over every leaf (``optax.global_norm`` is deprecated, and
    ``optax.tree.norm`` is newer than our lowest pinned optax)."""
    return jnp.sqrt(sum(jnp.sum(jnp.square(x)) for x in jax.tree_util.tree_leaves(tree)))
