"""`ppo`: a vector-scene transformer trained with PPO in the RL environment.

The ``vector_transformer`` network (``drivee2e_jax/models/vector_transformer.py``,
waypoints tracked by the simulator's PID + pure pursuit) trained by PPO on
``drivee2e_jax.envs`` (``drivee2e_jax/train/ppo.py``). Loads the bundled weights
``drivee2e_jax/zoo/weights/ppo.npz`` (``models.bundled``; how they were
trained: their ``.json`` and docs/baselines.md "Policy zoo"), or
``checkpoint=RUN`` (a PPO run folder or one of its checkpoints). With
neither: a one-line DriveE2EError naming the missing file.
"""

from drivee2e_jax.zoo._weights import learned_policy


def make_policy(checkpoint=None, **config):
    return learned_policy("vector_transformer", "traj", "ppo", checkpoint, required=True, **config)
