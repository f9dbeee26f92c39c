"""How often nuPlan TTC's culling cut a track it could have needed (issue 35 item 4).

The ``nuplan`` tick box-tests at most ``TTC_AGENT_CANDIDATES`` agents and
``TTC_OBSTACLE_CANDIDATES`` static obstacles per tick, chosen among those
that are relevant and whose closest approach passes the reach bound
(``metrics.nuplan.ttc_candidates``: every one that can overlap the projected
ego qualifies). ``NuplanTick.ttc_reachable`` counts the qualifying ones,
``ttc_overflow`` flags a tick where more qualified than were tested. This runs
the closed loop under ``--preset nuplan`` and prints, per policy, the active
ticks, the largest ``ttc_reachable``, and the ticks / episodes that overflowed.

    PYTHONPATH=$PWD python experiments/oracles/ttc_coverage.py --policy expert --policy constant_velocity --limit 60

For each episode whose TTC column fails (some active tick with TTC <= 0.95 s)
it also prints the first such tick and, with shapely on the host, nuPlan's
projection loop (``tests/helpers/nuplan_cases.shapely_ttc``) of the ego
against the map's static obstacle polygons alone: where that matches the
tick's TTC, the failure is an obstacle (which the step did not project before
issue 35 item 4).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.metrics.driving_score import score_preset
from drivee2e_jax.policy import load_policy
from drivee2e_jax.scenario.suite import load_suite
from drivee2e_jax.sim import SimConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests.helpers.nuplan_cases import shapely_ttc  # noqa: E402


def _obstacle_ttc(xy, yaw, speed, ego_lw, obstacles) -> float:
    """Shapely nuPlan TTC of the ego against the static obstacle polygons only."""
    polys = [[tuple(p) for p in np.asarray(obstacles.xy[o])[np.asarray(obstacles.point_valid[o])]]
             for o in np.flatnonzero(np.asarray(obstacles.valid))]
    polys = [p for p in polys if len(p) >= 3]
    return shapely_ttc((float(xy[0]), float(xy[1]), float(yaw), float(speed)), tuple(map(float, ego_lw)), [], polys)


def coverage(policy_name: str, suite, split: str, limit: int | None) -> dict:
    """Overflow statistics of one policy's rollout (numbers only, no scoring)."""
    res = evaluate(load_policy(policy_name), suite, split,
                   config=SimConfig(score=score_preset("nuplan")), limit=limit)
    act = np.asarray(res.logs.active, bool)  # (B, T)
    tick = res.logs.facts.nuplan
    reach = np.where(act, np.asarray(tick.ttc_reachable), 0)
    over = act & np.asarray(tick.ttc_overflow, bool)
    ids = [r["scenario_id"] for r in res.rows]
    packed = suite.pack(split)
    ttc = np.asarray(tick.ttc_s)
    speed = np.asarray(res.logs.speed)
    fails = {}
    for i in np.flatnonzero((act & (ttc <= 0.95) & (speed > 5e-3)).any(1)):
        k = int(np.flatnonzero(act[i] & (ttc[i] <= 0.95) & (speed[i] > 5e-3))[0])
        sc = packed.scenario
        entry = {"tick": k, "t_s": round(float(res.logs.t[i, k]), 2), "ttc_s": round(float(ttc[i, k]), 2)}
        m = sc.map.obstacles
        one = type(m)(xy=m.xy[i], point_valid=m.point_valid[i], valid=m.valid[i])
        e = int(np.asarray(sc.ego_index)[i])
        entry["shapely_obstacles_ttc_s"] = round(_obstacle_ttc(
            res.logs.xy[i, k], res.logs.yaw[i, k], speed[i, k], np.asarray(sc.tracks.size[i, e, :2]), one), 2)
        fails[ids[i]] = entry
    return {
        "policy": policy_name, "episodes": int(act.shape[0]), "active_ticks": int(act.sum()),
        "max_reachable": int(reach.max()) if reach.size else 0,
        "p99_reachable": float(np.percentile(reach[act], 99)) if act.any() else 0.0,
        "overflow_ticks": int(over.sum()),
        "overflow_episodes": [ids[i] for i in np.flatnonzero(over.any(1))],
        "ttc_failures": fails,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="twin15")
    ap.add_argument("--split", default="val")
    ap.add_argument("--policy", action="append", default=None)
    ap.add_argument("--limit", type=int, default=None)
    args = ap.parse_args(argv)
    suite = load_suite(args.suite)
    for name in args.policy or ["expert"]:
        print(json.dumps(coverage(name, suite, args.split, args.limit)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
