"""Records -> padded batches: the host-to-array boundary.

``pack`` turns ``ScenarioRecord``s (+ their ``MapRecord``s) into ONE
``types.Scenario`` whose leaves are numpy arrays with a leading batch axis
``B``, plus a host-side ``SuiteMeta`` table with one row per scenario. Convert
to JAX arrays when you need them (``batch.to_jax()``); packing itself never
touches a device.

Semantics (pinned by tests/scenario/test_pack.py):

* **Agents.** Row 0 is always the ego (``ego_index == 0``), the other tracks
  follow in increasing ``track_id``. Padding rows have ``track_id == -1`` and
  ``valid`` all False.
* **Time.** A sample at time ``t`` lands on step ``k = round(t / dt)``;
  ``valid[a, k]`` is True exactly where a sample exists. ``vel`` comes from
  the record, or, when the record has none, from ``np.gradient`` of the
  positions over the sample times (zero for a single sample). ``yaw`` is
  wrapped to (-pi, pi]. ``visible``/``quality`` default to True.
* **Route.** The record's waypoints are densified to 1.0 m arc-length spacing
  (as CARLA's route planner does; the last waypoint is kept exactly, so the
  last gap is <= 1 m). ``arc`` is the cumulative length of that polyline,
  ``length`` its last value; ``command`` comes from :func:`route_commands`.
  Padding repeats the last point and arc (so unmasked geometry stays sane),
  with ``command == VOID`` and ``valid == False``.
* **Map.** Polylines keep their points as a valid prefix; lane successors and
  stop-line lanes are converted from lane ids to lane rows (-1 = none/pad).
  ``drivable_edges`` is the boundary of the union of the drivable polygons
  (or of the lanes' areas when the map has none), ``scenario.drivable``.
* **Signals.** Row ``s`` of ``signals.state`` is the state array of stop line
  ``s``'s signal group (UNKNOWN when the group is -1 or absent from the
  record), extended to ``T`` with its last state.
* **Frame.** Every packed position (tracks, lanes, lane polygons, boundaries,
  crosswalks, stop lines, drivable areas and edges, obstacles, route) is in
  the scenario's LOCAL frame: the records are first moved by minus
  ``meta.origin[b]`` (``scenario.origin.map_origin`` of the map: its centre
  rounded to 1 km) in float64, and everything derived (lane polygons,
  drivable edges, the dense route, finite-difference velocities) is computed
  there before the cast to float32. Headings, velocities, sizes and arc
  lengths do not depend on the frame. World = local + ``meta.origin``
  (``unpack`` adds it back; ``meta.route_source`` / ``route_destination`` stay world).
* ``num_steps`` and ``dt_log`` come from the record; ``index`` is the row of
  the scenario in the suite's meta table (for a plain ``pack`` of a list: the
  position in that list).

Sizes are never data-dependent surprises: ``PackSizes.fit`` rounds the
maxima up, and a record that does not fit an explicit ``PackSizes`` is an
error naming the scenario and the field (never silently truncated).

The batch container is ``batch.PackedBatch`` / ``batch.SuiteMeta``, its sizes
``sizes.PackSizes`` / ``sizes.LEAVES``, the route steps ``routes``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import shapely

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.polyline import wrap_angle
from drivee2e_jax.records import (
    CATEGORIES,
    LANE_TYPES,
    MARKINGS,
    SIGNAL_STATES,
    MapRecord,
    RouteRecord,
    ScenarioRecord,
    TrackRecord,
)
from drivee2e_jax.scenario.batch import META_STR, PackedBatch, SuiteMeta, bucket
from drivee2e_jax.scenario.cache import PACK_FORMAT  # its home (no JAX): the cache key needs it
from drivee2e_jax.scenario.drivable import drivable_edges
from drivee2e_jax.scenario.flat import flatten_scenario, unflatten_scenario
from drivee2e_jax.scenario.lane_polygons import packed_lane_polygon
from drivee2e_jax.scenario.origin import ego_start, map_origin, translate_map, translate_scenario
from drivee2e_jax.scenario.routes import densify_route, junction_area, route_commands
from drivee2e_jax.scenario.sizes import PackSizes, alloc_leaves, map_of, record_needs

__all__ = ["PACK_FORMAT", "pack", "unpack", "pack_buckets", "track_order"]

# On-disk names -> enum values (by name, so a reordering of either side is caught).
_CATEGORY = {n: int(types.Category[n.upper()]) for n in CATEGORIES}
_CATEGORY_NAME = {v: k for k, v in _CATEGORY.items()}
_LANE_TYPE = {n: int(types.LaneType[n.upper()]) for n in LANE_TYPES}
_MARKING = {n: int(types.Marking[n.upper()]) for n in MARKINGS}
# record signal arrays hold indices into SIGNAL_STATES
_SIGNAL_LUT = np.array([int(types.SignalState[n.upper()]) for n in SIGNAL_STATES], np.int32)
_SIGNAL_INV = np.zeros(int(_SIGNAL_LUT.max()) + 1, np.int8)
_SIGNAL_INV[_SIGNAL_LUT] = np.arange(len(SIGNAL_STATES), dtype=np.int8)


# --------------------------------------------------------------------------
# pack
# --------------------------------------------------------------------------


def _pack_map(m: MapRecord, sizes: PackSizes) -> dict[str, np.ndarray]:
    """Unbatched map arrays (LEAVES names without B) + ``_stop_line_group``."""
    one = {k: v[0] for k, v in alloc_leaves(1, sizes).items() if k.startswith("map.")}

    def poly(prefix, rows):
        for i, p in enumerate(rows):
            p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
            one[f"{prefix}.xy"][i, : len(p)] = p
            one[f"{prefix}.point_valid"][i, : len(p)] = True
            one[f"{prefix}.valid"][i] = True

    lane_row = {ln.id: i for i, ln in enumerate(m.lanes)}
    poly("map.lanes", [ln.centerline for ln in m.lanes])
    poly("map.lane_polygons", [packed_lane_polygon(ln) for ln in m.lanes])
    for i, ln in enumerate(m.lanes):
        one["map.lane_type"][i] = _LANE_TYPE[ln.type]
        one["map.lane_width"][i] = ln.width
        one["map.lane_speed_limit"][i] = ln.speed_limit
        one["map.lane_left_marking"][i] = _MARKING[ln.left_marking]
        one["map.lane_right_marking"][i] = _MARKING[ln.right_marking]
        for j, sid in enumerate(ln.successors):
            if sid not in lane_row:
                raise DriveE2EError(f"map {m.map_id!r}: lanes[{i}].successors[{j}]: expected a lane id of this map, got {sid}")
            one["map.lane_successors"][i, j] = lane_row[sid]
    poly("map.boundaries", [b.points for b in m.boundaries])
    for i, b in enumerate(m.boundaries):
        one["map.boundary_marking"][i] = _MARKING[b.marking]
    poly("map.crosswalks", m.crosswalks)
    group = np.full(sizes.stop_lines, -1, np.int32)
    for i, sl in enumerate(m.stop_lines):
        one["map.stop_lines"][i] = np.asarray(sl.points, dtype=np.float64).reshape(2, 2)
        one["map.stop_line_valid"][i] = True
        if sl.lane_id != -1:
            if sl.lane_id not in lane_row:
                raise DriveE2EError(f"map {m.map_id!r}: stop_lines[{i}].lane_id: expected -1 or a lane id of this map, got {sl.lane_id}")
            one["map.stop_line_lane"][i] = lane_row[sl.lane_id]
        group[i] = sl.signal_group
    poly("map.drivable", m.drivable_areas)
    poly("map.obstacles", [o.polygon for o in m.obstacles])
    for i, o in enumerate(m.obstacles):
        one["map.obstacle_height"][i] = o.height
    edges, source = drivable_edges(m)
    one["map.drivable_edges"][: len(edges)] = edges
    one["map.drivable_edges_valid"][: len(edges)] = True
    one["map.drivable_source"] = np.int32(source)
    one["_stop_line_group"] = group
    return one


def _fd_velocity(xy: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``np.gradient(xy, t, axis=0)`` (second order inside, first order at the
    ends; zero for one sample), written out because it is 3x faster."""
    v = np.zeros_like(xy)
    if len(t) < 2:
        return v
    h = np.diff(t)[:, None]
    d = np.diff(xy, axis=0) / h  # segment velocities
    v[0], v[-1] = d[0], d[-1]
    if len(t) > 2:
        h1, h2 = h[:-1], h[1:]
        v[1:-1] = (h2 * d[:-1] + h1 * d[1:]) / (h1 + h2)
    return v


def track_order(s: ScenarioRecord) -> list[TrackRecord]:
    ego = [t for t in s.tracks if t.track_id == s.ego_track_id]
    if not ego:
        raise DriveE2EError(f"scenario {s.scenario_id!r}: ego_track_id: expected one of the track ids, got {s.ego_track_id}")
    return ego[:1] + sorted((t for t in s.tracks if t.track_id != s.ego_track_id), key=lambda t: t.track_id)


def _fill_tracks(out: dict, b: int, s: ScenarioRecord) -> None:
    dt = float(s.dt)
    for a, tr in enumerate(track_order(s)):
        t = np.asarray(tr.t, dtype=np.float64)
        k = np.rint(t / dt).astype(np.int64)
        where = f"scenario {s.scenario_id!r}: track {tr.track_id}"
        if len(k) == 0:
            raise DriveE2EError(f"{where}: t: expected at least one sample")
        if k[0] < 0 or k[-1] >= s.num_steps or (len(k) > 1 and np.any(np.diff(k) <= 0)):
            raise DriveE2EError(f"{where}: t: expected increasing times on the dt grid within num_steps={s.num_steps}")
        xy = np.asarray(tr.xy, dtype=np.float64).reshape(-1, 2)
        if tr.vel is not None:
            vel = np.asarray(tr.vel, dtype=np.float64).reshape(-1, 2)
        else:
            vel = _fd_velocity(xy, t)
        out["tracks.xy"][b, a, k] = xy
        out["tracks.yaw"][b, a, k] = wrap_angle(tr.yaw)
        out["tracks.vel"][b, a, k] = vel
        out["tracks.valid"][b, a, k] = True
        out["tracks.visible"][b, a, k] = True if tr.visible is None else np.asarray(tr.visible, bool)
        out["tracks.quality"][b, a, k] = True if tr.quality is None else np.asarray(tr.quality, bool)
        out["tracks.size"][b, a] = np.asarray(tr.size, dtype=np.float64)
        out["tracks.category"][b, a] = _CATEGORY[tr.category]
        out["tracks.track_id"][b, a] = tr.track_id


def _fill_signals(out: dict, b: int, s: ScenarioRecord, groups: np.ndarray) -> None:
    n = int(s.num_steps)
    for i, g in enumerate(groups):
        states = s.signals.get(int(g)) if g >= 0 else None
        if states is None:
            continue
        states = np.asarray(states)
        if len(states) != n:
            raise DriveE2EError(f"scenario {s.scenario_id!r}: signals[{int(g)}]: expected {n} states (num_steps), got {len(states)}")
        row = _SIGNAL_LUT[states.astype(np.int64)]
        out["signals.state"][b, i, :n] = row
        out["signals.state"][b, i, n:] = row[-1]


def _fill_route(out: dict, b: int, xy: np.ndarray, arc: np.ndarray, cmd: np.ndarray) -> None:
    n = len(xy)
    out["route.xy"][b, :n] = xy
    out["route.xy"][b, n:] = xy[-1]
    out["route.arc"][b, :n] = arc
    out["route.arc"][b, n:] = arc[-1]
    out["route.command"][b, :n] = cmd
    out["route.valid"][b, :n] = True
    out["route.length"][b] = arc[-1]


def _check_fits(needs: dict[str, tuple[int, str]], sizes: PackSizes) -> None:
    for k, (n, where) in needs.items():
        if n > getattr(sizes, k):
            raise DriveE2EError(f"{where}: needs {k}={n}, more than PackSizes.{k}={getattr(sizes, k)} "
                                "(records are never truncated; pass larger sizes)")


def pack(scenarios: Sequence[ScenarioRecord], maps: dict[str, MapRecord], sizes: PackSizes | None = None,
         *, index: Sequence[int] | None = None) -> PackedBatch:
    """Pack ``scenarios`` into one padded batch (see the module docstring).

    Args:
      scenarios: the records, in batch order.
      maps: map_id -> MapRecord (every scenario's map must be there).
      sizes: padded sizes; default ``PackSizes.fit(scenarios, maps)``. A record
        that does not fit raises DriveE2EError naming the scenario and field.
      index: ``Scenario.index`` / ``meta.index`` per scenario (default 0..B-1).
    """
    scenarios = list(scenarios)
    if not scenarios:
        raise DriveE2EError("nothing to pack: expected at least one scenario")
    for s in scenarios:
        map_of(maps, s.map_id, s)
    # The local frames: records moved by minus their map's origin (float64) before anything is derived.
    world = scenarios
    origins = np.array([map_origin(maps[s.map_id], ego_start(s)) for s in world], np.float64).reshape(-1, 2)
    local_maps: dict[str, MapRecord] = {}
    for s, o in zip(world, origins):  # one origin per map (a map without geometry moves as a no-op)
        if s.map_id not in local_maps:
            local_maps[s.map_id] = translate_map(maps[s.map_id], -o)
    maps = local_maps
    scenarios = [translate_scenario(s, -o) for s, o in zip(world, origins)]
    routes = [densify_route(s.route.waypoints) for s in scenarios]
    needs = record_needs(scenarios, maps, [r[0] for r in routes])
    if sizes is None:
        sizes = PackSizes.rounded({k: n for k, (n, _) in needs.items()})
    else:
        _check_fits(needs, sizes)
    b_total = len(scenarios)
    out = alloc_leaves(b_total, sizes)
    map_arrays, junctions = {}, {}
    for mid in dict.fromkeys(s.map_id for s in scenarios):
        map_arrays[mid] = _pack_map(maps[mid], sizes)
        junctions[mid] = junction_area(maps[mid])
    map_ids = np.array([s.map_id for s in scenarios])
    for mid, arrays in map_arrays.items():
        rows = np.flatnonzero(map_ids == mid)
        for k, v in arrays.items():
            if not k.startswith("_"):
                out[k][rows] = v

    for b, (s, (rxy, rarc)) in enumerate(zip(scenarios, routes)):
        _fill_tracks(out, b, s)
        _fill_signals(out, b, s, map_arrays[s.map_id]["_stop_line_group"])
        area = junctions[s.map_id]
        inside = None if area is None else shapely.contains_xy(area, rxy[:, 0], rxy[:, 1])
        _fill_route(out, b, rxy, rarc, route_commands(rxy, inside))
        out["dt_log"][b] = s.dt
        out["num_steps"][b] = s.num_steps
    idx = np.arange(b_total) if index is None else np.asarray(index, dtype=np.int64)
    if idx.shape != (b_total,):
        raise ValueError(f"index: expected {b_total} entries, got shape {idx.shape}")
    out["index"][:] = idx
    out["ego_index"][:] = 0
    meta = SuiteMeta(
        **{k: np.array([getattr(s, k) for s in scenarios], dtype=str) for k in META_STR},
        ego_track_id=np.array([s.ego_track_id for s in scenarios], np.int64),
        index=idx.astype(np.int64),
        num_agents=np.array([len(s.tracks) for s in scenarios], np.int32),
        num_steps=np.array([s.num_steps for s in scenarios], np.int32),
        dt=np.array([s.dt for s in scenarios], np.float64),
        route_source=np.array([np.asarray(s.route.source, np.float64).reshape(2) for s in world]),
        route_destination=np.array([np.asarray(s.route.destination, np.float64).reshape(2) for s in world]),
        stop_line_group=np.stack([map_arrays[s.map_id]["_stop_line_group"] for s in scenarios]),
        origin=origins,
    )
    return PackedBatch(unflatten_scenario(out).validate(), meta)


# --------------------------------------------------------------------------
# unpack
# --------------------------------------------------------------------------


def unpack(batch: PackedBatch) -> list[ScenarioRecord]:
    """Records back from a packed batch.

    Reproduces every track sample (times ``k * dt``, world positions: the
    packed local ones plus ``meta.origin``, yaw wrapped to (-pi, pi],
    velocity, flags; float32 precision of the local positions), ids, sizes, categories,
    metadata and map ids. Differences from the packed records, by design:
    tracks come back ego first then by id; ``vel`` is always present (finite
    differences where the record had none); route waypoints are the dense 1 m
    points; signals come back for the groups the map's stop lines reference
    (a referenced group absent from the record returns as all UNKNOWN).
    """
    f = {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}
    meta = batch.meta
    out = []
    for b in range(len(meta)):
        n, dt = int(f["num_steps"][b]), float(meta.dt[b])
        tracks = []
        for a in np.flatnonzero(f["tracks.valid"][b].any(axis=-1)):
            k = np.flatnonzero(f["tracks.valid"][b, a])
            tracks.append(TrackRecord(
                track_id=int(f["tracks.track_id"][b, a]),
                category=_CATEGORY_NAME[int(f["tracks.category"][b, a])],
                size=f["tracks.size"][b, a].astype(np.float64),
                t=k * dt,
                xy=f["tracks.xy"][b, a, k].astype(np.float64) + meta.origin[b],
                yaw=f["tracks.yaw"][b, a, k].astype(np.float64),
                vel=f["tracks.vel"][b, a, k].astype(np.float64),
                visible=f["tracks.visible"][b, a, k].copy(),
                quality=f["tracks.quality"][b, a, k].copy(),
            ))
        signals = {}
        for i, g in enumerate(meta.stop_line_group[b]):
            if g >= 0 and f["map.stop_line_valid"][b, i] and int(g) not in signals:
                signals[int(g)] = _SIGNAL_INV[f["signals.state"][b, i, :n]]
        rvalid = f["route.valid"][b]
        route = RouteRecord(waypoints=f["route.xy"][b][rvalid].astype(np.float64) + meta.origin[b],
                            source=meta.route_source[b].copy(), destination=meta.route_destination[b].copy())
        out.append(ScenarioRecord(
            scenario_id=str(meta.scenario_id[b]), split=str(meta.split[b]),
            intersection_id=str(meta.intersection_id[b]), map_id=str(meta.map_id[b]),
            behavior=str(meta.behavior[b]), weather=str(meta.weather[b]),
            time_of_day=str(meta.time_of_day[b]), ego_track_id=int(meta.ego_track_id[b]),
            route=route, dt=dt, num_steps=n, tracks=tracks, signals=signals,
        ))
    return out


def pack_buckets(scenarios: Sequence[ScenarioRecord], maps: dict[str, MapRecord], num_buckets: int = 4,
                 *, index: Sequence[int] | None = None) -> list[PackedBatch]:
    """``pack`` then ``bucket``: a few batches with little padding waste."""
    return bucket(pack(scenarios, maps, index=index), num_buckets)
