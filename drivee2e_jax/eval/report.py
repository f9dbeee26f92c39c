"""The human-readable report of a finished benchmark run (host side).

``write_report(run_dir)`` reads ``summary.json`` and ``scenarios.csv`` of a
results folder (see ``io.results``) and writes, each file atomically:

* ``report.md``: run description; side-by-side policy comparison (with 95 %
  confidence intervals of SR and DS, jerk, Bench2Drive smoothness and
  efficiency); SR and DS per behaviour group (DriveE2E Table 5 order) with
  group sizes; per-intersection and per-weather tables; infraction counts;
  mean ± std of every other numeric per-scenario column; the unsuccessful
  scenarios of each policy (worst first, capped); links to the plots; a
  legend of every code and column abbreviation used.
* ``plots/*.png`` (drawn by ``eval.plots``): SR / DS per behaviour group,
  infractions per km by type, comfort distributions.

Groups of fewer than ``SMALL_GROUP`` scenarios are flagged ``†`` wherever
their size is shown; their intervals are left out (``summary.CI_MIN_N``).

Where the numbers come from:

* One repetition (the usual case): the aggregates are read from
  ``summary.json`` exactly as the run wrote and printed them.
* Several repetitions (rows carry a ``repetition`` or ``seed`` column with
  more than one value): every aggregate is computed per repetition from
  ``scenarios.csv`` with ``summary.summarize``, then shown as
  ``mean ± sample std over repetitions``.

Per-scenario columns of ``scenarios.csv`` are classified generically, so new
columns need no code change: text columns and id-like ones (``*_id``,
``repetition``, ``seed``) are categorical and skipped; the event counts
(``metrics.episode.COUNT_COLUMNS`` and ``EXTRA_COUNTS``) are totalled; every
other numeric column gets a mean ± std row, except ``CSV_ONLY`` ones (a
second jerk definition: the report shows one jerk, defined in the legend).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval import plots
from drivee2e_jax.eval.summary import BEHAVIOR_ORDER, CI_MIN_N, CI_RESAMPLES, CI_SEED, summarize
from drivee2e_jax.files import atomic_write_text, read_json
from drivee2e_jax.metrics.episode import COUNT_COLUMNS

#: Integer columns that are event counts (totals reported), besides the
#: leaderboard's infraction counts (``metrics.episode.COUNT_COLUMNS``).
EXTRA_COUNTS = ("invalid_action", "collisions_cyclist_motorcycle", "lane_invasions")
#: Columns naming a repetition of the whole split, first match wins.
REPETITION_KEYS = ("repetition", "seed")
#: Never treated as numbers, even when their values parse as such.
CATEGORICAL = frozenset({"policy", "scenario_id", "split", "intersection_id", "behavior", "weather",
                         "time_of_day", "status", "id", "index", *REPETITION_KEYS})
#: Shown in the comparison tables; left out of the generic column table.
HEADLINE = frozenset({"route_completion", "infraction_score", "driving_score", "success", "driving_score_all",
                      "driving_score_at_fault", "success_all", "success_at_fault", "infraction_score_all",
                      "infraction_score_at_fault", "nuplan_score", "epdms"})
#: Kept in ``scenarios.csv`` but left out of the report's tables: the Behavior
#: Metrics eq. (2) "jerk" (mean signed speed change per step, m/s), so that the
#: report shows one jerk, ``JERK_COLUMN``.
CSV_ONLY = frozenset({"longitudinal_jerk_mps"})
#: The one jerk of the report: physical longitudinal jerk, mean |Δa|/Δt, m/s³.
JERK_COLUMN = "jerk_lon_mean_mps3"
#: Comfort columns drawn in comfort.png, when present.
COMFORT_COLUMNS = (JERK_COLUMN, "smoothness_pct")
#: Event counts not drawn in infractions_per_km.png (not a driving infraction).
NOT_PLOTTED = frozenset({"invalid_action"})
#: Groups with fewer scenarios than this are flagged "†" (and get no interval).
SMALL_GROUP = CI_MIN_N
#: Unsuccessful scenarios listed per policy.
MAX_FAILED = 20


class _Run:
    """Everything the sections need: run info, typed rows, per-repetition summaries."""

    def __init__(self, run_dir: Path):
        self.dir = run_dir
        summary = _read_json(run_dir / "summary.json", required=True)
        self.info = summary.get("run") or _read_json(run_dir / "run.json")
        self.columns, self.rows = load_rows(run_dir / "scenarios.csv")
        self.rep_key = next((k for k in REPETITION_KEYS if k in self.columns), None)
        self.reps = sorted({r[self.rep_key] for r in self.rows}, key=_num_first) if self.rep_key else []
        self.multi = len(self.reps) > 1
        self.policies = list(summary["policies"]) + sorted({r["policy"] for r in self.rows} - set(summary["policies"]))
        self.summaries = (_rep_summaries(self, summary) if self.multi else  # a policy only in the CSV shows "–"
                          {p: [summary["policies"][p]] if p in summary["policies"] else [] for p in self.policies})
        self.counts, self.others = classify_columns(self.columns, self.rows)

    def rows_of(self, policy: str) -> list[dict]:
        return [r for r in self.rows if r["policy"] == policy]


def write_report(run_dir: Path) -> Path:
    """Write ``report.md`` and ``plots/*.png`` into ``run_dir``; returns the report's path."""

    run_dir = Path(run_dir)
    run = _Run(run_dir)
    images = plots.write_plots(run_dir / "plots", **_plot_data(run))
    sections = [
        _run_section(run),
        _comparison_section(run),
        _behaviour_section(run, images),
        _group_section(run, "by_intersection", "Per intersection"),
        _group_section(run, "by_weather", "Per weather"),
        _counts_section(run, images),
        _other_section(run, images),
        _failed_section(run),
        _notes_section(run),
        _legend_section(run),
    ]
    path = run_dir / "report.md"
    atomic_write_text(path, "\n\n".join(s.strip("\n") for s in sections if s) + "\n")
    return path


# --------------------------------------------------------------------------- data


def load_rows(path: Path) -> tuple[list[str], list[dict]]:
    """``scenarios.csv`` as (columns, rows); numeric columns become floats (blank = NaN).

    The wall-clock columns of ``timing.json`` beside it (results.TIMING_COLUMNS,
    kept out of the CSV so it is deterministic) are joined back onto the rows
    by (policy, scenario_id, repetition).
    """
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        columns, rows = list(reader.fieldnames or []), list(reader)
    _join_timing(Path(path).parent / "timing.json", columns, rows)
    for c in columns:
        if c in CATEGORICAL or c.endswith("_id"):
            continue
        vals = [r.get(c) or "" for r in rows]
        if any(vals) and all(_is_number(v) for v in vals if v):
            for r, v in zip(rows, vals):
                r[c] = float(v) if v else math.nan
    return columns, rows


def _join_timing(path: Path, columns: list[str], rows: list[dict]) -> None:
    """Add ``timing.json``'s columns to ``rows`` in place (missing file: nothing)."""
    if not path.is_file():
        return
    try:
        timing = read_json(path)["rows"]
        by_key = {(str(t["policy"]), str(t["scenario_id"]), int(float(t.get("repetition") or 0))): t
                  for t in timing}
    except (ValueError, KeyError, TypeError, AttributeError):
        raise DriveE2EError(f"{path}: expected {{\"rows\": [{{\"policy\", \"scenario_id\", \"repetition\", "
                            f"...}}]}}; delete it and rerun the bench to rewrite it") from None
    added: list[str] = []
    for r in rows:
        t = by_key.get((str(r.get("policy")), str(r.get("scenario_id")), int(float(r.get("repetition") or 0))))
        for k, v in (t or {}).items():
            if k not in ("policy", "scenario_id", "repetition"):
                r[k] = "" if v is None else str(v)
                if k not in columns and k not in added:
                    added.append(k)
    columns += added


def classify_columns(columns: list[str], rows: list[dict]) -> tuple[list[str], list[str]]:
    """(event-count columns, other numeric columns) among the non-headline numeric ones."""
    counts, others = [], []
    for c in columns:
        vals = [r[c] for r in rows]
        if c in HEADLINE or not vals or not all(isinstance(v, float) for v in vals):
            continue
        if c not in CSV_ONLY:
            (counts if c in COUNT_COLUMNS or c in EXTRA_COUNTS else others).append(c)
    return counts, others


def _rep_summaries(run: _Run, summary: dict) -> dict[str, list[dict]]:
    """Per policy, one ``summary.summarize`` entry per repetition (policies missing a repetition skip it)."""

    out: dict[str, list[dict]] = {p: [] for p in run.policies}
    for rep in run.reps:
        rows = {p: [r for r in run.rows_of(p) if r[run.rep_key] == rep] for p in run.policies}
        s = summarize({p: rs for p, rs in rows.items() if rs}, run.info)
        for p, ps in s["policies"].items():
            if "outside_route_lanes_pct" not in run.columns:  # not in the CSV: unknown, not 0
                ps["overall"]["outside_route_lanes_pct"] = None
            out[p].append(ps)
    return out


def _plot_data(run: _Run) -> dict:
    groups = _behaviour_groups(run)
    by = {m: {p: [_stats([s["by_behavior"].get(g, {}).get(m) for s in run.summaries[p]]) for g in groups]
              for p in run.policies} for m in ("success_rate", "driving_score")}
    comfort = {c: {p: _finite(run.rows_of(p), c) for p in run.policies} for c in COMFORT_COLUMNS if c in run.others}
    kinds = [c for c in run.counts if c not in NOT_PLOTTED]
    rates = {c: {p: _stats(_per_rep(run, p, lambda rs, c=c: per_km(rs, c))) for p in run.policies} for c in kinds}
    return {"policies": run.policies, "groups": groups, "sizes": [_group_size(run, "by_behavior", g) for g in groups],
            "sr": by["success_rate"], "ds": by["driving_score"], "infractions": rates, "comfort": comfort,
            "repetitions": len(run.reps)}


def per_km(rows: list[dict], col: str) -> float:
    """Events of ``col`` per km driven over ``rows`` (LB 2.0: km = Σ length · RC / 100, floored at 1 m)."""
    km = sum(r["route_length_m"] * r["route_completion"] / 100.0 for r in rows) / 1000.0
    return sum(r[col] for r in rows if not math.isnan(r[col])) / max(km, 0.001)


# --------------------------------------------------------------------------- sections


def _run_section(run: _Run) -> str:
    i = run.info
    n_rows = {p: len(run.rows_of(p)) for p in run.policies}
    lines = [
        f"# Benchmark report: {i.get('suite', '?')} / {i.get('split', '?')}",
        "",
        f"* Suite **{i.get('suite', '?')}** v{i.get('suite_version', '?')}, split **{i.get('split', '?')}**, "
        f"scoring preset **{i.get('preset', '?')}**, collisions counted: **{i.get('collisions', 'all')}**, "
        f"other agents: **{i.get('agents', 'log')}**",
        f"* {i.get('num_scenarios', '?')} scenarios × {len(run.policies)} policies "
        f"({', '.join(f'`{p}`' for p in run.policies)}); {len(run.rows)} episode rows in `scenarios.csv`",
        f"* Simulation: dt {i.get('dt', '?')} s, control every {i.get('control_every', '?')} step(s), "
        f"latency {i.get('latency', '?')} step(s), seed {i.get('seed', '?')}",
    ]
    if run.multi:
        lines.append(f"* **{len(run.reps)} repetitions** (`{run.rep_key}` = {', '.join(run.reps)}): "
                     "every aggregate below is *mean ± sample std over repetitions*, each computed per repetition")
    elif run.rep_key:
        lines.append(f"* One repetition (`{run.rep_key}` = {run.reps[0] if run.reps else '?'})")
    if len(set(n_rows.values())) > 1:
        lines.append("* Rows per policy differ: " + ", ".join(f"`{p}` {n}" for p, n in n_rows.items()))
    lines.append("* Codes, statuses and column abbreviations: see [Legend](#legend) at the end")
    return "\n".join(lines)


_OVERALL = (  # (label, key in summary["overall"], decimals); a key ending in _ci95 is an interval
    ("Scenarios", "num_scenarios", 0),
    ("Success rate SR %", "success_rate", 1),
    ("SR 95 % CI", "success_rate_ci95", 1),
    ("Driving score DS", "driving_score", 2),
    ("DS 95 % CI", "driving_score_ci95", 2),
    ("DS std over scenarios", "driving_score_std", 2),
    ("Route completion RC %", "route_completion", 2),
    ("Infraction score IS", "infraction_score", 3),
    ("km driven", "km_driven", 2),
    ("Collisions / km", "collisions_per_km", 3),
    ("Red lights / km", "red_light_per_km", 3),
    ("Off-lane %", "outside_route_lanes_pct", 2),
    ("Invalid-action steps", "invalid_action_steps", 0),
    ("Jerk m/s³", JERK_COLUMN, 2),
    ("B2D smoothness %", "smoothness_pct", 1),
    ("B2D efficiency %", "efficiency_pct", 1),
)


def _attribution_metrics(run: _Run) -> list[tuple[str, str, int]]:
    """(label, summary key, decimals) of the collision-attribution and
    nuplan / navsim rows present in any policy's summary (``summary.
    collision_means`` / ``preset_means``); the run's ``collisions`` mode is
    marked "(chosen)". Older folders: none."""
    mode = run.info.get("collisions", "all")
    chosen = {m: " (chosen)" if m == mode else "" for m in ("all", "at_fault")}
    out = [(f"DS, all collisions{chosen['all']}", "driving_score_all", 2),
           (f"DS, at-fault collisions only{chosen['at_fault']}", "driving_score_at_fault", 2),
           (f"SR %, all collisions{chosen['all']}", "success_rate_all", 1),
           (f"SR %, at-fault collisions only{chosen['at_fault']}", "success_rate_at_fault", 1),
           ("Collisions at fault", "collisions_at_fault", 0),
           ("nuPlan score ×100", "nuplan_score", 2), ("NAVSIM EPDMS ×100", "epdms", 2)]
    keys = {k for p in run.policies for s in run.summaries[p] for k in s["overall"]}
    subs = sorted(k for k in keys if k.startswith(("nuplan_", "navsim_")) and k != "nuplan_score")
    return [m for m in out if m[1] in keys] + [(f"{k} (mean)", k, 3) for k in subs]


def _comparison_section(run: _Run) -> str:
    rows = [[label] + [_cell_of(run, [s["overall"] for s in run.summaries[p]], key, d) for p in run.policies]
            for label, key, d in (*_OVERALL, *_attribution_metrics(run)) if not (run.multi and key.endswith("_ci95"))]
    statuses = sorted({k for p in run.policies for s in run.summaries[p] for k in s["overall"].get("statuses", {})},
                      key=lambda k: (_status_rank(k), k))
    rows += [[f"status: {k}"] + [_fmt([s["overall"].get("statuses", {}).get(k, 0) for s in run.summaries[p]], 0)
                                 for p in run.policies] for k in statuses]
    return "## Policy comparison\n\n" + _table(["metric", *run.policies], rows, ("l",) + ("r",) * len(run.policies))


def _behaviour_section(run: _Run, images: dict[str, str]) -> str:
    groups = _behaviour_groups(run)
    if not groups:
        return ""
    head = ["policy"] + [f"{g} (n={_n(_group_size(run, 'by_behavior', g))})" for g in groups] + ["mean of groups"]
    out = ["## Per behaviour group (DriveE2E Table 5 order)"]
    for key, title, d, img in (("success_rate", "Success rate SR %", 1, "sr_by_behavior"),
                               ("driving_score", "Driving score DS", 2, "ds_by_behavior")):
        rows = []
        for p in run.policies:
            per_group = [[s["by_behavior"].get(g, {}) for s in run.summaries[p]] for g in groups]
            macro = [_mean([e[key] for e in rep if key in e]) for rep in zip(*per_group)]
            rows.append([f"`{p}`"] + [_cell_of(run, v, key, d, ci=True) for v in per_group] + [_fmt(macro, d)])
        out += [f"### {title}", _table(head, rows, ("l",) + ("r",) * (len(head) - 1)), _image(images, img, title)]
    return "\n\n".join(out + _small_note(run, [_group_size(run, "by_behavior", g) for g in groups]))


def _group_section(run: _Run, key: str, title: str) -> str:
    groups = sorted({g for p in run.policies for s in run.summaries[p] for g in s.get(key, {})}, key=_num_first)
    if not groups:
        return ""
    head = ["group", "n"] + [f"{p} {m}" for p in run.policies for m in ("SR %", "DS")]
    rows = [[g, _n(_group_size(run, key, g))]
            + [_cell_of(run, [s[key].get(g, {}) for s in run.summaries[p]], m, d, ci=True)
               for p in run.policies for m, d in (("success_rate", 1), ("driving_score", 2))] for g in groups]
    note = _small_note(run, [_group_size(run, key, g) for g in groups])
    return "\n\n".join([f"## {title}", _table(head, rows, ("l",) + ("r",) * (len(head) - 1)), *note])


def _counts_section(run: _Run, images: dict[str, str]) -> str:
    if not run.counts:
        return ""
    totals = {c: {p: _per_rep(run, p, lambda rs, c=c: sum(r[c] for r in rs if not math.isnan(r[c])))
                  for p in run.policies} for c in run.counts}
    nonzero = [c for c in run.counts if any(any(totals[c][p]) for p in run.policies)]
    zero = [c for c in run.counts if c not in nonzero]
    what = "total per repetition, mean ± std" if run.multi else "total over scenarios"
    out = [f"## Infraction and event counts ({what})"]
    if nonzero:
        rows = [[f"`{c}`"] + [_fmt(totals[c][p], 1 if run.multi else 0) for p in run.policies] for c in nonzero]
        out.append(_table(["column", *run.policies], rows, ("l",) + ("r",) * len(run.policies)))
    if zero:
        out.append("Zero for every policy: " + ", ".join(f"`{c}`" for c in zero) + ".")
    out.append(_image(images, "infractions_per_km", "Infractions and events per km driven"))
    return "\n\n".join(out)


def _other_section(run: _Run, images: dict[str, str]) -> str:
    out = ["## Other per-scenario columns"]
    if run.multi:
        out.append("Mean over scenarios, computed per repetition; ± is the std of that mean over repetitions.")
        cell = lambda p, c, d: _fmt(_per_rep(run, p, lambda rs: _mean(_finite(rs, c))), d)  # noqa: E731
    else:
        out.append("Mean ± sample std over scenarios.")
        cell = lambda p, c, d: _fmt_spread(_finite(run.rows_of(p), c), d)  # noqa: E731
    if run.others:
        rows = [[f"`{c}`"] + [cell(p, c, _decimals(run, c)) for p in run.policies] for c in run.others]
        out.append(_table(["column", *run.policies], rows, ("l",) + ("r",) * len(run.policies)))
    out.append(_image(images, "comfort", "Comfort per episode: jerk and Bench2Drive smoothness"))
    return "\n\n".join(out)


def _failed_section(run: _Run) -> str:
    out = [f"## Unsuccessful scenarios (worst {MAX_FAILED} per policy by DS)"]
    rep = [run.rep_key] if run.multi else []
    head = ["scenario", *rep, "behaviour", "intersection", "weather", "status", "RC", "DS", "infractions"]
    for p in run.policies:
        rows = run.rows_of(p)
        failed = sorted((r for r in rows if not r.get("success")),
                        key=lambda r: (r["driving_score"], r["route_completion"], r["scenario_id"]))
        shown = f"; the {MAX_FAILED} worst shown" if len(failed) > MAX_FAILED else ""
        out.append(f"### `{p}`: {len(failed)} of {len(rows)} episodes unsuccessful{shown}")
        cells = [[r["scenario_id"], *(r[k] for k in rep), r.get("behavior", ""), r.get("intersection_id", ""),
                  r.get("weather", ""), r["status"], f"{r['route_completion']:.1f}", f"{r['driving_score']:.2f}",
                  _infractions(run, r)] for r in failed[:MAX_FAILED]]
        if cells:
            out.append(_table(head, cells, ("l",) * (len(head) - 3) + ("r", "r", "l")))
    return "\n\n".join(out)


def _notes_section(run: _Run) -> str:
    source = (f"computed per repetition from `scenarios.csv` ({len(run.reps)} repetitions), "
              "shown as mean ± sample std over repetitions" if run.multi
              else "read from `summary.json` (one repetition: plain values, no ±)")
    return "\n".join([
        "## How to read this",
        "",
        f"* Aggregates are {source}.",
        "* Per-km rates follow CARLA Leaderboard 2.0 global statistics (entries / km driven, km = length × RC); "
        "the infraction plot uses the same rule for every event column.",
        "* Event counts: non-negative integer columns of `scenarios.csv`; 'other columns': every remaining "
        "numeric one (id-like and text columns are skipped, and `longitudinal_jerk_mps`: one jerk is shown).",
        "* Plots show only what depends on the policy: SR / DS per behaviour group, infractions per km by type, "
        "comfort (jerk, Bench2Drive smoothness) per episode.",
    ])


# --------------------------------------------------------------------------- helpers


#: DriveE2E's behaviour groups (paper, Table 5) and how a scenario gets its
#: label (twin15: verified from the logged ego, docs/twin15.md; imported
#: suites: inferred from the log with the same thresholds, scenario/labels.py).
BEHAVIOR_HELP = {
    "COV": "Competing with Other Vehicles: a vehicle on a conflicting path from another approach is in the "
           "junction while the ego waits at its stop line or crosses",
    "IPC": "Interaction with Pedestrians and Cyclists: a pedestrian or cyclist is on a crosswalk the ego's path "
           "crosses while the ego is within ~25 m before it",
    "UT": "Making a U-turn: heading change through the junction > 150°",
    "YLW": "Passing through during Yellow Lights: the ego crosses its stop line on yellow",
    "STR": "Going Straight through the intersection: heading change < 40°, on green",
    "LFT": "Making a Left Turn: heading change > 40° to the left",
    "RT": "Making a Right Turn: heading change > 40° to the right",
    "STP": "Stopping at Red Lights: the ego stops (< 0.1 m/s) at its stop line on red, then goes on green",
}
#: The leaderboard statuses (``metrics.driving_score.STATUS_NAMES``).
STATUS_HELP = {
    "Perfect": "route completed, no infraction entry at all",
    "Completed": "route completed with at least one infraction entry (still a success if all are min-speed ones)",
    "Failed": "not completed, no other reason recorded",
    "Failed - Agent timed out": "the route timeout ran out (300 s + route length / 1.39 m/s)",
    "Failed - Agent deviated from the route": ">= 30 m from the route, or > 30 % of it driven 15-30 m off",
    "Failed - Agent got blocked": "speed < 0.1 m/s for longer than 60 s (180 s in lb20)",
    "Failed - TickRuntime": "cut by the time cap or the end of the replay log before the route was completed",
}
#: Per-scenario columns of ``scenarios.csv`` (docs/metrics.md); listed in the legend when the report shows them.
COLUMN_HELP = {
    "collisions_pedestrian": "collisions with pedestrians (IS × 0.50 each)",
    "collisions_vehicle": "collisions with vehicles, bicycles and motorcycles included (IS × 0.60 each)",
    "collisions_layout": "collisions with static obstacles (IS × 0.65 each)",
    "red_light": "red lights run (IS × 0.70 each)",
    "outside_route_lanes": "entries driving outside the route lanes (IS × (1 − off-lane %/100))",
    "min_speed_infractions": "min-speed checkpoints below the surrounding traffic's speed (penalised only in "
                             "presets with min speed on)",
    "route_dev": "route deviations (ends the episode)",
    "vehicle_blocked": "blocked events (ends the episode)",
    "route_timeout": "route timeouts",
    "invalid_action": "steps with a NaN/inf or out-of-range action (repaired: NaN → full brake, others clipped)",
    "collisions_cyclist_motorcycle": "the vehicle collisions whose other party is a cyclist or motorcyclist",
    "lane_invasions": "crossings of a painted lane marking (the corners of one lane change count once)",
    "route_length_m": "route length, m",
    "episode_s": "simulated episode length, s",
    "eval_time_s": "wall-clock evaluation time per scenario, s",
    "route_speed_limit_kmh": "mean speed limit along the route, km/h",
    "outside_route_lanes_pct": "% of the route distance driven outside the route lanes",
    "outside_route_lanes_m": "route distance driven outside the route lanes, m",
    "position_deviation_mean_m": "mean distance to the centre of the lane being driven, m",
    "effective_completed_distance_m": "RC × route length, m",
    "completed_distance_m": "length of the path driven, m",
    "average_speed_kmh": "mean speed, km/h",
    "collisions_per_km": "collisions per effective km (Behavior Metrics)",
    "lane_invasions_per_km": "lane invasions per effective km",
    "front_time_pct_great": "% of time with the nearest agent ahead in the ego's corridor at 20-50 m",
    "front_time_pct_medium": "% of time with it at 15-20 m",
    "front_time_pct_short": "% of time with it at 6-15 m",
    "front_time_pct_dangerous": "% of time with it at 0-6 m",
    JERK_COLUMN: "**the** jerk of this report: mean over the steps driven of |Δa|/Δt of the ego's longitudinal "
                 "acceleration, m/s³ (Behavior Metrics' eq. (2) 'jerk', `longitudinal_jerk_mps`, a mean signed "
                 "speed change per step, stays in `scenarios.csv` only)",
    "smoothness_pct": "Bench2Drive smoothness: % of 20-step chunks whose Savitzky-Golay smoothed lon/lat "
                      "acceleration, jerks and yaw rate stay within B2D's bounds",
    "efficiency_pct": "Bench2Drive efficiency: mean over the route's min-speed checkpoints of ego speed / speed of "
                      "the surrounding vehicles, % (values > 1000 % ignored; > 100 % = faster than the traffic "
                      "around, normal at signals where queued vehicles count; – = no checkpoint reached)",
    "task_success": "1 if the driving task's success rule holds (`--task`)",
    "l2_1s_stp3": "open-loop L2 at 1 s, m (ST-P3: mean over the steps up to 1 s)",
    "l2_2s_stp3": "open-loop L2 at 2 s, m (ST-P3)",
    "l2_3s_stp3": "open-loop L2 at 3 s, m (ST-P3)",
    "l2_1s_uniad": "open-loop L2 at 1 s, m (UniAD: the value at 1 s)",
    "l2_2s_uniad": "open-loop L2 at 2 s, m (UniAD)",
    "l2_3s_uniad": "open-loop L2 at 3 s, m (UniAD)",
    "openloop_collision_rate": "open-loop collision rate of the predicted waypoints",
    "openloop_samples": "open-loop queries scored",
    "collisions_at_fault": "agent / layout collisions the ego is at fault for (nuPlan's attribution: a stopped "
                           "agent, rear-ending, or a lateral contact while in several lanes or off the drivable "
                           "area; layout always)",
}
#: The report's own abbreviations (comparison table, group tables).
ABBREVIATIONS = (
    ("n", "scenarios in the group (per repetition)"),
    ("SR %", "success rate: % of scenarios Perfect or Completed with no infraction entry except min-speed"),
    ("DS", "driving score: mean over scenarios of RC × IS, 0-100 (DriveE2E merge)"),
    ("RC %", "route completion: % of the route driven"),
    ("IS", "infraction score: product of the per-infraction factors, 1 = none"),
    ("95 % CI", f"95 % confidence interval: SR by the Wilson score interval; DS by a percentile bootstrap of the "
                f"mean over scenarios ({CI_RESAMPLES} resamples, seed {CI_SEED}); shown for groups of at least "
                f"{CI_MIN_N} scenarios and one repetition, as [low, high]"),
    ("DS std over scenarios", "sample std of the per-scenario DS (LB 2.0's scores_std_dev)"),
    ("km driven", "Σ route length × RC, km"),
    ("Collisions / km, Red lights / km", "LB 2.0 rates: events / km driven"),
    ("Off-lane %", "mean % of the route driven outside the route lanes"),
    ("Invalid-action steps", "steps whose action was NaN/inf or out of range (repaired)"),
    ("Jerk m/s³", f"mean over scenarios of `{JERK_COLUMN}` (below)"),
    ("B2D smoothness %, B2D efficiency %", "Bench2Drive smoothness and efficiency (below; efficiency: B2D's "
                                           "mean over routes)"),
    ("mean of groups", "unweighted mean over the behaviour groups present (cf. DriveE2E's ability mean)"),
    ("DS / SR %, all collisions; at-fault collisions only",
     "DS and SR with every collision with a logged agent counted, and with only the at-fault ones (nuPlan's "
     "attribution, `collisions_at_fault`); (chosen) = this run's `--collisions`, the DS / SR above"),
    ("nuPlan score ×100, NAVSIM EPDMS ×100", "preset nuplan / navsim headline scores: mean over scenarios of the "
                                              "per-scenario score (0-1) × 100; `nuplan_*` / `navsim_*` rows: means "
                                              "of the sub-metrics"),
    ("†", f"fewer than {SMALL_GROUP} episodes in the group: a noisy estimate, no confidence interval"),
    ("–", "no value (nothing to average, or not in this run's data)"),
)


def _legend_section(run: _Run) -> str:
    """Behaviour codes, statuses and every column or abbreviation the tables above use."""
    groups = _behaviour_groups(run)
    statuses = sorted({r["status"] for r in run.rows}, key=lambda k: (_status_rank(k), k))
    shown = [c for c in (*run.counts, *run.others, "efficiency_pct") if c in COLUMN_HELP and c in run.columns]
    out = ["## Legend"]
    if groups:
        out += ["**Behaviour groups** (DriveE2E's eight; docs/twin15.md)",
                _table(["code", "meaning"], [[g, BEHAVIOR_HELP.get(g, "(not a DriveE2E group)")] for g in groups],
                       ("l", "l"))]
    out += ["**Statuses** (CARLA leaderboard; success = Perfect or Completed with no infraction entry except "
            "min-speed)",
            _table(["status", "meaning"], [[k, STATUS_HELP.get(k, "")] for k in statuses], ("l", "l")),
            "**Abbreviations**",
            _table(["abbreviation", "meaning"], [list(a) for a in ABBREVIATIONS], ("l", "l"))]
    if run.multi:
        out.append("With repetitions, `a ± b` is the mean ± sample std over repetitions.")
    if shown:
        out += ["**Columns** (of `scenarios.csv`; docs/metrics.md)",
                _table(["column", "meaning"], [[f"`{c}`", COLUMN_HELP[c]] for c in dict.fromkeys(shown)],
                       ("l", "l"))]
    return "\n\n".join(out)


def _cell_of(run: _Run, entries: list[dict], key: str, decimals: int, ci: bool = False) -> str:
    """``key`` of one summary entry per repetition: a value, ``mean ± std`` or, for a ``*_ci95`` key, ``[lo, hi]``.

    ``ci``: append the entry's ``<key>_ci95`` interval where it has one (one repetition only)."""
    if key.endswith("_ci95"):
        lo_hi = entries[0].get(key) if len(entries) == 1 else None
        return f"[{lo_hi[0]:.{decimals}f}, {lo_hi[1]:.{decimals}f}]" if lo_hi else "–"
    cell = _fmt([e.get(key) for e in entries], decimals)
    if ci and not run.multi and entries and f"{key}_ci95" in entries[0]:
        cell += " " + _cell_of(run, entries, f"{key}_ci95", decimals)
    return cell


def _n(size: int) -> str:
    """A group size, flagged ``†`` below ``SMALL_GROUP``."""
    return f"{size} †" if size < SMALL_GROUP else str(size)


def _small_note(run: _Run, sizes: list[int]) -> list[str]:
    """The ``†`` footnote, when a size is flagged; a note on the intervals shown."""
    out = []
    if any(n >= SMALL_GROUP for n in sizes) and not run.multi:
        out.append(f"[low, high]: 95 % confidence interval (groups of {SMALL_GROUP} or more scenarios).")
    if any(n < SMALL_GROUP for n in sizes):
        out.append(f"† fewer than {SMALL_GROUP} episodes: a noisy estimate, no confidence interval.")
    return out


def _behaviour_groups(run: _Run) -> list[str]:
    present = {g for p in run.policies for s in run.summaries[p] for g in s.get("by_behavior", {})}
    return [g for g in BEHAVIOR_ORDER if g in present] + sorted(present - set(BEHAVIOR_ORDER))


def _group_size(run: _Run, key: str, group: str) -> int:
    """Scenarios of ``group`` in one repetition (the largest over policies)."""
    return max((s.get(key, {}).get(group, {}).get("num_scenarios", 0) for p in run.policies
                for s in run.summaries[p][:1]), default=0)


def _per_rep(run: _Run, policy: str, fn) -> list[float]:
    """``fn(rows)`` per repetition of ``policy`` (one value without repetitions)."""
    rows = run.rows_of(policy)
    if not run.multi:
        return [fn(rows)] if rows else []
    return [fn(rs) for rep in run.reps if (rs := [r for r in rows if r[run.rep_key] == rep])]


def _infractions(run: _Run, row: dict) -> str:
    found = [f"{c} {int(row[c])}" for c in run.counts if not math.isnan(row[c]) and row[c] > 0]
    return ", ".join(found) or "—"


def _decimals(run: _Run, col: str) -> int:
    vals = [abs(v) for v in _finite(run.rows, col)]
    top = max(vals, default=0.0)
    return 1 if top >= 100 else 2 if top >= 1 else 4


def _fmt(values, decimals: int) -> str:
    """One value as is, several as ``mean ± sample std`` (counts then get a decimal); ``–`` when there is none."""
    vals = [float(v) for v in values if v is not None and not math.isnan(float(v))]
    if not vals:
        return "–"
    if len(vals) == 1:
        return f"{vals[0]:.{decimals}f}"
    decimals = max(decimals, 1)
    return f"{_mean(vals):.{decimals}f} ± {_std(vals):.{decimals}f}"


def _fmt_spread(vals: list[float], decimals: int) -> str:
    """Mean ± sample std of ``vals`` (both shown even for one value)."""
    if not vals:
        return "–"
    return f"{_mean(vals):.{decimals}f} ± {_std(vals):.{decimals}f}"


def _finite(rows: list[dict], col: str) -> list[float]:
    return [r[col] for r in rows if isinstance(r.get(col), float) and math.isfinite(r[col])]


def _mean(vals) -> float:
    vals = list(vals)
    return sum(vals) / len(vals) if vals else math.nan


def _std(vals) -> float:
    """Sample std (divisor n - 1); 0 for a single value."""
    vals = list(vals)
    if len(vals) < 2:
        return 0.0
    m = _mean(vals)
    return math.sqrt(sum((v - m) ** 2 for v in vals) / (len(vals) - 1))


def _stats(values) -> tuple[float, float] | None:
    vals = [v for v in values if v is not None]
    return (_mean(vals), _std(vals)) if vals else None


def _table(head: list[str], rows: list[list], align) -> str:
    sep = {"l": ":--", "r": "--:"}
    lines = ["| " + " | ".join(_cell(h) for h in head) + " |", "|" + "|".join(sep[a] for a in align) + "|"]
    lines += ["| " + " | ".join(_cell(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _cell(v) -> str:
    return str(v).replace("|", "\\|").replace("\n", " ")


def _image(images: dict[str, str], key: str, alt: str) -> str:
    return f"![{alt}]({images[key]})" if key in images else ""


def _status_rank(status: str) -> int:
    return 0 if status == "Perfect" else 1 if status == "Completed" else 2


def _num_first(v: str):
    """Sort key: numeric strings by value, before the rest."""
    return (0, float(v), "") if _is_number(v) else (1, 0.0, v)


def _is_number(v: str) -> bool:
    try:
        float(v)
    except (TypeError, ValueError):
        return False
    return True


def _read_json(path: Path, required: bool = False) -> dict:
    """A JSON file of the results folder ({} when missing and not ``required``);
    DriveE2EError (one line) when unreadable, not JSON or with a repeated key."""
    if not required and not path.exists():
        return {}
    try:
        return read_json(path)
    except (OSError, ValueError) as e:
        raise DriveE2EError(f"{e}" if isinstance(e, ValueError) else f"{path}: unreadable ({e})") from None
