"""What a host policy costs: the state-only closed loop with the same policy in
JAX, as a numpy host policy through the bridge (``hostbridge`` + ``Rollout``:
compiled segments around one host call per step, what ``drivee2e bench``
uses), and as the former ``jax.pure_callback`` inside the compiled scan (kept
here for the comparison: JAX's persistent cache never stores a program with a
host callback, so every process compiled it again).

Under ``jit`` a JAX policy's observation is computed only as far as the policy
reads it (constant_velocity reads ``obs.ego``; lanes and agents are never
projected). A host policy gets what it declares in ``observation_fields``
(the example declares ``("ego",)``); one that declares nothing gets every
field, which costs the simulator the full vector observation. To separate the
two costs, ``jax_full`` is the JAX policy made to read every field (a zero
times the sum of all leaves), and the host variants run both ways
(``bridge`` / ``callback`` = declared fields, ``bridge_full`` / ``callback_full`` = every field).

    python experiments/perf/host_policy.py [--batch 200] [--steps 200] [--rounds 2] [--json]

The policy is constant_velocity (``drivee2e_jax/zoo/constant_velocity.py``) and its
numpy twin (``docs/examples/numpy_constant_velocity.py``): the same
waypoints, so the variants simulate the same episodes. Each variant is
compiled and warmed up first, then timed over ``--steps`` steps; the variants
are interleaved ``--rounds`` times and the best round of each is reported
(shared machine), with the overhead of each host variant relative to the JAX
one from the same round set. Never a unit test (issue: <= 25 % at B = 200).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # `python experiments/perf/host_policy.py` from a checkout

from drivee2e_jax import hostapi, hostbridge  # noqa: E402
from drivee2e_jax.policy import load_policy  # noqa: E402
from drivee2e_jax.rollout import Rollout  # noqa: E402
from drivee2e_jax.scenario import load_suite  # noqa: E402
from drivee2e_jax.sim import SimConfig, Simulator  # noqa: E402
from drivee2e_jax.types import Waypoints  # noqa: E402


class ReadsEverything:
    """A JAX policy: constant_velocity's waypoints plus 0 x every observation leaf."""

    def __init__(self, inner):
        self.inner = inner
        self.name, self.action_type, self.waypoint_dt = inner.name, inner.action_type, inner.waypoint_dt
        self.init, self.initial_state = inner.init, inner.initial_state

    def act(self, params, obs, state, key):
        action, state = self.inner.act(params, obs, state, key)
        total = sum(jnp.sum(jnp.asarray(x, jnp.float32)) for x in jax.tree_util.tree_leaves(obs))
        return Waypoints(xy=action.xy + 0.0 * total), state


class AllFields(hostapi.HostPolicy):
    """The numpy example with ``observation_fields = None``: it receives every field."""

    def __init__(self, inner):
        self.inner = inner
        self.name, self.action_type = inner.name, inner.action_type
        self.waypoint_dt, self.num_waypoints = inner.waypoint_dt, inner.num_waypoints

    def act(self, obs, state):
        return self.inner.act(obs, state)


def _batch(n: int):
    packed = load_suite("twin15").pack("val")
    rows = np.arange(n) % len(packed)
    packed = packed.select(rows)
    return jax.tree_util.tree_map(jnp.asarray, packed.scenario), packed.meta


def scanned(policy, batch, meta, steps: int, chunk: int = 50, bridge=None) -> float:
    """Seconds for ``steps`` steps of the rollout (a JAX policy, a bridged host
    policy, or ``InScan``: the bridge's callback inside the scan; ``bridge``:
    the bridge to start per batch, default ``policy``)."""
    bridge = policy if bridge is None else bridge
    sim = Simulator(SimConfig())
    ro = Rollout(sim, policy, None, chunk=chunk)
    keys = jax.random.split(jax.random.PRNGKey(0), int(batch.ego_index.shape[0]))
    hostbridge.begin(bridge, meta, batch)
    carry = ro.init(batch, keys)
    carry, _ = ro.advance(batch, carry)  # compile + warm up
    jax.block_until_ready(carry)
    hostbridge.begin(bridge, meta, batch)
    carry = ro.init(batch, keys)
    t0 = time.perf_counter()
    for _ in range(steps // chunk):
        carry, log = ro.advance(batch, carry)
    jax.block_until_ready((carry, log))
    hostbridge.raise_if_failed(bridge)
    return time.perf_counter() - t0


class InScan:
    """A bridged host policy seen as a plain JAX policy: its ``act`` (a
    ``jax.pure_callback``) runs inside the compiled scan, the path the bridge
    took before the compiled segments."""

    def __init__(self, bridge):
        self.bridge = bridge
        self.name, self.action_type, self.waypoint_dt = bridge.name, bridge.action_type, bridge.waypoint_dt
        self.init, self.initial_state, self.act = bridge.init, bridge.initial_state, bridge.act


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=200)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    steps = max(50, args.steps // 50 * 50)
    batch, meta = _batch(args.batch)
    jax_pol = load_policy(ROOT / "drivee2e_jax" / "zoo" / "constant_velocity.py")
    host = load_policy(ROOT / "docs" / "examples" / "numpy_constant_velocity.py")
    host_full = AllFields(host)
    bridge, full_bridge = hostbridge.wrap(host), hostbridge.wrap(host_full)
    variants = {
        "jax": lambda: scanned(jax_pol, batch, meta, steps),
        "jax_full": lambda: scanned(ReadsEverything(jax_pol), batch, meta, steps),
        "bridge": lambda: scanned(bridge, batch, meta, steps),
        "callback": lambda: scanned(InScan(bridge), batch, meta, steps, bridge=bridge),
        "bridge_full": lambda: scanned(full_bridge, batch, meta, steps),
        "callback_full": lambda: scanned(InScan(full_bridge), batch, meta, steps, bridge=full_bridge),
    }
    best = dict.fromkeys(variants, np.inf)
    load = [os.getloadavg()[0]]
    for _ in range(args.rounds):
        for name, run in variants.items():
            best[name] = min(best[name], run())
        load.append(os.getloadavg()[0])
    out = {
        "batch": args.batch, "steps": steps, "rounds": args.rounds, "device": str(jax.devices()[0]),
        **{f"{k}_s": round(v, 3) for k, v in best.items()},
        **{f"{k}_scenario_steps_per_s": round(args.batch * steps / v) for k, v in best.items()},
        # the host round trip, each against the JAX policy computing the same observation:
        "bridge_vs_jax_pct": round(100 * (best["bridge"] / best["jax"] - 1), 1),
        "callback_vs_jax_pct": round(100 * (best["callback"] / best["jax"] - 1), 1),
        "bridge_full_vs_jax_full_pct": round(100 * (best["bridge_full"] / best["jax_full"] - 1), 1),
        "callback_full_vs_jax_full_pct": round(100 * (best["callback_full"] / best["jax_full"] - 1), 1),
        # what the full observation costs the simulator:
        "jax_full_vs_jax_pct": round(100 * (best["jax_full"] / best["jax"] - 1), 1),
        "load_1min": [round(x, 2) for x in load],
    }
    if args.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k:>32}: {v}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
