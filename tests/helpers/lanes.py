"""Hand-built lanes for the per-tick lane facts: centrelines -> the map fields
``infractions.ego_lanes`` reads (lanes, their area polygons, types) -> ``EgoLanes``."""

from __future__ import annotations

from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np

from drivee2e_jax import infractions as inf
from drivee2e_jax.records import LaneRecord
from drivee2e_jax.scenario.lane_polygons import packed_lane_polygon
from drivee2e_jax.types import LaneType, Polylines


def polylines(polys, n=None):
    """Padded ``types.Polylines`` of point lists (vertices a valid prefix), ``n`` points per row (default: the longest)."""
    n = max(len(p) for p in polys) if n is None else n
    xy = np.zeros((len(polys), n, 2), np.float32)
    pv = np.zeros((len(polys), n), bool)
    for i, p in enumerate(polys):
        xy[i, : len(p)] = p
        pv[i, : len(p)] = True
    return Polylines(xy=jnp.asarray(xy), point_valid=jnp.asarray(pv), valid=jnp.asarray(pv.any(1)))


def lane_map(centrelines, widths=3.5, types=None, valid=None):
    """The lane fields of a ``MapData`` for centrelines (driving direction),
    widths (m) and ``LaneType``s; ``valid`` (M,) marks padded lanes."""
    m = len(centrelines)
    widths = np.broadcast_to(np.asarray(widths, float), (m,))
    types = np.zeros(m, np.int32) if types is None else np.asarray(types, np.int32)
    polys = [packed_lane_polygon(LaneRecord(id=i, centerline=np.asarray(c, float), width=float(w)))
             for i, (c, w) in enumerate(zip(centrelines, widths))]
    lanes, areas = polylines([np.asarray(c, float) for c in centrelines]), polylines(polys)
    if valid is not None:
        ok = jnp.asarray(valid)
        lanes = lanes.replace(valid=lanes.valid & ok)
        areas = areas.replace(valid=areas.valid & ok, point_valid=areas.point_valid & ok[:, None])
    return SimpleNamespace(lanes=lanes, lane_polygons=areas, lane_type=jnp.asarray(types))


def ego_lanes(ego, ego_lw, lmap, rear_offset=1.45):
    """``infractions.EgoLanes`` of ``ego`` on ``lane_map(...)``."""
    index = inf.lane_index(lmap.lane_polygons)
    return inf.ego_lanes(ego, jnp.asarray(ego_lw, jnp.float32), rear_offset, index, lmap)


CONNECTOR = int(LaneType.CONNECTOR)
DRIVING = int(LaneType.DRIVING)
