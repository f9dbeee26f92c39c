"""`vector_transformer_ft`: the vector-scene transformer after differentiable fine-tuning.

The ``vector_transformer`` network (``drivee2e_jax/models/vector_transformer.py``,
waypoints tracked by the simulator's PID + pure pursuit) fine-tuned closed-loop
through the simulator (``drivee2e finetune``, ``drivee2e_jax/train/finetune.py``).
Loads the bundled weights ``drivee2e_jax/zoo/weights/vector_transformer_ft.npz``
(``models.bundled``; how they were trained: their ``.json`` and
docs/baselines.md "Policy zoo"), or ``checkpoint=RUN`` (a fine-tuning run
folder or one of its checkpoints). With neither: a one-line DriveE2EError
naming the missing file (no random-init fallback: that is
``vector_transformer:bundled=false``).
"""

from drivee2e_jax.zoo._weights import learned_policy


def make_policy(checkpoint=None, **config):
    return learned_policy("vector_transformer", "traj", "vector_transformer_ft", checkpoint, required=True, **config)
