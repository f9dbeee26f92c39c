"""Headless sweeps from experiment configs (``drivee2e sweep experiments/<name>.toml``).

``config``: the TOML file <-> frozen dataclasses, checked; ``runner``: the
grid of runs, each a ``bench`` results folder, resumable, plus combined tables.
"""

from drivee2e_jax.sweep.config import SweepConfig, load_config, parse_config
from drivee2e_jax.sweep.runner import Run, expand, run_sweep

__all__ = ["Run", "SweepConfig", "expand", "load_config", "parse_config", "run_sweep"]
