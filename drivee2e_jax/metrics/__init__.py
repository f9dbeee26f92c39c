"""What counts: leaderboard criteria, per-route scores and aggregation.

* ``criteria``: stateful per-tick criteria (route completion, deviation,
  outside lanes, collision dedup, blocked, route timeout, min speed, red-light
  memory) as pure JAX functions with typed carries.
* ``driving_score``: ``ScoreConfig`` presets and ``route_score`` (RC, IS, DS,
  status, success) for one route.
* ``aggregate``: host-side aggregation over routes (LB 2.0 global record,
  Bench2Drive merge/efficiency, DriveE2E DS/SR/abilities).
* ``finegrained``: host-side per-episode columns from a ``StepLog``, built on
  ``behavior`` (Behavior Metrics, paper and tool-code definitions) and
  ``comfort`` (Bench2Drive smoothness).
* ``openloop``: L2 and collision conventions of UniAD / ST-P3 / VAD (the
  driver that runs a policy on the demonstrations is ``drivee2e_jax.eval.openloop``).

Definitions: ``shared/reference/METRICS.md`` sections 1-5.
"""

from drivee2e_jax.metrics import aggregate, criteria, driving_score
from drivee2e_jax.metrics.driving_score import (
    INFRACTION_KEYS,
    PENALTIES,
    STATUS_NAMES,
    RouteOutcome,
    RouteScore,
    ScoreConfig,
    Status,
    route_score,
    status_name,
)
from drivee2e_jax.types import CollisionClass

__all__ = [
    "aggregate",
    "criteria",
    "driving_score",
    "CollisionClass",
    "INFRACTION_KEYS",
    "PENALTIES",
    "STATUS_NAMES",
    "RouteOutcome",
    "RouteScore",
    "ScoreConfig",
    "Status",
    "route_score",
    "status_name",
]
