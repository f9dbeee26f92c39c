"""Scenarios: on-disk schema and validation, packing into padded arrays, suites.

* ``records``  host-side dataclasses (the on-disk schema in Python)
* ``schema``   suite folders <-> records, with validation naming file and field
  (``validate``: the checks; ``encode``: records -> JSON; ``problems``: Problem)
* ``pack``     records -> padded ``types.Scenario`` batch + host meta table
  (``batch``: the PackedBatch container; ``sizes``: PackSizes and the leaf
  table; ``flat``: dotted-path flattening; ``routes``: route spacing,
  densifying and commands)
* ``suite``    ``load_suite("twin15" | folder)`` with a packed on-disk cache
"""

from drivee2e_jax.scenario.batch import PackedBatch, SuiteMeta
from drivee2e_jax.scenario.pack import pack, pack_buckets, unpack
from drivee2e_jax.scenario.problems import Problem
from drivee2e_jax.scenario.schema import read_suite, validate_suite, write_suite
from drivee2e_jax.scenario.sizes import PackSizes
from drivee2e_jax.scenario.suite import Suite, load_suite

__all__ = [
    "PackedBatch",
    "PackSizes",
    "SuiteMeta",
    "pack",
    "pack_buckets",
    "unpack",
    "Problem",
    "read_suite",
    "validate_suite",
    "write_suite",
    "Suite",
    "load_suite",
]
