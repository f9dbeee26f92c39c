"""One intersection's static layout: ``build_layout(spec) -> Layout`` holds
the ``MapRecord`` plus the generator-side facts the traffic model needs
(legs, movements, dense lane geometry, signal layout).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from drivee2e_jax.records import MapRecord, StopLineRecord

from .lanes import LaneSet, build_lanes
from .legs import Corner, Leg, make_legs
from .markings import build_boundaries
from .movements import Movement, build_movements, turn_angle
from .roadside import build_obstacles, crosswalk_polygon, junction_polygon, leg_polygon
from .signals import SignalLayout, make_signal_layout
from .specs import SPEC_BY_ID, IntersectionSpec


@dataclass
class Layout:
    spec: IntersectionSpec
    legs: list[Leg]
    corners: list[Corner]
    moves: list[Movement]
    lanes: LaneSet
    signals: SignalLayout
    stop_line_of: dict[tuple[int, int], int]  # (leg, entry) -> stop line id
    crosswalk_of: dict[int, int]  # leg -> crosswalk index
    map: MapRecord


def _stop_lines(legs: list[Leg], lanes: LaneSet, sig: SignalLayout) -> tuple[list[StopLineRecord], dict]:
    out, index = [], {}
    for leg in legs:
        for i, e in enumerate(leg.entries):
            pts = np.stack([leg.point(leg.d_stop, e.offset - e.width / 2),
                            leg.point(leg.d_stop, e.offset + e.width / 2)])
            index[(leg.index, i)] = len(out)
            out.append(StopLineRecord(id=len(out), points=pts, lane_id=lanes.entry_near[(leg.index, i)],
                                      signal_group=sig.lane_group[(leg.index, i)]))
    return out, index


def _meta(spec: IntersectionSpec, legs: list[Leg], moves: list[Movement], sig: SignalLayout) -> dict:
    angles = [lg.spec.angle_deg for lg in legs]
    gaps = [((angles[(i + 1) % len(angles)] - a) % 360.0) for i, a in enumerate(angles)]
    # skew: how far the corners between crossing roads are from square
    # (the straight-through side of a T, ~180 deg, is not a corner)
    skew = max([abs(g - 90.0) for g in gaps if g < 150.0] or [0.0])
    return {
        "name": spec.name,
        "legs": len(legs),
        "leg_angles_deg": angles,
        "skew_deg": round(float(skew), 1),
        "lanes_in": [lg.spec.lanes_in for lg in legs],
        "lanes_out": [lg.spec.lanes_out for lg in legs],
        "left_pockets": [lg.spec.left_pocket for lg in legs],
        "right_pockets": [lg.spec.right_pocket for lg in legs],
        "u_turn_legs": [lg.index for lg in legs if lg.spec.u_turn],
        "bike_lanes": any(lg.spec.bike_lane for lg in legs),
        "plan": spec.plan,
        "free_right": spec.free_right,
        "signal_groups": {str(g.id): {"leg": g.leg, "kind": g.kind} for g in sig.groups},
        "signal_plan_semantics": "phase duration includes its yellow and all-red tail; a group green "
                                 "in the next phase stays green",
        "movements": len([m for m in moves if not m.bike]),
        "turn_angles_deg": {f"{m.leg}->{m.to_leg}": round(turn_angle(legs[m.leg], legs[m.to_leg]), 1)
                            for m in moves if not m.bike},
    }


@cache
def build_layout(map_id: str) -> Layout:
    """The layout of intersection ``map_id`` ("I01".."I15"); cached (maps do
    not depend on the seed). Treat the result as read-only."""
    spec = SPEC_BY_ID[map_id]
    legs, corners = make_legs(spec)
    moves = build_movements(legs, corners, spec.corner_radius)
    sig = make_signal_layout(spec, legs, moves)
    lanes = build_lanes(legs, moves)
    stop_lines, stop_index = _stop_lines(legs, lanes, sig)
    crosswalks, cw_index = [], {}
    for leg in legs:
        if leg.spec.crosswalk:
            cw_index[leg.index] = len(crosswalks)
            crosswalks.append(crosswalk_polygon(leg))
    drivable = [junction_polygon(legs, corners)] + [leg_polygon(leg) for leg in legs]
    mrec = MapRecord(
        map_id=spec.map_id, lanes=lanes.records, boundaries=build_boundaries(legs, corners),
        crosswalks=crosswalks, stop_lines=stop_lines, drivable_areas=drivable,
        obstacles=build_obstacles(legs, corners, drivable), signal_plan=sig.plan,
        meta=_meta(spec, legs, moves, sig),
    )
    return Layout(spec, legs, corners, moves, lanes, sig, stop_index, cw_index, mrec)
