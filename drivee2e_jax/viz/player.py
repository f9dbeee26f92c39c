"""The HTML episode player (host side): an index page plus one small file per episode.

``PlayerWriter(out_html)`` takes episode traces one at a time (``add``; a
trace can be dropped as soon as it is added, so a run of any size streams
through in bounded memory) and ``close()`` writes the page::

    player.html                     the player with the INDEX embedded (no episode data)
    player_files/episodes/e00000.js one per episode:  drivee2e_data("episode", "e00000", {...});
    player_files/maps/m0.js         one per map id:   drivee2e_data("map", "m0", {...});

The page loads an episode when it is opened by adding a ``<script src>`` for
its file: browsers refuse ``fetch()`` of ``file://`` URLs, but load scripts
from beside the page, so the folder works when the page is opened directly
(no server). Each file calls the page's ``drivee2e_data(kind, key, record)``.
``single_file=True`` embeds every episode and map in the page instead
(``write_player``; fine for a few episodes).

The page is the template ``player.html`` (vanilla JS + canvas, no network);
its embedded document (the ``__DATA__`` placeholder)::

    {"meta":      payload.enum_meta(),
     "files":     "player_files/" (relative to the page) or null (single file),
     "index":     [payload.index_entry(...)],      # every episode, in the order added
     "map_files": {map_id: file key},
     "episodes":  {key: episode record} and "maps": {key: map record}: single file only}

Episode records: ``viz/payload.py``. Maps are stored once per map id,
however many episodes drive on them.
"""

from __future__ import annotations

import html
import json
import shutil
from collections.abc import Iterable
from importlib import resources
from pathlib import Path

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import ForeignFiles, OwnFolder, atomic_write_text, check_own_file, check_own_folder
from drivee2e_jax.viz import payload

TEMPLATE = "player.html"
#: What the episode and map files call (defined by player.html).
CALLBACK = "drivee2e_data"
#: In the head of every page the player writes: how ``--force`` tells its own pages.
PAGE_SIGNATURE = b'<meta name="generator" content="drivee2e-jax episode player">'
#: What ``files_dir`` holds (the episode and map scripts ``PlayerWriter`` writes).
FILES_FOLDER = OwnFolder("episode player files", None, ("episodes/e*.js", "maps/m*.js"))


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


def files_dir(out_html: str | Path) -> Path:
    """The folder of per-episode files beside the page: ``<stem>_files``."""
    out = Path(out_html)
    return out.with_name(f"{out.stem}_files")


def check_overwrite(out_html: str | Path, *, single_file: bool) -> None:
    """Before ``--force`` rewrites a page: DriveE2EError (one line) when
    ``out_html`` exists but is not a page the player wrote (``PAGE_SIGNATURE``)
    or, unless ``single_file``, ``files_dir`` holds files it did not write
    (``FILES_FOLDER``): drivee2e never overwrites or deletes a user's files."""
    try:
        check_own_file(out_html, PAGE_SIGNATURE, "player page")
        if not single_file:
            check_own_folder(files_dir(out_html), FILES_FOLDER, redo=True)
    except ForeignFiles as e:
        raise DriveE2EError(str(e)) from None


def data_script(kind: str, key: str, record: dict) -> str:
    """The JavaScript of one episode / map file: a single ``drivee2e_data`` call."""
    return f"{CALLBACK}({embed_json(kind)},{embed_json(key)},{embed_json(record)});\n"


class PlayerWriter:
    """Streams traces into the player (module docstring).

    Args:
      out_html: the page to write; per-episode files go to ``files_dir(out_html)``
        (emptied of earlier episode / map files first).
      title: the page title.   single_file: embed everything in the page.
      payload_kw: ``payload.episode_payload`` options (sensors, periods, points).
    """

    def __init__(self, out_html: str | Path, *, title: str = "drivee2e episode player", single_file: bool = False,
                 **payload_kw):
        self.out = Path(out_html)
        self.title = title
        self.single = bool(single_file)
        self.payload_kw = payload_kw
        self.index: list[dict] = []
        self.map_files: dict[str, str] = {}
        self.inline: dict[str, dict] = {"episodes": {}, "maps": {}}
        self.bytes_written = 0
        self.dir = files_dir(self.out)
        if not self.single:
            for sub in ("episodes", "maps"):
                shutil.rmtree(self.dir / sub, ignore_errors=True)
                (self.dir / sub).mkdir(parents=True, exist_ok=True)

    def add(self, trace) -> dict:
        """Write one trace's episode file (and its map's, the first time);
        returns its index row."""
        ep, map_id, map_doc = payload.episode_payload(trace, **self.payload_kw)
        key = f"e{len(self.index):05d}"
        if map_id not in self.map_files:
            self.map_files[map_id] = mkey = f"m{len(self.map_files)}"
            self._put("map", mkey, map_doc)
        self._put("episode", key, ep)
        row = payload.index_entry(ep, key)
        self.index.append(row)
        return row

    def _put(self, kind: str, key: str, record: dict) -> None:
        if self.single:
            self.inline["episodes" if kind == "episode" else "maps"][key] = record
            return
        text = data_script(kind, key, record)
        path = self.dir / ("episodes" if kind == "episode" else "maps") / f"{key}.js"
        path.write_text(text, encoding="utf-8")
        self.bytes_written += len(text.encode("utf-8"))

    def document(self) -> dict:
        """The page's embedded document (module docstring)."""
        doc = {"meta": payload.enum_meta(), "files": None if self.single else f"{self.dir.name}/",
               "index": self.index, "map_files": self.map_files}
        if self.single:
            doc.update(self.inline)
        return doc

    def close(self) -> Path:
        """Write the page (atomically); returns its path."""
        page = render_player(self.document(), title=self.title)
        atomic_write_text(self.out, page)
        self.bytes_written += len(page.encode("utf-8"))
        return self.out


def write_player(traces: Iterable, out_path: str | Path, *, title: str = "drivee2e episode player",
                 single_file: bool = True, **payload_kw) -> Path:
    """Write the player for ``traces`` (one file by default; ``single_file=False``:
    the page plus its ``<stem>_files`` folder); returns the page's path."""
    writer = PlayerWriter(out_path, title=title, single_file=single_file, **payload_kw)
    for tr in traces:
        writer.add(tr)
    return writer.close()
