"""Small host-side file helpers shared by every layer (layer 0).

* ``atomic_write`` / ``atomic_write_text`` / ``atomic_write_json``: a file is
  written to a temporary sibling and ``os.replace``-d into place, so a reader
  (or a resumed run) sees the old or the new file, never half of one.
* ``cache_dir``: the root of drivee2e's on-disk caches (packed suites,
  visibility masks, JAX's compilation cache): ``$DRIVEE2E_CACHE``, default
  ``~/.cache/drivee2e``; ``off`` disables caching.
* ``remove_stray_temp_files``: delete the temp files ``atomic_write`` leaves
  behind when its process is killed (SIGKILL) between create and replace;
  call it only while no other process writes the folder (``lock_folder``).
* ``lock_folder``: an exclusive, non-blocking ``fcntl.flock`` on
  ``<folder>/.lock`` for as long as one writer owns a folder; a second one
  gets ``FolderLocked`` naming the holder (pid, host, start time, command).
* ``sha256_file`` / ``sha256_tree``: content hashes (fingerprints).
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import json
import os
import shlex
import socket
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX (Windows): folders are not locked
    fcntl = None

#: Environment variable naming the cache root (``off`` disables caching).
CACHE_ENV = "DRIVEE2E_CACHE"
#: ``atomic_write``'s temp files: ``.<name>.<8 random characters>.tmp`` beside the target.
TEMP_SUFFIX = ".tmp"
#: The lock file ``lock_folder`` holds inside the folder.
LOCK_NAME = ".lock"


class FolderLocked(RuntimeError):
    """``lock_folder``: another holder has the folder; ``str`` is one line
    naming it. (``files`` is layer 0 beside ``errors``: callers turn it into
    their user-facing error, as ``eval.results.RunDir`` does.)"""


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
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=TEMP_SUFFIX, dir=path.parent)
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


def is_stray_temp_file(path: Path) -> bool:
    """True for a file named as ``atomic_write``'s temp files are
    (``.<name>.<random>.tmp``)."""
    name = Path(path).name
    return name.startswith(".") and name.endswith(TEMP_SUFFIX) and name.count(".") >= 3


def remove_stray_temp_files(folder: str | Path) -> list[Path]:
    """Delete every ``atomic_write`` temp file under ``folder`` (recursively):
    those a killed process left. Only safe while no other process writes
    there (hold ``lock_folder``). Returns the paths removed."""
    folder = Path(folder)
    removed = []
    for f in sorted(folder.rglob(f".*{TEMP_SUFFIX}")) if folder.is_dir() else ():
        if f.is_file() and is_stray_temp_file(f):
            f.unlink(missing_ok=True)
            removed.append(f)
    return removed


def holder_record(command: str | None = None) -> dict:
    """Who holds a lock: pid, host, start time (UTC, ISO 8601) and command line
    (default: this process's ``sys.argv``)."""
    return {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "command": command if command is not None else shlex.join(sys.argv),
    }


def describe_holder(text: str) -> str:
    """One-line description of a lock file's content (``holder_record`` JSON)."""
    try:
        h = json.loads(text)
        return f"pid {h['pid']} on {h['host']}, started {h['started']}: {h['command']}"
    except (ValueError, TypeError, KeyError):
        return "holder unknown (empty or unreadable lock file)"


@contextlib.contextmanager
def lock_folder(path: str | Path, *, hint: str = "wait for it to finish or use another folder",
                command: str | None = None) -> Iterator[Path]:
    """Own folder ``path`` (created if missing) exclusively while the block runs.

    An exclusive, non-blocking ``fcntl.flock`` on ``<path>/.lock``, which
    records the holder (``holder_record``). The kernel drops the lock when the
    holder exits, even on SIGKILL, so a stale lock file never blocks anyone.
    A second holder (another process, or another ``lock_folder`` of the same
    folder in this one) gets ``FolderLocked``: ``<path>: in use by another run
    (pid ..., host, start time: command); <hint>``. The lock file stays (its
    content is cleared on release); deleting the folder while holding it is
    allowed. No-op where ``fcntl`` does not exist (Windows).
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    if fcntl is None:  # pragma: no cover - not POSIX
        yield path
        return
    fd = _acquire(path / LOCK_NAME, hint)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(holder_record(command)) + "\n").encode(), 0)
        yield path
    finally:
        with contextlib.suppress(OSError):
            os.ftruncate(fd, 0)
        os.close(fd)  # releases the flock


def _acquire(lock: Path, hint: str) -> int:
    """An fd of ``lock`` holding its exclusive flock; ``FolderLocked`` naming the holder."""
    for _ in range(5):
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = describe_holder(os.pread(fd, 4096, 0).decode("utf-8", "replace"))
            os.close(fd)
            raise FolderLocked(f"{lock.parent}: in use by another run ({holder}); {hint}") from None
        try:  # the file we locked is still the one at `lock` (not unlinked by a holder that just left)
            if os.stat(lock).st_ino == os.fstat(fd).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)
    raise FolderLocked(f"{lock}: the lock file keeps disappearing; {hint}")


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes (read in 1 MiB chunks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def sha256_tree(path: str | Path) -> str:
    """Hex sha256 of a file, or of a folder: every file below it (symlinks
    followed, ``atomic_write`` temp files skipped) as its relative POSIX path
    and its ``sha256_file``, in sorted order. Moving or touching the folder
    keeps the hash; any byte, name, added or removed file changes it."""
    path = Path(path)
    if not path.is_dir():
        return sha256_file(path)
    h = hashlib.sha256()
    for f in sorted(p for p in path.rglob("*") if p.is_file() and not is_stray_temp_file(p)):
        h.update(f"{f.relative_to(path).as_posix()}\0{sha256_file(f)}\n".encode())
    return h.hexdigest()
