"""Reading a suite folder shard by shard (``scenario.stream``): the same
arrays and meta as the in-memory ``Suite.pack(split).select(rows)``, errors
from the reading thread raised in the caller, bounded read-ahead."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.scenario.schema import SuiteWriter, write_suite
from drivee2e_jax.scenario.sizes import PackSizes
from drivee2e_jax.scenario.stream import SuiteIndex, shards
from drivee2e_jax.scenario.suite import load_suite
from tests.helpers.tiny_suite import build_tiny_suite


@pytest.fixture
def streamed_dir(tmp_path):
    """The tiny suite written by SuiteWriter in two blocks (meta.pack_sizes)."""
    rec = build_tiny_suite()
    w = SuiteWriter(tmp_path / "streamed", name="tiny", version="1", maps=rec.maps, key={})
    w.write_block(0, rec.scenarios[:3])
    w.write_block(1, rec.scenarios[3:])
    return w.finish({"source": "test"})


def _assert_same(batch, ref):
    assert batch.sizes == ref.sizes
    got, want = flatten_scenario(batch.scenario), flatten_scenario(ref.scenario)
    assert got.keys() == want.keys()
    for k in want:
        a, b = np.asarray(got[k]), np.asarray(want[k])
        assert a.dtype == b.dtype and np.array_equal(a, b), k
    for k, v in ref.meta.columns().items():  # str columns: the width may differ (the shard's own longest)
        w = getattr(batch.meta, k)
        assert w.dtype.kind == v.dtype.kind and w.shape == v.shape and np.array_equal(w, v), k
        if w.dtype.kind != "U":
            assert w.dtype == v.dtype, k


@pytest.mark.parametrize("which", ["pre-pass", "suite.json"])
@pytest.mark.parametrize("split", [None, "train", "val"])
@pytest.mark.parametrize("shard_size", [1, 2, 7])
def test_shards_equal_the_in_memory_batch(tiny_suite_dir, streamed_dir, drivee2e_cache, which, split, shard_size):
    folder = tiny_suite_dir if which == "pre-pass" else streamed_dir
    index = SuiteIndex.open(folder)
    assert index.sizes_from == which
    suite = load_suite(folder)
    full = suite.pack(split)
    assert index.sizes == full.sizes == PackSizes.fit(suite.records.scenarios, suite.records.maps)
    got = list(shards(index, split, shard_size))
    n = len(full)
    assert [len(rows) for rows, _ in got] == [min(shard_size, n - i) for i in range(0, n, shard_size)]
    assert np.array_equal(np.concatenate([rows for rows, _ in got]), np.arange(n))
    for rows, batch in got:
        assert rows.dtype == np.int64
        _assert_same(batch, suite.pack(split, sizes=index.sizes).select(rows))
    assert index.ids.tolist() == suite.meta.scenario_id.tolist()
    assert index.splits.tolist() == suite.meta.split.tolist()


def test_given_sizes_and_prefetch_variants(streamed_dir, drivee2e_cache):
    index = SuiteIndex.open(streamed_dir)
    big = index.sizes.replace(agents=index.sizes.agents + 8, route=index.sizes.route + 16)
    ref = load_suite(streamed_dir).pack(None, sizes=big)
    for prefetch in (0, 1, 3):
        for rows, batch in shards(index, None, 3, sizes=big, prefetch=prefetch):
            _assert_same(batch, ref.select(rows))
    small = index.sizes.replace(agents=1)
    with pytest.raises(DriveE2EError, match=r"needs agents=\d+, more than PackSizes.agents=1"):
        list(shards(index, None, 2, sizes=small))


@pytest.mark.parametrize("prefetch", [0, 1, 2])
def test_malformed_file_is_one_line_at_its_shard(streamed_dir, prefetch):
    p = streamed_dir / "scenarios" / "s_val.json"
    p.write_text(p.read_text().replace('"fog"', '"smog"'))
    index = SuiteIndex.open(streamed_dir)  # suite.json and maps only: still fine
    order = index.ids.tolist()
    bad = order.index("s_val")
    it = shards(index, None, 1, prefetch=prefetch)
    for _ in range(bad):
        next(it)  # the shards before the bad file come through
    with pytest.raises(DriveE2EError) as e:
        next(it)
    msg = str(e.value)
    assert "\n" not in msg and "scenarios/s_val.json: weather: expected one of" in msg and "'smog'" in msg


def test_broken_json_and_missing_file(streamed_dir):
    (streamed_dir / "scenarios" / "s_test.json").write_text("{not json")
    index = SuiteIndex.open(streamed_dir)
    with pytest.raises(DriveE2EError, match=r"s_test.json: line 1 column 2: expected valid JSON"):
        list(shards(index, "test", 4))
    (streamed_dir / "scenarios" / "s_test.json").unlink()
    with pytest.raises(DriveE2EError, match=r"s_test.json: expected a file \(listed in suite.json"):
        list(shards(SuiteIndex.open(streamed_dir), "test", 4))
    (streamed_dir / "scenarios" / "extra.json").write_text("{}")
    with pytest.raises(DriveE2EError, match=r"extra.json: expected to be listed in suite.json"):
        SuiteIndex.open(streamed_dir)


def test_bad_head_and_pack_sizes(streamed_dir, tmp_path):
    with pytest.raises(DriveE2EError, match="does not exist"):
        SuiteIndex.open(tmp_path / "nope")
    head = streamed_dir / "suite.json"
    head.write_text(head.read_text().replace('"stop_lines":', '"stop_linez":'))
    with pytest.raises(DriveE2EError, match=r"suite.json: meta.pack_sizes: expected an object with keys"):
        SuiteIndex.open(streamed_dir)


def test_empty_and_unknown_split_and_bad_arguments(tmp_path):
    rec = build_tiny_suite()
    rec.scenarios = [s for s in rec.scenarios if s.split != "test"]
    index = SuiteIndex.open(write_suite(rec, tmp_path / "no_test"))
    with pytest.raises(DriveE2EError, match=r"split 'test' of suite 'tiny' is empty; available splits: train \(2\), val \(1\)"):
        shards(index, "test", 2)  # at the call, before any reading
    with pytest.raises(DriveE2EError, match=r"unknown split 'dev'"):
        shards(index, "dev", 2)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(DriveE2EError, match="shard_size: expected an integer >= 1"):
            next(shards(index, "train", bad))
    with pytest.raises(DriveE2EError, match="prefetch: expected an integer >= 0"):
        next(shards(index, "train", 1, prefetch=-1))


def test_read_ahead_is_bounded_and_overlaps(streamed_dir, monkeypatch):
    """The thread packs the next shard while the caller holds the current one,
    never more than ``prefetch`` ahead; closing early stops the thread."""
    index = SuiteIndex.open(streamed_dir)
    made: list[int] = []
    real = SuiteIndex.pack_rows

    def counting(self, rows, sizes=None, **kw):
        made.append(int(rows[0]))
        return real(self, rows, sizes, **kw)

    monkeypatch.setattr(SuiteIndex, "pack_rows", counting)
    for prefetch in (1, 2):
        made.clear()
        taken = 0
        for _rows, _batch in shards(index, None, 1, prefetch=prefetch):
            taken += 1
            deadline = time.monotonic() + 2.0
            while len(made) < min(taken + prefetch, len(index)) and time.monotonic() < deadline:
                time.sleep(0.01)  # give the thread time to run ahead as far as it may
            time.sleep(0.05)
            assert len(made) == min(taken + prefetch, len(index))  # read ahead, and bounded
    before = threading.active_count()
    it = shards(index, None, 1, prefetch=1)
    next(it)
    it.close()
    assert threading.active_count() == before
    assert not any(t.name == "drivee2e-shards" for t in threading.enumerate())

