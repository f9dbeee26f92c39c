"""The optional sensors in the rollout: which are on, their assets, one call per step.

``SensorConfig`` (in ``SimConfig.sensors``) switches the BEV raster
(``observe.bev``) and the LiDAR (``observe.lidar``) on and sizes them; both
are off by default, and under ``jit`` a sensor that is off costs nothing. A
policy declares what it needs with ``required_sensors = ("bev", "lidar")``
(``SensorConfig.for_policy`` turns that into a config; ``evaluate`` does it).

What lands in ``Observation``:

* ``bev``: (H, W) int32, the hard-mode BEV **bit-packed**: bit i of a pixel
  is channel ``config.bev.channels[i]`` (``observe.bev.unpack_bits(obs.bev, C)``
  gives the (H, W, C) float image). Packed because the observation rides in
  the rollout carry: 800 scenarios x 128 x 128 x 14 float channels would be
  0.7 GB per step, the packed words are 52 MB.
* ``lidar``: (channels, azimuth_bins) float32 range image, m (``max_range``
  where a beam has no return); azimuth 0 = ego forward, counter-clockwise.

The BEV's static layers come from ``SensorAssets.raster`` (every map of the
suite rasterised once on the host, ``observe.raster.rasterize_maps``) and
the scenario's row in it, ``map_index``: the table is shared by the whole
batch (broadcast under ``vmap``), never copied per scenario.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax.observe import bev as bev_mod
from drivee2e_jax.observe import lidar as lidar_mod
from drivee2e_jax.observe import raycast
from drivee2e_jax.observe.raster import RasterTable, rasterize_maps

#: Sensor names a policy may list in ``required_sensors``.
SENSORS = ("bev", "lidar")


@dataclasses.dataclass(frozen=True)
class SensorConfig:
    """Which sensors run (static under jit); ``None`` = off.

    Attributes:
      bev: ``observe.bev.BevConfig`` (hard mode; <= 31 channels) or None.
      lidar: ``observe.lidar.LidarConfig`` or None.
      scene: ``observe.raycast.SceneConfig``: how many nearest agents /
        obstacles the ray casts consider, within what radius.
      raster_resolution: m per pixel of the pre-rasterised static map layers.
    """

    bev: bev_mod.BevConfig | None = None
    lidar: lidar_mod.LidarConfig | None = None
    scene: raycast.SceneConfig = raycast.SceneConfig()
    raster_resolution: float = 0.25

    def __post_init__(self):
        if self.bev is not None and (self.bev.soft or len(self.bev.channels) > 31):
            raise ValueError("SensorConfig.bev: the rollout carries the bit-packed BEV; needs soft=False and "
                             f"<= 31 channels, got soft={self.bev.soft}, {len(self.bev.channels)} channels")

    @property
    def enabled(self) -> tuple[str, ...]:
        return tuple(n for n in SENSORS if getattr(self, n) is not None)

    @classmethod
    def for_policy(cls, required: Sequence[str], base: SensorConfig | None = None) -> SensorConfig:
        """``base`` with every sensor in ``required`` on (default sizes) and
        every other one off. Raises ValueError naming an unknown sensor."""
        base = base or cls()
        bad = [s for s in required if s not in SENSORS]
        if bad:
            raise ValueError(f"required_sensors: unknown {bad[0]!r} (expected some of {', '.join(SENSORS)})")
        return dataclasses.replace(
            base,
            bev=(base.bev or bev_mod.BevConfig()) if "bev" in required else None,
            lidar=(base.lidar or lidar_mod.LidarConfig()) if "lidar" in required else None,
        )


@struct.dataclass
class SensorAssets:
    """Host-built inputs of the sensors, for one scenario.

    Attributes:
      raster: RasterTable of every map of the batch (shared, broadcast under vmap).
      map_index: () int32 this scenario's row in ``raster`` ((B,) when batched).
    """

    raster: RasterTable
    map_index: jnp.ndarray


def build_assets(packed, config: SensorConfig, maps) -> SensorAssets | None:
    """The assets of a packed batch (``None`` when no sensor needs any).

    Args:
      packed: a ``scenario.PackedBatch`` (its meta names each row's map).
      config: SensorConfig.
      maps: {map_id: MapRecord} of the suite (``suite.records.maps``).
    """
    if config.bev is None:
        return None

    used = sorted({str(m) for m in packed.meta.map_id})
    table = rasterize_maps({k: maps[k] for k in used}, resolution=config.raster_resolution)
    return SensorAssets(raster=table, map_index=np.asarray(table.index_of(packed.meta.map_id), np.int32))


def assets_axes(assets: SensorAssets | None):
    """``vmap`` in_axes of batched assets: the table broadcast, the index per scenario."""
    if assets is None:
        return None
    return SensorAssets(raster=None, map_index=0)


def render(config: SensorConfig, *, ego, ego_lw, agents, size, category, ego_row, obstacles, obstacle_height,
           stop_state, route_xy, route_valid, assets: SensorAssets | None, route_index=None) -> dict:
    """The enabled sensors of one scenario at one step.

    Args:
      ego: ``types.EgoState``.  ego_lw: (2,) m.
      agents: ``replay.AgentStates`` (A,) at this instant, ego row masked.
      size: (A, 3) m.  category: (A,) int32.  ego_row: () int32 the ego's own row.
      obstacles: ``types.Polylines`` (O, V) footprints.  obstacle_height: (O,) m.
      stop_state: (S,) int32 ``SignalState`` per stop line.
      route_xy: (R, 2) m; route_valid: (R,) bool.
      assets: ``SensorAssets`` (required when the BEV is on).
      route_index: () int32 the ego's progress point on the route: the BEV
        draws only ``BevConfig.route_window`` around it (None: the whole route).

    Returns: {"bev": (H, W) int32, "lidar": (C, Z) float32} for the enabled ones.
    """
    out = {}
    if config.bev is not None:
        if assets is None:
            raise ValueError("SensorConfig.bev is on but no SensorAssets were given (observe.sensors.build_assets)")
        if route_index is not None:
            route_xy, route_valid = bev_mod.route_window(route_xy, route_valid, route_index, config.bev)
        out["bev"] = bev_mod.render_bev_packed(
            ego_xy=ego.xy, ego_yaw=ego.yaw, ego_lw=ego_lw, agents_xy=agents.xy, agents_yaw=agents.yaw,
            agents_size=size, agents_category=category, agents_valid=agents.valid, stop_state=stop_state,
            route_xy=route_xy, route_valid=route_valid, table=assets.raster, map_index=assets.map_index,
            cfg=config.bev,
        )
    if config.lidar is not None:
        scene = raycast.select_scene(ego.xy, agents, size, category, obstacles, obstacle_height, config.scene,
                                     exclude=ego_row)
        out["lidar"] = lidar_mod.lidar_scan(scene, ego.xy, ego.yaw, config.lidar).range
    return out
