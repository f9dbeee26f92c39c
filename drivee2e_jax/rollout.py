"""Rollouts: ``lax.scan`` over time inside ``jit``, ``vmap`` over scenarios.

A whole suite split steps as one compiled program. Time is advanced in chunks
of ``chunk`` steps (one compiled ``advance`` reused for every chunk) so the
host can draw a progress bar and stop early once every episode is done; the
result is identical to a single scan.

Control timing (Behavior Metrics' synchronous / asynchronous modes): the
policy is queried every ``control_every`` simulation steps and its action is
held in between; ``latency`` delays each action by that many steps (the
previous action stays applied meanwhile; the first actions are a full brake).

The observation is rendered at the START of a step, from the simulator state,
right before the policy reads it (``Simulator.observe``), not carried from the
previous step: under ``jit`` XLA then computes only what the policy reads
(e.g. a LiDAR range image reduced by the policy is never written out) and
nothing image-sized rides in the scan carry. With ``control_every`` > 1 and a
``chunk`` that is a multiple of it, the steps without a query skip the
rendering and the policy entirely (``lax.cond`` on the scan index).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax.hostbridge import observed
from drivee2e_jax.lowered_cache import fingerprint, stored_jit
from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.observe import sensors
from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.sim import SimState, Simulator
from drivee2e_jax.types import Controls, Scenario, Waypoints


@dataclasses.dataclass(frozen=True)
class ControlTiming:
    """When the policy runs. ``control_every`` >= 1 steps, ``latency`` >= 0 steps."""

    control_every: int = 1
    latency: int = 0

    def __post_init__(self):
        if self.control_every < 1:
            raise ValueError(f"ControlTiming.control_every must be >= 1, got {self.control_every}")
        if self.latency < 0:
            raise ValueError(f"ControlTiming.latency must be >= 0, got {self.latency}")


@struct.dataclass
class Carry:
    """Rollout carry for one scenario.

    ``nonfinite``: () int32 steps of the running episode whose applied action
    held a NaN / inf (the simulator repairs those: ``sim.Simulator.to_controls``).
    """

    sim: SimState
    policy_state: Any
    held: Any  # the action currently applied
    queue: Any  # (latency, ...) actions waiting to take effect
    key: jnp.ndarray
    nonfinite: jnp.ndarray


def _brake_like(action):
    """A neutral action of the same structure (full brake / stay in place)."""
    if isinstance(action, Controls):
        z = jnp.zeros_like(action.throttle)
        return Controls(throttle=z, brake=jnp.ones_like(action.brake), steer=z)
    if isinstance(action, Waypoints):
        return Waypoints(xy=jnp.zeros_like(action.xy))
    return jax.tree_util.tree_map(jnp.zeros_like, action)


def _all_finite(action) -> jnp.ndarray:
    """() bool: every float leaf of ``action`` is finite."""
    leaves = [jnp.all(jnp.isfinite(a)) for a in jax.tree_util.tree_leaves(action)
              if jnp.issubdtype(jnp.asarray(a).dtype, jnp.inexact)]
    return jnp.all(jnp.stack(leaves)) if leaves else jnp.ones((), bool)


def _sim_functions(sim: Simulator):
    """``sim``'s (reset, step, observe) as the rollout calls them: for a plain
    ``Simulator`` the ``jax.jit``-wrapped functions shared by every rollout of
    an equal config (``_shared_sim_functions``), else its own methods."""
    if type(sim) is Simulator:
        try:
            return _shared_sim_functions(sim.config)
        except TypeError:  # an unhashable config: nothing to share
            pass
    return sim.reset, sim.step, sim.observe


@functools.lru_cache(maxsize=16)
def _shared_sim_functions(config):
    """jit-wrapped reset / step / observe of ``Simulator(config)``, one set per
    config. Called inside a rollout's own jit they are inlined by XLA (the
    compiled program is the same), but JAX traces each one once per argument
    shapes for the process, not once per rollout: a bench of several policies
    and the checkpoints of a trend trace the simulator once (it is most of a
    rollout's tracing time; ``view`` clears JAX's caches between policies)."""
    sim = Simulator(config)
    return jax.jit(sim.reset), jax.jit(sim.step, static_argnames=("observe",)), jax.jit(sim.observe)


def longest_episode(sim: Simulator, batch: Scenario) -> int:
    """Steps of the longest episode of ``batch`` (B, ...): the max of
    ``episode_lengths``."""
    return int(jnp.max(episode_lengths(sim, batch)))


def episode_lengths(sim: Simulator, batch: Scenario) -> jnp.ndarray:
    """(B,) int32 ``sim.episode_steps`` of every row of ``batch`` (B, ...), in
    one compiled pass per config (op by op, a vmap compiles one small program
    per primitive)."""
    return _batch_episode_steps(sim.config, batch)


#: (B,) int32 ``Simulator(config).episode_steps`` of every row of a batch, compiled once per config.
_batch_episode_steps = jax.jit(lambda config, batch: jax.vmap(Simulator(config).episode_steps)(batch),
                               static_argnums=0)


def episode_results(sim: Simulator, episode, route) -> ep.EpisodeResult:
    """``metrics.episode.finalize`` of every row: the scores of the episodes
    of a rollout's final carry (``carry.sim.episode``, (B, ...)) on their
    routes ((B, ...)), in one compiled call per score config (op by op, a
    vmap compiles ~40 small programs per call)."""
    return _batch_finalize(episode, route, sim.config.score)


_batch_finalize = jax.jit(lambda episode, route, score: jax.vmap(ep.finalize, in_axes=(0, 0, None))(episode, route, score),
                          static_argnums=2)


@struct.dataclass
class Start:
    """A reset batch before the policy's parameters are needed (``Rollout.reset``).

    ``sim``: SimState (B, ...); ``policy_state``: (B, ...) each scenario's
    ``policy.initial_state(obs)``; ``key``: (B, 2) the carry's PRNG keys;
    ``first_obs``: row 0's initial Observation, no batch axis: what
    ``evaluate`` initialises and checks the policy's parameters on.
    """

    sim: SimState
    policy_state: Any
    key: jnp.ndarray
    first_obs: Any


class Rollout:
    """Runs a policy on a batch of scenarios.

    Usage::

        ro = Rollout(sim, policy, params)
        carry = ro.init(batch, keys)              # vmapped reset, keys (B, 2)
        carry, logs = ro.advance(batch, carry)    # `chunk` steps, jitted

    ``init`` is ``start(reset(batch, keys), batch)``: ``reset`` (the
    simulator's reset and the policy's initial state, one compiled program)
    does not read the params, so a caller without params yet (``evaluate``)
    takes them from its ``first_obs``, sets ``ro.params`` and calls ``start``
    (a small program: the carry's neutral first action, shaped by ``act``).
    """

    def __init__(self, sim: Simulator, policy, params=None, *, timing: ControlTiming | None = None, chunk: int = 50,
                 assets=None):
        self.sim = sim
        self.policy = policy
        self.params = params
        self.assets = assets
        self.timing = timing or ControlTiming()
        self.chunk = int(chunk)
        self._sim_reset, self._sim_step, self._sim_observe = _sim_functions(sim)
        # Sensor assets: the map raster table is shared (broadcast), the map
        # index is per scenario; the policy params are broadcast.
        ax = sensors.assets_axes(assets)
        # Each program's lowered module is stored beside the compile cache
        # (lowered_cache): its trace depends on the arguments and on these.
        # Fingerprinted once for the three (the policy may hold large arrays).
        # A host policy's programs depend only on what crosses the boundary
        # (its fields and action), not on the host object (a PyTorch module).
        self.host = getattr(policy, "is_host_policy", False)
        traced = _host_signature(policy) if self.host else self.policy
        whole = functools.cache(lambda: fingerprint((type(self), self.sim, traced, self.timing, self.chunk, ax)))
        ident = lambda program: lambda: (program, whole())  # noqa: E731
        self.reset = _with_params(stored_jit(functools.partial(self._reset_batch, axes=ax), ident("reset")),
                                  lambda: (self.assets,))
        self._start = stored_jit(jax.vmap(self._start_one, in_axes=(0, 0, 0, None, None)), ident("start"))
        if self.host:
            # Compiled segments around the host call (the host loop below): no
            # callback inside a program, so JAX's persistent cache keeps them.
            self._host_observe = stored_jit(jax.vmap(self._observe_one, in_axes=(0, 0, ax)), ident("host_observe"))
            self._host_step = stored_jit(jax.vmap(self._given_step_one, in_axes=(0, 0, 0, ax, 0, None)),
                                         ident("host_step"))
            self._host_step_observe = stored_jit(
                jax.vmap(functools.partial(self._given_step_one, observe=True), in_axes=(0, 0, 0, ax, 0, None)),
                ident("host_step_observe"))
            self.advance = self._advance_host
        else:
            self.advance = _with_params(stored_jit(jax.vmap(self._advance_one, in_axes=(0, 0, ax, None)),
                                                   ident("advance")), lambda: (self.assets, self.params))

    def init(self, batch: Scenario, keys) -> Carry:
        """The carry of every scenario at t = 0: ``start(reset(batch, keys), batch)``."""
        return self.start(self.reset(batch, keys), batch)

    def start(self, started: Start, batch: Scenario | None = None) -> Carry:
        """The rollout's carry from ``reset``'s output, with ``self.params``;
        placed like ``batch`` when given (over a sharded batch XLA replicates
        the carry's constant leaves, and ``advance`` would then compile a
        second time for the carry it returns itself)."""
        carry = self._start(started.sim, started.policy_state, started.key, started.first_obs, self.params)
        placed = None if batch is None else batch.ego_index
        if isinstance(placed, jax.Array) and not isinstance(placed, jax.core.Tracer):  # numpy or traced: as is
            carry = jax.device_put(carry, placed.sharding)
        return carry

    def lower_init(self, batch: Scenario, keys) -> list:
        """The two programs ``init`` runs, lowered ahead of time for compile
        timing (``.compile()`` each): [``reset``, ``start``]."""
        reset = self.reset.lower(batch, keys)
        st = reset.out_info
        return [reset, self._start.lower(st.sim, st.policy_state, st.key, st.first_obs, self.params)]

    # one scenario -----------------------------------------------------------
    def _reset_batch(self, batch: Scenario, keys, assets, *, axes) -> Start:
        sim_state, pstate, key, obs = jax.vmap(self._reset_one, in_axes=(0, 0, axes))(batch, keys, assets)
        return Start(sim=sim_state, policy_state=pstate, key=key,
                     first_obs=jax.tree_util.tree_map(lambda a: a[0], obs))

    def _reset_one(self, scenario: Scenario, key, assets):
        k_reset, _, key = jax.random.split(key, 3)  # the middle key was the policy's (kept: same streams)
        sim_state, obs = self._sim_reset(k_reset, scenario, assets)
        return sim_state, self.policy.initial_state(obs), key, obs

    def _start_one(self, sim_state: SimState, pstate, key, first_obs, params) -> Carry:
        # Only the action's structure is needed: never run the policy here (a
        # host policy would be called for a step that does not exist).
        action, _ = jax.eval_shape(self.policy.act, params, first_obs, pstate, key)
        neutral = _brake_like(action)
        queue = jax.tree_util.tree_map(lambda a: jnp.stack([a] * self.timing.latency), neutral) if self.timing.latency else None
        return Carry(sim=sim_state, policy_state=pstate, held=neutral, queue=queue, key=key,
                     nonfinite=jnp.zeros((), jnp.int32))

    def _decide(self, scenario: Scenario, carry: Carry, assets, params, k_act, given=None):
        """(the policy's action, its new state) on the current observation;
        ``given``: the action a host policy already returned for it (the host
        loop), with the bridge's state, the control-step count, advanced."""
        if given is not None:
            return given, carry.policy_state + 1
        obs = self._sim_observe(scenario, carry.sim, assets)
        return self.policy.act(params, obs, carry.policy_state, k_act)

    def _step_one(self, scenario: Scenario, carry: Carry, assets, params, query=None, given=None):
        """One simulation step. ``query``: () bool whether the policy runs this
        step; None = from the step count. A static True / an unbatched value
        (the scan index) lets XLA skip the observation on the other steps.
        ``given``: a host policy's action for this step (``_advance_host``)."""
        key, k_act = jax.random.split(carry.key)
        every = self.timing.control_every
        last = carry.held if not self.timing.latency else jax.tree_util.tree_map(lambda q: q[-1], carry.queue)
        decide = functools.partial(self._decide, given=given)
        if every == 1:
            proposed, pstate = decide(scenario, carry, assets, params, k_act)
        elif query is None:
            query = (carry.sim.step % every) == 0
            proposed, pstate = decide(scenario, carry, assets, params, k_act)
            pick = lambda new, old: jax.tree_util.tree_map(lambda a, b: jnp.where(query, a, b), new, old)  # noqa: E731
            proposed, pstate = pick(proposed, last), pick(pstate, carry.policy_state)
        else:
            proposed, pstate = jax.lax.cond(
                query, lambda: decide(scenario, carry, assets, params, k_act),
                lambda: (last, carry.policy_state))
        if self.timing.latency:
            # Enqueue the newly decided action; apply the oldest one.
            applied = jax.tree_util.tree_map(lambda q: q[0], carry.queue)
            queue = jax.tree_util.tree_map(lambda q, a: jnp.concatenate([q[1:], a[None]]), carry.queue, proposed)
        else:
            applied = proposed
            queue = None
        sim_state, _, log = self._sim_step(scenario, carry.sim, applied, assets, observe=False)
        if self.sim.config.score.name == "navsim" and isinstance(applied, Waypoints):
            log = log.replace(plan=applied.xy)  # NAVSIM's extended comfort compares consecutive plans
        nonfinite = carry.nonfinite + (log.active & ~_all_finite(applied)).astype(jnp.int32)
        return Carry(sim=sim_state, policy_state=pstate, held=applied, queue=queue, key=key, nonfinite=nonfinite), log

    def _advance_one(self, scenario: Scenario, carry: Carry, assets, params):
        every = self.timing.control_every
        # Every chunk starts at a multiple of ``chunk`` steps: when that is a
        # multiple of ``control_every`` the query steps are known from the
        # scan index alone (equal to the step count of every running episode).
        static = every > 1 and self.chunk % every == 0

        def body(c, i):
            return self._step_one(scenario, c, assets, params, (i % every) == 0 if static else None)

        return jax.lax.scan(body, carry, jnp.arange(self.chunk), length=self.chunk)

    # a host policy: compiled segments around the host call ----------------
    def _observe_one(self, scenario: Scenario, carry: Carry, assets):
        """The observation a host policy reads (``hostbridge.observed``)."""
        return observed(self._sim_observe(scenario, carry.sim, assets), self.policy.observation_fields)

    def _given_step_one(self, scenario: Scenario, carry: Carry, ctx, assets, action, query, observe=False):
        """One step applying a host policy's ``action`` on a control step
        (``query``: () bool, one value for the batch), the held one otherwise;
        ``observe``: also the observation after the step (the next control
        step's: one program call per step instead of two).
        The episode's constants ``ctx`` come in apart from the carry and are
        not returned (the carry's ``sim.ctx`` is None): a program's outputs
        are new buffers, and copying ``ctx`` (~25 MB at B = 200) every step
        cost more than the step."""
        carry, log = self._step_one(scenario, _with_ctx(carry, ctx), assets, None,
                                    query if self.timing.control_every > 1 else None, given=action)
        out = (_with_ctx(carry, None), log)
        return (*out, self._observe_one(scenario, carry, assets)) if observe else out

    def _advance_host(self, batch: Scenario, carry: Carry):
        """``advance`` for a host policy: ``chunk`` steps as a Python loop of
        the compiled observation, the host ``act`` on the whole batch (numpy,
        ``HostBridge``) and the compiled step. The same steps, keys and
        control timing as the scan (the episodes step in lockstep, so the
        control steps are known on the host); no host callback inside a
        compiled program, so JAX's persistent cache keeps both programs
        (``docs/performance.md``, "Host policies"). Returns (carry, StepLog
        (B, chunk, ...) numpy)."""
        every = self.timing.control_every
        t = int(np.asarray(carry.sim.step).reshape(-1)[0])
        ctx = carry.sim.ctx
        carry = _with_ctx(carry, None)
        logs, action, obs = [], None, None
        for i in range(self.chunk):
            query = t % every == 0
            if query:
                if obs is None:  # the chunk's first control step; later ones come with the step before
                    obs = self._host_observe(batch, _with_ctx(carry, ctx), self.assets)
                action = self.policy._host_act(jax.tree_util.tree_map(np.asarray, obs))
            elif action is None:  # a chunk that starts between control steps: the held action is kept
                action = carry.held
            t += 1
            if t % every == 0 and i + 1 < self.chunk:
                carry, log, obs = self._host_step_observe(batch, carry, ctx, self.assets, action, np.asarray(query))
            else:
                carry, log = self._host_step(batch, carry, ctx, self.assets, action, np.asarray(query))
            logs.append(log)
        carry = _with_ctx(carry, ctx)
        # np.asarray leaf by leaf: ~5x faster than jax.device_get on the list.
        return carry, jax.tree_util.tree_map(lambda *xs: np.stack([np.asarray(x) for x in xs], axis=1), *logs)

    # host loop --------------------------------------------------------------
    def run(self, batch: Scenario, key, *, max_steps: int | None = None, progress: Callable[[int], None] | None = None):
        """Roll out until every episode is done or ``max_steps``.

        Returns (final Carry, StepLog stacked as (B, T_sim, ...) numpy arrays).
        ``progress(n_steps)`` is called after each chunk.
        """
        b = int(batch.ego_index.shape[0])
        keys = jax.random.split(key, b)
        carry = self.init(batch, keys)
        if max_steps is None:
            max_steps = longest_episode(self.sim, batch)
        logs = []
        done_steps = 0
        while done_steps < max_steps:
            carry, log = self.advance(batch, carry)
            logs.append(jax.tree_util.tree_map(np.asarray, log))
            done_steps += self.chunk
            if progress is not None:
                progress(min(self.chunk, max_steps - done_steps + self.chunk))
            if bool(np.all(np.asarray(carry.sim.episode.done))):
                break
        stacked = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=1), *logs)
        return carry, stacked


class LogReplay(StatelessPolicy):
    """The reference demonstration as a policy (``zoo/log_replay.py`` ships it
    by name): each step the controls that carry the simulated ego to the
    logged position 0.5 s ahead (``Observation.privileged.log_controls``,
    ``SimConfig.log_horizon_s``). ``evaluate``
    also rolls it out as NAVSIM's human reference."""

    name = "log_replay"
    action_type = "controls"

    def act(self, params, obs, policy_state, key):
        c = obs.privileged.log_controls
        # Past the end of the ego's log: hold still.
        ok = obs.privileged.log_valid
        return (
            Controls(
                throttle=jnp.where(ok, c.throttle, 0.0),
                brake=jnp.where(ok, c.brake, 1.0),
                steer=jnp.where(ok, c.steer, 0.0),
            ),
            policy_state,
        )


def balanced_chunk(total_steps: int, max_chunk: int, multiple: int = 1) -> int:
    """Steps per compiled chunk so that ``ceil(total_steps / max_chunk)``
    chunks cover ``total_steps`` with the least overshoot, rounded up to a
    multiple of ``multiple`` (``control_every``, so query-free steps stay
    static). E.g. 207 steps, ``max_chunk`` 50: 5 chunks of 42 (210 steps)
    instead of 5 of 50 (250 steps, 43 stepped after every log has ended)."""
    if total_steps < 1 or max_chunk < 1 or multiple < 1:
        raise ValueError(f"balanced_chunk: expected total_steps, max_chunk, multiple >= 1, got "
                         f"{total_steps}, {max_chunk}, {multiple}")
    n = -(-total_steps // max_chunk)
    size = -(-total_steps // n)
    return -(-size // multiple) * multiple


def _with_ctx(carry: Carry, ctx) -> Carry:
    """``carry`` with its simulator state's episode constants set to ``ctx``
    (None: taken out, as the host loop's step program passes them apart)."""
    return carry.replace(sim=carry.sim.replace(ctx=ctx))


def _host_signature(policy) -> tuple:
    """What a host policy's compiled segments depend on: the fields it reads
    and its action's type and length."""
    return ("host", policy.observation_fields, policy.action_type, policy.num_waypoints,
            tuple(policy.required_sensors), policy.sensor_config)


def _with_params(fn, get_extra):
    """Bind the sensor assets and policy params as the jitted function's last arguments."""

    def call(*args):
        return fn(*args, *get_extra())

    call.lower = lambda *args: fn.lower(*args, *get_extra())  # for compile timing
    return call


def shard_batch(batch, devices=None, *, replicate: bool = False):
    """Place a batched pytree with its leading axis split over ``devices``.

    The batch size must be divisible by the device count (``pad_rows``).
    With one device this is a plain ``device_put``. jit then runs each shard
    where it lives. ``replicate``: a full copy on every device instead (tables
    every scenario reads, e.g. the sensors' map rasters).
    """
    devices = list(devices or jax.devices())
    if len(devices) == 1:
        return jax.device_put(batch, devices[0])
    mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
    spec = jax.sharding.PartitionSpec() if replicate else jax.sharding.PartitionSpec("batch")
    return jax.device_put(batch, jax.sharding.NamedSharding(mesh, spec))


def pad_rows(batch, multiple: int):
    """``batch`` (leading axis B) padded to a multiple of ``multiple`` rows with
    copies of row 0: padding rows are real scenarios, so they step and finish
    like one, and never change the batch's episode length. Callers drop rows >= B."""
    b = int(jax.tree_util.tree_leaves(batch)[0].shape[0])
    pad = -b % multiple
    if not pad:
        return batch
    rows = np.concatenate([np.arange(b), np.zeros(pad, np.int64)])
    return jax.tree_util.tree_map(lambda a: a[rows], batch)


def shard_rollout_inputs(batch: Scenario, keys, assets, devices=None):
    """The rollout's inputs padded (``pad_rows``) to a multiple of the device
    count and split over ``devices`` (default: this process's devices).

    Args:
      batch: ``Scenario`` with leading axis B.  keys: (B, 2) PRNG keys.
      assets: ``sensors.SensorAssets`` or None; the raster table is
        replicated, ``map_index`` (B,) split with the batch.

    Returns (batch, keys, assets) with B' >= B rows; results have B' rows too:
    keep the first B.
    """
    devices = list(devices or jax.local_devices())
    batch, keys = shard_batch(pad_rows((batch, keys), len(devices)), devices)
    if assets is not None:
        assets = assets.replace(raster=shard_batch(assets.raster, devices, replicate=True),
                                map_index=shard_batch(pad_rows(assets.map_index, len(devices)), devices))
    return batch, keys, assets
