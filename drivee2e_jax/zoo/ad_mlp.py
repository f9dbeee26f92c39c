"""`ad_mlp`: the AD-MLP baseline (ego history + state + command -> 6 waypoints).

Needs a trained checkpoint (``drivee2e train --model ad_mlp ... --out RUN``)::

    from drivee2e_jax.policy import load_policy
    policy = load_policy("drivee2e_jax/zoo/ad_mlp.py", checkpoint="runs/ad_mlp")

``checkpoint`` is a run folder (its last epoch), ``RUN/checkpoints`` or one
``RUN/checkpoints/<epoch>``; the model config comes from the checkpoint
(``models.base.policy_from_checkpoint``). Without a checkpoint the environment variable
``DRIVEE2E_AD_MLP_CHECKPOINT`` is used (so ``drivee2e bench --policy
drivee2e_jax/zoo/ad_mlp.py`` works); with neither, the bundled weights
``drivee2e_jax/zoo/weights/ad_mlp.npz`` (``models.bundled``, docs/baselines.md
"Policy zoo"); with none of the three, a one-line error names them.
See drivee2e_jax/models/ad_mlp.py for the network.
"""

import os

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import bundled as bw
from drivee2e_jax.zoo._weights import learned_policy

ENV = "DRIVEE2E_AD_MLP_CHECKPOINT"


def make_policy(checkpoint=None):
    checkpoint = checkpoint or os.environ.get(ENV)
    if not checkpoint and not bw.has_bundled("ad_mlp"):
        npz, _ = bw.bundled_paths("ad_mlp")
        raise DriveE2EError(f"drivee2e_jax/zoo/ad_mlp.py: no checkpoint (pass make_policy(checkpoint=RUN_DIR) or set "
                            f"${ENV}) and no bundled weights ({npz} missing)")
    return learned_policy("ad_mlp", "traj", "ad_mlp", checkpoint or None)
