"""Lanelet2 OSM maps -> ``MapRecord`` (host side; the map half of ``lanelet2-csv``).

Reads the OSM XML that Lanelet2 writes (also JOSM-saved files, single or
double quotes alike):

* **Projection.** Nodes carry ``lat``/``lon``. When every node also has
  ``local_x``/``local_y`` tags (Autoware maps) those are used as metres.
  Otherwise points go through :func:`utm_projector`, which reproduces
  Lanelet2's ``UtmProjector(Origin(lat0, lon0))``: WGS84 transverse Mercator
  in the UTM zone of the origin (scale 0.9996), minus the origin's own
  projection, so the origin maps to (0, 0). The default origin is (0, 0), the
  origin of the INTERACTION and SinD maps, whose tracks are in that frame.
* **Lanelets** (``type=lanelet`` relations with ``left``/``right`` way
  members) become lanes (``lanelets.assemble_map``: midline, width,
  successors and junction connectors by geometry). Subtype ``crosswalk`` /
  ``walkway`` lanelets become crosswalk polygons, ``bicycle_lane`` lanes of
  type ``bike``; other subtypes (road, highway, main_road, play_street,
  none...) are driving lanes. ``speed_limit`` tags (km/h, or "50 mph") are used.
* **Markings** from a bound way's ``type``/``subtype`` (:func:`marking_of`).
* **Areas**: ``multipolygon`` relations / closed ways with subtype
  ``crosswalk`` become crosswalks.
* **Stop lines**: ``stop_line`` ways. ``traffic_light`` regulatory elements tie
  their ``ref_line`` (a stop line) to the ``refers`` light way; the light's
  signal group is the number in its name (``Traffic light 4`` -> 4, the
  column of the SinD/INTERACTION light CSV), else its way id. Stop lines with
  no regulatory element get group -1. A light with no ``ref_line`` stops the
  lanelets that list it (member role ``regulatory_element``) at their ends.
* Not read: right_of_way / traffic_sign / speed_limit regulatory elements,
  ``one_way=no`` vehicle lanelets are imported in their drawn direction only.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import BoundaryRecord, MapRecord
from drivee2e_jax.scenario.importers import common
from drivee2e_jax.scenario.importers.lanelets import Lanelet, StopLineSpec, assemble_map, orient_bounds

__all__ = ["OsmData", "utm_projector", "read_osm", "marking_of", "load_map", "signal_group_of_name"]

# WGS84
_A = 6378137.0
_F = 1.0 / 298.257223563
_K0 = 0.9996


def utm_projector(lat0: float = 0.0, lon0: float = 0.0) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """(lat, lon) degrees -> (n, 2) metres, as Lanelet2's ``UtmProjector(Origin(lat0, lon0))``.

    Transverse Mercator on WGS84 (Krueger series to n^4, sub-millimetre within
    a UTM zone) about the central meridian of the origin's UTM zone, scale
    0.9996, shifted so that the origin is (0, 0). Points across the equator or
    a zone border stay in the origin's zone (as Lanelet2 transfers them).
    """
    zone = int(math.floor((lon0 + 180.0) / 6.0)) % 60 + 1
    lam0 = math.radians(-183.0 + 6.0 * zone)
    n = _F / (2.0 - _F)
    big_a = _A / (1.0 + n) * (1.0 + n**2 / 4.0 + n**4 / 64.0)
    alpha = (n / 2 - 2 * n**2 / 3 + 5 * n**3 / 16 + 41 * n**4 / 180,
             13 * n**2 / 48 - 3 * n**3 / 5 + 557 * n**4 / 1440,
             61 * n**3 / 240 - 103 * n**4 / 140,
             49561 * n**4 / 161280)
    c = 2.0 * math.sqrt(n) / (1.0 + n)

    def raw(lat, lon):
        phi = np.radians(np.asarray(lat, np.float64))
        lam = np.radians(np.asarray(lon, np.float64)) - lam0
        s = np.sin(phi)
        t = np.sinh(np.arctanh(s) - c * np.arctanh(c * s))
        xi = np.arctan2(t, np.cos(lam))
        eta = np.arctanh(np.sin(lam) / np.sqrt(1.0 + t * t))
        x, y = eta.copy(), xi.copy()
        for j, a in enumerate(alpha, start=1):
            x = x + a * np.cos(2 * j * xi) * np.sinh(2 * j * eta)
            y = y + a * np.sin(2 * j * xi) * np.cosh(2 * j * eta)
        return np.stack([_K0 * big_a * x, _K0 * big_a * y], axis=-1)

    origin = raw(lat0, lon0)

    def project(lat, lon):
        return raw(lat, lon) - origin

    return project


@dataclass
class OsmData:
    """A parsed OSM file: node positions (m), ways (node ids + tags), relations."""

    path: Path
    xy: dict[int, np.ndarray]
    ways: dict[int, tuple[list[int], dict[str, str]]]
    relations: dict[int, tuple[list[tuple[str, int, str]], dict[str, str]]]  # members (type, ref, role), tags

    def way_points(self, way_id: int, where: str) -> np.ndarray:
        if way_id not in self.ways:
            raise DriveE2EError(f"{self.path}: {where}: expected a way id present in the file, got {way_id}")
        nodes = self.ways[way_id][0]
        missing = [n for n in nodes if n not in self.xy]
        if missing:
            raise DriveE2EError(f"{self.path}: way {way_id}: expected node {missing[0]} to be defined in the file")
        return np.array([self.xy[n] for n in nodes], np.float64)


def _tags(e: ET.Element) -> dict[str, str]:
    return {t.get("k", ""): t.get("v", "") for t in e.findall("tag")}


def _int(e: ET.Element, key: str, path: Path, what: str) -> int:
    v = e.get(key)
    try:
        return int(v)
    except (TypeError, ValueError):
        raise DriveE2EError(f"{path}: <{what}>: expected an integer '{key}' attribute, got {v!r}") from None


def read_osm(path: Path, origin: tuple[float, float] = (0.0, 0.0)) -> OsmData:
    """Parse an OSM XML file; node positions projected as the module docstring says."""
    path = Path(path)
    root = common.parse_xml(path, "OSM", "osm")
    ids, lat, lon, local = [], [], [], []
    for e in root.iter("node"):
        nid = _int(e, "id", path, "node")
        tags = _tags(e)
        try:
            la, lo = float(e.get("lat")), float(e.get("lon"))
        except (TypeError, ValueError):
            if "local_x" not in tags:
                raise DriveE2EError(f"{path}: <node id={nid}>: expected numeric 'lat' and 'lon' attributes "
                                    f"(or local_x/local_y tags)") from None
            la = lo = float("nan")
        ids.append(nid)
        lat.append(la)
        lon.append(lo)
        try:
            local.append((float(tags["local_x"]), float(tags["local_y"])) if "local_x" in tags else None)
        except (KeyError, ValueError):
            raise DriveE2EError(f"{path}: <node id={nid}>: expected numeric local_x and local_y tags") from None
    if ids and all(p is not None for p in local):
        pts = np.array(local, np.float64)
    else:
        pts = utm_projector(*origin)(np.array(lat), np.array(lon)).reshape(-1, 2) if ids else np.zeros((0, 2))
        if np.isnan(pts).any():
            i = int(np.flatnonzero(np.isnan(pts).any(axis=1))[0])
            raise DriveE2EError(f"{path}: <node id={ids[i]}>: expected lat/lon (not every node has local_x/local_y)")
    xy = {i: p for i, p in zip(ids, pts)}
    ways = {}
    for e in root.iter("way"):
        wid = _int(e, "id", path, "way")
        nodes = [_int(nd, "ref", path, f"way id={wid}><nd") for nd in e.findall("nd")]
        ways[wid] = (nodes, _tags(e))
    rels = {}
    for e in root.iter("relation"):
        rid = _int(e, "id", path, "relation")
        members = [(m.get("type", ""), _int(m, "ref", path, f"relation id={rid}><member"), m.get("role", ""))
                   for m in e.findall("member")]
        rels[rid] = (members, _tags(e))
    return OsmData(path=path, xy=xy, ways=ways, relations=rels)


_EDGE_TYPES = {"curbstone", "road_border", "guard_rail", "fence", "wall", "keepout", "jersey_barrier"}
_LINE_TYPES = {"line_thin", "line_thick"}
_NONE_TYPES = {"virtual", "zebra_marking", "stop_line", "pedestrian_marking", "bike_marking", "", None}


def marking_of(tags: dict[str, str]) -> str | None:
    """A bound way's ``MARKINGS`` name from its tags; None for an unknown type.

    curbstone / road_border / guard_rail / fence / wall -> road_edge;
    line_thin / line_thick: subtype dashed -> dashed, solid_solid ->
    double_solid, solid / dashed_solid / solid_dashed / none given -> solid
    (Lanelet2 treats an unspecified line as not crossable);
    virtual / zebra_marking / no type -> none.
    """
    t, sub = tags.get("type"), tags.get("subtype", "")
    if t in _EDGE_TYPES:
        return "road_edge"
    if t in _LINE_TYPES:
        return {"dashed": "dashed", "solid_solid": "double_solid", "dashed_dashed": "dashed"}.get(sub, "solid")
    if t in _NONE_TYPES:
        return "none"
    return None


_NUM = re.compile(r"(\d+)\s*$")


def signal_group_of_name(name: str) -> int | None:
    """The trailing number of a light's name or CSV column ('Traffic light 4' -> 4)."""
    m = _NUM.search(name.strip())
    return int(m.group(1)) if m else None


def _speed(tags: dict[str, str]) -> float | None:
    v = tags.get("speed_limit")
    if not v:
        return None
    m = re.match(r"\s*([0-9.]+)\s*(mph|km/h|kmh)?", v)
    if not m:
        return None
    return float(m.group(1)) * (0.44704 if m.group(2) == "mph" else 1.0 / 3.6)


def _area_polygon(osm: OsmData, members: list[tuple[str, int, str]], rid: int) -> np.ndarray | None:
    outer = [ref for typ, ref, role in members if typ == "way" and role == "outer"]
    if not outer:
        return None
    pts = [osm.way_points(w, f"relation {rid} outer") for w in outer]
    ring = pts[0]
    for p in pts[1:]:  # chain the outer ways end to end
        if np.linalg.norm(ring[-1] - p[0]) > np.linalg.norm(ring[-1] - p[-1]):
            p = p[::-1]
        ring = np.vstack([ring, p[1:]])
    if np.linalg.norm(ring[0] - ring[-1]) < 1e-6:
        ring = ring[:-1]
    return ring if len(ring) >= 3 else None


def load_map(path: Path, map_id: str, origin: tuple[float, float] = (0.0, 0.0)) -> tuple[MapRecord, list[str]]:
    """A Lanelet2 OSM file -> (MapRecord, notes). Lane ids are the lanelet
    relation ids (OSM ids may be negative; they are kept, the schema allows it)."""
    osm = read_osm(path, origin)
    notes: list[str] = []
    lanelets: list[Lanelet] = []
    crosswalks: list[np.ndarray] = []
    used_ways: set[int] = set()
    unknown: dict[str, int] = {}
    for rid, (members, tags) in sorted(osm.relations.items(), key=lambda kv: abs(kv[0])):
        rtype, sub = tags.get("type"), tags.get("subtype", "")
        if rtype == "multipolygon" and sub in ("crosswalk", "walkway"):
            ring = _area_polygon(osm, members, rid)
            if ring is not None:
                crosswalks.append(ring)
            continue
        if rtype != "lanelet":
            continue
        left = [ref for typ, ref, role in members if typ == "way" and role == "left"]
        right = [ref for typ, ref, role in members if typ == "way" and role == "right"]
        if len(left) != 1 or len(right) != 1:
            raise DriveE2EError(f"{osm.path}: <relation id={rid}> (lanelet): expected one 'left' and one 'right' "
                                f"way member, got {len(left)} and {len(right)}")
        lp = osm.way_points(left[0], f"relation {rid} left")
        rp = osm.way_points(right[0], f"relation {rid} right")
        if len(lp) < 2 or len(rp) < 2:
            raise DriveE2EError(f"{osm.path}: <relation id={rid}> (lanelet): expected bounds of >= 2 nodes each")
        lp, rp, flipped = orient_bounds(lp, rp)
        ltag, rtag = osm.ways[left[0]][1], osm.ways[right[0]][1]
        if flipped:
            ltag, rtag = rtag, ltag
        if sub in ("crosswalk", "walkway"):
            crosswalks.append(np.vstack([lp, rp[::-1]]))
            continue
        marks = []
        for way_tags in (ltag, rtag):
            m = marking_of(way_tags)
            if m is None:
                key = f"{way_tags.get('type')}/{way_tags.get('subtype', '')}"
                unknown[key] = unknown.get(key, 0) + 1
                m = "none"
            marks.append(m)
        used_ways.update((left[0], right[0]))
        lanelets.append(Lanelet(id=rid, left=lp, right=rp, left_marking=marks[0], right_marking=marks[1],
                                type="bike" if sub == "bicycle_lane" else "driving", speed_limit=_speed(tags),
                                name=tags.get("name", "")))
    for key, count in sorted(unknown.items()):
        notes.append(f"{osm.path.name}: {count} lanelet bound(s) of unknown way type {key!r} taken as unmarked")
    if not lanelets:
        raise DriveE2EError(f"{osm.path}: expected at least one lanelet relation (type=lanelet with left/right ways)")

    # stop lines, tied to lights through traffic_light regulatory elements
    group_of_line: dict[int, int] = {}
    stops: list[StopLineSpec] = []
    by_id = {ll.id: ll for ll in lanelets}
    users: dict[int, list[int]] = {}  # regulatory element -> lanelets naming it
    for rid, (members, tags) in osm.relations.items():
        if tags.get("type") == "lanelet":
            for _typ, ref, role in members:
                if role == "regulatory_element" and rid in by_id:
                    users.setdefault(ref, []).append(rid)
    for rid, (members, tags) in osm.relations.items():
        if tags.get("type") != "regulatory_element" or tags.get("subtype") != "traffic_light":
            continue
        lines = [ref for typ, ref, role in members if role == "ref_line"]
        lights = [ref for typ, ref, role in members if role == "refers"]
        if not lights:
            notes.append(f"{osm.path.name}: traffic_light regulatory element {rid} has no 'refers' light; ignored")
            continue
        name = osm.ways.get(lights[0], ([], {}))[1].get("name", "")
        group = signal_group_of_name(name)
        group = group if group is not None else abs(lights[0])
        for ln in lines:
            group_of_line[ln] = group
        if not lines:  # no stop line drawn: the lanelets that name the light stop at their end
            for lid in users.get(rid, []):
                ll = by_id[lid]
                stops.append(StopLineSpec(points=np.stack([ll.left[-1], ll.right[-1]]), signal_group=group,
                                          lanes=[lid]))
    extra: list[BoundaryRecord] = []
    for wid, (nodes, tags) in sorted(osm.ways.items(), key=lambda kv: abs(kv[0])):
        t = tags.get("type")
        if t == "stop_line":
            stops.append(StopLineSpec(points=osm.way_points(wid, f"way {wid}"),
                                      signal_group=group_of_line.get(wid, -1)))
        elif wid not in used_ways and marking_of(tags) == "road_edge" and len(nodes) >= 2:
            extra.append(BoundaryRecord(points=osm.way_points(wid, f"way {wid}"), marking="road_edge"))
    m = assemble_map(map_id, lanelets, crosswalks=crosswalks, stop_lines=stops, extra_boundaries=extra,
                     meta={"source": osm.path.name, "format": "lanelet2", "origin_latlon": list(origin)})
    if len(stops) and not m.stop_lines:
        notes.append(f"{osm.path.name}: none of the {len(stops)} stop line(s) crosses a lane's end; no stop lines kept")
    return m, notes
