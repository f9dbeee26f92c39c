"""`io.report.write_report` on small synthetic run folders: tables, numbers, PNGs, repetitions, atomic rewrite."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import pytest

pytest.importorskip("matplotlib")

from drivee2e_jax.eval import report  # noqa: E402
from drivee2e_jax.eval.results import BASE_COLUMNS, rows_to_csv  # noqa: E402
from drivee2e_jax.eval.summary import BEHAVIOR_ORDER, summarize, wilson_ci  # noqa: E402
from drivee2e_jax.files import atomic_write_json, atomic_write_text  # noqa: E402
from drivee2e_jax.metrics.driving_score import STATUS_NAMES  # noqa: E402

#: scenarios.csv header of a real run (twin15 val), plus a column no code knows about.
HEADER = (
    "policy,scenario_id,split,intersection_id,behavior,weather,time_of_day,route_length_m,route_completion,"
    "infraction_score,driving_score,success,status,episode_s,eval_time_s,collisions_pedestrian,collisions_vehicle,"
    "collisions_layout,red_light,outside_route_lanes,min_speed_infractions,route_dev,vehicle_blocked,route_timeout,"
    "invalid_action,collisions_cyclist_motorcycle"
).split(",") + ["l2_1s_stp3", "longitudinal_jerk_mps", "jerk_lon_mean_mps3", "smoothness_pct"]
COUNTS = HEADER[len(BASE_COLUMNS):-4]
RUN_INFO = {"suite": "toy", "suite_version": "1", "split": "val", "num_scenarios": 10, "preset": "paper", "dt": 0.1,
            "control_every": 1, "latency": 0, "seed": 0}
BEHAVIORS = ["COV"] * 4 + ["IPC"] * 4 + ["STR"] * 2
PNG = b"\x89PNG\r\n\x1a\n"


def _row(policy, i, status="Perfect", rc=100.0, collisions=0, l2=0.5, rep=None):
    is_ = 0.6 ** collisions
    row = {
        "policy": policy, "scenario_id": f"toy_{i:04d}", "split": "val", "intersection_id": f"I0{1 + i % 2}",
        "behavior": BEHAVIORS[i], "weather": "rain" if i < 3 else "clear", "time_of_day": "day",
        "route_length_m": 100.0 + 10 * i, "route_completion": rc, "infraction_score": is_,
        "driving_score": rc * is_, "success": status == "Perfect", "status": status,
        "outside_route_lanes_pct": 0.0, "outside_route_lanes_m": 0.0, "episode_s": 10.0 + i, "eval_time_s": 0.1,
        **{c: 0 for c in COUNTS}, "collisions_vehicle": collisions, "l2_1s_stp3": l2,
        "longitudinal_jerk_mps": -0.01 * i, "jerk_lon_mean_mps3": 1.0 + 0.1 * i, "smoothness_pct": 90.0 - i,
    }
    if rep is not None:
        row["repetition"] = rep
    return row


def _policies(rep=0):
    """good: fails IPC toy_0004 (timeout at RC 50) and toy_0005 (a collision); in repetition 1 also COV toy_0000.
    bad: stops short on every COV scenario, fine elsewhere."""
    good = [_row("good", i, l2=0.4 if i % 2 else 0.6) for i in range(10)]
    good[4] = _row("good", 4, "Failed - TickRuntime", rc=50.0, l2=0.6)
    good[5] = _row("good", 5, "Completed", collisions=1, l2=0.4)
    if rep == 1:
        good[0] = _row("good", 0, "Failed - TickRuntime", rc=20.0, l2=0.6)
    bad = [_row("bad", i, "Failed - TickRuntime", rc=10.0 * (i + 1), l2=1.5) if i < 4 else _row("bad", i, l2=1.5)
           for i in range(10)]
    return {"good": good, "bad": bad}


def _write_run(folder: Path, reps: int = 1) -> Path:
    by_policy = {"good": [], "bad": []}
    for rep in range(reps):
        for p, rows in _policies(rep).items():
            by_policy[p] += [{**r, "repetition": rep} if reps > 1 else r for r in rows]
    header = HEADER + (["repetition"] if reps > 1 else [])
    atomic_write_json(folder / "run.json", RUN_INFO)
    atomic_write_json(folder / "summary.json", summarize(by_policy, RUN_INFO))
    atomic_write_text(folder / "scenarios.csv", rows_to_csv([r for rs in by_policy.values() for r in rs], header))
    return folder


def _table_row(md: str, first_cell: str, after: str) -> list[str]:
    """Cells of the first table row starting with ``first_cell`` below the line containing ``after``."""
    text = md[md.index(after):]
    line = next(ln for ln in text.splitlines() if ln.startswith(f"| {first_cell} |"))
    return [c.strip() for c in line.strip("|").split("|")][1:]


def _check_pngs(run: Path) -> dict[str, int]:
    inodes = {}
    for name in ("sr_by_behavior", "ds_by_behavior", "infractions_per_km", "comfort"):
        png = run / "plots" / f"{name}.png"
        data = png.read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000, name
        inodes[name] = png.stat().st_ino
    return inodes


def _no_temp_files(run: Path) -> None:
    left = [p.name for p in run.rglob("*") if p.name.startswith(".") or p.name.endswith(".tmp")]
    assert not left, left


def test_behaviour_order_is_the_benchmarks():
    assert report.BEHAVIOR_ORDER == BEHAVIOR_ORDER


def test_one_repetition_tables_and_plots(tmp_path):
    run = _write_run(tmp_path / "run")
    path = report.write_report(run)
    assert path == run / "report.md"
    md = path.read_text()

    assert "# Benchmark report: toy / val" in md and "10 scenarios × 2 policies" in md
    # Comparison: straight from summary.json (good: 8 of 10 succeed, DS = (8*100 + 50 + 60) / 10;
    # bad: DS = (10 + 20 + 30 + 40 + 6*100) / 10).
    assert _table_row(md, "Success rate SR %", "## Policy comparison") == ["80.0", "60.0"]
    assert _table_row(md, "Driving score DS", "## Policy comparison") == ["91.00", "70.00"]
    assert _table_row(md, "status: Completed", "## Policy comparison") == ["1", "0"]
    # Behaviour groups in Table 5 order with their sizes; UT etc. absent from the suite are left out.
    sr = md[md.index("### Success rate SR %"):]
    assert "| policy | COV (n=4 †) | IPC (n=4 †) | STR (n=2 †) | mean of groups |" in sr
    assert _table_row(md, "`good`", "### Success rate SR %") == ["100.0", "50.0", "100.0", "83.3"]
    assert _table_row(md, "`bad`", "### Success rate SR %") == ["0.0", "100.0", "100.0", "66.7"]
    assert _table_row(md, "`bad`", "### Driving score DS") == ["25.00", "100.00", "100.00", "75.00"]
    assert _table_row(md, "I01", "## Per intersection")[0] == "5 †"
    assert _table_row(md, "rain", "## Per weather")[:3] == ["3 †", "100.0", "100.00"]
    assert "† fewer than 10 episodes" in md[md.index("## Per weather"):md.index("## Infraction")]
    # Counts and the column no code knows about (mean ± sample std over scenarios).
    assert _table_row(md, "`collisions_vehicle`", "## Infraction") == ["1", "0"]
    assert "`red_light`" in md[md.index("Zero for every policy"):]
    l2 = _table_row(md, "`l2_1s_stp3`", "## Other per-scenario columns")
    assert l2 == [f"0.50 ± {math.sqrt(10 * 0.01 / 9):.2f}", "1.50 ± 0.00"]  # 2 decimals: values up to 1.5
    assert "`success`" not in md[md.index("## Other"):] and "`scenario_id`" not in md
    # Failed scenarios, worst DS first, with status and infractions.
    assert "### `good`: 2 of 10 episodes unsuccessful" in md
    assert _table_row(md, "toy_0004", "### `good`")[3:] == ["Failed - TickRuntime", "50.0", "50.00", "—"]
    assert _table_row(md, "toy_0005", "### `good`")[-1] == "collisions_vehicle 1"
    for img in ("sr_by_behavior", "ds_by_behavior", "infractions_per_km", "comfort"):
        assert f"](plots/{img}.png)" in md
    _check_pngs(run)
    _no_temp_files(run)


def test_repetitions_are_mean_and_std_over_repetitions(tmp_path):
    run = _write_run(tmp_path / "run", reps=2)
    md = report.write_report(run).read_text()

    assert "**2 repetitions**" in md
    # good: SR 80 in repetition 0, 70 in repetition 1.
    assert _table_row(md, "Success rate SR %", "## Policy comparison") == ["75.0 ± 7.1", "60.0 ± 0.0"]
    assert _table_row(md, "Scenarios", "## Policy comparison") == ["10.0 ± 0.0", "10.0 ± 0.0"]
    # COV: 4/4 then 3/4.
    assert _table_row(md, "`good`", "### Success rate SR %")[:2] == ["87.5 ± 17.7", "50.0 ± 0.0"]
    assert "COV (n=4 †)" in md
    assert "| SR 95 % CI |" not in md and "| DS 95 % CI |" not in md  # per repetition: not averaged
    assert _table_row(md, "status: Perfect", "## Policy comparison") == ["7.5 ± 0.7", "6.0 ± 0.0"]
    assert _table_row(md, "`collisions_vehicle`", "## Infraction") == ["1.0 ± 0.0", "0.0 ± 0.0"]
    # Off-lane % is not a CSV column: unknown when recomputed, not a made-up 0.
    assert _table_row(md, "Off-lane %", "## Policy comparison") == ["–", "–"]
    assert "### `good`: 5 of 20 episodes unsuccessful" in md
    assert "| scenario | repetition |" in md
    _check_pngs(run)


def test_second_call_replaces_files_atomically(tmp_path, monkeypatch):
    run = _write_run(tmp_path / "run", reps=2)
    first = report.write_report(run)
    inode_md, inodes_png = first.stat().st_ino, _check_pngs(run)
    monkeypatch.setattr(report, "MAX_FAILED", 3)
    second = report.write_report(run)
    md = second.read_text()
    assert "### `bad`: 8 of 20 episodes unsuccessful; the 3 worst shown" in md
    # bad's worst: toy_0000 (DS 10) in both repetitions; good's worst: toy_0000 (DS 20) in repetition 1.
    assert md.count("| toy_0000 |") == 3
    # Replaced (a new file moved over the old one), not rewritten in place; nothing left behind.
    assert second.stat().st_ino != inode_md
    assert all(a != b for a, b in zip(_check_pngs(run).values(), inodes_png.values()))
    _no_temp_files(run)
    assert sorted(os.listdir(run)) == ["plots", "report.md", "run.json", "scenarios.csv", "summary.json"]
    assert json.loads((run / "run.json").read_text()) == RUN_INFO


def test_atomic_write_gives_the_umask_mode_and_leaves_no_temp_file(tmp_path):
    import os

    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(old)
    assert (os.stat(tmp_path / "a.txt").st_mode & 0o777) == 0o644  # mkstemp alone gives 0o600
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_legend_explains_codes_statuses_and_every_abbreviation(tmp_path):
    md = report.write_report(_write_run(tmp_path / "run")).read_text()
    legend = md[md.index("## Legend"):]
    first_cells = {ln.split("|")[1].strip() for ln in legend.splitlines() if ln.startswith("| ")}
    # the behaviour groups of the run (and only those), the statuses that occur
    assert {"COV", "IPC", "STR"} <= first_cells and "UT" not in first_cells
    assert {"Perfect", "Completed", "Failed - TickRuntime"} <= first_cells
    # every abbreviation in the comparison labels and group headers is in the legend
    for abbr in ("SR %", "DS", "RC %", "IS", "95 % CI", "n", "†", "Jerk m/s³", "mean of groups",
                 "Off-lane %", "km driven", "DS std over scenarios", "Invalid-action steps"):
        assert abbr in first_cells, abbr
    assert "`jerk_lon_mean_mps3`" in first_cells and "`collisions_vehicle`" in first_cells
    assert "Wilson" in legend and f"{report.CI_RESAMPLES} resamples" in legend
    # the help tables cover every code the project can produce
    assert set(report.BEHAVIOR_HELP) == set(BEHAVIOR_ORDER)
    assert set(report.STATUS_HELP) == set(STATUS_NAMES)


def test_one_jerk_column_in_the_tables(tmp_path):
    md = report.write_report(_write_run(tmp_path / "run")).read_text()
    assert "| `longitudinal_jerk_mps` |" not in md  # Behavior Metrics' eq. (2): scenarios.csv only
    assert _table_row(md, "`jerk_lon_mean_mps3`", "## Other")[0].startswith("1.45 ± ")  # mean of 1.0..1.9
    assert _table_row(md, "Jerk m/s³", "## Policy comparison") == ["1.45", "1.45"]  # summary.json's mean
    assert "longitudinal_jerk_mps" in md[md.index("## Legend"):]  # said where it went


def test_intervals_overall_and_for_groups_of_ten_or_more(tmp_path):
    # 24 scenarios: STR 12 (gets intervals), COV 12 (good fails 3 of them)
    rows = {"good": [], "bad": []}
    for i in range(24):
        beh = "STR" if i < 12 else "COV"
        for p in rows:
            r = _row(p, 0, "Failed - TickRuntime" if (p == "good" and i >= 21) else "Perfect",
                     rc=40.0 if (p == "good" and i >= 21) else 100.0, collisions=int(p == "bad" and i == 0))
            rows[p].append({**r, "scenario_id": f"t_{i:03d}", "behavior": beh, "intersection_id": f"I{i % 3}"})
    info = {**RUN_INFO, "num_scenarios": 24}
    run = tmp_path / "big"
    atomic_write_json(run / "run.json", info)
    summary = summarize(rows, info)
    atomic_write_json(run / "summary.json", summary)
    atomic_write_text(run / "scenarios.csv", rows_to_csv([r for rs in rows.values() for r in rs], HEADER))
    md = report.write_report(run).read_text()
    lo, hi = wilson_ci(21, 24)
    assert _table_row(md, "SR 95 % CI", "## Policy comparison")[0] == f"[{lo:.1f}, {hi:.1f}]"
    ds = summary["policies"]["good"]["overall"]["driving_score_ci95"]
    assert _table_row(md, "DS 95 % CI", "## Policy comparison")[0] == f"[{ds[0]:.2f}, {ds[1]:.2f}]"
    assert "COV (n=12) | STR (n=12)" in md and "†" not in md[md.index("## Per behaviour"):md.index("## Per inter")]
    lo, hi = wilson_ci(9, 12)
    assert _table_row(md, "`good`", "### Success rate SR %")[0] == f"75.0 [{lo:.1f}, {hi:.1f}]"
    assert _table_row(md, "`good`", "### Success rate SR %")[1] == "100.0 [75.8, 100.0]"
    # intersections of 8: flagged, no interval (good fails t_021 there)
    assert _table_row(md, "I0", "## Per intersection")[:2] == ["8 †", "87.5"]


def test_infractions_per_km_and_no_plot_without_events(tmp_path):
    rows = _policies()["good"]
    km = sum(r["route_length_m"] * r["route_completion"] / 100 for r in rows) / 1000
    assert report.per_km(report_rows(rows), "collisions_vehicle") == pytest.approx(1 / km)
    assert report.per_km(report_rows(rows[:1]), "red_light") == 0.0
    clean = {"good": [_row("good", i) for i in range(10)]}
    run = tmp_path / "clean"
    atomic_write_json(run / "run.json", RUN_INFO)
    atomic_write_json(run / "summary.json", summarize(clean, RUN_INFO))
    atomic_write_text(run / "scenarios.csv", rows_to_csv(clean["good"], HEADER))
    md = report.write_report(run).read_text()
    assert not (run / "plots" / "infractions_per_km.png").exists() and "infractions_per_km.png" not in md
    assert (run / "plots" / "comfort.png").read_bytes().startswith(PNG)


def report_rows(rows: list[dict]) -> list[dict]:
    """Rows as ``load_rows`` gives them (floats)."""
    return [{k: float(v) if isinstance(v, int | float) else v for k, v in r.items()} for r in rows]


def test_ds_and_sr_both_ways_and_nuplan_means_in_the_comparison(tmp_path):
    """A folder of this version (at_fault mode, preset nuplan): good's toy_0005
    collision is not at fault, so at-fault-only it scores DS 100 (IS 1) and
    succeeds; "(chosen)" marks the run's mode. bad has no attribution
    columns (an older policy file): its cells are "–"."""
    info = {**RUN_INFO, "preset": "nuplan", "collisions": "at_fault"}
    pols = _policies()
    for r in pols["good"]:
        hit = r["scenario_id"] == "toy_0005"
        r.update(driving_score_all=r["driving_score"], success_all=r["success"],
                 infraction_score_all=r["infraction_score"], driving_score_at_fault=100.0 if hit else r["driving_score"],
                 success_at_fault=True if hit else r["success"], infraction_score_at_fault=1.0 if hit else
                 r["infraction_score"], collisions_at_fault=0, nuplan_score=0.5, nuplan_ego_progress=1.0)
    run = tmp_path / "run"
    cols = ["driving_score_all", "success_all", "infraction_score_all", "driving_score_at_fault", "success_at_fault",
            "infraction_score_at_fault", "collisions_at_fault", "nuplan_score", "nuplan_ego_progress"]
    atomic_write_json(run / "run.json", info)
    atomic_write_json(run / "summary.json", summarize(pols, info))
    atomic_write_text(run / "scenarios.csv", rows_to_csv([r for rs in pols.values() for r in rs], HEADER + cols))
    md = report.write_report(run).read_text()
    after = "## Policy comparison"
    # good: DS all = (8 * 100 + 50 + 60) / 10 = 91; at fault: toy_0005 100 -> 95; SR 80 % / 90 %
    assert _table_row(md, "DS, all collisions", after) == ["91.00", "–"]
    assert _table_row(md, "DS, at-fault collisions only (chosen)", after) == ["95.00", "–"]
    assert _table_row(md, "SR %, all collisions", after) == ["80.0", "–"]
    assert _table_row(md, "SR %, at-fault collisions only (chosen)", after) == ["90.0", "–"]
    assert _table_row(md, "nuPlan score ×100", after) == ["50.00", "–"]
    assert _table_row(md, "nuplan_ego_progress (mean)", after) == ["1.000", "–"]
    assert "collisions counted: **at_fault**" in md and "other agents: **log**" in md


def test_a_folder_without_the_new_columns_has_no_attribution_rows(tmp_path):
    md = report.write_report(_write_run(tmp_path / "run")).read_text()
    assert "| DS, all collisions" not in md and "nuPlan score" not in md.split("## Legend")[0]
    assert "collisions counted: **all**" in md  # an older run.json: the defaults
