"""The typed run specification: what a benchmark run evaluated (``run.json``).

``RunSpec`` holds every setting that decides a run's per-scenario results
(suite, split, task, limit, variant, scoring preset, sim step, control
timing, observation noise, seed, repetitions) and builds the three things a
rollout needs from them: the packed batch (``batch``), the simulator config
(``sim_config``) and the control timing (``timing``). ``drivee2e bench``
(``eval.bench``) builds its spec from the command line and writes it as the
results folder's ``run.json`` (``to_json``); re-simulation (``eval.traces``)
reads it back (``RunSpec.load``) and calls the same builders, so the two can
never disagree on how a setting is applied.

JSON compatibility: ``to_json`` writes exactly the keys and values
``run.json`` has always had (resuming compares the stored dict with the new
one): suite, suite_version, split, num_scenarios, preset, dt, control_every,
latency, seed, open_loop, task, repetitions, then gps_noise_std /
compass_noise_std only when either is non-zero and variant / variant_removed
only for a variant other than ``complete``. ``from_json`` accepts older files
that lack keys (defaults as below) and ignores unknown ones.

A spec is *requested* (``limit`` as asked, ``suite_version`` /
``num_scenarios`` / ``variant_removed`` None) until ``resolve`` fills those
from the loaded suite and batch; only a resolved spec has a ``to_json``. A
spec read from ``run.json`` is resolved, with ``limit = num_scenarios``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.tasks import Task, apply_task, get_task
from drivee2e_jax.eval.variants import Variant, apply_variant, check_variant
from drivee2e_jax.metrics.driving_score import score_preset
from drivee2e_jax.observe.vector import ObsConfig
from drivee2e_jax.rollout import ControlTiming
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.sim import SimConfig

#: The results folder's file holding the spec.
RUN_JSON = "run.json"


@dataclasses.dataclass(frozen=True)
class RunBatch:
    """The scenarios a run evaluates (``RunSpec.batch``).

    Attributes:
      packed: the task-filtered ``scenario.pack.PackedBatch`` of the split;
        for a variant other than ``complete`` already cut to the run's
        scenarios and with the invisible agents removed. Evaluate its first
        ``num_scenarios`` rows (``evaluate(..., limit=spec.limit)``).
      variant: the ``eval.variants.Variant`` applied, or None (``complete``).
      num_scenarios: how many scenarios the run evaluates.
    """

    packed: Any
    variant: Variant | None
    num_scenarios: int

    def limited(self):
        """``packed`` cut to its first ``num_scenarios`` rows."""
        if len(self.packed) == self.num_scenarios:
            return self.packed
        return self.packed.select(np.arange(self.num_scenarios))


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """What a benchmark run evaluated (one ``run.json``).

    Attributes:
      suite: suite name or folder (as given to ``scenario.load_suite``).
      split: split name.
      preset: scoring preset (``metrics.driving_score.SCORE_PRESETS``).
      dt: simulation step, s.
      control_every: the policy acts every this many sim steps (>= 1).
      latency: steps between an observation and its action taking effect (>= 0).
      seed: PRNG seed (of repetition 0; repetition r uses seed + r).
      open_loop: waypoint policies were also scored open-loop on the logs.
      task: Behavior Metrics driving task (``eval.tasks.TASKS``).
      repetitions: runs per policy (>= 1).
      limit: only the first N scenarios of the (task-filtered) split; None =
        all. Not written: ``num_scenarios`` records the outcome.
      gps_noise_std: observation GPS noise, m (``observe.vector.ObsConfig``).
      compass_noise_std: observation compass noise, rad.
      variant: suite variant (``eval.variants.VARIANTS``).
      suite_version: version of the suite run on (None until resolved).
      num_scenarios: scenarios evaluated (None until resolved).
      variant_removed: per category, (agents removed, non-ego agents in the
        complete batch), in ``Variant.by_category`` order; None for
        ``complete`` or until resolved.
    """

    suite: str = "twin15"
    split: str = "val"
    preset: str = "paper"
    dt: float = 0.1
    control_every: int = 1
    latency: int = 0
    seed: int = 0
    open_loop: bool = False
    task: str = "route_navigation"
    repetitions: int = 1
    limit: int | None = None
    gps_noise_std: float = 0.0
    compass_noise_std: float = 0.0
    variant: str = "complete"
    suite_version: str | None = None
    num_scenarios: int | None = None
    variant_removed: tuple[tuple[str, tuple[int, int]], ...] | None = None

    def __post_init__(self):
        if self.limit is not None and self.limit < 1:
            raise DriveE2EError(f"--limit must be >= 1, got {self.limit}")
        if self.repetitions < 1:
            raise DriveE2EError(f"--repetitions must be >= 1, got {self.repetitions}")
        get_task(self.task)
        check_variant(self.variant)

    # -- builders --------------------------------------------------------------
    def task_spec(self) -> Task:
        """The ``eval.tasks.Task`` of ``task``."""
        return get_task(self.task)

    def load_suite(self):
        """The suite (``scenario.load_suite(suite)``)."""
        return load_suite(self.suite)

    def batch(self, suite) -> RunBatch:
        """The scenarios of this run in ``suite``: the split packed, filtered
        by the task; for a variant the first ``limit`` of them with the
        agents removed (masks computed, or read from the cache, only for
        those; the cache label is ``<suite>-<split>[-<task>]``)."""
        task = self.task_spec()
        packed = apply_task(task, suite.pack(self.split))
        n = min(len(packed), self.limit or len(packed))
        variant = None
        if self.variant != "complete":  # masks only for the scenarios run
            variant = apply_variant(packed.select(np.arange(n)), self.variant,
                                    f"{suite.name}-{self.split}{self.task_tag}")
            packed = variant.batch
        return RunBatch(packed=packed, variant=variant, num_scenarios=min(len(packed.meta), self.limit or len(packed.meta)))

    def resolve(self, suite, batch: RunBatch) -> RunSpec:
        """This spec with ``suite_version``, ``num_scenarios`` and
        ``variant_removed`` of ``suite`` and ``batch`` (``batch(suite)``)."""
        removed = None
        if batch.variant is not None:
            removed = tuple((str(c), (int(v[0]), int(v[1]))) for c, v in batch.variant.by_category.items())
        return dataclasses.replace(self, suite_version=suite.version, num_scenarios=batch.num_scenarios,
                                   variant_removed=removed)

    def obs_config(self) -> ObsConfig:
        """The default ``ObsConfig`` with this run's observation noise."""
        return dataclasses.replace(ObsConfig(), gps_noise_std=self.gps_noise_std,
                                   compass_noise_std=self.compass_noise_std)

    def sim_config(self) -> SimConfig:
        """The ``SimConfig`` of this run (before the policy's sensors are
        added, ``eval.closedloop.with_policy_sensors``): ``dt``, the scoring
        preset, the observation noise; everything else default. A bad value
        raises DriveE2EError."""
        try:
            return SimConfig(dt=self.dt, score=score_preset(self.preset), obs=self.obs_config())
        except ValueError as e:
            raise DriveE2EError(str(e)) from e

    def timing(self) -> ControlTiming:
        """The ``rollout.ControlTiming`` (control_every, latency); a bad value raises DriveE2EError."""
        try:
            return ControlTiming(self.control_every, self.latency)
        except ValueError as e:
            raise DriveE2EError(str(e)) from e

    def repetition_seeds(self) -> list[int] | None:
        """Seeds of the repetitions (seed, seed + 1, ...); None for a single run."""
        return None if self.repetitions == 1 else [self.seed + rep for rep in range(self.repetitions)]

    @property
    def task_tag(self) -> str:
        """``-<task>`` in folder names and cache labels ("" for ``route_navigation``)."""
        return "" if self.task == "route_navigation" else f"-{self.task}"

    def default_out(self) -> Path:
        """``results/<suite>-<split>[-<task>][-<variant>]`` (suite folder: its name)."""
        suite_tag = Path(self.suite).name if Path(self.suite).exists() else self.suite
        variant_tag = "" if self.variant == "complete" else f"-{self.variant}"
        return Path("results") / f"{suite_tag}-{self.split}{self.task_tag}{variant_tag}"

    # -- run.json --------------------------------------------------------------
    @property
    def resolved(self) -> bool:
        return self.num_scenarios is not None

    def to_json(self) -> dict:
        """The ``run.json`` dict (key order and optional keys as always written)."""
        if not self.resolved:
            raise ValueError("RunSpec.to_json: resolve() the spec against its suite first")
        out = {
            "suite": self.suite,
            "suite_version": self.suite_version,
            "split": self.split,
            "num_scenarios": self.num_scenarios,
            "preset": self.preset,
            "dt": self.dt,
            "control_every": self.control_every,
            "latency": self.latency,
            "seed": self.seed,
            "open_loop": self.open_loop,
            "task": self.task,
            "repetitions": self.repetitions,
        }
        if self.gps_noise_std or self.compass_noise_std:  # recorded only when used: older run.json stay resumable
            out.update(gps_noise_std=self.gps_noise_std, compass_noise_std=self.compass_noise_std)
        if self.variant != "complete":  # recorded only when used: older run.json stay resumable
            out.update(variant=self.variant, variant_removed={c: list(v) for c, v in self.variant_removed or ()})
        return out

    @classmethod
    def from_json(cls, info: dict) -> RunSpec:
        """The spec of a ``run.json`` dict. ``suite``, ``split`` and ``dt`` are
        required; other keys default as in older files (``limit`` =
        ``num_scenarios``); unknown keys are ignored. Raises DriveE2EError."""
        if not isinstance(info, dict):
            raise DriveE2EError(f"expected a JSON object, got {type(info).__name__}")
        missing = [k for k in ("suite", "split", "dt") if k not in info]
        if missing:
            raise DriveE2EError(f"no {', '.join(missing)}")
        try:
            n = info.get("num_scenarios")
            n = None if n is None else int(n)
            removed = info.get("variant_removed")
            if removed is not None:
                removed = tuple((str(c), (int(v[0]), int(v[1]))) for c, v in removed.items())
            version = info.get("suite_version")
            return cls(
                suite=str(info["suite"]),
                split=str(info["split"]),
                preset=str(info.get("preset", "paper")),
                dt=float(info["dt"]),
                control_every=int(info.get("control_every", 1)),
                latency=int(info.get("latency", 0)),
                seed=int(info.get("seed", 0)),
                open_loop=bool(info.get("open_loop", False)),
                task=str(info.get("task", "route_navigation")),
                repetitions=int(info.get("repetitions", 1)),
                limit=n or None,
                gps_noise_std=float(info.get("gps_noise_std", 0.0)),
                compass_noise_std=float(info.get("compass_noise_std", 0.0)),
                variant=str(info.get("variant", "complete")),
                suite_version=None if version is None else str(version),
                num_scenarios=n,
                variant_removed=removed,
            )
        except (TypeError, ValueError, AttributeError, IndexError) as e:
            raise DriveE2EError(f"bad value ({e})") from e

    @classmethod
    def load(cls, folder: str | Path) -> RunSpec:
        """The spec of a results folder's ``run.json``; DriveE2EError (one
        line, naming the file) when it is missing or unreadable."""
        path = Path(folder) / RUN_JSON
        try:
            info = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise DriveE2EError(f"{path}: unreadable ({e})") from e
        try:
            return cls.from_json(info)
        except DriveE2EError as e:
            raise DriveE2EError(f"{path}: {e}") from e
