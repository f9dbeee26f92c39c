"""Builders for the nuPlan CLS tests (``tests/metrics/test_nuplan.py``): one ego,
a few agents, straight lanes, and host-side fake episode logs / scenarios
(``SimpleNamespace`` with only the fields ``metrics.nuplan.episode_columns``
reads), plus a shapely oracle of nuPlan's constant-velocity TTC loop."""

from __future__ import annotations

import math
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
from shapely.geometry import Polygon

from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import EgoState


def ego_state(x: float, y: float, yaw: float, speed: float) -> EgoState:
    """An EgoState at (x, y) m, heading yaw rad, speed m/s (other fields 0)."""
    z = jnp.float32(0.0)
    return EgoState(xy=jnp.array([x, y], jnp.float32), yaw=jnp.float32(yaw), speed=jnp.float32(speed),
                    accel=z, steer=z, yaw_rate=z, t=z)


def agents(rows: list[tuple[float, float, float, float]]) -> AgentStates:
    """AgentStates from rows (x, y, yaw, speed along yaw); all valid."""
    a = np.asarray(rows, dtype=np.float32).reshape(-1, 4)
    vel = a[:, 3:4] * np.stack([np.cos(a[:, 2]), np.sin(a[:, 2])], axis=-1)
    return AgentStates(xy=jnp.asarray(a[:, :2]), yaw=jnp.asarray(a[:, 2]), vel=jnp.asarray(vel),
                       valid=jnp.ones(len(a), bool))


def shapely_box(x: float, y: float, yaw: float, length: float, width: float) -> Polygon:
    """The oriented box as a shapely polygon (nuPlan's ``OrientedBox.geometry``)."""
    c, s = math.cos(yaw), math.sin(yaw)
    pts = [(sx * length / 2, sy * width / 2) for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1))]
    return Polygon([(x + c * px - s * py, y + s * px + c * py) for px, py in pts])


def shapely_ttc(ego: tuple[float, float, float, float], ego_lw: tuple[float, float],
                tracks: list[tuple[float, float, float, float, float, float]],
                statics: list[list[tuple[float, float]]] = ()) -> float:
    """nuPlan's projection loop (``_compute_time_to_collision_at_timestamp``,
    time_to_collision_within_bound.py) with shapely boxes: ego (x, y, yaw,
    speed), tracks (x, y, yaw, speed, length, width), static objects as
    polygon vertex lists (speed 0: ``extract_tracks_info_excluding_collided_tracks``
    gives a non-``Agent`` speed 0); inf if none."""
    ex, ey, eh, ev = ego
    fixed = [Polygon(p) for p in statics]
    for k, t in enumerate(np.arange(0.1, 3.0, 0.1), start=1):
        eb = shapely_box(ex + k * 0.1 * ev * math.cos(eh), ey + k * 0.1 * ev * math.sin(eh), eh, *ego_lw)
        for x, y, h, v, ln, w in tracks:
            if eb.intersects(shapely_box(x + k * 0.1 * v * math.cos(h), y + k * 0.1 * v * math.sin(h), h, ln, w)):
                return float(t)
        if any(eb.intersects(p) for p in fixed):
            return float(t)
    return math.inf


def straight_lanes(specs: list[tuple[float, float]], half_len: int = 50):
    """Lanes along x at y = offset, running +x (direction +1) or -x (-1), 1 m
    spacing, width 3.5 m: (xy (M, P, 2), point_valid, valid, width) jnp arrays."""
    xs = np.arange(-half_len, half_len + 1, dtype=np.float32)
    lanes = [np.stack([xs if d > 0 else xs[::-1], np.full_like(xs, y)], axis=-1) for y, d in specs]
    xy = jnp.asarray(np.stack(lanes))
    m, p = xy.shape[:2]
    return xy, jnp.ones((m, p), bool), jnp.ones(m, bool), jnp.full(m, 3.5, jnp.float32)


def fake_log(n_active: int, n_pad: int, dt: float, *, x_end: float, speed: float, speed_limit,
             layout_hit=None, drivable_excess=None, oncoming=None, ttc=None):
    """A straight drive along +x: ``n_active`` steps ending at x_end, then
    ``n_pad`` inactive steps; numpy (T,) leaves as ``sim.StepLog``."""
    n = n_active + n_pad
    k = np.arange(1, n + 1)
    act = k <= n_active
    x = np.where(act, x_end * k / n_active, x_end)
    full = lambda v, fill: np.concatenate([np.broadcast_to(np.asarray(v, np.float64), (n_active,)),  # noqa: E731
                                           np.full(n_pad, fill)])
    facts = SimpleNamespace(
        agent_hit=np.zeros(n, bool), agent_hit_id=np.full(n, -1), agent_hit_category=np.zeros(n, int),
        at_fault=np.zeros(n, bool),
        layout_hit=full(np.zeros(n_active) if layout_hit is None else layout_hit, 0).astype(bool),
        drivable_excess_m=full(0.0 if drivable_excess is None else drivable_excess, 9.0),
        speed_limit=full(speed_limit, 0.0),
        nuplan=SimpleNamespace(ttc_s=full(np.inf if ttc is None else ttc, 0.0),
                               oncoming_m=full(0.0 if oncoming is None else oncoming, 99.0)),
    )
    return SimpleNamespace(t=k * dt, xy=np.stack([x, np.zeros(n)], -1), yaw=np.zeros(n),
                           speed=full(speed, 0.0), accel=np.zeros(n), steer=np.zeros(n), yaw_rate=np.zeros(n), active=act,
                           facts=facts)


def fake_scenario(expert_x, dt_log: float, route_len: int = 40):
    """Ego row 0 logged at x = expert_x[k] (y 0) at t = k dt_log; a straight
    route along +x from 0 to route_len m at 1 m."""
    ex = np.asarray(expert_x, dtype=np.float64)
    xy = np.zeros((2, len(ex), 2))
    xy[0, :, 0] = ex
    rx = np.arange(route_len + 1, dtype=np.float64)
    return SimpleNamespace(
        tracks=SimpleNamespace(xy=xy, valid=np.ones((2, len(ex)), bool)),
        ego_index=np.int32(0), dt_log=np.float32(dt_log), num_steps=np.int32(len(ex)),
        route=SimpleNamespace(xy=np.stack([rx, np.zeros_like(rx)], -1), valid=np.ones(len(rx), bool)),
    )
