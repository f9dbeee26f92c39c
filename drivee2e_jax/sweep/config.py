"""Experiment configs: ``experiments/<name>.toml`` mapped one to one onto frozen dataclasses.

Each TOML table is one dataclass below (``[sweep]`` -> ``SweepSection``,
``[[policies]]`` -> ``PolicySpec`` ..., the whole file -> ``SweepConfig``);
each key is one field. ``load_config(path)`` reads a file and checks it: an
unknown table or key, a value of the wrong type or out of range raises a
``DriveE2EError`` with one line naming the file, the table and the key, e.g.
``experiments/x.toml: [sim] unknown key 'dtt' (expected one of: dt, preset, ...)``.

Fields typed ``tuple[...]`` accept a single value or a list; the runner sweeps
every combination of the ``[data]`` and ``[sim]`` lists (``runner.expand``).
The reference is ``docs/sweeps.md``.
"""

from __future__ import annotations

import dataclasses
import tomllib
import types
import typing
from pathlib import Path

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.tasks import TASKS
from drivee2e_jax.eval.variants import VARIANTS
from drivee2e_jax.metrics.driving_score import COLLISION_MODES, SCORE_PRESETS
from drivee2e_jax.sim import AGENT_MODELS


@dataclasses.dataclass(frozen=True)
class SweepSection:
    """``[sweep]``: what the sweep is called and where it writes.

    Attributes:
      name: the sweep's name (letters, digits, ``-_.``).
      out: results folder; default ``results/sweeps/<name>``; ``--out`` overrides it.
    """

    name: str
    out: str | None = None


@dataclasses.dataclass(frozen=True)
class PolicySpec:
    """``[[policies]]``: one policy under test (one table per policy).

    Attributes:
      path: policy file (``.py``, relative to the working directory) or a
        reference policy name (log_replay, expert, stop, constant_velocity).
      name: its name in the results ("" = the name the policy gives itself);
        needed to tell two instances of one file apart.
      kwargs: keyword arguments of the file's ``make_policy(**kwargs)``, e.g.
        ``{ checkpoint = "runs/tcp/ckpt" }``.
    """

    path: str
    name: str = ""
    kwargs: dict = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class DataSection:
    """``[data]``: which scenarios; every list is a grid axis.

    Attributes:
      suites: suite names (``twin15``) or suite folders.
      splits: split names.
      variants: suite variants (``scenario.variants.VARIANTS``; ``complete`` = as recorded).
      tasks: driving tasks (``tasks.TASKS``).
      limit: only the first N scenarios of each split (None = all).
    """

    suites: tuple[str, ...] = ("twin15",)
    splits: tuple[str, ...] = ("val",)
    variants: tuple[str, ...] = ("complete",)
    tasks: tuple[str, ...] = ("route_navigation",)
    limit: int | None = None


@dataclasses.dataclass(frozen=True)
class RepetitionsSection:
    """``[repetitions]``: run every policy ``count`` times with seeds seed, seed + 1, ...

    The repetitions of one policy on one run are one batched rollout; they
    differ where something is random (observation noise, stochastic policies).

    Attributes:
      count: repetitions (>= 1).
      seed: the first PRNG seed.
    """

    count: int = 1
    seed: int = 0


@dataclasses.dataclass(frozen=True)
class SimSection:
    """``[sim]``: simulator settings; every list is a grid axis.

    Attributes:
      dt: simulation step, s (> 0).
      preset: scoring rules (``metrics.driving_score.SCORE_PRESETS``; paper = DriveE2E's paper).
      control_every: query the policy every k sim steps (>= 1).
      latency: action latency, sim steps (>= 0).
      gps_noise_std: GPS position noise of the observation, m (>= 0).
      compass_noise_std: compass heading noise, rad (>= 0).
      collisions: which collisions count against IS / DS / SR
        (``metrics.driving_score.COLLISION_MODES``): ``all`` (the paper's protocol) or
        ``at_fault`` (nuPlan's attribution); ``bench --collisions``.
      agents: the other agents (``sim.AGENT_MODELS``): ``log``
        (non-reactive replay) or ``idm`` (reactive IDM); ``bench --agents``.
    """

    dt: tuple[float, ...] = (0.1,)
    preset: tuple[str, ...] = ("paper",)
    control_every: tuple[int, ...] = (1,)
    latency: tuple[int, ...] = (0,)
    gps_noise_std: tuple[float, ...] = (0.0,)
    compass_noise_std: tuple[float, ...] = (0.0,)
    collisions: tuple[str, ...] = ("all",)
    agents: tuple[str, ...] = ("log",)


#: ``[sim]`` keys added after sweeps were first recorded, with the value an
#: older ``sweep.json`` without them stands for (resuming fills them in).
SIM_KEYS_ADDED = {"collisions": ["all"], "agents": ["log"]}

#: Aggregates a combined table can show (``summary.summary_of`` keys).
METRICS = (
    "success_rate", "driving_score", "route_completion", "infraction_score", "collisions_per_km",
    "red_light_per_km", "outside_route_lanes_pct", "km_driven", "task_success_rate", "efficiency_pct",
    "average_speed_kmh", "position_deviation_mean_m", "eval_time_s",
    "driving_score_all", "driving_score_at_fault", "success_rate_all", "success_rate_at_fault",
    "collisions_at_fault", "nuplan_score", "epdms",
)


@dataclasses.dataclass(frozen=True)
class OutputsSection:
    """``[outputs]``: what the combined tables hold.

    Attributes:
      metrics: columns of ``combined.csv`` / ``combined.md`` (``METRICS``);
        each is the mean over repetitions, with a ``<metric>_std`` column.
      compare: metrics shown in ``combined.md`` as one table each with the
        policies side by side (runs as rows).
      open_loop: also score waypoint policies open-loop (L2, ``bench --open-loop``).
    """

    metrics: tuple[str, ...] = (
        "success_rate", "driving_score", "route_completion", "infraction_score", "collisions_per_km",
        "red_light_per_km", "outside_route_lanes_pct",
    )
    compare: tuple[str, ...] = ("driving_score", "success_rate")
    open_loop: bool = False


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """A whole experiment file.

    Attributes:
      sweep: ``[sweep]``.  policies: ``[[policies]]`` (at least one).
      data: ``[data]``.  repetitions: ``[repetitions]``.  sim: ``[sim]``.
      outputs: ``[outputs]``.
    """

    sweep: SweepSection
    policies: tuple[PolicySpec, ...]
    data: DataSection = DataSection()
    repetitions: RepetitionsSection = RepetitionsSection()
    sim: SimSection = SimSection()
    outputs: OutputsSection = OutputsSection()

    def to_json(self) -> dict:
        """Plain JSON data (what ``sweep.json`` records)."""
        return json_safe(dataclasses.asdict(self))


def json_safe(obj):
    """Tuples as lists, recursively (so a config equals its JSON round trip)."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def load_config(path: str | Path) -> SweepConfig:
    """Read and check an experiment file (one-line ``DriveE2EError`` on any problem)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DriveE2EError(f"{path}: experiment config not found") from None
    except tomllib.TOMLDecodeError as e:
        raise DriveE2EError(f"{path}: not valid TOML ({e})") from None
    return parse_config(data, str(path))


def parse_config(data: dict, source: str = "<config>") -> SweepConfig:
    """``SweepConfig`` from parsed TOML ``data``; ``source`` names it in errors."""
    tables = {f.name: f for f in dataclasses.fields(SweepConfig)}
    unknown = [k for k in data if k not in tables]
    if unknown:
        raise DriveE2EError(f"{source}: unknown table [{unknown[0]}] (expected one of: {', '.join(tables)})")
    for name, table in (("sweep", "[sweep]"), ("policies", "[[policies]]")):
        if name not in data:
            raise DriveE2EError(f"{source}: missing {table}")
    pols = data["policies"]
    if not isinstance(pols, list) or not all(isinstance(p, dict) for p in pols):
        raise DriveE2EError(f"{source}: policies must be [[policies]] tables")
    if not pols:
        raise DriveE2EError(f"{source}: [[policies]] is empty (expected at least one policy)")
    hints = typing.get_type_hints(SweepConfig)
    kwargs = {"policies": tuple(_table(PolicySpec, p, source, f"[[policies]] #{i + 1}") for i, p in enumerate(pols))}
    for name, typ in hints.items():
        if name != "policies" and name in data:
            if not isinstance(data[name], dict):
                raise DriveE2EError(f"{source}: {name} must be a table [{name}], got {data[name]!r}")
            kwargs[name] = _table(typ, data[name], source, f"[{name}]")
    cfg = SweepConfig(**kwargs)
    _check_values(cfg, source)
    return cfg


def _table(cls, table: dict, source: str, where: str):
    """One dataclass from one TOML table, every key type-checked."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for key in table:
        if key not in fields:
            raise DriveE2EError(f"{source}: {where} unknown key {key!r} (expected one of: {', '.join(fields)})")
    missing = [n for n, f in fields.items()
               if n not in table and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise DriveE2EError(f"{source}: {where} missing key {missing[0]!r}")
    return cls(**{k: _value(hints[k], v, source, where, k) for k, v in table.items()})


def _value(typ, value, source: str, where: str, key: str):
    """``value`` converted to ``typ`` (str, int, float, bool, dict, X | None, tuple[X, ...])."""
    origin = typing.get_origin(typ)
    if origin is tuple:
        item = typing.get_args(typ)[0]
        items = value if isinstance(value, list) else [value]
        if not items:
            raise DriveE2EError(f"{source}: {where} {key}: empty list (expected at least one {_kind(item)})")
        return tuple(_value(item, v, source, where, key) for v in items)
    if origin in (typing.Union, types.UnionType):  # X | None: TOML has no null, so always X
        return _value(next(a for a in typing.get_args(typ) if a is not type(None)), value, source, where, key)
    ok = {
        str: isinstance(value, str),
        bool: isinstance(value, bool),
        int: isinstance(value, int) and not isinstance(value, bool),
        float: isinstance(value, (int, float)) and not isinstance(value, bool),
        dict: isinstance(value, dict),
    }[typ]
    if not ok:
        raise DriveE2EError(f"{source}: {where} {key}: expected {_kind(typ)}, got {value!r}")
    return float(value) if typ is float else value


def _kind(typ) -> str:
    return {str: "a string", bool: "true or false", int: "an integer", float: "a number", dict: "a table"}[typ]


def _check_values(cfg: SweepConfig, source: str) -> None:
    """Ranges and names (types are checked by ``_table``)."""

    def bad(where: str, msg: str):
        raise DriveE2EError(f"{source}: {where} {msg}")

    if not cfg.sweep.name or any(not (c.isalnum() or c in "-_.") for c in cfg.sweep.name):
        bad("[sweep]", f"name: {cfg.sweep.name!r} must be non-empty letters, digits, '-', '_' or '.'")
    names = [p.name for p in cfg.policies if p.name]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        bad("[[policies]]", f"name {dup[0]!r} is used twice (policy names must be unique)")
    d, s, r, o = cfg.data, cfg.sim, cfg.repetitions, cfg.outputs
    if d.limit is not None and d.limit < 1:
        bad("[data]", f"limit: must be >= 1, got {d.limit}")
    for v in d.variants:
        if v not in variant_names():
            bad("[data]", f"variants: unknown variant {v!r} (expected one of: {', '.join(variant_names())})")
    for t in d.tasks:
        if t not in TASKS:
            bad("[data]", f"tasks: unknown task {t!r} (expected one of: {', '.join(TASKS)})")
    if r.count < 1:
        bad("[repetitions]", f"count: must be >= 1, got {r.count}")
    checks = (("dt", lambda x: x > 0, "> 0 s"), ("control_every", lambda x: x >= 1, ">= 1"),
              ("latency", lambda x: x >= 0, ">= 0"), ("gps_noise_std", lambda x: x >= 0, ">= 0 m"),
              ("compass_noise_std", lambda x: x >= 0, ">= 0 rad"))
    for key, ok, want in checks:
        for x in getattr(s, key):
            if not ok(x):
                bad("[sim]", f"{key}: must be {want}, got {x}")
    for p in s.preset:
        if p not in SCORE_PRESETS:
            bad("[sim]", f"preset: unknown preset {p!r} (expected one of: {', '.join(SCORE_PRESETS)})")
    for key, choices, what in (("collisions", COLLISION_MODES, "collision mode"),
                               ("agents", AGENT_MODELS, "agent model")):
        for v in getattr(s, key):
            if v not in choices:
                bad("[sim]", f"{key}: unknown {what} {v!r} (expected one of: {', '.join(choices)})")
    for key in ("metrics", "compare"):
        for m in getattr(o, key):
            if m not in METRICS:
                bad("[outputs]", f"{key}: unknown metric {m!r} (expected one of: {', '.join(METRICS)})")
    for where, section in (("[data]", d), ("[sim]", s)):
        for f in dataclasses.fields(section):
            vals = getattr(section, f.name)
            if isinstance(vals, tuple) and len(set(vals)) != len(vals):
                bad(where, f"{f.name}: lists a value twice")


def variant_names() -> tuple[str, ...]:
    """The suite variants ``bench`` knows (``eval.variants.VARIANTS``)."""
    return tuple(VARIANTS)


def with_out(cfg: SweepConfig, out: str | Path | None) -> SweepConfig:
    """``cfg`` writing to ``out`` (None = unchanged)."""
    return cfg if out is None else dataclasses.replace(cfg, sweep=dataclasses.replace(cfg.sweep, out=str(out)))


def out_dir(cfg: SweepConfig) -> Path:
    """The sweep's results folder."""
    return Path(cfg.sweep.out) if cfg.sweep.out else Path("results") / "sweeps" / cfg.sweep.name

