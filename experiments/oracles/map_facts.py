"""Check a results folder's map facts against shapely on the map's own polygons.

Re-simulates every episode of a ``drivee2e bench`` results folder
(``eval.traces.iter_traces``, no sensors) and recomputes, on the host with
shapely, what the compiled step judged from the map: how far the ego's
corners are outside the union of the drivable polygons (nuPlan DAC at
>= 0.3 m, NAVSIM DAC at > 0), whether a single lane polygon holds the ego
(``multi_lane``), nuPlan's driving-direction compliance (travel against
the lane polygon holding the ego centre, 1 s windows) and, under ``--preset
navsim``, NAVSIM's lane-keeping deviation (the centre's distance to the
centreline of the lane holding it) and LK column. Prints, per policy, the episode agreement of both DACs,
the per-instant agreement, and every disagreeing episode.

    python experiments/oracles/map_facts.py results/twin15-val
    python experiments/oracles/map_facts.py results/twin15-val --policy expert --limit 50 --json out.json

The oracle itself is ``tests/helpers/map_oracle.py`` (also used by the tests).
Exit code 1 when an agreement is below ``--min-agree`` (default 0.99).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

from drivee2e_jax.eval import traces

# The oracle is loaded from its file, not through sys.path, so that the code
# under test is whichever drivee2e_jax is importable (PYTHONPATH=<another
# checkout> checks that checkout with this oracle).
_ORACLE = Path(__file__).resolve().parents[2] / "tests" / "helpers" / "map_oracle.py"
_spec = importlib.util.spec_from_file_location("map_oracle", _ORACLE)
map_oracle = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(map_oracle)


def check_policy(results: str, policy: str, limit: int | None) -> dict:
    """Per-episode comparisons of one policy's episodes (``map_oracle.compare``)."""
    run = traces.read_run(results, policy)
    maps = run.spec.load_suite().maps
    out = {}
    for tr in traces.iter_traces(results, policy, sensors=(), limit=limit):
        cmp = map_oracle.compare(tr, map_oracle.episode_oracle(tr, maps[tr.meta["map_id"]]))
        out[tr.scenario_id] = cmp
    return out


def summarize(policy: str, per_episode: dict) -> dict:
    n = len(per_episode)
    rows = list(per_episode.values())
    s = {"policy": policy, "episodes": n}
    for key in ("dac_nuplan", "dac_navsim"):
        agree = [r[key][0] == r[key][1] for r in rows]
        s[f"{key}_agree"] = float(np.mean(agree)) if n else 1.0
        s[f"{key}_sim_fails"] = int(sum(r[key][0] for r in rows))
        s[f"{key}_oracle_fails"] = int(sum(r[key][1] for r in rows))
        s[f"{key}_disagree"] = [sid for sid, r in per_episode.items() if r[key][0] != r[key][1]]
    dirs = [r["direction"] for r in rows if "direction" in r]
    s["direction_agree"] = float(np.mean([a == b for a, b in dirs])) if dirs else None
    s["direction_disagree"] = [sid + (" (borderline)" if r["direction_borderline"] else "")
                               for sid, r in per_episode.items()
                               if "direction" in r and r["direction"][0] != r["direction"][1]]
    lks = [r["lk"] for r in rows if "lk" in r]
    s["lk_agree"] = float(np.mean([a == b for a, b in lks])) if lks else None
    s["lk_disagree"] = [sid for sid, r in per_episode.items() if "lk" in r and r["lk"][0] != r["lk"][1]]
    inst = [r["lk_instant_agree"] for r in rows if "lk_instant_agree" in r]
    s["lk_instant_agree"] = float(np.mean(inst)) if inst else None
    s["lk_worst_gap_m"] = max((r["lk_worst_gap_m"] for r in rows if "lk_worst_gap_m" in r), default=None)
    s["excess_instant_agree"] = float(np.mean([r["excess_agree"] for r in rows])) if n else 1.0
    s["multi_lane_instant_agree"] = float(np.mean([r["multi_lane_agree"] for r in rows])) if n else 1.0
    s["lanes_overflow_steps"] = int(sum(r["lanes_overflow_steps"] for r in rows))
    s["worst_excess_gap_m"] = max((abs(r["excess_max"][0] - r["excess_max"][1]) for r in rows), default=0.0)
    return s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("results", help="a drivee2e bench results folder")
    ap.add_argument("--policy", action="append", help="policy in the folder (repeatable; default: all)")
    ap.add_argument("--limit", type=int, default=None, help="only the first N episodes per policy")
    ap.add_argument("--json", default=None, help="write the per-episode comparisons here")
    ap.add_argument("--min-agree", type=float, default=0.99, help="exit 1 below this DAC agreement")
    a = ap.parse_args(argv)
    policies = a.policy or traces.run_policies(a.results)
    ok, dump = True, {}
    for p in policies:
        per = check_policy(a.results, p, a.limit)
        s = summarize(p, per)
        dump[p] = {"summary": s, "episodes": per}
        print(f"{p}: {s['episodes']} episodes")
        for key, label in (("dac_nuplan", "nuPlan DAC (>= 0.3 m)"), ("dac_navsim", "NAVSIM DAC (> 0 m)")):
            print(f"  {label:22s} agree {100 * s[f'{key}_agree']:6.2f} %   fails: sim {s[f'{key}_sim_fails']:3d}, "
                  f"oracle {s[f'{key}_oracle_fails']:3d}   disagree: {', '.join(s[f'{key}_disagree']) or '-'}")
            ok &= s[f"{key}_agree"] >= a.min_agree
        if s["direction_agree"] is not None:
            print(f"  nuPlan driving direction agree {100 * s['direction_agree']:6.2f} %   disagree: "
                  f"{', '.join(s['direction_disagree']) or '-'}")
            ok &= s["direction_agree"] >= a.min_agree
        if s["lk_agree"] is not None:
            print(f"  NAVSIM lane keeping agree {100 * s['lk_agree']:6.2f} %   disagree: "
                  f"{', '.join(s['lk_disagree']) or '-'}")
            ok &= s["lk_agree"] >= a.min_agree
        if s["lk_instant_agree"] is not None:
            print(f"  per instant: LK deviation agree {100 * s['lk_instant_agree']:.2f} %, worst gap where a lane "
                  f"holds the centre {s['lk_worst_gap_m']:.3f} m")
        print(f"  per instant: excess agree {100 * s['excess_instant_agree']:.2f} %, multi-lane agree "
              f"{100 * s['multi_lane_instant_agree']:.2f} %, worst episode max-excess gap {s['worst_excess_gap_m']:.3f} m, "
              f"steps with more lanes than tested: {s['lanes_overflow_steps']}")
    if a.json:
        Path(a.json).write_text(json.dumps(dump, indent=1))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
