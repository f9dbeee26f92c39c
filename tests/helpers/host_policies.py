"""Host-policy test helpers: a numpy observation batch, tiny policy files, and
a ``drivee2e serve-policy`` subprocess that runs with JAX and Flax blocked."""

from __future__ import annotations

import os
import queue
import re
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from drivee2e_jax import hostapi

REPO = Path(__file__).resolve().parents[2]

#: Prepended to ``python -c`` programs: any attempt to import JAX or Flax fails.
NO_JAX = "import sys; sys.modules['jax'] = None; sys.modules['flax'] = None; sys.modules['jaxlib'] = None\n"

TINY_POLICY = '''\
"""A tiny numpy host policy for the remote tests (no JAX)."""
import time

import numpy as np

from drivee2e_jax.hostapi import Controls, HostPolicy, Waypoints


class Tiny(HostPolicy):
    def __init__(self, kind="controls", fail_at=-1, sleep_s=0.0):
        self.name = f"tiny_{kind}"
        self.action_type = kind
        self.waypoint_dt = 0.25
        self.num_waypoints = 3 if kind == "waypoints" else None
        self.required_sensors = ("bev",)
        self.fail_at, self.sleep_s = fail_at, sleep_s

    def reset(self, meta):
        return {"step": 0, "ids": [m["scenario_id"] for m in meta]}

    def act(self, obs, state):
        step = state["step"]
        if step == self.fail_at:
            raise RuntimeError(f"kaboom at step {step}")
        time.sleep(self.sleep_s)
        b = obs.ego.shape[0]
        if self.action_type == "waypoints":
            return Waypoints(xy=obs.route[:, :3] + step), {**state, "step": step + 1}
        bev = obs.bev.reshape(b, -1).sum(axis=1)
        radar = obs.sensors["radar"].reshape(b, -1).sum(axis=1)
        action = Controls(throttle=obs.ego[:, 0] + step, brake=np.full(b, np.nan), steer=bev + radar)
        return action, {**state, "step": step + 1}


def make_policy(kind="controls", fail_at=-1, sleep_s=0.0):
    return Tiny(kind, fail_at, sleep_s)
'''


def write_tiny_policy(folder: Path, name: str = "tiny_policy.py") -> Path:
    path = Path(folder) / name
    path.write_text(TINY_POLICY)
    return path


def make_observation(batch: int = 3, seed: int = 0, *, bev: bool = True, sensors: bool = True) -> hostapi.Observation:
    """A random host Observation with the documented dtypes (P=5 route points,
    K=4 agents, M=2 lanes x Q=3 points, an 8x6 BEV, a 'radar' sensor)."""
    rng = np.random.default_rng(seed)
    f32 = lambda *s: rng.normal(size=(batch, *s)).astype(np.float32)
    i32 = lambda *s: rng.integers(0, 4, size=(batch, *s)).astype(np.int32)
    b8 = lambda *s: rng.random(size=(batch, *s)) < 0.5
    ego = hostapi.EgoState(xy=f32(2), yaw=f32(), speed=f32(), accel=f32(), steer=f32(), yaw_rate=f32(), t=f32())
    controls = hostapi.Controls(throttle=f32(), brake=f32(), steer=f32())
    priv = hostapi.Privileged(ego=ego, log_next_xy=f32(2), log_next_yaw=f32(), log_valid=b8(), log_controls=controls)
    return hostapi.Observation(
        ego=f32(4), gps=f32(2), compass=f32(), route=f32(5, 2), route_valid=b8(5), command=i32(),
        agents=f32(4, 8), agents_category=i32(4), agents_valid=b8(4), lanes=f32(2, 3, 2), lanes_valid=b8(2, 3),
        signal_state=i32(), signal_distance=f32(), speed_limit=f32(), privileged=priv,
        bev=i32(8, 6) if bev else None, lidar=None, sensors={"radar": f32(3, 4)} if sensors else None,
    )


def meta_rows(batch: int = 3) -> list[dict]:
    return [{"scenario_id": f"s{i}", "split": "val", "intersection_id": "x", "map_id": "m", "behavior": "STR",
             "weather": "clear", "time_of_day": "day", "ego_track_id": i, "index": i, "num_agents": 4,
             "num_steps": 40, "dt": 0.1} for i in range(batch)]


class Server:
    """A running ``drivee2e serve-policy`` subprocess (JAX and Flax blocked)."""

    def __init__(self, proc: subprocess.Popen, address: str, stderr: Path):
        self.proc, self.address, self.stderr = proc, address, stderr

    @property
    def remote(self) -> str:
        return "remote://" + self.address.removeprefix("tcp://")

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(timeout=10)


@contextmanager
def serve_policy(spec: str, log_dir: Path, *, extra: tuple[str, ...] = (), start_timeout_s: float = 60.0):
    """Start ``drivee2e serve-policy SPEC --port 0`` in a subprocess with
    ``sys.modules['jax'] = None`` (so serving must not import JAX); yields a
    :class:`Server` once it prints its address; stops it on exit."""
    stderr = Path(log_dir) / f"server-{time.monotonic_ns()}.log"
    program = NO_JAX + (
        "from drivee2e_jax.cli import main\n"
        f"sys.exit(main(['serve-policy', {spec!r}, '--port', '0', *{list(extra)!r}]))\n"
    )
    # DRIVEE2E_JAX_CACHE=off: cli.main() enables JAX's compilation cache, which imports JAX otherwise
    # (tests/test_remote.py::test_serve_policy_without_jax_and_the_default_cache_setting).
    env = {**os.environ, "DRIVEE2E_JAX_CACHE": "off", "PYTHONPATH": str(REPO)}
    with open(stderr, "w") as err:
        proc = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE, stderr=err, text=True,
                                cwd=REPO, env=env)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    try:
        deadline = time.monotonic() + start_timeout_s
        address = None
        while address is None:
            left = deadline - time.monotonic()
            if left <= 0 or proc.poll() is not None and lines.empty():
                raise AssertionError(f"serve-policy did not start (rc={proc.poll()}): {stderr.read_text()[-2000:]}")
            try:
                line = lines.get(timeout=min(left, 0.5))
            except queue.Empty:
                continue
            m = re.search(r" on (tcp://\S+)", line)
            address = m.group(1) if m else None
        yield Server(proc, address, stderr)
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
