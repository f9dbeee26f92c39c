"""All 15 networks packed into padded numpy tables, built once per process.

Global ids: paths are numbered across intersections (``path_inter`` tells
whose), lanes too (``lane_offset[i] + local lane id``; crosswalk tracks are
extra "lanes" after the map's). Zone sides stay local to their
intersection (the traffic model keeps one claim array per scenario), and
signal groups are the map's own ids.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from .curves import headings
from .layout import build_layout
from .network import STEP, TRACK, Network, build_network, speed_profile  # noqa: F401
from .signals import cycle_states, remaining_green
from .specs import SPECS

KS = 5  # max segments per path
KB = 3  # max siblings per lane


@dataclass
class Tables:
    networks: list[Network]
    path_inter: np.ndarray  # (P,)
    path_local: np.ndarray  # (P,) index within its network
    path_kind: np.ndarray  # (P,) VEHICLE | BIKE | TRACK
    path_xy: np.ndarray  # (P, M, 2)
    path_yaw: np.ndarray  # (P, M) unwrapped
    path_vmax: np.ndarray  # (P, M) curvature speed limit, m/s
    path_len: np.ndarray  # (P,)
    path_stop: np.ndarray  # (P,) stop point arc
    path_j1: np.ndarray  # (P,) end of the junction part
    path_group: np.ndarray  # (P,) signal group (-1 none)
    path_rank: np.ndarray  # (P,)
    path_move: np.ndarray  # (P,) 0 straight 1 left 2 right 3 uturn -1 track
    path_leg: np.ndarray  # (P,) entry leg (tracks: the crossed leg)
    path_to_leg: np.ndarray  # (P,)
    path_limit: np.ndarray  # (P,) speed limit of the entry leg, m/s
    path_outer: np.ndarray  # (P,) bool: outer crosswalk track (cyclists allowed)
    seg_lane: np.ndarray  # (P, KS) global lane ids, -1 padded
    seg_start: np.ndarray  # (P, KS + 1) arc starts, +inf padded
    zones: ZoneTable
    sib_lane: np.ndarray  # (NL, KB) global lane ids, -1 padded
    sib_len: np.ndarray  # (NL, KB)
    lane_offset: np.ndarray  # (I,)
    cycle: np.ndarray  # (I, G, C) int8 signal states over one cycle (dt = 0.1 s)
    cycle_len: np.ndarray  # (I,)
    rem_green: np.ndarray  # (I, G, C) steps of green left
    num_groups: np.ndarray  # (I,)

    def paths_of(self, inter: int) -> np.ndarray:
        return np.flatnonzero(self.path_inter == inter)


@dataclass
class ZoneTable:
    """Conflict-zone sides of all intersections.

    Intervals are sized for heavy vehicles (a superset of the light ones);
    ``heavy_only`` marks pairs that conflict only when a heavy vehicle is
    involved (a bus's swing into the next lane), which two light vehicles
    ignore.
    """

    path_zs: np.ndarray  # (P, KZ) local zone-side ids, -1 padded
    path_zmax: np.ndarray  # (P,) arc past which the path holds no zone
    a: np.ndarray  # (Z,) global zone-side tables (index offset[i] + local)
    b: np.ndarray
    opp: np.ndarray  # (Z,) local id of the opposite side
    yields: np.ndarray  # (Z,) bool: this side yields to the other
    other: np.ndarray  # (Z,) global path id of the other side
    owner: np.ndarray  # (Z,) global path id of this side
    offset: np.ndarray  # (I,)
    count: np.ndarray  # (I,) zone sides per intersection
    heavy_only: np.ndarray  # (Z,) bool

    def sides(self, path: int, inter: int) -> np.ndarray:
        """Global ids of the zone sides of one path."""
        zs = self.path_zs[path]
        return zs[zs >= 0] + self.offset[inter]


def _zone_table(nets: list[Network], path_offset: np.ndarray, inter: np.ndarray,
                kind: np.ndarray, leg: np.ndarray, rank: np.ndarray) -> ZoneTable:
    zone_lists = [n.zones_heavy for n in nets]
    light_pairs = [{(z.p, z.q) for z in n.zones} for n in nets]
    sides_per = [2 * len(z) for z in zone_lists]
    offset = np.cumsum([0] + sides_per)[:-1]
    Z = int(sum(sides_per))
    P = len(inter)
    a_, b_ = np.zeros(Z), np.zeros(Z)
    opp, other, owner = np.zeros(Z, np.int64), np.zeros(Z, np.int64), np.zeros(Z, np.int64)
    yields = np.zeros(Z, bool)
    heavy_only = np.zeros(Z, bool)
    per_path: list[list[int]] = [[] for _ in range(P)]
    for i, zones in enumerate(zone_lists):
        for z, zn in enumerate(zones):
            gp, gq = path_offset[i] + zn.p, path_offset[i] + zn.q
            for side, (own, oth, a, b) in enumerate(((gp, gq, zn.a_p, zn.b_p), (gq, gp, zn.a_q, zn.b_q))):
                loc = 2 * z + side
                g = offset[i] + loc
                a_[g], b_[g] = a, b
                opp[g] = 2 * z + (1 - side)
                other[g], owner[g] = oth, own
                # side by side from one approach (a long body's swing into the
                # next lane) is first come, first served: nobody yields
                same_leg = kind[own] != TRACK and kind[oth] != TRACK and leg[own] == leg[oth]
                yields[g] = rank[own] < rank[oth] and not same_leg
                heavy_only[g] = (zn.p, zn.q) not in light_pairs[i]
                per_path[own].append(loc)
    KZ = max(len(x) for x in per_path)
    path_zs = np.full((P, KZ), -1, np.int64)
    path_zmax = np.full(P, -np.inf)
    for g, lst in enumerate(per_path):
        path_zs[g, :len(lst)] = lst
        if lst:
            path_zmax[g] = b_[offset[inter[g]] + np.asarray(lst)].max()
    return ZoneTable(path_zs, path_zmax, a_, b_, opp, yields, other, owner, offset, np.asarray(sides_per), heavy_only)


MOVE_CODE = {"straight": 0, "left": 1, "right": 2, "uturn": 3}


@cache
def build_tables(dt: float = 0.1) -> Tables:
    nets = [build_network(build_layout(sp.map_id)) for sp in SPECS]
    paths = [(i, j, p) for i, n in enumerate(nets) for j, p in enumerate(n.paths)]
    P = len(paths)
    M = max(len(p.xy) for _, _, p in paths)
    lane_offset = np.cumsum([0] + [n.num_segments for n in nets])[:-1]
    NL = int(lane_offset[-1] + nets[-1].num_segments)
    path_offset = np.cumsum([0] + [len(n.paths) for n in nets])[:-1]

    xy = np.zeros((P, M, 2))
    yaw = np.zeros((P, M))
    vmax = np.zeros((P, M))
    seg_lane = np.full((P, KS), -1, np.int64)
    seg_start = np.full((P, KS + 1), np.inf)
    cols = {k: np.zeros(P) for k in ("len", "stop", "j1", "rank")}
    kind, group, move, inter, local, leg, to_leg = (np.zeros(P, np.int64) for _ in range(7))
    limit = np.zeros(P)
    outer = np.zeros(P, bool)
    for g, (i, j, p) in enumerate(paths):
        n = len(p.xy)
        xy[g, :n] = p.xy
        xy[g, n:] = p.xy[-1]
        h = headings(p.xy)
        yaw[g, :n], yaw[g, n:] = h, h[-1]
        vp = speed_profile(p.xy)
        vmax[g, :n], vmax[g, n:] = vp, vp[-1]
        ids = p.lanes if p.kind == TRACK else p.lanes
        seg_lane[g, :len(ids)] = np.asarray(ids) + lane_offset[i]
        seg_start[g, :len(ids)] = p.seg_start
        cols["len"][g], cols["stop"][g], cols["j1"][g], cols["rank"][g] = p.length, p.stop_s, p.j1, p.rank
        kind[g], group[g], inter[g], local[g] = p.kind, p.group, i, j
        move[g] = MOVE_CODE.get(p.movement, -1)
        leg[g], to_leg[g], outer[g] = p.leg, p.to_leg, p.outer
        limit[g] = nets[i].layout.legs[p.leg].spec.speed_limit

    zones = _zone_table(nets, path_offset, inter, kind, leg, cols["rank"])

    sib_lane = np.full((NL, KB), -1, np.int64)
    sib_len = np.zeros((NL, KB))
    for i, n in enumerate(nets):
        for lane, lst in n.siblings.items():
            for k, (other, length) in enumerate(lst[:KB]):
                sib_lane[lane_offset[i] + lane, k] = lane_offset[i] + other
                sib_len[lane_offset[i] + lane, k] = length

    cycles = [cycle_states(n.layout.map.signal_plan, len(n.layout.signals.groups), dt) for n in nets]
    G = max(c.shape[0] for c in cycles)
    C = max(c.shape[1] for c in cycles)
    cycle = np.zeros((len(nets), G, C), np.int8)
    rem = np.zeros((len(nets), G, C), np.int32)
    for i, c in enumerate(cycles):
        cycle[i, :c.shape[0], :c.shape[1]] = c
        rem[i, :c.shape[0], :c.shape[1]] = remaining_green(c)
    return Tables(
        networks=nets, path_inter=inter, path_local=local, path_kind=kind, path_xy=xy, path_yaw=yaw,
        path_vmax=vmax, path_len=cols["len"], path_stop=cols["stop"], path_j1=cols["j1"], path_group=group,
        path_rank=cols["rank"], path_move=move, path_leg=leg, path_to_leg=to_leg, path_limit=limit,
        path_outer=outer, seg_lane=seg_lane, seg_start=seg_start, zones=zones,
        sib_lane=sib_lane, sib_len=sib_len,
        lane_offset=lane_offset, cycle=cycle, cycle_len=np.asarray([c.shape[1] for c in cycles]),
        rem_green=rem, num_groups=np.asarray([c.shape[0] for c in cycles]),
    )


def interp_path(tab: Tables, path: np.ndarray, s: np.ndarray):
    """Box centre (.., 2) and heading (..) of agents on ``path`` at arc ``s``."""
    f = np.clip(s / STEP, 0.0, tab.path_xy.shape[1] - 1.001)
    i = f.astype(np.int64)
    w = f - i
    p0 = tab.path_xy[path, i]
    p1 = tab.path_xy[path, i + 1]
    xy = p0 + (p1 - p0) * w[..., None]
    yaw = tab.path_yaw[path, i] * (1 - w) + tab.path_yaw[path, i + 1] * w
    return xy, yaw
