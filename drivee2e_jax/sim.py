"""The simulator: ``reset`` and ``step`` for ONE scenario, pure and jittable.

Per step: sanitise the action -> controls (waypoints go through the
controller) -> the ego's ``dynamics.DynamicsModel`` (``SimConfig.dynamics_model``,
the kinematic bicycle by default) -> replay every logged agent and the signals
at the new time -> infraction facts (``infractions``) -> leaderboard criteria
(``metrics.criteria``) -> observation. Non-ego agents replay the log and never
react (``SimConfig.agents = "log"``, the paper's protocol) unless
``SimConfig.agents = "idm"``: logged vehicles then keep their paths with an
IDM speed (``reactive``).

The scenario is passed explicitly to ``step`` (as gymnax passes ``EnvParams``)
rather than stored in the state, so the static log is not carried through the
``lax.scan``. Batch with ``jax.vmap`` (see ``rollout``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from drivee2e_jax import controller as ctl
from drivee2e_jax import dynamics, geometry, infractions, reactive, replay
from drivee2e_jax.dynamics import DynamicsModel, KinematicBicycle
from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.metrics import navsim, nuplan
from drivee2e_jax.metrics.driving_score import ScoreConfig, score_preset
from drivee2e_jax.observe import sensors
from drivee2e_jax.observe.vector import ObsConfig, observe, route_speed_limits
from drivee2e_jax.types import Controls, EgoState, Observation, Privileged, Scenario, Waypoints

#: Lanes near the route considered for the off-lane test and the lane observation.
NUM_CANDIDATE_LANES = 16
#: Lane boundaries near the route tested for lane invasions.
NUM_CANDIDATE_BOUNDARIES = 16

#: ``SimConfig.agents`` choices (``--agents``); "log" is the paper's non-reactive replay.
AGENT_MODELS = ("log", "idm")


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Simulator settings (static under jit).

    Attributes:
      dt: simulation step, s (the log may have another step; replay interpolates).
      dynamics: vehicle parameters of ``dynamics_model`` (for the kinematic
        bicycle a ``dynamics.BicycleParams``: wheelbase m, steer rad, accel
        m/s^2, speed m/s, drag); the waypoint controller steers for them too.
      controller: PID + pure-pursuit parameters for waypoint actions.
      obs: which vector observations and their sizes.
      sensors: ``observe.sensors.SensorConfig``: which registered sensors
        (``observe.registry``: BEV raster, LiDAR, ...) are on (all off by
        default) and their sizes.
      score: leaderboard criteria and penalties (preset ``paper`` by default).
      max_episode_s: episode cap in seconds; ``None`` = the scenario's log length.
      dynamics_model: the ego's ``dynamics.DynamicsModel`` (frozen, hashable:
        static under jit); default the kinematic bicycle.
      idm: ``reactive.IDMParams`` of the IDM agents (``agents="idm"``).
      agents: the other agents' model (``AGENT_MODELS``): "log" replays every
        recorded track (non-reactive, the paper's protocol); "idm" keeps each
        logged vehicle on its logged path with its speed from IDM, reacting
        to the ego and to each other (``reactive``; pedestrians, cyclists and
        static objects still replay).
      log_horizon_s: s, how far ahead along the ego's log the reference
        action aims (``Privileged.log_controls``, what ``log_replay`` drives
        with): the constant controls that reach the logged position
        ``log_horizon_s`` ahead, recomputed every step (a receding horizon;
        shortened to the end of the log, and to one step where the log has
        a gap there). One step (``dt``) matches the next logged position
        exactly and copies the log's 10 Hz position noise into the yaw rate
        and the acceleration; 0.5 s follows the log to centimetres with
        smooth controls (docs/metrics.md, "Comfort signals").
    """

    dt: float = 0.1
    dynamics: dynamics.BicycleParams = dataclasses.field(default_factory=dynamics.BicycleParams)
    controller: ctl.ControllerParams = dataclasses.field(default_factory=ctl.ControllerParams)
    obs: ObsConfig = dataclasses.field(default_factory=ObsConfig)
    sensors: sensors.SensorConfig = dataclasses.field(default_factory=sensors.SensorConfig)
    score: ScoreConfig = dataclasses.field(default_factory=lambda: score_preset("paper"))
    max_episode_s: float | None = None
    dynamics_model: DynamicsModel = dataclasses.field(default_factory=KinematicBicycle)
    agents: str = "log"
    idm: reactive.IDMParams = dataclasses.field(default_factory=reactive.IDMParams)
    log_horizon_s: float = 0.5

    def __post_init__(self):
        if self.agents not in AGENT_MODELS:
            raise ValueError(f"unknown agent model {self.agents!r}; expected one of {', '.join(AGENT_MODELS)}")
        if not isinstance(self.dynamics_model, DynamicsModel):
            raise TypeError(f"SimConfig.dynamics_model must be a dynamics.DynamicsModel, got {self.dynamics_model!r}")
        # The waypoint controller steers for the car being simulated.
        if self.controller.vehicle != self.dynamics:
            object.__setattr__(self, "controller", dataclasses.replace(self.controller, vehicle=self.dynamics))
        if not self.dt > 0:
            raise ValueError(f"SimConfig.dt must be > 0 s, got {self.dt}")
        if not self.log_horizon_s > 0:
            raise ValueError(f"SimConfig.log_horizon_s must be > 0 s, got {self.log_horizon_s}")
        if self.max_episode_s is not None and not self.max_episode_s > 0:
            raise ValueError(f"SimConfig.max_episode_s must be > 0 s, got {self.max_episode_s}")


@struct.dataclass
class SimContext:
    """Per-episode constants derived from the scenario once, at reset.

    Attributes:
      lanes:     (M,) int32 candidate lane rows near the route (-1 padded).
      markings:  ``infractions.MarkingSegments`` of the painted lane boundaries
                 near the route (lane-invasion test).
      stop_dir:  (S, 2) float32 travel direction across each stop line.
      stop_arc:  (S,) float32 route arc where the route crosses each stop line
                 (inf if it does not).
      ego_lw:    (2,) float32 ego length and width, m.
      speed_limit: (R,) float32 speed limit along the route, m/s.
      obstacles: (O, ...) ``geometry.PolygonSAT`` of the static obstacles.
      lanes_index: ``infractions.LaneIndex`` of the lane polygons: their
                 boxes and closed edges.
      log_overlap: (A, 2) int32 [first, last] log steps during which the
                 LOGGED ego box already overlaps each agent's logged box
                 ([T, -1]: none); a contact with that agent is ignored
                 meanwhile (``infractions.logged_overlap_spans``).
      path_arc:  (A, T) float32 arc length along each logged path, m, with
                 IDM agents (``reactive.path_arc``); None otherwise.
      leader_paths: ``reactive.LeaderPaths`` (A, P) each IDM agent's path
                 ahead for finding its leader; None without IDM agents.
      obstacle_discs: ``metrics.nuplan.ObstacleDiscs`` (O,) of the static
                 obstacles (nuPlan TTC's culling) under the ``nuplan`` preset;
                 None otherwise.
    """

    lanes: jnp.ndarray
    markings: infractions.MarkingSegments
    stop_dir: jnp.ndarray
    stop_arc: jnp.ndarray
    ego_lw: jnp.ndarray
    speed_limit: jnp.ndarray
    obstacles: geometry.PolygonSAT
    lanes_index: infractions.LaneIndex
    log_overlap: jnp.ndarray
    path_arc: jnp.ndarray | None = None
    leader_paths: reactive.LeaderPaths | None = None
    obstacle_discs: nuplan.ObstacleDiscs | None = None


@struct.dataclass
class SimState:
    """Everything that changes during an episode (one scenario).

    Attributes:
      ego: EgoState.
      step: () int32 steps taken.
      episode: ``metrics.episode.EpisodeCarry`` leaderboard criteria + counts.
      controller: ControllerState for waypoint actions.
      ctx: SimContext.
      key: PRNG key, split once per step.
      obs_key: PRNG key of the observation noise of THIS state, so
        ``Simulator.observe`` is a pure function of the state (the same key
        whether the observation is rendered at the end of ``step`` or at the
        start of the next one).
      idm: ``reactive.IDMState`` of the IDM agents (``SimConfig.agents`` =
        "idm"); None when the agents replay the log.
      collided: ``metrics.nuplan.CollisionMemory``, the tracks and obstacles
        touched so far (nuPlan's TTC excludes them for the rest of the
        episode), under the ``nuplan`` preset; None otherwise.
    """

    ego: EgoState
    step: jnp.ndarray
    episode: ep.EpisodeCarry
    controller: ctl.ControllerState
    ctx: SimContext
    key: jnp.ndarray
    obs_key: jnp.ndarray
    idm: reactive.IDMState | None = None
    collided: nuplan.CollisionMemory | None = None

    @property
    def done(self):
        return self.episode.done


@struct.dataclass
class StepLog:
    """Per-step record; the rollout stacks it into an episode log (T_sim, ...).

    Attributes:
      t: () s after the step.  xy: (2,) m.  yaw, speed, accel, steer, yaw_rate.
      throttle, brake, steer_cmd: the applied (sanitised) controls.
      active: () bool, the episode was running during this step.
      facts: ``infractions.StepFacts`` of this step.
      events: ``metrics.episode.StepEvents`` counted this step.
      route_completion: () % after the step.
      plan: (K, 2) the waypoints applied this step (ego frame, m) under the
        ``navsim`` preset with a waypoint policy (its extended comfort), else
        None; set by the rollout.
    """

    t: jnp.ndarray
    xy: jnp.ndarray
    yaw: jnp.ndarray
    speed: jnp.ndarray
    accel: jnp.ndarray
    steer: jnp.ndarray
    yaw_rate: jnp.ndarray
    throttle: jnp.ndarray
    brake: jnp.ndarray
    steer_cmd: jnp.ndarray
    active: jnp.ndarray
    facts: infractions.StepFacts
    events: ep.StepEvents
    route_completion: jnp.ndarray
    plan: jnp.ndarray | None = None


def _near_route(lines, route, m: int):
    """Rows of the ``m`` polylines of ``lines`` closest to the route (-1 padded)."""
    # Distance from each polyline point to the nearest route point (coarse: every 4th).
    # A running minimum over the route points, one elementwise step each, from
    # x and y planes, and one sqrt per polyline: XLA:CPU runs a reduction over
    # minor axes element by element, and this search was 80 % of ``reset``
    # (10-20x faster, the same rows; docs/performance.md). A fori_loop unrolled
    # 13 at a time: fully unrolled in Python it lowered 0.5 s slower from the cache.
    rx = jnp.where(route.valid[::4], route.xy[::4, 0], jnp.inf)
    ry = jnp.where(route.valid[::4], route.xy[::4, 1], jnp.inf)
    x, y = lines.xy[..., 0], lines.xy[..., 1]

    def nearer(i, d2):
        dx, dy = x - rx[i], y - ry[i]
        return jnp.minimum(d2, dx * dx + dy * dy)

    d2 = jax.lax.fori_loop(0, rx.shape[0], nearer, jnp.full(x.shape, jnp.inf, x.dtype), unroll=13)
    dmin = jnp.sqrt(jnp.where(lines.point_valid, d2, jnp.inf).min(axis=1))
    dmin = jnp.where(lines.valid, dmin, jnp.inf)
    k = min(m, dmin.shape[0])
    _, idx = jax.lax.top_k(-dmin, k)
    idx = jnp.where(jnp.isfinite(dmin[idx]), idx, -1)
    if k < m:
        idx = jnp.pad(idx, (0, m - k), constant_values=-1)
    return idx.astype(jnp.int32)


def _candidate_lanes(scenario: Scenario, m: int):
    """Rows of the ``m`` lanes closest to the route (static per episode)."""
    return _near_route(scenario.map.lanes, scenario.route, m)


def _route_stop_arcs(scenario: Scenario):
    """(S,) route arc at which the route crosses each stop line (inf if never)."""
    route = scenario.route
    p, q = route.xy[:-1], route.xy[1:]
    seg_ok = route.valid[:-1] & route.valid[1:]

    def one(line, valid):
        hit = jax.vmap(geometry.segments_intersect, in_axes=(0, 0, None, None))(p, q, line[0], line[1])
        hit = hit & seg_ok & valid
        return jnp.where(hit.any(), route.arc[jnp.argmax(hit)], jnp.inf)

    return jax.vmap(one)(scenario.map.stop_lines, scenario.map.stop_line_valid)


def _lane_rows(scenario: Scenario, idx):
    lanes = scenario.map.lanes
    safe = jnp.maximum(idx, 0)
    return (
        lanes.xy[safe],
        lanes.point_valid[safe] & (idx >= 0)[:, None],
        lanes.valid[safe] & (idx >= 0),
        scenario.map.lane_width[safe],
    )


def _route_markings(scenario: Scenario) -> infractions.MarkingSegments:
    """Painted marking segments of the boundaries nearest the route."""
    idx = _near_route(scenario.map.boundaries, scenario.route, NUM_CANDIDATE_BOUNDARIES)
    safe = jnp.maximum(idx, 0)
    bl = scenario.map.boundaries
    return infractions.marking_segments(
        bl.xy[safe], bl.point_valid[safe], bl.valid[safe] & (idx >= 0), scenario.map.boundary_marking[safe]
    )


def _route_speed_limits(scenario: Scenario, idx):
    lane_xy, lane_pv, lane_ok, _ = _lane_rows(scenario, idx)
    limit = scenario.map.lane_speed_limit[jnp.maximum(idx, 0)]
    return route_speed_limits(scenario.route, lane_xy, lane_pv, lane_ok, limit)


class Simulator:
    """``reset(key, scenario)`` and ``step(scenario, state, action)``.

    Holds only the static ``SimConfig``; every method is a pure function of
    its arguments and may be jitted / vmapped.
    """

    def __init__(self, config: SimConfig | None = None):
        self.config = config or SimConfig()

    @property
    def _nuplan(self) -> bool:
        """The ``nuplan`` preset: TTC's obstacle discs and collision memory are carried."""
        return self.config.score.name == "nuplan"

    # -- helpers -----------------------------------------------------------
    def agents(self, scenario: Scenario, t, state: SimState | None = None):
        """The other agents at time ``t`` (s), the ego's row marked invalid
        (``replay.AgentStates``, (A, ...)). With IDM agents (``SimConfig.agents``)
        they depend on the episode: pass its ``state``, whose time ``t`` must be
        (its ``reactive.IDMState.agents``)."""
        if self.config.agents == "idm":
            if state is None:
                raise ValueError("Simulator.agents: with agents='idm' the positions depend on the episode; pass state=")
            agents = state.idm.agents
        else:
            agents = replay.agents_at(scenario.tracks, t, scenario.dt_log)
        not_ego = jnp.arange(agents.valid.shape[0]) != scenario.ego_index
        return agents.replace(valid=agents.valid & not_ego)

    def _privileged(self, scenario: Scenario, ego: EgoState) -> Privileged:
        cfg = self.config
        tracks, e = scenario.tracks, scenario.ego_index
        nxt = replay.ego_log_at(tracks, e, ego.t + cfg.dt, scenario.dt_log)
        # Receding horizon (SimConfig.log_horizon_s): aim at the logged position h ahead,
        # h shortened to the log's last valid sample, one step where the log has a gap there.
        valid = tracks.valid[e]
        last = jnp.max(jnp.where(valid, jnp.arange(valid.shape[0]), 0)) * scenario.dt_log
        h = jnp.clip(last - ego.t, cfg.dt, max(cfg.log_horizon_s, cfg.dt))
        far = replay.ego_log_at(tracks, e, ego.t + h, scenario.dt_log)
        use_far = far.valid & nxt.valid
        h = jnp.where(use_far, h, cfg.dt)
        target_xy = jnp.where(use_far, far.xy, nxt.xy)
        target_yaw = jnp.where(use_far, far.yaw, nxt.yaw)
        controls = cfg.dynamics_model.inverse(ego, target_xy, target_yaw, h, cfg.dynamics)
        return Privileged(ego=ego, log_next_xy=nxt.xy, log_next_yaw=nxt.yaw, log_valid=nxt.valid, log_controls=controls)

    def observe(self, scenario: Scenario, state: SimState, assets=None) -> Observation:
        """The observation of ``state`` (what ``reset`` / ``step`` return).

        A pure function of the state: a rollout may render it right before the
        policy reads it (``step(..., observe=False)``), so under ``jit`` the
        outputs the policy does not read are never computed and nothing large
        rides in the scan carry. ``assets`` as in ``reset``."""
        return self._observe(scenario, state, self.agents(scenario, state.ego.t, state), state.obs_key, assets)

    def _observe(self, scenario: Scenario, state: SimState, agents, key, assets=None) -> Observation:
        lane_xy, lane_pv, _, _ = _lane_rows(scenario, state.ctx.lanes)
        signals = replay.signals_at(scenario.signals, state.ego.t, scenario.dt_log)
        obs = observe(
            ego=state.ego,
            agents=agents,
            size=scenario.tracks.size,
            category=scenario.tracks.category,
            route=scenario.route,
            route_index=ep.route_index(state.episode),
            progress_arc=ep.progress_arc(state.episode, scenario.route),
            lane_xy=lane_xy,
            lane_valid=lane_pv,
            stop_arc=state.ctx.stop_arc,
            stop_state=signals,
            speed_limit=state.ctx.speed_limit[ep.route_index(state.episode)],
            privileged=self._privileged(scenario, state.ego),
            key=key,
            cfg=self.config.obs,
        )
        if not self.config.sensors.enabled:
            return obs
        ctx = sensors.SensorContext(scenario=scenario, ego=state.ego, ego_lw=state.ctx.ego_lw, agents=agents,
                                    stop_state=signals, route_index=ep.route_index(state.episode),
                                    assets=assets, key=key)
        return sensors.to_observation(obs, sensors.render(self.config.sensors, ctx))

    def episode_steps(self, scenario: Scenario):
        """() int32 number of steps this scenario runs at most."""
        dur = scenario.duration
        for cap in (self.config.max_episode_s, self.config.score.time_cap_s):
            if cap is not None:
                dur = jnp.minimum(dur, cap)
        return jnp.floor(dur / self.config.dt + 1e-4).astype(jnp.int32)

    # -- public ------------------------------------------------------------
    def reset(self, key, scenario: Scenario, assets=None) -> tuple[SimState, Observation]:
        """Ego on its logged pose at t = 0; criteria initialised on the route.

        ``assets``: ``observe.sensors.SensorAssets`` of this scenario, needed
        when ``config.sensors`` turns on a sensor that reads the map rasters
        (the BEV; ``SensorConfig.needs_raster``)."""
        tr = scenario.tracks
        i = scenario.ego_index
        ego = self.config.dynamics_model.initial_state(tr.xy[i, 0], tr.yaw[i, 0], tr.vel[i, 0],
                                                      jnp.zeros((), jnp.float32))
        lanes = _candidate_lanes(scenario, NUM_CANDIDATE_LANES)
        path_arc = reactive.path_arc(tr) if self.config.agents == "idm" else None
        ctx = SimContext(
            lanes=lanes,
            markings=_route_markings(scenario),
            stop_dir=infractions.stop_line_directions(scenario.map),
            stop_arc=_route_stop_arcs(scenario),
            ego_lw=tr.size[i, :2],
            speed_limit=_route_speed_limits(scenario, lanes),
            obstacles=infractions.obstacle_sat(scenario.map),
            lanes_index=infractions.lane_index(scenario.map.lane_polygons),
            log_overlap=infractions.logged_overlap_spans(tr, i, tr.size[i, :2]),
            path_arc=path_arc,
            leader_paths=(reactive.leader_paths(tr, path_arc, scenario.map.lanes, scenario.map.lane_width,
                                                scenario.map.lane_successors)
                          if self.config.agents == "idm" else None),
            obstacle_discs=nuplan.obstacle_discs(scenario.map.obstacles) if self._nuplan else None,
        )
        n_overlaps = infractions.logged_overlap_count(
            ctx.log_overlap, self.episode_steps(scenario) * self.config.dt, scenario.dt_log)
        key, k_obs = jax.random.split(key)
        state = SimState(
            ego=ego,
            step=jnp.zeros((), jnp.int32),
            episode=ep.init(scenario.route, self.config.score, log_overlaps=n_overlaps),
            controller=ctl.init_controller_state(self.config.controller),
            ctx=ctx,
            key=key,
            obs_key=k_obs,
            idm=(reactive.init(tr, scenario.dt_log, self.config.idm, ego_index=i)
                 if self.config.agents == "idm" else None),
            collided=(nuplan.init_memory(tr.valid.shape[0], scenario.map.obstacles.valid.shape[0])
                      if self._nuplan else None),
        )
        obs = self._observe(scenario, state, self.agents(scenario, ego.t, state), k_obs, assets)
        return state, obs

    def to_controls(self, state: SimState, action) -> tuple[Controls, ctl.ControllerState, jnp.ndarray]:
        """Sanitised controls for ``action`` and whether it had to be repaired."""
        if isinstance(action, Waypoints):
            wp = action.xy
            bad = ~jnp.all(jnp.isfinite(wp))
            wp = jnp.where(jnp.isfinite(wp), wp, 0.0)
            controls, cstate = ctl.waypoints_to_controls(wp, state.ego.speed, state.controller, self.config.controller)
        elif isinstance(action, Controls):
            controls, cstate, bad = action, state.controller, jnp.zeros((), bool)
        else:
            raise TypeError(f"action must be Controls or Waypoints, got {type(action).__name__}")
        controls, repaired = sanitize_controls(controls)
        return controls, cstate, bad | repaired

    def step(self, scenario: Scenario, state: SimState, action, assets=None, *,
             observe: bool = True) -> tuple[SimState, Observation | None, StepLog]:
        """Advance one ``dt``. A finished episode stays frozen (``active`` False).
        ``assets`` as in ``reset``. ``observe=False``: return ``None`` instead
        of the observation (render it later with ``observe(scenario, state)``;
        identical for a running episode)."""
        cfg = self.config
        active = ~state.episode.done
        controls, cstate, invalid = self.to_controls(state, action)
        ego = cfg.dynamics_model.step(state.ego, controls, cfg.dt, cfg.dynamics)
        # Time from the step count: an accumulated float32 t drifts.
        ego = ego.replace(t=(state.step + 1).astype(jnp.float32) * cfg.dt)
        idm = state.idm
        if cfg.agents == "idm":  # the vehicles react to the ego's new pose and to each other
            idm = reactive.step(idm, scenario.tracks, state.ctx.path_arc, state.ctx.leader_paths, state.ego.t, cfg.dt,
                                scenario.dt_log,
                                ego.xy, ego.yaw, ego.speed, state.ctx.ego_lw, cfg.idm, ego_index=scenario.ego_index)
        agents = self.agents(scenario, ego.t, state.replace(idm=idm))
        signals = replay.signals_at(scenario.signals, ego.t, scenario.dt_log)
        facts, collided = self._facts(scenario, state, ego, agents, signals)
        truncate = state.step + 1 >= self.episode_steps(scenario)
        episode, events = ep.update(
            state.episode, scenario.route, ego, facts, invalid, truncate, cfg.dt, cfg.score
        )
        key, k_obs = jax.random.split(state.key)
        new = SimState(ego=ego, step=state.step + 1, episode=episode, controller=cstate, ctx=state.ctx, key=key,
                       obs_key=k_obs, idm=idm, collided=collided)
        # Freeze finished episodes: keep the old state, record nothing (the
        # per-episode constants in ctx need no select).
        new = jax.tree_util.tree_map(lambda a, b: jnp.where(active, a, b), new.replace(ctx=None), state.replace(ctx=None))
        new = new.replace(ctx=state.ctx)
        # = ``observe(scenario, new)`` for a running episode (its agents are at
        # the new time already); a frozen episode's observation is never acted on.
        obs = self._observe(scenario, new, agents, k_obs, assets) if observe else None
        log = StepLog(
            t=new.ego.t,
            xy=new.ego.xy,
            yaw=new.ego.yaw,
            speed=new.ego.speed,
            accel=new.ego.accel,
            steer=new.ego.steer,
            yaw_rate=new.ego.yaw_rate,
            throttle=controls.throttle,
            brake=controls.brake,
            steer_cmd=controls.steer,
            active=active,
            facts=facts,
            events=jax.tree_util.tree_map(lambda e: jnp.where(active, e, jnp.zeros_like(e)), events),
            route_completion=new.episode.route_completion,
        )
        return new, obs, log

    def _facts(self, scenario: Scenario, state: SimState, ego: EgoState, agents, signals):
        tr = scenario.tracks
        lw = state.ctx.ego_lw
        near, near_ok = infractions.nearest_rows(ego, agents)
        # A pair already overlapping in the log is not tested while that lasts.
        exempt = infractions.logged_overlap_exempt(state.ctx.log_overlap[near], ego.t, scenario.dt_log)
        overlap = infractions.candidate_overlaps(ego, lw, agents, tr.size, near)
        hit, hit_id, hit_cls, hit_cat, hit_row = infractions.agent_contacts(
            ego, lw, agents, tr.size, tr.category, tr.track_id, near, near_ok & ~exempt, overlap=overlap
        )
        red, red_i, red_lines = infractions.red_light_crossing(
            state.ego, ego, lw[0], scenario.map, state.ctx.stop_dir, signals
        )
        lane_xy, lane_pv, lane_ok, lane_w = _lane_rows(scenario, state.ctx.lanes)
        off, offset = infractions.lane_status(ego, lane_xy, lane_pv, lane_ok, lane_w)
        rear_offset = getattr(self.config.dynamics, "lr", 0.0)
        lanes = infractions.ego_lanes(ego, lw, rear_offset, state.ctx.lanes_index, scenario.map)
        multi_lane = lanes.multi_lane
        excess = infractions.drivable_excess(ego, lw, scenario.map)
        kind = infractions.collision_type(
            ego, lw, rear_offset, agents.xy[hit_row], agents.yaw[hit_row], tr.size[hit_row, :2],
            geometry.safe_norm(agents.vel[hit_row]),
        )
        kind = jnp.where(hit, kind, -1)
        bg, bg_ok = infractions.background_speed(ego, agents, tr.category)
        invaded, invaded_marking = infractions.lane_invasion(state.ego, ego, lw, state.ctx.markings)
        facts = infractions.StepFacts(
            agent_hit=hit,
            agent_hit_id=hit_id,
            agent_hit_class=hit_cls,
            agent_hit_category=hit_cat,
            layout_hit=infractions.layout_contact(ego, lw, state.ctx.obstacles),
            red_light=red,
            red_light_index=red_i,
            red_light_lines=red_lines,
            off_lane=off,
            lane_offset=offset,
            bg_speed=bg,
            bg_present=bg_ok,
            front_distance=infractions.front_distance(ego, lw, agents, tr.size),
            lane_invasion=invaded,
            lane_invasion_marking=invaded_marking,
            collision_type=kind,
            at_fault=hit & infractions.at_fault(kind, multi_lane, excess),
            multi_lane=multi_lane,
            lanes_overflow=lanes.overflow,
            drivable_excess_m=excess,
            speed_limit=state.ctx.speed_limit[ep.route_index(state.episode)],
        )
        preset = self.config.score.name
        if preset not in ("nuplan", "navsim"):
            return facts, state.collided
        # Every overlapping candidate and obstacle (nuPlan / NAVSIM count each track, once).
        ob_hit = infractions.layout_contacts(ego, lw, state.ctx.obstacles)
        facts = facts.replace(
            layout_hit=ob_hit.any(),
            contacts=infractions.contact_set(ego, lw, rear_offset, agents, tr.size, tr.category, tr.track_id, near,
                                             overlap & near_ok & ~exempt, multi_lane, excess, ob_hit))
        wheelbase = getattr(self.config.dynamics, "wheelbase", nuplan.DEFAULT_WHEELBASE)
        if preset == "navsim":
            return facts.replace(navsim=navsim.tick(
                ego, lw, agents, tr.size, near, near_ok, lanes.centre_in, lanes.rear_in, lanes.tangent,
                lanes.connector, multi_lane=multi_lane, off_drivable=excess > 0.0, wheelbase=wheelbase,
                centre_offset=lanes.centre_offset)), None
        # nuPlan drops a track from TTC at its first contact for the rest of the episode.
        collided = nuplan.remember(state.collided, near, overlap & near_ok, ob_hit)
        # nuPlan looks sideways for TTC between lanes, off the drivable area and in the junction.
        wide = multi_lane | (excess > 0.0) | jnp.any(lanes.centre_in & lanes.connector)
        return facts.replace(nuplan=nuplan.tick(
            state.ego.xy, ego, lw, agents, tr.size, lanes.centre_in, lanes.tangent, collided=collided.agents,
            obstacles=state.ctx.obstacles, discs=state.ctx.obstacle_discs, obstacle_collided=collided.obstacles,
            wide_view=wide, wheelbase=wheelbase)), collided


def sanitize_controls(c: Controls) -> tuple[Controls, jnp.ndarray]:
    """Clamp to the valid ranges; NaN/inf -> full brake, no steer.

    Returns the repaired controls and whether anything was out of range or
    non-finite (counted as ``invalid_action`` for the scenario; never allowed
    to poison other scenarios of the batch).
    """
    vals = jnp.stack([c.throttle, c.brake, c.steer]).astype(jnp.float32)
    finite = jnp.all(jnp.isfinite(vals))
    lo = jnp.array([0.0, 0.0, -1.0])
    hi = jnp.array([1.0, 1.0, 1.0])
    in_range = jnp.all((vals >= lo - 1e-6) & (vals <= hi + 1e-6))
    clipped = jnp.clip(jnp.where(jnp.isfinite(vals), vals, 0.0), lo, hi)
    safe = jnp.where(finite, clipped, jnp.array([0.0, 1.0, 0.0]))
    return Controls(throttle=safe[0], brake=safe[1], steer=safe[2]), ~(finite & in_range)
