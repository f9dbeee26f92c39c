"""The demonstration recorder and the streaming loader, on the tiny suite."""

import json

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import base
from drivee2e_jax.train.dataset import DemoDataset, flatten, unflatten


def test_manifest_and_shards(tiny_demos):
    m = json.loads((tiny_demos / "manifest.json").read_text())
    assert m["suite"] == "tiny" and m["split"] == "train" and m["num_scenarios"] == 2
    assert len(m["shards"]) == 2 and m["count"] == sum(s["count"] for s in m["shards"]) > 0
    assert m["leaves"]["obs.history"]["shape"] == [base.HISTORY_LEN, base.HISTORY_FEATURES]
    assert m["leaves"]["target.waypoints"]["shape"] == [6, 2]
    assert "obs.bev" not in m["leaves"]  # no sensor asked for


def test_straight_scenario_labels(tiny_demos):
    """s_straight drives east at a constant 10 m/s: the label is 5 m per 0.5 s
    ahead, the history 5 m per 0.5 s behind (where it exists)."""
    ds = DemoDataset(tiny_demos)
    sh = ds.load_shard(0)  # shard order = scenario order: s_straight first
    wp, ok = sh["target.waypoints"], sh["target.waypoint_valid"]
    full = ok.all(axis=1)
    assert full.any()
    np.testing.assert_allclose(wp[full], np.broadcast_to(5.0 * np.arange(1, 7)[:, None] * [1, 0], wp[full].shape),
                               atol=0.05)
    hist, hv = sh["obs.history"], sh["obs.history_valid"]
    lag = np.arange(base.HISTORY_LEN - 1, -1, -1) * 5.0  # oldest first; the newest is "now"
    for h, v in zip(hist, hv):
        np.testing.assert_allclose(h[v, 0], -lag[v], atol=0.05)
        np.testing.assert_allclose(h[v, 4], 10.0, atol=0.05)  # speed
        assert v[-1] and np.all(h[~v] == 0)


def test_loader_shapes_and_determinism(tiny_demos):
    ds = DemoDataset(tiny_demos)
    a = list(ds.batches(4, seed=1, epoch=1, shuffle_shards=1))
    b = list(ds.batches(4, seed=1, epoch=1, shuffle_shards=1))
    c = list(ds.batches(4, seed=1, epoch=2, shuffle_shards=1))
    assert len(a) == ds.steps_per_epoch(4) == len(ds) // 4
    assert a[0].obs.history.shape == (4, base.HISTORY_LEN, base.HISTORY_FEATURES)
    assert a[0].target.waypoints.shape == (4, 6, 2) and a[0].obs.ego.shape == (4, 4)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.target.waypoints, y.target.waypoints)
    assert any(not np.array_equal(x.target.waypoints, y.target.waypoints) for x, y in zip(a, c))
    # Every sample at most once per epoch.
    seen = np.concatenate([np.c_[x.obs.gps, x.obs.privileged.ego.t, x.target.waypoints.reshape(4, -1)] for x in a])
    assert len(np.unique(seen, axis=0)) == len(seen)
    # skip = resume mid-epoch
    rest = list(ds.batches(4, seed=1, epoch=1, shuffle_shards=1, skip=1))
    np.testing.assert_array_equal(rest[0].target.waypoints, a[1].target.waypoints)


def test_flatten_round_trip(tiny_demos):
    s = DemoDataset(tiny_demos).first()
    back = unflatten(flatten(s))
    assert back.obs.bev is None and back.obs.lidar is None
    for k, v in flatten(s).items():
        np.testing.assert_array_equal(flatten(back)[k], v)


def test_missing_manifest_is_one_line_error(tmp_path):
    with pytest.raises(DriveE2EError, match="manifest"):
        DemoDataset(tmp_path)
