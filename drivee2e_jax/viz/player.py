"""The self-contained HTML episode player (host side).

``write_player(traces, out_path, title=...)`` turns episode traces
(``drivee2e_jax.eval.traces.trace_episodes``) into ONE html file: the
template ``player.html`` (vanilla JS + canvas, no network) with the episodes
embedded as JSON in a ``<script type="application/json">`` tag. The embedded
document is::

    {"meta":     {"categories": [...], "signal_states": [...], "markings": [...],
                  "hit_classes": [...]},          # enum names by value
     "maps":     {map_id: {drivable, obstacles, crosswalks, lanes: [flat...],
                           boundaries: [[marking, flat]], stop_lines: [[x0,y0,x1,y1]]}},
     "episodes": [episode, ...]}                  # see viz/payload.py

Maps are stored once per map id, however many episodes drive on them.
"""

from __future__ import annotations

import html
import json
from collections.abc import Iterable
from importlib import resources
from pathlib import Path

from drivee2e_jax.files import atomic_write_text
from drivee2e_jax.viz import payload

TEMPLATE = "player.html"


def load_template() -> str:
    """The player's HTML template (package data of ``drivee2e_jax.viz``)."""
    return resources.files("drivee2e_jax.viz").joinpath(TEMPLATE).read_text(encoding="utf-8")


def embed_json(obj) -> str:
    """``obj`` as compact JSON safe inside a ``<script>`` element: every ``<``
    is escaped, so no ``</script>`` or ``<!--`` can end the element early."""
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")


def render_player(document: dict, *, title: str) -> str:
    """The player page for an already built document (see the module docstring)."""
    page = load_template().replace("__TITLE__", html.escape(title))
    head, sep, tail = page.partition("__DATA__")
    if not sep:
        raise RuntimeError(f"{TEMPLATE}: has no __DATA__ placeholder")
    return head + embed_json(document) + tail


def build_document(traces: Iterable, **payload_kw) -> dict:
    """Episode traces -> the embedded document (meta, shared maps, episodes).

    ``payload_kw`` go to ``payload.episode_payload`` (sensor subsampling)."""

    maps: dict[str, dict] = {}
    episodes = []
    for tr in traces:
        ep, map_id, map_doc = payload.episode_payload(tr, **payload_kw)
        maps.setdefault(map_id, map_doc)
        episodes.append(ep)
    return {"meta": payload.enum_meta(), "maps": maps, "episodes": episodes}


def write_player(traces: Iterable, out_path: str | Path, *, title: str = "drivee2e episode player",
                 **payload_kw) -> Path:
    """Write the player for ``traces`` to ``out_path`` atomically; returns the path."""
    out = Path(out_path)
    atomic_write_text(out, render_player(build_document(traces, **payload_kw), title=title))
    return out
