"""NAVSIM v2's EPDMS carried over to closed loop (``--preset navsim``).

NAVSIM scores a 4 s open-loop plan (simulated by LQR + bicycle at 0.1 s)
against the logged, non-reactive scene; drivee2e drives the whole episode in
closed loop. This module keeps NAVSIM's sub-metrics, thresholds and weights
and evaluates them on the executed episode instead of one 4 s proposal:

* ``tick`` (pure JAX, one scenario, one tick; runs inside the batched
  rollout): the per-tick facts that ``infractions.StepFacts`` lacks, as a
  ``NavsimTick`` (TTC violation, junction, oncoming).
* ``episode_columns`` (host, numpy, one episode): the sub-metric columns
  ``COLUMNS`` and ``epdms``.

EPDMS = NC * DAC * DDC * TLC * (5 EP + 5 TTC + 2 LK + 2 HC + 2 EC) / 16.
The weights are the code's (``PDMScorerConfig`` and
``config/pdm_scoring/scorer/pdm_scorer.yaml``; EC enters in
``run_pdm_score.compute_final_scores``), equal to docs/metrics.md.

References (autonomousvision/navsim, HEAD):
  S = navsim/planning/simulation/planner/pdm_planner/scoring/pdm_scorer.py
  U = .../scoring/pdm_scorer_utils.py (``get_collision_type``)
  C = .../scoring/pdm_comfort_metrics.py
  A = .../scoring/scene_aggregator.py (``_compute_two_frame_comfort``)
  E = navsim/evaluate/pdm_score.py (``pdm_score_from_interpolated_trajectory``:
      the human penalty filter)
  nuPlan: nuplan/planning/simulation/observation/idm/utils.py
      (``is_agent_ahead`` 30 deg, ``is_agent_behind`` 150 deg).

Every adaptation from NAVSIM's open-loop 4 s setting:

====  ==========================================  ==========================================
col   NAVSIM (open loop, one 4 s proposal)         here (closed loop, whole episode)
====  ==========================================  ==========================================
all   41 states at 0.1 s from t0                   every active step of the episode (sim dt)
NC    shapely intersects; at-fault = STOPPED_TRACK same rule per overlapping candidate
      / ACTIVE_FRONT / LATERAL in multi-lane or    (facts.contacts: every track touching at a
      non-drivable; agents 0, objects 0.5; a       step); agents 0, static obstacles 0.5 while
      track once hit not-at-fault is ignored        ego speed > 0.05 m/s (a stopped track); at
      afterwards                                   ego <= 0.05 it is STOPPED_EGO and that
                                                   obstacle row is ignored afterwards, as an
                                                   ignored track id
DAC   any corner outside the drivable polygons    facts.drivable_excess_m > 0: a corner outside
      (shapely contains, no tolerance)             the union of the map's drivable polygons,
                                                   exact (infractions.drivable_excess); none
DDC   centre not in an on-route lane, outside      centre not inside a lane running within
      intersections; travel summed over 1 s        90 deg of the ego heading (no route lane ids
      window; <2 m: 1, <6 m: 0.5, else 0           packed), outside connector lanes; same window
TLC   ego polygon intersects a red lane connector  facts.red_light (tail crosses a red stop line)
EP    progress along the centreline / max(PDM-     route progress / max(own progress * own
      Closed and agent progress, each masked by    multiplier product, LOGGED ego's progress over
      its multiplier product); <= 5 m -> 1         the same time, times the human's product when
                                                   ``human`` is given); <= 5 m -> 1
TTC   ego and the observed future agents at +0,    ego AND agents projected at constant velocity
      0.3, 0.6, 0.9 s; a track first met not        (tick needs only the current state); still
      ahead is ignored for the rest of the          the 16 nearest agents, static map obstacles
      proposal                                     not tested (issue 35 item 4 done for nuplan
                                                   only); the "ignore once met not ahead"
                                                   memory is per tick
LK    distance of centre to the PDM centreline     distance of the centre to the centreline of
      (the route lane chain from the on-route      the lane whose polygon holds it (lowest
      lane holding the ego at t0, lowest heading   heading error; none: the nearest lane's),
      error) > 0.5 m for ceil(2 s / 0.1 s)         ``NavsimTick.lane_offset``, > 0.5 m for
      consecutive states outside INTERSECTION      ceil(2 s / dt) consecutive active steps;
                                                   connector (junction) steps skipped; no
                                                   route lane ids are packed, so a finished
                                                   lane change is not a deviation here
HC    comfort bounds on 1.5 s human history +       bounds on the executed steps (no history
      the 4 s proposal (states from the LQR sim;   padding); the bicycle-model state as C reads
      lon / lat: centre acceleration from           it (``nuplan.ego_comfort_inputs``): lon =
      ``state_array_to_center_state_array``,       a_r + lr (w^2 + dw/dt), lat = 0, jerk of the
      jerk: rear-axle magnitude)                   rear-axle |a_r|; heading = yaw; < 4 steps -> 1
EC    states of two plans 0.5 s apart, overlap      consecutive policy plans (dt apart): both
      compared (RMS of accel, jerk, yaw rate,       waypoint sets (+ the ego origin at tau = 0)
      yaw accel differences); {0, 1} per frame      in the world frame, cubic spline resampled
                                                   at 0.1 s over the overlap; mean of the
                                                   per-pair pass over the episode; 1 when
                                                   ``plans`` is None (control policies)
human filter: a column where the human scores    ``human``: the same columns computed on a
      exactly 0 counts 1 (E), original scenes      StepLog evaluated along the logged ego
====  ==========================================  ==========================================
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from scipy.interpolate import CubicSpline
from scipy.signal import savgol_filter

from drivee2e_jax import geometry
from drivee2e_jax.dynamics import BicycleParams
from drivee2e_jax.metrics.nuplan import ego_comfort_inputs
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import EgoState

# --- PDMScorerConfig (S) -----------------------------------------------------
#: EPDMS weights (S ``PDMScorerConfig``; pdm_scorer.yaml).
WEIGHTS: Mapping[str, float] = {"ep": 5.0, "ttc": 5.0, "lk": 2.0, "hc": 2.0, "ec": 2.0}
#: Multiplier sub-metrics.
MULTIPLIERS = ("nc", "dac", "ddc", "tlc")
DDC_HORIZON_S = 1.0  # s, driving_direction_horizon
DDC_COMPLIANCE_M = 2.0  # m, driving_direction_compliance_threshold
DDC_VIOLATION_M = 6.0  # m, driving_direction_violation_threshold
TTC_STOPPED_SPEED = 5e-3  # m/s, stopped_speed_threshold (ttc)
#: TTC projection times: ``np.arange(0, int(1.0 * 10), 3)`` steps of 0.1 s (S ``_calculate_ttc``).
TTC_TIMES_S = (0.0, 0.3, 0.6, 0.9)
EP_MIN_PROGRESS_M = 5.0  # m, progress_distance_threshold
LK_DEVIATION_M = 0.5  # m, lane_keeping_deviation_limit
LK_WINDOW_S = 2.0  # s, lane_keeping_horizon_window
#: LK deviation logged when no lane is near the ego at all (m; any value > LK_DEVIATION_M fails alike).
LK_NO_LANE_M = 1000.0
#: Lanes holding the ego whose direction cosine to its heading is within this of the best one are
#: equally aligned (1e-3: about 2.6 deg off parallel); LK takes the nearest centreline among them.
LK_ALIGN_TIE = 1e-3
#: ``get_collision_type`` (U) ego stopped threshold; a static object is a stopped track.
COLLISION_STOPPED_SPEED = 5e-2  # m/s
NC_AGENT = 0.0  # at-fault collision with an AGENT_TYPES track (vehicle, pedestrian, bicycle)
NC_OBJECT = 0.5  # at-fault collision with a static object
#: nuPlan ``is_agent_ahead`` / ``is_agent_behind`` angle tolerances.
AHEAD_DEG = 30.0
BEHIND_DEG = 150.0
#: A lane "runs the ego's way" for DDC within this heading difference (rad).
ONCOMING_ALIGN_MAX = math.pi / 2

# --- comfort (C) ---------------------------------------------------------------
HC_LON_ACCEL = (-4.05, 2.40)  # m/s^2 MIN_LON_ACCEL, MAX_LON_ACCEL
HC_LAT_ACCEL = 4.89  # m/s^2 MAX_ABS_LAT_ACCEL
HC_JERK = 8.37  # m/s^3 MAX_ABS_MAG_JERK
HC_LON_JERK = 4.13  # m/s^3 MAX_ABS_LON_JERK
HC_YAW_ACCEL = 1.93  # rad/s^2 MAX_ABS_YAW_ACCEL
HC_YAW_RATE = 0.95  # rad/s MAX_ABS_YAW_RATE
EC_ACCEL = 0.7  # m/s^2 acceleration_threshold (RMS of the difference)
EC_JERK = 0.5  # m/s^3 jerk_threshold
EC_YAW_RATE = 0.1  # rad/s yaw_rate_threshold
EC_YAW_ACCEL = 0.1  # rad/s^2 yaw_accel_threshold
#: NAVSIM's proposal sampling interval (default_common.yaml), used to resample plans for EC.
EC_SAMPLE_S = 0.1
#: Default spacing of policy waypoints (``controller.ControllerParams.waypoint_dt``).
PLAN_DT_S = 0.5

#: Per-episode columns in CSV order.
COLUMNS = (
    "navsim_nc",
    "navsim_dac",
    "navsim_ddc",
    "navsim_tlc",
    "navsim_ep",
    "navsim_ttc",
    "navsim_lk",
    "navsim_hc",
    "navsim_ec",
    "epdms",
)


# =============================================================================
# Per tick (JAX)
# =============================================================================


@struct.dataclass
class NavsimTick:
    """NAVSIM facts of one tick (all scalars) that ``StepFacts`` lacks.

    Attributes:
      ttc_violation: bool, NAVSIM's TTC fails this tick (S ``_calculate_ttc``).
      in_junction:   bool, the ego centre lies on a CONNECTOR lane (NAVSIM's
                     INTERSECTION layer; used by DDC and LK).
      oncoming:      bool, the ego centre lies in no lane running its way
                     (NAVSIM's ONCOMING_TRAFFIC ego area, used by DDC).
      lane_offset:   m, LK's lateral deviation: the distance of the ego centre
                     to the centreline of the lane holding it (``lk_offset``).
    """

    ttc_violation: jnp.ndarray
    in_junction: jnp.ndarray
    oncoming: jnp.ndarray
    lane_offset: jnp.ndarray


def lk_offset(centre_in, tangent, centre_offset, yaw):
    """LK's lateral deviation, m: the distance of the ego centre to the
    centreline of the lane that holds it (NAVSIM: to the PDM centreline, the
    route lane chain from the on-route lane holding the ego with the lowest
    heading error; ``AbstractPDMPlanner._get_starting_lane``).

    Of the lanes whose polygon holds the centre (``centre_in``), the one whose
    direction at the centre (``tangent``) is closest to the ego heading
    ``yaw``; lanes aligned within ``LK_ALIGN_TIE`` of the best are a tie (NAVSIM
    takes the first in its map order, which a packed map does not keep), broken
    by the smaller offset: a nuScenes lane polygon can reach 9 m beside its own
    short centreline, parallel to the lane the ego drives in. When no lane
    holds the centre, the nearest tested lane's centreline (then
    the centre is outside every lane, at least half a lane width from any
    centreline in a map whose lanes tile the road). All (M,) arrays of
    ``infractions.EgoLanes``; ``LK_NO_LANE_M`` when no lane was tested (kept
    finite for the logs; any value > 0.5 m is a deviation).
    """
    align = jnp.where(centre_in, tangent @ jnp.stack([jnp.cos(yaw), jnp.sin(yaw)]), -jnp.inf)
    tied = centre_in & (align >= jnp.max(align) - LK_ALIGN_TIE)
    off = jnp.where(jnp.any(centre_in), jnp.min(jnp.where(tied, centre_offset, jnp.inf)), jnp.min(centre_offset))
    return jnp.minimum(off, LK_NO_LANE_M)


def ttc_violation(ego: EgoState, ego_lw, a_xy, a_yaw, a_vel, a_lw, a_ok, lax_zone, wheelbase: float):
    """() bool NAVSIM's time-to-collision failure at this tick.

    S ``PDMScorer._calculate_ttc``: the ego box and each agent box are
    projected at ``TTC_TIMES_S`` (ego along its heading at its speed; agents
    at constant velocity here, NAVSIM reads their logged future). The first
    projection where an agent box intersects the ego's (touching counts, as
    shapely ``intersects``) decides: violation if the agent is ahead of the
    ego rear axle (relative angle < 30 deg, nuPlan ``is_agent_ahead``), or if
    ``lax_zone`` (ego in multiple lanes, off the drivable area or its rear
    axle in a junction) and the agent is not behind (angle <= 150 deg);
    otherwise the agent is ignored for later projections. Nothing counts
    while the ego speed < 5e-3 m/s.

    Args:
      ego: EgoState (box centre). ego_lw: (2,) m.
      a_xy (K, 2), a_yaw (K,), a_vel (K, 2) m/s, a_lw (K, 2) m, a_ok (K,) bool: candidates.
      lax_zone: () bool. wheelbase: m (rear axle = centre - wheelbase / 2).
    """
    fwd = jnp.stack([jnp.cos(ego.yaw), jnp.sin(ego.yaw)])
    rear = ego.xy - 0.5 * wheelbase * fwd
    cos_ahead, cos_behind = math.cos(math.radians(AHEAD_DEG)), math.cos(math.radians(BEHIND_DEG))
    pen = jax.vmap(geometry.box_penetration, in_axes=(None, None, None, 0, 0, 0))
    hits, conds = [], []
    for dt in TTC_TIMES_S:
        exy = ego.xy + fwd * (ego.speed * dt)
        axy = a_xy + a_vel * dt
        hits.append(a_ok & (pen(exy, ego.yaw, ego_lw, axy, a_yaw, a_lw) >= 0.0))
        rel = axy - rear
        n = jnp.linalg.norm(rel, axis=-1)
        cos = jnp.sum(rel * fwd, axis=-1) / jnp.where(n > 0, n, 1.0)
        ahead = (n > 0) & (cos > cos_ahead)
        behind = (n > 0) & (cos < cos_behind)
        conds.append(ahead | (lax_zone & ~behind))
    hit = jnp.stack(hits)  # (4, K)
    cond = jnp.stack(conds)
    first = jnp.argmax(hit, axis=0)
    decided = jnp.take_along_axis(cond, first[None], axis=0)[0]
    return jnp.any(hit.any(axis=0) & decided) & (ego.speed >= TTC_STOPPED_SPEED)


def tick(
    ego: EgoState,
    ego_lw,
    agents: AgentStates,
    agent_size,
    near,
    near_ok,
    centre_in,
    rear_in,
    tangent,
    connector,
    multi_lane=False,
    off_drivable=False,
    wheelbase: float = BicycleParams().wheelbase,
    *,
    centre_offset,
) -> NavsimTick:
    """NAVSIM facts of one tick, one scenario.

    Args:
      ego: EgoState (box centre). ego_lw: (2,) length, width, m.
      agents: AgentStates (A,) at this tick (the ego's own row invalid).
      agent_size: (A, 3) m. near, near_ok: (K,) rows from
        ``infractions.nearest_rows`` and their validity (K <= 16).
      centre_in, rear_in (M,) bool, tangent (M, 2), connector (M,) bool: the
        tested lanes of ``infractions.EgoLanes`` (which lane polygons hold the
        ego centre and its rear axle, their unit direction at the centre,
        which are junction connectors).
      multi_lane, off_drivable: () bool this tick's ``StepFacts.multi_lane``
        and ``StepFacts.drivable_excess_m > 0`` (TTC's lax zone).
      wheelbase: m.
      centre_offset: (M,) m ``EgoLanes.centre_offset`` (LK's ``lk_offset``).
    """
    aligned = tangent @ jnp.stack([jnp.cos(ego.yaw), jnp.sin(ego.yaw)]) > math.cos(ONCOMING_ALIGN_MAX)
    junction = jnp.any(centre_in & connector)
    lax_zone = jnp.asarray(multi_lane) | jnp.asarray(off_drivable) | jnp.any(rear_in & connector)
    ttc = ttc_violation(
        ego,
        ego_lw,
        agents.xy[near],
        agents.yaw[near],
        agents.vel[near],
        agent_size[near, :2],
        near_ok & agents.valid[near],
        lax_zone,
        wheelbase,
    )
    return NavsimTick(ttc_violation=ttc, in_junction=junction, oncoming=~jnp.any(centre_in & aligned),
                      lane_offset=lk_offset(centre_in, tangent, centre_offset, ego.yaw))


# =============================================================================
# Per episode (host, numpy)
# =============================================================================


def no_at_fault_collision(active, agent_hit, hit_id, at_fault, layout_hit, speed) -> float:
    """NC in {0, 0.5, 1} (S ``_calculate_no_at_fault_collision``).

    Every track intersecting the ego at a step is classified (NAVSIM loops
    over all of them): an agent contact that is not at fault puts its id on
    an ignore list (no later contact with it counts); an at-fault one scores
    0 (every packed category is one of nuPlan's AGENT_TYPES). A static object
    contact is STOPPED_TRACK (at fault, 0.5) while the ego speed > 0.05 m/s
    (U ``get_collision_type``), else STOPPED_EGO (not at fault: that object
    is ignored afterwards, when obstacles carry their identity).

    Args: active (T,) bool; agent_hit, hit_id, at_fault (T,) or (T, K) (every
      overlapping candidate, ``infractions.ContactSet``); layout_hit (T,) or
      (T, O) bool per obstacle row; speed (T,) m/s.
    """
    hit, tid, fault = np.asarray(agent_hit, bool), np.asarray(hit_id), np.asarray(at_fault, bool)
    if hit.ndim == 1:
        hit, tid, fault = hit[:, None], tid[:, None], fault[:, None]
    lay = np.asarray(layout_hit, bool)
    lay = lay[:, None] if lay.ndim == 1 else lay
    identity = np.asarray(layout_hit).ndim == 2
    score, ignored, ignored_obs = 1.0, set(), set()
    for i in np.flatnonzero(active):
        for o in np.flatnonzero(lay[i]):
            if identity and o in ignored_obs:
                continue
            if speed[i] > COLLISION_STOPPED_SPEED:
                score = min(score, NC_OBJECT)
            elif identity:
                ignored_obs.add(o)
        for k in np.flatnonzero(hit[i]):
            t = int(tid[i, k])
            if t in ignored:
                continue
            if fault[i, k]:
                score = min(score, NC_AGENT)
            else:
                ignored.add(t)
    return score


def driving_direction_compliance(active, xy, oncoming, in_junction, dt: float) -> float:
    """DDC in {0, 0.5, 1} (S ``_calculate_driving_direction_compliance``).

    Per step the centre displacement since the previous step (0 at the
    first), kept only while oncoming and not in a junction; summed over the
    window of steps ``[t - h, t]``, h = int(1 s / dt); the maximum < 2 m -> 1,
    < 6 m -> 0.5, else 0. ``xy`` (T, 2) m, masks (T,), dt s.
    """
    idx = np.flatnonzero(active)
    if idx.size == 0:
        return 1.0
    p = np.asarray(xy, np.float64)[idx]
    prog = np.zeros(len(idx))
    prog[1:] = np.linalg.norm(np.diff(p, axis=0), axis=-1)
    prog[~(np.asarray(oncoming)[idx] & ~np.asarray(in_junction)[idx])] = 0.0
    h = int(DDC_HORIZON_S / dt + 1e-9)
    worst = max(prog[max(0, t - h) : t + 1].sum() for t in range(len(prog)))
    if worst < DDC_COMPLIANCE_M:
        return 1.0
    return 0.5 if worst < DDC_VIOLATION_M else 0.0


def lane_keeping(active, lane_offset, in_junction, dt: float) -> float:
    """LK in {0, 1} (S ``_calculate_lane_keeping``).

    0 once ``lane_offset`` > 0.5 m on ceil(2 s / dt) consecutive active
    steps; junction steps are skipped (they neither count nor reset the run,
    NAVSIM's ``continue``).
    """
    need = int(math.ceil(LK_WINDOW_S / dt - 1e-9))
    run = 0
    for i in np.flatnonzero(active):
        if in_junction[i]:
            continue
        run = run + 1 if lane_offset[i] > LK_DEVIATION_M else 0
        if run >= need:
            return 0.0
    return 1.0


def route_progress(xy, route_xy, route_arc, route_valid) -> np.ndarray:
    """Arc length (m) of the projection of points ``xy (N, 2)`` on the route
    polyline (global nearest segment, as ``PDMPath.project``)."""
    r = np.asarray(route_xy, np.float64)[np.asarray(route_valid, bool)]
    arc = np.asarray(route_arc, np.float64)[np.asarray(route_valid, bool)]
    p = np.atleast_2d(np.asarray(xy, np.float64))
    if len(r) < 2:
        return np.zeros(len(p))
    a, d = r[:-1], np.diff(r, axis=0)
    dd = np.maximum(np.sum(d * d, axis=-1), 1e-12)
    t = np.clip(np.einsum("nsk,sk->ns", p[:, None] - a[None], d) / dd, 0.0, 1.0)
    foot = a[None] + t[..., None] * d[None]
    j = np.argmin(np.linalg.norm(p[:, None] - foot, axis=-1), axis=-1)
    rows = np.arange(len(p))
    return arc[j] + t[rows, j] * (arc[j + 1] - arc[j])


def ego_progress(raw: float, multiplier: float, ref_raw: float) -> float:
    """EP in [0, 1] (S ``_aggregate_pdm_scores``): progress over the largest
    of own progress times own multiplier product and the reference's; 1 when
    that is <= 5 m. ``raw``, ``ref_raw`` m (>= 0)."""
    norm = max(raw * multiplier, ref_raw)
    if norm > EP_MIN_PROGRESS_M:
        return float(np.clip(raw / norm, 0.0, 1.0))
    return 1.0


def _smooth(y, window: int, poly: int, deriv: int = 0, delta: float = 1.0):
    """C's ``savgol_filter`` call, window clipped to the signal length."""
    return savgol_filter(y, window_length=min(window, y.shape[-1]), polyorder=poly, deriv=deriv, delta=delta, axis=-1)


def _yaw_derivative(heading, dt: float, deriv: int, poly: int):
    """C ``_extract_ego_yaw_rate``: S-G derivative of the unwrapped heading
    (window 5: its ``window_length`` argument is never passed on)."""
    unwrapped = np.asarray(heading, np.float64).copy()
    unwrapped[..., 1:] -= 2 * np.pi * np.cumsum(np.round(np.diff(unwrapped, axis=-1) / (2 * np.pi)), axis=-1)
    return np.round(_smooth(unwrapped, 5, poly, deriv, dt), 8)


def _inside(v, lo: float, hi: float) -> bool:
    return bool(np.all((v > lo) & (v < hi)))


def history_comfort(lon_accel, lat_accel, heading, dt: float, accel_magnitude=None) -> float:
    """HC in {0, 1} (C ``ego_is_comfortable``) on one trajectory sampled at
    ``dt`` s: lon / lat acceleration of the box centre (m/s^2, ego frame,
    C's ``state_array_to_center_state_array``), heading (rad) and the
    acceleration magnitude the jerk differentiates (C: the rear axle's, from
    the un-shifted states; None: hypot of lon and lat), each (n,). Strict
    bounds on the S-G smoothed signals (window 8), their jerks (S-G
    derivative, window 15), yaw rate and yaw acceleration (window 5). Fewer
    than 4 samples (C's yaw filter needs poly 3 < window): 1."""
    lon = np.asarray(lon_accel, np.float64)
    lat = np.asarray(lat_accel, np.float64)
    if lon.size < 4:
        return 1.0
    mag = np.hypot(lon, lat) if accel_magnitude is None else np.asarray(accel_magnitude, np.float64)
    s_lon, s_lat, s_mag = (np.round(_smooth(x, 8, 2), 8) for x in (lon, lat, mag))
    ok = (
        _inside(s_lon, *HC_LON_ACCEL)
        and _inside(s_lat, -HC_LAT_ACCEL, HC_LAT_ACCEL)
        and _inside(np.round(_smooth(s_mag, 15, 2, 1, dt), 8), -HC_JERK, HC_JERK)
        and _inside(np.round(_smooth(s_lon, 15, 2, 1, dt), 8), -HC_LON_JERK, HC_LON_JERK)
        and _inside(_yaw_derivative(heading, dt, 2, 3), -HC_YAW_ACCEL, HC_YAW_ACCEL)
        and _inside(_yaw_derivative(heading, dt, 1, 2), -HC_YAW_RATE, HC_YAW_RATE)
    )
    return 1.0 if ok else 0.0


def _ec_features(xy, yaw0, dt: float) -> dict[str, np.ndarray]:
    """C ``extract_features`` on positions ``xy (..., n, 2)`` sampled at
    ``dt``: acceleration magnitude, jerk, yaw rate, yaw acceleration, each
    (..., n) (heading from the velocity; ``yaw0`` (...,) where the plan
    stands still). Leading axes: several plans at once."""
    vel = np.gradient(xy, dt, axis=-2)
    acc = np.gradient(vel, dt, axis=-2)
    moving = np.linalg.norm(vel, axis=-1) > 1e-3
    heading = np.where(moving, np.arctan2(vel[..., 1], vel[..., 0]), np.asarray(yaw0, np.float64)[..., None])
    mag = np.round(_smooth(np.linalg.norm(acc, axis=-1), 8, 2), 8)
    return {
        "acceleration": mag,
        "jerk": np.round(_smooth(mag, 15, 2, 1, dt), 8),
        "yaw_rate": _yaw_derivative(heading, dt, 1, 2),
        "yaw_accel": _yaw_derivative(heading, dt, 2, 2),
    }


def _plan_spline(plans, poses_xy, poses_yaw, plan_dt: float) -> CubicSpline:
    """World-frame cubic splines tau -> xy of P plans at once (ego-frame
    waypoints ``plans (P, N, 2)`` at tau = plan_dt, 2 plan_dt, ...; the ego
    at tau = 0, as E ``transform_trajectory`` prepends the initial state;
    poses ``(P, 2)``, ``(P,)``): evaluated at ``tau (n,)`` -> (P, n, 2)."""
    plans = np.asarray(plans, np.float64)
    pts = np.concatenate([np.zeros(plans.shape[:-2] + (1, 2)), plans], axis=-2)
    c, s = np.cos(poses_yaw)[..., None], np.sin(poses_yaw)[..., None]
    world = np.stack([c * pts[..., 0] - s * pts[..., 1], s * pts[..., 0] + c * pts[..., 1]], axis=-1)
    world = world + np.asarray(poses_xy, np.float64)[..., None, :]
    return CubicSpline(np.arange(pts.shape[-2]) * plan_dt, world, axis=-2)


def _two_frame_batch(prev_plans, prev_xy, prev_yaw, cur_plans, cur_xy, cur_yaw, dt: float,
                     plan_dt: float) -> np.ndarray:
    """``two_frame_comfort`` of P plan pairs at once -> (P,) float in {0, 1}."""
    horizon = cur_plans.shape[-2] * plan_dt
    tau = np.arange(0.0, horizon - dt + 1e-9, EC_SAMPLE_S)
    if len(tau) < 3:
        return np.ones(len(cur_plans))
    f_prev = _ec_features(_plan_spline(prev_plans, prev_xy, prev_yaw, plan_dt)(tau + dt), prev_yaw, EC_SAMPLE_S)
    f_cur = _ec_features(_plan_spline(cur_plans, cur_xy, cur_yaw, plan_dt)(tau), cur_yaw, EC_SAMPLE_S)
    limits = {"acceleration": EC_ACCEL, "jerk": EC_JERK, "yaw_rate": EC_YAW_RATE, "yaw_accel": EC_YAW_ACCEL}
    ok = np.ones(len(cur_plans), bool)
    for k, lim in limits.items():
        ok &= np.sqrt(np.mean((f_cur[k] - f_prev[k]) ** 2, axis=-1)) <= lim
    return ok.astype(np.float64)


def two_frame_comfort(prev_plan, prev_pose, cur_plan, cur_pose, dt: float, plan_dt: float = PLAN_DT_S) -> float:
    """EC of one plan pair in {0, 1} (A ``_compute_two_frame_comfort``, C
    ``ego_is_two_frame_extended_comfort``).

    The previous plan (made ``dt`` s earlier) and the current one are
    compared over their overlap, resampled at 0.1 s: RMS of the feature
    differences <= 0.7 m/s^2, 0.5 m/s^3, 0.1 rad/s, 0.1 rad/s^2. Poses are
    (xy (2,), yaw) of the ego each plan was made from. Overlaps of < 3
    samples pass.
    """
    one = lambda a: np.asarray(a, np.float64)[None]  # noqa: E731
    return float(_two_frame_batch(one(prev_plan), one(prev_pose[0]), one(prev_pose[1]), one(cur_plan),
                                  one(cur_pose[0]), one(cur_pose[1]), dt, plan_dt)[0])


def extended_comfort(active, plans, poses_xy, poses_yaw, dt: float, plan_dt: float = PLAN_DT_S) -> float:
    """EC in [0, 1]: mean ``two_frame_comfort`` over consecutive active
    steps. ``plans`` (T, N, 2) ego frame; ``poses_xy (T, 2)``,
    ``poses_yaw (T,)``: the ego pose each plan was made from (start of the
    step). No pair: 1."""
    act = np.asarray(active, bool)
    k = np.flatnonzero(act[1:] & act[:-1]) + 1  # every pair (k - 1, k) in one batch
    if not len(k):
        return 1.0
    plans, xy, yaw = np.asarray(plans, np.float64), np.asarray(poses_xy, np.float64), np.asarray(poses_yaw, np.float64)
    return float(np.mean(_two_frame_batch(plans[k - 1], xy[k - 1], yaw[k - 1], plans[k], xy[k], yaw[k], dt, plan_dt)))


def _logged_ego_at(scenario: Any, t: float) -> tuple[np.ndarray, float]:
    """Logged ego (box centre xy (2,), yaw) at time ``t`` s: xy linearly
    interpolated between valid log samples, yaw of the nearest one."""
    e = int(scenario.ego_index)
    valid = np.asarray(scenario.tracks.valid[e], bool)
    steps = np.flatnonzero(valid)
    times = steps * float(scenario.dt_log)
    xy = np.asarray(scenario.tracks.xy[e], np.float64)[steps]
    p = np.array([np.interp(t, times, xy[:, 0]), np.interp(t, times, xy[:, 1])])
    yaw = float(np.asarray(scenario.tracks.yaw[e])[steps[np.argmin(np.abs(times - t))]])
    return p, yaw


def _sub_metrics(log: Any, scenario: Any, dt: float, plans, plan_dt: float, ref_raw: float, ref_mult: float):
    """The nine sub-metrics of one StepLog(-like) episode, unfiltered, and
    its multiplier product."""
    active = np.asarray(log.active, bool)
    f, nv = log.facts, log.facts.navsim
    speed = np.asarray(log.speed, np.float64)
    idx = np.flatnonzero(active)
    lon_acc, lat_acc, acc_mag = ego_comfort_inputs(
        speed[idx], np.asarray(log.accel, np.float64)[idx], np.asarray(log.steer, np.float64)[idx],
        np.asarray(log.yaw_rate, np.float64)[idx], dt)
    out = {
        "nc": (no_at_fault_collision(active, f.agent_hit, f.agent_hit_id, f.at_fault, f.layout_hit, speed)
               if getattr(f, "contacts", None) is None else
               no_at_fault_collision(active, f.contacts.hit, f.contacts.track_id, f.contacts.at_fault,
                                     f.contacts.obstacle_hit, speed)),
        "dac": 0.0 if np.any(active & (np.asarray(f.drivable_excess_m) > 0.0)) else 1.0,
        "ddc": driving_direction_compliance(
            active, log.xy, np.asarray(nv.oncoming, bool), np.asarray(nv.in_junction, bool), dt
        ),
        "tlc": 0.0 if np.any(active & np.asarray(f.red_light, bool)) else 1.0,
        "ttc": 0.0 if np.any(active & np.asarray(nv.ttc_violation, bool)) else 1.0,
        "lk": lane_keeping(active, np.asarray(nv.lane_offset, np.float64), np.asarray(nv.in_junction, bool), dt),
        "hc": history_comfort(lon_acc, lat_acc, np.asarray(log.yaw, np.float64)[idx], dt, acc_mag),
    }
    mult = out["nc"] * out["dac"] * out["ddc"] * out["tlc"]
    raw = 0.0
    if idx.size:
        t0 = float(log.t[idx[0]]) - dt
        start, _ = _logged_ego_at(scenario, t0)
        r = scenario.route
        prog = route_progress(np.stack([start, np.asarray(log.xy, np.float64)[idx[-1]]]), r.xy, r.arc, r.valid)
        raw = max(float(prog[1] - prog[0]), 0.0)
    out["ep"] = ego_progress(raw, mult, ref_raw * ref_mult)
    if plans is None or idx.size == 0:
        out["ec"] = 1.0
    else:
        xy = np.asarray(log.xy, np.float64)
        yaw = np.asarray(log.yaw, np.float64)
        p0, y0 = _logged_ego_at(scenario, float(log.t[0]) - dt)
        poses_xy = np.concatenate([p0[None], xy[:-1]])  # plan k is made from the pose before step k
        poses_yaw = np.concatenate([[y0], yaw[:-1]])
        out["ec"] = extended_comfort(active, np.asarray(plans, np.float64), poses_xy, poses_yaw, dt, plan_dt)
    return out, mult


def epdms(sub: Mapping[str, float]) -> float:
    """EPDMS of sub-metric values keyed nc, dac, ddc, tlc, ep, ttc, lk, hc, ec
    (``run_pdm_score.compute_final_scores``)."""
    mult = float(np.prod([sub[k] for k in MULTIPLIERS]))
    return mult * sum(WEIGHTS[k] * sub[k] for k in WEIGHTS) / sum(WEIGHTS.values())


def apply_human_filter(agent: Mapping[str, float], human: Mapping[str, float]) -> dict[str, float]:
    """E's human penalty filter: a sub-metric the human scores exactly 0 counts 1."""
    return {k: (1.0 if human[k] == 0 else v) for k, v in agent.items()}


def episode_columns(
    log: Any, scenario: Any, dt: float, human: Any = None, plans=None, plan_dt: float = PLAN_DT_S
) -> dict[str, float]:
    """The ``COLUMNS`` of ONE episode.

    Args:
      log: ``sim.StepLog`` as numpy (T, ...), ``facts.navsim`` a stacked
        ``NavsimTick``; only ``active`` steps count.
      scenario: unbatched numpy ``types.Scenario``.
      dt: simulation step, s.
      human: a StepLog-like log evaluated along the LOGGED ego (same fields),
        or None (no human filter).
      plans: (T, N, 2) the policy's waypoints (ego frame: box centre, x
        forward, m) at each step, ``plan_dt`` s apart; None: EC = 1.
    Returns: {column: value}; sub-metrics after the human filter, ``epdms``.
    """
    active = np.asarray(log.active, bool)
    idx = np.flatnonzero(active)
    ref_raw = 0.0
    if idx.size:
        t0, t1 = float(log.t[idx[0]]) - dt, float(log.t[idx[-1]])
        ends = np.stack([_logged_ego_at(scenario, t0)[0], _logged_ego_at(scenario, t1)[0]])
        prog = route_progress(ends, scenario.route.xy, scenario.route.arc, scenario.route.valid)
        ref_raw = max(float(prog[1] - prog[0]), 0.0)
    ref_mult = 1.0
    human_sub = None
    if human is not None:
        human_sub, ref_mult = _sub_metrics(human, scenario, dt, None, plan_dt, ref_raw, 1.0)
    sub, _ = _sub_metrics(log, scenario, dt, plans, plan_dt, ref_raw, ref_mult)
    if human_sub is not None:
        sub = apply_human_filter(sub, human_sub)
    cols = {f"navsim_{k}": float(sub[k]) for k in (*MULTIPLIERS, "ep", "ttc", "lk", "hc", "ec")}
    cols["epdms"] = epdms(sub)
    return cols
