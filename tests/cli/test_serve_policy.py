"""`drivee2e serve-policy`: user errors are one line on stderr, exit code 2."""

from __future__ import annotations

import pytest
import zmq

from drivee2e_jax.cli import main
from tests.helpers.host_policies import write_tiny_policy


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("drivee2e: error: ") and "\n" not in err, err
    return err


@pytest.mark.parametrize("body, expected", [
    ("policy = 3\n", "expected a drivee2e_jax.hostapi.HostPolicy"),
    ("class P:\n    name = 'p'\n    action_type = 'controls'\n    def init(self, k, o): ...\n"
     "    def initial_state(self, o): ...\n    def act(self, *a): ...\npolicy = P()\n", "a JAX policy"),
])
def test_not_a_host_policy(tmp_path, capsys, body, expected):
    path = tmp_path / "jaxy.py"
    path.write_text(body)
    assert main(["serve-policy", str(path), "--port", "0"]) == 2
    assert expected in _error_line(capsys)


def test_bad_arguments(tmp_path, capsys):
    good = write_tiny_policy(tmp_path)
    assert main(["serve-policy", str(good), "--port", "70000"]) == 2
    assert "--port 70000: expected a TCP port in 0..65535" in _error_line(capsys)
    assert main(["serve-policy", f"{good}:colour=red", "--port", "0"]) == 2
    assert "make_policy does not take ['colour']" in _error_line(capsys)
    assert main(["serve-policy", str(tmp_path / "missing.py"), "--port", "0"]) == 2
    assert "policy file not found" in _error_line(capsys)


def test_port_in_use(tmp_path, capsys):
    good = write_tiny_policy(tmp_path)
    with zmq.Context.instance().socket(zmq.ROUTER) as busy:
        busy.setsockopt(zmq.LINGER, 0)
        port = busy.bind_to_random_port("tcp://127.0.0.1")
        assert main(["serve-policy", str(good), "--port", str(port)]) == 2
    assert f"cannot listen on tcp://127.0.0.1:{port}" in _error_line(capsys)
