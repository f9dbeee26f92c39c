"""`drivee2e suite generate|info|validate`: make, describe and check suites."""

from __future__ import annotations

import contextlib
import json
import sys
import time
from pathlib import Path

from drivee2e_jax.cli import common

SUITE_EPILOG = """\
examples:
  drivee2e suite generate --out suites/twin15
  drivee2e suite info twin15
  drivee2e suite info suites/twin15 --json
  drivee2e suite validate suites/twin15
"""

GENERATE_EPILOG = """\
example:
  drivee2e suite generate --name twin15 --seed 0 --out suites/twin15

The folder holds suite.json, maps/<map_id>.json and scenarios/<id>.json; the
same name and seed always give the same bytes. An existing non-empty folder is
refused unless --force (which only ever replaces a suite folder).
"""

INFO_EPILOG = """\
examples:
  drivee2e suite info twin15
  drivee2e suite info suites/my_suite --json | python -m json.tool

--json prints exactly one JSON object with at least: num_scenarios, splits,
behaviors, intersections (a count), intersection_ids, categories (agent
category -> number of tracks), weathers, times_of_day, agents_per_scenario.
"""

VALIDATE_EPILOG = """\
example:
  drivee2e suite validate suites/my_suite

Prints every problem as `file: field: expected ...` and exits 1 if there is
any; prints `OK: N scenarios, M maps` and exits 0 otherwise.
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
    g.add_argument("--force", action="store_true", help="replace an existing suite folder at DIR")
    g.set_defaults(func=run_generate)

    i = common.add_command(
        actions, "info", help="counts by split, behaviour, intersection, agent category, weather/time",
        description="Describe a suite: scenarios by split, behaviour group, intersection, weather and time "
                    "of day, and agent tracks by category.",
        epilog=INFO_EPILOG,
    )
    i.add_argument("suite", help="built-in suite name (twin15) or suite folder")
    i.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    i.set_defaults(func=run_info)

    v = common.add_command(
        actions, "validate", help="check every file of a suite folder and list all problems",
        description="Validate a suite folder: every field of every file, cross-file references, "
                    "timestamps on the log grid. Lists all problems, not just the first.",
        epilog=VALIDATE_EPILOG,
    )
    v.add_argument("folder", type=Path, help="suite folder")
    v.set_defaults(func=run_validate)


def run_generate(args) -> int:
    from drivee2e_jax.scenario.schema import write_suite
    from drivee2e_jax.scenario.suite import generate_suite

    out: Path = args.out
    if out.exists() and out.is_dir() and any(out.iterdir()) and not args.force:
        # Fail before spending seconds on generation.
        raise common.DriveE2EError(f"{out} exists and is not empty; expected a new or empty folder "
                                   "(pass --force to replace a suite folder)")
    t0 = time.perf_counter()
    print(f"generating {args.name} (seed {args.seed}) ...", file=sys.stderr)
    records = generate_suite(args.name, args.seed)
    write_suite(records, out, overwrite=args.force, progress=True)
    print(f"wrote {len(records.scenarios)} scenarios, {len(records.maps)} maps to {out} "
          f"({time.perf_counter() - t0:.1f} s)")
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
    from drivee2e_jax.scenario.schema import validate_suite

    problems = validate_suite(args.folder, progress=True)
    if problems:
        for p in problems:
            print(p)
        print(f"{len(problems)} problem{'s' if len(problems) != 1 else ''} in {args.folder}", file=sys.stderr)
        return common.EXIT_PROBLEMS
    head = json.loads((args.folder / "suite.json").read_text(encoding="utf-8"))
    num_maps = len(list((args.folder / "maps").glob("*.json")))
    print(f"OK: {len(head['scenarios'])} scenarios, {num_maps} maps")
    return common.EXIT_OK
