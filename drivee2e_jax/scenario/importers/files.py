"""Reading source files and writing the suite folder (see
``importers.common``): ``read_table`` (Parquet / Feather), ``parse_xml``,
``write_result``."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import SuiteRecord
from drivee2e_jax.scenario.schema import write_suite

from .results import ImportResult
from .scenarios import safe_id

__all__ = ["write_result", "read_table", "parse_xml"]


def write_result(result: ImportResult, out: str | Path, *, name: str, force: bool = False) -> Path:
    """Write ``result`` as the suite folder ``out`` (validated; atomic; see ``schema.write_suite``).

    With no scenario the error names how many items were skipped and the first
    one's source and reason (usually the whole story: a file without an ego).
    """

    if not result.scenarios:
        n = len(result.skipped)
        first = f"; first: {result.skipped[0].source}: {result.skipped[0].reason}" if n else ""
        raise DriveE2EError(f"nothing to write to {out}: no scenario could be imported "
                            f"({n} item{'s' if n != 1 else ''} skipped{first})")
    used = {s.map_id for s in result.scenarios}
    suite = SuiteRecord(name=safe_id(name), version="1", maps={k: v for k, v in result.maps.items() if k in used},
                        scenarios=result.scenarios, meta=dict(result.meta))
    return write_suite(suite, out, overwrite=force)


def read_table(path: Path, columns: Sequence[str]) -> dict[str, np.ndarray]:
    """Columns of a Parquet (``.parquet``) or Feather/Arrow file as numpy arrays."""
    try:  # pyarrow is optional (the ``import`` extra): only Argoverse 2 needs it
        import pyarrow.feather as feather  # noqa: PLC0415
        import pyarrow.parquet as parquet  # noqa: PLC0415
    except ImportError:
        raise DriveE2EError(f"{path}: reading Parquet/Feather needs pyarrow; install it with "
                            "pip install 'drivee2e-jax[import]'") from None
    try:
        if str(path).endswith(".parquet"):
            table = parquet.read_table(path)
        else:
            table = feather.read_table(path)
    except FileNotFoundError:
        raise
    except Exception as e:  # noqa: BLE001 - pyarrow raises many types for a bad file
        raise DriveE2EError(f"{path}: not a readable {'Parquet' if str(path).endswith('.parquet') else 'Feather'} "
                            f"file ({type(e).__name__}: {' '.join(str(e).split())[:120]})") from None
    missing = [c for c in columns if c not in table.column_names]
    if missing:
        raise DriveE2EError(f"{path}: missing column {missing[0]!r}; expected columns {', '.join(columns)}")
    out = {}
    for c in columns:
        col = table.column(c)
        if _is_text(col.type):
            out[c] = np.asarray(col.to_pylist(), dtype=object)
        else:
            out[c] = col.to_numpy()
    return out


def _is_text(t) -> bool:
    import pyarrow as pa  # noqa: PLC0415 - optional (the ``import`` extra); read_table checked it is there

    return pa.types.is_string(t) or pa.types.is_large_string(t) or pa.types.is_dictionary(t)


def parse_xml(path: Path, what: str, root_tag: str):
    """The root element of the XML file ``path``, which must be ``<root_tag>``.

    ``what`` names the format in the errors ("CommonRoad", "OSM", ...).
    """

    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise DriveE2EError(f"{path}: expected well-formed {what} XML, got a parse error ({e})") from None
    except OSError as e:
        raise DriveE2EError(f"{path}: expected a readable {what} file, got {e.strerror or e}") from None
    if root.tag != root_tag:
        article = "an" if root_tag[0].lower() in "aeiou" else "a"
        raise DriveE2EError(f"{path}: expected {article} <{root_tag}> root element, got <{root.tag}>")
    return root
