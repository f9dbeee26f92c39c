"""Host policies in the rollout: one host call per control step for the whole batch.

A :class:`~drivee2e_jax.hostapi.HostPolicy` (PyTorch, ONNX, numpy, a remote
server...) runs outside JAX. :func:`wrap` turns it into a :class:`HostBridge`,
which ``rollout.Rollout`` drives as compiled segments around the host call:
per step a compiled observation of all B scenarios (only the fields the
policy declares), ``HostBridge._host_act`` on it (numpy, leading batch axis),
then the compiled step with the returned actions (the next control step's
observation comes out of the same program). Everything else -- chunking,
early stop, ``control_every`` / latency, scoring, results, resume,
``--repetitions``, ``view`` / ``export-mcap`` -- is the path a JAX policy
takes, with the same keys and steps.

Why segments and not a ``jax.pure_callback`` inside the compiled scan: JAX's
persistent compilation cache never stores a program that holds a host
callback, so every process compiled the whole rollout again (16-26 s before a
host policy's first step); the segments hold no callback and come from the
cache in the next process. ``HostBridge.act`` is still the callback, for the
open-loop runner (``eval.openloop``) and for shaping the action
(``jax.eval_shape``). ``docs/performance.md``, "Host policies", has both
measured.

The policy's state lives on the host (``HostPolicy.reset(meta)`` /
``act(obs, state)``); the JAX-side policy state is the control-step counter.
The host calls run in order, exactly once per control step.

Errors inside the host policy (an exception, a wrong action type, shape or
dtype) are caught in ``_host_act``: the failing step returns a full brake for
every scenario, later steps are skipped, and :func:`raise_if_failed` (called
by the drivers after every chunk) raises one line naming the policy
file, the control step and what was expected. NaN / inf actions are not
errors: the simulator counts and sanitises them as for JAX policies.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import hostapi
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.policy import raised_text
from drivee2e_jax.types import Controls, Waypoints

#: Top-level observation fields (``types.Observation``; the host containers mirror them).
OBS_FIELDS = hostapi.field_names(hostapi.Observation)
#: Fields that hold the optional sensors (None unless ``required_sensors`` turns them on).
SENSOR_FIELDS = frozenset({"bev", "lidar", "sensors"})


class HostBridge:
    """A ``HostPolicy`` seen as a JAX ``policy.Policy`` (see the module docstring).

    Attributes:
      host: the wrapped ``HostPolicy``.  source: what messages name (its file).
      name / action_type / waypoint_dt / required_sensors / sensor_config: the host policy's.
      num_waypoints: K of a waypoint policy (declared, or probed on the first batch).
      observation_fields: the fields the host policy reads (None = all): the
        others are None in what it receives, so XLA never computes them.
      step: control steps called since ``begin``.  failure: the one-line error, or None;
      failure_cause: the exception behind it (the policy's own traceback, which
        ``raise_if_failed`` chains for ``--debug``), or None.
    """

    is_host_policy = True

    def __init__(self, host: hostapi.HostPolicy, source: str | None = None):
        self.host = host
        self.source = source or getattr(host, "source", None) or f"host policy {host.name!r}"
        self.name = host.name
        self.action_type = host.action_type
        self.waypoint_dt = float(getattr(host, "waypoint_dt", 0.5))
        self.required_sensors = tuple(getattr(host, "required_sensors", ()) or ())
        self.sensor_config = getattr(host, "sensor_config", None)
        self.num_waypoints = getattr(host, "num_waypoints", None)
        fields = getattr(host, "observation_fields", None)
        self.observation_fields = None if fields is None else tuple(fields)
        self.batch = None
        self.state = None
        self.step = 0
        self.failure: str | None = None
        self.failure_cause: BaseException | None = None

    # host side ---------------------------------------------------------------
    def begin(self, meta_rows: list[dict]) -> None:
        """Start a batch: ``host.reset(meta_rows)`` (one dict per scenario, in batch order)."""
        self.batch = len(meta_rows)
        self.step = 0
        self.failure = None
        self.failure_cause = None
        try:
            self.state = self.host.reset(list(meta_rows))
        except DriveE2EError:
            raise
        except (Exception, SystemExit) as e:  # a user's policy: one line, not a traceback
            raise DriveE2EError(f"{self.source}: reset(meta) {raised_text(e, self.source)}") from e

    def _host_act(self, obs) -> Controls | Waypoints:
        """The callback: (B, ...) numpy observation -> (B, ...) numpy action."""
        b = hostapi.batch_size(obs, self.batch)
        if self.failure is None:
            where = f"{self.source}, step {self.step}"
            try:
                result = hostapi.check_act_result(self.host.act(hostapi.from_fields(obs), self.state), where)
                action = hostapi.check_action(result[0], self.action_type, b, where, num_waypoints=self.num_waypoints)
                self.state = result[1]
                self.step += 1
                return _to_types(action)
            except DriveE2EError as e:
                self.failure, self.failure_cause = e.message, e
            except (Exception, SystemExit) as e:  # noqa: BLE001 - any error of a user's policy becomes one line
                self.failure, self.failure_cause = f"{where}: act {raised_text(e, self.source)}", e
        return _brake(self.action_type, b, self.num_waypoints)

    def probe_num_waypoints(self, obs_batch) -> int:
        """K of a waypoint policy that did not declare ``num_waypoints``: one
        ``act`` on a throwaway state (``reset`` again afterwards)."""
        where = f"{self.source}, probing the number of waypoints"
        try:
            out = self.host.act(hostapi.from_fields(obs_batch), self.state)
        except DriveE2EError:
            raise
        except (Exception, SystemExit) as e:  # a user's policy: one line, not a traceback
            raise DriveE2EError(f"{where}: act {raised_text(e, self.source)}") from e
        result = hostapi.check_act_result(out, where)
        action = hostapi.check_action(result[0], "waypoints", hostapi.batch_size(obs_batch, self.batch), where)
        return int(action.xy.shape[1])

    # JAX side ----------------------------------------------------------------
    def init(self, key, obs):
        return None

    def initial_state(self, obs):
        return jnp.zeros((), jnp.int32)

    def act(self, params, obs, policy_state, key):
        shapes = _action_shapes(self.action_type, self.num_waypoints)
        obs = observed(obs, self.observation_fields)  # only what the policy reads is computed and sent
        action = jax.pure_callback(self._host_act, shapes, obs, vmap_method="expand_dims")
        return action, policy_state + 1


def observed(obs, observation_fields):
    """``obs`` (a ``types.Observation``) with the fields a host policy does not
    read set to None: ``observation_fields`` (None: all) plus the sensor fields
    (computed as ``required_sensors`` says). What the bridge sends and what
    ``check-policy`` shows the policy."""
    if observation_fields is None:
        return obs
    keep = set(observation_fields) | SENSOR_FIELDS
    return obs.replace(**{f: None for f in OBS_FIELDS if f not in keep})


def is_host(policy) -> bool:
    """Whether ``policy`` is a host policy (raw or already wrapped)."""
    return isinstance(policy, (hostapi.HostPolicy, HostBridge))


def wrap(policy, source: str | None = None):
    """``policy`` as a JAX policy: host policies get a :class:`HostBridge`,
    anything else is returned unchanged."""
    if isinstance(policy, hostapi.HostPolicy):
        return HostBridge(policy, source)
    return policy


def begin(policy, meta, scenario, first_obs=None) -> None:
    """Start a batch of a (wrapped) host policy; a no-op for JAX policies.

    ``meta``: the batch's ``SuiteMeta`` and ``scenario`` its ``Scenario``
    batch, turned into ``reset``'s rows (``meta_rows``) only for a host policy.
    ``first_obs()``: the first scenario's initial observation with a batch
    axis of 1, called only to probe the number of waypoints of a waypoint
    policy that does not declare ``num_waypoints`` (one ``act`` on a
    one-scenario batch, then ``reset`` for the real one)."""
    if not isinstance(policy, HostBridge):
        return
    rows = meta_rows(policy, meta, scenario)
    if policy.action_type == "waypoints" and policy.num_waypoints is None:
        if first_obs is None:
            raise DriveE2EError(f"{policy.source}: a waypoint host policy must declare num_waypoints")
        policy.begin(rows[:1])
        policy.num_waypoints = policy.probe_num_waypoints(jax.device_get(first_obs()))
    policy.begin(rows)


def meta_rows(policy, meta, scenario) -> list[dict]:
    """``meta.rows()`` for ``HostBridge.begin``; for a host policy with ``wants_route =
    True`` (CARLA-style agents, ``carla_agent``) each row also gets the
    scenario's whole route: ``route_xy`` ([[x, y], ...] world m, 1 m apart)
    and ``route_command`` ([int ``types.Command``]), its valid prefix."""
    rows = meta.rows()
    if getattr(getattr(policy, "host", policy), "wants_route", False):
        route = jax.device_get(scenario.route)
        xy, cmd, valid = np.asarray(route.xy), np.asarray(route.command), np.asarray(route.valid)
        for b, row in enumerate(rows):
            n = int(valid[b].sum())
            row["route_xy"], row["route_command"] = xy[b, :n].tolist(), cmd[b, :n].tolist()
    return rows


def raise_if_failed(policy) -> None:
    """Raise the host policy's one-line error, if its ``act`` failed, from
    the exception the policy raised (``--debug`` shows the policy's frames)."""
    if isinstance(policy, HostBridge) and policy.failure is not None:
        raise DriveE2EError(policy.failure) from policy.failure_cause


def _action_shapes(action_type: str, num_waypoints: int | None):
    """Per-scenario ``ShapeDtypeStruct`` pytree of the action (vmap adds B)."""
    f32 = jnp.float32
    if action_type == "controls":
        s = jax.ShapeDtypeStruct((), f32)
        return Controls(throttle=s, brake=s, steer=s)
    if num_waypoints is None:
        raise DriveE2EError("a waypoint host policy must declare num_waypoints (or be started with hostbridge.begin)")
    return Waypoints(xy=jax.ShapeDtypeStruct((int(num_waypoints), 2), f32))


def _to_types(action) -> Controls | Waypoints:
    """A checked ``hostapi`` action as the ``types`` pytree the callback returns."""
    if isinstance(action, hostapi.Controls):
        return Controls(throttle=action.throttle, brake=action.brake, steer=action.steer)
    return Waypoints(xy=action.xy)


def _brake(action_type: str, b: int, num_waypoints: int | None) -> Controls | Waypoints:
    """Full brake for every scenario (after a failure): zero throttle/steer,
    or waypoints all at the ego (stand still)."""
    if action_type == "controls":
        z = np.zeros((b,), np.float32)
        return Controls(throttle=z, brake=np.ones((b,), np.float32), steer=z)
    return Waypoints(xy=np.zeros((b, int(num_waypoints or 1), 2), np.float32))
