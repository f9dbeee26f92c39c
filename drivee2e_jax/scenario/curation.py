"""Deterministic curation checks of recorded scenarios (pure host functions).

Schema validation (``scenario.schema``) says whether a suite is *readable*;
these checks say whether a recorded scenario is *plausible* as a benchmark
case. Each :class:`Finding` names the scenario, the track and the time. They
are warnings: ``drivee2e suite validate`` prints them and fails only with
``--strict``. Importers use :func:`route_problems` and
:func:`track_plausibility` to choose an ego.

Checks
------
* **completeness** (:func:`check_completeness`): a track missing steps between
  its first and last sample (a gap: a step difference larger than the track's
  usual sampling stride, so a track sampled every 2nd step has none), an ego that does not cover every step of
  the log, an ego that is not visible at some step.
* **plausibility** (:func:`check_plausibility`): speed, acceleration and yaw
  rate against per-category bounds (:data:`BOUNDS`). Speed is the central
  difference of positions over 2 steps, acceleration the difference of those
  speeds over ``ACCEL_BASE_S`` (0.5 s; a shorter base turns 5 cm of box jitter
  at 10 Hz into several m/s^2), yaw rate the wrapped yaw difference over the
  same base, checked only above ``YAW_RATE_MIN_SPEED`` (heading of a standing
  box is noise) and never for pedestrians (they turn on the spot). Only runs of
  consecutive steps are differenced; a run of violations is one finding (its
  first time, the worst value).
* **route** (:func:`check_route`): the ego's route is at least
  ``MIN_ROUTE_LENGTH_M`` long and follows the lanes: every 1 m route point is
  within ``width / 2 + LANE_MARGIN_M`` of a lane centreline whose direction is
  within ``LANE_ALIGN_MAX`` of the route's (the simulator's off-lane rule),
  except stretches shorter than ``MAX_OFF_LANE_M``.
* **overlap** (:func:`check_overlaps`): the ego's logged box overlaps another
  agent's box at the same step (annotation overlap). An overlap present when
  the two first appear together is ignored by the simulator while it lasts
  (``infractions.logged_overlap_spans``); any other is a collision in the log
  that log replay is charged for.

Refusals
--------
:func:`fair_test_problems` says why a scenario cannot be a fair closed-loop
test at all; the importers skip such a scenario with that reason
(``importers.scenarios.windowed_scenarios``):

* the logged ego travels less than ``MIN_EGO_TRAVEL_M`` (its route, waypoints
  and destination, jitter-free: decimated to 2 m): nothing to drive.

Bounds per category (speed m/s, |acceleration| m/s^2, |yaw rate| rad/s) are
generous physical limits, not comfort limits: they catch annotation glitches
(identity switches, teleports), not aggressive drivers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely.geometry import Polygon

from drivee2e_jax.polyline import arc_length, polyline_length, resample_polyline, wrap_angle
from drivee2e_jax.records import MapRecord, RouteRecord, ScenarioRecord, SuiteRecord, TrackRecord

__all__ = [
    "Finding", "BOUNDS", "MIN_ROUTE_LENGTH_M", "route_lane_match", "route_problems", "check_completeness",
    "track_plausibility", "check_plausibility", "check_route", "check_overlaps", "curate_scenario", "curate_suite",
    "MIN_EGO_TRAVEL_M", "ego_travel_m", "fair_test_problems",
]

#: (max speed m/s, max |acceleration| m/s^2, max |yaw rate| rad/s or None) per category.
BOUNDS: dict[str, tuple[float, float, float | None]] = {
    "car": (45.0, 12.0, 1.5),
    "van": (45.0, 12.0, 1.5),
    "truck": (35.0, 8.0, 1.2),
    "bus": (35.0, 8.0, 1.2),
    "motorcycle": (50.0, 12.0, 2.0),
    "tricycle": (20.0, 8.0, 2.0),
    "cyclist": (15.0, 8.0, 3.0),
    "pedestrian": (6.0, 8.0, None),
}
ACCEL_BASE_S = 0.5
YAW_RATE_MIN_SPEED = 2.0  # m/s
#: A route shorter than this is no benchmark case, m.
MIN_ROUTE_LENGTH_M = 20.0
#: An imported scenario whose logged ego travels less than this is refused, m.
#: LB 2.0's RouteCompletionTest completes a route once RC > 99 % and the ego
#: is within 10 m of its last point (``metrics.criteria.RC_DISTANCE_M``): on a
#: shorter route the ego starts inside that radius and the route tests no
#: driving. A standing ego's log (box jitter of a few cm) gives a route of
#: ~0 m that not even its own replay completes (RC 0, ``Failed -
#: TickRuntime``). The automatic ego choice asks more (``MIN_ROUTE_LENGTH_M``).
MIN_EGO_TRAVEL_M = 10.0
#: The simulator's off-lane rule (``infractions``): width / 2 + 0.5 m, lanes within 120 deg.
LANE_MARGIN_M = 0.5
LANE_ALIGN_MAX = math.radians(120.0)
#: Off-lane route stretches up to this long are tolerated (lane changes across gaps in the map), m.
MAX_OFF_LANE_M = 5.0


@dataclass(frozen=True)
class Finding:
    """One curation warning: scenario, track (-1: none), time (s), check name, message."""

    scenario_id: str
    track_id: int
    t: float
    check: str
    message: str

    def __str__(self) -> str:
        who = f" track {self.track_id}" if self.track_id >= 0 else ""
        return f"{self.scenario_id}:{who} t={self.t:.1f} s: {self.check}: {self.message}"


# --------------------------------------------------------------------------
# Lanes and routes
# --------------------------------------------------------------------------


def _densify(points: np.ndarray, spacing: float = 1.0) -> np.ndarray:
    """Even points <= ``spacing`` apart (a zero-length path: its first point only)."""
    p = np.asarray(points, np.float64)
    if len(p) >= 2 and polyline_length(p) <= 0:
        return p[:1].copy()
    return resample_polyline(p, spacing, dedupe_tol=0.0, count_slack=0.0)


def route_lane_match(points: np.ndarray, map_rec: MapRecord) -> tuple[np.ndarray, np.ndarray]:
    """Snap a path to the map's lanes.

    Args:
      points: (n, 2) path, m (at least 2 points; directions from its differences).
      map_rec: the map.

    Returns:
      lane: (n,) int index into ``map_rec.lanes`` of the nearest lane running
        the path's way (within ``LANE_ALIGN_MAX``), -1 when none is within
        ``width / 2 + LANE_MARGIN_M``.
      offset: (n,) distance to that lane's centreline, m (inf when none).
    """
    p = np.asarray(points, np.float64)
    n = len(p)
    lane = np.full(n, -1, np.int64)
    offset = np.full(n, np.inf)
    segs = [(i, ln.centerline[:-1, :2], ln.centerline[1:, :2], ln.width) for i, ln in enumerate(map_rec.lanes)
            if len(ln.centerline) >= 2]
    if n == 0 or not segs:
        return lane, offset
    a = np.concatenate([s[1] for s in segs])
    b = np.concatenate([s[2] for s in segs])
    idx = np.concatenate([np.full(len(s[1]), s[0]) for s in segs])
    half = np.concatenate([np.full(len(s[1]), s[3] / 2.0 + LANE_MARGIN_M) for s in segs])
    # only segments that can be within reach of the path's bounding box
    lo, hi = p.min(axis=0) - half.max(), p.max(axis=0) + half.max()
    keep = np.all((np.maximum(a, b) >= lo) & (np.minimum(a, b) <= hi), axis=1)
    if not keep.any():
        return lane, offset
    a, b, idx, half = a[keep], b[keep], idx[keep], half[keep]
    d = np.gradient(p, axis=0) if n >= 2 else np.zeros_like(p)
    heading = np.arctan2(d[:, 1], d[:, 0])
    ab = b - a
    seg_heading = np.arctan2(ab[:, 1], ab[:, 0])
    ab2 = np.maximum(np.sum(ab * ab, axis=1), 1e-12)
    chunk = max(1, 2_000_000 // len(a))  # points per block: bounded memory for big maps
    for i0 in range(0, n, chunk):
        q = p[i0:i0 + chunk, None, :]  # (c, 1, 2) against (S, 2) segments
        u = np.clip(np.sum((q - a) * ab, axis=2) / ab2, 0.0, 1.0)
        dist = np.linalg.norm(a + u[..., None] * ab - q, axis=2)
        ok = (np.abs(wrap_angle(seg_heading[None, :] - heading[i0:i0 + chunk, None])) <= LANE_ALIGN_MAX) & (dist <= half)
        d = np.where(ok, dist, np.inf)
        j = np.argmin(d, axis=1)
        hit = np.isfinite(d[np.arange(len(j)), j])
        lane[i0:i0 + chunk] = np.where(hit, idx[j], -1)
        offset[i0:i0 + chunk] = np.where(hit, d[np.arange(len(j)), j], np.inf)
    return lane, offset


def _off_lane_stretches(route: RouteRecord, map_rec: MapRecord) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """The 1 m route points and the (s_start, s_end) arc ranges off every aligned lane."""
    pts = _densify(route.waypoints)
    if len(pts) < 2:
        return pts, []
    lane, _ = route_lane_match(pts, map_rec)
    s = arc_length(pts)
    out, start = [], None
    for i, li in enumerate(lane):
        if li < 0 and start is None:
            start = i
        if li >= 0 and start is not None:
            out.append((s[start], s[i - 1]))
            start = None
    if start is not None:
        out.append((s[start], s[-1]))
    return pts, out


def route_problems(route: RouteRecord, map_rec: MapRecord) -> list[str]:
    """Why ``route`` is no valid benchmark route (empty: it is): too short, or off the lanes."""
    length = float(np.sum(np.linalg.norm(np.diff(np.asarray(route.waypoints), axis=0), axis=1)))
    if length < MIN_ROUTE_LENGTH_M:
        return [f"route is {length:.1f} m long; expected >= {MIN_ROUTE_LENGTH_M:g} m"]
    _, stretches = _off_lane_stretches(route, map_rec)
    return [f"route leaves the lanes from {a:.0f} m to {b:.0f} m along it ({b - a:.0f} m > {MAX_OFF_LANE_M:g} m)"
            for a, b in stretches if b - a > MAX_OFF_LANE_M]


# --------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------


def _steps(tr: TrackRecord, dt: float) -> np.ndarray:
    return np.rint(np.asarray(tr.t, np.float64) / dt).astype(np.int64)


def check_completeness(s: ScenarioRecord) -> list[Finding]:
    """Track gaps; an ego not covering or not visible at every step."""
    out = []
    for tr in s.tracks:
        k = _steps(tr, s.dt)
        if len(k) == 0:
            out.append(Finding(s.scenario_id, tr.track_id, 0.0, "completeness", "track has no samples"))
            continue
        # a track sampled every s steps (a slower source) has gaps only beyond s
        stride = max(1, int(np.median(np.diff(k)))) if len(k) > 1 else 1
        for i in np.nonzero(np.diff(k) > stride)[0]:
            n = int(k[i + 1] - k[i] - 1)
            out.append(Finding(s.scenario_id, tr.track_id, float(k[i] + 1) * s.dt, "completeness",
                               f"gap of {n} step{'s' if n != 1 else ''} ({n * s.dt:.1f} s) until "
                               f"t={k[i + 1] * s.dt:.1f} s"))
        if tr.track_id == s.ego_track_id:
            if k[0] > 0 or k[-1] < s.num_steps - 1:
                out.append(Finding(s.scenario_id, tr.track_id, float(k[0]) * s.dt, "completeness",
                                   f"ego covers steps {k[0]}..{k[-1]}; expected 0..{s.num_steps - 1}"))
            if tr.visible is not None and not np.all(tr.visible):
                i = int(np.argmin(tr.visible))
                out.append(Finding(s.scenario_id, tr.track_id, float(tr.t[i]), "completeness",
                                   f"ego not visible at {int(np.sum(~np.asarray(tr.visible, bool)))} steps"))
    return out


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    out, start = [], None
    for i, m in enumerate(mask):
        if m and start is None:
            start = i
        if not m and start is not None:
            out.append((start, i))
            start = None
    if start is not None:
        out.append((start, len(mask)))
    return out


def track_kinematics(tr: TrackRecord, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-sample (t, speed, acceleration, yaw rate) estimates; NaN where the
    needed neighbours are missing (see the module docstring for the stencils)."""
    k = _steps(tr, dt)
    n = len(k)
    full = np.full(int(k.max() - k.min() + 1) if n else 0, np.nan)
    xy = np.full((len(full), 2), np.nan)
    yaw = full.copy()
    if n:
        xy[k - k.min()] = tr.xy
        yaw[k - k.min()] = tr.yaw
    speed = full.copy()
    if len(full) >= 3:
        speed[1:-1] = np.linalg.norm(xy[2:] - xy[:-2], axis=1) / (2 * dt)
    h = max(1, int(round(ACCEL_BASE_S / (2 * dt))))
    acc, yr = full.copy(), full.copy()
    if len(full) > 2 * h:
        acc[h:-h] = (speed[2 * h:] - speed[:-2 * h]) / (2 * h * dt)
        yr[h:-h] = wrap_angle(yaw[2 * h:] - yaw[:-2 * h]) / (2 * h * dt)
    t = (np.arange(len(full)) + (k.min() if n else 0)) * dt
    return t, speed, acc, yr


def track_plausibility(tr: TrackRecord, dt: float, scenario_id: str = "") -> list[Finding]:
    """Speed / acceleration / yaw-rate bounds of one track's category (:data:`BOUNDS`)."""
    bounds = BOUNDS.get(tr.category)
    if bounds is None or len(tr.t) < 3:
        return []
    vmax, amax, wmax = bounds
    t, v, a, w = track_kinematics(tr, dt)
    checks = [("speed", v, vmax, "m/s"), ("acceleration", np.abs(a), amax, "m/s^2")]
    if wmax is not None:
        checks.append(("yaw rate", np.where(v > YAW_RATE_MIN_SPEED, np.abs(w), np.nan), wmax, "rad/s"))
    out = []
    for name, x, bound, unit in checks:
        with np.errstate(invalid="ignore"):
            bad = np.nan_to_num(x, nan=0.0) > bound
        for i0, i1 in _runs(bad):
            out.append(Finding(scenario_id, tr.track_id, float(t[i0]), "plausibility",
                               f"{tr.category} {name} {np.nanmax(x[i0:i1]):.1f} {unit} > {bound:g} {unit}"
                               f" for {i1 - i0} step{'s' if i1 - i0 != 1 else ''}"))
    return out


def check_plausibility(s: ScenarioRecord) -> list[Finding]:
    """Speed / acceleration / yaw-rate bounds per category (:data:`BOUNDS`), every track."""
    out = []
    for tr in s.tracks:
        out += track_plausibility(tr, s.dt, s.scenario_id)
    return out


def check_route(s: ScenarioRecord, map_rec: MapRecord) -> list[Finding]:
    """The ego's route: long enough, following the lanes (times: the ego's nearest sample)."""
    ego = next((t for t in s.tracks if t.track_id == s.ego_track_id), None)
    out = []
    length = polyline_length(s.route.waypoints)
    if length < MIN_ROUTE_LENGTH_M:
        out.append(Finding(s.scenario_id, s.ego_track_id, 0.0, "route",
                           f"route is {length:.1f} m long; expected >= {MIN_ROUTE_LENGTH_M:g} m"))
        return out
    pts, stretches = _off_lane_stretches(s.route, map_rec)
    s_pts = arc_length(pts)
    for a, b in stretches:
        if b - a <= MAX_OFF_LANE_M:
            continue
        t = 0.0
        if ego is not None and len(ego.xy):
            p = pts[int(np.searchsorted(s_pts, a))]
            t = float(ego.t[int(np.argmin(np.linalg.norm(ego.xy - p, axis=1)))])
        out.append(Finding(s.scenario_id, s.ego_track_id, t, "route",
                           f"route leaves the lanes from {a:.0f} m to {b:.0f} m along it "
                           f"({b - a:.0f} m > {MAX_OFF_LANE_M:g} m)"))
    return out


def check_overlaps(s: ScenarioRecord) -> list[Finding]:
    """Ego box overlapping another agent's box at the same step (one finding per agent: the first time)."""
    ego = next((t for t in s.tracks if t.track_id == s.ego_track_id), None)
    if ego is None:
        return []

    def box(tr: TrackRecord, i: int) -> Polygon:
        c, sn = math.cos(tr.yaw[i]), math.sin(tr.yaw[i])
        hl, hw = tr.size[0] / 2, tr.size[1] / 2
        pts = [(tr.xy[i, 0] + c * x - sn * y, tr.xy[i, 1] + sn * x + c * y)
               for x, y in ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))]
        return Polygon(pts)

    reach_e = math.hypot(ego.size[0], ego.size[1]) / 2
    ego_k = _steps(ego, s.dt)
    out = []
    for tr in s.tracks:
        if tr.track_id == ego.track_id:
            continue
        reach = reach_e + math.hypot(tr.size[0], tr.size[1]) / 2
        k = _steps(tr, s.dt)
        _, jj, ii = np.intersect1d(k, ego_k, return_indices=True)
        near = np.linalg.norm(tr.xy[jj] - ego.xy[ii], axis=1) <= reach  # centres close enough to touch
        for j, i in zip(jj[near].tolist(), ii[near].tolist()):
            if box(ego, i).intersects(box(tr, j)):
                out.append(Finding(s.scenario_id, tr.track_id, float(k[j]) * s.dt, "overlap",
                                   f"{tr.category} box overlaps the ego's logged box"))
                break
    return out


def ego_travel_m(s: ScenarioRecord) -> float:
    """How far the logged ego travels, m: the length of its route's waypoints
    and destination (the logged path decimated to ~2 m, so box jitter of a
    standing ego adds nothing; ``routes.build_route``)."""
    pts = np.vstack([np.asarray(s.route.waypoints, np.float64).reshape(-1, 2),
                     np.asarray(s.route.destination, np.float64).reshape(1, 2)])
    return polyline_length(pts)


def fair_test_problems(s: ScenarioRecord) -> list[str]:
    """Why ``s`` cannot be a fair closed-loop test (empty: it can): an ego that
    travels less than ``MIN_EGO_TRAVEL_M``. One line each; the importers skip
    the scenario with them."""
    travel = ego_travel_m(s)
    if travel < MIN_EGO_TRAVEL_M:
        return [f"the logged ego travels {travel:.1f} m; expected >= {MIN_EGO_TRAVEL_M:g} m "
                "(a shorter route tests no driving)"]
    return []


def curate_scenario(s: ScenarioRecord, map_rec: MapRecord) -> list[Finding]:
    """All checks of one scenario, in a fixed order."""
    return check_completeness(s) + check_plausibility(s) + check_route(s, map_rec) + check_overlaps(s)


def curate_suite(suite: SuiteRecord) -> list[Finding]:
    """All checks of every scenario of a suite."""
    out = []
    for s in suite.scenarios:
        out += curate_scenario(s, suite.maps[s.map_id])
    return out
