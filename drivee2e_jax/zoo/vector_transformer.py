"""`vector_transformer`: the vector-scene transformer baseline (VAD's family).

Nearest agents + lane polylines + route + ego state as tokens, two
self-attention layers, a planning query -> 6 waypoints 0.5 s apart, tracked
by the simulator's PID + pure pursuit (``drivee2e_jax/models/vector_transformer.py``).

Usage: ``load_policy("drivee2e_jax/zoo/vector_transformer.py", checkpoint=RUN_DIR)`` or
``BenchConfig(policies=("vector_transformer",), policy_kwargs=({"checkpoint": RUN_DIR},))``
(a ``drivee2e train --model vector_transformer`` run folder or checkpoint;
``models.base.policy_from_checkpoint``). Without a checkpoint the bundled
weights ``drivee2e_jax/zoo/weights/vector_transformer.npz`` are loaded
(``models.bundled``, docs/baselines.md "Policy zoo"); when they are absent,
or with ``bundled=False``, the parameters are a fresh random init (smoke tests only).
"""

from drivee2e_jax.zoo._weights import learned_policy


def make_policy(checkpoint=None, bundled=True, **config):
    return learned_policy("vector_transformer", "traj", "vector_transformer", checkpoint, bundled=bundled, **config)
