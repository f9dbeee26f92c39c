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
* ``check_own_folder`` / ``check_own_file``: may drivee2e write (and, with
  ``--force``, redo) an output folder or file? A folder is drivee2e's when it
  holds its marker file (``run.json``, ``sweep.json``, ``config.json``, ...)
  and, for a redo, only files of the command's known set (``OwnFolder``); a
  file when its first bytes carry drivee2e's signature. Anything else raises
  ``ForeignFiles`` naming the folder and the files drivee2e did not write:
  ``--force`` never deletes or overwrites a user's file.
* ``loads_json`` / ``read_json``: the one way drivee2e reads JSON a user can
  edit: a duplicate key in an object is an error (``DuplicateKeyError``)
  instead of the last value silently winning.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import hashlib
import json
import os
import shlex
import socket
import sys
import tempfile
from collections.abc import Iterator, Sequence
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Any

import numpy as np
import orjson

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


# -- outputs drivee2e owns -------------------------------------------------------
class ForeignFiles(RuntimeError):
    """``check_own_folder`` / ``check_own_file``: the output holds files
    drivee2e did not write; ``str`` is one line naming the folder (or file)
    and those files. (Layer 0 like ``FolderLocked``: callers raise it again as
    their user-facing error.)"""


@dataclasses.dataclass(frozen=True)
class OwnFolder:
    """What one kind of drivee2e output folder holds.

    Attributes:
      what: its name in messages ("results", "sweep", "training run", ...).
      marker: the file every such folder has (``run.json``, ...); None for a
        folder recognised by its files alone.
      files: the relative POSIX paths drivee2e writes there, as patterns:
        ``fnmatch`` per path segment (``*`` never crosses a ``/``); a last
        segment ``**`` matches everything below (``checkpoints/*/**``).
        ``LOCK_NAME`` and ``atomic_write`` temp files are always allowed.
    """

    what: str
    marker: str | None
    files: tuple[str, ...]

    def owns(self, rel: str) -> bool:
        """Whether the relative POSIX path ``rel`` is one drivee2e writes there."""
        return any(_path_matches(rel, p) for p in self.files)

    def nested(self, prefix: str) -> tuple[str, ...]:
        """``files`` as seen from a parent folder, under ``prefix`` (a pattern)."""
        return tuple(f"{prefix}/{p}" for p in self.files)


def _path_matches(rel: str, pattern: str) -> bool:
    parts, pats = rel.split("/"), pattern.split("/")
    if pats[-1] == "**":
        pats = pats[:-1]
        return len(parts) > len(pats) and all(fnmatchcase(a, b) for a, b in zip(parts, pats))
    return len(parts) == len(pats) and all(fnmatchcase(a, b) for a, b in zip(parts, pats))


def folder_files(folder: str | Path) -> list[str]:
    """Relative POSIX paths of every file below ``folder`` (symlinks listed,
    not followed), sorted; lock files and ``atomic_write`` temp files left
    out. [] for a missing folder."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    out = []
    for root, dirs, names in os.walk(folder):
        base = Path(root)
        links = [d for d in dirs if (base / d).is_symlink()]  # listed as entries, never entered
        for name in [*names, *links]:
            if name == LOCK_NAME or is_stray_temp_file(base / name):
                continue
            out.append((base / name).relative_to(folder).as_posix())
    return sorted(out)


def _listed(paths: Sequence[str], limit: int = 5) -> str:
    more = len(paths) - limit
    return ", ".join(paths[:limit]) + (f" and {more} more" if more > 0 else "")


def check_own_folder(folder: str | Path, kind: OwnFolder, *, redo: bool) -> None:
    """Raise ``ForeignFiles`` unless drivee2e may write to ``folder`` as a
    ``kind`` folder: it is missing or empty (lock / temp files and empty
    subfolders aside), or holds ``kind.marker``; with ``redo`` (``--force``,
    which deletes or overwrites the old outputs) also only files of
    ``kind.files``. The message is one line naming the folder and the files
    drivee2e did not write (the first few)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ForeignFiles(f"{folder}: exists and is not a folder; expected a new folder or a drivee2e {kind.what} "
                           "folder (choose another --out)")
    files = folder_files(folder)
    if not files:
        return
    if kind.marker is not None and kind.marker not in files:
        raise ForeignFiles(f"{folder}: not a drivee2e {kind.what} folder (no {kind.marker}; holds {_listed(files)}); "
                           "drivee2e never writes into, nor with --force deletes, a folder it did not make: "
                           "choose another --out or empty it")
    foreign = [f for f in files if not kind.owns(f)] if redo or kind.marker is None else []
    if foreign:
        raise ForeignFiles(f"{folder}: holds files drivee2e did not write ({_listed(foreign)}); --force redoes only "
                           f"the files of a drivee2e {kind.what} folder: move them away or choose another --out")


def check_own_file(path: str | Path, signature: bytes, what: str, *, head: int = 4096) -> None:
    """Raise ``ForeignFiles`` when ``path`` exists but is not a file drivee2e
    wrote: a folder, or a file whose first ``head`` bytes lack ``signature``
    (what drivee2e writes near the top of every ``what`` file). Call it
    before overwriting ``path`` (``--force``)."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        return
    if path.is_dir() or path.is_symlink():
        raise ForeignFiles(f"{path}: is a {'folder' if path.is_dir() else 'symbolic link'}, not a {what} drivee2e "
                           "wrote; --force overwrites only drivee2e's own files: choose another --out")
    with open(path, "rb") as f:
        start = f.read(head)
    if signature not in start:
        raise ForeignFiles(f"{path}: not a {what} drivee2e wrote; --force overwrites only drivee2e's own files: "
                           "move it away or choose another --out")


# -- JSON a user can edit ----------------------------------------------------------
class DuplicateKeyError(json.JSONDecodeError):
    """An object of the JSON text has the same key twice (``loads_json``).
    A ``json.JSONDecodeError`` (so a ``ValueError``) whose ``msg`` and
    ``str`` are ``duplicate key 'KEY'``; ``key`` is the key."""

    def __init__(self, key: str):
        ValueError.__init__(self, f"duplicate key {key!r}")
        self.key = key
        self.msg = str(self)
        self.doc, self.pos, self.lineno, self.colno = "", 0, 1, 1

    def __reduce__(self):
        return DuplicateKeyError, (self.key,)


def _unique_pairs(pairs: list[tuple[str, Any]]) -> dict:
    out = dict(pairs)
    if len(out) != len(pairs):
        seen = set()
        for k, _ in pairs:
            if k in seen:
                raise DuplicateKeyError(k)
            seen.add(k)
    return out


_CONTAINERS = (dict, list)


def _keys_all_unique(raw: bytes, value: Any) -> bool:
    """True when the JSON text ``raw``, parsed into ``value`` (whose dicts
    keep one entry per key), repeats no key: the parsed dicts hold as many
    keys as ``raw`` has colons. Every object key has one colon and ``raw``
    has no other outside its strings, so a repeated key (or a colon inside a
    string: then the caller parses again, slowly but exactly) makes them
    differ. The walk visits the dicts and the lists that hold containers,
    scanning lists of numbers only while fewer dicts were found than ``raw``
    has ``{`` (one per object, more when strings hold braces)."""
    objects, colons = raw.count(b"{"), raw.count(b":")
    found = keys = 0
    stack, deferred = ([value] if type(value) in _CONTAINERS else []), []
    while True:
        while stack:
            x = stack.pop()
            if type(x) is dict:
                found += 1
                keys += len(x)
                stack.extend(y for y in x.values() if type(y) in _CONTAINERS)
            elif x and type(x[0]) in _CONTAINERS:
                stack.extend(y for y in x if type(y) in _CONTAINERS)
            elif len(x) > 1:
                deferred.append(x)  # a list of scalars, unless a container hides further on
        if found >= objects or not deferred:
            return keys == colons
        stack = [y for x in deferred for y in x if type(y) in _CONTAINERS]
        deferred = []


def loads_json(data: bytes | str) -> Any:
    """Parse JSON text; ``DuplicateKeyError`` when an object repeats a key,
    ``json.JSONDecodeError`` (both ``ValueError``) when it is not JSON,
    ``UnicodeDecodeError`` for bytes that are not UTF-8.

    Fast path: ``orjson`` (5x the standard library on a scenario file), whose
    dicts keep the last of repeated keys; ``_keys_all_unique`` compares the
    keys parsed with the colons of the text, and only when they differ does
    the standard library parse again with a hook that names the key. What orjson refuses (NaN /
    Infinity literals, integers beyond 64 bits, every error) goes to the
    standard library too, so values and errors are the standard library's."""
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    try:
        value = orjson.loads(raw)
    except (orjson.JSONDecodeError, RecursionError):
        pass
    else:
        if _keys_all_unique(raw, value):
            return value
    text = data if isinstance(data, str) else raw.decode("utf-8")
    return json.loads(text, object_pairs_hook=_unique_pairs)


class JSONFileError(ValueError):
    """``read_json``: the file is not UTF-8 JSON or repeats a key. ``str`` is
    one line, ``<path>: unreadable (<reason>)``; ``path`` and ``reason`` as
    attributes (``reason`` e.g. ``duplicate key 'x'``)."""

    def __init__(self, path: str | Path, reason: str):
        super().__init__(f"{path}: unreadable ({reason})")
        self.path, self.reason = Path(path), reason


def read_json(path: str | Path) -> Any:
    """The JSON value of the file ``path`` (``loads_json``: a repeated key is
    an error). ``OSError`` as raised; ``JSONFileError`` (a ``ValueError``,
    one line naming the file) when it is not UTF-8 JSON or repeats a key."""
    data = Path(path).read_bytes()
    try:
        return loads_json(data)
    except UnicodeDecodeError as e:
        raise JSONFileError(path, f"not UTF-8 text: byte {e.start} undecodable") from None
    except json.JSONDecodeError as e:
        raise JSONFileError(path, str(e)) from None
    except RecursionError:
        raise JSONFileError(path, "nesting too deep") from None
