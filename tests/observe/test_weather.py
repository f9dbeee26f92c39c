"""Weather degradation: clear is the identity, fog drops far and random beams."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax.observe import lidar, weather
from tests.helpers.ray_oracle import jax_scene


def test_clear_is_identity_and_fog_cuts_range():
    sc = dict(xy=np.array([[0, 0], [60, 0], [10, 5]], np.float32), yaw=np.zeros(3, np.float32),
              size=np.array([[4.5, 1.9, 1.6], [4, 2, 1.5], [4, 2, 1.5]], np.float32),
              category=np.zeros(3, np.int32), polys=[], heights=np.zeros(0, np.float32))
    cfg = lidar.LidarConfig(channels=16, azimuth_bins=90)
    scan = jax.jit(lidar.lidar_scan, static_argnums=3)(jax_scene(sc), jnp.zeros(2), jnp.zeros(()), cfg)
    key = jax.random.PRNGKey(0)
    clear = weather.degrade_lidar(scan, key, weather.weather_code("clear"), cfg.max_range)
    for a, b in zip(jax.tree_util.tree_leaves(clear), jax.tree_util.tree_leaves(scan)):
        np.testing.assert_array_equal(a, b)
    fog = weather.degrade_lidar(scan, key, weather.weather_code("fog"), cfg.max_range)
    reach = 0.4 * cfg.max_range
    assert (np.asarray(fog.hit_agent) != 1).all()  # the car at 58 m is beyond the fog's 34 m
    assert ((np.asarray(fog.range) <= reach) | (np.asarray(fog.hit_class) == 0)).all()
    near = np.asarray(scan.valid) & (np.asarray(scan.range).reshape(-1) <= reach)
    kept = np.asarray(fog.valid)[near].mean()
    assert 0.8 < kept < 0.97  # ~10 % random dropout
