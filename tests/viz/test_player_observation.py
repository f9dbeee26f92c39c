"""The episode player shows what the policy saw: a traced BEV frame equals,
bit for bit, the packed BEV the policy received at that step (oracle: a
separate ``Rollout.run`` of the same policy, whose recurrent state records
every observation it is given), at the policy's own BEV size and route
window, on the tiny suite of ``tests/helpers/tiny_suite.py``."""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
import pytest

from drivee2e_jax.eval import traces as episodes
from drivee2e_jax.eval.bench import BenchConfig, run_bench

# A recording policy: drives straight on at a fixed throttle; its recurrent
# state is (the number of calls, every packed BEV it received in call order).
# Its k-th call reads the observation of state k (the first ``act`` of
# ``Rollout.init`` only probes the action type: its state is dropped). ``kind`` picks its sensor config:
# "bev64" = a 64 x 64 BEV (not the default 128: as a policy trained on
# `drivee2e dataset build --bev-size 64`) with a 16-point route window (the
# tiny routes have <= 96 points, so the default window would draw the whole
# route), "blind" = no sensor at all (same driving, so the same trajectory).
POLICY_FILE = '''
import jax.numpy as jnp
from drivee2e_jax.observe.bev import BevConfig
from drivee2e_jax.observe.sensors import SensorConfig
from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls

BEV64 = BevConfig(height=64, width=64, route_points=16, route_behind=4)
BEVS = {"bev64": BEV64}
MAX_STEPS = 64


class Recorder(StatelessPolicy):
    action_type = "controls"

    def __init__(self, kind):
        self.name = f"rec_{kind}"
        self.required_sensors = ("bev",) if kind in BEVS else ()
        self.sensor_config = SensorConfig(bev=BEVS[kind]) if kind in BEVS else None

    def initial_state(self, obs):
        if not self.required_sensors:
            return None
        return jnp.zeros((), jnp.int32), jnp.zeros((MAX_STEPS,) + obs.bev.shape, obs.bev.dtype)

    def act(self, params, obs, state, key):
        z = jnp.zeros((), jnp.float32)
        if self.required_sensors:
            k, seen = state
            state = k + 1, seen.at[k].set(obs.bev)  # out of range (k >= MAX_STEPS): dropped
        return Controls(throttle=z + 0.4, brake=z, steer=z), state


def make_policy(kind="bev64"):
    return Recorder(kind)
'''
KINDS = ("bev64", "blind")
#: The recorder's BEV (as in POLICY_FILE).
BEV64 = {"height": 64, "width": 64, "route_points": 16, "route_behind": 4}


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """(results folder of the two recorders on the tiny suite's train split,
    the policy file, the suite folder)."""
    from drivee2e_jax.scenario.schema import write_suite
    from tests.helpers.tiny_suite import build_tiny_suite

    root = tmp_path_factory.mktemp("player_obs")
    suite = write_suite(build_tiny_suite(), root / "tiny")
    pol = root / "recorder.py"
    pol.write_text(POLICY_FILE)
    run = root / "run"
    cfg = BenchConfig(suite=str(suite), split="train", policies=(str(pol),) * len(KINDS),
                      policy_kwargs=tuple({"kind": k} for k in KINDS), out=run, progress=False)
    run_bench(cfg, print_fn=lambda s: None)
    return run, pol, suite


def _seen(pol_file: Path, suite_dir: Path, kind: str) -> np.ndarray:
    """(MAX_STEPS, B, H, W) int32: the packed BEV the policy received at
    steps 0, 1, ... of an independent rollout of the bench's split (after an
    episode ends its state is frozen, so later rows repeat the last one)."""
    import jax

    from drivee2e_jax.eval.closedloop import device_batch, init_params, with_policy_sensors
    from drivee2e_jax.metrics.driving_score import score_preset
    from drivee2e_jax.observe import sensors
    from drivee2e_jax.policy import load_policy
    from drivee2e_jax.rollout import Rollout
    from drivee2e_jax.scenario import load_suite
    from drivee2e_jax.sim import SimConfig, Simulator

    pol = load_policy(pol_file, kind=kind)
    s = load_suite(str(suite_dir))
    packed = s.pack("train")
    cfg = with_policy_sensors(SimConfig(dt=0.1, score=score_preset("paper")), pol)
    assets = sensors.build_assets(packed, cfg.sensors, s.maps)
    batch, _ = device_batch(packed)
    sim = Simulator(cfg)
    key = jax.random.PRNGKey(0)
    carry, _ = Rollout(sim, pol, init_params(pol, sim, batch, key, assets), assets=assets).run(batch, key)
    count, seen = carry.policy_state
    assert np.all(np.asarray(count) > 0)
    return np.swapaxes(np.asarray(seen), 0, 1)


def _packed(trace) -> np.ndarray:
    """(T, H, W) int32 the trace's BEV channels packed as ``observe.bev`` packs them."""
    return sum(trace.bev[c].astype(np.int32) << i for i, c in enumerate(trace.bev))


@pytest.fixture(scope="module")
def traced(setup):
    """(the bev64 recorder's traces, (steps, B, H, W) what it saw)."""
    run, pol, suite = setup
    traces = episodes.trace_episodes(run, "rec_bev64", sensors=("bev",))
    return traces, _seen(pol, suite, "bev64")


def test_every_traced_bev_frame_is_the_policys_observation(traced):
    traces, seen = traced
    assert len(traces) == 2
    for j, t in enumerate(traces):
        assert t.reproduced
        assert t.bev["route"].shape == (t.num_steps, 64, 64) and t.bev_resolution == 0.5
        np.testing.assert_array_equal(_packed(t), seen[: t.num_steps, j])
        assert np.any(t.bev["route"]) and np.any(t.bev["ego"])
        assert t.ego_speed[-1] > 3.0  # the ego drove on: its route window moved


def test_the_player_pictures_are_the_policys_observation(traced):
    """The PNG frames of the HTML player decode to the composite of the
    observation the policy received."""
    from PIL import Image

    from drivee2e_jax.observe.bev import BevConfig, unpack_bits
    from drivee2e_jax.viz import encode, payload

    traces, seen = traced
    t = traces[1]
    channels = BevConfig().channel_names
    assert tuple(t.bev) == channels
    pane = payload.bev_payload(t, 1)
    sheet = np.asarray(Image.open(io.BytesIO(base64.b64decode(pane["sheet"].split(",", 1)[1]))).convert("RGB"))
    h = pane["h"]
    assert pane["count"] == t.num_steps and sheet.shape[0] == h * t.num_steps
    for k in (0, t.num_steps // 2, t.num_steps - 1):
        img = sheet[k * h: (k + 1) * h]  # frame k of the sprite sheet
        want = encode.composite_bev(np.asarray(unpack_bits(seen[k, 1], len(channels))), channels)
        np.testing.assert_array_equal(img, want)


def test_a_policy_without_a_bev_gets_the_trace_bev_with_the_same_route_window(setup, traced):
    """The blind recorder drives as the bev64 one: rendered at the trace's
    BEV (here that same config), its frames are what bev64 saw."""
    from drivee2e_jax.observe.bev import BevConfig
    from drivee2e_jax.observe.sensors import SensorConfig

    run, _, _ = setup
    traces, seen = traced
    cfg = SensorConfig(bev=BevConfig(**BEV64))
    blind = episodes.trace_episodes(run, "rec_blind", sensor_config=cfg)
    for j, t in enumerate(blind):
        np.testing.assert_array_equal(t.ego_xy, traces[j].ego_xy)
        np.testing.assert_array_equal(_packed(t), seen[: t.num_steps, j])
    # A blind policy's default trace BEV: 128 px; a BEV policy's own config wins over sensor_config.
    assert episodes.trace_bev_sensors(SensorConfig(), episodes.default_sensor_config()).bev == BevConfig()
    assert episodes.trace_bev_sensors(cfg, episodes.default_sensor_config()).bev == cfg.bev


def test_the_player_page_of_a_policy_at_a_non_default_bev_size(traced, tmp_path):
    """What `drivee2e view` writes from these traces (the command itself is
    ``trace_episodes`` + ``write_player``; run on a real folder in docs/visual.md)."""
    from drivee2e_jax.viz.player import write_player

    traces, _ = traced
    out = tmp_path / "p.html"
    write_player(traces, out, title="bev64")
    assert out.stat().st_size > 10_000
