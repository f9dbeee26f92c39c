"""Visibility masks: agrees with the rendered first hits; occlusion."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings

from drivee2e_jax.observe import camera, lidar, visibility
from tests.helpers.ray_oracle import A_PAD, jax_scene, scenes

LCFG = lidar.LidarConfig(channels=8, azimuth_bins=90)
RIG = camera.CameraRigConfig(cameras=(
    camera.CameraConfig("front", (1.7, 0.0, 1.5), 0.0, 70.0, 16, 9),
    camera.CameraConfig("back", (-1.0, 0.0, 1.5), 180.0, 110.0, 16, 9)))


@jax.jit
def _all(s, xy, yaw):
    return (lidar.lidar_scan(s, xy, yaw, LCFG), visibility.lidar_visible(s, xy, yaw, A_PAD, LCFG),
            camera.camera_images(s, xy, yaw, RIG), visibility.camera_visible(s, xy, yaw, A_PAD, RIG))


@settings(max_examples=20, deadline=None)
@given(scenes())
def test_visible_iff_first_hit_somewhere(sc):
    scan, lvis, imgs, cvis = _all(jax_scene(sc), jnp.asarray(sc["xy"][0]), jnp.asarray(sc["yaw"][0]))
    rows = np.arange(A_PAD)
    np.testing.assert_array_equal(np.asarray(lvis), np.isin(rows, np.asarray(scan.hit_agent)))
    np.testing.assert_array_equal(np.asarray(cvis), np.isin(rows, np.asarray(imgs.agent)))
    assert not lvis[0] and not cvis[0]  # the ego itself


def _scene(*rows):
    rows = [(0, 0, 0, 4.5, 1.9, 1.6, 0)] + list(rows)
    a = np.array(rows, np.float32)
    return dict(xy=a[:, :2], yaw=a[:, 2], size=a[:, 3:6], category=a[:, 6].astype(np.int32), polys=[],
                heights=np.zeros(0, np.float32))


def test_box_behind_a_bus_is_invisible_and_tall_box_behind_a_car_is_visible():
    # Row 1: a bus at 10 m; row 2: a car hidden behind it; row 3: a car behind
    # a low box (row 4) but taller than the sight line over it; row 5: far left.
    sc = _scene((10, 0, 0, 12, 2.5, 3.5, 2), (25, 0, 0, 4, 2, 1.5, 0), (-25, 0, 0, 4, 6, 3.0, 1),
                (-10, 0, 0, 4, 8, 0.8, 0), (0, 30, 0, 4, 2, 1.5, 0))  # row 4 covers row 3 in 2-D
    _, lvis, _, cvis = _all(jax_scene(sc), jnp.zeros(2), jnp.zeros(()))
    np.testing.assert_array_equal(np.asarray(lvis)[:6], [False, True, False, True, True, True])
    np.testing.assert_array_equal(np.asarray(cvis)[:6], [False, True, False, True, True, False])  # no side camera
