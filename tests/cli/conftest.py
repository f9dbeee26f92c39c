"""Fixtures shared by the CLI tests."""

from __future__ import annotations

import pytest

from tests.helpers import road3


@pytest.fixture(scope="module")
def suite_dir(tmp_path_factory):
    """The ``road3`` suite folder (``tests/helpers/road3.py``), one per test module."""
    return road3.write(tmp_path_factory.mktemp("suites") / "road3")
