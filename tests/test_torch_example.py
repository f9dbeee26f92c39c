"""The PyTorch host-policy example (docs/examples/torch_policy.py) drives, in
process and served by ``drivee2e serve-policy`` (without JAX), with the same
rows. PyTorch is optional (not a dependency; CI does not install it): these
tests skip when it is absent."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.policy import load_policy
from drivee2e_jax.scenario import load_suite
from tests.helpers.host_policies import make_observation, meta_rows, serve_policy

pytestmark = pytest.mark.skipif(importlib.util.find_spec("torch") is None,
                                reason="PyTorch is not installed (optional, not a dependency: pip install torch)")

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "docs" / "examples" / "torch_policy.py"
LIMIT = 4  # twin15 val scenarios
SKIP = {"policy", "eval_time_s"}  # wall-clock and naming columns


def _module():
    spec = importlib.util.spec_from_file_location("torch_policy_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def in_process():
    """The route follower on LIMIT twin15 val scenarios, checking every action it returns."""
    pol = load_policy(EXAMPLE)
    seen = []
    act = pol.act

    def checked_act(obs, state):
        action, state = act(obs, state)
        seen.append((action.xy.shape, action.xy.dtype, bool(np.isfinite(action.xy).all())))
        return action, state

    pol.act = checked_act
    return evaluate(pol, load_suite("twin15"), "val", limit=LIMIT), seen


def test_route_follower_completes_twin15_scenarios_with_finite_actions(in_process):
    res, seen = in_process
    assert len(res.rows) == LIMIT and res.rows[0]["policy"] == "torch_route_follow"
    assert seen and all(s == ((LIMIT, 6, 2), np.float32, True) for s in seen), seen[:3]
    for row in res.rows:
        assert row["invalid_action"] == 0, row
        assert row["route_completion"] > 50.0, (row["scenario_id"], row["route_completion"], row["status"])


def test_served_torch_policy_gives_the_in_process_rows(in_process, tmp_path):
    res, _ = in_process
    with serve_policy(str(EXAMPLE), tmp_path) as server:  # JAX and Flax blocked in the server
        remote = evaluate(load_policy(server.remote), load_suite("twin15"), "val", limit=LIMIT)
    assert [r["scenario_id"] for r in remote.rows] == [r["scenario_id"] for r in res.rows]
    for a, b in zip(res.rows, remote.rows):
        assert {k: v for k, v in a.items() if k not in SKIP} == {k: v for k, v in b.items() if k not in SKIP}
    assert remote.events == res.events


def test_mlp_weights_round_trip_and_features(tmp_path):
    m = _module()
    obs = make_observation(batch=3)
    assert tuple(m.features(obs).shape) == (3, m.NUM_FEATURES)
    random_net = m.make_policy(mode="mlp", seed=3)
    assert random_net.name == "torch_mlp"
    path = m.save_weights(random_net.net, tmp_path / "mlp.pt")
    loaded = load_policy(EXAMPLE, mode="mlp", weights=str(path))
    a, _ = random_net.act(obs, random_net.reset(meta_rows(3)))
    b, _ = loaded.act(obs, loaded.reset(meta_rows(3)))
    assert a.xy.shape == (3, 6, 2) and a.xy.dtype == np.float32
    np.testing.assert_array_equal(a.xy, b.xy)
    c, _ = m.make_policy(mode="mlp", seed=3).act(obs, None)  # the seed fixes the random init
    np.testing.assert_array_equal(a.xy, c.xy)
    with pytest.raises(ValueError, match="mode="):
        m.make_policy(mode="nope")


def test_mlp_mode_conforms_to_the_policy_interface():
    from drivee2e_jax.testing import check_policy_file

    report = check_policy_file(f"{EXAMPLE}:mode=mlp", batch=2, steps=2)
    assert report.ok, [str(p) for p in report]
    assert report.summary.startswith("torch_mlp: host policy, Waypoints xy (B, 6, 2) float32, waypoint_dt 0.5 s")
