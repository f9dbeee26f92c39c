"""Leg frames and the junction box: where each leg's lanes, crosswalk and
stop line lie, and the kerb corners between neighbouring legs.

A leg is described in its own frame: ``d`` = distance from the centre along
the leg direction ``u``, ``o`` = lateral offset along ``n = rot90(u)``. Lanes
towards the junction ("entry") have ``o > 0``, lanes away from it ("exit")
``o < 0``. Along the leg, outwards from the centre::

    0 .. r        junction box (kerb corners are rounded inside it)
    r+1 .. r+1+cw crosswalk
    d_stop        stop line = end of entry lanes = start of exit lanes
    d_split       entry / exit lanes split in two chained lanes here; turn
                  pockets open here (taper), lane lines turn solid nearer
    d_end         map edge
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .curves import arc, line_intersection, rot90, unit
from .specs import IntersectionSpec, LegSpec

#: Crosswalk width, m.
CROSSWALK_WIDTH = 4.5
#: Gap between the junction box edge and the crosswalk, m.
CROSSWALK_SETBACK = 1.0
#: Gap between the crosswalk and the stop line, m.
STOP_SETBACK = 1.5
#: Length of the near (approach) lane segment and of the turn pockets, m.
POCKET_LENGTH = 50.0
#: Taper length over which a pocket moves one lane sideways, m.
TAPER_LENGTH = 25.0
#: Bike lane width, m.
BIKE_WIDTH = 1.5
#: Sidewalk width between the kerb and the building line, m.
SIDEWALK = 6.0


@dataclass
class EntryLane:
    """One lane towards the junction at the stop line (left to right)."""

    kind: str  # "left_pocket" | "through" | "right_pocket" | "bike"
    offset: float  # lateral offset o at the stop line, m
    width: float
    through_index: int  # index among the through lanes (-1 for pockets/bike)


@dataclass
class Leg:
    """Geometry of one leg (see module docstring for the distances)."""

    index: int
    spec: LegSpec
    theta: float  # rad
    u: np.ndarray  # (2,) outward unit vector
    n: np.ndarray  # (2,) rot90(u)
    entries: list[EntryLane]  # near-junction entry lanes, left (median) to right (kerb)
    exit_offsets: list[float]  # exit lane offsets (negative), median side first
    bike_exit_offset: float | None
    w_in: float  # kerb offset of the entry side at the stop line, m
    w_in_up: float  # kerb offset of the entry side upstream of a right pocket, m
    w_out: float  # kerb offset (positive number) of the exit side, m
    r: float = 0.0
    d_stop: float = 0.0
    d_split: float = 0.0
    d_end: float = 0.0

    def point(self, d, o) -> np.ndarray:
        """World point(s) at distance ``d`` along the leg and lateral offset ``o``."""
        d = np.asarray(d, float)[..., None]
        o = np.asarray(o, float)[..., None]
        return d * self.u + o * self.n

    def kerb_in(self, d) -> np.ndarray:
        """Entry-side kerb offset at distance ``d`` (tapers back upstream of a right pocket)."""
        d = np.asarray(d, float)
        return self.w_in_up + (self.w_in - self.w_in_up) * taper_weight(d - self.d_stop)

    @property
    def through_offsets(self) -> list[float]:
        return [e.offset for e in self.entries if e.kind == "through"]

    @property
    def crosswalk_span(self) -> tuple[float, float]:
        return self.r + CROSSWALK_SETBACK, self.r + CROSSWALK_SETBACK + CROSSWALK_WIDTH


def taper_weight(x) -> np.ndarray:
    """1 near the stop line, 0 upstream of the pocket, a cosine taper between.

    ``x`` is the distance upstream of the stop line, m.
    """
    x = np.asarray(x, float)
    a = POCKET_LENGTH - TAPER_LENGTH
    t = np.clip((x - a) / TAPER_LENGTH, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


def make_leg(i: int, spec: LegSpec, island: bool) -> Leg:
    w, m = spec.lane_width, spec.median
    if spec.right_pocket and spec.bike_lane:
        raise ValueError("a leg cannot have both a right pocket and a bike lane")
    entries: list[EntryLane] = []
    kinds = (["left_pocket"] if spec.left_pocket else []) + ["through"] * spec.lanes_in
    kinds += ["right_pocket"] if spec.right_pocket else []
    t = 0
    for j, kind in enumerate(kinds):
        entries.append(EntryLane(kind, m / 2 + w * (j + 0.5), w, t if kind == "through" else -1))
        t += kind == "through"
    w_in = m / 2 + w * len(kinds)
    if spec.bike_lane:
        entries.append(EntryLane("bike", w_in + BIKE_WIDTH / 2, BIKE_WIDTH, -1))
        w_in += BIKE_WIDTH
    lp = 1 if island else 0  # exit side painted island (see make_legs)
    w_out = m / 2 + w * (lp + spec.lanes_out) + (BIKE_WIDTH if spec.bike_lane else 0.0)
    theta = np.deg2rad(spec.angle_deg)
    u = unit(theta)
    return Leg(
        index=i, spec=spec, theta=theta, u=u, n=rot90(u), entries=entries,
        exit_offsets=[-(m / 2 + w * (lp + j + 0.5)) for j in range(spec.lanes_out)],
        bike_exit_offset=-(w_out - BIKE_WIDTH / 2) if spec.bike_lane else None,
        w_in=w_in, w_in_up=w_in - (w if spec.right_pocket else 0.0), w_out=w_out,
    )


@dataclass
class Corner:
    """The kerb between leg ``a``'s entry side and the next leg ``b``'s exit side.

    ``arc`` is the rounded kerb (None when the legs are nearly opposite and
    the kerb runs straight from one mouth to the next).
    """

    a: int
    b: int
    phi: float  # angle from leg a to leg b, rad
    t_a: float  # distance along leg a where the kerb arc starts, m
    t_b: float  # distance along leg b where it ends, m
    arc: np.ndarray | None
    apex: np.ndarray | None  # kerb corner point (the lines' intersection)


def make_corner(la: Leg, lb: Leg, radius: float) -> Corner:
    phi = (lb.theta - la.theta) % (2 * np.pi)
    if phi >= np.deg2rad(165.0):
        return Corner(la.index, lb.index, phi, 0.0, 0.0, None, None)
    pa = la.w_in * la.n
    pb = -lb.w_out * lb.n
    x = line_intersection(pa, la.u, pb, lb.u)
    dt = radius / np.tan(phi / 2)
    ta_pt = x + dt * la.u
    tb_pt = x + dt * lb.u
    bis = la.u + lb.u
    bis /= np.linalg.norm(bis)
    z = x + radius / np.sin(phi / 2) * bis
    a0 = np.arctan2(*(ta_pt - z)[::-1])
    a1 = np.arctan2(*(tb_pt - z)[::-1])
    # the kerb arc turns by (pi - phi); pick that way round
    da = (a1 - a0 + np.pi) % (2 * np.pi) - np.pi
    pts = arc(z, radius, a0, a0 + da, step=1.0)
    return Corner(la.index, lb.index, phi, float(ta_pt @ la.u), float(tb_pt @ lb.u), pts, x)


def make_legs(spec: IntersectionSpec) -> tuple[list[Leg], list[Corner]]:
    """Legs with their junction-box distances set, and the corners between them."""
    angles = [lg.angle_deg for lg in spec.legs]
    if angles != sorted(angles):
        raise ValueError(f"{spec.map_id}: legs must be listed in increasing angle")
    # a leg's exit lanes line up with the through lanes flowing into it:
    # shifted out by a lane where the straight-ahead approach has a left
    # pocket (the painted island opposite the pocket)
    lp_in = []
    for s in spec.legs:
        src = [o for o in spec.legs if o is not s and abs(((s.angle_deg - o.angle_deg) % 360.0) - 180.0) < 40.0]
        lp_in.append(any(o.left_pocket for o in src))
    legs = [make_leg(i, s, lp_in[i]) for i, s in enumerate(spec.legs)]
    k = len(legs)
    corners = [make_corner(legs[i], legs[(i + 1) % k], spec.corner_radius) for i in range(k)]
    for i, leg in enumerate(legs):
        need = [corners[i].t_a, corners[i - 1].t_b, 6.0]
        # a wide neighbour at a sharp angle reaches far along this leg; keep
        # the mouth clear of its kerb line too
        for c in (corners[i], corners[i - 1]):
            if c.apex is not None:
                need.append(float(c.apex @ leg.u))
        leg.r = float(max(need)) + 0.5
        leg.d_stop = leg.r + CROSSWALK_SETBACK + CROSSWALK_WIDTH + STOP_SETBACK
        leg.d_split = leg.d_stop + POCKET_LENGTH
        leg.d_end = leg.d_stop + spec.leg_length
    return legs, corners


def leg_line(leg: Leg, d0: float, d1: float, o) -> np.ndarray:
    """Points along leg from distance d0 to d1 at offset o (a number or o(d))."""
    d = np.linspace(d0, d1, max(2, int(abs(d1 - d0) / 0.5) + 1))
    o = o(d) if callable(o) else np.full_like(d, o)
    return leg.point(d, o)


def kerb_polyline(legs: list[Leg], c: Corner) -> np.ndarray:
    """The whole kerb of a corner, from leg a's far end round to leg b's."""
    a, b = legs[c.a], legs[c.b]
    if c.arc is None:
        pa = leg_line(a, a.d_end, a.r, a.kerb_in)
        pb = leg_line(b, b.r, b.d_end, -b.w_out)
        return np.concatenate([pa, pb])
    pa = leg_line(a, a.d_end, c.t_a, a.kerb_in)
    pb = leg_line(b, c.t_b, b.d_end, -b.w_out)
    return np.concatenate([pa[:-1], c.arc, pb[1:]])
