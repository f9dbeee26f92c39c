"""One episode's leaderboard bookkeeping: criteria carries, per-step events,
and the final per-route score.

``sim.step`` calls ``update`` once per tick with the tick's geometric facts
(``infractions.StepFacts``); the rollout calls ``finalize`` once at the end.
Everything is unbatched and jittable; ``vmap`` over scenarios.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax.metrics import criteria as cr
from drivee2e_jax.metrics.driving_score import INFRACTION_KEYS, RouteOutcome, ScoreConfig, route_score, status_name
from drivee2e_jax.types import COLLISION_TYPE_NAMES, Category, CollisionClass, Route

#: Default lane speed limit for the route-timeout budget, m/s (50 km/h).
SPEED_LIMIT = 13.9

#: Count columns of the per-scenario results, in order.
COUNT_COLUMNS = (
    "collisions_pedestrian",
    "collisions_vehicle",
    "collisions_layout",
    "red_light",
    "outside_route_lanes",
    "min_speed_infractions",
    "route_dev",
    "vehicle_blocked",
    "route_timeout",
    "invalid_action",
    "collisions_cyclist_motorcycle",
)


@struct.dataclass
class EpisodeCarry:
    """Criteria state and counters of one episode.

    Attributes:
      rc, in_route, outside, collision, blocked, timeout, min_speed, red:
        the ``metrics.criteria`` carries.
      collisions_pedestrian, collisions_vehicle, collisions_layout, red_light:
        () int32 counted events.  collisions_two_wheeler: () int32 vehicle
        collisions with a cyclist / motorcycle (finer class, also in vehicle).
      collisions_pedestrian_at_fault, collisions_vehicle_at_fault,
      collisions_layout_at_fault: () int32 the counted collisions that were
        the ego's fault (``infractions.at_fault``; layout always).
      invalid_action: () int32 steps whose action had to be repaired.
      done: () bool route ended (completed, deviated, blocked, timed out, cut).
      truncated: () bool ended by the episode cap / end of the log.
      t_end: () s simulated time when it ended (or now).
      log_overlaps: () int32 agents whose LOGGED box already overlaps the
        logged ego's when the two first appear together, by the end of the
        episode (a property of the log, set at reset; contacts with them are
        ignored while that overlap lasts: ``infractions.logged_overlap_spans``).
    """

    rc: cr.RouteCompletionCarry
    in_route: cr.InRouteCarry
    outside: cr.OutsideLanesCarry
    collision: cr.CollisionCarry
    blocked: cr.BlockedCarry
    timeout: cr.RouteTimeoutCarry
    min_speed: cr.MinSpeedCarry
    red: cr.RedLightCarry
    collisions_pedestrian: jnp.ndarray
    collisions_vehicle: jnp.ndarray
    collisions_layout: jnp.ndarray
    collisions_two_wheeler: jnp.ndarray
    collisions_pedestrian_at_fault: jnp.ndarray
    collisions_vehicle_at_fault: jnp.ndarray
    collisions_layout_at_fault: jnp.ndarray
    red_light: jnp.ndarray
    invalid_action: jnp.ndarray
    done: jnp.ndarray
    truncated: jnp.ndarray
    t_end: jnp.ndarray
    log_overlaps: jnp.ndarray

    @property
    def route_completion(self):
        return self.rc.value


@struct.dataclass
class StepEvents:
    """Events counted in one step (what ``extract_events`` turns into records).

    Attributes:
      collision: () bool a collision counted.  collision_class: () int32
      ``CollisionClass`` (-1 none).  collision_id: () int32 other track id
      (-1 static).  collision_category: () int32 ``Category`` (-1 static).
      collision_type: () int32 ``infractions.CollisionType`` of an agent
      contact (-1 none or static).  collision_at_fault: () bool the counted
      collision was the ego's fault (a static one always).
      red_light: () bool.  red_light_index: () int32 stop line row.
      route_deviation, blocked, route_timeout, completed, truncated: () bool.
      invalid_action: () bool.
    """

    collision: jnp.ndarray
    collision_class: jnp.ndarray
    collision_id: jnp.ndarray
    collision_category: jnp.ndarray
    collision_type: jnp.ndarray
    collision_at_fault: jnp.ndarray
    red_light: jnp.ndarray
    red_light_index: jnp.ndarray
    route_deviation: jnp.ndarray
    blocked: jnp.ndarray
    route_timeout: jnp.ndarray
    completed: jnp.ndarray
    truncated: jnp.ndarray
    invalid_action: jnp.ndarray


def init(route: Route, cfg: ScoreConfig, log_overlaps=0) -> EpisodeCarry:
    """The criteria at the start of an episode. ``log_overlaps``: () int32
    agents already overlapping the ego in the log (``EpisodeCarry``)."""
    i0 = jnp.zeros((), jnp.int32)
    f0 = jnp.zeros((), jnp.float32)
    b0 = jnp.zeros((), bool)
    return EpisodeCarry(
        rc=cr.route_completion_init(),
        in_route=cr.in_route_init(),
        outside=cr.outside_lanes_init(),
        collision=cr.collision_init(),
        blocked=cr.blocked_init(),
        timeout=cr.route_timeout_init(),
        min_speed=cr.min_speed_init(cfg.min_speed_checkpoints, capacity=cfg.min_speed_checkpoints + 1),
        red=cr.red_light_init(),
        collisions_pedestrian=i0,
        collisions_vehicle=i0,
        collisions_layout=i0,
        collisions_two_wheeler=i0,
        collisions_pedestrian_at_fault=i0,
        collisions_vehicle_at_fault=i0,
        collisions_layout_at_fault=i0,
        red_light=i0,
        invalid_action=i0,
        done=b0,
        truncated=b0,
        t_end=f0,
        log_overlaps=jnp.asarray(log_overlaps, jnp.int32),
    )


def route_index(carry: EpisodeCarry):
    """() int32 the route point the ego last passed (RouteCompletionTest's)."""
    return carry.rc.index


def progress_arc(carry: EpisodeCarry, route: Route):
    """() route arc of the ego's progress, m."""
    return route.arc[carry.rc.index]


def update(carry: EpisodeCarry, route: Route, ego, facts, invalid, truncate, dt, cfg: ScoreConfig):
    """One tick of every enabled criterion. Returns (carry, StepEvents)."""

    rc, completed = cr.route_completion_update(carry.rc, route, ego.xy, cfg.rc_threshold, cfg.rc_distance_m)
    in_route, deviated = cr.in_route_update(carry.in_route, route, ego.xy)
    outside = cr.outside_lanes_update(carry.outside, route, ego.xy, facts.off_lane)
    # Contacts: the replayed agent first (ids >= 1), then static layout (id 0).
    hit = jnp.stack([facts.agent_hit, facts.layout_hit])
    ids = jnp.stack([facts.agent_hit_id + 1, jnp.zeros((), jnp.int32)]).astype(jnp.int32)
    cls = jnp.stack([facts.agent_hit_class, jnp.asarray(CollisionClass.LAYOUT, jnp.int32)])
    collision, tick = cr.collision_update(carry.collision, hit, ids, cls, ego.xy, ego.speed, ego.t)
    blocked, is_blocked = cr.blocked_update(carry.blocked, ego.speed, ego.t, cfg.blocked_max_time_s)
    timeout, timed_out = cr.route_timeout_update(carry.timeout, route, ego.xy, jnp.asarray(SPEED_LIMIT), ego.t)
    # Checkpoints are always sampled (Bench2Drive's efficiency reads them even
    # where they carry no penalty); ``cfg.min_speed`` gates only the penalty.
    min_speed, _ = cr.min_speed_update(carry.min_speed, route, ego.xy, ego.speed, facts.bg_present, facts.bg_speed)
    red, red_events = cr.red_light_update(carry.red, facts.red_light_lines)
    red_event = red_events.any() & cfg.red_light

    coll_on = cfg.collisions
    ev_cls = jnp.where(tick.event & coll_on, tick.cls, -1)
    is_agent = tick.index == 0
    two_wheeler = is_agent & (
        (facts.agent_hit_category == Category.CYCLIST) | (facts.agent_hit_category == Category.MOTORCYCLE)
    )
    vru = (facts.agent_hit_category == Category.PEDESTRIAN) | (facts.agent_hit_category == Category.CYCLIST)
    fault = jnp.where(is_agent, facts.at_fault | (cfg.vru_at_fault & vru), True)
    ev_fault_cls = jnp.where(fault, ev_cls, -1)
    deviated = deviated & cfg.in_route
    is_blocked = is_blocked & cfg.blocked
    timed_out = timed_out & cfg.route_timeout
    ends = completed | deviated | is_blocked | timed_out | truncate
    new = EpisodeCarry(
        rc=rc,
        in_route=in_route,
        outside=outside,
        collision=collision,
        blocked=blocked,
        timeout=timeout,
        min_speed=min_speed,
        red=red,
        collisions_pedestrian=carry.collisions_pedestrian + (ev_cls == CollisionClass.PEDESTRIAN),
        collisions_vehicle=carry.collisions_vehicle + (ev_cls == CollisionClass.VEHICLE),
        collisions_layout=carry.collisions_layout + (ev_cls == CollisionClass.LAYOUT),
        collisions_two_wheeler=carry.collisions_two_wheeler + ((ev_cls == CollisionClass.VEHICLE) & two_wheeler),
        collisions_pedestrian_at_fault=carry.collisions_pedestrian_at_fault + (ev_fault_cls == CollisionClass.PEDESTRIAN),
        collisions_vehicle_at_fault=carry.collisions_vehicle_at_fault + (ev_fault_cls == CollisionClass.VEHICLE),
        collisions_layout_at_fault=carry.collisions_layout_at_fault + (ev_fault_cls == CollisionClass.LAYOUT),
        red_light=carry.red_light + red_event.astype(jnp.int32),
        invalid_action=carry.invalid_action + jnp.asarray(invalid, jnp.int32),
        done=carry.done | ends,
        truncated=carry.truncated | (truncate & ~(completed | deviated | is_blocked | timed_out)),
        t_end=ego.t,
        log_overlaps=carry.log_overlaps,
    )
    events = StepEvents(
        collision=ev_cls >= 0,
        collision_class=ev_cls.astype(jnp.int32),
        collision_id=jnp.where(is_agent, facts.agent_hit_id, -1).astype(jnp.int32),
        collision_category=jnp.where(is_agent, facts.agent_hit_category, -1).astype(jnp.int32),
        collision_type=jnp.where(is_agent & (ev_cls >= 0), facts.collision_type, -1).astype(jnp.int32),
        collision_at_fault=(ev_cls >= 0) & fault,
        red_light=red_event,
        red_light_index=jnp.where(red_event, facts.red_light_index, -1).astype(jnp.int32),
        route_deviation=deviated,
        blocked=is_blocked,
        route_timeout=timed_out,
        completed=completed,
        truncated=truncate & ~carry.done,
        invalid_action=jnp.asarray(invalid, bool),
    )
    return new, events


@struct.dataclass
class EpisodeResult:
    """Per-episode scores (unbatched; ``vmap`` for a batch).

    Attributes:
      route_completion, infraction_score, driving_score: () float (RC, DS in %).
      success: () bool.  status: () int32 ``driving_score.Status``.
      infractions: (12,) int32 entries per ``driving_score.INFRACTION_KEYS``.
      outside_lanes_pct: () float % of traversed route driven off-lane.
      outside_lanes_m: () float route distance passed while off-lane, m.
      collisions_two_wheeler, invalid_action: () int32.
      episode_s: () float simulated seconds until the episode ended.
      min_speed_pct: (K,) float ego / surrounding-traffic speed per closed
        min-speed checkpoint, % (recorded whether or not it is penalised).
      min_speed_valid: (K,) bool the checkpoint closed with samples.
      log_overlaps: () int32 agents overlapping the ego in the log itself
        (``EpisodeCarry.log_overlaps``; not an infraction).
      infraction_score_all, driving_score_all, success_all: the score with
        every collision counted; ``*_at_fault``: with only the ego's at-fault
        collisions (``ScoreConfig.collision_mode`` picks which one the
        headline ``infraction_score`` / ``driving_score`` / ``success`` /
        ``status`` are; ``infractions`` always holds every counted event).
      collisions_at_fault: () int32 counted collisions that were at fault.
    """

    route_completion: jnp.ndarray
    infraction_score: jnp.ndarray
    driving_score: jnp.ndarray
    success: jnp.ndarray
    status: jnp.ndarray
    infractions: jnp.ndarray
    outside_lanes_pct: jnp.ndarray
    outside_lanes_m: jnp.ndarray
    collisions_two_wheeler: jnp.ndarray
    invalid_action: jnp.ndarray
    episode_s: jnp.ndarray
    min_speed_pct: jnp.ndarray
    min_speed_valid: jnp.ndarray
    log_overlaps: jnp.ndarray
    infraction_score_all: jnp.ndarray
    driving_score_all: jnp.ndarray
    success_all: jnp.ndarray
    infraction_score_at_fault: jnp.ndarray
    driving_score_at_fault: jnp.ndarray
    success_at_fault: jnp.ndarray
    collisions_at_fault: jnp.ndarray


def finalize(carry: EpisodeCarry, route: Route, cfg: ScoreConfig) -> EpisodeResult:
    """Close the min-speed checkpoints and score the route (LB 2.0 rules)."""
    ms, _ = cr.min_speed_finalize(carry.min_speed, route)
    k = ms.values.shape[-1]
    outcome = RouteOutcome.empty(k).replace(
        route_completion=carry.rc.value,
        collisions_pedestrian=carry.collisions_pedestrian,
        collisions_vehicle=carry.collisions_vehicle,
        collisions_layout=carry.collisions_layout,
        red_light=carry.red_light,
        outside_lanes_m=jnp.where(cfg.outside_lanes, carry.outside.wrong, 0.0),
        outside_lanes_pct=cr.outside_lanes_percentage(carry.outside),
        min_speed_pct=ms.values,
        min_speed_valid=ms.valid & cfg.min_speed,
        route_deviation=carry.in_route.deviated,
        vehicle_blocked=carry.blocked.blocked,
        route_timeout=carry.timeout.timed_out,
        tick_runtime=carry.truncated & ~carry.rc.completed,
    )
    score_all = route_score(outcome, cfg)
    score_af = route_score(outcome.replace(
        collisions_pedestrian=carry.collisions_pedestrian_at_fault,
        collisions_vehicle=carry.collisions_vehicle_at_fault,
        collisions_layout=carry.collisions_layout_at_fault,
    ), cfg)
    score = score_af if cfg.collision_mode == "at_fault" else score_all
    return EpisodeResult(
        route_completion=score.route_completion,
        infraction_score=score.infraction_penalty,
        driving_score=score.driving_score,
        success=score.success,
        status=score.status,
        infractions=score_all.infractions,
        outside_lanes_pct=jnp.where(cfg.outside_lanes, outcome.outside_lanes_pct, 0.0),
        outside_lanes_m=score.outside_lanes_m,
        collisions_two_wheeler=carry.collisions_two_wheeler,
        invalid_action=carry.invalid_action,
        episode_s=carry.t_end,
        min_speed_pct=ms.values,
        min_speed_valid=ms.valid,
        log_overlaps=carry.log_overlaps,
        infraction_score_all=score_all.infraction_penalty,
        driving_score_all=score_all.driving_score,
        success_all=score_all.success,
        infraction_score_at_fault=score_af.infraction_penalty,
        driving_score_at_fault=score_af.driving_score,
        success_at_fault=score_af.success,
        collisions_at_fault=(carry.collisions_pedestrian_at_fault + carry.collisions_vehicle_at_fault
                             + carry.collisions_layout_at_fault),
    )


def counts_dict(res: EpisodeResult) -> dict[str, np.ndarray]:
    """Host-side: count columns (``COUNT_COLUMNS``, then ``log_overlaps``: the
    agents overlapping the ego in the log, not an infraction) as arrays over the batch."""
    inf = np.asarray(res.infractions)
    out = {k: inf[..., INFRACTION_KEYS.index(k)] for k in COUNT_COLUMNS if k in INFRACTION_KEYS}
    out["invalid_action"] = np.asarray(res.invalid_action)
    out["collisions_cyclist_motorcycle"] = np.asarray(res.collisions_two_wheeler)
    out["log_overlaps"] = np.asarray(res.log_overlaps)
    out["collisions_at_fault"] = np.asarray(res.collisions_at_fault)
    return out


_CLASS_EVENT = {0: "collisions_pedestrian", 1: "collisions_vehicle", 2: "collisions_layout"}


def extract_events(log) -> list[dict]:
    """Host-side: one episode's ``StepLog`` (numpy, (T, ...)) -> event records.

    Each record has ``type`` (an infraction key), ``t`` (s), ``x``, ``y`` (m)
    and type-specific fields (``other_track_id``, ``other_category``,
    ``collision_type`` (``infractions.COLLISION_TYPE_NAMES`` or "static"),
    ``at_fault``, ``stop_line``).
    """

    e = log.events
    out = []
    for i in np.flatnonzero(np.asarray(log.active)):
        base = {"t": round(float(log.t[i]), 3), "x": round(float(log.xy[i, 0]), 3), "y": round(float(log.xy[i, 1]), 3)}
        if e.collision[i]:
            rec = {"type": _CLASS_EVENT[int(e.collision_class[i])], **base}
            if e.collision_id[i] >= 0:
                rec["other_track_id"] = int(e.collision_id[i])
                rec["other_category"] = Category(int(e.collision_category[i])).name.lower()
            kind = int(e.collision_type[i])
            rec["collision_type"] = COLLISION_TYPE_NAMES[kind] if kind >= 0 else "static"
            rec["at_fault"] = bool(e.collision_at_fault[i])
            out.append(rec)
        if e.red_light[i]:
            out.append({"type": "red_light", **base, "stop_line": int(e.red_light_index[i])})
        for flag, name in (
            (e.route_deviation, "route_dev"),
            (e.blocked, "vehicle_blocked"),
            (e.route_timeout, "route_timeout"),
            (e.completed, "route_completed"),
            (e.truncated, "episode_cut"),
        ):
            if flag[i]:
                out.append({"type": name, **base})
        if e.invalid_action[i]:
            out.append({"type": "invalid_action", **base})
    return out


__all__ = [
    "COUNT_COLUMNS",
    "EpisodeCarry",
    "EpisodeResult",
    "StepEvents",
    "counts_dict",
    "extract_events",
    "finalize",
    "init",
    "progress_arc",
    "route_index",
    "status_name",
    "update",
]
