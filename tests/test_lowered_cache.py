"""lowered_cache: a rollout's lowered programs stored on disk and reused only
when everything its trace read is the same."""

from __future__ import annotations

import dataclasses
import importlib.util
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivee2e_jax import lowered_cache as lc
from drivee2e_jax.rollout import LogReplay, Rollout
from drivee2e_jax.sim import SimConfig, Simulator
from tests.helpers import sim_scenarios as ss


@pytest.fixture(scope="module")
def batch():
    b = ss.build([ss.clean(), ss.red_light(), ss.obstacle_ahead()])
    return jax.tree_util.tree_map(jnp.asarray, b.scenario)


@pytest.fixture
def store(tmp_path, monkeypatch):
    """A fresh, empty store folder, nothing remembered in-process (the
    compiled programs stay in the session's compilation cache)."""
    path = tmp_path / lc.FOLDER
    monkeypatch.setattr(lc, "folder", lambda: None if lc.os.environ.get(lc.ENV) == "off" else path)
    lc._PROGRAMS.clear()
    yield path
    lc._PROGRAMS.clear()


def _run(batch, policy=None, chunk=10):
    ro = Rollout(Simulator(SimConfig()), policy or LogReplay(), None, chunk=chunk)
    carry = ro.init(batch, jax.random.split(jax.random.PRNGKey(0), 3))
    carry, log = ro.advance(batch, carry)
    return ro, jax.tree_util.tree_map(np.asarray, (carry, log))


def _equal(a, b):
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb
    for x, y in zip(la, lb, strict=True):
        np.testing.assert_array_equal(x, y)


def _no_export(monkeypatch):
    def fail(*a, **k):
        raise AssertionError("lowered again although the program was stored")
    monkeypatch.setattr(lc.StoredJit, "_export", fail)


def test_stored_programs_are_reused_and_give_the_same_bits(batch, store, monkeypatch):
    monkeypatch.setenv(lc.ENV, "off")
    ro_plain, plain = _run(batch)
    assert not isinstance(ro_plain._start, lc.StoredJit)
    monkeypatch.delenv(lc.ENV)
    ro_first, first = _run(batch)
    assert isinstance(ro_first._start, lc.StoredJit)
    stored = sorted(store.glob("*.bin"))
    assert len(stored) == 3  # reset, start, advance
    assert all(p.read_bytes().startswith(lc.MAGIC) for p in stored)
    lc._PROGRAMS.clear()  # as a new process: only the files are left
    _no_export(monkeypatch)
    _, again = _run(batch)
    _equal(plain, first)
    _equal(plain, again)


def test_a_different_chunk_or_policy_attribute_is_a_different_program(batch, store):
    _run(batch, chunk=10)
    assert len(list(store.glob("*.bin"))) == 3
    _run(batch, chunk=5)
    assert len(list(store.glob("*.bin"))) == 6

    @dataclasses.dataclass(frozen=True)
    class Gain(LogReplay):
        gain: float = 1.0

        def act(self, params, obs, state, key):
            c, state = super().act(params, obs, state, key)
            return c.replace(throttle=c.throttle * self.gain), state

    Gain.__module__ = __name__  # a class of this test file: user code, fingerprinted by its file
    _, one = _run(batch, Gain(1.0))
    n = len(list(store.glob("*.bin")))
    _, half = _run(batch, Gain(0.5))
    assert len(list(store.glob("*.bin"))) == n + 3
    assert not np.array_equal(one[0].sim.ego.speed, half[0].sim.ego.speed)


def test_corrupt_files_are_lowered_again(batch, store):
    _, first = _run(batch)
    for p in store.glob("*.bin"):
        p.write_bytes(p.read_bytes()[:100])
    lc._PROGRAMS.clear()
    _, again = _run(batch)
    _equal(first, again)
    assert all(len(p.read_bytes()) > 1000 for p in store.glob("*.bin"))


def test_under_an_outer_trace_and_without_export_the_plain_jit_runs(batch, store):
    ro = Rollout(Simulator(SimConfig()), LogReplay(), None, chunk=5)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    shapes = jax.eval_shape(ro.init, batch, keys)  # tracers: nothing stored
    assert not store.exists() or not list(store.glob("*.bin"))
    assert shapes.sim.ego.speed.shape == (3,)

    class Printing(LogReplay):
        def act(self, params, obs, state, key):
            jax.debug.callback(lambda x: None, obs.ego)  # a host callback cannot be exported
            return super().act(params, obs, state, key)

    Printing.__module__ = __name__
    _, out = _run(batch, Printing())
    _, ref = _run(batch)
    _equal(out, ref)  # ran through the plain jit
    # log_replay's three programs and Printing's reset and start (they never
    # call act); its advance could not be exported.
    assert len(list(store.glob("*.bin"))) == 5


def test_no_store_without_a_compile_cache_folder(monkeypatch):
    old = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", None)
    try:
        assert lc.folder() is None
        assert not isinstance(Rollout(Simulator(SimConfig()), LogReplay(), None)._start, lc.StoredJit)
    finally:
        jax.config.update("jax_compilation_cache_dir", old)
    monkeypatch.setenv(lc.ENV, "off")
    assert lc.folder() is None


def _load_module(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def test_fingerprint_follows_the_code_not_the_module_name(tmp_path):
    helper = tmp_path / "lc_helper_mod.py"
    helper.write_text("GAIN = 2.0\n")
    policy = tmp_path / "lc_policy_mod.py"
    policy.write_text("import lc_helper_mod\nclass P:\n    def __init__(self):\n        self.k = 3\n")
    sys.path.insert(0, str(tmp_path))
    try:
        a = _load_module(policy, "lc_policy_name_a").P()
        b = _load_module(policy, "lc_policy_name_b").P()
        assert lc.fingerprint(a) == lc.fingerprint(b)  # a policy file loads under a new name each process
        b.k = 4
        assert lc.fingerprint(a) != lc.fingerprint(b)
        before = lc.fingerprint(a)
        helper.write_text("GAIN = 3.0\n")  # a helper the policy imports changed: another program
        assert lc.fingerprint(a) != before
        before = lc.fingerprint(a)
        sys.modules["lc_policy_name_a"].SCALE = 2.0  # a global set at import (from the environment, a file)
        assert lc.fingerprint(a) != before
    finally:
        sys.path.remove(str(tmp_path))
        for name in ("lc_helper_mod", "lc_policy_name_a", "lc_policy_name_b"):
            sys.modules.pop(name, None)


def test_fingerprint_of_values():
    assert lc.fingerprint({"a": np.arange(3), "b": (1, 2.0)}) == lc.fingerprint({"b": (1, 2.0), "a": np.arange(3)})
    assert lc.fingerprint(np.arange(3)) != lc.fingerprint(np.arange(3) + 1)  # arrays by content
    assert lc.fingerprint(np.arange(3, dtype=np.int32)) != lc.fingerprint(np.arange(3, dtype=np.int64))
    assert lc.fingerprint(SimConfig()) != lc.fingerprint(SimConfig(dt=0.05))
    cyc: list = [1]
    cyc.append(cyc)
    assert lc.fingerprint(cyc) == lc.fingerprint(cyc)
    assert lc.fingerprint(lambda x: x + 1) != lc.fingerprint(lambda x: x + 2)

    class Slotted:
        __slots__ = ("a",)

    with pytest.raises(lc.Unfingerprintable):
        lc.fingerprint(Slotted())
    main_cls = type("InMain", (), {"__module__": "__main__"})
    with pytest.raises(lc.Unfingerprintable):
        lc.fingerprint(main_cls())
