"""A LiDAR-like range sensor on the ego's roof (nuScenes-like defaults).

Frames: the ego frame has its origin at the ego box centre ON THE GROUND,
x forward, y left, z up. Azimuth 0 = ego forward, counter-clockwise positive;
azimuth column j is the beam at ``j * 360 / azimuth_bins`` degrees. Channel i
has elevation ``elevations_deg[i]`` (ascending: channel 0 is the lowest beam).

Ranges are 3-D distances along the beam from the sensor, m; a beam without a
return reports ``max_range`` with class ``raycast.HIT_NONE``. Hit classes:
0 none, 1 ground, 2 static obstacle, 3 + ``types.Category`` for agents
(3 car, 4 truck, 5 bus, 6 van, 7 motorcycle, 8 tricycle, 9 pedestrian,
10 cyclist). See ``raycast`` for the model (vertical faces, flat ground).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax import geometry
from drivee2e_jax.observe import raycast
from drivee2e_jax.observe.sensor_api import SensorBase, SensorContext

Array = jnp.ndarray


@dataclasses.dataclass(frozen=True)
class LidarConfig:
    """A spinning LiDAR.

    Attributes:
      channels:        number of beams per azimuth column.
      azimuth_bins:    columns over 360 deg.
      max_range:       m.
      elevation_max_deg, elevation_min_deg: span of uniformly spaced channels.
      elevations_deg:  explicit channel elevations (ascending), overriding the span.
      mount_xyz:       sensor position in the ego frame, m (z above ground).
      buffer:          raycast.BufferConfig.
    """

    channels: int = 64
    azimuth_bins: int = 360
    max_range: float = 85.0
    elevation_max_deg: float = 10.0
    elevation_min_deg: float = -30.0
    elevations_deg: tuple[float, ...] | None = None
    mount_xyz: tuple[float, float, float] = (0.0, 0.0, 1.84)
    buffer: raycast.BufferConfig = raycast.BufferConfig()

    def __post_init__(self):
        if self.channels < 1 or self.azimuth_bins < 4:
            raise ValueError(f"LidarConfig: channels >= 1 and azimuth_bins >= 4, got {self}")
        if self.max_range <= 0 or self.mount_xyz[2] <= 0:
            raise ValueError(f"LidarConfig: max_range and mount height must be > 0 m, got {self}")
        if self.elevations_deg is not None and len(self.elevations_deg) != self.channels:
            raise ValueError(f"LidarConfig.elevations_deg: {len(self.elevations_deg)} values, expected {self.channels}")
        if not -90 < self.elevation_min_deg <= self.elevation_max_deg < 90:
            raise ValueError("LidarConfig: need -90 < elevation_min_deg <= elevation_max_deg < 90")

    @property
    def elevations(self) -> np.ndarray:
        """(C,) channel elevations, rad, ascending."""
        if self.elevations_deg is not None:
            return np.radians(np.asarray(self.elevations_deg, np.float64))
        return np.radians(np.linspace(self.elevation_min_deg, self.elevation_max_deg, self.channels))

    @property
    def azimuths(self) -> np.ndarray:
        """(Z,) column azimuths in the ego frame, rad, in [0, 2 pi)."""
        return (2 * np.pi / self.azimuth_bins) * np.arange(self.azimuth_bins)


@struct.dataclass
class LidarScan:
    """One sweep (all beams at the same instant).

    Attributes:
      range:     (C, Z) float32 3-D range along the beam, m (max_range: none).
      hit_class: (C, Z) int32 hit code (module docstring).
      hit_agent: (C, Z) int32 row of the agent hit, -1 otherwise.
      points:    (C * Z, 3) float32 return positions in the ego frame, m
                 (row i * Z + j = channel i, column j; zeros where invalid).
      valid:     (C * Z,) bool, the beam has a return.
    """

    range: Array
    hit_class: Array
    hit_agent: Array
    points: Array
    valid: Array


def lidar_beams(scene: raycast.RayScene, ego_xy: Array, ego_yaw: Array, cfg: LidarConfig = LidarConfig()):
    """(PolarBuffer (Z, D), BeamHits (C, Z)) of the LiDAR: the shared
    intermediate of ``lidar_scan`` and ``visibility.lidar_visible``."""
    mount = jnp.asarray(cfg.mount_xyz[:2], jnp.float32)
    origin = geometry.from_frame(mount, ego_xy, ego_yaw)
    buf = raycast.polar_buffer(scene, origin, ego_yaw, cfg.azimuths, cfg.max_range, cfg.buffer, full_circle=True)
    tan = jnp.asarray(np.tan(cfg.elevations)[:, None], jnp.float32)  # (C, 1)
    return buf, raycast.solve_elevation(buf, tan, float(cfg.mount_xyz[2]), cfg.max_range)


def lidar_scan(scene: raycast.RayScene, ego_xy: Array, ego_yaw: Array, cfg: LidarConfig = LidarConfig()) -> LidarScan:
    """Sweep the LiDAR of an ego at ``ego_xy (2,)`` m, heading ``ego_yaw`` rad.

    ``scene`` comes from ``raycast.select_scene`` (its radius should be >=
    ``cfg.max_range``); pass the ego row as ``exclude`` there. Under ``jit``
    the fields a caller does not use are not computed.
    """
    buf, hits = lidar_beams(scene, ego_xy, ego_yaw, cfg)
    z0 = float(cfg.mount_xyz[2])
    tan = jnp.asarray(np.tan(cfg.elevations)[:, None], jnp.float32)
    found = jnp.isfinite(hits.range)
    r_h = jnp.where(found, hits.range, 0.0)
    # The range image straight from the buffer: a policy that reads only it
    # never computes the per-beam layer choice of ``hits``.
    rng = raycast.beam_ranges(buf, np.tan(cfg.elevations)[:, None], z0, cfg.max_range)
    az = cfg.azimuths
    c, s = jnp.asarray(np.cos(az), jnp.float32), jnp.asarray(np.sin(az), jnp.float32)
    pts = jnp.stack([cfg.mount_xyz[0] + r_h * c, cfg.mount_xyz[1] + r_h * s, z0 + r_h * tan], axis=-1)
    pts = jnp.where(found[..., None], pts, 0.0)
    return LidarScan(
        range=rng.astype(jnp.float32),
        hit_class=hits.code,
        hit_agent=hits.agent,
        points=pts.reshape(-1, 3).astype(jnp.float32),
        valid=found.reshape(-1),
    )


class LidarSensor(SensorBase):
    """The LiDAR in the sensor registry (``observe.registry``).

    ``render(ctx, cfg)``: (C, Z) float32 range image, m (``LidarScan.range``)
    of ``ctx.ray_scene()``. ``trace(ctx, cfg)``: the point cloud
    ``{"points": (C*Z, 3) float32 ego frame m, "hit_class": (C*Z,) int32,
    "valid": (C*Z,) bool}``; ``points(frame, cfg)``: its valid returns."""

    name = "lidar"
    display = "pointcloud"

    def default_config(self) -> LidarConfig:
        return LidarConfig()

    def render(self, ctx: SensorContext, cfg: LidarConfig) -> Array:
        return lidar_scan(ctx.ray_scene(), ctx.ego.xy, ctx.ego.yaw, cfg).range

    def trace(self, ctx: SensorContext, cfg: LidarConfig) -> dict:
        scan = lidar_scan(ctx.ray_scene(), ctx.ego.xy, ctx.ego.yaw, cfg)
        return {"points": scan.points, "hit_class": scan.hit_class.reshape(-1), "valid": scan.valid}

    def points(self, frame, cfg: LidarConfig) -> tuple[np.ndarray, np.ndarray]:
        ok = np.asarray(frame["valid"], bool)
        return np.asarray(frame["points"], np.float32)[ok], np.asarray(frame["hit_class"])[ok]


#: The LiDAR's registry entry.
SENSOR = LidarSensor()
