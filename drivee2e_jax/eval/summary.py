"""Aggregates of a run's per-scenario rows and the console tables.

``summarize`` turns the rows of every policy into ``summary.json``'s content
(overall, per behaviour group, intersection and weather); ``summary_of`` is the
aggregate of one set of rows (SR, DS, RC, IS, LB 2.0 per-km rates, Bench2Drive
efficiency and multi-ability, fine-grained means, open-loop means);
``format_tables`` prints them. Host side, plain Python + numpy.
"""

from __future__ import annotations

import math

import numpy as np

from drivee2e_jax.metrics.aggregate import RouteResult, b2d_efficiency, drivee2e_merge, lb_global
from drivee2e_jax.metrics.driving_score import INFRACTION_KEYS
from drivee2e_jax.metrics.finegrained import SUMMARY_COLUMNS

#: Per-scenario open-loop columns (``openloop.evaluate_openloop``).
OPEN_LOOP_COLUMNS = (
    "l2_1s_stp3", "l2_2s_stp3", "l2_3s_stp3", "l2_1s_uniad", "l2_2s_uniad", "l2_3s_uniad",
    "openloop_collision_rate", "openloop_samples",
)


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


def summary_of(rows: list[dict], brief: bool = False) -> dict:
    """SR / DS / RC / IS over ``rows`` plus LB 2.0 per-km infraction rates.

    SR and DS follow DriveE2E's merge (sum over the scenarios run / their
    number; SR in %); per-km rates follow LB 2.0's global statistics.
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
    if "task_success" in rows[0]:
        out["task_success_rate"] = round(100.0 * float(np.mean([bool(r["task_success"]) for r in rows])), 4)
    if brief:
        return out
    out["abilities"] = ability_scores(rows)
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
    if any(r.min_speed_pct for r in recs):
        out["efficiency_pct"] = round(b2d_efficiency(recs), 4)
    return out


#: Bench2Drive's five abilities mapped onto the source's behaviour groups
#: (B2D maps its own scenario types; ours is a judgement from the labels'
#: meaning, docs/metrics.md): Merging = entering or crossing a conflicting
#: stream (competing vehicles, left and right turns); Emergency_Brake =
#: something may appear in the path (pedestrians / cyclists, competing
#: vehicles); Give_Way = yielding (pedestrians / cyclists, unprotected left
#: turns, U-turns); Traffic_Signs = obeying signals (red-light stops, yellow
#: passes, straight through on the signal); Overtaking has no group here.
ABILITIES = {
    "Merging": ("COV", "LFT", "RT"),
    "Overtaking": (),
    "Emergency_Brake": ("IPC", "COV"),
    "Give_Way": ("IPC", "LFT", "UT"),
    "Traffic_Signs": ("STP", "YLW", "STR"),
}


def ability_scores(rows: list[dict]) -> dict:
    """Bench2Drive multi-ability success rates (%), by ``ABILITIES``.

    Per ability: successes / scenarios of its behaviour groups (B2D's
    ``ability_benchmark``, same success test as SR); abilities without a
    scenario are left out; ``mean`` averages the abilities present (B2D
    averages its five). Returns {} when no row has a mapped group.
    """
    out = {}
    for ability, groups in ABILITIES.items():
        sel = [r for r in rows if r["behavior"] in groups]
        if sel:
            out[ability] = round(100.0 * float(np.mean([bool(r["success"]) for r in sel])), 4)
    if out:
        out["mean"] = round(float(np.mean(list(out.values()))), 4)
    return out


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


def _counts(values) -> dict:
    out: dict = {}
    for v in values:
        out[v] = out.get(v, 0) + 1
    return dict(sorted(out.items()))


def _group(rows, key):
    groups: dict = {}
    for r in rows:
        groups.setdefault(r[key], []).append(r)
    return {g: summary_of(rs, brief=True) for g, rs in sorted(groups.items())}


BEHAVIOR_ORDER = ("COV", "IPC", "UT", "YLW", "STR", "LFT", "RT", "STP")


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
            cells = "".join(f"{ab[a]:>{aw}.1f}" if a in ab else f"{'-':>{aw}}" for a in names)
            lines.append(f"{name:<{nw}}{cells}{ab.get('mean', float('nan')):>8.1f}")
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
