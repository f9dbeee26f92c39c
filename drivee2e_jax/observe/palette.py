"""The one BEV palette and raster -> RGB encoder (host side, numpy).

Every picture of a BEV raster (the HTML player's BEV pane, the MCAP export's
``bev`` topic, ``eval.traces.to_jsonable``) is drawn here, so they all show the
same colours. Channels paint in the order given (a pixel takes the colour of
the last channel that is on, blended by its value in [0, 1]); history
channels (``vehicle@-1``, ``observe.bev.BevConfig.channel_names``) reuse
their base colour at half brightness; unknown names are grey.

It sits in ``observe`` (below both ``viz`` and ``io``, which are one layer
and independent of each other) so both can import it; ``observe.png``
writes the pictures as PNG (Pillow, kept out of the simulator's imports).
"""

from __future__ import annotations

import numpy as np

#: RGB (0-255) of each BEV channel name (``observe.bev.ALL_CHANNELS``).
BEV_COLORS = {
    "drivable": (52, 55, 61), "lane": (90, 96, 110), "solid": (232, 232, 232), "dashed": (170, 170, 170),
    "road_edge": (185, 190, 199), "crosswalk": (120, 120, 130), "obstacle": (120, 90, 60),
    "stop_line": (154, 160, 166), "stop_red": (255, 59, 48), "stop_yellow": (255, 204, 0),
    "stop_green": (52, 199, 89), "route": (50, 100, 190), "vehicle": (78, 154, 241),
    "pedestrian": (242, 101, 95), "cyclist": (92, 208, 108), "ego": (255, 159, 26),
}
#: Colour of a channel name not in ``BEV_COLORS``.
UNKNOWN_COLOR = (128, 128, 128)


def channel_color(name: str) -> tuple[float, float, float]:
    """RGB (0-255 floats) of channel ``name``; a history channel ``base@-f``
    is its base colour at half brightness."""
    base, _, back = name.partition("@")
    rgb = BEV_COLORS.get(base, UNKNOWN_COLOR)
    return tuple(float(c) * (0.5 if back else 1.0) for c in rgb)


def composite_bev(bev, channels) -> np.ndarray:
    """(H, W, C) channel stack (bool or [0, 1] floats) -> (H, W, 3) uint8 picture.

    Row 0 is farthest ahead, column 0 on the ego's left (``observe.bev``).
    Raises ValueError when the stack does not have one plane per channel name."""
    bev = np.asarray(bev, dtype=np.float32)
    if bev.ndim != 3 or bev.shape[-1] != len(channels):
        raise ValueError(f"BEV: expected (H, W, {len(channels)}) for channels {list(channels)}, got {bev.shape}")
    img = np.zeros(bev.shape[:2] + (3,), np.float32)
    for c, name in enumerate(channels):
        colour = np.array(channel_color(name), np.float32)
        a = np.clip(bev[..., c], 0.0, 1.0)[..., None]
        img = img * (1.0 - a) + colour * a
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


def bev_rgb(bev: dict, k: int) -> np.ndarray:
    """(H, W, 3) uint8 picture of instant ``k`` of a trace's BEV
    ``{channel: (T, H, W) bool}`` (``eval.traces.EpisodeTrace.bev``), its
    channels painted in the dict's order (``composite_bev``)."""
    names = list(bev)
    return composite_bev(np.stack([np.asarray(bev[c][k]) for c in names], axis=-1), names)

