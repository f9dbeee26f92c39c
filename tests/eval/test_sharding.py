"""Sharding over (forced) host devices gives the same results as one device.

``evaluate`` pads the batch to a multiple of the device count with copies of
a real scenario and drops the padding rows; the sensors' raster table is
replicated, ``map_index`` split with the batch. The oracle is the same call
on one device.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = r"""
import json, sys
import jax, numpy as np
from drivee2e_jax import compile_cache
compile_cache.enable()  # the folder the test session pinned in $DRIVEE2E_JAX_CACHE
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.observe.sensors import SensorConfig, build_assets
from drivee2e_jax.policy import load_policy
from drivee2e_jax.rollout import shard_rollout_inputs
from drivee2e_jax.scenario import load_suite
from drivee2e_jax.sim import SimConfig
assert len(jax.devices()) == 2, jax.devices()
suite = load_suite(sys.argv[1], cache=False)
cfg = SimConfig(sensors=SensorConfig.for_policy(("bev",)))
packed = suite.pack(None).select(np.arange(3))  # odd: one padding row on 2 devices
assets = build_assets(packed, cfg.sensors, suite.maps)
keys = jax.random.split(jax.random.PRNGKey(0), 3)
b, k, a = shard_rollout_inputs(jax.device_put(packed.scenario), keys, assets)
out = {"placed": {"rows": int(b.ego_index.shape[0]), "keys": int(k.shape[0]), "map_index": int(a.map_index.shape[0]),
                  "shards": len(b.ego_index.sharding.device_set), "raster_replicated": bool(a.raster.words.sharding.is_fully_replicated),
                  "padding_is_row0": bool(np.array_equal(np.asarray(b.ego_index)[3], np.asarray(b.ego_index)[0]))}}
for pol_name in ("expert",):
    pol = load_policy(sys.argv[2] + "/" + pol_name + ".py")
    for name, devs in (("one", jax.devices()[:1]), ("two", None)):
        res = evaluate(pol, packed, None, config=cfg, maps=suite.maps, devices=devs, chunk=25)
        out[pol_name + "/" + name] = {
            "rows": [{k: v for k, v in r.items() if k != "eval_time_s"} for r in res.rows],
            "events": res.events, "xy": np.asarray(res.logs.xy).round(5).tolist(),
        }
print(json.dumps(out))
"""


def test_sharded_evaluate_matches_single_device():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(ROOT / "drivee2e_jax" / "scenario" / "examples" / "tiny"), str(ROOT / "drivee2e_jax" / "zoo")],
        capture_output=True, text=True, env=env, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    placed = out["placed"]
    assert placed == {"rows": 4, "keys": 4, "map_index": 4, "shards": 2, "raster_replicated": True,
                      "padding_is_row0": True}
    for pol in ("expert",):
        one, two = out[f"{pol}/one"], out[f"{pol}/two"]
        assert len(one["rows"]) == 3  # the padding row is never scored
        assert [r["scenario_id"] for r in one["rows"]] == [r["scenario_id"] for r in two["rows"]]
        assert one["rows"] == two["rows"]
        assert one["events"] == two["events"]
        assert np.asarray(one["xy"]).shape[0] == 3
        assert one["xy"] == two["xy"]
