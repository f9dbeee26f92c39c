"""Reinforcement-learning environments over a suite split.

* ``envs.functional``: a pure JAX environment (gymnax / Jumanji style):
  ``DriveEnv`` with ``reset(key, params)`` / ``step(key, state, action, params)``,
  ``EnvParams`` / ``EnvState``, the documented ``RewardConfig``,
  ``AutoResetWrapper`` and its batched form ``VmapAutoResetWrapper`` (resets
  only the environments that ended); jit / vmap / ``lax.scan`` it.
* ``envs.gym``: Gymnasium environments on top of it: ``DriveE2EVectorEnv``
  (``gymnasium.vector.VectorEnv``, SAME_STEP autoreset) and ``DriveE2EEnv``
  (``gymnasium.Env``), registered as ``drivee2e_jax/DriveE2E-v0``.

docs/envs.md has examples, the spaces, the reward and the info keys.
"""

from drivee2e_jax.envs.functional import (
    AutoResetWrapper,
    DriveEnv,
    EnvParams,
    EnvState,
    RewardConfig,
    VmapAutoResetWrapper,
    make_params,
)
from drivee2e_jax.envs.gym import ENV_ID, DriveE2EEnv, DriveE2EVectorEnv

__all__ = [
    "ENV_ID",
    "AutoResetWrapper",
    "DriveE2EEnv",
    "DriveE2EVectorEnv",
    "DriveEnv",
    "EnvParams",
    "EnvState",
    "RewardConfig",
    "VmapAutoResetWrapper",
    "make_params",
]
