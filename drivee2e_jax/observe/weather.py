"""Optional weather degradation of the LiDAR and radar (off by default).

Per weather code of ``scenario.records.WEATHERS`` ("clear", "cloudy", "rain",
"fog"): a beam / return is dropped with probability ``dropout`` and returns
beyond ``range_factor * max_range`` are lost. The numbers are ASSUMPTIONS of
the right order of magnitude, not calibrated values: published LiDAR studies
in fog / rain chambers report large range losses in dense fog and moderate
ones in rain, while 77 GHz radar is barely affected; we encode that ordering
(fog > rain > cloudy = clear for the LiDAR, radar an order milder). Seeded by
a PRNG key passed by the caller (split it per step).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from drivee2e_jax.observe import raycast
from drivee2e_jax.observe.lidar import LidarScan
from drivee2e_jax.observe.radar import RadarReturns
from drivee2e_jax.records import WEATHERS

Array = jnp.ndarray


@dataclasses.dataclass(frozen=True)
class Degradation:
    """Per weather code (index of ``WEATHERS``): dropout probability and the
    fraction of the nominal max range that survives, for LiDAR and radar."""

    lidar_dropout: tuple[float, ...] = (0.0, 0.0, 0.05, 0.10)
    lidar_range_factor: tuple[float, ...] = (1.0, 1.0, 0.8, 0.4)
    radar_dropout: tuple[float, ...] = (0.0, 0.0, 0.01, 0.01)
    radar_range_factor: tuple[float, ...] = (1.0, 1.0, 0.95, 0.95)

    def __post_init__(self):
        for name in ("lidar_dropout", "lidar_range_factor", "radar_dropout", "radar_range_factor"):
            vals = getattr(self, name)
            if len(vals) != len(WEATHERS) or not all(0.0 <= v <= 1.0 for v in vals):
                raise ValueError(f"Degradation.{name}: {len(WEATHERS)} values in [0, 1] expected, got {vals}")


def weather_code(name: str) -> int:
    """Index of a weather name in ``WEATHERS``."""
    return WEATHERS.index(name)


def degrade_lidar(scan: LidarScan, key: Array, weather: Array, max_range: float,
                  cfg: Degradation = Degradation()) -> LidarScan:
    """Drop beams at random and beyond the weather's reduced range.
    ``weather``: () int32 code; dropped beams become "no return"."""
    drop = jnp.asarray(cfg.lidar_dropout)[weather]
    reach = jnp.asarray(cfg.lidar_range_factor)[weather] * max_range
    keep = (jax.random.uniform(key, scan.range.shape) >= drop) & (scan.range <= reach)
    keep = keep & (scan.hit_class != raycast.HIT_NONE)
    flat = keep.reshape(-1)
    return LidarScan(range=jnp.where(keep, scan.range, max_range), hit_class=jnp.where(keep, scan.hit_class, 0),
                     hit_agent=jnp.where(keep, scan.hit_agent, -1),
                     points=jnp.where(flat[:, None], scan.points, 0.0), valid=scan.valid & flat)


def degrade_radar(ret: RadarReturns, key: Array, weather: Array, max_range: float,
                  cfg: Degradation = Degradation()) -> RadarReturns:
    """Drop radar returns at random and beyond the reduced range (no compaction:
    dropped entries stay in place with ``valid`` False)."""
    drop = jnp.asarray(cfg.radar_dropout)[weather]
    reach = jnp.asarray(cfg.radar_range_factor)[weather] * max_range
    keep = ret.valid & (jax.random.uniform(key, ret.range.shape) >= drop) & (ret.range <= reach)
    return ret.replace(valid=keep, agent=jnp.where(keep, ret.agent, -1),
                       hit_class=jnp.where(keep, ret.hit_class, raycast.HIT_NONE))
