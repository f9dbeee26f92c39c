"""Argoverse 2 importer: motion-forecasting scenarios and sensor-log annotations.

Inputs (each path one recording, or a folder searched for recordings):

* motion forecasting: ``scenario_<id>.parquet`` (one row per track and
  timestep, 110 steps at 10 Hz, city frame) or its folder, with the vector
  map ``log_map_archive_*.json`` next to it. The recorded ego is the track
  ``"AV"``. The data has no object sizes: ``DEFAULT_SIZES`` per category.
* sensor log: a folder with ``annotations.feather`` (cuboids at 10 Hz in the
  EGO frame of their timestamp), ``city_SE3_egovehicle.feather`` (ego poses in
  the city frame, a higher rate) and ``map/log_map_archive_*.json``. Cuboids
  are moved to the city frame with the ego pose of the same ``timestamp_ns``.
  ``num_interior_pts == 0`` (no lidar return inside the box) is written as
  not visible. ``annotations_with_ego.feather`` (the AV2 scenario-mining /
  RefAV variant: the same cuboids plus one row per annotated timestamp for
  the ego itself, ``category`` ``"EGO_VEHICLE"``, a per-log random
  ``track_uuid``, box at the ego-frame origin) is read the same way; its
  ego rows (``EGO_CATEGORY``) are dropped, since the ego comes from the poses
  and an agent there would overlap it. A folder holding both files is read
  from ``annotations.feather``.

The ego pose is that of the AV2 ego-vehicle frame, whose origin is the centre
of the rear axle; the written ego box centre is ``EGO_CENTER_OFFSET_M``
ahead of it (the Ford Fusion hybrid of the Argo fleet: ``EGO_SIZE``).

Map: lane segments -> lanes (centreline, or the mean of the boundaries where
there is none; width the mean distance between the boundaries; BIKE lanes
``bike``; intersection lanes ``connector``), their boundaries (deduplicated)
with ``MARKINGS`` from the mark types, pedestrian crossings (edge1 + edge2
reversed), drivable areas. No signal states exist in AV2.

Categories: moving road users map onto ``CATEGORIES`` (tables below); static
objects with a known size (bollards, cones, signs, ...) become static
obstacles when they do not move; everything else is reported as Skipped.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import DuplicateKeyError, loads_json
from drivee2e_jax.polyline import polyline_length, resample_polyline
from drivee2e_jax.records import BoundaryRecord, LaneRecord, MapRecord
from drivee2e_jax.scenario.importers import common
from drivee2e_jax.scenario.importers.common import ImportOptions, ImportResult, RawTrack, Skipped

__all__ = ["load", "load_map", "FORECAST_CATEGORIES", "SENSOR_CATEGORIES", "MARK_TYPES"]

#: Forecasting ``object_type`` -> CATEGORIES (None: known, not a road user).
FORECAST_CATEGORIES: dict[str, str | None] = {
    "vehicle": "car", "bus": "bus", "motorcyclist": "motorcycle", "cyclist": "cyclist",
    "pedestrian": "pedestrian", "riderless_bicycle": None, "static": None, "background": None,
    "construction": None, "unknown": None,
}
#: Forecasting types written as static obstacles (when they do not move), with their kind.
FORECAST_STATIC = {"riderless_bicycle": "bicycle"}
#: Sensor-log ``category`` -> CATEGORIES. Riders (BICYCLIST, MOTORCYCLIST) are
#: annotated on top of their vehicle's box, so only the vehicle is kept.
SENSOR_CATEGORIES: dict[str, str | None] = {
    "REGULAR_VEHICLE": "car", "LARGE_VEHICLE": "van", "BUS": "bus", "ARTICULATED_BUS": "bus",
    "SCHOOL_BUS": "bus", "BOX_TRUCK": "truck", "TRUCK": "truck", "TRUCK_CAB": "truck",
    "VEHICULAR_TRAILER": "truck", "MOTORCYCLE": "motorcycle", "BICYCLE": "cyclist",
    "PEDESTRIAN": "pedestrian", "OFFICIAL_SIGNALER": "pedestrian", "WHEELCHAIR": "pedestrian",
    "WHEELED_RIDER": "pedestrian", "WHEELED_DEVICE": None, "STROLLER": None, "DOG": None,
    "BICYCLIST": None, "MOTORCYCLIST": None, "RAILED_VEHICLE": None, "ANIMAL": None,
    "BOLLARD": None, "CONSTRUCTION_CONE": None, "CONSTRUCTION_BARREL": None, "SIGN": None,
    "STOP_SIGN": None, "MOBILE_PEDESTRIAN_CROSSING_SIGN": None, "MESSAGE_BOARD_TRAILER": None,
    "TRAFFIC_LIGHT_TRAILER": None,
}
#: Sensor-log categories written as static obstacles (when they do not move).
SENSOR_STATIC = {
    "BOLLARD": "bollard", "CONSTRUCTION_CONE": "cone", "CONSTRUCTION_BARREL": "barrel", "SIGN": "sign",
    "STOP_SIGN": "sign", "MOBILE_PEDESTRIAN_CROSSING_SIGN": "sign", "MESSAGE_BOARD_TRAILER": "trailer",
    "TRAFFIC_LIGHT_TRAILER": "trailer",
}
#: AV2 ``LaneMarkType`` -> MARKINGS (mixed dash/solid lines count as solid).
MARK_TYPES = {
    "NONE": "none", "UNKNOWN": "none", "DASHED_WHITE": "dashed", "DASHED_YELLOW": "dashed",
    "DOUBLE_DASH_WHITE": "dashed", "DOUBLE_DASH_YELLOW": "dashed", "SOLID_WHITE": "solid",
    "SOLID_YELLOW": "solid", "SOLID_BLUE": "solid", "DASH_SOLID_WHITE": "solid", "DASH_SOLID_YELLOW": "solid",
    "SOLID_DASH_WHITE": "solid", "SOLID_DASH_YELLOW": "solid", "DOUBLE_SOLID_WHITE": "double_solid",
    "DOUBLE_SOLID_YELLOW": "double_solid",
}
LANE_TYPES = {"VEHICLE": "driving", "BUS": "driving", "BIKE": "bike"}

#: The Argo ego vehicle (Ford Fusion hybrid), length/width/height m; box centre ahead of the rear axle, m.
EGO_SIZE = (4.87, 1.85, 1.48)
EGO_CENTER_OFFSET_M = 1.42
#: Map content further than this from the ego's path is dropped, m.
MAP_RADIUS_M = 100.0
FORECAST_DT = 0.1
FORECAST_COLUMNS = ("track_id", "object_type", "timestep", "position_x", "position_y", "heading",
                    "velocity_x", "velocity_y", "scenario_id")
#: Annotation file names of a sensor-log folder, in order of preference.
ANNOTATION_FILES = ("annotations.feather", "annotations_with_ego.feather")
#: The ``category`` of the ego's own rows in ``annotations_with_ego.feather``.
EGO_CATEGORY = "EGO_VEHICLE"
ANNOTATION_COLUMNS = ("timestamp_ns", "track_uuid", "category", "length_m", "width_m", "height_m",
                      "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m", "num_interior_pts")
POSE_COLUMNS = ("timestamp_ns", "qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")
LICENSE = "Argoverse 2: CC BY-NC-SA 4.0 (cite Wilson et al., Argoverse 2, NeurIPS Datasets & Benchmarks 2021)"


# --------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------


def _units(path: Path) -> list[tuple[str, Path]]:
    """The recordings under ``path``: ("forecast", parquet) / ("sensor", log folder)."""
    if path.is_file():
        if path.suffix == ".parquet":
            return [("forecast", path)]
        if path.name in ANNOTATION_FILES:
            return [("sensor", path.parent)]
        raise DriveE2EError(f"{path}: expected an AV2 scenario_<id>.parquet, an annotations.feather "
                            "(or annotations_with_ego.feather), or a folder holding them")
    if _annotation_file(path) is not None:
        return [("sensor", path)]
    found = sorted(path.rglob("scenario_*.parquet"))
    logs = sorted({p.parent for name in ANNOTATION_FILES for p in path.rglob(name)})
    units = [("forecast", p) for p in found] + [("sensor", p) for p in logs]
    if not units:
        raise DriveE2EError(f"{path}: no AV2 scenario_*.parquet or annotations(_with_ego).feather found")
    return units


def _annotation_file(folder: Path) -> Path | None:
    """The sensor log's annotation file (``ANNOTATION_FILES`` order), or None."""
    return next((folder / n for n in ANNOTATION_FILES if (folder / n).is_file()), None)


def _map_file(folder: Path) -> Path:
    found = sorted(folder.glob("log_map_archive_*.json")) + sorted(folder.glob("map/log_map_archive_*.json"))
    if not found:
        raise DriveE2EError(f"{folder}: no log_map_archive_*.json (the AV2 vector map) next to the log")
    return found[0]


# --------------------------------------------------------------------------
# Map
# --------------------------------------------------------------------------


def _points(obj, where: str) -> np.ndarray:
    try:
        p = np.array([[float(q["x"]), float(q["y"])] for q in obj], np.float64)
    except (TypeError, KeyError, ValueError):
        raise DriveE2EError(f"{where}: expected a list of {{x, y, z}} points") from None
    if len(p) < 2:
        raise DriveE2EError(f"{where}: expected at least 2 points, got {len(p)}")
    return p


def _even(p: np.ndarray, spacing: float) -> np.ndarray:
    """``p`` at even spacing, no de-duplication or count slack (as imported so far)."""
    return resample_polyline(p, spacing, dedupe_tol=0.0, count_slack=0.0)


def _mean_width(left: np.ndarray, right: np.ndarray) -> float:
    n = 20
    a, b = _even(left, polyline_length(left) / n + 1e-9), _even(right, polyline_length(right) / n + 1e-9)
    m = min(len(a), len(b))
    a = a[np.linspace(0, len(a) - 1, m).astype(int)]
    b = b[np.linspace(0, len(b) - 1, m).astype(int)]
    return float(np.mean(np.linalg.norm(a - b, axis=1)))


def _centerline(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    n = max(len(left), len(right), 2)
    a = _even(left, polyline_length(left) / (n - 1) + 1e-9)
    b = _even(right, polyline_length(right) / (n - 1) + 1e-9)
    m = min(len(a), len(b))
    a = a[np.linspace(0, len(a) - 1, m).astype(int)]
    b = b[np.linspace(0, len(b) - 1, m).astype(int)]
    return (a + b) / 2.0


def _ccw(poly: np.ndarray) -> np.ndarray:
    x, y = poly[:, 0], poly[:, 1]
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    return poly if area >= 0 else poly[::-1].copy()


def load_map(path: Path, map_id: str) -> MapRecord:
    """An AV2 vector-map JSON as a MapRecord (the whole map, uncropped)."""
    try:
        obj = loads_json(Path(path).read_bytes())
    except DuplicateKeyError as e:
        raise DriveE2EError(f"{path}: not valid JSON ({e.msg})") from None
    except json.JSONDecodeError as e:
        raise DriveE2EError(f"{path}: not valid JSON ({e.msg} at line {e.lineno})") from None
    except UnicodeDecodeError as e:
        raise DriveE2EError(f"{path}: not UTF-8 text (byte {e.start})") from None
    if not isinstance(obj, dict) or "lane_segments" not in obj:
        raise DriveE2EError(f"{path}: expected an AV2 map object with 'lane_segments'")
    segs = obj["lane_segments"]
    segs = list(segs.values()) if isinstance(segs, dict) else list(segs)
    lanes, boundaries, seen = [], [], set()
    for i, seg in enumerate(segs):
        where = f"{path}: lane_segments[{seg.get('id', i) if isinstance(seg, dict) else i}]"
        if not isinstance(seg, dict):
            raise DriveE2EError(f"{where}: expected an object")
        for key in ("id", "left_lane_boundary", "right_lane_boundary"):
            if key not in seg:
                raise DriveE2EError(f"{where}: missing field {key!r}")
        left = _points(seg["left_lane_boundary"], f"{where}.left_lane_boundary")
        right = _points(seg["right_lane_boundary"], f"{where}.right_lane_boundary")
        center = (_points(seg["centerline"], f"{where}.centerline") if seg.get("centerline")
                  else _centerline(left, right))
        lmark = common.map_marking(str(seg.get("left_lane_mark_type", "NONE")), MARK_TYPES, f"{where}.left_lane_mark_type")
        rmark = common.map_marking(str(seg.get("right_lane_mark_type", "NONE")), MARK_TYPES, f"{where}.right_lane_mark_type")
        ltype = LANE_TYPES.get(str(seg.get("lane_type", "VEHICLE")))
        if ltype is None:
            raise DriveE2EError(f"{where}.lane_type: expected one of {', '.join(LANE_TYPES)}, "
                                f"got {seg.get('lane_type')!r}")
        if ltype == "driving" and seg.get("is_intersection"):
            ltype = "connector"
        lanes.append(LaneRecord(id=int(seg["id"]), centerline=center, width=max(_mean_width(left, right), 1.0),
                                type=ltype, successors=[int(s) for s in seg.get("successors") or []],
                                left_marking=lmark, right_marking=rmark,
                                left_boundary=left, right_boundary=right))
        for pts, mark in ((left, lmark), (right, rmark)):
            key = tuple(np.round(pts[[0, -1]], 1).ravel())
            rkey = tuple(np.round(pts[[-1, 0]], 1).ravel())
            if mark == "none" or key in seen or rkey in seen:
                continue
            seen.add(key)
            boundaries.append(BoundaryRecord(points=pts, marking=mark))
    ids = {ln.id for ln in lanes}
    for ln in lanes:
        ln.successors = [s for s in ln.successors if s in ids]
    crossings = obj.get("pedestrian_crossings") or {}
    crossings = list(crossings.values()) if isinstance(crossings, dict) else list(crossings)
    crosswalks = []
    for i, c in enumerate(crossings):
        e1 = _points(c.get("edge1"), f"{path}: pedestrian_crossings[{i}].edge1")
        e2 = _points(c.get("edge2"), f"{path}: pedestrian_crossings[{i}].edge2")
        crosswalks.append(_ccw(np.vstack([e1, e2[::-1]])))
    areas = obj.get("drivable_areas") or {}
    areas = list(areas.values()) if isinstance(areas, dict) else list(areas)
    drivable = [_ccw(_points(a.get("area_boundary"), f"{path}: drivable_areas[{i}].area_boundary"))
                for i, a in enumerate(areas)]
    return MapRecord(map_id=map_id, lanes=lanes, boundaries=boundaries, crosswalks=crosswalks,
                     drivable_areas=drivable, meta={"source": "argoverse2", "file": Path(path).name})


# --------------------------------------------------------------------------
# Tracks
# --------------------------------------------------------------------------


def _ego_box_center(xy: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    return xy + EGO_CENTER_OFFSET_M * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)


def _forecast(path: Path, options: ImportOptions):
    cols = common.read_table(path, FORECAST_COLUMNS)
    n = len(cols["track_id"])
    if n == 0:
        raise DriveE2EError(f"{path}: no rows; expected one row per track and timestep")
    raws, obstacles, skipped = [], [], []
    ids = cols["track_id"].astype(str)
    types = cols["object_type"].astype(str)
    for tid in sorted(set(ids.tolist())):
        m = ids == tid
        k = cols["timestep"][m].astype(np.int64)
        order = np.argsort(k)
        typ = str(types[m][0])
        xy = np.stack([cols["position_x"][m], cols["position_y"][m]], axis=1).astype(np.float64)[order]
        yaw = cols["heading"][m].astype(np.float64)[order]
        vel = np.stack([cols["velocity_x"][m], cols["velocity_y"][m]], axis=1).astype(np.float64)[order]
        t = k[order] * FORECAST_DT
        if not np.all(np.isfinite(xy)) or not np.all(np.isfinite(yaw)):
            skipped.append(Skipped(f"{path.name} track {tid}", "non-finite position or heading"))
            continue
        if tid == "AV":
            xy = _ego_box_center(xy, yaw)
            raws.append(RawTrack(tid, "car", t, xy, yaw, np.array(EGO_SIZE), vel))
            continue
        cat, skip = common.map_category(typ, FORECAST_CATEGORIES, f"{path.name} track {tid}")
        if cat is None:
            raw = RawTrack(tid, "cyclist", t, xy, yaw, np.array([1.8, 0.6, 1.1]))
            out = common.static_or_skip(raw, FORECAST_STATIC.get(typ), skip, f"category {typ!r}")
            (skipped if isinstance(out, Skipped) else obstacles).append(out)
            continue
        raws.append(RawTrack(tid, cat, t, xy, yaw, np.array(common.DEFAULT_SIZES[cat]), vel))
    sid = str(cols["scenario_id"][0])
    num_steps = int(cols["timestep"].max()) + 1
    return raws, obstacles, sid, "AV", num_steps, FORECAST_DT, skipped


def _quat_to_matrix(qw, qx, qy, qz) -> np.ndarray:
    """(n,) quaternion components -> (n, 3, 3) rotation matrices."""
    q = np.stack([qw, qx, qy, qz], axis=1).astype(np.float64)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1),
    ], axis=1)


def _without_ego(ann: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The annotation columns without the ego's own rows (``category == EGO_CATEGORY``)."""
    keep = ann["category"].astype(str) != EGO_CATEGORY
    return ann if keep.all() else {k: v[keep] for k, v in ann.items()}


def _sensor(folder: Path, options: ImportOptions):
    ann_path = _annotation_file(folder) or folder / ANNOTATION_FILES[0]
    pose_path = folder / "city_SE3_egovehicle.feather"
    for p in (ann_path, pose_path):
        if not p.is_file():
            raise DriveE2EError(f"{folder}: missing {p.name}; expected an AV2 sensor log folder")
    ann = _without_ego(common.read_table(ann_path, ANNOTATION_COLUMNS))
    pose = common.read_table(pose_path, POSE_COLUMNS)
    if len(ann["timestamp_ns"]) == 0:
        raise DriveE2EError(f"{ann_path}: no rows; expected one cuboid per track and timestamp")
    pose_ts = pose["timestamp_ns"].astype(np.int64)
    order = np.argsort(pose_ts)
    pose_ts = pose_ts[order]
    rot = _quat_to_matrix(pose["qw"][order], pose["qx"][order], pose["qy"][order], pose["qz"][order])
    trans = np.stack([pose["tx_m"], pose["ty_m"], pose["tz_m"]], axis=1).astype(np.float64)[order]
    ts = ann["timestamp_ns"].astype(np.int64)
    j = np.searchsorted(pose_ts, ts)
    j = np.clip(j, 0, len(pose_ts) - 1)
    if not np.all(pose_ts[j] == ts):
        bad = int(ts[np.argmax(pose_ts[j] != ts)])
        raise DriveE2EError(f"{pose_path}: no ego pose at annotation timestamp_ns {bad}; "
                            "expected a pose for every annotated timestamp")
    t0 = int(ts.min())
    frames = np.unique(ts)
    # every annotated frame on the grid: t = round((ts - t0) / dt) * dt (the log is 10 Hz with jitter)
    local = np.stack([ann["tx_m"], ann["ty_m"], ann["tz_m"]], axis=1).astype(np.float64)
    city = np.einsum("nij,nj->ni", rot[j], local) + trans[j]
    r_obj = _quat_to_matrix(ann["qw"], ann["qx"], ann["qy"], ann["qz"])
    r_city = np.einsum("nij,njk->nik", rot[j], r_obj)
    yaw = np.arctan2(r_city[:, 1, 0], r_city[:, 0, 0])
    t = (ts - t0) * 1e-9
    uuids = ann["track_uuid"].astype(str)
    cats = ann["category"].astype(str)
    size = np.stack([ann["length_m"], ann["width_m"], ann["height_m"]], axis=1).astype(np.float64)
    visible = ann["num_interior_pts"].astype(np.int64) > 0
    raws, obstacles, skipped = [], [], []
    for uid in sorted(set(uuids.tolist())):
        m = uuids == uid
        o = np.argsort(t[m])
        cat_src = str(cats[m][0])
        cat, skip = common.map_category(cat_src, SENSOR_CATEGORIES, f"{folder.name} track {uid}")
        raw = RawTrack(uid, cat or "car", t[m][o], city[m][o, :2], yaw[m][o], size[m][o], None, visible[m][o])
        if cat is None:
            out = common.static_or_skip(raw, SENSOR_STATIC.get(cat_src), skip, f"category {cat_src!r}")
            (skipped if isinstance(out, Skipped) else obstacles).append(out)
            continue
        raws.append(raw)
    # the ego: poses over the annotated span (their own, higher rate)
    span = (pose_ts >= t0) & (pose_ts <= frames.max())
    eyaw = np.arctan2(rot[span][:, 1, 0], rot[span][:, 0, 0])
    exy = _ego_box_center(trans[span][:, :2], eyaw)
    raws.append(RawTrack("AV", "car", (pose_ts[span] - t0) * 1e-9, exy, eyaw, np.array(EGO_SIZE)))
    dt = options.dt
    num_steps = int(round((frames.max() - t0) * 1e-9 / dt)) + 1
    return raws, obstacles, folder.name, "AV", num_steps, dt, skipped


# --------------------------------------------------------------------------
# load
# --------------------------------------------------------------------------


def _one(kind: str, path: Path, options: ImportOptions, limit: int | None) -> ImportResult:
    if kind == "forecast":
        raws, obstacles, sid, ego_src, num_steps, dt_src, skipped = _forecast(path, options)
        folder, label = path.parent, f"av2_{sid}"
    else:
        raws, obstacles, sid, ego_src, num_steps, dt_src, skipped = _sensor(path, options)
        folder, label = path, f"av2_{sid}"
    notes: list[str] = []
    dt = options.dt
    if kind == "forecast" and abs(dt - dt_src) > 1e-9:
        num_steps = int(math.floor((num_steps - 1) * dt_src / dt)) + 1
        notes.append(f"{label}: resampled from {dt_src:g} s to {dt:g} s steps (linear interpolation)")
    if options.ego is not None:
        if options.ego not in {r.source_id for r in raws}:
            raise DriveE2EError(f"--ego {options.ego}: no such track in {path}; the recorded ego is 'AV'")
        notes.append(f"{label}: ego is track {options.ego} (--ego) instead of the recorded AV")
        ego_src = options.ego
    conv = common.convert_tracks(raws, ego_src, dt, num_steps, path.name)
    skipped += conv.skipped
    ego = next((tr for tr in conv.tracks if tr.track_id == conv.ids[ego_src]), None)
    if ego is None:
        raise DriveE2EError(f"{path}: the ego track {ego_src!r} has no samples on the grid")
    full = load_map(_map_file(folder), common.safe_id(f"{label}_map"))
    full.obstacles = obstacles
    map_rec = common.crop_map(full, ego.xy, MAP_RADIUS_M)
    if conv.gap_tracks:
        notes.append(f"{label}: {conv.gap_tracks} tracks have gaps > {common.DEFAULT_MAX_GAP_S:g} s "
                     "(left as missing steps, not interpolated)")
    if obstacles:
        notes.append(f"{label}: {len(obstacles)} static objects written as static obstacles")
    scenarios = common.windowed_scenarios(label, map_rec, conv.tracks, conv.ids[ego_src], dt, num_steps, options,
                                          str(path), skipped, notes, limit=limit, intersection_id=label)
    meta = {"source": "argoverse2", "license": LICENSE,
            "track_ids": {s.scenario_id: {str(k): v for k, v in conv.ids.table().items()} for s in scenarios}}
    return ImportResult(maps={map_rec.map_id: map_rec}, scenarios=scenarios, skipped=skipped, notes=notes, meta=meta)


def load(paths: list[Path], options: ImportOptions) -> ImportResult:
    """Import AV2 forecasting scenarios and/or sensor logs (see the module docstring)."""
    results = []
    count = 0
    for path in paths:
        for kind, unit in _units(Path(path)):
            limit = None if options.max_scenarios is None else options.max_scenarios - count
            if limit is not None and limit <= 0:
                break
            r = _one(kind, unit, options, limit)
            count += len(r.scenarios)
            results.append(r)
    return common.merge_results(results)
