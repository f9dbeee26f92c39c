"""Shared CLI plumbing: parser helpers, error handling, progress bars.

Every subcommand module ``drivee2e_jax/cli/<name>.py`` exposes
``add_parser(subparsers)`` which adds its parser (use :func:`add_command` for
the house style: description + example epilog, raw formatting) and sets
``func=<callable(args) -> int>`` with ``set_defaults``. Keep heavy imports
(jax, the simulator) inside the ``func`` so that ``drivee2e --help`` is quick
and one broken module cannot break the others.

Errors: :class:`DriveE2EError` and the other *expected* errors (missing or
unreadable files, invalid JSON, out of memory) print one line ``drivee2e:
error: <message>`` on stderr and exit 2; anything else is a bug: one line
naming the exception plus "rerun with --debug for the traceback", exit 1.
Ctrl-C prints ``drivee2e: interrupted`` and exits 130. ``--debug`` (accepted
anywhere on the command line) prints every error's traceback, causes
included, before that line, and keeps the exit code.
"""

from __future__ import annotations

import argparse
import json
import sys
import textwrap
from collections.abc import Callable
from typing import Any

from drivee2e_jax.errors import DriveE2EError, one_line

PROG = "drivee2e"

#: Exit codes: 0 ok, 1 the command ran and found problems, 2 bad input / usage.
EXIT_OK, EXIT_PROBLEMS, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130

#: Errors a user can fix: printed as one line, no traceback.
EXPECTED_ERRORS: tuple[type[BaseException], ...] = (
    DriveE2EError,
    FileNotFoundError,
    FileExistsError,
    NotADirectoryError,
    IsADirectoryError,
    PermissionError,
    OSError,  # disk full, too many open files, ...: the environment, not the code
    json.JSONDecodeError,
    UnicodeDecodeError,
    MemoryError,
)
#: Longest message line printed for an unexpected error (a JAX error can run to pages).
MAX_MESSAGE = 300


def add_command(subparsers, name: str, *, help: str, description: str, epilog: str,
                **kwargs: Any) -> argparse.ArgumentParser:
    """A subcommand parser with a description and an example epilog.

    The description is wrapped to 79 columns unless it has its own newlines
    (raw formatting keeps the epilog's examples as written)."""
    if "\n" not in description:
        description = textwrap.fill(description, 79)
    return subparsers.add_parser(
        name, help=help, description=description, epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs,
    )


def pop_debug(argv: list[str]) -> tuple[list[str], bool]:
    """Remove every ``--debug`` before a ``--`` terminator; report if any was there."""
    if "--" in argv:
        i = argv.index("--")
        head, tail = argv[:i], argv[i:]
    else:
        head, tail = argv, []
    kept = [a for a in head if a != "--debug"]
    return kept + tail, len(kept) != len(head)


def error_message(exc: BaseException) -> str:
    """The one-line text for an expected error."""
    if isinstance(exc, DriveE2EError):
        return str(exc)
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}"
    text = one_line(exc)
    if isinstance(exc, json.JSONDecodeError):
        return f"invalid JSON: {text}"
    if isinstance(exc, UnicodeDecodeError):
        return f"a file is not UTF-8 text: {text}"
    if isinstance(exc, MemoryError):
        return f"out of memory{': ' + text if text else ''} (try fewer scenarios, e.g. --limit, or a smaller batch)"
    return text or type(exc).__name__


def unexpected_message(exc: BaseException) -> str:
    """The one line for an unexpected error (a bug): its type, its message cut
    at ``MAX_MESSAGE`` characters, and how to see the traceback."""
    text = one_line(exc, MAX_MESSAGE)
    return f"{type(exc).__name__}{': ' + text if text else ''} (unexpected; rerun with --debug for the traceback)"



def print_error(message: str) -> None:
    """``drivee2e: error: MESSAGE`` on stderr, on a line of its own: open tqdm
    bars (a bench interrupted by a remote policy's error) are cleared first and
    redrawn after it instead of the line being glued to the bar."""
    line = f"{PROG}: error: {message}"
    tqdm_module = sys.modules.get("tqdm")  # only loaded when a bar may be open
    if tqdm_module is not None and getattr(tqdm_module.tqdm, "_instances", None):
        tqdm_module.tqdm.write(line, file=sys.stderr)
    else:
        print(line, file=sys.stderr)


def print_traceback(exc: BaseException) -> None:
    """``--debug``: the full traceback of ``exc`` on stderr, its causes first
    (``raise ... from``): a policy's error shows the policy file's own frames
    (the one-line error keeps the cause, ``hostbridge`` / ``testing``)."""
    import traceback

    tqdm_module = sys.modules.get("tqdm")
    for bar in list(getattr(getattr(tqdm_module, "tqdm", None), "_instances", None) or ()):
        bar.close()  # the traceback starts on a line of its own, not after a half-drawn bar
    traceback.print_exception(exc, file=sys.stderr)
    sys.stderr.flush()


def run(func: Callable[[argparse.Namespace], int | None], args: argparse.Namespace, *, debug: bool) -> int:
    """Call a subcommand: expected errors -> one line + exit 2, Ctrl-C -> exit
    130, any other exception -> one line + exit 1. ``debug``: the traceback
    (with its causes) is printed before the line, and the exit code is the
    same (a script that checks it behaves the same with --debug); Ctrl-C is
    re-raised."""
    try:
        code = func(args)
        sys.stdout.flush()
        return EXIT_OK if code is None else int(code)
    except BrokenPipeError:  # e.g. `drivee2e suite info twin15 | head`
        try:
            sys.stdout = open("/dev/null", "w")  # noqa: SIM115 - silence the flush at exit
        except OSError:
            pass
        return EXIT_OK
    except EXPECTED_ERRORS as e:
        if debug:
            print_traceback(e)
        print_error(error_message(e))
        return EXIT_USAGE
    except KeyboardInterrupt:
        if debug:
            raise
        print(f"{PROG}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as e:  # noqa: BLE001 - a bug: one line, the traceback behind --debug
        if debug:
            print_traceback(e)
        print_error(unexpected_message(e))
        return EXIT_PROBLEMS
