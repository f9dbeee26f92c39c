"""The reference demonstration dataset: what a policy sees along the log, and the label.

``build_dataset`` rolls the ``log_replay`` policy out over a suite split with
the sensors a model declares and records, every ``every``-th simulation step
(default 5 x 0.1 s = 2 Hz), one ``Sample``: the ``HistoryObservation`` a
policy gets at that step (the ego history kept by the same
``models.base.push_history`` the policy uses) and its ``Target``
(``models.base.targets_from_log``). Samples count while the episode runs and
the next logged waypoint exists.

The BEV is rendered at ``DatasetConfig.bev_size`` / ``bev_resolution``
(default 128 x 128 at 0.5 m/px; TCP is sized for 64 x 64 at 1 m/px, so
``bev_size=64`` renders its input directly instead of pooling): the manifest
records it, ``DemoDataset.check_model`` refuses a model that cannot read it,
and ``training_bev`` hands it to the policy of a checkpoint trained on it, so
evaluation renders the same BEV.

On disk (``OUT/``): ``shard-00000.npz`` ... one per chunk of scenarios, the
flattened leaves (``"obs.ego"``, ``"target.waypoints"``, ...) stacked over
samples, each written atomically; ``manifest.json`` (written last) with the
suite, version, split, sensors, the BEV size, sampling, per-shard counts and
every leaf's per-sample shape and dtype. ``DemoDataset(OUT).batches(...)`` streams
shuffled fixed-size batches holding only a few shards in memory.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import math
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import device_batch
from drivee2e_jax.files import ForeignFiles, OwnFolder, atomic_write, atomic_write_json, check_own_folder
from drivee2e_jax.jsonfile import BadJSON, read_json
from drivee2e_jax.models import base
from drivee2e_jax.models.checkpoint import DATA_FORMAT as FORMAT
from drivee2e_jax.models.checkpoint import DATA_MANIFEST as MANIFEST
from drivee2e_jax.models.checkpoint import DEFAULT_BEV, bev_of_manifest
from drivee2e_jax.observe import sensors as sens
from drivee2e_jax.observe.bev import BevConfig, check_bev
from drivee2e_jax.observe.sensors import SensorConfig
from drivee2e_jax.policy import load_policy, reference_policy_dir
from drivee2e_jax.rollout import longest_episode
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.scenario.flat import flatten_dataclass, unflatten_dataclass
from drivee2e_jax.sim import SimConfig, Simulator

#: The BEV rendered unless ``DatasetConfig`` sizes it (= the simulator's default).


@struct.dataclass
class Sample:
    """One demonstration sample: the policy input and its label.

    Attributes:
      obs: ``models.base.HistoryObservation``.
      target: ``models.base.Target``.
    """

    obs: base.HistoryObservation
    target: base.Target


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    """How demonstrations are recorded.

    Attributes:
      sensors: sensors rendered into the observation ("bev", "lidar").
      every: record every ``every``-th simulation step.
      num_waypoints, waypoint_dt: the target's future points.
      scenarios_per_shard: scenarios rolled out together and written as one shard.
      sim_dt: simulation step, s.
      bev_size: px, side of the square BEV (when "bev" is in ``sensors``).
      bev_resolution: m/px; None = the default BEV's 64 m extent / ``bev_size``.
    """

    sensors: tuple[str, ...] = ()
    every: int = 5
    num_waypoints: int = 6
    waypoint_dt: float = 0.5
    scenarios_per_shard: int = 25
    sim_dt: float = 0.1
    bev_size: int = DEFAULT_BEV.height
    bev_resolution: float | None = None

    def __post_init__(self):
        if self.every < 1 or self.scenarios_per_shard < 1 or self.num_waypoints < 1:
            raise DriveE2EError("dataset: every, scenarios_per_shard and num_waypoints must be >= 1")
        if self.bev_size < 1 or (self.bev_resolution is not None and self.bev_resolution <= 0):
            raise DriveE2EError(f"dataset: --bev-size must be >= 1 and --bev-resolution > 0, got "
                                f"{self.bev_size} and {self.bev_resolution}")
        if self.bev_resolution is None:
            object.__setattr__(self, "bev_resolution", DEFAULT_BEV.height * DEFAULT_BEV.resolution / self.bev_size)
        try:
            _ = self.sensor_config  # validates the BEV (tiles must divide it)
        except ValueError as e:
            raise DriveE2EError(f"dataset --sensors / --bev-size {self.bev_size} / --bev-resolution "
                                f"{self.bev_resolution:g}: {e}") from e

    @property
    def bev(self) -> BevConfig:
        """The BEV rendered when "bev" is in ``sensors``."""
        return dataclasses.replace(DEFAULT_BEV, height=self.bev_size, width=self.bev_size,
                                   resolution=float(self.bev_resolution))

    @property
    def sensor_config(self):
        """``observe.sensors.SensorConfig`` of the recording (ValueError on a bad one)."""

        return SensorConfig.for_policy(tuple(self.sensors), SensorConfig(bev=self.bev))


# --------------------------------------------------------------------------
# Flat <-> pytree
# --------------------------------------------------------------------------


def flatten(sample) -> dict:
    """{"obs.ego": leaf, ...} of a ``Sample`` (None slots left out)."""
    return {k: v for k, v in flatten_dataclass(sample).items() if v is not None}


def unflatten(flat: dict, cls=Sample):
    """Inverse of ``flatten`` (missing optional leaves become None)."""
    return unflatten_dataclass(cls, flat, optional=True)


# --------------------------------------------------------------------------
# Recording (jitted, one scenario vmapped)
# --------------------------------------------------------------------------


def _log_replay_policy():

    return load_policy(reference_policy_dir() / "log_replay.py")


def make_recorder(sim, cfg: DatasetConfig, n_records: int, assets_axes=None) -> Callable:
    """jit(vmap(one scenario)): (batch, keys, assets) -> (Sample (B, N, ...), keep (B, N)).

    Sensors render only at recorded steps: the steps in between run a copy
    of ``sim`` with the sensors off (same states, same log-replay actions)."""
    demo = _log_replay_policy()
    plain = type(sim)(dataclasses.replace(sim.config, sensors=SensorConfig.for_policy((), sim.config.sensors)))

    def act(ob):
        return demo.act(None, ob, None, None)[0]

    def one(scenario, key, assets):
        state, obs = sim.reset(key, scenario, assets)

        def replay_step(carry, _):
            st, ob = carry
            st, ob, _ = sim.step(scenario, st, act(ob), assets)
            return (st, ob), None

        def plain_step(carry, _):  # carries the next action: no sensor slots in the carry
            st, a = carry
            st, ob, _ = plain.step(scenario, st, a)
            return (st, act(ob)), None

        def advance(st, ob):
            """``cfg.every`` log-replay steps; only the last one renders the sensors."""
            if not sim.config.sensors.enabled:
                (st, ob), _ = jax.lax.scan(replay_step, (st, ob), None, length=cfg.every)
                return st, ob
            (st, a), _ = jax.lax.scan(plain_step, (st, act(ob)), None, length=cfg.every - 1)
            st, ob, _ = sim.step(scenario, st, a, assets)
            return st, ob

        def record(carry, _):
            st, ob, hist = carry
            hist = base.push_history(hist, ob)
            target = base.targets_from_log(scenario, st.ego, ob, cfg.num_waypoints, cfg.waypoint_dt)
            sample = Sample(obs=base.with_history(ob, hist), target=target)
            keep = ~st.episode.done & target.waypoint_valid[0]
            st, ob = advance(st, ob)
            return (st, ob, hist), (sample, keep)

        _, out = jax.lax.scan(record, (state, obs, base.empty_history(obs)), None, length=n_records)
        return out

    return jax.jit(jax.vmap(one, in_axes=(0, 0, assets_axes)))


def _np_save_npz(arrays: dict) -> Callable:
    def write(f):
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        f.write(buf.getvalue())

    return write


#: What a dataset folder holds (no marker: a killed build leaves shards without
#: manifest.json and a rerun redoes them); any other file refuses the folder.
DATASET_FOLDER = OwnFolder("dataset", None, (MANIFEST, "shard-*.npz"))


def build_dataset(suite, split: str, out: str | Path, cfg: DatasetConfig = DatasetConfig(), *,
                  limit: int | None = None, seed: int = 0,
                  progress: Callable[[int, int], None] | None = None) -> dict:
    """Record the demonstrations of ``suite``'s ``split`` into ``out``; returns the manifest.

    Args:
      suite: a ``scenario.Suite`` (or its name / folder).
      split: split name.  out: output folder (created; existing shards are
        overwritten; a folder holding other files than a dataset's,
        ``DATASET_FOLDER``, is refused: drivee2e never overwrites a user's file).
      cfg: ``DatasetConfig``.  limit: only the first ``limit`` scenarios.
      seed: PRNG seed (observation noise).  progress: ``progress(done, total)`` scenarios.
    """

    t0 = time.perf_counter()
    try:  # before any work: shards and the manifest overwrite only a dataset's own files
        check_own_folder(out, DATASET_FOLDER, redo=True)
    except ForeignFiles as e:
        raise DriveE2EError(str(e)) from None
    suite = load_suite(suite)
    packed = suite.pack(split)
    n = len(packed.meta) if limit is None else min(limit, len(packed.meta))
    if n == 0:
        raise DriveE2EError(f"dataset: split {split!r} of suite {suite.name!r} has no scenarios")
    packed = packed.select(np.arange(n))
    sim_cfg = SimConfig(dt=cfg.sim_dt, sensors=cfg.sensor_config)
    sim = Simulator(sim_cfg)
    assets = sens.build_assets(packed, sim_cfg.sensors, suite.maps)
    batch, _ = device_batch(packed)
    total = longest_episode(sim, batch)
    n_records = max(1, math.ceil(total / cfg.every))
    run = make_recorder(sim, cfg, n_records, sens.assets_axes(assets))

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    c = cfg.scenarios_per_shard
    shards, shapes, count = [], {}, 0
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    for s, start in enumerate(range(0, n, c)):
        # Pad the last chunk to the same size (one compilation), then drop the pad.
        rows = np.minimum(np.arange(start, start + c), n - 1)
        real = np.arange(start, start + c) < n
        chunk = jax.tree_util.tree_map(lambda a, rows=rows: a[rows], batch)
        ch_assets = None if assets is None else assets.replace(map_index=jnp.asarray(assets.map_index[rows]))
        samples, keep = run(chunk, keys[rows], ch_assets)
        keep = np.asarray(keep) & real[:, None]
        flat = {k: np.asarray(v)[keep] for k, v in flatten(samples).items()}
        name = f"shard-{s:05d}.npz"
        atomic_write(out / name, _np_save_npz(flat), binary=True)
        m = int(keep.sum())
        shards.append({"file": name, "count": m, "scenarios": int(real.sum())})
        shapes = {k: {"shape": list(v.shape[1:]), "dtype": str(v.dtype)} for k, v in flat.items()}
        count += m
        if progress:
            progress(min(start + c, n), n)
    manifest = {
        "format": FORMAT,
        "suite": suite.name,
        "suite_version": suite.version,
        "split": split,
        "num_scenarios": n,
        "sensors": list(cfg.sensors),
        "bev": None if sim_cfg.sensors.bev is None else {
            "height": cfg.bev_size, "width": cfg.bev_size, "resolution": cfg.bev_resolution},
        "config": dataclasses.asdict(cfg),
        "history_len": base.HISTORY_LEN,
        "history_dt": base.HISTORY_DT,
        "count": count,
        "shards": shards,
        "leaves": shapes,
        "bytes": int(sum((out / s["file"]).stat().st_size for s in shards)),
        "build_s": round(time.perf_counter() - t0, 2),
    }
    atomic_write_json(out / MANIFEST, manifest)
    return manifest


# --------------------------------------------------------------------------
# Streaming loader
# --------------------------------------------------------------------------


class DemoDataset:
    """A recorded dataset folder; ``batches`` streams it.

    Attributes:
      path: the folder.  manifest: its ``manifest.json`` (dict).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        mf = self.path / MANIFEST
        if not mf.is_file():
            raise DriveE2EError(f"{mf}: no dataset manifest (build one with `drivee2e dataset build`)")
        try:
            self.manifest = read_json(mf)
        except BadJSON as e:
            raise DriveE2EError(f"{mf}: unreadable manifest ({e.detail})") from e
        except OSError as e:
            raise DriveE2EError(f"{mf}: unreadable manifest ({e})") from e
        if self.manifest.get("format") != FORMAT:
            raise DriveE2EError(f"{mf}: format {self.manifest.get('format')!r}, expected {FORMAT}")

    def __len__(self) -> int:
        return int(self.manifest["count"])

    @property
    def bev(self) -> BevConfig | None:
        """The BEV the samples were rendered at (None: no BEV)."""
        return bev_of_manifest(self.manifest)

    def check_model(self, model, name: str | None = None) -> None:
        """One-line DriveE2EError unless ``model`` can train on this data: it
        has every sensor the model requires, at a BEV size the model reads
        (``observe.bev.check_bev``)."""
        name = name or getattr(model, "name", "?")
        missing = set(getattr(model, "required_sensors", ())) - set(self.manifest["sensors"])
        if missing:
            raise DriveE2EError(f"{self.path}: model {name!r} needs sensors {sorted(missing)} the dataset lacks "
                                f"(rebuild with `drivee2e dataset build --sensors {','.join(sorted(missing))}`)")
        check_bev(self.bev, model, f"{self.path}")

    @property
    def digest(self) -> str:
        """sha256 of the manifest file: identifies the data a run trained on."""
        return hashlib.sha256((self.path / MANIFEST).read_bytes()).hexdigest()

    def load_shard(self, i: int) -> dict:
        """The flat arrays of shard ``i`` (numpy)."""
        f = self.path / self.manifest["shards"][i]["file"]
        try:
            with np.load(f) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError) as e:
            raise DriveE2EError(f"{f}: unreadable shard ({e})") from e

    def first(self) -> Sample:
        """The first sample (unbatched, numpy leaves)."""
        for i, s in enumerate(self.manifest["shards"]):
            if s["count"]:
                return unflatten({k: v[0] for k, v in self.load_shard(i).items()})
        raise DriveE2EError(f"{self.path}: the dataset holds no samples")

    def steps_per_epoch(self, batch_size: int) -> int:
        return len(self) // batch_size

    def batches(self, batch_size: int, *, seed: int = 0, epoch: int = 0, shuffle_shards: int = 4,
                skip: int = 0) -> Iterator[Sample]:
        """Shuffled ``Sample`` batches (numpy leaves, leading axis ``batch_size``).

        Deterministic in (seed, epoch): shard order and the order inside a
        buffer of ``shuffle_shards`` shards are permuted by
        ``np.random.default_rng([seed, epoch])``. The remainder that does not
        fill a batch is dropped (fixed shapes, one compilation); an epoch
        yields exactly ``steps_per_epoch(batch_size)`` batches. ``skip`` drops
        the first batches (resuming mid-epoch).
        """
        rng = np.random.default_rng([seed, epoch])
        order = rng.permutation(len(self.manifest["shards"]))
        pending: dict | None = None
        emitted = 0
        for g in range(0, len(order), max(1, shuffle_shards)):
            parts = [self.load_shard(int(i)) for i in order[g:g + shuffle_shards]]
            if pending is not None:
                parts.insert(0, pending)
            buf = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
            m = len(next(iter(buf.values())))
            perm = rng.permutation(m)
            full = m // batch_size * batch_size
            for b in range(0, full, batch_size):
                if emitted >= skip:
                    idx = perm[b:b + batch_size]
                    yield unflatten({k: v[idx] for k, v in buf.items()})
                emitted += 1
            pending = {k: v[perm[full:]] for k, v in buf.items()}
