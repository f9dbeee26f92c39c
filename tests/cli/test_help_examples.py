"""Every example of every ``--help`` runs.

The examples are the indented ``drivee2e ...`` lines of the ``examples:`` (or
``example:``) block of each parser's epilog, every subcommand and sub-subcommand
of :func:`drivee2e_jax.cli.build_parser`. They run in-process through
:func:`drivee2e_jax.cli.main` (one process: JAX's compile caches are shared) in
one temporary working folder, in :data:`ORDER` of their commands, so that earlier
examples make what later ones use: ``dataset build`` the demonstrations, ``train`` the run that ``bench``,
``trend``, ``finetune`` and ``check-policy`` load, ``bench`` the results that
``view`` and ``export-mcap`` replay. An example given twice runs once.

To bound the time, :data:`FASTER` appends flags to some commands (the last
occurrence of a flag wins, so they override the example's own): ``--limit 5``
scenarios for ``bench`` (the ``view`` and ``export-mcap`` examples name
scenarios among the first 5 of twin15 val), ``--limit 2`` for ``dataset
build``, ``trend`` and ``view``; a batch of 16 for ``train`` (the 2-scenario
demonstrations hold under one default batch); 2 steps of horizon 5 on a pool
of 2 for ``finetune``; ``--no-sensors`` for ``view`` (rendering the sensor
panes took ~20 s of a page's ~45 s; tests/viz/test_player_observation.py
checks them) and ``--policy stop`` (each policy of the page is re-simulated:
the bench's three took 58 s of the first page example and 30 s of each later
one; tests/viz/test_player_html.py covers pages of several policies).

The working folder holds what the examples assume from a checkout
(``experiments/``, ``docs/examples/``) and the
placeholders of :data:`PLACEHOLDERS` (``my_policy.py``, ``path/to/suite``).
Examples that cannot run in one process, and ``suite generate`` (the slowest
example, covered twice elsewhere), are listed in :data:`NOT_RUN` with the
reason and the tests that cover them.
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from drivee2e_jax import cli

REPO = Path(__file__).resolve().parents[2]

#: Commands in the order their examples run (makers before users); a command
#: not listed runs after these, in ``drivee2e --help`` order.
ORDER = (
    ("suite", "generate"), ("suite",), ("suite", "info"), ("suite", "validate"), ("suite", "import"), (),
    ("dataset", "build"), ("dataset",), ("dataset", "info"), ("train",), ("finetune",), ("rl",), ("bench",), ("trend",),
    ("sweep",), ("view",), ("export-mcap",), ("check-policy",), ("serve-policy",),
)

#: Flags appended to a command's examples to keep the test short (see the module docstring).
FASTER = {
    ("bench",): ["--limit", "5"],  # the view / export-mcap examples name val scenarios among the first 5
    ("dataset", "build"): ["--limit", "2"],
    ("trend",): ["--limit", "2"],
    ("view",): ["--limit", "2", "--no-sensors", "--policy", "stop"],  # see the docstring
    ("train",): ["--batch-size", "16"],
    ("finetune",): ["--steps", "2", "--horizon", "5", "--batch", "2", "--ckpt-every", "1"],
    ("rl",): ["--envs", "4", "--rollout-steps", "4", "--minibatches", "2", "--epochs", "1", "--env-steps", "32",
              "--limit", "4", "--ckpt-every", "1"],
}

#: Examples not run here: (text in the example, why, the test that covers it).
NOT_RUN = (
    ("--coordinator", "needs two cooperating processes", "tests/eval/test_distributed.py"),
    ("drivee2e serve-policy", "a server that blocks until stopped", "tests/cli/test_serve_policy.py, tests/test_remote.py"),
    ("remote://", "needs a running serve-policy server", "tests/test_remote.py"),
    ("drivee2e suite import", "needs recorded data the user downloads", "tests/cli/test_suite_import.py"),
    ("drivee2e suite generate", "25-75 s for all 800 twin15 scenarios, which the test session already generates",
     "tests/scenario/test_twin15.py (the generator), tests/cli/test_suite.py (the command, --out / --force)"),
)

#: Paths the examples name as placeholders for the user's own -> what stands in for them.
PLACEHOLDERS = {
    "my_policy.py": REPO / "drivee2e_jax" / "zoo" / "constant_velocity.py",
    "path/to/suite": REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny",
}

#: Checkout folders the examples name (copied into the working folder).
FROM_CHECKOUT = ("experiments", "docs/examples")


#: The first line of an epilog's examples block.
EXAMPLES_HEADER = re.compile(r"examples?( \(.*\))?:")


@dataclass(frozen=True)
class Example:
    command: tuple[str, ...]  # the parser's command path, () for `drivee2e` itself
    line: str  # the example as printed
    argv: list[str]  # the arguments after `drivee2e`
    pipe: list[str]  # the shell command it is piped into, if any


def examples_of(epilog: str | None) -> list[str]:
    """The ``drivee2e ...`` lines of an epilog's ``examples:`` block (its header
    may be ``example:`` or carry a note: ``examples (after ...):``; the block
    ends at the first line that is neither indented nor blank)."""
    lines, out, inside = (epilog or "").splitlines(), [], False
    for line in lines:
        if not inside:
            inside = EXAMPLES_HEADER.fullmatch(line) is not None
            continue
        if line.strip() and not line.startswith((" ", "\t")):
            break
        if line.strip().startswith("drivee2e "):
            out.append(line.strip())
    return out


def parse_example(command: tuple[str, ...], line: str) -> Example:
    """Split an example line into argv (comment dropped, quotes honoured) and a pipe."""
    tokens = shlex.split(line, comments=True)
    head, pipe = (tokens[: tokens.index("|")], tokens[tokens.index("|") + 1:]) if "|" in tokens else (tokens, [])
    assert head[0] == "drivee2e", line
    return Example(command, line, head[1:], pipe)


def _parsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) of the parser and every sub(-sub)command parser."""
    yield path, parser
    for action in parser._actions:  # argparse keeps subparsers only here
        if isinstance(action, argparse._SubParsersAction):
            seen = set()
            for name, sub in action.choices.items():
                if id(sub) not in seen:  # aliases share a parser
                    seen.add(id(sub))
                    yield from _parsers(sub, (*path, name))


def collect_examples(parser: argparse.ArgumentParser) -> list[Example]:
    """Every distinct example of every parser, in :data:`ORDER` of their commands."""
    found = [parse_example(path, line) for path, p in _parsers(parser) for line in examples_of(p.epilog)]
    rank = {c: i for i, c in enumerate(ORDER)}
    found.sort(key=lambda e: rank.get(e.command, len(ORDER)))  # stable: listing order within a command
    distinct, seen = [], set()
    for e in found:
        key = (tuple(e.argv), tuple(e.pipe))
        if key not in seen:
            seen.add(key)
            distinct.append(e)
    return distinct


def _command_of(argv: list[str], parser: argparse.ArgumentParser) -> tuple[str, ...]:
    """The command path an argv names (``["dataset", "build", ...]`` -> ``("dataset", "build")``)."""
    commands = {path for path, _ in _parsers(parser)}
    path: tuple[str, ...] = ()
    for token in argv:
        if (*path, token) not in commands:
            break
        path = (*path, token)
    return path


def _not_run(example: Example) -> tuple[str, str] | None:
    for text, why, covered_by in NOT_RUN:
        if text in example.line:
            return why, covered_by
    return None


def _prepare(workdir: Path) -> None:
    """The checkout folders and placeholders the examples assume."""
    for rel in FROM_CHECKOUT:
        shutil.copytree(REPO / rel, workdir / rel, ignore=shutil.ignore_patterns("__pycache__", "results", "runs"))
    for rel, source in PLACEHOLDERS.items():
        (workdir / rel).parent.mkdir(parents=True, exist_ok=True)
        (shutil.copytree if source.is_dir() else shutil.copy)(source, workdir / rel)


def _check_pipe(example: Example, out: str) -> str | None:
    """What is wrong with the piped output, if anything (only ``python -m json.tool`` is known)."""
    if example.pipe[-3:] != ["python", "-m", "json.tool"]:
        return f"unknown pipe {shlex.join(example.pipe)!r}: teach this test to check it"
    try:
        json.loads(out)
    except json.JSONDecodeError as e:
        return f"output is not JSON for json.tool: {e}"
    return None


def test_examples_of_reads_the_block_and_only_it():
    epilog = ("examples:\n  drivee2e a --x 1   # note\n\n  # then, elsewhere:\n  drivee2e b | python -m json.tool\n"
              "\nText naming drivee2e c, not an example.\n  drivee2e d\n")
    lines = examples_of(epilog)
    assert lines == ["drivee2e a --x 1   # note", "drivee2e b | python -m json.tool"]
    a, b = (parse_example(("a",), line) for line in lines)
    assert (a.argv, a.pipe) == (["a", "--x", "1"], [])
    assert (b.argv, b.pipe) == (["b"], ["python", "-m", "json.tool"])
    assert parse_example((), """drivee2e t --cfg '{"h": [64, 64]}'""").argv == ["t", "--cfg", '{"h": [64, 64]}']
    assert examples_of("no block here\n  drivee2e x\n") == []
    assert examples_of("example (after `drivee2e bench`):\n  drivee2e y\n") == ["drivee2e y"]


def test_every_subcommand_has_examples_and_the_order_makes_before_it_uses():
    parser = cli.build_parser()
    examples = collect_examples(parser)
    commands = {e.argv[0] for e in examples}
    missing = [c.replace("_", "-") for c in cli.SUBCOMMANDS if c.replace("_", "-") not in commands]
    assert not missing, f"subcommands without a runnable --help example: {missing}"
    first = {}
    for i, e in enumerate(examples):
        first.setdefault(_command_of(e.argv, parser), i)
    assert first[("suite", "generate")] < first[("dataset", "build")] < first[("train",)] < first[("trend",)]
    assert first[("bench",)] < first[("view",)]


@pytest.mark.slow
def test_every_help_example_runs(tmp_path, monkeypatch, capsys):
    """Each example exits 0 (``check-policy``'s conformance failures included);
    a piped example's output suits the pipe. All failures are reported together."""
    parser = cli.build_parser()
    examples = collect_examples(parser)
    _prepare(tmp_path)
    monkeypatch.chdir(tmp_path)
    failures, timings, skipped = [], [], []
    for example in examples:
        reason = _not_run(example)
        if reason is not None:
            skipped.append((example.line, *reason))
            continue
        argv = example.argv + FASTER.get(_command_of(example.argv, parser), [])
        start = time.perf_counter()
        try:
            code = cli.main(argv)
        except BaseException as e:  # noqa: BLE001 - report every example, not the first failure
            code = f"raised {type(e).__name__}: {e}"
        out, err = capsys.readouterr()
        timings.append((time.perf_counter() - start, shlex.join(argv)))
        problem = None if code == 0 else f"exit {code}: {(err.strip().splitlines() or [''])[-1][:300]}"
        if problem is None and example.pipe:
            problem = _check_pipe(example, out)
        if problem is not None:
            failures.append(f"drivee2e {' '.join(example.command)} --help: {example.line}\n    -> {problem}")
    with capsys.disabled():
        print(f"\n{len(timings)} examples in {sum(t for t, _ in timings):.0f} s; slowest:")
        for seconds, command in sorted(timings, reverse=True)[:8]:
            print(f"  {seconds:6.1f} s  drivee2e {command}")
    assert len(timings) >= 20, (timings, skipped)  # the collector found the examples
    assert not failures, f"{len(failures)} of {len(timings)} --help examples failed:\n" + "\n".join(failures)
