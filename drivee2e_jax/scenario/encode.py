"""Records -> JSON-shaped objects and the bytes of a suite file.

``suite_obj``, ``scenario_obj``, ``map_obj`` give the on-disk objects of a
record (a track column-wise, signal states as indices); ``jsonify`` rounds
floats (``DECIMALS``) and turns numpy into lists; ``dumps`` writes the fixed
layout, so the same suite always gives the same bytes.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from drivee2e_jax.records import (
    SCHEMA_VERSION,
    MapRecord,
    RouteRecord,
    ScenarioRecord,
    SuiteRecord,
    TrackRecord,
)
from drivee2e_jax.scenario.problems import is_int

__all__ = ["DECIMALS", "suite_obj", "scenario_obj", "map_obj", "jsonify", "dumps"]

# Decimal places per JSON key when writing (1 mm, 1 mm/s, 1e-4 rad, 1e-4 s).
DECIMALS = {
    "t": 4, "x": 3, "y": 3, "yaw": 4, "vx": 3, "vy": 3, "size": 3,
    "waypoints": 3, "source": 3, "destination": 3,
    "centerline": 3, "left_boundary": 3, "right_boundary": 3, "width": 3, "speed_limit": 3, "points": 3, "polygon": 3,
    "height": 3, "crosswalks": 3, "drivable_areas": 3,
    "duration": 3, "yellow_duration": 3, "all_red": 3, "dt": 6,
}


# --------------------------------------------------------------------------
# Records -> JSON-shaped objects
# --------------------------------------------------------------------------


def _track_obj(tr: TrackRecord) -> dict:
    xy = np.asarray(tr.xy)
    x, y = (xy[:, 0], xy[:, 1]) if xy.ndim == 2 and xy.shape[1] == 2 else (xy, xy)
    out = {"track_id": tr.track_id, "category": tr.category, "size": np.asarray(tr.size),
           "t": np.asarray(tr.t), "x": x, "y": y, "yaw": np.asarray(tr.yaw)}
    if tr.vel is not None:
        vel = np.asarray(tr.vel)
        out["vx"], out["vy"] = (vel[:, 0], vel[:, 1]) if vel.ndim == 2 and vel.shape[1] == 2 else (vel, vel)
    if tr.visible is not None:
        out["visible"] = np.asarray(tr.visible)
    if tr.quality is not None:
        out["quality"] = np.asarray(tr.quality)
    return out


def _group_key(item: tuple) -> tuple:
    k = item[0]
    return (0, int(k), "") if is_int(k) else (1, 0, str(k))


def scenario_obj(s: ScenarioRecord) -> dict:
    r = s.route
    return {
        "schema_version": SCHEMA_VERSION,
        "scenario_id": s.scenario_id, "split": s.split, "intersection_id": s.intersection_id,
        "map_id": s.map_id, "behavior": s.behavior, "weather": s.weather, "time_of_day": s.time_of_day,
        "ego_track_id": s.ego_track_id, "dt": s.dt, "num_steps": s.num_steps,
        "route": {"waypoints": np.asarray(r.waypoints), "source": np.asarray(r.source),
                  "destination": np.asarray(r.destination)} if isinstance(r, RouteRecord) else r,
        "signals": {str(g): np.asarray(a) for g, a in sorted(s.signals.items(), key=_group_key)},
        "tracks": [_track_obj(t) for t in s.tracks],
    }


def _lane_obj(ln) -> dict:
    obj = {"id": ln.id, "centerline": np.asarray(ln.centerline), "width": ln.width,
           "speed_limit": ln.speed_limit, "type": ln.type, "successors": list(ln.successors),
           "left_marking": ln.left_marking, "right_marking": ln.right_marking}
    # Optional keys: written only when the lane has them, so old suites round-trip unchanged.
    if ln.left_boundary is not None:
        obj["left_boundary"] = np.asarray(ln.left_boundary)
    if ln.right_boundary is not None:
        obj["right_boundary"] = np.asarray(ln.right_boundary)
    if ln.polygon is not None:
        obj["polygon"] = np.asarray(ln.polygon)
    return obj


def map_obj(m: MapRecord) -> dict:
    return {
        "schema_version": SCHEMA_VERSION,
        "map_id": m.map_id,
        "lanes": [_lane_obj(ln) for ln in m.lanes],
        "boundaries": [{"points": np.asarray(b.points), "marking": b.marking} for b in m.boundaries],
        "crosswalks": [np.asarray(p) for p in m.crosswalks],
        "stop_lines": [{"id": s.id, "points": np.asarray(s.points), "lane_id": s.lane_id,
                        "signal_group": s.signal_group} for s in m.stop_lines],
        "drivable_areas": [np.asarray(p) for p in m.drivable_areas],
        "obstacles": [{"polygon": np.asarray(o.polygon), "height": o.height, "kind": o.kind} for o in m.obstacles],
        "signal_plan": [{"duration": p.duration, "green": list(p.green), "yellow_duration": p.yellow_duration,
                         "all_red": p.all_red} for p in m.signal_plan],
        "meta": m.meta,
    }


def suite_obj(suite: SuiteRecord) -> dict:
    return {
        "name": suite.name, "version": suite.version, "schema_version": SCHEMA_VERSION,
        "meta": suite.meta,
        "scenarios": [{"id": s.scenario_id, "split": s.split, "intersection_id": s.intersection_id,
                       "behavior": s.behavior} for s in suite.scenarios],
    }


def jsonify(v: Any, nd: int | None = None) -> Any:
    """Plain JSON values, floats rounded to ``nd`` places (-0.0 folded to 0.0)."""
    if isinstance(v, dict):
        return {str(k): jsonify(x, DECIMALS.get(str(k), nd)) for k, x in v.items()}
    if isinstance(v, np.ndarray):
        if v.dtype.kind == "b":
            return v.astype(np.int8).tolist()
        if v.dtype.kind == "f" and nd is not None:
            return (np.round(v.astype(np.float64), nd) + 0.0).tolist()
        return v.tolist()
    if isinstance(v, (list, tuple)):
        return [jsonify(x, nd) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return (round(float(v), nd) + 0.0) if nd is not None else float(v)
    return v


def dumps(obj: dict) -> str:
    """Fixed layout: one top-level key per line, one list-of-objects item per line."""
    def compact(v: Any) -> str:
        return json.dumps(v, separators=(",", ":"), ensure_ascii=False, allow_nan=False)

    lines = ["{"]
    items = list(obj.items())
    for i, (key, value) in enumerate(items):
        sep = "," if i < len(items) - 1 else ""
        if isinstance(value, list) and value and all(isinstance(e, dict) for e in value):
            lines.append(f" {json.dumps(key)}:[")
            lines += [f"  {compact(e)}{',' if j < len(value) - 1 else ''}" for j, e in enumerate(value)]
            lines.append(f" ]{sep}")
        else:
            lines.append(f" {json.dumps(key)}:{compact(value)}{sep}")
    lines.append("}")
    return "\n".join(lines) + "\n"
