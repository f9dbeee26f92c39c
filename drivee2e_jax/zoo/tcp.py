"""`tcp`: the TCP-like baseline with situation-based fusion (the source's "TCP" row).

A BEV + ego-state + command network (``drivee2e_jax/models/tcp.py``) with a
trajectory head and a control head. ``mode``:

* ``fused`` (this file's default, policy name ``tcp``): TCP's blend
  (``models.base.fuse_controls``): the trajectory goes through the waypoint
  controller; going straight the trajectory branch leads (0.7 / 0.3), turning
  (more than 10 of the last 20 fused steers above 0.1, TCP's memory, kept in
  the policy state) the control branch leads;
* ``traj`` (``drivee2e_jax/zoo/tcp_traj.py``, "TCP-traj"): waypoints only, tracked by
  the simulator's PID + pure pursuit;
* ``ctrl`` (``drivee2e_jax/zoo/tcp_ctrl.py``, "TCP-ctr"): the control head only.

Usage: ``load_policy("drivee2e_jax/zoo/tcp.py", checkpoint=RUN_DIR)`` or
``BenchConfig(policies=("tcp",), policy_kwargs=({"checkpoint": RUN_DIR},))``,
where RUN_DIR is a ``drivee2e train --model tcp`` run folder, its
``checkpoints/`` or one ``checkpoints/<epoch>`` (the model config is read
from the checkpoint; ``models.base.policy_from_checkpoint``). Without a
checkpoint the bundled weights ``drivee2e_jax/zoo/weights/<name>.npz`` of
the mode's policy name are loaded (``tcp``, ``tcp_traj``, ``tcp_ctrl``; the
latter two fall back to the ``tcp`` pair: one network, two heads;
``models.bundled``, docs/baselines.md "Policy zoo"); with none bundled (or
``bundled=False``) the parameters are a fresh random init (smoke tests only). The
simulator renders the BEV the training data was rendered at (the dataset's
``--bev-size``, recorded in its manifest; 128 x 128 at 0.5 m/px by default,
which the model max-pools to its 64 x 64; ``--bev-size 64`` renders TCP's
own input, 4x cheaper); a ``SimConfig`` that sets another BEV is refused.
"""

from __future__ import annotations

from drivee2e_jax.models import base
from drivee2e_jax.zoo._weights import learned_policy

MODES = {"fused": "tcp", "traj": "tcp_traj", "ctrl": "tcp_ctrl"}


def make_policy(checkpoint=None, mode: base.Mode = "fused", bundled: bool = True, **config) -> base.ModelPolicy:
    if mode not in MODES:
        raise ValueError(f"tcp: mode must be one of {', '.join(MODES)}, got {mode!r}")
    name = MODES[mode]
    return learned_policy("tcp", mode, name, checkpoint, bundles=tuple(dict.fromkeys((name, "tcp"))),
                          bundled=bundled, **config)
