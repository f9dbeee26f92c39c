"""`ad_mlp`: the AD-MLP baseline (ego history + state + command -> 6 waypoints).

Needs a trained checkpoint (``drivee2e train --model ad_mlp ... --out RUN``)::

    from drivee2e_jax.policy import load_policy
    policy = load_policy("drivee2e_jax/zoo/ad_mlp.py", checkpoint="runs/ad_mlp")

``checkpoint`` is a run folder (its last epoch), ``RUN/checkpoints`` or one
``RUN/checkpoints/<epoch>``; the model config comes from the checkpoint
(``models.base.policy_from_checkpoint``). Without a checkpoint the environment variable
``DRIVEE2E_AD_MLP_CHECKPOINT`` is used (so ``drivee2e bench --policy
drivee2e_jax/zoo/ad_mlp.py`` works); with neither, a one-line error names both.
See drivee2e_jax/models/ad_mlp.py for the network.
"""

import os

from drivee2e_jax.errors import DriveE2EError

ENV = "DRIVEE2E_AD_MLP_CHECKPOINT"


def make_policy(checkpoint=None):
    from drivee2e_jax.models.base import policy_from_checkpoint

    checkpoint = checkpoint or os.environ.get(ENV)
    if not checkpoint:
        raise DriveE2EError(f"drivee2e_jax/zoo/ad_mlp.py: no checkpoint (pass make_policy(checkpoint=RUN_DIR) or set ${ENV})")
    return policy_from_checkpoint("ad_mlp", checkpoint, "traj")
