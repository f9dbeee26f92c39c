"""Worked cases of the per-tick criteria (``drivee2e_jax.metrics.criteria``):
CR-01 / CR-02 / CR-06 driven tick by tick through jitted ``lax.scan``s (one
trace each), from a case dict of ``metric_cases.json``."""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.metrics import criteria as cr
from drivee2e_jax.metrics.driving_score import RouteOutcome, ScoreConfig, route_score
from drivee2e_jax.types import Route


def straight_route(n_points: int, pad_to: int, spacing: float = 1.0, dtype=np.float32) -> Route:
    """Route along +x, ``n_points`` valid points ``spacing`` apart, padded."""
    x = np.arange(pad_to, dtype=dtype) * spacing
    valid = np.arange(pad_to) < n_points
    xy = np.stack([x, np.zeros_like(x)], -1)
    return Route(
        xy=jnp.asarray(xy),
        arc=jnp.asarray(x),
        command=jnp.zeros((pad_to,), jnp.int32),
        valid=jnp.asarray(valid),
        length=jnp.asarray((n_points - 1) * spacing, dtype),
    )


def tol(case) -> float:
    t = case["tolerance"]
    return 0.0 if t.get("exact") else float(t["abs"])


def _rc_scan_impl(route: Route, ego_xy, threshold):
    def body(c, xy):
        c, _ = cr.route_completion_update(c, route, xy, threshold)
        return c, c.value

    return jax.lax.scan(body, cr.route_completion_init(ego_xy.dtype), ego_xy)


@jax.jit
@chex.assert_max_traces(n=1)
def _scan_route_completion_batch(route: Route, ego_xy, threshold):
    return jax.vmap(_rc_scan_impl, in_axes=(0, 0, None))(route, ego_xy, threshold)


@jax.jit
@chex.assert_max_traces(n=1)
def _scan_min_speed(carry0: cr.MinSpeedCarry, route: Route, ego_xy, speed, bg_present, bg_speed, active):
    def body(c, x):
        xy, v, bp, bs, act = x
        new, (closed, _) = cr.min_speed_update(c, route, xy, v, bp, bs)
        new = jax.tree_util.tree_map(lambda a, b: jnp.where(act, a, b), new, c)
        return new, closed & act

    c, closed = jax.lax.scan(body, carry0, (ego_xy, speed, bg_present, bg_speed, active))
    c, _ = cr.min_speed_finalize(c, route)
    return c, cr.min_speed_actual_value(c)


@jax.jit
@chex.assert_max_traces(n=1)
def _scan_collisions(hit, other_id, other_class, ego_xy, ego_speed, t):
    def body(c, x):
        c, tick = cr.collision_update(c, *x)
        return c, tick

    return jax.lax.scan(body, cr.collision_init(), (hit, other_id, other_class, ego_xy, ego_speed, t))


_CR01_RUNS = {"a": (100, 55.3), "b": (200, 198.5), "c": (200, 199.1)}  # route length m, stop x m


_CR01_TICKS = 1000  # 0.25 m per tick (5 m/s at 0.05 s): reaches 200 m after 800


def run_cr01(case: dict) -> None:
    """CR-01: straight route, 1 m spacing; ego from x=0 along +x at 5 m/s
    (0.05 s ticks), stops at a given x and stays. All three runs in one vmap."""
    names = sorted(_CR01_RUNS)
    routes, tracks = [], []
    for name in names:
        length, stop = _CR01_RUNS[name]
        assert case["input"]["runs"][name]["route_length_m"] == length
        routes.append(straight_route(length + 1, pad_to=256))
        x = np.minimum(0.25 * np.arange(_CR01_TICKS), stop)
        tracks.append(np.stack([x, np.zeros_like(x)], -1).astype(np.float32))
    route = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *routes)
    carry, values = _scan_route_completion_batch(route, jnp.asarray(np.stack(tracks)), 99.0)
    values = np.asarray(values)
    assert np.all(np.diff(values, axis=1) >= 0), "RC must never decrease"
    for i, name in enumerate(names):
        want = case["expected"][name]
        assert float(carry.value[i]) == pytest.approx(want["RC"], abs=tol(case)), name
        assert bool(carry.completed[i]) == want["completed"], name


_CR02_TICKS = 320


def _cr02_ticks():
    """Each tick: v = 5 m/s if x < 50 else 10, x += v * 0.05; the criterion
    sees the new x and v; stop once x >= 100.5. Padded to a fixed length."""
    xs, vs, x = [], [], 0.0
    while True:
        v = 5.0 if x < 50 else 10.0
        x += v * 0.05
        xs.append(x)
        vs.append(v)
        if x >= 100.5:
            break
    n = len(xs)
    assert n <= _CR02_TICKS
    pad = _CR02_TICKS - n
    xy = np.stack([np.array(xs + [xs[-1]] * pad), np.zeros(_CR02_TICKS)], -1).astype(np.float32)
    speed = np.array(vs + [0.0] * pad, np.float32)
    active = np.arange(_CR02_TICKS) < n
    return xy, speed, active


def run_cr02(case: dict) -> None:
    """CR-02: both background vehicles at 10 m/s; LB 2.0 (4 checkpoints,
    events < 100 %) and Bench2Drive (20 checkpoints, every checkpoint)."""
    route = straight_route(101, pad_to=128)
    xy, speed, active = _cr02_ticks()
    bg_present = np.ones(_CR02_TICKS, bool)
    bg_speed = np.full(_CR02_TICKS, 10.0, np.float32)  # mean of two vehicles at 10 m/s
    exp = case["expected"]
    for variant, cfg in (("lb20_checkpoints_4", ScoreConfig.lb20()), ("b2d_checkpoints_20", ScoreConfig.b2d())):
        carry0 = cr.min_speed_init(cfg.min_speed_checkpoints, capacity=20)
        carry, actual = _scan_min_speed(carry0, route, xy, speed, bg_present, bg_speed, active)
        values = np.asarray(carry.values)[np.asarray(carry.valid)]
        events = values if cfg.min_speed_record_all else values[values < 100]
        np.testing.assert_allclose(events, exp[variant]["min_speed_event_percentages"], atol=tol(case), rtol=0)
        key = "criterion_actual_value" if cfg.min_speed_record_all else "criterion_actual_value_mean_of_all_checkpoints"
        assert float(actual) == pytest.approx(exp[variant][key], abs=tol(case))
        if variant == "lb20_checkpoints_4":
            with jax.enable_x64(True):
                outcome = RouteOutcome.empty(20, jnp.float64).replace(
                    route_completion=jnp.float64(100.0),
                    min_speed_pct=jnp.asarray(np.asarray(carry.values), jnp.float64),
                    min_speed_valid=carry.valid,
                )
                score = route_score(outcome, ScoreConfig.lb20())
                assert float(score.infraction_penalty) == pytest.approx(exp["lb20_IS_from_these_events"], abs=tol(case))


_EVENT_CLASS = {
    "COLLISION_PEDESTRIAN": cr.CollisionClass.PEDESTRIAN,
    "COLLISION_VEHICLE": cr.CollisionClass.VEHICLE,
    "COLLISION_STATIC": cr.CollisionClass.LAYOUT,
}


def carla_collision_class(type_id: str) -> int:
    """The caller's classification of a CARLA ``type_id`` (CollisionTest order)."""
    if ("static" in type_id or "traffic" in type_id) and "sidewalk" not in type_id:
        return cr.CollisionClass.LAYOUT
    if "vehicle" in type_id:
        return cr.CollisionClass.VEHICLE
    if "walker" in type_id:
        return cr.CollisionClass.PEDESTRIAN
    return cr.CollisionClass.OTHER


def run_cr06(case: dict) -> None:
    """CR-06: scripted sensor events; the criterion ticks every 0.05 s in
    between. The ego moves on y = 0, linearly between the scripted x's, at
    5 m/s except at the scripted events' own speeds."""
    seq = case["input"]["sequence"]
    dt, n = 0.05, int(round(seq[-1]["t_s"] / 0.05))
    t = dt * np.arange(1, n + 1)
    x = np.interp(t, [0.0] + [e["t_s"] for e in seq], [0.0] + [e["ego_x"] for e in seq])
    speed = np.full(n, 5.0)
    hit, oid, ocls = np.zeros((n, 1), bool), np.zeros((n, 1), np.int32), np.zeros((n, 1), np.int32)
    for e in seq:
        k = int(round(e["t_s"] / dt)) - 1
        hit[k, 0], oid[k, 0], ocls[k, 0] = True, e["other_id"], carla_collision_class(e["other_type"])
        speed[k], x[k] = e["ego_speed"], e["ego_x"]
    xy = np.stack([x, np.zeros(n)], -1).astype(np.float32)
    carry, ticks = _scan_collisions(hit, oid, ocls, xy, speed.astype(np.float32), t.astype(np.float32))
    counted = np.asarray(ticks.counted)
    events = np.asarray(ticks.cls)[np.asarray(ticks.event)]
    exp = case["expected"]
    assert list(events) == [_EVENT_CLASS[name] for name in exp["events_in_order"]]
    assert int(carry.count) == exp["criterion_count_incl_untyped"] == counted.sum()
    with jax.enable_x64(True):
        outcome = RouteOutcome.empty(1, jnp.float64).replace(
            route_completion=jnp.float64(100.0),
            collisions_pedestrian=jnp.int32((events == cr.CollisionClass.PEDESTRIAN).sum()),
            collisions_vehicle=jnp.int32((events == cr.CollisionClass.VEHICLE).sum()),
            collisions_layout=jnp.int32((events == cr.CollisionClass.LAYOUT).sum()),
        )
        assert float(route_score(outcome, ScoreConfig.lb20()).infraction_penalty) == exp["IS_lb20"]
