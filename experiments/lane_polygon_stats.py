"""Lane area polygons per map of a suite: sources, vertex counts, centreline
containment and coverage of the drivable areas (issue 35, item 2).

    PYTHONPATH=$PWD python experiments/lane_polygon_stats.py <suite folder or twin15> ...
"""

from __future__ import annotations

import sys

import numpy as np
import shapely
from shapely.geometry import Point, Polygon

from drivee2e_jax.scenario import twin15
from drivee2e_jax.scenario.lane_polygons import lane_polygon_source, packed_lane_polygon
from drivee2e_jax.scenario.schema import read_suite


def stats(name: str) -> None:
    maps = twin15.maps() if name == "twin15" else read_suite(name).maps
    for mid, m in sorted(maps.items()):
        polys = [packed_lane_polygon(ln) for ln in m.lanes]
        src = [lane_polygon_source(ln) for ln in m.lanes]
        shp = [Polygon(p) for p in polys]
        inside = [np.mean([s.buffer(1e-3).contains(Point(q)) for q in ln.centerline]) for s, ln in zip(shp, m.lanes)]
        # AV2 centrelines end on the lane's end chord (rounded to ~5 mm): within 1 cm counts them in
        near = [np.mean([s.distance(Point(q)) <= 0.01 for q in ln.centerline]) for s, ln in zip(shp, m.lanes)]
        far = max(max(s.distance(Point(q)) for q in ln.centerline) for s, ln in zip(shp, m.lanes))
        nv = [len(p) for p in polys]
        line = (f"{name} map {mid}: lanes {len(m.lanes)}, own polygon {src.count('polygon')}, "
                f"from boundaries {src.count('boundaries')}, "
                f"centreline {src.count('centerline')}, valid {sum(s.is_valid for s in shp)}, "
                f"vertices max {max(nv)} mean {np.mean(nv):.1f}, centreline points inside own polygon "
                f"{100 * np.mean(inside):.2f} % (within 1 cm {100 * np.mean(near):.2f} %, farthest {far:.3f} m)")
        if m.drivable_areas:
            lanes = shapely.union_all([shapely.make_valid(s) for s in shp])
            road = shapely.union_all([shapely.make_valid(Polygon(p)) for p in m.drivable_areas])
            line += (f"; drivable {road.area:.0f} m2, drivable minus lanes {road.difference(lanes).area:.0f} m2, "
                     f"lanes minus drivable {lanes.difference(road).area:.0f} m2")
        else:
            line += "; no drivable_areas"
        print(line, flush=True)


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        stats(arg)
