"""Scenarios: on-disk schema and validation, packing into padded arrays, suites.

* ``records``  host-side dataclasses (the on-disk schema in Python)
* ``schema``   suite folders <-> records, with validation naming file and field
* ``pack``     records -> padded ``types.Scenario`` batch + host meta table
* ``suite``    ``load_suite("twin15" | folder)`` with a packed on-disk cache
"""

from drivee2e_jax.scenario.pack import PackedBatch, PackSizes, SuiteMeta, pack, pack_buckets, unpack
from drivee2e_jax.scenario.schema import Problem, read_suite, validate_suite, write_suite
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
