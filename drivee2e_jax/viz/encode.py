"""Compact, JSON-ready encodings of host arrays for the HTML episode player.

Host side only (numpy + Pillow). The player embeds everything in one HTML
file, so the encodings trade a little precision for size:

* coordinates rounded to 1 cm (``round_list``), invalid samples as ``null``;
* polylines / polygons as flat ``[x0, y0, x1, y1, ...]`` lists;
* the BEV as one palette PNG per episode (``bev_sheet_uri``: the kept frames
  stacked top to bottom, pixel = ``bev_index``), its binary channels composited in fixed colours
  (later channels paint over earlier ones; the colours are
  ``observe.palette``'s, shared with the MCAP export);
* LiDAR points as base64 of little-endian int16 ego-frame x, y (``LIDAR_SCALE``
  metres per unit) plus base64 uint8 hit classes, at most ``max_points`` a frame.
"""

from __future__ import annotations

import base64
import io

import numpy as np
from PIL import Image

# The BEV palette and encoder are shared with the MCAP export (``observe.palette``).
from drivee2e_jax.observe.palette import BEV_COLORS, channel_color, composite_bev
from drivee2e_jax.observe.png import png_bytes

__all__ = ["BEV_COLORS", "LIDAR_SCALE", "bev_index", "bev_index_from_bits", "bev_palette", "bev_sheet_uri",
           "channel_color", "composite_bev", "encode_lidar_points", "flat_points", "png_data_uri", "round_list"]

#: Metres per int16 unit of an encoded LiDAR point (+-327 m range at 1 cm).
LIDAR_SCALE = 0.01


def round_list(a, decimals: int = 2, valid=None) -> list:
    """``a`` rounded to a (nested) list; entries where ``valid`` is False (or
    that are not finite) become ``None``. ``valid`` has ``a``'s leading shape."""
    a = np.asarray(a, dtype=np.float64)
    ok = np.isfinite(a)
    if valid is not None:
        v = np.asarray(valid, bool)
        ok &= v.reshape(v.shape + (1,) * (a.ndim - v.ndim))
    r = np.round(a, decimals)
    if decimals <= 0:
        r = r.astype(np.int64)
    out = r.astype(object)
    out[~ok] = None
    return out.tolist()


def flat_points(xy, point_valid=None, decimals: int = 2) -> list[float]:
    """(N, 2) points (only the valid ones) -> flat ``[x0, y0, x1, y1, ...]``."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    keep = np.isfinite(xy).all(axis=1)
    if point_valid is not None:
        keep &= np.asarray(point_valid, bool).reshape(-1)
    return np.round(xy[keep], decimals).reshape(-1).tolist()


def png_data_uri(rgb: np.ndarray) -> str:
    """(H, W, 3) uint8 -> ``data:image/png;base64,...``."""

    return "data:image/png;base64," + base64.b64encode(png_bytes(rgb)).decode("ascii")


def bev_palette(channels) -> np.ndarray:
    """(C + 1, 3) uint8: entry 0 the empty pixel, entry i + 1 a pixel whose
    last lit channel is ``channels[i]``: ``composite_bev``'s colours exactly
    (it is evaluated on one pixel per channel)."""
    c = len(channels)
    one_hot = np.concatenate([np.zeros((1, c)), np.eye(c)])[None]  # (1, C + 1, C)
    return composite_bev(one_hot, list(channels))[0]


def bev_index(planes) -> np.ndarray:
    """C arrays (F, H, W) bool, one per channel -> (F, H, W) uint8 palette
    index (``bev_palette``): 1 + the last channel lit, 0 where none is."""
    if len(planes) > 255:
        raise ValueError(f"BEV: at most 255 channels fit a palette PNG, got {len(planes)}")
    index = np.zeros(np.shape(planes[0]), np.uint8)
    for i, plane in enumerate(planes):
        index[np.asarray(plane, bool)] = i + 1
    return index


def bev_index_from_bits(bits, num: int) -> np.ndarray:
    """Bit-packed frames ``bits (F, H, W)`` int (bit i = channel i, ``observe.bev``)
    -> the (F, H, W) uint8 ``bev_index`` of their first ``num`` channels:
    1 + the highest bit set (the last channel lit), in one pass (``frexp``'s
    exponent of a positive integer is its highest bit + 1)."""
    if num > 255:
        raise ValueError(f"BEV: at most 255 channels fit a palette PNG, got {num}")
    masked = np.asarray(bits).astype(np.int64) & ((1 << num) - 1)
    exact = np.float32 if num <= 24 else np.float64  # integers below 2**24 are exact in float32
    return np.frexp(masked.astype(exact))[1].astype(np.uint8)


def bev_sheet_uri(index, channels) -> str:
    """(F, H, W) uint8 ``bev_index`` frames -> ONE palette PNG data URI, the
    frames stacked top to bottom: an (F * H, W) picture whose pixels are
    ``composite_bev`` of each frame (palette ``bev_palette(channels)``).
    zlib level 1: these pictures are mostly runs, and level 6 is ~3x slower
    for a few % of size."""
    index = np.asarray(index, np.uint8)
    f, h, w = index.shape
    img = Image.fromarray(index.reshape(f * h, w), "P")
    img.putpalette(bev_palette(channels).reshape(-1).tolist())
    buf = io.BytesIO()
    img.save(buf, format="PNG", compress_level=1)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def encode_lidar_points(xy, hit_class, max_points: int, rng: np.random.Generator) -> dict:
    """One frame of ego-frame points (P, 2) m with (P,) int hit classes -> the
    player's ``{"xy": base64 int16, "c": base64 uint8}``; a uniform random
    subset of at most ``max_points`` points is kept."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(hit_class).reshape(-1)
    keep = np.flatnonzero(np.isfinite(xy).all(axis=1))
    if keep.size > max_points:
        keep = np.sort(rng.choice(keep, size=max_points, replace=False))
    q = np.clip(np.round(xy[keep] / LIDAR_SCALE), -32768, 32767).astype("<i2")
    return {"xy": base64.b64encode(q.tobytes()).decode("ascii"),
            "c": base64.b64encode(np.clip(c[keep], 0, 255).astype(np.uint8).tobytes()).decode("ascii")}
