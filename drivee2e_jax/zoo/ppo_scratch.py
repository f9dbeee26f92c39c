"""`ppo_scratch`: the vector MLP trained by PPO from a random init, no demonstrations.

The ``vector_mlp`` network (``drivee2e_jax/models/vector_mlp.py``: the ego's
past and a flat vector of the scene; two waypoints tracked by the
simulator's PID + pure pursuit) trained by PPO on ``drivee2e_jax.envs``
(``drivee2e_jax/train/ppo.py``; ``experiments/rl/run.py``, run
``ppo_scratch_mlp``). Loads the bundled weights
``drivee2e_jax/zoo/weights/ppo_scratch.npz`` (``models.bundled``; how they
were trained: their ``.json`` and docs/baselines.md "Policy zoo"), or
``checkpoint=RUN`` (a ``drivee2e rl --model vector_mlp`` run folder or one of
its checkpoints). With neither: a one-line DriveE2EError naming the missing
file.
"""

from drivee2e_jax.zoo._weights import learned_policy


def make_policy(checkpoint=None, **config):
    return learned_policy("vector_mlp", "traj", "ppo_scratch", checkpoint, required=True, **config)
