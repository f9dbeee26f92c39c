"""Signal groups, fixed-time phase plans and their state over time.

Groups (ids are small ints, unique per map):

* ``through`` per leg: the through and shared lanes (and the bike lane);
* ``left`` per leg, only where a leg has a left-only lane and the plan gives
  lefts their own (protected) time;
* ``ped`` per crosswalk.

Free-right pockets have no signal (stop line group -1: a yield line).

Plan semantics (``records.SignalPhase``): a phase lasts ``duration`` seconds
*including* its ``yellow_duration`` and ``all_red`` tail. A group green in a
phase turns yellow, then red, in that tail, unless it is also green in the
next phase, in which case it simply stays green. Pedestrian groups are green
(walk) in every phase in which no movement enters from their leg and no
straight movement leaves into it; turning traffic yields to them. Their
yellow is the flashing "don't start" clearance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivee2e_jax.records import SignalPhase

from .legs import Leg
from .movements import LEFT, STRAIGHT, UTURN, Movement
from .specs import IntersectionSpec

RED, YELLOW, GREEN = 1, 2, 3
YELLOW_S = 3.0
ALL_RED_S = 2.0


@dataclass
class Group:
    id: int
    leg: int
    kind: str  # "through" | "left" | "ped"


@dataclass
class SignalLayout:
    """Groups of one map, the group of every entry lane and the phase plan."""

    groups: list[Group]
    lane_group: dict[tuple[int, int], int]  # (leg, entry index) -> group id (-1 = none)
    plan: list[SignalPhase]

    def ped_group(self, leg: int) -> int:
        return next(g.id for g in self.groups if g.leg == leg and g.kind == "ped")


def make_signal_layout(spec: IntersectionSpec, legs: list[Leg], moves: list[Movement]) -> SignalLayout:
    by_lane: dict[tuple[int, int], list[Movement]] = {}
    for mv in moves:
        by_lane.setdefault((mv.leg, mv.entry), []).append(mv)
    groups: list[Group] = []

    def new(leg: int, kind: str) -> int:
        groups.append(Group(len(groups), leg, kind))
        return groups[-1].id

    own_left = spec.plan in ("protected", "lead_left")
    lane_group: dict[tuple[int, int], int] = {}
    for leg in legs:
        g_t = new(leg.index, "through")
        g_l = None
        for i, e in enumerate(leg.entries):
            kinds = {mv.kind for mv in by_lane.get((leg.index, i), [])}
            if e.kind == "right_pocket" and spec.free_right:
                lane_group[(leg.index, i)] = -1
            elif own_left and kinds and kinds <= {LEFT, UTURN}:
                g_l = new(leg.index, "left") if g_l is None else g_l
                lane_group[(leg.index, i)] = g_l
            else:
                lane_group[(leg.index, i)] = g_t
    for leg in legs:
        if leg.spec.crosswalk:
            new(leg.index, "ped")
    layout = SignalLayout(groups, lane_group, [])
    layout.plan = _plan(spec, legs, moves, layout)
    return layout


def _plan(spec: IntersectionSpec, legs: list[Leg], moves: list[Movement], sl: SignalLayout) -> list[SignalPhase]:
    def of(leg_ids, kind):
        return [g.id for g in sl.groups if g.leg in leg_ids and g.kind == kind]

    stages: list[tuple[list[int], float]] = []  # (vehicle groups green, green seconds)
    for pair in spec.pairs:
        t, lf = of(pair, "through"), of(pair, "left")
        if spec.plan == "permissive" or spec.plan == "split":
            stages.append((t + lf, spec.green_through))
        elif spec.plan == "protected":
            stages.append((t, spec.green_through))
            if lf:
                stages.append((lf, spec.green_left))
        elif spec.plan == "lead_left":
            if lf:
                stages.append((lf, spec.green_left))
            stages.append((t + lf, spec.green_through))
        else:
            raise ValueError(f"{spec.map_id}: unknown plan {spec.plan!r}")
    phases = []
    for green, g_s in stages:
        phases.append(SignalPhase(duration=g_s + YELLOW_S + ALL_RED_S,
                                  green=sorted(green + _walking(green, legs, moves, sl)),
                                  yellow_duration=YELLOW_S, all_red=ALL_RED_S))
    peds = [g.id for g in sl.groups if g.kind == "ped"]
    if any(all(p not in ph.green for ph in phases) for p in peds):
        # some crosswalk never gets a conflict-free phase: an exclusive
        # pedestrian phase ("scramble") for all of them
        phases.append(SignalPhase(duration=14.0 + YELLOW_S + ALL_RED_S, green=peds,
                                  yellow_duration=YELLOW_S, all_red=ALL_RED_S))
    return phases


def _walking(green: list[int], legs: list[Leg], moves: list[Movement], sl: SignalLayout) -> list[int]:
    active = [mv for mv in moves if sl.lane_group[(mv.leg, mv.entry)] in green]
    out = []
    for g in sl.groups:
        if g.kind != "ped":
            continue
        enters = any(mv.leg == g.leg for mv in active)
        straight_in = any(mv.to_leg == g.leg and mv.kind == STRAIGHT for mv in active)
        if not enters and not straight_in:
            out.append(g.id)
    return out


def cycle_states(plan: list[SignalPhase], num_groups: int, dt: float) -> np.ndarray:
    """(num_groups, N) int8 states over one cycle of N = cycle / dt steps."""
    durs = [int(round(p.duration / dt)) for p in plan]
    out = np.full((num_groups, sum(durs)), RED, np.int8)
    start = 0
    for i, (p, n) in enumerate(zip(plan, durs)):
        nxt = plan[(i + 1) % len(plan)]
        g_end = n - int(round((p.yellow_duration + p.all_red) / dt))
        y_end = n - int(round(p.all_red / dt))
        for g in p.green:
            if g in nxt.green:
                out[g, start:start + n] = GREEN
            else:
                out[g, start:start + g_end] = GREEN
                out[g, start + g_end:start + y_end] = YELLOW
        start += n
    return out


def remaining_green(states: np.ndarray) -> np.ndarray:
    """(G, N) steps until each group next stops being green (0 when not
    green), over a cyclic timeline. Groups green throughout get N."""
    g, n = states.shape
    green = np.concatenate([states, states], axis=1) == GREEN
    idx = np.arange(2 * n)
    stop = np.where(green, 4 * n, idx[None, :])
    nxt = np.minimum.accumulate(stop[:, ::-1], axis=1)[:, ::-1]  # next non-green index
    out = (nxt - idx[None, :])[:, :n]
    return np.minimum(out, n).astype(np.int32)


def states_at(cycle: np.ndarray, offset_steps: int, num_steps: int, start: int = 0) -> np.ndarray:
    """(G, num_steps) states for steps ``start..start+num_steps-1`` of a
    plan shifted by ``offset_steps``."""
    n = cycle.shape[1]
    idx = (np.arange(start, start + num_steps) + offset_steps) % n
    return cycle[:, idx]
