"""The step's map facts agree with shapely on re-simulated twin15 episodes.

A ``drivee2e bench --preset nuplan`` run of the expert and constant velocity
on the first twin15 val scenarios, re-simulated (``eval.traces``), against
``tests/helpers/map_oracle.py`` (shapely on the suite's own drivable polygons):
the drivable excess at every instant, nuPlan's / NAVSIM's DAC and nuPlan's
driving-direction compliance per episode, and ``multi_lane`` at (nearly)
every instant. Constant velocity drives straight where its route turns, so some of
its episodes leave the road by far more than 0.3 m: the comparison is not
vacuous (asserted).
"""

from __future__ import annotations

import pytest

from drivee2e_jax.cli import main
from drivee2e_jax.eval import traces
from tests.helpers import map_oracle

N = 16


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("oracle") / "run"
    rc = main(["bench", "--suite", "twin15", "--split", "val", "--limit", str(N), "--preset", "nuplan",
               "--policy", "expert", "--policy", "constant_velocity", "--out", str(out), "--no-progress"])
    assert rc == 0
    return out


@pytest.mark.parametrize("policy", ["expert", "constant_velocity"])
def test_drivable_area_matches_shapely(run, policy):
    maps = traces.read_run(run, policy).spec.load_suite().maps
    worst = 0.0
    for tr in traces.iter_traces(run, policy, sensors=()):
        oracle = map_oracle.episode_oracle(tr, maps[tr.meta["map_id"]])
        cmp = map_oracle.compare(tr, oracle)
        assert cmp["excess_agree"] == 1.0, (tr.scenario_id, cmp)
        assert cmp["dac_nuplan"][0] == cmp["dac_nuplan"][1], (tr.scenario_id, cmp)
        assert cmp["dac_navsim"][0] == cmp["dac_navsim"][1], (tr.scenario_id, cmp)
        assert cmp["nuplan_drivable_area_compliance"] == (0.0 if cmp["dac_nuplan"][1] else 1.0)
        # Lane polygons: float32 point-in-polygon against shapely's covers, 1 mm simplification.
        assert cmp["multi_lane_agree"] >= 0.98, (tr.scenario_id, cmp)
        # A worst 1 s window within 5 cm of a threshold may tip either way (see map_oracle).
        assert cmp["direction"][0] == cmp["direction"][1] or cmp["direction_borderline"], (tr.scenario_id, cmp)
        assert cmp["lanes_overflow_steps"] == 0
        worst = max(worst, cmp["excess_max"][1])
    if policy == "constant_velocity":
        assert worst > map_oracle.NUPLAN_DAC_M  # it leaves the road somewhere: the check can fail


@pytest.fixture(scope="module")
def navsim_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("oracle_navsim") / "run"
    rc = main(["bench", "--suite", "twin15", "--split", "val", "--limit", "8", "--preset", "navsim",
               "--policy", "expert", "--policy", "constant_velocity", "--out", str(out), "--no-progress"])
    assert rc == 0
    return out


def test_navsim_lane_keeping_matches_shapely(navsim_run):
    """LK's deviation (centre to the centreline of the lane polygon holding it, NAVSIM's
    Point.distance(linestring)) and the LK column, against shapely on the suite's lanes."""
    worst, cols = 0.0, []
    for policy in ("expert", "constant_velocity"):
        maps = traces.read_run(navsim_run, policy).spec.load_suite().maps
        for tr in traces.iter_traces(navsim_run, policy, sensors=()):
            oracle = map_oracle.episode_oracle(tr, maps[tr.meta["map_id"]])
            cmp = map_oracle.compare(tr, oracle)
            assert cmp["lk_instant_agree"] >= 0.99, (policy, tr.scenario_id, cmp)
            assert cmp["lk"][0] == cmp["lk"][1], (policy, tr.scenario_id, cmp)
            assert cmp["navsim_lk"] >= cmp["lk"][0]  # the column: the human filter may only raise it
            worst = max(worst, float(oracle["lk_deviation"][~oracle["lk_junction"]].max(initial=0.0)))
            cols.append(cmp["lk"][1])
    assert worst > map_oracle.LK_DEVIATION_M  # some deviation exceeds the limit: the check can fail
