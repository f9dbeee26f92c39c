"""How far twin15's packed lane polygons (centreline ± width/2, scenario/lane_polygons.py)
lie from the lane edges the generator itself defines (issue 35 item 2, part B).

The generator gives every lane one constant width around a dense (0.25 m) centreline
(scenario/twin15/lanes.py); its true edges are the parallel curves at ± width/2 of
that dense curve (shapely ``buffer`` with flat caps). A turn pocket's painted area
differs in its taper, where the pocket opens between the median edge
``m/2 + w (1 - taper)`` and the line at ``m/2 + w`` (scenario/twin15/markings.py):
reported separately.

    PYTHONPATH=$PWD python experiments/twin15_lane_edges.py
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
from shapely.geometry import LineString, Polygon

from drivee2e_jax.scenario.lane_polygons import packed_lane_polygon
from drivee2e_jax.scenario.twin15 import build
from drivee2e_jax.scenario.twin15.legs import leg_line, taper_weight


def main() -> None:
    worst: dict[str, list[float]] = defaultdict(list)
    pocket_painted: list[tuple[str, float, float]] = []
    for sp in build.SPECS:
        lay = build.build_layout(sp.map_id)
        for rec, info in zip(lay.map.lanes, lay.lanes.info):
            fallback = Polygon(packed_lane_polygon(rec))
            true = LineString(info.dense).buffer(0.5 * rec.width, cap_style="flat", join_style="round",
                                                  quad_segs=16)
            worst[info.role].append(fallback.hausdorff_distance(true))
            if info.role == "pocket":
                leg = lay.legs[info.leg]
                e, w, m = leg.entries[info.index], leg.spec.lane_width, leg.spec.median
                d0, d1 = leg.d_stop, leg.d_split
                if e.kind == "left_pocket":
                    inner = leg_line(leg, d0, d1, lambda d, leg=leg, m=m, w=w: m / 2 + w * (1 - taper_weight(d - leg.d_stop)))
                    outer = leg_line(leg, d0, d1, m / 2 + w)
                else:  # right pocket: between the last through lane's edge and the tapering kerb
                    inner = leg_line(leg, d0, d1, e.offset - e.width / 2)
                    outer = leg_line(leg, d0, d1, leg.kerb_in)
                painted = Polygon(np.concatenate([inner, outer[::-1]])).buffer(0)
                pocket_painted.append((f"{sp.map_id} lane {rec.id}", fallback.hausdorff_distance(painted),
                                       fallback.symmetric_difference(painted).area))
    for role, v in sorted(worst.items()):
        v = np.asarray(v)
        print(f"{role:12s} lanes {len(v):4d}: Hausdorff(fallback polygon, dense centreline ± w/2) "
              f"max {v.max():.4f} m, mean {v.mean():.4f} m")
    if pocket_painted:
        h = np.array([p[1] for p in pocket_painted])
        a = np.array([p[2] for p in pocket_painted])
        print(f"pockets vs their painted area (median edge / lane line / kerb, d_stop..d_split): "
              f"{len(h)} pockets, Hausdorff max {h.max():.2f} m mean {h.mean():.2f} m, "
              f"symmetric difference max {a.max():.1f} m2 mean {a.mean():.1f} m2")


if __name__ == "__main__":
    main()
