"""The recorded-traffic formats ``drivee2e suite import`` reads (no heavy imports).

``FORMATS`` maps each CLI format name to its importer module in
``drivee2e_jax/scenario/importers/``; a new importer is that module plus one
line here. Kept apart from the importers so the CLI can list the formats
without importing numpy, shapely or JAX.
"""

#: CLI format name -> module name in ``drivee2e_jax.scenario.importers``.
FORMATS: dict[str, str] = {
    "lanelet2-csv": "lanelet2_csv",
    "argoverse2": "argoverse2",
    "scenarionet": "scenarionet",
    "commonroad": "commonroad",
    "opendrive": "opendrive",
}
