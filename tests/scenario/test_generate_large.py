"""twin15 at N scenarios (``num_scenarios``) and the streaming, resumable
suite writer (``generate_to``, ``schema.SuiteWriter``).

Kept fast: counts come from ``plan_suite`` / ``assign`` alone (no traffic
simulated) and the generator runs only on a few scenario indices.
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter

import pytest

from drivee2e_jax import cli
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario import twin15
from drivee2e_jax.scenario.schema import SuiteWriter, read_suite, write_suite
from drivee2e_jax.scenario.sizes import PackSizes
from drivee2e_jax.scenario.twin15 import build
from drivee2e_jax.scenario.twin15.scenarios import PER_200, id_width
from tests.helpers.tiny_suite import build_tiny_suite

# N = 800 is unchanged: its plan below (RNG draws only, the same on every
# machine) and its simulated logs through tests/eval/test_golden.py (twin15
# val's results of four policies). The logs themselves are not pinned by hash
# here: the traffic simulation's floats depend on the CPU's numpy SIMD paths
# (on an AVX2-only AMD EPYC, twin15_0000's route is 129.48 m at fbb6faa, where
# the machine that stored the golden results made 128.77 m).


def test_1600_counts_from_assign():
    metas = build.plan_suite(0, 1600)
    assert len(metas) == 1600 and [m.index for m in metas] == list(range(1600))
    assert metas[0].scenario_id == "twin15_0000" and metas[-1].scenario_id == "twin15_1599"
    assert Counter(m.split for m in metas) == {"train": 800, "val": 400, "test": 400}
    for split, scale in (("train", 4), ("val", 2), ("test", 2)):  # per 200, times N/800, twice for train
        labels = Counter(m.label for m in metas if m.split == split)
        assert labels == {k: v * scale for k, v in PER_200.items()}
        per_inter = Counter(m.inter for m in metas if m.split == split)
        assert sorted(per_inter) == list(range(15))  # every intersection in every split
        assert max(per_inter.values()) - min(per_inter.values()) <= 1
    assert Counter(m.weather for m in metas).keys() == {"clear", "cloudy", "rain", "fog"}


def test_800_plan_is_the_old_plan():
    """Every split / label / intersection / weather draw of N = 800 is the
    one the generator made before N became a parameter (hash from commit fbb6faa)."""
    metas = build.plan_suite(0)
    rows = [(m.scenario_id, m.split, m.label, m.inter, m.weather, m.time_of_day) for m in metas]
    assert hashlib.sha256(json.dumps(rows).encode()).hexdigest() == \
        "237f207421ec86d4d996150025553ef3c59447c9dd595c0e261f7bc96536f642"


def test_ids_and_names():
    assert [id_width(n) for n in (800, 8000, 10000, 10800, 80000)] == [4, 4, 4, 5, 5]
    assert [build.suite_name(n) for n in (800, 1600, 80000)] == ["twin15", "twin15x2", "twin15x100"]
    for bad in (0, -800, 1000, 799, 800.0, True, "800"):
        with pytest.raises(DriveE2EError, match=r"num_scenarios: expected a positive multiple of 800") as e:
            build.suite_name(bad)
        assert "\n" not in str(e.value)
    with pytest.raises(DriveE2EError, match=r"scenarios: expected indices in 0..1599, got 1600"):
        twin15.generate(0, scenarios=[1600], num_scenarios=1600)


def test_generate_to_blocks_and_resume(tmp_path, monkeypatch):
    """Two blocks of a 1600 suite (3 scenarios); killed after the first block,
    the same call resumes and generates only the second; the folder equals
    the in-memory suite written by write_suite (plus pack_sizes)."""
    picks = [3, 900, 1201]
    out = tmp_path / "big"
    calls = []
    real = build._generate_some

    def spy(seed, metas, todo, workers):
        calls.append(list(todo))
        if len(calls) == 2 and "kill" in spy.mode:
            raise KeyboardInterrupt  # as a Ctrl-C / kill mid-generation
        return real(seed, metas, todo, workers)

    spy.mode = "kill"
    monkeypatch.setattr(build, "_generate_some", spy)
    with pytest.raises(KeyboardInterrupt):
        twin15.generate_to(out, 0, num_scenarios=1600, scenarios=picks, workers=1)
    partial = tmp_path / ".big.partial"
    assert not out.exists() and partial.is_dir()
    assert sorted(p.name for p in (partial / "scenarios").iterdir()) == ["twin15_0003.json"]
    spy.mode = "resume"
    calls.clear()
    seen = []
    twin15.generate_to(out, 0, num_scenarios=1600, scenarios=picks, workers=1,
                       progress=lambda stage, done, total, info: seen.append((stage, done, total)))
    assert calls == [[900, 1201]]  # block 0 was kept
    assert seen == [("generating twin15x2", 1, 3), ("generating twin15x2", 3, 3)]
    assert not partial.exists()

    monkeypatch.setattr(build, "_generate_some", real)
    mem = twin15.generate(0, scenarios=picks, num_scenarios=1600, workers=1)
    ref = write_suite(mem, tmp_path / "ref")
    for p in (ref / "scenarios").iterdir():
        assert (out / "scenarios" / p.name).read_bytes() == p.read_bytes()
    for p in (ref / "maps").iterdir():
        assert (out / "maps" / p.name).read_bytes() == p.read_bytes()
    head, ref_head = (json.loads((d / "suite.json").read_text()) for d in (out, ref))
    sizes = head["meta"].pop("pack_sizes")
    assert head == ref_head and head["name"] == "twin15x2" and head["meta"]["num_scenarios"] == 1600
    assert sizes == PackSizes.fit(mem.scenarios, mem.maps).as_dict()
    assert [s.scenario_id for s in read_suite(out).scenarios] == ["twin15_0003", "twin15_0900", "twin15_1201"]


def _tiny_blocks():
    rec = build_tiny_suite()
    return rec, [rec.scenarios[:2], rec.scenarios[2:]]


def _writer(path, key, **kw):
    rec, _ = _tiny_blocks()
    return SuiteWriter(path, name="tiny", version="1", maps=rec.maps, key=key, **kw)


def test_suite_writer_resume_rules_and_lock(tmp_path):
    rec, blocks = _tiny_blocks()
    out = tmp_path / "s"
    w = _writer(out, {"seed": 0})
    w.write_block(0, blocks[0], {"n": 2})
    with pytest.raises(DriveE2EError, match="being written by another process"):
        _writer(out, {"seed": 0})
    w.close()  # killed here
    w = _writer(out, {"seed": 0})
    assert w.done(0) and not w.done(1)
    w.close()
    w = _writer(out, {"seed": 1})  # another generation: the partial folder is discarded
    assert not w.done(0)
    w.write_block(1, blocks[1], {"n": 2})
    w.write_block(0, blocks[0], {"n": 2})  # any order: suite.json follows the block numbers
    path = w.finish(lambda stats: {"blocks": len(stats), "n": sum(s["n"] for s in stats)})
    head = json.loads((path / "suite.json").read_text())
    assert [e["id"] for e in head["scenarios"]] == [s.scenario_id for s in rec.scenarios]
    assert head["meta"]["blocks"] == 2 and head["meta"]["n"] == 4
    assert head["meta"]["pack_sizes"] == PackSizes.fit(rec.scenarios, rec.maps).as_dict()
    ref = write_suite(rec, tmp_path / "ref")
    for p in (ref / "scenarios").iterdir():
        assert (path / "scenarios" / p.name).read_bytes() == p.read_bytes()
    assert read_suite(path).scenarios[3].scenario_id == rec.scenarios[3].scenario_id
    # --force rules as write_suite's
    with pytest.raises(DriveE2EError, match="not empty"):
        _writer(out, {"seed": 1})
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "x.txt").write_text("keep me")
    with pytest.raises(DriveE2EError, match="not a suite folder"):
        _writer(tmp_path / "other", {}, overwrite=True)
    w = _writer(out, {"seed": 2}, overwrite=True)
    w.write_block(0, blocks[0])
    w.finish({})
    assert len(list((out / "scenarios").iterdir())) == 2


def test_suite_writer_rejects_bad_records(tmp_path):
    rec, blocks = _tiny_blocks()
    bad = blocks[0][0]
    bad.weather = "smog"
    w = _writer(tmp_path / "s", {})
    with pytest.raises(DriveE2EError, match=r"scenarios/s_straight.json: weather: expected one of") as e:
        w.write_block(0, blocks[0])
    assert "\n" not in str(e.value)
    w.write_block(1, blocks[1])
    w.write_block(2, blocks[1])  # the same ids twice
    with pytest.raises(DriveE2EError, match="a unique scenario id"):
        w.finish({})
    w.close()


def test_cli_scenarios_errors(capsys, tmp_path):
    code = cli.main(["suite", "generate", "--scenarios", "1000", "--out", str(tmp_path / "x")])
    _, err = capsys.readouterr()
    assert code == 2 and err.count("\n") == 1
    assert "num_scenarios: expected a positive multiple of 800, got 1000" in err
    assert not (tmp_path / "x").exists()
