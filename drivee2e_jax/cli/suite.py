"""`drivee2e suite generate|info|validate`: make, describe and check suites."""

from __future__ import annotations

import contextlib
import importlib
import json
import sys
import time
from pathlib import Path

from drivee2e_jax.cli import common
from drivee2e_jax.progress import progress

SUITE_EPILOG = """\
examples:
  drivee2e suite generate --out suites/twin15
  drivee2e suite info twin15
  drivee2e suite info twin15 --json
  drivee2e suite validate tiny     # a suite folder, or the name of an example suite shipped in the package
  drivee2e suite import argoverse2 data/av2/ --out suites/av2
"""

IMPORT_EPILOG = """\
examples:
  drivee2e suite import argoverse2 ../shared/data/argoverse2 --out suites/av2
  drivee2e suite import scenarionet ../shared/data/nuscenes_scenarionet/*.pkl --out suites/nusc --split val
  drivee2e suite import argoverse2 log_dir/ --out suites/av2_5s --window-s 5 --max-scenarios 10
  drivee2e suite import opendrive maps/town.xodr recordings/ --out suites/od

formats: argoverse2 (scenario_*.parquet with its log_map_archive_*.json, or a
sensor-log folder with annotations.feather + city_SE3_egovehicle.feather +
map/), scenarionet (sd_*.pkl, read with a restricted unpickler), lanelet2-csv,
commonroad, opendrive. Each PATH is one recording (file or folder) or a folder
searched for recordings; opendrive reads all PATHs together (a .xodr map plus
the track CSVs / recording folders driven on it). See docs/importers.md. Tracks are resampled onto the 0.1 s grid (never across
gaps); the recorded ego drives, or --ego names one, or one is chosen by the
curation rules. Needs the import extra for Parquet/Feather:
pip install 'drivee2e-jax[import]'. Check the result with
`drivee2e suite validate DIR`.
"""

GENERATE_EPILOG = """\
examples:
  drivee2e suite generate --out suites/twin15      # --name twin15 --seed 0: the defaults
  drivee2e suite generate --scenarios 8000 --out suites/twin15x10

The folder holds suite.json, maps/<map_id>.json and scenarios/<id>.json; the
same name, seed and --scenarios always give the same bytes. An existing
non-empty folder is refused unless --force (which only ever replaces a suite
folder).

twin15 is written 800 scenarios at a time (memory stays that of 800, about
0.7 GB per process, whatever --scenarios; 40-70 s per 800 on 2 cores). --scenarios N (a
multiple of 800) scales the splits (N/2, N/4, N/4) and label counts; the suite
is named twin15x<N/800>. suite.json's meta records pack_sizes, so
drivee2e_jax.scenario.stream reads the suite shard by shard without a pre-pass.
A killed run leaves .<DIR>.partial next to DIR: the same command resumes
after the blocks already written. See docs/suite_format.md (Large suites).
"""

INFO_EPILOG = """\
examples:
  drivee2e suite info twin15
  drivee2e suite info tiny --json | python -m json.tool

--json prints exactly one JSON object with at least: num_scenarios, splits,
behaviors, intersections (a count), intersection_ids, categories (agent
category -> number of tracks), weathers, times_of_day, agents_per_scenario.
"""

VALIDATE_EPILOG = """\
example:
  drivee2e suite validate tiny

Prints every problem as `file: field: expected ...` and exits 1 if there is
any. Then runs the curation checks of recorded scenarios (track gaps, speed /
acceleration / yaw-rate bounds per category, the ego route following the lanes,
ego box overlaps; see drivee2e_jax/scenario/curation.py) and prints each finding
as `warning: <scenario>: track <id> t=<s>: <check>: ...` on stderr: they fail
the command (exit 1) only with --strict. Prints `OK: N scenarios, M maps`
otherwise.
"""


def add_parser(subparsers) -> None:
    p = common.add_command(
        subparsers, "suite", help="generate, describe or validate a scenario suite",
        description="Work with scenario suites: the built-in twin15 or a suite folder "
                    "(suite.json, maps/, scenarios/).",
        epilog=SUITE_EPILOG,
    )
    actions = p.add_subparsers(dest="action", metavar="<action>", required=True)

    g = common.add_command(
        actions, "generate", help="write a built-in suite as a suite folder",
        description="Generate a built-in suite (deterministic for a seed) and write it as a suite folder.",
        epilog=GENERATE_EPILOG,
    )
    g.add_argument("--name", default="twin15", help="built-in suite to generate (default: twin15)")
    g.add_argument("--seed", type=int, default=0, help="generator seed (default: 0)")
    g.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder to write (new or empty)")
    g.add_argument("--force", action="store_true", help="replace an existing suite folder at DIR (only one holding nothing but suite files)")
    g.add_argument("--scenarios", type=int, default=None, metavar="N",
                   help="number of scenarios, a multiple of 800 (twin15 only; default: 800)")
    g.set_defaults(func=run_generate)

    i = common.add_command(
        actions, "info", help="counts by split, behaviour, intersection, agent category, weather/time",
        description="Describe a suite: scenarios by split, behaviour group, intersection, weather and time "
                    "of day, and agent tracks by category.",
        epilog=INFO_EPILOG,
    )
    i.add_argument("suite", help="built-in suite name (twin15, or tiny: the example shipped in the package) or suite folder")
    i.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    i.set_defaults(func=run_info)

    v = common.add_command(
        actions, "validate", help="check every file of a suite folder and list all problems",
        description="Validate a suite folder: every field of every file, cross-file references, "
                    "timestamps on the log grid. Lists all problems, not just the first.",
        epilog=VALIDATE_EPILOG,
    )
    v.add_argument("folder", type=Path, help="suite folder (or 'tiny', the example suite shipped in the package)")
    v.add_argument("--strict", action="store_true", help="curation findings are errors (exit 1)")
    v.add_argument("--no-curation", action="store_true", help="schema checks only")
    v.set_defaults(func=run_validate)

    from drivee2e_jax.scenario.formats import FORMATS

    m = common.add_command(
        actions, "import", help="convert recorded traffic (Argoverse 2, ScenarioNet, ...) into a suite folder",
        description="Import real recorded traffic into a suite folder: tracks resampled onto the log grid, the "
                    "ego's logged path as its route, behaviour labels inferred, unusable tracks reported.",
        epilog=IMPORT_EPILOG,
    )
    m.add_argument("format", choices=list(FORMATS), metavar="FORMAT", help=f"one of {', '.join(FORMATS)}")
    m.add_argument("paths", nargs="+", type=Path, metavar="PATH", help="input files or folders")
    m.add_argument("--out", type=Path, required=True, metavar="DIR", help="suite folder to write (new or empty)")
    m.add_argument("--split", default="test", help="split of every imported scenario (default: test)")
    m.add_argument("--ego", default=None, metavar="ID",
                   help="source track id to use as ego (default: the recorded ego, else chosen automatically)")
    m.add_argument("--max-scenarios", type=int, default=None, metavar="N", help="stop after N scenarios")
    m.add_argument("--window-s", type=float, default=None, metavar="S",
                   help="cut recordings into windows of S seconds (default: whole recordings)")
    m.add_argument("--name", default=None, help="suite name (default: the folder name of --out)")
    m.add_argument("--force", action="store_true", help="replace an existing suite folder at DIR (only one holding nothing but suite files)")
    m.add_argument("--verbose", "-v", action="store_true", help="print every skipped item and note")
    m.set_defaults(func=run_import)


def run_generate(args) -> int:
    from drivee2e_jax.scenario.schema import write_suite
    from drivee2e_jax.scenario.suite import BUILTIN_SUITES, generate_suite

    out: Path = args.out
    if out.exists() and out.is_dir() and any(out.iterdir()) and not args.force:
        # Fail before spending seconds on generation.
        raise common.DriveE2EError(f"{out} exists and is not empty; expected a new or empty folder "
                                   "(pass --force to replace a suite folder)")
    module = importlib.import_module(BUILTIN_SUITES[args.name][0]) if args.name in BUILTIN_SUITES else None
    if module is not None and hasattr(module, "generate_to"):  # streamed block by block (bounded memory)
        return _generate_streamed(args, module)
    if args.scenarios is not None and module is not None:
        raise common.DriveE2EError(f"--scenarios: built-in suite {args.name!r} has a fixed size; expected "
                                   "no --scenarios (only twin15 scales)")
    t0 = time.perf_counter()
    print(f"generating {args.name} (seed {args.seed}) ...", file=sys.stderr)
    records = generate_suite(args.name, args.seed)
    write_suite(records, out, overwrite=args.force, progress=True)
    print(f"wrote {len(records.scenarios)} scenarios, {len(records.maps)} maps to {out} "
          f"({time.perf_counter() - t0:.1f} s)")
    return common.EXIT_OK


def _generate_streamed(args, module) -> int:
    from drivee2e_jax.progress import ProgressBars

    n = module.NUM_SCENARIOS if args.scenarios is None else args.scenarios
    name = module.suite_name(n)  # checks n (a one-line error for a bad --scenarios)
    partial = args.out.parent / f".{args.out.name}.partial"
    t0 = time.perf_counter()
    print(f"generating {name}: {n} scenarios (seed {args.seed}) into {args.out} ..."
          + (f" (resuming from {partial} if it is the same generation)" if partial.is_dir() else ""),
          file=sys.stderr)
    bars = ProgressBars(unit="scenario")
    try:
        module.generate_to(args.out, args.seed, num_scenarios=n, overwrite=args.force, progress=bars)
    finally:
        bars.close()
    num_maps = len(list((args.out / "maps").glob("*.json")))
    print(f"wrote {n} scenarios, {num_maps} maps to {args.out} ({time.perf_counter() - t0:.1f} s)")
    return common.EXIT_OK


def _table(title: str, counts: dict[str, int], total: int, *, skip_zero: bool = False) -> list[str]:
    rows = [(k, v) for k, v in counts.items() if v or not skip_zero]
    width = max([len(k) for k, _ in rows] + [8])
    lines = [title]
    for k, v in rows:
        pct = 100.0 * v / total if total else 0.0
        lines.append(f"  {k:<{width}}  {v:>7}  {pct:5.1f}%")
    return lines


def run_info(args) -> int:
    from drivee2e_jax.scenario.suite import load_suite

    suite = load_suite(args.suite)
    if not suite.ready:
        print(f"building the packed cache of {suite.name} (first use; later loads take well under a second) ...",
              file=sys.stderr)
    with contextlib.redirect_stdout(sys.stderr):  # stdout carries only the result (one JSON object)
        info = suite.info()
    if args.json:
        print(json.dumps(info, sort_keys=False))
        return common.EXIT_OK
    n = info["num_scenarios"]
    a, s = info["agents_per_scenario"], info["steps_per_scenario"]
    tracks = sum(info["categories"].values())
    lines = [
        f"suite {info['name']} (version {info['version']}): {n} scenarios, {info['num_maps']} maps, "
        f"{info['intersections']} intersections",
        f"agents per scenario: mean {a['mean']:g}, max {a['max']}; log steps: mean {s['mean']:g}, max {s['max']}",
        "",
    ]
    for title, key, total, skip in (("split", "splits", n, False), ("behaviour", "behaviors", n, False),
                                    ("intersection", "intersection_ids", n, True),
                                    ("agent category (tracks)", "categories", tracks, False),
                                    ("weather", "weathers", n, False), ("time of day", "times_of_day", n, False)):
        lines += _table(title, info[key], total, skip_zero=skip) + [""]
    print("\n".join(lines).rstrip())
    return common.EXIT_OK


def run_validate(args) -> int:
    from drivee2e_jax.jsonfile import read_json
    from drivee2e_jax.scenario.schema import read_suite, validate_suite
    from drivee2e_jax.scenario.suite import EXAMPLE_SUITES

    if not args.folder.exists() and str(args.folder) in EXAMPLE_SUITES:
        args.folder = EXAMPLE_SUITES[str(args.folder)]
    problems = validate_suite(args.folder, progress=True)
    if problems:
        for p in problems:
            print(p)
        print(f"{len(problems)} problem{'s' if len(problems) != 1 else ''} in {args.folder}", file=sys.stderr)
        return common.EXIT_PROBLEMS
    head = read_json(args.folder / "suite.json")
    num_maps = len(list((args.folder / "maps").glob("*.json")))
    from drivee2e_jax.scenario.lane_polygons import map_notes

    records = read_suite(args.folder)
    for mid in sorted(records.maps):  # notes, not problems: stderr, exit code unchanged
        for line in map_notes(records.maps[mid]):
            print(f"note: {line}", file=sys.stderr)
    findings = []
    if not args.no_curation:
        from drivee2e_jax.scenario.curation import curate_suite

        findings = curate_suite(records)
        for f in findings:  # warnings go to stderr: stdout keeps the one-line verdict
            print(f"warning: {f}", file=sys.stderr)
    if findings:
        by_check: dict[str, int] = {}
        for f in findings:
            by_check[f.check] = by_check.get(f.check, 0) + 1
        summary = ", ".join(f"{v} {k}" for k, v in by_check.items())
        print(f"{len(findings)} curation finding{'s' if len(findings) != 1 else ''} ({summary})"
              + (" (--strict: failing)" if args.strict else ""), file=sys.stderr)
        if args.strict:
            return common.EXIT_PROBLEMS
    print(f"OK: {len(head['scenarios'])} scenarios, {num_maps} maps")
    return common.EXIT_OK


def run_import(args) -> int:
    from drivee2e_jax.scenario import importers
    from drivee2e_jax.scenario.importers.common import ImportOptions, merge_results, write_result

    out: Path = args.out
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
        raise common.DriveE2EError(f"{out} exists and is not empty; expected a new or empty folder "
                                   "(pass --force to replace a suite folder)")
    for p in args.paths:
        if not p.exists():
            raise common.DriveE2EError(f"{p}: no such file or folder")
    options = ImportOptions(split=args.split, ego=args.ego, max_scenarios=args.max_scenarios,
                            window_s=args.window_s, name=args.name)
    t0 = time.perf_counter()
    mod = importers.module(args.format)  # an unknown/unavailable format fails before any reading
    if getattr(mod, "LOAD_ALL_PATHS_AT_ONCE", False):
        # the paths belong together (an OpenDRIVE map given next to track folders stored elsewhere)
        result = importers.load(args.format, args.paths, options)
    else:
        result = merge_results(_load_each(importers, args.format, args.paths, options))
    name = args.name or out.name
    write_result(result, out, name=name, force=args.force)
    _print_import_summary(result, out, time.perf_counter() - t0, verbose=args.verbose)
    return common.EXIT_OK


def _load_each(importers, fmt: str, paths: list[Path], options) -> list:
    """One ``load`` per input path (with a progress bar over the inputs), honouring --max-scenarios."""
    from dataclasses import replace

    results = []
    count = 0
    bar = progress(paths, desc=f"importing {fmt}", unit="input", disable=None if len(paths) > 1 else True)
    for path in bar:
        if options.max_scenarios is not None and count >= options.max_scenarios:
            break
        left = None if options.max_scenarios is None else options.max_scenarios - count
        r = importers.load(fmt, [path], replace(options, max_scenarios=left))
        count += len(r.scenarios)
        results.append(r)
    return results


def _print_import_summary(result, out: Path, seconds: float, *, verbose: bool) -> None:
    behaviours: dict[str, int] = {}
    for s in result.scenarios:
        behaviours[s.behavior] = behaviours.get(s.behavior, 0) + 1
    tracks = sum(len(s.tracks) for s in result.scenarios)
    used = {s.map_id for s in result.scenarios}
    lines = [f"wrote {len(result.scenarios)} scenarios ({', '.join(f'{k} {v}' for k, v in sorted(behaviours.items()))}), "
             f"{len(used)} maps, {tracks} tracks to {out} ({seconds:.1f} s)"]
    if result.skipped:
        reasons: dict[str, list[str]] = {}
        for sk in result.skipped:
            reasons.setdefault(sk.reason, []).append(sk.source)
        lines.append(f"skipped {len(result.skipped)}:")
        for reason, sources in sorted(reasons.items(), key=lambda x: (-len(x[1]), x[0])):
            lines.append(f"  {len(sources):>5}  {reason}")
            if verbose:
                lines += [f"         {src}" for src in sources]
    notes = result.notes if verbose else [n for n in result.notes if ": behaviour " not in n]
    if notes:
        lines.append("notes:")
        lines += [f"  {n}" for n in notes]
    lines.append(f"next: drivee2e suite validate {out}")
    print("\n".join(lines))
