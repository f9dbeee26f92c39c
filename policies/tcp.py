"""`tcp`: the TCP-like baseline with situation-based fusion (the source's "TCP" row).

A BEV + ego-state + command network (``drivee2e_jax/models/tcp.py``) with a
trajectory head and a control head. ``mode``:

* ``fused`` (this file's default, policy name ``tcp``): TCP's blend
  (``models.base.fuse_controls``): the trajectory goes through the waypoint
  controller; going straight the trajectory branch leads (0.7 / 0.3), turning
  (|trajectory steer| > 0.1) the control branch leads;
* ``traj`` (``policies/tcp_traj.py``, "TCP-traj"): waypoints only, tracked by
  the simulator's PID + pure pursuit;
* ``ctrl`` (``policies/tcp_ctrl.py``, "TCP-ctr"): the control head only.

Usage: ``load_policy("policies/tcp.py", checkpoint=RUN_DIR)`` or
``BenchConfig(policies=("tcp",), policy_kwargs=({"checkpoint": RUN_DIR},))``,
where RUN_DIR is a ``drivee2e train --model tcp`` run folder, its
``checkpoints/`` or one ``checkpoints/<epoch>`` (the model config is read
from the checkpoint). Without a checkpoint the parameters are a fresh random
init (smoke tests only). The simulator renders the BEV at
``SimConfig.sensors``' size (default 128 x 128), which the model max-pools to
its 64 x 64; ``SimConfig(sensors=model.sensor_config)`` renders 64 x 64
directly (4x cheaper; train on the same size you drive with).
"""

from __future__ import annotations

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.models import base, get_model

MODES = {"fused": "tcp", "traj": "tcp_traj", "ctrl": "tcp_ctrl"}


class _ModelPolicy(base.ModelPolicy):
    """``base.ModelPolicy`` that initialises fresh parameters when it has none."""

    def init(self, key, obs):
        if self.params is not None:
            return self.params
        return self.model.init(key, base.with_history(obs, base.push_history(base.empty_history(obs), obs)))


def model_policy(model_name: str, checkpoint=None, mode: base.Mode = "traj", name: str | None = None,
                 **config) -> base.ModelPolicy:
    """A policy driving ``model_name`` with the parameters of ``checkpoint``
    (its stored ``model_config`` overrides ``config``), or freshly initialised."""
    params = None
    if checkpoint is not None:
        from drivee2e_jax.train import checkpoint as ckpt

        path = ckpt.resolve(checkpoint)
        meta = ckpt.read_meta(path)
        if meta.get("model", model_name) != model_name:
            raise DriveE2EError(f"{checkpoint}: a {meta['model']!r} checkpoint, expected a {model_name!r} one")
        config = {**config, **meta.get("model_config", {})}
        params = ckpt.load_params(path)
    return _ModelPolicy(get_model(model_name, **config), params, mode, name=name)


def make_policy(checkpoint=None, mode: base.Mode = "fused", **config) -> base.ModelPolicy:
    if mode not in MODES:
        raise ValueError(f"tcp: mode must be one of {', '.join(MODES)}, got {mode!r}")
    return model_policy("tcp", checkpoint, mode, name=MODES[mode], **config)
