"""Host policies: the numpy side of the policy interface, in any framework.

A *host policy* runs outside the jitted rollout, on the whole batch at once,
on numpy arrays: wrap a PyTorch / ONNX / TensorFlow model (or a rule-based
agent) in a :class:`HostPolicy` and the simulator hands it one
:class:`Observation` per control step. The same object can be served from
another process, whose environment needs neither JAX nor Flax, with
``drivee2e serve-policy FILE --port N`` (``drivee2e_jax.remote``).

This module imports numpy only (no JAX, no Flax): the containers below mirror
``drivee2e_jax.types`` field for field (same names, same order, same nesting;
``tests/test_hostapi.py`` compares them recursively with the flax dataclasses
so they cannot drift), with one extra leading batch axis ``B`` on every leaf.
Shapes, dtypes and units are documented once, in ``drivee2e_jax/types.py``.

What is here:

* the containers :class:`Observation` (with :class:`Privileged`,
  :class:`EgoState`), :class:`Controls`, :class:`Waypoints`;
* :func:`from_fields` (any object with the right attribute names, e.g. a
  ``types.Observation`` of jax arrays after ``jax.device_get``, -> container),
  :func:`flatten` / :func:`unflatten` (container <-> ``[(path, array)]``);
* :func:`check_action` / :func:`check_act_result`: validate what a host
  policy returned, with one-line :class:`DriveE2EError` messages;
* :class:`HostPolicy` (the base class), :func:`describe`,
  :func:`validate_host_policy`, and :func:`load_host_policy` (a JAX-free
  loader of policy files).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import inspect
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any, Literal

import numpy as np

from drivee2e_jax.errors import DriveE2EError, one_line

ActionType = Literal["controls", "waypoints"]
ACTION_TYPES = ("controls", "waypoints")

# --------------------------------------------------------------------------
# Containers (numpy, leading batch axis B). Keep in step with types.py:
# tests/test_hostapi.py fails when a field is added, removed or renamed there.
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class EgoState:
    """``types.EgoState`` batched: xy (B, 2), yaw, speed, accel, steer,
    yaw_rate, t (B,), float32, SI units (m, rad, m/s, m/s^2, rad/s, s)."""

    xy: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    steer: np.ndarray
    yaw_rate: np.ndarray
    t: np.ndarray


@dataclasses.dataclass(frozen=True)
class Controls:
    """A controls action, ``types.Controls`` batched: one row per scenario.

    Attributes:
      throttle: (B,) float32 in [0, 1].
      brake:    (B,) float32 in [0, 1].
      steer:    (B,) float32 in [-1, 1]; +1 = full left (counter-clockwise).

    Values outside the ranges are clipped and NaN / inf are replaced by the
    simulator, which counts them as invalid actions (not an error here).
    """

    throttle: np.ndarray
    brake: np.ndarray
    steer: np.ndarray


@dataclasses.dataclass(frozen=True)
class Waypoints:
    """A trajectory action, ``types.Waypoints`` batched.

    Attributes:
      xy: (B, K, 2) float32 future ego positions in the CURRENT ego frame
          (x forward, y left, m), ``HostPolicy.waypoint_dt`` seconds apart
          (the first point is ``waypoint_dt`` after now). The simulator's PID
          + pure-pursuit controller turns them into controls.
    """

    xy: np.ndarray


@dataclasses.dataclass(frozen=True)
class Privileged:
    """``types.Privileged`` batched: ground truth a benchmark policy must not
    use (reference policies do): ego (EgoState), log_next_xy (B, 2),
    log_next_yaw (B,), log_valid (B,) bool, log_controls (Controls)."""

    ego: EgoState
    log_next_xy: np.ndarray
    log_next_yaw: np.ndarray
    log_valid: np.ndarray
    log_controls: Controls


@dataclasses.dataclass(frozen=True)
class Observation:
    """What a host policy sees each control step: ``types.Observation`` with a
    leading batch axis B on every array (row b = scenario b of the batch, in
    the order of the ``meta`` rows given to ``HostPolicy.reset``).

    Ego-frame vectors: x forward, y left, metres. Attributes (see types.py):

      ego:             (B, 4) float32 [speed m/s, accel m/s^2, yaw_rate rad/s, steer rad].
      gps:             (B, 2) float32 world position, m.
      compass:         (B,) float32 world heading, rad.
      route:           (B, P, 2) float32 next route points, ego frame, m.
      route_valid:     (B, P) bool.
      command:         (B,) int32 ``types.Command``.
      agents:          (B, K, 8) float32 x, y, cos dyaw, sin dyaw, vx, vy, length, width.
      agents_category: (B, K) int32 ``types.Category``.
      agents_valid:    (B, K) bool.
      lanes:           (B, M, Q, 2) float32 lane centrelines, ego frame, m.
      lanes_valid:     (B, M, Q) bool.
      signal_state:    (B,) int32 ``types.SignalState`` of the next stop line.
      signal_distance: (B,) float32 route distance to it, m (1e3 if none).
      speed_limit:     (B,) float32 m/s.
      privileged:      Privileged (ground truth; benchmark policies must not use it).
      bev:             (B, H, W) int32 bit-packed BEV channels, or None unless
                       ``"bev"`` is in ``required_sensors``.
      lidar:           (B, C, Z) float32 LiDAR range image, m, or None unless
                       ``"lidar"`` is in ``required_sensors``.
      sensors:         {name: array (B, ...)} of other enabled sensors, or None.
    """

    ego: np.ndarray
    gps: np.ndarray
    compass: np.ndarray
    route: np.ndarray
    route_valid: np.ndarray
    command: np.ndarray
    agents: np.ndarray
    agents_category: np.ndarray
    agents_valid: np.ndarray
    lanes: np.ndarray
    lanes_valid: np.ndarray
    signal_state: np.ndarray
    signal_distance: np.ndarray
    speed_limit: np.ndarray
    privileged: Privileged
    bev: np.ndarray | None = None
    lidar: np.ndarray | None = None
    sensors: dict | None = None

    @property
    def batch_size(self) -> int:
        """B: the leading axis of the first field that holds an array (a
        field the policy does not observe is None: ``observation_fields``
        may leave out ``ego``)."""
        return batch_size(self)


#: Fields holding a nested container, per container class.
_NESTED: dict[type, dict[str, type]] = {
    Observation: {"privileged": Privileged},
    Privileged: {"ego": EgoState, "log_controls": Controls},
}
#: Fields that may be None.
_OPTIONAL: dict[type, frozenset[str]] = {Observation: frozenset({"bev", "lidar", "sensors"})}
#: Fields holding a {name: array-or-dict} mapping.
_MAPPINGS: dict[type, frozenset[str]] = {Observation: frozenset({"sensors"})}

CONTAINERS = (Observation, Privileged, EgoState, Controls, Waypoints)


def field_names(cls: type) -> tuple[str, ...]:
    """The field names of a container class, in order."""
    return tuple(f.name for f in dataclasses.fields(cls))


# --------------------------------------------------------------------------
# Conversion (numpy + duck typing: works on jax arrays, torch CPU tensors ...)
# --------------------------------------------------------------------------


def _as_array(value: Any, what: str) -> np.ndarray:
    try:
        array = np.asarray(value)
    except Exception as e:  # noqa: BLE001 - a user's object: report it in one line
        raise DriveE2EError(f"{what}: cannot be converted to a numpy array ({type(value).__name__}: "
                            f"{type(e).__name__}: {e})") from e
    # a policy may write into it (torch.from_numpy warns on read-only arrays; callbacks hand those over)
    return array if array.flags.writeable else array.copy()


def _mapping_from(value: Mapping, what: str) -> dict:
    return {str(k): _mapping_from(v, f"{what}[{k!r}]") if isinstance(v, Mapping) else _as_array(v, f"{what}[{k!r}]")
            for k, v in value.items()}


def from_fields(obj: Any, cls: type = Observation):
    """A host container of class ``cls`` from any object with the same
    attribute names (recursively): a ``types.Observation`` of jax or numpy
    arrays, another host container, a ``SimpleNamespace`` ...; every leaf goes
    through ``np.asarray``. (For jax arrays, ``jax.device_get`` the whole tree
    first: one device->host transfer instead of one per leaf.)

    Raises DriveE2EError naming the first missing attribute.
    """
    kwargs = {}
    for name in field_names(cls):
        what = f"{cls.__name__}.{name}"
        if not hasattr(obj, name):
            if name in _OPTIONAL.get(cls, ()):
                kwargs[name] = None
                continue
            raise DriveE2EError(f"{type(obj).__name__} has no field {name!r} (expected the fields of "
                                f"{cls.__name__}: {', '.join(field_names(cls))})")
        value = getattr(obj, name)
        # optional, or a top-level observation field left out by HostPolicy.observation_fields
        if value is None and (name in _OPTIONAL.get(cls, ()) or cls is Observation):
            kwargs[name] = None
        elif name in _NESTED.get(cls, {}):
            kwargs[name] = from_fields(value, _NESTED[cls][name])
        elif name in _MAPPINGS.get(cls, ()):
            if not isinstance(value, Mapping):
                raise DriveE2EError(f"{what}: expected a dict {{name: array}} or None, got {type(value).__name__}")
            kwargs[name] = _mapping_from(value, what)
        else:
            kwargs[name] = _as_array(value, what)
    return cls(**kwargs)


def batch_size(obs: Any, default: int | None = None) -> int:
    """B of a batched host container: the leading axis of its first array
    leaf of rank >= 1, whichever fields it holds; ``default`` when it holds
    none (an error without one)."""
    for _, leaf in flatten(obs):
        if leaf.ndim >= 1:
            return int(leaf.shape[0])
    if default is None:
        raise DriveE2EError("the observation holds no array to take the batch size from "
                            "(observation_fields selected nothing)")
    return int(default)


def flatten(container: Any) -> list[tuple[tuple[str, ...], np.ndarray]]:
    """``[(path, array)]`` of a container's leaves in field order; ``None``
    fields are left out; a mapping field contributes ``(field, key, ...)``
    paths. :func:`unflatten` inverts it."""
    out: list[tuple[tuple[str, ...], np.ndarray]] = []

    def walk(prefix: tuple[str, ...], value: Any) -> None:
        if value is None:
            return
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            for name in field_names(type(value)):
                walk((*prefix, name), getattr(value, name))
        elif isinstance(value, Mapping):
            for k, v in value.items():
                walk((*prefix, str(k)), v)
        else:
            out.append((prefix, np.asarray(value)))

    walk((), container)
    return out


def unflatten(cls: type, items: Sequence[tuple[Sequence[str], np.ndarray]]):
    """Rebuild a container of class ``cls`` from :func:`flatten`'s pairs.

    Raises DriveE2EError on a missing required field or an unknown path."""
    tree: dict = {}
    for path, arr in items:
        node = tree
        for p in path[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise DriveE2EError(f"{cls.__name__}: path {'.'.join(path)} clashes with a leaf")
        node[path[-1]] = arr

    def build(c: type, d: dict, prefix: str):
        names = field_names(c)
        unknown = sorted(set(d) - set(names))
        if unknown:
            raise DriveE2EError(f"{c.__name__}: unknown field(s) {', '.join(prefix + u for u in unknown)} "
                                f"(expected {', '.join(names)})")
        kwargs = {}
        for name in names:
            if name not in d:
                # optional, or a top-level observation field left out by HostPolicy.observation_fields
                if name in _OPTIONAL.get(c, ()) or c is Observation:
                    kwargs[name] = None
                    continue
                raise DriveE2EError(f"{c.__name__}: missing field {prefix}{name}")
            v = d[name]
            if name in _NESTED.get(c, {}):
                if not isinstance(v, dict):
                    raise DriveE2EError(f"{c.__name__}: {prefix}{name} must be a {_NESTED[c][name].__name__}")
                kwargs[name] = build(_NESTED[c][name], v, f"{prefix}{name}.")
            else:
                kwargs[name] = v
        return c(**kwargs)

    return build(cls, tree, "")


# --------------------------------------------------------------------------
# Validating actions
# --------------------------------------------------------------------------

#: Per-scenario shape of each action leaf (None = any length on that axis).
_ACTION_SHAPES: dict[type, dict[str, tuple[int | None, ...]]] = {
    Controls: {"throttle": (), "brake": (), "steer": ()},
    Waypoints: {"xy": (None, 2)},
}


def _describe_value(value: Any) -> str:
    if isinstance(value, Mapping):
        keys = ", ".join(map(str, list(value)[:6]))
        return f"a dict with keys [{keys}]"
    if isinstance(value, tuple | list):
        return f"a {type(value).__name__} of {len(value)} item(s)"
    if value is None:
        return "None"
    return f"a {type(value).__module__}.{type(value).__qualname__}"


def _fmt_shape(shape: tuple) -> str:
    return "(" + ", ".join("K" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"


def check_action(action: Any, action_type: str, batch: int, where: str, *,
                 num_waypoints: int | None = None) -> Controls | Waypoints:
    """Validate a host policy's action for a batch of ``batch`` scenarios.

    ``action`` is a :class:`Controls` / :class:`Waypoints` (or any object with
    the same attribute names, e.g. the flax ``types`` classes; leaves may be
    numpy arrays, jax arrays, CPU torch tensors, lists of numbers ...). Returns
    a new container of C-contiguous float32 numpy arrays.

    Raises :class:`DriveE2EError`, one line starting with ``where`` (e.g.
    ``"my_torch.py, step 12"``), naming the field and the expected
    vs the received shape/dtype, when the action is of the wrong kind (a dict,
    a tuple, Controls for a waypoint policy ...), a leaf is not numeric
    (strings, objects, complex, bool), has the wrong shape or the wrong batch
    size, or ``num_waypoints`` is given and differs. NaN / inf are NOT errors:
    the simulator counts and sanitises invalid actions.
    """
    if action_type not in ACTION_TYPES:
        raise DriveE2EError(f"{where}: action_type is {action_type!r}, expected 'controls' or 'waypoints'")
    cls = Controls if action_type == "controls" else Waypoints
    fields = _ACTION_SHAPES[cls]
    sig = f"{cls.__name__}({', '.join(fields)})"
    if isinstance(action, Mapping) or not all(hasattr(action, f) for f in fields):
        other = Waypoints if cls is Controls else Controls
        hint = ""
        if not isinstance(action, Mapping) and all(hasattr(action, f) for f in _ACTION_SHAPES[other]):
            hint = f" (a {other.__name__} action, but the policy's action_type is {action_type!r})"
        elif isinstance(action, Mapping):
            hint = f" (build drivee2e_jax.hostapi.{cls.__name__}(**d) from the dict)"
        raise DriveE2EError(f"{where}: the action is {_describe_value(action)}, expected "
                            f"drivee2e_jax.hostapi.{sig} with a leading batch axis B={batch}{hint}")
    out = {}
    for name, tail in fields.items():
        what = f"{where}: action {cls.__name__}.{name}"
        value = getattr(action, name)
        expected = _fmt_shape((batch, *tail))
        if value is None or isinstance(value, str | bytes | Mapping):
            raise DriveE2EError(f"{what} is {_describe_value(value)}, expected a float32 array of shape {expected}")
        try:
            arr = np.asarray(value)
        except Exception as e:  # noqa: BLE001 - e.g. a CUDA tensor, a tensor requiring grad
            raise DriveE2EError(f"{what}: a {type(value).__name__} that numpy cannot read "
                                f"({type(e).__name__}: {one_line(e)}), expected a float32 array of "
                                f"shape {expected} (for torch: tensor.detach().cpu().numpy())") from e
        if arr.dtype.kind not in "fiu":
            raise DriveE2EError(f"{what} has dtype {arr.dtype} ({_describe_value(value)}), expected a float32 "
                                f"array of shape {expected}")
        if arr.ndim != 1 + len(tail):
            raise DriveE2EError(f"{what} has shape {_fmt_shape(arr.shape)}, expected {expected} "
                                f"(batch B={batch}{', K waypoints' if None in tail else ''}) float32")
        if arr.shape[0] != batch:
            raise DriveE2EError(f"{what} has batch size {arr.shape[0]} (shape {_fmt_shape(arr.shape)}), expected "
                                f"{batch}: one row per scenario, shape {expected}")
        for axis, (want, got) in enumerate(zip(tail, arr.shape[1:]), start=1):
            if want is None:
                if num_waypoints is not None and got != num_waypoints:
                    raise DriveE2EError(f"{what} has {got} waypoints (shape {_fmt_shape(arr.shape)}), expected "
                                        f"num_waypoints={num_waypoints}: shape {_fmt_shape((batch, num_waypoints, *tail[axis:]))}")
                if got < 1:
                    raise DriveE2EError(f"{what} has no waypoints (shape {_fmt_shape(arr.shape)}), expected {expected} with K >= 1")
            elif got != want:
                raise DriveE2EError(f"{what} has shape {_fmt_shape(arr.shape)}, expected {expected} float32")
        out[name] = np.ascontiguousarray(arr, dtype=np.float32)
    return cls(**out)


def check_act_result(result: Any, where: str) -> tuple[Any, Any]:
    """``HostPolicy.act`` must return ``(action, state)``; DriveE2EError
    (one line, starting with ``where``) otherwise."""
    if not isinstance(result, tuple) or len(result) != 2:
        raise DriveE2EError(f"{where}: act(obs, state) returned {_describe_value(result)}, expected a pair "
                            f"(action, state)")
    return result


# --------------------------------------------------------------------------
# The base class
# --------------------------------------------------------------------------


class HostPolicy:
    """Base class of a host policy: any framework, whole batch, numpy in/out.

    Subclass it, set the attributes, implement :meth:`act` (and :meth:`reset`
    when the policy keeps state)::

        class MyTorchPolicy(HostPolicy):
            name = "my_torch"
            action_type = "waypoints"
            waypoint_dt = 0.5
            num_waypoints = 4

            def reset(self, meta):
                return {"history": None}

            def act(self, obs, state):
                with torch.no_grad():
                    xy = self.net(torch.from_numpy(obs.route))  # (B, 4, 2)
                return Waypoints(xy=xy.cpu().numpy()), state

        policy = MyTorchPolicy()          # or: def make_policy(**kwargs): ...

    Attributes:
      name:             short name used in result tables.
      action_type:      ``"controls"`` (act returns :class:`Controls`) or
                        ``"waypoints"`` (act returns :class:`Waypoints`).
      waypoint_dt:      time between waypoints, s (waypoints only; default 0.5).
      num_waypoints:    K, the number of waypoints act returns (waypoints
                        only); None = not declared (any K >= 1 is accepted).
      required_sensors: optional sensors the observation must carry, e.g.
                        ``("bev",)`` or ``("lidar",)`` (default none: those
                        slots are None).
      observation_fields: the top-level ``Observation`` fields ``act`` reads,
                        e.g. ``("ego", "route", "route_valid")``; the others
                        arrive as None and the simulator does not compute
                        them (lanes and agents are most of a step's cost).
                        None (default) = every field.

    Lifecycle, per batch of B scenarios (the simulator runs a split in one or
    more batches): ``state = reset(meta)`` once, then every control step
    ``action, state = act(obs, state)`` with an :class:`Observation` of the
    whole batch. All scenarios of a batch step together; a scenario that has
    ended keeps receiving observations (its actions are ignored). ``close()``
    is called when the policy is no longer needed (e.g. the server stops).

    The policy must not keep per-batch data on ``self``: keep it in ``state``
    (any Python object; it never leaves the policy's process), so one policy
    object can serve several batches or clients.
    """

    name: str = "host_policy"
    action_type: ActionType = "controls"
    waypoint_dt: float = 0.5
    num_waypoints: int | None = None
    required_sensors: tuple[str, ...] = ()
    observation_fields: tuple[str, ...] | None = None

    def reset(self, meta: list[dict]) -> Any:
        """Start a batch; returns the initial policy state (default None).

        ``meta`` has one dict per scenario, in batch-row order (the 1-D
        columns of ``scenario.SuiteMeta.rows()``): ``scenario_id``,
        ``split``, ``intersection_id``, ``map_id``, ``behavior`` (one of COV,
        IPC, UT, YLW, STR, LFT, RT, STP), ``weather``, ``time_of_day`` (str),
        ``ego_track_id``, ``index`` (row in the suite's meta table),
        ``num_agents``, ``num_steps`` (int), ``dt`` (float, log step in s).
        A benchmark policy should not condition on it (it is for logging and
        per-scenario bookkeeping); treat unknown keys as optional.
        """
        return None

    def act(self, obs: Observation, state: Any) -> tuple[Controls | Waypoints, Any]:
        """One control step for the whole batch: ``obs`` (:class:`Observation`,
        leading axis B) -> ``(action, new_state)``, the action a
        :class:`Controls` with (B,) leaves or a :class:`Waypoints` with xy
        (B, K, 2), float32 (numpy, or anything ``np.asarray`` reads)."""
        raise NotImplementedError(f"{type(self).__name__}.act(obs, state) is not implemented")

    def close(self) -> None:
        """Release resources (GPU memory, files); default: nothing."""


def describe(policy: HostPolicy) -> dict:
    """The policy's declared interface, as plain JSON-able values (what the
    remote handshake reports): name, action_type, waypoint_dt, num_waypoints,
    required_sensors."""
    nw = getattr(policy, "num_waypoints", None)
    return {
        "name": str(policy.name),
        "action_type": str(policy.action_type),
        "waypoint_dt": float(getattr(policy, "waypoint_dt", 0.5)),
        "num_waypoints": None if nw is None else int(nw),
        "required_sensors": [str(s) for s in getattr(policy, "required_sensors", ()) or ()],
        "observation_fields": (None if getattr(policy, "observation_fields", None) is None
                               else [str(f) for f in policy.observation_fields]),
    }


def validate_host_policy(policy: Any, where: str) -> HostPolicy:
    """Check a host policy's declared attributes; DriveE2EError (one line,
    starting with ``where``) when something is off. Returns the policy."""
    if not isinstance(policy, HostPolicy):
        kind = ("a JAX policy (init / initial_state / act), which runs in-process only"
                if all(hasattr(policy, m) for m in ("init", "initial_state", "act")) else _describe_value(policy))
        raise DriveE2EError(f"{where}: the policy is {kind}, expected a drivee2e_jax.hostapi.HostPolicy subclass instance")
    if policy.action_type not in ACTION_TYPES:
        raise DriveE2EError(f"{where}: action_type is {policy.action_type!r}, expected 'controls' or 'waypoints'")
    if not isinstance(policy.name, str) or not policy.name:
        raise DriveE2EError(f"{where}: name is {policy.name!r}, expected a non-empty string")
    rs = policy.required_sensors
    if isinstance(rs, str) or not isinstance(rs, tuple | list) or not all(isinstance(s, str) for s in rs):
        raise DriveE2EError(f"{where}: required_sensors is {rs!r}, expected a tuple of sensor names, e.g. ('bev',)")
    if policy.action_type == "waypoints":
        dt = policy.waypoint_dt
        if isinstance(dt, bool) or not isinstance(dt, int | float) or not dt > 0:
            raise DriveE2EError(f"{where}: waypoint_dt is {dt!r}, expected a positive number of seconds")
        nw = policy.num_waypoints
        if nw is not None and (isinstance(nw, bool) or not isinstance(nw, int) or nw < 1):
            raise DriveE2EError(f"{where}: num_waypoints is {nw!r}, expected a positive int or None")
    fields = getattr(policy, "observation_fields", None)
    if fields is not None:
        known = field_names(Observation)
        if isinstance(fields, str) or not isinstance(fields, tuple | list) or not all(f in known for f in fields):
            raise DriveE2EError(f"{where}: observation_fields is {fields!r}, expected None or a tuple of "
                                f"Observation fields: {', '.join(known)}")
    return policy


# --------------------------------------------------------------------------
# Loading a policy file without JAX
# --------------------------------------------------------------------------


def import_file(path: str | Path, what: str = "policy") -> ModuleType:
    """Import a user's Python file as a fresh module (no JAX imported here);
    DriveE2EError (one line naming the file) when it is missing or fails to
    import. ``what`` names the file's role in messages."""
    p = Path(path)
    if not p.is_file():
        hint = " (expected a .py file defining `policy` or `make_policy`)" if what == "policy" else ""
        raise DriveE2EError(f"{path}: {what} file not found{hint}")
    mod_name = f"drivee2e_{what}_{p.stem}_{abs(hash(str(p.resolve())))}"
    spec = importlib.util.spec_from_file_location(mod_name, p)
    if spec is None or spec.loader is None:
        raise DriveE2EError(f"{path}: cannot be imported as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as e:  # a user's file: report, don't crash
        sys.modules.pop(mod_name, None)
        raise DriveE2EError(f"{path}: importing the {what} failed: {type(e).__name__}: {e}") from e
    return module


def load_policy_object(path: str | Path, **kwargs) -> Any:
    """Import a policy file and return its ``policy`` object, or the result of
    ``make_policy(**kwargs)``; checks nothing about the object. Imports no JAX
    itself (the file may). DriveE2EError (one line) when the file is missing,
    fails to import, or defines neither name, or kwargs don't fit."""
    module = import_file(path, "policy")
    if hasattr(module, "make_policy"):
        try:
            inspect.signature(module.make_policy).bind(**kwargs)
        except TypeError as e:
            raise DriveE2EError(f"{path}: make_policy does not take {sorted(kwargs)}: {e}") from e
        try:
            return module.make_policy(**kwargs)
        except DriveE2EError:
            raise
        except Exception as e:  # noqa: BLE001 - a user's factory
            raise DriveE2EError(f"{path}: make_policy({', '.join(sorted(kwargs))}) failed: {type(e).__name__}: {e}") from e
    if kwargs:
        raise DriveE2EError(f"{path}: arguments {sorted(kwargs)} given, but the file defines no make_policy(**kwargs)")
    if hasattr(module, "policy"):
        return module.policy
    raise DriveE2EError(f"{path}: defines neither `policy` nor `make_policy()` (expected one of them)")


def load_host_policy(path: str | Path, **kwargs) -> HostPolicy:
    """Load a :class:`HostPolicy` from a policy file (``policy`` or
    ``make_policy(**kwargs)``) without importing JAX; DriveE2EError (one line)
    when the file cannot be loaded or the object is not a valid HostPolicy."""
    return validate_host_policy(load_policy_object(path, **kwargs), str(path))
