"""Leaderboard criteria as pure per-tick JAX functions (one route, unbatched).

Each criterion of CARLA's scenario_runner (``atomic_criteria.py`` and
``timer.py``, branch ``leaderboard-2.0``; see ``shared/reference/METRICS.md``
section 1) becomes a typed carry plus two pure functions::

    carry = xxx_init(...)
    carry, out = xxx_update(carry, <this tick's facts>, ...)

No Python branching on traced values and fixed shapes throughout, so every
update can run inside ``jax.lax.scan`` and be ``jax.vmap``-ed by the caller.
The route is passed to every update (not stored in the carry) so the static
polyline is not threaded through the scan. The simulator computes the raw
geometric facts (``infractions.py``); these functions only keep the
leaderboard's bookkeeping: windows, strict inequalities, rounding, memories.

Route conventions (``types.Route``): points ``xy (R, 2)`` with a valid prefix,
``arc (R,)`` cumulative length from the first point. CARLA's waypoint forward
vector (the lane tangent) is taken from the polyline by central differences
(one-sided at both ends). Distances are 2-D (CARLA's are 3-D; our world is
flat).

Tick order inside one CARLA tree tick is irrelevant between criteria (each
reads the same actor snapshot and all are ticked before the tree stops), so
the caller may update them in any order. Once a terminating criterion fires
(route completed, deviation, blocked, route timeout) the route ends after that
tick; every update below freezes its carry once its own criterion has fired.

Stop signs (``RunningStopTest``) are not implemented: the twin15
intersections are all signalised, so the criterion could never fire. A
``stop_infraction`` count can still be passed to ``driving_score``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from drivee2e_jax.types import CollisionClass, Route

Array = jnp.ndarray

# -- scenario_runner constants (names follow the source) ---------------------
RC_WINDOW = 2  # RouteCompletionTest.WINDOWS_SIZE: checks i .. i + 2
RC_DISTANCE_M = 10.0  # RouteCompletionTest.DISTANCE_THRESHOLD (strict <)
RC_THRESHOLD_LB = 99.0  # RouteCompletionTest.PERCENTAGE_THRESHOLD (strict >)
IN_ROUTE_WINDOW = 5  # InRouteTest.WINDOWS_SIZE: checks i .. i + 5
IN_ROUTE_MAX_M = 30.0  # offroad_max in route_scenario.py
IN_ROUTE_MAX_PCT = 30.0  # InRouteTest.MAX_ROUTE_PERCENTAGE (strict >)
OUTSIDE_LANES_WINDOW = 3  # OutsideRouteLanesTest.WINDOWS_SIZE: checks i+1 .. i+3
COLLISION_RADIUS_M = 5.0  # CollisionTest.COLLISION_RADIUS
COLLISION_ID_TIME_S = 5.0  # CollisionTest.MAX_ID_TIME
COLLISION_MIN_SPEED = 0.1  # CollisionTest.EPSILON, m/s (strict <: dropped)
BLOCKED_MIN_SPEED = 0.1  # ActorBlockedTest min_speed in route_scenario.py, m/s
TIMEOUT_MIN_S = 300.0  # RouteTimeoutBehavior.MIN_TIMEOUT
TIMEOUT_SPEED_FRACTION = 0.1  # RouteTimeoutBehavior.TIMEOUT_ROUTE_PERC / 100
TIMEOUT_WINDOW = 3  # RouteTimeoutBehavior._wsize: checks i .. i + 3
MIN_SPEED_WINDOW = 2  # MinimumSpeedRouteTest.WINDOWS_SIZE
MIN_SPEED_FINAL_PROGRESS = 0.95  # terminate(): last checkpoint if progress > 95 %


# ---------------------------------------------------------------------------
# Route helpers
# ---------------------------------------------------------------------------


def route_last_index(route: Route) -> Array:
    """() int32 index of the last valid route point."""
    return jnp.maximum(jnp.sum(route.valid.astype(jnp.int32)) - 1, 0)


def route_length(route: Route) -> Array:
    """() route length (arc of the last valid point), m."""
    return route.arc[route_last_index(route)]


def route_forward(route: Route, j: Array, last: Array) -> Array:
    """(2,) unit forward vector of route point ``j`` (central difference).

    A degenerate point (zero-length neighbourhood) gets a zero vector, so the
    ego is never "ahead" of it.
    """
    a = route.xy[jnp.clip(j - 1, 0, last)]
    b = route.xy[jnp.clip(j + 1, 0, last)]
    d = b - a
    n = jnp.linalg.norm(d)
    return jnp.where(n > 0, d / jnp.where(n > 0, n, 1.0), jnp.zeros_like(d))


def route_ahead(route: Route, j: Array, last: Array, ego_xy: Array) -> Array:
    """() bool: ego strictly ahead of route point ``j`` (``wp_veh . wp_dir > 0``)."""
    jj = jnp.clip(j, 0, route.xy.shape[0] - 1)
    return jnp.dot(ego_xy - route.xy[jj], route_forward(route, jj, last)) > 0


def _advance(route: Route, index: Array, ego_xy: Array, window: int, last: Array) -> Array:
    """Index after scanning points ``index .. min(index + window, last)``.

    The source loop sets ``index = j`` for every ``j`` the ego is strictly
    ahead of, so the result is the largest such ``j`` (or ``index``).
    """
    new = index
    for k in range(window + 1):  # static unroll, window is a small constant
        j = index + k
        new = jnp.where((j <= last) & route_ahead(route, j, last, ego_xy), j, new)
    return new


def round_decimals(x: Array, decimals: int) -> Array:
    """Round half to even at ``decimals`` places, as Python's ``round`` on the
    source's values: ``round(x * 10**d) / 10**d`` (XLA's ``jnp.round(x, d)``
    multiplies by ``10**-d`` instead, which misses e.g. 0.117 by one ulp)."""
    scale = 10.0**decimals
    return jnp.round(x * scale) / scale


def _freeze(done: Array, old, new):
    """``old`` where ``done`` (the criterion already fired), else ``new``."""
    return jax.tree_util.tree_map(lambda o, n: jnp.where(done, o, n), old, new)


def _zero(dtype):
    return jnp.zeros((), dtype)


# ---------------------------------------------------------------------------
# RouteCompletionTest
# ---------------------------------------------------------------------------


@struct.dataclass
class RouteCompletionCarry:
    """Attributes:
    index:     () int32 last route point the ego was strictly ahead of.
    value:     () float route completion RC, % rounded to 2 decimals; 100 once
               completed.
    completed: () bool, RC > threshold and ego < 10 m from the last point.
    """

    index: Array
    value: Array
    completed: Array


def route_completion_init(dtype=jnp.float32) -> RouteCompletionCarry:
    return RouteCompletionCarry(index=jnp.zeros((), jnp.int32), value=_zero(dtype), completed=jnp.zeros((), bool))


def route_completion_update(
    carry: RouteCompletionCarry,
    route: Route,
    ego_xy: Array,
    threshold: float = RC_THRESHOLD_LB,
    distance_m: float = RC_DISTANCE_M,
) -> tuple[RouteCompletionCarry, Array]:
    """One tick of RouteCompletionTest.

    Window ``i .. min(i + 2, last)``, strictly-ahead test, RC = round(P_i, 2)
    with P_i = 100 arc_i / arc_last (so RC never decreases and moves at most
    2 points per tick). Completion when RC > ``threshold`` (strict; 99 in LB,
    97 in DriveE2E) and the ego is < ``distance_m`` from the last point, then
    RC := 100. Returns (carry, completed this tick).
    """
    last = route_last_index(route)
    index = _advance(route, carry.index, ego_xy, RC_WINDOW, last)
    length = route.arc[last]
    pct = jnp.where(length > 0, route.arc[index] / jnp.where(length > 0, length, 1.0) * 100.0, 0.0)
    value = round_decimals(pct, 2).astype(carry.value.dtype)
    reached = (value > threshold) & (jnp.linalg.norm(ego_xy - route.xy[last]) < distance_m)
    value = jnp.where(reached, 100.0, value).astype(value.dtype)
    new = RouteCompletionCarry(index=index, value=value, completed=reached)
    new = _freeze(carry.completed, carry, new)
    return new, new.completed & ~carry.completed


# ---------------------------------------------------------------------------
# InRouteTest (route deviation)
# ---------------------------------------------------------------------------


@struct.dataclass
class InRouteCarry:
    """Attributes:
    index:        () int32 closest route point found so far.
    out_distance: () float route arc advanced while not in the safe band, m.
    in_safe:      () bool, last distance < max_m was also < min_m.
    deviated:     () bool, the criterion fired (route ends).
    """

    index: Array
    out_distance: Array
    in_safe: Array
    deviated: Array


def in_route_init(dtype=jnp.float32) -> InRouteCarry:
    return InRouteCarry(
        index=jnp.zeros((), jnp.int32),
        out_distance=_zero(dtype),
        in_safe=jnp.ones((), bool),
        deviated=jnp.zeros((), bool),
    )


def in_route_update(
    carry: InRouteCarry,
    route: Route,
    ego_xy: Array,
    max_m: float = IN_ROUTE_MAX_M,
    min_m: float | None = None,
    max_pct: float = IN_ROUTE_MAX_PCT,
) -> tuple[InRouteCarry, Array]:
    """One tick of InRouteTest.

    Closest point among ``i .. min(i + 5, last)`` (ties go to the later point,
    as the source's ``<=``). Distance >= ``max_m`` deviates. The safe flag is
    refreshed only when distance < ``max_m`` (safe iff < ``min_m``, default
    ``max_m / 2``); when the closest index advances while not safe, the
    advanced arc is added to the off-route total, and a total > ``max_pct`` %
    of the route deviates. Returns (carry, deviated this tick).
    """
    min_m = 0.5 * max_m if min_m is None else min_m
    last = route_last_index(route)
    j = carry.index + jnp.arange(IN_ROUTE_WINDOW + 1)
    d = jnp.linalg.norm(route.xy[jnp.clip(j, 0, route.xy.shape[0] - 1)] - ego_xy, axis=-1)
    d = jnp.where(j <= last, d, jnp.inf)
    k = IN_ROUTE_WINDOW - jnp.argmin(d[::-1])  # last index attaining the minimum
    closest, shortest = carry.index + k, d[k]
    within = shortest < max_m
    in_safe = jnp.where(within, shortest < min_m, carry.in_safe)
    advanced = closest != carry.index
    added = advanced & ~in_safe
    out = carry.out_distance + jnp.where(added, route.arc[closest] - route.arc[carry.index], 0.0)
    length = route.arc[last]
    pct = jnp.where(length > 0, 100.0 * out / jnp.where(length > 0, length, 1.0), 0.0)
    deviated = ~within | (added & (pct > max_pct))
    out = out.astype(carry.out_distance.dtype)
    new = InRouteCarry(index=closest, out_distance=out, in_safe=in_safe, deviated=deviated)
    new = _freeze(carry.deviated, carry, new)
    return new, new.deviated & ~carry.deviated


# ---------------------------------------------------------------------------
# OutsideRouteLanesTest (distance accounting; the off-lane test is the caller's)
# ---------------------------------------------------------------------------


@struct.dataclass
class OutsideLanesCarry:
    """Attributes:
    index:     () int32 last passed route point.
    traversed: () float route distance passed, m.
    wrong:     () float part of it passed while off-lane, m.
    """

    index: Array
    traversed: Array
    wrong: Array


def outside_lanes_init(dtype=jnp.float32) -> OutsideLanesCarry:
    return OutsideLanesCarry(index=jnp.zeros((), jnp.int32), traversed=_zero(dtype), wrong=_zero(dtype))


def outside_lanes_update(carry: OutsideLanesCarry, route: Route, ego_xy: Array, off_lane: Array) -> OutsideLanesCarry:
    """One tick of OutsideRouteLanesTest's distance accounting.

    ``off_lane`` is this tick's ``outside_lane_active or wrong_lane_active``
    (computed by the caller). Points ``i+1 .. min(i+3, last)`` are scanned in
    order; each one the ego is strictly ahead of adds the distance from the
    current point to it (then becomes current) to the traversed distance, and
    also to the wrong distance while ``off_lane``.
    """
    last = route_last_index(route)
    index, traversed, wrong = carry.index, carry.traversed, carry.wrong
    start = carry.index
    for k in range(1, OUTSIDE_LANES_WINDOW + 1):
        j = start + k
        passed = (j <= last) & route_ahead(route, j, last, ego_xy)
        d = jnp.linalg.norm(route.xy[jnp.clip(j, 0, route.xy.shape[0] - 1)] - route.xy[index]).astype(traversed.dtype)
        traversed = traversed + jnp.where(passed, d, 0.0)
        wrong = wrong + jnp.where(passed & off_lane, d, 0.0)
        index = jnp.where(passed, j, index)
    return OutsideLanesCarry(index=index, traversed=traversed, wrong=wrong)


def outside_lanes_event(carry: OutsideLanesCarry) -> Array:
    """() bool: the route has an outside-route-lanes event (wrong distance > 0)."""
    return carry.wrong > 0


def outside_lanes_percentage(carry: OutsideLanesCarry) -> Array:
    """() p = wrong / traversed * 100 (unrounded, as the event dict); 0 if no event."""
    ok = outside_lanes_event(carry) & (carry.traversed > 0)
    return jnp.where(ok, 100.0 * carry.wrong / jnp.where(ok, carry.traversed, 1.0), 0.0)


# ---------------------------------------------------------------------------
# CollisionTest (dedup of collision-sensor contacts)
# ---------------------------------------------------------------------------


@struct.dataclass
class CollisionCarry:
    """Attributes:
    last_id:      () int32 id of the last counted collision (-1: none; id 0 =
                  static is never remembered).
    last_time:    () float time of the last counted collision, s.
    last_xy:      (2,) float ego position at the last counted collision, m.
    has_location: () bool, ``last_xy`` is still remembered.
    count:        () int32 collisions counted by the criterion (incl. OTHER).
    """

    last_id: Array
    last_time: Array
    last_xy: Array
    has_location: Array
    count: Array


@struct.dataclass
class CollisionTick:
    """Attributes:
    counted: () bool, a contact was counted this tick.
    index:   () int32 which contact (-1 if none).
    cls:     () int32 ``CollisionClass`` of it (-1 if none).
    event:   () bool, counted and PEDESTRIAN / VEHICLE / LAYOUT (a penalty).
    """

    counted: Array
    index: Array
    cls: Array
    event: Array


def collision_init(dtype=jnp.float32) -> CollisionCarry:
    return CollisionCarry(
        last_id=jnp.full((), -1, jnp.int32),
        last_time=_zero(dtype),
        last_xy=jnp.zeros((2,), dtype),
        has_location=jnp.zeros((), bool),
        count=jnp.zeros((), jnp.int32),
    )


def collision_update(
    carry: CollisionCarry,
    hit: Array,
    other_id: Array,
    other_class: Array,
    ego_xy: Array,
    ego_speed: Array,
    t: Array,
) -> tuple[CollisionCarry, CollisionTick]:
    """One tick of CollisionTest with ``M`` candidate contacts.

    Args:
      hit:         (M,) bool, the ego touches contact m this tick.
      other_id:    (M,) int32 actor id, >= 0; 0 means a static object (never
                   remembered, as CARLA's id 0). Give agents ids >= 1.
      other_class: (M,) int32 ``CollisionClass``.
      ego_xy:      (2,) ego position, m.  ego_speed: () m/s.  t: () game time, s.

    Order within the tick: first the memory is refreshed as the source's
    ``update()`` does (location forgotten once the ego is > 5 m from it, id
    forgotten once > 5 s elapsed since the last counted collision), then
    the contacts are processed in ascending index ``m`` as sensor events. A
    contact is dropped if (a) its id equals the remembered id, (b) the ego is
    within 5 m (<=) of the remembered location, or (c) ego speed < 0.1 m/s.
    A counted contact sets time, location and (if nonzero) id. Since the
    location is then the ego's own, every later contact of the same tick is
    dropped by (b): at most one collision counts per tick, the lowest-index
    eligible one; put the contact you want to win first.

    Returns (carry, CollisionTick).
    """
    hit, other_id, other_class = (jnp.atleast_1d(jnp.asarray(a)) for a in (hit, other_id, other_class))
    dist = jnp.linalg.norm(ego_xy - carry.last_xy)
    near = carry.has_location & (dist <= COLLISION_RADIUS_M)
    last_id = jnp.where(
        (carry.last_id >= 0) & (t - carry.last_time > COLLISION_ID_TIME_S), jnp.int32(-1), carry.last_id
    )
    same = (last_id >= 0) & (other_id == last_id)
    eligible = hit & ~same & ~near & (ego_speed >= COLLISION_MIN_SPEED)
    counted = eligible.any()
    i = jnp.argmax(eligible)
    cid, cls = other_id[i].astype(jnp.int32), other_class[i].astype(jnp.int32)
    new = CollisionCarry(
        last_id=jnp.where(counted & (cid != 0), cid, last_id),
        last_time=jnp.where(counted, t, carry.last_time).astype(carry.last_time.dtype),
        last_xy=jnp.where(counted, ego_xy, carry.last_xy).astype(carry.last_xy.dtype),
        has_location=near | counted,
        count=carry.count + counted.astype(jnp.int32),
    )
    tick = CollisionTick(
        counted=counted,
        index=jnp.where(counted, i, -1).astype(jnp.int32),
        cls=jnp.where(counted, cls, -1),
        event=counted & (cls >= CollisionClass.PEDESTRIAN) & (cls <= CollisionClass.LAYOUT),
    )
    return new, tick


# ---------------------------------------------------------------------------
# ActorBlockedTest
# ---------------------------------------------------------------------------


@struct.dataclass
class BlockedCarry:
    """Attributes:
    last_valid_time: () float last time the ego was not "slow", s (0 = unset;
                     the source tests it for truthiness, so 0.0 also re-arms).
    blocked:         () bool, the criterion fired (route ends).
    """

    last_valid_time: Array
    blocked: Array


def blocked_init(dtype=jnp.float32) -> BlockedCarry:
    return BlockedCarry(last_valid_time=_zero(dtype), blocked=jnp.zeros((), bool))


def blocked_update(
    carry: BlockedCarry, ego_speed: Array, t: Array, max_time_s: float, min_speed: float = BLOCKED_MIN_SPEED
) -> tuple[BlockedCarry, Array]:
    """One tick of ActorBlockedTest: blocked when speed < ``min_speed`` and
    ``t - last_valid_time > max_time_s`` (180 s LB, 60 s B2D / DriveE2E); any
    other tick (including the first) sets ``last_valid_time = t``.
    Returns (carry, blocked this tick)."""
    check = (ego_speed < min_speed) & (carry.last_valid_time != 0)
    blocked = check & (t - carry.last_valid_time > max_time_s)
    new = BlockedCarry(
        last_valid_time=jnp.where(check, carry.last_valid_time, t).astype(carry.last_valid_time.dtype), blocked=blocked
    )
    new = _freeze(carry.blocked, carry, new)
    return new, new.blocked & ~carry.blocked


# ---------------------------------------------------------------------------
# RouteTimeoutBehavior (timer.py)
# ---------------------------------------------------------------------------


@struct.dataclass
class RouteTimeoutCarry:
    """Attributes:
    index:      () int32 last route point passed (window i .. i + 3).
    budget:     () float time budget, s (300 + sum of d_arc / (0.1 speed_limit)).
    start_time: () float game time of the first update, s.
    started:    () bool.
    timed_out:  () bool, elapsed > budget (route ends).
    """

    index: Array
    budget: Array
    start_time: Array
    started: Array
    timed_out: Array


def route_timeout_init(dtype=jnp.float32, min_timeout_s: float = TIMEOUT_MIN_S) -> RouteTimeoutCarry:
    return RouteTimeoutCarry(
        index=jnp.zeros((), jnp.int32),
        budget=jnp.full((), min_timeout_s, dtype),
        start_time=_zero(dtype),
        started=jnp.zeros((), bool),
        timed_out=jnp.zeros((), bool),
    )


def route_timeout_update(
    carry: RouteTimeoutCarry, route: Route, ego_xy: Array, speed_limit: Array, t: Array
) -> tuple[RouteTimeoutCarry, Array]:
    """One tick of RouteTimeoutBehavior.

    ``speed_limit`` (m/s, > 0) is the ego lane's limit this tick (CARLA's
    ``get_speed_limit() / 3.6``). Advancing from point i to j (window
    ``i .. i + 3``, strictly ahead) adds ``(arc_j - arc_i) / (0.1 speed_limit)``
    to the budget. The start time is the first update's ``t`` (the source's
    ``initialise``). Timed out when ``t - start > budget`` (strict).
    Returns (carry, timed out this tick).
    """
    start = jnp.where(carry.started, carry.start_time, t).astype(carry.start_time.dtype)
    last = route_last_index(route)
    index = _advance(route, carry.index, ego_xy, TIMEOUT_WINDOW, last)
    gain = (route.arc[index] - route.arc[carry.index]) / (TIMEOUT_SPEED_FRACTION * speed_limit)
    budget = (carry.budget + jnp.where(index > carry.index, gain, 0.0)).astype(carry.budget.dtype)
    timed_out = (t - start) > budget
    started = jnp.ones((), bool)
    new = RouteTimeoutCarry(index=index, budget=budget, start_time=start, started=started, timed_out=timed_out)
    new = _freeze(carry.timed_out, carry, new)
    return new, new.timed_out & ~carry.timed_out


# ---------------------------------------------------------------------------
# MinimumSpeedRouteTest
# ---------------------------------------------------------------------------


@struct.dataclass
class MinSpeedCarry:
    """Attributes:
    index:        () int32 last passed route point (window i .. i + 2).
    checkpoints:  () int32 number of checkpoints n (4 LB, 20 B2D).
    current_dist: () float arc at the last checkpoint close, m.
    ego_sum, bg_sum: () float sums of ego speed / background mean speed, m/s.
    samples:      () int32 ticks accumulated since the last close.
    values:       (K,) float closed checkpoint percentages (rounded to 2).
    count:        () int32 number of closed checkpoints (valid prefix of values).
    """

    index: Array
    checkpoints: Array
    current_dist: Array
    ego_sum: Array
    bg_sum: Array
    samples: Array
    values: Array
    count: Array

    @property
    def valid(self) -> Array:
        """(K,) bool mask of closed checkpoints."""
        return jnp.arange(self.values.shape[-1]) < self.count[..., None]


def min_speed_init(checkpoints: int, capacity: int | None = None, dtype=jnp.float32) -> MinSpeedCarry:
    """``capacity`` (static, default ``checkpoints``) sizes ``values``: strict
    ">" closes at most n - 1 times along the route, plus the final close."""
    capacity = checkpoints if capacity is None else capacity
    if checkpoints < 1 or capacity < checkpoints:
        raise ValueError(f"min_speed_init: need 1 <= checkpoints <= capacity, got {checkpoints}, {capacity}")
    return MinSpeedCarry(
        index=jnp.zeros((), jnp.int32),
        checkpoints=jnp.asarray(checkpoints, jnp.int32),
        current_dist=_zero(dtype),
        ego_sum=_zero(dtype),
        bg_sum=_zero(dtype),
        samples=jnp.zeros((), jnp.int32),
        values=jnp.zeros((capacity,), dtype),
        count=jnp.zeros((), jnp.int32),
    )


def _min_speed_close(carry: MinSpeedCarry, close: Array, arc_now: Array) -> tuple[MinSpeedCarry, Array]:
    """``_set_traffic_event``: value = round(100 mean(ego) / mean(bg), 2), or
    100 without samples (or a zero background sum); then reset the sums."""
    n = jnp.maximum(carry.samples, 1).astype(carry.ego_sum.dtype)
    ok = (carry.samples > 0) & (carry.bg_sum != 0)
    ratio = (carry.ego_sum / n) / jnp.where(ok, carry.bg_sum / n, 1.0) * 100.0
    value = jnp.where(ok, round_decimals(ratio, 2), 100.0).astype(carry.values.dtype)
    slot = jnp.arange(carry.values.shape[-1]) == carry.count
    zero = jnp.zeros_like(carry.ego_sum)
    new = carry.replace(
        values=jnp.where(close & slot, value, carry.values),
        count=carry.count + close.astype(jnp.int32),
        current_dist=jnp.where(close, arc_now, carry.current_dist).astype(carry.current_dist.dtype),
        ego_sum=jnp.where(close, zero, carry.ego_sum),
        bg_sum=jnp.where(close, zero, carry.bg_sum),
        samples=jnp.where(close, 0, carry.samples),
    )
    return new, value


def min_speed_update(
    carry: MinSpeedCarry, route: Route, ego_xy: Array, ego_speed: Array, bg_present: Array, bg_mean_speed: Array
) -> tuple[MinSpeedCarry, tuple[Array, Array]]:
    """One tick of MinimumSpeedRouteTest.

    Order as in the source: advance the index (window ``i .. i + 2``); close
    a checkpoint when ``arc_i - arc_at_last_close > L / n`` (strict); then, if
    at least one background vehicle exists (``bg_present``), add this tick's
    ego speed and the background vehicles' mean speed to the sums.
    Returns (carry, (closed this tick, its value)).
    """
    last = route_last_index(route)
    index = _advance(route, carry.index, ego_xy, MIN_SPEED_WINDOW, last)
    arc_now = route.arc[index]
    step = route.arc[last] / carry.checkpoints.astype(arc_now.dtype)
    close = arc_now - carry.current_dist > step
    carry, value = _min_speed_close(carry.replace(index=index), close, arc_now)
    add = jnp.asarray(bg_present, bool)
    carry = carry.replace(
        ego_sum=carry.ego_sum + jnp.where(add, ego_speed, 0.0).astype(carry.ego_sum.dtype),
        bg_sum=carry.bg_sum + jnp.where(add, bg_mean_speed, 0.0).astype(carry.bg_sum.dtype),
        samples=carry.samples + add.astype(jnp.int32),
    )
    return carry, (close, value)


def min_speed_finalize(carry: MinSpeedCarry, route: Route) -> tuple[MinSpeedCarry, tuple[Array, Array]]:
    """The source's ``terminate``: one more checkpoint if progress
    ``arc_i / L > 0.95`` (strict). Call once when the route ends (for any
    reason). Returns (carry, (closed, value))."""
    last = route_last_index(route)
    length = route.arc[last]
    close = (length > 0) & (route.arc[carry.index] / jnp.where(length > 0, length, 1.0) > MIN_SPEED_FINAL_PROGRESS)
    carry, value = _min_speed_close(carry, close, route.arc[carry.index])
    return carry, (close, value)


def min_speed_actual_value(carry: MinSpeedCarry) -> Array:
    """() the criterion's ``actual_value``: round(mean of closed values, 2), or 100."""
    valid = carry.valid
    n = jnp.sum(valid)
    mean = jnp.sum(jnp.where(valid, carry.values, 0.0)) / jnp.maximum(n, 1)
    return jnp.where(n > 0, round_decimals(mean, 2), 100.0).astype(carry.values.dtype)


# ---------------------------------------------------------------------------
# RunningRedLightTest memory ("not the light last run")
# ---------------------------------------------------------------------------


@struct.dataclass
class RedLightCarry:
    """Attributes:
    last: () int32 the light last run (-1: none). It stays suppressed until
          another light is run.
    """

    last: Array


def red_light_init() -> RedLightCarry:
    return RedLightCarry(last=jnp.full((), -1, jnp.int32))


def red_light_update(carry: RedLightCarry, ran: Array) -> tuple[RedLightCarry, Array]:
    """One tick of RunningRedLightTest's bookkeeping.

    ``ran`` (S,) bool is the caller's geometric test per light s (red, trigger
    centre <= 15 m, tail segment crossing a stop line of the ego's lane with
    heading . lane > 0); the light id is its index s (one signal per stop line
    as in ``Signals``). Lights are visited in index order and the light last
    run is skipped, so light s == last may fire again only after another
    light fired earlier in the same tick. Returns (carry, (S,) bool events).
    """
    ran = jnp.atleast_1d(jnp.asarray(ran, bool))
    s = jnp.arange(ran.shape[0])
    fresh = ran & (s != carry.last)
    first = jnp.argmax(fresh)
    events = ran & ((s != carry.last) | (fresh.any() & (s > first)))
    last_event = ran.shape[0] - 1 - jnp.argmax(events[::-1])
    return RedLightCarry(last=jnp.where(events.any(), last_event, carry.last).astype(jnp.int32)), events
