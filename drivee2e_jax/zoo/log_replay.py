"""`log_replay`: reproduces the reference demonstration.

Each step it applies the controls that move the simulated ego onto the logged
next pose (``Observation.privileged.log_controls``, from ``dynamics.inverse``).
Because the target is recomputed from the current simulated state, tracking
error does not accumulate. On a clean log it scores SR = 1, DS = 100: a check
of the simulator and of the scenario, not a driving policy.
"""

import jax.numpy as jnp

from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import Controls


class LogReplay(StatelessPolicy):
    name = "log_replay"
    action_type = "controls"

    def act(self, params, obs, policy_state, key):
        c = obs.privileged.log_controls
        # Past the end of the ego's log: hold still.
        ok = obs.privileged.log_valid
        return (
            Controls(
                throttle=jnp.where(ok, c.throttle, 0.0),
                brake=jnp.where(ok, c.brake, 1.0),
                steer=jnp.where(ok, c.steer, 0.0),
            ),
            policy_state,
        )


policy = LogReplay()
