"""Host-side scenario records: the on-disk schema, in Python.

These plain dataclasses (numpy arrays, strings) are what generators and
importers produce, what ``scenario.schema`` reads and writes as JSON, and what
``scenario.pack`` turns into padded JAX arrays (``drivee2e_jax.types``). They
never enter ``jit``.

A suite folder on disk::

    suite.json                 {"name", "version", "scenarios": [{"id", "split"}], ...}
    maps/<map_id>.json         one MapRecord
    scenarios/<id>.json        one ScenarioRecord

Field names below are the JSON keys. Units: metres, seconds, radians, m/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: The on-disk schema version written into suite.json / every record.
SCHEMA_VERSION = 1

CATEGORIES = ("car", "truck", "bus", "van", "motorcycle", "tricycle", "pedestrian", "cyclist")
BEHAVIORS = ("COV", "IPC", "UT", "YLW", "STR", "LFT", "RT", "STP")
SPLITS = ("train", "val", "test")
WEATHERS = ("clear", "cloudy", "rain", "fog")
TIMES_OF_DAY = ("day", "dusk", "night")
LANE_TYPES = ("driving", "turn_pocket", "connector", "bike", "parking")
MARKINGS = ("none", "dashed", "solid", "double_solid", "road_edge")
SIGNAL_STATES = ("unknown", "red", "yellow", "green")


@dataclass
class LaneRecord:
    """One lane: centreline in driving direction."""

    id: int
    centerline: np.ndarray  # (n, 2) float
    width: float = 3.5
    speed_limit: float = 13.9  # m/s (50 km/h)
    type: str = "driving"  # one of LANE_TYPES
    successors: list[int] = field(default_factory=list)  # lane ids
    left_marking: str = "dashed"  # one of MARKINGS
    right_marking: str = "dashed"
    # Optional lane edges, (n, 2) float m, in the driving direction; left = left of travel.
    # When both are present they define the lane's area polygon (scenario/lane_polygons.py).
    left_boundary: np.ndarray | None = None
    right_boundary: np.ndarray | None = None
    # Optional lane area as the source draws it, (n >= 3, 2) float m, a simple ring in any
    # orientation (nuScenes / nuPlan lane polygons via ScenarioNet). It takes precedence
    # over the boundaries and the centreline fallback (scenario/lane_polygons.py).
    polygon: np.ndarray | None = None


@dataclass
class BoundaryRecord:
    """A lane boundary or road edge polyline with its marking type."""

    points: np.ndarray  # (n, 2)
    marking: str  # one of MARKINGS


@dataclass
class StopLineRecord:
    """A stop line across one lane, guarded by one signal group."""

    id: int
    points: np.ndarray  # (2, 2) end points
    lane_id: int  # the lane whose traffic it stops (-1: none)
    signal_group: int  # key into ScenarioRecord.signals (-1: unsignalised)


@dataclass
class ObstacleRecord:
    """A static obstacle (building, pole, signal pole, ...)."""

    polygon: np.ndarray  # (n, 2) footprint, counter-clockwise
    height: float
    kind: str = "building"


@dataclass
class SignalPhase:
    """One phase of a fixed-time signal plan."""

    duration: float  # s
    green: list[int]  # signal groups green during this phase
    yellow_duration: float = 3.0  # s of yellow at the end for those groups
    all_red: float = 2.0  # s all-red clearance after the yellow


@dataclass
class MapRecord:
    """The static map of one intersection (``maps/<map_id>.json``)."""

    map_id: str
    lanes: list[LaneRecord]
    boundaries: list[BoundaryRecord] = field(default_factory=list)
    crosswalks: list[np.ndarray] = field(default_factory=list)  # (n, 2) polygons
    stop_lines: list[StopLineRecord] = field(default_factory=list)
    drivable_areas: list[np.ndarray] = field(default_factory=list)  # (n, 2) polygons
    obstacles: list[ObstacleRecord] = field(default_factory=list)
    signal_plan: list[SignalPhase] = field(default_factory=list)
    meta: dict = field(default_factory=dict)  # free-form (legs, skew, ...)


@dataclass
class TrackRecord:
    """One agent's logged track. Samples are at timestamps ``t`` (s from the
    scenario start), which must lie on the scenario grid ``k * dt``."""

    track_id: int
    category: str  # one of CATEGORIES
    size: np.ndarray  # (3,) length, width, height
    t: np.ndarray  # (n,)
    xy: np.ndarray  # (n, 2) box centre
    yaw: np.ndarray  # (n,)
    vel: np.ndarray | None = None  # (n, 2) when available
    visible: np.ndarray | None = None  # (n,) bool, default all True
    quality: np.ndarray | None = None  # (n,) bool, default all True


@dataclass
class RouteRecord:
    """The ego's reference route (coarse waypoints; packing densifies to 1 m)."""

    waypoints: np.ndarray  # (n, 2)
    source: np.ndarray  # (2,)
    destination: np.ndarray  # (2,)


@dataclass
class ScenarioRecord:
    """One scenario (``scenarios/<scenario_id>.json``)."""

    scenario_id: str
    split: str  # one of SPLITS
    intersection_id: str
    map_id: str
    behavior: str  # one of BEHAVIORS
    weather: str  # one of WEATHERS
    time_of_day: str  # one of TIMES_OF_DAY
    ego_track_id: int
    route: RouteRecord
    dt: float  # log step, s
    num_steps: int  # log length in steps
    tracks: list[TrackRecord]
    signals: dict[int, np.ndarray] = field(default_factory=dict)  # group -> (num_steps,) int8 SIGNAL_STATES index


@dataclass
class SuiteRecord:
    """A whole suite in memory: maps by id and the scenarios."""

    name: str
    version: str
    maps: dict[str, MapRecord]
    scenarios: list[ScenarioRecord]
    meta: dict = field(default_factory=dict)
