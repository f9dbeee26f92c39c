"""The checked-in example suite and the quickstart notebook stay true."""

from __future__ import annotations

import filecmp
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

from drivee2e_jax.scenario.schema import write_suite
from tests.helpers.tiny_suite import build_tiny_suite

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "drivee2e_jax" / "scenario" / "examples" / "tiny"


def _same_tree(a: Path, b: Path) -> list[str]:
    cmp = filecmp.dircmp(a, b)
    diff = [str(a / n) for n in cmp.left_only + cmp.right_only + cmp.diff_files + cmp.funny_files]
    for sub in cmp.common_dirs:
        diff += _same_tree(a / sub, b / sub)
    return diff


def test_example_suite_matches_the_test_fixture(tmp_path):
    fresh = write_suite(build_tiny_suite(), tmp_path / "tiny")
    assert _same_tree(EXAMPLE, Path(fresh)) == [], "regenerate drivee2e_jax/scenario/examples/tiny from tests/helpers/tiny_suite.py"


def test_example_suite_validates(capsys):
    from drivee2e_jax.cli import main

    assert main(["suite", "validate", str(EXAMPLE)]) == 0


def _run_notebook(name: str, tmp_path: Path, **settings: str) -> str:
    """Execute ``notebooks/<name>.py`` with ``settings`` as environment
    variables (its own cache unless one is set); returns its stdout."""
    env = dict(os.environ, DRIVEE2E_CACHE=os.environ.get("DRIVEE2E_CACHE", str(tmp_path / "cache")), **settings)
    proc = subprocess.run(
        [sys.executable, str(ROOT / "notebooks" / f"{name}.py")], capture_output=True, text=True, env=env, timeout=900
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_quickstart_notebook_runs(tmp_path):
    out = _run_notebook("quickstart", tmp_path, DRIVEE2E_QUICKSTART_SUITE=str(EXAMPLE),
                        DRIVEE2E_QUICKSTART_SPLIT="train", DRIVEE2E_QUICKSTART_LIMIT="2")
    for name in ("log_replay", "expert", "stop"):
        assert name in out
    assert "2 scenarios in split 'train'" in out
    assert "events:" in out and "mean speed per episode" in out
    assert "scenarios.csv" in out and "summary.json" in out
    assert "states, ego at t=0" in out and "player.html" in out


def test_own_policy_notebook_runs(tmp_path):
    out = _run_notebook("own_policy", tmp_path, DRIVEE2E_OWN_POLICY_SUITE=str(EXAMPLE),
                        DRIVEE2E_OWN_POLICY_SPLIT="train", DRIVEE2E_OWN_POLICY_LIMIT="2")
    assert "loaded route_follower -> waypoints" in out
    assert "waypoints (2, 6, 2)" in out
    for name in ("route_follower", "expert", "stop"):
        assert f"{name} " in out and "(2 episodes)" in out
    assert "episode status:" in out


def test_trend_notebook_runs(tmp_path):
    out = _run_notebook("trend", tmp_path, DRIVEE2E_TREND_SUITE=str(EXAMPLE), DRIVEE2E_TREND_TRAIN_SPLIT="train",
                        DRIVEE2E_TREND_EVAL_SPLIT="train", DRIVEE2E_TREND_LIMIT="2", DRIVEE2E_TREND_EPOCHS="2")
    assert "trained 2 epochs" in out and "checkpoints: ['1', '2']" in out
    rows = [ln.split() for ln in out.splitlines() if ln.strip()[:1] in ("1", "2") and len(ln.split()) == 5]
    assert [r[0] for r in rows] == ["1", "2"]  # one trend row per checkpoint, in epoch order
    assert "trend.csv columns: ['checkpoint', 'epoch'" in out and "lowest L2@2s at epoch" in out


@pytest.mark.skipif(importlib.util.find_spec("torch") is None,
                    reason="PyTorch is not installed (optional, not a dependency: pip install torch)")
def test_torch_policy_notebook_runs(tmp_path):
    out = _run_notebook("torch_policy", tmp_path, DRIVEE2E_TORCH_SUITE=str(EXAMPLE), DRIVEE2E_TORCH_SPLIT="train",
                        DRIVEE2E_TORCH_LIMIT="2", DRIVEE2E_TORCH_STEPS="50")
    assert "loaded torch_route_follow -> waypoints (6 waypoints, 0.5 s apart)" in out
    for name in ("torch_route_follow", "stop", "torch_mlp"):
        assert f"{name} " in out and "(2 episodes)" in out
    assert "(features, waypoints) pairs" in out and "loaded torch_mlp from torch_mlp.pt" in out
    assert "serving torch_route_follow (waypoints)" in out and "remote rows == in-process rows: True" in out


def test_public_evaluate_stays_a_function_after_its_module_is_imported():
    import drivee2e_jax as de
    import drivee2e_jax.eval.closedloop  # noqa: F401  (a submodule import must not shadow de.evaluate)

    assert callable(de.evaluate)
    assert de.evaluate.__name__ == "evaluate"
