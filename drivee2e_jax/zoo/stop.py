"""`stop`: a policy that never moves (full brake). A lower bound: RC ~ 0."""

import jax.numpy as jnp

from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls


class Stop(StatelessPolicy):
    name = "stop"
    action_type = "controls"

    def act(self, params, obs, policy_state, key):
        z = jnp.zeros((), jnp.float32)
        return Controls(throttle=z, brake=jnp.ones((), jnp.float32), steer=z), policy_state


policy = Stop()
