"""The packed cache's JAX-free half (scenario/cache.py) and what suite.py
reads without importing the generator: the built-in suite's VERSION."""

from __future__ import annotations

import pytest

from drivee2e_jax.scenario import cache, pack
from drivee2e_jax.scenario.suite import _Builtin, _declared_version


def test_pack_format_has_one_value():
    """The cache key takes PACK_FORMAT from scenario.cache (no JAX): it must be
    the one scenario.pack packs by."""
    assert pack.PACK_FORMAT == cache.PACK_FORMAT


def test_twin15_version_is_read_without_importing_it():
    from drivee2e_jax.scenario import twin15

    assert _declared_version("drivee2e_jax.scenario.twin15") == str(twin15.VERSION)


@pytest.mark.parametrize("source, expected", [
    ('VERSION = "7"\n', "7"),
    ("VERSION: int = 3\n", "3"),
    ('VERSION = "7"\nVERSION = "8"\n', None),  # rebound: only importing tells
    ('import os\nVERSION = os.environ.get("V", "1")\n', None),  # computed
    ('from .v import VERSION\n', None),
    ('VERSION = "7"\ndef bump():\n    global VERSION\n    VERSION = "8"\n', None),
    ('from x import *\nVERSION = "7"\n', None),
    ("VERSION = (\n", None),  # not Python
    ("X = 1\n", None),
])
def test_declared_version(tmp_path, monkeypatch, source, expected):
    (tmp_path / "fake_generator_mod.py").write_text(source)
    monkeypatch.syspath_prepend(str(tmp_path))
    assert _declared_version("fake_generator_mod") == expected
    assert _declared_version("no_such_generator_module") is None


def test_builtin_version_prefers_a_loaded_module(monkeypatch):
    """A module already imported (or replaced in sys.modules, as tests do)
    gives its live VERSION."""
    import sys
    import types

    fake = types.ModuleType("drivee2e_jax.scenario.twin15")
    fake.VERSION, fake.generate = "live-2", lambda seed=0: None
    monkeypatch.setitem(sys.modules, "drivee2e_jax.scenario.twin15", fake)
    assert _Builtin("twin15").version == "live-2"
