"""`drivee2e view`: write the HTML episode player for a results folder."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli import common

EPILOG = """\
examples (after `drivee2e bench`, which writes results/twin15-val for log_replay, expert and stop):
  drivee2e view results/twin15-val --out view/player.html            # every policy and scenario
  drivee2e view results/twin15-val --out p.html --policy expert --scenario twin15_0001
  drivee2e view results/twin15-val --out p.html --scenario twin15_0000 --single-file --force
  drivee2e view results/twin15-val --out p.html --limit 20 --no-sensors --force

Writes the page and, beside it, a folder <page>_files/ with one small file per
episode that the page loads when the episode is opened (keep the two
together; no server needed: open the page in any browser). --single-file puts
everything in the page (for a few episodes). Episodes are re-simulated from
the folder's run.json and policy files, a chunk at a time (the bench is
deterministic, so the traces reproduce the stored scores; a mismatch warns).
The page lists every (policy, scenario) episode, filterable and sortable by
status, DS, behaviour and infraction type; "compare with" plays another
policy's episode of the same scenario side by side on one time slider.
Controls: play/pause (Space), step (Left/Right), scrub, speed, follow-ego or
drag/scroll to pan/zoom; click an infraction marker to jump to it.
See docs/visual.md.
"""

#: One BEV (LiDAR) frame per this many seconds in the page; the traces render sensors only there.
BEV_PERIOD_S, LIDAR_PERIOD_S = 0.2, 0.5


def add_parser(subparsers) -> None:
    p = common.add_command(
        subparsers, "view", help="write an HTML episode player for a results folder",
        description="Re-simulate the episodes of a `drivee2e bench` results folder and write an HTML player: "
                    "an index of every (policy, scenario) episode, and per episode the top-down scene, the BEV "
                    "the policy saw (its own size and route window), a LiDAR point cloud, metric timelines and "
                    "infractions, loaded on demand from one small file per episode.",
        epilog=EPILOG,
    )
    p.add_argument("results_dir", type=Path, metavar="RESULTS_DIR", help="a `drivee2e bench` output folder")
    p.add_argument("--out", type=Path, required=True, metavar="PAGE.html",
                   help="the page to write (episode files go to <PAGE>_files/ beside it)")
    p.add_argument("--policy", action="append", default=None, metavar="NAME",
                   help="policy in the folder (repeatable; default: every policy of the run)")
    p.add_argument("--scenario", action="append", default=None, metavar="ID",
                   help="scenario id to include (repeatable; default: every scenario of the run)")
    p.add_argument("--limit", type=int, default=None, metavar="N", help="only the first N chosen scenarios")
    p.add_argument("--no-sensors", action="store_true", help="leave out the BEV and LiDAR panes (faster, smaller)")
    p.add_argument("--single-file", action="store_true",
                   help="embed every episode in the page (no <PAGE>_files folder; for a few episodes)")
    p.add_argument("--chunk-size", type=int, default=None, metavar="N",
                   help="episodes rendered per batch (memory vs speed; default: 8)")
    p.add_argument("--force", action="store_true",
                   help="overwrite an existing page and its episode folder (only ones drivee2e wrote)")
    p.add_argument("--title", default=None, help="page title (default: the results folder's name)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _check_args(args) -> None:
    """One-line DriveE2EError for a bad results folder, --out or number."""
    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.viz.player import check_overwrite, files_dir

    if not Path(args.results_dir).is_dir():
        raise DriveE2EError(f"{args.results_dir}: no such results folder")
    out = Path(args.out)
    if out.is_dir() or out.suffix.lower() not in (".html", ".htm"):
        raise DriveE2EError(f"--out {out}: {'is a folder; ' if out.is_dir() else ''}expected an .html file path")
    for path in (out, files_dir(out)):
        if path.exists() and not args.force and not (args.single_file and path != out):
            raise DriveE2EError(f"--out {out}: {path} exists; use --force to overwrite")
    check_overwrite(out, single_file=args.single_file)  # --force rewrites only the player's own files
    if args.limit is not None and args.limit < 1:
        raise DriveE2EError(f"--limit {args.limit}: expected a positive number of scenarios")
    if args.chunk_size is not None and args.chunk_size < 1:
        raise DriveE2EError(f"--chunk-size {args.chunk_size}: expected a positive number of episodes")


def _plan(args) -> list[tuple[str, int]]:
    """(policy, number of episodes) to write, every name and id checked before any work."""
    from drivee2e_jax.eval.traces import run_policies, run_scenarios, select_rows

    policies = list(dict.fromkeys(args.policy or run_policies(args.results_dir)))
    plan = []
    for name in policies:
        rows = select_rows(run_scenarios(args.results_dir, name), args.scenario)
        plan.append((name, len(rows) if args.limit is None else min(len(rows), args.limit)))
    return plan


def run(args) -> int:
    from drivee2e_jax.errors import DriveE2EError

    _check_args(args)
    from drivee2e_jax.eval.traces import TRACE_CHUNK, check_results, iter_traces
    from drivee2e_jax.observe import registry
    from drivee2e_jax.progress import progress
    from drivee2e_jax.viz.player import PlayerWriter, files_dir

    plan = _plan(args)
    total = sum(n for _, n in plan)
    if not total:
        raise DriveE2EError(f"{args.results_dir}: no episodes to show")
    check_results(args.results_dir, [name for name, _ in plan])  # stale results: refused before any file is written
    results = Path(args.results_dir)
    title = args.title or results.resolve().name
    writer = PlayerWriter(args.out, title=title, single_file=args.single_file, sensors=not args.no_sensors,
                          bev_period_s=BEV_PERIOD_S, lidar_period_s=LIDAR_PERIOD_S)
    bar = progress(total=total, unit="ep", desc="view", disable=True if args.no_progress else None)
    try:
        for name, _ in plan:
            bar.set_description(f"{name}: re-simulating")
            stride, lidar_stride = _strides(results, name)
            for k, tr in enumerate(iter_traces(results, name, args.scenario, limit=args.limit,
                                               sensors=() if args.no_sensors else registry.shown(),
                                               chunk_size=args.chunk_size or TRACE_CHUNK,
                                               sensor_stride=stride, lidar_stride=lidar_stride)):
                if k == 0:
                    bar.set_description(name)
                writer.add(tr)
                bar.update(1)
            _release()
    finally:
        bar.close()
    out = writer.close()
    where = out if args.single_file else f"{out} + {files_dir(out)}/"
    n = len(writer.index)
    print(f"wrote {where} ({n} episode{'s' * (n != 1)}, {writer.bytes_written / 2**20:.1f} MiB); "
          f"open {out} in a browser")
    return common.EXIT_OK


def _release() -> None:
    """Drop the finished policy's compiled programs and hand freed heap back
    to the system before the next policy simulates: without it each policy's
    peak sits on the last one's leftovers (compiled programs; glibc keeps the
    freed pages of the episode files' JSON). The next policy's programs come
    back from the persistent compile cache."""
    import ctypes
    import gc

    import jax

    gc.collect()
    jax.clear_caches()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: nothing to trim
        pass


def _strides(results: Path, policy: str) -> tuple[int, int]:
    """(sensor, LiDAR) strides in instants at the run's dt: one frame per
    ``BEV_PERIOD_S`` / ``LIDAR_PERIOD_S`` (what the page keeps)."""
    from drivee2e_jax.eval.traces import read_run

    dt = float(read_run(results, policy).spec.dt)
    return tuple(max(1, int(round(period / dt))) for period in (BEV_PERIOD_S, LIDAR_PERIOD_S))
