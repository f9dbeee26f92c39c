"""``twin15``: the built-in default suite, a procedural stand-in for the
DriveE2E benchmark's 800 scenarios at 15 signalised intersections.

``generate(seed) -> SuiteRecord`` is deterministic in ``(seed, VERSION)``:
15 fixed intersection maps (``I01``..``I15``) and 800 scenarios
(``twin15_0000``..``twin15_0799``; train / val / test = 400 / 200 / 200)
whose agent logs come from one run of a rule-based traffic model each,
with one vehicle designated as the ego. See ``docs/twin15.md``.

``generate(seed, num_scenarios=N)`` scales it to any positive multiple N of
800 (splits N/2, N/4, N/4, label counts x N/800, more scenarios per
intersection; suite name ``twin15x<N/800>``), and ``generate_to(path, ...)``
streams such a suite into a suite folder block by block (bounded memory,
resumable; ``drivee2e suite generate --scenarios N``).

Modules, in data-flow order: ``specs`` (the 15 designs) -> ``legs``,
``movements``, ``lanes``, ``markings``, ``roadside``, ``signals`` ->
``layout`` (one MapRecord) -> ``network`` (agent paths, conflict zones) ->
``tables`` (all networks as arrays) -> ``demand``, ``egoplan``, ``plan``
(who appears when) -> ``traffic`` (the simulation) -> ``labels`` (log
window, overlap removal, label checks) -> ``assemble`` (records) ->
``build`` (batches and retries).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from drivee2e_jax.progress import ProgressFn
from drivee2e_jax.records import SuiteRecord

from . import build
from .build import suite_name
from .scenarios import NUM_SCENARIOS

#: Bump whenever the generated suite changes (caches key on it).
VERSION = "1"

__all__ = ["generate", "generate_to", "maps", "suite_name", "NUM_SCENARIOS", "VERSION"]


def maps() -> dict:
    """{map_id: MapRecord} of the 15 intersections, without generating any
    traffic (seed-independent; a few seconds)."""
    return {sp.map_id: build.build_layout(sp.map_id).map for sp in build.SPECS}


def generate(seed: int = 0, *, scenarios: Iterable[int] | None = None, workers: int | None = None,
             num_scenarios: int = NUM_SCENARIOS) -> SuiteRecord:
    """The twin15 suite for ``seed`` (15 maps, 800 scenarios, dt 0.1 s, 201 steps).

    Args:
      seed: the randomness of the traffic (maps never change).
      scenarios: only these scenario indices (0..num_scenarios-1), e.g. for a
        quick look; each comes out exactly as in the full suite.
      workers: processes sharing the work (default 2 on a machine with two
        or more cores, or ``$DRIVEE2E_TWIN15_WORKERS``); results do not
        depend on it.
      num_scenarios: N, a positive multiple of 800 (else DriveE2EError); 800
        is the suite as it always was. All N records are held in memory:
        for large N use :func:`generate_to`.
    """
    return build.generate(int(seed), VERSION, scenarios=scenarios, workers=workers, num_scenarios=num_scenarios)


def generate_to(path: str | os.PathLike, seed: int = 0, *, num_scenarios: int = NUM_SCENARIOS,
                scenarios: Iterable[int] | None = None, workers: int | None = None, overwrite: bool = False,
                progress: ProgressFn | None = None) -> Path:
    """Generate the suite of ``generate(seed, num_scenarios=...)`` straight
    into the suite folder ``path``, 800 scenarios at a time (peak memory
    that of an 800-scenario generation, whatever N), and return ``path``.

    Atomic like ``schema.write_suite`` (``overwrite`` = ``--force``) and
    resumable: a killed run restarted with the same arguments continues
    after the blocks already written (``.<name>.partial`` next to ``path``).
    suite.json's meta also holds ``pack_sizes`` (the PackSizes ``pack``
    fits for the whole suite). ``progress(stage, done, total, info)`` is
    called after every block (``done`` in scenarios).
    """
    return build.generate_to(path, int(seed), VERSION, num_scenarios=num_scenarios, scenarios=scenarios,
                             workers=workers, overwrite=overwrite, progress=progress)
