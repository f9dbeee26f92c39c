"""``commonroad``: CommonRoad XML scenarios (2018b and 2020a) -> scenarios.

One ``.xml`` file (or every ``*.xml`` in a folder) is one scenario on its own map.

* **Time step** from the root's ``timeStepSize`` (s); states at integer
  ``time`` steps are resampled onto ``options.dt`` by ``common.convert_tracks``.
* **Lanelets** (``lanelets.assemble_map``): ``leftBound``/``rightBound``
  polylines (already in driving direction), ``successor`` refs, line markings
  (:data:`MARKING_TABLE`; with no ``lineMarking`` — all of 2018b — a bound is
  ``road_edge`` when no lanelet is adjacent on that side, ``solid`` next to
  opposite traffic, ``dashed`` next to same-direction traffic), speed limit
  from ``speedLimit`` (2018b) or a referenced speed-limit traffic sign's
  ``additionalValue`` (2020a; sign ids R2-1, 274, 274.1 ... — any
  ``trafficSignID`` starting with ``R2-1`` or ``274``), lanelet types
  ``crosswalk`` -> crosswalk polygon, ``sidewalk`` skipped,
  ``bicycleLane`` -> bike lane. ``intersection`` incomings' successors
  (left/right/straight) are connector lanes, and so is any other lanelet that
  geometry marks as one (it crosses another lane: the NGSIM maps draw the
  junction box as further lanelets after the listed successors).
* **Stop lines**: a lanelet's ``stopLine`` (its points, else the lanelet's
  end), guarded by the ``stopLine``'s ``trafficLightRef``, else the lanelet's.
* **Traffic lights** (2020a): each light is one signal group (its id); its
  ``cycle`` of (``duration`` steps, ``color``) repeats from ``timeOffset``
  (CommonRoad's semantics: state at step k is the cycle element at
  ``(k - timeOffset) mod cycle length``). green -> green, yellow -> yellow,
  red / redYellow -> red, inactive -> unknown. Inactive lights
  (``active`` false) are unknown throughout. The cycles were written by the
  CommonRoad authors, not measured, and are imported as given.
* **Obstacles**: ``dynamicObstacle`` (2020a) or ``obstacle`` with role
  ``dynamic`` (2018b) become tracks (:data:`CATEGORY_TABLE`); shape
  rectangle (length, width), circle (2r), polygon (its extent); position
  ``point`` (or the centre of a rectangle/circle), ``orientation`` and
  ``velocity`` ``exact`` or the middle of an interval; speed is along the
  orientation. Static obstacles (``staticObstacle`` / role ``static``,
  ``parkedVehicle``) become map obstacles.
* **Ego**: a CommonRoad planning problem has an initial state and a goal, not
  a recorded trajectory, and its vehicle is not among the obstacles, so it
  cannot be log-replayed. The ego is therefore a recorded obstacle:
  ``options.ego`` (an obstacle id), else ``common.select_ego`` (the
  curation rules: present at every step, moving >= 20 m, on the lanes,
  no implausible speed / acceleration / yaw rate; longest path wins). NGSIM
  positions are video-tracked and noisy: in the Peachtree sample every
  vehicle long enough to drive has an acceleration spike > 12 m/s^2, so no
  ego is chosen there (``--ego`` forces one). The planning problem's initial state and goal are kept
  in ``suite.json`` meta (``planning_problems``) and the removed vehicle is
  reported in the notes.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import MapRecord, ObstacleRecord
from drivee2e_jax.scenario.importers import common
from drivee2e_jax.scenario.importers.common import ImportOptions, ImportResult, RawTrack, Skipped
from drivee2e_jax.scenario.importers.lanelets import Lanelet, StopLineSpec, assemble_map

__all__ = ["CATEGORY_TABLE", "MARKING_TABLE", "read_scenario", "light_states", "load"]

CATEGORY_TABLE: dict[str, str | None] = {
    "car": "car", "truck": "truck", "bus": "bus", "bicycle": "cyclist", "pedestrian": "pedestrian",
    "priorityVehicle": "car", "taxi": "car", "motorcycle": "motorcycle",
    "parkedVehicle": None, "constructionZone": None, "train": None, "roadBoundary": None, "building": None,
    "pillar": None, "median_strip": None, "unknown": None,
}
MARKING_TABLE = {"dashed": "dashed", "broad_dashed": "dashed", "solid": "solid", "broad_solid": "solid",
                 "no_marking": "none", "unknown": "dashed", "curb": "road_edge", "lowered_curb": "road_edge",
                 "dashed_dashed": "dashed", "solid_solid": "double_solid", "solid_dashed": "solid",
                 "dashed_solid": "solid"}
_LIGHT_COLOR = {"green": 3, "yellow": 2, "red": 1, "redYellow": 1, "inactive": 0}
_STATIC_TYPES = ("parkedVehicle", "constructionZone", "roadBoundary", "building", "pillar", "median_strip")


class _Reader:
    """Element access with one-line errors naming the file and the element."""

    def __init__(self, path: Path):
        self.path = path

    def err(self, where: str, expected: str, got: str = "") -> DriveE2EError:
        return DriveE2EError(f"{self.path}: {where}: expected {expected}" + (f", got {got}" if got else ""))

    def num(self, e: ET.Element | None, where: str) -> float:
        if e is None:
            raise self.err(where, "a number element", "missing")
        try:
            return float((e.text or "").strip())
        except ValueError:
            raise self.err(where, "a number", repr((e.text or "").strip()[:30])) from None

    def value(self, e: ET.Element | None, where: str, default: float | None = None) -> float | None:
        """An ``exact`` value or the middle of ``intervalStart``/``intervalEnd``."""
        if e is None:
            if default is None:
                raise self.err(where, "an element", "missing")
            return default
        if e.find("exact") is not None:
            return self.num(e.find("exact"), f"{where}/exact")
        if e.find("intervalStart") is not None:
            return 0.5 * (self.num(e.find("intervalStart"), f"{where}/intervalStart")
                          + self.num(e.find("intervalEnd"), f"{where}/intervalEnd"))
        if (e.text or "").strip():
            return self.num(e, where)
        raise self.err(where, "<exact> or <intervalStart>/<intervalEnd>", "neither")

    def points(self, e: ET.Element | None, where: str) -> np.ndarray:
        if e is None:
            raise self.err(where, "a polyline element", "missing")
        pts = [(self.num(p.find("x"), f"{where}/point[{i}]/x"), self.num(p.find("y"), f"{where}/point[{i}]/y"))
               for i, p in enumerate(e.findall("point"))]
        if len(pts) < 2:
            raise self.err(where, "at least 2 <point>s", str(len(pts)))
        return np.array(pts, np.float64)

    def position(self, e: ET.Element | None, where: str) -> np.ndarray:
        if e is None:
            raise self.err(where, "a <position>", "missing")
        p = e.find("point")
        if p is None:
            p = e.find("rectangle/center")
        if p is None:
            p = e.find("circle/center")
        if p is None:
            raise self.err(where, "a <point> (or a rectangle/circle centre)", "none")
        return np.array([self.num(p.find("x"), f"{where}/x"), self.num(p.find("y"), f"{where}/y")])


def _parse(path: Path) -> ET.Element:
    return common.parse_xml(path, "CommonRoad", "commonRoad")


def _speed_signs(root: ET.Element, r: _Reader) -> dict[str, float]:
    out = {}
    for s in root.findall("trafficSign"):
        for el in s.findall("trafficSignElement"):
            sid = (el.findtext("trafficSignID") or "").strip()
            if (sid.startswith("R2-1") or sid.startswith("274")) and el.find("additionalValue") is not None:
                out[s.get("id", "")] = r.num(el.find("additionalValue"),
                                             f"trafficSign id={s.get('id')}/additionalValue")
    return out


def _markings(le: ET.Element, r: _Reader, adj: dict[str, str | None]) -> tuple[str, str]:
    out = []
    for side in ("left", "right"):
        m = le.findtext(f"{side}Bound/lineMarking")
        if m is not None:
            m = m.strip()
            if m not in MARKING_TABLE:
                raise r.err(f"lanelet id={le.get('id')}/{side}Bound/lineMarking",
                            f"one of {', '.join(MARKING_TABLE)}", repr(m))
            out.append(MARKING_TABLE[m])
        else:
            d = adj[side]
            out.append("road_edge" if d is None else ("solid" if d == "opposite" else "dashed"))
    return out[0], out[1]


def read_map(root: ET.Element, path: Path, map_id: str) -> tuple[MapRecord, list[str]]:
    """The lanelet network of a CommonRoad file -> (MapRecord, notes)."""
    r = _Reader(path)
    notes: list[str] = []
    signs = _speed_signs(root, r)
    connectors: set[int] = set()
    for inter in root.findall("intersection"):
        for inc in inter.findall("incoming"):
            for tag in ("successorsRight", "successorsStraight", "successorsLeft"):
                connectors.update(int(e.get("ref")) for e in inc.findall(tag) if e.get("ref"))
    lanelets, crosswalks, stops = [], [], []
    for i, le in enumerate(root.findall("lanelet")):
        where = f"lanelet id={le.get('id')}"
        try:
            lid = int(le.get("id"))
        except (TypeError, ValueError):
            raise r.err(f"lanelet[{i}]", "an integer 'id' attribute", repr(le.get("id"))) from None
        left = r.points(le.find("leftBound"), f"{where}/leftBound")
        right = r.points(le.find("rightBound"), f"{where}/rightBound")
        types = {(t.text or "").strip() for t in le.findall("laneletType")}
        if "crosswalk" in types:
            crosswalks.append(np.vstack([left, right[::-1]]))
            continue
        if "sidewalk" in types:
            continue
        adj = {}
        for side, tag in (("left", "adjacentLeft"), ("right", "adjacentRight")):
            a = le.find(tag)
            adj[side] = None if a is None else a.get("drivingDir", "same")
        lm, rm = _markings(le, r, adj)
        speed = None
        if le.find("speedLimit") is not None:
            speed = r.num(le.find("speedLimit"), f"{where}/speedLimit")
        for ref in le.findall("trafficSignRef"):
            speed = signs.get(ref.get("ref", ""), speed)
        succ = [int(s.get("ref")) for s in le.findall("successor") if s.get("ref")]
        lanelets.append(Lanelet(id=lid, left=left, right=right, left_marking=lm, right_marking=rm,
                                type="bike" if "bicycleLane" in types else "driving", speed_limit=speed,
                                successors=succ, connector=True if lid in connectors else None,
                                markings_guessed=le.find("leftBound/lineMarking") is None
                                or le.find("rightBound/lineMarking") is None))
        sl = le.find("stopLine")
        if sl is not None:
            pts = np.array([[r.num(p.find("x"), f"{where}/stopLine/point/x"),
                             r.num(p.find("y"), f"{where}/stopLine/point/y")] for p in sl.findall("point")])
            if len(pts) < 2:
                pts = np.stack([left[-1], right[-1]])
            ref = sl.find("trafficLightRef")
            if ref is None:
                ref = le.find("trafficLightRef")
            group = int(ref.get("ref")) if ref is not None and ref.get("ref") else -1
            stops.append(StopLineSpec(points=pts, signal_group=group, lanes=[lid]))
    if not lanelets:
        raise DriveE2EError(f"{path}: expected at least one <lanelet>")
    ids = {ll.id for ll in lanelets}
    for ll in lanelets:
        missing = [s for s in ll.successors if s not in ids]
        if missing:
            notes.append(f"{path.name}: lanelet {ll.id}: successor {missing[0]} is not a vehicle lanelet; dropped")
            ll.successors = [s for s in ll.successors if s in ids]
    m = assemble_map(map_id, lanelets, crosswalks=crosswalks, stop_lines=stops,
                     meta={"source": path.name, "format": f"commonroad {root.get('commonRoadVersion', '?')}"})
    return m, notes


def light_states(cycle: list[tuple[int, int]], offset: int, step_of: np.ndarray) -> np.ndarray:
    """SIGNAL_STATES index at source steps ``step_of`` (k,) of a light with
    ``cycle`` [(duration steps, state index)] starting at ``offset``."""
    dur = np.array([d for d, _ in cycle], np.int64)
    total = int(dur.sum())
    starts = np.r_[0, np.cumsum(dur)[:-1]]
    pos = np.mod(np.asarray(step_of, np.int64) - offset, total)
    i = np.searchsorted(starts, pos, side="right") - 1
    return np.array([cycle[j][1] for j in i], np.int8)


def _lights(root: ET.Element, r: _Reader) -> dict[int, tuple[list[tuple[int, int]], int, bool]]:
    out = {}
    for tl in root.findall("trafficLight"):
        where = f"trafficLight id={tl.get('id')}"
        cyc = []
        for j, ce in enumerate(tl.findall("cycle/cycleElement")):
            color = (ce.findtext("color") or "").strip()
            if color not in _LIGHT_COLOR:
                raise r.err(f"{where}/cycleElement[{j}]/color", f"one of {', '.join(_LIGHT_COLOR)}", repr(color))
            d = int(r.num(ce.find("duration"), f"{where}/cycleElement[{j}]/duration"))
            if d <= 0:
                raise r.err(f"{where}/cycleElement[{j}]/duration", "a positive number of steps", str(d))
            cyc.append((d, _LIGHT_COLOR[color]))
        if not cyc:
            raise r.err(f"{where}/cycle", "at least one <cycleElement>", "none")
        off_e = tl.find("cycle/timeOffset")
        off = int(r.num(off_e, f"{where}/cycle/timeOffset")) if off_e is not None else 0
        active = (tl.findtext("active") or "true").strip().lower() != "false"
        out[int(tl.get("id"))] = (cyc, off, active)
    return out


def _shape_size(o: ET.Element, r: _Reader, where: str) -> np.ndarray | None:
    rect = o.find("shape/rectangle")
    if rect is not None:
        return np.array([r.num(rect.find("length"), f"{where}/shape/rectangle/length"),
                         r.num(rect.find("width"), f"{where}/shape/rectangle/width")])
    circ = o.find("shape/circle")
    if circ is not None:
        d = 2 * r.num(circ.find("radius"), f"{where}/shape/circle/radius")
        return np.array([d, d])
    poly = o.find("shape/polygon")
    if poly is not None:
        p = r.points(poly, f"{where}/shape/polygon")
        return p.max(0) - p.min(0)
    return None


def _states(o: ET.Element, r: _Reader, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(steps (n,), xy (n, 2), yaw (n,), speed (n,)) from initialState + trajectory."""
    elems = [o.find("initialState")] + o.findall("trajectory/state")
    if elems[0] is None:
        raise r.err(where, "an <initialState>", "missing")
    k, xy, yaw, v = [], [], [], []
    for j, s in enumerate(elems):
        w = f"{where}/{'initialState' if j == 0 else f'trajectory/state[{j - 1}]'}"
        k.append(int(round(r.value(s.find("time"), f"{w}/time"))))
        xy.append(r.position(s.find("position"), f"{w}/position"))
        yaw.append(r.value(s.find("orientation"), f"{w}/orientation"))
        v.append(r.value(s.find("velocity"), f"{w}/velocity", default=float("nan")))
    k, xy, yaw, v = np.array(k), np.array(xy), np.array(yaw), np.array(v)
    if np.any(np.diff(k) <= 0):
        j = int(np.flatnonzero(np.diff(k) <= 0)[0]) + 1
        raise r.err(f"{where}/trajectory/state[{j - 1}]/time", "increasing time steps", f"{k[j]} after {k[j - 1]}")
    return k, xy, yaw, v


def read_scenario(path: Path, map_id: str, root: ET.Element | None = None,
                  ) -> tuple[MapRecord, list[RawTrack], dict, float, list[Skipped], list[str]]:
    """One CommonRoad file -> (map, raw tracks (t in s), {light id: (cycle, offset, active)},
    time step s, skipped, notes). Static obstacles are added to the map. ``root``: the
    already parsed file, if any."""
    path = Path(path)
    root = _parse(path) if root is None else root
    r = _Reader(path)
    try:
        step = float(root.get("timeStepSize"))
        assert step > 0
    except (TypeError, ValueError, AssertionError):
        raise r.err("<commonRoad timeStepSize>", "a positive number (s)", repr(root.get("timeStepSize"))) from None
    m, notes = read_map(root, path, map_id)
    skipped: list[Skipped] = []
    raws: list[RawTrack] = []
    obstacles = [(o, "dynamic") for o in root.findall("dynamicObstacle")]
    obstacles += [(o, "static") for o in root.findall("staticObstacle")]
    obstacles += [(o, (o.findtext("role") or "").strip()) for o in root.findall("obstacle")]
    for o, role in obstacles:
        oid = o.get("id", "?")
        where = f"obstacle id={oid}"
        src = f"{path} obstacle {oid}"
        kind = (o.findtext("type") or "").strip()
        size = _shape_size(o, r, where)
        if size is None:
            skipped.append(Skipped(src, "no rectangle/circle/polygon shape"))
            continue
        if role == "static" or kind in _STATIC_TYPES:
            k, xy, yaw, _ = _states(o, r, where)
            m.obstacles.append(ObstacleRecord(polygon=common.box_polygon(xy[0], float(yaw[0]), *map(float, size)),
                                              height=1.5, kind=kind or "static"))
            continue
        if role != "dynamic":
            skipped.append(Skipped(src, f"obstacle role {role!r}; expected dynamic or static"))
            continue
        cat, skip = common.map_category(kind, CATEGORY_TABLE, src)
        if skip is not None:
            skipped.append(skip)
            continue
        k, xy, yaw, v = _states(o, r, where)
        vel = None
        if not np.isnan(v).any():
            vel = np.stack([v * np.cos(yaw), v * np.sin(yaw)], axis=1)
        h = common.DEFAULT_SIZES[cat][2]
        raws.append(RawTrack(source_id=str(oid), category=cat, t=k * step, xy=xy, yaw=yaw,
                             size=np.array([size[0], size[1], h]), vel=vel))
    return m, raws, _lights(root, r), step, skipped, notes


def _planning_problems(root: ET.Element, r: _Reader) -> list[dict]:
    out = []
    for pp in root.findall("planningProblem"):
        init = pp.find("initialState")
        entry: dict = {"id": pp.get("id")}
        if init is not None and init.find("position") is not None:
            xy = r.position(init.find("position"), "planningProblem/initialState/position")
            entry["initial_xy"] = [round(float(x), 3) for x in xy]
            entry["initial_yaw"] = r.value(init.find("orientation"), "planningProblem/initialState/orientation", 0.0)
            entry["initial_speed"] = r.value(init.find("velocity"), "planningProblem/initialState/velocity", 0.0)
        goals = []
        for g in pp.findall("goalState"):
            pos = g.find("position")
            if pos is not None and pos.find("lanelet") is not None:
                goals.append({"lanelets": [int(e.get("ref")) for e in pos.findall("lanelet")]})
            elif pos is not None:
                try:
                    xy = r.position(pos, "planningProblem/goalState/position")
                    goals.append({"xy": [round(float(x), 3) for x in xy]})
                except DriveE2EError:
                    pass
        entry["goals"] = goals
        out.append(entry)
    return out


def _load_file(path: Path, options: ImportOptions, result: ImportResult) -> None:
    root = _parse(path)
    map_id = common.safe_id(root.get("benchmarkID") or path.stem)
    m, raws, lights, step, skipped, notes = read_scenario(path, map_id, root)
    result.skipped += skipped
    result.notes += notes
    result.maps[map_id] = m
    pps = _planning_problems(root, _Reader(path))
    if pps:
        result.meta.setdefault("planning_problems", {})[map_id] = pps
        result.notes.append(f"{path.name}: the planning problem's vehicle (start {pps[0].get('initial_xy')}) has no "
                            "recorded trajectory and is not among the obstacles; the ego is a recorded obstacle")
    if not raws:
        result.skipped.append(Skipped(str(path), "no dynamic obstacle with a usable trajectory, so no ego"))
        return
    if options.ego is not None and options.ego not in {t.source_id for t in raws}:
        raise DriveE2EError(f"{path}: --ego {options.ego!r}: expected a dynamic obstacle id of the file "
                            f"({', '.join(sorted(t.source_id for t in raws)[:12])})")
    dt = options.dt
    t_end = max(float(t.t[-1]) for t in raws)
    num_steps = int(math.floor(t_end / dt + 1e-6)) + 1
    conv = common.convert_tracks(raws, options.ego, dt, num_steps, str(path), max_gap_s=max(1.5 * step, 0.15))
    result.skipped += conv.skipped
    ego = None if options.ego is None else conv.ids[options.ego]
    remaining = None if options.max_scenarios is None else options.max_scenarios - len(result.scenarios)

    def states_at(t: np.ndarray) -> dict[int, np.ndarray]:
        src_steps = np.rint(t / step).astype(np.int64)
        return {g: (light_states(c, off, src_steps) if active else np.zeros(len(t), np.int8))
                for g, (c, off, active) in sorted(lights.items())}

    scen = common.windowed_scenarios(map_id, m, conv.tracks, ego, dt, num_steps, options, str(path),
                                     result.skipped, result.notes, limit=remaining, signals=states_at,
                                     source_ids=conv.ids.table())
    result.scenarios += scen
    result.meta.setdefault("track_ids", {})[map_id] = {str(k): v for k, v in conv.ids.table().items()}


def load(paths: list[Path], options: ImportOptions) -> ImportResult:
    """Import CommonRoad XML files (see the module docstring)."""
    result = ImportResult(maps={}, scenarios=[], skipped=[], notes=[], meta={"source_format": "commonroad"})
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(p.glob("*.xml"))
            if not found:
                raise DriveE2EError(f"{p}: expected CommonRoad .xml files in the folder; found none")
            files += found
        else:
            files.append(p)
    for f in files:
        if options.max_scenarios is not None and len(result.scenarios) >= options.max_scenarios:
            break
        _load_file(f, options, result)
    return result
