"""Every nuPlan and NAVSIM sub-metric per policy, from two ``drivee2e bench`` folders.

    drivee2e bench --split val --preset nuplan --policy log_replay --policy expert ... --out R_NUPLAN
    drivee2e bench --split val --preset navsim --policy log_replay --policy expert ... --out R_NAVSIM
    python experiments/presets/table.py R_NUPLAN R_NAVSIM

Prints two markdown tables (the ones in ``docs/results.md``, "The log, the
expert and the baselines under the nuPlan and NAVSIM presets"): per policy the
mean of each column over its episodes, and for the multipliers (nuPlan's
collisions, drivable area, progress, direction; NAVSIM's NC, DAC, DDC, TLC)
the number of episodes below 1 in brackets. Policies appear in the order of
the first folder's rows.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

NUPLAN = [("nuplan_no_ego_at_fault_collisions", "collisions", True),
          ("nuplan_drivable_area_compliance", "drivable", True),
          ("nuplan_ego_is_making_progress", "making progress", True),
          ("nuplan_driving_direction_compliance", "direction", True),
          ("nuplan_ego_progress_along_expert_route", "progress", False),
          ("nuplan_time_to_collision_within_bound", "TTC", False),
          ("nuplan_speed_limit_compliance", "speed limit", False),
          ("nuplan_ego_is_comfortable", "comfortable", False),
          ("nuplan_score", "**score**", False)]
NAVSIM = [("navsim_nc", "NC", True), ("navsim_dac", "DAC", True), ("navsim_ddc", "DDC", True),
          ("navsim_tlc", "TLC", True), ("navsim_ep", "EP", False), ("navsim_ttc", "TTC", False),
          ("navsim_lk", "LK", False), ("navsim_hc", "HC", False), ("navsim_ec", "EC", False),
          ("epdms", "**EPDMS**", False)]


def rows_by_policy(folder: Path) -> dict[str, list[dict]]:
    path = folder / "scenarios.csv"
    if not path.is_file():
        raise SystemExit(f"{path}: missing; expected the scenarios.csv of a finished drivee2e bench folder")
    out: dict[str, list[dict]] = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            out.setdefault(row["policy"], []).append(row)
    return out


def table(rows: dict[str, list[dict]], cols: list[tuple[str, str, bool]]) -> str:
    present = [c for c in cols if any(c[0] in r[0] for r in rows.values())]
    if not present:
        raise SystemExit(f"none of the columns {cols[0][0]}... in this folder: was it run with the matching --preset?")
    head = ["policy", "n", "DS", *(c[1] for c in present)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for pol, rs in rows.items():
        cells = [pol, str(len(rs)), f"{sum(float(r['driving_score']) for r in rs) / len(rs):.2f}"]
        for key, _, multiplier in present:
            v = [float(r[key]) for r in rs]
            cell = f"{sum(v) / len(v):.3f}"
            if multiplier:
                cell += f" ({sum(x < 1.0 for x in v)})"
            cells.append(cell)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[0], "\nusage: python experiments/presets/table.py R_NUPLAN R_NAVSIM",
              file=sys.stderr)
        return 2
    print(table(rows_by_policy(Path(argv[0])), NUPLAN))
    print()
    print(table(rows_by_policy(Path(argv[1])), NAVSIM))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
