"""Map clean-up for sources without a full lane graph (see
``importers.common``): ``map_marking``, ``infer_successors``, ``crop_map``."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.polyline import polyline_heading, resample_polyline, wrap_angle
from drivee2e_jax.records import MARKINGS, LaneRecord, MapRecord

__all__ = ["map_marking", "infer_successors", "crop_map"]


def map_marking(value: str, table: Mapping[str, str], where: str) -> str:
    """Source marking name -> records.MARKINGS name; unknown values are an error naming ``where``."""
    m = table.get(value)
    if m is None:
        raise DriveE2EError(f"{where}: unknown lane marking {value!r}; expected one of {', '.join(sorted(table))}")
    assert m in MARKINGS, m
    return m


def infer_successors(lanes: list[LaneRecord], tol_m: float = 1.0, max_angle: float = math.pi / 4) -> None:
    """Fill each lane's ``successors`` (in place) from geometry: lane b follows
    lane a when b starts within ``tol_m`` of a's end and their headings there
    differ by less than ``max_angle``."""
    usable = [ln for ln in lanes if len(ln.centerline) >= 2]
    if not usable:
        return
    starts = np.array([ln.centerline[0, :2] for ln in usable])
    for a in usable:
        end = a.centerline[-1, :2]
        ha = polyline_heading(a.centerline, at_end=True)
        near = np.nonzero(np.linalg.norm(starts - end, axis=1) <= tol_m)[0]
        succ = []
        for j in near:
            b = usable[j]
            if b.id == a.id:
                continue
            if abs(wrap_angle(polyline_heading(b.centerline) - ha)) < max_angle:
                succ.append(b.id)
        a.successors = sorted(set(a.successors) | set(succ))


def _near(points: np.ndarray, xy: np.ndarray, radius: float) -> bool:
    p = np.asarray(points, np.float64).reshape(-1, 2)
    if p.size == 0:
        return False
    d = np.min(np.linalg.norm(p[:, None, :] - xy[None, :, :], axis=2))
    return bool(d <= radius)


def crop_map(m: MapRecord, xy: np.ndarray, radius_m: float) -> MapRecord:
    """The part of ``m`` within ``radius_m`` of any point of ``xy`` (k, 2).

    Polylines and polygons are kept whole when any of their points (after
    densifying to 2 m) is near; successors pointing at dropped lanes are removed.
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    xy = xy[:: max(1, len(xy) // 200)]

    def near(p: np.ndarray) -> bool:
        return _near(resample_polyline(np.asarray(p)[:, :2], 2.0, dedupe_tol=0.0, count_slack=0.0), xy, radius_m)

    lanes = [replace(ln) for ln in m.lanes if near(ln.centerline)]
    kept = {ln.id for ln in lanes}
    for ln in lanes:
        ln.successors = [s for s in ln.successors if s in kept]
    return replace(
        m, lanes=lanes,
        boundaries=[b for b in m.boundaries if near(b.points)],
        crosswalks=[c for c in m.crosswalks if near(np.vstack([c, c[:1]]))],
        stop_lines=[s for s in m.stop_lines if near(s.points) and (s.lane_id in kept or s.lane_id == -1)],
        drivable_areas=[g for g in m.drivable_areas if near(np.vstack([g, g[:1]]))],
        obstacles=[o for o in m.obstacles if near(np.vstack([o.polygon, o.polygon[:1]]))],
    )
