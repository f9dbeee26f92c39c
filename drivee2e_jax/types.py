"""The pytrees of drivee2e-jax: one place to look up a shape.

Every array pytree here is a frozen ``flax.struct`` dataclass written for ONE
scenario (unbatched shapes below). A packed suite carries one extra leading
batch axis ``B`` on every leaf. Every padded axis has a boolean ``valid`` mask.

Frames and units: world frame x east, y north, metres; yaw counter-clockwise
from +x, radians; time in seconds; speeds in m/s. SI everywhere inside the
simulator; units appear in names only where they are not SI base units.

Symbols used in shapes:

* ``A`` agents (the ego is one of them, at ``Scenario.ego_index``)
* ``T`` log steps (``Scenario.dt_log`` apart, starting at t = 0)
* ``L`` lanes, ``N`` points per polyline, ``P`` vertices per lane polygon
* ``E`` lane boundaries / road edges
* ``C`` crosswalks, ``V`` polygon vertices
* ``S`` stop lines, ``G`` drivable-area polygons, ``O`` static obstacles
* ``D`` edges of the drivable area's boundary
* ``R`` route points (1 m apart, as CARLA's route planner densifies them)
* ``K`` successor lanes per lane
"""

from __future__ import annotations

import enum

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

Array = jnp.ndarray


# --------------------------------------------------------------------------
# Enumerations (stored as int32 in arrays; names are the on-disk strings)
# --------------------------------------------------------------------------


class Category(enum.IntEnum):
    """Agent category. CARLA counts cyclists and motorcycles as vehicles for
    the Driving Score; the finer class is kept for reporting."""

    CAR = 0
    TRUCK = 1
    BUS = 2
    VAN = 3
    MOTORCYCLE = 4
    TRICYCLE = 5
    PEDESTRIAN = 6
    CYCLIST = 7

    @classmethod
    def parse(cls, name: str) -> Category:
        return cls[name.upper()]


class CollisionClass(enum.IntEnum):
    """How CARLA's CollisionTest classifies the other actor's ``type_id``.

    The source tests ``static``/``traffic`` (and not ``sidewalk``) first, then
    ``vehicle``, then ``walker``; anything else (e.g. ``static.sidewalk``) is
    counted by the criterion but produces no penalty event (OTHER).
    """

    PEDESTRIAN = 0
    VEHICLE = 1
    LAYOUT = 2
    OTHER = 3


class CollisionType(enum.IntEnum):
    """nuPlan's collision types (``nuplan/planning/metrics/utils/collision_utils.py``,
    ``CollisionType``), in its order; ``infractions.collision_type`` classifies."""

    STOPPED_EGO = 0
    STOPPED_TRACK = 1
    ACTIVE_FRONT = 2
    ACTIVE_REAR = 3
    ACTIVE_LATERAL = 4


#: Names of ``CollisionType`` in results (events, tables); a static-layout
#: contact is "static".
COLLISION_TYPE_NAMES = ("stopped_ego", "stopped_track", "active_front", "active_rear", "active_lateral")


#: Categories that CARLA scores as ``collisions_vehicle`` (everything but walkers).
VEHICLE_LIKE = tuple(c for c in Category if c != Category.PEDESTRIAN)


class Behavior(enum.IntEnum):
    """The source benchmark's eight behaviour groups (Table 5 order)."""

    COV = 0  # competing with other vehicles
    IPC = 1  # interaction with pedestrians and cyclists
    UT = 2  # U-turn
    YLW = 3  # passing through during a yellow light
    STR = 4  # going straight through the intersection
    LFT = 5  # left turn
    RT = 6  # right turn
    STP = 7  # stopping at a red light


class SignalState(enum.IntEnum):
    UNKNOWN = 0
    RED = 1
    YELLOW = 2
    GREEN = 3


class Command(enum.IntEnum):
    """CARLA's high-level route command (``RoadOption``) per route point."""

    VOID = -1
    LEFT = 1
    RIGHT = 2
    STRAIGHT = 3
    LANEFOLLOW = 4
    CHANGELANELEFT = 5
    CHANGELANERIGHT = 6


class LaneType(enum.IntEnum):
    DRIVING = 0
    TURN_POCKET = 1
    CONNECTOR = 2  # a lane inside the junction linking an entry to an exit
    BIKE = 3
    PARKING = 4


class Marking(enum.IntEnum):
    """Marking type of a lane boundary polyline."""

    NONE = 0
    DASHED = 1
    SOLID = 2
    DOUBLE_SOLID = 3
    ROAD_EDGE = 4  # kerb: the edge of the drivable surface


# --------------------------------------------------------------------------
# Scenario pytrees
# --------------------------------------------------------------------------


@struct.dataclass
class Tracks:
    """Logged agent tracks on the scenario's time grid ``t_k = k * dt_log``.

    Attributes:
      xy:        (A, T, 2) float32 box centre, m.
      yaw:       (A, T) float32 heading, rad.
      vel:       (A, T, 2) float32 world-frame velocity, m/s.
      size:      (A, 3) float32 box length, width, height, m.
      category:  (A,) int32 ``Category``.
      valid:     (A, T) bool, the agent exists (is observed) at step t.
      visible:   (A, T) bool, the source's visibility flag.
      quality:   (A, T) bool, the source's quality flag (True = trusted).
      track_id:  (A,) int32 id from the source record (-1 for padding).
    """

    xy: Array
    yaw: Array
    vel: Array
    size: Array
    category: Array
    valid: Array
    visible: Array
    quality: Array
    track_id: Array

    @property
    def agent_valid(self) -> Array:
        """(A,) bool: the agent exists at some step (False for padding)."""
        return self.valid.any(axis=-1)

    @property
    def num_agents(self) -> int:
        return self.xy.shape[-3]

    @property
    def num_steps(self) -> int:
        return self.xy.shape[-2]


@struct.dataclass
class Polylines:
    """A padded set of polylines or polygons (closed implicitly).

    Attributes:
      xy:          (P, N, 2) float32 points, m.
      point_valid: (P, N) bool (packing writes valid points as a prefix; the
                   geometry functions do not rely on it).
      valid:       (P,) bool, the polyline exists.
    """

    xy: Array
    point_valid: Array
    valid: Array


@struct.dataclass
class MapData:
    """The static map of one intersection.

    Attributes:
      lanes:            Polylines (L, N) lane centrelines, in driving direction.
      lane_type:        (L,) int32 ``LaneType``.
      lane_width:       (L,) float32, m.
      lane_speed_limit: (L,) float32, m/s.
      lane_successors:  (L, K) int32 indices into lanes, -1 padded.
      lane_left_marking, lane_right_marking: (L,) int32 ``Marking``.
      lane_polygons:    Polylines (L, P) lane area polygons, counter-clockwise, from
                        the lane's left/right boundaries where the source has them,
                        else the curved centreline ± width/2 (built on the host by
                        ``scenario.lane_polygons``; polygons over
                        ``lane_polygons.MAX_VERTICES`` vertices are simplified with
                        a few cm tolerance). Open rings (first vertex not repeated).
      boundaries:       Polylines (E, N) lane boundaries and road edges.
      boundary_marking: (E,) int32 ``Marking``.
      crosswalks:       Polylines (C, V) crosswalk polygons.
      stop_lines:       (S, 2, 2) float32 segment end points, m.
      stop_line_lane:   (S,) int32 index of the lane the line guards (-1: none).
      stop_line_valid:  (S,) bool.
      drivable:         Polylines (G, V) drivable-area polygons.
      obstacles:        Polylines (O, V) static obstacle footprints.
      obstacle_height:  (O,) float32, m.
      drivable_edges:   (D, 4) float32 [ax, ay, bx, by] edges of the boundary of
                        the drivable AREA (the union of ``drivable``, or of the
                        lane areas when the map has no drivable polygons), m,
                        every ring (holes too); ``scenario.drivable``.
      drivable_edges_valid: (D,) bool.
      drivable_source:  () int32 ``scenario.drivable.DrivableSource``
                        (0 none, 1 drivable polygons, 2 lane areas).
    """

    lanes: Polylines
    lane_type: Array
    lane_width: Array
    lane_speed_limit: Array
    lane_successors: Array
    lane_left_marking: Array
    lane_right_marking: Array
    lane_polygons: Polylines
    boundaries: Polylines
    boundary_marking: Array
    crosswalks: Polylines
    stop_lines: Array
    stop_line_lane: Array
    stop_line_valid: Array
    drivable: Polylines
    obstacles: Polylines
    obstacle_height: Array
    drivable_edges: Array
    drivable_edges_valid: Array
    drivable_source: Array


@struct.dataclass
class Signals:
    """Traffic-signal state per stop line over the log.

    Attributes:
      state: (S, T) int32 ``SignalState`` of the signal guarding stop line s at
        log step t (UNKNOWN for padding and for unsignalised lines).
    """

    state: Array


@struct.dataclass
class Route:
    """The reference route: the logged ego path densified to 1 m.

    Attributes:
      xy:      (R, 2) float32 points, m.
      arc:     (R,) float32 cumulative arc length from the first point, m.
      command: (R,) int32 ``Command`` at each point.
      valid:   (R,) bool; valid points are a prefix.
      length:  () float32 arc length of the last valid point, m.
    """

    xy: Array
    arc: Array
    command: Array
    valid: Array
    length: Array


@struct.dataclass
class Scenario:
    """Everything the simulator needs about one episode.

    Attributes:
      tracks:      Tracks (A, T).
      map:         MapData.
      signals:     Signals (S, T).
      route:       Route (R,).
      ego_index:   () int32 row of the ego in ``tracks``.
      dt_log:      () float32 log step, s.
      num_steps:   () int32 number of valid log steps (<= T).
      index:       () int32 row of this scenario in the host-side meta table.
    """

    tracks: Tracks
    map: MapData
    signals: Signals
    route: Route
    ego_index: Array
    dt_log: Array
    num_steps: Array
    index: Array

    def validate(self) -> Scenario:
        """Check that shape prefixes agree (batched or not); returns self.

        Raises ValueError naming the field whose shape disagrees.
        """
        tr = self.tracks
        lead = tr.xy.shape[:-3]
        a, t = tr.xy.shape[-3], tr.xy.shape[-2]
        checks = {
            "tracks.xy": (tr.xy.shape, lead + (a, t, 2)),
            "tracks.yaw": (tr.yaw.shape, lead + (a, t)),
            "tracks.vel": (tr.vel.shape, lead + (a, t, 2)),
            "tracks.size": (tr.size.shape, lead + (a, 3)),
            "tracks.category": (tr.category.shape, lead + (a,)),
            "tracks.valid": (tr.valid.shape, lead + (a, t)),
            "tracks.visible": (tr.visible.shape, lead + (a, t)),
            "tracks.quality": (tr.quality.shape, lead + (a, t)),
            "tracks.track_id": (tr.track_id.shape, lead + (a,)),
            "signals.state": (self.signals.state.shape, lead + (self.map.stop_lines.shape[-3], t)),
            "route.arc": (self.route.arc.shape, self.route.xy.shape[:-1]),
            "route.command": (self.route.command.shape, self.route.xy.shape[:-1]),
            "route.valid": (self.route.valid.shape, self.route.xy.shape[:-1]),
            "ego_index": (self.ego_index.shape, lead),
        }
        for name, (got, want) in checks.items():
            if tuple(got) != tuple(want):
                raise ValueError(f"Scenario.{name}: shape {tuple(got)}, expected {tuple(want)}")
        return self

    @property
    def duration(self) -> Array:
        """() float32 log duration, s."""
        return (self.num_steps - 1).astype(jnp.float32) * self.dt_log


def batch_size(tree) -> int:
    """Leading batch size of a batched pytree (first leaf's first axis)."""

    return int(jax.tree_util.tree_leaves(tree)[0].shape[0])


def to_numpy(tree):
    """Host copy of a pytree (numpy leaves)."""

    return jax.tree_util.tree_map(np.asarray, tree)


# --------------------------------------------------------------------------
# Ego and action pytrees
# --------------------------------------------------------------------------


@struct.dataclass
class EgoState:
    """The simulated ego (kinematic bicycle, reference point = box centre).

    Attributes:
      xy:       (2,) float32 position, m.
      yaw:      () float32 heading, rad.
      speed:    () float32 longitudinal speed, m/s (>= 0; no reversing).
      accel:    () float32 mean longitudinal acceleration actually reached over
                the last step, (v1 - v0) / dt, m/s^2.
      steer:    () float32 front-wheel steering angle, rad.
      yaw_rate: () float32 rad/s over the last step.
      t:        () float32 simulation time, s.
    """

    xy: Array
    yaw: Array
    speed: Array
    accel: Array
    steer: Array
    yaw_rate: Array
    t: Array


@struct.dataclass
class Controls:
    """CARLA-style low-level controls.

    Attributes:
      throttle: () float32 in [0, 1].
      brake:    () float32 in [0, 1].
      steer:    () float32 in [-1, 1]; +1 = full left (counter-clockwise).
    """

    throttle: Array
    brake: Array
    steer: Array


@struct.dataclass
class Waypoints:
    """A trajectory action: future ego positions in the ego frame.

    Attributes:
      xy: (K, 2) float32 points, m, x forward, y left, spaced
          ``ControllerParams.waypoint_dt`` (default 0.5 s) apart in time.
    """

    xy: Array


# --------------------------------------------------------------------------
# Observations
# --------------------------------------------------------------------------


@struct.dataclass
class Privileged:
    """Ground truth a benchmark policy must not use, but reference policies do
    (log replay, the rule-based expert's perfect signal knowledge).

    Attributes:
      ego:          EgoState, the exact simulated ego state.
      log_next_xy:  (2,) float32 the logged ego position one sim step ahead, m.
      log_next_yaw: () float32 the logged ego heading one sim step ahead, rad.
      log_valid:    () bool, the logged ego exists at that time.
      log_controls: Controls that carry the simulated ego to the logged
                    position ``SimConfig.log_horizon_s`` (0.5 s) ahead
                    (``dynamics.inverse`` over that horizon, recomputed every
                    step; one step at the end of the log): the reference
                    demonstration expressed as an action from the CURRENT
                    simulated state, smooth where the log's positions jitter.
    """

    ego: EgoState
    log_next_xy: Array
    log_next_yaw: Array
    log_valid: Array
    log_controls: Controls


@struct.dataclass
class Observation:
    """What the policy sees, rendered from the ego's current SIMULATED state.

    Ego-frame vectors have x forward, y left, metres. Optional sensor slots
    (``bev``, ``lidar``) are ``None`` unless the policy lists them in
    ``required_sensors`` or ``SimConfig.sensors`` enables them
    (``observe/sensors.py``).

    Attributes:
      ego:            (4,) float32 [speed m/s, accel m/s^2, yaw_rate rad/s, steer rad].
      gps:            (2,) float32 world position, m (noisy if configured).
      compass:        () float32 world heading, rad (noisy if configured).
      route:          (P, 2) float32 next route points ahead, ego frame.
      route_valid:    (P,) bool.
      command:        () int32 ``Command`` at the next route point.
      agents:         (K, 8) float32 nearest agents: x, y, cos dyaw, sin dyaw,
                      vx, vy (ego frame, m/s), length, width.
      agents_category:(K,) int32 ``Category``.
      agents_valid:   (K,) bool.
      lanes:          (M, Q, 2) float32 nearby lane centrelines, ego frame.
      lanes_valid:    (M, Q) bool.
      signal_state:   () int32 ``SignalState`` of the next stop line on the route.
      signal_distance:() float32 route distance to that stop line, m (1e3 if none).
      speed_limit:    () float32 speed limit of the lane the route runs on at the
                      ego's route position, m/s (CARLA agents' ``get_speed_limit``).
      privileged:     Privileged.
      bev:            (H, W) int32 bit-packed BEV channels (bit c = channel c of
                      ``BevConfig.channels``; ``observe.bev.unpack_bits(bev, C)``
                      gives (H, W, C) float32), or None.
      lidar:          (C, Z) float32 LiDAR range image, m (channels x azimuth
                      bins; ``observe.lidar``), or None.
      sensors:        {name: output} of the other enabled registered sensors
                      (``observe.registry``), or None when none is on.
    """

    ego: Array
    gps: Array
    compass: Array
    route: Array
    route_valid: Array
    command: Array
    agents: Array
    agents_category: Array
    agents_valid: Array
    lanes: Array
    lanes_valid: Array
    signal_state: Array
    signal_distance: Array
    speed_limit: Array
    privileged: Privileged
    bev: Array | None = None
    lidar: Array | None = None
    sensors: dict | None = None
