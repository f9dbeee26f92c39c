"""Policy conformance: does a policy object keep the contract the rollout relies on?

``check_policy(policy)`` runs a policy on a few real observations (the first
``batch`` scenarios of a small suite, observed at a few instants along their
logs) and returns a :class:`Report`: a list of :class:`Problem`, each ONE line
that names the policy's file and what was expected. An empty report means
conformant; ``report.summary`` then says what was found (action type and
shapes, state leaves, sensors). ``check_policy_file(path)`` loads a policy
file first; ``drivee2e check-policy FILE`` prints either.
``checked_params`` / ``check_traceable`` are the cheap subset ``evaluate``
runs before compiling a rollout (``jax.eval_shape`` of ``initial_state`` and
``act`` on one observation): the first problem as one DriveE2EError line.

What is checked:

* declared attributes (both kinds): ``name`` a non-empty string,
  ``action_type`` "controls" or "waypoints", for waypoint policies
  ``waypoint_dt`` > 0 and ``num_waypoints`` (when declared) a positive int,
  ``required_sensors`` names of registered sensors (``observe.registry``).
* JAX policies (``policy.Policy``): ``init`` and ``initial_state`` run on a
  real observation; ``act`` returns a pair ``(action, state)``; the action is
  the declared ``types.Controls`` (three float32 scalars) or
  ``types.Waypoints`` (xy (K, 2) float32, K = ``num_waypoints`` when
  declared); the state keeps its tree structure, shapes and dtypes from step
  to step (``lax.scan`` carries it); the actions are finite; two calls with
  the same inputs and key agree; ``jax.jit(act)`` traces (no Python ``if``
  on an array) and agrees with the eager call; ``jax.vmap(act)`` over the
  batch agrees with per-scenario calls.
* host policies (``hostapi.HostPolicy``): ``reset(meta)`` and ``act(obs,
  state)`` on a real batch observation run without raising; the action passes
  ``hostapi.check_action`` (kind, shapes, batch size, numeric); the state comes
  back; the actions are finite; two fresh ``reset`` + ``act`` on the same
  input give equal actions.

A check that makes the later ones meaningless when it fails (``act`` raising,
an action of the wrong kind or shape, a state that changes structure) ends
the run; the others all report.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax
import numpy as np

from drivee2e_jax import hostapi, hostbridge
from drivee2e_jax.errors import DriveE2EError, one_line
from drivee2e_jax.observe import registry
from drivee2e_jax.observe.sensors import SensorConfig, assets_axes, build_assets
from drivee2e_jax.policy import load_policy, parse_policy_spec, raised_text, user_frame
from drivee2e_jax.remote import is_remote_spec
from drivee2e_jax.scenario import Suite, load_suite
from drivee2e_jax.scenario.suite import EXAMPLE_SUITES
from drivee2e_jax.sim import SimConfig, Simulator
from drivee2e_jax.types import Controls, Waypoints

__all__ = ["Problem", "Report", "check_policy", "check_policy_file", "check_initial_state", "check_traceable", "checked_params",
           "DEFAULT_SUITE", "TINY_SUITE"]

#: ``suite="tiny"``: the repository's four-scenario example suite.
TINY_SUITE = EXAMPLE_SUITES["tiny"]
DEFAULT_SUITE = "tiny"
#: Observations per scenario (consecutive ``act`` calls: a policy's warm-up,
#: history buffer or first action chunk fails within them), and simulator steps
#: (along the log) between them.
DEFAULT_STEPS = 10
STEP_STRIDE = 5
#: Tolerance of the jit / vmap comparisons: XLA fuses float ops differently
#: from eager dispatch, and GPUs multiply float32 matrices in TF32 (~1e-3).
RTOL, ATOL = 2e-3, 1e-4
#: Tolerance of "the same call twice" (GPU reductions may use atomics: ulps).
SAME_RTOL, SAME_ATOL = 1e-5, 1e-6
#: Longest problem line (a JAX error can run to pages).
MAX_LINE = 400

_FIELDS = {"controls": (Controls, {"throttle": (), "brake": (), "steer": ()}),
           "waypoints": (Waypoints, {"xy": (None, 2)})}


@dataclasses.dataclass(frozen=True)
class Problem:
    """One way a policy breaks the contract.

    Attributes:
      check:   which check found it: attributes, init, initial_state, act,
               action, state, finite, determinism, jit, vmap, reset.
      message: one line, starting with the policy's file, saying what was expected.
    """

    check: str
    message: str
    #: The exception behind the problem, if any (the policy's own traceback, which
    #: ``checked_params`` chains for ``--debug``); not part of equality.
    cause: BaseException | None = dataclasses.field(default=None, compare=False, repr=False)

    def __str__(self) -> str:
        return self.message


class Report(list):
    """The problems :func:`check_policy` found (a ``list[Problem]``; empty:
    conformant), plus ``source`` (what the messages name) and ``summary``
    (one line: kind, action type and shapes, state, sensors, what ran)."""

    def __init__(self, source: str):
        super().__init__()
        self.source = source
        self.summary = ""

    @property
    def ok(self) -> bool:
        return not self

    def add(self, check: str, text: str, cause: BaseException | None = None) -> None:
        """Record ``"<source>: <text>"`` (``cause``: the exception behind it)."""
        self.add_line(check, f"{self.source}: {text}", cause)

    def add_line(self, check: str, line: str, cause: BaseException | None = None) -> None:
        self.append(Problem(check, _one_line(line), cause))

    def __repr__(self) -> str:
        return f"Report({self.source!r}, {list.__repr__(self)})"


# --------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------


def check_policy(policy: Any, *, source: str | None = None, suite: str | Path | Suite = DEFAULT_SUITE,
                 batch: int = 4, steps: int = DEFAULT_STEPS, seed: int = 0) -> Report:
    """Check a policy object (a JAX ``policy.Policy`` or a
    ``hostapi.HostPolicy``) on real observations; loads no policy itself.

    Args:
      policy: the object (a ``hostbridge.HostBridge`` is unwrapped).
      source: what the messages name (default: ``policy.source``, else its name).
      suite: ``"tiny"`` (``TINY_SUITE``), a built-in suite name (``"twin15"``),
        a suite folder or a ``scenario.Suite``; its first ``batch`` scenarios
        (all splits) are observed ``steps`` times, ``STEP_STRIDE`` simulator
        steps apart along their logs.
      seed: PRNG seed of the policy's keys.

    Returns the :class:`Report` (empty: conformant). Raises DriveE2EError only
    when the suite cannot be loaded.
    """
    policy = getattr(policy, "host", policy) if getattr(policy, "is_host_policy", False) else policy
    name = getattr(policy, "name", None)
    source = str(source or getattr(policy, "source", None) or f"policy {name!r}")
    report = Report(source)
    host = isinstance(policy, hostapi.HostPolicy)
    if not _check_attributes(policy, report, host):
        return report
    required = tuple(getattr(policy, "required_sensors", ()) or ())
    try:
        sensors = SensorConfig.for_policy(required, getattr(policy, "sensor_config", None))
    except (ValueError, TypeError, AttributeError) as e:
        report.add("attributes", f"required_sensors / sensor_config rejected: {_exc(e)}")
        return report
    probe = _probe(_resolve_suite(suite), sensors, int(batch), int(steps))
    if host:
        info = _check_host(policy, report, probe)
    else:
        info = _check_jax(policy, report, probe, jax.random.PRNGKey(seed))
    if info is not None:
        kind = "host policy" if host else "JAX policy"
        t = len(probe.obs)
        what = (f"{probe.batch} scenario(s) x {t} step(s) (act calls 0-{t - 1}, simulator steps 0-"
                f"{(t - 1) * STEP_STRIDE} along the logs)" + ("" if host else ", jit + vmap"))
        report.summary = (f"{name}: {kind}, {info['action']}, state: {info['state']}, "
                          f"sensors: {', '.join(required) or 'none'}; {what}")
    return report


def checked_params(policy: Any, obs, key, params: Any = None, *, where: str = "on one observation") -> Any:
    """A JAX policy's parameters, checked before a rollout is compiled.

    ``init(key, obs)`` runs when ``params`` is None (eagerly, as ``evaluate``
    always ran it), then :func:`check_traceable`. ``obs``: ONE scenario's
    observation (no batch axis); ``where``: what the messages say it was.
    Raises DriveE2EError with the first problem (one line naming the policy's
    file) instead of a JAX traceback; returns the params.
    """
    if params is None:
        try:
            params = policy.init(key, obs)
        except DriveE2EError:
            raise
        except Exception as e:  # noqa: BLE001 - a user's policy: one line
            source = _source_of(policy)
            raise DriveE2EError(f"{source}: init(key, obs) {raised_text(e, source)} ({where})") from e
    report = check_traceable(policy, obs, params, key, where=where)
    if report:
        raise DriveE2EError(report[0].message) from report[0].cause  # --debug: the policy's own frames
    return params


def check_traceable(policy: Any, obs, params, key, *, source: str | None = None,
                    where: str = "on one observation") -> Report:
    """Trace ``initial_state(obs)`` and ``act(params, obs, state, key)`` once,
    abstractly (``jax.eval_shape``: nothing runs on arrays, nothing compiles),
    and check what the compiled rollout relies on: both trace (no Python
    ``if`` on an array), ``params`` and the state are arrays, ``act`` returns
    a pair whose action is the declared ``types.Controls`` / ``Waypoints``
    (shapes, float32) and whose state keeps ``initial_state``'s structure,
    shapes and dtypes. ``obs``: ONE scenario's observation (no batch axis).

    Returns a :class:`Report` with at most one problem (the first found).
    """
    report = Report(str(source or _source_of(policy)))
    where = f"traced {where}"
    bad = next(((p, leaf) for p, leaf in _leaves(params) if _dtype(leaf) is None), None)
    if bad is not None:
        report.add("init", f"init(key, obs) returned params with {_describe(bad[1])} at {bad[0] or 'its root'}, "
                           f"expected a pytree of arrays (the rollout passes params through jax.jit)")
        return report
    ok, state0 = _traced_initial_state(report, policy, obs, where)
    if not ok:
        return report
    try:
        result = _traced(policy.act, params, obs, state0, key)
    except Exception as e:  # noqa: BLE001
        report.add("act", f"act(params, obs, state, key) {_trace_failure(e, report.source)} ({where})", e)
        return report
    _check_result(report, result, state0, policy.action_type, getattr(policy, "num_waypoints", None), where)
    del report[1:]
    return report


def check_initial_state(policy: Any, obs, *, where: str = "on one observation") -> Report:
    """Only the ``initial_state(obs)`` part of :func:`check_traceable` (no
    params needed): ``Rollout.reset`` traces it inside the compiled reset, so
    when that fails ``evaluate`` asks this for the one-line cause."""
    report = Report(_source_of(policy))
    _traced_initial_state(report, policy, obs, f"traced {where}")
    return report


def _traced_initial_state(report: Report, policy: Any, obs, where: str):
    """(True, ``initial_state(obs)``'s abstract value), or (False, None) after
    adding the problem to ``report`` (a policy without state returns None)."""
    try:
        state0 = _traced(policy.initial_state, obs)
    except Exception as e:  # noqa: BLE001 - a user's policy: one line
        report.add("initial_state", f"initial_state(obs) {_trace_failure(e, report.source)} ({where})", e)
        return False, None
    return (True, state0) if _state_leaves_ok(report, state0) else (False, None)


def _traced(fn, *args):
    """What ``fn(*args)`` returns under ``jax.eval_shape``: its arrays as
    ``ShapeDtypeStruct``, anything else (a str, a hostapi container) as is."""
    out = []

    def run(*a):
        out.append(jax.tree_util.tree_map(_abstract, fn(*a)))

    jax.eval_shape(run, *args)
    return out[0]


def _abstract(x):
    if isinstance(x, jax.Array | np.ndarray | np.generic):
        return jax.ShapeDtypeStruct(np.shape(x), x.dtype)
    return x


def _source_of(policy: Any) -> str:
    return str(getattr(policy, "source", None) or f"policy {getattr(policy, 'name', None)!r}")


def _trace_failure(e: BaseException, source: str | None) -> str:
    """What went wrong while tracing, with the policy's line: branching on a
    traced value gets its fix, anything else is ``raised ...``."""
    frame = user_frame(e, source)
    at = f" at {frame}" if frame else ""
    if isinstance(e, jax.errors.TracerBoolConversionError):
        return f"branches on a traced value (Python if/while/bool on an array){at}; use jnp.where or jax.lax.cond"
    if isinstance(e, jax.errors.ConcretizationTypeError | jax.errors.TracerIntegerConversionError):
        return (f"uses a traced value where a concrete one is needed (int() / float(), a shape or a Python index "
                f"computed from an array){at}; keep it an array (jnp.where, lax.dynamic_slice) and sizes fixed")
    if isinstance(e, jax.errors.TracerArrayConversionError):
        return f"converts a traced value to numpy{at}; use jax.numpy on arrays"
    return raised_text(e, source)


def check_policy_file(path: str | Path, *, policy_kwargs: Mapping | None = None, **kwargs) -> Report:
    """Load a policy file and :func:`check_policy` it.

    ``path``: ``FILE[:key=value,...]`` (``make_policy`` arguments, JSON values;
    ``name=`` renames), a reference policy name (``stop``) or a
    ``remote://HOST:PORT`` spec; ``policy_kwargs``: more ``make_policy``
    arguments; ``kwargs``: :func:`check_policy`'s. The object is loaded
    without being validated, so a bad ``action_type`` is a problem in the
    report; DriveE2EError (one line) when the file cannot be loaded at all.
    """
    spec = str(path)
    if is_remote_spec(spec):
        if policy_kwargs:
            raise DriveE2EError(f"{spec}: a remote policy takes no make_policy arguments (give them to serve-policy)")
        return check_policy(load_policy(spec), source=spec, **kwargs)
    file, spec_kwargs, name = parse_policy_spec(spec)
    policy = hostapi.load_policy_object(file, **{**spec_kwargs, **dict(policy_kwargs or {})})
    if name:
        try:
            policy.name = name
        except AttributeError as e:
            raise DriveE2EError(f"{spec}: cannot rename the policy to {name!r} ({e})") from e
    return check_policy(policy, source=str(file), **kwargs)


# --------------------------------------------------------------------------
# Declared attributes
# --------------------------------------------------------------------------


def _check_attributes(policy: Any, report: Report, host: bool) -> bool:
    """Record attribute problems; False when running the policy is pointless."""
    go = True
    methods = ("reset", "act") if host else ("init", "initial_state", "act")
    missing = [m for m in methods if not callable(getattr(policy, m, None))]
    if missing:
        expected = "drivee2e_jax.hostapi.HostPolicy" if host else "drivee2e_jax.policy.Policy: init, initial_state, act"
        report.add("attributes", f"the policy ({_describe(policy)}) lacks {', '.join(m + '()' for m in missing)} "
                                 f"(expected {expected})")
        go = False
    name = getattr(policy, "name", None)
    if not isinstance(name, str) or not name.strip():
        report.add("attributes", f"name is {name!r}, expected a non-empty string (it names the policy in results)")
    at = getattr(policy, "action_type", None)
    if at not in hostapi.ACTION_TYPES:
        report.add("attributes", f"action_type is {at!r}, expected 'controls' or 'waypoints'")
        go = False
    elif at == "waypoints":
        dt = getattr(policy, "waypoint_dt", None)
        if isinstance(dt, bool) or not isinstance(dt, int | float | np.number) or not (math.isfinite(dt) and dt > 0):
            report.add("attributes", f"waypoint_dt is {dt!r}, expected a positive number of seconds between waypoints")
        nw = getattr(policy, "num_waypoints", None)
        if nw is not None and (isinstance(nw, bool) or not isinstance(nw, int | np.integer) or nw < 1):
            report.add("attributes", f"num_waypoints is {nw!r}, expected a positive int (or None: any K >= 1)")
            go = False
    rs = getattr(policy, "required_sensors", ())
    rs = () if rs is None else rs
    if isinstance(rs, str) or not isinstance(rs, tuple | list) or not all(isinstance(s, str) for s in rs):
        report.add("attributes", f"required_sensors is {rs!r}, expected a tuple of sensor names, e.g. ('bev',)")
        go = False
    else:
        unknown = [s for s in rs if s not in registry.names()]
        if unknown:
            report.add("attributes", f"required_sensors names the unknown sensor {unknown[0]!r}, expected some of "
                                     f"{', '.join(registry.names())} (observe.registry)")
            go = False
    return go


# --------------------------------------------------------------------------
# Real observations
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Probe:
    """Observations of ``batch`` scenarios at ``len(obs)`` instants.

    obs: batched ``types.Observation`` (jax arrays, leading axis B) per instant.
    meta: the scenarios' ``SuiteMeta.rows()`` (what ``HostPolicy.reset`` gets).
    """

    obs: tuple
    meta: tuple

    @property
    def batch(self) -> int:
        return len(self.meta)

    @property
    def ids(self) -> list[str]:
        return [str(m.get("scenario_id", i)) for i, m in enumerate(self.meta)]


_PROBES: dict = {}


def _resolve_suite(suite):
    if isinstance(suite, Suite):
        return suite
    text = str(suite)
    if text == "tiny" and not Path(text).is_dir():
        return str(TINY_SUITE)
    return text


def _probe(suite, sensors: SensorConfig, batch: int, steps: int) -> _Probe:
    """The observations (cached per suite name, sensors, batch and steps)."""
    if batch < 1 or steps < 1:
        raise DriveE2EError(f"check_policy: batch and steps must be >= 1, got batch={batch}, steps={steps}")
    try:
        key = (suite if isinstance(suite, str) else id(suite), sensors, batch, steps)
        hash(key)
    except TypeError:
        key = None
    if key is not None and key in _PROBES:
        return _PROBES[key][0]
    loaded = load_suite(suite)
    packed = loaded.pack(None)
    packed = packed.select(np.arange(min(batch, len(packed))))
    sim = Simulator(SimConfig(sensors=sensors))
    assets = build_assets(packed, sensors, loaded.maps)
    ax = assets_axes(assets)
    scenario = jax.device_put(packed.scenario)
    n = len(packed)
    reset = jax.jit(jax.vmap(sim.reset, in_axes=(0, 0, ax)))
    step = jax.jit(jax.vmap(lambda s, st, a, x: sim.step(s, st, a, x)[:2], in_axes=(0, 0, 0, ax)))
    state, obs = reset(jax.random.split(jax.random.PRNGKey(0), n), scenario, assets)
    out = [obs]
    for _ in range(steps - 1):
        for _ in range(STEP_STRIDE):  # drive along the log: the observations change
            state, obs = step(scenario, state, obs.privileged.log_controls, assets)
        out.append(obs)
    probe = _Probe(obs=tuple(out), meta=tuple(packed.meta.rows()))
    if key is not None:
        _PROBES[key] = (probe, suite)  # keep a Suite object alive: its id is the key
    return probe


def _row(tree, i: int):
    return jax.tree_util.tree_map(lambda a: a[i], tree)


# --------------------------------------------------------------------------
# JAX policies
# --------------------------------------------------------------------------


def _check_jax(policy, report: Report, probe: _Probe, key) -> dict | None:
    at = policy.action_type
    nw = getattr(policy, "num_waypoints", None)
    ids, n_obs, b = probe.ids, len(probe.obs), probe.batch
    k_init, key = jax.random.split(key)
    keys = [jax.random.split(jax.random.fold_in(key, t), b) for t in range(n_obs)]
    obs0 = _row(probe.obs[0], 0)
    try:
        params = policy.init(k_init, obs0)
    except Exception as e:  # noqa: BLE001 - a user's policy: one line
        report.add("init", f"init(key, obs) {raised_text(e, report.source)}")
        return None
    try:
        state0 = policy.initial_state(obs0)
    except Exception as e:  # noqa: BLE001
        report.add("initial_state", f"initial_state(obs) {raised_text(e, report.source)}")
        return None
    if not _state_leaves_ok(report, state0):
        return None

    # eager, scenario 0, along its log
    state, first, flagged = state0, None, False
    for t in range(n_obs):
        where = f"step {t}, scenario {ids[0]}"
        try:
            result = policy.act(params, _row(probe.obs[t], 0), state, keys[t][0])
        except Exception as e:  # noqa: BLE001
            report.add("act", f"act(params, obs, state, key) {raised_text(e, report.source)} ({where})")
            return None
        if not _check_result(report, result, state0, at, nw, where):
            return None
        action, new_state = result
        flagged = flagged or _flag_nonfinite(report, action, where)
        first = first or (action, new_state)
        state = new_state

    # determinism: the same call again
    try:
        again = policy.act(params, obs0, state0, keys[0][0])
    except Exception as e:  # noqa: BLE001
        report.add("determinism", f"act raised {_exc(e)} when called again with the same inputs (step 0, scenario {ids[0]})")
        return None
    diff = _difference(first, again, same_call=True)
    if diff:
        report.add("determinism", f"act is not deterministic: two calls with the same params, observation, state and "
                                  f"key differ ({diff}; step 0, scenario {ids[0]}); draw randomness from `key` "
                                  f"(jax.random), not numpy.random / random / time / global state")

    # jit: traceable, and the same result
    jitted = jax.jit(policy.act)
    try:
        j_out = jitted(params, obs0, state0, keys[0][0])
    except Exception as e:  # noqa: BLE001
        report.add("jit", _trace_problem("jax.jit", e, report.source))
        return None
    diff = _difference(first, tuple(j_out), same_call=False)
    if diff and not any(p.check == "determinism" for p in report):
        report.add("jit", f"act under jax.jit differs from the eager call ({diff}; step 0, scenario {ids[0]}): act "
                          f"must be a pure function of (params, obs, state, key), without Python side effects")

    # vmap over the batch, as the rollout runs it
    vinit = jax.jit(jax.vmap(policy.initial_state))
    vact = jax.jit(jax.vmap(policy.act, in_axes=(None, 0, 0, 0)))
    try:
        states = states0 = vinit(probe.obs[0])
        outs = []
        for t in range(n_obs):
            actions, states = vact(params, probe.obs[t], states, keys[t])
            outs.append((actions, states))
    except Exception as e:  # noqa: BLE001
        report.add("vmap", _trace_problem(f"jax.vmap over {b} scenarios", e, report.source))
        return None
    for t, (actions, _) in enumerate(outs):
        for i in range(b):
            if not flagged:
                flagged = _flag_nonfinite(report, _row(actions, i), f"step {t}, scenario {ids[i]}")
    if not any(p.check in ("determinism", "jit") for p in report):  # the same cause, reported already
        for i in range(b):
            try:
                single = jitted(params, _row(probe.obs[0], i), _row(states0, i), keys[0][i])
            except Exception as e:  # noqa: BLE001
                report.add("vmap", f"act under jax.jit raised {_exc(e)} (step 0, scenario {ids[i]})")
                return None
            diff = _difference(tuple(single), _row(outs[0], i), same_call=False)
            if diff:
                report.add("vmap", f"jax.vmap(act) over {b} scenarios differs from calling act on each ({diff}; "
                                   f"step 0, scenario {ids[i]}): act sees ONE scenario, scenarios must not mix")
                break

    n_leaves = len(_leaves(state0))
    size = sum(int(np.size(leaf)) for _, leaf in _leaves(state0))
    return {"action": _action_text(first[0], at, policy, batched=False),
            "state": f"{n_leaves} leaves ({size} values)" if n_leaves else "None" if state0 is None else "no arrays"}


def _check_action(report: Report, action, at: str, nw, where: str) -> bool:
    cls, fields = _FIELDS[at]
    other_at = "waypoints" if at == "controls" else "controls"
    other = _FIELDS[other_at][0]
    sig = ("drivee2e_jax.types.Controls(throttle, brake, steer) of float32 scalars" if cls is Controls
           else "drivee2e_jax.types.Waypoints(xy) with xy (K, 2) float32")
    if isinstance(action, other):
        report.add("action", f"act returned a {other.__name__} action ({where}), but action_type is {at!r}: expected "
                             f"{sig} (or declare action_type = {other_at!r})")
        return False
    if not isinstance(action, cls):
        hint = ""
        if isinstance(action, Mapping):
            hint = f" (build drivee2e_jax.types.{cls.__name__}(**d) from the dict)"
        elif isinstance(action, hostapi.Controls | hostapi.Waypoints):
            hint = " (the hostapi containers are for host policies; a JAX policy returns the drivee2e_jax.types ones)"
        report.add("action", f"act returned {_describe(action)} as the action ({where}), expected {sig}{hint}")
        return False
    ok = True
    for name, tail in fields.items():
        leaf = getattr(action, name)
        what = f"action {cls.__name__}.{name}"
        want = "()" if not tail else f"({nw if nw is not None else 'K'}, 2)"
        dt = _dtype(leaf)
        if dt is None:
            report.add("action", f"{what} is {_describe(leaf)} ({where}), expected a float32 array of shape {want}")
            ok = False
            continue
        shape = tuple(np.shape(leaf))
        if dt != np.float32:
            report.add("action", f"{what} has dtype {dt} ({where}), expected float32 (.astype(jnp.float32))")
            ok = False
        if not tail:
            if shape != ():
                report.add("action", f"{what} has shape {shape} ({where}), expected (): one scalar per scenario "
                                     f"(act sees ONE scenario; the rollout vmaps it)")
                ok = False
        elif len(shape) != 2 or shape[1] != 2:
            report.add("action", f"{what} has shape {shape} ({where}), expected {want}: K ego-frame points (x, y) "
                                 f"of ONE scenario (the rollout vmaps act)")
            ok = False
        elif shape[0] < 1:
            report.add("action", f"{what} has no waypoints (shape {shape}, {where}), expected {want} with K >= 1")
            ok = False
        elif nw is not None and shape[0] != nw:
            report.add("action", f"{what} has {shape[0]} waypoints (shape {shape}, {where}), expected "
                                 f"num_waypoints={nw}: shape {want}")
            ok = False
    return ok


def _check_result(report: Report, result, state0, at: str, nw, where: str) -> bool:
    """Record what is wrong with ``act``'s return value (a pair, the declared
    action, ``state0``'s structure); whether it is all right."""
    if not isinstance(result, tuple | list) or len(result) != 2:
        report.add("act", f"act returned {_describe(result)} ({where}), expected a pair (action, policy_state)")
        return False
    return _check_action(report, result[0], at, nw, where) and _check_state(report, state0, result[1], where)


def _state_leaves_ok(report: Report, state0) -> bool:
    """Record a policy state leaf that is no array (``lax.scan`` carries the state)."""
    for path, leaf in _leaves(state0):
        dt = _dtype(leaf)
        if dt is None or dt.kind not in "biuf":
            report.add("state", f"initial_state returned a state with {_describe(leaf)} at {path or 'its root'}, "
                                f"expected arrays only (lax.scan carries the policy state)")
            return False
    return True


def _check_state(report: Report, ref, new, where: str) -> bool:
    t_ref, t_new = jax.tree_util.tree_structure(ref), jax.tree_util.tree_structure(new)
    tail = "return the state with the same structure, shapes and dtypes (lax.scan carries it)"
    if t_ref != t_new:
        report.add("state", f"act changed the policy state's structure ({where}): initial_state gave "
                            f"{_tree_text(ref, t_ref)}, act returned {_tree_text(new, t_new)}; {tail}")
        return False
    for (path, a), (_, b) in zip(_leaves(ref), _leaves(new)):
        if _aval(a) != _aval(b):
            report.add("state", f"act changed the policy state at {path or 'its root'} ({where}): "
                                f"{_aval_text(a)} from initial_state, {_aval_text(b)} from act; {tail}")
            return False
    return True


def _trace_problem(under: str, e: Exception, source: str | None = None) -> str:
    """One line for an act that fails when traced (the hint before the error text)."""
    frame = user_frame(e, source)
    at = f" at {frame}" if frame else ""
    if isinstance(e, jax.errors.ConcretizationTypeError | jax.errors.TracerIntegerConversionError):
        return (f"act fails under {under}: Python control flow or conversion on a traced value{at}; use jnp.where / "
                f"lax.cond (lax.while_loop) instead of if / while / int() / float() on arrays ({_exc(e, 80)})")
    if isinstance(e, jax.errors.TracerArrayConversionError):
        return f"act fails under {under}: it converts a traced value to numpy{at}; use jax.numpy on arrays ({_exc(e, 80)})"
    return f"act raised under {under}: {_exc(e)}{at}"


# --------------------------------------------------------------------------
# Host policies
# --------------------------------------------------------------------------


def _check_host(policy, report: Report, probe: _Probe) -> dict | None:
    at, nw, b, ids = policy.action_type, getattr(policy, "num_waypoints", None), probe.batch, probe.ids
    fields = getattr(policy, "observation_fields", None)
    fields = None if fields is None else tuple(fields)
    # exactly what bench sends: the fields the policy asked for (hostbridge.observed)
    obs = [hostapi.from_fields(jax.device_get(hostbridge.observed(o, fields))) for o in probe.obs]

    def reset():
        try:
            return True, policy.reset([dict(m) for m in probe.meta])
        except (Exception, SystemExit) as e:  # noqa: BLE001 - a user's policy: one line
            report.add("reset", f"reset(meta) {raised_text(e, report.source)} (a batch of {b} scenarios)")
            return False, None

    def act(o, state, t):
        where = report.source
        try:
            result = policy.act(o, state)
        except (Exception, SystemExit) as e:  # noqa: BLE001
            report.add("act", f"act(obs, state) {raised_text(e, report.source)} (step {t}, a batch of {b} scenarios)")
            return None
        try:
            action, new_state = hostapi.check_act_result(result, where)
            return hostapi.check_action(action, at, b, where, num_waypoints=nw), new_state
        except DriveE2EError as e:
            report.add_line("action", f"{e.message} (step {t})")
            return None

    ok, state = reset()
    if not ok:
        return None
    start_state, first, flagged = state, None, False
    for t, o in enumerate(obs):
        out = act(o, state, t)
        if out is None:
            return None
        action, new_state = out
        if new_state is None and state is not None:
            report.add("state", f"act returned the state None (step {t}) after reset / the previous step gave "
                                f"{_describe(state)}: return (action, new_state)")
            return None
        for i in range(b):
            if not flagged:
                flagged = _flag_nonfinite(report, _host_row(action, i), f"step {t}, scenario {ids[i]}")
        first = first or action
        state = new_state

    ok, again_state = reset()
    if not ok:
        return None
    out = act(obs[0], again_state, 0)
    if out is None:
        return None
    diff = _difference((_as_dict(first), None), (_as_dict(out[0]), None), same_call=True)
    if diff:
        report.add("determinism", f"two fresh reset(meta) + act(obs) on the same observation give different "
                                  f"actions ({diff}; step 0); seed any randomness in reset, keep no state on self")
    return {"action": _action_text(first, at, policy, batched=True),
            "state": "None" if start_state is None else _describe(start_state)}


# --------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------


def _flag_nonfinite(report: Report, action, where: str) -> bool:
    """Record the first non-finite action leaf; whether one was found."""
    for name, value in _as_dict(action).items():
        arr = np.asarray(value, dtype=np.float64)
        if not np.all(np.isfinite(arr)):
            bad = arr[~np.isfinite(arr)].ravel()[0]
            report.add("finite", f"act returned a non-finite action: {type(action).__name__}.{name} holds {bad} "
                                 f"({where}); the simulator would brake instead and count an invalid action")
            return True
    return False


def _action_text(action, at: str, policy, *, batched: bool) -> str:
    if at == "controls":
        return f"Controls throttle/brake/steer {'(B,)' if batched else '()'} float32"
    k = int(np.shape(action.xy)[-2])
    return f"Waypoints xy ({'B, ' if batched else ''}{k}, 2) float32, waypoint_dt {float(policy.waypoint_dt):g} s"


def _as_dict(container) -> dict:
    """A ``hostapi`` container's fields (it is no pytree)."""
    return {f.name: getattr(container, f.name) for f in dataclasses.fields(container)}


def _host_row(container, i: int):
    return type(container)(**{k: v[i] for k, v in _as_dict(container).items()})


def _leaves(tree) -> list[tuple[str, Any]]:
    flat, _ = jax.tree_util.tree_flatten_with_path(tree)
    return [(jax.tree_util.keystr(path), leaf) for path, leaf in flat]


def _dtype(x) -> np.dtype | None:
    """The dtype ``x`` has under jit (Python floats are weakly float32), None if not numeric."""
    if isinstance(x, bool):
        return np.dtype(bool)
    if isinstance(x, int):
        return np.dtype(np.int32)
    if isinstance(x, float):
        return np.dtype(np.float32)
    dt = getattr(x, "dtype", None)
    try:
        return None if dt is None else np.dtype(dt)
    except TypeError:
        return None


def _aval(x) -> tuple:
    dt = _dtype(x)
    return tuple(np.shape(x)), None if dt is None else jax.dtypes.canonicalize_dtype(dt)


def _aval_text(x) -> str:
    shape, dt = _aval(x)
    return f"shape {shape} {dt}"


def _tree_text(tree, treedef) -> str:
    if tree is None:
        return "None"
    text = str(treedef)
    return text if len(text) <= 100 else text[:97] + "..."


def _difference(a, b, *, same_call: bool) -> str:
    """'' when the (action, state) pairs ``a`` and ``b`` agree (``same_call``: the same call
    twice, else jit / vmap vs eager; see the tolerances above), else where they first differ."""
    try:
        return _first_difference(a, b, same_call=same_call)
    except Exception as e:  # noqa: BLE001 - e.g. a second call returned something else entirely
        return f"the results cannot be compared: {_exc(e, 80)}"


def _first_difference(a, b, *, same_call: bool) -> str:
    for label, x, y in (("action", a[0], b[0]), ("state", a[1], b[1])):
        if jax.tree_util.tree_structure(x) != jax.tree_util.tree_structure(y):
            return f"the {label}s have different structures"
        for (path, u), (_, v) in zip(_leaves(x), _leaves(y)):
            u, v = np.asarray(u), np.asarray(v)
            name = f"{label}{path}"
            if u.shape != v.shape:
                return f"{name} has shapes {u.shape} and {v.shape}"
            if u.dtype.kind not in "biuf" or v.dtype.kind not in "biuf":
                continue
            uf, vf = u.astype(np.float64), v.astype(np.float64)
            rtol, atol = (SAME_RTOL, SAME_ATOL) if same_call else (RTOL, ATOL)
            same = np.allclose(uf, vf, rtol=rtol, atol=atol, equal_nan=True)
            if not same:
                diff = np.abs(np.where(np.isnan(uf) & np.isnan(vf), 0.0, uf - vf))
                j = np.unravel_index(np.nanargmax(np.where(np.isnan(diff), np.inf, diff)), diff.shape) if diff.ndim else ()
                return f"{name}{[int(k) for k in j] if j else ''}: {uf[j]:.6g} vs {vf[j]:.6g}"
    return ""


def _describe(value: Any) -> str:
    if value is None:
        return "None"
    if isinstance(value, Mapping):
        keys = ", ".join(map(str, list(value)[:6]))
        return f"a dict with keys [{keys}]"
    if isinstance(value, tuple | list):
        return f"a {type(value).__name__} of {len(value)} item(s)"
    if isinstance(value, str):
        return f"a str {value[:20]!r}"
    return f"a {type(value).__module__}.{type(value).__qualname__}"


def _exc(e: BaseException, limit: int = 200) -> str:
    """``Type: message`` on one line, the message cut at ``limit`` characters."""
    text = one_line(e, limit)
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _one_line(text: str) -> str:
    return one_line(text, MAX_LINE)
