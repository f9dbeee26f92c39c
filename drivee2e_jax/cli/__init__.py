"""The ``drivee2e`` command line: one command, subcommands in their own modules.

Each ``drivee2e_jax/cli/<module>.py`` listed in :data:`SUBCOMMANDS` exposes
``add_parser(subparsers)`` (see ``cli.common``). Modules are imported
defensively: a module that does not exist yet is skipped, and one that fails
to import becomes a subcommand that reports the failure, so the others keep
working. When the command line names a subcommand only its module is
imported, which keeps ``drivee2e suite ...`` free of unrelated imports.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys

from drivee2e_jax.cli import common

#: Subcommand modules, in the order ``drivee2e --help`` lists them. A module's
#: command name is its name with "_" -> "-" (``export_mcap`` -> ``export-mcap``).
SUBCOMMANDS = ("bench", "sweep", "suite", "dataset", "train", "finetune", "rl", "trend", "view", "export_mcap", "serve_policy", "check_policy")

DESCRIPTION = """\
drivee2e: a JAX ego-closed-loop replay benchmark for end-to-end driving policies.
The ego is driven by the policy under test; every other agent replays its log."""

EPILOG = """\
examples:
  drivee2e suite info twin15            # what is in the built-in suite
  drivee2e suite generate --out suites/twin15
  drivee2e bench --split val            # evaluate the reference policies

Add --debug anywhere to see the traceback of an error.
"""


def _command_module(argv: list[str]) -> str | None:
    """The module of the subcommand named on the command line, if any."""
    for token in argv:
        if token == "--":
            return None
        if not token.startswith("-"):
            mod = token.replace("-", "_")
            return mod if mod in SUBCOMMANDS else None
    return None


def _unavailable(subparsers, mod: str, exc: BaseException) -> None:
    name = mod.replace("_", "-")
    p = subparsers.choices.get(name)  # add_parser may have failed half-way
    if p is None:
        p = subparsers.add_parser(name, help=f"(unavailable: {type(exc).__name__})")
        p.add_argument("rest", nargs=argparse.REMAINDER, help=argparse.SUPPRESS)

    def fail(args):
        if args.debug:
            raise exc
        raise common.DriveE2EError(f"subcommand {name!r} is unavailable: the module drivee2e_jax.cli.{mod} "
                                   f"failed to import ({type(exc).__name__}: {exc}); rerun with --debug")

    p.set_defaults(func=fail)


class _VersionAction(argparse.Action):
    """``--version``: looks the version up only when asked (``importlib.metadata``
    costs ~30 ms, which every other command would pay for nothing)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="show program's version number and exit"):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        from importlib.metadata import PackageNotFoundError, version

        try:
            text = version("drivee2e-jax")
        except PackageNotFoundError:  # a checkout on sys.path, not installed as a distribution
            from drivee2e_jax import __version__ as text
        print(f"{parser.prog} {text}")  # on stdout, as argparse's own version action
        parser.exit()


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The full parser, or one with only the ``only`` subcommand module."""
    parser = argparse.ArgumentParser(
        prog=common.PROG, description=DESCRIPTION, epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks of errors (allowed anywhere)")
    parser.add_argument("--version", action=_VersionAction)
    subparsers = parser.add_subparsers(dest="command", metavar="<command>", required=True)
    for mod in SUBCOMMANDS if only is None else (only,):
        try:
            module = importlib.import_module(f"{__name__}.{mod}")
        except ModuleNotFoundError as e:
            if e.name == f"{__name__}.{mod}":
                continue  # not written yet
            _unavailable(subparsers, mod, e)
            continue
        except Exception as e:  # noqa: BLE001 - keep the other subcommands alive
            _unavailable(subparsers, mod, e)
            continue
        try:
            module.add_parser(subparsers)
        except Exception as e:  # noqa: BLE001 - a broken add_parser must not hide the rest
            _unavailable(subparsers, mod, e)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``drivee2e`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code.

    Run as the program (``argv`` None: the console script, ``python -m``;
    without --debug), a Ctrl-C leaves through ``os._exit(130)`` after
    flushing (:func:`_interrupted`): a normal interpreter shutdown while XLA's
    compile threads still run aborted with "pure virtual method called"
    (SIGABRT, exit 134) in about 3 of 10 tries.
    """
    if argv is None and "--debug" not in sys.argv[1:]:
        signal.signal(signal.SIGINT, _interrupted)  # commands with their own handler (serve-policy) replace it
    code = _main(argv)
    if argv is None and code == common.EXIT_INTERRUPTED:
        _interrupted()
    return code


def _interrupted(*_signal_args) -> None:
    """Ctrl-C of the program: ``drivee2e: interrupted``, flush, ``os._exit(130)``.

    Leaving through ``os._exit`` skips the interpreter shutdown that aborted
    while XLA's compile threads ran, and a handler rather than
    KeyboardInterrupt: JAX's garbage-collection callback swallowed the
    exception ("Exception ignored in _xla_gc_callback") and the run went on to
    exit 0. Results are written atomically (a kill loses nothing; rerun to resume).
    """
    try:
        print(f"{common.PROG}: interrupted", file=sys.stderr)
    except (OSError, ValueError):
        pass
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(common.EXIT_INTERRUPTED)


def _main(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    argv, debug = common.pop_debug(argv)
    try:
        parser = build_parser(_command_module(argv))
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version, usage errors
        return e.code if isinstance(e.code, int) else (0 if e.code is None else common.EXIT_USAGE)
    except KeyboardInterrupt:  # Ctrl-C while the subcommand's module imports
        if debug:
            raise
        print(f"{common.PROG}: interrupted", file=sys.stderr)
        return common.EXIT_INTERRUPTED
    args.debug = debug
    return common.run(_with_compile_cache, args, debug=debug)


def _with_compile_cache(args: argparse.Namespace) -> int | None:
    """Run the subcommand with the persistent compile cache on (reruns, resumed
    sweeps and trend checkpoints reuse compiled rollouts); inside ``common.run``
    so that its errors are one line too."""
    from drivee2e_jax import compile_cache

    compile_cache.enable()
    return args.func(args)
