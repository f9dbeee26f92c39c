"""Which scenario is what: split, behaviour label, intersection and
weather / time of day for each of the N scenario ids (N = 800 by default,
any positive multiple of 800: ``scale = N / 800``).

Label counts follow the source benchmark exactly: per 200 scenarios COV 36,
IPC 34, UT 5, YLW 17, STR 36, LFT 26, RT 24, STP 22; train holds N/2 (twice
those per 200, times ``scale``), val and test N/4 each. Ids are
``twin15_0000``.. (4 digits; more only when N > 10000, e.g. ``twin15_00000``
for N = 80000). With ``scale == 1`` every random draw is the one the
800-scenario suite has always made. Within each split the intersections share
the scenarios as evenly as possible (every intersection in every split),
and each label goes to intersections that can produce it (U-turns only
where they are allowed, and so on), rarest labels placed first.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from drivee2e_jax.records import SPLITS

PER_200 = {"COV": 36, "IPC": 34, "UT": 5, "YLW": 17, "STR": 36, "LFT": 26, "RT": 24, "STP": 22}
SPLIT_SCALE = {"train": 2, "val": 1, "test": 1}
WEATHER_P = {"clear": 0.5, "cloudy": 0.27, "rain": 0.16, "fog": 0.07}
TIME_P = {"day": 0.62, "dusk": 0.16, "night": 0.22}
NUM_SCENARIOS = 200 * sum(SPLIT_SCALE.values())


@dataclass
class Meta:
    index: int
    scenario_id: str
    split: str
    label: str
    inter: int
    weather: str
    time_of_day: str


def id_width(num_scenarios: int) -> int:
    """Digits of the scenario ids: 4, or as many as ``num_scenarios - 1`` needs above 10000."""
    return max(4, len(str(num_scenarios - 1)))


def assign(rng: np.random.Generator, capable: dict[str, set[int]], num_inters: int, scale: int = 1) -> list[Meta]:
    """One Meta per scenario index (``NUM_SCENARIOS * scale`` of them): splits,
    labels and intersections drawn from ``rng`` (see the module docstring)."""
    slots: list[tuple[str, str, int]] = []
    for split in SPLITS:
        n = 200 * SPLIT_SCALE[split] * scale
        quota = np.full(num_inters, n // num_inters)
        quota[rng.permutation(num_inters)[: n % num_inters]] += 1
        labels = [lab for lab, k in PER_200.items() for _ in range(k * SPLIT_SCALE[split] * scale)]
        # rarest capability first so every label finds room
        order = sorted(range(len(labels)), key=lambda i: (len(capable[labels[i]]), rng.random()))
        used: Counter = Counter()
        for i in order:
            lab = labels[i]
            cands = [j for j in capable[lab] if quota[j] > 0]
            if not cands:
                raise RuntimeError(f"no intersection left for a {lab} scenario in {split}")
            # spread each label over its intersections, then fill the emptiest
            key = {j: (used[(lab, j)], -quota[j]) for j in cands}
            best = min(key.values())
            j = int(rng.choice([j for j in cands if key[j] == best]))
            quota[j] -= 1
            used[(lab, j)] += 1
            slots.append((split, lab, j))
    perm = rng.permutation(len(slots))
    w_names, w_p = list(WEATHER_P), np.array(list(WEATHER_P.values()))
    t_names, t_p = list(TIME_P), np.array(list(TIME_P.values()))
    out = []
    width = id_width(len(slots))
    for idx, k in enumerate(perm):
        split, lab, j = slots[k]
        weather = w_names[rng.choice(len(w_names), p=w_p)]
        tod = t_names[rng.choice(len(t_names), p=t_p)]
        out.append(Meta(idx, f"twin15_{idx:0{width}d}", split, lab, j, weather, tod))
    return out
