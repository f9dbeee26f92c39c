"""eval.runspec: run.json <-> RunSpec round trip, older files, the builders."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.eval import runspec
from drivee2e_jax.eval.bench import BenchConfig
from drivee2e_jax.eval.results import RunDir
from drivee2e_jax.eval.runspec import RunSpec, batch_sha256, check_dt_against_logs, pick_split
from drivee2e_jax.eval.tasks import TASKS
from drivee2e_jax.eval.variants import VARIANTS
from drivee2e_jax.metrics.driving_score import SCORE_PRESETS
from drivee2e_jax.records import SuiteRecord
from drivee2e_jax.rollout import ControlTiming
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.scenario.schema import write_suite
from tests.helpers import sim_scenarios as ss

#: run.json as ``drivee2e bench`` wrote it before RunSpec (default flags, 3 scenarios).
OLD_RUN_JSON = {
    "suite": "twin15", "suite_version": "1.3", "split": "val", "num_scenarios": 3, "preset": "paper", "dt": 0.1,
    "control_every": 1, "latency": 0, "seed": 0, "open_loop": False, "task": "route_navigation", "repetitions": 1,
}
BASE_KEYS = list(OLD_RUN_JSON)

finite = st.floats(0.001, 1.0, allow_nan=False, allow_infinity=False)
specs = st.builds(
    RunSpec,
    suite=st.sampled_from(["twin15", "suites/road3", "x"]),
    split=st.sampled_from(["val", "train", "test"]),
    preset=st.sampled_from(SCORE_PRESETS),
    dt=finite,
    control_every=st.integers(1, 5),
    latency=st.integers(0, 4),
    seed=st.integers(0, 2**31 - 1),
    open_loop=st.booleans(),
    task=st.sampled_from(list(TASKS)),
    repetitions=st.integers(1, 5),
    gps_noise_std=st.sampled_from([0.0, 0.5, 2.0]),
    compass_noise_std=st.sampled_from([0.0, 0.01]),
    variant=st.sampled_from(VARIANTS),
    suite_version=st.sampled_from(["1", "1.3", "?"]),
    num_scenarios=st.integers(1, 500),
).map(lambda s: dataclasses.replace(
    s, limit=s.num_scenarios,
    variant_removed=None if s.variant == "complete" else (("vehicle", (3, 10)), ("pedestrian", (0, 2))),
))


@settings(deadline=None, max_examples=60)
@given(spec=specs)
def test_run_json_round_trips(spec):
    d = spec.to_json()
    text = json.loads(json.dumps(d))  # what RunDir compares with
    assert text == d
    back = RunSpec.from_json(text)
    assert back == spec
    assert back.to_json() == d and list(back.to_json()) == list(d)
    optional = [k for k in d if k not in BASE_KEYS]
    assert list(d)[: len(BASE_KEYS)] == BASE_KEYS
    want = []
    if spec.gps_noise_std or spec.compass_noise_std:
        want += ["gps_noise_std", "compass_noise_std"]
    if spec.variant != "complete":
        want += ["variant", "variant_removed"]
    assert optional == want


def test_old_run_json_loads_and_writes_back_unchanged():
    spec = RunSpec.from_json(OLD_RUN_JSON)
    assert spec.to_json() == OLD_RUN_JSON
    assert (spec.dt, spec.num_scenarios, spec.limit, spec.variant) == (0.1, 3, 3, "complete")
    with_extras = {**OLD_RUN_JSON, "gps_noise_std": 1.5, "compass_noise_std": 0.0, "variant": "visible_all",
                   "variant_removed": {"vehicle": [2, 7], "pedestrian": [0, 1]}}
    assert RunSpec.from_json(with_extras).to_json() == with_extras


def test_older_run_json_without_the_later_keys_loads_with_defaults():
    oldest = {"suite": "twin15", "split": "val", "dt": 0.2, "num_scenarios": 5, "seed": 3}
    spec = RunSpec.from_json(oldest)
    assert (spec.task, spec.repetitions, spec.preset, spec.open_loop) == ("route_navigation", 1, "paper", False)
    assert spec.timing() == ControlTiming(1, 0)
    cfg = spec.sim_config()
    assert cfg.dt == 0.2 and cfg.score.name == "paper" and cfg.obs.gps_noise_std == 0.0
    assert RunSpec.from_json({k: v for k, v in oldest.items() if k != "num_scenarios"}).limit is None
    assert RunSpec.from_json({**OLD_RUN_JSON, "written_by_a_later_version": 1}).to_json() == OLD_RUN_JSON


@pytest.mark.parametrize("bad, match", [
    ({"split": "val", "dt": 0.1}, "no suite"),
    ({**OLD_RUN_JSON, "task": "flying"}, "unknown task"),
    ({**OLD_RUN_JSON, "variant": "invisible"}, "unknown variant"),
    ({**OLD_RUN_JSON, "dt": "fast"}, "bad value"),
    ([1, 2], "JSON object"),
])
def test_bad_run_json_is_a_one_line_error(bad, match):
    with pytest.raises(DriveE2EError, match=match):
        RunSpec.from_json(bad)


def test_load_names_the_file(tmp_path):
    with pytest.raises(DriveE2EError, match="run.json: unreadable"):
        RunSpec.load(tmp_path)
    (tmp_path / "run.json").write_text(json.dumps({**OLD_RUN_JSON, "repetitions": 0}))
    with pytest.raises(DriveE2EError, match=r"run.json: --repetitions must be >= 1"):
        RunSpec.load(tmp_path)
    (tmp_path / "run.json").write_text(json.dumps(OLD_RUN_JSON))
    assert RunSpec.load(tmp_path).to_json() == OLD_RUN_JSON


def test_checks_and_builders_raise_one_line_errors():
    with pytest.raises(DriveE2EError, match="--limit must be >= 1"):
        RunSpec(limit=0)
    with pytest.raises(DriveE2EError, match="--repetitions"):
        RunSpec(repetitions=0)
    with pytest.raises(DriveE2EError, match="dt"):
        RunSpec(dt=0.0).sim_config()
    with pytest.raises(DriveE2EError):
        RunSpec(control_every=0).timing()
    with pytest.raises(ValueError, match="resolve"):
        RunSpec().to_json()
    assert RunSpec(seed=4).repetition_seeds() is None
    assert RunSpec(seed=4, repetitions=3).repetition_seeds() == [4, 5, 6]
    cfg = RunSpec(gps_noise_std=0.5, compass_noise_std=0.02, preset="lb21", dt=0.05).sim_config()
    assert (cfg.obs.gps_noise_std, cfg.obs.compass_noise_std, cfg.score.name, cfg.dt) == (0.5, 0.02, "lb21", 0.05)


@pytest.fixture(scope="module")
def suite_dir(tmp_path_factory):
    maps = {m.map_id: m for m in (ss.road_map(), ss.road_map(obstacle=True))}
    scns = [ss.clean(), ss.blocked_by_car(), ss.red_light()]
    return write_suite(SuiteRecord("road3", "1", maps, scns), tmp_path_factory.mktemp("suites") / "road3")


def test_batch_and_resolve_on_a_suite(suite_dir):
    spec = RunSpec(suite=str(suite_dir), split="val", limit=2)
    suite = spec.load_suite()
    rb = spec.batch(suite)
    assert rb.variant is None and rb.num_scenarios == 2 and len(rb.packed) == 3
    assert list(rb.limited().meta.scenario_id) == list(rb.packed.meta.scenario_id[:2])
    done = spec.resolve(suite, rb)
    assert (done.suite_version, done.num_scenarios, done.variant_removed) == ("1", 2, None)
    again = RunSpec.from_json(done.to_json())
    rb2 = again.batch(again.load_suite())
    assert list(rb2.limited().meta.scenario_id) == list(rb.limited().meta.scenario_id)
    assert np.array_equal(np.asarray(rb2.limited().scenario.tracks.xy), np.asarray(rb.limited().scenario.tracks.xy))
    assert spec.default_out().name == "road3-val"
    assert RunSpec(task="lane_following", variant="visible_all").default_out().as_posix() == "results/twin15-val-lane_following-visible_all"


def test_a_run_json_without_fingerprints_is_refused_as_older(suite_dir, tmp_path):
    """A run.json written before fingerprints: the spec of the same flags still
    writes exactly what bench wrote, but RunDir refuses to resume it (its
    results cannot be checked against this run) until --force."""
    old = {"suite": str(suite_dir), "suite_version": "1", "split": "val", "num_scenarios": 3, "preset": "paper",
           "dt": 0.1, "control_every": 1, "latency": 0, "seed": 0, "open_loop": False, "task": "route_navigation",
           "repetitions": 1}
    out = tmp_path / "run"
    out.mkdir()
    (out / "run.json").write_text(json.dumps(old, indent=2))
    spec = BenchConfig(suite=str(suite_dir), split="val").run_spec()
    suite = spec.load_suite()
    rb = spec.batch(suite)
    spec = spec.resolve(suite, rb)
    assert spec.to_json() == old
    info = {**spec.to_json(), "fingerprint": {"suite_sha256": batch_sha256(rb.limited()), "drivee2e_version": "x"}}
    with pytest.raises(DriveE2EError, match="written by an older drivee2e version"):
        RunDir(out, info)
    RunDir(out, info, force=True).close()
    RunDir(out, info).close()  # now it has fingerprints
    with pytest.raises(DriveE2EError, match="differs in seed"):
        RunDir(out, {**info, **dataclasses.replace(spec, seed=1).to_json()})


@pytest.mark.parametrize("kwargs, flag", [
    ({"dt": float("inf")}, "--dt"), ({"dt": float("nan")}, "--dt"), ({"dt": 1e6}, "--dt"), ({"dt": 0.0}, "--dt"),
    ({"dt": -1.0}, "--dt"), ({"dt": True}, "--dt"), ({"control_every": 0}, "--control-every"),
    ({"control_every": 1.5}, "--control-every"), ({"latency": -1}, "--latency"), ({"seed": -1}, "--seed"),
    ({"seed": 2**32}, "--seed"), ({"seed": 2**32 - 2, "repetitions": 3}, "--seed"), ({"limit": 0}, "--limit"),
    ({"repetitions": 0}, "--repetitions"), ({"gps_noise_std": float("nan")}, "--gps-noise-std"),
    ({"compass_noise_std": -0.1}, "--compass-noise-std"),
])
def test_every_setting_is_checked_with_one_line_naming_its_flag(kwargs, flag):
    with pytest.raises(DriveE2EError) as e:
        RunSpec(**kwargs)
    assert str(e.value).startswith(f"{flag} must be") and "\n" not in str(e.value)


def test_settings_at_their_bounds_are_accepted():
    RunSpec(dt=1.0, seed=2**32 - 3, repetitions=3, latency=0, control_every=1, limit=1)


def test_dt_may_not_exceed_the_log_step(suite_dir):
    meta = RunSpec(suite=str(suite_dir)).load_suite().meta
    check_dt_against_logs(0.1, meta)  # the log step itself
    check_dt_against_logs(0.05, meta)
    with pytest.raises(DriveE2EError, match=r"--dt 0.2 exceeds the log step 0.1 s of scenario \w+"):
        check_dt_against_logs(0.2, meta)


def test_pick_split_prefers_val_then_the_only_non_empty_one():
    assert pick_split({"train": 5, "val": 2})[0] == "val"
    split, note = pick_split({"test": 4}, "suite s")
    assert split == "test" and "only non-empty split" in note
    with pytest.raises(DriveE2EError, match=r"--split: suite s has no val split; name one of: train \(3\), test \(2\)"):
        pick_split({"train": 3, "test": 2}, "suite s")


def test_the_suite_fingerprint_covers_the_evaluated_arrays(suite_dir):
    spec = RunSpec(suite=str(suite_dir))
    rb = spec.batch(spec.load_suite())
    h = batch_sha256(rb.limited())
    assert batch_sha256(spec.batch(spec.load_suite()).limited()) == h  # deterministic
    two = dataclasses.replace(spec, limit=2)
    assert batch_sha256(two.batch(two.load_suite()).limited()) != h
    packed = rb.limited()
    xy = np.array(packed.scenario.tracks.xy)
    xy[0, 0, 0, 0] += 0.01
    moved = dataclasses.replace(packed, scenario=packed.scenario.replace(tracks=packed.scenario.tracks.replace(xy=xy)))
    assert batch_sha256(moved) != h


@pytest.mark.parametrize("kwargs, want", [
    ({"collisions": "foo"}, "--collisions: unknown collision mode 'foo'; expected one of all, at_fault"),
    ({"agents": "reactive"}, "--agents: unknown agent model 'reactive'; expected one of log, idm"),
    ({"preset": "carla"}, "--preset: unknown scoring preset 'carla'; expected one of "),
])
def test_unknown_choices_are_one_line_listing_the_choices(kwargs, want):
    with pytest.raises(DriveE2EError) as e:
        RunSpec(**kwargs)
    assert str(e.value).startswith(want) and "\n" not in str(e.value)


def test_preset_error_lists_every_score_preset():
    with pytest.raises(DriveE2EError) as e:
        BenchConfig(preset="carla").run_spec()
    listed = str(e.value).split("expected one of ")[1].split(", ")
    assert listed == list(SCORE_PRESETS)


def test_collisions_and_agents_round_trip_and_old_files_read_as_defaults():
    """Written only when not the default (older run.json stay resumable and
    compare equal); read back exactly; absent = all / log."""
    base = RunSpec.from_json(OLD_RUN_JSON)
    assert (base.collisions, base.agents) == ("all", "log")
    assert base.to_json() == OLD_RUN_JSON  # defaults add no key
    spec = dataclasses.replace(base, collisions="at_fault", agents="idm")
    d = spec.to_json()
    assert (d["collisions"], d["agents"]) == ("at_fault", "idm")
    assert list(d)[: len(BASE_KEYS)] == BASE_KEYS
    assert RunSpec.from_json(json.loads(json.dumps(d))) == spec
    only = dataclasses.replace(base, agents="idm").to_json()
    assert "collisions" not in only and only["agents"] == "idm"


def test_sim_config_carries_collision_mode_and_agents():
    """Needs the core's ScoreConfig.collision_mode and SimConfig.agents
    (a TypeError until they land)."""
    cfg = RunSpec(preset="lb21", collisions="at_fault", agents="idm").sim_config()
    assert (cfg.score.name, cfg.score.collision_mode, cfg.agents) == ("lb21", "at_fault", "idm")
    cfg = RunSpec().sim_config()
    assert (cfg.score.collision_mode, cfg.agents) == ("all", "log")


@pytest.mark.parametrize("change, key", [
    ({"collisions": "at_fault"}, "collisions"), ({"agents": "idm"}, "agents"), ({"preset": "lb21"}, "preset"),
])
def test_a_folder_of_another_collision_mode_agent_model_or_preset_is_refused(tmp_path, change, key):
    """RunDir compares run.json key by key: another setting is one line naming
    it, unless --force (which clears the old policy files: never mixed)."""
    spec = RunSpec.from_json(OLD_RUN_JSON)
    fp = {"fingerprint": {"suite_sha256": "s", "drivee2e_version": "x"}}
    out = tmp_path / "run"
    run = RunDir(out, {**spec.to_json(), **fp})
    run.save_policy("p", [{"scenario_id": "a", "driving_score": 1.0}], {}, {})
    run.close()
    other = {**dataclasses.replace(spec, **change).to_json(), **fp}
    with pytest.raises(DriveE2EError) as e:
        RunDir(out, other)
    assert f"differs in {key}" in str(e.value) and "--force" in str(e.value) and "\n" not in str(e.value)
    RunDir(out, other, force=True).close()
    assert not (out / "policies" / "p.json").exists()
    assert json.loads((out / "run.json").read_text()).get(key) == other[key]


def test_suite_fingerprint_counts_the_origin_only_where_it_is_not_zero():
    """A suite near (0, 0) (origin 0: twin15, tiny) keeps the fingerprint it had before
    ``meta.origin`` existed, so its results folders stay current; a moved origin changes it."""
    b = ss.build([ss.clean()])
    assert not b.meta.origin.any()
    before = hashlib.sha256()  # the fingerprint as computed before the origin column
    for name, leaf in sorted(flatten_scenario(b.scenario).items()):
        runspec._hash_array(before, f"scenario.{name}", leaf)
    for name, col in sorted(b.meta.columns().items()):
        if name != "origin":
            runspec._hash_array(before, f"meta.{name}", col)
    assert batch_sha256(b) == before.hexdigest()
    moved = dataclasses.replace(b, meta=dataclasses.replace(b.meta, origin=b.meta.origin + (4e6, 5e5)))
    assert batch_sha256(moved) != batch_sha256(b)
