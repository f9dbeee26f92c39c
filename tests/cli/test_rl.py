"""`drivee2e rl`: bad input is one line and exit code 2, before anything compiles.

The command's examples (a run from scratch, fine-tuning from an imitation run,
--resume, bench and trend on the PPO run) run in tests/cli/test_help_examples.py;
PPO itself in tests/train/test_ppo.py.
"""

from __future__ import annotations

import pytest

from drivee2e_jax.cli import main
from drivee2e_jax.cli.rl import parse_kv


@pytest.mark.parametrize(("argv", "message"), [
    (["--reward", "comfrt=1"], "--reward: bad item 'comfrt=1' (expected k=v with k in at_fault_only, collision_layout"),
    (["--reward", "comfort=lots"], "--reward: comfort='lots' is not a float"),
    (["--reward", "outside_lanes=maybe"], "--reward: outside_lanes='maybe' is not a bool"),
    (["--model-config", "hidden=ax2", "--model", "ad_mlp"], "--model-config: hidden='ax2' is not a widths"),
    (["--model-config", "depth=3"], "--model-config: bad item 'depth=3'"),
    (["--envs", "0"], "ppo: num_envs must be >= 1, got 0"),
    (["--envs", "3", "--rollout-steps", "3"], "ppo: minibatches (4) must divide envs x rollout steps (3 x 3)"),
    (["--gamma", "1.5"], "ppo: gamma and gae_lambda must lie in [0, 1]"),
    (["--model", "resnet"], "--model resnet: unknown model"),
    (["--init", "runs/none"], "runs/none: no checkpoint found"),
])
def test_bad_input_is_one_line(tmp_path, capsys, argv, message):
    code = main(["rl", "--out", str(tmp_path / "run"), "--no-progress", *argv])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert err.startswith("drivee2e: error: ") and message in err, err
    assert "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_parse_kv_types():
    fields = {"a": float, "b": bool, "c": int}
    assert parse_kv(" a=0.5, b=false ,c=3", "--x", fields) == {"a": 0.5, "b": False, "c": 3}
    assert parse_kv("a=none", "--x", fields) == {"a": None}
    assert parse_kv("", "--x", fields) == {}
