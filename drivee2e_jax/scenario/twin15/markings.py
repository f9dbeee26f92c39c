"""Lane boundary polylines with their marking types.

* ``road_edge``: the kerbs, one polyline per corner (leg a's entry-side kerb,
  the rounded corner, leg b's exit-side kerb);
* ``double_solid`` / ``solid``: between opposite directions (a narrow
  median is a double line, a wide painted median has a solid edge on each
  side); lane lines on the approach (the last 30 m before a stop line) and
  around pockets and bike lanes;
* ``dashed``: between same-direction lanes elsewhere.

Points are <= 2 m apart and no polyline has more than 64 points (longer
ones are split into chained pieces).
"""

from __future__ import annotations

import numpy as np

from drivee2e_jax.polyline import resample_polyline
from drivee2e_jax.records import BoundaryRecord

from .curves import chunk
from .lanes import MAX_LANE_POINTS
from .legs import BIKE_WIDTH, POCKET_LENGTH, TAPER_LENGTH, Corner, Leg, kerb_polyline, taper_weight
from .legs import leg_line as _leg_line

#: Length of the solid approach lines before a stop line, m.
SOLID_APPROACH = 30.0
STEP = 2.0


def _add(out: list[BoundaryRecord], pts: np.ndarray, marking: str) -> None:
    for piece in chunk(resample_polyline(pts, STEP), MAX_LANE_POINTS):
        out.append(BoundaryRecord(points=piece, marking=marking))


def build_boundaries(legs: list[Leg], corners: list[Corner]) -> list[BoundaryRecord]:
    out: list[BoundaryRecord] = []
    for c in corners:
        _add(out, kerb_polyline(legs, c), "road_edge")
    for leg in legs:
        sp = leg.spec
        w, m = sp.lane_width, sp.median
        ent = leg.entries
        has_lp = any(e.kind == "left_pocket" for e in ent)
        # between the directions
        island = -leg.exit_offsets[0] - w / 2 - m / 2 > 0.1
        if m <= 0.6 and not has_lp and not island:
            _add(out, _leg_line(leg, leg.d_stop, leg.d_end, 0.0), "double_solid")
        else:
            _add(out, _leg_line(leg, leg.d_stop, leg.d_end, leg.exit_offsets[0] + w / 2), "solid")
            edge = (lambda d, m=m, w=w, leg=leg: m / 2 + w * (1 - taper_weight(d - leg.d_stop))) if has_lp else m / 2
            _add(out, _leg_line(leg, leg.d_stop, leg.d_end, edge), "solid")
        # between entry lanes
        pocket_end = leg.d_stop + POCKET_LENGTH - TAPER_LENGTH / 2
        for i in range(len(ent) - 1):
            e0, e1 = ent[i], ent[i + 1]
            o = e0.offset + e0.width / 2
            if e1.kind == "bike":
                _add(out, _leg_line(leg, leg.d_stop, leg.d_end, o), "solid")
            elif "pocket" in e0.kind or "pocket" in e1.kind:
                _add(out, _leg_line(leg, leg.d_stop, pocket_end, o), "solid")
            else:
                _add(out, _leg_line(leg, leg.d_stop, leg.d_stop + SOLID_APPROACH, o), "solid")
                _add(out, _leg_line(leg, leg.d_stop + SOLID_APPROACH, leg.d_end, o), "dashed")
        # between exit lanes
        offs = leg.exit_offsets
        for j in range(len(offs) - 1):
            _add(out, _leg_line(leg, leg.d_stop, leg.d_end, offs[j] - w / 2), "dashed")
        if sp.bike_lane:
            _add(out, _leg_line(leg, leg.d_stop, leg.d_end, -(leg.w_out - BIKE_WIDTH)), "solid")
    return out
