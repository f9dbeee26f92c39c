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


def _attributed_rows() -> list[dict]:
    """4 scenarios; scenario 0 was rear-ended (a collision, not at fault: nuPlan
    collision_utils ACTIVE_REAR), scenario 1 rear-ended a car (ACTIVE_FRONT,
    at fault). With all collisions both score IS 0.6 (LB 2.0 vehicle
    collision 0.6; DS = RC 100 x 0.6 = 60), at-fault only scenario 0 keeps
    IS 1 (DS 100, success). Scenarios 2, 3: clean (DS 100) / RC 40."""
    rows = _rows("p", 4, 3, lambda i: "STR")
    ds_all, ds_af = (60.0, 60.0, 100.0, 40.0), (100.0, 60.0, 100.0, 40.0)
    ok_all, ok_af = (False, False, True, False), (True, False, True, False)
    for i, r in enumerate(rows):
        r.update(driving_score_all=ds_all[i], driving_score_at_fault=ds_af[i], success_all=ok_all[i],
                 success_at_fault=ok_af[i], infraction_score_all=ds_all[i] / (100.0 if i < 3 else 40.0),
                 infraction_score_at_fault=ds_af[i] / (100.0 if i < 3 else 40.0),
                 collisions_at_fault=int(i == 1), driving_score=ds_all[i], success=ok_all[i])
    return rows


def test_summary_gives_ds_and_sr_both_ways():
    o = summarize({"p": _attributed_rows()}, {"num_scenarios": 4})["policies"]["p"]["overall"]
    assert o["driving_score_all"] == pytest.approx((60 + 60 + 100 + 40) / 4)  # 65
    assert o["driving_score_at_fault"] == pytest.approx((100 + 60 + 100 + 40) / 4)  # 75
    assert (o["success_rate_all"], o["success_rate_at_fault"]) == (25.0, 50.0)
    assert o["infraction_score_all"] == pytest.approx((0.6 + 0.6 + 1 + 1) / 4)
    assert o["collisions_at_fault"] == 1


def test_console_marks_the_chosen_collision_mode():
    rows = _attributed_rows()
    for mode, star in (("all", "DS*"), ("at_fault", "DS at-fault*")):
        text = format_tables(summarize({"p": rows}, {"num_scenarios": 4, "collisions": mode}))
        head = next(ln for ln in text.splitlines() if ln.startswith("collisions "))
        assert star in head and head.count("*") == 2  # DS and SR of the chosen mode
        line = text.splitlines()[text.splitlines().index(head) + 2]
        assert line.split()[1:] == ["65.00", "75.00", "25.0", "50.0", "1"]


def test_rows_without_the_new_columns_give_dashes_not_errors():
    old = _rows("old", 3, 2, lambda i: "STR")
    new = _attributed_rows()
    s = summarize({"new": new, "old": old}, {"num_scenarios": 4})
    assert "driving_score_all" not in s["policies"]["old"]["overall"]
    assert "nuplan_score" not in s["policies"]["old"]["overall"]
    text = format_tables(s)
    line = next(ln for ln in text.splitlines() if ln.startswith("old ") and ln.split()[1] == "-")
    assert line.split()[1:] == ["-"] * 5
    assert "collisions" not in format_tables(summarize({"old": old}, {"num_scenarios": 3})).split("\n")[0]
    assert not any(ln.startswith("collisions ") for ln in
                   format_tables(summarize({"old": old}, {"num_scenarios": 3})).splitlines())


def test_nuplan_and_navsim_scores_x100_and_sub_metric_means():
    rows = _rows("p", 2, 2, lambda i: "STR")
    rows[0].update(nuplan_score=0.5, nuplan_no_ego_at_fault_collisions=1.0, nuplan_ego_progress=0.25)
    rows[1].update(nuplan_score=1.0, nuplan_no_ego_at_fault_collisions=0.5, nuplan_ego_progress=True)
    o = summarize({"p": rows}, {"num_scenarios": 2})["policies"]["p"]["overall"]
    assert o["nuplan_score"] == 75.0  # mean(0.5, 1.0) x 100
    assert (o["nuplan_no_ego_at_fault_collisions"], o["nuplan_ego_progress"]) == (0.75, 0.625)
    nav = _rows("q", 2, 2, lambda i: "STR")
    nav[0].update(epdms=0.8, navsim_ttc="True")
    nav[1].update(epdms=float("nan"), navsim_ttc="False")
    s = summarize({"p": rows, "q": nav}, {"num_scenarios": 2})
    q = s["policies"]["q"]["overall"]
    assert (q["epdms"], q["navsim_ttc"]) == (80.0, 0.5)  # NaN scenario skipped
    text = format_tables(s)
    lines = text.splitlines()
    head = lines.index(next(ln for ln in lines if ln.startswith("nuPlan score x100")))
    assert lines[head].split()[-2:] == ["p", "q"]
    assert lines[head + 2].split() == ["nuPlan", "score", "75.00", "-"]  # q has no nuPlan score
    assert lines[head + 3].split() == ["ego_progress", "0.625", "-"]
    assert lines[head + 4].split() == ["no_ego_at_fault_collisions", "0.750", "-"]
    epd = lines.index(next(ln for ln in lines if ln.startswith("EPDMS x100")))
    assert lines[epd + 2].split() == ["EPDMS", "-", "80.00"] and lines[epd + 3].split() == ["ttc", "-", "0.500"]
