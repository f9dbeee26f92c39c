"""Aggregates of a run's per-scenario rows and the console tables.

``summarize`` turns the rows of every policy into ``summary.json``'s content
(overall, per behaviour group, intersection and weather); ``summary_of`` is the
aggregate of one set of rows (SR, DS, RC, IS, LB 2.0 per-km rates, Bench2Drive
efficiency and multi-ability, fine-grained means, open-loop means, 95 %
confidence intervals of SR and DS); ``format_tables`` prints them. Host side,
plain Python + numpy.

Collision attribution (``collision_means``): rows of this version carry DS /
SR / IS with every collision counted (``*_all``) and with only nuPlan's
at-fault ones (``*_at_fault``; nuPlan ``collision_utils`` /
``no_ego_at_fault_collisions``); the summary gives both means side by side
and ``format_tables`` marks the run's ``collisions`` mode. Presets nuplan /
navsim add ``nuplan_score`` / ``epdms`` (x100, mean over scenarios) and the
mean of every ``nuplan_*`` / ``navsim_*`` sub-metric (``preset_means``).
Rows of older folders lack these columns: the keys are then absent and the
tables show "-".

Confidence intervals (docs/metrics.md, "Confidence intervals"): SR by the
Wilson score interval (``wilson_ci``), DS by a percentile bootstrap of the
mean over scenarios (``bootstrap_mean_ci``, ``CI_RESAMPLES`` resamples, seed
``CI_SEED``: the same rows always give the same interval). Overall always;
per group only for groups of at least ``CI_MIN_N`` scenarios.
"""

from __future__ import annotations

import math

import numpy as np

from drivee2e_jax.metrics.abilities import (
    ABILITY_NAMES,
    B2D_ABILITIES,
    BEHAVIOR_SCENARIO_TYPES,
    b2d_abilities,
    routes_from_rows,
)
from drivee2e_jax.metrics.aggregate import RouteResult, b2d_efficiency, drivee2e_merge, lb_global
from drivee2e_jax.metrics.driving_score import INFRACTION_KEYS
from drivee2e_jax.metrics.finegrained import SUMMARY_COLUMNS

#: Per-scenario open-loop columns (``openloop.evaluate_openloop``).
OPEN_LOOP_COLUMNS = (
    "l2_1s_stp3", "l2_2s_stp3", "l2_3s_stp3", "l2_1s_uniad", "l2_2s_uniad", "l2_3s_uniad",
    "openloop_collision_rate", "openloop_samples",
)


#: Two-sided 95 % normal quantile, Phi^-1(0.975).
Z95 = 1.959963984540054
#: Bootstrap resamples of the DS interval and the seed of their generator.
CI_RESAMPLES = 10_000
CI_SEED = 0
#: Groups smaller than this get no interval (and are flagged in the report).
CI_MIN_N = 10


def wilson_ci(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion, in % (no continuity correction).

    Args:
      successes: k, 0 <= k <= n.
      n: trials (scenarios), >= 1.
      z: normal quantile (default two-sided 95 %).

    Returns:
      (low, high) in %, within [0, 100]; contains 100 k / n.
    """
    if not (n >= 1 and 0 <= successes <= n):
        raise ValueError(f"wilson_ci: need 0 <= successes <= n and n >= 1, got {successes} of {n}")
    p = successes / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    lo = 0.0 if successes == 0 else max(centre - half, 0.0)  # exact ends: no 1e-15 residue at k = 0 or n
    hi = 1.0 if successes == n else min(centre + half, 1.0)
    return 100.0 * lo, 100.0 * hi


def bootstrap_mean_ci(values, resamples: int = CI_RESAMPLES, seed: int = CI_SEED,
                      level: float = 0.95) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``values``.

    ``resamples`` means of ``len(values)`` draws with replacement (numpy
    ``default_rng(seed)``, drawn in blocks so memory stays ~8 MB whatever
    the size); the interval is their ``(1 - level) / 2`` and ``(1 + level) / 2``
    quantiles (linear interpolation). Deterministic for a given seed; stays
    inside [min, max] of ``values`` (DS: inside [0, 100]).

    Args:
      values: (n,) per-scenario values (e.g. DS), finite, n >= 1.
      resamples: B >= 1.
      seed: generator seed.
      level: confidence level in (0, 1).

    Returns:
      (low, high) in the unit of ``values``.
    """
    x = np.asarray(values, dtype=np.float64).reshape(-1)
    if x.size == 0 or not np.all(np.isfinite(x)):
        raise ValueError(f"bootstrap_mean_ci: need >= 1 finite value, got {x.size} values")
    if not (resamples >= 1 and 0 < level < 1):
        raise ValueError(f"bootstrap_mean_ci: need resamples >= 1 and 0 < level < 1, got {resamples}, {level}")
    rng = np.random.default_rng(seed)
    block = max(1, 1_000_000 // x.size)
    means = np.concatenate([x[rng.integers(0, x.size, (min(block, resamples - i), x.size))].mean(axis=1)
                            for i in range(0, resamples, block)])
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def ci95(rows: list[dict], successes: int) -> dict:
    """``success_rate_ci95`` (Wilson) and ``driving_score_ci95`` (bootstrap) of ``rows``, rounded, as [lo, hi]."""
    sr = wilson_ci(successes, len(rows))
    ds = bootstrap_mean_ci([float(r["driving_score"]) for r in rows])
    return {"success_rate_ci95": [round(v, 4) for v in sr], "driving_score_ci95": [round(v, 4) for v in ds]}


def _open_loop_means(rows: list[dict]) -> dict:
    """Pooled open-loop values: per-scenario values weighted by their samples."""
    use = [r for r in rows if r.get("openloop_samples")]
    if not use:
        return {}
    w = np.array([r["openloop_samples"] for r in use], float)
    out = {"openloop_samples": int(w.sum())}
    for c in OPEN_LOOP_COLUMNS[:-1]:
        v = np.array([r[c] if finite(r.get(c)) else np.nan for r in use], float)
        ok = np.isfinite(v)
        if ok.any():
            out[c] = round(float(np.sum(v[ok] * w[ok]) / np.sum(w[ok])), 4)
    return out


def summarize(rows_by_policy: dict[str, list[dict]], run_info: dict) -> dict:
    """Aggregates per policy, and per behaviour group / intersection / weather."""
    out = {"run": run_info, "policies": {}}
    for name, rows in rows_by_policy.items():
        out["policies"][name] = {
            "overall": summary_of(rows),
            "by_behavior": _group(rows, "behavior"),
            "by_intersection": _group(rows, "intersection_id"),
            "by_weather": _group(rows, "weather"),
        }
    return out


def summary_of(rows: list[dict], brief: bool = False, ci: bool = True) -> dict:
    """SR / DS / RC / IS over ``rows`` plus LB 2.0 per-km infraction rates.

    SR and DS follow DriveE2E's merge (sum over the scenarios run / their
    number; SR in %); per-km rates follow LB 2.0's global statistics.
    ``ci``: add ``success_rate_ci95`` / ``driving_score_ci95`` ([lo, hi], %
    and DS points, see ``ci95``).
    """

    if not rows:
        return {"num_scenarios": 0}
    recs = [
        RouteResult(
            route_id=r["scenario_id"],
            route_length_m=r["route_length_m"],
            score_route=r["route_completion"],
            score_penalty=r["infraction_score"],
            score_composed=r["driving_score"],
            status=r["status"],
            infractions={k: r[k] for k in INFRACTION_KEYS if r.get(k)},
            outside_lanes_m=r.get("outside_route_lanes_m", 0.0),
            # The route's mean checkpoint ratio: B2D efficiency averages these.
            min_speed_pct=(float(r["efficiency_pct"]),) if finite(r.get("efficiency_pct")) else (),
            category=r["behavior"],
        )
        for r in rows
    ]
    merged = drivee2e_merge(recs, route_nums=len(recs))
    out = {
        "num_scenarios": len(rows),
        "success_rate": round(merged["success rate"], 4),
        "driving_score": round(merged["driving score"], 4),
        "route_completion": round(float(np.mean([r["route_completion"] for r in rows])), 4),
    }
    if ci:
        out.update(ci95(rows, merged["success num"]))
    if "task_success" in rows[0]:
        out["task_success_rate"] = round(100.0 * float(np.mean([bool(r["task_success"]) for r in rows])), 4)
    if brief:
        return out
    out["abilities"] = ability_scores(rows)
    out["abilities_junction_credit"] = has_junction_data(rows)
    g = lb_global(recs, planned_routes=len(recs))
    per_km = g["infractions"]
    collisions = sum(per_km[k] for k in ("collisions_pedestrian", "collisions_vehicle", "collisions_layout"))
    out.update(
        {
            "infraction_score": round(float(np.mean([r["infraction_score"] for r in rows])), 4),
            "driving_score_std": g["scores_std_dev"]["score_composed"],
            "km_driven": round(g["km_driven"], 4),
            "collisions_per_km": round(collisions, 3),
            "red_light_per_km": per_km["red_light"],
            "infractions_per_km": per_km,
            "outside_route_lanes_pct": round(float(np.mean([r.get("outside_route_lanes_pct", 0) for r in rows])), 3),
            "statuses": _counts(r["status"] for r in rows),
            "eval_time_s": round(float(np.mean([r["eval_time_s"] for r in rows])), 4),
            "episode_s": round(float(np.mean([r["episode_s"] for r in rows])), 3),
            "invalid_action_steps": int(sum(r.get("invalid_action", 0) for r in rows)),
        }
    )
    out.update(_fine_means(rows))
    out.update(_open_loop_means(rows))
    out.update(collision_means(rows))
    out.update(preset_means(rows))
    if any(r.min_speed_pct for r in recs):
        out["efficiency_pct"] = round(b2d_efficiency(recs), 4)
    return out


#: Bench2Drive's five abilities as behaviour groups: the groups whose B2D
#: scenario type (``abilities.BEHAVIOR_SCENARIO_TYPES``, docs/metrics.md) is in
#: the ability's list. Merging = COV, Emergency_Brake = IPC, Traffic_Signs =
#: every group (all cross a signalised junction); Overtaking and Give_Way have
#: no group.
ABILITIES = {
    a: tuple(g for g, t in BEHAVIOR_SCENARIO_TYPES.items() if t in B2D_ABILITIES[a]) for a in ABILITY_NAMES
}
#: Bench2Drive ``ability_benchmark.py`` version whose junction rule the summary applies.
ABILITY_VERSION = "0.0.4"


def has_junction_data(rows: list[dict]) -> bool:
    """Whether every row carries the junction-credit inputs (``route_junction_index``,
    ``route_waypoints``: the route's first junction waypoint at 1 m and its waypoint count)."""
    return bool(rows) and all(r.get("route_waypoints") not in (None, "") and "route_junction_index" in r
                              for r in rows)


def ability_scores(rows: list[dict], version: str = ABILITY_VERSION) -> dict:
    """Bench2Drive multi-ability success fractions (``abilities.b2d_abilities``).

    Each row stands for the B2D scenario type of its behaviour group
    (``BEHAVIOR_SCENARIO_TYPES``); per ability: successes / routes of its types
    (B2D's ``ability_benchmark``, same success test as SR), plus Traffic_Signs'
    junction credit when the rows carry the junction inputs
    (``has_junction_data``; a route without a junction then earns none). Unlike
    B2D (which divides by zero), abilities without a route are left out and
    ``mean`` averages those present. Values are fractions in [0, 1], unrounded
    as B2D writes them; {} when no row has a mapped group.
    """
    routes = routes_from_rows(rows)
    return b2d_abilities(routes, version, junction_credit=has_junction_data(rows), strict=False, skip_empty=True)


def finite(v) -> bool:
    # "" = a blank CSV cell (rows read back by io.report.load_rows: an all-blank column stays text)
    return v is not None and v != "" and not math.isnan(float(v))


def _fine_means(rows: list[dict]) -> dict:
    """Means of the fine-grained columns over scenarios (NaN rows skipped)."""

    out = {}
    for c in SUMMARY_COLUMNS:
        vals = [float(r[c]) for r in rows if finite(r.get(c))]
        if vals:
            out[c] = round(float(np.mean(vals)), 4)
    return out


#: (summary key, per-scenario column, scale) of the collision-attribution
#: means: DS in points (mean of the per-scenario DS), SR in % (share of
#: successful scenarios), IS as a fraction.
COLLISION_MEANS = (
    ("driving_score_all", "driving_score_all", 1.0),
    ("driving_score_at_fault", "driving_score_at_fault", 1.0),
    ("success_rate_all", "success_all", 100.0),
    ("success_rate_at_fault", "success_at_fault", 100.0),
    ("infraction_score_all", "infraction_score_all", 1.0),
    ("infraction_score_at_fault", "infraction_score_at_fault", 1.0),
)
#: Headline scores of the nuplan / navsim presets: (per-scenario column in
#: 0..1, sub-metric column prefix); the summary key is the column, x100.
PRESET_SCORES = (("nuplan_score", "nuplan_"), ("epdms", "navsim_"))


def as_bool(v) -> bool | None:
    """A per-scenario boolean as stored (bool, 0/1, "True"/"False" from a
    CSV); None for a missing or blank value."""
    if v is None or v == "" or (isinstance(v, float) and math.isnan(v)):
        return None
    if isinstance(v, str):
        return v.strip().lower() in ("true", "1", "1.0", "yes")
    return bool(v)


def collision_means(rows: list[dict]) -> dict:
    """DS / SR / IS with all collisions and at-fault only (``COLLISION_MEANS``),
    plus ``collisions_at_fault`` (total count), over ``rows``. A key is
    present only when every row has its column (older rows: none)."""
    out: dict = {}
    for key, col, scale in COLLISION_MEANS:
        vals = [as_bool(r.get(col)) if col.startswith("success") else r.get(col) for r in rows]
        if rows and all(v is not None and (isinstance(v, bool) or finite(v)) for v in vals):
            out[key] = round(scale * float(np.mean([float(v) for v in vals])), 4)
    if rows and all(finite(r.get("collisions_at_fault")) for r in rows):
        out["collisions_at_fault"] = int(sum(float(r["collisions_at_fault"]) for r in rows))
    return out


def preset_means(rows: list[dict]) -> dict:
    """``nuplan_score`` / ``epdms`` x100 (mean over the scenarios that have
    it) and the mean of each ``nuplan_*`` / ``navsim_*`` sub-metric column
    (booleans as 0/1; NaN / blank skipped), rounded to 4 decimals."""
    out: dict = {}
    for score, prefix in PRESET_SCORES:
        vals = [float(r[score]) for r in rows if finite(r.get(score))]
        if vals:
            out[score] = round(100.0 * float(np.mean(vals)), 4)
        cols = sorted({c for r in rows for c in r if c.startswith(prefix) and c != score})
        for c in cols:
            vals = [v for v in (_number(r.get(c)) for r in rows) if v is not None]
            if vals:
                out[c] = round(float(np.mean(vals)), 4)
    return out


def _number(v) -> float | None:
    """A sub-metric value as a float (booleans and "True" / "False" as 1 / 0);
    None for missing, blank, NaN or text."""
    if isinstance(v, str) and v.strip().lower() in ("true", "false"):
        return float(v.strip().lower() == "true")
    if isinstance(v, bool | int | float | np.number) and finite(v):
        return float(v)
    return None


def _counts(values) -> dict:
    out: dict = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return dict(sorted(out.items()))


def _group(rows, key):
    groups: dict = {}
    for r in rows:
        groups.setdefault(r[key], []).append(r)
    return {g: summary_of(rs, brief=True, ci=len(rs) >= CI_MIN_N) for g, rs in sorted(groups.items())}


BEHAVIOR_ORDER = ("COV", "IPC", "UT", "YLW", "STR", "LFT", "RT", "STP")


def _ci_table(pols: dict, nw: int) -> list[str]:
    """Console lines: SR and DS with their 95 % intervals per policy (none when no policy has them)."""
    if not any("success_rate_ci95" in s["overall"] for s in pols.values()):
        return []
    head = f"{'95% CI':<{nw}}{'SR %':>7}{'SR 95% CI':>16}{'DS':>8}{'DS 95% CI':>16}"
    lines = ["", head, "-" * len(head)]
    for name, s in pols.items():
        o = s["overall"]
        cells = [f"[{o[k][0]:.1f}, {o[k][1]:.1f}]" if k in o else "-"
                 for k in ("success_rate_ci95", "driving_score_ci95")]
        lines.append(f"{name:<{nw}}{o['success_rate']:>7.1f}{cells[0]:>16}{o['driving_score']:>8.2f}{cells[1]:>16}")
    lines.append(f"(SR: Wilson score interval; DS: percentile bootstrap over scenarios, {CI_RESAMPLES} resamples, "
                 f"seed {CI_SEED})")
    return lines


def _cell(o: dict, key: str, width: int, decimals: int) -> str:
    v = o.get(key)
    return f"{v:>{width}.{decimals}f}" if v is not None and finite(v) else f"{'-':>{width}}"


def _collision_table(pols: dict, nw: int, mode: str) -> list[str]:
    """Console lines: DS and SR with all collisions and at-fault only, side by
    side; ``*`` marks the run's collision mode (the headline DS / SR). None
    when no policy's rows carry the attribution columns."""
    if not any("driving_score_all" in s["overall"] or "driving_score_at_fault" in s["overall"]
               for s in pols.values()):
        return []
    mark = {m: "*" if m == mode else "" for m in ("all", "at_fault")}
    cols = ((f"DS{mark['all']}", "driving_score_all", 2), (f"DS at-fault{mark['at_fault']}", "driving_score_at_fault", 2),
            (f"SR %{mark['all']}", "success_rate_all", 1),
            (f"SR at-fault{mark['at_fault']}", "success_rate_at_fault", 1),
            ("coll at-fault", "collisions_at_fault", 0))
    widths = [max(9, len(h) + 2) for h, _, _ in cols]
    head = f"{'collisions':<{nw}}" + "".join(f"{h:>{w}}" for (h, _, _), w in zip(cols, widths))
    lines = ["", head, "-" * len(head)]
    for name, s in pols.items():
        lines.append(f"{name:<{nw}}" + "".join(_cell(s["overall"], k, w, d) for (_, k, d), w in zip(cols, widths)))
    lines.append(f"(* = the run's --collisions {mode}: the DS / SR above; all = every collision with a logged agent "
                 "counts, at-fault = nuPlan's attribution)")
    return lines


def _preset_table(pols: dict, nw: int) -> list[str]:
    """Console lines: the nuPlan score / EPDMS (x100, mean over scenarios) and
    the mean of each sub-metric, one table per preset present in any
    policy's summary; transposed (a row per metric, a column per policy)
    since the sub-metric names are long."""
    lines: list[str] = []
    for score, prefix, title in (("nuplan_score", "nuplan_", "nuPlan score"), ("epdms", "navsim_", "EPDMS")):
        if not any(score in s["overall"] for s in pols.values()):
            continue
        subs = sorted({k for s in pols.values() for k in s["overall"] if k.startswith(prefix) and k != score})
        mw = max(nw, len(title) + 9, *(len(k) - len(prefix) + 4 for k in subs))
        widths = [max(9, len(n) + 2) for n in pols]
        head = f"{title + ' x100':<{mw}}" + "".join(f"{n:>{w}}" for n, w in zip(pols, widths))
        lines += ["", head, "-" * len(head)]
        lines.append(f"{title:<{mw}}" + "".join(_cell(s["overall"], score, w, 2) for s, w in zip(pols.values(), widths)))
        for k in subs:
            lines.append(f"{'  ' + k[len(prefix):]:<{mw}}"
                         + "".join(_cell(s["overall"], k, w, 3) for s, w in zip(pols.values(), widths)))
        lines.append(f"({title}: mean over scenarios x100; indented: sub-metric means over scenarios, "
                     f"columns {prefix}* of scenarios.csv)")
    return lines


def format_tables(summary: dict) -> str:
    """The two tables printed at the end of a run (plain text)."""
    pols = summary["policies"]
    nw = max(18, *(len(n) + 2 for n in pols))  # name column width
    lines = []
    task = summary["run"].get("task", "route_navigation")
    with_task = task != "route_navigation"
    head = f"{'policy':<{nw}}{'SR %':>7}{'DS':>8}{'RC':>8}{'IS':>7}{'coll/km':>9}{'red/km':>8}{'offlane%':>9}{'t/scn s':>9}"
    head += f"{'task SR%':>10}" if with_task else ""
    title = "Closed-loop results (mean over scenarios)" + (f", task {task}" if with_task else "")
    lines += [title, head, "-" * len(head)]
    for name, s in pols.items():
        o = s["overall"]
        lines.append(
            f"{name:<{nw}}{o['success_rate']:>7.1f}{o['driving_score']:>8.2f}{o['route_completion']:>8.2f}"
            f"{o['infraction_score']:>7.3f}{o['collisions_per_km']:>9.3f}{o['red_light_per_km']:>8.3f}"
            f"{o['outside_route_lanes_pct']:>9.2f}{o['eval_time_s']:>9.3f}"
            + (f"{o.get('task_success_rate', float('nan')):>10.1f}" if with_task else "")
        )
    lines += _ci_table(pols, nw)
    lines += _collision_table(pols, nw, summary["run"].get("collisions", "all"))
    lines += _preset_table(pols, nw)
    groups = [g for g in BEHAVIOR_ORDER if any(g in s["by_behavior"] for s in pols.values())]
    head = f"{'SR % by behaviour':<{nw}}" + "".join(f"{g:>7}" for g in groups)
    lines += ["", head, "-" * len(head)]
    for name, s in pols.items():
        cells = "".join(
            f"{s['by_behavior'][g]['success_rate']:>7.1f}" if g in s["by_behavior"] else f"{'-':>7}" for g in groups
        )
        lines.append(f"{name:<{nw}}{cells}")
    head = f"{'DS by behaviour':<{nw}}" + "".join(f"{g:>7}" for g in groups)
    lines += ["", head, "-" * len(head)]
    for name, s in pols.items():
        cells = "".join(
            f"{s['by_behavior'][g]['driving_score']:>7.1f}" if g in s["by_behavior"] else f"{'-':>7}" for g in groups
        )
        lines.append(f"{name:<{nw}}{cells}")
    names = [a for a in ABILITIES if any(a in s["overall"].get("abilities", {}) for s in pols.values())]
    if names:
        aw = max(len(a) for a in names) + 2
        head = f"{'B2D abilities SR %':<{nw}}" + "".join(f"{a:>{aw}}" for a in names) + f"{'mean':>8}"
        lines += ["", head, "-" * len(head)]
        for name, s in pols.items():
            ab = s["overall"].get("abilities", {})
            cells = "".join(f"{100 * ab[a]:>{aw}.1f}" if a in ab else f"{'-':>{aw}}" for a in names)
            lines.append(f"{name:<{nw}}{cells}{100 * ab.get('mean', float('nan')):>8.1f}")
    fine = (
        ("dev m", "position_deviation_mean_m", 8.3),
        ("km/h", "average_speed_kmh", 7.1),
        ("jerk", "jerk_lon_mean_mps3", 7.2),
        ("inv/km", "lane_invasions_per_km", 8.2),
        ("dang%", "front_time_pct_dangerous", 7.1),
        ("smooth%", "smoothness_pct", 9.1),
        ("eff%", "efficiency_pct", 7.1),
    )
    head = f"{'fine-grained':<{nw}}" + "".join(f"{h:>{int(w)}}" for h, _, w in fine)
    lines += ["", head, "-" * len(head)]
    for name, s in pols.items():
        o = s["overall"]
        cells = "".join(
            f"{o[k]:>{w}f}" if k in o else f"{'-':>{int(w)}}" for _, k, w in fine
        )
        lines.append(f"{name:<{nw}}{cells}")
    ol = [(name, s["overall"]) for name, s in pols.items() if "l2_1s_stp3" in s["overall"]]
    if ol:
        head = f"{'open-loop':<{nw}}" + "".join(
            f"{h:>9}" for h in ("L2@1s", "L2@2s", "L2@3s", "L2@1s*", "L2@2s*", "L2@3s*", "coll%")
        )
        lines += ["", head, "-" * len(head)]
        for name, o in ol:
            vals = [o.get(f"l2_{k}s_stp3") for k in (1, 2, 3)] + [o.get(f"l2_{k}s_uniad") for k in (1, 2, 3)]
            vals.append(100 * o["openloop_collision_rate"] if "openloop_collision_rate" in o else None)
            lines.append(f"{name:<{nw}}" + "".join(f"{v:>9.3f}" if v is not None else f"{'-':>9}" for v in vals))
        lines.append("(L2 in m, ST-P3 convention = mean over steps up to t; * = UniAD convention = value at t)")
    n = summary["run"].get("num_scenarios")
    lines.append(f"\n(n = {n} scenarios per policy; group sizes in summary.json)")
    lines.append(
        "fine-grained: lane-centre deviation m, average speed km/h, longitudinal jerk m/s^3, lane invasions/km,"
        " % of time < 6 m behind a vehicle, Bench2Drive smoothness % and efficiency % (docs/metrics.md)"
    )
    return "\n".join(lines)
