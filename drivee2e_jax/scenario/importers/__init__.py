"""Importers of recorded traffic into the suite format (host side).

One module per source format, each exposing
``load(paths: list[Path], options: ImportOptions) -> ImportResult``
(see ``importers.common`` for the shared types and helpers). Modules are
imported lazily, so a format whose optional dependency is missing fails only
when it is used.

    from drivee2e_jax.scenario.importers import import_suite, ImportOptions
    result = import_suite("argoverse2", [Path("scenario_x.parquet")], Path("suites/av2"), ImportOptions())
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from pathlib import Path

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.formats import FORMATS
from drivee2e_jax.scenario.importers.common import ImportOptions, ImportResult, Skipped, write_result

__all__ = ["FORMATS", "ImportOptions", "ImportResult", "Skipped", "load", "import_suite", "module"]



def module(fmt: str):
    """The importer module of a CLI format name."""
    if fmt not in FORMATS:
        raise DriveE2EError(f"unknown import format {fmt!r}; expected one of {', '.join(FORMATS)}")
    name = f"{__name__}.{FORMATS[fmt]}"
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as e:
        if e.name == name:
            raise DriveE2EError(f"import format {fmt!r} is not available in this version "
                                f"(no module {name})") from None
        raise


def load(fmt: str, paths: Sequence[Path], options: ImportOptions) -> ImportResult:
    """Read ``paths`` with the importer of ``fmt`` (nothing is written)."""
    paths = [Path(p) for p in paths]
    if not paths:
        raise DriveE2EError(f"{fmt}: expected at least one input path")
    for p in paths:
        if not p.exists():
            raise DriveE2EError(f"{p}: no such file or folder")
    return module(fmt).load(paths, options)


def import_suite(fmt: str, paths: Sequence[Path], out: Path, options: ImportOptions,
                 force: bool = False) -> ImportResult:
    """Import ``paths`` and write the suite folder ``out``; returns what was imported.

    ``out`` is refused when it exists and is not empty unless ``force`` (and
    then only a suite folder is replaced); it is checked before reading.
    """
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())) and not force:
        raise DriveE2EError(f"{out} exists and is not empty; expected a new or empty folder "
                            "(pass --force to replace a suite folder)")
    result = load(fmt, paths, options)
    name = options.name or out.name
    write_result(result, out, name=name, force=force)
    return result
