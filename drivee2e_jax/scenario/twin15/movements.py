"""Turning movements: which entry lane may go to which exit lane, and the
junction connector curve for each such pair.

Movements are classified by the heading change from the entry heading
(``-u_a``) to the exit heading (``u_b``): straight within 40 degrees, left
or right beyond, U-turn back into the same leg. Lane use follows common
practice: pockets serve their own turn, the leftmost through lane turns left
when there is no left pocket (exclusively from three lanes up), the
rightmost turns right (exclusively from four lanes up), the remaining lanes
go straight. Cyclists in bike lanes only go straight.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivee2e_jax.scenario.labels import TURN_MIN_DEG

from .curves import arc, bezier, line_intersection, smooth
from .legs import Corner, Leg, kerb_polyline

STRAIGHT, LEFT, RIGHT, UTURN = "straight", "left", "right", "uturn"


@dataclass
class Movement:
    """One connector: entry lane ``entry`` (index into ``legs[leg].entries``)
    to exit lane ``exit`` (index into ``legs[to_leg].exit_offsets``; -1 =
    the bike lane) of leg ``to_leg``."""

    leg: int
    entry: int
    to_leg: int
    exit: int
    kind: str  # STRAIGHT | LEFT | RIGHT | UTURN
    bike: bool = False
    geometry: np.ndarray | None = None  # (n, 2) dense centreline, stop line to exit lane start


def turn_angle(a: Leg, b: Leg) -> float:
    """Heading change (deg, + = left) entering from leg a and leaving by leg b."""
    d = np.rad2deg(b.theta - (a.theta + np.pi))
    return float((d + 180.0) % 360.0 - 180.0)


def classify(a: Leg, b: Leg) -> str:
    if a.index == b.index:
        return UTURN
    d = turn_angle(a, b)
    if d > TURN_MIN_DEG:
        return LEFT
    if d < -TURN_MIN_DEG:
        return RIGHT
    return STRAIGHT


def _blocks(n: int, k: int) -> list[list[int]]:
    """Split lanes 0..n-1 (left to right) among k targets (left to right);
    targets share a lane when there are fewer lanes than targets."""
    if k == 0:
        return []
    if n >= k:
        edges = np.round(np.linspace(0, n, k + 1)).astype(int)
        return [list(range(edges[i], edges[i + 1])) for i in range(k)]
    return [[min(n - 1, int(i * n / k))] for i in range(k)]


def assign_lanes(legs: list[Leg]) -> list[Movement]:
    """All movements of the intersection (without geometry)."""
    moves: list[Movement] = []
    for a in legs:
        targets = sorted((b for b in legs if b.index != a.index), key=lambda b: -turn_angle(a, b))
        lefts = [b for b in targets if classify(a, b) == LEFT]
        rights = [b for b in targets if classify(a, b) == RIGHT]
        straights = [b for b in targets if classify(a, b) == STRAIGHT]
        ent = a.entries
        thr = [i for i, e in enumerate(ent) if e.kind == "through"]
        lp = [i for i, e in enumerate(ent) if e.kind == "left_pocket"]
        rp = [i for i, e in enumerate(ent) if e.kind == "right_pocket"]
        nt = len(thr)
        serve: dict[int, list[Movement]] = {i: [] for i in range(len(ent))}
        # lanes (entry indices) that carry each turn class
        left_lanes = lp + ([thr[0]] if (not lp or a.spec.dual_left) and lefts else [])
        right_lanes = rp if rp else ([thr[-1]] if rights else [])
        excl_left = (not lp and nt >= 3 and lefts) or a.spec.dual_left
        excl_right = not rp and nt >= 4 and rights
        straight_lanes = [i for i in thr if not ((excl_left and i in left_lanes) or (excl_right and i in right_lanes))]
        if not straights:
            # no straight exit (stem of a T, Y junction): the middle lanes
            # join the nearer turn
            straight_lanes = []
            for i in thr:
                if i not in left_lanes and i not in right_lanes:
                    (left_lanes if thr.index(i) < nt / 2 else right_lanes).append(i)
        # lefts: the leftmost left lanes to the leftmost exit lanes
        for t, b in enumerate(lefts):
            lanes = left_lanes if t == 0 else [left_lanes[-1]]
            for j, i in enumerate(lanes):
                ex = min(j, len(b.exit_offsets) - 1)
                serve[i].append(Movement(a.index, i, b.index, ex, LEFT))
        for t, b in enumerate(rights[::-1]):
            lanes = right_lanes if t == 0 else [right_lanes[0]]
            for j, i in enumerate(lanes[::-1]):
                ex = max(0, len(b.exit_offsets) - 1 - j)
                serve[i].append(Movement(a.index, i, b.index, ex, RIGHT))
        for b, block in zip(straights, _blocks(len(straight_lanes), len(straights))):
            lanes = [straight_lanes[i] for i in block]
            nout = len(b.exit_offsets)
            ts = [ent[i].through_index for i in lanes]
            # keep lane positions across the junction; when there are more
            # lanes than exits the leftmost ones merge
            shift = max(0, max(ts) - (nout - 1))
            for i, t_i in zip(lanes, ts):
                serve[i].append(Movement(a.index, i, b.index, max(0, t_i - shift), STRAIGHT))
        if a.spec.u_turn:
            i = (lp or thr)[0]
            serve[i].append(Movement(a.index, i, a.index, 0, UTURN))
        bike = [i for i, e in enumerate(ent) if e.kind == "bike"]
        if bike and straights:
            b = min(straights, key=lambda b: abs(turn_angle(a, b)))
            if b.bike_exit_offset is not None:
                serve[bike[0]].append(Movement(a.index, bike[0], b.index, -1, STRAIGHT, bike=True))
        for i in sorted(serve):
            moves += serve[i]
    return moves


def connector_geometry(mv: Movement, legs: list[Leg], corner_radius: float, shrink: float = 1.0,
                       step: float = 0.25) -> np.ndarray:
    """Dense centreline of a movement from the stop line to the exit lane start.

    Turns follow the entry lane line, a circular arc tangent to both lane
    lines, then the exit lane line (right turns hug the kerb radius, lefts
    and angled straights take the widest arc that fits between the stop
    lines); near-parallel movements use an S-shaped Bezier. The result is
    smoothed so curvature has no jumps (the straight ends stay exact).
    """
    a, b = legs[mv.leg], legs[mv.to_leg]
    oe = a.entries[mv.entry].offset
    ox = b.bike_exit_offset if mv.exit < 0 else b.exit_offsets[mv.exit]
    if mv.kind == UTURN:
        return _uturn(a, oe, ox, step)
    e0, x0 = a.point(a.d_stop, oe), b.point(b.d_stop, ox)
    h1, h2 = -a.u, b.u
    turn = float(np.arctan2(h1[0] * h2[1] - h1[1] * h2[0], h1 @ h2))  # + = left
    q = line_intersection(e0, h1, x0, h2)
    room = -1.0 if q is None else min((q - e0) @ h1, (x0 - q) @ h2) - 1.0
    if abs(turn) < np.deg2rad(8.0) or room < 3.0 or shrink <= 0.0:
        # near-parallel lane lines (or crossing behind a stop line): an S-curve
        e1, x1 = a.point(a.r, oe), b.point(b.r, ox)
        chord = np.linalg.norm(x1 - e1)
        curve = bezier(e1, e1 + chord / 3 * h1, x1 - chord / 3 * h2, x1, n=400)
        rough = np.concatenate([np.stack([e0]), curve, np.stack([x0])])
        return smooth(rough, 0.8, step)
    half = abs(turn) / 2
    r_fit = room / np.tan(half)
    if mv.kind == RIGHT:
        kerb = min(a.kerb_in(a.d_stop) - oe, b.w_out + ox)
        radius = min(r_fit, corner_radius + kerb)
    elif mv.kind == LEFT:
        radius = min(r_fit, 30.0)
    else:
        radius = min(r_fit, 250.0)
    radius = max(radius * shrink, 4.0)
    dt = radius * np.tan(half)
    t1 = q - dt * h1
    side = np.array([-h1[1], h1[0]]) * np.sign(turn)  # towards the turn centre
    center = t1 + radius * side
    a0 = np.arctan2(*(t1 - center)[::-1])
    pts = arc(center, radius, a0, a0 + turn, step=step)
    rough = np.concatenate([np.stack([e0]), pts, np.stack([x0])])
    return smooth(rough, 1.0, step)


def _uturn(a: Leg, oe: float, ox: float, step: float) -> np.ndarray:
    """A 'light bulb' U-turn: in past the crosswalk, swing out, loop left
    around a circle of >= 6 m radius inside the box, and back out."""
    f, lft = -a.u, -a.n  # forward into the box, left of the entry heading
    origin = a.point(a.d_stop, 0.0)
    le, lx = -oe, -ox  # lateral positions in the (f, lft) frame (ox < 0 -> lx > 0)
    radius = max(6.0, (lx - le) / 2 + 0.5)
    lc = (le + lx) / 2
    fa = a.d_stop - a.r  # the junction box edge
    fc = fa + 0.6 * radius + 1.5
    ang = np.linspace(np.deg2rad(-125), np.deg2rad(125), 60)
    loop = np.stack([fc + radius * np.cos(ang), lc + radius * np.sin(ang)], axis=1)
    local = np.concatenate([[[0.0, le], [fa, le]], loop, [[fa, lx], [0.0, lx]]])
    world = origin + local[:, :1] * f + local[:, 1:] * lft
    return smooth(world, 1.6, step)


def build_movements(legs: list[Leg], corners: list[Corner], corner_radius: float) -> list[Movement]:
    """All movements with their connector geometry.

    Where the preferred curve passes too close to a kerb (a narrow leg's
    corner jutting into a skewed junction), tighter arcs and finally an
    S-curve are tried; the candidate with the most kerb clearance wins.
    """
    kerbs = np.concatenate([kerb_polyline(legs, c) for c in corners])
    reach = max(leg.d_stop for leg in legs) + 10.0
    kerbs = kerbs[np.linalg.norm(kerbs, axis=1) < reach]  # only the junction's kerbs matter
    moves = assign_lanes(legs)
    for mv in moves:
        # a bus (1.28 m half width) still keeps ~0.2 m from the kerb
        need = 0.7 if mv.bike else 1.5
        best, best_clear = None, -1.0
        for shrink in (1.0, 0.6, 0.35, 0.2, 0.0):
            geom = connector_geometry(mv, legs, corner_radius, shrink)
            pts = geom[::2]
            clear = float(np.sqrt(((pts[:, None, :] - kerbs[None, :, :]) ** 2).sum(-1).min()))
            if clear > best_clear:
                best, best_clear = geom, clear
            if clear >= need or mv.kind == UTURN:
                break
        mv.geometry = best
    return moves


__all__ = ["Movement", "build_movements", "assign_lanes", "classify", "turn_angle",
           "STRAIGHT", "LEFT", "RIGHT", "UTURN"]
