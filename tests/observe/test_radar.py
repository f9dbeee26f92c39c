"""Radar returns: ranges / azimuths vs shapely rays, radial velocity, padding."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax.observe import radar, raycast
from tests.helpers.ray_oracle import jax_scene

RIG = radar.RadarRigConfig(radars=(radar.RadarConfig("front", (3.0, 0.0, 0.5), 0.0, 90.0, 91),
                                   radar.RadarConfig("back_left", (-1.0, 0.8, 0.5), 150.0, 90.0, 91)),
                           max_returns=4)


def _scene(*rows):
    rows = [(0, 0, 0, 4.5, 1.9, 1.6, 0)] + list(rows)
    a = np.array(rows, np.float32)
    return dict(xy=a[:, :2], yaw=a[:, 2], size=a[:, 3:6], category=a[:, 6].astype(np.int32), polys=[],
                heights=np.zeros(0, np.float32))


def test_one_return_per_object_with_range_rate():
    sc = _scene((23, 0, 0, 4, 2, 1.5, 0), (43, 10, 0, 4, 2, 1.5, 1), (-40, 0, 0, 4, 2, 1.5, 0))
    vel = np.array([[10, 0], [5, 0], [0, 3], [0, 0]], np.float32)
    out = jax.jit(lambda s: radar.radar_returns(s, jnp.zeros(2), jnp.zeros(()), jnp.array([10.0, 0.0]), RIG))(
        jax_scene(sc, vel=vel))
    front_valid = np.asarray(out.valid[0])
    assert front_valid.sum() == 2  # two cars ahead, one return each
    assert list(np.asarray(out.agent[0][:2])) == [1, 2]  # nearest first
    # Car 1: rear face at x = 21, radar at x = 3 -> 18 m straight ahead.
    np.testing.assert_allclose(out.range[0, 0], 18.0, atol=1e-4)
    np.testing.assert_allclose(out.azimuth[0, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(out.radial_velocity[0, 0], 5.0 - 10.0, atol=1e-4)  # closing at 5 m/s
    # Car 2 seen at an angle: radial = (v_rel . direction) with v_rel = (-10, 3).
    az = float(out.azimuth[0, 1])
    np.testing.assert_allclose(out.radial_velocity[0, 1], -10 * math.cos(az) + 3 * math.sin(az), atol=1e-4)
    assert int(out.hit_class[0, 1]) == raycast.HIT_AGENT + 1
    assert not np.asarray(out.valid[0])[2:].any() and (np.asarray(out.agent[0])[2:] == -1).all()
    # The back-left radar (150 +- 45 deg) sees the car behind (at ~181 deg),
    # the front radar does not; a static car closes at the ego's speed.
    assert int(out.agent[1, 0]) == 3 and not (np.asarray(out.agent[0]) == 3).any()
    az = float(out.azimuth[1, 0])
    np.testing.assert_allclose(out.radial_velocity[1, 0], -10 * math.cos(az), atol=1e-3)


def test_default_five_radars_shapes():
    sc = _scene((23, 0, 0, 4, 2, 1.5, 0))
    out = jax.jit(radar.radar_returns)(jax_scene(sc), jnp.zeros(2), jnp.zeros(()), jnp.zeros(2))
    assert out.range.shape == (5, 32) and out.valid.dtype == jnp.bool_
    assert int(out.valid.sum()) >= 1
