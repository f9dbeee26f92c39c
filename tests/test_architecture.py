"""The shape of the code base, checked: the tests tree mirrors the package,
test modules never import each other, and ``drivee2e_jax`` has no import
cycle (function-level imports included).

The layers themselves (which package may import which) are import-linter's
contracts in ``pyproject.toml`` (``lint-imports``); grimp, the graph library
under import-linter, gives the module graph here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import grimp

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
PACKAGE = REPO / "drivee2e_jax"

#: Folders of ``tests/`` that mirror no package folder, and why.
NOT_MIRRORED = {
    "helpers": "code the test modules share (scenes, suites, oracles, worked-case checkers)",
    "data": "data files the tests read",
    "e2e": "the repository end to end: example suite, notebooks, experiment drivers",
}


def _python_files() -> list[Path]:
    """The tests' own Python files (``tests/data`` holds data, third-party code included)."""
    return sorted(
        p for p in TESTS.rglob("*.py")
        if "__pycache__" not in p.parts and p.relative_to(TESTS).parts[0] != "data"
    )


def _test_dirs() -> list[Path]:
    """Folders under ``tests/``, less caches (``__pycache__``, ``.hypothesis`` ...)."""
    return sorted(
        p for p in TESTS.rglob("*")
        if p.is_dir() and not any(s.startswith((".", "__")) for s in p.relative_to(TESTS).parts)
    )


def _imported(path: Path) -> list[tuple[int, int, str]]:
    """(line, relative level, dotted name) of every import in ``path``, at
    any depth (function-level imports too)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out.extend((node.lineno, 0, a.name) for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            out.append((node.lineno, node.level, base))
            out.extend((node.lineno, node.level, f"{base}.{a.name}" if base else a.name) for a in node.names)
    return out


def test_no_test_module_imports_another():
    """What two test files share lives in ``tests/helpers`` and is imported
    as ``tests.helpers...``: no import of a ``test_*`` module or of
    ``conftest``, no bare sibling-module import that only works with a test
    folder on ``sys.path``, no relative import."""
    local_names = {p.stem for p in _python_files() if p.stem != "__init__"}
    bad = []
    for path in _python_files():
        where = path.relative_to(REPO)
        for line, level, name in _imported(path):
            parts = name.split(".")
            if level:
                bad.append(f"{where}:{line}: relative import ({'.' * level}{name})")
            elif any(p.startswith("test_") or p == "conftest" for p in parts):
                bad.append(f"{where}:{line}: imports a test module ({name})")
            elif parts[0] in local_names:
                bad.append(f"{where}:{line}: bare import of a module of tests/ ({name}); use tests.helpers")
            elif parts[0] == "tests" and len(parts) > 1 and parts[1] != "helpers":
                bad.append(f"{where}:{line}: imports {name}; only tests.helpers is shared")
    assert not bad, "\n".join(dict.fromkeys(bad))


def _cycles(graph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan,
    iterative), and modules importing themselves."""
    modules = sorted(graph.modules)
    edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in modules}
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = 0
    for root in modules:
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            v, i = work.pop()
            if i == 0:
                index[v] = low[v] = counter
                counter += 1
                stack.append(v)
                on_stack.add(v)
            if i < len(edges[v]):
                work.append((v, i + 1))
                w = edges[v][i]
                if w not in index:
                    work.append((w, 0))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1 or v in edges[v]:
                    found.append(sorted(comp))
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[v])
    return found


def test_no_import_cycle_in_the_package():
    graph = grimp.build_graph("drivee2e_jax", cache_dir=None)
    assert len(graph.modules) > 50, sorted(graph.modules)  # the whole package was scanned
    cycles = _cycles(graph)
    report = []
    for comp in cycles:
        chain = graph.find_shortest_chain(importer=comp[0], imported=comp[-1]) or ()
        back = graph.find_shortest_chain(importer=comp[-1], imported=comp[0]) or ()
        report.append(f"{len(comp)} modules: {', '.join(comp)}\n  e.g. {' -> '.join(chain)} -> ... -> {' -> '.join(back)}")
    assert not cycles, "import cycles in drivee2e_jax:\n" + "\n".join(report)


def test_cycle_finder_finds_a_cycle():
    """The checker above is not vacuous."""
    graph = grimp.ImportGraph()
    for m in ("p", "p.a", "p.b", "p.c", "p.d"):
        graph.add_module(m)
    for a, b in (("p.a", "p.b"), ("p.b", "p.c"), ("p.c", "p.a"), ("p.c", "p.d")):
        graph.add_import(importer=a, imported=b)
    assert _cycles(graph) == [["p.a", "p.b", "p.c"]]


def test_the_tests_tree_mirrors_the_package():
    """Every folder of ``tests/`` is a package folder of ``drivee2e_jax``
    (tests of ``drivee2e_jax/eval/*.py`` in ``tests/eval/``, of top-level
    modules in ``tests/``), or one of ``NOT_MIRRORED``."""
    bad = []
    for d in _test_dirs():
        rel = d.relative_to(TESTS)
        if rel.parts[0] in NOT_MIRRORED:
            continue
        if not (PACKAGE / rel / "__init__.py").is_file():
            bad.append(f"tests/{rel.as_posix()}/ has no package drivee2e_jax/{rel.as_posix()}/")
    assert not bad, "\n".join(bad)


def test_every_test_folder_is_a_package():
    """``__init__.py`` everywhere (``tests/data`` aside): test modules get
    unique dotted names (``tests.eval.test_openloop`` next to
    ``tests.metrics.test_openloop``) and helpers import as ``tests.helpers``."""
    missing = [
        f"tests/{d.relative_to(TESTS).as_posix()}/__init__.py"
        for d in [TESTS, *_test_dirs()]
        if d != TESTS / "data" and TESTS / "data" not in d.parents and not (d / "__init__.py").is_file()
    ]
    assert not missing, "missing: " + ", ".join(missing)


def test_helpers_hold_no_tests_and_data_lives_in_data():
    """``tests/helpers`` is shared code only (pytest would collect a
    ``test_*.py`` there); files other than Python live in ``tests/data``."""
    helpers = TESTS / "helpers"
    bad = [f"{p.relative_to(REPO)}: a test module among the helpers" for p in helpers.rglob("test_*.py")]
    for p in TESTS.rglob("*"):
        rel = p.relative_to(TESTS)
        if p.is_file() and p.suffix not in (".py", ".pyc") and rel.parts[0] != "data" and not any(
            s.startswith(".") or s == "__pycache__" for s in rel.parts
        ):
            bad.append(f"tests/{rel.as_posix()}: a data file outside tests/data")
    assert not bad, "\n".join(bad)


IMPORT_EVERYTHING = """
import importlib, pkgutil, sys
from jax._src import xla_bridge
import drivee2e_jax
for m in pkgutil.walk_packages(drivee2e_jax.__path__, "drivee2e_jax."):
    if m.name.endswith("__main__"):
        continue
    importlib.import_module(m.name)
    if xla_bridge._backends:
        sys.exit("importing " + m.name + " initialised the JAX backend")
"""


def test_importing_any_module_leaves_the_jax_backend_alone():
    """No module computes with JAX at import time: ``jax.distributed.initialize``
    (``drivee2e bench --coordinator``) must run before the backend starts, and
    imports stay cheap. Module constants are numpy or plain floats."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", IMPORT_EVERYTHING], capture_output=True, text=True,
                          cwd=Path(__file__).resolve().parents[1], timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:] or proc.stdout[-2000:]
