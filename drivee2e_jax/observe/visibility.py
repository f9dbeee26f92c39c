"""Which agents the ego's sensors see unoccluded, per step.

An agent is visible to a sensor if it is the FIRST return of at least one of
its beams (LiDAR) or pixels (any camera of the rig). The basis of
occlusion-based agent filtering (drop agents never visible along a run).
"""

from __future__ import annotations

import jax.numpy as jnp

from drivee2e_jax.observe import camera, lidar, raycast

Array = jnp.ndarray

#: Default sensors (frozen configs, shared).
DEFAULT_LIDAR = lidar.LidarConfig()
DEFAULT_CAMERAS = camera.CameraRigConfig()


def seen_agents(buf: raycast.PolarBuffer, hits: raycast.BeamHits, num_agents: int) -> Array:
    """(A,) bool from a buffer (..., Z, D) and its beams (..., C, Z): agent rows
    that are the first hit of some beam. Reduces over the beams of each
    buffer slot first, so the scatter is over Z * D slots, not every beam."""
    depth = buf.range.shape[-1]
    slot_hit = jnp.stack([jnp.any(hits.layer == d, axis=-2) for d in range(depth)], axis=-1)  # (..., Z, D)
    rows = jnp.where(slot_hit & (buf.agent >= 0), buf.agent, num_agents).reshape(-1)
    return jnp.zeros((num_agents + 1,), bool).at[rows].set(True)[:num_agents]


def lidar_visible(scene: raycast.RayScene, ego_xy: Array, ego_yaw: Array, num_agents: int,
                  cfg: lidar.LidarConfig = DEFAULT_LIDAR) -> Array:
    """(A,) bool: agents that are the first hit of at least one LiDAR beam."""
    buf, hits = lidar.lidar_beams(scene, ego_xy, ego_yaw, cfg)
    return seen_agents(buf, hits, num_agents)


def camera_visible(scene: raycast.RayScene, ego_xy: Array, ego_yaw: Array, num_agents: int,
                   cfg: camera.CameraRigConfig = DEFAULT_CAMERAS) -> Array:
    """(A,) bool: agents seen by at least one pixel of any camera of the rig."""
    buf, hits = camera.camera_beams(scene, ego_xy, ego_yaw, cfg)
    return seen_agents(buf, hits, num_agents)
