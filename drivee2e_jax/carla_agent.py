"""CARLA-leaderboard-style agents as host policies (Bench2Drive / TCP ports).

A CARLA Leaderboard 2.0 agent subclasses ``leaderboard.autoagents.
autonomous_agent.AutonomousAgent``: ``setup(path_to_conf_file)``,
``sensors()`` (a list of sensor dicts), ``set_global_plan(gps, world)``,
``run_step(input_data, timestamp) -> carla.VehicleControl`` and ``destroy()``.
This module mirrors that interface without CARLA, so such agent code runs in
drivee2e-jax with two changed imports (docs/leaderboard_agents.md)::

    from drivee2e_jax import carla_agent as autonomous_agent   # was: from leaderboard.autoagents import autonomous_agent
    from drivee2e_jax.carla_agent import carla                 # was: import carla  (VehicleControl, Location, ...)

and :class:`CarlaAgentPolicy` wraps the agent class as a
:class:`~drivee2e_jax.hostapi.HostPolicy`: one agent instance per scenario of
the batch; each control step it builds every agent's ``input_data``
(``{sensor id: (frame, data)}``) from the batch observation and turns the
returned ``VehicleControl`` rows into :class:`hostapi.Controls`.

Frames. drivee2e-jax is right-handed (world x east, y north; ego x forward, y
left; yaw counter-clockwise; ``types``); CARLA is left-handed (x forward /
east, y right / south, z up; yaw clockwise, degrees). A drivee2e world point
(x, y) is CARLA location (x, -y, 0); CARLA's ``steer`` +1 is full RIGHT, the
drivee2e ``Controls.steer`` +1 full LEFT, so ``steer = -control.steer``.

Sensors (``input_data[id] = (frame, data)``, frame = control step, int):

* ``sensor.other.gnss``: float64 [lat, lon, alt] (deg, deg, m) of the sensor
  position (its x / y / z mount offsets applied), from ``obs.gps`` by the
  leaderboard's ``_location_to_gps`` with ``lat_ref`` / ``lon_ref`` (default
  0, 0 as in CARLA's towns; TCP's ``RoutePlanner`` constants assume it).
* ``sensor.other.imu``: float64 [accel x, y, z (m/s^2), gyro x, y, z (rad/s),
  compass (rad)] in CARLA's vehicle frame (x forward, y right, z up):
  accel x = ``obs.ego`` longitudinal accel, y = -speed * yaw rate (centripetal,
  right positive), z = +9.81 (gravity, as CARLA's IMU reads at rest); gyro z =
  -yaw rate (positive turning right); compass = heading clockwise from north
  in [0, 2 pi) (= pi/2 - ``obs.compass``).
* ``sensor.speedometer``: ``{'speed': m/s}``.
* ``sensor.lidar.ray_cast``: float32 (N, 4) [x, y, z, intensity] of the
  returns of ``obs.lidar`` (the range image, beams without a return dropped),
  in the REQUESTED sensor frame of CARLA (x forward, y right, z up, origin at
  the spec's x / y / z, rotated by its yaw; pitch / roll ignored); the beams
  themselves come from drivee2e's LiDAR (64 x 360, +10 to -30 deg, 85 m,
  mount 1.84 m above the ego centre: the leaderboard's LiDAR settings);
  intensity = exp(-0.004 * distance) (CARLA's atmosphere attenuation).
* ``sensor.drivee2e.bev`` (not CARLA): (H, W, C) float32 0/1, the unpacked
  BEV (``observe.bev``: ego drives up, column 0 = ego's left), or the packed
  (H, W) int32 with ``'packed': True``.
* ``sensor.drivee2e.observation`` (not CARLA): ``{field: array}``, this
  scenario's row of every ``hostapi.Observation`` field but ``privileged``.

No counterpart (a one-line :class:`DriveE2EError` naming the sensor id, or
zeros with ``fill_missing="zeros"``): ``sensor.camera.rgb`` / ``depth`` /
``semantic_segmentation`` / ``instance_segmentation`` (zeros: (height,
width, 4) uint8 BGRA, as the leaderboard gives images), ``sensor.other.radar``
(zeros: an empty (0, 4) float32). ``sensor.opendrive_map`` and every other
type always raise.

The global plan: when ``reset``'s meta rows carry the scenario's route
(``route_xy`` world m and ``route_command``, added by
``hostbridge.meta_rows`` for a policy with ``wants_route = True``, as this
one is) ``set_global_plan`` gets the whole route before ``setup``, as in the
leaderboard. Without them (a served policy) it is built before the first
``run_step`` from the observed route ahead (``obs.route``, 10 points 2 m
apart) and extended in place, in the same lists, as more comes into view.

This module imports numpy only (no JAX): it is served by ``drivee2e
serve-policy`` like any host policy.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import types as pytypes
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_jax import hostapi
from drivee2e_jax.errors import DriveE2EError

EARTH_RADIUS_EQUA = 6378137.0  # m, the leaderboard's route_manipulation constant
GRAVITY = 9.81  # m/s^2, what CARLA's IMU accelerometer reads upward at rest

# The drivee2e LiDAR's defaults (observe.lidar.LidarConfig; tests check they agree).
LIDAR_ELEVATION_DEG = (-30.0, 10.0)
LIDAR_MOUNT = (0.0, 0.0, 1.84)
LIDAR_MAX_RANGE = 85.0
LIDAR_ATTENUATION = 0.004  # 1/m, CARLA's atmosphere_attenuation_rate
BEV_CHANNELS = 14  # len(observe.bev.DEFAULT_CHANNELS)

#: Sensor types with a counterpart here -> what ``input_data[id][1]`` is.
SUPPORTED = {
    "sensor.other.gnss": "float64 [lat, lon, alt]",
    "sensor.other.imu": "float64 [ax, ay, az, gx, gy, gz, compass]",
    "sensor.speedometer": "{'speed': m/s}",
    "sensor.lidar.ray_cast": "float32 (N, 4) x, y, z, intensity",
    "sensor.drivee2e.bev": "float32 (H, W, C) BEV",
    "sensor.drivee2e.observation": "{field: array} observation row",
}
#: CARLA sensor types without a counterpart that ``fill_missing="zeros"`` feeds zeros.
ZERO_FILLABLE = ("sensor.camera.rgb", "sensor.camera.depth", "sensor.camera.semantic_segmentation",
                 "sensor.camera.instance_segmentation", "sensor.other.radar")


# --------------------------------------------------------------------------
# The leaderboard's small types
# --------------------------------------------------------------------------


class Track(enum.Enum):
    """The CARLA leaderboard's tracks (``autonomous_agent.Track``)."""

    SENSORS = "SENSORS"
    MAP = "MAP"
    SENSORS_QUALIFIER = "SENSORS_QUALIFIER"
    MAP_QUALIFIER = "MAP_QUALIFIER"


class RoadOption(enum.IntEnum):
    """CARLA's ``agents.navigation.local_planner.RoadOption`` (= ``types.Command``)."""

    VOID = -1
    LEFT = 1
    RIGHT = 2
    STRAIGHT = 3
    LANEFOLLOW = 4
    CHANGELANELEFT = 5
    CHANGELANERIGHT = 6


@dataclasses.dataclass
class VehicleControl:
    """``carla.VehicleControl``: throttle [0, 1], steer [-1, 1] (+1 = full
    RIGHT, CARLA's sign), brake [0, 1]. ``hand_brake`` becomes a full brake;
    ``reverse`` is not modelled (the ego does not reverse): a full brake."""

    throttle: float = 0.0
    steer: float = 0.0
    brake: float = 0.0
    hand_brake: bool = False
    reverse: bool = False
    manual_gear_shift: bool = False
    gear: int = 0


@dataclasses.dataclass
class Location:
    """``carla.Location``, m, CARLA's left-handed world (y = -drivee2e y)."""

    x: float = 0.0
    y: float = 0.0
    z: float = 0.0

    def distance(self, other: Location) -> float:
        return math.sqrt((self.x - other.x) ** 2 + (self.y - other.y) ** 2 + (self.z - other.z) ** 2)


@dataclasses.dataclass
class Rotation:
    """``carla.Rotation``, degrees (yaw clockwise seen from above)."""

    pitch: float = 0.0
    yaw: float = 0.0
    roll: float = 0.0


@dataclasses.dataclass
class Transform:
    """``carla.Transform``: ``location`` and ``rotation``."""

    location: Location = dataclasses.field(default_factory=Location)
    rotation: Rotation = dataclasses.field(default_factory=Rotation)


#: Stand-in for the ``carla`` module in agent code: ``from drivee2e_jax.carla_agent import carla``.
carla = pytypes.SimpleNamespace(VehicleControl=VehicleControl, Location=Location, Rotation=Rotation,
                                Transform=Transform)


# --------------------------------------------------------------------------
# Coordinates
# --------------------------------------------------------------------------


def location_to_gps(lat_ref: float, lon_ref: float, location: Location) -> dict:
    """The leaderboard's ``route_manipulation._location_to_gps``: a CARLA
    location -> ``{'lat', 'lon', 'z'}`` (degrees, m)."""
    scale = math.cos(lat_ref * math.pi / 180.0)
    mx = scale * lon_ref * math.pi * EARTH_RADIUS_EQUA / 180.0 + location.x
    my = scale * EARTH_RADIUS_EQUA * math.log(math.tan((90.0 + lat_ref) * math.pi / 360.0)) - location.y
    lon = mx * 180.0 / (math.pi * EARTH_RADIUS_EQUA * scale)
    lat = 360.0 * math.atan(math.exp(my / (EARTH_RADIUS_EQUA * scale))) / math.pi - 90.0
    return {"lat": lat, "lon": lon, "z": location.z}


def gps_to_location(lat: float, lon: float, lat_ref: float = 0.0, lon_ref: float = 0.0) -> np.ndarray:
    """Inverse of :func:`location_to_gps` (Bench2Drive's ``gps_to_location``):
    (2,) CARLA world x, y, m."""
    scale = math.cos(lat_ref * math.pi / 180.0)
    my = math.log(math.tan((lat + 90.0) * math.pi / 360.0)) * (EARTH_RADIUS_EQUA * scale)
    mx = lon * (math.pi * EARTH_RADIUS_EQUA * scale) / 180.0
    y = scale * EARTH_RADIUS_EQUA * math.log(math.tan((90.0 + lat_ref) * math.pi / 360.0)) - my
    x = mx - scale * lon_ref * math.pi * EARTH_RADIUS_EQUA / 180.0
    return np.array([x, y])


def carla_compass(yaw) -> np.ndarray:
    """CARLA's compass (heading clockwise from north, [0, 2 pi)) of a
    drivee2e world heading ``yaw`` (counter-clockwise from east, rad)."""
    return np.mod(np.pi / 2 - np.asarray(yaw, np.float64), 2 * np.pi)


def to_carla_location(xy, z: float = 0.0) -> Location:
    """A drivee2e world point (x east, y north, m) as a CARLA ``Location``."""
    return Location(float(xy[0]), -float(xy[1]), float(z))


def downsample_route(route: Sequence, sample_factor: float) -> list[int]:
    """The leaderboard's ``route_manipulation.downsample_route``: indices of
    ``[(Transform, RoadOption)]`` kept at most ``sample_factor`` m apart, plus
    the first, the last, lane changes and every change of road option."""
    ids, prev, dist = [], None, 0.0
    lane_changes = (RoadOption.CHANGELANELEFT, RoadOption.CHANGELANERIGHT)
    for i, point in enumerate(route):
        curr = point[1]
        if prev is None or curr in lane_changes or (prev != curr and prev not in lane_changes) \
                or dist > sample_factor or i == len(route) - 1:
            ids.append(i)
            dist = 0.0
        else:
            dist += point[0].location.distance(route[i - 1][0].location)
        prev = curr
    return ids


# --------------------------------------------------------------------------
# The agent base class
# --------------------------------------------------------------------------


class AutonomousAgent:
    """The CARLA leaderboard's ``AutonomousAgent`` (2.0 / Bench2Drive): agent
    code subclasses it unchanged but for the import.

    Lifecycle (as ``leaderboard_evaluator``): ``__init__(host, port, debug)``,
    ``set_global_plan(gps, world)``, ``setup(path_to_conf_file)``,
    ``sensors()``, then ``run_step(input_data, timestamp)`` every control
    step, ``destroy()`` at the end. ``set_global_plan`` keeps the route
    downsampled to ``plan_sample_distance`` m (Bench2Drive: 50; the
    leaderboard: 200) in ``_global_plan`` (``[({'lat', 'lon', 'z'},
    RoadOption)]``) and ``_global_plan_world_coord`` (``[(Transform,
    RoadOption)]``), and the dense GPS route in ``_plan_gps_HACK``
    (Bench2Drive's name).
    """

    plan_sample_distance: float = 50.0

    def __init__(self, carla_host: str = "localhost", carla_port: int = 2000, debug: bool = False):
        self.track = Track.SENSORS
        self._global_plan = None
        self._global_plan_world_coord = None
        self._plan_gps_HACK = None
        self.wallclock_t0 = None
        self.hero_actor = None  # Bench2Drive's get_hero(): there is no CARLA actor here
        self._metric_info: dict = {}

    def setup(self, path_to_conf_file: str) -> None:
        """Initialise the agent (load a model ...); set ``self.track``."""

    def sensors(self) -> list[dict]:
        """The sensor suite: ``[{'type': 'sensor.other.gnss', 'id': 'GPS', 'x': ..., ...}, ...]``."""
        return []

    def run_step(self, input_data: dict, timestamp: float) -> VehicleControl:
        """One control step: ``input_data[id] = (frame, data)`` -> a ``VehicleControl``."""
        return VehicleControl()

    def destroy(self) -> None:
        """Clean up."""

    @staticmethod
    def get_ros_version() -> int:
        return -1

    def set_global_plan(self, global_plan_gps: list, global_plan_world_coord: list) -> None:
        ds_ids = downsample_route(global_plan_world_coord, self.plan_sample_distance)
        self._global_plan_world_coord = [(global_plan_world_coord[x][0], global_plan_world_coord[x][1]) for x in ds_ids]
        self._global_plan = [global_plan_gps[x] for x in ds_ids]
        self._plan_gps_HACK = global_plan_gps

    def get_metric_info(self) -> dict:
        """Bench2Drive's per-step ego record (CARLA frame, from the public
        observation): acceleration, angular_velocity, forward_vector,
        right_vector, location (x, y, z), rotation (roll, pitch, yaw deg)."""
        return dict(self._metric_info)


# --------------------------------------------------------------------------
# Sensors
# --------------------------------------------------------------------------


def _spec_pose(spec: Mapping) -> tuple[float, float, float, float]:
    return (float(spec.get("x", 0.0)), float(spec.get("y", 0.0)), float(spec.get("z", 0.0)),
            float(spec.get("yaw", 0.0)))


def parse_sensors(specs: Any, where: str, fill_missing: str | None = None) -> list[dict]:
    """Check an agent's ``sensors()`` list; returns it as a list of dicts.

    Raises DriveE2EError (one line, starting with ``where``) on a malformed
    entry, a duplicate id, or a sensor type without a counterpart here (unless
    ``fill_missing == "zeros"`` and the type is in ``ZERO_FILLABLE``), naming
    the sensor id and listing the types that exist."""
    if fill_missing not in (None, "zeros"):
        raise DriveE2EError(f"{where}: fill_missing is {fill_missing!r}, expected None or 'zeros'")
    if not isinstance(specs, list | tuple):
        raise DriveE2EError(f"{where}: sensors() returned a {type(specs).__name__}, expected a list of dicts")
    out, seen = [], set()
    available = ", ".join(SUPPORTED)
    for i, spec in enumerate(specs):
        if not isinstance(spec, Mapping) or "type" not in spec or "id" not in spec:
            raise DriveE2EError(f"{where}: sensors()[{i}] is {spec!r}, expected a dict with 'type' and 'id'")
        sid, typ = str(spec["id"]), str(spec["type"])
        if sid in seen:
            raise DriveE2EError(f"{where}: sensor id {sid!r} is used twice")
        seen.add(sid)
        if typ not in SUPPORTED and not (fill_missing == "zeros" and typ in ZERO_FILLABLE):
            hint = (" (or CarlaAgentPolicy(..., fill_missing='zeros') feeds zeros)" if typ in ZERO_FILLABLE else "")
            raise DriveE2EError(f"{where}: sensor {sid!r} of type {typ!r} has no counterpart in drivee2e-jax; "
                                f"available: {available}{hint}")
        out.append(dict(spec))
    return out


def required_sensors_for(specs: Sequence[Mapping]) -> tuple[str, ...]:
    """The drivee2e ``required_sensors`` an agent's sensor list needs."""
    types = {s["type"] for s in specs}
    out = []
    if "sensor.drivee2e.bev" in types:
        out.append("bev")
    if "sensor.lidar.ray_cast" in types:
        out.append("lidar")
    return tuple(out)


def unpack_bev(bits: np.ndarray, num: int) -> np.ndarray:
    """numpy ``observe.bev.unpack_bits``: (..., num) float32 bits of int32 ``bits``."""
    return ((np.asarray(bits)[..., None] >> np.arange(num, dtype=np.int32)) & 1).astype(np.float32)


def lidar_points(rng: np.ndarray, spec: Mapping, *, elevation_deg=LIDAR_ELEVATION_DEG, elevations=None,
                 mount=LIDAR_MOUNT, max_range: float = LIDAR_MAX_RANGE) -> np.ndarray:
    """(N, 4) float32 CARLA LiDAR points [x, y, z, intensity] of ONE range
    image ``rng (C, Z)`` (m; channel i at elevation ``elevations[i]`` rad or
    uniformly over ``elevation_deg``, column j at azimuth j * 360 / Z deg
    counter-clockwise from forward), expressed in the frame the agent's
    ``spec`` requests (x forward, y RIGHT, z up; origin at spec x, y, z with
    CARLA's y right; yaw in degrees clockwise). Beams without a return
    (range >= max_range) are dropped."""
    rng = np.asarray(rng, np.float64)
    c, z = rng.shape
    el = (np.radians(np.linspace(elevation_deg[0], elevation_deg[1], c)) if elevations is None
          else np.asarray(elevations, np.float64))
    az = 2 * np.pi / z * np.arange(z)
    keep = np.isfinite(rng) & (rng < max_range - 1e-3)
    ci, zi = np.nonzero(keep)
    r = rng[ci, zi]
    ce = np.cos(el)[ci]
    p = np.stack([r * ce * np.cos(az[zi]) + mount[0], r * ce * np.sin(az[zi]) + mount[1],
                  r * np.sin(el)[ci] + mount[2]], axis=-1)  # ego frame (y left), origin ego centre on the ground
    sx, sy, sz, syaw = _spec_pose(spec)
    q = p - np.array([sx, -sy, sz])  # relative to the requested mount (CARLA y right -> y left)
    psi = -math.radians(syaw)  # the sensor's yaw, counter-clockwise
    cs, sn = math.cos(psi), math.sin(psi)
    xs, ys = cs * q[:, 0] + sn * q[:, 1], -sn * q[:, 0] + cs * q[:, 1]
    dist = np.sqrt(xs * xs + ys * ys + q[:, 2] ** 2)
    return np.stack([xs, -ys, q[:, 2], np.exp(-LIDAR_ATTENUATION * dist)], axis=-1).astype(np.float32)


def _zeros_for(spec: Mapping) -> np.ndarray:
    if spec["type"] == "sensor.other.radar":
        return np.zeros((0, 4), np.float32)
    return np.zeros((int(spec.get("height", 600)), int(spec.get("width", 800)), 4), np.uint8)


class _Batch:
    """Per-step quantities shared by every agent of the batch (numpy, (B, ...))."""

    def __init__(self, obs: hostapi.Observation):
        self.obs = obs
        ego = np.asarray(obs.ego, np.float64)
        self.speed, self.accel, self.yaw_rate = ego[:, 0], ego[:, 1], ego[:, 2]
        self.xy = np.asarray(obs.gps, np.float64)
        self.yaw = np.asarray(obs.compass, np.float64)
        self.compass = carla_compass(self.yaw)
        self.t = np.asarray(obs.privileged.ego.t, np.float64)


# --------------------------------------------------------------------------
# The host policy
# --------------------------------------------------------------------------


@dataclasses.dataclass
class _Agents:
    """A batch's state: one agent per scenario, its sensors, the step count."""

    agents: list
    specs: list
    step: int = 0
    plans: list | None = None  # per row: (gps list, world list) extended in place (no route in meta)


class CarlaAgentPolicy(hostapi.HostPolicy):
    """A CARLA-leaderboard-style agent class as a host policy (controls).

    Args:
      agent_class: an :class:`AutonomousAgent` subclass (or any class with the
        same methods), constructed as ``agent_class(host, port, debug)``.
      config: ``path_to_conf_file`` given to ``setup``.
      name: the result tables' name (default: the class name).
      fill_missing: ``"zeros"`` feeds zero images / empty radar to sensors
        without a counterpart (RGB, depth, semantic cameras, radar); default
        None: they are a one-line DriveE2EError at construction.
      lat_ref, lon_ref: the GNSS reference (CARLA towns: 0, 0).
      sensor_config: an ``observe.sensors.SensorConfig`` fixing the LiDAR /
        BEV sizes (read duck-typed; default: drivee2e's defaults).
      host, port, debug: passed to the agent constructor (unused here).

    One probe agent is constructed, ``setup`` and asked for ``sensors()`` at
    construction (to declare ``required_sensors``), then destroyed. ``reset``
    builds B agents (construct, ``set_global_plan``, ``setup``); ``act``
    calls each agent's ``run_step``; ``close`` destroys the agents built.
    """

    action_type = "controls"
    wants_route = True  # hostbridge.meta_rows adds each scenario's route to the meta rows

    def __init__(self, agent_class: type, config: str = "", *, name: str | None = None,
                 fill_missing: str | None = None, lat_ref: float = 0.0, lon_ref: float = 0.0,
                 sensor_config: Any = None, host: str = "localhost", port: int = 2000, debug: bool = False):
        self.agent_class = agent_class
        self.config = str(config)
        self.name = name or getattr(agent_class, "__name__", "carla_agent")
        self.fill_missing = fill_missing
        self.lat_ref, self.lon_ref = float(lat_ref), float(lon_ref)
        self.sensor_config = sensor_config
        self._ctor = (host, int(port), bool(debug))
        self.where = f"CARLA agent {self.name}"
        lidar = getattr(sensor_config, "lidar", None)
        self._lidar = {"elevations": None if lidar is None else np.asarray(lidar.elevations, np.float64),
                       "mount": LIDAR_MOUNT if lidar is None else tuple(lidar.mount_xyz),
                       "max_range": LIDAR_MAX_RANGE if lidar is None else float(lidar.max_range)}
        bev = getattr(sensor_config, "bev", None)
        self._bev_channels = BEV_CHANNELS if bev is None else len(bev.channels)
        self._live: list[list] = []
        probe = self._new_agent()
        try:
            self._call(probe, "setup", self.config)
            self.specs = parse_sensors(self._call(probe, "sensors"), self.where, fill_missing)
        finally:
            self._call(probe, "destroy")
        self.required_sensors = required_sensors_for(self.specs)

    @classmethod
    def from_file(cls, path: str | Path, config: str = "", **kwargs) -> CarlaAgentPolicy:
        """The agent class named by ``get_entry_point()`` in a leaderboard agent file."""
        module = hostapi.import_file(path, "agent")
        if not hasattr(module, "get_entry_point"):
            raise DriveE2EError(f"{path}: defines no get_entry_point() (the leaderboard's agent entry point)")
        entry = module.get_entry_point()
        if not hasattr(module, str(entry)):
            raise DriveE2EError(f"{path}: get_entry_point() returned {entry!r}, which the file does not define")
        return cls(getattr(module, entry), config, **kwargs)

    # -- helpers ---------------------------------------------------------------
    def _new_agent(self):
        try:
            return self.agent_class(*self._ctor)
        except Exception as e:  # noqa: BLE001 - a user's agent: one line
            raise DriveE2EError(f"{self.where}: {self.name}(host, port, debug) failed: {type(e).__name__}: {e}") from e

    def _call(self, agent, method: str, *args):
        try:
            return getattr(agent, method)(*args)
        except DriveE2EError:
            raise
        except Exception as e:  # noqa: BLE001 - a user's agent: one line
            raise DriveE2EError(f"{self.where}: {method}() raised {type(e).__name__}: {e}") from e

    def _plan(self, xy: np.ndarray, command: np.ndarray) -> tuple[list, list]:
        """(gps plan, world plan) of a drivee2e world route ``xy (R, 2)``."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        if len(xy) == 0:
            return [], []
        d = np.diff(xy, axis=0)
        heading = np.arctan2(d[:, 1], d[:, 0]) if len(d) else np.zeros(0)
        heading = np.concatenate([heading, heading[-1:]]) if len(heading) else np.zeros(1)
        gps, world = [], []
        for p, h, c in zip(xy, heading, np.asarray(command).reshape(-1)):
            loc = to_carla_location(p)
            opt = RoadOption(int(c)) if int(c) in RoadOption._value2member_map_ else RoadOption.LANEFOLLOW
            world.append((Transform(loc, Rotation(yaw=-math.degrees(float(h)))), opt))
            gps.append((location_to_gps(self.lat_ref, self.lon_ref, loc), opt))
        return gps, world

    # -- HostPolicy ------------------------------------------------------------
    def reset(self, meta: list[dict]) -> _Agents:
        agents, have_route = [], all("route_xy" in m and "route_command" in m for m in meta)
        for m in meta:
            agent = self._new_agent()
            if have_route:
                gps, world = self._plan(np.asarray(m["route_xy"], np.float64), np.asarray(m["route_command"]))
                self._call(agent, "set_global_plan", gps, world)
            self._call(agent, "setup", self.config)
            agents.append(agent)
        specs = parse_sensors(self._call(agents[0], "sensors"), self.where, self.fill_missing) if agents else []
        extra = sorted(set(required_sensors_for(specs)) - set(self.required_sensors))
        if extra:
            raise DriveE2EError(f"{self.where}: sensors() after set_global_plan asks for {', '.join(extra)}, which the "
                                f"probe agent did not (required_sensors={self.required_sensors})")
        self._live.append(agents)
        return _Agents(agents=agents, specs=specs, plans=None if have_route else [None] * len(agents))

    def _extend_plans(self, state: _Agents, batch: _Batch) -> None:
        """No route in meta: the plan from the observed route ahead, grown in place."""
        obs = batch.obs
        route = np.asarray(obs.route, np.float64)
        valid = np.asarray(obs.route_valid, bool)
        for b, agent in enumerate(state.agents):
            c, s = math.cos(batch.yaw[b]), math.sin(batch.yaw[b])
            pts = route[b][valid[b]]
            world = batch.xy[b] + np.stack([c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1]], -1)
            cmd = np.full(len(world), int(obs.command[b]))
            if state.plans[b] is None:
                gps, wc = self._plan(np.concatenate([batch.xy[b][None], world]), np.concatenate([cmd[:1], cmd]))
                self._call(agent, "set_global_plan", gps, wc)
                lists = [agent._global_plan, agent._global_plan_world_coord, agent._plan_gps_HACK]
                state.plans[b] = (lists, [world[-1] if len(world) else batch.xy[b]])
                continue
            lists, last = state.plans[b]
            tail = last[0]
            new = [p for p in world if np.hypot(*(p - tail)) > 1.0 and (p - tail) @ (p - batch.xy[b]) > 0]
            if new:
                gps, wc = self._plan(np.asarray(new), cmd[:len(new)])
                done = set()
                for lst, items in zip(lists, (gps, wc, gps)):
                    if isinstance(lst, list) and id(lst) not in done:  # an agent may keep one list twice
                        lst.extend(items)
                        done.add(id(lst))
                last[0] = np.asarray(new[-1])

    def _input_data(self, state: _Agents, batch: _Batch, b: int) -> dict:
        obs, frame, out = batch.obs, state.step, {}
        for spec in state.specs:
            typ, sid = spec["type"], str(spec["id"])
            if typ == "sensor.other.gnss":
                sx, sy, sz, _ = _spec_pose(spec)
                c, s = math.cos(batch.yaw[b]), math.sin(batch.yaw[b])
                p = batch.xy[b] + np.array([c * sx + s * sy, s * sx - c * sy])  # CARLA y right -> left
                g = location_to_gps(self.lat_ref, self.lon_ref, to_carla_location(p, sz))
                data = np.array([g["lat"], g["lon"], g["z"]], np.float64)
            elif typ == "sensor.other.imu":
                v, w = batch.speed[b], batch.yaw_rate[b]
                data = np.array([batch.accel[b], -v * w, GRAVITY, 0.0, 0.0, -w, batch.compass[b]], np.float64)
            elif typ == "sensor.speedometer":
                data = {"speed": float(batch.speed[b])}
            elif typ == "sensor.lidar.ray_cast":
                data = lidar_points(obs.lidar[b], spec, **self._lidar)
            elif typ == "sensor.drivee2e.bev":
                data = (np.asarray(obs.bev[b]) if spec.get("packed")
                        else unpack_bev(obs.bev[b], int(spec.get("channels", self._bev_channels))))
            elif typ == "sensor.drivee2e.observation":
                data = {f: (getattr(obs, f)[b] if f != "sensors" else {k: v[b] for k, v in obs.sensors.items()})
                        for f in hostapi.field_names(hostapi.Observation)
                        if f != "privileged" and getattr(obs, f) is not None}
            else:  # fill_missing="zeros" (parse_sensors let it through)
                data = _zeros_for(spec)
            out[sid] = (frame, data)
        return out

    def _metric_info(self, batch: _Batch, b: int) -> dict:
        c, s = math.cos(batch.yaw[b]), math.sin(batch.yaw[b])
        v, a, w = batch.speed[b], batch.accel[b], batch.yaw_rate[b]
        return {"acceleration": [a * c - v * w * s, -(a * s + v * w * c), 0.0],
                "angular_velocity": [0.0, 0.0, -math.degrees(w)],
                "forward_vector": [c, -s, 0.0], "right_vector": [s, c, 0.0],
                "location": [float(batch.xy[b, 0]), -float(batch.xy[b, 1]), 0.0],
                "rotation": [0.0, 0.0, -math.degrees(batch.yaw[b])]}

    def act(self, obs: hostapi.Observation, state: _Agents) -> tuple[hostapi.Controls, _Agents]:
        batch = _Batch(obs)
        n = len(state.agents)
        if obs.batch_size != n:
            raise DriveE2EError(f"{self.where}: observation of {obs.batch_size} scenarios, reset built {n} agents")
        if state.plans is not None:
            self._extend_plans(state, batch)
        out = np.zeros((3, n), np.float32)
        for b, agent in enumerate(state.agents):
            agent._metric_info = self._metric_info(batch, b)
            control = self._call(agent, "run_step", self._input_data(state, batch, b), float(batch.t[b]))
            out[:, b] = control_to_row(control, f"{self.where}, scenario row {b}, step {state.step}")
        state.step += 1
        return hostapi.Controls(throttle=out[0], brake=out[1], steer=out[2]), state

    def close(self) -> None:
        for agents in self._live:
            for agent in agents:
                try:
                    agent.destroy()
                except Exception:  # noqa: BLE001, S110 - best effort at shutdown
                    pass
        self._live = []


def control_to_row(control: Any, where: str) -> tuple[float, float, float]:
    """(throttle, brake, steer) in drivee2e's convention of a CARLA
    ``VehicleControl`` (steer +1 = right -> -1 here; hand_brake or reverse ->
    full brake, no throttle). NaN passes through (the simulator counts it)."""
    if not all(hasattr(control, k) for k in ("throttle", "steer", "brake")):
        raise DriveE2EError(f"{where}: run_step returned {type(control).__name__}, expected a VehicleControl "
                            f"(throttle, steer, brake)")
    try:
        throttle, steer, brake = float(control.throttle), float(control.steer), float(control.brake)
    except (TypeError, ValueError) as e:
        raise DriveE2EError(f"{where}: VehicleControl fields must be numbers: {e}") from e
    if getattr(control, "hand_brake", False) or getattr(control, "reverse", False):
        throttle, brake = 0.0, 1.0
    return throttle, brake, -steer
