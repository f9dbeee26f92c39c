"""``twin15``: the built-in default suite, a procedural stand-in for the
DriveE2E benchmark's 800 scenarios at 15 signalised intersections.

``generate(seed) -> SuiteRecord`` is deterministic in ``(seed, VERSION)``:
15 fixed intersection maps (``I01``..``I15``) and 800 scenarios
(``twin15_0000``..``twin15_0799``; train / val / test = 400 / 200 / 200)
whose agent logs come from one run of a rule-based traffic model each,
with one vehicle designated as the ego. See ``docs/twin15.md``.

Modules, in data-flow order: ``specs`` (the 15 designs) -> ``legs``,
``movements``, ``lanes``, ``markings``, ``roadside``, ``signals`` ->
``layout`` (one MapRecord) -> ``network`` (agent paths, conflict zones) ->
``tables`` (all networks as arrays) -> ``demand``, ``egoplan``, ``plan``
(who appears when) -> ``traffic`` (the simulation) -> ``labels`` (log
window, overlap removal, label checks) -> ``assemble`` (records) ->
``build`` (batches and retries).
"""

from __future__ import annotations

from collections.abc import Iterable

from drivee2e_jax.records import SuiteRecord

from . import build

#: Bump whenever the generated suite changes (caches key on it).
VERSION = "1"

__all__ = ["generate", "maps", "VERSION"]


def maps() -> dict:
    """{map_id: MapRecord} of the 15 intersections, without generating any
    traffic (seed-independent; a few seconds)."""
    return {sp.map_id: build.build_layout(sp.map_id).map for sp in build.SPECS}


def generate(seed: int = 0, *, scenarios: Iterable[int] | None = None, workers: int | None = None) -> SuiteRecord:
    """The twin15 suite for ``seed`` (15 maps, 800 scenarios, dt 0.1 s, 201 steps).

    Args:
      seed: the randomness of the traffic (maps never change).
      scenarios: only these scenario indices (0..799), e.g. for a quick look;
        each comes out exactly as in the full suite.
      workers: processes sharing the work (default 2 on a machine with two
        or more cores, or ``$DRIVEE2E_TWIN15_WORKERS``); results do not
        depend on it.
    """
    return build.generate(int(seed), VERSION, scenarios=scenarios, workers=workers)
