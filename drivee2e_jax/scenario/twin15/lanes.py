"""Lane records of one intersection: entry and exit lanes (each split into
a far and a near segment), turn pockets, bike lanes and junction connectors,
chained by successors.

Every lane keeps a dense centreline (0.25 m) for building agent paths; the
``LaneRecord`` centreline is that curve resampled at <= 2 m (straight lanes)
or <= 1 m (pockets, connectors), so paths and map agree to a few cm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from drivee2e_jax.polyline import resample_polyline
from drivee2e_jax.records import LaneRecord

from .legs import BIKE_WIDTH, Leg, taper_weight
from .movements import Movement

#: Dense sampling of lane geometry used for agent paths, m.
DENSE_STEP = 0.25
#: Max points per lane centreline (packing pads every polyline to one size).
MAX_LANE_POINTS = 64


@dataclass
class LaneInfo:
    """Generator-side facts about one lane (same index as its LaneRecord)."""

    role: str  # entry_far | entry_near | pocket | exit_near | exit_far | connector
    leg: int
    index: int  # entry index (entry roles) / exit index (exit roles, -1 bike) / movement index
    dense: np.ndarray  # (n, 2) at DENSE_STEP
    bike: bool = False


@dataclass
class LaneSet:
    records: list[LaneRecord] = field(default_factory=list)
    info: list[LaneInfo] = field(default_factory=list)
    entry_near: dict[tuple[int, int], int] = field(default_factory=dict)  # (leg, entry) -> lane id
    entry_far: dict[tuple[int, int], int] = field(default_factory=dict)  # (leg, entry) -> upstream lane id
    exit_near: dict[tuple[int, int], int] = field(default_factory=dict)  # (leg, exit) -> lane id
    exit_far: dict[tuple[int, int], int] = field(default_factory=dict)
    connector: dict[int, int] = field(default_factory=dict)  # movement index -> lane id

    def add(self, dense: np.ndarray, info: LaneInfo, *, width: float, speed: float, kind: str,
            left: str, right: str, step: float) -> int:
        lid = len(self.records)
        # long curved lanes get coarser (still <= 2 m) so they fit the point budget
        length = float(np.linalg.norm(np.diff(dense, axis=0), axis=1).sum())
        pts = resample_polyline(dense, min(2.0, max(step, length / (MAX_LANE_POINTS - 1.5))))
        if len(pts) > MAX_LANE_POINTS:
            raise ValueError(f"lane {lid} ({info.role}) needs {len(pts)} points > {MAX_LANE_POINTS}")
        self.records.append(LaneRecord(id=lid, centerline=pts, width=float(width), speed_limit=float(speed),
                                       type=kind, successors=[], left_marking=left, right_marking=right))
        info.dense = dense
        self.info.append(info)
        return lid


def _median_marking(leg: Leg) -> str:
    island = -leg.exit_offsets[0] - leg.spec.lane_width / 2 - leg.spec.median / 2 > 0.1
    return "double_solid" if leg.spec.median <= 0.6 and not leg.spec.left_pocket and not island else "solid"


def _straight(leg: Leg, d0: float, d1: float, o: float) -> np.ndarray:
    return resample_polyline(np.stack([leg.point(d0, o), leg.point(d1, o)]), DENSE_STEP)


def _pocket(leg: Leg, o_from: float, o_to: float) -> np.ndarray:
    d = np.arange(leg.d_split, leg.d_stop - 1e-9, -DENSE_STEP / 2)
    d = np.append(d, leg.d_stop)
    o = o_from + (o_to - o_from) * taper_weight(d - leg.d_stop)
    return resample_polyline(leg.point(d, o), DENSE_STEP)


def build_lanes(legs: list[Leg], moves: list[Movement]) -> LaneSet:
    ls = LaneSet()
    for leg in legs:
        sp = leg.spec
        ent = leg.entries
        thr = [i for i, e in enumerate(ent) if e.kind == "through"]
        has_lp = any(e.kind == "left_pocket" for e in ent)
        has_rp = any(e.kind == "right_pocket" for e in ent)
        has_bike = sp.bike_lane
        med = _median_marking(leg)
        # entry through lanes and bike lane: far + near segments
        for i, e in enumerate(ent):
            if e.kind not in ("through", "bike"):
                continue
            bike = e.kind == "bike"
            first = i == thr[0]
            last = i == thr[-1]
            if bike:
                lf = ln = "solid"
                rf = rn = "road_edge"
            else:
                lf = med if first else "dashed"
                ln = "solid" if (not first or has_lp) else med
                kerb = "solid" if has_bike else "road_edge"
                rf = kerb if last else "dashed"
                rn = kerb if (last and not has_rp) else "solid"
            kind = "bike" if bike else "driving"
            speed = 6.0 if bike else sp.speed_limit
            far = ls.add(_straight(leg, leg.d_end, leg.d_split, e.offset),
                         LaneInfo("entry_far", leg.index, i, None, bike),
                         width=e.width, speed=speed, kind=kind, left=lf, right=rf, step=2.0)
            near = ls.add(_straight(leg, leg.d_split, leg.d_stop, e.offset),
                          LaneInfo("entry_near", leg.index, i, None, bike),
                          width=e.width, speed=speed, kind=kind, left=ln, right=rn, step=2.0)
            ls.records[far].successors.append(near)
            ls.entry_far[(leg.index, i)] = far
            ls.entry_near[(leg.index, i)] = near
        # pockets branch off the adjacent through lane's far segment
        for i, e in enumerate(ent):
            if e.kind not in ("left_pocket", "right_pocket"):
                continue
            src = thr[0] if e.kind == "left_pocket" else thr[-1]
            dense = _pocket(leg, ent[src].offset, e.offset)
            left, right = (med, "solid") if e.kind == "left_pocket" else ("solid", "road_edge")
            lid = ls.add(dense, LaneInfo("pocket", leg.index, i, None), width=e.width, speed=sp.speed_limit,
                         kind="turn_pocket", left=left, right=right, step=1.0)
            far = ls.entry_far[(leg.index, src)]
            ls.records[far].successors.append(lid)
            ls.entry_far[(leg.index, i)] = far
            ls.entry_near[(leg.index, i)] = lid
        # exit lanes (and the outbound bike lane, exit index -1)
        outs = list(enumerate(leg.exit_offsets)) + ([(-1, leg.bike_exit_offset)] if has_bike else [])
        n_out = len(leg.exit_offsets)
        for j, o in outs:
            bike = j < 0
            if bike:
                left, right, width, kind, speed = "solid", "road_edge", BIKE_WIDTH, "bike", 6.0
            else:
                left = med if j == 0 else "dashed"
                right = ("solid" if has_bike else "road_edge") if j == n_out - 1 else "dashed"
                width, kind, speed = sp.lane_width, "driving", sp.speed_limit
            near = ls.add(_straight(leg, leg.d_stop, leg.d_split, o), LaneInfo("exit_near", leg.index, j, None, bike),
                          width=width, speed=speed, kind=kind, left=left, right=right, step=2.0)
            far = ls.add(_straight(leg, leg.d_split, leg.d_end, o), LaneInfo("exit_far", leg.index, j, None, bike),
                         width=width, speed=speed, kind=kind, left=left, right=right, step=2.0)
            ls.records[near].successors.append(far)
            ls.exit_near[(leg.index, j)] = near
            ls.exit_far[(leg.index, j)] = far
    # junction connectors
    for k, mv in enumerate(moves):
        a, b = legs[mv.leg], legs[mv.to_leg]
        width = a.entries[mv.entry].width
        speed = 6.0 if mv.bike else min(a.spec.speed_limit, b.spec.speed_limit)
        lid = ls.add(mv.geometry, LaneInfo("connector", mv.leg, k, None, mv.bike), width=width, speed=speed,
                     kind="connector", left="none", right="none", step=1.0)
        ls.records[ls.entry_near[(mv.leg, mv.entry)]].successors.append(lid)
        ls.records[lid].successors.append(ls.exit_near[(mv.to_leg, mv.exit)])
        ls.connector[k] = lid
    return ls
