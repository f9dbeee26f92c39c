"""Agent categories: plausible body sizes and driving styles.

Sizes are (length, width, height) ranges in metres; styles are the IDM
parameters: desired speed (a fraction of the lane's limit for motor
vehicles, absolute for the slow categories), maximum acceleration and
comfortable braking (m/s^2), time headway (s) and standstill gap (m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivee2e_jax.records import CATEGORIES

CAT = {name: i for i, name in enumerate(CATEGORIES)}


@dataclass(frozen=True)
class Style:
    size: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    speed: tuple[float, float]  # fraction of the limit (motor) or m/s (absolute=True)
    absolute: bool
    v_cap: float  # m/s
    a_max: tuple[float, float]
    b_comf: tuple[float, float]
    t_head: tuple[float, float]
    s0: float


STYLES: dict[str, Style] = {
    # name: Style(size l/w/h, speed, absolute, v_cap, a_max, b_comf, t_head, s0)
    "car": Style(((4.3, 4.9), (1.75, 1.9), (1.4, 1.6)), (0.88, 1.04), False, 17.0,
                 (1.6, 2.4), (2.2, 3.0), (1.1, 1.6), 2.0),
    "van": Style(((4.8, 5.5), (1.9, 2.05), (1.9, 2.3)), (0.85, 1.0), False, 16.0,
                 (1.4, 2.0), (2.2, 2.8), (1.2, 1.7), 2.0),
    "truck": Style(((6.5, 9.5), (2.3, 2.5), (2.8, 3.5)), (0.78, 0.9), False, 13.0,
                   (0.9, 1.3), (2.0, 2.5), (1.5, 2.0), 2.5),
    "bus": Style(((10.5, 12.0), (2.5, 2.55), (3.0, 3.3)), (0.75, 0.88), False, 12.0,
                 (0.9, 1.2), (2.0, 2.4), (1.6, 2.0), 2.5),
    "motorcycle": Style(((1.9, 2.2), (0.7, 0.9), (1.2, 1.5)), (0.9, 1.08), False, 16.0,
                        (2.0, 3.0), (2.5, 3.2), (1.0, 1.4), 1.5),
    "tricycle": Style(((2.6, 3.2), (1.1, 1.4), (1.5, 1.9)), (6.0, 9.0), True, 9.0,
                      (1.2, 1.8), (2.0, 2.6), (1.2, 1.6), 1.5),
    "pedestrian": Style(((0.45, 0.6), (0.5, 0.65), (1.5, 1.9)), (1.05, 1.6), True, 2.0,
                        (0.8, 1.2), (1.5, 2.0), (0.6, 0.9), 0.4),
    "cyclist": Style(((1.7, 1.9), (0.55, 0.7), (1.6, 1.8)), (3.5, 5.5), True, 7.0,
                     (1.0, 1.5), (2.0, 2.5), (1.0, 1.3), 1.0),
}

#: Motor traffic mix (shares sum to 1).
VEHICLE_MIX = {"car": 0.63, "van": 0.10, "truck": 0.06, "bus": 0.05, "motorcycle": 0.09, "tricycle": 0.07}


def sample(rng: np.random.Generator, cats: np.ndarray, limit: np.ndarray) -> dict[str, np.ndarray]:
    """Sizes and IDM parameters for agents of categories ``cats`` (codes)
    on lanes with speed limits ``limit`` (m/s)."""
    n = len(cats)
    out = {k: np.zeros(n) for k in ("length", "width", "height", "v_des", "a_max", "b_comf", "t_head", "s0")}
    u = rng.random((n, 7))
    for name, st in STYLES.items():
        m = cats == CAT[name]
        if not m.any():
            continue
        um = u[m]
        for j, key in enumerate(("length", "width", "height")):
            lo, hi = st.size[j]
            out[key][m] = lo + (hi - lo) * um[:, j]
        lo, hi = st.speed
        base = lo + (hi - lo) * um[:, 3]
        out["v_des"][m] = np.minimum(base if st.absolute else base * limit[m], st.v_cap)
        for j, key in ((4, "a_max"), (5, "b_comf"), (6, "t_head")):
            lo, hi = getattr(st, key)
            out[key][m] = lo + (hi - lo) * um[:, j]
        out["s0"][m] = st.s0
    return out
