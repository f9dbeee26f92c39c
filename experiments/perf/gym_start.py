"""How long a new process takes to a stepped Gymnasium vector env, and how
much of it is XLA compilation (``jax.monitoring``): run it twice with the
same ``DRIVEE2E_JAX_CACHE`` folder to see what the persistent cache saves
(docs/performance.md, "Host policies").

    DRIVEE2E_JAX_CACHE=/tmp/gymcache python experiments/perf/gym_start.py   # twice
"""

import json
import time

t0 = time.perf_counter()
import jax  # noqa: E402

compiled = [0.0]


def _on_duration(event, seconds, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        compiled[0] += seconds


jax.monitoring.register_event_duration_secs_listener(_on_duration)
import numpy as np  # noqa: E402

from drivee2e_jax.envs.gym import DriveE2EVectorEnv  # noqa: E402

env = DriveE2EVectorEnv("twin15", "val", num_envs=4, limit=8)
env.reset(seed=0)
for _ in range(5):
    env.step(np.zeros(env.action_space.shape, np.float32))
print(json.dumps({"compile_s": round(compiled[0], 1), "wall_s": round(time.perf_counter() - t0, 1)}))
