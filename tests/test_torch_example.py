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


def _docs_snippet() -> str:
    """The ``# my_torch_policy.py`` block of docs/host_policies.md, as written."""
    text = (REPO / "docs" / "host_policies.md").read_text()
    start = text.index("```python\n# my_torch_policy.py") + len("```python\n")
    return text[start:text.index("```", start)]


ROUTE_HEAD = """
import sys, torch
class RouteHead(torch.nn.Module):  # ego-frame route (B, P, 2) -> the points 2, 4, 6, 8 m ahead
    def forward(self, route):
        return route[:, 2:10:2, :]
torch.jit.script(RouteHead()).save(sys.argv[1])
"""


def test_the_policy_written_from_the_docs_runs_everywhere_and_a_broken_one_is_one_line(tmp_path):
    """Issue 39: the PyTorch snippet of docs/host_policies.md (it observes only
    ``("route",)``) passes check-policy, benches in process and served with
    the same rows; a bug in its ``act`` is one line naming its file:line in
    process and from the server."""
    import subprocess
    import sys

    from drivee2e_jax.errors import DriveE2EError
    from drivee2e_jax.testing import check_policy_file

    snippet = _docs_snippet()
    assert 'observation_fields = ("route",)' in snippet
    good, ckpt = tmp_path / "my_torch_policy.py", tmp_path / "model.pt"
    good.write_text(snippet)
    (tmp_path / "make_checkpoint.py").write_text(ROUTE_HEAD)  # TorchScript reads the module's source file
    subprocess.run([sys.executable, str(tmp_path / "make_checkpoint.py"), str(ckpt)], check=True, timeout=120)
    spec = f"{good}:checkpoint={ckpt}"
    report = check_policy_file(spec, batch=2, steps=2)
    assert report.ok, [str(p) for p in report]
    local = evaluate(load_policy(spec), load_suite("twin15"), "val", limit=2)
    with serve_policy(spec, tmp_path) as server:
        remote = evaluate(load_policy(server.remote), load_suite("twin15"), "val", limit=2)
    strip = lambda rows: [{k: v for k, v in r.items() if k not in SKIP} for r in rows]  # noqa: E731
    assert strip(remote.rows) == strip(local.rows) and local.rows[0]["route_completion"] > 50.0

    line = "            xy = self.net(x)                                        # (B, 4, 2)\n"
    assert line in snippet
    broken = tmp_path / "broken_policy.py"
    broken.write_text(snippet.replace(line, "            xy = self.net(x)[:, :, 5]\n"))
    lineno = snippet[:snippet.index(line)].count("\n") + 1
    bad = f"{broken}:checkpoint={ckpt}"
    with pytest.raises(DriveE2EError) as in_process:
        evaluate(load_policy(bad), load_suite("twin15"), "val", limit=2)
    with serve_policy(bad, tmp_path) as server, pytest.raises(DriveE2EError) as served:
        evaluate(load_policy(server.remote), load_suite("twin15"), "val", limit=2)
    for err in (in_process.value, served.value):
        assert "\n" not in str(err) and f"{broken}:{lineno}" in str(err) and "IndexError" in str(err), str(err)
