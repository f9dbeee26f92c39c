"""Small host-side file helpers shared by every layer (layer 0).

* ``atomic_write`` / ``atomic_write_text`` / ``atomic_write_json``: a file is
  written to a temporary sibling and ``os.replace``-d into place, so a reader
  (or a resumed run) sees the old or the new file, never half of one.
* ``cache_dir``: the root of drivee2e's on-disk caches (packed suites,
  visibility masks, JAX's compilation cache): ``$DRIVEE2E_CACHE``, default
  ``~/.cache/drivee2e``; ``off`` disables caching.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

#: Environment variable naming the cache root (``off`` disables caching).
CACHE_ENV = "DRIVEE2E_CACHE"


def cache_dir() -> Path | None:
    """The cache root (None when caching is disabled with ``off``)."""
    value = os.environ.get(CACHE_ENV, "").strip()
    if value.lower() in ("off", "0", "none", "false"):
        return None
    return Path(value or "~/.cache/drivee2e").expanduser()


def atomic_write(path: Path, write, binary: bool = False) -> None:
    """Call ``write(f)`` on a temp file next to ``path``, then ``os.replace`` it,
    so readers see the old or the new file, never half of one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with (os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8", newline="")) as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (see ``atomic_write``)."""
    atomic_write(path, lambda f: f.write(text))


def atomic_write_json(path: Path, obj: Any) -> None:
    atomic_write_text(path, json.dumps(obj, indent=1, sort_keys=False, allow_nan=False, default=json_default) + "\n")


def json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
