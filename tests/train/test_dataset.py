"""The demonstration recorder and the streaming loader, on the tiny suite."""

import json
from pathlib import Path

import numpy as np
import pytest

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import base
from drivee2e_jax.train.dataset import DemoDataset, flatten, unflatten

TINY = Path(__file__).resolve().parents[2] / "drivee2e_jax" / "scenario" / "examples" / "tiny"


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


# --------------------------------------------------------------------------
# The BEV size: recorded, checked against the model, handed to the policy
# --------------------------------------------------------------------------

#: A slim TCP sized for 32 x 32 at 2 m/px: reads a 64 x 64 at 1 m/px BEV by pooling.
SMALL_TCP = {"bev_size": 32, "bev_resolution": 2.0, "conv_features": (8, 8, 8, 8), "hidden": 32, "gru_hidden": 16}


@pytest.fixture(scope="module")
def bev64(tmp_path_factory):
    """One tiny-suite scenario recorded with a 64 x 64 BEV (default 64 m extent)."""
    from drivee2e_jax.train.dataset import DatasetConfig, build_dataset

    out = tmp_path_factory.mktemp("demos64")
    build_dataset(str(TINY), "train", out, DatasetConfig(sensors=("bev",), bev_size=64, every=10), limit=1)
    return out


def test_bev_size_is_rendered_and_recorded(bev64, capsys):
    """--bev-size 64 keeps the 64 m extent (1 m/px): the manifest says so and
    the first sample is exactly the simulator's reset BEV at that size."""
    import jax

    from drivee2e_jax.cli import main
    from drivee2e_jax.models.tcp import TCP_BEV
    from drivee2e_jax.observe import sensors
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.sim import SimConfig, Simulator

    m = json.loads((bev64 / "manifest.json").read_text())
    assert m["bev"] == {"height": 64, "width": 64, "resolution": 1.0}
    assert m["leaves"]["obs.bev"]["shape"] == [64, 64]
    ds = DemoDataset(bev64)
    assert ds.bev == TCP_BEV  # TCP's own input

    suite = load_suite(TINY)
    packed = suite.pack("train").select(np.arange(1))
    cfg = sensors.SensorConfig(bev=TCP_BEV)
    assets = sensors.build_assets(packed, cfg, suite.maps)
    first = jax.tree_util.tree_map(lambda a: a[0], packed.scenario)
    _, obs = jax.jit(Simulator(SimConfig(sensors=cfg)).reset)(
        jax.random.split(jax.random.PRNGKey(0), 1)[0], first, assets.replace(map_index=assets.map_index[0]))
    recorded = ds.load_shard(0)["obs.bev"][0]
    assert np.count_nonzero(recorded) > 0
    np.testing.assert_array_equal(recorded, np.asarray(obs.bev))

    assert main(["dataset", "info", str(bev64)]) == 0
    assert "BEV 64x64 at 1 m/px" in capsys.readouterr().out


def test_bad_bev_size_is_one_line_error(tmp_path, capsys):
    from drivee2e_jax.cli import main
    from drivee2e_jax.train.dataset import DatasetConfig

    with pytest.raises(DriveE2EError, match="bev-size 60"):  # tiles of 8 px
        DatasetConfig(sensors=("bev",), bev_size=60)
    with pytest.raises(DriveE2EError, match="bev-size must be >= 1"):
        DatasetConfig(bev_size=0)
    assert main(["dataset", "build", "--suite", str(TINY), "--sensors", "bev", "--bev-size", "60",
                 "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--bev-size 60" in err and "tile" in err


def test_a_model_that_cannot_read_the_dataset_bev_is_refused(bev64, tiny_demos):
    from drivee2e_jax.models.registry import get_model

    ds = DemoDataset(bev64)
    ds.check_model(get_model("tcp"))  # 64 x 64 at 1 m/px: its size
    ds.check_model(get_model("tcp", **SMALL_TCP))  # an integer multiple: pooled
    ds.check_model(get_model("ad_mlp"))  # no BEV
    for bad in ({"bev_size": 64, "bev_resolution": 0.5}, {"bev_size": 128, "bev_resolution": 0.5},
                {"bev_size": 48, "bev_resolution": 64 / 48}):
        with pytest.raises(DriveE2EError, match=r"BEV 64x64 at 1 m/px does not fit model 'tcp'") as e:
            ds.check_model(get_model("tcp", **bad))
        assert "\n" not in str(e.value)
    with pytest.raises(DriveE2EError, match=r"needs sensors \['bev'\]"):
        DemoDataset(tiny_demos).check_model(get_model("tcp"))
    # A manifest from before the size was recorded: the default 128 x 128 at 0.5 m/px.
    from drivee2e_jax.models.checkpoint import bev_of_manifest

    legacy = bev_of_manifest({"sensors": ["bev"]})
    assert (legacy.height, legacy.resolution) == (128, 0.5) and bev_of_manifest({"sensors": []}) is None


@pytest.fixture(scope="module")
def small_tcp(bev64):
    """(model, first sample's obs, params of a seed-0 init) of SMALL_TCP."""
    import jax
    import jax.numpy as jnp

    from drivee2e_jax.models.registry import get_model

    model = get_model("tcp", **SMALL_TCP)
    obs = jax.tree_util.tree_map(jnp.asarray, DemoDataset(bev64).first().obs)
    return model, obs, jax.jit(model.init)(jax.random.PRNGKey(0), obs)


def _save_tcp_checkpoint(run, params, **meta):
    from drivee2e_jax.models import checkpoint

    checkpoint.save(run, 1, {"params": params}, {"model": "tcp", "model_config": SMALL_TCP, **meta})


def test_policy_is_evaluated_at_its_training_bev(bev64, small_tcp, tmp_path):
    import jax

    from drivee2e_jax.eval.closedloop import with_policy_sensors
    from drivee2e_jax.observe import sensors
    from drivee2e_jax.observe.bev import BevConfig
    from drivee2e_jax.sim import SimConfig

    ds = DemoDataset(bev64)
    model, obs, params = small_tcp
    _save_tcp_checkpoint(tmp_path / "run", params, config={"data": str(bev64)}, data_digest=ds.digest)
    pol = base.policy_from_checkpoint("tcp", tmp_path / "run", "traj")
    assert pol.sensor_config.bev == ds.bev and pol.model == model
    jax.tree_util.tree_map(np.testing.assert_array_equal, pol.init(None, obs), params)  # restored
    assert with_policy_sensors(SimConfig(), pol).sensors.bev == ds.bev
    assert with_policy_sensors(SimConfig(sensors=sensors.SensorConfig(bev=ds.bev)), pol).sensors.bev == ds.bev
    with pytest.raises(DriveE2EError, match=r"SimConfig.sensors.bev is 128x128 at 0.5 m/px but the policy was "
                                            r"trained on 64x64 at 1 m/px"):
        with_policy_sensors(SimConfig(sensors=sensors.SensorConfig(bev=BevConfig())), pol)

    # The BEV stored with the checkpoint wins; one the model cannot read is refused.
    _save_tcp_checkpoint(tmp_path / "bad", params, data_bev={"height": 48, "width": 48, "resolution": 1.0})
    with pytest.raises(DriveE2EError, match=r"bad \(its training data\): BEV 48x48 at 1 m/px does not fit"):
        base.policy_from_checkpoint("tcp", tmp_path / "bad")
    # Training data that is gone or changed: unknown, the simulator's BEV.
    _save_tcp_checkpoint(tmp_path / "gone", params, config={"data": str(tmp_path / "nowhere")})
    assert base.policy_from_checkpoint("tcp", tmp_path / "gone").sensor_config is None
    _save_tcp_checkpoint(tmp_path / "changed", params, config={"data": str(bev64)}, data_digest="0" * 64)
    assert base.policy_from_checkpoint("tcp", tmp_path / "changed").sensor_config is None
    with pytest.raises(DriveE2EError, match="a 'tcp' checkpoint, expected a 'ad_mlp' one"):
        base.policy_from_checkpoint("ad_mlp", tmp_path / "run")


def test_model_policy_without_parameters_draws_a_random_init(small_tcp):
    import jax

    model, obs, params = small_tcp
    pol = base.policy_from_checkpoint("tcp", None, "fused", name="tcp", **SMALL_TCP)
    assert pol.params is None and pol.sensor_config is None and pol.model == model
    got = jax.jit(pol.init)(jax.random.PRNGKey(0), obs)
    jax.tree_util.tree_map(np.testing.assert_array_equal, got, params)  # model.init with the same key
    other = jax.jit(pol.init)(jax.random.PRNGKey(1), obs)
    assert not all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(other),
                                                         jax.tree_util.tree_leaves(params)))


def test_build_refuses_a_folder_holding_other_files(tmp_path):
    from drivee2e_jax.train.dataset import build_dataset

    out = tmp_path / "demos"
    out.mkdir()
    (out / "manifest.json").write_text("{}")
    (out / "notes.md").write_text("the user's")
    with pytest.raises(DriveE2EError, match=rf"^{out}: holds files drivee2e did not write \(notes.md\)"):
        build_dataset("tiny", "train", out)
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "notes.md"]
