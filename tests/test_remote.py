"""remote: host policies served over ZeroMQ by a `drivee2e serve-policy`
subprocess that runs with JAX and Flax blocked (loopback only, bounded waits)."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zmq

from drivee2e_jax import __version__, hostapi, remote
from drivee2e_jax.errors import DriveE2EError
from tests.helpers.host_policies import NO_JAX, REPO, make_observation, meta_rows, serve_policy, write_tiny_policy

TIMEOUT_S = 10.0


def _one_line(e: pytest.ExceptionInfo) -> str:
    msg = str(e.value)
    assert "\n" not in msg, msg
    return msg


@pytest.fixture
def policy_file(tmp_path):
    return write_tiny_policy(tmp_path)


# --------------------------------------------------------------------------
# Specs and frames (in-process)
# --------------------------------------------------------------------------


def test_parse_remote_spec():
    s = remote.parse_remote_spec("remote://127.0.0.1:5555")
    assert s == remote.RemoteSpec(address="tcp://127.0.0.1:5555", kwargs={}, name="")
    s = remote.parse_remote_spec("remote://localhost:6000:timeout_s=120,name=torch_uniad")
    assert s.address == "tcp://localhost:6000" and s.kwargs == {"timeout_s": 120.0} and s.name == "torch_uniad"
    assert remote.is_remote_spec("remote://h:1") and not remote.is_remote_spec("drivee2e_jax/zoo/expert.py")
    for bad, why in [("remote://127.0.0.1", "expected remote://HOST:PORT"), ("remote://h:99999", "port '99999'"),
                     ("remote://h:abc", "port 'abc'"), ("remote://h:5:colour=red", "unknown option 'colour=red'"),
                     ("remote://h:5:timeout_s=-1", "timeout_s='-1'"), ("tcp://h:5", "not a remote policy spec")]:
        with pytest.raises(DriveE2EError, match=why):
            remote.parse_remote_spec(bad)


def test_frames_roundtrip_every_leaf():
    obs = make_observation(2)
    items = hostapi.flatten(obs)
    frames = remote.encode({"op": "act", "id": 3, "meta": [{"n": np.int64(2)}]}, items)
    header, arrays = remote.decode([bytes(f) for f in frames])
    assert header == {"op": "act", "id": 3, "meta": [{"n": 2}]}
    assert [p for p, _ in arrays] == [p for p, _ in items]
    for (_, a), (_, b) in zip(items, arrays):
        assert a.dtype == b.dtype and a.shape == b.shape and b.flags.writeable
        np.testing.assert_array_equal(a, b)
    odd = [(("scalar",), np.float32(3.5)), (("flag",), np.array(True)), (("empty",), np.zeros((2, 0), np.int32)),
           (("transposed",), np.arange(6.0).reshape(2, 3).T)]
    _, back = remote.decode(remote.encode({}, odd))
    for (p1, a), (p2, b) in zip(odd, back):
        assert p1 == p2 and np.asarray(a).shape == b.shape and np.asarray(a).dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    with pytest.raises(remote._WireError, match="lists 1 arrays, the message has 0 buffers"):
        remote.decode([frames[0][:0] + b'{"arrays": [{"path": ["x"], "dtype": "<f4", "shape": [1]}]}'])
    with pytest.raises(remote._WireError, match="not JSON"):
        remote.decode([b"\x00garbage"])
    with pytest.raises(remote._WireError, match="only numeric and bool"):
        remote.encode({}, [(("s",), np.array(["text"]))])


# --------------------------------------------------------------------------
# A served policy (subprocess, JAX blocked)
# --------------------------------------------------------------------------


def test_round_trip_controls(policy_file, tmp_path):
    with serve_policy(str(policy_file), tmp_path) as server, \
            remote.RemotePolicy(server.remote, timeout_s=TIMEOUT_S) as pol:
        assert isinstance(pol, hostapi.HostPolicy)
        assert (pol.name, pol.action_type, pol.required_sensors) == ("tiny_controls", "controls", ("bev",))
        assert pol.server_info["protocol"] == remote.PROTOCOL_VERSION and pol.server_info["package"] == __version__
        assert pol.server_info["source"] == str(policy_file)
        state = pol.reset(meta_rows(3))
        assert isinstance(state, remote.RemoteState) and state.step == 0
        obs = make_observation(3)
        for step in range(3):
            action, state = pol.act(obs, state)
            assert isinstance(action, hostapi.Controls) and state.step == step + 1
            np.testing.assert_allclose(action.throttle, obs.ego[:, 0] + step, rtol=1e-6)  # state kept server-side
            assert np.isnan(action.brake).all()  # NaN passes: the simulator sanitises it
            expected = obs.bev.reshape(3, -1).sum(1) + obs.sensors["radar"].reshape(3, -1).sum(1)
            np.testing.assert_allclose(action.steer, expected, rtol=1e-5)
        # a second batch (another session) starts at step 0 again, and the first one carries on
        other = pol.reset(meta_rows(2))
        a2, _ = pol.act(make_observation(2, seed=1), other)
        np.testing.assert_allclose(a2.throttle, make_observation(2, seed=1).ego[:, 0], rtol=1e-6)
        a3, _ = pol.act(obs, state)
        np.testing.assert_allclose(a3.throttle, obs.ego[:, 0] + 3, rtol=1e-6)


def test_round_trip_waypoints_with_make_policy_kwargs(policy_file, tmp_path):
    with serve_policy(f"{policy_file}:kind=waypoints,name=wp", tmp_path) as server:
        pol = remote.RemotePolicy(server.address, timeout_s=TIMEOUT_S)
        try:
            assert (pol.name, pol.action_type, pol.num_waypoints, pol.waypoint_dt) == ("wp", "waypoints", 3, 0.25)
            obs = make_observation(2, bev=False, sensors=False)
            action, state = pol.act(obs, pol.reset(meta_rows(2)))
            assert isinstance(action, hostapi.Waypoints) and action.xy.dtype == np.float32
            np.testing.assert_allclose(action.xy, obs.route[:, :3])
        finally:
            pol.close()


def test_a_policy_error_is_one_line_naming_the_file_and_step(policy_file, tmp_path):
    with serve_policy(f"{policy_file}:fail_at=1", tmp_path) as server, \
            remote.RemotePolicy(server.remote, timeout_s=TIMEOUT_S) as pol:
        obs = make_observation(2)
        _, state = pol.act(obs, pol.reset(meta_rows(2)))
        with pytest.raises(DriveE2EError) as e:
            pol.act(obs, state)
        msg = _one_line(e)
        assert msg.startswith(f"remote policy at {server.address}: ")
        assert "tiny_policy.py" in msg and "step 1" in msg and "RuntimeError: kaboom at step 1" in msg
        # the policy's own file:line reaches the client (the server's traceback is not all there is)
        line = next(i for i, text in enumerate(policy_file.read_text().splitlines(), 1) if "kaboom" in text)
        assert f"{os.path.realpath(policy_file)}:{line}" in msg or f"{policy_file}:{line}" in msg, msg
        # the server keeps serving, and the traceback went to its log
        pol.act(obs, pol.reset(meta_rows(2)))
        assert "Traceback" in server.stderr.read_text()
        # a wrong batch size is answered too, in one line
        with pytest.raises(DriveE2EError, match="observation batch size 3, the session was reset with 2"):
            pol.act(make_observation(3), pol.reset(meta_rows(2)))


def test_handshake_protocol_mismatch(policy_file, tmp_path, monkeypatch):
    with serve_policy(str(policy_file), tmp_path) as server:
        # an old / new client: the server refuses in one line
        sock = zmq.Context.instance().socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(server.address)
        try:
            sock.send_multipart(remote.encode({"v": 99, "id": 1, "op": "hello", "protocol": 99, "package": "9.9"}))
            assert sock.poll(int(TIMEOUT_S * 1000)), "no reply"
            reply, _ = remote.decode(sock.recv_multipart())
            assert reply["ok"] is False and "protocol mismatch" in reply["error"]
            assert "client speaks drivee2e remote protocol 99 (drivee2e-jax 9.9)" in reply["error"]
            # garbage is answered, not fatal
            sock.send_multipart([b"not json"])
            assert sock.poll(int(TIMEOUT_S * 1000)), "no reply"
            reply, _ = remote.decode(sock.recv_multipart())
            assert reply["ok"] is False and "not JSON" in reply["error"]
        finally:
            sock.close(linger=0)
        # the client side of it
        monkeypatch.setattr(remote, "PROTOCOL_VERSION", 2)
        with pytest.raises(DriveE2EError) as e:
            remote.RemotePolicy(server.remote, timeout_s=TIMEOUT_S)
        msg = _one_line(e)
        assert msg.startswith(f"remote policy at {server.address}: protocol mismatch") and "speaks 1" in msg


def test_server_killed_mid_run(policy_file, tmp_path):
    timeout_s = 5.0
    with serve_policy(str(policy_file), tmp_path) as server, \
            remote.RemotePolicy(server.remote, timeout_s=timeout_s) as pol:
        obs = make_observation(2)
        _, state = pol.act(obs, pol.reset(meta_rows(2)))
        server.kill()
        t0 = time.monotonic()
        with pytest.raises(DriveE2EError) as e:
            pol.act(obs, state)
        elapsed = time.monotonic() - t0
        msg = _one_line(e)
        assert msg.startswith(f"remote policy at {server.address}: ") and "step 1" in msg, msg
        assert "the policy server died or was stopped" in msg, msg
        assert elapsed < remote.RECONNECT_GRACE_S + 1.5 < timeout_s, elapsed  # the lost connection is noticed


def test_server_killed_while_acting(policy_file, tmp_path):
    with serve_policy(f"{policy_file}:sleep_s=5", tmp_path) as server, \
            remote.RemotePolicy(server.remote, timeout_s=30) as pol:
        state = pol.reset(meta_rows(2))
        threading.Timer(0.5, server.kill).start()
        t0 = time.monotonic()
        with pytest.raises(DriveE2EError) as e:
            pol.act(make_observation(2), state)
        msg = _one_line(e)
        assert msg == (f"remote policy at {server.address}: the connection was lost while waiting for the reply to "
                       f"act (step 0): the policy server died or was stopped")
        assert time.monotonic() - t0 < 4.0


def test_a_slow_policy_times_out(policy_file, tmp_path):
    with serve_policy(f"{policy_file}:sleep_s=2", tmp_path) as server, \
            remote.RemotePolicy(server.remote, timeout_s=0.5) as pol:
        t0 = time.monotonic()
        with pytest.raises(DriveE2EError) as e:
            pol.act(make_observation(2), pol.reset(meta_rows(2)))
        msg = _one_line(e)
        assert msg.startswith(f"remote policy at {server.address}: no reply to act (step 0) within 0.5 s"), msg
        assert time.monotonic() - t0 < 2.0


def test_no_server_there():
    with zmq.Context.instance().socket(zmq.ROUTER) as probe:  # a free port, then nobody listening
        port = probe.bind_to_random_port("tcp://127.0.0.1")
        probe.unbind(f"tcp://127.0.0.1:{port}")
    t0 = time.monotonic()
    with pytest.raises(DriveE2EError) as e:
        remote.RemotePolicy(f"remote://127.0.0.1:{port}", timeout_s=0.5)
    msg = _one_line(e)
    assert f"tcp://127.0.0.1:{port}" in msg and "no reply to hello within 0.5 s; not connected" in msg, msg
    assert time.monotonic() - t0 < 5.0


def test_serve_in_process_until_stopped():
    """serve() in a thread: ready callback, once=True ends after close, stop ends it otherwise."""

    class Half(hostapi.HostPolicy):
        name = "half"

        def act(self, obs, state):
            b = obs.batch_size
            return hostapi.Controls(np.full(b, 0.5), np.zeros(b), np.zeros(b)), state

    addresses: list[str] = []
    stop = threading.Event()
    t = threading.Thread(target=remote.serve, args=(Half(), 0), kwargs=dict(ready=addresses.append, stop=stop,
                                                                           once=True, log=lambda line: None))
    t.start()
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while not addresses and time.monotonic() < deadline:
            time.sleep(0.01)
        with remote.RemotePolicy(addresses[0], timeout_s=TIMEOUT_S) as pol:
            action, _ = pol.act(make_observation(2), pol.reset(meta_rows(2)))
            np.testing.assert_array_equal(action.throttle, [0.5, 0.5])
        t.join(TIMEOUT_S)  # close() sent `close`: once=True returns
        assert not t.is_alive()
    finally:
        stop.set()
        t.join(TIMEOUT_S)


def test_serving_imports_no_jax():
    """hostapi, remote and the serve-policy command import neither JAX nor Flax."""
    program = NO_JAX + (
        "import drivee2e_jax.hostapi, drivee2e_jax.remote, drivee2e_jax.policy\n"
        "from drivee2e_jax.cli import main\n"
        "code = main(['serve-policy', '--help'])\n"
        "assert code == 0, code\n"
        "print('ok', 'jax' in sys.modules and sys.modules['jax'] is not None)\n"
    )
    out = subprocess.run([sys.executable, "-c", program], capture_output=True, text=True, cwd=REPO, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "usage: drivee2e serve-policy" in out.stdout and "--port PORT" in out.stdout
    assert out.stdout.strip().endswith("ok False"), out.stdout[-500:]


def test_serve_policy_without_jax_and_the_default_cache_setting(policy_file, tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "DRIVEE2E_JAX_CACHE"}
    program = NO_JAX + f"from drivee2e_jax.cli import main\nsys.exit(main(['serve-policy', {str(policy_file)!r}, '--port', '0']))\n"
    proc = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=REPO, env={**env, "PYTHONPATH": str(REPO)})
    watchdog = threading.Timer(60, proc.kill)  # bounded: a hung server is killed, readline() then sees EOF
    watchdog.start()
    try:
        line = proc.stdout.readline()  # the "serving ... on tcp://..." line, or EOF when it crashed
        assert " on tcp://127.0.0.1:" in line, proc.stderr.read()[-1000:] if proc.poll() is not None else line
    finally:
        watchdog.cancel()
        proc.kill()
        proc.wait(timeout=10)
