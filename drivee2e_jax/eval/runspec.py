"""The typed run specification: what a benchmark run evaluated (``run.json``).

``RunSpec`` holds every setting that decides a run's per-scenario results
(suite, split, task, limit, variant, scoring preset, sim step, control
timing, observation noise, seed, repetitions, collision mode, agent model)
and builds the three things a rollout needs from them: the packed batch
(``batch``), the simulator config
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
only for a variant other than ``complete``, collisions only when not ``all``
and agents only when not ``log`` (so a folder made with other settings
differs in that key and is refused, while older folders stay resumable).
``from_json`` accepts older files that lack keys (defaults as below) and
ignores unknown ones.

A spec is *requested* (``limit`` as asked, ``suite_version`` /
``num_scenarios`` / ``variant_removed`` None) until ``resolve`` fills those
from the loaded suite and batch; only a resolved spec has a ``to_json``. A
spec read from ``run.json`` is resolved, with ``limit = num_scenarios``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from pathlib import Path
from typing import Any

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.tasks import Task, apply_task, get_task
from drivee2e_jax.eval.variants import Variant, apply_variant, check_variant
from drivee2e_jax.jsonfile import read_json
from drivee2e_jax.metrics.driving_score import COLLISION_MODES, SCORE_PRESETS, score_preset
from drivee2e_jax.observe.vector import ObsConfig
from drivee2e_jax.rollout import ControlTiming
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.sim import AGENT_MODELS, SimConfig

#: The results folder's file holding the spec.
RUN_JSON = "run.json"
#: Largest simulation step, s. One tick moves the ego up to ``speed * dt``
#: between two contact / red-light / lane checks (``infractions`` checks the
#: poses at the ticks only): at 1 s and 10 m/s that is 10 m, over twice a car
#: length, so larger steps silently miss collisions (and ``--dt 1e6`` would run
#: zero steps). The data-dependent bound, dt <= the log step, is
#: ``check_dt_against_logs``.
MAX_DT = 1.0
#: PRNG seeds are 32-bit: ``jax.random.PRNGKey(2**32)`` equals ``PRNGKey(0)``.
SEED_LIMIT = 2**32


def _is_int(v) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def check_settings(spec: RunSpec) -> None:
    """DriveE2EError (one line naming the flag) for a setting no run can use:
    dt not a finite number in (0, ``MAX_DT``] s, control_every < 1,
    latency < 0, a seed outside [0, 2**32 - repetitions], repetitions or
    limit < 1, negative or non-finite observation noise, an unknown
    preset, collision mode or agent model (``check_choice``)."""
    check_choice("--preset", "scoring preset", spec.preset, SCORE_PRESETS)
    check_choice("--collisions", "collision mode", spec.collisions, COLLISION_MODES)
    check_choice("--agents", "agent model", spec.agents, AGENT_MODELS)
    dt = spec.dt
    if isinstance(dt, bool) or not isinstance(dt, int | float | np.number) or not math.isfinite(dt) or not (
            0 < dt <= MAX_DT):
        raise DriveE2EError(f"--dt must be a finite number of seconds in (0, {MAX_DT:g}], got {dt!r}")
    if not _is_int(spec.control_every) or spec.control_every < 1:
        raise DriveE2EError(f"--control-every must be an integer >= 1 (sim steps), got {spec.control_every!r}")
    if not _is_int(spec.latency) or spec.latency < 0:
        raise DriveE2EError(f"--latency must be an integer >= 0 (sim steps), got {spec.latency!r}")
    if not _is_int(spec.repetitions) or spec.repetitions < 1:
        raise DriveE2EError(f"--repetitions must be >= 1, got {spec.repetitions!r}")
    if spec.limit is not None and (not _is_int(spec.limit) or spec.limit < 1):
        raise DriveE2EError(f"--limit must be >= 1, got {spec.limit!r}")
    if not _is_int(spec.seed) or not 0 <= spec.seed <= SEED_LIMIT - spec.repetitions:
        raise DriveE2EError(f"--seed must be an integer in [0, {SEED_LIMIT - spec.repetitions}] (32-bit PRNG seeds, "
                            f"one per repetition), got {spec.seed!r}")
    for flag, v in (("--gps-noise-std", spec.gps_noise_std), ("--compass-noise-std", spec.compass_noise_std)):
        if isinstance(v, bool) or not isinstance(v, int | float | np.number) or not (math.isfinite(v) and v >= 0):
            raise DriveE2EError(f"{flag} must be a finite number >= 0, got {v!r}")


def check_choice(flag: str, what: str, value: object, choices: tuple[str, ...]) -> None:
    """DriveE2EError, one line naming ``flag`` and listing ``choices``, when
    ``value`` is not one of them (e.g. ``--collisions: unknown collision mode
    'foo'; expected one of all, at_fault``)."""
    if not isinstance(value, str) or value not in choices:
        raise DriveE2EError(f"{flag}: unknown {what} {value!r}; expected one of {', '.join(choices)}")


def check_dt_against_logs(dt: float, meta) -> None:
    """DriveE2EError when ``dt`` exceeds the log step of a scenario in
    ``meta`` (``SuiteMeta``; its ``dt`` column, s): replay interpolates
    between log samples, and a longer tick would step over logged samples
    unchecked (an agent crossing the ego between two ticks is never seen)."""
    if len(meta) == 0:
        return
    i = int(np.argmin(meta.dt))
    if dt > float(meta.dt[i]) * (1 + 1e-6):
        raise DriveE2EError(f"--dt {dt:g} exceeds the log step {float(meta.dt[i]):g} s of scenario "
                            f"{meta.scenario_id[i]!s} (ticks would skip logged samples); use --dt <= {float(meta.dt[i]):g}")


def pick_split(splits: dict[str, int], suite_name: str = "suite") -> tuple[str, str]:
    """The split to run when none is given, and a line saying why.

    ``splits``: the non-empty splits (``Suite.splits``: name -> count).
    ``val`` when it has scenarios, else the only non-empty split; otherwise
    DriveE2EError listing the splits."""
    listed = ", ".join(f"{s} ({n})" for s, n in splits.items()) or "none"
    if splits.get("val"):
        return "val", f"split val ({splits['val']} scenarios; --split picks another)"
    full = [s for s, n in splits.items() if n]
    if len(full) == 1:
        return full[0], f"split {full[0]}: the only non-empty split of {suite_name} (no --split given)"
    raise DriveE2EError(f"--split: {suite_name} has no val split; name one of: {listed}")


def batch_sha256(packed) -> str:
    """Hex sha256 of a packed batch (``scenario.pack.PackedBatch``): every
    array leaf of its ``Scenario`` (name, dtype, shape, bytes) and every meta
    column. This is the suite fingerprint of a run: it covers exactly what is
    evaluated (split, task filter, limit and variant applied), whether the
    suite is a folder or generated, and ignores paths and mtimes. Adding a
    scenario that changes the suite-wide padded sizes changes it too (a
    conservative miss). ``meta.origin`` counts only where it is non-zero: a
    suite near (0, 0) packs as it did before the column existed and keeps its
    fingerprint (and its results folders stay current)."""
    h = hashlib.sha256()
    for name, leaf in sorted(flatten_scenario(packed.scenario).items()):
        _hash_array(h, f"scenario.{name}", leaf)
    for name, col in sorted(packed.meta.columns().items()):
        if name == "origin" and not np.asarray(col).any():
            continue
        _hash_array(h, f"meta.{name}", col)
    return h.hexdigest()


def folder_fingerprint(index, split: str, n: int) -> str:
    """Hex sha256 of a streamed folder run's inputs without reading every
    scenario: suite.json and the map files by content, the split's first
    ``n`` scenario files by name, size and modification time (hashing the
    content of a suite larger than memory would read it twice)."""
    h = hashlib.sha256()
    folder = Path(index.folder)
    for rel in ["suite.json", *sorted(f"maps/{p.name}" for p in (folder / "maps").glob("*.json"))]:
        data = (folder / rel).read_bytes()
        h.update(f"{rel}:{len(data)}\n".encode())
        h.update(data)
    for row in index.rows(split)[:n]:
        rel = f"scenarios/{index.ids[row]}.json"
        st = (folder / rel).stat()
        h.update(f"{rel}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def _hash_array(h, name: str, value) -> None:
    a = np.ascontiguousarray(np.asarray(value))
    if a.dtype.kind in "OUS":  # text columns: their values, not object pointers
        a = np.asarray([str(v) for v in a.ravel()]).reshape(a.shape)
        data = "\0".join(a.ravel().tolist()).encode()
    else:
        data = a.tobytes()
    h.update(f"{name}:{a.dtype.str}:{a.shape}:{len(data)}\n".encode())
    h.update(data)


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
      collisions: which collisions count against IS / DS / SR
        (``metrics.driving_score.COLLISION_MODES``): ``all`` (every collision with a logged agent,
        the paper's protocol) or ``at_fault`` (nuPlan's attribution).
      agents: the other agents (``sim.AGENT_MODELS``): ``log`` (non-reactive
        replay of the logs) or ``idm`` (reactive IDM vehicles).
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
    collisions: str = "all"
    agents: str = "log"
    suite_version: str | None = None
    num_scenarios: int | None = None
    variant_removed: tuple[tuple[str, tuple[int, int]], ...] | None = None

    def __post_init__(self):
        check_settings(self)
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
        preset with this run's collision mode, the agent model, the
        observation noise; everything else default. A bad value raises
        DriveE2EError."""
        try:
            score = dataclasses.replace(score_preset(self.preset), collision_mode=self.collisions)
            return SimConfig(dt=self.dt, score=score, obs=self.obs_config(), agents=self.agents)
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
        if self.collisions != "all":  # recorded only when used: older run.json stay resumable
            out["collisions"] = self.collisions
        if self.agents != "log":
            out["agents"] = self.agents
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
                collisions=str(info.get("collisions", "all")),
                agents=str(info.get("agents", "log")),
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
            info = read_json(path)  # BadJSON (a DriveE2EError) names the file and what was expected
        except OSError as e:
            raise DriveE2EError(f"{path}: unreadable ({e})") from e
        try:
            return cls.from_json(info)
        except DriveE2EError as e:
            raise DriveE2EError(f"{path}: {e}") from e
