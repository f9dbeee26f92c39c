"""`vector_mlp`: an MLP over the ego's past and a flat vector of the scene.

AD-MLP's network over its ego inputs plus the route points, the nearest
agents, the next signal and its distance and the speed limit
(``drivee2e_jax/models/vector_mlp.py``); its waypoints are tracked by the
simulator's PID + pure pursuit. The model PPO trains from scratch at
simulator speed (``drivee2e rl --model vector_mlp``, docs/training.md).

Usage: ``--policy vector_mlp:checkpoint=RUN`` (a ``drivee2e rl`` or
``drivee2e train --model vector_mlp`` run folder or checkpoint;
``models.base.policy_from_checkpoint``). No weights are bundled under this
name (the PPO-from-scratch ones are ``ppo_scratch``); without a checkpoint
the parameters are a fresh random init (smoke tests only).
"""

from drivee2e_jax.zoo._weights import learned_policy


def make_policy(checkpoint=None, **config):
    return learned_policy("vector_mlp", "traj", "vector_mlp", checkpoint, bundled=False, **config)
