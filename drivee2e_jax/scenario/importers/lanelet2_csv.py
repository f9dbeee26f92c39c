"""``lanelet2-csv``: drone recordings on a Lanelet2 map (SinD, INTERACTION family).

Inputs (each path is self-contained; see :func:`find_recordings`):

* a **recording folder** holding track CSVs — SinD ``Veh_smoothed_tracks.csv``
  / ``Ped_smoothed_tracks.csv`` (+ ``Veh_tracks_meta.csv``,
  ``Ped_tracks_meta.csv``, ``recording_metas.csv``, a traffic-light CSV
  ``Traffic_Lights.csv`` / ``TrafficLight_<name>.csv``), or INTERACTION
  ``vehicle_tracks_NNN.csv`` / ``pedestrian_tracks_NNN.csv`` (one recording
  per NNN). Its map is the ``.osm`` in the folder, else in its parent folder
  (SinD layout), else ``../../maps/<folder name>.osm`` (INTERACTION layout);
* a **city/location folder** holding one ``.osm`` and recording sub-folders:
  every recording;
* a **track CSV file**: that recording only (map found as above);
* an **.osm file** alone: the map only (no scenario: a map has no ego).

Tracks (``read_tracks``): columns ``track_id, timestamp_ms, agent_type, x, y``
are required; ``vx, vy`` are used when present; yaw from ``yaw_rad`` (SinD)
or ``psi_rad`` (INTERACTION), else (pedestrians) the direction of motion while
faster than 0.2 m/s, held otherwise; size from ``length, width`` (else the
category default of ``common.DEFAULT_SIZES``). Times are
``timestamp_ms / 1000`` from the recording's first sample; SinD's 100.1 ms
frames are resampled onto the ``options.dt`` grid by ``common.convert_tracks``.
Source ids are kept as text (``"12"``, ``"P3"``); integer ids come from
``common.TrackIds`` and the table is in ``suite.json`` meta.

Categories (:data:`CATEGORY_TABLE`): car, truck, bus, van, motorcycle,
tricycle, pedestrian as named; bicycle -> cyclist; INTERACTION's
``pedestrian/bicycle`` -> pedestrian (the source does not tell them apart).

Ego: ``options.ego`` (a source track id) else ``common.select_ego`` per window
(default window :data:`DEFAULT_WINDOW_S`). A recording without vehicle tracks
(SinD's public repository keeps ``Veh_smoothed_tracks.csv`` in Git LFS) gives
a ``Skipped`` naming the missing file, not a crash.

Signals: the light CSV holds change events (``RawFrameID``,
``timestamp(ms)``, one column per light; 0 red, 1 green, 3 yellow; a state
holds until the next row; before the first row the state is unknown). Column
``... light N`` is signal group N, the group the map's ``traffic_light``
regulatory elements give their stop lines (``lanelet2.load_map``). States are
sampled at every log step of each scenario (``ScenarioRecord.signals``; cut per
window by ``common.windowed_scenarios``).
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import MapRecord
from drivee2e_jax.scenario.importers import common
from drivee2e_jax.scenario.importers.common import ImportOptions, ImportResult, RawTrack, Skipped
from drivee2e_jax.scenario.importers.lanelet2 import load_map, signal_group_of_name

__all__ = ["CATEGORY_TABLE", "DEFAULT_WINDOW_S", "Recording", "recordings_of", "find_map",
           "find_recordings", "import_recording", "read_tracks", "read_signal_events", "signal_states", "load"]

#: Window length when ``options.window_s`` is None, s (twin15 logs are 20 s).
DEFAULT_WINDOW_S = 20.0

CATEGORY_TABLE: dict[str, str | None] = {
    "car": "car", "truck": "truck", "bus": "bus", "van": "van", "motorcycle": "motorcycle",
    "tricycle": "tricycle", "pedestrian": "pedestrian", "bicycle": "cyclist", "cyclist": "cyclist",
    "pedestrian/bicycle": "pedestrian",
}

_LFS = b"version https://git-lfs.github.com/spec"
_VEH_NAMES = ("Veh_smoothed_tracks.csv", "Veh_tracks.csv")
_PED_NAMES = ("Ped_smoothed_tracks.csv", "Ped_tracks.csv")
_INTER = re.compile(r"^(vehicle|pedestrian)_tracks_(\d+)\.csv$")
_LIGHTS = re.compile(r"^(Traffic_?Lights?.*|TrafficLight_.*)\.csv$", re.IGNORECASE)
# source light CSV value -> SIGNAL_STATES index (0 unknown, 1 red, 2 yellow, 3 green)
_LIGHT_STATE = {0: 1, 1: 3, 2: 2, 3: 2}


@dataclass
class Recording:
    """One recording: a name, its folder, track CSVs, light CSV, map, and what is missing (one line each)."""

    name: str
    folder: Path
    tracks: list[Path]
    lights: Path | None
    osm: Path | None
    missing: list[str]


def _is_lfs_pointer(p: Path) -> bool:
    try:
        with open(p, "rb") as f:
            return f.read(len(_LFS)) == _LFS
    except OSError:
        return False


def find_map(folder: Path, suffix: str = ".osm") -> Path | None:
    """The one ``*<suffix>`` map of a recording folder: in the folder, else its
    parent (SinD layout), else ``../../maps/<folder name><suffix>`` (INTERACTION)."""
    for cand in (folder, folder.parent):
        found = sorted(cand.glob(f"*{suffix}"))
        if len(found) == 1:
            return found[0]
        if len(found) > 1:
            raise DriveE2EError(f"{cand}: expected one {suffix} map, found {len(found)} "
                                f"({', '.join(p.name for p in found)})")
    inter = folder.parent.parent / "maps" / f"{folder.name}{suffix}"
    return inter if inter.is_file() else None


def _recordings_in(folder: Path, only: Path | None = None) -> list[Recording]:
    """The recordings of one folder (SinD: one; INTERACTION: one per NNN)."""
    files = sorted(p for p in folder.iterdir() if p.is_file())
    names = {p.name for p in files}
    lights = next((p for p in files if _LIGHTS.match(p.name)), None)
    out = []
    inter: dict[str, list[Path]] = {}
    for p in files:
        m = _INTER.match(p.name)
        if m:
            inter.setdefault(m.group(2), []).append(p)
    if inter:
        for num, paths in sorted(inter.items()):
            if only is not None and only not in paths:
                continue
            out.append(Recording(f"{folder.name}_{num}", folder, sorted(paths), lights, None, []))
    else:
        tracks, missing = [], []
        for group in (_VEH_NAMES, _PED_NAMES):
            p = next((folder / n for n in group if n in names), None)
            if p is not None and _is_lfs_pointer(p):
                missing.append(f"{p.name} is a Git LFS pointer, not the data")
            elif p is not None:
                tracks.append(p)
            else:
                missing.append(f"no {group[0]}")
        if tracks or lights is not None or any(n.endswith("_meta.csv") or n.endswith("_metas.csv") for n in names):
            out.append(Recording(folder.name, folder, tracks, lights, None, missing))
    return out


def recordings_of(path: Path) -> list[Recording]:
    """The recordings of a track CSV file or a folder (or its sub-folders), without their map."""
    path = Path(path)
    if path.is_file():
        if path.suffix != ".csv":
            raise DriveE2EError(f"{path}: expected a track .csv, a recording folder or an .osm map")
        recs = _recordings_in(path.parent, only=path)
    else:
        recs = _recordings_in(path)
        if not recs:
            for sub in sorted(p for p in path.iterdir() if p.is_dir()):
                recs += _recordings_in(sub)
    if not recs:
        raise DriveE2EError(f"{path}: expected track CSVs (Veh_smoothed_tracks.csv / Ped_smoothed_tracks.csv or "
                            "vehicle_tracks_NNN.csv / pedestrian_tracks_NNN.csv); found none")
    return recs


def find_recordings(path: Path) -> tuple[list[Recording], Path]:
    """(recordings, map) of one input path (rules in the module docstring)."""
    path = Path(path)
    if path.is_file() and path.suffix == ".osm":
        return [], path
    recs = recordings_of(path)
    osm = find_map(path.parent if path.is_file() else path)
    if osm is None:
        raise DriveE2EError(f"{path}: expected a Lanelet2 .osm map in the folder, its parent, or ../../maps/; "
                            "found none")
    for r in recs:
        r.osm = osm
    return recs, osm


def _read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    if _is_lfs_pointer(path):
        raise DriveE2EError(f"{path}: is a Git LFS pointer, not the data; expected the CSV itself (git lfs pull)")
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as e:
        raise DriveE2EError(f"{path}: expected a readable UTF-8 CSV, got {e}") from None
    if not rows:
        raise DriveE2EError(f"{path}: expected a header row, got an empty file")
    return [h.strip() for h in rows[0]], [r for r in rows[1:] if r and any(c.strip() for c in r)]


def _column(path: Path, header: list[str], rows: list[list[str]], name: str, numeric: bool = True,
            required: bool = True) -> np.ndarray | None:
    if name not in header:
        if required:
            raise DriveE2EError(f"{path}: missing column {name!r}; expected a header with {name}")
        return None
    j = header.index(name)
    vals = []
    for i, r in enumerate(rows):
        if j >= len(r):
            raise DriveE2EError(f"{path}: line {i + 2}: expected {len(header)} fields, got {len(r)}")
        vals.append(r[j].strip())
    if not numeric:
        return np.array(vals, dtype=object)
    try:
        return np.array([float(v) for v in vals], np.float64)
    except ValueError:
        bad = next(i for i, v in enumerate(vals) if not _is_float(v))
        raise DriveE2EError(f"{path}: line {bad + 2}, column {name!r}: expected a number, got {vals[bad]!r}") from None


def _is_float(v: str) -> bool:
    try:
        float(v)
        return True
    except ValueError:
        return False


def _motion_yaw(vel: np.ndarray, xy: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Direction of motion where faster than 0.2 m/s, held (back- then forward-filled) elsewhere."""
    if vel is None:
        vel = np.gradient(xy, t, axis=0) if len(t) >= 2 else np.zeros_like(xy)
    speed = np.linalg.norm(vel, axis=1)
    yaw = np.arctan2(vel[:, 1], vel[:, 0])
    ok = speed > 0.2
    if not ok.any():
        return np.zeros(len(t))
    idx = np.where(ok, np.arange(len(t)), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = np.flatnonzero(ok)[0]
    return yaw[idx]


def read_tracks(path: Path, t0_ms: float | None = None) -> tuple[list[RawTrack], list[Skipped], float]:
    """One track CSV -> (raw tracks, skipped, t0_ms). Times are s after ``t0_ms``
    (default: the file's first timestamp)."""
    header, rows = _read_csv(path)
    tid = _column(path, header, rows, "track_id", numeric=False)
    ts = _column(path, header, rows, "timestamp_ms")
    kind = _column(path, header, rows, "agent_type", numeric=False)
    x, y = _column(path, header, rows, "x"), _column(path, header, rows, "y")
    vx, vy = (_column(path, header, rows, c, required=False) for c in ("vx", "vy"))
    yaw_col = next((c for c in ("yaw_rad", "psi_rad") if c in header), None)
    yaw = _column(path, header, rows, yaw_col) if yaw_col else None
    length, width = (_column(path, header, rows, c, required=False) for c in ("length", "width"))
    if not len(rows):
        return [], [Skipped(str(path), "no track rows (header only)")], t0_ms or 0.0
    t0 = float(ts.min()) if t0_ms is None else t0_ms
    raws, skipped = [], []
    order = np.lexsort((ts, tid))
    bounds = np.flatnonzero(np.r_[True, tid[order][1:] != tid[order][:-1], True])
    for a, b in zip(bounds[:-1], bounds[1:]):
        sel = order[a:b]
        src = str(tid[sel[0]])
        kinds = set(kind[sel])
        cat, skip = common.map_category(str(kind[sel[0]]), CATEGORY_TABLE, f"{path} track {src}")
        if skip is not None:
            skipped.append(skip)
            continue
        if len(kinds) > 1:
            skipped.append(Skipped(f"{path} track {src}", f"changes agent_type ({', '.join(sorted(kinds))})"))
            continue
        t = (ts[sel] - t0) / 1000.0
        xy = np.stack([x[sel], y[sel]], axis=1)
        vel = np.stack([vx[sel], vy[sel]], axis=1) if vx is not None and vy is not None else None
        h = yaw[sel] if yaw is not None else _motion_yaw(vel, xy, t)
        d = common.DEFAULT_SIZES[cat]
        if length is not None and width is not None:
            size = np.stack([length[sel], width[sel], np.full(len(sel), d[2])], axis=1)
        else:
            size = np.array(d, np.float64)
        raws.append(RawTrack(source_id=src, category=cat, t=t, xy=xy, yaw=h, size=size, vel=vel))
    return raws, skipped, t0


def read_signal_events(path: Path) -> tuple[np.ndarray, dict[int, np.ndarray]]:
    """A light CSV -> (change times (n,) ms, {group: (n,) SIGNAL_STATES index})."""
    header, rows = _read_csv(path)
    tcol = next((c for c in header if c.lower().startswith("timestamp")), None)
    if tcol is None:
        raise DriveE2EError(f"{path}: missing column 'timestamp(ms)'; expected a light-change CSV")
    t = _column(path, header, rows, tcol)
    groups: dict[int, np.ndarray] = {}
    for c in header:
        if "light" not in c.lower():
            continue
        g = signal_group_of_name(c)
        if g is None:
            raise DriveE2EError(f"{path}: column {c!r}: expected a light name ending in its number")
        raw = _column(path, header, rows, c)
        bad = [v for v in raw if int(v) not in _LIGHT_STATE or v != int(v)]
        if bad:
            raise DriveE2EError(f"{path}: column {c!r}: expected states 0 (red), 1 (green), 3 (yellow), got {bad[0]:g}")
        groups[g] = np.array([_LIGHT_STATE[int(v)] for v in raw], np.int8)
    if not groups:
        raise DriveE2EError(f"{path}: expected at least one 'Traffic light N' column")
    order = np.argsort(t, kind="stable")
    return t[order], {g: s[order] for g, s in groups.items()}


def signal_states(times_ms: np.ndarray, states: np.ndarray, t_ms: np.ndarray) -> np.ndarray:
    """State at each query time (k,) ms: the last change at or before it; unknown (0) before the first."""
    i = np.searchsorted(times_ms, t_ms, side="right") - 1
    return np.where(i >= 0, states[np.maximum(i, 0)], 0).astype(np.int8)


def _map_id(osm: Path) -> str:
    return common.safe_id(osm.stem)


def import_recording(rec: Recording, map_rec: MapRecord, options: ImportOptions, result: ImportResult) -> None:
    """Scenarios of one recording on ``map_rec`` appended to ``result`` (unusable parts as Skipped)."""
    raws: list[RawTrack] = []
    per_file = []
    for p in rec.tracks:
        r, skipped, t0_file = read_tracks(p)
        per_file.append((r, t0_file))
        result.skipped += skipped
    t0 = min((t for _, t in per_file), default=0.0)  # one clock: the recording's earliest sample
    for r, t0_file in per_file:
        for raw in r:
            raw.t = raw.t + (t0_file - t0) / 1000.0
        raws += r
    where = str(rec.folder if len(rec.tracks) != 1 else rec.tracks[0])
    vehicles = [r for r in raws if r.category in common.VEHICLES]
    if not vehicles:
        why = "; ".join(rec.missing) or "no vehicle (car/truck/bus/van) track in the files"
        meta = rec.folder / "Veh_tracks_meta.csv"
        if meta.is_file():
            why += f"; {meta.name} lists {len(_read_csv(meta)[1])} vehicles whose tracks are absent"
        result.skipped.append(Skipped(str(rec.folder), f"no vehicle tracks, so no ego ({why}); "
                                             f"{len(raws)} other track(s) not used"))
        return
    if options.ego is not None and options.ego not in {r.source_id for r in raws}:
        raise DriveE2EError(f"{where}: --ego {options.ego!r}: expected a track_id of the recording")
    dt = options.dt
    t_end = max(float(r.t[-1]) for r in raws)
    num_steps = int(np.floor(t_end / dt + 1e-6)) + 1
    conv = common.convert_tracks(raws, options.ego, dt, num_steps, where)
    result.skipped += conv.skipped
    if conv.gap_tracks:
        result.notes.append(f"{rec.name}: {conv.gap_tracks} track(s) have gaps > {common.DEFAULT_MAX_GAP_S:g} s "
                            "(not interpolated)")
    opts = options if options.window_s is not None else replace(options, window_s=DEFAULT_WINDOW_S)
    remaining = None if options.max_scenarios is None else options.max_scenarios - len(result.scenarios)
    if remaining is not None and remaining <= 0:
        return
    base = common.safe_id(rec.name)
    ego = None if options.ego is None else conv.ids[options.ego]
    states_at = None
    if rec.lights is not None:
        times, groups = read_signal_events(rec.lights)

        def states_at(t: np.ndarray) -> dict[int, np.ndarray]:
            return {g: signal_states(times, st, t0 + t * 1000.0) for g, st in sorted(groups.items())}

    scen = common.windowed_scenarios(base, map_rec, conv.tracks, ego, dt, num_steps, opts, where,
                                     result.skipped, result.notes, limit=remaining, signals=states_at,
                                     source_ids=conv.ids.table())
    if rec.lights is not None:
        unknown = sorted(set(groups) - {s.signal_group for s in map_rec.stop_lines})
        if unknown:
            result.notes.append(f"{rec.name}: light group(s) {unknown} of {rec.lights.name} guard no stop line of "
                                f"the map (no traffic_light regulatory element names them)")
    result.scenarios += scen
    result.meta.setdefault("track_ids", {})[base] = {str(k): v for k, v in conv.ids.table().items()}


def load(paths: list[Path], options: ImportOptions) -> ImportResult:
    """Import Lanelet2 + drone-CSV recordings (see the module docstring)."""
    result = ImportResult(maps={}, scenarios=[], skipped=[], notes=[],
                          meta={"source_format": "lanelet2-csv"})
    for path in paths:
        recs, osm = find_recordings(Path(path))
        map_id = _map_id(osm)
        if map_id not in result.maps:
            m, notes = load_map(osm, map_id)
            result.maps[map_id] = m
            result.notes += notes
        if not recs:
            result.notes.append(f"{osm}: a map alone gives no scenario (no tracks, so no ego)")
        for rec in recs:
            if options.max_scenarios is not None and len(result.scenarios) >= options.max_scenarios:
                break
            import_recording(rec, result.maps[map_id], options, result)
    return result
