"""Traffic demand: who appears where and when (background agents).

Arrivals are Poisson per entry leg (motor traffic), per bike path and per
crosswalk track; each motor arrival picks a turning movement (straight
55 %, left 20 %, right 20 %, U-turn 5 % where allowed, renormalised over
what the leg offers), then a lane serving it, then a category.
"""

from __future__ import annotations

import numpy as np

from .agents import CAT, VEHICLE_MIX
from .network import BIKE, TRACK, VEHICLE
from .tables import Tables

#: Motor arrivals per entry lane and second, and the cap per leg.
LANE_RATE = 0.085
LEG_CAP = 0.36
BIKE_RATE = 0.022  # per bike path
PED_RATE = 0.011  # per crosswalk track
CROSS_CYCLIST_RATE = 0.004  # per outer crosswalk track
MOVE_SHARE = np.array([0.55, 0.20, 0.20, 0.05])  # straight, left, right, U-turn
_MIX_NAMES = list(VEHICLE_MIX)
_MIX_P = np.array([VEHICLE_MIX[k] for k in _MIX_NAMES])
_MIX_CODES = np.array([CAT[k] for k in _MIX_NAMES])


def _poisson_times(rng, rate: float, horizon: float) -> np.ndarray:
    n = rng.poisson(rate * horizon)
    return np.sort(rng.random(n) * horizon)


def background(rng: np.random.Generator, tab: Tables, inter: int, horizon_s: float, density: float,
               ped_density: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(path, spawn time s, category code) of background arrivals."""
    paths = tab.paths_of(inter)
    out_p, out_t, out_c = [], [], []
    kinds = tab.path_kind[paths]
    veh = paths[kinds == VEHICLE]
    for leg in np.unique(tab.path_leg[veh]):
        mine = veh[tab.path_leg[veh] == leg]
        lanes = len(np.unique(tab.seg_lane[mine, 1]))
        rate = min(LANE_RATE * lanes, LEG_CAP) * density
        t = _poisson_times(rng, rate, horizon_s)
        if not len(t):
            continue
        moves = tab.path_move[mine]
        share = np.array([MOVE_SHARE[m] if (moves == m).any() else 0.0 for m in range(4)])
        share /= share.sum()
        mv = rng.choice(4, size=len(t), p=share)
        # a lane (path) serving the movement, uniformly
        order = np.argsort(moves, kind="stable")
        counts = np.bincount(moves, minlength=4)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        pick = starts[mv] + (rng.random(len(t)) * counts[mv]).astype(np.int64)
        choice = mine[order[pick]]
        cat = _MIX_CODES[rng.choice(len(_MIX_NAMES), size=len(t), p=_MIX_P)]
        heavy = np.isin(cat, (CAT["bus"], CAT["truck"]))
        cat[heavy & (tab.path_move[choice] == 3)] = CAT["car"]  # no heavy U-turns
        out_p.append(choice), out_t.append(t), out_c.append(cat)
    for p in paths[kinds == BIKE]:
        t = _poisson_times(rng, BIKE_RATE * density, horizon_s)
        out_p.append(np.full(len(t), p)), out_t.append(t), out_c.append(np.full(len(t), CAT["cyclist"]))
    for p in paths[kinds == TRACK]:
        t = _poisson_times(rng, PED_RATE * ped_density, horizon_s)
        out_p.append(np.full(len(t), p)), out_t.append(t), out_c.append(np.full(len(t), CAT["pedestrian"]))
        if tab.path_outer[p]:
            t = _poisson_times(rng, CROSS_CYCLIST_RATE * ped_density, horizon_s)
            out_p.append(np.full(len(t), p)), out_t.append(t), out_c.append(np.full(len(t), CAT["cyclist"]))
    return np.concatenate(out_p), np.concatenate(out_t), np.concatenate(out_c)
