"""The sensor registry: a toy sensor registered here renders into the
observation, the episode trace, the HTML player and the MCAP export."""

from __future__ import annotations

import base64
import dataclasses
import io
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from mcap.reader import make_reader
from PIL import Image

from drivee2e_jax.eval import traces as episodes
from drivee2e_jax.eval.bench import BenchConfig, run_bench
from drivee2e_jax.io import mcap_export as mx
from drivee2e_jax.observe import registry, sensors
from drivee2e_jax.observe.sensor_api import Sensor, SensorBase, SensorContext, SensorFrames
from drivee2e_jax.scenario.pack import pack
from drivee2e_jax.sim import SimConfig, Simulator
from drivee2e_jax.viz import payload

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "drivee2e_jax" / "scenario" / "examples" / "tiny"


@dataclasses.dataclass(frozen=True)
class GaugeConfig:
    size: int = 4
    scale: float = 10.0


class Gauge(SensorBase):
    """A toy image sensor: a (size, size) square filled with speed / scale,
    plus a noise sample from its own key."""

    name = "gauge"
    display = "image"

    def default_config(self) -> GaugeConfig:
        return GaugeConfig()

    def render(self, ctx: SensorContext, cfg: GaugeConfig):
        level = jnp.clip(ctx.ego.speed / cfg.scale, 0.0, 1.0)
        return jnp.full((cfg.size, cfg.size), level, jnp.float32)

    def image(self, frame, cfg: GaugeConfig) -> np.ndarray:
        v = np.round(np.asarray(frame, np.float64) * 255).astype(np.uint8)
        return np.repeat(v[..., None], 3, axis=-1)


class Beacon(SensorBase):
    """A toy point-cloud sensor: one point 5 m ahead of the ego, class 1."""

    name = "beacon"
    display = "pointcloud"

    def default_config(self):
        return ()

    def render(self, ctx: SensorContext, cfg):
        return jnp.array([[5.0, 0.0, 0.0]], jnp.float32)

    def points(self, frame, cfg):
        return np.asarray(frame, np.float32), np.ones(len(frame), np.int64)


@pytest.fixture
def toys():
    gauge, beacon = registry.register(Gauge()), registry.register(Beacon())
    yield gauge, beacon
    registry.unregister("gauge")
    registry.unregister("beacon")


def test_builtins_and_registration_rules(toys):
    assert registry.names()[:2] == ("bev", "lidar") and {"gauge", "beacon"} <= set(registry.names())
    assert isinstance(registry.get("gauge"), Sensor)
    assert registry.get("bev").display == "image" and registry.get("lidar").display == "pointcloud"
    with pytest.raises(ValueError, match="already registered"):
        registry.register(Gauge())
    with pytest.raises(ValueError, match="display must be one of"):
        registry.register(type("Bad", (SensorBase,), {"name": "bad", "display": "hologram"})())
    with pytest.raises(ValueError, match="reserved"):
        registry.register(type("Scene", (SensorBase,), {"name": "scene"})())
    with pytest.raises(ValueError, match="built in"):
        registry.unregister("bev")
    with pytest.raises(ValueError, match="unknown sensor 'nope'"):
        registry.get("nope")


def test_sensor_config_turns_a_registered_sensor_on(toys):
    cfg = sensors.SensorConfig.for_policy(("gauge", "lidar"))
    assert cfg.enabled == ("lidar", "gauge") and cfg.get("gauge") == GaugeConfig() and cfg.bev is None
    assert not cfg.needs_raster and hash(cfg) == hash(sensors.SensorConfig.for_policy(("lidar", "gauge")))
    assert cfg.with_sensor("gauge", None).enabled == ("lidar",)
    with pytest.raises(ValueError, match="unknown sensor"):
        sensors.SensorConfig(others=(("nope", GaugeConfig()),))


def test_a_registered_sensor_lands_in_the_observation(toys, tiny_suite):
    packed = pack(tiny_suite.scenarios, tiny_suite.maps)
    scn = jax.tree_util.tree_map(jnp.asarray, packed.scenario)
    cfg = sensors.SensorConfig.for_policy(("gauge",), sensors.SensorConfig(others=(("gauge", GaugeConfig(size=3)),)))
    sim = Simulator(SimConfig(sensors=cfg))
    keys = jax.random.split(jax.random.PRNGKey(0), len(packed))
    state, obs = jax.jit(jax.vmap(sim.reset))(keys, scn)
    assert obs.bev is None and obs.lidar is None and set(obs.sensors) == {"gauge"}
    got = np.asarray(obs.sensors["gauge"])
    assert got.shape == (len(packed), 3, 3)
    want = np.clip(np.asarray(state.ego.speed) / 10.0, 0, 1)
    np.testing.assert_allclose(got[:, 0, 0], want, rtol=1e-6)
    # Every sensor gets its own key, and without sensors nothing changes.
    ctx_key = jax.random.PRNGKey(3)
    ctx = SensorContext(scenario=None, ego=None, ego_lw=None, agents=None, stop_state=None, key=ctx_key)
    assert not np.array_equal(np.asarray(ctx.for_sensor("gauge").key), np.asarray(ctx.for_sensor("beacon").key))
    _, plain = jax.jit(jax.vmap(Simulator(SimConfig()).reset))(keys, scn)
    assert plain.sensors is None


def _fake_trace(n: int = 5):
    """Just what the player's sensor panes and the MCAP sensor topics read."""
    return type("T", (), {
        "times": np.arange(n) * 0.1, "dt": 0.1, "scenario_id": "s0", "bev": None, "lidar_points": None,
        "sensors": {"gauge": SensorFrames(GaugeConfig(size=2), np.linspace(0, 1, n)[:, None, None] * np.ones((n, 2, 2))),
                    "beacon": SensorFrames((), np.tile([[[5.0, 0.0, 0.0]]], (n, 1, 1)).astype(np.float32))},
    })()


def test_player_panes_follow_the_display(toys):
    panes = {p["name"]: p for p in payload.sensor_panes(_fake_trace(), 2, 1, 100)}
    img = panes["gauge"]
    assert img["display"] == "image" and img["stride"] == 2 and len(img["frames"]) == 3
    rgb = np.asarray(Image.open(io.BytesIO(base64.b64decode(img["frames"][2].split(",", 1)[1]))).convert("RGB"))
    assert rgb.shape == (2, 2, 3) and (rgb == 255).all()
    pc = panes["beacon"]
    assert pc["display"] == "pointcloud" and len(pc["frames"]) == 5
    xy = np.frombuffer(base64.b64decode(pc["frames"][0]["xy"]), "<i2").reshape(-1, 2) * pc["scale"]
    np.testing.assert_allclose(xy, [[5.0, 0.0]])


def test_mcap_topics_follow_the_display(toys):
    tr = _fake_trace()
    assert mx.topics(tr)["/s0/gauge"] == "foxglove.CompressedImage"
    assert mx.topics(tr)["/s0/beacon"] == "foxglove.PointCloud"
    img = mx.sensor_message(tr, "gauge", 4, 7)
    rgb = np.asarray(Image.open(io.BytesIO(img.data)).convert("RGB"))
    assert img.format == "png" and (rgb == 255).all()
    cloud = mx.sensor_message(tr, "beacon", 0, 7)
    pts = np.frombuffer(cloud.data, mx._POINT_DTYPE)
    assert pts["x"].tolist() == [5.0] and pts["class"].tolist() == [1]


def test_a_registered_sensor_is_traced_shown_and_exported(toys, tmp_path):
    out = tmp_path / "run"
    run_bench(BenchConfig(suite=str(TINY), split="train", policies=(str(REPO / "drivee2e_jax" / "zoo" / "constant_velocity.py"),),
                          out=out, limit=1, progress=False), print_fn=lambda s: None)
    (tr,) = episodes.trace_episodes(out, sensors=("gauge", "beacon"))
    assert tr.reproduced and tr.bev is None and tr.lidar_points is None
    frames = tr.sensors["gauge"].frames
    assert frames.shape == (tr.num_steps, 4, 4)
    np.testing.assert_allclose(frames[:, 0, 0], np.clip(tr.ego_speed / 10.0, 0, 1), rtol=1e-6)
    ep, _, _ = payload.episode_payload(tr)
    assert [p["name"] for p in ep["sensors"]] == ["gauge", "beacon"]
    path = mx.write_mcap([tr], tmp_path / "e.mcap")
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
    counts = {c.topic: summary.statistics.channel_message_counts[i] for i, c in summary.channels.items()}
    p = f"/{tr.scenario_id}"
    assert topics[f"{p}/gauge"] == "foxglove.CompressedImage" and topics[f"{p}/beacon"] == "foxglove.PointCloud"
    assert counts[f"{p}/gauge"] == counts[f"{p}/beacon"] == tr.num_steps
    assert json.loads(json.dumps(ep["sensors"]))  # plain JSON
