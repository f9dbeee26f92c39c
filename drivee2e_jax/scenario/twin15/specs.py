"""The 15 twin intersections, as data.

Each intersection is a list of legs around a centre at the origin. A leg is a
two-way road leaving the junction in direction ``angle_deg`` (CCW from east);
traffic keeps to the right, so the lanes *towards* the junction lie on the
leg's left side when looking outwards (``+n`` = the leg direction rotated by
+90 degrees) and the lanes *away* from it on the right side.

Nothing here is random: the maps are the same for every seed (the seed only
changes the traffic), so a map id names one geometry for good.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class LegSpec:
    """One approach of an intersection.

    Attributes:
      angle_deg:    direction of the leg from the centre, degrees CCW from east.
      lanes_in:     through lanes towards the junction (1..4), pockets excluded.
      lanes_out:    lanes leaving the junction (1..4).
      left_pocket:  an extra left-turn lane opens near the stop line (takes
                    the space of a wide painted median upstream).
      right_pocket: an extra right-turn lane opens near the stop line (the
                    kerb widens by one lane).
      dual_left:    the leftmost through lane also turns left (with a pocket:
                    two left-turn lanes).
      median:       painted median width at the stop line, m.
      lane_width:   m (>= 3.25 so two buses side by side keep 0.6 m apart).
      u_turn:       U-turns are allowed from the leftmost lane.
      bike_lane:    a 1.5 m kerb-side bike lane in both directions.
      crosswalk:    a signalised crosswalk across the leg.
      speed_limit:  m/s.
    """

    angle_deg: float
    lanes_in: int
    lanes_out: int
    left_pocket: bool = False
    right_pocket: bool = False
    dual_left: bool = False
    median: float = 0.6
    lane_width: float = 3.5
    u_turn: bool = False
    bike_lane: bool = False
    crosswalk: bool = True
    speed_limit: float = 13.9


@dataclass(frozen=True)
class IntersectionSpec:
    """One signalised intersection.

    Attributes:
      map_id:        "I01".."I15" (also the intersection id).
      name:          a short description.
      legs:          LegSpec per leg, in increasing angle.
      pairs:         legs served by one signal stage (index tuples into legs).
      plan:          phasing style: "permissive" (lefts yield in the through
                     phase), "protected" (through phase, then a protected
                     left phase), "lead_left" (a short protected left phase,
                     then the lefts continue permissive with the through
                     phase) or "split" (one phase per stage, all movements).
      green_through: green time of a through phase, s.
      green_left:    green time of a protected left phase, s.
      corner_radius: kerb radius at the corners, m.
      free_right:    right-turn pockets are unsignalised (yield to everyone).
      leg_length:    length of each leg beyond its stop line, m.
    """

    map_id: str
    name: str
    legs: tuple[LegSpec, ...]
    pairs: tuple[tuple[int, ...], ...]
    plan: str
    green_through: float = 24.0
    green_left: float = 12.0
    corner_radius: float = 10.0
    free_right: bool = False
    leg_length: float = 88.0


def _l(angle, n_in, n_out, **kw) -> LegSpec:
    return LegSpec(float(angle), n_in, n_out, **kw)


SPECS: tuple[IntersectionSpec, ...] = (
    IntersectionSpec(
        "I01", "orthogonal 2x2 lanes, permissive lefts, bike lanes",
        tuple(_l(a, 2, 2, bike_lane=True) for a in (0, 90, 180, 270)),
        ((0, 2), (1, 3)), "permissive", green_through=26.0),
    IntersectionSpec(
        "I02", "arterial with protected lefts and U-turns",
        (_l(0, 3, 3, left_pocket=True, median=3.0, u_turn=True, speed_limit=16.7),
         _l(90, 2, 2),
         _l(180, 3, 3, left_pocket=True, median=3.0, u_turn=True, speed_limit=16.7),
         _l(270, 2, 2)),
        ((0, 2), (1, 3)), "protected", green_through=28.0, corner_radius=12.0),
    IntersectionSpec(
        "I03", "skewed 75 degrees, leading lefts",
        tuple(_l(a, 2, 2, left_pocket=True, lane_width=3.4) for a in (0, 75, 180, 255)),
        ((0, 2), (1, 3)), "lead_left", green_through=22.0, green_left=8.0, corner_radius=9.0),
    IntersectionSpec(
        "I04", "T junction, stem from the north",
        (_l(0, 2, 2, speed_limit=15.3),
         _l(90, 2, 1, lane_width=3.3),
         _l(180, 2, 2, left_pocket=True, speed_limit=15.3)),
        ((0, 2), (1,)), "lead_left", green_through=26.0, green_left=9.0, corner_radius=10.0),
    IntersectionSpec(
        "I05", "five legs, split phasing",
        (_l(0, 2, 2), _l(70, 2, 2, lane_width=3.3), _l(145, 2, 2),
         _l(215, 1, 1, lane_width=3.6), _l(290, 2, 2)),
        ((0,), (1,), (2,), (3,), (4,)), "split", green_through=13.0, corner_radius=8.0),
    IntersectionSpec(
        "I06", "grand arterial, 4 lanes + pockets, free rights",
        (_l(0, 4, 4, left_pocket=True, right_pocket=True, median=3.0, u_turn=True, speed_limit=16.7),
         _l(90, 3, 3, left_pocket=True, right_pocket=True, median=1.0),
         _l(180, 4, 4, left_pocket=True, right_pocket=True, median=3.0, u_turn=True, speed_limit=16.7),
         _l(270, 3, 3, left_pocket=True, right_pocket=True, median=1.0)),
        ((0, 2), (1, 3)), "protected", green_through=30.0, green_left=14.0, corner_radius=14.0,
        free_right=True, leg_length=96.0),
    IntersectionSpec(
        "I07", "small neighbourhood crossing, one lane each way",
        tuple(_l(a, 1, 1, median=0.3, lane_width=3.6, bike_lane=True, speed_limit=11.1)
              for a in (0, 90, 180, 270)),
        ((0, 2), (1, 3)), "permissive", green_through=20.0, corner_radius=7.0, leg_length=80.0),
    IntersectionSpec(
        "I08", "Y junction, split phasing",
        (_l(0, 2, 2, left_pocket=True), _l(120, 1, 1, lane_width=3.6), _l(235, 2, 2)),
        ((0,), (1,), (2,)), "split", green_through=16.0, corner_radius=9.0),
    IntersectionSpec(
        "I09", "skewed 100 degrees, free right pockets on the main road",
        (_l(0, 3, 3, right_pocket=True, median=1.5, speed_limit=15.3),
         _l(100, 2, 2),
         _l(185, 3, 3, right_pocket=True, median=1.5, speed_limit=15.3),
         _l(280, 2, 2, crosswalk=False)),
        ((0, 2), (1, 3)), "protected", green_through=26.0, green_left=11.0, corner_radius=11.0,
        free_right=True),
    IntersectionSpec(
        "I10", "asymmetric lane counts, leading lefts, bike lanes",
        (_l(0, 3, 2, left_pocket=True, bike_lane=True),
         _l(90, 2, 2, bike_lane=True),
         _l(180, 2, 3, left_pocket=True, bike_lane=True),
         _l(270, 2, 2, bike_lane=True)),
        ((0, 2), (1, 3)), "lead_left", green_through=24.0, green_left=9.0, corner_radius=10.0),
    IntersectionSpec(
        "I11", "five-leg arterial node",
        (_l(0, 3, 3, median=1.5), _l(60, 1, 1, lane_width=3.6), _l(150, 2, 2),
         _l(200, 2, 2), _l(290, 2, 2, left_pocket=True)),
        ((0,), (1,), (2,), (3,), (4,)), "split", green_through=12.0, corner_radius=8.0),
    IntersectionSpec(
        "I12", "skewed T with U-turns on the main road",
        (_l(0, 3, 3, median=3.0, u_turn=True),
         _l(100, 2, 2),
         _l(190, 3, 3, left_pocket=True, median=3.0, u_turn=True)),
        ((0, 2), (1,)), "protected", green_through=25.0, green_left=10.0, corner_radius=10.0),
    IntersectionSpec(
        "I13", "dual left turns on the main road",
        (_l(0, 3, 3, left_pocket=True, dual_left=True, median=2.0, speed_limit=15.3),
         _l(90, 2, 2, left_pocket=True),
         _l(180, 3, 3, left_pocket=True, dual_left=True, median=2.0, speed_limit=15.3),
         _l(270, 2, 2, left_pocket=True)),
        ((0, 2), (1, 3)), "protected", green_through=26.0, green_left=13.0, corner_radius=12.0),
    IntersectionSpec(
        "I14", "skewed three-lane crossing with bike lanes",
        tuple(_l(a, 3, 3, lane_width=3.3, bike_lane=True) for a in (10, 95, 170, 265)),
        ((0, 2), (1, 3)), "permissive", green_through=25.0, corner_radius=10.0),
    IntersectionSpec(
        "I15", "wide boulevard meets a lane, free rights and U-turns",
        (_l(0, 4, 4, right_pocket=True, median=3.0, u_turn=True, speed_limit=16.7),
         _l(90, 1, 1, lane_width=3.6),
         _l(180, 4, 4, right_pocket=True, median=3.0, u_turn=True, speed_limit=16.7),
         _l(270, 1, 1, lane_width=3.6)),
        ((0, 2), (1, 3)), "protected", green_through=30.0, green_left=12.0, corner_radius=12.0,
        free_right=True, leg_length=96.0),
)

SPEC_BY_ID: dict[str, IntersectionSpec] = {s.map_id: s for s in SPECS}
