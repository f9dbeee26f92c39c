"""Layer 3: evaluating policies on a suite and writing what was found.

* ``closedloop``: ``evaluate`` -- one policy, one split, one batched rollout ->
  per-scenario rows and infraction events.
* ``openloop``: a waypoint policy scored on the logged demonstrations (L2,
  collision rate).
* ``tasks``: Behavior Metrics driving tasks (scenario filter + success rule).
* ``variants``: occlusion-filtered suite variants (visibility masks, cached).
* ``runspec``: the typed run specification (``run.json``) that builds the batch,
  simulator config and timing for the bench and for re-simulation alike.
* ``bench``: the main job (policies x split), ``summary``: aggregates and
  console tables, ``results``: the resumable results folder, ``report`` +
  ``plots``: ``report.md``.
* ``traces``: re-simulating a results folder's episodes for the player and MCAP.
* ``distributed``: several processes / hosts (``jax.distributed``).
"""
