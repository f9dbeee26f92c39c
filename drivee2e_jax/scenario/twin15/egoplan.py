"""Choosing the ego and timing the signals so a behaviour label can happen.

For every intersection we list, per label, the paths an ego may take (and
for COV / IPC the partner paths that make the interaction possible and the
part of the signal cycle when both have right of way). A scenario then
picks one, spawns the ego at the map edge, predicts when it reaches its
stop line in free flow, and shifts the signal plan so that moment falls
where the label needs it: inside a green (STR, LFT, RT, UT, COV, IPC),
a few seconds before green (STP), or just after the yellow onset (YLW).
The traffic model then runs as usual and the label is verified from the
log (``labels``); a miss is retried with fresh randomness.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .network import STEP, TRACK, VEHICLE
from .signals import GREEN, YELLOW
from .tables import Tables

DT = 0.1
LABELS = ("COV", "IPC", "UT", "YLW", "STR", "LFT", "RT", "STP")


@dataclass
class Option:
    path: int  # global ego path id
    partners: list[int] = field(default_factory=list)  # COV: vehicle paths; IPC: crosswalk tracks
    window: np.ndarray | None = None  # (C,) bool cycle steps when the interaction can happen
    ego_yields: bool = False  # COV: the ego gives way to the partners (else they to it)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Cyclic runs of True as (start, length)."""
    n = len(mask)
    if mask.all():
        return [(0, n)]
    if not mask.any():
        return []
    start = int(np.argmin(mask))  # a False: rotate so no run wraps
    m = np.roll(mask, -start)
    edges = np.diff(np.concatenate([[0], m.astype(np.int8), [0]]))
    ups, downs = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [((int(u) + start) % n, int(d - u)) for u, d in zip(ups, downs)]


def path_turn_deg(tab: Tables, path: int) -> float:
    """Heading change (deg, + = left) from the stop line to the connector end."""
    i0 = int(tab.path_stop[path] / STEP)
    i1 = int(tab.path_j1[path] / STEP)
    return float(np.rad2deg(tab.path_yaw[path, i1] - tab.path_yaw[path, i0]))


def green_mask(tab: Tables, inter: int, path: int) -> np.ndarray:
    c = tab.cycle_len[inter]
    g = tab.path_group[path]
    if g < 0:
        return np.ones(c, bool)
    return tab.cycle[inter, g, :c] == GREEN


def _zone_partners(tab: Tables, path: int, crossing_only: bool = False) -> list[int]:
    """Paths conflicting with ``path`` for a car; ``crossing_only`` drops
    merges (both zones running to the ends of the connectors), where two
    cars can never be inside the junction together."""
    zt = tab.zones
    zs = zt.sides(path, tab.path_inter[path])
    zs = zs[~zt.heavy_only[zs]]  # the ego is a car
    if crossing_only:
        other = zt.other[zs]
        opp = zt.offset[tab.path_inter[path]] + zt.opp[zs]
        merge = (zt.b[zs] >= tab.path_j1[path] - 1.0) & (zt.b[opp] >= tab.path_j1[other] - 1.0)
        zs = zs[~merge]
    return sorted(set(int(q) for q in zt.other[zs]))


_CACHE: dict[int, dict[tuple[int, str], list[Option]]] = {}


def options_for(tab: Tables) -> dict[tuple[int, str], list[Option]]:
    """(intersection, label) -> ego options (computed once per Tables)."""
    if id(tab) not in _CACHE:
        _CACHE[id(tab)] = _options(tab)
    return _CACHE[id(tab)]


def _options(tab: Tables) -> dict[tuple[int, str], list[Option]]:
    out: dict[tuple[int, str], list[Option]] = {}
    for inter in range(len(tab.cycle_len)):
        paths = tab.paths_of(inter)
        veh = [int(p) for p in paths if tab.path_kind[p] == VEHICLE]
        for p in veh:
            mv, sig = int(tab.path_move[p]), tab.path_group[p] >= 0
            gp = green_mask(tab, inter, p)
            label = {0: "STR", 1: "LFT", 2: "RT", 3: "UT"}[mv]
            # clear-cut movements only, so the logged turn is unambiguous
            turn = abs(path_turn_deg(tab, p))
            if (mv == 0 and turn <= 30.0) or (mv in (1, 2) and turn >= 50.0) or mv == 3:
                out.setdefault((inter, label), []).append(Option(p))
            if sig and mv in (0, 1):
                out.setdefault((inter, "STP"), []).append(Option(p))
                if mv == 0:
                    out.setdefault((inter, "YLW"), []).append(Option(p))
            if mv == 3:
                continue
            partners = _zone_partners(tab, p)
            crossing = set(_zone_partners(tab, p, crossing_only=True))
            rank = tab.path_rank[p]
            # when no higher-priority vehicle stream crosses the ego's path:
            # an ego that must yield to through traffic rarely gets a log
            free = gp.copy()
            for q in partners:
                if tab.path_kind[q] == VEHICLE and tab.path_leg[q] != tab.path_leg[p] and tab.path_rank[q] > rank:
                    free &= ~green_mask(tab, inter, q)
            cov, cov_win, ipc, ipc_win = [], np.zeros_like(gp), [], np.zeros_like(gp)
            give, give_win = [], np.zeros_like(gp)
            for q in partners:
                if tab.path_kind[q] != VEHICLE or tab.path_leg[q] == tab.path_leg[p] or q not in crossing:
                    continue
                both = gp & green_mask(tab, inter, q)
                if not any(n >= 80 for _, n in _runs(both)):
                    continue
                if tab.path_rank[q] > rank:
                    # the ego gives way to a competitor and enters right
                    # behind it, while the competitor is still inside
                    give.append(q)
                    give_win |= both
                else:
                    # a competitor that gives way to the ego and follows it in
                    cov.append(q)
                    cov_win |= both & free
            if give:
                out.setdefault((inter, "COV"), []).append(Option(p, give, give_win, ego_yields=True))
            elif cov and cov_win.any():
                out.setdefault((inter, "COV"), []).append(Option(p, cov, cov_win))
            for q in partners:
                if tab.path_kind[q] == TRACK:
                    walk = tab.cycle[inter, tab.path_group[q], :tab.cycle_len[inter]] == GREEN
                    both = free & walk
                    if any(n >= 80 for _, n in _runs(both)):
                        ipc.append(q)
                        ipc_win |= both
            if ipc and mv in (1, 2):
                out.setdefault((inter, "IPC"), []).append(Option(p, ipc, ipc_win))
    return out


def capable(tab: Tables) -> dict[str, set[int]]:
    """Label -> intersections that can produce it."""
    caps: dict[str, set[int]] = {lab: set() for lab in LABELS}
    for (inter, label), opts in options_for(tab).items():
        # COV needs an ego that gives way (the other kind alone rarely works out)
        if opts and (label != "COV" or any(o.ego_yields for o in opts)):
            caps[label].add(inter)
    return caps


def free_flow_time(tab: Tables, path: int, v_des: float, s0: float, s1: float) -> float:
    """Seconds to drive path from s0 to s1 at min(v_des, curve limit)."""
    i0, i1 = int(s0 / STEP), max(int(s0 / STEP) + 1, int(s1 / STEP))
    v = np.minimum(v_des, tab.path_vmax[path, i0:i1])
    return float((STEP / np.maximum(v, 0.5)).sum())


_APPROACH: dict[int, np.ndarray] = {}


def approach_time(tab: Tables) -> np.ndarray:
    """(P,) free-flow seconds from each path's start to its stop point at
    90 % of the limit (cached per Tables)."""
    if id(tab) not in _APPROACH:
        _APPROACH[id(tab)] = np.array([free_flow_time(tab, p, 0.9 * tab.path_limit[p], 2.5, tab.path_stop[p])
                                       for p in range(len(tab.path_len))])
    return _APPROACH[id(tab)]


def pick_timing(rng: np.random.Generator, tab: Tables, inter: int, label: str, opt: Option,
                arrival_step: int) -> int | None:
    """Signal offset (steps) that puts the ego's stop-line arrival where the
    label needs it in the cycle, or None when this option cannot."""
    c = int(tab.cycle_len[inter])
    g = tab.path_group[opt.path]
    gp = green_mask(tab, inter, opt.path)
    s = 1.0 / DT
    if label in ("STR", "LFT", "RT", "UT"):
        runs = [(a, n) for a, n in _runs(gp) if n >= 8 * s]
        if not runs:
            return None
        a, n = runs[rng.integers(len(runs))]
        target = a + rng.integers(int(1.5 * s), int(min(n - 5 * s, 14 * s)) + 1)
    elif label in ("COV", "IPC"):
        runs = [(a, n) for a, n in _runs(opt.window) if n >= 6 * s]
        if not runs:
            return None
        a, n = runs[rng.integers(len(runs))]
        target = a + rng.integers(int(0.5 * s), int(n - 3 * s) + 1)
    elif label == "STP":
        runs = [(a, n) for a, n in _runs(gp) if n >= 8 * s]
        if g < 0 or not runs:
            return None
        a, _ = runs[rng.integers(len(runs))]
        target = a - rng.integers(int(4.5 * s), int(9.0 * s) + 1)
    elif label == "YLW":
        ylw = tab.cycle[inter, g, :c] == YELLOW if g >= 0 else np.zeros(c, bool)
        runs = _runs(ylw)
        if not runs:
            return None
        a, _ = runs[rng.integers(len(runs))]
        target = a + rng.integers(int(0.3 * s), int(1.4 * s) + 1)
    else:
        raise ValueError(label)
    return int((target - arrival_step) % c)
