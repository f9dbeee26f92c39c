"""The three-scenario ``road3`` suite folder of the CLI tests, and a bench run on it."""

from __future__ import annotations

from pathlib import Path

from drivee2e_jax.records import SuiteRecord
from drivee2e_jax.scenario.schema import write_suite
from tests.helpers import sim_scenarios as ss


def write(folder: Path) -> Path:
    """Write ``road3`` into ``folder``: three hand-built scenarios with known
    outcomes on two maps (``clean``, ``car_ahead`` blocked by a car, a red
    light). Returns the suite folder."""
    maps = {m.map_id: m for m in (ss.road_map(), ss.road_map(obstacle=True))}
    scns = [ss.clean(), ss.blocked_by_car(), ss.red_light()]
    return write_suite(SuiteRecord("road3", "1", maps, scns), folder)


def bench(suite_dir, out, *extra) -> int:
    """``drivee2e bench`` of ``log_replay`` and ``stop`` on ``suite_dir`` into ``out``: the exit code."""
    from drivee2e_jax.cli import main

    return main(["bench", "--suite", str(suite_dir), "--out", str(out), "--no-progress",
                 "--policy", "log_replay", "--policy", "stop", *extra])
