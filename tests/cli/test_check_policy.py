"""`drivee2e check-policy`: ok lines and exit 0, one line per problem and
exit 1, one-line errors and exit 2 for unloadable files and bad arguments."""

from __future__ import annotations

from drivee2e_jax.cli import main
from drivee2e_jax.policy import reference_policy_dir

SMALL = ["--batch", "2", "--steps", "2"]
HOST_EXAMPLE = reference_policy_dir().parents[1] / "docs" / "examples" / "numpy_constant_velocity.py"

BAD = """\
import jax.numpy as jnp

from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls


class P(StatelessPolicy):
    name = "bad"
    action_type = "controls"

    def act(self, params, obs, state, key):
        return Controls(throttle=jnp.zeros((2,), jnp.float32), brake=jnp.zeros((), jnp.int32),
                        steer=jnp.zeros((), jnp.float32)), state


policy = P()
"""


def test_conformant_policies_exit_0(capsys):
    code = main(["check-policy", "stop", str(HOST_EXAMPLE), *SMALL])
    out = capsys.readouterr().out.splitlines()
    assert code == 0, out
    assert len(out) == 2
    assert out[0].startswith("ok: ") and "drivee2e_jax/zoo/stop.py (stop: JAX policy, Controls" in out[0]
    assert out[1].startswith(f"ok: {HOST_EXAMPLE} (np_constant_velocity: host policy, Waypoints xy (B, 6, 2) float32")


def test_problems_exit_1_one_line_each(tmp_path, capsys):
    bad = tmp_path / "bad.py"
    bad.write_text(BAD)
    code = main(["check-policy", str(bad), "stop", *SMALL])
    out = capsys.readouterr().out.splitlines()
    assert code == 1, out
    problems = [line for line in out if not line.startswith("ok: ")]
    assert len(problems) == 2 and all(line.startswith(f"{bad}: ") for line in problems)
    assert "action Controls.throttle has shape (2,)" in problems[0]
    assert "action Controls.brake has dtype int32" in problems[1]
    assert out[-1].startswith("ok: ") and "stop" in out[-1]


def test_unloadable_files_and_usage_errors_exit_2(tmp_path, capsys):
    assert main(["check-policy", str(tmp_path / "missing.py")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("drivee2e: error: ") and "policy file not found" in err and "\n" not in err
    assert main(["check-policy", "stop:colour=red"]) == 2
    assert "make_policy" in capsys.readouterr().err
    assert main(["check-policy", "stop", "--batch", "0"]) == 2
    assert "--batch 0" in capsys.readouterr().err
    assert main(["check-policy"]) == 2
    assert main(["check-policy", "stop", "--suite", str(tmp_path / "nowhere")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_help_has_examples(capsys):
    assert main(["check-policy", "--help"]) == 0
    out = capsys.readouterr().out
    assert "examples:" in out and "drivee2e check-policy my_policy.py" in out
