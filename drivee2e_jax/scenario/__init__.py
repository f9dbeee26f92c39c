"""Scenarios: on-disk schema and validation, packing into padded arrays, suites.

* ``records``  host-side dataclasses (the on-disk schema in Python)
* ``schema``   suite folders <-> records, with validation naming file and field
  (``validate``: the checks; ``encode``: records -> JSON; ``problems``: Problem);
  ``SuiteWriter`` writes a large suite block by block
* ``pack``     records -> padded ``types.Scenario`` batch + host meta table
  (``batch``: the PackedBatch container; ``sizes``: PackSizes and the leaf
  table; ``flat``: dotted-path flattening; ``routes``: route spacing,
  densifying and commands)
* ``suite``    ``load_suite("twin15" | folder)`` with a packed on-disk cache
  (``meta``: SuiteMeta, ``cache``: the cache key and sidecar, both without JAX)
* ``stream``   suites larger than memory: ``SuiteIndex.open(folder)`` (suite.json
  and maps only), ``shards(index, split, n)`` (read and packed shard by shard)
"""

import importlib

# Loaded on first use, so the host-only parts (importers, schema, curation)
# and the CLI's parsers do not pay for JAX: name -> module of this package.
# (``pack`` is the submodule; its function is ``scenario.pack.pack``.)
_LAZY = {
    "PackedBatch": "batch", "SuiteMeta": "meta",
    "pack_buckets": "pack", "unpack": "pack",
    "Problem": "problems",
    "read_suite": "schema", "validate_suite": "schema", "write_suite": "schema",
    "PackSizes": "sizes",
    "Suite": "suite", "load_suite": "suite",
}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "PackedBatch",
    "PackSizes",
    "SuiteMeta",
    "pack_buckets",
    "unpack",
    "Problem",
    "read_suite",
    "validate_suite",
    "write_suite",
    "Suite",
    "load_suite",
]
