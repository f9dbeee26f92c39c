"""Size and per-call cost of the AD-MLP baseline, for its docstring.

    python experiments/perf/ad_mlp_cost.py [DATA]      # DATA: a demonstrations folder (drivee2e dataset build)
"""

from __future__ import annotations

import sys
import time

import jax
import jax.numpy as jnp

from drivee2e_jax.models.ad_mlp import make_model
from drivee2e_jax.train.dataset import DemoDataset


def main(data: str) -> None:
    model = make_model()
    obs = jax.tree_util.tree_map(jnp.asarray, DemoDataset(data).first().obs)
    params = model.init(jax.random.PRNGKey(0), obs)
    n = sum(x.size for x in jax.tree_util.tree_leaves(params))
    one = jax.jit(model.apply)
    many = jax.jit(jax.vmap(model.apply, in_axes=(None, 0)))
    batch = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (256,) + a.shape), obs)
    for fn, arg, label in ((one, obs, "1 sample"), (many, batch, "batch of 256")):
        jax.block_until_ready(fn(params, arg))
        t0 = time.perf_counter()
        for _ in range(200):
            jax.block_until_ready(fn(params, arg))
        print(f"{label}: {(time.perf_counter() - t0) / 200 * 1e3:.3f} ms")
    print(f"parameters: {n}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "data/demos-train")
