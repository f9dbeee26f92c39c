"""Validation of suite contents (JSON-shaped objects: lists from files or
numpy arrays from records), collecting every problem with its file and field.

``check_suite_json``, ``check_scenario``, ``check_map``, ``check_cross``
check one object each (records back when valid); ``validate_records`` checks
an in-memory ``SuiteRecord`` as it would be written. Reading and writing
folders is ``schema``'s.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from shapely.geometry import Polygon
from shapely.validation import explain_validity

from drivee2e_jax.records import (
    BEHAVIORS,
    CATEGORIES,
    LANE_TYPES,
    MARKINGS,
    SCHEMA_VERSION,
    SIGNAL_STATES,
    SPLITS,
    TIMES_OF_DAY,
    WEATHERS,
    BoundaryRecord,
    LaneRecord,
    MapRecord,
    ObstacleRecord,
    RouteRecord,
    ScenarioRecord,
    SignalPhase,
    StopLineRecord,
    SuiteRecord,
    TrackRecord,
)
from drivee2e_jax.scenario.encode import map_obj, scenario_obj, suite_obj
from drivee2e_jax.scenario.problems import (
    INT32_RANGE,
    SAFE_ID,
    Checker,
    Problem,
    is_int,
    is_num,
    join_path,
    json_kind,
    short,
)

__all__ = [
    "GRID_TOLERANCE_S", "MIN_BOX_SIZE_M", "check_suite_json", "check_scenario", "check_map", "check_cross",
    "validate_records",
]

#: A timestamp is "on the grid" when it is within this of some ``k * dt``.
GRID_TOLERANCE_S = 1e-3
#: Smallest box length / width, m. The smallest road users are ~0.5 m across
#: (``importers.common.DEFAULT_SIZES``: pedestrian 0.6 m) and the importers
#: clamp static obstacles to 0.1 m; a thinner box is a missing size written as
#: 0, whose collisions silently vanish. Height may be 0: only the ray sensors
#: read it, and the schema has always allowed it.
MIN_BOX_SIZE_M = 0.1
#: What a map without lanes is told (no documented format is lane-free).
NO_LANES = ("at least one lane (without lanes every step is off-lane and DS is 0: the route, the "
            "off-lane rule and the observation's lanes all read them)")


# --------------------------------------------------------------------------
# Record checks on JSON-shaped objects (lists from files or numpy from records)
# --------------------------------------------------------------------------

_SUITE_REQ = ("name", "version", "schema_version", "scenarios")
_SUITE_OPT = ("meta",)
_ENTRY_REQ = ("id", "split", "intersection_id", "behavior")
_SCEN_REQ = ("scenario_id", "split", "intersection_id", "map_id", "behavior", "weather",
             "time_of_day", "ego_track_id", "dt", "num_steps", "route", "tracks")
_SCEN_OPT = ("schema_version", "signals")
_TRACK_REQ = ("track_id", "category", "size", "t", "x", "y", "yaw")
_TRACK_OPT = ("vx", "vy", "visible", "quality")
_ROUTE_REQ = ("waypoints", "source", "destination")
_MAP_REQ = ("map_id", "lanes")
_MAP_OPT = ("schema_version", "boundaries", "crosswalks", "stop_lines", "drivable_areas",
            "obstacles", "signal_plan", "meta")
_LANE_REQ = ("id", "centerline")
_LANE_OPT = ("width", "speed_limit", "type", "successors", "left_marking", "right_marking",
             "left_boundary", "right_boundary", "polygon")
_SIGNAL_TEXT = "a signal state index: " + ", ".join(f"{i}={n}" for i, n in enumerate(SIGNAL_STATES))


def _ring_problem(ring: np.ndarray) -> str:
    """Why ``ring`` (n, 2) m is not a simple polygon with area ('' when it is), in a few words."""
    shp = Polygon(ring)
    if shp.area <= 0.0:
        return "zero area"
    return "" if shp.is_valid else " ".join(explain_validity(shp).split())[:80]


def _check_schema_version(c: Checker, obj: dict) -> None:
    if "schema_version" not in obj:
        return
    v = obj["schema_version"]
    if not is_int(v) or v != SCHEMA_VERSION:
        c.add("schema_version", f"{SCHEMA_VERSION} (the schema version this drivee2e reads)", short(v))


def check_suite_json(obj: Any, c: Checker) -> tuple[dict, list[dict]] | None:
    """Returns (header, entries) with entries [{id, split, intersection_id, behavior, row}]."""
    mark = c.mark()
    if not c.fields(obj, "", _SUITE_REQ, _SUITE_OPT):
        return None
    name = c.string(obj, "name", "")
    version = obj.get("version")
    if "version" in obj and not isinstance(version, str):
        if is_num(version):
            version = str(version)
        else:
            c.add("version", "a string", json_kind(version))
    _check_schema_version(c, obj)
    meta = obj.get("meta", {})
    if not isinstance(meta, dict):
        c.add("meta", "an object", json_kind(meta))
    entries: list[dict] = []
    listed = c.listing(obj, "scenarios", "")
    seen: dict[str, int] = {}
    for i, e in enumerate(listed or []):
        p = f"scenarios[{i}]"
        m = c.mark()
        if not c.fields(e, p, _ENTRY_REQ):
            continue
        sid = c.string(e, "id", p, pattern=SAFE_ID)
        split = c.string(e, "split", p, choices=SPLITS)
        inter = c.string(e, "intersection_id", p)
        beh = c.string(e, "behavior", p, choices=BEHAVIORS)
        if sid is not None and sid in seen:
            c.add(f"{p}.id", "a unique scenario id", f"{sid!r} (also scenarios[{seen[sid]}])")
            continue
        if sid is not None:
            seen[sid] = i
        if c.mark() == m:
            entries.append({"id": sid, "split": split, "intersection_id": inter, "behavior": beh, "row": i})
    if listed is not None and not listed:
        c.add("scenarios", "at least one scenario", "an empty list")
    if c.mark() > mark:
        return None
    return {"name": name, "version": version, "meta": meta}, entries


def _check_track(obj: Any, p: str, c: Checker, dt: float | None, num_steps: int | None,
                 ego: int | None = None) -> TrackRecord | None:
    mark = c.mark()
    if not c.fields(obj, p, _TRACK_REQ, _TRACK_OPT):
        return None
    tid = c.integer(obj, "track_id", p)
    cat = c.string(obj, "category", p, choices=CATEGORIES)
    size = c.array(obj["size"], join_path(p, "size"), length=3, minimum=0.0) if "size" in obj else None
    if size is not None and (size[:2] < MIN_BOX_SIZE_M).any():
        who = "the ego" if tid is not None and tid == ego else "an agent"
        c.add(join_path(p, "size"), f"length and width >= {MIN_BOX_SIZE_M:g} m (a smaller box never collides)",
              f"[{', '.join(f'{v:g}' for v in size)}] (track_id {tid}, {who})")
    cols = {}
    for key in ("t", "x", "y", "yaw", "vx", "vy"):
        if key in obj:
            cols[key] = c.array(obj[key], join_path(p, key), position=key in ("x", "y"))
    for key in ("visible", "quality"):
        if key in obj:
            cols[key] = c.flags(obj[key], join_path(p, key))
    if ("vx" in obj) != ("vy" in obj):
        missing = "vy" if "vx" in obj else "vx"
        c.add(join_path(p, missing), "vx and vy together (or neither)", "missing")
    t = cols.get("t")
    if t is not None:
        if len(t) == 0:
            c.add(join_path(p, "t"), "at least one sample", "an empty list")
        for key, a in cols.items():
            if key != "t" and a is not None and len(a) != len(t):
                c.add(join_path(p, key), f"{len(t)} values (as many as t)", f"{len(a)}")
        if dt is not None and num_steps is not None and len(t):
            _check_times(t, join_path(p, "t"), c, dt, num_steps)
    if c.mark() > mark:
        return None
    vel = None if "vx" not in obj else np.stack([cols["vx"], cols["vy"]], axis=1)
    return TrackRecord(
        track_id=tid, category=cat, size=size, t=t, xy=np.stack([cols["x"], cols["y"]], axis=1),
        yaw=cols["yaw"], vel=vel, visible=cols.get("visible"), quality=cols.get("quality"),
    )


def _check_times(t: np.ndarray, p: str, c: Checker, dt: float, num_steps: int) -> None:
    k = np.rint(t / dt)
    off = np.abs(t - k * dt) > GRID_TOLERANCE_S
    if off.any():
        i = int(np.flatnonzero(off)[0])
        c.add(f"{p}[{i}]", f"a multiple of dt={dt:g} s (within {GRID_TOLERANCE_S * 1e3:g} ms)", short(t[i]))
        return
    if len(t) > 1:
        bad = np.diff(k) <= 0
        if bad.any():
            i = int(np.flatnonzero(bad)[0]) + 1
            c.add(f"{p}[{i}]", "increasing timestamps", f"{t[i]:.6g} after {t[i - 1]:.6g}")
            return
    if k[0] < 0:
        c.add(f"{p}[0]", "a time >= 0", short(t[0]))
    if k[-1] >= num_steps:
        i = int(np.flatnonzero(k >= num_steps)[0])
        c.add(f"{p}[{i}]", f"a time <= {(num_steps - 1) * dt:.6g} s (num_steps={num_steps}, dt={dt:g})", short(t[i]))


def _check_route(obj: Any, p: str, c: Checker) -> RouteRecord | None:
    mark = c.mark()
    if not c.fields(obj, p, _ROUTE_REQ):
        return None
    wp = (c.array(obj["waypoints"], join_path(p, "waypoints"), cols=2, min_len=2, position=True)
          if "waypoints" in obj else None)
    src = c.array(obj["source"], join_path(p, "source"), length=2, position=True) if "source" in obj else None
    dst = (c.array(obj["destination"], join_path(p, "destination"), length=2, position=True)
           if "destination" in obj else None)
    if c.mark() > mark:
        return None
    return RouteRecord(waypoints=wp, source=src, destination=dst)


def check_scenario(obj: Any, c: Checker) -> ScenarioRecord | None:
    mark = c.mark()
    if not c.fields(obj, "", _SCEN_REQ, _SCEN_OPT):
        return None
    _check_schema_version(c, obj)
    sid = c.string(obj, "scenario_id", "", pattern=SAFE_ID)
    split = c.string(obj, "split", "", choices=SPLITS)
    inter = c.string(obj, "intersection_id", "")
    map_id = c.string(obj, "map_id", "", pattern=SAFE_ID)
    beh = c.string(obj, "behavior", "", choices=BEHAVIORS)
    weather = c.string(obj, "weather", "", choices=WEATHERS)
    tod = c.string(obj, "time_of_day", "", choices=TIMES_OF_DAY)
    ego = c.integer(obj, "ego_track_id", "")
    dt = c.number(obj, "dt", "", positive=True)
    num_steps = c.integer(obj, "num_steps", "", minimum=1)
    route = _check_route(obj["route"], "route", c) if "route" in obj else None

    tracks: list[TrackRecord] = []
    seen: dict[int, int] = {}
    for i, tobj in enumerate(c.listing(obj, "tracks", "") or []):
        tr = _check_track(tobj, f"tracks[{i}]", c, dt, num_steps, ego)
        if tr is None:
            continue
        if tr.track_id in seen:
            c.add(f"tracks[{i}].track_id", "a unique track id", f"{tr.track_id} (also tracks[{seen[tr.track_id]}])")
            continue
        seen[tr.track_id] = i
        tracks.append(tr)
    if "tracks" in obj and isinstance(obj["tracks"], list) and not obj["tracks"]:
        c.add("tracks", "at least one track (the ego)", "an empty list")
    raw_ids = {t["track_id"] for t in obj.get("tracks") or [] if isinstance(t, dict) and is_int(t.get("track_id"))}
    if ego is not None and isinstance(obj.get("tracks"), list) and ego not in raw_ids:
        ids = sorted(raw_ids)
        shown = ", ".join(map(str, ids[:12])) + (", ..." if len(ids) > 12 else "")
        c.add("ego_track_id", f"one of the track ids ({shown})", str(ego))

    signals: dict[int, np.ndarray] = {}
    sig = obj.get("signals", {})
    if not isinstance(sig, dict):
        c.add("signals", "an object {signal group: [states]}", json_kind(sig))
        sig = {}
    for key, states in sig.items():
        p = f'signals["{key}"]'
        try:
            group = int(key)
            if not INT32_RANGE[0] <= group <= INT32_RANGE[1]:  # stop lines' signal_group is an int32
                raise ValueError(key)
        except (TypeError, ValueError):
            c.add(p, f"an integer signal group in [{INT32_RANGE[0]}, {INT32_RANGE[1]}] as key", short(key))
            continue
        a = c.ints(states, p, choices=range(len(SIGNAL_STATES)), choice_text=_SIGNAL_TEXT)
        if a is None:
            continue
        if num_steps is not None and len(a) != num_steps:
            c.add(p, f"{num_steps} states (one per log step, num_steps)", f"{len(a)}")
            continue
        signals[group] = a.astype(np.int8)
    if c.mark() > mark:
        return None
    return ScenarioRecord(
        scenario_id=sid, split=split, intersection_id=inter, map_id=map_id, behavior=beh,
        weather=weather, time_of_day=tod, ego_track_id=ego, route=route, dt=dt,
        num_steps=num_steps, tracks=tracks, signals=signals,
    )


def _polygons(obj: dict, key: str, c: Checker, min_len: int) -> list[np.ndarray]:
    out = []
    for i, poly in enumerate(c.listing(obj, key, "", default=[]) or []):
        a = c.array(poly, f"{key}[{i}]", cols=2, min_len=min_len, position=True)
        if a is not None:
            out.append(a)
    return out


def check_map(obj: Any, c: Checker) -> MapRecord | None:
    mark = c.mark()
    if not c.fields(obj, "", _MAP_REQ, _MAP_OPT):
        return None
    _check_schema_version(c, obj)
    map_id = c.string(obj, "map_id", "", pattern=SAFE_ID)

    lanes: list[LaneRecord] = []
    lane_ids: dict[int, int] = {}
    successor_refs: list[tuple[str, int]] = []
    for i, lobj in enumerate(c.listing(obj, "lanes", "") or []):
        p = f"lanes[{i}]"
        m = c.mark()
        if not c.fields(lobj, p, _LANE_REQ, _LANE_OPT):
            continue
        lid = c.integer(lobj, "id", p)
        cl = (c.array(lobj["centerline"], join_path(p, "centerline"), cols=2, min_len=2, position=True)
              if "centerline" in lobj else None)
        width = c.number(lobj, "width", p, minimum=0.0, default=LaneRecord.width)
        speed = c.number(lobj, "speed_limit", p, minimum=0.0, default=LaneRecord.speed_limit)
        ltype = c.string(lobj, "type", p, choices=LANE_TYPES, default=LaneRecord.type)
        succ = c.ints(lobj["successors"], join_path(p, "successors")) if "successors" in lobj else np.zeros(0, np.int64)
        left = c.string(lobj, "left_marking", p, choices=MARKINGS, default=LaneRecord.left_marking)
        right = c.string(lobj, "right_marking", p, choices=MARKINGS, default=LaneRecord.right_marking)
        lb = (c.array(lobj["left_boundary"], join_path(p, "left_boundary"), cols=2, min_len=2, position=True)
              if "left_boundary" in lobj else None)
        rb = (c.array(lobj["right_boundary"], join_path(p, "right_boundary"), cols=2, min_len=2, position=True)
              if "right_boundary" in lobj else None)
        lp = (c.array(lobj["polygon"], join_path(p, "polygon"), cols=2, min_len=3, position=True)
              if "polygon" in lobj else None)
        if lp is not None and (why := _ring_problem(lp)):
            c.add(join_path(p, "polygon"), "a simple ring (the lane's area, >= 3 distinct points, no "
                  "self-intersection)", why)
        if lid is not None and lid in lane_ids:
            c.add(join_path(p, "id"), "a unique lane id", f"{lid} (also lanes[{lane_ids[lid]}])")
            continue
        if lid is not None:
            lane_ids[lid] = i
        if c.mark() > m:
            continue
        successor_refs += [(f"{p}.successors[{j}]", int(s)) for j, s in enumerate(succ)]
        lanes.append(LaneRecord(id=lid, centerline=cl, width=width, speed_limit=speed, type=ltype,
                                successors=[int(s) for s in succ], left_marking=left, right_marking=right,
                                left_boundary=lb, right_boundary=rb, polygon=lp))
    if isinstance(obj.get("lanes"), list) and not obj["lanes"]:
        c.add("lanes", NO_LANES, "an empty list")
    ids_text = _ids_text(lane_ids)
    for p, s in successor_refs:
        if s not in lane_ids:
            c.add(p, f"a lane id of this map ({ids_text})", str(s))

    boundaries = []
    for i, bobj in enumerate(c.listing(obj, "boundaries", "", default=[]) or []):
        p = f"boundaries[{i}]"
        if not c.fields(bobj, p, ("points", "marking")):
            continue
        pts = (c.array(bobj["points"], join_path(p, "points"), cols=2, min_len=2, position=True)
               if "points" in bobj else None)
        mk = c.string(bobj, "marking", p, choices=MARKINGS)
        if pts is not None and mk is not None:
            boundaries.append(BoundaryRecord(points=pts, marking=mk))

    crosswalks = _polygons(obj, "crosswalks", c, 3)
    drivable = _polygons(obj, "drivable_areas", c, 3)

    stop_lines = []
    stop_ids: dict[int, int] = {}
    for i, sobj in enumerate(c.listing(obj, "stop_lines", "", default=[]) or []):
        p = f"stop_lines[{i}]"
        m = c.mark()
        if not c.fields(sobj, p, ("id", "points", "lane_id", "signal_group")):
            continue
        sid = c.integer(sobj, "id", p)
        pts = (c.array(sobj["points"], join_path(p, "points"), cols=2, length=2, position=True)
               if "points" in sobj else None)
        lane_id = c.integer(sobj, "lane_id", p)
        group = c.integer(sobj, "signal_group", p, minimum=-1)
        if lane_id is not None and lane_id != -1 and lane_id not in lane_ids:
            c.add(join_path(p, "lane_id"), f"-1 or a lane id of this map ({ids_text})", str(lane_id))
        if sid is not None and sid in stop_ids:
            c.add(join_path(p, "id"), "a unique stop line id", f"{sid} (also stop_lines[{stop_ids[sid]}])")
        elif sid is not None:
            stop_ids[sid] = i
        if c.mark() == m:
            stop_lines.append(StopLineRecord(id=sid, points=pts, lane_id=lane_id, signal_group=group))

    obstacles = []
    for i, oobj in enumerate(c.listing(obj, "obstacles", "", default=[]) or []):
        p = f"obstacles[{i}]"
        m = c.mark()
        if not c.fields(oobj, p, ("polygon", "height"), ("kind",)):
            continue
        poly = (c.array(oobj["polygon"], join_path(p, "polygon"), cols=2, min_len=3, position=True)
                if "polygon" in oobj else None)
        height = c.number(oobj, "height", p, minimum=0.0)
        kind = c.string(oobj, "kind", p, default=ObstacleRecord.kind)
        if c.mark() == m:
            obstacles.append(ObstacleRecord(polygon=poly, height=height, kind=kind))

    plan = []
    for i, pobj in enumerate(c.listing(obj, "signal_plan", "", default=[]) or []):
        p = f"signal_plan[{i}]"
        m = c.mark()
        if not c.fields(pobj, p, ("duration", "green"), ("yellow_duration", "all_red")):
            continue
        dur = c.number(pobj, "duration", p, positive=True)
        green = c.ints(pobj["green"], join_path(p, "green")) if "green" in pobj else None
        yellow = c.number(pobj, "yellow_duration", p, minimum=0.0, default=SignalPhase.yellow_duration)
        all_red = c.number(pobj, "all_red", p, minimum=0.0, default=SignalPhase.all_red)
        if c.mark() == m:
            plan.append(SignalPhase(duration=dur, green=[int(g) for g in green], yellow_duration=yellow,
                                    all_red=all_red))

    meta = obj.get("meta", {})
    if not isinstance(meta, dict):
        c.add("meta", "an object", json_kind(meta))
    if c.mark() > mark:
        return None
    return MapRecord(map_id=map_id, lanes=lanes, boundaries=boundaries, crosswalks=crosswalks,
                     stop_lines=stop_lines, drivable_areas=drivable, obstacles=obstacles,
                     signal_plan=plan, meta=dict(meta))


def _ids_text(ids: Iterable[int], limit: int = 12) -> str:
    ids = sorted(ids)
    return ", ".join(map(str, ids[:limit])) + (", ..." if len(ids) > limit else "") if ids else "none"


def check_cross(obj: Any, c: Checker, entry: dict | None, map_ids: Iterable[str] | Mapping[str, Any]) -> None:
    """Checks against other files: the scenario file says what suite.json
    says about it, and its map exists (``map_ids``: the map ids, or
    {map_id: MapRecord or None}: then a map without lanes is named here too)."""
    if not isinstance(obj, dict):
        return
    if entry is not None:
        for key, value in (("scenario_id", entry["id"]), ("split", entry["split"]),
                           ("intersection_id", entry["intersection_id"]), ("behavior", entry["behavior"])):
            got = obj.get(key)
            allowed = {"split": SPLITS, "behavior": BEHAVIORS}.get(key)
            if isinstance(got, str) and got != value and (allowed is None or got in allowed):
                c.add(key, f"{value!r} as listed in suite.json (scenarios[{entry['row']}])", repr(got))
    map_id = obj.get("map_id")
    records = map_ids if isinstance(map_ids, Mapping) else {}
    map_ids = sorted(map_ids)
    if isinstance(map_id, str) and map_id not in map_ids:
        c.add("map_id", f"one of the suite's maps ({', '.join(map_ids) or 'none: maps/ is empty'})", repr(map_id))
    elif isinstance(records.get(map_id), MapRecord) and not records[map_id].lanes:
        c.add("map_id", f"a map with {NO_LANES}", f"{map_id!r} (maps/{map_id}.json has no lanes)")


def validate_records(suite: SuiteRecord) -> list[Problem]:
    """Every problem in an in-memory suite, named as in the folder it would
    be written to (``scenarios/<id>.json: tracks[2].t[5]: ...``)."""
    if not isinstance(suite, SuiteRecord):
        raise TypeError(f"expected a SuiteRecord, got {type(suite).__name__}")
    problems: list[Problem] = []
    check_suite_json(suite_obj(suite), Checker("suite.json", problems))
    for key, m in suite.maps.items():
        c = Checker(f"maps/{key}.json", problems)
        if check_map(map_obj(m), c) is not None and m.map_id != key:
            c.add("map_id", f"{key!r} (the key of SuiteRecord.maps)", repr(m.map_id))
    for s in suite.scenarios:
        c = Checker(f"scenarios/{s.scenario_id}.json", problems)
        obj = scenario_obj(s)
        check_scenario(obj, c)
        check_cross(obj, c, None, suite.maps)
    return problems
