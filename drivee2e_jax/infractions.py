"""Per-step infraction facts: the geometry behind every leaderboard event.

These pure functions (one scenario, one tick) answer *what happened this tick*:
which actor the ego box touches, whether its tail crossed a red stop line,
whether it is off its lanes, how fast the surrounding traffic moves. The
stateful leaderboard logic that turns facts into counted events (collision
de-duplication, route completion windows, checkpoints ...) lives in
``metrics.criteria``; ``sim.step`` wires the two together.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from drivee2e_jax import geometry
from drivee2e_jax.replay import SNAP, AgentStates
from drivee2e_jax.types import (
    Category,
    CollisionClass,
    CollisionType,
    EgoState,
    LaneType,
    MapData,
    Marking,
    SignalState,
    Tracks,
)

# Collision classes as CARLA's collision test names them.
CLASS_WALKER = int(CollisionClass.PEDESTRIAN)
CLASS_VEHICLE = int(CollisionClass.VEHICLE)

#: Half-angle (rad) within which a lane counts as running the ego's way. LB 2.0
#: flags a "wrong lane" on a heading jump of > 150 deg; 120 deg is the
#: junction-exit bound it also uses, so a lane > 120 deg off is opposite traffic.
LANE_ALIGN_MAX = math.radians(120.0)  # rad; a plain float: nothing touches the JAX backend at import
#: LB 2.0: off-lane if distance to the lane centre > lane_width / 2 + 0.5 m.
LANE_MARGIN = 0.5
#: Radius (m) within which moving vehicles count as surrounding "background"
#: traffic for the minimum-speed checkpoints (LB spawns them around the ego).
BACKGROUND_RADIUS = 50.0


@struct.dataclass
class StepFacts:
    """Raw facts about one tick (all scalars).

    Attributes:
      agent_hit:     bool, the ego box overlaps a replayed agent's box.
      agent_hit_id:  int32 that agent's track id (the lowest row if several).
      agent_hit_class: int32 CLASS_WALKER or CLASS_VEHICLE.
      agent_hit_category: int32 finer ``Category`` of that agent.
      layout_hit:    bool, the ego box overlaps a static obstacle.
      red_light:     bool, the ego's tail crossed a stop line showing red.
      red_light_index: int32 that stop line's row (-1 if none).
      red_light_lines: (S,) bool every stop line crossed on red this tick.
      off_lane:      bool, no lane running the ego's way is within width/2 + 0.5 m.
      lane_offset:   float32 distance to the nearest aligned lane centre, m.
      bg_speed:      float32 mean speed of moving vehicles within 50 m, m/s.
      bg_present:    bool, at least one such vehicle.
      front_distance: float32 centre distance to the nearest agent ahead in the
                     ego's lane corridor, m (inf if none).
      lane_invasion: bool, a corner of the ego box crossed a painted lane
                     marking (dashed, solid, double solid) this tick.
      lane_invasion_marking: int32 ``Marking`` of the crossed line (the
                     strictest if several; NONE if none).
      collision_type: int32 ``CollisionType`` of this tick's agent contact
                     (-1 none; ``collision_type``).
      at_fault:      bool, that contact is the ego's fault (``at_fault``).
      multi_lane:    bool, no single lane polygon holds all four ego corners
                     (``ego_lanes``).
      lanes_overflow: bool, more lanes could hold the ego than ``ego_lanes``
                     tested (``LANES_PER_TICK``): lane facts may be incomplete.
      drivable_excess_m: float32 how far the farthest ego corner lies outside
                     the map's drivable area, m (0 on it; ``drivable_excess``).
      speed_limit:   float32 lane speed limit at the ego's route point, m/s.
      nuplan:        ``metrics.nuplan.NuplanTick`` under the ``nuplan``
                     preset, else None.
      navsim:        ``metrics.navsim.NavsimTick`` under the ``navsim``
                     preset, else None.
      contacts:      ``ContactSet``, every overlapping candidate and obstacle
                     (the scalar ``agent_hit*`` fields keep only the nearest),
                     under the ``nuplan`` and ``navsim`` presets, else None.
    """

    agent_hit: jnp.ndarray
    agent_hit_id: jnp.ndarray
    agent_hit_class: jnp.ndarray
    agent_hit_category: jnp.ndarray
    layout_hit: jnp.ndarray
    red_light: jnp.ndarray
    red_light_index: jnp.ndarray
    red_light_lines: jnp.ndarray
    off_lane: jnp.ndarray
    lane_offset: jnp.ndarray
    bg_speed: jnp.ndarray
    bg_present: jnp.ndarray
    front_distance: jnp.ndarray
    lane_invasion: jnp.ndarray
    lane_invasion_marking: jnp.ndarray
    collision_type: jnp.ndarray
    at_fault: jnp.ndarray
    multi_lane: jnp.ndarray
    lanes_overflow: jnp.ndarray
    drivable_excess_m: jnp.ndarray
    speed_limit: jnp.ndarray
    nuplan: Any = None
    navsim: Any = None
    contacts: Any = None


@struct.dataclass
class ContactSet:
    """Every contact of one tick (the nuPlan / NAVSIM bookkeeping).

    nuPlan's ``find_new_collisions`` (no_ego_at_fault_collisions.py) tests the
    ego box against every tracked object and registers each overlapping track
    token; the scalar ``StepFacts.agent_hit*`` fields keep only the nearest
    overlapping agent (enough for the leaderboard's one event per contact).

    Attributes:
      hit:       (K,) bool the ego box overlaps candidate row k (the rows of
                 ``nearest_rows``; a logged-overlap exempt row is False).
      track_id:  (K,) int32 track id of each candidate row.
      category:  (K,) int32 ``Category`` of each candidate row.
      at_fault:  (K,) bool ``hit`` and that contact is the ego's fault
                 (``collision_type`` + ``at_fault`` per row).
      obstacle_hit: (O,) bool the ego box overlaps static obstacle o (its row
                 in ``MapData.obstacles``: the obstacle's identity).
    """

    hit: jnp.ndarray
    track_id: jnp.ndarray
    category: jnp.ndarray
    at_fault: jnp.ndarray
    obstacle_hit: jnp.ndarray


#: At most this many agents per episode are exempt for a logged overlap with
#: the ego that is there when they first appear together
#: (``logged_overlap_spans``).
MAX_LOGGED_OVERLAPS = 8

#: Agents tested for contact each tick: the nearest by centre distance. An
#: overlapping agent is within half the sum of the two box diagonals (< 9 m
#: for a bus against a car), so it is among these unless 16 others are closer.
CONTACT_CANDIDATES = 16


def nearest_rows(ego: EgoState, agents: AgentStates, k: int = CONTACT_CANDIDATES):
    """(k,) rows of the valid agents nearest the ego (nearest first), and their validity."""
    d = agents.xy - ego.xy
    d2 = geometry.dot(d, d)
    k = min(k, d2.shape[0])
    neg, idx = jax.lax.top_k(-jnp.where(agents.valid, d2, jnp.inf), k)
    return idx, jnp.isfinite(neg)


def candidate_overlaps(ego: EgoState, ego_lw, agents: AgentStates, size, near):
    """(K,) bool: the ego box overlaps the box of candidate row ``near[k]``
    (validity not applied)."""
    return jax.vmap(geometry.boxes_overlap, in_axes=(None, None, None, 0, 0, 0))(
        ego.xy, ego.yaw, ego_lw, agents.xy[near], agents.yaw[near], size[near, :2]
    )


def agent_contacts(ego: EgoState, ego_lw, agents: AgentStates, size, category, track_id, near, near_ok,
                   overlap=None):
    """Which replayed agent (if any) the ego box overlaps.

    Tests the candidate rows ``near`` (nearest first, from ``nearest_rows``)
    and returns (hit, track id, class, category, row) of the nearest
    overlapping one. CARLA reports one collision event per contact; one per tick is
    enough here because ``CollisionDedup`` drops repeats of the same actor
    within 5 s and any contact within 5 m of the last counted one. Every
    overlapping row (nuPlan counts each track): ``contact_set``.
    ``overlap``: (K,) ``candidate_overlaps`` if already computed.
    """
    if overlap is None:
        overlap = candidate_overlaps(ego, ego_lw, agents, size, near)
    overlap = overlap & near_ok
    i = near[jnp.argmax(overlap)]
    cat = category[i]
    cls = jnp.where(cat == Category.PEDESTRIAN, CLASS_WALKER, CLASS_VEHICLE)
    return overlap.any(), track_id[i], cls.astype(jnp.int32), cat.astype(jnp.int32), i


def contact_set(ego: EgoState, ego_lw, rear_offset, agents: AgentStates, size, category, track_id, near, hit,
                multi_lane, drivable_excess_m, obstacle_hit) -> ContactSet:
    """``ContactSet`` of one tick: every overlapping candidate row with its
    nuPlan collision type and fault, and the obstacles touched.

    Args:
      ego: EgoState after the step.  ego_lw: (2,) m.  rear_offset: () m.
      agents: AgentStates (A,).  size: (A, 3) m.  category, track_id: (A,) int.
      near: (K,) candidate rows.  hit: (K,) bool overlapping and counted
        (``candidate_overlaps & near_ok & ~exempt``).
      multi_lane: () bool.  drivable_excess_m: () m (``at_fault``'s lateral rule).
      obstacle_hit: (O,) bool (``layout_contacts``).
    """
    kind = jax.vmap(collision_type, in_axes=(None, None, None, 0, 0, 0, 0))(
        ego, ego_lw, rear_offset, agents.xy[near], agents.yaw[near], size[near, :2],
        geometry.safe_norm(agents.vel[near]),
    )
    fault = hit & at_fault(kind, multi_lane, drivable_excess_m)
    return ContactSet(hit=hit, track_id=track_id[near].astype(jnp.int32), category=category[near].astype(jnp.int32),
                      at_fault=fault, obstacle_hit=obstacle_hit)


#: nuPlan's ``stopped_speed_threshold``: a speed at or below this is stopped, m/s.
STOPPED_SPEED = 0.05
#: nuPlan's ``is_agent_behind`` angle tolerance: a track whose centre lies more
#: than this far off the ego's heading, seen from the rear axle, is behind.
BEHIND_ANGLE = math.radians(150.0)


def collision_type(ego: EgoState, ego_lw, rear_offset, other_xy, other_yaw, other_lw, other_speed):
    """() int32 ``CollisionType`` of a contact between the ego and one track.

    nuPlan's ``_get_collision_type`` (``no_ego_at_fault_collisions.py``), in
    its order: the ego stopped (speed <= 0.05 m/s); else the track stopped;
    else ACTIVE_REAR when the track's centre is behind the ego's rear axle
    (angle to the heading > 150 deg, ``idm/utils.py: is_agent_behind``); else
    ACTIVE_FRONT when the ego's front edge (FL-FR) touches the track's box;
    else ACTIVE_LATERAL.

    Args:
      ego: the ego after the step (box centre ``xy``, ``yaw``, ``speed`` m/s).
      ego_lw: (2,) ego length, width, m.  rear_offset: () m from the rear axle
        to the box centre.
      other_xy (2,), other_yaw (), other_lw (2,), other_speed (): the track, m, rad, m/s.
    """
    heading = jnp.stack([jnp.cos(ego.yaw), jnp.sin(ego.yaw)])
    to_other = other_xy - (ego.xy - rear_offset * heading)
    cos_angle = geometry.dot(heading, to_other) / jnp.maximum(geometry.safe_norm(to_other), 1e-9)
    behind = cos_angle < math.cos(BEHIND_ANGLE)
    corners = geometry.box_corners(ego.xy, ego.yaw, ego_lw[0], ego_lw[1])  # FR, FL, RL, RR
    front = geometry.segment_box_intersect(corners[1], corners[0], other_xy, other_yaw, other_lw)
    kind = jnp.where(
        ego.speed <= STOPPED_SPEED, CollisionType.STOPPED_EGO,
        jnp.where(other_speed <= STOPPED_SPEED, CollisionType.STOPPED_TRACK,
                  jnp.where(behind, CollisionType.ACTIVE_REAR,
                            jnp.where(front, CollisionType.ACTIVE_FRONT, CollisionType.ACTIVE_LATERAL))))
    return kind.astype(jnp.int32)


def at_fault(kind, multi_lane, drivable_excess_m):
    """() bool: a contact of ``CollisionType`` ``kind`` is the ego's fault.

    nuPlan's ``classify_at_fault_collisions``: a stopped track or the ego's
    front hitting something, or a lateral contact while the ego is in several
    lanes or outside the drivable area. Contacts with the ego stopped and
    rear-end contacts are never its fault (-1, no contact: False).
    """
    lateral = (kind == CollisionType.ACTIVE_LATERAL) & (multi_lane | (drivable_excess_m > 0.0))
    return (kind == CollisionType.STOPPED_TRACK) | (kind == CollisionType.ACTIVE_FRONT) | lateral


def area_distance(points, edges, edges_valid):
    """(Q,) distance (m) of each point outside an area given by its boundary
    edges; 0 inside or on it.

    Exact for any union of simple polygons (holes included) whose boundary
    rings are flattened into ``edges`` (``scenario.drivable.drivable_edges``):
    a point is inside when a ray from it towards +x crosses an odd number of
    edges (even-odd rule), and its distance to the area is then its distance
    to the nearest edge. An area without any valid edge has distance 0 (not
    judged).

    Args:
      points: (Q, 2) m.  edges: (D, 4) [ax, ay, bx, by] m.  edges_valid: (D,) bool.
    """
    px, py = points[:, 0:1], points[:, 1:2]  # (Q, 1)
    ax, ay, bx, by = (edges[None, :, i] for i in range(4))  # (1, D)
    straddles = (ay > py) != (by > py)
    dy = jnp.where(straddles, by - ay, 1.0)
    x_cross = ax + (py - ay) * (bx - ax) / dy
    crossings = straddles & edges_valid[None] & (px < x_cross)
    inside = (jnp.sum(crossings, axis=1) % 2) == 1  # (Q,)
    ex, ey = bx - ax, by - ay
    t = jnp.clip(((px - ax) * ex + (py - ay) * ey) / jnp.maximum(ex * ex + ey * ey, 1e-12), 0.0, 1.0)
    dx, dyy = px - (ax + t * ex), py - (ay + t * ey)
    d2 = jnp.where(edges_valid[None], dx * dx + dyy * dyy, jnp.inf).min(axis=1)
    dist = jnp.sqrt(jnp.where(jnp.isfinite(d2), d2, 0.0))
    return jnp.where(inside | ~edges_valid.any(), 0.0, dist)


def drivable_excess(ego: EgoState, ego_lw, map_data: MapData):
    """() float32 how far the farthest ego corner lies outside the drivable
    area, m (0 when all four are on it).

    nuPlan's ``drivable_area_compliance`` measures each corner's distance to
    the DRIVABLE_AREA layer (``get_distance_to_nearest_map_object``) and fails
    at >= 0.3 m; NAVSIM's ``PDMScorer`` fails when any corner is outside the
    drivable polygons. Both read this value (``area_distance`` over
    ``MapData.drivable_edges``: the union of the map's drivable polygons, or of
    its lane areas when it has none).
    """
    corners = geometry.box_corners(ego.xy, ego.yaw, ego_lw[0], ego_lw[1])
    return area_distance(corners, map_data.drivable_edges, map_data.drivable_edges_valid).max()


#: Lanes tested per tick for the ego centre and rear axle: those whose box
#: meets the ego's bounding box (every lane holding a point of the ego box is
#: among them unless ``EgoLanes.overflow``). On twin15 val's logged ego poses
#: at most 14 lane boxes meet it.
LANES_PER_TICK = 16
#: Lanes tested per tick for ``multi_lane``: those whose box holds the ego's
#: whole bounding box (a lane holding all four corners does). On twin15 val's
#: logged ego poses at most 12 do, 2 on average.
LANES_FULL_PER_TICK = 12


@struct.dataclass
class LaneIndex:
    """The map's lane polygons prepared once per episode (``lane_index``).

    Attributes:
      boxes: (L, 4) float32 [xmin, ymin, xmax, ymax] of each lane polygon, m
             (empty, +inf/-inf, for padding).
      edges: (L, P, 4) float32 [ax, ay, by, dxdy] of the polygon's closed
             edges: start, end y and the inverse slope (bx - ax) / (by - ay)
             (0 for a horizontal edge, which no horizontal ray crosses), m.
      edge_valid: (L, P) bool (False for padding).
    """

    boxes: jnp.ndarray
    edges: jnp.ndarray
    edge_valid: jnp.ndarray


def lane_index(lane_polygons) -> LaneIndex:
    """``LaneIndex`` of ``types.Polylines`` (L, P) lane polygons
    (``MapData.lane_polygons``, vertices a valid prefix as packing writes
    them)."""
    ok = lane_polygons.point_valid & lane_polygons.valid[:, None]
    x, y = lane_polygons.xy[..., 0], lane_polygons.xy[..., 1]
    lo = lambda a: jnp.where(ok, a, jnp.inf).min(axis=1)  # noqa: E731
    hi = lambda a: jnp.where(ok, a, -jnp.inf).max(axis=1)  # noqa: E731
    # Packed polygons hold their vertices as a valid prefix: vertex i's edge
    # runs to vertex i + 1, the last valid one's back to vertex 0.
    nxt_ok = jnp.concatenate([ok[:, 1:], jnp.zeros_like(ok[:, :1])], axis=1)
    nxt = jnp.where(nxt_ok[..., None], jnp.roll(lane_polygons.xy, -1, axis=1), lane_polygons.xy[:, :1])
    dy = nxt[..., 1] - y
    inv_slope = jnp.where(dy != 0, (nxt[..., 0] - x) / jnp.where(dy != 0, dy, 1.0), 0.0)
    return LaneIndex(boxes=jnp.stack([lo(x), lo(y), hi(x), hi(y)], axis=-1),
                     edges=jnp.stack([x, y, nxt[..., 1], inv_slope], axis=-1), edge_valid=ok)


@struct.dataclass
class LaneHits:
    """Which lanes hold which points this tick (``lane_hits``).

    Attributes:
      rows:     (M,) int32 lane rows tested (those whose grown box holds the
                ego centre; -1 padded).
      inside:   (Q, M) bool point q lies in lane ``rows[m]``'s polygon.
      overflow: () bool more than M lane boxes held the centre.
    """

    rows: jnp.ndarray
    inside: jnp.ndarray
    overflow: jnp.ndarray


def lane_rows(lo, hi, index: LaneIndex, m: int = LANES_PER_TICK, *, contain: bool = False):
    """(rows (M,) int32 -1 padded, overflow () bool): the lanes whose box meets
    the axis-aligned box [lo, hi] ((2,) each, m) -- or, with ``contain``,
    holds all of it -- at most ``m`` of them. Every lane polygon holding a
    point of [lo, hi] (all of it) is among them unless ``overflow``."""
    b = index.boxes
    if contain:
        meets = (b[:, 0] <= lo[0]) & (hi[0] <= b[:, 2]) & (b[:, 1] <= lo[1]) & (hi[1] <= b[:, 3])
    else:
        meets = (b[:, 0] <= hi[0]) & (lo[0] <= b[:, 2]) & (b[:, 1] <= hi[1]) & (lo[1] <= b[:, 3])
    m = min(m, b.shape[0])
    score, rows = jax.lax.top_k(meets.astype(jnp.float32), m)
    return jnp.where(score > 0, rows, -1).astype(jnp.int32), jnp.sum(meets) > m


def points_in_lanes(points, rows, index: LaneIndex):
    """(Q, M) bool: point q of ``points`` (Q, 2) lies in lane ``rows[m]``'s
    polygon (even-odd rule over its precomputed edges; False for row -1)."""
    safe = jnp.maximum(rows, 0)
    e, ok = index.edges[safe], index.edge_valid[safe] & (rows >= 0)[:, None]  # (M, P, 4), (M, P)
    px, py = points[:, 0, None, None], points[:, 1, None, None]  # (Q, 1, 1)
    ax, ay, by, inv = (e[None, ..., i] for i in range(4))  # (1, M, P)
    crossings = ((ay > py) != (by > py)) & ok[None] & (px < ax + (py - ay) * inv)
    return (jnp.sum(crossings, axis=-1) % 2) == 1


def lane_hits(points, index: LaneIndex, m: int = LANES_PER_TICK) -> LaneHits:
    """Point-in-polygon of ``points`` (Q, 2) against every lane whose box
    meets the points' bounding box, at most ``m`` (``lane_rows``).

    Exact for each lane: the polygon is the lane's own area (its boundaries,
    or its curved centreline +- width / 2; ``MapData.lane_polygons``), tested
    with the even-odd rule along every edge, curves and junction connectors
    included -- no straight-over-a-car-length approximation. Every lane that
    holds one of the points is tested unless ``overflow``.
    """
    rows, overflow = lane_rows(points.min(axis=0), points.max(axis=0), index, m)
    return LaneHits(rows=rows, inside=points_in_lanes(points, rows, index), overflow=overflow)


@struct.dataclass
class EgoLanes:
    """Where the ego box lies among the map's lanes this tick, from the lanes'
    own polygons (``ego_lanes``). M = ``LANES_PER_TICK`` lanes tested.

    Attributes:
      multi_lane: () bool no single lane polygon holds all four corners
                  (nuPlan ``ego_lane_change.py``: "ego in multiple lanes";
                  also True when no lane holds them, e.g. off the lanes).
      centre_in:  (M,) bool the ego centre lies in lane ``rows[m]``.
      rear_in:    (M,) bool the ego's rear axle does.
      tangent:    (M, 2) unit driving direction of lane ``rows[m]`` at the
                  ego centre (its centreline's nearest segment).
      centre_offset: (M,) m distance of the ego centre to lane ``rows[m]``'s
                  centreline polyline (``geometry.nearest_segment``; inf for
                  a padded row). NAVSIM's lane-keeping deviation.
      connector:  (M,) bool lane ``rows[m]`` is a junction CONNECTOR.
      rows:       (M,) int32 the lanes tested (-1 padded).
      overflow:   () bool more lanes could hold the ego than were tested.
    """

    multi_lane: jnp.ndarray
    centre_in: jnp.ndarray
    rear_in: jnp.ndarray
    tangent: jnp.ndarray
    connector: jnp.ndarray
    rows: jnp.ndarray
    overflow: jnp.ndarray
    centre_offset: jnp.ndarray


def ego_lanes(ego: EgoState, ego_lw, rear_offset, index: LaneIndex, map_data: MapData) -> EgoLanes:
    """``EgoLanes`` of the ego box this tick.

    The corners (``multi_lane``) and the centre / rear axle (the NAVSIM and
    nuPlan facts) are tested apart, so a preset that reads only
    ``multi_lane`` leaves the rest out of the compiled step.

    Args:
      ego: the ego after the step.  ego_lw: (2,) m.  rear_offset: () m from
        the rear axle to the box centre.
      index: ``lane_index(map_data.lane_polygons, half-diagonal)``, once per episode.
      map_data: ``MapData`` (lanes, lane_type).
    """
    fwd = jnp.stack([jnp.cos(ego.yaw), jnp.sin(ego.yaw)])
    corners = geometry.box_corners(ego.xy, ego.yaw, ego_lw[0], ego_lw[1])
    # multi_lane: a lane holding all four corners has a box holding the
    # ego's whole bounding box -- few lanes do (twin15 val: at most 12).
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    full, full_over = lane_rows(lo, hi, index, LANES_FULL_PER_TICK, contain=True)
    held = jnp.all(points_in_lanes(corners, full, index), axis=0)
    # The centre and rear axle: the lanes whose box meets the ego's box.
    rows, overflow = lane_rows(lo, hi, index)
    in_axis = points_in_lanes(jnp.stack([ego.xy, ego.xy - rear_offset * fwd]), rows, index)  # (2, M)
    safe = jnp.maximum(rows, 0)
    lanes = map_data.lanes
    dist, heading = jax.vmap(geometry.nearest_segment, in_axes=(None, 0, 0))(ego.xy, lanes.xy[safe],
                                                                            lanes.point_valid[safe])
    return EgoLanes(
        multi_lane=~jnp.any(held),
        centre_in=in_axis[0],
        rear_in=in_axis[1],
        tangent=jnp.stack([jnp.cos(heading), jnp.sin(heading)], axis=-1),
        connector=(map_data.lane_type[safe] == LaneType.CONNECTOR) & (rows >= 0),
        rows=rows,
        overflow=overflow | full_over,
        centre_offset=jnp.where(rows >= 0, dist, jnp.inf),
    )


def logged_overlap_spans(tracks: Tracks, ego_index, ego_lw):
    """Where the LOGGED ego box already overlaps another agent's logged box.

    A non-reactive replay cannot undo a contact the log starts with (an
    annotation overlap, an agent detected inside the ego's box): the other
    agent drives on as recorded, so a policy that follows the log would be
    charged for the data. As NAVSIM does (``PDMObservation.update`` collects
    the tracks already intersecting the ego at the current frame and
    ``PDMScorer._calculate_no_at_fault_collision`` skips them), such a pair
    is exempt from the contact test while that logged overlap lasts.

    Precisely: for agent a, let k0 be the first log step at which both a
    and the ego are valid. If their logged boxes overlap at k0 (depth >
    ``geometry.EPS``), the pair is exempt from k0 through the last step of
    that run of overlapping steps (up to the first step at which they no
    longer overlap, or a sample is missing). An overlap that begins later,
    after the two were apart, is a collision in the log: it is not exempt
    (``curation.check_overlaps`` warns about every logged overlap).

    Computed once per episode (at reset): one box test per agent at its k0,
    then the T steps of at most ``MAX_LOGGED_OVERLAPS`` agents that overlap
    there (more than that many boxes inside the ego's at first sight is no
    log; the extra ones are not exempt).

    Args:
      tracks: the scenario's ``types.Tracks`` (A agents, T log steps).
      ego_index: () int32 the ego's row.  ego_lw: (2,) ego length, width, m.

    Returns: (A, 2) int32 [first, last] exempt log steps per agent; [T, -1]
      (empty) for an agent not overlapping the ego when first seen with it,
      and for the ego's own row.
    """
    num_agents, num_steps = tracks.valid.shape
    ego_xy, ego_yaw, ego_ok = tracks.xy[ego_index], tracks.yaw[ego_index], tracks.valid[ego_index]
    others = jnp.arange(num_agents) != ego_index
    steps = jnp.arange(num_steps)
    both = tracks.valid & ego_ok[None] & others[:, None]  # (A, T)
    k0 = jnp.where(both, steps, num_steps).min(axis=1)  # (A,) first common step (T: never)
    kk = jnp.minimum(k0, num_steps - 1)
    rows = jnp.arange(num_agents)
    born = jax.vmap(geometry.boxes_overlap, in_axes=(0, 0, None, 0, 0, 0))(
        ego_xy[kk], ego_yaw[kk], ego_lw, tracks.xy[rows, kk], tracks.yaw[rows, kk], tracks.size[:, :2]
    ) & (k0 < num_steps)
    m = min(MAX_LOGGED_OVERLAPS, num_agents)
    _, sel = jax.lax.top_k(born.astype(jnp.float32), m)  # the born-overlapping rows first

    def run_end(r):
        ov = jax.vmap(geometry.boxes_overlap, in_axes=(0, 0, None, 0, 0, None))(
            ego_xy, ego_yaw, ego_lw, tracks.xy[r], tracks.yaw[r], tracks.size[r, :2]
        ) & both[r]
        return jnp.where((steps > k0[r]) & ~ov, steps, num_steps).min()  # first step apart again

    end = jax.vmap(run_end)(sel)
    ok = born[sel]
    spans = jnp.tile(jnp.array([[num_steps, -1]], jnp.int32), (num_agents, 1))
    first = jnp.where(ok, k0[sel], num_steps)
    last = jnp.where(ok, end - 1, -1)
    return spans.at[sel].set(jnp.stack([first, last], axis=-1).astype(jnp.int32))


def logged_overlap_exempt(spans, t, dt_log):
    """(k,) bool: the rows of ``spans`` (k, 2) whose logged overlap lasts at ``t``.

    ``t`` (s) counts as inside [first, last] (log steps of ``dt_log`` s) when
    either log sample bracketing it is: a time within ``replay.SNAP`` steps of
    a sample is that sample, as ``replay.agents_at`` treats it.
    """
    u = t / dt_log
    lo = jnp.floor(u + SNAP)
    hi = jnp.ceil(u - SNAP)
    return (hi >= spans[:, 0]) & (lo <= spans[:, 1])


def logged_overlap_count(spans, t_end, dt_log):
    """() int32 agents with an exempt logged overlap (``spans`` (A, 2) of
    ``logged_overlap_spans``) beginning by ``t_end`` s, on a log of step ``dt_log`` s."""
    begun = (spans[:, 0] <= spans[:, 1]) & (spans[:, 0] <= jnp.floor(t_end / dt_log + SNAP))
    return jnp.sum(begun).astype(jnp.int32)


def obstacle_sat(map_data: MapData) -> geometry.PolygonSAT:
    """(O, ...) separating-axis data of every static obstacle (once per episode)."""
    obs = map_data.obstacles
    return jax.vmap(geometry.polygon_sat)(obs.xy, obs.point_valid & obs.valid[:, None])


def layout_contacts(ego: EgoState, ego_lw, sat: geometry.PolygonSAT):
    """(O,) bool: the ego box overlaps static obstacle footprint o (convex)."""
    depth = jax.vmap(geometry.polygon_sat_box_penetration, in_axes=(0, None, None, None))(
        sat, ego.xy, ego.yaw, ego_lw
    )
    return depth > geometry.EPS


def layout_contact(ego: EgoState, ego_lw, sat: geometry.PolygonSAT):
    """Whether the ego box overlaps any static obstacle footprint (convex)."""
    return layout_contacts(ego, ego_lw, sat).any()


def stop_line_directions(map_data: MapData):
    """(S, 2) unit direction of travel across each stop line (its lane's heading).

    Falls back to the stop line's normal when the guarded lane is unknown.
    """
    lanes = map_data.lanes
    mid = map_data.stop_lines.mean(axis=1)

    def one(mid_s, lane_s, seg):
        lane = jnp.maximum(lane_s, 0)
        proj = geometry.project_to_polyline(mid_s, lanes.xy[lane], lanes.point_valid[lane])
        d_lane = jnp.stack([jnp.cos(proj.heading), jnp.sin(proj.heading)])
        e = seg[1] - seg[0]
        normal = jnp.stack([-e[1], e[0]]) / (jnp.linalg.norm(e) + 1e-9)
        return jnp.where(lane_s >= 0, d_lane, normal)

    return jax.vmap(one)(mid, map_data.stop_line_lane, map_data.stop_lines)


def red_light_crossing(prev: EgoState, ego: EgoState, ego_length, map_data: MapData, stop_dir, state):
    """Whether the ego's tail crossed a stop line showing red this tick.

    LB 2.0 tests the tail segment (0.8 * half-length to half-length + 1 m
    behind the centre) against each stop line at 20 Hz. At our 10 Hz a car at
    15 m/s moves 1.5 m per tick and could jump over a 1.5 m segment, so we test
    the swept segment from last tick's far tail point to this tick's near tail
    point, which contains both tail segments. Heading must agree with the lane
    (dot > 0), as in LB.

    Returns (any: bool, first stop line row: int32 or -1, (S,) bool per line).
    """
    half = 0.5 * ego_length

    def fwd(e):
        return jnp.stack([jnp.cos(e.yaw), jnp.sin(e.yaw)])

    a = prev.xy - fwd(prev) * (half + 1.0)
    b = ego.xy - fwd(ego) * (0.8 * half)
    crossed = jax.vmap(geometry.segments_intersect, in_axes=(None, None, 0, 0))(
        a, b, map_data.stop_lines[:, 0], map_data.stop_lines[:, 1]
    )
    f = fwd(ego)
    aligned = stop_dir[:, 0] * f[0] + stop_dir[:, 1] * f[1] > 0.0
    red = crossed & aligned & map_data.stop_line_valid & (state == SignalState.RED)
    return red.any(), jnp.where(red.any(), jnp.argmax(red), -1).astype(jnp.int32), red


def lane_status(ego: EgoState, lane_xy, lane_point_valid, lane_valid, lane_width):
    """Off-lane test against candidate lanes (M of them).

    A lane counts if it runs within ``LANE_ALIGN_MAX`` of the ego heading; the
    ego is off-lane when the nearest such centreline is farther than
    width / 2 + 0.5 m (LB 2.0's test; an opposite-direction lane never counts,
    which is LB's "wrong lane"). Connector lanes cover junction interiors, so
    turning through the junction on a connector is on-lane.

    Returns (off_lane: bool, offset to nearest aligned lane centre: float32).
    """
    # Lanes are sampled at <= 2 m, so the nearest-vertex projection is exact here.
    dist, heading = jax.vmap(geometry.nearest_segment, in_axes=(None, 0, 0))(ego.xy, lane_xy, lane_point_valid)
    aligned = jnp.abs(geometry.wrap_angle(heading - ego.yaw)) < LANE_ALIGN_MAX
    ok = lane_valid & aligned
    excess = jnp.where(ok, dist - (0.5 * lane_width + LANE_MARGIN), jnp.inf)
    offset = jnp.where(ok, dist, jnp.inf).min()
    return ~(excess.min() <= 0.0), offset


def background_speed(ego: EgoState, agents: AgentStates, category):
    """Mean speed of vehicles within ``BACKGROUND_RADIUS`` (LB min-speed input)."""
    d = geometry.row_norms(agents.xy - ego.xy)
    is_vehicle = (category != Category.PEDESTRIAN) & (category != Category.CYCLIST)
    sel = agents.valid & is_vehicle & (d < BACKGROUND_RADIUS)
    speed = geometry.row_norms(agents.vel)
    n = sel.sum()
    return jnp.where(n > 0, jnp.sum(jnp.where(sel, speed, 0.0)) / jnp.maximum(n, 1), 0.0), n > 0


def front_distance(ego: EgoState, ego_lw, agents: AgentStates, size):
    """Centre distance to the nearest agent ahead inside the ego's lane corridor.

    Corridor: ahead (x > 0 in the ego frame) and laterally within half the ego
    width + half the agent width + 0.5 m. Used for Behavior Metrics'
    front-vehicle buckets; inf if nothing is ahead.
    """
    rel = geometry.to_frame(agents.xy, ego.xy, ego.yaw)
    in_corridor = (rel[:, 0] > 0) & (jnp.abs(rel[:, 1]) < 0.5 * ego_lw[1] + 0.5 * size[:, 1] + 0.5)
    d = jnp.where(agents.valid & in_corridor, geometry.row_norms(rel), jnp.inf)
    return d.min()


def _cross2(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


@struct.dataclass
class MarkingSegments:
    """Painted lane-marking segments near the route, flattened (per episode).

    Attributes:
      a:       (K, 2) segment start points, m.
      ab:      (K, 2) segment vectors (end - start), m.
      marking: (K,) int32 ``Marking`` of the segment's line; ``NONE`` for
               padding, invalid points and unpainted lines (road edges).
    """

    a: jnp.ndarray
    ab: jnp.ndarray
    marking: jnp.ndarray


def marking_segments(bnd_xy, bnd_point_valid, bnd_valid, bnd_marking) -> MarkingSegments:
    """The painted segments of M boundary polylines, computed once at reset.

    Only painted markings count (dashed, solid, double solid); road edges
    are the off-road criteria's business.

    Args:
      bnd_xy: (M, N, 2) boundary polylines, m; bnd_point_valid (M, N) bool;
      bnd_valid: (M,) bool; bnd_marking: (M,) int32 ``Marking``.

    Returns: ``MarkingSegments`` with K = M * (N - 1).
    """
    a, b = bnd_xy[:, :-1], bnd_xy[:, 1:]
    seg_ok = bnd_point_valid[:, :-1] & bnd_point_valid[:, 1:]
    painted = bnd_valid & (bnd_marking >= Marking.DASHED) & (bnd_marking <= Marking.DOUBLE_SOLID)
    marking = jnp.where(seg_ok & painted[:, None], bnd_marking[:, None], Marking.NONE).astype(jnp.int32)
    return MarkingSegments(a=a.reshape(-1, 2), ab=(b - a).reshape(-1, 2), marking=marking.reshape(-1))


def lane_invasion(prev: EgoState, ego: EgoState, ego_lw, segments: MarkingSegments):
    """Whether a corner of the ego box crossed a painted lane marking this tick.

    CARLA's lane-invasion sensor (the input of Behavior Metrics' lane
    invasions) fires when the vehicle's box crosses a marking. Each corner's
    motion over the tick (last tick's corner -> this tick's) is tested for a
    proper crossing with every painted segment of ``segments``
    (``marking_segments`` of the boundaries near the route, built at reset
    so no map rows are gathered per step).

    Args:
      prev, ego: the ego before and after the tick.  ego_lw: (2,) m.
      segments: ``MarkingSegments`` (K,).

    Returns (crossed: bool, the crossed line's ``Marking``: int32, strictest).
    """
    c0 = geometry.box_corners(prev.xy, prev.yaw, ego_lw[0], ego_lw[1])  # (4, 2)
    c1 = geometry.box_corners(ego.xy, ego.yaw, ego_lw[0], ego_lw[1])
    a, ab = segments.a, segments.ab  # (K, 2)
    p0, p1 = c0[:, None], c1[:, None]  # (4, 1, 2)
    o1, o2 = _cross2(ab, p0 - a), _cross2(ab, p1 - a)
    d = p1 - p0
    o3 = _cross2(d, a - p0)
    o4 = o3 + _cross2(d, ab)  # cross(d, b - p0) with b = a + ab
    hit = (o1 * o2 < 0) & (o3 * o4 < 0)  # (4, K)
    marking = jnp.max(jnp.where(hit.any(axis=0), segments.marking, Marking.NONE))
    return marking > Marking.NONE, marking.astype(jnp.int32)
