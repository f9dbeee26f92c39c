"""JAX's persistent compilation cache, shared by every drivee2e command and the tests.

A rollout compiles in tens of seconds on a CPU; the compiled program depends
only on shapes, the simulator config and the policy code, so reruns, resumed
sweeps, every checkpoint of a trend study and CI on the same machine can reuse
it from disk.

Where: ``$DRIVEE2E_JAX_CACHE`` if set, else ``<suite cache>/jax``
(``$DRIVEE2E_CACHE``, default ``~/.cache/drivee2e``). Either set to ``off``
disables it. The tests pin ``DRIVEE2E_JAX_CACHE`` once per session, so tests
that point ``DRIVEE2E_CACHE`` at a temporary folder (and the subprocesses they
start) still share compiled programs.

``enable`` does not import JAX: before JAX is imported it sets JAX's own
environment variables (``JAX_COMPILATION_CACHE_DIR``,
``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS``), which JAX reads when it is
first imported (and which processes started afterwards inherit); once JAX is
imported it updates ``jax.config``. So every ``drivee2e`` command enables the
cache, and those that never need JAX (``drivee2e suite info`` from a warm
packed cache, ``serve-policy``) do not pay ~1 s for importing it.

The rollout's lowered programs are stored in a subfolder of the same folder
(``lowered_cache``), so a warm start skips tracing them too.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

from drivee2e_jax.files import cache_dir

JAX_CACHE_ENV = "DRIVEE2E_JAX_CACHE"
#: Programs that compile faster than this are not written to disk, s.
MIN_COMPILE_S = 1.0
#: JAX's environment variables for its options ``jax_compilation_cache_dir`` and
#: ``jax_persistent_cache_min_compile_time_secs`` (read when JAX is imported).
JAX_DIR_ENV, JAX_MIN_TIME_ENV = "JAX_COMPILATION_CACHE_DIR", "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"


def compile_cache_dir() -> Path | None:
    """The folder of the persistent compilation cache, or None when disabled."""
    value = os.environ.get(JAX_CACHE_ENV, "").strip()
    if value:
        return None if value.lower() in ("off", "0", "none", "false") else Path(value).expanduser()
    base = cache_dir()
    return None if base is None else base / "jax"


def enable() -> Path | None:
    """Point JAX at the persistent cache (idempotent; never imports JAX);
    returns the folder used, or None when disabled or JAX is not installed
    (a policy server in a PyTorch environment)."""
    path = compile_cache_dir()
    if path is None:
        return None
    jax = sys.modules.get("jax")
    if jax is None:
        if importlib.util.find_spec("jax") is None:
            return None
        os.environ[JAX_DIR_ENV] = str(path)
        os.environ[JAX_MIN_TIME_ENV] = repr(float(MIN_COMPILE_S))
        return path
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    return path
