"""Per-route scoring: reference cases LB-01/02/04 (LB 2.0 and 2.1) and the
per-route part of B2D-01, plus statuses, presets, switches and precision.

``check_lb_route_case`` / ``b2d01_outcomes`` / ``check_b2d01_routes`` take a
case dict (metric_cases.json format); they live in
``tests/helpers/metric_cases/driving_score.py``, shared with
``test_metric_cases.py`` and the aggregation checks.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax.metrics.driving_score import (
    INFRACTION_KEYS,
    PENALTIES,
    RouteOutcome,
    ScoreConfig,
    Status,
    outcome_from_events,
    route_score,
)
from tests.helpers.metric_cases import subset_case  # the tests' shared case loader
from tests.helpers.metric_cases.driving_score import check_b2d01_routes, check_lb_route_case, counts_dict, score64

# ---------------------------------------------------------------------------
# LB-xx per-route cases
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("case_id", ["LB-01", "LB-02", "LB-04"])
def test_lb_route_cases(case_id):
    check_lb_route_case(subset_case(case_id))


# ---------------------------------------------------------------------------
# B2D-01 per-route part
# ---------------------------------------------------------------------------


def test_b2d01_per_route():
    check_b2d01_routes(subset_case("B2D-01"))


# ---------------------------------------------------------------------------
# Status, success, switches
# ---------------------------------------------------------------------------


def outcome(rc=100.0, checkpoints=4, **kw) -> RouteOutcome:
    with jax.enable_x64(True):
        o = RouteOutcome.empty(checkpoints, jnp.float64)
    kw = {k: np.asarray(v) for k, v in kw.items()}
    return o.replace(route_completion=np.float64(rc), **kw)


def min_speeds(values, k=4):
    pct = np.zeros(k)
    pct[: len(values)] = values
    return {"min_speed_pct": pct, "min_speed_valid": np.arange(k) < len(values)}


@pytest.mark.parametrize(
    "flags, want",
    [
        ({}, Status.FAILED),
        ({"tick_runtime": True}, Status.FAILED_TICK_RUNTIME),
        ({"tick_runtime": True, "route_timeout": True}, Status.FAILED_TIMEOUT),
        ({"route_timeout": True, "route_deviation": True}, Status.FAILED_DEVIATED),
        ({"route_deviation": True, "vehicle_blocked": True, "route_timeout": True}, Status.FAILED_BLOCKED),
    ],
)
def test_failure_reason_is_the_last_that_applies(flags, want):
    s = score64(outcome(rc=42.0, **flags), ScoreConfig.b2d())
    assert int(s.status) == want
    assert not bool(s.success)


def test_perfect_needs_no_entry_at_all():
    assert int(score64(outcome(), ScoreConfig.lb20()).status) == Status.PERFECT
    # A route timeout entry with RC 100 (possible in the source) -> Completed, not success.
    s = score64(outcome(route_timeout=True), ScoreConfig.lb20())
    assert int(s.status) == Status.COMPLETED and not bool(s.success)
    # A recorded min-speed entry -> Completed, still a success.
    s = score64(outcome(**min_speeds([80.0])), ScoreConfig.lb20())
    assert int(s.status) == Status.COMPLETED and bool(s.success)
    # RC 99.99 is not completed.
    assert int(score64(outcome(rc=99.99), ScoreConfig.lb20()).status) == Status.FAILED


def test_min_speed_recording_and_penalty_per_preset():
    o = outcome(**min_speeds([50.0, 100.0, 120.0, 99.99]))
    lb = score64(o, ScoreConfig.lb20())  # events only < 100, penalised
    assert counts_dict(lb) == {"min_speed_infractions": 2}
    assert float(lb.infraction_penalty) == pytest.approx(round(0.85 * (1 - 0.3 * 0.0001), 6), abs=1e-12)
    b2d = score64(o, ScoreConfig.b2d())  # every checkpoint recorded, never penalised
    assert counts_dict(b2d) == {"min_speed_infractions": 4}
    assert float(b2d.infraction_penalty) == 1.0 and float(b2d.driving_score) == 100.0
    assert bool(b2d.success)
    de2e = score64(o, ScoreConfig.drivee2e())
    assert float(de2e.infraction_penalty) == float(lb.infraction_penalty)


def test_drivee2e_disables_red_light_and_outside_lanes():
    o = outcome(red_light=2, outside_lanes_m=30.0, outside_lanes_pct=10.0)
    s = score64(o, ScoreConfig.drivee2e())
    assert float(s.infraction_penalty) == 1.0 and int(s.status) == Status.PERFECT and bool(s.success)
    s = score64(o, ScoreConfig.lb20())
    assert float(s.infraction_penalty) == pytest.approx(0.7 * 0.7 * 0.9, abs=1e-12)
    assert counts_dict(s) == {"red_light": 2, "outside_route_lanes": 1}
    assert not bool(s.success)


def test_each_switch_silences_its_criterion():
    o = outcome(
        rc=50.0, collisions_vehicle=1, stop_infraction=1, route_deviation=True, vehicle_blocked=True,
        route_timeout=True, tick_runtime=True, **min_speeds([10.0]),
    )
    off = ScoreConfig(
        name="off", collisions=False, stop_sign=False, min_speed=False, in_route=False, blocked=False,
        route_timeout=False,
    )
    s = score64(o, off)
    assert counts_dict(s) == {} and float(s.infraction_penalty) == 1.0
    # A cut route is reported as such whatever the preset: in replay the end of
    # the log cuts it even without a configured cap.
    assert int(s.status) == Status.FAILED_TICK_RUNTIME
    s = score64(o.replace(tick_runtime=np.asarray(False)), off)
    assert int(s.status) == Status.FAILED  # every failure reason switched off


def test_lb21_formula_and_rounding():
    o = outcome(rc=50.0, collisions_pedestrian=1, outside_lanes_m=10.0, outside_lanes_pct=10.0)
    s = score64(o, ScoreConfig.lb21())
    assert float(s.infraction_penalty) == pytest.approx(0.45, abs=1e-12)
    assert float(s.driving_score) == pytest.approx(22.5, abs=1e-12)
    # DS uses the unrounded IS: 100 / 3 * (1 / 2.35) = 14.184397163... -> 14.184397
    s = score64(outcome(rc=100.0 / 3, collisions_vehicle=1, red_light=1, stop_infraction=1), ScoreConfig.lb21())
    assert float(s.route_completion) == 33.333333
    assert float(s.infraction_penalty) == 0.425532
    assert float(s.driving_score) == 14.184397


def test_penalty_table_matches_scoring():
    fields = {"collisions_pedestrian": "collisions_pedestrian", "collisions_vehicle": "collisions_vehicle",
              "collisions_layout": "collisions_layout", "red_light": "red_light",
              "stop_infraction": "stop_infraction", "scenario_timeouts": "scenario_timeouts",
              "yield_emergency_vehicle_infractions": "yield_emergency_vehicle"}
    for p in PENALTIES:
        if p.kind != "fixed":
            continue
        o = outcome(**{fields[p.key]: 2})
        assert float(score64(o, ScoreConfig.lb20()).infraction_penalty) == pytest.approx(p.lb20**2, abs=1e-6)
        assert float(score64(o, ScoreConfig.lb21()).infraction_penalty) == pytest.approx(1 / (1 + 2 * p.lb21), abs=1e-6)
    assert {p.key for p in PENALTIES} == set(INFRACTION_KEYS)


def test_float32_jit_vmap_matches_float64():
    rng = np.random.default_rng(0)
    n = 12
    fields = dict(
        route_completion=rng.uniform(0, 100, n),
        collisions_vehicle=rng.integers(0, 3, n).astype(np.int32),
        collisions_pedestrian=rng.integers(0, 2, n).astype(np.int32),
        red_light=rng.integers(0, 2, n).astype(np.int32),
        outside_lanes_m=rng.uniform(0, 20, n) * (rng.uniform(size=n) < 0.5),
        outside_lanes_pct=rng.uniform(0, 20, n),
        min_speed_pct=rng.uniform(40, 130, (n, 4)),
        min_speed_valid=rng.uniform(size=(n, 4)) < 0.7,
        route_deviation=rng.uniform(size=n) < 0.2,
    )
    fields["route_completion"][:4] = 100.0

    def batch(dtype):
        o = RouteOutcome.empty(4, dtype)
        o = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), o)
        cast = {k: jnp.asarray(v, dtype if np.asarray(v).dtype == np.float64 else None) for k, v in fields.items()}
        return o.replace(**cast)

    scorer = jax.jit(jax.vmap(route_score, in_axes=(0, None)), static_argnums=1)
    for cfg in (ScoreConfig.lb20(), ScoreConfig.lb21(), ScoreConfig.b2d(), ScoreConfig.drivee2e()):
        s32 = scorer(batch(jnp.float32), cfg)
        assert s32.driving_score.dtype == jnp.float32 and s32.driving_score.shape == (n,)
        with jax.enable_x64(True):
            s64 = scorer(batch(jnp.float64), cfg)
            assert s64.driving_score.dtype == jnp.float64
        np.testing.assert_allclose(np.asarray(s32.driving_score), np.asarray(s64.driving_score), atol=2e-4)
        assert np.array_equal(np.asarray(s32.status), np.asarray(s64.status))
        assert np.array_equal(np.asarray(s32.success), np.asarray(s64.success))
        assert np.array_equal(np.asarray(s32.infractions), np.asarray(s64.infractions))


# ---------------------------------------------------------------------------
# Config, presets, host helpers
# ---------------------------------------------------------------------------


def test_presets_and_validation():
    names = ("lb20", "lb21", "b2d", "drivee2e")
    assert tuple(ScoreConfig.preset(n).name for n in names) == names
    de = ScoreConfig.drivee2e()
    assert (de.rc_threshold, de.blocked_max_time_s, de.red_light, de.outside_lanes) == (97.0, 60.0, False, False)
    assert de.max_ticks(0.1) == 121 and ScoreConfig.b2d().max_ticks(0.05) == 4000
    assert ScoreConfig.lb20().max_ticks(0.1) is None
    assert hash(ScoreConfig.b2d()) == hash(ScoreConfig.b2d())  # usable as a static jit argument
    with pytest.raises(ValueError, match="formula"):
        ScoreConfig(formula="lb30")
    with pytest.raises(ValueError, match="rc_threshold"):
        ScoreConfig(rc_threshold=100.0)
    with pytest.raises(ValueError, match="min_speed_checkpoints"):
        ScoreConfig(min_speed_checkpoints=0)
    with pytest.raises(ValueError, match="unknown score preset"):
        ScoreConfig.preset("carla")


def test_outcome_from_events_errors():
    with pytest.raises(ValueError, match=r"events\[0\].type"):
        outcome_from_events([{"type": "WRONG_WAY_INFRACTION"}])
    two = {"type": "OUTSIDE_ROUTE_LANES_INFRACTION", "percentage": 1.0, "distance": 2.0}
    with pytest.raises(ValueError, match="at most one"):
        outcome_from_events([two, two])
