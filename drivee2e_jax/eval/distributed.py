"""Several processes / hosts with JAX's own runtime (``jax.distributed``).

Each process evaluates one contiguous, balanced part of the scenarios
(``process_shard``) on its own local devices (``evaluate(shard=...)`` splits
that part again over them); the per-scenario rows and events are then
gathered so that process 0 holds all of them and writes the results folder
alone (``gather_result``, ``on_root``).

Why the rows travel through ``multihost_utils.process_allgather`` as JSON
bytes: they are host data (dicts of strings, numbers and nulls), not arrays;
the collective runs over the channel ``jax.distributed`` already set up
(gloo on CPU, NCCL on GPU), so it needs no shared file system and no private
API (the coordination service's key-value store is ``jax._src``), and a
process that died makes the others fail instead of waiting for a file.

Launch: ``initialize(coordinator, num_processes, process_id)`` or the
environment (``DRIVEE2E_COORDINATOR``, ``DRIVEE2E_NUM_PROCESSES``,
``DRIVEE2E_PROCESS_ID``); coordinator ``auto`` = JAX's cluster detection
(SLURM, Open MPI, TPU). See docs/scaling.md.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils

from drivee2e_jax.errors import DriveE2EError

ENV_COORDINATOR = "DRIVEE2E_COORDINATOR"
ENV_NUM_PROCESSES = "DRIVEE2E_NUM_PROCESSES"
ENV_PROCESS_ID = "DRIVEE2E_PROCESS_ID"


def initialize(coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None) -> bool:
    """Join a multi-process JAX run; call before any other JAX work.

    Args:
      coordinator: ``HOST:PORT`` of process 0's coordination service, or
        ``"auto"`` (JAX detects SLURM / Open MPI / TPU and picks all three);
        ``None``: ``$DRIVEE2E_COORDINATOR``, else a single process (no-op).
      num_processes: processes in the run (``$DRIVEE2E_NUM_PROCESSES``).
      process_id: this process, 0 .. num_processes - 1 (``$DRIVEE2E_PROCESS_ID``).

    Returns True when more than one process takes part. Calling it again in
    an initialized process is a no-op.
    """

    coordinator = coordinator or os.environ.get(ENV_COORDINATOR) or None
    num_processes = _int_arg(num_processes, ENV_NUM_PROCESSES, "--num-processes")
    process_id = _int_arg(process_id, ENV_PROCESS_ID, "--process-id")
    if jax.distributed.is_initialized():
        return jax.process_count() > 1
    if coordinator is None:
        if num_processes not in (None, 1) or process_id not in (None, 0):
            raise DriveE2EError(f"--num-processes/--process-id need --coordinator HOST:PORT (or ${ENV_COORDINATOR})")
        return False
    if coordinator == "auto":
        jax.distributed.initialize(num_processes=num_processes, process_id=process_id)
        return jax.process_count() > 1
    if num_processes is None or process_id is None:
        raise DriveE2EError(f"--coordinator {coordinator}: also give --num-processes and --process-id "
                            f"(or ${ENV_NUM_PROCESSES} / ${ENV_PROCESS_ID}), or use --coordinator auto on a cluster")
    if num_processes < 1 or not 0 <= process_id < num_processes:
        raise DriveE2EError(f"--process-id must be in 0..{num_processes - 1} and --num-processes >= 1, "
                            f"got {process_id} of {num_processes}")
    if num_processes == 1:
        return False
    jax.distributed.initialize(coordinator, num_processes, process_id)
    return True


def _int_arg(value: int | None, env: str, flag: str) -> int | None:
    if value is not None:
        return int(value)
    raw = os.environ.get(env)
    if not raw:
        return None
    try:
        return int(raw)
    except ValueError:
        raise DriveE2EError(f"${env} (or {flag}): expected an integer, got {raw!r}") from None


def process_shard(n: int, process_index: int | None = None, process_count: int | None = None) -> range:
    """This process's scenarios: a contiguous range of ``0..n-1``; the
    ``n % process_count`` first processes take one scenario more than the
    others, so the parts differ by at most one and cover ``0..n-1`` once, in order.
    Defaults: ``jax.process_index()`` / ``jax.process_count()``."""

    index = jax.process_index() if process_index is None else process_index
    count = jax.process_count() if process_count is None else process_count
    if count < 1 or not 0 <= index < count:
        raise ValueError(f"process_shard: process {index} of {count}")
    base, extra = divmod(int(n), count)
    start = index * base + min(index, extra)
    return range(start, start + base + (index < extra))


def process_count() -> int:
    """Processes in the run (1 without ``initialize``)."""

    return jax.process_count()


def is_root() -> bool:
    """True on process 0 (and in a single-process run)."""

    return jax.process_index() == 0


def allgather_json(obj: Any) -> list:
    """Every process's ``obj`` (JSON-serialisable), in process order, on every
    process; ``[obj]`` in a single-process run."""

    if jax.process_count() == 1:
        return [obj]

    blob = np.frombuffer(json.dumps(obj, allow_nan=True).encode(), np.uint8)
    sizes = np.asarray(multihost_utils.process_allgather(np.array([blob.size], np.int64))).reshape(-1)
    buf = np.zeros(int(sizes.max()), np.uint8)
    buf[: blob.size] = blob
    parts = np.asarray(multihost_utils.process_allgather(buf))
    return [json.loads(bytes(parts[i, : sizes[i]]).decode()) for i in range(len(sizes))]


def on_root(fn: Callable[[], Any], share: Callable[[Any], Any] | None = None):
    """``fn()`` on process 0 only. Returns (its result on process 0 / None
    elsewhere, ``share(result)`` on every process). A ``DriveE2EError`` on
    process 0 is raised on every process, so none waits for the others."""
    result, shared, error = None, None, None
    if is_root():
        try:
            result = fn()
            shared = share(result) if share else None
        except DriveE2EError as e:
            error = str(e)
    shared, error = allgather_json([shared, error])[0]
    if error is not None:
        raise DriveE2EError(error)
    return result, shared


def gather_result(res):
    """An ``evaluation.EvalResult`` holding every process's rows and events
    (scenario order: shards are contiguous; grouped by repetition), the
    slowest process's times and ``logs=None`` (step logs stay per process).
    ``res`` itself in a single-process run."""

    if jax.process_count() == 1:
        return res
    parts = allgather_json({"rows": res.rows, "events": res.events, "compile_s": res.compile_s,
                            "wall_s": res.wall_s, "steps": res.steps, "warnings": list(res.warnings)})
    rows = sorted((r for p in parts for r in p["rows"]), key=lambda r: r.get("repetition") or 0)  # stable
    events = {k: v for p in parts for k, v in p["events"].items()}
    # Each process's warnings count its own share of the episodes: keep every distinct line.
    warnings = list(dict.fromkeys(w for p in parts for w in p["warnings"]))
    return dataclasses.replace(res, rows=rows, events=events, logs=None, warnings=warnings,
                               **{k: max(p[k] for p in parts) for k in ("compile_s", "wall_s", "steps")})
