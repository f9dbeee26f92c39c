"""Sharding a batch over (forced) host devices gives the same results as one device."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import json, sys
sys.path.insert(0, sys.argv[1])
import jax, jax.numpy as jnp, numpy as np
import sim_scenarios as ss
from drivee2e_jax.policy import load_policy
from drivee2e_jax.rollout import Rollout, shard_batch
from drivee2e_jax.sim import Simulator, SimConfig
assert len(jax.devices()) == 2, jax.devices()
batch = ss.build([ss.clean(), ss.blocked_by_car(), ss.red_light(), ss.pedestrian_ahead()])
pol = load_policy(sys.argv[2])
ro = Rollout(Simulator(SimConfig()), pol, None, chunk=20)
plain = jax.tree_util.tree_map(jnp.asarray, batch.scenario)
out = {}
for name, scn in (("one", plain), ("sharded", shard_batch(plain))):
    carry, logs = ro.run(scn, jax.random.PRNGKey(0))
    out[name] = {"xy": np.asarray(logs.xy).round(5).tolist(), "rc": np.asarray(carry.sim.episode.rc.value).tolist(),
                 "shards": len(carry.sim.ego.xy.sharding.device_set)}
print(json.dumps(out))
"""


def test_sharded_rollout_matches_single_device():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(ROOT / "tests"), str(ROOT / "policies" / "log_replay.py")],
        capture_output=True, text=True, env=env, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["sharded"]["shards"] == 2
    assert out["one"]["rc"] == out["sharded"]["rc"]
    assert out["one"]["xy"] == out["sharded"]["xy"]
