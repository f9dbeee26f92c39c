"""Suites: loading by name or folder, splits, info, the packed cache."""

from __future__ import annotations

import sys
import time
import types as pytypes

import numpy as np
import pytest

from drivee2e_jax import files
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario import Suite, load_suite
from drivee2e_jax.scenario import suite as suite_mod
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.scenario.pack import pack
from drivee2e_jax.scenario.schema import read_suite, write_suite


def _flat(batch):
    return {k: np.asarray(v) for k, v in flatten_scenario(batch.scenario).items()}


def _assert_same(a, b):
    fa, fb = _flat(a), _flat(b)
    assert fa.keys() == fb.keys()
    for k in fa:
        np.testing.assert_array_equal(fa[k], fb[k], err_msg=k)
    for k, v in a.meta.columns().items():
        np.testing.assert_array_equal(getattr(b.meta, k), v, err_msg=k)


def _cache_files(cache):
    return sorted(p.name for p in (cache / "suites").glob("*")) if (cache / "suites").exists() else []


@pytest.fixture
def fake_twin15(monkeypatch, tiny_suite):
    """A stand-in generator module for the built-in name, counting calls."""
    mod = pytypes.ModuleType("drivee2e_jax.scenario.twin15")
    mod.VERSION = "test-1"
    mod.calls = []

    def generate(seed=0):
        mod.calls.append(seed)
        from tests.helpers.tiny_suite import build_tiny_suite

        rec = build_tiny_suite()
        rec.name = "twin15"
        return rec

    mod.generate = generate
    monkeypatch.setitem(sys.modules, "drivee2e_jax.scenario.twin15", mod)
    monkeypatch.setattr(suite_mod, "_GENERATED", {})
    return mod


def test_folder_suite_basics(tiny_suite, tiny_suite_dir, drivee2e_cache):
    s = load_suite(tiny_suite_dir)
    assert isinstance(s, Suite) and (s.name, s.version) == ("tiny", "1.0")
    assert s.splits == {"train": 2, "val": 1, "test": 1}
    assert len(s) == 4 and s.meta.scenario_id.tolist() == ["s_straight", "s_left", "s_val", "s_test"]
    val = s.pack("val")
    assert val.meta.scenario_id.tolist() == ["s_val"]
    assert np.asarray(val.scenario.index).tolist() == [2]  # the row in suite.meta
    assert val.sizes == s.pack().sizes  # every split shares the suite's sizes
    disk = read_suite(tiny_suite_dir)  # rounded to 1 mm on disk
    _assert_same(s.pack(), pack(disk.scenarios, disk.maps))
    assert s.records.scenarios[0].scenario_id == "s_straight"
    train = s.pack("train", sizes=s.pack().sizes.replace(agents=16))
    assert train.sizes.agents == 16 and len(train) == 2


def test_info(tiny_suite_dir, drivee2e_cache):
    info = load_suite(tiny_suite_dir).info()
    assert info["num_scenarios"] == 4
    assert info["splits"] == {"train": 2, "val": 1, "test": 1}
    assert info["behaviors"]["STR"] == 1 and info["behaviors"]["UT"] == 0 and len(info["behaviors"]) == 8
    assert info["intersections"] == 2 and info["intersection_ids"] == {"i0": 3, "i1": 1}
    assert info["categories"] == {"car": 3, "truck": 1, "bus": 1, "van": 1, "motorcycle": 1,
                                  "tricycle": 1, "pedestrian": 1, "cyclist": 2}
    assert info["weathers"] == {"clear": 1, "cloudy": 1, "rain": 1, "fog": 1}
    assert info["times_of_day"] == {"day": 2, "dusk": 1, "night": 1}
    assert info["agents_per_scenario"] == {"mean": 2.75, "max": 4}


def test_unknown_and_empty_splits(tiny_suite, tmp_path, drivee2e_cache):
    s = load_suite(write_suite(tiny_suite, tmp_path / "t"))
    with pytest.raises(DriveE2EError, match=r"unknown split 'dev' for suite 'tiny'; expected one of: "
                                            r"train \(2\), val \(1\), test \(1\)"):
        s.pack("dev")
    tiny_suite.scenarios = [x for x in tiny_suite.scenarios if x.split != "val"]
    s2 = load_suite(write_suite(tiny_suite, tmp_path / "noval"))
    with pytest.raises(DriveE2EError, match=r"split 'val' of suite 'tiny' is empty; available splits: "
                                            r"train \(2\), test \(1\)"):
        s2.pack("val")


def test_bad_names_and_paths(tmp_path):
    with pytest.raises(DriveE2EError, match=r"unknown suite 'twin16'; expected a built-in suite name \(twin15, tiny\)"):
        load_suite("twin16")
    with pytest.raises(DriveE2EError, match="does not exist"):
        load_suite(tmp_path / "missing")
    with pytest.raises(DriveE2EError, match="not a suite folder"):
        load_suite(tmp_path)
    (tmp_path / "f.txt").write_text("x")
    with pytest.raises(DriveE2EError, match="is a file"):
        load_suite(tmp_path / "f.txt")


def test_invalid_folder_raises_one_line(tiny_suite_dir, drivee2e_cache):
    p = tiny_suite_dir / "scenarios" / "s_val.json"
    p.write_text(p.read_text().replace('"fog"', '"smog"'))
    s = load_suite(tiny_suite_dir)
    with pytest.raises(DriveE2EError, match=r"s_val.json: weather: expected one of clear"):
        s.pack()


def test_cache_hit_is_fast_equal_and_needs_no_records(tiny_suite_dir, drivee2e_cache, monkeypatch):
    s0 = load_suite(tiny_suite_dir)
    assert not s0.ready
    first = s0.pack()
    assert s0.ready and load_suite(tiny_suite_dir).ready
    files = _cache_files(drivee2e_cache)
    assert len(files) == 2 and files[0].endswith(".json") and files[1].endswith(".npz")

    def boom(*a, **k):
        raise AssertionError("records were read although the cache is valid")

    monkeypatch.setattr(suite_mod.schema, "read_suite", boom)
    t0 = time.perf_counter()
    s = load_suite(tiny_suite_dir)
    val = s.pack("val")
    elapsed = time.perf_counter() - t0
    assert elapsed < 1.0, elapsed
    assert s._records is None
    _assert_same(s.pack(), first)
    assert val.meta.scenario_id.tolist() == ["s_val"]
    assert s.info()["num_scenarios"] == 4


def test_corrupt_cache_is_rebuilt(tiny_suite_dir, drivee2e_cache, caplog):
    fresh = load_suite(tiny_suite_dir).pack()
    npz = next((drivee2e_cache / "suites").glob("*.npz"))
    side = npz.with_suffix(".json")

    npz.write_bytes(b"not a zip file" + b"\0" * 100)  # size changes: caught from the sidecar
    _assert_same(load_suite(tiny_suite_dir).pack(), fresh)
    assert npz.stat().st_size > 1000

    size = npz.stat().st_size
    npz.write_bytes(b"\0" * size)  # same size, garbage: caught when the npz is opened
    _assert_same(load_suite(tiny_suite_dir).pack(), fresh)

    data = bytearray(npz.read_bytes())  # one flipped bit inside an array: caught by the zip CRC
    data[len(data) // 2] ^= 0x10
    npz.write_bytes(bytes(data))
    _assert_same(load_suite(tiny_suite_dir).pack(), fresh)
    assert "CRC mismatch" in caplog.text

    side.write_text("{ truncated")
    _assert_same(load_suite(tiny_suite_dir).pack(), fresh)
    assert "unusable" in caplog.text
    assert len(_cache_files(drivee2e_cache)) == 2


def test_cache_key_follows_the_files(tiny_suite_dir, drivee2e_cache):
    load_suite(tiny_suite_dir).pack()
    before = _cache_files(drivee2e_cache)
    p = tiny_suite_dir / "scenarios" / "s_val.json"
    p.write_text(p.read_text().replace('"fog"', '"rain"'))
    s = load_suite(tiny_suite_dir)
    assert s.info()["weathers"]["rain"] == 2
    after = _cache_files(drivee2e_cache)
    assert after != before and len(after) == 2  # the stale entry was replaced


def test_cache_can_be_disabled(tiny_suite_dir, monkeypatch, tmp_path):
    monkeypatch.setenv("DRIVEE2E_CACHE", "off")
    assert load_suite(tiny_suite_dir).pack("test").meta.scenario_id.tolist() == ["s_test"]
    assert files.cache_dir() is None
    monkeypatch.delenv("DRIVEE2E_CACHE")
    assert str(files.cache_dir()).endswith(".cache/drivee2e")


def test_builtin_suite_generates_once_then_uses_the_cache(fake_twin15, drivee2e_cache, monkeypatch):
    s = load_suite("twin15")
    assert s.name == "twin15" and s.version == "test-1"
    assert s.splits == {"train": 2, "val": 1, "test": 1}
    assert fake_twin15.calls == [0]
    monkeypatch.setattr(suite_mod, "_GENERATED", {})  # a new process: only the disk cache is left
    s2 = load_suite("twin15")
    assert s2.pack("train").meta.scenario_id.tolist() == ["s_straight", "s_left"]
    assert fake_twin15.calls == [0]
    fake_twin15.VERSION = "test-2"  # a new generator version invalidates the cache
    load_suite("twin15").pack()
    assert fake_twin15.calls == [0, 0]


def test_builtin_invalid_records_are_reported(fake_twin15, drivee2e_cache):
    real = fake_twin15.generate

    def bad(seed=0):
        rec = real(seed)
        rec.scenarios[0].tracks[0].category = "ufo"
        return rec

    fake_twin15.generate = bad
    with pytest.raises(DriveE2EError, match=r"built-in suite 'twin15' .* invalid record: .*tracks\[0\]\.category"):
        load_suite("twin15").pack()


def test_builtin_missing_generator(monkeypatch, drivee2e_cache):
    monkeypatch.setitem(sys.modules, "drivee2e_jax.scenario.twin15", None)  # import raises ModuleNotFoundError
    monkeypatch.setattr(suite_mod, "_GENERATED", {})
    with pytest.raises(DriveE2EError, match=r"built-in suite 'twin15' is not available: module "
                                            r"drivee2e_jax.scenario.twin15 is missing"):
        load_suite("twin15").info()


def test_from_records_and_buckets(tiny_suite):
    s = Suite.from_records(tiny_suite)
    buckets = s.pack_buckets("train", num_buckets=2)
    assert sorted(i for b in buckets for i in b.meta.index.tolist()) == [0, 1]
    assert load_suite(s) is s
    tiny_suite.scenarios[0].weather = "snow"
    with pytest.raises(DriveE2EError, match="weather"):
        Suite.from_records(tiny_suite)


def test_package_exports():
    import drivee2e_jax
    from drivee2e_jax import scenario

    assert drivee2e_jax.load_suite is scenario.load_suite
    for name in ("load_suite", "Suite", "pack", "PackedBatch", "PackSizes"):
        assert hasattr(scenario, name)
