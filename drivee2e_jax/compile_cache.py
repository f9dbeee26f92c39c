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
"""

from __future__ import annotations

import os
from pathlib import Path

from drivee2e_jax.files import cache_dir

JAX_CACHE_ENV = "DRIVEE2E_JAX_CACHE"
#: Programs that compile faster than this are not written to disk, s.
MIN_COMPILE_S = 1.0


def compile_cache_dir() -> Path | None:
    """The folder of the persistent compilation cache, or None when disabled."""
    value = os.environ.get(JAX_CACHE_ENV, "").strip()
    if value:
        return None if value.lower() in ("off", "0", "none", "false") else Path(value).expanduser()
    base = cache_dir()
    return None if base is None else base / "jax"


def enable() -> Path | None:
    """Point JAX at the persistent cache (idempotent); returns the folder used."""
    path = compile_cache_dir()
    if path is None:
        return None
    try:  # `drivee2e --help` and the JAX-free serve-policy enable the cache without importing JAX eagerly
        import jax  # noqa: PLC0415
    except ImportError:  # a policy server in an environment without JAX
        return None

    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    return path
