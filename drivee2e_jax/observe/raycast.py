"""Ray-casting core shared by the LiDAR, cameras, radar and visibility.

Three stages, each a pure function of ONE scenario at one instant:

1. ``select_scene``: the ``K`` nearest valid agents (boxes with heights) and the
   ``O'`` nearest static obstacles (extruded polygons, one vertical face per
   edge) around the ego, in the world frame. Built once per step and shared
   by every sensor.
2. ``polar_buffer``: a 2-D depth buffer over a fan of horizontal rays from one
   sensor origin: per ray the ``D`` nearest object faces it enters (horizontal
   range, height of the object's top, hit code, agent row). Each object is
   tested only on the rays of a small angular window starting at its first
   ray (``BufferConfig.window_deg``); the few objects whose angular extent is
   widest (boxes / walls very close to the sensor) are tested on every ray,
   so near objects are never clipped. The tier windows are cut into disjoint
   ray segments, so each (object, ray) pair is tested once, with the
   per-object terms (a box's cos / sin, the sensor in its frame) computed
   once. Candidates are merged per ray by ``D`` rounds of scatter-min on
   integer keys (range bits with the object id in the low bits), and the
   winners' exact ranges are gathered from their candidates, so ranges are
   differentiable in the agents' poses away from box corners.
3. ``solve_elevation``: a beam at elevation ``phi`` from mount height ``z0`` is
   at height ``z0 + r tan(phi)`` at horizontal range ``r``; it hits the first
   buffered face whose height span [0, top] contains that height and passes
   over lower ones; a beam that hits no face and points down hits the ground
   at ``r = z0 / tan(-phi)``. Roofs are not modelled (a beam that clears a
   face's top edge passes over the object), and a beam that clears all ``D``
   buffered faces can only hit the ground.

Hit codes (``hit_class`` of every sensor): 0 ``HIT_NONE`` (no return / sky),
1 ``HIT_GROUND``, 2 ``HIT_STATIC`` (static obstacle), ``HIT_AGENT + c`` for an
agent of ``types.Category`` c (3 = car ... 10 = cyclist).

A sensor inside a box or polygon does not see that object (entry distances
must be > 0): pass the ego's row as ``exclude`` so its own box is never hit.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax import geometry
from drivee2e_jax.observe.xla_cpu import materialize
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import Polylines

Array = jnp.ndarray

HIT_NONE = 0
HIT_GROUND = 1
HIT_STATIC = 2
HIT_AGENT = 3  # + types.Category

#: Key of "no candidate" (``pack_key``); above every packed finite range.
MISS = 2**31 - 1


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Which objects the sensors consider.

    Attributes:
      num_agents:    K, nearest valid agents kept (by distance to their box).
      num_obstacles: nearest static obstacles kept (all their edges).
      radius:        objects farther than this from the ego (m) are dropped;
                     set it to the largest sensor range.
    """

    num_agents: int = 32
    num_obstacles: int = 8
    radius: float = 100.0

    def __post_init__(self):
        if self.num_agents < 1 or self.num_obstacles < 0:
            raise ValueError(f"SceneConfig: num_agents >= 1 and num_obstacles >= 0, got {self}")
        if self.radius <= 0:
            raise ValueError(f"SceneConfig.radius must be > 0 m, got {self.radius}")


@dataclasses.dataclass(frozen=True)
class BufferConfig:
    """Shape and windows of a polar depth buffer.

    Each object is tested on the rays of an angular window starting at its
    first ray. Windows come in tiers ``(count, window_deg)``: the ``count``
    objects of widest angular extent (0 = all objects) are tested over
    ``window_deg`` (capped at a half circle for a full-circle fan, which any
    box or wall not containing the sensor fits in, and at the whole fan
    otherwise). An object is exact when its extent fits the widest tier its
    rank reaches; otherwise its far side is clipped. The defaults keep every
    object exact unless more than 6 agents (8 edges) span over 10 deg, or more
    than 2 agents (4 edges) over 45 deg, i.e. unless several objects lie within
    a few metres of the sensor at once.

    Attributes:
      depth:       D, nearest faces kept per ray (a beam can pass over D-1).
      agent_tiers: window tiers of the agent boxes.
      edge_tiers:  window tiers of the static obstacle edges.
    """

    depth: int = 3
    agent_tiers: tuple[tuple[int, float], ...] = ((0, 10.0), (6, 45.0), (2, 180.0))
    edge_tiers: tuple[tuple[int, float], ...] = ((0, 10.0), (8, 45.0), (4, 180.0))

    def __post_init__(self):
        tiers = self.agent_tiers + self.edge_tiers
        if self.depth < 1 or any(n < 0 or deg <= 0 for n, deg in tiers):
            raise ValueError(f"BufferConfig: depth >= 1, tier counts >= 0 and windows > 0 deg, got {self}")


@struct.dataclass
class RayScene:
    """The objects the sensors see, world frame (one scenario, one instant).

    Attributes:
      agent_xy:     (K, 2) box centres, m.      agent_yaw: (K,) rad.
      agent_lw:     (K, 2) length, width, m.    agent_height: (K,) m.
      agent_vel:    (K, 2) world velocity, m/s.
      agent_code:   (K,) int32 hit code (``HIT_AGENT + category``).
      agent_row:    (K,) int32 row in the scenario's agent arrays.
      agent_valid:  (K,) bool.
      edge_a, edge_b: (E, 2) obstacle edge end points, m (E = O' * V).
      edge_height:  (E,) m.   edge_obstacle: (E,) int32 obstacle row.
      edge_orient:  (E,) float32 +1 / -1: the polygon winds counter-clockwise /
                    clockwise (only edges facing the sensor are hit, so a ray
                    enters an obstacle once and never sees its far side).
      edge_valid:   (E,) bool.
    """

    agent_xy: Array
    agent_yaw: Array
    agent_lw: Array
    agent_height: Array
    agent_vel: Array
    agent_code: Array
    agent_row: Array
    agent_valid: Array
    edge_a: Array
    edge_b: Array
    edge_height: Array
    edge_obstacle: Array
    edge_orient: Array
    edge_valid: Array

    @property
    def num_agents(self) -> int:
        return self.agent_xy.shape[-2]

    @property
    def num_edges(self) -> int:
        return self.edge_a.shape[-2]


def select_scene(
    ego_xy: Array,
    agents: AgentStates,
    size: Array,
    category: Array,
    obstacles: Polylines,
    obstacle_height: Array,
    cfg: SceneConfig = SceneConfig(),
    exclude: Array | int = -1,
) -> RayScene:
    """The nearest agents and obstacles around the ego.

    Args:
      ego_xy: (2,) m.  agents: AgentStates (A,) at this instant (xy, yaw, vel,
      valid).  size: (A, 3) length, width, height, m.  category: (A,) int32.
      obstacles: Polylines (O, V) footprints.  obstacle_height: (O,) m.
      cfg: SceneConfig.  exclude: () int32 agent row never returned (the ego's
      own logged row), -1 for none.
    """
    a = agents.xy.shape[0]
    k = min(cfg.num_agents, a)
    half_diag = 0.5 * geometry.safe_norm(size[:, :2])
    gap = geometry.safe_norm(agents.xy - ego_xy) - half_diag
    ok = agents.valid & (jnp.arange(a) != exclude) & (gap <= cfg.radius)
    _, idx = jax.lax.top_k(-jnp.where(ok, gap, jnp.inf), k)
    valid = ok[idx]

    o = obstacles.xy.shape[0]
    n_obs = min(cfg.num_obstacles, o)
    start, end, e_ok = jax.vmap(geometry.closed_edges)(obstacles.xy, obstacles.point_valid)  # (O, V, ...)
    seg_d = jax.vmap(jax.vmap(geometry.point_segment_distance, (None, 0, 0)), (None, 0, 0))(ego_xy, start, end)
    o_gap = jnp.min(jnp.where(e_ok, seg_d, jnp.inf), axis=1)
    o_ok = obstacles.valid & (o_gap <= cfg.radius)
    if n_obs > 0:
        _, oidx = jax.lax.top_k(-jnp.where(o_ok, o_gap, jnp.inf), n_obs)
    else:
        oidx = jnp.zeros((0,), jnp.int32)
    v = obstacles.xy.shape[1]
    area2 = jnp.sum(jnp.where(e_ok, geometry.cross2(start, end), 0.0), axis=1)  # twice the signed area
    edge_valid = (e_ok[oidx] & o_ok[oidx][:, None]).reshape(-1)
    return RayScene(
        agent_xy=agents.xy[idx],
        agent_yaw=agents.yaw[idx],
        agent_lw=size[idx, :2],
        agent_height=size[idx, 2],
        agent_vel=agents.vel[idx],
        agent_code=(HIT_AGENT + category[idx]).astype(jnp.int32),
        agent_row=jnp.where(valid, idx, -1).astype(jnp.int32),
        agent_valid=valid,
        edge_a=start[oidx].reshape(-1, 2),
        edge_b=end[oidx].reshape(-1, 2),
        edge_height=jnp.repeat(obstacle_height[oidx], v),
        edge_obstacle=jnp.repeat(oidx, v).astype(jnp.int32),
        edge_orient=jnp.repeat(jnp.where(area2[oidx] >= 0, 1.0, -1.0), v),
        edge_valid=edge_valid,
    )


@struct.dataclass
class PolarBuffer:
    """Per horizontal ray the D nearest faces, nearest first.

    Attributes:
      range:  (Z, D) float32 horizontal entry distance, m (+inf: none).
      top:    (Z, D) float32 height of the object's top, m (its bottom is 0).
      code:   (Z, D) int32 hit code (``HIT_STATIC`` / ``HIT_AGENT + c``;
              ``HIT_NONE`` when empty).
      agent:  (Z, D) int32 agent row, -1 for obstacles and empty slots.
      object: (Z, D) int32 scene object: agent slot k < K, or K + edge index
              (one wall face) for obstacles; -1 when empty.
    """

    range: Array
    top: Array
    code: Array
    agent: Array
    object: Array


def _angular_extent(rel: Array, heading: Array) -> tuple[Array, Array]:
    """(lo, span) in rad of points ``rel (P, 2)`` (relative to the sensor)
    seen from the sensor with heading ``heading``; lo in the sensor frame.
    Valid when the points lie within less than pi of their first point's
    direction (any convex object that does not contain the sensor)."""
    az = jnp.arctan2(rel[:, 1], rel[:, 0]) - heading
    d = geometry.wrap_angle(az - az[0])
    lo = az[0] + jnp.min(d)
    return geometry.wrap_angle(lo), jnp.max(d) - jnp.min(d)


def _first_ray(lo: Array, span: Array, azimuths: Array, full_circle: bool) -> tuple[Array, Array]:
    """(index of the first ray at or after ``lo``, number of rays in
    [lo, lo + span]). Rays: ascending ``azimuths (Z,)``, sensor frame."""
    z = azimuths.shape[0]
    if full_circle:
        rel = azimuths - azimuths[0]
        u = jnp.mod(lo - azimuths[0], 2 * jnp.pi)
        ext = jnp.concatenate([rel, rel + 2 * jnp.pi])
        start = jnp.searchsorted(ext, u, side="left")
        count = jnp.searchsorted(ext, u + span, side="right") - start
        return jnp.mod(start, z), count
    start = jnp.searchsorted(azimuths, lo, side="left")
    count = jnp.searchsorted(azimuths, lo + span, side="right") - start
    return start, count


def _segments(tiers, spacing: float, z: int, full_circle: bool, n: int) -> list[tuple[int, int, int]]:
    """Static disjoint window segments ``(rows, off_lo, off_hi)``: the ``rows``
    objects of largest ray count (``n`` = all, in their own order) are tested
    on ray offsets [off_lo, off_hi) from their first ray. Their union per
    object is the widest tier window its rank reaches, so every (object, ray)
    pair of the tiers is tested exactly once (no duplicate candidates)."""
    cap = z // 2 + 2 if full_circle else z
    width = {}
    for num, deg in tiers:
        w = int(min(cap, math.ceil(math.radians(deg) / spacing) + 1))
        rows = n if num == 0 else min(num, n)
        width[w] = max(width.get(w, 0), rows)
    out, lo = [], 0
    for w in sorted(width):
        rows = max(r for ww, r in width.items() if ww >= w)  # ranks whose window reaches w
        if rows > 0 and w > lo:
            out.append((rows, lo, w))
        lo = w
    return out


def pack_key(dist: Array, ident, id_bits: int, max_range: float) -> Array:
    """int32 keys ordering candidates by range: the float32 bits of ``dist``
    (m, >= 0) with the low ``id_bits`` replaced by ``ident`` (breaking ties);
    ``MISS`` where ``dist >= max_range``. Shared with ``observe.radar``."""
    ok = dist < max_range
    bits = jax.lax.bitcast_convert_type(jnp.where(ok, dist, 0.0).astype(jnp.float32), jnp.int32)
    key = ((bits >> id_bits) << id_bits) | ident
    return jnp.where(ok, key, MISS)


def _box_frames(scene: RayScene, origin: Array) -> tuple[Array, ...]:
    """Per agent box, computed once: (c, s) of its yaw, the sensor origin in the
    box frame (ox, oy) and the half length / width, each (K,). What
    ``geometry.ray_box_distance`` derives per call (one cos / sin per ray)."""
    c, s = jnp.cos(scene.agent_yaw), jnp.sin(scene.agent_yaw)
    p = origin - scene.agent_xy
    ox, oy = c * p[:, 0] + s * p[:, 1], -s * p[:, 0] + c * p[:, 1]
    return tuple(materialize(x) for x in (c, s, ox, oy, 0.5 * scene.agent_lw[:, 0], 0.5 * scene.agent_lw[:, 1]))


def _ray_box(frame: tuple[Array, ...], direction: Array) -> Array:
    """``geometry.ray_box_distance`` (same operations, same result) from a box
    frame of ``_box_frames`` (scalars) and a unit ``direction (2,)``."""
    c, s, ox, oy, hl, hw = frame
    dx, dy = c * direction[0] + s * direction[1], -s * direction[0] + c * direction[1]
    return geometry.slab_entry(ox, oy, dx, dy, hl, hw)


def _edge_frames(scene: RayScene, origin: Array) -> tuple[Array, ...]:
    """Per obstacle edge, computed once: e = b - a, w = a - origin (each (E, 2))
    and cross(w, e) (E,), the per-edge terms of ``geometry.ray_segment_distance``."""
    e = scene.edge_b - scene.edge_a
    w = scene.edge_a - origin
    return tuple(materialize(x) for x in (e, w, geometry.cross2(w, e)))


def _ray_segment(frame: tuple[Array, ...], direction: Array) -> Array:
    """``geometry.ray_segment_distance`` from an edge frame of ``_edge_frames``
    and a unit ``direction (2,)``."""
    return geometry.segment_entry(*frame, direction)


def polar_buffer(
    scene: RayScene,
    origin: Array,
    heading: Array,
    azimuths: Array,
    max_range: float,
    cfg: BufferConfig = BufferConfig(),
    full_circle: bool = True,
    spacing: float | None = None,
) -> PolarBuffer:
    """The D nearest faces along each horizontal ray of a fan.

    Args:
      scene: RayScene (K agents, E edges).  origin: (2,) sensor position, m.
      heading: () sensor heading, rad (world).  azimuths: (Z,) numpy (static,
      from the sensor config) ascending ray azimuths in the sensor frame, rad
      (counter-clockwise, 0 = forward).
      max_range: faces at or beyond this horizontal range (m) are dropped.
      cfg: BufferConfig.  full_circle: the fan wraps around (LiDAR); False for
      a fan narrower than pi (camera, radar).  spacing: static ray spacing
      (rad) that sizes the windows; required when ``azimuths`` is traced
      (e.g. several cameras under one vmap), else their mean spacing.
    """
    if spacing is None:
        azimuths = np.asarray(azimuths, np.float32)
        spacing = _spacing(azimuths, full_circle)
    z = azimuths.shape[0]
    k, e = scene.num_agents, scene.num_edges
    id_bits = max(1, (k + e - 1).bit_length())
    world_az = heading + azimuths
    dirs = jnp.stack([jnp.cos(world_az), jnp.sin(world_az)], axis=-1)  # (Z, 2)

    groups = []
    if k > 0:
        frame = _box_frames(scene, origin)
        valid = scene.agent_valid

        def agent_dist(i, rays_dir, frame=frame, valid=valid):
            d = jax.vmap(_ray_box, (None, 0))(tuple(f[i] for f in frame), rays_dir)
            return jnp.where(valid[i], d, jnp.inf)

        corners = jax.vmap(geometry.box_corners)(scene.agent_xy, scene.agent_yaw, scene.agent_lw[:, 0],
                                                 scene.agent_lw[:, 1])
        groups.append((0, corners, valid, cfg.agent_tiers, agent_dist))
    if e > 0:
        frame = _edge_frames(scene, origin)
        facing = geometry.cross2(frame[0], -frame[1]) * scene.edge_orient < 0
        valid = scene.edge_valid & facing

        def edge_dist(i, rays_dir, frame=frame, valid=valid):
            d = jax.vmap(_ray_segment, (None, 0))(tuple(f[i] for f in frame), rays_dir)
            return jnp.where(valid[i], d, jnp.inf)

        groups.append((k, jnp.stack([scene.edge_a, scene.edge_b], axis=1), scene.edge_valid, cfg.edge_tiers,
                       edge_dist))

    cand_ray, cand_dist, cand_id, lookup = [], [], [], []
    base = 0
    for id0, points, valid, tiers, dist_fn in groups:
        n = points.shape[0]
        lo, span = jax.vmap(_angular_extent, (0, None))(points - origin, heading)
        start, count = jax.vmap(_first_ray, (0, 0, None, None))(lo, span, azimuths, full_circle)
        count = jnp.where(valid, count, -1)
        segs = _segments(tiers, spacing, z, full_circle, n)
        ranked = any(rows < n for rows, _, _ in segs)
        order = jax.lax.top_k(count, n)[1] if ranked else jnp.arange(n)
        rank = jnp.zeros((n,), jnp.int32).at[order].set(jnp.arange(n, dtype=jnp.int32)) if ranked else jnp.arange(n)
        seg_info = []
        for rows_n, off_lo, off_hi in segs:
            rows = jnp.arange(n) if rows_n == n else order[:rows_n]
            ray = start[rows][:, None] + jnp.arange(off_lo, off_hi)
            ray = jnp.mod(ray, z) if full_circle else jnp.where(ray < z, ray, z)
            cand_ray.append(ray.reshape(-1))
            cand_dist.append(jax.vmap(dist_fn)(rows, dirs[jnp.minimum(ray, z - 1)]).reshape(-1))
            cand_id.append(jnp.broadcast_to((id0 + rows)[:, None], ray.shape).reshape(-1))
            seg_info.append((base, rows_n == n, off_lo, off_hi))
            base += rows_n * (off_hi - off_lo)
        lookup.append((id0, n, start, rank, seg_info))
    cand_ray = jnp.concatenate(cand_ray)
    cand_dist = jnp.concatenate(cand_dist)
    cand_key = pack_key(cand_dist, jnp.concatenate(cand_id).astype(jnp.int32), id_bits, max_range)
    m = cand_key.shape[0]

    def winner_index(layer):
        # (Z,) candidate index of each ray's winning key (m: none), from the
        # object id, its first ray and its rank: each (object, ray) pair is
        # one candidate.
        ident = layer & ((1 << id_bits) - 1)
        ray = jnp.arange(z)
        where = jnp.full((z,), m, jnp.int32)
        for id0, n, start, rank, seg_info in lookup:
            obj = jnp.clip(ident - id0, 0, n - 1)
            off = ray - start[obj]
            if full_circle:
                off = jnp.mod(off, z)
            pos = rank[obj]
            idx = jnp.zeros((z,), jnp.int32)
            for seg_base, all_rows, off_lo, off_hi in seg_info:
                row = obj if all_rows else pos
                idx = jnp.where(off >= off_lo, seg_base + row * (off_hi - off_lo) + (off - off_lo), idx)
            mine = (ident >= id0) & (ident < id0 + n) & (layer != MISS)
            where = jnp.where(mine, idx, where)
        return where

    layers, idxs = [], []
    ck = cand_key
    for d in range(cfg.depth):
        # Every candidate ray is in [0, z] (z: past a narrow fan, dropped).
        # The next round excludes this round's winners by their index (a
        # scatter of Z) instead of comparing every candidate with its ray's
        # key (a gather of all candidates).
        buf = jnp.full((z + 1,), MISS, jnp.int32).at[cand_ray].min(ck, mode="promise_in_bounds")
        layers.append(buf[:z])
        idxs.append(winner_index(buf[:z]))
        if d + 1 < cfg.depth:
            ck = jnp.concatenate([ck, jnp.full((1,), MISS, jnp.int32)])  # slot m: "no winner"
            ck = ck.at[idxs[-1]].set(MISS, mode="promise_in_bounds")[:m]
    keys = jnp.stack(layers, axis=-1)  # (Z, D)
    # The winners' exact ranges: gathered from their candidates, not
    # recomputed per (ray, layer).
    rng = cand_dist[jnp.clip(jnp.stack(idxs, axis=-1), 0, m - 1)]
    return _decode(scene, keys, rng, id_bits)


def _spacing(azimuths: np.ndarray, full_circle: bool) -> float:
    """Mean ray spacing of a fan, rad (static)."""
    z = azimuths.shape[0]
    if full_circle:
        return 2 * math.pi / z
    return float(azimuths[-1] - azimuths[0]) / max(z - 1, 1) if z > 1 else 1.0


def _decode(scene: RayScene, keys: Array, rng: Array, id_bits: int) -> PolarBuffer:
    """The buffer from the winners' packed keys (Z, D) and exact ranges (Z, D)."""
    k, e = scene.num_agents, scene.num_edges
    found = keys != MISS
    ident = keys & ((1 << id_bits) - 1)
    is_agent = found & (ident < k)
    ka = jnp.clip(ident, 0, max(k - 1, 0))
    ke = jnp.clip(ident - k, 0, max(e - 1, 0))
    if e > 0:
        top_seg, obj_seg = scene.edge_height[ke], k + ke
    else:
        top_seg, obj_seg = jnp.zeros(keys.shape), jnp.zeros(keys.shape, jnp.int32)
    out = PolarBuffer(
        range=jnp.where(found, rng, jnp.inf),
        top=jnp.where(is_agent, scene.agent_height[ka], top_seg),
        code=jnp.where(found, jnp.where(is_agent, scene.agent_code[ka], HIT_STATIC), HIT_NONE).astype(jnp.int32),
        agent=jnp.where(is_agent, scene.agent_row[ka], -1).astype(jnp.int32),
        object=jnp.where(found, jnp.where(is_agent, ka, obj_seg), -1).astype(jnp.int32),
    )
    # Materialise the buffer: consumers broadcast it over channels / rows and
    # XLA would otherwise recompute its gathers once per beam
    # (``optimization_barrier`` does not stop XLA:CPU's fusion; a reduction does).
    return jax.tree_util.tree_map(materialize, out)


def _layer_terms(buf: PolarBuffer) -> tuple[Array, Array]:
    """Per (layer, ray), computed once for all beams: the range with inf as 0
    and the face top with -inf where there is no face (a beam at height
    >= 0 is then never under it); each (D, Z)."""
    finite = jnp.isfinite(buf.range)
    return (materialize(jnp.where(finite, buf.range, 0.0).T),
            materialize(jnp.where(finite, buf.top, -jnp.inf).T))


def _layer_hit(rs: Array, top: Array, t, slant, mount_height: float, max_range: float) -> tuple[Array, Array]:
    """(3-D distance ``rs * slant``, whether beams of tangent ``t`` hit the
    face at horizontal range ``rs``: their height there is within [0, ``top``]
    and the distance within ``max_range``), from one layer of ``_layer_terms``."""
    h = mount_height + rs * t
    m = rs * slant
    return m, (h >= 0.0) & (h <= top) & (m <= max_range)


def beam_ranges(buf: PolarBuffer, tan_elev: np.ndarray, mount_height: float, max_range: float) -> Array:
    """(C, Z) float32 3-D range along each beam of its first return, m
    (``max_range`` where none): ``solve_elevation``'s range as ONE chain of
    selects, nearest layer last, with the ground return a per-channel
    constant. Measured 2.7x cheaper than ranges from ``solve_elevation`` when
    only the range image is read (no per-beam layer index, no second pass).

    Args:
      buf: PolarBuffer (Z, D).  tan_elev: (C, 1) numpy (static) tangents of the
      channel elevations.  mount_height, max_range: m.
    """
    t = np.asarray(tan_elev, np.float64)
    slant = np.sqrt(1.0 + t * t)
    down = t < 0
    r_ground = mount_height / np.where(down, -t, 1.0)
    ground = np.where(down & (r_ground * slant <= max_range), r_ground * slant, max_range)
    t32, slant32 = t.astype(np.float32), slant.astype(np.float32)
    rs, top = _layer_terms(buf)
    out = jnp.broadcast_to(jnp.asarray(ground, jnp.float32), (t.shape[0], buf.range.shape[0]))
    for d in reversed(range(buf.range.shape[1])):
        m, hit = _layer_hit(rs[d], top[d], t32, slant32, mount_height, max_range)
        out = jnp.where(hit, m, out)
    return out


@struct.dataclass
class BeamHits:
    """Result of the elevation solve for a grid of beams.

    Attributes:
      range:  (C, Z) float32 HORIZONTAL range of the return, m (+inf: none).
      code:   (C, Z) int32 hit code.
      agent:  (C, Z) int32 agent row, -1 otherwise.
      layer:  (C, Z) int32 buffer layer hit (0..D-1), D for the ground, -1 none.
    """

    range: Array
    code: Array
    agent: Array
    layer: Array


def solve_elevation(buf: PolarBuffer, tan_elev: Array, mount_height: float, max_range: float) -> BeamHits:
    """First return of beams that share the buffer's rays.

    Args:
      buf: PolarBuffer (Z, D).  tan_elev: (C, Z) or (C, 1) tangent of each
      beam's elevation (up positive).  mount_height: sensor height above the
      ground, m.  max_range: returns whose 3-D distance along the beam exceeds
      this (m) are dropped.
    """
    t = tan_elev
    depth = buf.range.shape[1]
    slant = jnp.sqrt(1.0 + t * t)  # 3-D distance per metre of horizontal range
    down = t < 0
    r_ground = mount_height / jnp.where(down, -t, 1.0)
    ground = down & (r_ground * slant <= max_range)
    shape = jnp.broadcast_shapes(t.shape, buf.range.shape[:1])
    layer = jnp.broadcast_to(jnp.where(ground, depth, -1), shape)
    rs, top = _layer_terms(buf)
    for d in reversed(range(depth)):
        _, hit = _layer_hit(rs[d], top[d], t, slant, mount_height, max_range)
        layer = jnp.where(hit, d, layer)
    # Materialise the choice once: otherwise XLA re-fuses the whole solve into
    # every consumer (range, class, agent, points), several times the cost.
    layer = materialize(layer.astype(jnp.int32))
    rng = jnp.where(layer == depth, r_ground, jnp.inf)
    code = jnp.where(layer == depth, HIT_GROUND, HIT_NONE)
    agent = jnp.full(shape, -1, jnp.int32)
    for d in range(depth):
        sel = layer == d
        rng = jnp.where(sel, buf.range[:, d], rng)
        code = jnp.where(sel, buf.code[:, d], code)
        agent = jnp.where(sel, buf.agent[:, d], agent)
    return BeamHits(range=rng, code=code.astype(jnp.int32), agent=agent, layer=layer)
