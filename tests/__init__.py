"""The tests, a package mirroring ``drivee2e_jax`` (``tests/test_architecture.py``).

Every test folder is a package, so test modules have unique dotted names
(``tests.eval.test_openloop`` and ``tests.metrics.test_openloop`` coexist)
and the shared helpers import as ``from tests.helpers import ...`` — with
the repository root on ``sys.path`` (``pythonpath = ["."]`` in
``pyproject.toml``). Test modules never import each other: what two test
files share lives in ``tests/helpers``.
"""

try:
    import pytest
except ImportError:  # a helper used outside the tests (experiments/perf/bev.py --quick)
    pytest = None

if pytest is not None:
    # Plain ``assert``s in the shared checkers (tests/helpers) report their
    # operands like the ones in test modules do.
    pytest.register_assert_rewrite("tests.helpers")
