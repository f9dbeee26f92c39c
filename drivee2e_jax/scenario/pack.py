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
* **Signals.** Row ``s`` of ``signals.state`` is the state array of stop line
  ``s``'s signal group (UNKNOWN when the group is -1 or absent from the
  record), extended to ``T`` with its last state.
* ``num_steps`` and ``dt_log`` come from the record; ``index`` is the row of
  the scenario in the suite's meta table (for a plain ``pack`` of a list: the
  position in that list).

Sizes are never data-dependent surprises: ``PackSizes.fit`` rounds the
maxima up, and a record that does not fit an explicit ``PackSizes`` is an
error naming the scenario and the field (never silently truncated).
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import numpy as np

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
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

__all__ = [
    "PACK_FORMAT",
    "PackSizes",
    "SuiteMeta",
    "PackedBatch",
    "pack",
    "unpack",
    "resize",
    "fit_sizes",
    "bucket",
    "pack_buckets",
    "padding_efficiency",
    "densify_route",
    "route_commands",
    "flatten_dataclass",
    "unflatten_dataclass",
    "flatten_scenario",
    "unflatten_scenario",
]

#: Version of the packed-array semantics; bump it when they change so that
#: on-disk packed caches are rebuilt.
PACK_FORMAT = 2  # 2: obstacle footprints have their own vertex count

#: Route densification step, m.
ROUTE_SPACING_M = 1.0

# On-disk names -> enum values (by name, so a reordering of either side is caught).
_CATEGORY = {n: int(types.Category[n.upper()]) for n in CATEGORIES}
_CATEGORY_NAME = {v: k for k, v in _CATEGORY.items()}
_LANE_TYPE = {n: int(types.LaneType[n.upper()]) for n in LANE_TYPES}
_MARKING = {n: int(types.Marking[n.upper()]) for n in MARKINGS}
# record signal arrays hold indices into SIGNAL_STATES
_SIGNAL_LUT = np.array([int(types.SignalState[n.upper()]) for n in SIGNAL_STATES], np.int32)
_SIGNAL_INV = np.zeros(int(_SIGNAL_LUT.max()) + 1, np.int8)
_SIGNAL_INV[_SIGNAL_LUT] = np.arange(len(SIGNAL_STATES), dtype=np.int8)
_UNKNOWN = int(types.SignalState.UNKNOWN)
_VOID = int(types.Command.VOID)


# --------------------------------------------------------------------------
# Sizes
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class PackSizes:
    """Padded maxima of a batch (the symbols of ``drivee2e_jax.types``).

    Attributes:
      agents (A), steps (T), lanes (L), points (N: lane centreline and
      boundary points), boundaries (E), crosswalks (C), vertices (V: crosswalk
      and drivable polygon vertices), stop_lines (S), drivable (G), obstacles
      (O), obstacle_vertices (V_O: static obstacle footprint vertices, sized
      apart because the simulator tests every obstacle against the ego each
      step and footprints are small), route (R: 1 m route points),
      successors (K).
    """

    agents: int
    steps: int
    lanes: int
    points: int
    boundaries: int
    crosswalks: int
    vertices: int
    stop_lines: int
    drivable: int
    obstacles: int
    route: int
    successors: int
    obstacle_vertices: int = 4

    #: ``fit`` rounds each maximum up to a multiple of this.
    MULTIPLE: typing.ClassVar[dict[str, int]] = dict(
        agents=8, steps=8, lanes=8, points=4, boundaries=8, crosswalks=4, vertices=4,
        stop_lines=4, drivable=4, obstacles=4, route=16, successors=4, obstacle_vertices=4,
    )

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise DriveE2EError(f"PackSizes.{f.name}: expected an integer >= 1, got {v!r}")
            object.__setattr__(self, f.name, int(v))

    @classmethod
    def rounded(cls, needs: dict[str, int]) -> PackSizes:
        """Sizes holding ``needs`` (name -> count), rounded up per ``MULTIPLE``."""
        return cls(**{k: m * max(1, math.ceil(needs.get(k, 0) / m)) for k, m in cls.MULTIPLE.items()})

    @classmethod
    def fit(cls, scenarios: Sequence[ScenarioRecord], maps: dict[str, MapRecord]) -> PackSizes:
        """The maxima over ``scenarios`` (and their maps), rounded up."""
        needs = _needs(scenarios, maps, [densify_route(s.route.waypoints)[0] for s in scenarios])
        return cls.rounded({k: n for k, (n, _) in needs.items()})

    @classmethod
    def of(cls, scenario: types.Scenario) -> PackSizes:
        """The padded sizes of a packed (batched) Scenario, read off its shapes."""
        m = scenario.map
        return cls(
            agents=scenario.tracks.xy.shape[-3], steps=scenario.tracks.xy.shape[-2],
            lanes=m.lanes.xy.shape[-3], points=m.lanes.xy.shape[-2],
            boundaries=m.boundaries.xy.shape[-3], crosswalks=m.crosswalks.xy.shape[-3],
            vertices=m.crosswalks.xy.shape[-2], stop_lines=m.stop_lines.shape[-3],
            drivable=m.drivable.xy.shape[-3], obstacles=m.obstacles.xy.shape[-3],
            route=scenario.route.xy.shape[-2], successors=m.lane_successors.shape[-1],
            obstacle_vertices=m.obstacles.xy.shape[-2],
        )

    def replace(self, **changes: int) -> PackSizes:
        return dataclasses.replace(self, **changes)

    def as_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


# --------------------------------------------------------------------------
# The leaf table: axes, dtype and pad value of every packed array
# --------------------------------------------------------------------------

_F, _I, _B = np.float32, np.int32, np.bool_


def _poly(prefix: str, rows: str, pts: str) -> dict:
    return {
        f"{prefix}.xy": ((rows, pts, 2), _F, 0),
        f"{prefix}.point_valid": ((rows, pts), _B, False),
        f"{prefix}.valid": ((rows,), _B, False),
    }


#: flat leaf name -> (axes after B: a PackSizes field name or a fixed length,
#: dtype, pad value). Pad "edge" repeats the last entry; "signal" is UNKNOWN
#: along S and repeats the last state along T.
LEAVES: dict[str, tuple[tuple, Any, Any]] = {
    "tracks.xy": (("agents", "steps", 2), _F, 0),
    "tracks.yaw": (("agents", "steps"), _F, 0),
    "tracks.vel": (("agents", "steps", 2), _F, 0),
    "tracks.size": (("agents", 3), _F, 0),
    "tracks.category": (("agents",), _I, 0),
    "tracks.valid": (("agents", "steps"), _B, False),
    "tracks.visible": (("agents", "steps"), _B, False),
    "tracks.quality": (("agents", "steps"), _B, False),
    "tracks.track_id": (("agents",), _I, -1),
    **_poly("map.lanes", "lanes", "points"),
    "map.lane_type": (("lanes",), _I, 0),
    "map.lane_width": (("lanes",), _F, 0),
    "map.lane_speed_limit": (("lanes",), _F, 0),
    "map.lane_successors": (("lanes", "successors"), _I, -1),
    "map.lane_left_marking": (("lanes",), _I, 0),
    "map.lane_right_marking": (("lanes",), _I, 0),
    **_poly("map.boundaries", "boundaries", "points"),
    "map.boundary_marking": (("boundaries",), _I, 0),
    **_poly("map.crosswalks", "crosswalks", "vertices"),
    "map.stop_lines": (("stop_lines", 2, 2), _F, 0),
    "map.stop_line_lane": (("stop_lines",), _I, -1),
    "map.stop_line_valid": (("stop_lines",), _B, False),
    **_poly("map.drivable", "drivable", "vertices"),
    **_poly("map.obstacles", "obstacles", "obstacle_vertices"),
    "map.obstacle_height": (("obstacles",), _F, 0),
    "signals.state": (("stop_lines", "steps"), _I, "signal"),
    "route.xy": (("route", 2), _F, "edge"),
    "route.arc": (("route",), _F, "edge"),
    "route.command": (("route",), _I, _VOID),
    "route.valid": (("route",), _B, False),
    "route.length": ((), _F, 0),
    "ego_index": ((), _I, 0),
    "dt_log": ((), _F, 0),
    "num_steps": ((), _I, 0),
    "index": ((), _I, 0),
}


def _alloc(b: int, sizes: PackSizes) -> dict[str, np.ndarray]:
    out = {}
    for name, (axes, dtype, pad) in LEAVES.items():
        shape = (b, *(getattr(sizes, a) if isinstance(a, str) else a for a in axes))
        fill = _UNKNOWN if pad == "signal" else (0 if pad == "edge" else pad)
        out[name] = np.full(shape, fill, dtype=dtype)
    return out


def flatten_dataclass(obj) -> dict[str, Any]:
    """{"a.b": leaf, ...}: every leaf of a nest of dataclasses, by dotted path."""
    out = {}

    def walk(o, prefix):
        for f in dataclasses.fields(o):
            v = getattr(o, f.name)
            if dataclasses.is_dataclass(v):
                walk(v, f"{prefix}{f.name}.")
            else:
                out[f"{prefix}{f.name}"] = v

    walk(obj, "")
    return out


def unflatten_dataclass(cls, flat: dict[str, Any], *, optional: bool = False):
    """Inverse of :func:`flatten_dataclass` for the dataclass ``cls`` (nested
    dataclass fields by their type hints). ``optional``: a missing leaf is
    None instead of a KeyError."""

    def build(klass, prefix):
        kwargs = {}
        for name, hint in typing.get_type_hints(klass).items():
            if dataclasses.is_dataclass(hint):
                kwargs[name] = build(hint, f"{prefix}{name}.")
            else:
                key = f"{prefix}{name}"
                kwargs[name] = flat.get(key) if optional else flat[key]
        return klass(**kwargs)

    return build(cls, "")


def flatten_scenario(scenario: types.Scenario) -> dict[str, Any]:
    """{"tracks.xy": leaf, ...} for every leaf (the names of ``LEAVES``)."""
    return flatten_dataclass(scenario)


def unflatten_scenario(flat: dict[str, Any]) -> types.Scenario:
    """Inverse of :func:`flatten_scenario`."""
    return unflatten_dataclass(types.Scenario, flat)


# --------------------------------------------------------------------------
# Host meta table
# --------------------------------------------------------------------------

_META_STR = ("scenario_id", "split", "intersection_id", "map_id", "behavior", "weather", "time_of_day")
_META_NUM = {"ego_track_id": np.int64, "index": np.int64, "num_agents": np.int32,
             "num_steps": np.int32, "dt": np.float64}
_META_2D = {"route_source": np.float64, "route_destination": np.float64, "stop_line_group": np.int32}


@dataclass(frozen=True)
class SuiteMeta:
    """Host-side columnar table, one row per packed scenario (row i <-> batch row i).

    1-D columns (length B): ``scenario_id, split, intersection_id, map_id,
    behavior, weather, time_of_day`` (numpy str), ``ego_track_id`` and
    ``index`` (int64; ``index`` equals ``Scenario.index``: the row in the
    suite's meta table), ``num_agents``, ``num_steps`` (int32), ``dt``
    (float64, the record's exact log step).

    2-D columns kept so that :func:`unpack` can rebuild the records:
    ``route_source``, ``route_destination`` (B, 2) float64 and
    ``stop_line_group`` (B, S) int32 (signal group of each stop line, -1 none).
    """

    scenario_id: np.ndarray
    split: np.ndarray
    intersection_id: np.ndarray
    map_id: np.ndarray
    behavior: np.ndarray
    weather: np.ndarray
    time_of_day: np.ndarray
    ego_track_id: np.ndarray
    index: np.ndarray
    num_agents: np.ndarray
    num_steps: np.ndarray
    dt: np.ndarray
    route_source: np.ndarray
    route_destination: np.ndarray
    stop_line_group: np.ndarray

    def __len__(self) -> int:
        return len(self.scenario_id)

    def columns(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def select(self, rows: Sequence[int] | np.ndarray) -> SuiteMeta:
        rows = np.asarray(rows)
        return SuiteMeta(**{k: v[rows] for k, v in self.columns().items()})

    take = select  # numpy-style alias

    def rows(self) -> list[dict[str, Any]]:
        """One plain dict per row with the 1-D columns (Python scalars)."""
        cols = {k: getattr(self, k).tolist() for k in (*_META_STR, *_META_NUM)}
        return [dict(zip(cols, vals)) for vals in zip(*cols.values())]

    to_dicts = rows

    def count(self, column: str) -> dict[str, int]:
        """value -> number of rows, in order of first appearance."""
        values, first, counts = np.unique(getattr(self, column), return_index=True, return_counts=True)
        order = np.argsort(first)
        return {str(values[i]): int(counts[i]) for i in order}

    def to_json(self) -> dict[str, list]:
        return {k: v.tolist() for k, v in self.columns().items()}

    @classmethod
    def from_json(cls, data: dict[str, list]) -> SuiteMeta:
        cols = {k: np.asarray(data[k], dtype=str) for k in _META_STR}
        cols.update({k: np.asarray(data[k], dtype=t) for k, t in {**_META_NUM, **_META_2D}.items()})
        n = len(cols["scenario_id"])
        for k, v in cols.items():
            if len(v) != n:
                raise ValueError(f"SuiteMeta.{k}: {len(v)} rows, expected {n}")
        for k in ("route_source", "route_destination"):
            cols[k] = cols[k].reshape(n, 2)
        cols["stop_line_group"] = cols["stop_line_group"].reshape(n, -1)
        return cls(**cols)


# --------------------------------------------------------------------------
# Packed batch
# --------------------------------------------------------------------------


@dataclass(frozen=True)
class PackedBatch:
    """A padded batch: ``scenario`` (types.Scenario, numpy leaves with leading
    axis B) and its host ``meta`` table (row i describes batch row i)."""

    scenario: types.Scenario
    meta: SuiteMeta

    def __len__(self) -> int:
        return len(self.meta)

    @property
    def sizes(self) -> PackSizes:
        return PackSizes.of(self.scenario)

    @property
    def padding_efficiency(self) -> float:
        return padding_efficiency(self)

    def select(self, rows: Sequence[int] | np.ndarray) -> PackedBatch:
        """The rows ``rows`` (a new batch, same padded sizes)."""
        rows = np.asarray(rows, dtype=np.int64)
        flat = {k: np.asarray(v)[rows] for k, v in flatten_scenario(self.scenario).items()}
        return PackedBatch(unflatten_scenario(flat).validate(), self.meta.select(rows))

    def resize(self, sizes: PackSizes) -> PackedBatch:
        return resize(self, sizes)

    def fit(self) -> PackedBatch:
        """This batch with the tightest (rounded) sizes that hold its rows."""
        return resize(self, fit_sizes(self))

    def to_jax(self) -> types.Scenario:
        """The scenario pytree as JAX arrays on the default device."""

        return jax.device_put(self.scenario)

    def __repr__(self) -> str:
        s = self.sizes
        return (f"PackedBatch(B={len(self)}, A={s.agents}, T={s.steps}, L={s.lanes}, R={s.route}, "
                f"padding_efficiency={self.padding_efficiency:.2f})")


def padding_efficiency(batches: PackedBatch | Iterable[PackedBatch]) -> float:
    """Valid agent-steps / padded agent-steps over one batch or several."""
    if isinstance(batches, PackedBatch):
        batches = [batches]
    valid = padded = 0
    for b in batches:
        v = np.asarray(b.scenario.tracks.valid)
        valid += int(v.sum())
        padded += v.size
    return valid / padded if padded else 0.0


# --------------------------------------------------------------------------
# Route densification and commands
# --------------------------------------------------------------------------


def densify_route(waypoints: np.ndarray, spacing: float = ROUTE_SPACING_M) -> tuple[np.ndarray, np.ndarray]:
    """Resample a polyline every ``spacing`` m of arc length, keeping the last
    point exactly; returns (xy (n, 2) float64, arc (n,) cumulative length of
    the resampled polyline). Repeated waypoints are dropped first."""
    w = np.asarray(waypoints, dtype=np.float64).reshape(-1, 2)
    if len(w) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    seg = np.linalg.norm(np.diff(w, axis=0), axis=1)
    w = w[np.r_[seg > 1e-9, True]]  # of a run of repeats keep the last (the exact end)
    if len(w) == 1:
        return w.copy(), np.zeros(1)
    s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(w, axis=0), axis=1))]
    q = np.arange(0.0, s[-1], spacing)
    if s[-1] - q[-1] < 1e-6:
        q = q[:-1]
    q = np.r_[q, s[-1]]
    xy = np.stack([np.interp(q, s, w[:, 0]), np.interp(q, s, w[:, 1])], axis=1)
    xy[-1] = w[-1]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    return xy, arc


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def route_commands(xy: np.ndarray, in_junction: np.ndarray | None = None, *,
                   turn_deg: float = 30.0, window_m: float = 5.0, curve_deg: float = 15.0) -> np.ndarray:
    """CARLA-style high-level command per route point (int32 ``Command``).

    A *turn region* is a run of points either inside the junction
    (``in_junction``, e.g. near connector lanes; gaps of <= 3 points are
    closed) or, when no junction is known, where the heading changes by more
    than ``curve_deg`` over +-``window_m`` of arc. Over each region the total
    heading change (entering segment to leaving segment) decides: > +turn_deg
    LEFT, < -turn_deg RIGHT, otherwise STRAIGHT inside a junction and
    LANEFOLLOW on a plain curve. Every other point is LANEFOLLOW.
    """
    xy = np.asarray(xy, dtype=np.float64)
    n = len(xy)
    cmd = np.full(n, int(types.Command.LANEFOLLOW), np.int32)
    if n < 2:
        return cmd
    d = np.diff(xy, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    hp = np.r_[heading, heading[-1]]  # heading leaving each point
    junction = in_junction is not None and bool(np.any(in_junction))
    if junction:
        mask = np.asarray(in_junction, bool).copy()
        for i0, i1 in _runs(~mask):
            if i0 > 0 and i1 < n and i1 - i0 <= 3:
                mask[i0:i1] = True
    else:
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(d, axis=1))]
        change = np.interp(arc + window_m, arc, hp) - np.interp(arc - window_m, arc, hp)
        mask = np.abs(change) > np.radians(curve_deg)
    turn = np.radians(turn_deg)
    for i0, i1 in _runs(mask):
        dh = hp[min(i1, n - 1)] - hp[max(i0 - 1, 0)]
        if dh > turn:
            cmd[i0:i1] = int(types.Command.LEFT)
        elif dh < -turn:
            cmd[i0:i1] = int(types.Command.RIGHT)
        elif junction:
            cmd[i0:i1] = int(types.Command.STRAIGHT)
    return cmd


def _junction_area(m: MapRecord):
    """Shapely area covered by the map's connector lanes (None without any)."""
    import shapely

    parts = [shapely.LineString(np.asarray(ln.centerline)).buffer(ln.width / 2.0)
             for ln in m.lanes if ln.type == "connector" and len(ln.centerline) >= 2]
    if not parts:
        return None
    area = shapely.union_all(parts)
    shapely.prepare(area)
    return area


# --------------------------------------------------------------------------
# Needs (what each record requires of PackSizes)
# --------------------------------------------------------------------------


def _map_needs(m: MapRecord) -> dict[str, tuple[int, str]]:
    def most(items, key, what):
        best = (0, "")
        for i, it in enumerate(items):
            n = key(it)
            if n > best[0]:
                best = (n, what(i))
        return best

    where = f"map {m.map_id!r}"
    pts = max(
        most(m.lanes, lambda ln: len(ln.centerline), lambda i: f"{where} lanes[{i}].centerline"),
        most(m.boundaries, lambda b: len(b.points), lambda i: f"{where} boundaries[{i}].points"),
    )
    verts = max(
        most(m.crosswalks, len, lambda i: f"{where} crosswalks[{i}]"),
        most(m.drivable_areas, len, lambda i: f"{where} drivable_areas[{i}]"),
    )
    obstacle_verts = most(m.obstacles, lambda o: len(o.polygon), lambda i: f"{where} obstacles[{i}].polygon")
    return {
        "lanes": (len(m.lanes), f"{where} lanes"),
        "points": pts,
        "boundaries": (len(m.boundaries), f"{where} boundaries"),
        "crosswalks": (len(m.crosswalks), f"{where} crosswalks"),
        "vertices": verts,
        "stop_lines": (len(m.stop_lines), f"{where} stop_lines"),
        "drivable": (len(m.drivable_areas), f"{where} drivable_areas"),
        "obstacles": (len(m.obstacles), f"{where} obstacles"),
        "obstacle_vertices": obstacle_verts,
        "successors": most(m.lanes, lambda ln: len(ln.successors), lambda i: f"{where} lanes[{i}].successors"),
    }


def _needs(scenarios: Sequence[ScenarioRecord], maps: dict[str, MapRecord],
           routes: Sequence[np.ndarray]) -> dict[str, tuple[int, str]]:
    """Per size name: (max count, 'which record needs it')."""
    best: dict[str, tuple[int, str]] = {k: (0, "") for k in PackSizes.MULTIPLE}
    for mid in dict.fromkeys(s.map_id for s in scenarios):
        for k, v in _map_needs(_get_map(maps, mid, None)).items():
            if v[0] > best[k][0]:
                best[k] = v
    for s, r in zip(scenarios, routes):
        where = f"scenario {s.scenario_id!r}"
        for k, v in (("agents", (len(s.tracks), f"{where} tracks")),
                     ("steps", (int(s.num_steps), f"{where} num_steps")),
                     ("route", (len(r), f"{where} route at 1 m spacing"))):
            if v[0] > best[k][0]:
                best[k] = v
    return best


def _get_map(maps: dict[str, MapRecord], map_id: str, scenario: ScenarioRecord | None) -> MapRecord:
    try:
        return maps[map_id]
    except KeyError:
        where = f"scenario {scenario.scenario_id!r}: map_id" if scenario is not None else f"map {map_id!r}"
        raise DriveE2EError(f"{where}: expected one of the maps given to pack "
                            f"({', '.join(sorted(maps)) or 'none'}), got {map_id!r}") from None


# --------------------------------------------------------------------------
# pack
# --------------------------------------------------------------------------


def _pack_map(m: MapRecord, sizes: PackSizes) -> dict[str, np.ndarray]:
    """Unbatched map arrays (LEAVES names without B) + ``_stop_line_group``."""
    one = {k: v[0] for k, v in _alloc(1, sizes).items() if k.startswith("map.")}

    def poly(prefix, rows):
        for i, p in enumerate(rows):
            p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
            one[f"{prefix}.xy"][i, : len(p)] = p
            one[f"{prefix}.point_valid"][i, : len(p)] = True
            one[f"{prefix}.valid"][i] = True

    lane_row = {ln.id: i for i, ln in enumerate(m.lanes)}
    poly("map.lanes", [ln.centerline for ln in m.lanes])
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


def _wrap(yaw: np.ndarray) -> np.ndarray:
    """Wrap to (-pi, pi]."""
    return np.pi - np.mod(np.pi - yaw, 2.0 * np.pi)


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
        out["tracks.yaw"][b, a, k] = _wrap(np.asarray(tr.yaw, dtype=np.float64))
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
        _get_map(maps, s.map_id, s)
    routes = [densify_route(s.route.waypoints) for s in scenarios]
    needs = _needs(scenarios, maps, [r[0] for r in routes])
    if sizes is None:
        sizes = PackSizes.rounded({k: n for k, (n, _) in needs.items()})
    else:
        _check_fits(needs, sizes)
    b_total = len(scenarios)
    out = _alloc(b_total, sizes)
    map_arrays, junctions = {}, {}
    for mid in dict.fromkeys(s.map_id for s in scenarios):
        map_arrays[mid] = _pack_map(maps[mid], sizes)
        junctions[mid] = _junction_area(maps[mid])
    map_ids = np.array([s.map_id for s in scenarios])
    for mid, arrays in map_arrays.items():
        rows = np.flatnonzero(map_ids == mid)
        for k, v in arrays.items():
            if not k.startswith("_"):
                out[k][rows] = v

    import shapely

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
        **{k: np.array([getattr(s, k) for s in scenarios], dtype=str) for k in _META_STR},
        ego_track_id=np.array([s.ego_track_id for s in scenarios], np.int64),
        index=idx.astype(np.int64),
        num_agents=np.array([len(s.tracks) for s in scenarios], np.int32),
        num_steps=np.array([s.num_steps for s in scenarios], np.int32),
        dt=np.array([s.dt for s in scenarios], np.float64),
        route_source=np.array([np.asarray(s.route.source, np.float64).reshape(2) for s in scenarios]),
        route_destination=np.array([np.asarray(s.route.destination, np.float64).reshape(2) for s in scenarios]),
        stop_line_group=np.stack([map_arrays[s.map_id]["_stop_line_group"] for s in scenarios]),
    )
    return PackedBatch(unflatten_scenario(out).validate(), meta)


# --------------------------------------------------------------------------
# unpack
# --------------------------------------------------------------------------


def unpack(batch: PackedBatch) -> list[ScenarioRecord]:
    """Records back from a packed batch.

    Reproduces every track sample (times ``k * dt``, positions, yaw wrapped to
    (-pi, pi], velocity, flags; float32 precision), ids, sizes, categories,
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
                xy=f["tracks.xy"][b, a, k].astype(np.float64),
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
        route = RouteRecord(waypoints=f["route.xy"][b][rvalid].astype(np.float64),
                            source=meta.route_source[b].copy(), destination=meta.route_destination[b].copy())
        out.append(ScenarioRecord(
            scenario_id=str(meta.scenario_id[b]), split=str(meta.split[b]),
            intersection_id=str(meta.intersection_id[b]), map_id=str(meta.map_id[b]),
            behavior=str(meta.behavior[b]), weather=str(meta.weather[b]),
            time_of_day=str(meta.time_of_day[b]), ego_track_id=int(meta.ego_track_id[b]),
            route=route, dt=dt, num_steps=n, tracks=tracks, signals=signals,
        ))
    return out


# --------------------------------------------------------------------------
# resize / fit / buckets
# --------------------------------------------------------------------------


def _used(f: dict[str, np.ndarray], meta: SuiteMeta) -> dict[str, np.ndarray]:
    """Per size name: (B,) the count each row actually uses."""

    def last(mask, axis):  # 1 + index of the last True along ``axis`` (0 if none)
        m = mask.any(axis=tuple(i for i in range(1, mask.ndim) if i != axis)) if mask.ndim > 2 else mask
        n = m.shape[-1]
        return np.where(m.any(-1), n - np.argmax(m[..., ::-1], axis=-1), 0)

    agents = last(f["tracks.valid"], 1)
    steps = np.maximum(last(f["tracks.valid"], 2), f["num_steps"])
    return {
        "agents": agents,
        "steps": steps,
        "lanes": last(f["map.lanes.valid"], 1),
        "points": np.maximum(last(f["map.lanes.point_valid"], 2), last(f["map.boundaries.point_valid"], 2)),
        "boundaries": last(f["map.boundaries.valid"], 1),
        "crosswalks": last(f["map.crosswalks.valid"], 1),
        "vertices": np.maximum.reduce([last(f[f"map.{p}.point_valid"], 2) for p in ("crosswalks", "drivable")]),
        "obstacle_vertices": last(f["map.obstacles.point_valid"], 2),
        "stop_lines": last(f["map.stop_line_valid"], 1),
        "drivable": last(f["map.drivable.valid"], 1),
        "obstacles": last(f["map.obstacles.valid"], 1),
        "route": last(f["route.valid"], 1),
        "successors": last(f["map.lane_successors"] >= 0, 2),
    }


def fit_sizes(batch: PackedBatch) -> PackSizes:
    """The tightest rounded sizes that hold every row of ``batch``."""
    used = _used({k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}, batch.meta)
    return PackSizes.rounded({k: int(v.max(initial=0)) for k, v in used.items()})


def _pad_axis(a: np.ndarray, axis: int, new: int, pad: Any) -> np.ndarray:
    old = a.shape[axis]
    if new <= old:
        return np.take(a, np.arange(new), axis=axis)
    widths = [(0, 0)] * a.ndim
    widths[axis] = (0, new - old)
    if pad == "edge":
        return np.pad(a, widths, mode="edge")
    return np.pad(a, widths, mode="constant", constant_values=pad)


def resize(batch: PackedBatch, sizes: PackSizes) -> PackedBatch:
    """Re-pad a batch to ``sizes`` without its records: axes grow with the
    pad values of ``LEAVES`` and shrink only over padding (otherwise a
    DriveE2EError names the scenario and the size that is too small)."""
    old = batch.sizes
    if old == sizes:
        return batch
    f = {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}
    used = _used(f, batch.meta)
    for k, counts in used.items():
        limit = getattr(sizes, k)
        if limit < getattr(old, k) and (counts > limit).any():
            b = int(np.flatnonzero(counts > limit)[0])
            raise DriveE2EError(f"scenario {str(batch.meta.scenario_id[b])!r}: needs {k}={int(counts[b])}, "
                                f"more than PackSizes.{k}={limit} (records are never truncated; pass larger sizes)")
    out = {}
    for name, a in f.items():
        axes, _, pad = LEAVES[name]
        for ax, size_name in enumerate(axes, start=1):
            if not isinstance(size_name, str):
                continue
            p = pad
            if pad == "signal":
                p = "edge" if size_name == "steps" else _UNKNOWN
            a = _pad_axis(a, ax, getattr(sizes, size_name), p)
        out[name] = a
    meta = dataclasses.replace(batch.meta, stop_line_group=_pad_axis(batch.meta.stop_line_group, 1, sizes.stop_lines, -1))
    return PackedBatch(unflatten_scenario(out).validate(), meta)


def bucket(batch: PackedBatch, num_buckets: int = 4) -> list[PackedBatch]:
    """Split a batch into <= ``num_buckets`` batches by (agents, steps) so that
    padding waste stays small; each bucket is re-fitted to its rows.

    Rows are grouped by their rounded (agents, steps) need, the groups sorted
    by area, and the sorted list cut into contiguous buckets minimising the
    total padded agent-steps (exact dynamic programme over the cut points).
    Row order inside a bucket follows the input; ``meta.index`` maps back.
    """
    if num_buckets < 1:
        raise DriveE2EError(f"num_buckets: expected an integer >= 1, got {num_buckets}")
    f = {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}
    used = _used(f, batch.meta)
    ra = 8 * np.maximum(1, np.ceil(used["agents"] / 8)).astype(np.int64)
    rt = 8 * np.maximum(1, np.ceil(used["steps"] / 8)).astype(np.int64)
    keys = sorted(set(zip(ra.tolist(), rt.tolist())), key=lambda k: (k[0] * k[1], k))
    count = {k: 0 for k in keys}
    for k in zip(ra.tolist(), rt.tolist()):
        count[k] += 1
    m = len(keys)
    k_max = min(num_buckets, m)

    def cost(i, j):  # keys[i:j] in one bucket
        a = max(k[0] for k in keys[i:j])
        t = max(k[1] for k in keys[i:j])
        return a * t * sum(count[k] for k in keys[i:j])

    best = {(0, 0): (0, None)}
    for c in range(1, k_max + 1):
        for j in range(1, m + 1):
            cands = [(best[(c - 1, i)][0] + cost(i, j), i) for i in range(j) if (c - 1, i) in best]
            if cands:
                best[(c, j)] = min(cands)
    c = min((c for c in range(1, k_max + 1) if (c, m) in best), key=lambda c: best[(c, m)][0])
    cuts, j = [], m
    while c > 0:
        i = best[(c, j)][1]
        cuts.append((i, j))
        j, c = i, c - 1
    out = []
    row_key = list(zip(ra.tolist(), rt.tolist()))
    for i, j in reversed(cuts):
        members = set(keys[i:j])
        rows = [r for r, k in enumerate(row_key) if k in members]
        out.append(batch.select(rows).fit())
    return out


def pack_buckets(scenarios: Sequence[ScenarioRecord], maps: dict[str, MapRecord], num_buckets: int = 4,
                 *, index: Sequence[int] | None = None) -> list[PackedBatch]:
    """``pack`` then ``bucket``: a few batches with little padding waste."""
    return bucket(pack(scenarios, maps, index=index), num_buckets)
