"""The rule-based multi-agent traffic model, run once per scenario to make
the logs (all scenarios of a batch step together, vectorised over agents).

Every agent follows a fixed path (``network``) with the Intelligent Driver
Model: a free-road term towards a desired speed capped by the path's
curvature profile, and the harder of the obstacle terms: the leader (the
nearest rear ahead on the agent's own chain of lanes, including agents just
branching off the same lane) and, while it may not go on, its stop point
(stop line or kerb) or, for pedestrians and cyclists, the edge of the next
conflict zone.

Vehicles *commit* to crossing the junction once they are within their
decision distance of the stop line and first in their queue, and only if

* signal: green (free rights: always); a vehicle caught by the yellow goes
  only if it could not stop at 3.5 m/s^2, and committed vehicles that can
  still stop at 3 m/s^2 withdraw;
* reservation: no conflict zone of their path is claimed by someone else;
* yielding: no higher-priority vehicle with right of way (straight over
  right over left over U-turn, on conflicting approaches) would reach a
  shared zone before this one has cleared it by 1.5 s, and no pedestrian
  or cyclist is in, or within 3 m of, a shared zone.

A committed vehicle claims all zones of its path and releases each one
once its rear has passed it. Pedestrians and cyclists commit on the walk
signal (with >= 5 s of it left) and claim zones one at a time as they reach
them, stopping before a zone a vehicle holds. Two agents thus never occupy
conflicting zones at once; queues keep agents on one lane apart. The
generator still checks the finished logs with oriented boxes.

Zones are sized for heavy vehicles; pairs that only conflict through a
heavy body's swing (``ZoneTable.heavy_only``) are ignored between two
light vehicles.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .network import HEAVY_LENGTH, STEP, TRACK, VEHICLE
from .signals import GREEN, YELLOW
from .tables import Tables, ZoneTable  # noqa: F401

DT = 0.1  # s
B_MAX = 5.9  # m/s^2, hardest braking (logs must stay within 6)
LOOK = 100.0  # m before its stop point an agent starts checking permission
STOP_GAP = 0.4  # m kept between a front and a closed stop line
RELEASE = 0.3  # m past a zone before it is released
YIELD_GAP = 1.5  # s margin kept ahead of a higher-priority vehicle
VRU_NEAR = 3.0  # m: vehicles yield to people this close to a shared zone
VRU_BINS = 80  # 1 m occupancy bins along a pedestrian / cyclist path ...
VRU_BIN0 = 8.0  # ... starting this far before its stop point
WALK_LEFT = 50  # steps of walk needed at least to start crossing
CLEARANCE = 50  # steps of yellow + all red after a walk phase
MAX_WAIT = 60  # steps a spawn may be delayed before it is dropped
KEY = 1024.0  # lane arc positions are < KEY m
V_CROSS = 6.0  # m/s typical vehicle speed inside the junction


@dataclass
class Agents:
    """Agents of a batch (all arrays (N,)); ``t_spawn`` in steps."""

    scen: np.ndarray
    path: np.ndarray
    t_spawn: np.ndarray
    length: np.ndarray
    width: np.ndarray
    v_des: np.ndarray
    a_max: np.ndarray
    b_comf: np.ndarray
    t_head: np.ndarray
    s0: np.ndarray
    ego: np.ndarray  # bool: never dropped, spawns first


@dataclass
class SimResult:
    s: np.ndarray  # (R, N) float32 arc position, NaN when absent
    v: np.ndarray  # (R, N) float32 speed
    rec_start: int
    spawn_step: np.ndarray  # (N,) -1 = never spawned
    last_step: np.ndarray  # (S,) last simulated step of each scenario
    stats: dict = field(default_factory=dict)


def simulate(tab: Tables, inter: np.ndarray, offset: np.ndarray, ag: Agents, n_steps: int,
             rec_start: int, finish: tuple[np.ndarray, np.ndarray, int, int] | None = None) -> SimResult:
    """Run ``n_steps`` of scenarios (``inter``, signal ``offset``) with agents
    ``ag``; positions and speeds are logged from step ``rec_start`` on.

    ``finish = (ego, s_end, margin, after_spawn)``: a scenario stops
    ``margin`` steps after its agent ``ego[i]`` reaches arc ``s_end[i]``
    (its log is complete), but not before ``after_spawn`` steps after that
    agent appeared, so finished scenarios cost nothing; ``SimResult.last_step``
    tells when each stopped.
    """
    return _Sim(tab, inter, offset, ag, n_steps, rec_start, finish).run()


def _time_to_cover(dist, v, a, vcap):
    """Time (s) to cover ``dist`` from speed v accelerating at a up to vcap."""
    dist = np.maximum(dist, 0.0)
    vcap = np.maximum(vcap, v + 1e-3)
    d_acc = (vcap ** 2 - v ** 2) / (2 * a)
    t_in = (np.sqrt(v ** 2 + 2 * a * np.minimum(dist, d_acc)) - v) / a
    return t_in + np.maximum(dist - d_acc, 0.0) / vcap


class _Sorted:
    """Agents' rear positions sorted by (scenario, lane, arc): leaders are
    found with searchsorted. Arcs are kept apart from the combined sort key
    so results never depend on how many scenarios share the batch."""

    def __init__(self, group: np.ndarray, u: np.ndarray, agents: np.ndarray):
        order = np.argsort(group * KEY + u, kind="stable")
        self.group = group[order]
        self.keys = self.group * KEY + u[order]
        self.u = u[order]
        self.agents = agents[order]

    def next_in(self, group: np.ndarray, u: np.ndarray):
        """First entry of ``group`` with arc > u: (agent or -1, its arc)."""
        if not len(self.keys):
            return np.full(len(group), -1), np.full(len(group), np.inf)
        pos = np.searchsorted(self.keys, group * KEY + u, side="right")
        pc = np.minimum(pos, len(self.keys) - 1)
        ok = (pos < len(self.keys)) & (self.group[pc] == group)
        return np.where(ok, self.agents[pc], -1), np.where(ok, self.u[pc], np.inf)


@dataclass
class _Sides:
    """Zone sides of some agents' paths in one table (rows = agents)."""

    zs: np.ndarray  # (n, KZ) local ids (0 where invalid)
    valid: np.ndarray
    g: np.ndarray  # global ids
    opp: np.ndarray  # local ids of the opposite sides

    @classmethod
    def of(cls, zt: ZoneTable, paths: np.ndarray, inters: np.ndarray) -> _Sides:
        zs = zt.path_zs[paths]
        valid = zs >= 0
        zs = np.maximum(zs, 0)
        g = zt.offset[inters][:, None] + zs
        return cls(zs, valid, g, zt.opp[g])


@dataclass
class _View:
    """Per-step arrays over the active agents (index = position in ``act``)."""

    act: np.ndarray
    pa: np.ndarray
    sc: np.ndarray
    s: np.ndarray
    v: np.ndarray
    half: np.ndarray
    lead: np.ndarray
    lead_pos: np.ndarray  # leader's rear on my path (inf: none)
    st: np.ndarray  # signal state
    rem: np.ndarray  # steps of green left
    d: np.ndarray  # stop point minus front
    lane_c: np.ndarray
    u_c: np.ndarray


class _Sim:
    def __init__(self, tab: Tables, inter, offset, ag: Agents, n_steps: int, rec_start: int, finish=None):
        self.tab, self.inter, self.offset, self.ag = tab, inter, offset, ag
        self.finish = finish
        self.last_step = np.full(len(inter), n_steps - 1, np.int64)
        self.n_steps, self.rec_start = n_steps, rec_start
        S, N = len(inter), len(ag.path)
        self.S, self.N = S, N
        self.NLG = tab.sib_lane.shape[0]
        self.ZMAX = int(tab.zones.count.max()) + 1
        self.P = len(tab.path_len)
        self.ainter = inter[ag.scen]
        self.kind = tab.path_kind[ag.path]
        self.vru = self.kind != VEHICLE
        self.group = tab.path_group[ag.path]
        self.stop = tab.path_stop[ag.path]
        self.plen = tab.path_len[ag.path]
        self.heavy = ag.length > HEAVY_LENGTH
        # steps a person needs to cross (kerb to kerb)
        self.cross_steps = (tab.path_j1[ag.path] - self.stop) / np.maximum(ag.v_des, 0.5) / DT
        self.half = ag.length / 2
        self.sqrt_ab = np.sqrt(ag.a_max * ag.b_comf)
        self.prio = (10.0 - tab.path_rank[ag.path]) * 1e7 + np.arange(N)
        self.prio[ag.ego] -= 5e6  # the ego wins ties inside its own priority class
        # VRU paths numbered per intersection, for the occupancy bins
        self.vru_local = np.full(self.P, -1, np.int64)
        for i in range(len(tab.cycle_len)):
            ps = tab.paths_of(i)
            ps = ps[tab.path_kind[ps] != VEHICLE]
            self.vru_local[ps] = np.arange(len(ps))
        self.VMAX = int(self.vru_local.max()) + 1

        self.s = np.zeros(N)
        self.v = np.zeros(N)
        # index of the path segment (lane) under each agent's centre and rear;
        # agents move less than a lane per step, so these only ever step up
        self.seg_c = np.zeros(N, np.int64)
        self.seg_r = np.zeros(N, np.int64)
        self.reach = np.zeros(N)  # pedestrians / cyclists: claimed up to this arc
        self.committed = np.zeros(N, bool)
        self.spawn_step = np.full(N, -1, np.int64)
        R = n_steps - rec_start
        self.s_hist = np.full((R, N), np.nan, np.float32)
        self.v_hist = np.full((R, N), np.nan, np.float32)
        self.order = np.lexsort((~ag.ego, ag.t_spawn))
        self.ptr = 0
        self.pending = np.zeros(0, np.int64)
        self.act = np.zeros(0, np.int64)
        # zone sides claimed by light holders (cars, people, ...) and by heavy ones
        self.held = {k: np.zeros(S * self.ZMAX, bool) for k in ("l", "h")}
        self.req = np.full(S * self.ZMAX, np.inf)
        self.approach = np.full(S * self.P, np.inf)
        self.occ = np.zeros((S, self.VMAX, VRU_BINS), bool)
        self.stats = {"clamped": 0, "dropped": 0}

    # ------------------------------------------------------------------ loop
    def run(self) -> SimResult:
        G = np.arange(self.tab.cycle.shape[1])
        k = 0
        while k < self.n_steps:
            # the unlogged warm-up runs at twice the step (the model is
            # smooth enough) to save time
            dk = 2 if k + 2 <= self.rec_start else 1
            cidx = (k + self.offset) % self.tab.cycle_len[self.inter]
            sig = self.tab.cycle[self.inter[:, None], G[None, :], cidx[:, None]]
            rem = self.tab.rem_green[self.inter[:, None], G[None, :], cidx[:, None]]
            index = self._index()
            self._spawn(k, index)
            if k >= self.rec_start and len(self.act):
                self.s_hist[k - self.rec_start, self.act] = self.s[self.act]
                self.v_hist[k - self.rec_start, self.act] = self.v[self.act]
            if len(self.act):
                w = self._view(index, sig, rem)
                self._withdraw(w)
                self._hold_vehicles(w)
                stop_at = self._vru_claims(w)
                permitted = self._commit(w)
                self._move(w, permitted, stop_at, dk * DT)
            if self.finish is not None:
                self._retire(k)
            k += dk
        self.stats["never_spawned"] = int((self.spawn_step < 0).sum())
        return SimResult(self.s_hist, self.v_hist, self.rec_start, self.spawn_step, self.last_step, self.stats)

    def _retire(self, k: int) -> None:
        """Stop scenarios whose log is complete: drop all their agents."""
        ego, s_end, margin, margin_after_spawn = self.finish
        reached = (self.last_step == self.n_steps - 1) & (self.spawn_step[ego] >= 0) & (self.s[ego] >= s_end)
        # a log must also fit between the ego's spawn and this end
        need = np.maximum(k + margin, self.spawn_step[ego] + margin_after_spawn)
        self.last_step[reached] = np.minimum(need[reached], self.n_steps - 1)
        over = self.last_step <= k
        if over.any():
            self.act = self.act[~over[self.ag.scen[self.act]]]
            self.pending = self.pending[~over[self.ag.scen[self.pending]]]

    # ------------------------------------------------------------ positions
    def _index(self) -> _Sorted:
        """Sorted rear positions (plus ghosts on sibling lanes near a split)."""
        tab, act = self.tab, self.act
        pa = self.ag.path[act]
        rear = self.s[act] - self.half[act]
        kr = self.seg_r[act]
        lane = tab.seg_lane[pa, kr]
        u = rear - tab.seg_start[pa, kr]
        sc = self.ag.scen[act]
        groups, us, who = [sc * self.NLG + lane], [u], [act]
        sib = tab.sib_lane[lane]
        gh = (sib >= 0) & (u[:, None] < tab.sib_len[lane])
        if gh.any():
            ii, jj = np.nonzero(gh)
            groups.append(sc[ii] * self.NLG + sib[ii, jj])
            us.append(u[ii])
            who.append(act[ii])
        return _Sorted(np.concatenate(groups), np.concatenate(us), np.concatenate(who))

    def _spawn(self, k: int, index: _Sorted) -> None:
        ag, tab = self.ag, self.tab
        end = self.ptr
        while end < self.N and ag.t_spawn[self.order[end]] <= k:
            end += 1
        if end > self.ptr:
            self.pending = np.concatenate([self.pending, self.order[self.ptr:end]])
            self.ptr = end
        c = self.pending
        if not len(c):
            return
        g0 = ag.scen[c] * self.NLG + tab.seg_lane[ag.path[c], 0]
        first, u_first = index.next_in(g0, np.full(len(c), -1.0))
        v_first = np.where(first >= 0, self.v[np.maximum(first, 0)], 0.0)
        gap = u_first - ag.length[c]
        v_sp = np.where(np.isinf(gap), ag.v_des[c], np.minimum(ag.v_des[c], v_first + 1.0))
        # crosswalk tracks start just 3 m before the kerb: arrive walking pace
        v_sp = np.where(self.kind[c] == TRACK, np.minimum(v_sp, 1.4), v_sp)
        ok = gap >= ag.s0[c] + 2.0 + v_sp * ag.t_head[c] * 0.6
        chosen = np.zeros(len(c), bool)
        if ok.any():
            cand = np.flatnonzero(ok)
            _, first_idx = np.unique(g0[cand], return_index=True)  # one per lane and step
            chosen[cand[first_idx]] = True
        new = c[chosen]
        self.s[new] = self.half[new] + 0.01
        self.seg_c[new] = (self.tab.seg_start[ag.path[new], 1:] <= self.s[new][:, None]).sum(1)
        self.seg_r[new] = 0
        self.v[new] = v_sp[chosen]
        self.reach[new] = self.stop[new] - 1.0  # nothing claimed yet (zones start at the kerb)
        self.spawn_step[new] = k
        late = ~chosen & (k - ag.t_spawn[c] > MAX_WAIT) & ~ag.ego[c]
        self.stats["dropped"] += int(late.sum())
        self.pending = c[~chosen & ~late]
        if len(new):
            self.act = np.concatenate([self.act, new])

    def _view(self, index: _Sorted, sig, rem) -> _View:
        tab, act = self.tab, self.act
        pa, sc = self.ag.path[act], self.ag.scen[act]
        s, half = self.s[act], self.half[act]
        starts = tab.seg_start[pa]
        kc = self.seg_c[act]
        lane = tab.seg_lane[pa, kc]
        u = s - tab.seg_start[pa, kc]
        lead, lead_u = index.next_in(sc * self.NLG + lane, u)
        lead_pos = np.where(lead >= 0, s + (lead_u - u), np.inf)
        for m in (1, 2, 3):  # nobody ahead on this lane: look along the path
            todo = (lead < 0) & (kc + m < tab.seg_lane.shape[1])
            if not todo.any():
                break
            t = np.flatnonzero(todo)
            seg = kc[t] + m
            ln = tab.seg_lane[pa[t], seg]
            okl = (ln >= 0) & (starts[t, seg] - s[t] < 120.0)
            t, seg, ln = t[okl], seg[okl], ln[okl]
            if not len(t):
                break
            a2, u2 = index.next_in(sc[t] * self.NLG + ln, np.full(len(t), -1.0))
            lead[t] = a2
            lead_pos[t] = np.where(a2 >= 0, starts[t, seg] + u2, np.inf)
        ga = self.group[act]
        st = np.where(ga >= 0, sig[sc, np.maximum(ga, 0)], GREEN)
        rm = np.where(ga >= 0, rem[sc, np.maximum(ga, 0)], 10 ** 6)
        return _View(act, pa, sc, s, self.v[act], half, lead, lead_pos, st, rm, self.stop[act] - (s + half),
                     lane, u)

    # ---------------------------------------------------------------- rules
    def _withdraw(self, w: _View) -> None:
        """Committed vehicles that can still stop at a yellow, or that sit
        behind an uncommitted leader before the line, give up their claim."""
        com = self.committed[w.act]
        lead_c = np.maximum(w.lead, 0)
        lead_unc = (w.lead >= 0) & ~self.committed[lead_c] & (w.lead_pos < self.stop[w.act] + 0.5)
        before = w.d > -0.5
        yellow = ~self.vru[w.act] & (w.st == YELLOW) & (w.d > w.v ** 2 / 6.0 + 0.5)
        out = com & before & (yellow | lead_unc)
        self.committed[w.act[out]] = False

    def _mark(self, key: str, idx: np.ndarray, w: _View, upto: np.ndarray | None = None) -> None:
        """Mark the zones of agents ``idx`` whose rear has not yet passed them
        (and, for people, that start within their claimed reach)."""
        if not len(idx):
            return
        zt = self.tab.zones
        z = _Sides.of(zt, w.pa[idx], self.ainter[w.act[idx]])
        rear = w.s[idx] - w.half[idx]
        live = z.valid & (rear[:, None] < zt.b[z.g] + RELEASE)
        if upto is not None:
            live &= zt.a[z.g] <= upto[:, None]
        hi, hj = np.nonzero(live)
        self.held[key][w.sc[idx][hi] * self.ZMAX + z.zs[hi, hj]] = True

    def _hold_vehicles(self, w: _View) -> None:
        for h in self.held.values():
            h[:] = False
        com = self.committed[w.act] & ~self.vru[w.act]
        hold = com & (w.s - w.half < self.tab.zones.path_zmax[w.pa] + RELEASE)
        hv = self.heavy[w.act]
        self._mark("l", np.flatnonzero(hold & ~hv), w)
        self._mark("h", np.flatnonzero(hold & hv), w)

    def _vru_claims(self, w: _View) -> np.ndarray:
        """Committed pedestrians / cyclists extend their claims to the zones
        just ahead unless a vehicle holds them; returns, per active agent,
        the arc it must stop before (inf: none)."""
        stop_at = np.full(len(w.act), np.inf)
        idx = np.flatnonzero(self.vru[w.act] & self.committed[w.act])
        self.occ[:] = False
        if not len(idx):
            return stop_at
        a = w.act[idx]
        zh = self.tab.zones
        # what people already hold blocks other people too
        self._mark("l", idx, w, self.reach[a])
        z = _Sides.of(zh, w.pa[idx], self.ainter[a])
        front = w.s[idx] + w.half[idx]
        ahead = front + 2.0 + 1.2 * w.v[idx]
        za = zh.a[z.g]
        near = z.valid & (za > self.reach[a][:, None]) & (za <= ahead[:, None])
        row = w.sc[idx][:, None] * self.ZMAX
        taken = near & (self.held["l"][row + z.opp] | self.held["h"][row + z.opp])
        # two people reaching conflicting zones in the same step: the first
        # in priority order goes, the other waits
        new = near & ~taken
        if new.any():
            keys = np.broadcast_to(self.prio[a][:, None], z.zs.shape)
            slots = row + z.zs
            np.minimum.at(self.req, slots[new], keys[new])
            taken |= new & (self.req[row + z.opp] < keys)
            self.req[slots[new]] = np.inf
        first_taken = np.where(taken, za, np.inf).min(1)
        self.reach[a] = np.maximum(self.reach[a], np.minimum(ahead, first_taken - 0.01))
        stop_at[idx] = np.where(np.isfinite(first_taken), first_taken - 0.1, np.inf)
        self._mark("l", idx, w, self.reach[a])
        # where people are (and will be within VRU_NEAR), for vehicles' yielding
        bins = np.floor(front - self.stop[a] + VRU_BIN0).astype(np.int64)
        vl = self.vru_local[w.pa[idx]]
        for off in range(int(VRU_NEAR) + 1):
            b = np.minimum(np.maximum(bins + off, 0), VRU_BINS - 1)
            self.occ[w.sc[idx], vl, b] = True
        return stop_at

    def _commit(self, w: _View) -> np.ndarray:
        """Decide who may enter; returns ``permitted`` (no stop-point obstacle)."""
        act = w.act
        com = self.committed[act]
        vru = self.vru[act]
        unc = ~com & (w.d > -0.5) & (w.d < LOOK)
        green = w.st == GREEN
        # people start only if they can finish before the clearance ends
        walk_need = self.cross_steps[act] - CLEARANCE
        sig_ok = np.where(self.kind[act] == TRACK, green & (w.rem >= np.maximum(walk_need, WALK_LEFT)),
                          green | ((w.st == YELLOW) & (w.d <= w.v ** 2 / 7.0)))
        lead_c = np.maximum(w.lead, 0)
        head = (w.lead < 0) | self.committed[lead_c] | (w.lead_pos > self.stop[act] + 0.5)
        permitted = unc & sig_ok
        # people waiting at the kerb on walk count as (about to be) on the crosswalk
        waiting = np.flatnonzero(unc & sig_ok & vru & head & (w.d < 1.5))
        if len(waiting):
            bins = np.floor(w.s[waiting] + w.half[waiting] - self.stop[act[waiting]] + VRU_BIN0).astype(np.int64)
            vl = self.vru_local[w.pa[waiting]]
            for off in range(int(VRU_NEAR) + 1):
                self.occ[w.sc[waiting], vl, np.minimum(np.maximum(bins + off, 0), VRU_BINS - 1)] = True
        app = np.flatnonzero(unc & sig_ok & ~vru)
        if len(app):
            tau = np.maximum(w.d[app], 0.0) / np.maximum(w.v[app], 2.0)
            np.minimum.at(self.approach, w.sc[app] * self.P + w.pa[app], tau)
        decide = np.where(vru, w.v + 0.6, w.v ** 2 / 5.0 + 0.5 * w.v + 3.0)
        # people commit on the signal alone (they claim zones as they go)
        go = np.flatnonzero(permitted & head & vru & (w.d <= decide))
        self.committed[act[go]] = True
        # zones only matter near the decision point; further out only the
        # signal shapes the approach
        chk = np.flatnonzero(permitted & head & ~vru & (w.d < decide + 12.0))
        if len(chk):
            blocked = self._blocked(w, chk)
            permitted[chk[blocked]] = False
            now = chk[~blocked & (w.d[chk] <= decide[chk])]
            if len(now):
                won = self._resolve(w, now)
                self.committed[act[now[won]]] = True
                permitted[now[~won]] = False
        if len(app):
            self.approach[w.sc[app] * self.P + w.pa[app]] = np.inf
        return permitted

    def _blocked(self, w: _View, chk: np.ndarray) -> np.ndarray:
        """Vehicles ``chk`` that may not commit: a zone is claimed, or they
        must yield."""
        tab = self.tab
        zt = tab.zones
        ac = w.act[chk]
        light = ~self.heavy[ac]
        z = _Sides.of(zt, w.pa[chk], self.ainter[ac])
        real = z.valid & ~(light[:, None] & zt.heavy_only[z.g])  # two cars ignore a bus-only conflict
        row = w.sc[chk][:, None] * self.ZMAX
        claimed = self.held["h"][row + z.opp] | (self.held["l"][row + z.opp] & real)
        blocked = (claimed & z.valid).any(1)
        y = real & zt.yields[z.g]
        if y.any():
            other = zt.other[z.g]
            o_vru = tab.path_kind[other] != VEHICLE
            og = zt.offset[self.ainter[ac]][:, None] + z.opp
            # vehicles with right of way arriving before we clear
            t_arr = self.approach[w.sc[chk][:, None] * self.P + other] + (zt.a[og] - tab.path_stop[other]) / V_CROSS
            dist = zt.b[z.g] + w.half[chk][:, None] - w.s[chk][:, None]
            t_clr = _time_to_cover(dist, w.v[chk][:, None], self.ag.a_max[ac][:, None], 8.0)
            blocked |= (y & ~o_vru & (t_arr <= t_clr + YIELD_GAP)).any(1)
            # people in or near the shared zone
            yv = y & o_vru
            if yv.any():
                ii, jj = np.nonzero(yv)
                q = other[ii, jj]
                b0 = np.floor(zt.a[og[ii, jj]] - tab.path_stop[q] + VRU_BIN0).astype(np.int64)
                b1 = np.floor(zt.b[og[ii, jj]] - tab.path_stop[q] + VRU_BIN0).astype(np.int64)
                occ = self.occ[w.sc[chk][ii], self.vru_local[q]]
                rows = np.arange(len(ii))
                hit = np.zeros(len(ii), bool)
                for off in range(10):
                    b = b0 + off
                    hit |= (b <= b1) & occ[rows, np.minimum(np.maximum(b, 0), VRU_BINS - 1)]
                blocked[np.unique(ii[hit])] = True
        return blocked

    def _resolve(self, w: _View, now: np.ndarray) -> np.ndarray:
        """Simultaneous requests for conflicting zones (heavy table, a
        superset): the higher priority wins. Returns the winners mask."""
        z = _Sides.of(self.tab.zones, w.pa[now], self.ainter[w.act[now]])
        slots = w.sc[now][:, None] * self.ZMAX + z.zs
        keys = np.broadcast_to(self.prio[w.act[now]][:, None], z.zs.shape)
        np.minimum.at(self.req, slots[z.valid], keys[z.valid])
        beaten = (z.valid & (self.req[w.sc[now][:, None] * self.ZMAX + z.opp] < keys)).any(1)
        self.req[slots[z.valid]] = np.inf
        return ~beaten

    # ------------------------------------------------------------- dynamics
    def _move(self, w: _View, permitted: np.ndarray, stop_at: np.ndarray, dt: float) -> None:
        ag, tab, act = self.ag, self.tab, w.act
        va, sa, ha = w.v, w.s, w.half
        com = self.committed[act]
        vmax = tab.path_vmax[w.pa, np.minimum(((sa + np.maximum(va, 2.0)) / STEP).astype(np.int64),
                                              tab.path_vmax.shape[1] - 1)]
        v0 = np.maximum(np.minimum(ag.v_des[act], vmax), 0.5)
        a = ag.a_max[act]
        free = a * (1.0 - (va / v0) ** 4)
        has_lead = w.lead >= 0
        v_lead = np.where(has_lead, self.v[np.maximum(w.lead, 0)], 0.0)
        gap = w.lead_pos - sa - ha
        s_star = ag.s0[act] + np.maximum(0.0, va * ag.t_head[act] + va * (va - v_lead) / (2 * self.sqrt_ab[act]))
        acc_l = np.where(has_lead, free - a * (s_star / np.maximum(gap, 0.05)) ** 2, np.inf)
        # a closed stop point (or the next zone a person may not enter yet)
        closed = ~com & (w.d > -0.5) & (w.d < LOOK) & ~permitted
        stop_pos = np.where(closed, self.stop[act] - STOP_GAP, np.inf)
        stop_pos = np.minimum(stop_pos, stop_at)
        d_stop = stop_pos - (sa + ha)
        # drivers brake for a closed line at a steady rate once it needs a
        # good part of their comfortable braking (no IDM creeping at the end)
        b_need = va * va / (2 * np.maximum(d_stop, 0.05))
        brake = np.where(d_stop < 0.3, -va / dt, -1.15 * b_need)
        acc_s = np.where(np.isfinite(stop_pos) & ((b_need >= 0.5 * ag.b_comf[act]) | (d_stop < 0.3)), brake, np.inf)
        # ... and roll up gently when they stopped short
        acc_s = np.where(np.isfinite(stop_pos) & (va < 1.0) & (d_stop > 1.0),
                         np.minimum(free, 0.6 * (d_stop - 0.5) - va), acc_s)
        acc = np.maximum(np.minimum(np.minimum(free, np.minimum(acc_l, acc_s)), a), -B_MAX)
        v_new = va + acc * dt
        ds = np.where(v_new < 0, va * va / (2 * np.maximum(-acc, 1e-6)), va * dt + 0.5 * acc * dt * dt)
        v_new = np.maximum(v_new, 0.0)
        s_new = sa + ds
        # hard limits (a well-behaved IDM never needs them; counted)
        lim = np.minimum(np.where(has_lead, w.lead_pos - ha - 0.2, np.inf),
                         np.where(np.isfinite(stop_pos) & (d_stop > 0), stop_pos - ha + 0.05, np.inf))
        over = s_new > np.maximum(lim, sa)
        if over.any():
            self.stats["clamped"] += int(over.sum())
            s_new = np.where(over, np.maximum(lim, sa), s_new)
        self.s[act] = s_new
        self.v[act] = v_new
        kc, kr = self.seg_c[act], self.seg_r[act]
        self.seg_c[act] = kc + (s_new >= tab.seg_start[w.pa, kc + 1])
        self.seg_r[act] = kr + (s_new - ha >= tab.seg_start[w.pa, kr + 1])
        done = s_new >= self.plen[act] - ha
        if done.any():
            self.committed[act[done]] = False
            self.act = act[~done]
