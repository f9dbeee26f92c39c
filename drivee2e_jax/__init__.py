"""drivee2e-jax: a JAX ego-closed-loop replay benchmark for end-to-end driving.

Data path: scenario records -> packed arrays (``Scenario``) -> ``SimState`` ->
observations -> policy -> action -> dynamics -> infractions -> metrics -> results.
"""

__version__ = "0.1.0"

import importlib

# The public names load on first use: `import drivee2e_jax` imports neither JAX
# nor Flax, so the CLI starts fast and the JAX-free parts (host policies, the
# policy server) run in environments without JAX.
_LAZY = {
    "load_suite": ("drivee2e_jax.scenario", "load_suite"),
    "Simulator": ("drivee2e_jax.sim", "Simulator"),
    "SimConfig": ("drivee2e_jax.sim", "SimConfig"),
    "evaluate": ("drivee2e_jax.eval.closedloop", "evaluate"),
    "load_policy": ("drivee2e_jax.policy", "load_policy"),
    "metrics": ("drivee2e_jax.metrics", None),
    "enable_compile_cache": ("drivee2e_jax.compile_cache", "enable"),
}


def __getattr__(name):
    if name in _LAZY:
        mod, attr = _LAZY[name]
        m = importlib.import_module(mod)
        return m if attr is None else getattr(m, attr)
    raise AttributeError(f"module 'drivee2e_jax' has no attribute {name!r}")


__all__ = list(_LAZY)
