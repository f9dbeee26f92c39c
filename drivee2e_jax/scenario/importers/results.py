"""What an importer's ``load`` takes and returns: ``ImportOptions``,
``Skipped``, ``ImportResult`` and ``merge_results`` (see ``importers.common``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import SPLITS, MapRecord, ScenarioRecord

__all__ = ["ImportOptions", "Skipped", "ImportResult", "merge_results"]


@dataclass(frozen=True)
class ImportOptions:
    split: str = "test"              # split given to every imported scenario (records.SPLITS)
    ego: str | None = None           # track id to use as ego where the data has no recorded ego; None = auto
    max_scenarios: int | None = None  # stop after this many scenarios
    window_s: float | None = None    # cut long recordings into windows of this many seconds (None: format default)
    dt: float = 0.1                  # log step of the written scenarios, s (resample if the source differs)
    name: str | None = None          # suite name (default: from the input)

    def __post_init__(self):
        if self.split not in SPLITS:
            raise DriveE2EError(f"--split: expected one of {', '.join(SPLITS)}, got {self.split!r}")
        if self.max_scenarios is not None and self.max_scenarios < 1:
            raise DriveE2EError(f"--max-scenarios: expected an integer >= 1, got {self.max_scenarios}")
        if self.window_s is not None and not self.window_s > 0:
            raise DriveE2EError(f"--window-s: expected a number > 0, got {self.window_s}")
        if not self.dt > 0:
            raise DriveE2EError(f"dt: expected a number > 0, got {self.dt}")


@dataclass
class Skipped:
    source: str  # file, and track id / window where relevant
    reason: str  # one line: why it could not be used


@dataclass
class ImportResult:
    maps: dict[str, MapRecord]
    scenarios: list[ScenarioRecord]
    skipped: list[Skipped]
    notes: list[str]  # non-fatal remarks worth printing
    meta: dict = field(default_factory=dict)  # into suite.json "meta" (source, licence, id tables)


def merge_results(results: Sequence[ImportResult]) -> ImportResult:
    """One ImportResult from several (maps merged by id; scenario ids must be unique)."""
    merged = ImportResult(maps={}, scenarios=[], skipped=[], notes=[], meta={})
    seen: set[str] = set()
    for r in results:
        merged.maps.update(r.maps)
        for s in r.scenarios:
            if s.scenario_id in seen:
                raise DriveE2EError(f"scenario id {s.scenario_id!r} comes from two inputs; "
                                    "expected each recording once")
            seen.add(s.scenario_id)
            merged.scenarios.append(s)
        merged.skipped += r.skipped
        merged.notes += r.notes
        for k, v in r.meta.items():
            if isinstance(v, dict) and isinstance(merged.meta.get(k), dict):
                merged.meta[k].update(v)
            elif isinstance(v, list) and isinstance(merged.meta.get(k), list):
                merged.meta[k] += [x for x in v if x not in merged.meta[k]]
            else:
                merged.meta.setdefault(k, v if not isinstance(v, (dict, list)) else type(v)(v))
    return merged
