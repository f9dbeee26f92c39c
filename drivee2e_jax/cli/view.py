"""`drivee2e view`: write a self-contained HTML episode player for a results folder."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli import common

EPILOG = """\
examples:
  drivee2e view results/twin15-val --out player.html
  drivee2e view results/twin15-val --out player.html --policy expert --scenario twin15_val_0003
  drivee2e view results/run --out player.html --limit 5 --no-sensors --force

The episodes are re-simulated from the folder's run.json and policy files (the
bench is deterministic, so the traces reproduce the stored scores; a mismatch
warns). The page needs no network: open it in any browser. Controls: episode
picker, play/pause (Space), step (Left/Right), scrub, speed, follow-ego or
drag/scroll to pan/zoom; click an infraction marker on the timeline to jump to
it. See docs/visual.md.
"""


def add_parser(subparsers) -> None:
    p = common.add_command(
        subparsers, "view", help="write an HTML episode player for a results folder",
        description="Re-simulate episodes of a `drivee2e bench` results folder and write one self-contained "
                    "HTML file that plays them: top-down scene, the BEV the policy saw (its own size and route "
                    "window), a LiDAR point cloud, metric timelines and infractions.",
        epilog=EPILOG,
    )
    p.add_argument("results_dir", type=Path, metavar="RESULTS_DIR", help="a `drivee2e bench` output folder")
    p.add_argument("--out", type=Path, required=True, help="the HTML file to write")
    p.add_argument("--policy", default=None, help="policy in the folder (default: the run's first)")
    p.add_argument("--scenario", action="append", default=None, metavar="ID",
                   help="scenario id to include (repeatable; default: every scenario of the run)")
    p.add_argument("--limit", type=int, default=None, metavar="N", help="only the first N chosen scenarios")
    p.add_argument("--no-sensors", action="store_true", help="leave out the BEV and LiDAR panes (faster, smaller)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    p.add_argument("--title", default=None, help="page title (default: the folder name and policy)")
    p.set_defaults(func=run)


def run(args) -> int:
    from drivee2e_jax.errors import DriveE2EError

    results = Path(args.results_dir)
    if not results.is_dir():
        raise DriveE2EError(f"{results}: no such results folder")
    out = Path(args.out)
    if out.is_dir():
        raise DriveE2EError(f"--out {out}: is a folder; expected an .html file path")
    if out.exists() and not args.force:
        raise DriveE2EError(f"--out {out}: exists; use --force to overwrite")
    if args.limit is not None and args.limit < 1:
        raise DriveE2EError(f"--limit {args.limit}: expected a positive number of scenarios")

    from drivee2e_jax.eval.traces import trace_episodes
    from drivee2e_jax.observe import registry
    from drivee2e_jax.viz.player import write_player

    traces = trace_episodes(results, policy=args.policy, scenario_ids=args.scenario,
                            sensors=() if args.no_sensors else registry.shown(), limit=args.limit)
    if not traces:
        raise DriveE2EError(f"{results}: no episodes to show")
    title = args.title or f"{results.resolve().name} · {traces[0].policy}"
    write_player(traces, out, title=title, sensors=not args.no_sensors)
    size_kb = out.stat().st_size / 1024
    print(f"wrote {out} ({len(traces)} episodes, {size_kb:.0f} KiB); open it in a browser")
    return common.EXIT_OK
