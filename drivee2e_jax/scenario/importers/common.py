"""Shared host-side machinery of the recorded-traffic importers.

Every format module (``importers/<format>.py``) exposes
``load(paths: list[Path], options: ImportOptions) -> ImportResult`` and uses
the helpers below, so that resampling, routes, ego choice, behaviour labels,
categories and writing work the same for every source. Nothing here runs
under ``jit``; arrays are numpy. Units: metres, seconds, radians, m/s.

Inputs
------
Each input path handed to ``load`` is self-contained: one file, or one folder
holding one recording (a format may also search a folder for recordings). The
CLI calls ``load`` once per path (for its progress bar) and combines the
results with ``merge_results``; ``load`` must also accept several paths. A
format whose paths belong together (an OpenDRIVE map and track folders stored
elsewhere) sets ``LOAD_ALL_PATHS_AT_ONCE = True`` and the CLI calls its
``load`` once with every path.

Result types
------------
``ImportOptions(split, ego, max_scenarios, window_s, dt, name)``
    What the user asked for (frozen; see the field comments).
``Skipped(source, reason)``
    One thing that could not be used (a track, a window, a file), with a
    one-line reason. Never drop data silently: add a ``Skipped``.
``ImportResult(maps, scenarios, skipped, notes, meta={})``
    What a ``load`` returns. ``meta`` (optional, default ``{}``) goes into
    ``suite.json``'s ``meta`` (source, licence, track-id tables, ...).

Tracks
------
``RawTrack(source_id, category, t, xy, yaw, size, vel=None, visible=None)``
    A source track before resampling: ``t`` (n,) s from the scenario start
    (any rate, increasing), ``xy`` (n, 2), ``yaw`` (n,), ``size`` (3,) or
    (n, 3) length/width/height (a per-sample size is reduced to its median),
    ``vel`` (n, 2) or None, ``visible`` (n,) bool or None. ``category`` is
    already a ``records.CATEGORIES`` name.
``resample(t, values, dt, num_steps, *, max_gap_s=DEFAULT_MAX_GAP_S, angles=()) -> Resampled``
    Linear interpolation of ``values`` (n, d) at the grid times ``k * dt``,
    ``0 <= k < num_steps``, that lie inside the sampled span. Grid times in a
    gap longer than ``max_gap_s`` between two samples are left OUT (never
    interpolated across); the gaps are returned. Columns listed in ``angles``
    are unwrapped before and wrapped to (-pi, pi] after interpolation.
    ``Resampled(k, values, gaps, interpolated)``: ``k`` (m,) int grid steps,
    ``values`` (m, d), ``gaps`` list of (t_start, t_end) s, ``interpolated``
    (m,) bool True where the grid time is not within ``GRID_SNAP_S`` of a sample.
``resample_track(raw, track_id, dt, num_steps, *, max_gap_s=...) -> (TrackRecord | None, Resampled | None)``
    A ``RawTrack`` on the grid as a ``TrackRecord`` (None, None when no grid
    time is covered).
``box_polygon(xy, yaw, length, width) -> (4, 2)`` counter-clockwise footprint.
``static_obstacle(raw, kind) -> ObstacleRecord | None``: a parked/static object
    as a static obstacle (its median pose), None when it moves more than
    ``STATIC_MAX_MOTION_M``.
``static_or_skip(raw, kind, skip, what) -> ObstacleRecord | Skipped``: a
    track with no agent category: its static obstacle when ``kind`` is given
    and it does not move, else ``skip`` (``kind`` None) or a Skipped saying
    that ``what`` (e.g. "category 'SIGN'") moves.
``convert_tracks(raws, ego_source, dt, num_steps, source, *, max_gap_s=...) -> Converted``
    Every RawTrack resampled with ids from ``TrackIds``; ``Converted(tracks,
    ids, skipped, gap_tracks, interpolated_fraction)``.
``TrackIds``: deterministic ``source id (str) -> int`` numbering (ego = 0,
    others 1.. in sorted source-id order); ``.table()`` gives ``{int: source}``.

Categories and markings
-----------------------
``map_category(value, table, source) -> (category | None, Skipped | None)``
    ``table`` maps source names to a ``records.CATEGORIES`` name, or to
    ``None`` for known-but-unusable ones (static objects...). Unknown names and
    ``None`` both give a ``Skipped`` naming the source and the value.
``map_marking(value, table, where) -> str``: onto ``records.MARKINGS``; an
    unknown value raises DriveE2EError naming ``where``.

Maps
----
``resample_polyline(points, spacing) -> (m, 2)``: even arc-length spacing,
    first and last points kept. ``polyline_length(points) -> float``.
``infer_successors(lanes, tol_m=1.0, max_angle=pi/4)``: fills
    ``LaneRecord.successors`` from geometry (end point within ``tol_m`` of a
    start point, headings within ``max_angle``), for sources without a lane graph.
``crop_map(m, xy, radius_m) -> MapRecord``: only what lies within ``radius_m``
    of any of the points ``xy`` (k, 2); successors to dropped lanes removed.

Ego, route, behaviour
---------------------
``build_route(track, spacing_m=ROUTE_SPACING_M) -> RouteRecord``: the ego's own
    logged path from its first to its last sample (as twin15 does), decimated to
    ~``spacing_m``, with exact source and destination. The path is what the
    log replay drives; ``curation.route_lane_match`` snaps it to the map's lanes
    to check it follows them (``curation.check_route``).
``select_ego(tracks, map_rec, num_steps, dt) -> (track | None, reasons)``:
    the source benchmark's curation rule for a scenario without a recorded ego
    (see the function); ``reasons`` maps each rejected vehicle's id to why.
    Candidates with a plausibility finding are passed over (reason starting
    ``PLAUSIBILITY_PREFIX``) and named in the "ego chosen automatically" note.
``infer_behavior(scenario, map_rec) -> (label, why)``: see the function for
    the rule (STP / IPC / COV when the data shows it, else the turn label).
``route_heading_change(waypoints) -> float``: signed total heading change, rad.

Scenarios and windows
---------------------
``windows(num_steps, dt, window_s) -> list[(k0, k1)]``: non-overlapping step
    ranges; the whole log when ``window_s`` is None.
``cut_window(tracks, k0, k1, dt) -> list[TrackRecord]``: tracks restricted to
    steps ``[k0, k1)`` with times shifted to start at 0 (empty ones dropped).
``make_scenario(scenario_id, map_rec, tracks, ego_id, dt, num_steps, options, ...) -> ScenarioRecord``:
    builds the route and the behaviour label and fills the defaults.
``windowed_scenarios(base_id, map_rec, tracks, ego_id, dt, num_steps, options, source, skipped, notes, *, signals=None, **kw) -> list[ScenarioRecord]``
    Cuts the log into ``windows`` and makes one scenario per window whose ego
    (``ego_id``, or ``select_ego`` when None) covers every step; other windows
    become Skipped. Honours ``options.max_scenarios``. ``signals`` (see
    ``window_signals``) gives every window its own signal states.
``window_signals(signals, k0, k1, dt, num_steps) -> {group: (k1 - k0,) int8}``:
    ``signals`` is None (no signals), a function of log times ``t`` (k,) s ->
    {group: (k,) SIGNAL_STATES index}, or full-log arrays {group: (num_steps,)};
    the states at steps ``[k0, k1)``.
``merge_results(results) -> ImportResult``: one result from several (maps by
    id; a repeated scenario id is an error).
``safe_id(text) -> str``: a portable scenario/map id.
``write_result(result, out, *, name, force=False) -> Path``: the suite folder
    via ``schema.write_suite`` (validated, atomic: a temp sibling then a
    rename; a non-empty folder is refused unless ``force``).
``read_table(path, columns) -> dict[str, np.ndarray]``: a Parquet or Feather
    file's columns (needs the ``import`` extra: pyarrow); a missing column is
    a DriveE2EError naming the file and the column.
``parse_xml(path, what, root_tag) -> Element``: an XML file's root element; a
    parse error, an unreadable file or another root tag is a one-line
    DriveE2EError naming the file and ``what`` (e.g. "CommonRoad").
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Union

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import (
    BEHAVIORS,
    CATEGORIES,
    MARKINGS,
    SPLITS,
    LaneRecord,
    MapRecord,
    ObstacleRecord,
    RouteRecord,
    ScenarioRecord,
    SuiteRecord,
    TrackRecord,
)
from drivee2e_jax.scenario import curation
from drivee2e_jax.scenario.schema import write_suite

__all__ = [
    "ImportOptions", "Skipped", "ImportResult", "RawTrack", "Resampled", "TrackIds",
    "DEFAULT_MAX_GAP_S", "GRID_SNAP_S", "ROUTE_SPACING_M", "STATIC_MAX_MOTION_M", "VEHICLES",
    "DEFAULT_SIZES", "PLAUSIBILITY_PREFIX", "resample", "resample_track", "box_polygon", "static_obstacle", "static_or_skip",
    "map_category", "map_marking", "resample_polyline", "polyline_length", "infer_successors",
    "crop_map", "build_route", "select_ego", "infer_behavior", "route_heading_change",
    "windows", "cut_window", "window_signals", "make_scenario", "Converted", "convert_tracks", "windowed_scenarios",
    "merge_results", "safe_id", "write_result", "read_table", "parse_xml",
]

#: Gaps between samples longer than this are not interpolated across, s
#: (1.5 steps of a 10 Hz source; 2 Hz sources pass their own value).
DEFAULT_MAX_GAP_S = 0.15
#: A grid time within this of a source sample counts as measured, not interpolated, s.
GRID_SNAP_S = 1e-3
#: Route waypoint spacing, m (twin15 uses 1.5-2 m).
ROUTE_SPACING_M = 2.0
#: A "static" object that moves more than this over the log stays a track, m.
STATIC_MAX_MOTION_M = 0.5
#: Categories that can be an ego / count as vehicles for COV.
VEHICLES = ("car", "truck", "bus", "van")
#: Default box (length, width, height) per category for sources without sizes, m.
DEFAULT_SIZES = {
    "car": (4.5, 1.9, 1.6), "truck": (8.0, 2.5, 3.5), "bus": (12.0, 2.6, 3.2), "van": (5.2, 2.0, 2.2),
    "motorcycle": (2.1, 0.8, 1.5), "tricycle": (2.8, 1.2, 1.6), "pedestrian": (0.6, 0.6, 1.75),
    "cyclist": (1.8, 0.7, 1.7),
}


# --------------------------------------------------------------------------
# Result types
# --------------------------------------------------------------------------


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


# --------------------------------------------------------------------------
# Tracks
# --------------------------------------------------------------------------


@dataclass
class RawTrack:
    """A source track before resampling (see the module docstring)."""

    source_id: str
    category: str
    t: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    size: np.ndarray
    vel: np.ndarray | None = None
    visible: np.ndarray | None = None


@dataclass
class Resampled:
    """Grid samples of one series: steps (m,), values (m, d), gaps [(t0, t1)], interpolated (m,)."""

    k: np.ndarray
    values: np.ndarray
    gaps: list[tuple[float, float]]
    interpolated: np.ndarray


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles to (-pi, pi]."""
    w = np.mod(np.asarray(a, np.float64) + np.pi, 2 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)


def resample(t: np.ndarray, values: np.ndarray, dt: float, num_steps: int, *,
             max_gap_s: float = DEFAULT_MAX_GAP_S, angles: Sequence[int] = ()) -> Resampled:
    """Linear interpolation of ``values`` (n, d) sampled at ``t`` (n,) s onto
    ``k * dt`` (0 <= k < num_steps), never across a gap > ``max_gap_s``.

    Duplicate timestamps keep their first sample. Columns in ``angles`` are
    interpolated along the shorter arc (unwrapped) and wrapped to (-pi, pi].
    """
    t = np.asarray(t, np.float64)
    v = np.asarray(values, np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if t.ndim != 1 or v.shape[0] != t.shape[0]:
        raise ValueError(f"resample: t {t.shape} and values {v.shape} disagree")
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 1e-9]) if t.size else np.zeros(0, bool)
    t, v = t[keep], v[keep].copy()
    for c in angles:
        v[:, c] = np.unwrap(v[:, c])
    empty = Resampled(np.zeros(0, np.int64), np.zeros((0, v.shape[1])), [], np.zeros(0, bool))
    if t.size == 0:
        return empty
    grid = np.arange(num_steps) * dt
    inside = (grid >= t[0] - GRID_SNAP_S) & (grid <= t[-1] + GRID_SNAP_S)
    gaps = [(float(a), float(b)) for a, b in zip(t[:-1], t[1:]) if b - a > max_gap_s + 1e-9]
    for a, b in gaps:
        inside &= ~((grid > a + GRID_SNAP_S) & (grid < b - GRID_SNAP_S))
    k = np.nonzero(inside)[0]
    g = np.clip(grid[k], t[0], t[-1])
    out = np.stack([np.interp(g, t, v[:, c]) for c in range(v.shape[1])], axis=1) if k.size else empty.values
    for c in angles:
        out[:, c] = _wrap(out[:, c])
    near = np.abs(t[np.clip(np.searchsorted(t, g), 0, t.size - 1)] - g)
    near = np.minimum(near, np.abs(t[np.clip(np.searchsorted(t, g) - 1, 0, t.size - 1)] - g))
    return Resampled(k.astype(np.int64), out, gaps, near > GRID_SNAP_S)


def resample_track(raw: RawTrack, track_id: int, dt: float, num_steps: int, *,
                   max_gap_s: float = DEFAULT_MAX_GAP_S) -> tuple[TrackRecord | None, Resampled | None]:
    """``raw`` on the grid as a TrackRecord with id ``track_id``; (None, None) if nothing is covered."""
    cols = [raw.xy[:, 0], raw.xy[:, 1], raw.yaw]
    if raw.vel is not None:
        cols += [raw.vel[:, 0], raw.vel[:, 1]]
    if raw.visible is not None:
        cols.append(np.asarray(raw.visible, np.float64))
    r = resample(raw.t, np.stack(cols, axis=1), dt, num_steps, max_gap_s=max_gap_s, angles=(2,))
    if r.k.size == 0:
        return None, None
    size = np.asarray(raw.size, np.float64)
    if size.ndim == 2:
        size = np.median(size, axis=0)
    v = r.values
    vel = v[:, 3:5].copy() if raw.vel is not None else None
    visible = (v[:, -1] > 0.5) if raw.visible is not None else None
    track = TrackRecord(track_id=int(track_id), category=raw.category, size=size.reshape(3), t=r.k * dt,
                        xy=v[:, 0:2].copy(), yaw=v[:, 2].copy(), vel=vel, visible=visible)
    return track, r


def box_polygon(xy: np.ndarray, yaw: float, length: float, width: float) -> np.ndarray:
    """The (4, 2) counter-clockwise footprint of a box centred at ``xy`` (2,) m."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = length / 2.0, width / 2.0
    local = np.array([[hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw]])
    rot = np.array([[c, -s], [s, c]])
    return local @ rot.T + np.asarray(xy, np.float64)


def static_obstacle(raw: RawTrack, kind: str) -> ObstacleRecord | None:
    """A static object as a static obstacle at its median pose; None if it moves."""
    xy = np.asarray(raw.xy, np.float64)
    if xy.shape[0] == 0:
        return None
    centre = np.median(xy, axis=0)
    if np.max(np.linalg.norm(xy - centre, axis=1)) > STATIC_MAX_MOTION_M:
        return None
    size = np.asarray(raw.size, np.float64)
    size = np.median(size, axis=0) if size.ndim == 2 else size
    yaw = float(np.angle(np.mean(np.exp(1j * np.asarray(raw.yaw)))))
    length, width = max(float(size[0]), 0.1), max(float(size[1]), 0.1)
    return ObstacleRecord(polygon=box_polygon(centre, yaw, length, width), height=max(float(size[2]), 0.1), kind=kind)


def static_or_skip(raw: RawTrack, kind: str | None, skip: Skipped, what: str) -> ObstacleRecord | Skipped:
    """A track without an agent category as a static obstacle of ``kind``, or why not.

    ``skip`` is the category's own Skipped, returned when ``kind`` is None (no
    static kind for it); a track that moves gives a Skipped at ``skip.source``
    saying ``what`` (e.g. "category 'SIGN'") moves.
    """
    if kind is None:
        return skip
    ob = static_obstacle(raw, kind)
    if ob is not None:
        return ob
    return Skipped(skip.source, f"{what} moves; no agent category for it")


@dataclass
class Converted:
    """Tracks on the grid: records, their ids, what was skipped, how many had gaps,
    and the fraction of written samples that are interpolated (not measured)."""

    tracks: list[TrackRecord]
    ids: TrackIds
    skipped: list[Skipped]
    gap_tracks: int
    interpolated_fraction: float


def convert_tracks(raws: Sequence[RawTrack], ego_source: str | None, dt: float, num_steps: int, source: str, *,
                   max_gap_s: float = DEFAULT_MAX_GAP_S) -> Converted:
    """Resample every raw track onto the grid (see ``resample_track``)."""
    ids = TrackIds([r.source_id for r in raws], ego_source)
    tracks, skipped, gap_tracks, interp, total = [], [], 0, 0, 0
    for raw in raws:
        if len(raw.t) == 0:
            skipped.append(Skipped(f"{source} track {raw.source_id}", "empty track (no samples)"))
            continue
        tr, r = resample_track(raw, ids[raw.source_id], dt, num_steps, max_gap_s=max_gap_s)
        if tr is None:
            skipped.append(Skipped(f"{source} track {raw.source_id}",
                                   f"no sample on the {dt:g} s grid within 0..{(num_steps - 1) * dt:g} s"))
            continue
        gap_tracks += bool(r.gaps)
        interp += int(r.interpolated.sum())
        total += len(r.k)
        tracks.append(tr)
    return Converted(tracks, ids, skipped, gap_tracks, interp / total if total else 0.0)


class TrackIds:
    """Deterministic integer ids: the ego is 0, the others 1.. in sorted source-id order."""

    def __init__(self, source_ids: Sequence[str], ego: str | None):
        others = sorted(s for s in set(source_ids) if s != ego)
        self._ids = {s: i + 1 for i, s in enumerate(others)}
        if ego is not None:
            self._ids[ego] = 0

    def __getitem__(self, source_id: str) -> int:
        return self._ids[source_id]

    def table(self) -> dict[int, str]:
        return {i: s for s, i in sorted(self._ids.items(), key=lambda x: x[1])}


# --------------------------------------------------------------------------
# Categories and markings
# --------------------------------------------------------------------------


def map_category(value: str, table: Mapping[str, str | None], source: str) -> tuple[str | None, Skipped | None]:
    """Source category -> records.CATEGORIES name, or (None, Skipped) when unusable/unknown."""
    if value in table and table[value] is not None:
        cat = table[value]
        assert cat in CATEGORIES, cat
        return cat, None
    if value in table:
        return None, Skipped(source, f"category {value!r} has no agent category (not a road user)")
    return None, Skipped(source, f"unknown category {value!r}; expected one of {', '.join(sorted(table))}")


def map_marking(value: str, table: Mapping[str, str], where: str) -> str:
    """Source marking name -> records.MARKINGS name; unknown values are an error naming ``where``."""
    m = table.get(value)
    if m is None:
        raise DriveE2EError(f"{where}: unknown lane marking {value!r}; expected one of {', '.join(sorted(table))}")
    assert m in MARKINGS, m
    return m


# --------------------------------------------------------------------------
# Maps
# --------------------------------------------------------------------------


def polyline_length(points: np.ndarray) -> float:
    """Arc length of a (n, 2) polyline, m."""
    p = np.asarray(points, np.float64)
    return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))) if len(p) > 1 else 0.0


def resample_polyline(points: np.ndarray, spacing: float) -> np.ndarray:
    """A (n, 2) polyline at ~even ``spacing`` m; first and last points kept exactly."""
    p = np.asarray(points, np.float64)[:, :2]
    if len(p) < 2:
        return p.copy()
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    if s[-1] <= 0:
        return p[[0, -1]].copy()
    n = max(int(math.ceil(s[-1] / spacing)), 1)
    q = np.linspace(0.0, s[-1], n + 1)
    return np.stack([np.interp(q, s, p[:, 0]), np.interp(q, s, p[:, 1])], axis=1)


def _heading(p: np.ndarray, at_end: bool) -> float:
    d = p[-1] - p[-2] if at_end else p[1] - p[0]
    return math.atan2(d[1], d[0])


def infer_successors(lanes: list[LaneRecord], tol_m: float = 1.0, max_angle: float = math.pi / 4) -> None:
    """Fill each lane's ``successors`` (in place) from geometry: lane b follows
    lane a when b starts within ``tol_m`` of a's end and their headings there
    differ by less than ``max_angle``."""
    usable = [ln for ln in lanes if len(ln.centerline) >= 2]
    if not usable:
        return
    starts = np.array([ln.centerline[0, :2] for ln in usable])
    for a in usable:
        end = a.centerline[-1, :2]
        ha = _heading(a.centerline, True)
        near = np.nonzero(np.linalg.norm(starts - end, axis=1) <= tol_m)[0]
        succ = []
        for j in near:
            b = usable[j]
            if b.id == a.id:
                continue
            if abs(_wrap(_heading(b.centerline, False) - ha)) < max_angle:
                succ.append(b.id)
        a.successors = sorted(set(a.successors) | set(succ))


def _near(points: np.ndarray, xy: np.ndarray, radius: float) -> bool:
    p = np.asarray(points, np.float64).reshape(-1, 2)
    if p.size == 0:
        return False
    d = np.min(np.linalg.norm(p[:, None, :] - xy[None, :, :], axis=2))
    return bool(d <= radius)


def crop_map(m: MapRecord, xy: np.ndarray, radius_m: float) -> MapRecord:
    """The part of ``m`` within ``radius_m`` of any point of ``xy`` (k, 2).

    Polylines and polygons are kept whole when any of their points (after
    densifying to 2 m) is near; successors pointing at dropped lanes are removed.
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    xy = xy[:: max(1, len(xy) // 200)]

    def near(p: np.ndarray) -> bool:
        return _near(resample_polyline(np.asarray(p)[:, :2], 2.0), xy, radius_m)

    lanes = [replace(ln) for ln in m.lanes if near(ln.centerline)]
    kept = {ln.id for ln in lanes}
    for ln in lanes:
        ln.successors = [s for s in ln.successors if s in kept]
    return replace(
        m, lanes=lanes,
        boundaries=[b for b in m.boundaries if near(b.points)],
        crosswalks=[c for c in m.crosswalks if near(np.vstack([c, c[:1]]))],
        stop_lines=[s for s in m.stop_lines if near(s.points) and (s.lane_id in kept or s.lane_id == -1)],
        drivable_areas=[g for g in m.drivable_areas if near(np.vstack([g, g[:1]]))],
        obstacles=[o for o in m.obstacles if near(np.vstack([o.polygon, o.polygon[:1]]))],
    )


# --------------------------------------------------------------------------
# Route, ego selection, behaviour
# --------------------------------------------------------------------------


def build_route(track: TrackRecord, spacing_m: float = ROUTE_SPACING_M) -> RouteRecord:
    """The ego's logged path, first to last sample, as route waypoints ~``spacing_m`` apart."""
    xy = np.asarray(track.xy, np.float64)
    if len(xy) == 0:
        raise DriveE2EError(f"track {track.track_id}: the ego track is empty; expected samples for a route")
    keep = [0]
    for i in range(1, len(xy)):
        if np.linalg.norm(xy[i] - xy[keep[-1]]) >= spacing_m:
            keep.append(i)
    if keep[-1] != len(xy) - 1:
        if len(keep) > 1 and np.linalg.norm(xy[-1] - xy[keep[-1]]) < 0.5 * spacing_m:
            keep[-1] = len(xy) - 1
        else:
            keep.append(len(xy) - 1)
    wp = xy[keep]
    if len(wp) == 1:  # a standing ego: a degenerate route of one point, repeated
        wp = np.vstack([wp, wp])
    return RouteRecord(waypoints=wp.copy(), source=xy[0].copy(), destination=xy[-1].copy())


def route_heading_change(waypoints: np.ndarray, min_step_m: float = 0.5) -> float:
    """Signed total heading change along a (n, 2) path, rad (left positive).

    Steps shorter than ``min_step_m`` are merged so that jitter of a standing
    vehicle adds no heading change.
    """
    p = np.asarray(waypoints, np.float64)
    pts = [p[0]] if len(p) else []
    for q in p[1:]:
        if np.linalg.norm(q - pts[-1]) >= min_step_m:
            pts.append(q)
    if len(pts) < 3:
        return 0.0
    d = np.diff(np.array(pts), axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    return float(np.sum(_wrap(np.diff(h))))


#: How ``select_ego`` starts the reason of a candidate rejected for a plausibility finding.
PLAUSIBILITY_PREFIX = "implausible motion: "


def select_ego(tracks: Sequence[TrackRecord], map_rec: MapRecord, num_steps: int, dt: float,
               ) -> tuple[TrackRecord | None, dict[int, str]]:
    """Pick an ego by the curation rules of the source benchmarks (nuPlan /
    Waymo-style "ego candidate"): a vehicle (``VEHICLES``) present at every
    step of the window, visible at every step, whose logged path is at least
    ``curation.MIN_ROUTE_LENGTH_M`` long, gives a route that follows the
    lanes (``curation.route_problems`` finds nothing) and has no plausibility
    finding (``curation.track_plausibility``: speed, acceleration, yaw rate
    within the category's bounds; an annotation glitch in the ego's log would
    be replayed as the ego's own driving). Among candidates the longest path
    wins (ties: lowest track id). Returns the track (or None) and the reason
    each other vehicle was rejected; a candidate rejected only for
    plausibility has a reason starting with ``PLAUSIBILITY_PREFIX``."""

    reasons: dict[int, str] = {}
    best: tuple[float, int, TrackRecord] | None = None
    for tr in tracks:
        if tr.category not in VEHICLES:
            continue
        k = np.rint(np.asarray(tr.t) / dt).astype(int)
        if len(np.unique(k)) < num_steps or k.min() != 0:
            reasons[tr.track_id] = f"present at {len(np.unique(k))} of {num_steps} steps"
            continue
        if tr.visible is not None and not np.all(tr.visible):
            reasons[tr.track_id] = "not visible at every step"
            continue
        length = polyline_length(tr.xy)
        if length < curation.MIN_ROUTE_LENGTH_M:
            reasons[tr.track_id] = f"moves {length:.1f} m < {curation.MIN_ROUTE_LENGTH_M:g} m"
            continue
        bad = curation.route_problems(build_route(tr), map_rec)
        if bad:
            reasons[tr.track_id] = bad[0]
            continue
        found = curation.track_plausibility(tr, dt)
        if found:
            more = f" (+{len(found) - 1} more)" if len(found) > 1 else ""
            reasons[tr.track_id] = f"{PLAUSIBILITY_PREFIX}{found[0].message} at t={found[0].t:.1f} s{more}"
            continue
        key = (-length, tr.track_id, tr)
        if best is None or key[:2] < best[:2]:
            best = key
    return (best[2] if best else None), reasons


#: Behaviour rule constants (see ``infer_behavior``).
STOP_SPEED = 0.1  # m/s: "stopped"
STOP_MIN_S = 1.0  # s stopped, then driving on at least STOP_RESUME_M
STOP_RESUME_M = 5.0
IPC_AHEAD_M = 25.0  # the ego within this before (or on) a crossing its path crosses
COV_AHEAD_M = 25.0
COV_MIN_ANGLE = math.radians(30.0)


def _speeds(tr: TrackRecord, dt: float) -> np.ndarray:
    """Speeds from positions (not the source's velocity field, which some conversions leave at zero)."""
    if len(tr.t) < 2:
        return np.zeros(len(tr.t))
    return np.linalg.norm(np.gradient(tr.xy, tr.t, axis=0), axis=1)


def infer_behavior(scenario: ScenarioRecord, map_rec: MapRecord) -> tuple[str, str]:
    """The behaviour label of a recorded scenario and a one-line why.

    In this order (the first that holds wins):

    * YLW is never inferred (needs signal states, which the sources lack).
    * STP: the ego is stopped (< 0.1 m/s, from its positions) for >= 1 s and
      afterwards drives on >= 5 m (a stop-and-go at a junction or behind traffic).
    * IPC: a pedestrian or cyclist is inside a crosswalk polygon that the
      ego's path crosses, while the ego is within 25 m before or on it.
    * COV: another vehicle's path crosses the ego's path at > 30 deg, and the
      other vehicle passes the crossing point while the ego is within 25 m
      before it (it has not yet reached it).
    * else the turn label from the route's total heading change: > 150 deg
      UT; > 40 deg left LFT; > 40 deg right RT; otherwise STR.

    The test of each rule is host-side (shapely).
    """
    from shapely.geometry import LineString, Point, Polygon

    dt = scenario.dt
    ego = next(t for t in scenario.tracks if t.track_id == scenario.ego_track_id)
    speed = _speeds(ego, dt)
    stopped = speed < STOP_SPEED
    run = 0
    for i, s in enumerate(stopped):
        run = run + 1 if s else 0
        if run * dt >= STOP_MIN_S and polyline_length(ego.xy[i:]) >= STOP_RESUME_M:
            return "STP", f"ego stopped >= {STOP_MIN_S:g} s at t={ego.t[i]:.1f} s, then drove on"
    path = LineString(ego.xy) if len(ego.xy) >= 2 and polyline_length(ego.xy) > 0 else None
    if path is not None:
        arc_ego = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ego.xy, axis=0), axis=1))])
        step_of = {int(round(t / dt)): i for i, t in enumerate(ego.t)}
        for cw in map_rec.crosswalks:
            poly = Polygon(cw)
            if not poly.is_valid or not path.intersects(poly):
                continue
            cross = path.intersection(poly)
            s_in = path.project(Point(cross.representative_point()))
            for tr in scenario.tracks:
                if tr.category not in ("pedestrian", "cyclist"):
                    continue
                for t, p in zip(tr.t, tr.xy):
                    i = step_of.get(int(round(t / dt)))
                    if i is None or not poly.contains(Point(p)):
                        continue
                    if -poly.length <= s_in - arc_ego[i] <= IPC_AHEAD_M:
                        return "IPC", f"{tr.category} {tr.track_id} on a crosswalk ahead of the ego at t={t:.1f} s"
        for tr in scenario.tracks:
            if tr.track_id == ego.track_id or tr.category not in VEHICLES or len(tr.xy) < 2:
                continue
            if polyline_length(tr.xy) < 1.0:
                continue
            other = LineString(tr.xy)
            hit = path.intersection(other)
            if hit.is_empty:
                continue
            pt = hit.representative_point() if hit.geom_type != "Point" else hit
            s_e, s_o = path.project(pt), other.project(pt)
            ie = int(np.clip(np.searchsorted(arc_ego, s_e), 1, len(ego.xy) - 1))
            arc_o = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(tr.xy, axis=0), axis=1))])
            io = int(np.clip(np.searchsorted(arc_o, s_o), 1, len(tr.xy) - 1))
            de, do = ego.xy[ie] - ego.xy[ie - 1], tr.xy[io] - tr.xy[io - 1]
            ang = abs(_wrap(math.atan2(de[1], de[0]) - math.atan2(do[1], do[0])))
            if min(ang, math.pi - ang) < COV_MIN_ANGLE:
                continue
            i_ego = step_of.get(int(round(tr.t[io] / dt)))
            if i_ego is not None and 0 < s_e - arc_ego[i_ego] <= COV_AHEAD_M:
                return "COV", f"vehicle {tr.track_id} crossed the ego's path ahead of it at t={tr.t[io]:.1f} s"
    turn = math.degrees(route_heading_change(scenario.route.waypoints))
    if abs(turn) > 150:
        return "UT", f"heading change {turn:.0f} deg"
    if turn > 40:
        return "LFT", f"heading change {turn:.0f} deg"
    if turn < -40:
        return "RT", f"heading change {turn:.0f} deg"
    return "STR", f"heading change {turn:.0f} deg"


# --------------------------------------------------------------------------
# Scenarios, windows, writing
# --------------------------------------------------------------------------


def windows(num_steps: int, dt: float, window_s: float | None) -> list[tuple[int, int]]:
    """Non-overlapping ``[k0, k1)`` step ranges of ``window_s`` (the whole log if None).
    A last piece shorter than half a window is dropped."""
    if window_s is None:
        return [(0, num_steps)]
    w = max(1, int(round(window_s / dt)))
    out = [(k, min(k + w, num_steps)) for k in range(0, num_steps, w)]
    if len(out) > 1 and out[-1][1] - out[-1][0] < w / 2:
        out.pop()
    return out


def cut_window(tracks: Sequence[TrackRecord], k0: int, k1: int, dt: float) -> list[TrackRecord]:
    """The tracks' samples at steps ``[k0, k1)``, times shifted to start at 0; empty tracks dropped."""
    out = []
    for tr in tracks:
        k = np.rint(np.asarray(tr.t) / dt).astype(int)
        m = (k >= k0) & (k < k1)
        if not m.any():
            continue
        out.append(replace(
            tr, t=(k[m] - k0) * dt, xy=tr.xy[m], yaw=tr.yaw[m],
            vel=None if tr.vel is None else tr.vel[m],
            visible=None if tr.visible is None else tr.visible[m],
            quality=None if tr.quality is None else tr.quality[m],
        ))
    return out


#: Signal states of a whole log: a function of log times (k,) s -> {group: (k,)
#: SIGNAL_STATES index}, or full-log arrays {group: (num_steps,)}.
SignalSource = Union[Callable[[np.ndarray], Mapping[int, np.ndarray]], Mapping[int, np.ndarray]]


def window_signals(signals: SignalSource | None, k0: int, k1: int, dt: float,
                   num_steps: int) -> dict[int, np.ndarray]:
    """The signal states at log steps ``[k0, k1)`` as {group: (k1 - k0,) int8}."""
    if signals is None:
        return {}
    if callable(signals):
        states = signals((k0 + np.arange(k1 - k0)) * dt)
    else:
        for g, v in signals.items():
            if len(v) != num_steps:
                raise ValueError(f"signals[{g}]: expected {num_steps} states (one per log step), got {len(v)}")
        states = {g: np.asarray(v)[k0:k1] for g, v in signals.items()}
    return {int(g): np.asarray(v, np.int8) for g, v in sorted(states.items())}


_UNSAFE = re.compile(r"[^A-Za-z0-9_.\-]+")


def safe_id(text: str) -> str:
    """A portable id (file name) from any text."""
    s = _UNSAFE.sub("_", str(text)).strip("_.-") or "x"
    return s if s[0].isalnum() else "x" + s


def make_scenario(scenario_id: str, map_rec: MapRecord, tracks: list[TrackRecord], ego_id: int, dt: float,
                  num_steps: int, options: ImportOptions, *, intersection_id: str | None = None,
                  weather: str = "clear", time_of_day: str = "day",
                  signals: Mapping[int, np.ndarray] | None = None) -> tuple[ScenarioRecord, str]:
    """A ScenarioRecord with the ego's route and the inferred behaviour; also the label's why.

    ``signals``: {group: (num_steps,) SIGNAL_STATES index} of this scenario.
    """
    ego = next((t for t in tracks if t.track_id == ego_id), None)
    if ego is None:
        raise DriveE2EError(f"{scenario_id}: no track {ego_id} to use as ego")
    s = ScenarioRecord(
        scenario_id=safe_id(scenario_id), split=options.split, intersection_id=intersection_id or map_rec.map_id,
        map_id=map_rec.map_id, behavior="STR", weather=weather, time_of_day=time_of_day, ego_track_id=ego_id,
        route=build_route(ego), dt=dt, num_steps=num_steps, tracks=sorted(tracks, key=lambda t: t.track_id),
        signals=dict(signals or {}),
    )
    label, why = infer_behavior(s, map_rec)
    assert label in BEHAVIORS
    s.behavior = label
    return s, why


def windowed_scenarios(base_id: str, map_rec: MapRecord, tracks: list[TrackRecord], ego_id: int | None, dt: float,
                       num_steps: int, options: ImportOptions, source: str, skipped: list[Skipped],
                       notes: list[str], *, limit: int | None = None, signals: SignalSource | None = None,
                       source_ids: Mapping[int, str] | None = None, **kwargs) -> list[ScenarioRecord]:
    """One scenario per window of the log (see the module docstring).

    ``limit``: at most this many scenarios (default ``options.max_scenarios``).
    ``source_ids``: track id -> source id (``TrackIds.table()``), to name
    tracks in notes and skip reasons as the user knows them (``--ego`` takes
    source ids).
    ``signals``: the whole log's signal states (``SignalSource``), cut to each
    window by ``window_signals``; None: no signals.
    ``kwargs`` go to ``make_scenario`` (intersection_id, weather, time_of_day).
    """
    limit = options.max_scenarios if limit is None else limit
    spans = windows(num_steps, dt, options.window_s)

    def name(i: int) -> str:
        return f"{i} (source {source_ids[i]})" if source_ids and i in source_ids else str(i)

    out = []
    for w, (k0, k1) in enumerate(spans):
        if limit is not None and len(out) >= limit:
            break
        sid = base_id if len(spans) == 1 else f"{base_id}_w{w:02d}"
        where = source if len(spans) == 1 else f"{source} window {k0 * dt:g}-{k1 * dt:g} s"
        cut = cut_window(tracks, k0, k1, dt)
        n = k1 - k0
        ego = ego_id
        if ego is None:
            chosen, reasons = select_ego(cut, map_rec, n, dt)
            if chosen is None:
                # the near misses (rejected only for their motion) first: they are what --ego could pick
                near = sorted(reasons.items(), key=lambda x: not x[1].startswith(PLAUSIBILITY_PREFIX))
                why = "; ".join(f"{name(i)}: {r}" for i, r in near[:3])
                motion_only = bool(near) and near[0][1].startswith(PLAUSIBILITY_PREFIX)
                hint = "; --ego SOURCE_ID uses one anyway" if motion_only else ""
                skipped.append(Skipped(where, f"no vehicle qualifies as ego ({why or 'no vehicles'}){hint}"))
                continue
            ego = chosen.track_id
            passed = [f"track {name(i)}: {r}" for i, r in reasons.items() if r.startswith(PLAUSIBILITY_PREFIX)]
            notes.append(f"{sid}: ego chosen automatically: track {name(ego)} (the longest qualifying path)"
                         + (f"; candidates passed over: {'; '.join(passed)}" if passed else ""))
        tr = next((t for t in cut if t.track_id == ego), None)
        k = np.rint(np.asarray(tr.t) / dt).astype(int) if tr is not None else np.zeros(0, int)
        if tr is None or len(np.unique(k)) < n:
            have = len(np.unique(k))
            skipped.append(Skipped(where, f"the ego (track {ego}) is present at {have} of {n} steps; "
                                          "expected every step"))
            continue
        s, why = make_scenario(sid, map_rec, cut, ego, dt, n, options,
                               signals=window_signals(signals, k0, k1, dt, num_steps), **kwargs)
        notes.append(f"{s.scenario_id}: behaviour {s.behavior} ({why})")
        out.append(s)
    return out


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


def write_result(result: ImportResult, out: str | Path, *, name: str, force: bool = False) -> Path:
    """Write ``result`` as the suite folder ``out`` (validated; atomic; see ``schema.write_suite``).

    With no scenario the error names how many items were skipped and the first
    one's source and reason (usually the whole story: a file without an ego).
    """

    if not result.scenarios:
        n = len(result.skipped)
        first = f"; first: {result.skipped[0].source}: {result.skipped[0].reason}" if n else ""
        raise DriveE2EError(f"nothing to write to {out}: no scenario could be imported "
                            f"({n} item{'s' if n != 1 else ''} skipped{first})")
    used = {s.map_id for s in result.scenarios}
    suite = SuiteRecord(name=safe_id(name), version="1", maps={k: v for k, v in result.maps.items() if k in used},
                        scenarios=result.scenarios, meta=dict(result.meta))
    return write_suite(suite, out, overwrite=force)


def read_table(path: Path, columns: Sequence[str]) -> dict[str, np.ndarray]:
    """Columns of a Parquet (``.parquet``) or Feather/Arrow file as numpy arrays."""
    try:
        import pyarrow.feather as feather
        import pyarrow.parquet as parquet
    except ImportError:
        raise DriveE2EError(f"{path}: reading Parquet/Feather needs pyarrow; install it with "
                            "pip install 'drivee2e-jax[import]'") from None
    try:
        if str(path).endswith(".parquet"):
            table = parquet.read_table(path)
        else:
            table = feather.read_table(path)
    except FileNotFoundError:
        raise
    except Exception as e:  # noqa: BLE001 - pyarrow raises many types for a bad file
        raise DriveE2EError(f"{path}: not a readable {'Parquet' if str(path).endswith('.parquet') else 'Feather'} "
                            f"file ({type(e).__name__}: {' '.join(str(e).split())[:120]})") from None
    missing = [c for c in columns if c not in table.column_names]
    if missing:
        raise DriveE2EError(f"{path}: missing column {missing[0]!r}; expected columns {', '.join(columns)}")
    out = {}
    for c in columns:
        col = table.column(c)
        if _is_text(col.type):
            out[c] = np.asarray(col.to_pylist(), dtype=object)
        else:
            out[c] = col.to_numpy()
    return out


def _is_text(t) -> bool:
    import pyarrow as pa

    return pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_dictionary(t)


def parse_xml(path: Path, what: str, root_tag: str):
    """The root element of the XML file ``path``, which must be ``<root_tag>``.

    ``what`` names the format in the errors ("CommonRoad", "OSM", ...).
    """

    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise DriveE2EError(f"{path}: expected well-formed {what} XML, got a parse error ({e})") from None
    except OSError as e:
        raise DriveE2EError(f"{path}: expected a readable {what} file, got {e.strerror or e}") from None
    if root.tag != root_tag:
        article = "an" if root_tag[0].lower() in "aeiou" else "a"
        raise DriveE2EError(f"{path}: expected {article} <{root_tag}> root element, got <{root.tag}>")
    return root
