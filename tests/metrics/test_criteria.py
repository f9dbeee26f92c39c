"""Per-tick criteria: reference cases CR-01 / CR-02 / CR-06 driven tick by tick
through ``lax.scan``, plus hand-built edge cases (strict inequalities,
rounding, window limits, memories).

The ``run_cr0x`` drivers take a case dict (metric_cases.json format); they
live in ``tests/helpers/metric_cases/criteria.py``, shared with
``test_metric_cases.py``, which feeds them the full shared file.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.metrics import criteria as cr
from tests.helpers.metric_cases import subset_case
from tests.helpers.metric_cases.criteria import _CR01_TICKS, _rc_scan_impl, run_cr01, run_cr02, run_cr06, straight_route

# ---------------------------------------------------------------------------
# Jitted scans, one trace each (fixed shapes; batched with vmap); the worked
# cases' scans are in tests/helpers/metric_cases/criteria.py
# ---------------------------------------------------------------------------

_rc_scan = jax.jit(_rc_scan_impl)


# ---------------------------------------------------------------------------
# CR-01 route completion
# ---------------------------------------------------------------------------


def test_cr01_route_completion():
    run_cr01(subset_case("CR-01"))


# ---------------------------------------------------------------------------
# CR-02 minimum-speed checkpoints
# ---------------------------------------------------------------------------


def test_cr02_min_speed():
    run_cr02(subset_case("CR-02"))


# ---------------------------------------------------------------------------
# CR-06 collision dedup
# ---------------------------------------------------------------------------


def test_cr06_collision_dedup():
    run_cr06(subset_case("CR-06"))


# ---------------------------------------------------------------------------
# Route completion edge cases
# ---------------------------------------------------------------------------


def _walk(route_points: int, target, threshold=99.0, step=0.5, ticks=2100, pad_to=1024):
    """Ego walks along +x (at the target's y) in ``step`` m ticks to ``target``, then stays."""
    tx, ty = target
    x = np.minimum(step * np.arange(ticks), tx)
    xy = np.stack([x, np.full_like(x, ty)], -1).astype(np.float32)
    carry, values = _rc_scan(straight_route(route_points, pad_to), jnp.asarray(xy), threshold)
    return carry, np.asarray(values)


def _rc_steps(route, points, threshold=99.0):
    carry, values = _rc_scan(route, jnp.asarray(np.asarray(points, np.float32)), threshold)
    return carry, np.asarray(values)


def test_rc_strictly_ahead_and_window():
    route = straight_route(11, pad_to=16)
    # Exactly on point 2: not ahead of it (dot = 0).
    carry, _ = _rc_steps(route, [(2.0, 0.0), (3.0, 0.0)])
    assert int(carry.index) == 2
    # A 10 m jump moves the index by at most 2 points per tick.
    for n, want in ((1, 2), (2, 4), (3, 6)):
        carry, _ = _rc_steps(route, [(9.5, 0.0)] * n)
        assert int(carry.index) == want


def test_rc_rounding_two_decimals_and_monotone():
    route = straight_route(4, pad_to=8)  # 3 m: P = 0, 33.33.., 66.66.., 100
    _, values = _rc_steps(route, [(1.5, 0.0), (2.5, 0.0), (0.0, 0.0)])
    assert list(values) == pytest.approx([33.33, 66.67, 66.67], abs=1e-5)


def test_rc_threshold_and_distance_are_strict():
    # 1000 m route: P_i = i / 10. 99.1 % and 8.5 m from the end: complete.
    assert bool(_walk(1001, (991.5, 0.0))[0].completed)
    # 99.0 % is not > 99.
    assert not bool(_walk(1001, (990.5, 0.0))[0].completed)
    # 99.1 % but exactly 10 m from the last point (8-6-10 triangle): not < 10 ...
    carry, _ = _walk(1001, (992.0, 6.0))
    assert float(carry.value) == pytest.approx(99.1) and not bool(carry.completed)
    # ... 5.9 m off the route is.
    assert bool(_walk(1001, (992.0, 5.9))[0].completed)
    # DriveE2E threshold 97: 98 % completes, exactly 97 % does not; LB's 99 does not at 98 %.
    assert bool(_walk(101, (98.5, 0.0), threshold=97.0)[0].completed)
    assert not bool(_walk(101, (97.5, 0.0), threshold=97.0)[0].completed)
    assert not bool(_walk(101, (98.5, 0.0), threshold=99.0)[0].completed)


def test_rc_frozen_after_completion():
    route = straight_route(101, pad_to=128)
    pts = [(min(0.5 * k, 100.5), 0.0) for k in range(300)] + [(0.0, 50.0)] * 3
    carry, values = _rc_steps(route, pts)
    assert bool(carry.completed) and float(carry.value) == 100.0
    first = int(np.argmax(values == 100.0))
    assert 0 < first < 300 and np.all(values[first:] == 100.0)


def test_rc_padding_uses_last_valid_point():
    # 50 m route in a 1024-point buffer whose padding continues along +x.
    carry, _ = _walk(51, (55.0, 0.0))
    assert bool(carry.completed) and int(carry.index) == 50


# ---------------------------------------------------------------------------
# InRouteTest
# ---------------------------------------------------------------------------


_in_route_step = jax.jit(cr.in_route_update)
_min_speed_step = jax.jit(cr.min_speed_update)
_blocked_step = jax.jit(cr.blocked_update)
_collision_step = jax.jit(cr.collision_update)


def _in_route_run(route, points):
    c = cr.in_route_init()
    fired = []
    for p in points:
        c, f = _in_route_step(c, route, jnp.asarray(p, jnp.float32))
        fired.append(bool(f))
    return c, fired


def test_in_route_max_distance_is_strict():
    route = straight_route(101, pad_to=128)
    assert not bool(_in_route_run(route, [(0.0, 29.99)])[0].deviated)
    c, fired = _in_route_run(route, [(0.0, 30.0), (0.0, 0.0)])
    assert bool(c.deviated) and fired == [True, False]


def test_in_route_out_of_safe_band_arc_over_30_percent():
    route = straight_route(101, pad_to=128)  # 100 m
    # Drive parallel at y = 20 (>= 15, < 30): every advanced metre is "out".
    pts = [(float(x), 20.0) for x in range(0, 60)]
    c, fired = _in_route_run(route, pts)
    # Out total reaches 31 m (> 30 %) when the closest index becomes 31.
    assert fired.index(True) == 31 and bool(c.deviated)
    # At y = 14.9 (safe band) nothing accumulates.
    c, fired = _in_route_run(route, [(float(x), 14.9) for x in range(0, 60)])
    assert not any(fired) and float(c.out_distance) == 0.0


def test_in_route_exactly_30_percent_does_not_deviate():
    route = straight_route(101, pad_to=128)
    c, fired = _in_route_run(route, [(float(x), 20.0) for x in range(0, 31)] + [(30.0, 0.0)] * 3)
    assert float(c.out_distance) == 30.0 and not any(fired)


def test_in_route_window_limits_closest_point():
    route = straight_route(101, pad_to=128)
    # A 50 m jump: the window i..i+5 only reaches point 5, 45 m away -> deviation.
    c, fired = _in_route_run(route, [(50.0, 0.0)])
    assert fired == [True] and int(c.index) == 5


def test_in_route_tie_goes_to_later_point():
    route = straight_route(11, pad_to=16)
    c, _ = _in_route_run(route, [(0.5, 0.0)])
    assert int(c.index) == 1


# ---------------------------------------------------------------------------
# OutsideRouteLanesTest accounting
# ---------------------------------------------------------------------------


def test_outside_lanes_accumulation_and_window():
    route = straight_route(101, pad_to=128)
    c = cr.outside_lanes_init()
    for x, off in [(1.5, False), (3.5, True), (5.5, True), (7.5, False), (30.0, False)]:
        c = cr.outside_lanes_update(c, route, jnp.asarray([x, 0.0]), jnp.asarray(off))
    # Window i+1..i+3: the 30 m jump passes only points 8..10.
    assert int(c.index) == 10
    assert float(c.traversed) == 10.0 and float(c.wrong) == 4.0
    assert bool(cr.outside_lanes_event(c))
    assert float(cr.outside_lanes_percentage(c)) == pytest.approx(40.0)


def test_outside_lanes_no_event_when_never_off():
    route = straight_route(11, pad_to=16)
    c = cr.outside_lanes_update(cr.outside_lanes_init(), route, jnp.asarray([2.5, 0.0]), jnp.asarray(False))
    assert not bool(cr.outside_lanes_event(c)) and float(cr.outside_lanes_percentage(c)) == 0.0


# ---------------------------------------------------------------------------
# CollisionTest dedup edge cases
# ---------------------------------------------------------------------------


def _collide(c, t, x, oid=10, cls=cr.CollisionClass.VEHICLE, speed=5.0, hit=True):
    return _collision_step(
        c, jnp.asarray([hit]), jnp.asarray([oid]), jnp.asarray([cls]), jnp.asarray([x, 0.0]), jnp.float32(speed),
        jnp.float32(t),
    )


def test_collision_same_id_window_is_5s_inclusive():
    c, k = _collide(cr.collision_init(), 1.0, 0.0)
    assert bool(k.counted)
    c5, k5 = _collide(c, 6.0, 50.0)  # exactly 5 s later, far away: still the same collision
    assert not bool(k5.counted)
    c6, k6 = _collide(c, 6.5, 50.0)
    assert bool(k6.counted)


def test_collision_location_radius_and_forgetting():
    c, _ = _collide(cr.collision_init(), 1.0, 0.0, oid=1)
    _, k = _collide(c, 2.0, 5.0, oid=2)  # exactly 5 m: dropped (<=)
    assert not bool(k.counted)
    _, k = _collide(c, 2.0, 5.01, oid=2)
    assert bool(k.counted)
    # Once the ego was > 5 m away the location is forgotten, even if it comes back.
    c2, _ = _collide(c, 1.5, 6.0, oid=0, hit=False)
    _, k = _collide(c2, 2.0, 1.0, oid=2)
    assert bool(k.counted)


def test_collision_min_speed_is_strict():
    _, k = _collide(cr.collision_init(), 1.0, 0.0, speed=0.1)
    assert bool(k.counted)
    _, k = _collide(cr.collision_init(), 1.0, 0.0, speed=0.0999)
    assert not bool(k.counted)


def test_collision_static_refreshes_time_but_not_id():
    c, _ = _collide(cr.collision_init(), 1.0, 0.0, oid=10)
    c, k = _collide(c, 4.0, 20.0, oid=0, cls=cr.CollisionClass.LAYOUT)
    assert bool(k.counted) and int(c.last_id) == 10
    # Same vehicle at t = 8: 7 s after it was hit, but 4 s after the last counted collision.
    _, k = _collide(c, 8.0, 40.0, oid=10)
    assert not bool(k.counted)
    # Repeated static contacts far apart all count (id 0 is never remembered).
    _, k = _collide(c, 4.5, 60.0, oid=0, cls=cr.CollisionClass.LAYOUT)
    assert bool(k.counted)


def test_collision_other_class_counts_without_event():
    c, k = _collide(cr.collision_init(), 1.0, 0.0, oid=0, cls=cr.CollisionClass.OTHER)
    assert bool(k.counted) and not bool(k.event) and int(c.count) == 1


def test_collision_several_contacts_in_one_tick():
    c, _ = _collide(cr.collision_init(), 1.0, 0.0, oid=7)
    c = c.replace(has_location=jnp.asarray(False))  # only the id memory remains
    hit = jnp.asarray([True, True, True])
    ids = jnp.asarray([7, 3, 0])
    cls = jnp.asarray([1, 0, 2])
    c2, k = cr.collision_update(c, hit, ids, cls, jnp.asarray([10.0, 0.0]), jnp.float32(5.0), jnp.float32(2.0))
    # Contact 0 is the remembered id; contact 1 counts; contact 2 is then within 5 m.
    assert int(k.index) == 1 and int(k.cls) == 0 and int(c2.count) == int(c.count) + 1
    assert int(c2.last_id) == 3


# ---------------------------------------------------------------------------
# ActorBlockedTest, RouteTimeoutBehavior
# ---------------------------------------------------------------------------


def _blocked_run(times, speeds, max_time=60.0):
    c = cr.blocked_init()
    fired = []
    for t, v in zip(times, speeds):
        c, f = _blocked_step(c, jnp.float32(v), jnp.float32(t), max_time)
        fired.append(bool(f))
    return c, fired


def test_blocked_strictly_more_than_max_time():
    times = 0.5 * np.arange(1, 130)  # 0.5 .. 64.5 s, stopped throughout
    c, fired = _blocked_run(times, np.zeros_like(times))
    # last_valid = 0.5 (first tick); 60.5 - 0.5 = 60 is not > 60; 61.0 is.
    assert times[fired.index(True)] == 61.0 and sum(fired) == 1


def test_blocked_moving_resets_and_zero_time_rearms():
    times = 0.5 * np.arange(1, 200)
    speeds = np.where(times == 30.0, 0.1, 0.0)  # 0.1 m/s is not "slow"
    _, fired = _blocked_run(times, speeds)
    assert times[fired.index(True)] == 90.5
    # A first tick at t = 0 leaves the timer unset (the source tests truthiness).
    _, fired = _blocked_run([0.0, 1.0, 61.0, 61.5], [0.0] * 4)
    assert fired == [False, False, False, True]


def test_route_timeout_budget_and_window():
    route = straight_route(101, pad_to=128)
    c = cr.route_timeout_init()
    # Limit 10 m/s: each metre passed adds 1 / (0.1 * 10) = 1 s. Jump 50 m: window i..i+3.
    c, _ = cr.route_timeout_update(c, route, jnp.asarray([50.0, 0.0]), jnp.float32(10.0), jnp.float32(0.05))
    assert int(c.index) == 3 and float(c.budget) == pytest.approx(303.0)
    c, f = cr.route_timeout_update(c, route, jnp.asarray([3.5, 0.0]), jnp.float32(10.0), jnp.float32(303.05))
    assert not bool(f)  # elapsed 303.0 is not > 303
    c, f = cr.route_timeout_update(c, route, jnp.asarray([3.5, 0.0]), jnp.float32(10.0), jnp.float32(303.1))
    assert bool(f) and bool(c.timed_out)


# ---------------------------------------------------------------------------
# MinimumSpeedRouteTest edge cases
# ---------------------------------------------------------------------------


def _ms_walk(route, xs, checkpoints=4, bg_present=True, bg=10.0, ego=5.0):
    c = cr.min_speed_init(checkpoints)
    for x in xs:
        c, _ = _min_speed_step(
            c, route, jnp.asarray([x, 0.0]), jnp.float32(ego), jnp.asarray(bg_present), jnp.float32(bg)
        )
    return c


def test_min_speed_close_is_strict():
    route = straight_route(101, pad_to=128)  # L / 4 = 25 m
    c = _ms_walk(route, np.arange(0.5, 25.6, 0.5))  # index reaches 25: 25 - 0 is not > 25
    assert int(c.count) == 0
    c = _ms_walk(route, np.arange(0.5, 26.6, 0.5))
    assert int(c.count) == 1 and float(c.values[0]) == 50.0


def test_min_speed_without_samples_or_zero_background_is_100():
    route = straight_route(101, pad_to=128)
    c = _ms_walk(route, np.arange(0.5, 26.6, 0.5), bg_present=False)
    assert float(c.values[0]) == 100.0
    c = _ms_walk(route, np.arange(0.5, 26.6, 0.5), bg=0.0)
    assert float(c.values[0]) == 100.0


def test_min_speed_final_checkpoint_needs_more_than_95_percent():
    route = straight_route(101, pad_to=128)
    c = _ms_walk(route, np.arange(0.5, 95.6, 0.5))  # index 95: 0.95 is not > 0.95
    n = int(c.count)
    c2, (closed, _) = cr.min_speed_finalize(c, route)
    assert not bool(closed) and int(c2.count) == n
    c = _ms_walk(route, np.arange(0.5, 96.6, 0.5))
    c2, (closed, _) = cr.min_speed_finalize(c, route)
    assert bool(closed) and int(c2.count) == int(c.count) + 1
    assert float(cr.min_speed_actual_value(cr.min_speed_init(4))) == 100.0


def test_min_speed_rounds_to_two_decimals():
    route = straight_route(101, pad_to=128)
    c = _ms_walk(route, np.arange(0.5, 26.6, 0.5), ego=1.0, bg=3.0)
    assert float(c.values[0]) == pytest.approx(33.33, abs=1e-5)


# ---------------------------------------------------------------------------
# Red-light memory
# ---------------------------------------------------------------------------


def test_red_light_not_the_light_last_run():
    c = cr.red_light_init()
    seq = [[True, False], [True, False], [False, True], [True, False], [True, True], [True, True]]
    got = []
    for ran in seq:
        c, ev = cr.red_light_update(c, jnp.asarray(ran))
        got.append([bool(e) for e in ev])
    assert got == [
        [True, False],  # light 0 run
        [False, False],  # light 0 again: suppressed
        [False, True],  # light 1
        [True, False],  # light 0 is no longer the last one
        [False, True],  # last = 0: light 0 skipped, light 1 fires
        [True, True],  # last = 1: light 0 fires first, then 1 is no longer the last
    ]
    assert int(c.last) == 1


# ---------------------------------------------------------------------------
# Batching and dtype
# ---------------------------------------------------------------------------


def test_single_vs_batched_and_float64_agree():
    runs = [(101, 99.6), (101, 40.2), (51, 50.7)]
    routes = [straight_route(n, pad_to=128) for n, _ in runs]
    tracks = []
    for _, stop in runs:
        x = np.minimum(0.25 * np.arange(_CR01_TICKS), stop)
        tracks.append(np.stack([x, np.zeros_like(x)], -1).astype(np.float32))
    batch = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *routes)
    bc, bv = jax.jit(jax.vmap(_rc_scan_impl, in_axes=(0, 0, None)))(batch, jnp.asarray(np.stack(tracks)), 99.0)
    for i, (n, _) in enumerate(runs):
        sc, sv = _rc_scan(routes[i], jnp.asarray(tracks[i]), 99.0)
        assert np.array_equal(np.asarray(sv), np.asarray(bv[i]))
        assert bool(sc.completed) == bool(bc.completed[i])
        with jax.enable_x64(True):
            c64, v64 = jax.jit(_rc_scan_impl)(
                straight_route(n, pad_to=128, dtype=np.float64), jnp.asarray(tracks[i], jnp.float64), 99.0
            )
            assert v64.dtype == jnp.float64
            np.testing.assert_allclose(np.asarray(v64), np.asarray(sv), atol=1e-4)
