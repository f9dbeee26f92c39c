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
