"""Routes, host-side: the spacing constants, building a route from a logged
path, densifying it for packing, and its high-level commands.

* ``build_route(track, spacing_m=LOG_ROUTE_SPACING_M) -> RouteRecord``: an
  imported ego's logged path decimated to ~``spacing_m``, its last waypoint
  ``ROUTE_END_MARGIN_M`` short of the logged end (the importers).
* ``route_heading_change(waypoints) -> float``: signed total heading change, rad.
* ``densify_route(waypoints, spacing=ROUTE_STEP_M) -> (xy, arc)``: the packed
  route points (``pack``).
* ``route_commands(xy, in_junction) -> (n,) int32 Command``: CARLA-style
  commands per route point; ``junction_area(map)`` gives ``in_junction``.

The three spacings are different things and differ on purpose:
``ROUTE_STEP_M`` (1.0 m) is the step of the packed route every policy sees;
``LOG_ROUTE_SPACING_M`` (2.0 m) and ``TWIN15_ROUTE_SPACING_M`` (1.5 m) are
how far apart the waypoints of a written route record are, for imported
logs and the twin15 generator.
"""

from __future__ import annotations

import numpy as np
import shapely

from drivee2e_jax import types
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.polyline import arc_length, densify_polyline, wrap_angle
from drivee2e_jax.records import MapRecord, RouteRecord, TrackRecord

__all__ = [
    "ROUTE_STEP_M", "LOG_ROUTE_SPACING_M", "TWIN15_ROUTE_SPACING_M", "ROUTE_END_MARGIN_M",
    "build_route", "route_heading_change", "densify_route", "route_commands", "junction_area",
]

#: Step of the packed route (``Scenario.route``), m: waypoints are densified
#: to it as CARLA's route planner does.
ROUTE_STEP_M = 1.0
#: Waypoint spacing of an imported log's route record, m.
LOG_ROUTE_SPACING_M = 2.0
#: Waypoint spacing of a twin15 route record, m (1.5-2 m; see ``twin15.assemble``).
TWIN15_ROUTE_SPACING_M = 1.5
#: How far before the logged ego's last position an imported route ends, m.
#: LB 2.0's RouteCompletionTest passes a route point only once the ego is
#: STRICTLY ahead of it, and a replay of the log ends exactly on the last
#: logged position: a route ending there is never completed by the log
#: itself (RC stops at the last point short of it, ``Failed - TickRuntime``).
#: 0.5 m is far above the replay's tracking error at the end of the log and
#: far below a route point step (``ROUTE_STEP_M``).
ROUTE_END_MARGIN_M = 0.5


def _cut_end(wp: np.ndarray, margin: float) -> np.ndarray:
    """The polyline ``wp`` (n, 2) without its last ``margin`` m of arc (unchanged
    when it is not longer than ``margin``)."""
    arc = arc_length(wp)
    end = arc[-1] - margin
    if end <= 0.0:
        return wp
    j = int(np.searchsorted(arc, end, side="left"))  # first point at or past ``end``; j >= 1
    r = (end - arc[j - 1]) / (arc[j] - arc[j - 1])
    if r <= 0.0:
        return wp[:j]
    return np.vstack([wp[:j], wp[j - 1] + r * (wp[j] - wp[j - 1])])


def build_route(track: TrackRecord, spacing_m: float = LOG_ROUTE_SPACING_M) -> RouteRecord:
    """The ego's logged path, first to last sample, as route waypoints ~``spacing_m`` apart.

    The last waypoint lies ``ROUTE_END_MARGIN_M`` before the logged end along
    the path, so that replaying the log completes the route; ``source`` and
    ``destination`` are the exact logged ends. An ego that moves less than
    the margin keeps its whole (degenerate) path."""
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
    else:
        wp = _cut_end(wp, ROUTE_END_MARGIN_M)
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
    return float(np.sum(wrap_angle(np.diff(h))))


def densify_route(waypoints: np.ndarray, spacing: float = ROUTE_STEP_M) -> tuple[np.ndarray, np.ndarray]:
    """Resample a polyline every ``spacing`` m of arc length, keeping the last
    point exactly; returns (xy (n, 2) float64, arc (n,) cumulative length of
    the resampled polyline). Repeated waypoints are dropped first
    (``polyline.densify_polyline``)."""
    return densify_polyline(waypoints, spacing)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True."""
    d = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def route_commands(xy: np.ndarray, in_junction: np.ndarray | None = None, *,
                   turn_deg: float = 30.0, window_m: float = 5.0, curve_deg: float = 15.0) -> np.ndarray:
    """CARLA-style high-level command per route point (int32 ``Command``).

    A *turn region* is a run of points either inside the junction
    (``in_junction``, e.g. near connector lanes; gaps of <= 3 points are
    closed) or, when no junction is known, where the heading changes by more
    than ``curve_deg`` over +-``window_m`` of arc. Over each region the total
    heading change (entering segment to leaving segment) decides: > +turn_deg
    LEFT, < -turn_deg RIGHT, otherwise STRAIGHT inside a junction and
    LANEFOLLOW on a plain curve. Every other point is LANEFOLLOW.
    """
    xy = np.asarray(xy, dtype=np.float64)
    n = len(xy)
    cmd = np.full(n, int(types.Command.LANEFOLLOW), np.int32)
    if n < 2:
        return cmd
    d = np.diff(xy, axis=0)
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    hp = np.r_[heading, heading[-1]]  # heading leaving each point
    junction = in_junction is not None and bool(np.any(in_junction))
    if junction:
        mask = np.asarray(in_junction, bool).copy()
        for i0, i1 in _runs(~mask):
            if i0 > 0 and i1 < n and i1 - i0 <= 3:
                mask[i0:i1] = True
    else:
        arc = arc_length(xy)
        change = np.interp(arc + window_m, arc, hp) - np.interp(arc - window_m, arc, hp)
        mask = np.abs(change) > np.radians(curve_deg)
    turn = np.radians(turn_deg)
    for i0, i1 in _runs(mask):
        dh = hp[min(i1, n - 1)] - hp[max(i0 - 1, 0)]
        if dh > turn:
            cmd[i0:i1] = int(types.Command.LEFT)
        elif dh < -turn:
            cmd[i0:i1] = int(types.Command.RIGHT)
        elif junction:
            cmd[i0:i1] = int(types.Command.STRAIGHT)
    return cmd


def junction_area(m: MapRecord):
    """Shapely area covered by the map's connector lanes (None without any)."""
    parts = [shapely.LineString(np.asarray(ln.centerline)).buffer(ln.width / 2.0)
             for ln in m.lanes if ln.type == "connector" and len(ln.centerline) >= 2]
    if not parts:
        return None
    area = shapely.union_all(parts)
    shapely.prepare(area)
    return area
