"""Hand-built StepLog-like episodes and scenarios for ``metrics.navsim`` tests.

Plain ``SimpleNamespace`` objects carrying exactly the fields
``navsim.episode_columns`` reads, so the tests do not depend on the
simulator (or on ``StepFacts`` gaining its NAVSIM fields).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np


def straight_log(n: int, dt: float = 0.1, speed: float = 10.0, **overrides) -> SimpleNamespace:
    """An ego driving along +x at ``speed`` m/s from x = 0 for ``n`` steps of
    ``dt`` s, every fact clean. ``overrides``: any field of the log, of
    ``facts`` (prefix ``f_``) or of ``facts.navsim`` (prefix ``nv_``)."""
    t = (np.arange(n) + 1) * dt
    facts = SimpleNamespace(
        agent_hit=np.zeros(n, bool),
        agent_hit_id=np.full(n, -1, np.int32),
        at_fault=np.zeros(n, bool),
        collision_type=np.full(n, -1, np.int32),
        layout_hit=np.zeros(n, bool),
        drivable_excess_m=np.zeros(n, np.float32),
        red_light=np.zeros(n, bool),
        lane_offset=np.zeros(n, np.float32),
        navsim=SimpleNamespace(
            ttc_violation=np.zeros(n, bool), in_junction=np.zeros(n, bool), oncoming=np.zeros(n, bool),
            lane_offset=np.zeros(n, np.float32),
        ),
    )
    log = SimpleNamespace(
        t=t,
        xy=np.stack([speed * t, np.zeros(n)], axis=-1),
        yaw=np.zeros(n),
        speed=np.full(n, speed),
        accel=np.zeros(n),
        steer=np.zeros(n),
        yaw_rate=np.zeros(n),
        active=np.ones(n, bool),
        facts=facts,
    )
    for k, v in overrides.items():
        if k.startswith("nv_"):
            setattr(facts.navsim, k[3:], np.asarray(v))
        elif k.startswith("f_"):
            setattr(facts, k[2:], np.asarray(v))
        else:
            setattr(log, k, np.asarray(v))
    return log


def straight_scenario(log_speed: float = 10.0, steps: int = 101, dt_log: float = 0.1, route_m: int = 300):
    """Logged ego along +x at ``log_speed`` m/s from x = 0 (``steps`` samples
    of ``dt_log``); a straight 1 m route along +x of ``route_m`` m."""
    tx = np.arange(steps) * dt_log * log_speed
    tracks = SimpleNamespace(
        xy=np.stack([tx, np.zeros(steps)], axis=-1)[None],
        yaw=np.zeros((1, steps)),
        valid=np.ones((1, steps), bool),
    )
    rx = np.arange(route_m + 1, dtype=np.float64)
    route = SimpleNamespace(xy=np.stack([rx, np.zeros_like(rx)], axis=-1), arc=rx, valid=np.ones(len(rx), bool))
    return SimpleNamespace(tracks=tracks, route=route, ego_index=0, dt_log=dt_log)
