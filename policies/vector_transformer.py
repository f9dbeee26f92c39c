"""`vector_transformer`: the vector-scene transformer baseline (VAD's family).

Nearest agents + lane polylines + route + ego state as tokens, two
self-attention layers, a planning query -> 6 waypoints 0.5 s apart, tracked
by the simulator's PID + pure pursuit (``drivee2e_jax/models/vector_transformer.py``).

Usage: ``load_policy("policies/vector_transformer.py", checkpoint=RUN_DIR)`` or
``BenchConfig(policies=("vector_transformer",), policy_kwargs=({"checkpoint": RUN_DIR},))``
(a ``drivee2e train --model vector_transformer`` run folder or checkpoint).
Without a checkpoint the parameters are a fresh random init (smoke tests only).
"""

import importlib.util
from pathlib import Path


def _tcp_policy_module():
    """``policies/tcp.py``, which holds the checkpoint -> policy helper ``model_policy``."""
    spec = importlib.util.spec_from_file_location("drivee2e_policy_tcp_helpers", Path(__file__).with_name("tcp.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def make_policy(checkpoint=None, **config):
    return _tcp_policy_module().model_policy("vector_transformer", checkpoint, "traj", name="vector_transformer",
                                             **config)
