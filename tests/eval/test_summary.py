"""95 % confidence intervals of ``eval.summary`` against scipy.stats (independent oracle, test-only):
Wilson against ``binomtest(...).proportion_ci(method="wilson")``, the bootstrap against
``scipy.stats.bootstrap(method="percentile")`` (a different generator: agreement within
Monte Carlo error) and a t-interval; then the intervals in ``summarize`` and the console table."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.eval.summary import (
    CI_MIN_N,
    bootstrap_mean_ci,
    format_tables,
    summarize,
    wilson_ci,
)

stats = pytest.importorskip("scipy.stats")


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 400).flatmap(lambda n: st.tuples(st.integers(0, n), st.just(n))))
def test_wilson_equals_scipy(kn):
    k, n = kn
    want = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    lo, hi = wilson_ci(k, n)
    assert lo == pytest.approx(100 * want.low, abs=1e-9)
    assert hi == pytest.approx(100 * want.high, abs=1e-9)
    assert lo <= 100 * k / n <= hi


def test_wilson_known_value_and_bad_input():
    # 8 of 10: the textbook Wilson interval 0.4902-0.9433
    assert wilson_ci(8, 10) == pytest.approx((49.0162, 94.3318), abs=1e-4)
    assert wilson_ci(0, 5)[0] == 0.0 and wilson_ci(5, 5)[1] == 100.0
    with pytest.raises(ValueError, match="wilson_ci"):
        wilson_ci(3, 2)
    with pytest.raises(ValueError, match="wilson_ci"):
        wilson_ci(0, 0)


@pytest.mark.parametrize("n, kind", [(12, "bimodal"), (60, "uniform"), (200, "bimodal")])
def test_bootstrap_agrees_with_scipy_bootstrap(n, kind):
    rng = np.random.default_rng(n)
    # DS-like: bimodal = many 100s and a spread of low scores
    x = np.where(rng.random(n) < 0.6, 100.0, rng.uniform(0, 60, n)) if kind == "bimodal" else rng.uniform(0, 100, n)
    want = stats.bootstrap((x,), np.mean, n_resamples=20_000, method="percentile", confidence_level=0.95,
                           random_state=np.random.default_rng(123)).confidence_interval
    lo, hi = bootstrap_mean_ci(x)
    se = x.std(ddof=1) / np.sqrt(n)
    # two Monte Carlo estimates of the same quantiles: agree to a small fraction of the standard error
    assert lo == pytest.approx(want.low, abs=0.15 * se)
    assert hi == pytest.approx(want.high, abs=0.15 * se)
    t = stats.t.interval(0.95, n - 1, loc=x.mean(), scale=se)
    if n >= 60:  # large samples: close to the t-interval
        assert lo == pytest.approx(t[0], abs=0.35 * se) and hi == pytest.approx(t[1], abs=0.35 * se)
    else:  # 12 skewed scores: the t-interval is symmetric, the bootstrap follows the skew (why docs choose it)
        assert hi - x.mean() < x.mean() - lo and t[1] > hi


def test_bootstrap_is_deterministic_bounded_and_blocked():
    x = [100.0] * 7 + [0.0] * 3
    assert bootstrap_mean_ci(x) == bootstrap_mean_ci(list(x))  # fixed seed
    y = np.linspace(0.0, 100.0, 13) ** 1.5 / 10
    assert bootstrap_mean_ci(y, seed=1) != bootstrap_mean_ci(y)
    lo, hi = bootstrap_mean_ci(x)
    assert 0.0 <= lo < 70.0 < hi <= 100.0
    assert bootstrap_mean_ci([42.0] * 5) == (42.0, 42.0)  # no spread, no interval
    big = np.random.default_rng(0).uniform(0, 100, 3000)  # more than one block of draws
    lo, hi = bootstrap_mean_ci(big, resamples=2000)
    assert lo < big.mean() < hi and hi - lo == pytest.approx(2 * 1.96 * big.std() / np.sqrt(3000), rel=0.1)
    with pytest.raises(ValueError, match="bootstrap_mean_ci"):
        bootstrap_mean_ci([])
    with pytest.raises(ValueError, match="bootstrap_mean_ci"):
        bootstrap_mean_ci([1.0, float("nan")])


def _rows(policy: str, n: int, successes: int, behavior_of) -> list[dict]:
    return [{
        "policy": policy, "scenario_id": f"s{i:03d}", "behavior": behavior_of(i), "intersection_id": "I01",
        "weather": "clear", "route_length_m": 100.0, "route_completion": 100.0 if i < successes else 40.0,
        "infraction_score": 1.0, "driving_score": 100.0 if i < successes else 40.0,
        "success": i < successes, "status": "Perfect" if i < successes else "Failed - TickRuntime",
        "eval_time_s": 0.1, "episode_s": 10.0,
    } for i in range(n)]


def test_summarize_adds_intervals_overall_and_to_groups_of_at_least_ten():
    rows = _rows("p", 14, 9, lambda i: "STR" if i < 11 else "LFT")
    s = summarize({"p": rows}, {"num_scenarios": 14})["policies"]["p"]
    o = s["overall"]
    want = stats.binomtest(9, 14).proportion_ci(method="wilson")
    assert o["success_rate_ci95"] == pytest.approx([100 * want.low, 100 * want.high], abs=1e-4)
    lo, hi = o["driving_score_ci95"]
    assert lo < o["driving_score"] < hi and [lo, hi] == pytest.approx(
        bootstrap_mean_ci([r["driving_score"] for r in rows]), abs=1e-4)
    assert CI_MIN_N == 10
    assert "success_rate_ci95" in s["by_behavior"]["STR"]  # 11 scenarios
    assert "success_rate_ci95" not in s["by_behavior"]["LFT"] and "driving_score_ci95" not in s["by_behavior"]["LFT"]


def test_console_table_shows_the_intervals():
    rows = _rows("p", 10, 8, lambda i: "STR")
    text = format_tables(summarize({"p": rows}, {"num_scenarios": 10}))
    line = next(ln for ln in text.splitlines() if ln.startswith("p ") and "[" in ln)
    assert "[49.0, 94.3]" in line  # Wilson 8 of 10
    assert "Wilson" in text and "bootstrap" in text


def _ability_rows(junction: bool) -> list[dict]:
    """COV succeeds; IPC fails at RC 60 (past its junction), STP at RC 60 with a red light, STR at RC 45."""
    rows = _rows("p", 4, 1, lambda i: ("COV", "IPC", "STP", "STR")[i])
    for r, rc in zip(rows[1:], (60.0, 60.0, 45.0)):
        r["route_completion"] = r["driving_score"] = rc
    rows[2]["red_light"] = 1
    if junction:
        for r in rows:
            r["route_junction_index"], r["route_waypoints"] = 40, 100  # junction test: RC / 100 > (41 + 8) / 100
    return rows


def test_abilities_are_bench2drive_fractions_with_the_junction_credit():
    """By hand (B2D 0.0.4 rules, behaviour groups as docs/metrics.md maps them): Merging = COV 1/1,
    Emergency_Brake = IPC 0/1, Traffic_Signs = all four: COV succeeds, IPC fails but passes its
    junction (0.60 > 0.49, no red light) -> 2/4; STP (red light) and STR (0.45) get no credit.
    Overtaking and Give_Way have no route: left out, the mean is over the three present."""
    s = summarize({"p": _ability_rows(junction=True)}, {"num_scenarios": 4})["policies"]["p"]["overall"]
    assert s["abilities"] == pytest.approx({"Merging": 1.0, "Emergency_Brake": 0.0, "Traffic_Signs": 0.5,
                                            "mean": 0.5}, abs=1e-12)
    assert s["abilities_junction_credit"] is True
    line = next(ln for ln in format_tables({"run": {}, "policies": {"p": {"overall": s, "by_behavior": {}}}})
                .splitlines()[::-1] if ln.startswith("p ") and "100.0" in ln)
    assert line.split()[1:] == ["100.0", "0.0", "50.0", "50.0"]  # printed in %


def test_abilities_without_junction_data_give_no_credit():
    s = summarize({"p": _ability_rows(junction=False)}, {"num_scenarios": 4})["policies"]["p"]["overall"]
    assert s["abilities"]["Traffic_Signs"] == 0.25 and s["abilities"]["mean"] == pytest.approx(1.25 / 3, abs=1e-6)
    assert s["abilities_junction_credit"] is False
