"""nuPlan's closed-loop score (CLS): the ``--preset nuplan`` scoring.

What: the eight per-scenario metrics nuPlan's closed-loop challenges score
(``nuplan/planning/script/config/common/simulation_metric/
simulation_closed_loop_nonreactive_agents.yaml``) and their combination by
``WeightedAverageMetricAggregator._compute_scenario_score``
(``nuplan/planning/metrics/aggregator/weighted_average_metric_aggregator.py``,
weights in ``nuplan/planning/script/config/simulation/metric_aggregator/
closed_loop_nonreactive_agents_weighted_average.yaml``)::

    score = (no_ego_at_fault_collisions * drivable_area_compliance
             * ego_is_making_progress * driving_direction_compliance)
            * (5 progress + 5 ttc + 4 speed_limit + 2 comfortable) / 16

Why two halves: the parts that need the world at every tick (time to
collision against the replayed agents, travel against a lane's direction)
are a cheap pure-JAX ``tick`` that runs inside the batched rollout and lands
in ``StepFacts.nuplan``; everything else is a host-side (numpy) function of
one episode's stacked ``StepLog`` (``episode_columns``), like the other
fine-grained columns.

Adaptations from nuPlan (all sources are motional/nuplan-devkit):

======================================  ==========================================================
nuPlan                                  here
======================================  ==========================================================
map polygons (lanes, lane connectors,   the drivable area is the union of the map's drivable
roadblocks, DRIVABLE_AREA layer)        polygons, exact (``infractions.drivable_excess``; nuPlan
                                        also accepts a corner in the ego centre's lane polygon,
                                        inside that area on these maps); lanes are centrelines
                                        +- width/2; a junction is a CONNECTOR lane
20 Hz history, us timestamps            the sim's steps (10 Hz by default), ``StepLog.t`` in s;
                                        only ``active`` steps are samples
expert route = roadblocks the expert    ``scenario.route`` (the logged ego path at 1 m): progress
drives through; progress per roadblock  = arc of the foot point on that polyline (ego vs logged ego
baseline (``PerFrameProgress...``)      over the same duration), not summed per roadblock
TTC: ``observation.tracked_objects``    every replayed agent and every static map obstacle (speed
incl. static objects (speed 0)          0, its polygon; ahead/behind from its vertex mean) that is
                                        relevant and not collided; culled to <= 16 agents and <= 8
                                        obstacles by a closest-approach reach bound that keeps every
                                        one that can overlap (``ttc_candidates``); ``ttc_overflow``
                                        flags a tick where more qualified (``ttc_reachable``)
TTC: tracks collided earlier are        exact: ``CollisionMemory`` (per-episode, nuplan preset)
excluded at later ticks                 holds every track / obstacle touched so far; a new at-fault
                                        contact sets that tick's TTC to 0 on the host, as nuPlan
TTC lateral tracks while "not in        ``wide_view`` argument: the caller passes
common/connected route objs" or in an   ``multi_lane | on a connector``
intersection
driving direction: progress along the   ``oncoming_m``: travel against the nearest lane holding
baseline of the lane/connector the ego  the ego centre (within width/2) that runs against the
centre is in, summed over 1 s windows   heading, only when no lane running its way holds it; the
                                        windows sum these (travel with the lane never offsets)
collision classes VRU (pedestrian,      PEDESTRIAN, CYCLIST -> VRU; every other ``Category`` ->
bicycle), vehicle, object; every        vehicle; every overlapping candidate of the 16 nearest
track overlapping at a tick is new      agents counts (``StepFacts.contacts``); static obstacles
once per scenario                       -> object, each obstacle row once, at its first contact, at
                                        fault only if the ego moves > 0.05 m/s then (stopped ego:
                                        not at fault, as nuPlan)
comfort: ``center_acceleration_2d``    ``ego_comfort_inputs``: nuPlan's bicycle-model state rebuilt
x / y for the lon / lat bounds, the     from the step log: rear-axle acceleration (a_r, 0) with a_r
rear-axle acceleration's magnitude      = d/dt (speed * cos beta) (no lateral term, as nuPlan's
for the jerk; 20 Hz, the first sample   ``KinematicBicycleModel``); centre x = a_r + lr (w^2 + dw/dt),
the logged state's IMU values           centre y = 0 (nuPlan's ``get_acceleration_shifted``); jerk of
                                        |a_r|; the first sample is the first simulated step
comfort on < 3-5 samples: raises        a signal too short for its Savitzky-Golay fit is not
                                        checked (counts as within bounds)
======================================  ==========================================================

Every column is a float in [0, 1] and never None (nuPlan's aggregator skips
None columns and renormalises the weights; the only "skip" case of the
progress metric, no expert route, scores 1.0 in nuPlan and here too).
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from scipy.signal import savgol_filter

from drivee2e_jax import geometry
from drivee2e_jax.dynamics import BicycleParams
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import Category, EgoState

Array = jnp.ndarray

# --------------------------------------------------------------------------
# Constants (plain Python floats: no JAX backend at import)
# --------------------------------------------------------------------------

#: TTC projection step and horizon, s (``time_to_collision_within_bound_statistics.yaml``).
TTC_STEP_S = 0.1
TTC_HORIZON_S = 3.0
#: Number of projection steps: ``len(np.arange(0.1, 3.0, 0.1))`` = 29 (0.1 ... 2.9 s),
#: the loop of ``_compute_time_to_collision_at_timestamp``.
TTC_STEPS = 29
#: TTC must be strictly above this, s (``least_min_ttc``).
TTC_LEAST_MIN_S = 0.95
#: ``get_collision_type`` (utils/collision_utils.py) stopped_speed_threshold: a contact
#: while the ego is at or below it is STOPPED_EGO_COLLISION (not at fault), m/s.
COLLISION_STOPPED_SPEED = 5e-2
#: Ego at or below this speed is "stopped": TTC not evaluated (``compute_time_to_collision``), m/s.
TTC_STOPPED_SPEED = 5e-3
#: ``is_agent_ahead`` / ``is_agent_behind`` angle tolerances (idm/utils.py), rad.
AHEAD_ANGLE = math.radians(30.0)
BEHIND_ANGLE = math.radians(150.0)
#: nuPlan's ego reference for ahead/behind is the rear axle: centre - wheelbase / 2.
DEFAULT_WHEELBASE = BicycleParams.wheelbase

#: no_ego_at_fault_collisions thresholds (VRU, vehicle, object).
COLLISION_THRESHOLDS = (0, 0, 1)
#: Categories counted as VRUs (nuPlan ``VRU_types``: PEDESTRIAN, BICYCLE).
VRU_CATEGORIES = (int(Category.PEDESTRIAN), int(Category.CYCLIST))
#: drivable_area_compliance ``max_violation_threshold``, m.
DRIVABLE_MAX_VIOLATION_M = 0.3
#: driving_direction_compliance thresholds (m) and window (s).
DIRECTION_COMPLIANCE_M = 2.0
DIRECTION_VIOLATION_M = 6.0
DIRECTION_HORIZON_S = 1.0
#: ego_progress_along_expert_route ``score_progress_threshold``, m.
PROGRESS_THRESHOLD_M = 2.0
#: ego_is_making_progress ``min_progress_threshold`` (ratio).
MIN_PROGRESS_RATIO = 0.2
#: speed_limit_compliance ``max_overspeed_value_threshold``, m/s.
MAX_OVERSPEED_MPS = 2.23
#: Comfort bounds (strict), from the low_level ego_*_statistics.yaml configs.
LON_ACC_BOUNDS = (-4.05, 2.40)  # m/s^2
MAX_ABS_LAT_ACC = 4.89  # m/s^2
MAX_ABS_JERK = 8.37  # m/s^3
MAX_ABS_LON_JERK = 4.13  # m/s^3
MAX_ABS_YAW_ACC = 1.93  # rad/s^2
MAX_ABS_YAW_RATE = 0.95  # rad/s
#: Weighted-average weights (closed_loop_nonreactive_agents_weighted_average.yaml).
WEIGHTS = {
    "nuplan_ego_progress_along_expert_route": 5.0,
    "nuplan_time_to_collision_within_bound": 5.0,
    "nuplan_speed_limit_compliance": 4.0,
    "nuplan_ego_is_comfortable": 2.0,
}
#: Weight of a scored metric not listed in ``WEIGHTS`` (nuPlan's ``default: 1.0``).
DEFAULT_WEIGHT = 1.0
MULTIPLIERS = (
    "nuplan_no_ego_at_fault_collisions",
    "nuplan_drivable_area_compliance",
    "nuplan_ego_is_making_progress",
    "nuplan_driving_direction_compliance",
)
#: Per-episode columns of ``episode_columns``, in order.
COLUMNS = (*MULTIPLIERS, *WEIGHTS, "nuplan_score")


# --------------------------------------------------------------------------
# Per tick (JAX)
# --------------------------------------------------------------------------


#: Agent rows box-tested for TTC per tick: the relevant agents whose closest
#: approach over the horizon passes the reach bound (``ttc_candidates``), nearest
#: approach first. More qualifying sets ``NuplanTick.ttc_overflow``.
TTC_AGENT_CANDIDATES = 16
#: Static obstacles box-tested for TTC per tick (same culling).
TTC_OBSTACLE_CANDIDATES = 8
#: Slack added to the reach bound, m (float32 rounding of the closest approach).
TTC_REACH_SLACK_M = 1e-2


@struct.dataclass
class NuplanTick:
    """nuPlan facts of one tick, one scenario (all scalars).

    Attributes:
      ttc_s:      float32 time to collision, s (a multiple of 0.1 in [0.1, 2.9];
                  inf if none within the horizon, or the ego is stopped).
      oncoming_m: float32 ego travel this tick against the direction of the
                  lane it is on, m (>= 0).
      ttc_reachable: int32 relevant tracks + obstacles not collided so far whose
                  closest approach passes the reach bound (``ttc_candidates``):
                  every one that could overlap the projected ego.
      ttc_overflow: bool more than ``TTC_AGENT_CANDIDATES`` agents or
                  ``TTC_OBSTACLE_CANDIDATES`` obstacles qualified: the furthest
                  approaching ones were not box-tested (TTC may be too high).
    """

    ttc_s: Array
    oncoming_m: Array
    ttc_reachable: Array
    ttc_overflow: Array


@struct.dataclass
class CollisionMemory:
    """Which tracks and obstacles the ego has touched so far in the episode
    (nuPlan's ``collided_track_ids``: excluded from TTC from their first
    contact on, ``extract_tracks_info_excluding_collided_tracks``).

    Attributes:
      agents: (A,) bool per track row.  obstacles: (O,) bool per obstacle row.
    """

    agents: Array
    obstacles: Array


def init_memory(num_agents: int, num_obstacles: int) -> CollisionMemory:
    """Nothing touched yet."""
    return CollisionMemory(agents=jnp.zeros((num_agents,), bool), obstacles=jnp.zeros((num_obstacles,), bool))


def remember(memory: CollisionMemory, near: Array, overlap: Array, obstacle_hit: Array) -> CollisionMemory:
    """``memory`` plus this tick's contacts: candidate rows ``near`` (K,) whose
    box overlaps the ego (``overlap`` (K,) bool, validity applied) and the
    obstacles in ``obstacle_hit`` (O,) bool."""
    agents = memory.agents.at[near].set(memory.agents[near] | overlap)
    return CollisionMemory(agents=agents, obstacles=memory.obstacles | obstacle_hit)


@struct.dataclass
class ObstacleDiscs:
    """A disc around each static obstacle polygon (computed once per episode).

    Attributes:
      centre: (O, 2) mean of the valid vertices, m (a box footprint's centre,
              nuPlan's ``tracked_object.center`` for the ahead/behind test).
      radius: (O,) largest vertex distance from ``centre``, m: the disc holds
              the (convex) polygon.
      valid:  (O,) bool.
    """

    centre: Array
    radius: Array
    valid: Array


def obstacle_discs(obstacles) -> ObstacleDiscs:
    """``ObstacleDiscs`` of ``MapData.obstacles`` (Polylines (O, V))."""
    pv = obstacles.point_valid & obstacles.valid[:, None]
    n = jnp.maximum(pv.sum(-1), 1)[:, None]
    centre = jnp.where(pv[..., None], obstacles.xy, 0.0).sum(1) / n
    r = jnp.where(pv, jnp.linalg.norm(obstacles.xy - centre[:, None], axis=-1), 0.0).max(-1)
    return ObstacleDiscs(centre=centre.astype(jnp.float32), radius=r.astype(jnp.float32), valid=pv.any(-1))


def _heading_vec(yaw: Array) -> Array:
    """(..., 2) unit vector of heading ``yaw`` (...,)."""
    return jnp.stack([jnp.cos(yaw), jnp.sin(yaw)], axis=-1)


def ttc_relevant(ego: EgoState, xy: Array, valid: Array, wide_view: Array, wheelbase: float) -> Array:
    """(K,) bool: which tracks nuPlan projects for TTC.

    ``extract_tracks_info_excluding_collided_tracks``
    (nuplan/planning/metrics/evaluation_metrics/common/time_to_collision_within_bound.py):
    a track counts if it is ahead of the ego's rear axle (relative angle
    < 30 deg, ``is_agent_ahead``), or, while the ego is between lanes / off
    the route objects / in an intersection (``wide_view``), if it is not
    behind (angle > 150 deg, ``is_agent_behind``). A track exactly at the
    rear axle has an undefined angle (NaN in nuPlan): neither.

    Args:
      ego: EgoState (centre xy, yaw).  xy: (K, 2) track centres, m.
      valid: (K,) bool.  wide_view: () bool.  wheelbase: m.
    """
    h = _heading_vec(ego.yaw)
    rel = xy - (ego.xy - 0.5 * wheelbase * h)
    n = jnp.linalg.norm(rel, axis=-1)
    cos = jnp.clip((rel @ h) / jnp.where(n > 0, n, 1.0), -1.0, 1.0)
    angle = jnp.where(n > 0, jnp.arccos(cos), jnp.nan)
    ahead = angle < AHEAD_ANGLE
    behind = angle > BEHIND_ANGLE
    return valid & (ahead | (wide_view & ~behind & (n > 0)))


def closest_approach(ego: EgoState, xy: Array, vel: Array) -> Array:
    """(K,) smallest centre distance, m, between the ego and each track over
    the projection times t in [0.1, 2.9] s, both at constant velocity (ego
    along its heading at its speed; ``vel`` (K, 2) m/s, 0 for a static
    object). A lower bound of the distance at every projected sample."""
    ev = ego.speed * _heading_vec(ego.yaw)
    dp, dv = xy - ego.xy, vel - ev
    t_lo, t_hi = TTC_STEP_S, TTC_STEP_S * TTC_STEPS
    t_star = jnp.clip(-jnp.sum(dp * dv, -1) / jnp.maximum(jnp.sum(dv * dv, -1), 1e-12), t_lo, t_hi)
    return jnp.linalg.norm(dp + dv * t_star[..., None], axis=-1)


def earliest_reach(ego: EgoState, xy: Array, vel: Array, reach: Array) -> Array:
    """(K,) first time t >= 0, s, at which the centres come within ``reach``
    (K,) m at constant velocity (0 if already; inf if never): no box overlap
    can come earlier. The rank of ``ttc_candidates``."""
    ev = ego.speed * _heading_vec(ego.yaw)
    dp, dv = xy - ego.xy, vel - ev
    a = jnp.sum(dv * dv, -1)
    b = jnp.sum(dp * dv, -1)
    c = jnp.sum(dp * dp, -1) - reach * reach
    disc = b * b - a * c
    t = (-b - jnp.sqrt(jnp.maximum(disc, 0.0))) / jnp.maximum(a, 1e-12)
    return jnp.where(c <= 0.0, 0.0, jnp.where((disc >= 0.0) & (b < 0.0) & (a > 1e-12), t, jnp.inf))


def ttc_candidates(gap: Array, eligible: Array, k: int, rank: Array) -> tuple[Array, Array, Array]:
    """Cull the tracks to box-test for TTC, provably keeping every one that can hit.

    Two shapes overlap only if their centres are closer than the sum of the
    radii of discs around each centre that hold them (half the box diagonal;
    ``ObstacleDiscs.radius``); so a track whose ``closest_approach`` over
    [0.1, 2.9] s exceeds that reach (``gap`` > 0) overlaps the projected ego
    at no sample and its TTC is inf. Of the ``eligible`` tracks with ``gap`` <= 0,
    the ``k`` that can touch first (smallest ``rank``, ``earliest_reach``) are kept.

    Args: gap (N,) closest approach - reach, m; eligible (N,) bool; k static;
      rank (N,) s.
    Returns: rows (k,) int32, ok (k,) bool, qualifying () int32 (> k: some were cut).
    """
    can = eligible & (gap <= TTC_REACH_SLACK_M)
    k = min(k, gap.shape[0])
    _, rows = jax.lax.top_k(jnp.where(can, -jnp.minimum(rank, 1e6), -jnp.inf), k)
    return rows, can[rows], jnp.sum(can).astype(jnp.int32)


def time_to_collision(ego: EgoState, ego_lw: Array, xy: Array, yaw: Array, speed: Array, lw: Array,
                      relevant: Array, obstacles: geometry.PolygonSAT | None = None,
                      obstacle_relevant: Array | None = None) -> Array:
    """() float32 nuPlan TTC against K tracks (and static obstacles): earliest projection time, s, or inf.

    ``_compute_time_to_collision_at_timestamp`` (time_to_collision_within_bound.py):
    the ego and every track move at constant speed along their heading
    (``_get_ego_tracks_displacement_info``; a static object has speed 0,
    ``extract_tracks_info_excluding_collided_tracks``); at t = 0.1, 0.2, ..., 2.9 s the
    boxes are tested and the first overlap gives the TTC. nuPlan's
    elongated-box pre-filter (``_get_relevant_tracks``) is only a speed-up
    (an elongated box covers every projected box); here a circle test on
    the closest approach of the centres over the horizon masks the tracks
    that cannot touch, and the box tests run only if one is left.

    Args:
      ego: EgoState (xy, yaw, speed).  ego_lw: (2,) length, width, m.
      xy: (K, 2) m.  yaw: (K,) rad.  speed: (K,) m/s.  lw: (K, 2) m.
      relevant: (K,) bool (``ttc_relevant`` minus tracks collided so far).
      obstacles: (J, ...) ``geometry.PolygonSAT`` static obstacle footprints
        (convex), or None.  obstacle_relevant: (J,) bool.
    """
    ev = ego.speed * _heading_vec(ego.yaw)  # (2,)
    av = speed[:, None] * _heading_vec(yaw)  # (K, 2)
    reach = 0.5 * (jnp.hypot(ego_lw[0], ego_lw[1]) + jnp.hypot(lw[:, 0], lw[:, 1]))
    cand = relevant & (closest_approach(ego, xy, av) <= reach + TTC_REACH_SLACK_M)
    ob_cand = jnp.zeros((0,), bool) if obstacles is None else obstacle_relevant
    steps = TTC_STEP_S * jnp.arange(1, TTC_STEPS + 1, dtype=jnp.float32)  # (S,)

    def boxes(_):
        ego_xy = ego.xy + steps[:, None] * ev  # (S, 2)
        ag_xy = xy[None] + steps[:, None, None] * av[None]  # (S, K, 2)
        per_track = jax.vmap(geometry.boxes_overlap, in_axes=(None, None, None, 0, 0, 0))
        hit = jax.vmap(per_track, in_axes=(0, None, None, 0, None, None))(ego_xy, ego.yaw, ego_lw, ag_xy, yaw, lw)
        hit_s = (hit & cand[None]).any(-1)
        if obstacles is not None:
            per_ob = jax.vmap(geometry.polygon_sat_box_penetration, in_axes=(0, None, None, None))
            depth = jax.vmap(per_ob, in_axes=(None, 0, None, None))(obstacles, ego_xy, ego.yaw, ego_lw)  # (S, J)
            hit_s = hit_s | ((depth > geometry.EPS) & ob_cand[None]).any(-1)
        return jnp.where(hit_s.any(), steps[jnp.argmax(hit_s)], jnp.inf)

    ttc = jax.lax.cond(cand.any() | ob_cand.any(), boxes, lambda _: jnp.float32(jnp.inf), None)
    return jnp.where(ego.speed > TTC_STOPPED_SPEED, ttc, jnp.inf).astype(jnp.float32)


def oncoming_travel(prev_xy: Array, ego: EgoState, centre_in: Array, tangent: Array) -> Array:
    """() float32 ego travel this tick against its lane's direction, m (>= 0).

    ``DrivingDirectionComplianceStatistics._extract_metric``
    (driving_direction_compliance.py) measures the ego centre's progress
    along the baseline of the lane (or connector) it is in; negative progress
    is driving against the lane. Here: the lanes whose POLYGON holds the ego
    centre (``infractions.EgoLanes``); if one of them runs the ego's way
    (tangent . heading >= 0), it is not oncoming (0); otherwise the first
    holding lane gives ``max(0, -(xy - prev_xy) . tangent)``.

    Args:
      prev_xy: (2,) ego centre before the step, m.  ego: EgoState after it.
      centre_in: (M,) bool the lane polygon holds the ego centre.
      tangent: (M, 2) unit lane direction at the ego centre.
    """
    with_ego = tangent @ _heading_vec(ego.yaw) >= 0.0
    against = centre_in & ~with_ego
    j = jnp.argmax(against)
    back = -jnp.dot(ego.xy - prev_xy, tangent[j])
    on_wrong = against.any() & ~(centre_in & with_ego).any()
    return jnp.where(on_wrong, jnp.maximum(back, 0.0), 0.0).astype(jnp.float32)


def tick(prev_xy: Array, ego: EgoState, ego_lw: Array, agents: AgentStates, agent_size: Array,
         centre_in: Array, tangent: Array, *, collided: Array | None = None,
         obstacles: geometry.PolygonSAT | None = None, discs: ObstacleDiscs | None = None,
         obstacle_collided: Array | None = None, wide_view: Array | bool = False,
         wheelbase: float = DEFAULT_WHEELBASE, k: int = TTC_AGENT_CANDIDATES,
         k_obstacles: int = TTC_OBSTACLE_CANDIDATES) -> NuplanTick:
    """nuPlan facts of one tick (pure JAX, one scenario).

    TTC looks at every replayed agent and every static obstacle (nuPlan's
    ``observation.tracked_objects``, static objects at speed 0) that is
    relevant (``ttc_relevant``) and not collided so far; ``ttc_candidates``
    culls them by closest approach (provably keeping every one that can
    overlap the projected ego) to at most ``k`` agents and ``k_obstacles``
    obstacles, and ``ttc_overflow`` says when more qualified.

    Args:
      prev_xy: (2,) ego centre before the step, m.
      ego: EgoState after the step (centre xy, yaw, speed >= 0).
      ego_lw: (2,) ego length, width, m.
      agents: AgentStates (A,) at the tick's time (the ego's row invalid).
      agent_size: (A, 3) length, width, height, m.
      centre_in, tangent: (M,) bool, (M, 2): the lanes whose polygon holds the
        ego centre and their unit direction there (``infractions.EgoLanes``).
      collided: (A,) bool tracks the ego has touched so far, this tick
        included (``CollisionMemory.agents``); None: the agents overlapping
        the ego now (a tick without memory).
      obstacles, discs: (O, ...) ``geometry.PolygonSAT`` and ``ObstacleDiscs``
        of the static obstacles, or None (no obstacles projected).
      obstacle_collided: (O,) bool obstacles touched so far (None: those
        overlapping now).
      wide_view: () bool, the ego is in several lanes / off the lanes / in a
        junction: lateral tracks count for TTC (``ttc_relevant``).
      wheelbase: m, for the rear axle (``dynamics.BicycleParams.wheelbase``).
      k, k_obstacles: static box-test budgets.

    Returns:
      NuplanTick.
    """
    wide = jnp.asarray(wide_view)
    lw_all = agent_size[:, :2]
    if collided is None:
        collided = jax.vmap(geometry.boxes_overlap, in_axes=(None, None, None, 0, 0, 0))(
            ego.xy, ego.yaw, ego_lw, agents.xy, agents.yaw, lw_all)
    speed_all = jnp.linalg.norm(agents.vel, axis=-1)
    vel_all = speed_all[:, None] * _heading_vec(agents.yaw)  # nuPlan: speed along the heading
    reach = 0.5 * (jnp.hypot(ego_lw[0], ego_lw[1]) + jnp.hypot(lw_all[:, 0], lw_all[:, 1]))
    eligible = ttc_relevant(ego, agents.xy, agents.valid & ~collided, wide, wheelbase)
    rows, ok, n_agents = ttc_candidates(closest_approach(ego, agents.xy, vel_all) - reach, eligible, k,
                                        earliest_reach(ego, agents.xy, vel_all, reach))
    overflow = n_agents > rows.shape[0]
    reachable = n_agents
    ob_sat = ob_ok = None
    if obstacles is not None and discs.centre.shape[0] > 0:  # a map may pack no obstacle rows
        if obstacle_collided is None:
            depth = jax.vmap(geometry.polygon_sat_box_penetration, in_axes=(0, None, None, None))(
                obstacles, ego.xy, ego.yaw, ego_lw)
            obstacle_collided = depth > geometry.EPS  # = infractions.layout_contacts
        ob_reach = 0.5 * jnp.hypot(ego_lw[0], ego_lw[1]) + discs.radius
        still = jnp.zeros_like(discs.centre)
        ob_gap = closest_approach(ego, discs.centre, still) - ob_reach
        ob_elig = ttc_relevant(ego, discs.centre, discs.valid & ~obstacle_collided, wide, wheelbase)
        ob_rows, ob_ok, n_obs = ttc_candidates(ob_gap, ob_elig, k_obstacles,
                                               earliest_reach(ego, discs.centre, still, ob_reach))
        ob_sat = jax.tree_util.tree_map(lambda x: x[ob_rows], obstacles)
        overflow = overflow | (n_obs > ob_rows.shape[0])
        reachable = reachable + n_obs
    return NuplanTick(
        ttc_s=time_to_collision(ego, ego_lw, agents.xy[rows], agents.yaw[rows], speed_all[rows], lw_all[rows], ok,
                                ob_sat, ob_ok),
        oncoming_m=oncoming_travel(prev_xy, ego, centre_in, tangent),
        ttc_reachable=reachable.astype(jnp.int32),
        ttc_overflow=overflow,
    )


# --------------------------------------------------------------------------
# Per episode (host, numpy)
# --------------------------------------------------------------------------


def _new_layout_faults(layout_hit, speed) -> np.ndarray:
    """(n,) int: at-fault static-object collisions that begin at each tick.

    A static obstacle is a stopped track: ``get_collision_type``
    (utils/collision_utils.py) makes the contact STOPPED_EGO_COLLISION (not at
    fault) when the ego speed <= ``COLLISION_STOPPED_SPEED``, else
    STOPPED_TRACK_COLLISION (at fault). ``find_new_collisions``
    (no_ego_at_fault_collisions.py) registers a track token at its first
    contact, fixing the type then, and never again in the scenario.

    ``layout_hit`` (n, O) bool per obstacle row (``ContactSet.obstacle_hit``):
    each obstacle counts once, at its first contact tick, if the ego moves then.
    ``layout_hit`` (n,) bool (no obstacle identity, legacy logs): every rising
    edge at which the ego moves counts.
    """
    lay = np.asarray(layout_hit, dtype=bool)
    moving = np.asarray(speed, dtype=np.float64) > COLLISION_STOPPED_SPEED
    if lay.ndim == 1:
        rise = lay & ~np.concatenate([[False], lay[:-1]])
        return (rise & moving).astype(int)
    first = lay & (np.cumsum(lay, axis=0) == 1)  # (n, O): each obstacle's first contact tick
    return (first & moving[:, None]).sum(axis=1)


def _new_agent_collisions(agent_hit, agent_id, agent_category, at_fault):
    """The tracks' first contacts, in tick order: [(tick, category, at fault), ...].

    ``find_new_collisions`` (no_ego_at_fault_collisions.py): every track whose
    box overlaps the ego's is registered once, at its first contact tick, with
    that tick's collision type. The arguments are (n,) (one contact per tick)
    or (n, K) (every overlapping candidate, ``ContactSet``).
    """
    hit = np.asarray(agent_hit, dtype=bool)
    tid, cat, fault = np.asarray(agent_id), np.asarray(agent_category), np.asarray(at_fault, dtype=bool)
    if hit.ndim == 1:
        hit, tid, cat, fault = hit[:, None], tid[:, None], cat[:, None], fault[:, None]
    seen: set[int] = set()
    out = []
    for i, k in zip(*np.nonzero(hit)):
        if int(tid[i, k]) in seen:
            continue
        seen.add(int(tid[i, k]))
        out.append((int(i), int(cat[i, k]), bool(fault[i, k])))
    return out


def collision_counts(agent_hit, agent_id, agent_category, at_fault, layout_hit,
                     speed=None) -> tuple[int, int, int]:
    """At-fault collisions (VRU, vehicle, object) over the active ticks.

    ``find_new_collisions`` + ``classify_at_fault_collisions``
    (no_ego_at_fault_collisions.py): each track is counted once, at its
    first contact tick, if that contact is at fault; ``get_fault_type_statistics``
    (utils/collision_utils.py) groups by type. Several tracks first touched at
    the same tick count each. Layout contacts: objects (``_new_layout_faults``);
    ``speed`` None (legacy callers) counts every one as at fault.

    Args: agent_hit, agent_id, agent_category, at_fault: (n,) or (n, K) (bool,
      int, int, bool); layout_hit (n,) or (n, O) bool; speed (n,) m/s.
    """
    vru = veh = 0
    for _, cat, fault in _new_agent_collisions(agent_hit, agent_id, agent_category, at_fault):
        if fault:
            if cat in VRU_CATEGORIES:
                vru += 1
            else:
                veh += 1
    if speed is None:
        speed = np.full(len(layout_hit), np.inf)
    obj = int(np.sum(_new_layout_faults(layout_hit, speed)))
    return vru, veh, obj


def collision_score(vru: int, veh: int, obj: int) -> float:
    """``EgoAtFaultCollisionStatistics.compute_score``: 1 without at-fault
    collisions, else the product over types of max(0, 1 - n / (threshold + 1))."""
    if vru + veh + obj == 0:
        return 1.0
    return float(np.prod([max(0.0, 1.0 - n / (thr + 1)) for n, thr in zip((vru, veh, obj), COLLISION_THRESHOLDS,
                                                                          strict=True)]))


def _first_fault_ticks(agent_hit, agent_id, at_fault, layout_hit, speed) -> np.ndarray:
    """(n,) bool: ticks with a NEW at-fault collision (nuPlan's
    ``timestamps_at_fault_collisions``; their TTC is 0). Shapes as
    ``collision_counts``."""
    out = np.zeros(len(agent_hit), dtype=bool)
    for i, _, fault in _new_agent_collisions(agent_hit, agent_id, np.zeros(np.shape(agent_hit), int), at_fault):
        out[i] |= fault
    return out | (_new_layout_faults(layout_hit, speed) > 0)


def ttc_score(ttc_s, speed, new_fault) -> float:
    """``TimeToCollisionStatistics.compute``: 1 iff every sample has
    0.95 < TTC; TTC is inf while the ego is stopped and 0 at a new at-fault
    collision (time_to_collision_within_bound.py)."""
    ttc = np.where(np.asarray(speed) > TTC_STOPPED_SPEED, np.asarray(ttc_s, dtype=np.float64), np.inf)
    ttc = np.where(new_fault, 0.0, ttc)
    return float(np.all(TTC_LEAST_MIN_S < ttc))


def drivable_score(drivable_excess_m) -> float:
    """``DrivableAreaComplianceStatistics``: 0 if a corner ever lies
    >= 0.3 m outside the drivable area (``is_corner_far_from_drivable_area``)."""
    e = np.asarray(drivable_excess_m, dtype=np.float64)
    return 0.0 if e.size and np.max(e) >= DRIVABLE_MAX_VIOLATION_M else 1.0


def _n_horizon(t) -> int:
    """``int(time_horizon / mean dt)`` (driving_direction_compliance.py), robust
    to float rounding of the step."""
    t = np.asarray(t, dtype=np.float64)
    if len(t) < 2:
        return 0
    return int(round(DIRECTION_HORIZON_S / float(np.mean(np.diff(t))), 6))


def direction_score(oncoming_m, t) -> float:
    """``DrivingDirectionComplianceStatistics.compute``: the largest travel
    against the lanes over any window of the last n_horizon + 1 samples:
    < 2 m -> 1, < 6 m -> 0.5, else 0."""
    x = np.asarray(oncoming_m, dtype=np.float64)
    if x.size == 0:
        return 1.0
    n = _n_horizon(t)
    c = np.concatenate([[0.0], np.cumsum(x)])
    i = np.arange(len(x))
    worst = float(np.max(c[i + 1] - c[np.maximum(0, i - n)]))
    if worst < DIRECTION_COMPLIANCE_M:
        return 1.0
    return 0.5 if worst < DIRECTION_VIOLATION_M else 0.0


def route_arc(points, route_xy, route_valid) -> np.ndarray:
    """(N,) arc length, m, of each point's foot on the route polyline (nearest segment)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    r = np.asarray(route_xy, dtype=np.float64)[np.asarray(route_valid, dtype=bool)]
    if len(r) == 1:
        return np.zeros(len(p))
    a, d = r[:-1], np.diff(r, axis=0)  # (S, 2)
    seg = np.linalg.norm(d, axis=-1)
    cum = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    rel = p[:, None, :] - a[None]
    u = np.clip(np.sum(rel * d, -1) / np.maximum(seg**2, 1e-12), 0.0, 1.0)  # (N, S)
    dist = np.linalg.norm(rel - u[..., None] * d, axis=-1)
    j = np.argmin(dist, axis=1)
    k = np.arange(len(p))
    return cum[j] + u[k, j] * seg[j]


def progress_ratio(ego_progress: float, expert_progress: float) -> float:
    """``EgoProgressAlongExpertRouteStatistics.compute``: 0 below -2 m, else
    min(1, max(ego, 2) / max(expert, 2))."""
    if ego_progress < -PROGRESS_THRESHOLD_M:
        return 0.0
    return min(1.0, max(ego_progress, PROGRESS_THRESHOLD_M) / max(expert_progress, PROGRESS_THRESHOLD_M))


def speed_limit_score(speed, speed_limit, t) -> float:
    """``SpeedLimitComplianceStatistics._compute_violation_metric_score``
    (speed_limit_compliance.py): max(0, 1 - sum(overspeed) * mean dt /
    (2.23 m/s * (t_last - t_first))); 1 for a zero duration. Ticks without a
    positive speed limit have no violation (``_get_speed_limit_violation``)."""
    t = np.asarray(t, dtype=np.float64)
    lim = np.asarray(speed_limit, dtype=np.float64)
    over = np.where(np.isfinite(lim) & (lim > 0), np.maximum(np.asarray(speed, dtype=np.float64) - lim, 0.0), 0.0)
    if len(t) < 2 or t[-1] - t[0] <= 0:
        return 1.0
    loss = over.sum() * float(np.mean(np.diff(t))) / (max(MAX_OVERSPEED_MPS, 1e-3) * (t[-1] - t[0]))
    return float(max(0.0, 1.0 - loss))


def _sg(x: np.ndarray, window: int, poly: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray | None:
    """nuPlan's Savitzky-Golay call (window clipped to the length; None if too short)."""
    w = min(window, len(x))
    if not poly < w:
        return None
    return np.round(savgol_filter(x, window_length=w, polyorder=poly, deriv=deriv, delta=delta), 8)


def ego_comfort_inputs(speed, accel, steer, yaw_rate, dt: float,
                       lr: float = 0.5 * DEFAULT_WHEELBASE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The accelerations nuPlan's comfort metrics read, from the simulated ego's step log.

    nuPlan's simulated ego is a ``KinematicBicycleModel`` state referenced at
    the rear axle (nuplan/planning/simulation/controller/motion_model/
    kinematic_bicycle.py, ``propagate_state``): its ``rear_axle_acceleration_2d``
    is (a_r, 0), a_r the change of the rear axle's forward speed over the step
    (the lateral term is 0 "by model assumption"), ``angular_velocity`` w the
    yaw rate and ``angular_acceleration`` (w_k - w_{k-1}) / dt. From it
    (nuplan/common/actor_state/dynamic_car_state.py):

    * ``center_acceleration_2d`` = ``get_acceleration_shifted((lr, 0), (a_r, 0),
      w, dw/dt)`` = (a_r + lr w^2 + lr dw/dt, 0): both rigid-body terms are
      added along the displacement, so the centre's lateral acceleration is 0
      and its longitudinal one carries the angular terms. ``EgoLonAcceleration``
      and ``EgoLatAcceleration`` read its x and y (``extract_ego_acceleration``).
    * ``DynamicCarState.acceleration`` = |rear_axle_acceleration_2d| = |a_r|:
      what ``EgoJerkStatistics`` differentiates (``acceleration_coordinate=
      'magnitude'``).

    Our bicycle (``dynamics.step``) is referenced at the box centre, half-way
    along the wheelbase (``lr = wheelbase / 2``, nuPlan's
    ``rear_axle_to_center_dist``); the rear axle moves along the heading at the
    centre speed times cos(beta), beta = atan(tan(steer) / 2) the centre's slip
    angle, so a_r = (v_k cos beta_k - v_{k-1} cos beta_{k-1}) / dt. Before the
    first row: speed ``speed[0] - accel[0] * dt`` with the first row's slip
    angle and yaw rate (so dw/dt = 0 there). The simulator's initial state has
    steer and yaw rate 0 (``dynamics.ego_from_log``: not measured), where
    nuPlan's first sample is the logged state with its measured angular
    velocity; taking them literally would put a spurious lr * w / dt into the
    first longitudinal sample of an episode that starts in a curve.

    Args: (T,) each: centre speed m/s, ``StepLog.accel`` m/s^2 (the step's
      mean (v1 - v0) / dt), front-wheel angle rad, mean yaw rate rad/s (rows
      in time order from the episode's first step); dt s; lr m.
    Returns: (lon, lat, magnitude), each (T,) m/s^2: the centre's x and y
      acceleration and the rear axle's acceleration magnitude.
    """
    v = np.asarray(speed, np.float64)
    a = np.asarray(accel, np.float64)
    w = np.asarray(yaw_rate, np.float64)
    cb = np.cos(np.arctan(0.5 * np.tan(np.asarray(steer, np.float64))))  # dynamics.step: lr / L = 1/2
    v_r = v * cb
    if len(v) == 0:
        return v, v, v
    v_r_prev = np.concatenate([[(v[0] - a[0] * dt) * cb[0]], v_r[:-1]])
    a_r = (v_r - v_r_prev) / dt
    w_dot = np.diff(w, prepend=w[0]) / dt
    lon = a_r + lr * w**2 + lr * w_dot
    return lon, np.zeros_like(lon), np.abs(a_r)


def path_comfort_inputs(xy, yaw, dt: float, window: int = 9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Comfort inputs of a logged path that has no measured accelerations.

    nuPlan reads a logged ego's accelerations from its IMU; a recorded path
    (positions at ``dt``) has none, and differentiating positions step by
    step turns centimetres of noise into m/s^2. This is a Savitzky-Golay
    estimate (window ``window`` clipped to the path, order 3, second
    derivative) of the acceleration vector, projected on the logged heading
    (lon) and its normal (lat); the magnitude is their hypot (the IMU sees
    both). A diagnostic reference for "is the log itself comfortable", not
    a metric column.

    Args: xy (n, 2) m, yaw (n,) rad, dt s.  Returns: (lon, lat, magnitude), each (n,) m/s^2.
    """
    xy = np.asarray(xy, np.float64)
    yaw = np.asarray(yaw, np.float64)
    w = min(window, len(xy) if len(xy) % 2 else len(xy) - 1)
    if w <= 3:
        z = np.zeros(len(xy))
        return z, z, z
    acc = savgol_filter(xy, w, 3, deriv=2, delta=dt, axis=0)
    lon = acc[:, 0] * np.cos(yaw) + acc[:, 1] * np.sin(yaw)
    lat = -acc[:, 0] * np.sin(yaw) + acc[:, 1] * np.cos(yaw)
    return lon, lat, np.hypot(lon, lat)


def comfort_signals(accel, lat_accel, yaw, t, accel_magnitude=None) -> dict[str, np.ndarray | None]:
    """nuPlan's six comfort signals (nuplan/planning/metrics/utils/state_extractors.py).

    * ``extract_ego_acceleration``: SG window min(8, n), order 2 (no derivative).
    * ``extract_ego_jerk``: SG first derivative, window min(15, n), order 2, of
      the smoothed acceleration (``approximate_derivatives``, spacing = mean dt).
    * ``extract_ego_yaw_rate``: SG derivative of the ``phase_unwrap``-ped
      heading; ``approximate_derivatives``'s default window 5 (the 15 passed
      to ``extract_ego_yaw_rate`` is never forwarded), order 2 for the rate,
      order 3 + second derivative for the yaw acceleration
      (``EgoYawAccelerationStatistics``).
    Every signal is rounded to 8 decimals as nuPlan. None: too short to fit.
    The acceleration window 8 is even: scipy (nuPlan pins 1.9.1) then
    evaluates each interior fit half a sample late, while the ``interp`` ends
    are unshifted, so even a steady ramp gets a kinked smoothed acceleration
    and a non-constant jerk; kept as nuPlan computes it.

    Args: (n,) lon acc m/s^2, lat acc m/s^2, heading rad, time s, and the
      acceleration magnitude the jerk differentiates, m/s^2 (nuPlan: the
      rear axle's, ``ego_comfort_inputs``; None: hypot of lon and lat).
    """
    a = np.asarray(accel, dtype=np.float64)
    la = np.asarray(lat_accel, dtype=np.float64)
    am = np.hypot(a, la) if accel_magnitude is None else np.asarray(accel_magnitude, dtype=np.float64)
    h = np.asarray(yaw, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    dt = float(np.mean(np.diff(t))) if len(t) > 1 else 1.0
    adj = np.zeros_like(h)
    adj[1:] = np.cumsum(np.round(np.diff(h) / (2.0 * np.pi)))
    h = h - 2.0 * np.pi * adj
    lon = _sg(a, 8, 2)
    mag = _sg(am, 8, 2)
    return {
        "lon_acc": lon,
        "lat_acc": _sg(la, 8, 2),
        "jerk": None if mag is None else _sg(mag, 15, 2, 1, dt),
        "lon_jerk": None if lon is None else _sg(lon, 15, 2, 1, dt),
        "yaw_acc": _sg(h, 5, 3, 2, dt),
        "yaw_rate": _sg(h, 5, 2, 1, dt),
    }


def comfort_score(accel, lat_accel, yaw, t, accel_magnitude=None) -> float:
    """``EgoIsComfortableStatistics``: 1 iff all six signals stay strictly
    inside their bounds (``WithinBoundMetricBase._compute_within_bound``).
    Arguments as ``comfort_signals``."""
    s = comfort_signals(accel, lat_accel, yaw, t, accel_magnitude)
    bounds = {
        "lon_acc": LON_ACC_BOUNDS,
        "lat_acc": (-MAX_ABS_LAT_ACC, MAX_ABS_LAT_ACC),
        "jerk": (-MAX_ABS_JERK, MAX_ABS_JERK),
        "lon_jerk": (-MAX_ABS_LON_JERK, MAX_ABS_LON_JERK),
        "yaw_acc": (-MAX_ABS_YAW_ACC, MAX_ABS_YAW_ACC),
        "yaw_rate": (-MAX_ABS_YAW_RATE, MAX_ABS_YAW_RATE),
    }
    ok = all(s[k] is None or bool(np.all((s[k] > lo) & (s[k] < hi))) for k, (lo, hi) in bounds.items())
    return float(ok)


def combine(columns: dict[str, float | None]) -> float:
    """``WeightedAverageMetricAggregator._compute_scenario_score``: product of
    the multiplier metrics times the weighted mean of the others.

    Every column except ``nuplan_score`` and None values takes part, as in
    nuplan-devkit (``_compute_scenario_score`` iterates over all metric columns
    except its excluded keys, skips None); a metric missing from ``WEIGHTS``
    gets ``DEFAULT_WEIGHT`` (``_get_metric_weight``: ``metric_weights['default']``,
    1.0 in ``closed_loop_*_weighted_average.yaml``). 0 if no weight is left.
    """
    factor, num, total = 1.0, 0.0, 0.0
    for k, v in columns.items():
        if k == "nuplan_score" or v is None:
            continue
        if k in MULTIPLIERS:
            factor *= float(v)
        else:
            w = WEIGHTS.get(k, DEFAULT_WEIGHT)
            num += w * float(v)
            total += w
    return factor * (num / total if total else 0.0)


def episode_columns(log: Any, scenario: Any, dt: float) -> dict[str, float]:
    """nuPlan's per-scenario metrics and CLS of ONE episode (host side).

    Args:
      log: a ``sim.StepLog`` with numpy (T, ...) leaves; ``log.facts`` carries
        agent_hit, agent_hit_id, agent_hit_category, at_fault, layout_hit,
        drivable_excess_m, speed_limit and ``nuplan`` (NuplanTick, (T,) leaves),
        and ``contacts`` (``infractions.ContactSet``, (T, K) / (T, O) leaves:
        every track and obstacle touched; when None the scalar agent_hit* /
        layout_hit fields are used, one contact per tick).
      scenario: an unbatched numpy ``types.Scenario``.
      dt: simulation step, s (used only when fewer than 2 steps are active).

    Returns:
      {column: value in [0, 1]} for every name in ``COLUMNS``.
    """
    act = np.asarray(log.active, dtype=bool)
    f = log.facts
    if getattr(f, "nuplan", None) is None:
        raise ValueError("nuplan.episode_columns: log.facts.nuplan is None (run the rollout with the nuplan preset)")
    sel = lambda x: np.asarray(x)[act]  # noqa: E731 - active rows
    t, speed = sel(log.t).astype(np.float64), sel(log.speed).astype(np.float64)
    c = getattr(f, "contacts", None)
    if c is None:  # one contact per tick, obstacles without identity
        hit, tid, cat = sel(f.agent_hit).astype(bool), sel(f.agent_hit_id), sel(f.agent_hit_category)
        fault, lay = sel(f.at_fault).astype(bool), sel(f.layout_hit).astype(bool)
    else:  # every overlapping candidate, each obstacle by its row
        hit, tid, cat = sel(c.hit).astype(bool), sel(c.track_id), sel(c.category)
        fault, lay = sel(c.at_fault).astype(bool), sel(c.obstacle_hit).astype(bool)

    # Progress along the route: ego vs logged ego from t = 0 over the same duration.
    tr = scenario.tracks
    e = int(scenario.ego_index)
    dt_log = float(scenario.dt_log)
    n_log = int(scenario.num_steps)
    route_valid = np.asarray(scenario.route.valid, dtype=bool)
    if not route_valid.any():
        ratio = 1.0  # nuPlan: no expert route -> ratio 1.0
    else:
        t_end = float(t[-1]) if len(t) else 0.0
        k = int(np.clip(round(t_end / dt_log), 0, max(n_log - 1, 0)))
        log_valid = np.flatnonzero(np.asarray(tr.valid[e, : k + 1], dtype=bool))
        k = int(log_valid[-1]) if len(log_valid) else 0
        start = np.asarray(tr.xy[e, 0], dtype=np.float64)
        ego_end = np.asarray(log.xy, dtype=np.float64)[act][-1] if len(t) else start
        arcs = route_arc(np.stack([start, ego_end, np.asarray(tr.xy[e, k], dtype=np.float64)]),
                         scenario.route.xy, route_valid)
        ratio = progress_ratio(float(arcs[1] - arcs[0]), float(arcs[2] - arcs[0]))

    times = t if len(t) > 1 else np.arange(max(len(t), 1)) * dt
    lon_acc, lat_acc, acc_mag = ego_comfort_inputs(speed, sel(log.accel), sel(log.steer), sel(log.yaw_rate), dt)
    cols = {
        "nuplan_no_ego_at_fault_collisions": collision_score(*collision_counts(hit, tid, cat, fault, lay, speed)),
        "nuplan_drivable_area_compliance": drivable_score(sel(f.drivable_excess_m)),
        "nuplan_ego_is_making_progress": float(ratio >= MIN_PROGRESS_RATIO),
        "nuplan_driving_direction_compliance": direction_score(sel(f.nuplan.oncoming_m), times),
        "nuplan_ego_progress_along_expert_route": float(ratio),
        "nuplan_time_to_collision_within_bound": ttc_score(sel(f.nuplan.ttc_s), speed,
                                                           _first_fault_ticks(hit, tid, fault, lay, speed)),
        "nuplan_speed_limit_compliance": speed_limit_score(speed, sel(f.speed_limit), t),
        "nuplan_ego_is_comfortable": comfort_score(lon_acc, lat_acc, sel(log.yaw), times, acc_mag),
    }
    cols["nuplan_score"] = combine(cols)
    return cols


__all__ = [
    "COLUMNS",
    "NuplanTick",
    "collision_counts",
    "collision_score",
    "combine",
    "comfort_score",
    "comfort_signals",
    "direction_score",
    "drivable_score",
    "ego_comfort_inputs",
    "path_comfort_inputs",
    "episode_columns",
    "oncoming_travel",
    "progress_ratio",
    "route_arc",
    "speed_limit_score",
    "tick",
    "time_to_collision",
    "ttc_relevant",
    "ttc_score",
]
