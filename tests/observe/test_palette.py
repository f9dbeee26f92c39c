"""The one BEV palette: the player and the MCAP export draw the same picture."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from drivee2e_jax.observe import palette
from drivee2e_jax.observe.bev import DEFAULT_CHANNELS, BevConfig
from drivee2e_jax.observe.png import png_bytes
from drivee2e_jax.viz import encode


def test_later_channels_paint_over_earlier_ones_in_exact_colours():
    stack = np.zeros((2, 3, 3), bool)
    stack[0, 0, 0] = True  # drivable only
    stack[0, 1, :2] = True  # drivable, then vehicle on top
    stack[1, 2, 2] = True  # unknown channel: grey
    img = palette.composite_bev(stack, ("drivable", "vehicle", "mystery"))
    assert tuple(img[0, 0]) == palette.BEV_COLORS["drivable"]
    assert tuple(img[0, 1]) == palette.BEV_COLORS["vehicle"]
    assert tuple(img[1, 2]) == palette.UNKNOWN_COLOR and tuple(img[1, 1]) == (0, 0, 0)
    with pytest.raises(ValueError, match="expected"):
        palette.composite_bev(stack, ("drivable",))


def test_history_channels_are_their_base_colour_dimmed():
    names = BevConfig(history_frames=1).channel_names
    assert "vehicle@-1" in names
    assert palette.channel_color("vehicle@-1") == tuple(0.5 * c for c in palette.BEV_COLORS["vehicle"])


def test_trace_pictures_and_player_pictures_are_the_same_encoder():
    rng = np.random.default_rng(0)
    bev = {c: rng.random((2, 5, 6)) > 0.7 for c in DEFAULT_CHANNELS}
    stack = np.stack([bev[c][1] for c in DEFAULT_CHANNELS], axis=-1)
    np.testing.assert_array_equal(palette.bev_rgb(bev, 1), encode.composite_bev(stack, DEFAULT_CHANNELS))
    assert encode.BEV_COLORS is palette.BEV_COLORS
    rgb = palette.bev_rgb(bev, 0)
    back = np.asarray(Image.open(io.BytesIO(png_bytes(rgb))).convert("RGB"))
    np.testing.assert_array_equal(back, rgb)
