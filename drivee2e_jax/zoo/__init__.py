"""The policy zoo: reference policies shipped with the package, found by name.

Each ``<name>.py`` here is a policy file (``make_policy()`` or ``POLICY``)
loaded by path, never imported as a module: ``drivee2e bench --policy
expert`` resolves to ``drivee2e_jax/zoo/expert.py``
(``drivee2e_jax.policy.resolve_policy_path``). Rule-based: ``log_replay``,
``expert``, ``stop``, ``constant_velocity``. Learned: ``ad_mlp``, ``tcp``,
``tcp_traj``, ``tcp_ctrl``, ``vector_transformer``, ``vector_transformer_ft``,
``ppo``: a checkpoint argument (``checkpoint=RUN``), else the trained weights
bundled in ``weights/<name>.npz`` + ``<name>.json`` (``models/bundled.py``,
loaded by ``_weights.py``; docs/baselines.md "Policy zoo"), else each file's
fallback (a random init or a one-line error, see each file).
"""
