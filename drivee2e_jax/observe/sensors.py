"""The optional sensors in the rollout: which are on, their assets, one call per step.

``SensorConfig`` (in ``SimConfig.sensors``) switches the registered sensors
(``observe.registry``: the BEV raster ``observe.bev``, the LiDAR
``observe.lidar``, and any sensor registered since) on and sizes them; all
are off by default, and under ``jit`` a sensor that is off costs nothing. A
policy declares what it needs with ``required_sensors = ("bev", "lidar")``
(``SensorConfig.for_policy`` turns that into a config; ``evaluate`` does it).

``render(config, ctx)`` renders every enabled sensor from ONE
``SensorContext`` (``observe.sensor_api``) and ``to_observation`` puts the
outputs in the ``Observation``.

What lands in ``Observation``:

* ``bev``: (H, W) int32, the hard-mode BEV **bit-packed**: bit i of a pixel
  is channel ``config.bev.channels[i]`` (``observe.bev.unpack_bits(obs.bev, C)``
  gives the (H, W, C) float image). Packed because the observation rides in
  the rollout carry: 800 scenarios x 128 x 128 x 14 float channels would be
  0.7 GB per step, the packed words are 52 MB.
* ``lidar``: (channels, azimuth_bins) float32 range image, m (``max_range``
  where a beam has no return); azimuth 0 = ego forward, counter-clockwise.
* ``sensors``: {name: output} of every other enabled sensor (None when none is on).

The BEV's static layers come from ``SensorAssets.raster`` (every map of the
suite rasterised once on the host, ``observe.raster.rasterize_map``, each
placed in its map's local frame: the raster origin minus the packed
``meta.origin``, in float64) and the scenario's row in it, ``map_index``: the
table is shared by the whole batch (broadcast under ``vmap``), never copied
per scenario.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from drivee2e_jax.observe import bev as bev_mod
from drivee2e_jax.observe import lidar as lidar_mod
from drivee2e_jax.observe import raycast, registry
from drivee2e_jax.observe.raster import rasterize_map, stack_rasters
from drivee2e_jax.observe.sensor_api import SensorAssets, SensorContext

__all__ = ["SensorAssets", "SensorConfig", "SensorContext", "assets_axes", "build_assets", "render",
           "to_observation"]


@dataclasses.dataclass(frozen=True)
class SensorConfig:
    """Which sensors run (static under jit); ``None`` = off.

    Attributes:
      bev: ``observe.bev.BevConfig`` (hard mode; <= 31 channels) or None.
      lidar: ``observe.lidar.LidarConfig`` or None.
      scene: ``observe.raycast.SceneConfig``: how many nearest agents /
        obstacles the ray casts consider, within what radius.
      raster_resolution: m per pixel of the pre-rasterised static map layers.
      others: ``((name, config), ...)`` of the registered sensors without a
        field of their own (``registry.SLOTTED``), sorted by name; use
        ``with_sensor`` / ``get`` rather than this tuple.
    """

    bev: bev_mod.BevConfig | None = None
    lidar: lidar_mod.LidarConfig | None = None
    scene: raycast.SceneConfig = raycast.SceneConfig()
    raster_resolution: float = 0.25
    others: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self):
        if self.bev is not None and (self.bev.soft or len(self.bev.channels) > 31):
            raise ValueError("SensorConfig.bev: the rollout carries the bit-packed BEV; needs soft=False and "
                             f"<= 31 channels, got soft={self.bev.soft}, {len(self.bev.channels)} channels")
        others = tuple(sorted((str(n), c) for n, c in dict(self.others).items() if c is not None))
        for n, _ in others:
            if n in registry.SLOTTED:
                raise ValueError(f"SensorConfig.others: {n!r} has its own field (SensorConfig.{n})")
            registry.get(n)  # ValueError on an unknown sensor
        object.__setattr__(self, "others", others)

    def get(self, name: str) -> Any:
        """The config of sensor ``name``, None when it is off."""
        if name in registry.SLOTTED:
            return getattr(self, name)
        return dict(self.others).get(name)

    def with_sensor(self, name: str, config: Any) -> SensorConfig:
        """This config with sensor ``name`` set to ``config`` (None: off)."""
        if name in registry.SLOTTED:
            return dataclasses.replace(self, **{name: config})
        registry.get(name)
        return dataclasses.replace(self, others=(*((n, c) for n, c in self.others if n != name), (name, config)))

    @property
    def enabled(self) -> tuple[str, ...]:
        """Names of the sensors that are on, in registry order."""
        return tuple(n for n in registry.names() if self.get(n) is not None)

    @property
    def needs_raster(self) -> bool:
        """Whether an enabled sensor reads the map rasters (``build_assets``)."""
        return any(registry.get(n).needs_raster for n in self.enabled)

    @classmethod
    def for_policy(cls, required: Sequence[str], base: SensorConfig | None = None) -> SensorConfig:
        """``base`` with every sensor in ``required`` on (``base``'s config,
        else the sensor's ``default_config()``) and every other one off.
        Raises ValueError naming an unknown sensor."""
        base = base or cls()
        known = registry.names()
        bad = [s for s in required if s not in known]
        if bad:
            raise ValueError(f"required_sensors: unknown {bad[0]!r} (expected some of {', '.join(known)})")
        out = base
        for n in known:
            on = n in required
            out = out.with_sensor(n, (base.get(n) or registry.get(n).default_config()) if on else None)
        return out


def build_assets(packed, config: SensorConfig, maps) -> SensorAssets | None:
    """The assets of a packed batch (``None`` when no sensor needs any).

    Args:
      packed: a ``scenario.PackedBatch`` (its meta names each row's map).
      config: SensorConfig.
      maps: {map_id: MapRecord} of the suite (``suite.records.maps``).
    """
    if not config.needs_raster:
        return None

    used = sorted({str(m) for m in packed.meta.map_id})
    # The packed positions are local (world - meta.origin, one origin per map): shift each raster alike.
    origin = {str(m): np.asarray(o, np.float64) for m, o in zip(packed.meta.map_id, packed.meta.origin)}
    rasters = [rasterize_map(maps[k], resolution=config.raster_resolution) for k in used]
    table = stack_rasters([dataclasses.replace(r, origin=r.origin - origin[k]) for k, r in zip(used, rasters)])
    return SensorAssets(raster=table, map_index=np.asarray(table.index_of(packed.meta.map_id), np.int32))


def assets_axes(assets: SensorAssets | None):
    """``vmap`` in_axes of batched assets: the table broadcast, the index per scenario."""
    if assets is None:
        return None
    return SensorAssets(raster=None, map_index=0)


def render(config: SensorConfig, ctx: SensorContext) -> dict:
    """The enabled sensors of one scenario at one instant.

    Args:
      config: SensorConfig (static).
      ctx: ``SensorContext`` of the instant (its ``scene`` is replaced by
        ``config.scene``; each sensor gets ``ctx.for_sensor(name)``, its own key).

    Returns: {name: output} of the enabled sensors, e.g. {"bev": (H, W) int32,
    "lidar": (C, Z) float32} (``Sensor.render``; ``to_observation`` puts it
    in an ``Observation``).
    """
    ctx = ctx.replace(scene=config.scene)
    return {n: registry.get(n).render(ctx.for_sensor(n), config.get(n)) for n in config.enabled}


def to_observation(obs, out: dict):
    """``obs`` (``types.Observation``) with the ``render`` outputs ``out``:
    ``bev`` / ``lidar`` in their own slots, every other sensor in ``obs.sensors``."""
    slots = {n: v for n, v in out.items() if n in registry.SLOTTED}
    others = {n: v for n, v in out.items() if n not in registry.SLOTTED}
    if others:
        slots["sensors"] = others
    return obs.replace(**slots) if slots else obs
