"""`drivee2e export-mcap`: re-simulate episodes of a results folder into an MCAP file for Foxglove."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli.common import add_command

EPILOG = """\
examples (after `drivee2e bench --split val --limit 5`, which writes results/twin15-val):
  drivee2e export-mcap results/twin15-val --scenario twin15_0000 --out ep.mcap
  drivee2e export-mcap results/twin15-val --policy expert --scenario twin15_0000 --scenario twin15_0001 --out two.mcap
  drivee2e export-mcap results/twin15-val --out all.mcap --no-sensors --force

Episodes are re-simulated (rollouts are deterministic) with the run's settings
from the folder the bench ran in; each episode's Driving Score is checked
against the stored one. Messages use Foxglove's published protobuf schemas
(the metrics topic is JSON). Open the file in Foxglove (File > Open local
file); topics are /<scenario>/{tf,scene,map,bev,lidar,metrics,infractions}
(docs/visual.md).
"""


def add_parser(subparsers) -> None:
    p = add_command(
        subparsers, "export-mcap",
        help="write episodes of a results folder as an MCAP log (Foxglove)",
        description="Re-simulate episodes of a `drivee2e bench` results folder and write them to one MCAP file "
        "in Foxglove's published schemas: scene entities (ego, agents, map, route, signals), the BEV as an "
        "image, LiDAR as a point cloud, metrics and infractions.",
        epilog=EPILOG,
    )
    p.add_argument("results", type=Path, metavar="RESULTS_DIR", help="a `drivee2e bench` output folder")
    p.add_argument("--policy", default=None, help="policy name in the folder (default: the run's first policy)")
    p.add_argument("--scenario", action="append", dest="scenarios", metavar="ID",
                   help="scenario id to export; repeatable (default: every scenario of the run)")
    p.add_argument("--out", type=Path, required=True, metavar="FILE.mcap", help="output file")
    p.add_argument("--no-sensors", action="store_true", help="leave out the BEV and LiDAR topics (smaller, faster)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output file (only one drivee2e wrote)")
    p.set_defaults(func=run)


def run(args) -> int:
    from drivee2e_jax.errors import DriveE2EError

    out: Path = args.out
    if out.exists() and not args.force:
        raise DriveE2EError(f"{out}: exists; use --force to overwrite or choose another --out")
    if out.exists() and out.is_dir():
        raise DriveE2EError(f"{out}: is a folder; expected a file name ending in .mcap")

    from drivee2e_jax.eval.traces import trace_episodes
    from drivee2e_jax.io.mcap_export import check_overwrite, topics, write_mcap

    check_overwrite(out)  # --force rewrites only an MCAP file drivee2e wrote
    from drivee2e_jax.observe import registry

    traces = trace_episodes(args.results, args.policy, args.scenarios,
                            sensors=() if args.no_sensors else registry.shown())
    write_mcap(traces, out)
    n_topics = sum(len(topics(t)) for t in traces)
    bad = [t.scenario_id for t in traces if not t.reproduced]
    print(f"{out}: {len(traces)} episode(s) of {traces[0].policy if traces else '?'}, {n_topics} topics, "
          f"{out.stat().st_size / 1e6:.1f} MB")
    if bad:
        print(f"warning: re-simulated driving score differs from the stored one for {', '.join(bad)}")
    return 0
