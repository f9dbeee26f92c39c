"""Where the IDM step's time goes: ``reactive.leaders`` and ``reactive.step``
jitted alone over the first B twin15 scenarios at one time (agents and ego
where their logs put them), and the step with ``leaders`` stubbed out.

    python experiments/idm/leaders_bench.py [--batch 800] [--t 5.0] [--repeat 5]

Prints the minimum and median wall time of ``--repeat`` calls of each (ms).
On a shared machine only ratios within one run mean anything.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import reactive, replay
from drivee2e_jax.scenario import load_suite


def _time(name: str, fn, *args, repeat: int) -> None:
    fn = jax.jit(fn)
    jax.block_until_ready(fn(*args))
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - t0)
    print(f"{name:<22} min {1e3 * min(ts):8.1f} ms  median {1e3 * float(np.median(ts)):8.1f} ms", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batch", type=int, default=800)
    ap.add_argument("--t", type=float, default=5.0, help="time of the snapshot, s")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    packed = load_suite("twin15").pack(None)
    sc = packed.select(np.arange(args.batch) % len(packed)).to_jax()
    t = jnp.float32(args.t)

    def setup(s):
        tr, ego = s.tracks, s.ego_index
        arc = reactive.path_arc(tr)
        paths = reactive.leader_paths(tr, arc, s.map.lanes, s.map.lane_width, s.map.lane_successors)
        return arc, paths, reactive.init(tr, s.dt_log, ego_index=ego)

    arc, paths, state = jax.jit(jax.vmap(setup))(sc)

    def leaders(s, arc, paths):
        tr, ego = s.tracks, s.ego_index
        now = replay.agents_at(tr, t, s.dt_log)
        e = replay.ego_log_at(tr, ego, t, s.dt_log)
        num = tr.category.shape[0]
        lw = tr.size[:, :2]
        return reactive.leaders(
            reactive.arc_at(arc, t, s.dt_log), lw, paths, jnp.concatenate([now.xy, e.xy[None]]),
            jnp.concatenate([now.yaw, e.yaw[None]]), jnp.concatenate([now.vel, e.vel[None]]),
            jnp.concatenate([lw, lw[ego][None]]), jnp.concatenate([now.valid & (jnp.arange(num) != ego), e.valid[None]]),
            jnp.arange(num), 0.0)

    def step(s, arc, paths, state):
        e = replay.ego_log_at(s.tracks, s.ego_index, t, s.dt_log)
        return reactive.step(state, s.tracks, arc, paths, t, 0.1, s.dt_log, e.xy, e.yaw, jnp.linalg.norm(e.vel),
                             s.tracks.size[s.ego_index, :2], ego_index=s.ego_index)

    _time("leaders", jax.vmap(leaders), sc, arc, paths, repeat=args.repeat)
    _time("step", jax.vmap(step), sc, arc, paths, state, repeat=args.repeat)
    real = reactive.leaders
    reactive.leaders = lambda s, *a: (s > jnp.inf, s, s)  # no leader anywhere: the step without the search
    try:
        _time("step without leaders", jax.vmap(step), sc, arc, paths, state, repeat=args.repeat)
    finally:
        reactive.leaders = real


if __name__ == "__main__":
    main()
