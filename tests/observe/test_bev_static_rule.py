"""``bev.sample_static`` pinned to its nearest-neighbour rule.

The rule (float32, as documented in ``observe.bev``): BEV pixel (r, c) with
ego-frame centre (X, Y) reads raster pixel ``(floor(py), floor(px))`` with
``px = off_x + (cos X - sin Y) / res``, ``py = off_y + (sin X + cos Y) / res``,
``off = (ego_xy - origin) / res``, and 0 outside the map's true (H, W). Here
it is checked two ways on a table of random words (so that reading even one
neighbouring raster pixel anywhere shows):

* bit for bit against ``_frozen``, the sampler as of 2026-11-27 run through
  XLA the same way: a faster gather must keep every output pixel;
* against the rule written out in numpy float32 (cos / sin taken from XLA),
  equal except where a sample point lies within 1e-3 raster px of a pixel
  edge: XLA:CPU rounds the affine map differently from numpy at a few
  (~2e-5 of the) pixels, so an "equivalent" rewrite of the float expression
  is not bit-identical, and the frozen copy is the real pin.

Poses include exactly axis-aligned and near-axis-aligned headings, ego
positions on raster pixel corners and centres, and views past the map edges.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.observe.bev import BevConfig, pixel_centres, sample_static
from drivee2e_jax.observe.raster import TILE, table_from_pixels
from drivee2e_jax.observe.xla_cpu import materialize

RES = 0.25


def _table(rng, maps=3, hm=401, wm=420):
    """(tiled RasterTable, its (M, Hm, Wm) row-major words) of random words."""
    words = rng.integers(1, 2**16, (maps, hm, wm)).astype(np.uint16)
    words[0, hm - 1] = 0  # the out-of-map sentinel row
    shape = np.array([[hm - 1, wm], [300, 350], [hm - 1, 200]], np.int32)[:maps]
    for k, (h, w) in enumerate(shape):
        words[k, h:], words[k, :, w:] = 0, 0
    origin = rng.uniform(-80, 80, (maps, 2)).astype(np.float32)
    table = table_from_pixels(words, origin, shape, RES, tuple(map(str, range(maps))))
    return table, table.pixels()


def _frozen(ego_xy, ego_yaw, table, map_index, cfg):
    """``sample_static`` as committed before 2026-11-27 (do not edit)."""
    centres = jnp.asarray(pixel_centres(cfg))
    c, s = materialize(jnp.stack([jnp.cos(ego_yaw), jnp.sin(ego_yaw)]))
    origin = table.origin[map_index]
    off = (ego_xy - origin) / table.resolution
    px = off[0] + (c * centres[..., 0] - s * centres[..., 1]) / table.resolution
    py = off[1] + (s * centres[..., 0] + c * centres[..., 1]) / table.resolution
    ix = jnp.floor(px).astype(jnp.int32)
    iy = jnp.floor(py).astype(jnp.int32)
    h, w = table.shape[map_index, 0], table.shape[map_index, 1]
    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    _, hm, wm = table.words.shape
    flat = jnp.where(inside, (map_index * hm + iy) * wm + ix, (hm - 1) * wm)
    flat = materialize(flat)
    return table.words.reshape(-1)[flat].astype(jnp.int32)


def test_tiled_table_holds_the_same_pixels():
    rng = np.random.default_rng(3)
    table, pixels = _table(rng, hm=37, wm=50)
    assert table.raster_shape == pixels.shape[1:] == (48, 64) and TILE == 16
    assert table.words.shape == (3, 3, 4, TILE, TILE)
    iy, ix = np.meshgrid(np.arange(48), np.arange(64), indexing="ij")
    for m in range(3):
        np.testing.assert_array_equal(table.words.reshape(-1)[table.flat_index(m, iy, ix)], pixels[m])
    np.testing.assert_array_equal(pixels[:, :37, :50] != 0, np.asarray(
        [(np.arange(37)[:, None] < h) & (np.arange(50) < w) for h, w in table.shape]))


def _reference(table, ego_xy, ego_yaw, map_index, cfg):
    f32 = np.float32
    cs = np.asarray(jax.jit(jax.vmap(lambda y: jnp.stack([jnp.cos(y), jnp.sin(y)])))(jnp.asarray(ego_yaw)))
    centres = pixel_centres(cfg)
    out = np.zeros((len(ego_yaw), cfg.height, cfg.width), np.int32)
    tie = np.zeros(out.shape, bool)
    for b in range(len(ego_yaw)):
        c, s = f32(cs[b, 0]), f32(cs[b, 1])
        m = int(map_index[b])
        off = (ego_xy[b].astype(f32) - table.origin[m]) / f32(RES)
        px = off[0] + (c * centres[..., 0] - s * centres[..., 1]) / f32(RES)
        py = off[1] + (s * centres[..., 0] + c * centres[..., 1]) / f32(RES)
        assert px.dtype == py.dtype == np.float32
        ix, iy = np.floor(px).astype(np.int64), np.floor(py).astype(np.int64)
        h, w = table.shape[m]
        inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        out[b][inside] = table.words[m, iy[inside], ix[inside]]
        tie[b] = (np.abs(px - np.round(px)) < 1e-3) | (np.abs(py - np.round(py)) < 1e-3)
    return out, tie


@pytest.mark.parametrize("size", [(128, 128), (64, 96)])
def test_sample_static_is_the_nearest_neighbour_rule_bit_for_bit(size):
    rng = np.random.default_rng(7)
    table, pixels = _table(rng)
    rowmajor = table.replace(words=pixels)
    cfg = BevConfig(height=size[0], width=size[1])
    n = 48
    axis = np.array([0.0, np.pi / 2, np.pi, -np.pi / 2, -np.pi, np.pi / 4, 3 * np.pi / 4])
    yaw = np.concatenate([axis, axis + 1e-7, axis - 3e-7, rng.uniform(-np.pi, np.pi, n - 3 * len(axis))])
    map_index = rng.integers(0, 3, n).astype(np.int32)
    # Ego positions on raster pixel corners and centres (exact floors), and
    # anywhere, some near or past the map edges (the sentinel).
    corner = table.origin[map_index] + RES * rng.integers(0, 300, (n, 2))
    ego = np.where(rng.random((n, 1)) < 0.3, corner, table.origin[map_index] + rng.uniform(-20, 120, (n, 2)))
    ego[::5] += 0.5 * RES
    ego, yaw = ego.astype(np.float32), yaw.astype(np.float32)
    args = (jnp.asarray(ego), jnp.asarray(yaw), jnp.asarray(map_index))
    def run(f, t):
        return np.asarray(jax.jit(jax.vmap(lambda e, y, m, tb: f(e, y, tb, m, cfg), in_axes=(0, 0, 0, None)))(
            *args, jax.device_put(t)))

    got, frozen = run(sample_static, table), run(_frozen, rowmajor)
    assert got.dtype == np.int32 and got.shape == (n, *size)
    np.testing.assert_array_equal(got, frozen)
    want, tie = _reference(rowmajor, ego, yaw, map_index, cfg)
    np.testing.assert_array_equal(np.where(tie, 0, got), np.where(tie, 0, want))
    assert tie.mean() < 0.15  # the checked part is most of the image (ties: the exact-corner poses)
    # Not vacuous: most pixels read the map, and some read outside it.
    assert (want != 0).mean() > 0.3 and (want == 0).sum() > 1000


def test_table_from_pixels_rejects_a_bad_word_image():
    ok = np.zeros((1, 32, 20), np.uint16)
    with pytest.raises(DriveE2EError, match="pixel \\(31, 0\\) of map 0 must be 0"):
        table_from_pixels(np.where(np.arange(32)[:, None] == 31, 5, ok).astype(np.uint16), [[0, 0]], [[31, 20]],
                          RES, ("m",))
    with pytest.raises(DriveE2EError, match="expected \\(M, H, W\\) uint16"):
        table_from_pixels(ok.astype(np.int32), [[0, 0]], [[31, 20]], RES, ("m",))
    assert table_from_pixels(ok[:, :31], [[0, 0]], [[30, 20]], RES, ("m",)).raster_shape == (32, 32)
