"""The interface every trainable baseline implements, and its bridge to ``Policy``.

A ``Model`` is a Flax Linen network wrapped with its loss, written for ONE
sample (the training loop and the rollout ``vmap`` it)::

    params = model.init(key, obs)                  # a plain variables pytree
    out = model.apply(params, obs)                 # ModelOutput, pure
    loss, metrics = model.loss(params, obs, target)

``obs`` is a ``HistoryObservation``: the simulator's ``types.Observation``
plus the ego's own recent past (``history``, 8 samples 0.5 s apart, in the
current ego frame). The simulator's Observation has no memory, so
``as_policy`` keeps the past in the policy state (``EgoHistory``) and the
demonstration recorder (``train.dataset``) runs the very same
``push_history`` / ``with_history`` code, so training and driving see the
same inputs. Models that need no history ignore the field.

``Target`` is the demonstration label of one sample (``targets_from_log``):
the logged future positions of the ego in its current frame and the controls
that reproduce the log (``Observation.privileged.log_controls``).
"""

from __future__ import annotations

from typing import Any, Literal, NamedTuple, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
from flax import struct

from drivee2e_jax import controller as ctl
from drivee2e_jax import geometry, replay
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import checkpoint as ckpt
from drivee2e_jax.models.checkpoint import load_params, training_bev
from drivee2e_jax.models.registry import get_model
from drivee2e_jax.observe.bev import check_bev
from drivee2e_jax.observe.sensors import SensorConfig
from drivee2e_jax.types import Controls, EgoState, Observation, Scenario, Waypoints

#: Past ego samples the history holds, and their spacing in s (4 s of past).
HISTORY_LEN = 8
HISTORY_DT = 0.5
#: Per history sample: x, y (m, current ego frame), cos dyaw, sin dyaw,
#: speed (m/s), accel (m/s^2), yaw rate (rad/s).
HISTORY_FEATURES = 7

Mode = Literal["traj", "ctrl", "fused"]


@struct.dataclass
class Target:
    """The demonstration label of one sample.

    Attributes:
      waypoints:      (K, 2) float32 logged ego positions at ``dt * (1..K)`` s
                      ahead, in the ego frame now (x forward, y left), m; 0
                      where invalid.
      waypoint_valid: (K,) bool, the log covers that future time.
      controls:       (3,) float32 throttle [0, 1], brake [0, 1], steer [-1, 1]
                      that move the ego onto its next logged pose.
      command:        () int32 ``types.Command`` at the next route point.
    """

    waypoints: jnp.ndarray
    waypoint_valid: jnp.ndarray
    controls: jnp.ndarray
    command: jnp.ndarray


@struct.dataclass
class EgoHistory:
    """The policy-state memory of the ego's past (world frame), oldest first.

    Attributes:
      xy:    (H, 2) float32 world position (``Observation.gps``), m.
      yaw:   (H,) float32 world heading (``Observation.compass``), rad.
      ego:   (H, 4) float32 ``Observation.ego`` (speed, accel, yaw rate, steer).
      t:     (H,) float32 time the sample was taken, s.
      valid: (H,) bool.
    """

    xy: jnp.ndarray
    yaw: jnp.ndarray
    ego: jnp.ndarray
    t: jnp.ndarray
    valid: jnp.ndarray


@struct.dataclass
class HistoryObservation(Observation):
    """``types.Observation`` plus the ego's recent past.

    Attributes (in addition to Observation's):
      history:       (H, 7) float32 per past sample, oldest first: x, y in the
                     CURRENT ego frame (m), cos / sin of heading minus the
                     current heading, speed (m/s), accel (m/s^2), yaw rate
                     (rad/s); 0 where invalid.
      history_valid: (H,) bool.
    """

    history: jnp.ndarray | None = None
    history_valid: jnp.ndarray | None = None


@struct.dataclass
class ModelOutput:
    """What a model predicts for one sample.

    Attributes:
      waypoints: (K, 2) float32 future ego positions, ego frame, m,
                 ``model.waypoint_dt`` apart.
      controls:  ``types.Controls`` (control head) or None.
    """

    waypoints: jnp.ndarray
    controls: Controls | None = None


@runtime_checkable
class Model(Protocol):
    """A trainable baseline (see the module docstring).

    Attributes:
      name: registry name (``models.MODELS``).
      required_sensors: sensors the observation must carry (``("bev",)``...).
      waypoint_dt: s between predicted waypoints.
      num_waypoints: K.
    """

    name: str
    required_sensors: tuple[str, ...]
    waypoint_dt: float
    num_waypoints: int

    def init(self, key, obs: HistoryObservation) -> Any: ...

    def apply(self, params, obs: HistoryObservation) -> ModelOutput: ...

    def loss(self, params, obs: HistoryObservation, target: Target) -> tuple[jnp.ndarray, dict]: ...


# --------------------------------------------------------------------------
# History (pure, one sample)
# --------------------------------------------------------------------------


def empty_history(obs: Observation) -> EgoHistory:
    """An all-invalid ``EgoHistory`` shaped for ``obs``."""
    h = HISTORY_LEN
    return EgoHistory(
        xy=jnp.zeros((h, 2), jnp.float32), yaw=jnp.zeros((h,), jnp.float32),
        ego=jnp.zeros((h, 4), jnp.float32), t=jnp.full((h,), -1e9, jnp.float32),
        valid=jnp.zeros((h,), bool),
    )


def push_history(hist: EgoHistory, obs: Observation) -> EgoHistory:
    """Append the current sample when ``HISTORY_DT`` has passed since the last.

    The clock is ``obs.privileged.ego.t`` (time only, no privileged state), so
    the spacing is the same whether the policy runs every 0.1 s (closed loop)
    or every 0.5 s (open loop, the recorder).
    """
    t = obs.privileged.ego.t.astype(jnp.float32)
    due = ~hist.valid[-1] | (t >= hist.t[-1] + HISTORY_DT - 1e-3)
    shifted = EgoHistory(
        xy=jnp.concatenate([hist.xy[1:], obs.gps[None].astype(jnp.float32)]),
        yaw=jnp.concatenate([hist.yaw[1:], obs.compass[None].astype(jnp.float32)]),
        ego=jnp.concatenate([hist.ego[1:], obs.ego[None].astype(jnp.float32)]),
        t=jnp.concatenate([hist.t[1:], t[None]]),
        valid=jnp.concatenate([hist.valid[1:], jnp.ones((1,), bool)]),
    )
    return jax.tree_util.tree_map(lambda a, b: jnp.where(due, a, b), shifted, hist)


def with_history(obs: Observation, hist: EgoHistory) -> HistoryObservation:
    """``obs`` with ``hist`` expressed in the current ego frame (gps/compass)."""
    xy = geometry.to_frame(hist.xy, obs.gps, obs.compass)
    dyaw = geometry.wrap_angle(hist.yaw - obs.compass)
    feats = jnp.concatenate(
        [xy, jnp.cos(dyaw)[:, None], jnp.sin(dyaw)[:, None], hist.ego[:, :3]], axis=-1
    ).astype(jnp.float32)
    feats = jnp.where(hist.valid[:, None], feats, 0.0)
    fields = {f: getattr(obs, f) for f in obs.__dataclass_fields__ if f not in ("history", "history_valid")}
    return HistoryObservation(**fields, history=feats, history_valid=hist.valid)


# --------------------------------------------------------------------------
# Targets
# --------------------------------------------------------------------------


def controls_vector(c: Controls) -> jnp.ndarray:
    """(3,) float32 [throttle, brake, steer] of a ``Controls``."""
    return jnp.stack([c.throttle, c.brake, c.steer]).astype(jnp.float32)


def targets_from_log(scenario: Scenario, ego: EgoState, obs: Observation, num_waypoints: int = 6,
                     dt: float = 0.5) -> Target:
    """The demonstration label at the ego's current state (one scenario).

    Args:
      scenario: the (unbatched) ``Scenario``.
      ego: the simulated ``EgoState`` (its pose defines the frame; ``t`` the time).
      obs: the observation at that state (command, ``privileged.log_controls``).
      num_waypoints: K future points, ``dt`` s apart (first at ``dt``).
    """
    times = ego.t + dt * jnp.arange(1, num_waypoints + 1, dtype=jnp.float32)
    fut = jax.vmap(lambda tt: replay.ego_log_at(scenario.tracks, scenario.ego_index, tt, scenario.dt_log))(times)
    wp = geometry.to_frame(fut.xy, ego.xy, ego.yaw)
    return Target(
        waypoints=jnp.where(fut.valid[:, None], wp, 0.0).astype(jnp.float32),
        waypoint_valid=fut.valid,
        controls=controls_vector(obs.privileged.log_controls),
        command=obs.command.astype(jnp.int32),
    )


def waypoint_l1(pred: jnp.ndarray, target: Target) -> jnp.ndarray:
    """() masked mean L1 distance between ``pred (K, 2)`` and the target, m."""
    m = target.waypoint_valid[:, None].astype(jnp.float32)
    return jnp.sum(jnp.abs(pred - target.waypoints) * m) / jnp.maximum(2.0 * jnp.sum(m[:, 0]), 1.0)


def waypoint_l2(pred: jnp.ndarray, target: Target) -> jnp.ndarray:
    """() masked mean per-point L2 distance, m (a metric, not a loss)."""
    d = jnp.sqrt(jnp.sum((pred - target.waypoints) ** 2, axis=-1) + 1e-12)
    m = target.waypoint_valid.astype(jnp.float32)
    return jnp.sum(d * m) / jnp.maximum(jnp.sum(m), 1.0)


# --------------------------------------------------------------------------
# Model -> Policy
# --------------------------------------------------------------------------


class PolicyState(NamedTuple):
    """``as_policy``'s recurrent state.

    Attributes:
      history: the ego history (``EgoHistory``).
      controller: the fused mode's waypoint-controller PID memory.
      fused_steers: (FUSE_WINDOW,) float32 |steer| of the last fused actions,
        oldest first (zeros before the first), TCP's turning memory.
    """

    history: EgoHistory
    controller: ctl.ControllerState
    fused_steers: jnp.ndarray


#: TCP's situation-based fusion: a steer above this (|steer| in [-1, 1])
#: counts as turning ...
FUSE_TURN_STEER = 0.1
#: ... and the car is turning (the control branch leads) when more than
#: FUSE_TURN_COUNT of the last FUSE_WINDOW fused actions steered so
#: (``tcp_agent.py``: 20 frames, > 10 of them).
FUSE_WINDOW = 20
FUSE_TURN_COUNT = 10
#: Weight of the trailing branch in the blend.
FUSE_ALPHA = 0.3


def is_turning(fused_steers: jnp.ndarray) -> jnp.ndarray:
    """() bool TCP's turning status from the |steer| of the last fused
    actions (``PolicyState.fused_steers``)."""
    return jnp.sum(fused_steers > FUSE_TURN_STEER) > FUSE_TURN_COUNT


def fuse_controls(traj: Controls, ctrl: Controls, turning: jnp.ndarray | None = None) -> Controls:
    """TCP's fused action (Wu et al. 2022, ``tcp_agent.py``).

    Going straight trust the trajectory branch: steer and throttle = 0.7
    traj + 0.3 ctrl; turning: 0.7 ctrl + 0.3 traj. Brake = the larger of the
    two; throttle capped at 0.75 as TCP does. ``turning``: () bool, TCP's
    status from its recent steers (``is_turning``); None: the memoryless
    rule |traj steer| > 0.1.
    """
    if turning is None:
        turning = jnp.abs(traj.steer) > FUSE_TURN_STEER
    w_ctrl = jnp.where(turning, 1.0 - FUSE_ALPHA, FUSE_ALPHA)
    steer = jnp.clip(w_ctrl * ctrl.steer + (1.0 - w_ctrl) * traj.steer, -1.0, 1.0)
    throttle = jnp.clip(w_ctrl * ctrl.throttle + (1.0 - w_ctrl) * traj.throttle, 0.0, 0.75)
    return Controls(throttle=throttle, brake=jnp.maximum(traj.brake, ctrl.brake), steer=steer)


class ModelPolicy:
    """A ``policy.Policy`` driving with a ``Model`` (see ``as_policy``).

    Attributes (besides the Policy protocol's):
      model, params (None: ``init`` draws a fresh random init), mode.
      controller: ``ControllerParams`` of the fused mode's trajectory branch.
      sensor_config: ``observe.sensors.SensorConfig`` fixing the size the
        required sensors are rendered at (the BEV of the training data,
        ``policy_from_checkpoint``), or None: the simulator's.
    """

    def __init__(self, model: Model, params=None, mode: Mode = "traj",
                 controller: ctl.ControllerParams | None = None, name: str | None = None,
                 sensor_config=None):
        if mode not in ("traj", "ctrl", "fused"):
            raise ValueError(f"as_policy: mode must be 'traj', 'ctrl' or 'fused', got {mode!r}")
        self.model, self.params, self.mode = model, params, mode
        self.name = name or (model.name if mode == "traj" else f"{model.name}-{mode}")
        self.action_type = "waypoints" if mode == "traj" else "controls"
        self.waypoint_dt = float(model.waypoint_dt)
        self.required_sensors = tuple(getattr(model, "required_sensors", ()) or ())
        self.controller = controller or ctl.ControllerParams(waypoint_dt=self.waypoint_dt)
        self.sensor_config = sensor_config
        if sensor_config is not None:
            check_bev(sensor_config.bev, model, f"policy {self.name!r}")

    def init(self, key, obs):
        """The restored parameters, or a fresh random init of the model when
        there are none (smoke tests only)."""
        if self.params is not None:
            return self.params
        return self.model.init(key, with_history(obs, push_history(empty_history(obs), obs)))

    # Equal policies share compiled programs (``openloop``'s runner cache):
    # the parameters are an argument of ``act``, not part of the program.
    def _key(self):
        return type(self), self.model, self.mode, self.controller, self.name, self.sensor_config

    def __eq__(self, other):
        return isinstance(other, ModelPolicy) and self._key() == other._key()

    def __hash__(self):
        return hash(self._key())

    def initial_state(self, obs) -> PolicyState:
        return PolicyState(history=empty_history(obs), controller=ctl.init_controller_state(self.controller),
                           fused_steers=jnp.zeros((FUSE_WINDOW,), jnp.float32))

    def act(self, params, obs, policy_state: PolicyState, key):
        hist = push_history(policy_state.history, obs)
        out = self.model.apply(self.params if params is None else params, with_history(obs, hist))
        cstate, steers = policy_state.controller, policy_state.fused_steers
        if self.mode == "traj":
            action = Waypoints(xy=out.waypoints.astype(jnp.float32))
        elif self.mode == "ctrl":
            action = _require_controls(out, self.model)
        else:
            traj, cstate = ctl.waypoints_to_controls(out.waypoints, obs.ego[0], cstate, self.controller)
            action = fuse_controls(traj, _require_controls(out, self.model), is_turning(steers))
            steers = jnp.concatenate([steers[1:], jnp.abs(action.steer).astype(jnp.float32)[None]])
        return action, PolicyState(history=hist, controller=cstate, fused_steers=steers)


def _require_controls(out: ModelOutput, model) -> Controls:
    if out.controls is None:
        raise ValueError(f"model {model.name!r} has no control head: use mode='traj'")
    return out.controls


def as_policy(model: Model, params_or_checkpoint, mode: Mode = "traj", **kwargs) -> ModelPolicy:
    """A ``Policy`` for ``model``.

    Args:
      model: a ``Model``.
      params_or_checkpoint: its parameters (None: a random init), or a
        checkpoint path (a run folder, its ``checkpoints/`` or one
        ``checkpoints/<epoch>``; ``train.checkpoint``).
      mode: "traj" -> Waypoints action (the simulator's PID + pure pursuit);
        "ctrl" -> the control head's Controls; "fused" -> TCP's blend of the
        two (``fuse_controls``).
      kwargs: ``ModelPolicy``'s controller, name, sensor_config.
    """
    params = params_or_checkpoint
    if isinstance(params, (str, bytes)) or hasattr(params, "__fspath__"):

        params = load_params(params_or_checkpoint)
    return ModelPolicy(model, params, mode, **kwargs)


def policy_from_checkpoint(model_name: str, checkpoint=None, mode: Mode = "traj", name: str | None = None,
                           **config) -> ModelPolicy:
    """The policy files' one loader: ``model_name`` driven in ``mode``.

    Args:
      model_name: registry name (``models.MODELS``).
      checkpoint: a run folder, its ``checkpoints/`` or one
        ``checkpoints/<epoch>``; None: a fresh random init (smoke tests).
        Its stored ``model`` must be ``model_name`` and its ``model_config``
        overrides ``config``; the BEV its training data was rendered at
        (``train.dataset.training_bev``) becomes the policy's
        ``sensor_config``, so evaluation renders the same BEV.
      mode, name: as ``ModelPolicy``.  config: ``make_model`` arguments.
    Raises DriveE2EError (one line) on a checkpoint of another model or
    training data whose BEV the model cannot read.
    """

    params, bev = None, None
    if checkpoint is not None:

        path = ckpt.resolve(checkpoint)
        meta = ckpt.read_meta(path)
        if meta.get("model", model_name) != model_name:
            raise DriveE2EError(f"{checkpoint}: a {meta['model']!r} checkpoint, expected a {model_name!r} one")
        config = {**config, **meta.get("model_config", {})}
        params = ckpt.restore(path)["params"]
        bev = training_bev(meta)
    return policy_from_params(model_name, params, mode, name, bev=bev, origin=str(checkpoint), **config)


def policy_from_params(model_name: str, params, mode: Mode = "traj", name: str | None = None, *,
                       bev=None, origin: str = "", **config) -> ModelPolicy:
    """``model_name`` built with ``config`` and driven in ``mode`` with
    ``params`` (None: a fresh random init); ``bev`` (the BEV its training data
    was rendered at, or None) becomes the policy's ``sensor_config`` after
    ``check_bev`` (errors name ``origin``). Shared by checkpoints
    (``policy_from_checkpoint``) and the zoo's bundled weights."""
    model = get_model(model_name, **config)
    sensor_config = None
    if bev is not None:
        check_bev(bev, model, f"{origin} (its training data)")
        sensor_config = SensorConfig(bev=bev)
    return ModelPolicy(model, params, mode, name=name, sensor_config=sensor_config)
