"""`drivee2e check-policy`: does a policy file keep the Policy / HostPolicy contract?"""

from __future__ import annotations

from drivee2e_jax.cli.common import EXIT_OK, EXIT_PROBLEMS, add_command

EPILOG = """\
examples:
  drivee2e check-policy my_policy.py
  drivee2e check-policy expert constant_velocity
  drivee2e check-policy docs/examples/numpy_constant_velocity.py      # a host policy
  drivee2e check-policy ad_mlp:checkpoint=runs/ad_mlp --suite twin15
  drivee2e check-policy stop --batch 2 --steps 2

FILE defines `policy` or `make_policy(**kwargs)` (FILE:key=value,... passes
make_policy arguments, JSON values): a JAX policy (drivee2e_jax.policy.Policy)
or a host policy (drivee2e_jax.hostapi.HostPolicy). The policy runs on the
first --batch scenarios of --suite (default: tiny, the 4-scenario example
suite shipped in the package), at --steps instants along their logs. Checked: the
declared attributes (name, action_type, waypoint_dt, num_waypoints,
required_sensors); the action's type, shapes and dtypes (float32); a stable
policy state; finite actions; the same action for the same inputs and key;
for JAX policies also jax.jit (no Python `if` on arrays) and jax.vmap over
scenarios, both agreeing with plain calls. See docs/policies.md.

Prints `ok: FILE (summary)` or one line per problem. Exit status: 0 every
file conforms, 1 problems were found, 2 a file could not be loaded or the
arguments are wrong.
"""


def add_parser(subparsers) -> None:
    p = add_command(subparsers, "check-policy", help="check that a policy file keeps the policy contract",
                    description="Load policy files (JAX or host policies) and run each on a few real observations: "
                    "declared attributes, action type / shapes / dtypes, state structure, finite and deterministic "
                    "actions, and for JAX policies jax.jit and jax.vmap. One line per problem.",
                    epilog=EPILOG)
    p.add_argument("policies", nargs="+", metavar="FILE",
                   help="policy file (.py) or reference policy name, optionally FILE:key=value,...")
    p.add_argument("--suite", default="tiny",
                   help="tiny (the 4-scenario example suite shipped in the package), twin15, or a suite folder "
                        "(default: tiny)")
    p.add_argument("--batch", type=int, default=4, metavar="N", help="scenarios to observe (default: 4)")
    # 10 = testing.DEFAULT_STEPS (not imported here: parsing stays free of JAX; a test pins the two equal)
    p.add_argument("--steps", type=int, default=10, metavar="N",
                   help="consecutive observations (act calls) per scenario, 5 simulator steps apart "
                        "(default: 10: covers a policy's warm-up / first action chunk)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the policy's keys (default: 0)")
    p.set_defaults(func=run)


def run(args) -> int:
    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.testing import check_policy_file

    if args.batch < 1 or args.steps < 1:
        raise DriveE2EError(f"--batch {args.batch} --steps {args.steps}: expected positive numbers")
    code = EXIT_OK
    for spec in args.policies:
        report = check_policy_file(spec, suite=args.suite, batch=args.batch, steps=args.steps, seed=args.seed)
        if report.ok:
            print(f"ok: {report.source} ({report.summary})", flush=True)
        else:
            code = EXIT_PROBLEMS
            for problem in report:
                print(problem, flush=True)
    return code
