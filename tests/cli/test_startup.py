"""`drivee2e` starts without JAX where it does not need it.

``drivee2e --help``, every subcommand's (and sub-subcommand's) ``--help`` and
``drivee2e suite info`` answered from a warm packed cache must not import JAX
or Flax (importing them costs ~1 s; docs/performance.md, "Start-up"). Each
case runs in a fresh interpreter and reports what it has imported: a
structural check, not a timing one. The cold ``suite info`` (which packs,
and so imports JAX) shows that the probe does see JAX when it is there.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from drivee2e_jax import cli

REPO = Path(__file__).resolve().parents[2]
HEAVY = ("jax", "flax")

#: Runs ``main(argv)`` and prints, as its last stdout line, the exit code and
#: which of HEAVY the interpreter has imported by then.
PROBE = f"""
import json, sys
from drivee2e_jax.cli import main
code = main(json.loads(sys.argv[1]))
sys.stdout.flush()
print(json.dumps({{"code": code, "heavy": [m for m in {HEAVY!r} if m in sys.modules]}}))
"""


def _probe(argv: list[str], cache: Path) -> tuple[int, list[str], str]:
    env = {**os.environ, "DRIVEE2E_CACHE": str(cache), "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-c", PROBE, json.dumps(argv)], capture_output=True, text=True,
                          env=env, cwd=REPO, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    return result["code"], result["heavy"], proc.stdout


def _commands() -> list[list[str]]:
    """Every command path of the parser: [], [bench], ..., [suite, info], ..."""
    out = []

    def walk(parser: argparse.ArgumentParser, path: list[str]) -> None:
        out.append(path)
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, [*path, name])

    walk(cli.build_parser(), [])
    return out


def test_every_command_is_probed():
    paths = _commands()
    assert len(paths) > len(cli.SUBCOMMANDS)  # the top level, each subcommand and its actions
    assert ["suite", "info"] in paths and ["check-policy"] in paths


@pytest.mark.parametrize("path", _commands(), ids=lambda p: " ".join(p) or "drivee2e")
def test_help_imports_no_jax(path, tmp_path):
    code, heavy, out = _probe([*path, "--help"], tmp_path / "cache")
    assert code == 0 and "usage: drivee2e" in out
    assert heavy == [], f"`drivee2e {' '.join(path)} --help` imported {heavy}"


def test_suite_info_from_a_warm_cache_imports_no_jax(tmp_path):
    cache = tmp_path / "cache"
    code, heavy, _ = _probe(["suite", "info", "tiny"], cache)  # cold: packs, and so imports JAX
    assert code == 0 and "jax" in heavy  # the probe sees JAX when it is imported
    assert sorted(p.suffix for p in (cache / "suites").iterdir()) == [".json", ".npz"]

    code, heavy, out = _probe(["suite", "info", "tiny"], cache)
    assert code == 0 and "suite tiny (version 1.0): 4 scenarios" in out
    assert heavy == [], f"`drivee2e suite info tiny` from a warm cache imported {heavy}"

    code, heavy, out = _probe(["suite", "info", "tiny", "--json"], cache)
    info = json.loads(out.splitlines()[0])
    assert code == 0 and info["num_scenarios"] == 4 and sum(info["categories"].values()) > 0
    assert heavy == []

    folder = REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny"  # the same suite, named by its folder
    code, heavy, out = _probe(["suite", "info", str(folder)], cache)
    assert code == 0 and "4 scenarios" in out and heavy == []


def test_builtin_cache_key_imports_no_generator(tmp_path):
    """The built-in suite's cache key (its generator's VERSION) is found without
    importing the generator, which imports JAX; with an empty cache only
    `ready` is asked, so nothing is generated."""
    script = ("import sys\nfrom drivee2e_jax.scenario.suite import load_suite\n"
              "s = load_suite('twin15')\nprint(s.version, s.ready, "
              "[m for m in ('jax', 'flax', 'drivee2e_jax.scenario.twin15') if m in sys.modules])")
    env = {**os.environ, "DRIVEE2E_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(REPO)}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, cwd=REPO,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    from drivee2e_jax.scenario import twin15

    assert proc.stdout.split() == [str(twin15.VERSION), "False", "[]"]


def test_version_is_looked_up_only_when_asked(capsys):
    from drivee2e_jax import __version__

    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"drivee2e {__version__}"
