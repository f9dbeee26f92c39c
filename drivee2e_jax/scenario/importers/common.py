"""Shared host-side machinery of the recorded-traffic importers.

Every format module (``importers/<format>.py``) exposes
``load(paths: list[Path], options: ImportOptions) -> ImportResult`` and uses
the helpers below, so that resampling, routes, ego choice, behaviour labels,
categories and writing work the same for every source. Nothing here runs
under ``jit``; arrays are numpy. Units: metres, seconds, radians, m/s.

This module is the importers' documented entry point: the names below live
in ``results`` (options and results), ``tracks`` (tracks onto the grid),
``maps`` (map clean-up), ``behavior`` (ego choice, labels), ``scenarios``
(windows, scenario records), ``files`` (reading, writing) and are imported
here for the format modules. Polyline helpers are ``drivee2e_jax.polyline``'s,
route building ``scenario.routes``'s.

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
(``drivee2e_jax.polyline``: ``resample_polyline(points, spacing) -> (m, 2)``
    even arc-length spacing, first and last points kept; ``polyline_length``.)
``infer_successors(lanes, tol_m=1.0, max_angle=pi/4)``: fills
    ``LaneRecord.successors`` from geometry (end point within ``tol_m`` of a
    start point, headings within ``max_angle``), for sources without a lane graph.
``crop_map(m, xy, radius_m) -> MapRecord``: only what lies within ``radius_m``
    of any of the points ``xy`` (k, 2); successors to dropped lanes removed.

Ego, route, behaviour
---------------------
``build_route(track, spacing_m=routes.LOG_ROUTE_SPACING_M) -> RouteRecord``: the ego's own
    logged path from its first to its last sample (as twin15 does), decimated to
    ~``spacing_m``, with exact source and destination; the last waypoint lies
    ``routes.ROUTE_END_MARGIN_M`` (0.5 m) before the destination so that the
    log's replay passes it. The path is what the
    log replay drives; ``curation.route_lane_match`` snaps it to the map's lanes
    to check it follows them (``curation.check_route``). ``windowed_scenarios``
    skips a scenario that ``curation.fair_test_problems`` refuses (an ego that
    travels < ``curation.MIN_EGO_TRAVEL_M``).
``select_ego(tracks, map_rec, num_steps, dt) -> (track | None, reasons)``:
    the source benchmark's curation rule for a scenario without a recorded ego
    (see the function); ``reasons`` maps each rejected vehicle's id to why.
    Candidates with a plausibility finding are passed over (reason starting
    ``PLAUSIBILITY_PREFIX``) and named in the "ego chosen automatically" note.
``infer_behavior(scenario, map_rec) -> (label, why)``: see the function for
    the rule (STP / IPC / COV when the data shows it, else the turn label;
    thresholds in ``scenario.labels``, shared with twin15).
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

from drivee2e_jax.scenario.routes import build_route, route_heading_change

from .behavior import PLAUSIBILITY_PREFIX, infer_behavior, select_ego
from .files import parse_xml, read_table, write_result
from .maps import crop_map, infer_successors, map_marking
from .results import ImportOptions, ImportResult, Skipped, merge_results
from .scenarios import SignalSource, cut_window, make_scenario, safe_id, window_signals, windowed_scenarios, windows
from .tracks import (
    DEFAULT_MAX_GAP_S,
    DEFAULT_SIZES,
    GRID_SNAP_S,
    STATIC_MAX_MOTION_M,
    VEHICLES,
    Converted,
    RawTrack,
    Resampled,
    TrackIds,
    box_polygon,
    convert_tracks,
    map_category,
    resample,
    resample_track,
    static_obstacle,
    static_or_skip,
)

__all__ = [
    "ImportOptions", "Skipped", "ImportResult", "RawTrack", "Resampled", "TrackIds",
    "DEFAULT_MAX_GAP_S", "GRID_SNAP_S", "STATIC_MAX_MOTION_M", "VEHICLES",
    "DEFAULT_SIZES", "PLAUSIBILITY_PREFIX", "resample", "resample_track", "box_polygon", "static_obstacle",
    "static_or_skip", "map_category", "map_marking", "infer_successors",
    "crop_map", "build_route", "select_ego", "infer_behavior", "route_heading_change",
    "windows", "cut_window", "window_signals", "SignalSource", "make_scenario", "Converted", "convert_tracks",
    "windowed_scenarios", "merge_results", "safe_id", "write_result", "read_table", "parse_xml",
]
