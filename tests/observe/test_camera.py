"""Pinhole cameras vs the shapely + numpy oracle of the same pixel rays."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import assume, given, settings
from shapely.geometry import Point, Polygon

from drivee2e_jax import geometry as geo
from drivee2e_jax.observe import camera, raycast
from tests.helpers.ray_oracle import beam, clipped, faces, jax_scene, scenes, shapes

RIG = camera.CameraRigConfig(cameras=(camera.CameraConfig("front", (1.7, 0.0, 1.5), 0.0, 70.0, 16, 9),
                                      camera.CameraConfig("back", (-1.0, 0.2, 1.6), 180.0, 110.0, 16, 9)))
_render = jax.jit(lambda s, xy, yaw: camera.camera_images(s, xy, yaw, RIG))


@settings(max_examples=20, deadline=None)
@given(scenes())
def test_camera_depth_vs_oracle(sc):
    ego_xy, yaw = sc["xy"][0], float(sc["yaw"][0])
    out = _render(jax_scene(sc), jnp.asarray(ego_xy), jnp.asarray(yaw))
    objs = shapes(sc)
    checked = 0
    for n, cam in enumerate(RIG.cameras):
        origin = np.asarray(geo.from_frame(jnp.asarray(cam.mount_xyz[:2]), jnp.asarray(ego_xy), yaw), np.float64)
        if any(Polygon(p).buffer(1e-2).contains(Point(origin)) for p in sc["polys"]):
            continue
        az = cam.column_azimuths
        if clipped(sc, origin, (az[0] - az[-1]) / (cam.width - 1), RIG.buffer, need_spacing=np.min(-np.diff(az))):
            continue
        tans = cam.pixel_tan_elevation
        for u, az in enumerate(cam.column_azimuths):
            hits, clean = faces(origin, yaw + math.radians(cam.yaw_deg) + az, objs, RIG.max_range)
            if not clean:
                continue
            for v in range(cam.height):
                r, code, row, ok = beam(hits, float(tans[v, u]), cam.mount_xyz[2], RIG.max_range, RIG.buffer.depth)
                if not ok:
                    continue
                checked += 1
                want = r * math.cos(az) if math.isfinite(r) else RIG.max_range
                np.testing.assert_allclose(out.depth[n, v, u], want, atol=2e-3, err_msg=f"camera {n} pixel {v},{u}")
                assert int(out.semantic[n, v, u]) == code
                assert int(out.agent[n, v, u]) == row
    assume(checked > 0)


def test_box_straight_ahead_fills_the_centre_and_ground_below():
    sc = dict(xy=np.array([[0, 0], [20, 0]], np.float32), yaw=np.zeros(2, np.float32),
              size=np.array([[4.5, 1.9, 1.6], [4, 2, 1.5]], np.float32), category=np.array([0, 7], np.int32),
              polys=[], heights=np.zeros(0, np.float32))
    out = _render(jax_scene(sc), jnp.zeros(2), jnp.zeros(()))
    front = RIG.cameras[0]
    v, u = front.height // 2 + 1, front.width // 2  # just below the horizon, centre column
    # Depth along the optical axis to the car's rear face at x = 18 from a camera at x = 1.7.
    np.testing.assert_allclose(out.depth[0, v, u], 18.0 - 1.7, atol=1e-4)
    assert int(out.semantic[0, v, u]) == raycast.HIT_AGENT + 7 and int(out.agent[0, v, u]) == 1
    assert (np.asarray(out.semantic[0, -1]) == raycast.HIT_GROUND).all()  # bottom row sees the road
    assert (np.asarray(out.semantic[0, 0]) == raycast.HIT_NONE).all()  # top row sees the sky
    assert not (np.asarray(out.agent[1]) == 1).any()  # the back camera does not see it


def test_default_rig_shapes():
    sc = dict(xy=np.array([[0, 0], [20, 0]], np.float32), yaw=np.zeros(2, np.float32),
              size=np.array([[4.5, 1.9, 1.6], [4, 2, 1.5]], np.float32), category=np.array([0, 0], np.int32),
              polys=[], heights=np.zeros(0, np.float32))
    out = jax.jit(camera.camera_images)(jax_scene(sc), jnp.zeros(2), jnp.zeros(()))
    assert out.depth.shape == (6, 36, 64) and out.depth.dtype == jnp.float32
    assert out.semantic.shape == (6, 36, 64) and out.semantic.dtype == jnp.int32
    assert np.isfinite(np.asarray(out.depth)).all()


def test_rig_rejects_mixed_resolutions():
    with pytest.raises(ValueError):
        camera.CameraRigConfig(cameras=(camera.CameraConfig("a", (0, 0, 1.5), 0.0, 70.0, 16, 9),
                                        camera.CameraConfig("b", (0, 0, 1.5), 0.0, 70.0, 8, 9)))
