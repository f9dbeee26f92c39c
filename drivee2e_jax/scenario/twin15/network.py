"""Agent paths and their conflict zones, as padded numpy tables for the
traffic model.

A *path* is what one agent follows from spawn to despawn:

* vehicle / bike path: entry lane (far, near) -> junction connector -> exit
  lane (near, far), the lanes' dense centrelines joined and resampled every
  ``STEP`` m;
* crosswalk track: a straight line across a crosswalk from 3 m behind one
  kerb to 3 m behind the other, 2 tracks per walking direction, each keeping
  to its right.

Arc positions ``s`` are measured from the path start. Each path has a
*stop point* (vehicles: the stop line; tracks: the kerb) and a *junction
part* (stop point .. end of the connector / far kerb) where it may meet
other paths.

A *conflict zone* is a pair of intervals ``[a_p, b_p]`` on path p and
``[a_q, b_q]`` on path q within which two agents' boxes could come closer
than a margin (centreline distance below both half widths, the outward
swing of a long body on a curve, and the margin). Agents claim all zones of
their path when they commit to enter the junction and release each one
once their rear has passed it; nobody may commit while an opposite side of
one of their zones is claimed. Paths starting from the same lane are not
zoned: they follow each other (see ``siblings``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivee2e_jax.polyline import arc_length, resample_polyline

from .curves import curvature
from .layout import Layout
from .legs import CROSSWALK_WIDTH
from .movements import LEFT, RIGHT, STRAIGHT, UTURN

#: Path sampling, m (positions are interpolated between samples).
STEP = 0.5
VEHICLE, BIKE, TRACK = 0, 1, 2
#: Design bodies per path kind (length, width), m: the largest agents allowed.
#: Two vehicle classes get their own zone tables: "light" bodies up to
#: 5.6 x 2.1 m and "heavy" ones (buses, trucks) up to 12 x 2.55 m. Heavy
#: vehicles never make U-turns.
LIGHT = (5.6, 2.1)
HEAVY = (12.0, 2.55)
HEAVY_LENGTH = 5.6  # m: longer bodies count as heavy
VRU_DESIGN = (1.9, 0.7)
#: Clearance kept between zoned bodies, m.
MARGIN_VEHICLE = 0.6
MARGIN_VRU = 0.6
MARGIN_VRU_VRU = 0.1
#: Crosswalk track lateral positions from the crosswalk centre line, m.
TRACK_OFFSETS = (0.55, 1.5)
#: How far tracks reach onto the sidewalk behind each kerb, m.
SIDEWALK_REACH = 3.0
#: Limits shaping a path's speed profile.
A_LAT = 2.2  # m/s^2 lateral acceleration
YAW_RATE = 0.8  # rad/s
B_PROFILE = 1.3  # m/s^2 braking ahead of curves
#: Priority ranks: the lower rank yields.
RANK = {"vru": 5.0, STRAIGHT: 3.0, RIGHT: 2.0, LEFT: 1.0, UTURN: 0.0, "free_right": 0.5}


@dataclass
class Path:
    kind: int
    xy: np.ndarray  # (M, 2) exactly STEP apart, a few samples past the end
    length: float
    lanes: list[int]  # segment ids along the path (lane ids; tracks get their own ids)
    seg_start: list[float]  # arc position where each segment starts
    stop_s: float
    j0: float  # junction part
    j1: float
    group: int  # signal group (-1 = none: free right)
    movement: str | None
    rank: float
    leg: int
    to_leg: int
    entry: int  # entry lane index on its leg (-1 for tracks)
    move_index: int  # movement index (-1 for tracks)
    crosswalk: int = -1  # leg whose crosswalk a track crosses
    direction: int = 0  # tracks: +1 towards the entry side, -1 back
    outer: bool = False  # tracks: the outer (cyclist-capable) track


def uniform(xy: np.ndarray, extra: int = 4) -> np.ndarray:
    """Samples exactly STEP apart from the start (so ``s / STEP`` indexes
    them), continuing ``extra`` samples straight past the end."""
    s = arc_length(xy)
    q = np.arange(0.0, s[-1] + (extra + 0.5) * STEP, STEP)
    pts = np.stack([np.interp(q, s, xy[:, 0]), np.interp(q, s, xy[:, 1])], axis=1)
    beyond = q > s[-1]
    d = (xy[-1] - xy[-2]) / np.linalg.norm(xy[-1] - xy[-2])
    pts[beyond] = xy[-1] + (q[beyond] - s[-1])[:, None] * d
    return pts


def _join(parts: list[np.ndarray]) -> tuple[np.ndarray, list[float]]:
    starts, pts, acc = [], [], 0.0
    for i, p in enumerate(parts):
        starts.append(acc)
        acc += float(arc_length(p)[-1])
        pts.append(p if i == 0 else p[1:])
    return np.concatenate(pts), starts


def vehicle_paths(lay: Layout) -> list[Path]:
    ls, out = lay.lanes, []
    for k, mv in enumerate(lay.moves):
        chain = [ls.entry_far[(mv.leg, mv.entry)], ls.entry_near[(mv.leg, mv.entry)], ls.connector[k],
                 ls.exit_near[(mv.to_leg, mv.exit)], ls.exit_far[(mv.to_leg, mv.exit)]]
        xy, starts = _join([ls.info[c].dense for c in chain])
        grp = lay.signals.lane_group[(mv.leg, mv.entry)]
        if mv.bike:
            rank = RANK["vru"]
        elif grp < 0:
            rank = RANK["free_right"]
        else:
            rank = RANK[mv.kind]
        length = starts[-1] + float(arc_length(ls.info[chain[-1]].dense)[-1])
        out.append(Path(BIKE if mv.bike else VEHICLE, uniform(xy), length, chain, starts, starts[2], starts[2],
                        starts[3], grp, mv.kind, rank, mv.leg, mv.to_leg, mv.entry, k))
    return out


def crosswalk_tracks(lay: Layout, first_segment_id: int) -> list[Path]:
    out = []
    for leg in lay.legs:
        if leg.index not in lay.crosswalk_of:
            continue
        d0, _ = leg.crosswalk_span
        dc = d0 + CROSSWALK_WIDTH / 2
        grp = lay.signals.ped_group(leg.index)
        for direction in (+1, -1):
            for j, off in enumerate(TRACK_OFFSETS):
                d = dc + direction * off  # keep right: towards +n walks on the outer side
                o0, o1 = -leg.w_out - SIDEWALK_REACH, leg.w_in + SIDEWALK_REACH
                if direction < 0:
                    o0, o1 = o1, o0
                ends = np.stack([leg.point(d, o0), leg.point(d, o1)])
                total = float(np.linalg.norm(ends[1] - ends[0]))
                xy = uniform(resample_polyline(ends, STEP))
                kerb = SIDEWALK_REACH
                out.append(Path(TRACK, xy, total, [first_segment_id + len(out)], [0.0], kerb, kerb, total - kerb, grp,
                                None, RANK["vru"], leg.index, leg.index, -1, -1, crosswalk=leg.index,
                                direction=direction, outer=j == 1))
    return out


def speed_profile(xy: np.ndarray) -> np.ndarray:
    """(M,) max speed along a path (m/s) from its curvature (lateral
    acceleration and yaw-rate limits), lowered ahead of curves so that
    braking at B_PROFILE reaches each limit in time."""
    k = np.abs(curvature(xy))
    k = np.maximum.reduce([k, np.roll(k, 1), np.roll(k, -1)])
    v = np.minimum(np.sqrt(A_LAT / np.maximum(k, 1e-6)), YAW_RATE / np.maximum(k, 1e-6))
    v = np.minimum(v, 30.0)
    # v_i <= min_j>=i sqrt(v_j^2 + 2 b (s_j - s_i)): a reversed running minimum
    s = np.arange(len(v)) * STEP
    e = v ** 2 + 2 * B_PROFILE * s
    e = np.minimum.accumulate(e[::-1])[::-1]
    return np.sqrt(np.maximum(e - 2 * B_PROFILE * s, 0.0))


def _design(p: Path, heavy: bool) -> tuple[float, float]:
    if p.kind == VEHICLE:
        return HEAVY if heavy and p.movement != UTURN else LIGHT
    return VRU_DESIGN


@dataclass
class Zone:
    p: int
    q: int
    a_p: float
    b_p: float
    a_q: float
    b_q: float


def conflict_zones(paths: list[Path], heavy: bool) -> list[Zone]:
    """Zones between pairs of paths, sized for light (or heavy) vehicles on both."""
    parts = []
    for p in paths:
        i0, i1 = int(np.floor(p.j0 / STEP)), int(np.ceil(p.j1 / STEP)) + 1
        pts = p.xy[i0:i1]
        s = np.arange(i0, i0 + len(pts)) * STEP
        length, width = _design(p, heavy)
        # a body's ends swing out by (L/2)^2 k / 2 on a curve; a point of the
        # path is swept by bodies centred up to L/2 away, so take the
        # largest curvature within that reach
        k = np.abs(curvature(p.xy))
        w = int(np.ceil(length / 2 / STEP))
        k = np.lib.stride_tricks.sliding_window_view(np.pad(k, w, mode="edge"), 2 * w + 1).max(1)
        swing = (length / 2) ** 2 * k[i0:i0 + len(pts)] / 2
        reach = width / 2 + swing
        parts.append((pts[:, 0], pts[:, 1], s, reach, pts.min(0) - reach.max(), pts.max(0) + reach.max()))
    out = []
    for i, p in enumerate(paths):
        xp, yp, sp, hp, lo_p, hi_p = parts[i]
        for j in range(i + 1, len(paths)):
            q = paths[j]
            xq, yq, sq, hq, lo_q, hi_q = parts[j]
            sep = 0.0
            if p.kind != TRACK and q.kind != TRACK and (p.leg, p.entry) == (q.leg, q.entry):
                # same entry lane: they follow each other until they part
                # (siblings); only a later re-convergence (a U-turn loop
                # crossing a left turn) needs a zone
                n = min(len(xp), len(xq))
                apart = np.hypot(xp[:n] - xq[:n], yp[:n] - yq[:n]) > 3.1
                if not apart.any():
                    continue
                sep = (np.argmax(apart) + 4) * STEP
            vru_p, vru_q = p.kind != VEHICLE, q.kind != VEHICLE
            margin = MARGIN_VRU_VRU if (vru_p and vru_q) else MARGIN_VRU if (vru_p or vru_q) else MARGIN_VEHICLE
            if np.any(lo_p - margin > hi_q) or np.any(lo_q - margin > hi_p):
                continue
            dx = xp[:, None] - xq[None, :]
            dy = yp[:, None] - yq[None, :]
            lim = hp[:, None] + hq[None, :] + margin
            hit = dx * dx + dy * dy < lim * lim
            if sep > 0.0:
                hit &= ((sp - sp[0]) > sep)[:, None] & ((sq - sq[0]) > sep)[None, :]
            if not hit.any():
                continue
            rows = hit.any(1)
            cols = hit.any(0)
            out.append(Zone(i, j, float(sp[rows].min()), float(sp[rows].max()),
                            float(sq[cols].min()), float(sq[cols].max())))
    return out


def siblings(lay: Layout, threshold: float = 3.1) -> dict[int, list[tuple[int, float]]]:
    """Lanes branching from one lane: for each, its siblings and the length
    over which the two stay closer than ``threshold`` (agents there still
    follow each other across the branches)."""
    by_parent: dict[int, list[int]] = {}
    for rec in lay.map.lanes:
        if len(rec.successors) > 1:
            by_parent[rec.id] = list(rec.successors)
    out: dict[int, list[tuple[int, float]]] = {}
    for kids in by_parent.values():
        for a in kids:
            for b in kids:
                if a == b:
                    continue
                pa, pb = lay.lanes.info[a].dense, lay.lanes.info[b].dense
                sa, sb = arc_length(pa), arc_length(pb)
                q = np.arange(0.0, min(sa[-1], sb[-1]), 0.25)
                xa = np.stack([np.interp(q, sa, pa[:, 0]), np.interp(q, sa, pa[:, 1])], 1)
                xb = np.stack([np.interp(q, sb, pb[:, 0]), np.interp(q, sb, pb[:, 1])], 1)
                far = np.linalg.norm(xa - xb, axis=1) >= threshold
                length = float(q[np.argmax(far)]) if far.any() else float(q[-1])
                out.setdefault(a, []).append((b, length))
    return out


@dataclass
class Network:
    """One intersection's paths and zones (lists; see ``tables`` for arrays)."""

    layout: Layout
    paths: list[Path]
    zones: list[Zone]  # sized for light vehicles
    zones_heavy: list[Zone]  # sized for heavy vehicles (a superset)
    siblings: dict[int, list[tuple[int, float]]]
    num_segments: int  # lanes + tracks


def build_network(lay: Layout) -> Network:
    paths = vehicle_paths(lay)
    paths += crosswalk_tracks(lay, len(lay.map.lanes))
    segments = len(lay.map.lanes) + sum(p.kind == TRACK for p in paths)
    return Network(lay, paths, conflict_zones(paths, False), conflict_zones(paths, True), siblings(lay), segments)


__all__ = ["Network", "Path", "Zone", "build_network", "speed_profile", "VEHICLE", "BIKE", "TRACK", "STEP"]
