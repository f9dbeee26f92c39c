"""PNG bytes of an RGB picture (host side, Pillow): the one encoder of the
player's image panes, the MCAP export's image topics and ``eval.traces.to_jsonable``."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image


def png_bytes(rgb: np.ndarray) -> bytes:
    """PNG file bytes of an (H, W, 3) uint8 image (lossless)."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb, dtype=np.uint8), "RGB").save(buf, format="PNG", optimize=True)
    return buf.getvalue()
