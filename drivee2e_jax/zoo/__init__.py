"""The policy zoo: reference policies shipped with the package, found by name.

Each ``<name>.py`` here is a policy file (``make_policy()`` or ``POLICY``)
loaded by path, never imported as a module: ``drivee2e bench --policy
expert`` resolves to ``drivee2e_jax/zoo/expert.py``
(``drivee2e_jax.policy.resolve_policy_path``). Rule-based: ``log_replay``,
``expert``, ``stop``, ``constant_velocity``. Learned (need a checkpoint
argument or environment variable, see each file): ``ad_mlp``, ``tcp``,
``tcp_traj``, ``tcp_ctrl``, ``vector_transformer``.
"""
