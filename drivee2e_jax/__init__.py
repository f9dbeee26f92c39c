"""drivee2e-jax: a JAX ego-closed-loop replay benchmark for end-to-end driving.

Data path: scenario records -> packed arrays (``Scenario``) -> ``SimState`` ->
observations -> policy -> action -> dynamics -> infractions -> metrics -> results.
"""

__version__ = "0.1.0"
