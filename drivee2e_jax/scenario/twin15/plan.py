"""One scenario attempt: its signal offset, its ego and everyone else who
will appear (``Plan``), ready to be simulated in a batch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import agents as cat_mod
from .agents import CAT
from .demand import background
from .egoplan import Option, approach_time, free_flow_time, options_for, pick_timing
from .network import TRACK
from .tables import Tables

DT = 0.1
#: Steps simulated per scenario: warm-up, the ego's approach and the 201-step log.
SIM_STEPS = 520
#: First step that may be logged (the junction has filled by then).
WARMUP_STEPS = 150
EGO_SPAWN = (165, 205)  # steps


@dataclass
class Plan:
    index: int
    inter: int
    label: str
    time_of_day: str
    offset: int  # signal offset, steps
    option: Option
    ego_spawn: int  # steps
    d_after: float  # m the ego log continues past its junction exit
    agents: dict[str, np.ndarray]  # per agent (ego first): path, t_spawn, cat, size and IDM fields


def _density(rng: np.random.Generator, tod: str) -> tuple[float, float]:
    lo, hi = {"day": (0.9, 1.35), "dusk": (0.85, 1.2), "night": (0.5, 0.85)}[tod]
    ped = {"day": 1.2, "dusk": 0.9, "night": 0.45}[tod]
    return float(rng.uniform(lo, hi)), float(ped * rng.uniform(0.7, 1.4))


def make_plan(rng: np.random.Generator, tab: Tables, index: int, inter: int, label: str, tod: str) -> Plan | None:
    opts = options_for(tab).get((inter, label), [])
    if not opts:
        return None
    ego_size = cat_mod.sample(rng, np.array([CAT["car"]]), np.array([13.9]))
    length = float(ego_size["length"][0])
    if label == "COV":
        # mostly an ego giving way (it then enters right behind the competitor)
        giving = [o for o in opts if o.ego_yields]
        leading = [o for o in opts if not o.ego_yields]
        opts = giving if giving and (not leading or rng.random() < 0.75) else leading or giving
    if label == "STP" and rng.random() < 0.75:
        straight = [o for o in opts if tab.path_move[o.path] == 0]
        opts = straight or opts
    for _ in range(6):
        opt = opts[rng.integers(len(opts))]
        p = opt.path
        v_des = float(min(0.93 * tab.path_limit[p], 15.0))
        spawn = int(rng.integers(*EGO_SPAWN))
        arrive = spawn + int(round(free_flow_time(tab, p, v_des, length / 2, tab.path_stop[p] - length / 2) / DT))
        offset = pick_timing(rng, tab, inter, label, opt, arrive)
        if offset is not None:
            break
    else:
        return None
    density, ped_density = _density(rng, tod)
    horizon = SIM_STEPS * DT
    bp, bt, bc = background(rng, tab, inter, horizon, density, ped_density)
    # keep the ego's lane clear ahead of it, so it meets the signal as timed
    # (turning lanes hold slow queues: clear them longer)
    clear = {"STR": 10.0, "STP": 14.0, "YLW": 14.0}.get(label, 22.0)
    behind = 4.0 if label == "COV" else 0.5  # COV: a gap behind the ego lets a competitor in
    lane0 = tab.seg_lane[p, 0]
    gone = (tab.seg_lane[bp, 0] == lane0) & (bt > spawn * DT - clear) & (bt < spawn * DT + behind)
    bp, bt, bc = bp[~gone], bt[~gone], bc[~gone]
    extra_p, extra_t, extra_c = [], [], []
    if label == "COV" and opt.ego_yields:
        # one or two competitors just ahead of the ego, and otherwise a quiet
        # spell on their approach, so the ego goes right behind them
        q = int(opt.partners[rng.integers(len(opt.partners))])
        tq = approach_time(tab)[q]
        legs = tab.path_leg[bp]
        t_at = bt + approach_time(tab)[bp]
        quiet = (legs == tab.path_leg[q]) & (tab.path_kind[bp] == 0) & (t_at > arrive * DT - 7.0) & \
            (t_at < arrive * DT + 7.0)
        bp, bt, bc = bp[~quiet], bt[~quiet], bc[~quiet]
        for lag in rng.uniform(-2.5, -0.3, int(rng.integers(1, 3))):
            extra_p.append(q)
            extra_t.append(arrive * DT - tq + lag)
            extra_c.append(CAT["car"] if rng.random() < 0.8 else CAT["van"])
    elif label == "COV":
        # competitors reaching their stop lines as the ego reaches its own:
        # they wait for the ego to pass, then go while it is still inside
        for q in rng.permutation(opt.partners)[:2]:
            tq = approach_time(tab)[q]
            for lag in (rng.uniform(-3.0, 0.0), rng.uniform(0.5, 3.0)):
                extra_p.append(int(q))
                extra_t.append(arrive * DT - tq + lag)
                extra_c.append(CAT["car"] if rng.random() < 0.8 else CAT["van"])
    elif label == "IPC":
        # people reaching the crosswalks the ego turns across as it arrives
        for _ in range(int(rng.integers(2, 5))):
            q = int(opt.partners[rng.integers(len(opt.partners))])
            extra_p.append(q)
            extra_t.append(arrive * DT + rng.uniform(-4.0, 0.5))
            extra_c.append(CAT["cyclist"] if (tab.path_outer[q] and rng.random() < 0.25) else CAT["pedestrian"])
    path = np.concatenate([[p], bp, np.asarray(extra_p, np.int64)]).astype(np.int64)
    t = np.concatenate([[spawn * DT], bt, np.asarray(extra_t, float)])
    cats = np.concatenate([[CAT["car"]], bc, np.asarray(extra_c, np.int64)]).astype(np.int64)
    keep = (t >= 0) & (t < horizon)
    keep[0] = True
    path, t, cats = path[keep], t[keep], cats[keep]
    par = cat_mod.sample(rng, cats, tab.path_limit[path])
    # cyclists ride slowly across crosswalks
    on_track = (cats == CAT["cyclist"]) & (tab.path_kind[path] == TRACK)
    par["v_des"][on_track] = rng.uniform(2.5, 3.5, on_track.sum())
    for key in ("length", "width", "height"):
        par[key][0] = ego_size[key][0]
    par["v_des"][0], par["a_max"][0], par["b_comf"][0], par["t_head"][0], par["s0"][0] = v_des, 2.0, 2.8, 1.3, 2.0
    agents = {"path": path, "t_spawn": np.round(t / DT).astype(np.int64), "cat": cats, **par}
    agents["ego"] = np.zeros(len(path), bool)
    agents["ego"][0] = True
    d_after = float(rng.uniform(18.0, 28.0))
    return Plan(index, inter, label, tod, offset, opt, spawn, d_after, agents)
