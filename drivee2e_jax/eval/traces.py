"""Episode traces: re-simulate scenarios of a results folder into host-side arrays.

A results folder (``drivee2e bench``, see ``io.results``) stores per-scenario
rows and infraction events, not trajectories. Rollouts are deterministic, so
``trace_episodes(results_dir)`` re-runs the chosen episodes with the run's
exact settings (suite, split, task, limit, dt, control timing, preset, seed:
the same PRNG key per scenario and the same policy parameters as the bench)
and returns one :class:`EpisodeTrace` per episode: numpy arrays for the
episode player (``to_jsonable``) and the MCAP export (``io.mcap_export``).
The re-simulated Driving Score is checked against the stored one
(``EpisodeTrace.reproduced``; a mismatch warns).

What is reproduced from ``run.json`` / the policy file: suite (+ version
check), split, task, limit, variant, dt, preset, control timing, observation
noise, seed (repetition 0), ``policy_path`` + ``policy_kwargs``.

Time axis: index ``k`` of every per-step array is the state at
``times[k] = k * dt`` s, ``k = 0`` the reset state (the ego on its logged
start pose) up to the step that ended the episode (``T = steps + 1``).
Conventions per field group:

* state fields (ego pose, agents, signals, sensors, ``route_completion``,
  ``speed``) describe the instant ``times[k]``;
* action fields (``controls``, ``plan_xy``) are what the policy applied FROM
  state k (during the step k -> k+1); the last state has none (zeros /
  ``plan_valid`` False);
* ``timeline`` facts and events describe the step that ENDED at ``times[k]``
  (index 0 is empty: zeros).

Frames and units as in ``types``: x east, y north, m; yaw CCW from +x,
rad; s; m/s. Positions are in the scenario's LOCAL frame, the one the
simulator computes in (the packed arrays: world minus ``meta.origin``, see
``scenario.origin``); ``EpisodeTrace.origin`` is that frame's world (x, y)
(float64), so world = local + origin. The infraction events (``events``,
``resim_events``) are in the world frame, as in the results folder. Sensors are rendered from the SIMULATED state of each instant.
The BEV frame k is ``Simulator.observe`` of state k, the function the
rollout renders the policy's observation with (same route window around the
ego's route progress, ``observe.bev.route_window``): for a policy that sees a
BEV it is bit for bit the BEV the policy received at step k, at the policy's
own ``sensor_config`` (size, resolution, channels); a policy without one gets
the trace's BEV (``default_sensor_config``). The LiDAR is the trace's own light
point cloud (``observe.lidar``), whatever LiDAR the policy saw.
"""

from __future__ import annotations

import base64
import dataclasses
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from drivee2e_jax import hostbridge, replay
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval.closedloop import begin_rollout, device_batch, events_to_world, with_policy_sensors
from drivee2e_jax.eval.results import check_policy_current, check_run_current, policy_fingerprint, run_fingerprint
from drivee2e_jax.eval.runspec import RUN_JSON, RunSpec, batch_sha256, folder_fingerprint
from drivee2e_jax.geometry import from_frame
from drivee2e_jax.jsonfile import read_json
from drivee2e_jax.metrics import episode as ep
from drivee2e_jax.observe import registry
from drivee2e_jax.observe import sensors as sensors_mod
from drivee2e_jax.observe.bev import BevConfig
from drivee2e_jax.observe.lidar import LidarConfig
from drivee2e_jax.observe.palette import bev_rgb
from drivee2e_jax.observe.png import png_bytes
from drivee2e_jax.observe.sensor_api import SensorContext, SensorFrames
from drivee2e_jax.observe.sensors import SensorConfig
from drivee2e_jax.policy import load_policy, resolve_policy_path
from drivee2e_jax.rollout import ControlTiming, Rollout, balanced_chunk, episode_results, longest_episode
from drivee2e_jax.scenario.stream import SuiteIndex
from drivee2e_jax.sim import SimConfig, Simulator
from drivee2e_jax.types import Waypoints, to_numpy

#: The built-in sensors a trace renders by default (``trace_episodes(sensors=...)``);
#: any sensor of ``observe.registry`` can be asked for.
TRACE_SENSORS = ("bev", "lidar")
#: |re-simulated - stored| Driving Score above which a trace counts as not reproduced.
DS_TOLERANCE = 1e-3
#: Episodes whose sensor frames ``iter_traces`` renders per compiled call (and holds at once).
TRACE_CHUNK = 8


def default_sensor_config(sensors: Sequence[str] = TRACE_SENSORS):
    """The trace's ``SensorConfig``: 128x128 BEV at 0.5 m/px (default channels)
    and a light 16-channel x 180-bin LiDAR (2880 beams; a file per episode
    stays ~10 MB), any other registered sensor (``observe.registry``) at its
    ``default_config()``, only those named in ``sensors``."""

    known = registry.names()
    bad = [s for s in sensors if s not in known]
    if bad:
        raise DriveE2EError(f"sensors: unknown {bad[0]!r}; expected some of {', '.join(known)}")
    cfg = SensorConfig(
        bev=BevConfig() if "bev" in sensors else None,
        lidar=LidarConfig(channels=16, azimuth_bins=180) if "lidar" in sensors else None,
    )
    for name in sensors:
        if name not in registry.SLOTTED:
            cfg = cfg.with_sensor(name, registry.get(name).default_config())
    return cfg


# --------------------------------------------------------------------------
# The trace
# --------------------------------------------------------------------------


@dataclasses.dataclass
class StaticMap:
    """The episode's static map, padding removed (world frame, m).

    Attributes:
      lanes:            list of L arrays (N_i, 2), lane centrelines in driving direction.
      lane_type:        (L,) int ``types.LaneType``.
      lane_speed_limit: (L,) float m/s.
      boundaries:       list of E arrays (N_i, 2), lane boundaries and road edges.
      boundary_marking: (E,) int ``types.Marking``.
      crosswalks:       list of C polygons (V_i, 2).
      stop_lines:       (S, 2, 2) float segment end points (valid lines only).
      stop_line_row:    (S,) int the line's row in the packed map (what a
                        ``red_light`` event's ``stop_line`` refers to).
      stop_line_lane:   (S,) int row of the lane the line guards (-1 none).
      drivable:         list of G polygons (V_i, 2), the drivable area.
      obstacles:        list of O polygons (V_i, 2), static obstacle footprints.
      obstacle_height:  (O,) float m.
    """

    lanes: list
    lane_type: np.ndarray
    lane_speed_limit: np.ndarray
    boundaries: list
    boundary_marking: np.ndarray
    crosswalks: list
    stop_lines: np.ndarray
    stop_line_row: np.ndarray
    stop_line_lane: np.ndarray
    drivable: list
    obstacles: list
    obstacle_height: np.ndarray


@dataclasses.dataclass
class AgentsTrace:
    """Every non-ego logged agent replayed at the trace's times (``replay.agents_at``).

    Attributes:
      track_id: (A,) int source track id.   category: (A,) int ``types.Category``.
      size:     (A, 3) float length, width, height, m.
      xy:       (T, A, 2) float box centre, m.   yaw: (T, A) float rad.
      vel:      (T, A, 2) float world-frame velocity, m/s.
      valid:    (T, A) bool the agent exists at times[k] (values are
                finite but meaningless where False).
    """

    track_id: np.ndarray
    category: np.ndarray
    size: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    vel: np.ndarray
    valid: np.ndarray


@dataclasses.dataclass
class EpisodeTrace:
    """One re-simulated episode (module docstring: time axis conventions).

    Attributes:
      scenario_id, policy: names.   meta: {split, intersection_id, map_id,
        behavior, weather, time_of_day}.
      row: the stored per-scenario results row (``io.results`` columns).
      dt: sim step, s.   times: (T,) float s, ``k * dt``.
      ego_size: (3,) float length, width, height, m.
      ego_xy: (T, 2) m.  ego_yaw: (T,) rad.  ego_speed: (T,) m/s.
      ego_accel: (T,) m/s^2.  ego_steer: (T,) front-wheel angle, rad.
      ego_yaw_rate: (T,) rad/s.
      controls: (T, 3) float applied throttle [0,1], brake [0,1], steer [-1,1].
      plan_xy: (T, K, 2) float the policy's waypoints in the (local) map frame, m
        (None for a controls policy).   plan_valid: (T,) bool.
      agents: AgentsTrace.
      signals: (T, S) int ``types.SignalState`` per valid stop line
        (columns as ``map.stop_lines``).
      map: StaticMap.
      route_xy: (R, 2) m.  route_arc: (R,) m.  route_command: (R,) int ``types.Command``.
      route_length: m.
      timeline: {name: (T,) array} per-step metric timelines: ``speed`` m/s,
        ``route_completion`` %, ``facts.<f>`` for every scalar
        ``infractions.StepFacts`` field (``lane_offset``, ``front_distance`` m
        may be inf), ``events.<e>`` for every ``metrics.episode.StepEvents`` field.
      events: the stored infraction events (type, t s, x, y m world frame, ...).
      resim_events: the same extracted from the re-simulation (world frame).
      origin: (2,) float64 world (x, y) of the local frame's (0, 0), m.
      driving_score, stored_driving_score: re-simulated and stored DS.
      reproduced: |difference| <= DS_TOLERANCE.
      bev: {channel: (T, H, W) bool} (a ``PackedBev``) or None; image row 0 is farthest ahead,
        column 0 on the ego's left (``observe.bev``).  bev_resolution: m/px.
      lidar_points: (T, N, 3) float32 returns in the ego frame (origin at the
        box centre on the ground, x forward, y left, z up), m, or None.
      lidar_class: (T, N) int8 hit class (``observe.lidar``: 1 ground,
        2 obstacle, 3 + Category agents).  lidar_valid: (T, N) bool.
      sensors: {name: ``observe.sensor_api.SensorFrames``} of every other
        registered sensor traced (``Sensor.trace`` per instant, leading axis
        T, and its config); shown by the player and the MCAP export as the
        sensor's ``display`` says.
      sensor_stride: ``bev`` and ``sensors`` hold instants 0, s, 2s, ...
        only: ceil(T / s) frames, frame i at ``times[i * s]`` (1: every
        instant; ``iter_traces(sensor_stride=s)``).
      lidar_stride: the same for ``lidar_*``.
    """

    scenario_id: str
    policy: str
    meta: dict
    row: dict
    dt: float
    times: np.ndarray
    ego_size: np.ndarray
    ego_xy: np.ndarray
    ego_yaw: np.ndarray
    ego_speed: np.ndarray
    ego_accel: np.ndarray
    ego_steer: np.ndarray
    ego_yaw_rate: np.ndarray
    controls: np.ndarray
    plan_xy: np.ndarray | None
    plan_valid: np.ndarray
    agents: AgentsTrace
    signals: np.ndarray
    map: StaticMap
    route_xy: np.ndarray
    route_arc: np.ndarray
    route_command: np.ndarray
    route_length: float
    timeline: dict
    events: list
    resim_events: list
    driving_score: float
    stored_driving_score: float
    reproduced: bool
    bev: dict | None = None
    bev_resolution: float | None = None
    lidar_points: np.ndarray | None = None
    lidar_class: np.ndarray | None = None
    lidar_valid: np.ndarray | None = None
    sensors: dict = dataclasses.field(default_factory=dict)
    sensor_stride: int = 1
    lidar_stride: int = 1
    origin: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))

    @property
    def num_steps(self) -> int:
        """T, the number of traced instants (steps + 1)."""
        return int(self.times.shape[0])


# --------------------------------------------------------------------------
# Reading the results folder
# --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RunRecord:
    """What ``trace_episodes`` needs from a results folder.

    Attributes:
      path: the results folder.  info: run.json as read.
      policy: the policy traced.  data: its ``policies/<policy>.json``.
      spec: run.json as a ``RunSpec`` (the settings re-simulation uses).
    """

    path: Path
    info: dict  # run.json
    policy: str
    data: dict  # policies/<policy>.json
    spec: RunSpec


def read_run(results_dir: str | Path, policy: str | None = None) -> RunRecord:
    """run.json and one policy's file. ``policy=None`` = the run's first policy
    (order of summary.json, else file name). Raises DriveE2EError (one line)."""
    path = Path(results_dir)
    meta = path / "run.json"
    if not meta.is_file():
        raise DriveE2EError(f"{path}: not a drivee2e results folder (no run.json; expected the --out of `drivee2e bench`)")
    info = _read_json(meta)
    try:
        spec = RunSpec.from_json(info)
    except DriveE2EError as e:
        raise DriveE2EError(f"{meta}: {e}") from e
    files = _policy_files(path)
    order = list(files)
    name = order[0] if policy is None else policy
    if name not in files:
        raise DriveE2EError(f"--policy {policy}: not in {path} (expected one of {', '.join(order)})")
    return RunRecord(path=path, info=info, policy=name, data=files[name], spec=spec)


def _policy_files(path: Path) -> dict[str, dict]:
    """{policy name: its ``policies/<name>.json``} of a results folder, in the
    run's order (summary.json's, else by file name). Raises DriveE2EError when none."""
    files = {}
    for f in sorted((path / "policies").glob("*.json")):
        data = _checked_policy_file(f, _read_json(f))
        files[str(data.get("policy", f.stem))] = data
    if not files:
        raise DriveE2EError(f"{path / 'policies'}: no finished policy file (run `drivee2e bench` to the end first)")
    order = list(files)
    if (path / "summary.json").is_file():
        summary = _read_json(path / "summary.json")
        listed = summary.get("policies") if isinstance(summary, dict) else None
        if not isinstance(listed, dict):
            raise DriveE2EError(f"{path / 'summary.json'}: a corrupt results file: expected a JSON object whose "
                                f"\"policies\" is an object (policy name -> summary), as `drivee2e bench` writes it, "
                                f"got {_kind(summary if listed is None else listed)}")
        order = [p for p in listed if p in files] + [p for p in order if p not in listed]
    return {p: files[p] for p in order}


def _checked_policy_file(path: Path, data: Any) -> dict:
    """``data`` of ``policies/<name>.json`` when it has what ``view`` /
    ``export-mcap`` read (an object with a ``rows`` list of objects with a
    ``scenario_id``); else DriveE2EError naming the file and what was expected."""
    expected = ("a JSON object with \"policy\" and \"rows\" (a list of scenario rows with \"scenario_id\"), "
                "as `drivee2e bench` writes it")
    rows = data.get("rows") if isinstance(data, dict) else None
    if not isinstance(rows, list):
        got = _kind(data) if not isinstance(data, dict) else ("an object without \"rows\"" if "rows" not in data
                                                               else f"\"rows\" {_kind(rows)}")
        raise DriveE2EError(f"{path}: a corrupt results file: expected {expected}, got {got}; "
                            "rerun `drivee2e bench` for this policy")
    bad = next((i for i, r in enumerate(rows) if not isinstance(r, dict) or "scenario_id" not in r), None)
    if bad is not None:
        raise DriveE2EError(f"{path}: a corrupt results file: expected {expected}, got rows[{bad}] "
                            f"{_kind(rows[bad]) if not isinstance(rows[bad], dict) else 'without scenario_id'}; "
                            "rerun `drivee2e bench` for this policy")
    return data


def _kind(value: Any) -> str:
    """A JSON value's kind for an error line: 'an empty list', 'a list of 3', 'a string', ..."""
    if isinstance(value, list):
        return f"a list of {len(value)}" if value else "an empty list"
    if isinstance(value, dict):
        return "an object"
    return {str: "a string", bool: "a boolean", type(None): "null"}.get(type(value), "a number")


def run_policies(results_dir: str | Path) -> list[str]:
    """The finished policies of a results folder, in the run's order.
    Raises DriveE2EError (one line) on a folder that is not a finished run."""
    return list(_policy_files(read_run(results_dir).path))


def run_scenarios(results_dir: str | Path, policy: str | None = None) -> list[str]:
    """Scenario ids of ``policy``'s stored rows (the first repetition), in run order."""
    return list(stored_rows(read_run(results_dir, policy)))


def _read_json(path: Path) -> Any:
    try:
        return read_json(path)  # BadJSON (a DriveE2EError) names the file and what was expected
    except OSError as e:
        raise DriveE2EError(f"{path}: unreadable ({e})") from e


def stored_rows(run: RunRecord) -> dict[str, dict]:
    """scenario id -> its stored row (the first repetition)."""
    return {r["scenario_id"]: r for r in run.data["rows"] if not r.get("repetition")}


def _load_run_policy(run: RunRecord):
    """The run's policy, loaded as the bench loaded it (path + keyword arguments)."""
    return load_policy(_policy_file(run), **(run.data.get("policy_kwargs") or {}))


def _portable_policy_path(run: RunRecord) -> str | None:
    """The policy file from the policy file's ``provenance.policy`` (written by
    ``eval.results.stored_path``): a zoo name, or a path relative to the
    results folder (a moved folder, another installation); None if neither."""
    stored = (run.data.get("provenance") or {}).get("policy")
    if not stored:
        return None
    inside = Path(run.path) / stored
    if inside.is_file():
        return str(inside)
    try:
        return str(resolve_policy_path(stored))
    except DriveE2EError:
        return None


def _policy_file(run: RunRecord) -> str:
    """The run's policy file: ``policy_path``, else the portable recorded one."""
    path = run.data.get("policy_path")
    if not path:
        raise DriveE2EError(f"{run.path}/policies: {run.policy}'s file has no policy_path")
    if not Path(path).is_file():
        path = _portable_policy_path(run) or path
    if not Path(path).is_file():
        raise DriveE2EError(f"{path}: the policy file of {run.policy!r} recorded in {run.path} is missing "
                            "(trace from the folder the bench ran in)")
    return str(path)


def check_current(run: RunRecord, packed) -> None:
    """Refuse (DriveE2EError, one line saying what changed) to re-simulate a
    stale run: the fingerprints bench compares on resume
    (``eval.results.check_run_current`` / ``check_policy_current``), with the
    suite and the policy as they are now. ``packed``: the run's batch
    (``RunSpec.batch(...).limited()``)."""
    stored = run.info.get("fingerprint") if isinstance(run.info, dict) else None
    suite = {}
    if isinstance(stored, dict) and "suite_files_sha256" in stored:  # a run streamed from a suite folder
        spec = run.spec
        suite["suite_files_sha256"] = folder_fingerprint(SuiteIndex.open(spec.suite), spec.split, spec.num_scenarios)
    else:
        suite["suite_sha256"] = batch_sha256(packed)
    check_run_current(run.path, run.info, run_fingerprint(**suite))
    if "remote" not in (run.data.get("fingerprint") or {}):
        kwargs = run.data.get("policy_kwargs") or {}
        check_policy_current(run.path, run.policy, run.data, policy_fingerprint(_policy_file(run), kwargs))


def check_results(results_dir: str | Path, policies: Sequence[str] | None = None) -> None:
    """``check_current`` for each of ``policies`` (default: every policy) of a
    results folder, before a reader writes anything (``drivee2e view``)."""
    names = list(policies or run_policies(results_dir))
    first = read_run(results_dir, names[0])
    _, packed = _run_packed(first)
    for name in names:
        check_current(first if name == first.policy else read_run(results_dir, name), packed)


def _run_packed(run: RunRecord):
    """(suite, the packed batch the bench evaluated: task-filtered, limited,
    variant applied with the same mask cache label): ``RunSpec.batch``."""

    spec = run.spec
    suite = spec.load_suite()
    if spec.suite_version is not None and str(suite.version) != str(spec.suite_version):
        warnings.warn(f"{run.path}: run on suite version {spec.suite_version}, now {suite.version}; "
                      "traces may differ", stacklevel=3)
    return suite, spec.batch(suite).limited()


def select_rows(scenario_ids_all: Sequence[str], wanted: Sequence[str] | None) -> np.ndarray:
    """Rows of ``wanted`` ids in ``scenario_ids_all`` (all when None).
    An unknown id raises DriveE2EError listing a few valid ones."""
    ids = [str(s) for s in scenario_ids_all]
    if wanted is None:
        return np.arange(len(ids))
    where = {s: i for i, s in enumerate(ids)}
    for s in wanted:
        if s not in where:
            few = ", ".join(ids[:5]) + (", ..." if len(ids) > 5 else "")
            raise DriveE2EError(f"--scenario {s}: not in this run ({len(ids)} scenarios: {few})")
    return np.array([where[s] for s in dict.fromkeys(wanted)], np.int64)


# --------------------------------------------------------------------------
# Re-simulation
# --------------------------------------------------------------------------


def trace_episodes(
    results_dir: str | Path,
    policy: str | None = None,
    scenario_ids: Sequence[str] | None = None,
    *,
    sensors: Sequence[str] = TRACE_SENSORS,
    sensor_config=None,
    limit: int | None = None,
) -> list[EpisodeTrace]:
    """Re-simulate episodes of a results folder; one trace per episode.

    Args:
      results_dir: a ``drivee2e bench`` output folder.
      policy: policy name in it (None: the run's first policy).
      scenario_ids: ids to trace (None: every scenario of the run).
      sensors: names of registered sensors (``observe.registry``) to render
        per step (``()``: none; default the built-in ``("bev", "lidar")``).
      sensor_config: an ``observe.sensors.SensorConfig`` overriding
        ``default_sensor_config(sensors)``; its BEV is used only for a policy
        that sees none (``trace_bev_sensors``).
      limit: only the first N chosen scenarios.

    Every trace is held at once: for many episodes with sensors use
    ``iter_traces`` (a chunk at a time). Raises DriveE2EError (one line) on a
    bad folder, policy or scenario id. Warns when a re-simulated Driving
    Score differs from the stored one.
    """
    return list(iter_traces(results_dir, policy, scenario_ids, sensors=sensors, sensor_config=sensor_config,
                            limit=limit))


def iter_traces(
    results_dir: str | Path,
    policy: str | None = None,
    scenario_ids: Sequence[str] | None = None,
    *,
    sensors: Sequence[str] = TRACE_SENSORS,
    sensor_config=None,
    limit: int | None = None,
    chunk_size: int = TRACE_CHUNK,
    sensor_stride: int = 1,
    lidar_stride: int | None = None,
) -> Iterator[EpisodeTrace]:
    """``trace_episodes`` as a stream: the run is re-simulated once (small:
    ego states and step logs), then sensor frames are rendered and traces
    assembled ``chunk_size`` episodes at a time (one compiled call a chunk;
    the next chunk renders while this one is handed out), so at most two
    chunks of frames are held; each trace is yielded as soon as it is
    assembled (drop it to free it).

    Args (others as ``trace_episodes``):
      chunk_size: episodes whose frames are rendered per call (>= 1).
      sensor_stride: render the BEV and other sensors only at every s-th
        instant (``EpisodeTrace.sensor_stride``; agents and signals keep every one).
      lidar_stride: the same for the LiDAR (default: ``sensor_stride``).

    Bad arguments raise DriveE2EError here, before anything is simulated;
    the simulation runs at the first ``next()``.
    """
    lidar_stride = sensor_stride if lidar_stride is None else lidar_stride
    if min(int(chunk_size), int(sensor_stride), int(lidar_stride)) < 1:
        raise DriveE2EError(f"iter_traces: chunk_size, sensor_stride and lidar_stride must be >= 1, got "
                            f"{chunk_size}, {sensor_stride}, {lidar_stride}")
    run = read_run(results_dir, policy)
    suite, packed = _run_packed(run)
    check_current(run, packed)  # the suite and policy are still those benched
    rows = select_rows(packed.meta.scenario_id, scenario_ids)
    if limit is not None:
        rows = rows[: max(int(limit), 0)]
    sensor_cfg = sensor_config if sensor_config is not None else default_sensor_config(tuple(sensors))
    return _stream(run, suite, packed, rows, sensor_cfg, int(chunk_size), int(sensor_stride), int(lidar_stride))


def _stream(run: RunRecord, suite, packed, rows: np.ndarray, sensor_cfg, chunk: int, stride: int, lidar_stride: int):
    """The generator behind ``iter_traces``: chunk k + 1's frames render
    (asynchronously) while chunk k's traces are assembled and consumed, so at
    most two chunks of frames and one trace are held."""
    if not len(rows):
        return
    sim_out = _simulate(_load_run_policy(run), _run_settings(run), suite, packed, rows)
    stored = stored_rows(run)
    render = FrameRenderer(sim_out, suite, packed, sensor_cfg, chunk, stride, lidar_stride)
    bev_cfg = None if render.bev_sim is None else render.bev_sim.config.sensors.bev
    starts = range(0, len(rows), chunk)
    part = _chunk(sim_out, packed, rows, 0, chunk)
    started = render.start(part)
    for j0 in starts:
        nxt = _chunk(sim_out, packed, rows, j0 + chunk, j0 + 2 * chunk) if j0 + chunk < len(rows) else None
        ahead = None if nxt is None else render.start(nxt)  # dispatched before this chunk is waited for
        frames = render.finish(part, started)
        for j, row in enumerate(part["rows"]):
            sid = str(packed.meta.scenario_id[row])
            tr = _episode_trace(run, packed, int(row), j, part, frames, stored.get(sid, {}), bev_cfg, sensor_cfg,
                                stride, lidar_stride)
            if not tr.reproduced:
                warnings.warn(f"{sid}: re-simulated driving score {tr.driving_score:.4f} differs from the stored "
                              f"{tr.stored_driving_score:.4f} ({run.path})", stacklevel=2)
            yield tr
        part, started = nxt, ahead
        del frames


def _chunk(sim_out: dict, packed, rows: np.ndarray, a: int, b: int) -> dict:
    """``sim_out`` restricted to chosen rows ``a:b`` (chunk-local index j), with
    their numpy ``Scenario`` rows gathered from ``packed`` ("batch")."""
    sl = lambda tree: jax.tree_util.tree_map(lambda x: x[a:b], tree)  # noqa: E731
    part = rows[a:b]
    return {**sim_out, "rows": part, "ctx": sl(sim_out["ctx"]), "states": sl(sim_out["states"]),
            "logs": sl(sim_out["logs"]), "actions": None if sim_out["actions"] is None else sl(sim_out["actions"]),
            "driving_score": sim_out["driving_score"][a:b],
            "batch": jax.tree_util.tree_map(lambda x: np.asarray(x)[part], packed.scenario)}


@dataclasses.dataclass(frozen=True)
class RunSettings:
    """The rollout settings of a run (``run.json``): simulator config without
    the policy's sensors, control timing and PRNG seed (of repetition 0)."""

    sim: SimConfig
    timing: ControlTiming
    seed: int


def _run_settings(run: RunRecord) -> RunSettings:
    """``RunSettings`` of ``run.json``: the ``RunSpec`` builders the bench uses."""

    try:
        return RunSettings(sim=run.spec.sim_config(), timing=run.spec.timing(), seed=run.spec.seed)
    except DriveE2EError as e:
        raise DriveE2EError(f"{run.path / RUN_JSON}: {e}") from e


class TracingRollout(Rollout):
    """A Rollout whose scan also emits, per step, the action applied and
    the simulator state after the step (without its per-episode constants
    ``ctx``): the trace renders its frames from those states with
    ``Simulator.observe``, the function the policy's observation comes from."""

    def _step_one(self, scenario, carry, assets, params, query=None, given=None):
        carry, log = super()._step_one(scenario, carry, assets, params, query, given)
        return carry, (log, carry.held, carry.sim.replace(ctx=None))


def _simulate(pol, settings: RunSettings, suite, packed, rows: np.ndarray) -> dict:
    """Roll ``pol`` out on ``packed`` exactly as ``evaluate`` did; keep ``rows``.

    The whole evaluated batch is re-run, not only ``rows``: the same batch
    shape, PRNG keys and parameters as the bench, so the floats are
    bit-identical whichever scenarios are asked for.

    Returns {"sim": the rollout's Simulator, "assets": its SensorAssets of
    ``packed`` (None without a BEV), and for ``rows`` only (leading axis
    len(rows)): "ctx" ``sim.SimContext``, "states" ``SimState`` without ctx
    with axis 1 = T_pad + 1 instants (the reset state, then the state after
    every step), "logs" ``StepLog`` (T_pad steps), "actions" the applied
    actions (T_pad steps; None for a controls policy), "driving_score" (len(rows),)}
    (``_chunk`` adds the chunk's numpy ``Scenario`` rows, "batch").
    """

    pol = hostbridge.wrap(pol)  # a host policy: the same host calls as the bench made
    try:
        cfg = with_policy_sensors(settings.sim, pol)
    except ValueError as e:  # an unknown required sensor
        raise DriveE2EError(f"policy {getattr(pol, 'name', '?')!r}: {e}") from e
    assets = sensors_mod.build_assets(packed, cfg.sensors, suite.maps)
    batch, meta = device_batch(packed)
    sim = Simulator(cfg)
    key = jax.random.PRNGKey(settings.seed)
    total = longest_episode(sim, batch)
    chunk = balanced_chunk(total, 50, settings.timing.control_every)  # as evaluate chunks it
    ro = TracingRollout(sim, pol, None, timing=settings.timing, chunk=chunk, assets=assets)
    pick = lambda tree: jax.tree_util.tree_map(lambda a: np.asarray(a)[rows], tree)  # noqa: E731
    # The same reset and params as evaluate (one device: its batch is not padded).
    carry = begin_rollout(ro, batch, jax.random.split(key, len(packed)), key, meta)
    first = pick(carry.sim)
    chunks, steps = [], 0
    while steps < total and not bool(np.all(np.asarray(carry.sim.episode.done))):
        carry, out = ro.advance(batch, carry)
        hostbridge.raise_if_failed(pol)
        chunks.append(pick(out))
        steps += ro.chunk
    logs, actions, states = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=1), *chunks)
    states = jax.tree_util.tree_map(lambda a, b: np.concatenate([a[:, None], b], axis=1),
                                    first.replace(ctx=None), states)
    res = episode_results(sim, carry.sim.episode, batch.route)
    return {
        "sim": sim,
        "assets": assets,
        "ctx": first.ctx,
        "states": states,
        "logs": logs,
        "actions": actions if pol.action_type == "waypoints" else None,
        "driving_score": np.asarray(res.driving_score)[rows],
    }


def _episode_length(log_active: np.ndarray) -> int:
    """Steps the episode ran (the active flags are a prefix)."""
    return int(np.sum(log_active))


# --------------------------------------------------------------------------
# Per-step frames: agents, signals, sensors at the traced times
# --------------------------------------------------------------------------


def trace_bev_sensors(policy_sensors, sensor_cfg):
    """The ``SensorConfig`` the trace's BEV frames are rendered with: the
    policy's own (``policy_sensors``, the rollout's ``SimConfig.sensors``)
    when it sees a BEV, so each frame IS the policy's observation; else the
    BEV of ``sensor_cfg`` (the trace's). None when ``sensor_cfg`` asks for no BEV."""

    if sensor_cfg.bev is None:
        return None
    if policy_sensors.bev is not None:
        return SensorConfig.for_policy(("bev",), policy_sensors)
    return SensorConfig(bev=sensor_cfg.bev, scene=sensor_cfg.scene, raster_resolution=sensor_cfg.raster_resolution)


def _frame_fns(sim, bev_sim, sensor_cfg) -> dict:
    """Per-instant functions of one scenario's state, by group (a group is
    left out when it has nothing to render): "base" the replayed agents and
    signals; "sensors" the BEV (``bev_sim.observe(...).bev``, exactly the
    policy's observation when ``bev_sim`` is the rollout's simulator) and
    every other sensor's ``Sensor.trace`` (key ``sensor.<name>``); "lidar" the
    LiDAR point cloud of ``sensor_cfg.lidar`` (its own stride: the heaviest)."""

    others = [n for n in sensor_cfg.enabled if n not in registry.SLOTTED]

    def base(scenario, ctx, state, assets):
        t = state.ego.t
        return {"agents": sim.agents(scenario, t, state.replace(ctx=ctx)), "signals": replay.signals_at(scenario.signals, t, scenario.dt_log)}

    def context(scenario, ctx, state, assets):
        seen = base(scenario, ctx, state, assets)
        return SensorContext(scenario=scenario, ego=state.ego, ego_lw=ctx.ego_lw, agents=seen["agents"],
                             stop_state=seen["signals"], route_index=ep.route_index(state.episode), assets=assets,
                             key=state.obs_key, scene=sensor_cfg.scene)

    def sensors(scenario, ctx, state, assets):
        state = state.replace(ctx=ctx)
        out = {}
        if bev_sim is not None:
            out["bev"] = bev_sim.observe(scenario, state, assets).bev
        sctx = context(scenario, ctx, state, assets)
        for n in others:
            out[f"sensor.{n}"] = registry.get(n).trace(sctx.for_sensor(n), sensor_cfg.get(n))
        return out

    def lidar(scenario, ctx, state, assets):
        scan = registry.get("lidar").trace(context(scenario, ctx, state.replace(ctx=ctx), assets), sensor_cfg.lidar)
        return {"lidar_points": scan["points"], "lidar_class": scan["hit_class"], "lidar_valid": scan["valid"]}

    fns = {"base": base}
    if bev_sim is not None or others:
        fns["sensors"] = sensors
    if sensor_cfg.lidar is not None:
        fns["lidar"] = lidar
    return fns


def _over_chunk(one):
    """jit of ``one`` (scenario, ctx, state, assets) over a chunk of episodes
    (``lax.map``: one episode's intermediates at a time) and each episode's
    instants (``vmap``). Takes (batch (C, ...), ctx (C, ...), states (C, T, ...),
    assets with map_index (C,) or None)."""
    per_episode = jax.vmap(one, in_axes=(None, None, 0, None))

    def run(batch, ctx, states, assets):
        index = None if assets is None else assets.map_index

        def body(x):
            sc, cx, st, mi = x
            return per_episode(sc, cx, st, None if assets is None else assets.replace(map_index=mi))

        return jax.lax.map(body, (batch, ctx, states, index))

    return jax.jit(run)


def _row(tree, i: int):
    """Row ``i`` of every leaf of a batched (numpy) pytree."""

    return jax.tree_util.tree_map(lambda a: a[i], tree)


def _pad_rows(tree, n: int):
    """A batched pytree padded to ``n`` rows with copies of its last row (one compile per chunk size)."""
    b = int(jax.tree_util.tree_leaves(tree)[0].shape[0])
    if b >= n:
        return tree
    idx = np.r_[np.arange(b), np.full(n - b, b - 1)]
    return jax.tree_util.tree_map(lambda a: np.asarray(a)[idx], tree)


class FrameRenderer:
    """Renders a chunk of episodes' per-instant frames (``_chunk`` output),
    one compiled call per group of ``_frame_fns``: agents and signals at
    every instant, the BEV and other sensors at every ``stride``-th instant
    (0, s, 2s, ...), the LiDAR at every ``lidar_stride``-th. ``start`` only
    dispatches the calls (JAX runs them asynchronously), ``finish`` waits for
    them, so the host can assemble one chunk while the next one renders.
    ``bev_sim``: the Simulator the BEV frames come from (None: no BEV)."""

    def __init__(self, sim_out: dict, suite, packed, sensor_cfg, chunk: int, stride: int, lidar_stride: int):
        sim = sim_out["sim"]
        bev_sensors = trace_bev_sensors(sim.config.sensors, sensor_cfg)
        if bev_sensors is None:
            bev_sim, assets = None, None
        elif sim.config.sensors.bev is not None:  # the policy sees a BEV: trace_bev_sensors kept its own
            bev_sim, assets = sim, sim_out["assets"]
        else:
            bev_sim = Simulator(dataclasses.replace(sim.config, sensors=bev_sensors))
            assets = sensors_mod.build_assets(packed, bev_sensors, suite.maps)
        if assets is None and sensor_cfg.needs_raster:  # another registered sensor reads the map rasters
            assets = sensors_mod.build_assets(packed, sensor_cfg, suite.maps)
        self.bev_sim, self.assets, self.chunk = bev_sim, assets, chunk
        self.strides = {"base": 1, "sensors": stride, "lidar": lidar_stride}
        self.fns = {k: _over_chunk(f) for k, f in _frame_fns(sim, bev_sim, sensor_cfg).items()}

    def start(self, part: dict) -> dict:
        """Dispatch the chunk's calls; returns {group: device outputs}."""
        assets = None if self.assets is None else self.assets.replace(
            map_index=_pad_rows(np.asarray(self.assets.map_index)[part["rows"]], self.chunk))
        batch, ctx, states = (_pad_rows(part[k], self.chunk) for k in ("batch", "ctx", "states"))
        return {k: fn(batch, ctx, jax.tree_util.tree_map(lambda a, s=self.strides[k]: a[:, ::s], states), assets)
                for k, fn in self.fns.items()}

    def finish(self, part: dict, started: dict) -> list[dict]:
        """Per episode of ``part``: numpy frames {agents, signals: (T_pad + 1, ...),
        bev / sensor.<name>: every ``stride``-th instant, lidar_*: every ``lidar_stride``-th}."""
        out = {}
        for group in started.values():
            out.update(to_numpy(group))
        return [_row(out, j) for j in range(len(part["rows"]))]

    def __call__(self, part: dict) -> list[dict]:
        """``finish(part, start(part))``."""
        return self.finish(part, self.start(part))


# --------------------------------------------------------------------------
# Assembling one trace
# --------------------------------------------------------------------------


class PackedBev(Mapping):
    """{channel: (F, H, W) bool} of bit-packed BEV frames: ``bits (F, H, W)``
    int, bit i = channel ``names[i]`` (``observe.bev``). A channel is unpacked
    (numpy, then kept) when first read, so a consumer of the packed ``bits``
    (the player's sprite sheet) never pays for F x H x W x C booleans."""

    def __init__(self, bits, names: Sequence[str]):
        self.bits = np.asarray(bits)
        self.names = tuple(names)
        self._planes: dict[str, np.ndarray] = {}

    def __getitem__(self, channel: str) -> np.ndarray:
        if channel not in self._planes:
            i = self.names.index(channel) if channel in self.names else None
            if i is None:
                raise KeyError(channel)
            self._planes[channel] = ((self.bits >> i) & 1).astype(bool)
        return self._planes[channel]

    def __iter__(self):
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)


def _polys(lines, keep=None) -> list:
    """Valid polylines of a numpy ``types.Polylines`` as a list of (N_i, 2) arrays."""
    rows = np.flatnonzero(lines.valid) if keep is None else keep
    return [np.asarray(lines.xy[i][lines.point_valid[i]], np.float64) for i in rows]


def static_map(m) -> StaticMap:
    """Host ``StaticMap`` of one unbatched numpy ``types.MapData``."""
    lanes = np.flatnonzero(m.lanes.valid)
    bounds = np.flatnonzero(m.boundaries.valid)
    stops = np.flatnonzero(m.stop_line_valid)
    obst = np.flatnonzero(m.obstacles.valid)
    return StaticMap(
        lanes=_polys(m.lanes, lanes),
        lane_type=np.asarray(m.lane_type)[lanes],
        lane_speed_limit=np.asarray(m.lane_speed_limit)[lanes],
        boundaries=_polys(m.boundaries, bounds),
        boundary_marking=np.asarray(m.boundary_marking)[bounds],
        crosswalks=_polys(m.crosswalks),
        stop_lines=np.asarray(m.stop_lines, np.float64)[stops],
        stop_line_row=stops,
        stop_line_lane=np.asarray(m.stop_line_lane)[stops],
        drivable=_polys(m.drivable),
        obstacles=_polys(m.obstacles, obst),
        obstacle_height=np.asarray(m.obstacle_height)[obst],
    )


def _timeline(log, n: int, ego_speed: np.ndarray, rc0: float) -> dict:
    """Per-step metric timelines (T = n + 1; index 0 = the reset state)."""
    out = {"speed": ego_speed, "route_completion": np.concatenate([[rc0], np.asarray(log.route_completion[:n])])}
    for group, obj in (("facts", log.facts), ("events", log.events)):
        fields = [(f"{group}.{f.name}", getattr(obj, f.name)) for f in dataclasses.fields(obj)]
        # a preset's own per-tick facts (facts.navsim / facts.nuplan) one level down
        fields += [(f"{name}.{g.name}", getattr(sub, g.name)) for name, sub in list(fields)
                   if dataclasses.is_dataclass(sub) for g in dataclasses.fields(sub)]
        for name, v in fields:
            if dataclasses.is_dataclass(v) or v is None:
                continue
            v = np.asarray(v)
            if v.ndim != 1:  # per-stop-line arrays (red_light_lines) are not timelines
                continue
            out[name] = np.concatenate([np.zeros(1, v.dtype), v[:n]])
    return out


def _episode_trace(run: RunRecord, packed, row: int, j: int, sim_out: dict, frames: list, stored: dict,
                   bev_cfg, sensor_cfg=None, stride: int = 1, lidar_stride: int = 1) -> EpisodeTrace:
    """Trace of chosen row ``j`` (packed row ``row``); ``bev_cfg``: the
    ``BevConfig`` of ``frames``' BEV (None: no BEV); ``sensor_cfg``: the
    trace's ``SensorConfig`` (configs of the other sensors' frames);
    ``stride``, ``lidar_stride``: the sensor / LiDAR frames hold every
    stride-th instant."""

    log = _row(sim_out["logs"], j)
    n = _episode_length(np.asarray(log.active))
    t_len = n + 1
    sc = _row(sim_out["batch"], j)
    ego = _row(sim_out["states"], j).ego  # (T_pad + 1,) instants
    cut = lambda a: np.asarray(a)[:t_len]  # noqa: E731
    cut_s = lambda a, s=stride: np.asarray(a)[: -(-t_len // s)]  # noqa: E731  sensor instants 0, s, 2s, ... < t_len
    fr = frames[j]
    meta = {k: str(getattr(packed.meta, k)[row]) for k in
            ("split", "intersection_id", "map_id", "behavior", "weather", "time_of_day")}

    # Actions taken FROM state k: log rows 0..n-1; the final state has none.
    controls = np.zeros((t_len, 3), np.float32)
    controls[:n] = np.stack([log.throttle[:n], log.brake[:n], log.steer_cmd[:n]], axis=-1)
    plan_valid = np.zeros(t_len, bool)
    plan_valid[:n] = True
    plan = None
    held = None if sim_out["actions"] is None else _row(sim_out["actions"], j)
    if isinstance(held, Waypoints):
        wp = np.asarray(held.xy[:n])  # (n, K, 2) ego frame of state k
        world = jax.vmap(from_frame)(wp, np.asarray(ego.xy[:n]), np.asarray(ego.yaw[:n]))
        plan = np.zeros((t_len,) + wp.shape[1:], np.float32)
        plan[:n] = np.asarray(world)

    ego_idx = int(sc.ego_index)
    others = np.flatnonzero(np.asarray(sc.tracks.valid).any(axis=-1) & (np.arange(sc.tracks.xy.shape[0]) != ego_idx))
    ag = fr["agents"]
    agents = AgentsTrace(
        track_id=np.asarray(sc.tracks.track_id)[others],
        category=np.asarray(sc.tracks.category)[others],
        size=np.asarray(sc.tracks.size)[others],
        xy=cut(ag.xy)[:, others],
        yaw=cut(ag.yaw)[:, others],
        vel=cut(ag.vel)[:, others],
        valid=cut(ag.valid)[:, others],
    )
    smap = static_map(sc.map)
    route_ok = np.asarray(sc.route.valid)
    ds = float(sim_out["driving_score"][j])
    stored_ds = float(stored.get("driving_score", np.nan))
    trace = EpisodeTrace(
        scenario_id=str(packed.meta.scenario_id[row]),
        policy=run.policy,
        meta=meta,
        row=stored,
        dt=float(run.spec.dt),
        times=cut(ego.t).astype(np.float64),
        ego_size=np.asarray(sc.tracks.size[ego_idx]),
        ego_xy=cut(ego.xy),
        ego_yaw=cut(ego.yaw),
        ego_speed=cut(ego.speed),
        ego_accel=cut(ego.accel),
        ego_steer=cut(ego.steer),
        ego_yaw_rate=cut(ego.yaw_rate),
        controls=controls,
        plan_xy=plan,
        plan_valid=plan_valid,
        agents=agents,
        signals=cut(fr["signals"])[:, smap.stop_line_row],
        map=smap,
        route_xy=np.asarray(sc.route.xy)[route_ok],
        route_arc=np.asarray(sc.route.arc)[route_ok],
        route_command=np.asarray(sc.route.command)[route_ok],
        route_length=float(sc.route.length),
        timeline=_timeline(log, n, cut(ego.speed), 0.0),
        events=list(run.data.get("events", {}).get(str(packed.meta.scenario_id[row]), [])),
        resim_events=events_to_world(ep.extract_events(log), packed.meta.origin[row]),
        driving_score=ds,
        stored_driving_score=stored_ds,
        reproduced=bool(abs(ds - stored_ds) <= DS_TOLERANCE),
        origin=np.asarray(packed.meta.origin[row], np.float64).copy(),
    )
    trace.sensor_stride, trace.lidar_stride = int(stride), int(lidar_stride)
    if "bev" in fr:
        trace.bev = PackedBev(cut_s(fr["bev"]), bev_cfg.channel_names)
        trace.bev_resolution = float(bev_cfg.resolution)
    if "lidar_points" in fr:
        trace.lidar_points = cut_s(fr["lidar_points"], lidar_stride).astype(np.float32)
        trace.lidar_class = cut_s(fr["lidar_class"], lidar_stride).astype(np.int8)
        trace.lidar_valid = cut_s(fr["lidar_valid"], lidar_stride)
    for name in () if sensor_cfg is None else sensor_cfg.enabled:  # registry order
        if f"sensor.{name}" in fr:
            frames = jax.tree_util.tree_map(cut_s, fr[f"sensor.{name}"])
            trace.sensors[name] = SensorFrames(config=sensor_cfg.get(name), frames=frames)
    return trace


# --------------------------------------------------------------------------
# JSON for the episode player
# --------------------------------------------------------------------------


def _r(a, nd: int):
    """Rounded nested lists; non-finite -> None (JSON has no inf/NaN)."""
    a = np.asarray(a)
    if a.dtype == bool:
        return a.astype(int).tolist()
    if np.issubdtype(a.dtype, np.integer):
        return a.tolist()
    out = np.round(a.astype(np.float64), nd)
    return out.tolist() if np.all(np.isfinite(out)) else _nan_to_none(out.tolist())


def _nan_to_none(x):
    if isinstance(x, list):
        return [_nan_to_none(v) for v in x]
    return None if isinstance(x, float) and not np.isfinite(x) else x


def to_jsonable(trace: EpisodeTrace, *, bev: bool = False, lidar_stride: int = 0) -> dict:
    """A compact JSON-ready dict of ``trace`` (lists, floats rounded: positions
    to cm, angles to mrad; non-finite -> null; positions local, ``origin``
    the world (x, y) of the local (0, 0), events world). Sensors are left out unless
    asked: ``bev=True`` adds ``bev_png``: one base64 PNG per sensor frame
    (T, or ceil(T / ``trace.sensor_stride``)) of ``bev_rgb`` (the
    shared palette of ``observe.palette``; row 0 farthest ahead) and ``bev_resolution``;
    ``lidar_stride=s`` adds ``lidar``: T dicts {xyz: every s-th valid return
    (ego frame, m), class: its hit class}.

    Keys mirror the ``EpisodeTrace`` fields; ``agents`` and ``map`` are dicts
    of the same names; bool arrays become 0/1.
    """
    a = trace.agents
    m = trace.map
    out = {
        "scenario_id": trace.scenario_id,
        "policy": trace.policy,
        "meta": trace.meta,
        "row": {k: _jsonable_value(v) for k, v in trace.row.items()},
        "dt": trace.dt,
        "times": _r(trace.times, 3),
        "ego_size": _r(trace.ego_size, 2),
        "ego_xy": _r(trace.ego_xy, 2),
        "ego_yaw": _r(trace.ego_yaw, 3),
        "ego_speed": _r(trace.ego_speed, 2),
        "ego_accel": _r(trace.ego_accel, 2),
        "ego_steer": _r(trace.ego_steer, 3),
        "ego_yaw_rate": _r(trace.ego_yaw_rate, 3),
        "controls": _r(trace.controls, 3),
        "plan_xy": None if trace.plan_xy is None else _r(trace.plan_xy, 2),
        "plan_valid": _r(trace.plan_valid, 0),
        "agents": {
            "track_id": _r(a.track_id, 0), "category": _r(a.category, 0), "size": _r(a.size, 2),
            "xy": _r(a.xy, 2), "yaw": _r(a.yaw, 3), "valid": _r(a.valid, 0),
        },
        "signals": _r(trace.signals, 0),
        "map": {
            "lanes": [_r(p, 2) for p in m.lanes], "lane_type": _r(m.lane_type, 0),
            "boundaries": [_r(p, 2) for p in m.boundaries], "boundary_marking": _r(m.boundary_marking, 0),
            "crosswalks": [_r(p, 2) for p in m.crosswalks], "stop_lines": _r(m.stop_lines, 2),
            "stop_line_row": _r(m.stop_line_row, 0), "drivable": [_r(p, 2) for p in m.drivable],
            "obstacles": [_r(p, 2) for p in m.obstacles], "obstacle_height": _r(m.obstacle_height, 2),
        },
        "route_xy": _r(trace.route_xy, 2),
        "route_command": _r(trace.route_command, 0),
        "route_length": round(trace.route_length, 3),
        "timeline": {k: _r(v, 3) for k, v in trace.timeline.items()},
        "events": trace.events,
        "driving_score": round(trace.driving_score, 4),
        "stored_driving_score": _jsonable_value(trace.stored_driving_score),
        "reproduced": trace.reproduced,
        "origin": [float(v) for v in trace.origin],
    }
    if bev and trace.bev is not None:
        out["bev_png"] = [base64.b64encode(png_bytes(bev_rgb(trace.bev, k))).decode("ascii")
                          for k in range(len(next(iter(trace.bev.values()))))]
        out["bev_resolution"] = trace.bev_resolution
    if lidar_stride and trace.lidar_points is not None:
        s = int(lidar_stride)
        out["lidar"] = [
            {"xyz": _r(p[v][::s], 2), "class": _r(c[v][::s], 0)}
            for p, c, v in zip(trace.lidar_points, trace.lidar_class, trace.lidar_valid)
        ]
    return out


def _jsonable_value(v):
    if isinstance(v, (np.generic,)):
        v = v.item()
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v
