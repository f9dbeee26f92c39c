"""`drivee2e dataset`: record the reference demonstrations for imitation training."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.cli.common import add_command

EPILOG = """\
examples:
  drivee2e dataset build --suite twin15 --split train --out data/demos-train
  drivee2e dataset build --suite twin15 --split train --sensors bev --bev-size 64 --out data/demos-train-bev64
  drivee2e dataset build --suite twin15 --split val --limit 20 --every 10 --out data/demos-val20
  drivee2e dataset info data/demos-train

build rolls log_replay over the split and records every --every-th step (5 x
0.1 s = 2 Hz) the observation a policy gets (with the sensors listed in
--sensors and the ego's 4 s history) and the label (6 logged future waypoints
0.5 s apart, the log-reproducing controls, the route command), as .npz shards
plus manifest.json. Train on it with `drivee2e train --data DIR`.
The BEV is rendered --bev-size px square at --bev-resolution m/px (default
128 at 0.5 = 64 m; a size alone keeps the 64 m extent): give TCP its own 64 x
64 at 1 m/px with --bev-size 64. The manifest records it; training refuses a
model that cannot read it, and a policy restored from the checkpoint is
evaluated at the same BEV.
"""


def add_parser(subparsers) -> None:
    p = add_command(subparsers, "dataset", help="record demonstrations for imitation training",
                    description="Build or inspect a demonstration dataset (chunked .npz shards + manifest.json) "
                                "for `drivee2e train --data DIR`. Subcommands: build (record a split's "
                                "demonstrations into a folder), info (summarise a built folder). "
                                "`drivee2e dataset <action> --help` lists each one's flags.",
                    epilog=EPILOG)
    sub = p.add_subparsers(dest="action", metavar="<action>", required=True)
    b = sub.add_parser("build", help="record a split's demonstrations into --out (shards + manifest.json)",
                       description="Roll log_replay over a suite split and record, every --every-th 0.1 s step, "
                                   "the observation a policy gets (with --sensors and the ego's 4 s history) and "
                                   "its label (6 logged future waypoints 0.5 s apart, the log-reproducing "
                                   "controls, the route command). Writes OUT/shard-NNNNN.npz (one per --shard "
                                   "scenarios, compressed, each written atomically; existing shards are "
                                   "overwritten) and OUT/manifest.json last (suite, version, split, sensors, BEV "
                                   "size, sampling, counts, leaf shapes), then prints the summary `info` prints.")
    b.add_argument("--suite", default="twin15", help="suite name or suite folder to record (default: twin15)")
    b.add_argument("--split", default="train", help="split of the suite to record (default: train)")
    b.add_argument("--sensors", default="",
                   help="comma-separated sensors rendered into the observation: bev, lidar (default: none, "
                        "vector observation only); a model trained on the data needs the same sensors")
    b.add_argument("--bev-size", type=int, default=128,
                   help="BEV raster side, px, with --sensors bev (default: 128; 64 = TCP's own input)")
    b.add_argument("--bev-resolution", type=float, default=None,
                   help="BEV m/px (default: 64 m / --bev-size, i.e. 0.5 at 128, 1.0 at 64)")
    b.add_argument("--every", type=int, default=5,
                   help="record one sample every k-th 0.1 s simulation step (default: 5 = 2 Hz)")
    b.add_argument("--limit", type=int, default=None,
                   help="record only the first N scenarios of the split (default: all)")
    b.add_argument("--shard", type=int, default=25, help="scenarios per .npz shard (default: 25)")
    b.add_argument("--seed", type=int, default=0, help="PRNG seed of the rollout (observation noise; default: 0)")
    b.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    b.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    b.set_defaults(func=run_build)
    i = sub.add_parser("info", help="print a built dataset's summary (from its manifest.json)",
                       description="Print one line about a dataset folder, read from its manifest.json: suite, "
                                   "version, split, scenarios, samples, shards, size on disk, sensors and BEV, "
                                   "build time, and the per-sample shapes of the main observation leaves. "
                                   "Writes nothing.")
    i.add_argument("path", type=Path, help="dataset folder written by `drivee2e dataset build` (holds manifest.json)")
    i.set_defaults(func=run_info)


def run_build(args) -> int:
    from drivee2e_jax.progress import progress
    from drivee2e_jax.train.dataset import DatasetConfig, build_dataset

    sensors = tuple(s.strip() for s in args.sensors.split(",") if s.strip())
    cfg = DatasetConfig(sensors=sensors, every=args.every, scenarios_per_shard=args.shard, bev_size=args.bev_size,
                        bev_resolution=args.bev_resolution)
    bar = progress(total=None, desc="scenarios", disable=True if args.no_progress else None)

    def update(done, total):
        bar.total = total
        bar.n = done
        bar.refresh()

    m = build_dataset(args.suite, args.split, args.out, cfg, limit=args.limit, seed=args.seed, progress=update)
    bar.close()
    print(_summary(m, args.out))
    return 0


def run_info(args) -> int:
    from drivee2e_jax.train.dataset import DemoDataset

    print(_summary(DemoDataset(args.path).manifest, args.path))
    return 0


def _summary(m: dict, path) -> str:
    leaves = ", ".join(f"{k}{tuple(v['shape'])}" for k, v in m["leaves"].items() if k.startswith("obs.") and
                       k.split(".")[1] in ("bev", "lidar", "history", "agents", "lanes"))
    from drivee2e_jax.models.checkpoint import bev_of_manifest
    from drivee2e_jax.observe.bev import bev_label

    bev = bev_of_manifest(m)
    return (f"{path}: {m['suite']} v{m['suite_version']} {m['split']}, {m['num_scenarios']} scenarios, "
            f"{m['count']} samples in {len(m['shards'])} shards, {m['bytes'] / 1e6:.1f} MB, sensors "
            f"{','.join(m['sensors']) or 'none'}{f' (BEV {bev_label(bev)})' if bev else ''}, "
            f"built in {m['build_s']:.0f} s; {leaves}")
