"""From a simulated scenario to a verified 201-step log.

``cut`` picks the log window around the ego, drops agents whose boxes
overlap (any pair) or come within 0.5 m of the ego, and checks from the
logged tracks that the behaviour label holds:

* every label: the ego never crosses its stop line on red;
* STR / LFT / RT / UT: crosses on green (or a free right), and the logged
  heading change through the junction is < 40 deg / left / right / > 150 deg;
* STP: stops (< 0.1 m/s) within 3 m of its stop line on red, then crosses
  on green;
* YLW: crosses its stop line on yellow;
* COV: a vehicle on a conflicting path from another approach is inside the
  junction while the ego is at its stop line (waiting for a gap) or inside;
* IPC: a pedestrian or cyclist is on a crosswalk the ego's path crosses
  while the ego is within ~25 m before (or on) that crossing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivee2e_jax.scenario.labels import IPC_AHEAD_M, STOP_LINE_NEAR_M, STOP_SPEED_MPS, turn_label

from .boxes import find_overlaps
from .network import TRACK, VEHICLE
from .plan import WARMUP_STEPS, Plan
from .signals import GREEN, RED, YELLOW
from .tables import Tables, interp_path
from .traffic import SimResult

LOG_STEPS = 201
END_MARGIN = 20  # the ego log ends this many steps before the scenario log
#: Steps simulated past the ego's log end: leaves room to place the window
#: (its end lies END_MARGIN..FINISH_MARGIN steps after the ego's last step).
FINISH_MARGIN = 70
EGO_CLEARANCE = 0.5  # m kept between the ego and every other box


@dataclass
class Cut:
    t0: int  # first logged sim step
    rows: np.ndarray  # (A,) agent rows (into the batch) kept, ego first
    s: np.ndarray  # (A, T) arc positions (NaN when absent)
    v: np.ndarray  # (A, T) speeds
    xy: np.ndarray  # (A, T, 2)
    yaw: np.ndarray  # (A, T)
    valid: np.ndarray  # (A, T)
    removed: int  # agents dropped for overlaps
    removed_near_ego: int  # of which for coming within EGO_CLEARANCE of the ego
    signals: np.ndarray  # (G, T) int8 states of the map's groups


class Miss(Exception):
    """The attempt does not give a valid scenario of its label."""


def _first(mask: np.ndarray) -> int:
    return int(np.argmax(mask)) if mask.any() else -1


def cut(rng: np.random.Generator, tab: Tables, plan: Plan, rows: np.ndarray, res: SimResult, scen_row: int) -> Cut:
    """Window, clean and verify one scenario (``rows[0]`` is the ego, the
    scenario is row ``scen_row`` of the batch ``res``)."""
    s_hist, v_hist, rec_start, spawn_step = res.s, res.v, res.rec_start, res.spawn_step
    ego = rows[0]
    p = int(plan.agents["path"][0])
    length = float(plan.agents["length"][0])
    se = s_hist[:, ego].astype(float)
    if spawn_step[ego] < 0 or np.isnan(se).all():
        raise Miss("ego never spawned")
    stop, j1 = tab.path_stop[p], tab.path_j1[p]
    steps = np.arange(len(se)) + rec_start
    seen = ~np.isnan(se)
    k_cross = _first(seen & (se + length / 2 > stop))
    k_end = _first(seen & (se >= j1 + plan.d_after))
    if k_cross < 0 or k_end < 0:
        raise Miss("ego did not get through")
    k_cross, k_end = steps[k_cross], steps[k_end]
    ve = v_hist[:, ego].astype(float)
    near_line = seen & (steps < k_cross) & (stop - (se + length / 2) < STOP_LINE_NEAR_M) & (ve < STOP_SPEED_MPS)
    lo = max(int(spawn_step[ego]), k_end - (LOG_STEPS - 1 - END_MARGIN), WARMUP_STEPS)
    hi = min(k_cross - 25, int(res.last_step[scen_row]) + 1 - LOG_STEPS)
    if plan.label == "STP":
        k_stop = _first(near_line)
        if k_stop < 0:
            raise Miss("ego never stopped at its line")
        hi = min(hi, steps[k_stop] - 10)
    if lo > hi:
        raise Miss("no log window fits the ego")
    t0 = int(rng.integers(lo, hi + 1))
    win = slice(t0 - rec_start, t0 - rec_start + LOG_STEPS)
    s = s_hist[win][:, rows].T.astype(float)
    v = v_hist[win][:, rows].T.astype(float)
    valid = ~np.isnan(s)
    valid[0, k_end - t0 + 1:] = False  # the ego's log ends past the junction
    s[~valid] = np.nan
    alive = valid.any(1)
    alive[0] = True
    rows, s, v, valid = rows[alive], s[alive], v[alive], valid[alive]
    paths = plan.agents["path"][_local(rows, ego)]
    xy, yaw = interp_path(tab, paths[:, None], np.nan_to_num(s))
    size = np.stack([plan.agents["length"][_local(rows, ego)], plan.agents["width"][_local(rows, ego)]], 1)
    inflate = np.zeros(len(rows))
    inflate[0] = EGO_CLEARANCE
    drop = np.zeros(len(rows), bool)
    near_ego = 0
    for a, b, _ in find_overlaps(xy, yaw, size, valid, inflate):
        if drop[a] or drop[b]:
            continue
        victim = b if a == 0 else max(a, b)  # the ego stays; else the later arrival goes
        drop[victim] = True
        near_ego += int(a == 0)
    keep = ~drop
    cutres = Cut(t0, rows[keep], s[keep], v[keep], xy[keep], yaw[keep], valid[keep], int(drop.sum()), near_ego,
                 _signals(tab, plan, t0))
    _verify(tab, plan, cutres, paths[keep], k_cross)
    return cutres


def _local(rows: np.ndarray, ego: int) -> np.ndarray:
    """Batch rows -> indices into the plan's agent arrays (rows of one plan are contiguous)."""
    return rows - ego


def _signals(tab: Tables, plan: Plan, t0: int) -> np.ndarray:
    i = plan.inter
    c = tab.cycle_len[i]
    idx = (np.arange(t0, t0 + LOG_STEPS) + plan.offset) % c
    return tab.cycle[i, :tab.num_groups[i]][:, idx]


def _verify(tab: Tables, plan: Plan, c: Cut, paths: np.ndarray, k_cross: int) -> None:
    p = int(paths[0])
    g = tab.path_group[p]
    kc = k_cross - c.t0
    state = GREEN if g < 0 else int(c.signals[g, kc])
    if state == RED:
        raise Miss("ego crossed on red")
    label = plan.label
    if label == "YLW":
        if state != YELLOW:
            raise Miss("ego did not cross on yellow")
        return
    if state != GREEN:
        raise Miss("ego crossed on yellow")
    if label in ("STR", "LFT", "RT", "UT"):
        yaw = np.unwrap(c.yaw[0][c.valid[0]])
        s = c.s[0][c.valid[0]]
        i0 = _first(s >= tab.path_stop[p])
        i1 = _first(s >= tab.path_j1[p])
        if i0 < 0 or i1 < 0:
            raise Miss("ego turn not logged")
        turn = np.rad2deg(yaw[i1] - yaw[i0])
        got = turn_label(turn, left_uturns_only=True)
        if got != label:
            raise Miss(f"ego turned {turn:.0f} deg")
        return
    if label == "STP":
        s0, v0 = c.s[0], c.v[0]
        length = float(plan.agents["length"][0])
        near = c.valid[0] & (tab.path_stop[p] - (s0 + length / 2) < STOP_LINE_NEAR_M) & (v0 < STOP_SPEED_MPS)
        red = c.signals[g] == RED
        if not (near & red).any():
            raise Miss("ego did not stop on red")
        return
    half = plan.agents["length"][c.rows - c.rows[0]] / 2
    zs = tab.zones.sides(p, plan.inter)
    zs = zs[~tab.zones.heavy_only[zs]]
    others = tab.zones.other[zs]
    if label == "COV":
        partners = set(int(q) for q in others if tab.path_kind[q] == VEHICLE and tab.path_leg[q] != tab.path_leg[p])
        mine = np.array([int(q) in partners for q in paths])
        mine[0] = False
        # the ego competes from the moment it is at its stop line (waiting
        # for a gap counts) until it has left the junction
        s0 = np.nan_to_num(c.s, nan=-1e9)
        # (centres: the competitor is well inside, not just touching the edge)
        inside = c.valid & (s0 > tab.path_stop[paths][:, None]) & (s0 < tab.path_j1[paths][:, None])
        ego_at = c.valid[0] & (s0[0] + half[0] > tab.path_stop[p] - 2.0) & (s0[0] < tab.path_j1[p])
        if not (inside[mine] & ego_at).any():
            raise Miss("no competing vehicle in the junction with the ego")
        return
    if label == "IPC":
        s0 = np.nan_to_num(c.s, nan=-1e9)
        rear = s0[0] - half[0]
        for z, q in zip(zs, others):
            if tab.path_kind[q] != TRACK:
                continue
            # the ego within ~25 m before the crossing (or on it), a person's
            # centre on the crossing between the kerbs
            ego_near = c.valid[0] & (s0[0] >= tab.zones.a[z] - IPC_AHEAD_M) & (rear <= tab.zones.b[z])
            mine = paths == q
            on = c.valid[mine] & (s0[mine] > tab.path_stop[q]) & (s0[mine] < tab.path_j1[q])
            if (on & ego_near).any():
                return
        raise Miss("nobody crossed in front of the ego")
    raise ValueError(label)
