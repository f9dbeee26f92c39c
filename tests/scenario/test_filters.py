"""scenario.filters on the tiny suite with hand-made visibility masks."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.scenario.filters import filter_invisible, never_visible
from drivee2e_jax.scenario.flat import flatten_scenario
from drivee2e_jax.scenario.pack import pack
from drivee2e_jax.scenario.schema import read_suite, validate_suite, write_suite

# packed track order (ego first, then by track id) of the tiny suite:
#   s_straight: 7 ego car, 3 truck, 12 pedestrian     s_left: 2 ego car, 5 cyclist
#   s_val: 1 ego van, 4 motorcycle                    s_test: 0 ego car, 8 cyclist, 9 bus, 11 tricycle
ORDER = {"s_straight": [7, 3, 12], "s_left": [2, 5], "s_val": [1, 4], "s_test": [0, 8, 9, 11]}


def masks(suite, value=False, agents=None, steps=None):
    """One (A, T) mask per scenario, all ``value``; ``agents`` / ``steps`` pad beyond the scenario."""
    out = {}
    for s in suite.scenarios:
        a = len(s.tracks) if agents is None else agents
        t = s.num_steps if steps is None else steps
        out[s.scenario_id] = np.full((a, t), value, bool)
    return out


def ids(suite):
    return {s.scenario_id: sorted(t.track_id for t in s.tracks) for s in suite.scenarios}


def test_never_visible_vehicles_removed_people_and_egos_kept(tiny_suite):
    before = copy.deepcopy(ids(tiny_suite))
    out = filter_invisible(tiny_suite, masks(tiny_suite))
    assert ids(out) == {"s_straight": [7, 12], "s_left": [2, 5], "s_val": [1], "s_test": [0, 8]}
    f = out.meta["filters"][-1]
    assert f == {"filter": "invisible", "categories": "vehicles", "removed_tracks": 4,
                 "removed": {"s_straight": [3], "s_val": [4], "s_test": [9, 11]}}
    assert out.meta["purpose"] == "tests"  # the rest of the meta is kept
    assert ids(tiny_suite) == before and "filters" not in tiny_suite.meta  # the input is not touched
    assert out.maps is tiny_suite.maps


def test_all_categories_removes_everyone_but_the_ego(tiny_suite):
    out = filter_invisible(tiny_suite, masks(tiny_suite), categories="all")
    assert ids(out) == {"s_straight": [7], "s_left": [2], "s_val": [1], "s_test": [0]}
    assert out.meta["filters"][-1]["removed_tracks"] == 7
    # chained filters are all recorded
    again = filter_invisible(out, masks(out), categories="all")
    assert [f["removed_tracks"] for f in again.meta["filters"]] == [7, 0]


def test_everything_visible_removes_nothing(tiny_suite):
    out = filter_invisible(tiny_suite, masks(tiny_suite, True), categories="all")
    assert ids(out) == ids(tiny_suite) and out.meta["filters"][-1]["removed"] == {}


def test_rows_follow_the_packed_order_and_only_sampled_steps_count(tiny_suite):
    vis = masks(tiny_suite)
    row_bus = ORDER["s_test"].index(9)
    vis["s_test"][row_bus, 19] = True  # the bus is sampled at steps 0..19
    s_test = next(s for s in tiny_suite.scenarios if s.scenario_id == "s_test")
    assert never_visible(s_test, vis["s_test"]) == [8, 11]
    assert ids(filter_invisible(tiny_suite, vis))["s_test"] == [0, 8, 9]
    vis["s_test"][row_bus] = False
    vis["s_test"][row_bus, 20:] = True  # seen only where it has no sample: counts for nothing
    assert never_visible(s_test, vis["s_test"]) == [8, 9, 11]
    # the ego's row (0) is never a reason to keep or drop anyone
    vis = masks(tiny_suite)
    vis["s_test"][0] = True
    assert never_visible(s_test, vis["s_test"]) == [8, 9, 11]


def test_masks_from_the_packed_batch_line_up(tiny_suite):
    """Masks built on packed arrays (padded to the suite's A and T) address the same tracks."""
    batch = pack(tiny_suite.scenarios, tiny_suite.maps)
    flat = flatten_scenario(batch.scenario)
    track_id, valid = np.asarray(flat["tracks.track_id"]), np.asarray(flat["tracks.valid"])
    for b, s in enumerate(tiny_suite.scenarios):
        assert track_id[b, :len(s.tracks)].tolist() == ORDER[s.scenario_id]
    # "the sensors see exactly the motorcycle and the truck": on the packed rows, where valid
    seen = valid & np.isin(track_id, [3, 4])[..., None]
    vis = {s.scenario_id: seen[b] for b, s in enumerate(tiny_suite.scenarios)}
    out = filter_invisible(tiny_suite, vis, categories="all")
    assert ids(out) == {"s_straight": [3, 7], "s_left": [2], "s_val": [1, 4], "s_test": [0]}


def test_padded_masks_and_a_valid_written_suite(tiny_suite, tmp_path):
    out = filter_invisible(tiny_suite, masks(tiny_suite, agents=8, steps=64))
    folder = write_suite(out, tmp_path / "variant")
    assert validate_suite(folder) == []
    back = read_suite(folder)
    assert back.meta["filters"][0]["removed"]["s_test"] == [9, 11]


def test_bad_inputs_are_one_line_errors(tiny_suite):
    vis = masks(tiny_suite)
    with pytest.raises(DriveE2EError, match="categories: expected one of vehicles, all, got 'cars'"):
        filter_invisible(tiny_suite, vis, categories="cars")
    del vis["s_val"]
    with pytest.raises(DriveE2EError, match="no mask for scenario 's_val'"):
        filter_invisible(tiny_suite, vis)
    vis = masks(tiny_suite) | {"nope": np.zeros((1, 1), bool)}
    with pytest.raises(DriveE2EError, match="scenario 'nope' is not in suite 'tiny'"):
        filter_invisible(tiny_suite, vis)
    vis = masks(tiny_suite)
    vis["s_test"] = vis["s_test"][:2]
    with pytest.raises(DriveE2EError, match=r"'s_test': visibility mask: expected shape \(>= 4 tracks, >= 50 steps\)"):
        filter_invisible(tiny_suite, vis)
    vis = masks(tiny_suite)
    vis["s_left"] = vis["s_left"].astype(np.float32)
    with pytest.raises(DriveE2EError, match="expected dtype bool, got float32"):
        filter_invisible(tiny_suite, vis)
