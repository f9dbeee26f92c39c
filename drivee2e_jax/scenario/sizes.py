"""Padded sizes of a packed batch and the table of its leaves.

* ``PackSizes``: the padded maxima (agents, steps, lanes, ...); ``fit``
  rounds what records need up to ``PackSizes.MULTIPLE``.
* ``LEAVES``: flat leaf name -> (axes, dtype, pad value) of every packed
  array; ``alloc_leaves(b, sizes)`` allocates them filled with their pads.
* ``record_needs(scenarios, maps, routes)``: what each size must hold, and
  which record needs it (for the errors); ``map_of`` finds a scenario's map.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import MapRecord, ScenarioRecord
from drivee2e_jax.scenario.drivable import drivable_edges
from drivee2e_jax.scenario.lane_polygons import packed_lane_polygon
from drivee2e_jax.scenario.routes import densify_route

__all__ = ["PackSizes", "LEAVES", "alloc_leaves", "record_needs", "map_needs", "map_of"]

_UNKNOWN = int(types.SignalState.UNKNOWN)
_VOID = int(types.Command.VOID)


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
      successors (K), lane_vertices (P: lane area polygon vertices, at most
      ``lane_polygons.MAX_VERTICES`` after host simplification), drivable_edges
      (D: edges of the drivable area's boundary, ``scenario.drivable``).
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
    drivable_edges: int = 16
    lane_vertices: int = 8

    #: ``fit`` rounds each maximum up to a multiple of this.
    MULTIPLE: typing.ClassVar[dict[str, int]] = dict(
        agents=8, steps=8, lanes=8, points=4, boundaries=8, crosswalks=4, vertices=4,
        stop_lines=4, drivable=4, obstacles=4, route=16, successors=4, obstacle_vertices=4,
        drivable_edges=16, lane_vertices=8,
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
        needs = record_needs(scenarios, maps, [densify_route(s.route.waypoints)[0] for s in scenarios])
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
            obstacle_vertices=m.obstacles.xy.shape[-2], lane_vertices=m.lane_polygons.xy.shape[-2],
            drivable_edges=m.drivable_edges.shape[-2],
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
    **_poly("map.lane_polygons", "lanes", "lane_vertices"),
    **_poly("map.boundaries", "boundaries", "points"),
    "map.boundary_marking": (("boundaries",), _I, 0),
    **_poly("map.crosswalks", "crosswalks", "vertices"),
    "map.stop_lines": (("stop_lines", 2, 2), _F, 0),
    "map.stop_line_lane": (("stop_lines",), _I, -1),
    "map.stop_line_valid": (("stop_lines",), _B, False),
    **_poly("map.drivable", "drivable", "vertices"),
    **_poly("map.obstacles", "obstacles", "obstacle_vertices"),
    "map.obstacle_height": (("obstacles",), _F, 0),
    "map.drivable_edges": (("drivable_edges", 4), _F, 0),
    "map.drivable_edges_valid": (("drivable_edges",), _B, False),
    "map.drivable_source": ((), _I, 0),
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


def alloc_leaves(b: int, sizes: PackSizes) -> dict[str, np.ndarray]:
    out = {}
    for name, (axes, dtype, pad) in LEAVES.items():
        shape = (b, *(getattr(sizes, a) if isinstance(a, str) else a for a in axes))
        fill = _UNKNOWN if pad == "signal" else (0 if pad == "edge" else pad)
        out[name] = np.full(shape, fill, dtype=dtype)
    return out


# --------------------------------------------------------------------------
# Needs (what each record requires of PackSizes)
# --------------------------------------------------------------------------


def map_needs(m: MapRecord) -> dict[str, tuple[int, str]]:
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
    lane_verts = most(m.lanes, lambda ln: len(packed_lane_polygon(ln)),
                      lambda i: f"{where} lanes[{i}] area polygon")
    obstacle_verts = most(m.obstacles, lambda o: len(o.polygon), lambda i: f"{where} obstacles[{i}].polygon")
    edges, _ = drivable_edges(m)
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
        "lane_vertices": lane_verts,
        "successors": most(m.lanes, lambda ln: len(ln.successors), lambda i: f"{where} lanes[{i}].successors"),
        "drivable_edges": (len(edges), f"{where} drivable area boundary edges"),
    }


def record_needs(scenarios: Sequence[ScenarioRecord], maps: dict[str, MapRecord],
           routes: Sequence[np.ndarray]) -> dict[str, tuple[int, str]]:
    """Per size name: (max count, 'which record needs it')."""
    best: dict[str, tuple[int, str]] = {k: (0, "") for k in PackSizes.MULTIPLE}
    for mid in dict.fromkeys(s.map_id for s in scenarios):
        for k, v in map_needs(map_of(maps, mid, None)).items():
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


def map_of(maps: dict[str, MapRecord], map_id: str, scenario: ScenarioRecord | None) -> MapRecord:
    try:
        return maps[map_id]
    except KeyError:
        where = f"scenario {scenario.scenario_id!r}: map_id" if scenario is not None else f"map {map_id!r}"
        raise DriveE2EError(f"{where}: expected one of the maps given to pack "
                            f"({', '.join(sorted(maps)) or 'none'}), got {map_id!r}") from None
