"""The package as users install it: ``requires-python`` true to the code, the
wheel complete (reference policies, the player page, every module), and the
cheap entry points (``import drivee2e_jax``, ``drivee2e --help``) free of JAX.

The install itself, at the dependencies' lowest allowed versions and from a
folder outside the checkout, is ``scripts/wheel_check.sh`` (run by ``.ci/run``).
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import tomllib
import zipfile
from email.parser import Parser
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.specifiers import SpecifierSet

from drivee2e_jax.cli import SUBCOMMANDS

REPO = Path(__file__).resolve().parents[1]
PACKAGE = REPO / "drivee2e_jax"
PYPROJECT = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))

#: Standard-library modules and names newer than Python 3.8, with the version
#: that added them: an import of one sets a floor under ``requires-python``.
NEWER_STDLIB = {
    "zoneinfo": (3, 9), "graphlib": (3, 9),
    "tomllib": (3, 11), "wsgiref.types": (3, 11),
    "typing.Self": (3, 11), "typing.Never": (3, 11), "typing.LiteralString": (3, 11),
    "typing.assert_never": (3, 11), "typing.assert_type": (3, 11), "typing.reveal_type": (3, 11),
    "typing.Required": (3, 11), "typing.NotRequired": (3, 11), "typing.dataclass_transform": (3, 11),
    "enum.StrEnum": (3, 11), "datetime.UTC": (3, 11), "asyncio.TaskGroup": (3, 11),
    "typing.override": (3, 12), "typing.TypeAliasType": (3, 12), "itertools.batched": (3, 12),
    "warnings.deprecated": (3, 13), "copy.replace": (3, 13),
}

#: Heavy modules the cheap entry points must not load.
HEAVY = ("jax", "jaxlib", "flax", "optax", "orbax", "chex", "scipy", "matplotlib")


def _package_files(suffix: str | None = None) -> list[Path]:
    """Files of ``drivee2e_jax/`` (``__pycache__`` left out), optionally one suffix only."""
    return sorted(
        p for p in PACKAGE.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
        and (suffix is None or p.suffix == suffix)
    )


def _lowest_admitted(spec: str) -> tuple[int, int]:
    """The lowest Python 3.x that the ``requires-python`` specifier admits."""
    specifier = SpecifierSet(spec)
    return min((3, minor) for minor in range(0, 30) if specifier.contains(f"3.{minor}"))


def _stdlib_floors(paths: list[Path]) -> dict[str, tuple[tuple[int, int], str]]:
    """Each newer stdlib feature the files import -> (version that added it, first file:line)."""
    found = {}
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            else:
                continue
            for name in names:
                if name in NEWER_STDLIB and name not in found:
                    found[name] = (NEWER_STDLIB[name], f"{path.name}:{node.lineno}")
    return found


def test_requires_python_admits_no_python_the_code_cannot_run_on():
    """Every stdlib module the package imports exists on the lowest Python
    ``requires-python`` admits, and every file parses with that version's grammar."""
    lowest = _lowest_admitted(PYPROJECT["project"]["requires-python"])
    floors = _stdlib_floors(_package_files(".py"))
    assert "tomllib" in floors  # the scan sees the sweep config reader (3.11): it is not vacuous
    too_new = [f"{name} needs Python {v[0]}.{v[1]} ({where})" for name, (v, where) in floors.items() if v > lowest]
    assert not too_new, f"requires-python admits {lowest[0]}.{lowest[1]}, but: " + "; ".join(too_new)
    for path in _package_files(".py"):
        ast.parse(path.read_text(encoding="utf-8"), filename=str(path), feature_version=lowest)


def test_ruff_targets_the_lowest_supported_python():
    """ruff (pyupgrade, syntax checks) writes for the oldest Python users may have."""
    lowest = _lowest_admitted(PYPROJECT["project"]["requires-python"])
    assert PYPROJECT["tool"]["ruff"]["target-version"] == f"py{lowest[0]}{lowest[1]}"


def test_lowest_admitted_reads_specifiers():
    assert _lowest_admitted(">=3.11") == (3, 11)
    assert _lowest_admitted(">=3.9,!=3.10.*") == (3, 9)
    assert _lowest_admitted("~=3.12") == (3, 12)


def test_stdlib_floor_scan_finds_imports(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("import os\nfrom typing import Self, Any\nfrom itertools import batched\n")
    found = _stdlib_floors([src])
    assert {k: v for k, (v, _) in found.items()} == {"typing.Self": (3, 11), "itertools.batched": (3, 12)}


#: The name of the weights pair the ``wheel`` fixture adds to its copy of the package.
WEIGHTS_PROBE = "packaging_probe"


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> zipfile.ZipFile:
    """The wheel built from a copy of this checkout's package files (so no
    ``build/`` is left in the checkout, nor a stale one read), offline
    (``--no-build-isolation``: the test extras carry setuptools; about 1 s)."""
    src, out = tmp_path_factory.mktemp("src"), tmp_path_factory.mktemp("wheel")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    shutil.copytree(PACKAGE, src / PACKAGE.name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    probe = src / PACKAGE.name / "zoo" / "weights"  # a weights pair, so the package-data rule is tested
    probe.mkdir(exist_ok=True)  # whether or not the checkout bundles any yet
    for suffix in (".npz", ".json"):
        (probe / f"{WEIGHTS_PROBE}{suffix}").write_bytes(b"{}")
    proc = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation", "--no-index",
         "-w", str(out), str(src)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    (path,) = out.glob("drivee2e_jax-*.whl")
    with zipfile.ZipFile(path) as z:
        yield z


def test_the_wheel_holds_every_module_the_zoo_and_the_player(wheel):
    names = set(wheel.namelist())
    zoo = [p for p in _package_files(".py") if p.parent.name == "zoo" and p.stem != "__init__"]
    assert len(zoo) >= 5, zoo  # the reference policies resolve_policy_path finds by name
    expected = {p.relative_to(REPO).as_posix() for p in _package_files()}
    assert "drivee2e_jax/viz/player.html" in expected
    assert "drivee2e_jax/scenario/examples/tiny/suite.json" in expected  # the example suite, loadable by name
    missing = sorted(expected - names)
    assert not missing, "not in the wheel: " + ", ".join(missing)


def test_the_wheel_holds_the_zoo_weights(wheel):
    """``drivee2e_jax/zoo/weights/*.npz`` + ``*.json`` (the zoo's bundled
    weights, ``models/bundled.py``) are package data: the fixture's probe pair
    and every pair of this checkout are in the wheel, each npz with its json."""
    names = set(wheel.namelist())
    weights = "drivee2e_jax/zoo/weights"
    assert {f"{weights}/{WEIGHTS_PROBE}.npz", f"{weights}/{WEIGHTS_PROBE}.json"} <= names, "package-data lacks weights"
    here = sorted(p for p in (PACKAGE / "zoo" / "weights").glob("*") if p.suffix in (".npz", ".json"))
    missing = sorted({p.relative_to(REPO).as_posix() for p in here} - names)
    assert not missing, "bundled weights not in the wheel: " + ", ".join(missing)
    stems = {suffix: {p.stem for p in here if p.suffix == suffix} for suffix in (".npz", ".json")}
    assert stems[".npz"] == stems[".json"], f"weights without their pair: {stems}"


def _normal(requirement: str) -> tuple[str, SpecifierSet]:
    """(name, version ranges) of a requirement string, however it is spelled."""
    req = Requirement(requirement)
    return req.name.lower(), req.specifier


def test_the_wheel_metadata_matches_pyproject(wheel):
    meta_name = next(n for n in wheel.namelist() if n.endswith(".dist-info/METADATA"))
    meta = Parser().parsestr(wheel.read(meta_name).decode())
    assert meta["Requires-Python"] == PYPROJECT["project"]["requires-python"]
    required = {_normal(r) for r in meta.get_all("Requires-Dist") if "extra ==" not in r}
    assert required == {_normal(d) for d in PYPROJECT["project"]["dependencies"]}
    entry_points = wheel.read(meta_name.replace("METADATA", "entry_points.txt")).decode()
    assert "drivee2e = drivee2e_jax.cli:main" in entry_points


CHEAP_ENTRY_POINTS = """
import contextlib, io, sys
import drivee2e_jax
after_import = sorted(m for m in {heavy!r} if m in sys.modules)
from drivee2e_jax.cli import main
codes = []
for argv in [["--help"]] + [[c.replace("_", "-"), "--help"] for c in {commands!r}]:
    with contextlib.redirect_stdout(io.StringIO()):
        codes.append(main(argv))
print(after_import, sorted(m for m in {heavy!r} if m in sys.modules), codes)
"""


def test_import_and_help_load_no_jax():
    """``import drivee2e_jax`` and ``drivee2e [<command>] --help`` stay instant:
    no JAX, Flax, SciPy or matplotlib behind them."""
    program = CHEAP_ENTRY_POINTS.format(heavy=HEAVY, commands=SUBCOMMANDS)
    proc = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split("\n")[0] == f"[] [] {[0] * (len(SUBCOMMANDS) + 1)}", proc.stdout
