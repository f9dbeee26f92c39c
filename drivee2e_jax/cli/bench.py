"""`drivee2e bench`: evaluate policies on a suite split, closed loop, all at once."""

from __future__ import annotations

import argparse
from pathlib import Path

EPILOG = """\
examples:
  drivee2e bench                                   # twin15 val, the three reference policies
  drivee2e bench --policy expert --split test --out results/expert-test
  drivee2e bench --suite path/to/suite --policy my_policy.py --control-every 2 --latency 1
  drivee2e bench --open-loop --policy constant_velocity --policy expert --out results/ol
  drivee2e bench --task lane_following --policy expert --repetitions 3
  drivee2e bench --variant visible_vehicles --policy log_replay --policy expert
  drivee2e bench --policy ad_mlp:checkpoint=runs/ad_mlp/checkpoints/3,name=ad_mlp_e3 --policy stop
  drivee2e bench --policy expert --preset nuplan --agents idm --collisions at_fault --out results/nuplan-idm
  drivee2e bench --coordinator 10.0.0.1:4000 --num-processes 2 --process-id 0   # and --process-id 1 elsewhere
  drivee2e bench --suite path/to/suite --shard-size 2 --policy log_replay --out results/streamed   # read shard by shard

Reference policies can be named without a path: log_replay, expert, stop,
constant_velocity. --open-loop adds L2 at 1/2/3 s (ST-P3 and UniAD
conventions) and the open-loop collision rate for waypoint policies.
--task picks a Behavior Metrics driving task: route_navigation (default,
every scenario), driving_in_traffic (scenarios with a logged vehicle ahead;
success also needs never < 6 m behind it), lane_following (straight routes,
other agents and signals removed; success also needs lane deviation <= 0.5 m
and average speed 0.7-1.1 x the speed limit); see drivee2e_jax/eval/tasks.py.
--variant re-evaluates the split with the agents never visible from the ego's
cameras along the logged run removed: visible_vehicles (vehicles only) or
visible_all (every category); complete (default) = as recorded. The masks are
computed once per split and cached (scenario/variants.py).
--preset nuplan / navsim make nuPlan's closed-loop score / NAVSIM's EPDMS the
headline (rows also carry nuplan_* / navsim_* sub-metrics; LB-style RC / DS
are still computed). --collisions at_fault counts only the collisions nuPlan
holds the ego responsible for; the tables show DS and SR both ways anyway.
--agents idm makes the other vehicles react (IDM) instead of replaying logs.
Results go to results/<suite>-<split>[-<task>][-<variant>]/ unless --out is given. One run at a
time writes a folder (a second one stops, naming the first). A rerun resumes: a finished policy is
skipped only while the suite content, settings, package version and its policy file / the modules
it imports from its folder / arguments / checkpoint are unchanged (else the run stops and says what
changed; --force starts over); remote policies are always re-run. --force never deletes a file
drivee2e did not write: a folder without run.json, or holding other files, is refused. The tables
list every finished policy of the folder (docs/results.md).
"""


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "bench",
        help="evaluate policies closed-loop on a suite split (the main job)",
        description="Run every episode of a suite split in one batched, jit-compiled closed-loop rollout per policy; "
        "print SR / DS / RC / infraction rates per policy and per behaviour group; write per-scenario results.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--suite", default="twin15", help="suite name (twin15) or suite folder (default: twin15)")
    p.add_argument("--split", default=None,
                   help="split to evaluate (default: val, or the suite's only non-empty split)")
    p.add_argument(
        "--policy",
        action="append",
        dest="policies",
        metavar="P",
        help="policy file (.py) or reference policy name, optionally with make_policy arguments as "
        "P:key=value,... (name=... renames it in the results); repeatable (default: log_replay, expert, stop)",
    )
    p.add_argument("--out", type=Path, default=None, help="results folder (default: results/<suite>-<split>)")
    p.add_argument("--force", action="store_true", help="redo an existing results folder (only one holding nothing but bench's files)")
    p.add_argument(
        "--preset",
        default="paper",
        metavar="NAME",
        help="scoring rules: paper, drivee2e, lb20, lb21, b2d, nuplan (nuPlan closed-loop score) or navsim "
             "(NAVSIM EPDMS) (default: paper = DriveE2E as its paper defines SR/DS; see docs/metrics.md)",
    )
    p.add_argument(
        "--collisions",
        default="all",
        metavar="MODE",
        help="which collisions count against IS / DS / SR: all (every collision with a logged agent, the paper's "
             "protocol; default) or at_fault (nuPlan's attribution: hitting a stopped agent, rear-ending, or a "
             "lateral contact while changing lanes / off the drivable area)",
    )
    p.add_argument(
        "--agents",
        default="log",
        metavar="MODEL",
        help="the other agents: log (replay the recorded tracks, non-reactive; default) or idm (vehicles react "
             "to the ego with the Intelligent Driver Model)",
    )
    p.add_argument("--dt", type=float, default=0.1,
                   help="simulation step in seconds, 0 < dt <= 1 and <= the log step (default: 0.1)")
    p.add_argument("--control-every", type=int, default=1, help="query the policy every k sim steps (default: 1)")
    p.add_argument("--latency", type=int, default=0, help="action latency in sim steps (default: 0)")
    p.add_argument("--limit", type=int, default=None, help="evaluate only the first N scenarios of the split")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed (observation noise, stochastic policies)")
    p.add_argument(
        "--open-loop",
        action="store_true",
        help="also score waypoint policies open-loop on the logged demonstrations (L2 at 1/2/3 s, collision rate)",
    )
    p.add_argument(
        "--task",
        default="route_navigation",
        choices=("route_navigation", "driving_in_traffic", "lane_following"),
        help="driving task: scenario filter + success rule (default: route_navigation)",
    )
    p.add_argument("--repetitions", type=int, default=1, metavar="N",
                   help="run each policy N times (seeds seed..seed+N-1); report gives mean ± std (default: 1)")
    p.add_argument("--variant", default="complete", metavar="NAME",
                   help="suite variant: complete, visible_vehicles or visible_all (agents never visible from the "
                        "ego's cameras along the logged run removed; default: complete)")
    p.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="several processes (jax.distributed): process 0's address, or 'auto' on SLURM / Open MPI "
                        "(default: $DRIVEE2E_COORDINATOR, else one process); docs/scaling.md")
    p.add_argument("--num-processes", type=int, default=None, metavar="N",
                   help="processes in the run (default: $DRIVEE2E_NUM_PROCESSES)")
    p.add_argument("--process-id", type=int, default=None, metavar="I",
                   help="this process, 0..N-1; process 0 writes the results (default: $DRIVEE2E_PROCESS_ID)")
    p.add_argument("--shard-size", type=int, default=None, metavar="N",
                   help="stream the split through the compiled rollout N scenarios at a time; a suite folder is "
                        "then read shard by shard, never whole (suites larger than memory); same results as "
                        "without (default: the whole split in one batch); docs/scaling.md")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    from drivee2e_jax.eval.bench import BenchConfig, run_bench
    from drivee2e_jax.policy import DEFAULT_POLICIES, parse_policy_spec

    specs = [parse_policy_spec(p) for p in (args.policies or DEFAULT_POLICIES)]
    cfg = BenchConfig(
        suite=args.suite,
        split=args.split,
        policies=tuple(str(path) for path, _, _ in specs),
        policy_kwargs=tuple(kw for _, kw, _ in specs),
        policy_names=tuple(name for _, _, name in specs),
        out=args.out,
        force=args.force,
        preset=args.preset,
        dt=args.dt,
        control_every=args.control_every,
        latency=args.latency,
        limit=args.limit,
        seed=args.seed,
        progress=not args.no_progress,
        open_loop=args.open_loop,
        task=args.task,
        repetitions=args.repetitions,
        variant=args.variant,
        collisions=args.collisions,
        agents=args.agents,
        coordinator=args.coordinator,
        num_processes=args.num_processes,
        process_id=args.process_id,
        shard_size=args.shard_size,
    )
    run_bench(cfg, print_fn=print)
    return 0
