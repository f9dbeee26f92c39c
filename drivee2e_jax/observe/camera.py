"""Pinhole cameras from the ray-casting core: depth and semantic images.

Each camera sits at ``mount_xyz`` in the ego frame (origin at the ego box
centre on the ground, x forward, y left, z up) looking along ``yaw_deg``
(counter-clockwise from ego forward) with a horizontal optical axis (no
pitch or roll). Pixel (v, u), row 0 at the top and column 0 at the left of
the image, looks along ``(1, -(u + 0.5 - W/2) / f, (H/2 - v - 0.5) / f)`` in
the camera frame (x forward, y left, z up), ``f = (W/2) / tan(hfov/2)``.
Columns share an azimuth, so each camera is one polar buffer (its columns)
plus the analytic elevation solve per pixel (``raycast``).

``depth`` is the z-buffer depth ALONG THE OPTICAL AXIS (the hit point's
forward coordinate in the camera frame, as a CARLA depth camera), m;
``max_range`` where a pixel sees nothing (sky) or only beyond ``max_range``
(3-D distance). ``semantic`` holds the ``raycast`` hit codes (0 sky / none,
1 ground, 2 static obstacle, 3 + ``types.Category``).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax import geometry
from drivee2e_jax.observe import raycast

Array = jnp.ndarray


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """One camera (reduced resolution).

    Attributes:
      name: str.  mount_xyz: ego-frame position, m.  yaw_deg: heading in the
      ego frame, deg.  hfov_deg: horizontal field of view (< 180), deg.
      width, height: pixels.
    """

    name: str
    mount_xyz: tuple[float, float, float]
    yaw_deg: float
    hfov_deg: float = 70.0
    width: int = 64
    height: int = 36

    def __post_init__(self):
        if not 0 < self.hfov_deg < 180 or self.width < 1 or self.height < 1 or self.mount_xyz[2] <= 0:
            raise ValueError(f"CameraConfig {self.name}: need 0 < hfov_deg < 180, pixels >= 1, mount z > 0")

    @property
    def focal(self) -> float:
        """Focal length, pixels."""
        return 0.5 * self.width / math.tan(math.radians(self.hfov_deg) / 2)

    @property
    def column_azimuths(self) -> np.ndarray:
        """(W,) azimuth of each column in the camera frame, rad (descending)."""
        x = (np.arange(self.width) + 0.5 - self.width / 2) / self.focal
        return np.arctan(-x)

    @property
    def pixel_tan_elevation(self) -> np.ndarray:
        """(H, W) tangent of each pixel ray's elevation."""
        x = (np.arange(self.width) + 0.5 - self.width / 2) / self.focal
        z = (self.height / 2 - np.arange(self.height) - 0.5) / self.focal
        return z[:, None] / np.sqrt(1.0 + x[None, :] ** 2)


#: nuScenes-like surround rig (positions approximate a mid-size car; back 110 deg).
SURROUND = (
    CameraConfig("front", (1.7, 0.0, 1.5), 0.0, 70.0),
    CameraConfig("front_left", (1.5, 0.5, 1.5), 55.0, 70.0),
    CameraConfig("front_right", (1.5, -0.5, 1.5), -55.0, 70.0),
    CameraConfig("back", (-1.0, 0.0, 1.5), 180.0, 110.0),
    CameraConfig("back_left", (-0.3, 0.5, 1.5), 110.0, 70.0),
    CameraConfig("back_right", (-0.3, -0.5, 1.5), -110.0, 70.0),
)


@dataclasses.dataclass(frozen=True)
class CameraRigConfig:
    """All cameras (same width and height, so the images stack).

    Attributes:
      cameras: tuple of CameraConfig.  max_range: m.  buffer: raycast.BufferConfig.
    """

    cameras: tuple[CameraConfig, ...] = SURROUND
    max_range: float = 100.0
    buffer: raycast.BufferConfig = raycast.BufferConfig()

    def __post_init__(self):
        if not self.cameras or len({(c.width, c.height) for c in self.cameras}) != 1:
            raise ValueError("CameraRigConfig.cameras: need at least one camera, all of one width and height")
        if self.max_range <= 0:
            raise ValueError(f"CameraRigConfig.max_range must be > 0 m, got {self.max_range}")


@struct.dataclass
class CameraImages:
    """Images of every camera of the rig (N cameras).

    Attributes:
      depth:    (N, H, W) float32 depth along the optical axis, m.
      semantic: (N, H, W) int32 hit code.
      agent:    (N, H, W) int32 row of the agent seen, -1 otherwise.
    """

    depth: Array
    semantic: Array
    agent: Array


def _rig_arrays(cfg: CameraRigConfig):
    """Stacked per-camera constants: mount (N, 3), yaw (N,), ascending column
    azimuths (N, W), pixel tan elevation (N, H, W) in image order, and the
    smallest mean column spacing (sizes the buffer windows for all)."""
    cams = cfg.cameras
    az = np.stack([c.column_azimuths[::-1] for c in cams]).astype(np.float32)
    spacing = float(min((a[-1] - a[0]) / max(len(a) - 1, 1) for a in az))
    return (np.array([c.mount_xyz for c in cams], np.float32), np.radians([c.yaw_deg for c in cams]).astype(np.float32),
            az, np.stack([c.pixel_tan_elevation for c in cams]).astype(np.float32), spacing)


def camera_beams(scene: raycast.RayScene, ego_xy: Array, ego_yaw: Array, cfg: CameraRigConfig = CameraRigConfig()):
    """(PolarBuffer (N, W, D), BeamHits (N, H, W)) of every camera, columns in
    image order (left to right). The cameras share one vmapped program."""
    mount, yaw, az, tan, spacing = _rig_arrays(cfg)

    def one(mount_xyz, cam_yaw, azimuths, tan_elev):
        origin = geometry.from_frame(mount_xyz[:2], ego_xy, ego_yaw)
        buf = raycast.polar_buffer(scene, origin, ego_yaw + cam_yaw, azimuths, cfg.max_range, cfg.buffer,
                                   full_circle=False, spacing=spacing)
        buf = jax.tree_util.tree_map(lambda x: x[::-1], buf)  # back to image column order
        return buf, raycast.solve_elevation(buf, tan_elev, mount_xyz[2], cfg.max_range)

    return jax.vmap(one)(jnp.asarray(mount), jnp.asarray(yaw), jnp.asarray(az), jnp.asarray(tan))


def camera_images(scene: raycast.RayScene, ego_xy: Array, ego_yaw: Array,
                  cfg: CameraRigConfig = CameraRigConfig()) -> CameraImages:
    """Render every camera of the rig for an ego at ``ego_xy (2,)``, ``ego_yaw``."""
    _, hits = camera_beams(scene, ego_xy, ego_yaw, cfg)
    cos_col = jnp.asarray(np.stack([np.cos(c.column_azimuths) for c in cfg.cameras]), jnp.float32)[:, None, :]
    found = jnp.isfinite(hits.range)
    depth = jnp.where(found, hits.range * cos_col, cfg.max_range)
    return CameraImages(depth=depth.astype(jnp.float32), semantic=hits.code, agent=hits.agent)
