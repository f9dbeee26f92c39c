"""Micro-benchmark of the ray-casting sensors (never a unit test).

    python experiments/perf/ray.py                 # readable table
    python experiments/perf/ray.py --json          # one JSON object per line
    python experiments/perf/ray.py --quick         # B=64 and 800, 64x360, K=32 only

Per configuration: the cost of ONE step of a sensor for B synthetic scenes
(A = 128 agents scattered within 70 m, 8 box-shaped buildings), under
``jit(vmap(select_scene + sensor))``: compile time, scenario-steps/s and
microseconds per scenario-step. ``lidar`` returns only the range image (what a
policy consumes; XLA drops the unused outputs), ``lidar_full`` every field
(classes, agent rows, point cloud). ``camera`` = the six default surround
cameras (depth + class), ``radar`` = the five default radars. Numbers are
wall-clock medians (and best) of ``--reps`` calls on whatever else the machine
is doing, plus the process CPU time per scenario-step (summed over threads:
less sensitive to other processes, but counts both cores when XLA uses them).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import time


def _scenes(batch: int, agents: int = 128, obstacles: int = 8, seed: int = 0):
    import jax.numpy as jnp
    import numpy as np

    from drivee2e_jax.replay import AgentStates
    from drivee2e_jax.types import Polylines

    rng = np.random.default_rng(seed)
    xy = rng.uniform(-70, 70, (batch, agents, 2)).astype(np.float32)
    xy[:, 0] = 0.0  # the ego
    yaw = rng.uniform(-np.pi, np.pi, (batch, agents)).astype(np.float32)
    vel = rng.normal(0, 5, (batch, agents, 2)).astype(np.float32)
    size = np.tile(np.array([4.5, 1.9, 1.6], np.float32), (batch, agents, 1))
    size[:, ::5] = [12.0, 2.5, 3.5]
    cat = rng.integers(0, 8, (batch, agents)).astype(np.int32)
    c = rng.uniform(-60, 60, (batch, obstacles, 1, 2))
    c = np.where(np.abs(c) < 12, 12 * np.sign(c) + c, c)
    half = rng.uniform(3, 15, (batch, obstacles, 1, 2))
    sq = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float32)
    poly = (c + half * sq).astype(np.float32)
    agent_states = AgentStates(xy=jnp.asarray(xy), yaw=jnp.asarray(yaw), vel=jnp.asarray(vel),
                               valid=jnp.ones((batch, agents), bool))
    obs = Polylines(xy=jnp.asarray(poly), point_valid=jnp.ones((batch, obstacles, 4), bool),
                    valid=jnp.ones((batch, obstacles), bool))
    height = jnp.asarray(rng.uniform(3, 20, (batch, obstacles)).astype(np.float32))
    return agent_states, jnp.asarray(size), jnp.asarray(cat), obs, height


def _sensor(kind: str, channels: int, bins: int, k: int):

    from drivee2e_jax.observe import raycast

    scene_cfg = raycast.SceneConfig(num_agents=k, radius=100.0)

    def scene_of(agents, size, cat, obs, height):
        return raycast.select_scene(agents.xy[0], agents, size, cat, obs, height, scene_cfg, exclude=0)

    if kind.startswith("lidar"):
        from drivee2e_jax.observe import lidar

        cfg = lidar.LidarConfig(channels=channels, azimuth_bins=bins)

        def f(agents, size, cat, obs, height):
            scan = lidar.lidar_scan(scene_of(agents, size, cat, obs, height), agents.xy[0], agents.yaw[0], cfg)
            return scan if kind == "lidar_full" else scan.range
        return f
    if kind == "camera":
        from drivee2e_jax.observe import camera

        def f(agents, size, cat, obs, height):
            return camera.camera_images(scene_of(agents, size, cat, obs, height), agents.xy[0], agents.yaw[0])
        return f
    if kind == "radar":
        from drivee2e_jax.observe import radar

        def f(agents, size, cat, obs, height):
            return radar.radar_returns(scene_of(agents, size, cat, obs, height), agents.xy[0], agents.yaw[0],
                                       agents.vel[0])
        return f
    raise ValueError(kind)


def measure(kind: str, batch: int, channels: int, bins: int, k: int, reps: int) -> dict:
    import jax

    args = _scenes(batch)
    fn = jax.jit(jax.vmap(_sensor(kind, channels, bins, k)))
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - t0
    times, cpu = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    med = sorted(times)[len(times) // 2]
    cpu_med = sorted(cpu)[len(cpu) // 2]
    return dict(sensor=kind, batch=batch, beams=f"{channels}x{bins}" if kind.startswith("lidar") else "-", agents_k=k,
                compile_s=round(compile_s, 2), steps_per_s=round(batch / med, 1),
                us_per_step=round(1e6 * med / batch, 1), cpu_us_per_step=round(1e6 * cpu_med / batch, 1),
                best_us_per_step=round(1e6 * min(times) / batch, 1), cpus=os.cpu_count())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--sensors", default="lidar,lidar_full,camera,radar")
    ap.add_argument("--batches", default="64,800")
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args(argv)
    batches = [int(b) for b in args.batches.split(",")]
    configs = []
    for kind in args.sensors.split(","):
        if kind.startswith("lidar") and not args.quick:
            grid = itertools.product(batches, [(32, 180), (64, 360), (64, 720)], [16, 32, 64])
        else:
            grid = itertools.product(batches, [(64, 360)], [32])
        configs += [(kind, b, c, z, k) for b, (c, z), k in grid]
    if not args.json:
        print(f"{'sensor':<11}{'B':>5}{'beams':>9}{'K':>4}{'compile s':>11}{'steps/s':>11}{'us/step':>9}{'best':>9}{'cpu us':>9}  cpus={os.cpu_count()}")
    for kind, b, c, z, k in configs:
        row = measure(kind, b, c, z, k, args.reps)
        if args.json:
            print(json.dumps(row), flush=True)
        else:
            print(f"{row['sensor']:<11}{b:>5}{row['beams']:>9}{k:>4}{row['compile_s']:>11}{row['steps_per_s']:>11}"
                  f"{row['us_per_step']:>9}{row['best_us_per_step']:>9}{row['cpu_us_per_step']:>9}", flush=True)


if __name__ == "__main__":
    main()
