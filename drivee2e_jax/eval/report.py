"""The human-readable report of a finished benchmark run (host side).

``write_report(run_dir)`` reads ``summary.json`` and ``scenarios.csv`` of a
results folder (see ``io.results``) and writes, each file atomically:

* ``report.md``: run description; side-by-side policy comparison; SR and DS
  per behaviour group (DriveE2E Table 5 order) with group sizes;
  per-intersection and per-weather tables; infraction counts; mean ± std of
  every other numeric per-scenario column; the unsuccessful scenarios of each
  policy (worst first, capped); links to the plots.
* ``plots/*.png`` (drawn by ``io.plots``).

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
other numeric column gets a mean ± std row.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from drivee2e_jax.eval import plots
from drivee2e_jax.eval.results import BASE_COLUMNS
from drivee2e_jax.eval.summary import BEHAVIOR_ORDER, summarize
from drivee2e_jax.files import atomic_write_text
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
HEADLINE = frozenset({"route_completion", "infraction_score", "driving_score", "success"})
#: Unsuccessful scenarios listed per policy.
MAX_FAILED = 20
#: Extra numeric columns drawn next to DS and RC in metric_distributions.png.
MAX_DIST_COLUMNS = 6


class _Run:
    """Everything the sections need: run info, typed rows, per-repetition summaries."""

    def __init__(self, run_dir: Path):
        self.dir = run_dir
        summary = json.loads((run_dir / "summary.json").read_text())
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
        _counts_section(run),
        _other_section(run, images),
        _failed_section(run),
        _notes_section(run),
    ]
    path = run_dir / "report.md"
    atomic_write_text(path, "\n\n".join(s.strip("\n") for s in sections if s) + "\n")
    return path


# --------------------------------------------------------------------------- data


def load_rows(path: Path) -> tuple[list[str], list[dict]]:
    """``scenarios.csv`` as (columns, rows); numeric columns become floats (blank = NaN)."""
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        columns, rows = list(reader.fieldnames or []), list(reader)
    for c in columns:
        if c in CATEGORICAL or c.endswith("_id"):
            continue
        vals = [r.get(c) or "" for r in rows]
        if any(vals) and all(_is_number(v) for v in vals if v):
            for r, v in zip(rows, vals):
                r[c] = float(v) if v else math.nan
    return columns, rows


def classify_columns(columns: list[str], rows: list[dict]) -> tuple[list[str], list[str]]:
    """(event-count columns, other numeric columns) among the non-headline numeric ones."""
    counts, others = [], []
    for c in columns:
        vals = [r[c] for r in rows]
        if c in HEADLINE or not vals or not all(isinstance(v, float) for v in vals):
            continue
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
    varying = [c for c in sorted(run.others, key=lambda c: c in BASE_COLUMNS) if _varies(run, c)]
    cols = ["driving_score", "route_completion"] + varying[:MAX_DIST_COLUMNS]
    dists = {c: {p: [r[c] for r in run.rows_of(p) if not math.isnan(r[c])] for p in run.policies} for c in cols}
    return {"policies": run.policies, "groups": groups, "sizes": [_group_size(run, "by_behavior", g) for g in groups],
            "sr": by["success_rate"], "ds": by["driving_score"], "distributions": dists, "repetitions": len(run.reps)}


def _varies(run: _Run, col: str) -> bool:
    """Whether ``col`` takes more than one value within some policy (else a box plot says nothing)."""
    return any(len({r[col] for r in run.rows_of(p) if not math.isnan(r[col])}) > 1 for p in run.policies)


# --------------------------------------------------------------------------- sections


def _run_section(run: _Run) -> str:
    i = run.info
    n_rows = {p: len(run.rows_of(p)) for p in run.policies}
    lines = [
        f"# Benchmark report: {i.get('suite', '?')} / {i.get('split', '?')}",
        "",
        f"* Suite **{i.get('suite', '?')}** v{i.get('suite_version', '?')}, split **{i.get('split', '?')}**, "
        f"scoring preset **{i.get('preset', '?')}**",
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
    return "\n".join(lines)


_OVERALL = (  # (label, key in summary["overall"], decimals)
    ("Scenarios", "num_scenarios", 0),
    ("Success rate SR %", "success_rate", 1),
    ("Driving score DS", "driving_score", 2),
    ("DS std over scenarios", "driving_score_std", 2),
    ("Route completion RC %", "route_completion", 2),
    ("Infraction score IS", "infraction_score", 3),
    ("km driven", "km_driven", 2),
    ("Collisions / km", "collisions_per_km", 3),
    ("Red lights / km", "red_light_per_km", 3),
    ("Off-lane %", "outside_route_lanes_pct", 2),
    ("Invalid-action steps", "invalid_action_steps", 0),
)


def _comparison_section(run: _Run) -> str:
    rows = [[label] + [_fmt([s["overall"].get(key) for s in run.summaries[p]], d) for p in run.policies]
            for label, key, d in _OVERALL]
    statuses = sorted({k for p in run.policies for s in run.summaries[p] for k in s["overall"].get("statuses", {})},
                      key=lambda k: (_status_rank(k), k))
    rows += [[f"status: {k}"] + [_fmt([s["overall"].get("statuses", {}).get(k, 0) for s in run.summaries[p]], 0)
                                 for p in run.policies] for k in statuses]
    return "## Policy comparison\n\n" + _table(["metric", *run.policies], rows, ("l",) + ("r",) * len(run.policies))


def _behaviour_section(run: _Run, images: dict[str, str]) -> str:
    groups = _behaviour_groups(run)
    if not groups:
        return ""
    head = ["policy"] + [f"{g} (n={_group_size(run, 'by_behavior', g)})" for g in groups] + ["mean of groups"]
    out = ["## Per behaviour group (DriveE2E Table 5 order)"]
    for key, title, d, img in (("success_rate", "Success rate SR %", 1, "sr_by_behavior"),
                               ("driving_score", "Driving score DS", 2, "ds_by_behavior")):
        rows = []
        for p in run.policies:
            per_group = [[s["by_behavior"].get(g, {}).get(key) for s in run.summaries[p]] for g in groups]
            macro = [_mean([v for v in rep if v is not None]) for rep in zip(*per_group)]
            rows.append([f"`{p}`"] + [_fmt(v, d) for v in per_group] + [_fmt(macro, d)])
        out += [f"### {title}", _table(head, rows, ("l",) + ("r",) * (len(head) - 1)), _image(images, img, title)]
    return "\n\n".join(out)


def _group_section(run: _Run, key: str, title: str) -> str:
    groups = sorted({g for p in run.policies for s in run.summaries[p] for g in s.get(key, {})}, key=_num_first)
    if not groups:
        return ""
    head = ["group", "n"] + [f"{p} {m}" for p in run.policies for m in ("SR %", "DS")]
    rows = [[g, str(_group_size(run, key, g))]
            + [_fmt([s[key].get(g, {}).get(m) for s in run.summaries[p]], d)
               for p in run.policies for m, d in (("success_rate", 1), ("driving_score", 2))] for g in groups]
    return f"## {title}\n\n" + _table(head, rows, ("l",) + ("r",) * (len(head) - 1))


def _counts_section(run: _Run) -> str:
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
    out.append(_image(images, "metric_distributions", "Per-policy distributions"))
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
        "* SR: % of scenarios finished (Perfect or Completed) with no infraction except min-speed; "
        "DS: mean over scenarios of RC × IS (DriveE2E merge); 'DS std over scenarios' is LB 2.0's scores_std_dev.",
        "* Per-km rates follow CARLA Leaderboard 2.0 global statistics (entries / km driven, km = length × RC).",
        "* 'mean of groups' is the unweighted mean over the behaviour groups present (cf. DriveE2E's ability mean).",
        "* Event counts: non-negative integer columns of `scenarios.csv`; 'other columns': every remaining "
        "numeric one (id-like and text columns are skipped).",
    ])


# --------------------------------------------------------------------------- helpers


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


def _read_json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.exists() else {}
