"""``opendrive``: OpenDRIVE ``.xodr`` maps (+ optional INTERACTION-format tracks).

An OpenDRIVE file is a map with no traffic. ``drivee2e suite import opendrive
MAP.xodr [TRACKS.csv ... | RECORDING_FOLDER ...]`` reads the map and, for
every track CSV / recording folder, builds scenarios on that map with the same
CSV reader, ego choice and windows as ``lanelet2-csv``
(``lanelet2_csv.import_recording``); a track path given without an ``.xodr``
finds the map next to it (see :func:`load`). With only an ``.xodr`` the result
holds the map and no scenario, so nothing is written (a suite needs at least
one scenario; the CLI says "no scenario could be imported").

Geometry (host side, numpy):

* **Reference line** (``planView``): ``line``, ``arc``, ``spiral`` (a
  clothoid: curvature linear in s, integrated numerically with 8-point
  Gauss-Legendre per <= 0.5 m step; tested against Fresnel integrals),
  ``poly3`` (v(u) in the local frame; s -> u by the numeric arc length) and
  ``paramPoly3`` (``pRange`` ``normalized`` p in [0, 1] or ``arcLength``
  p in [0, length]; s -> p by the numeric arc length, so points are placed by
  true arc length either way). Sampled every :data:`STEP_M` plus every
  geometry and lane-section start.
* **Lanes**: ``laneOffset`` and lane ``width`` cubics (``sOffset`` relative
  to the record / the lane section), lanes stacked outward from the offset
  reference line; each lane of each lane section becomes one lane whose
  centreline is the middle of its inner and outer border, in driving direction
  (right-hand traffic: right lanes (id < 0) run along +s, left lanes against
  it; ``rule="LHT"`` on the road swaps that).
* **Lane types**: driving / entry / exit / onRamp / offRamp /
  connectingRamp / bidirectional -> driving, biking -> bike, parking ->
  parking; lanes of a road inside a junction (``junction != -1``) are
  ``connector`` lanes. Other types (sidewalk, shoulder, border, median,
  restricted, none, ...) carry no traffic and are not lanes.
* **Markings**: a lane's ``roadMark`` (the first record of the section) marks
  its outer border; its inner border carries the mark of the next lane inward
  (the centre lane for +-1). solid -> solid, broken -> dashed, solid solid ->
  double_solid, solid broken / broken solid -> solid, broken broken / botts
  dots -> dashed, curb / edge / grass -> road_edge, none -> none; an outer
  border with no mark next to no vehicle lane is a road_edge. Junction lanes
  are unmarked.
* **Successors** come from geometry (``lanelets.assemble_map``: a lane
  starting where another ends, heading within 45 deg); OpenDRIVE lanes meet
  exactly at their borders, so this recovers the road, lane-section and
  junction links (including every connecting lane leaving one incoming lane).
* Lane ids: ``road_index * 1000 + section_index * 100 + 50 + lane id``
  (road index in file order); the table id -> "road/section/lane" is in the
  map's meta. Signals and objects are not read.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import MapRecord
from drivee2e_jax.scenario.importers import common
from drivee2e_jax.scenario.importers.common import ImportOptions, ImportResult
from drivee2e_jax.scenario.importers.lanelet2_csv import find_map, import_recording, recordings_of
from drivee2e_jax.scenario.importers.lanelets import Lanelet, assemble_map

__all__ = ["STEP_M", "Geometry", "eval_geometry", "reference_line", "read_map", "load"]

#: Reference-line sampling step, m.
STEP_M = 1.0
_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)

LANE_TYPES = {"driving": "driving", "entry": "driving", "exit": "driving", "onRamp": "driving",
              "offRamp": "driving", "connectingRamp": "driving", "bidirectional": "driving",
              "biking": "bike", "parking": "parking"}
ROAD_MARKS = {"solid": "solid", "broken": "dashed", "solid solid": "double_solid", "solid broken": "solid",
              "broken solid": "solid", "broken broken": "dashed", "botts dots": "dashed", "curb": "road_edge",
              "edge": "road_edge", "grass": "road_edge", "none": "none", "custom": "solid"}


@dataclass
class Geometry:
    """One planView record: start s, x, y, hdg, length, kind and its parameters."""

    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str
    params: dict


# --------------------------------------------------------------------------
# Reference line
# --------------------------------------------------------------------------


def _integrate(f, a: float, b: float, n: int) -> np.ndarray:
    """Cumulative integral of vector f(t) -> (k, d) over n equal steps of [a, b] (n+1 values)."""
    edges = np.linspace(a, b, n + 1)
    h = (edges[1:] - edges[:-1]) / 2.0
    mids = (edges[1:] + edges[:-1]) / 2.0
    t = mids[:, None] + h[:, None] * _GL_X[None, :]
    vals = f(t.reshape(-1)).reshape(n, len(_GL_X), -1)
    steps = np.einsum("nkd,k->nd", vals, _GL_W) * h[:, None]
    return np.vstack([np.zeros((1, steps.shape[1])), np.cumsum(steps, axis=0)])


def _arc_inverse(deriv, p_end: float, ds: np.ndarray, length: float) -> np.ndarray:
    """Parameters p at arc lengths ``ds`` of a curve with derivative ``deriv(p) -> (k, 2)``
    over p in [0, p_end] (numeric arc length on a fine grid, then interpolation)."""
    n = max(64, int(math.ceil(length / 0.1)))
    arc = _integrate(lambda p: np.linalg.norm(deriv(p), axis=1)[:, None], 0.0, p_end, n)[:, 0]
    grid = np.linspace(0.0, p_end, n + 1)
    return np.interp(np.clip(ds, 0.0, arc[-1]), arc, grid)


def eval_geometry(g: Geometry, ds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (k, 2) and headings (k,) at distances ``ds`` (k,) in [0, length] along one geometry."""
    ds = np.asarray(ds, np.float64)
    c, s = math.cos(g.hdg), math.sin(g.hdg)
    if g.kind == "line":
        xy = np.stack([g.x + ds * c, g.y + ds * s], axis=1)
        return xy, np.full(len(ds), g.hdg)
    if g.kind == "arc":
        k = g.params["curvature"]
        if abs(k) < 1e-12:
            return eval_geometry(Geometry(g.s, g.x, g.y, g.hdg, g.length, "line", {}), ds)
        h = g.hdg + k * ds
        xy = np.stack([g.x + (np.sin(h) - s) / k, g.y - (np.cos(h) - c) / k], axis=1)
        return xy, h
    if g.kind == "spiral":
        k0, k1 = g.params["curvStart"], g.params["curvEnd"]
        rate = (k1 - k0) / g.length if g.length > 0 else 0.0

        def head(t):
            return g.hdg + k0 * t + 0.5 * rate * t * t

        n = max(1, int(math.ceil(g.length / 0.5)))
        cum = _integrate(lambda t: np.stack([np.cos(head(t)), np.sin(head(t))], axis=1), 0.0, g.length, n)
        grid = np.linspace(0.0, g.length, n + 1)
        # between grid nodes integrate the short remainder exactly enough with one more GL pass
        i = np.clip(np.searchsorted(grid, ds, side="right") - 1, 0, n)
        base = cum[i]
        rest = np.array([_integrate(lambda t: np.stack([np.cos(head(t)), np.sin(head(t))], axis=1), a, b, 1)[-1]
                         if b > a else np.zeros(2) for a, b in zip(grid[i], ds)]).reshape(-1, 2)
        xy = np.array([g.x, g.y]) + base + rest
        return xy, head(ds)
    if g.kind == "poly3":
        a, b, cc, d = (g.params[k] for k in ("a", "b", "c", "d"))

        def deriv(u):
            return np.stack([np.ones_like(u), b + 2 * cc * u + 3 * d * u * u], axis=1)

        u = _arc_inverse(deriv, g.length, ds, g.length)
        v = a + b * u + cc * u * u + d * u ** 3
        dv = b + 2 * cc * u + 3 * d * u * u
        local_h = np.arctan(dv)
        xy = np.stack([g.x + u * c - v * s, g.y + u * s + v * c], axis=1)
        return xy, g.hdg + local_h
    if g.kind == "paramPoly3":
        P = g.params
        p_end = 1.0 if P["pRange"] == "normalized" else g.length

        def deriv(p):
            return np.stack([P["bU"] + 2 * P["cU"] * p + 3 * P["dU"] * p * p,
                             P["bV"] + 2 * P["cV"] * p + 3 * P["dV"] * p * p], axis=1)

        p = _arc_inverse(deriv, p_end, ds, g.length)
        u = P["aU"] + P["bU"] * p + P["cU"] * p * p + P["dU"] * p ** 3
        v = P["aV"] + P["bV"] * p + P["cV"] * p * p + P["dV"] * p ** 3
        du = deriv(p)
        xy = np.stack([g.x + u * c - v * s, g.y + u * s + v * c], axis=1)
        return xy, g.hdg + np.arctan2(du[:, 1], du[:, 0])
    raise ValueError(g.kind)


def reference_line(geoms: list[Geometry], s_query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points (k, 2) and headings (k,) of a road's reference line at road s values (k,)."""
    s_query = np.asarray(s_query, np.float64)
    starts = np.array([g.s for g in geoms])
    idx = np.clip(np.searchsorted(starts, s_query, side="right") - 1, 0, len(geoms) - 1)
    xy = np.zeros((len(s_query), 2))
    hdg = np.zeros(len(s_query))
    for i in np.unique(idx):
        m = idx == i
        g = geoms[i]
        xy[m], hdg[m] = eval_geometry(g, np.clip(s_query[m] - g.s, 0.0, g.length))
    return xy, hdg


# --------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------


class _Reader:
    def __init__(self, path: Path):
        self.path = path

    def num(self, e: ET.Element, key: str, where: str, default: float | None = None) -> float:
        v = e.get(key)
        if v is None:
            if default is not None:
                return default
            raise DriveE2EError(f"{self.path}: {where}: expected a numeric '{key}' attribute, got none")
        try:
            return float(v)
        except ValueError:
            raise DriveE2EError(f"{self.path}: {where}: expected a numeric '{key}' attribute, got {v!r}") from None


def _geometries(road: ET.Element, r: _Reader, where: str) -> list[Geometry]:
    out = []
    for j, ge in enumerate(road.findall("planView/geometry")):
        w = f"{where}/planView/geometry[{j}]"
        base = [r.num(ge, k, w) for k in ("s", "x", "y", "hdg", "length")]
        kids = [k for k in ge if k.tag in ("line", "arc", "spiral", "poly3", "paramPoly3")]
        if len(kids) != 1:
            raise DriveE2EError(f"{r.path}: {w}: expected one of <line>, <arc>, <spiral>, <poly3>, <paramPoly3>, "
                                f"got {', '.join('<' + k.tag + '>' for k in ge) or 'none'}")
        k = kids[0]
        params: dict = {}
        if k.tag == "arc":
            params["curvature"] = r.num(k, "curvature", f"{w}/arc")
        elif k.tag == "spiral":
            params = {n: r.num(k, n, f"{w}/spiral") for n in ("curvStart", "curvEnd")}
        elif k.tag == "poly3":
            params = {n: r.num(k, n, f"{w}/poly3") for n in "abcd"}
        elif k.tag == "paramPoly3":
            params = {n + uv: r.num(k, n + uv, f"{w}/paramPoly3") for uv in "UV" for n in "abcd"}
            rng = k.get("pRange", "normalized")
            if rng not in ("normalized", "arcLength"):
                raise DriveE2EError(f"{r.path}: {w}/paramPoly3: expected pRange 'normalized' or 'arcLength', "
                                    f"got {rng!r}")
            params["pRange"] = rng
        if base[4] <= 0:
            raise DriveE2EError(f"{r.path}: {w}: expected a positive 'length', got {base[4]:g}")
        out.append(Geometry(*base, kind=k.tag, params=params))
    if not out:
        raise DriveE2EError(f"{r.path}: {where}: expected at least one <planView><geometry>")
    return sorted(out, key=lambda g: g.s)


def _cubics(elems: list[ET.Element], r: _Reader, where: str, s_key: str) -> list[tuple[float, ...]]:
    """(start, a, b, c, d) records sorted by start."""
    out = [(r.num(e, s_key, where), *(r.num(e, k, where) for k in "abcd")) for e in elems]
    return sorted(out)


def _eval_cubic(recs, s: np.ndarray) -> np.ndarray:
    """Piecewise cubic a + b ds + c ds^2 + d ds^3 with ds = s - start of the active record (0 before the first)."""
    out = np.zeros(len(s))
    if not recs:
        return out
    starts = np.array([rc[0] for rc in recs])
    idx = np.searchsorted(starts, s, side="right") - 1
    for i in np.unique(idx):
        if i < 0:
            continue
        m = idx == i
        s0, a, b, c, d = recs[i]
        ds = s[m] - s0
        out[m] = a + b * ds + c * ds * ds + d * ds ** 3
    return out


def _mark(lane: ET.Element | None) -> str | None:
    if lane is None:
        return None
    rm = lane.find("roadMark")
    if rm is None:
        return None
    return ROAD_MARKS.get(rm.get("type", "none").strip(), "solid")


def _section_lanelets(road_index: int, sec_index: int, road: ET.Element, sec: ET.Element, s0: float, s1: float,
                      geoms, offsets, junction: bool, lht: bool, r: _Reader, where: str, table: dict) -> list[Lanelet]:
    n = max(2, int(math.ceil((s1 - s0) / STEP_M)) + 1)
    s = np.linspace(s0, s1, n)
    s[-1] = s1 - 1e-9 if s1 > s0 else s1
    ref, hdg = reference_line(geoms, s)
    normal = np.stack([-np.sin(hdg), np.cos(hdg)], axis=1)
    t0 = _eval_cubic(offsets, s)
    center = sec.find("center/lane")
    out = []
    for side, sign in (("left", 1), ("right", -1)):
        lanes = sorted(sec.findall(f"{side}/lane"), key=lambda e: abs(int(e.get("id", "0"))))
        inner_t = t0.copy()
        inner_mark = _mark(center)
        for j, ln in enumerate(lanes):
            lid = int(r.num(ln, "id", f"{where}/{side}/lane[{j}]"))
            if lid == 0 or (lid > 0) != (sign > 0):
                raise DriveE2EError(f"{r.path}: {where}/{side}/lane[{j}]: expected a lane id of sign "
                                    f"{'+' if sign > 0 else '-'}, got {lid}")
            width = _eval_cubic(_cubics(ln.findall("width"), r, f"{where}/lane id={lid}/width", "sOffset"), s - s0)
            outer_t = inner_t + sign * width
            own_mark = _mark(ln)
            ltype = LANE_TYPES.get(ln.get("type", "none"))
            if ltype is not None and np.max(width) > 0.05:
                nxt = lanes[j + 1] if j + 1 < len(lanes) else None
                nxt_vehicle = nxt is not None and LANE_TYPES.get(nxt.get("type", "none")) is not None
                outer_mark = own_mark or ("dashed" if nxt_vehicle else "road_edge")
                in_mark = inner_mark or "dashed"
                if junction:
                    outer_mark = in_mark = "none"
                inner = ref + inner_t[:, None] * normal
                outer = ref + outer_t[:, None] * normal
                forward = (sign < 0) != lht
                if forward:  # driving along +s: the inner border is on the left for right lanes
                    left, right, lm, rm = ((inner, outer, in_mark, outer_mark) if sign < 0
                                           else (outer, inner, outer_mark, in_mark))
                else:
                    left, right, lm, rm = ((outer[::-1], inner[::-1], outer_mark, in_mark) if sign < 0
                                           else (inner[::-1], outer[::-1], in_mark, outer_mark))
                lane_id = road_index * 1000 + sec_index * 100 + 50 + lid
                table[lane_id] = f"{road.get('id')}/{sec_index}/{lid}"
                out.append(Lanelet(id=lane_id, left=left, right=right, left_marking=lm, right_marking=rm,
                                   type="connector" if junction and ltype == "driving" else ltype,
                                   connector=junction if ltype == "driving" else False,
                                   name=table[lane_id]))
            inner_t = outer_t
            inner_mark = own_mark
    return out


def read_map(path: Path, map_id: str | None = None) -> tuple[MapRecord, list[str]]:
    """An OpenDRIVE file -> (MapRecord, notes); rules in the module docstring."""
    path = Path(path)
    r = _Reader(path)
    root = common.parse_xml(path, "OpenDRIVE", "OpenDRIVE")
    notes: list[str] = []
    lanelets: list[Lanelet] = []
    table: dict[int, str] = {}
    roads = root.findall("road")
    if not roads:
        raise DriveE2EError(f"{path}: expected at least one <road>")
    for ri, road in enumerate(roads):
        where = f"road id={road.get('id')}"
        length = r.num(road, "length", where)
        geoms = _geometries(road, r, where)
        offsets = _cubics(road.findall("lanes/laneOffset"), r, f"{where}/laneOffset", "s")
        junction = road.get("junction", "-1").strip() not in ("-1", "")
        lht = road.get("rule", "RHT").upper() == "LHT"
        secs = road.findall("lanes/laneSection")
        if not secs:
            raise DriveE2EError(f"{path}: {where}: expected at least one <lanes><laneSection>")
        starts = [r.num(sc, "s", f"{where}/laneSection") for sc in secs]
        order = np.argsort(starts, kind="stable")
        for k, si in enumerate(order):
            s0 = starts[si]
            s1 = starts[order[k + 1]] if k + 1 < len(order) else length
            if s1 - s0 < 1e-6:
                continue
            lanelets += _section_lanelets(ri, k, road, secs[si], s0, s1, geoms, offsets, junction, lht, r,
                                          f"{where}/laneSection[{si}]", table)
    if not lanelets:
        raise DriveE2EError(f"{path}: expected at least one driving/biking/parking lane; found none")
    n_unknown = sum(1 for ln in root.iter("lane") if ln.get("type") not in LANE_TYPES and ln.get("id") != "0")
    if n_unknown:
        notes.append(f"{path.name}: {n_unknown} lane(s) of non-traffic types (sidewalk, shoulder, border, ...) "
                     "are not lanes of the map")
    m = assemble_map(map_id or common.safe_id(path.stem), lanelets,
                     meta={"source": path.name, "format": "opendrive",
                           "lane_ids": {str(k): v for k, v in sorted(table.items())}})
    return m, notes


#: ``load`` wants every input path in one call when a map and its tracks are
#: given as separate paths (see ``load``); per-path calls still work when the
#: ``.xodr`` sits next to (or above) the tracks.
LOAD_ALL_PATHS_AT_ONCE = True


def load(paths: list[Path], options: ImportOptions) -> ImportResult:
    """Import ``.xodr`` maps plus INTERACTION-format track CSVs / recording folders.

    A track path uses the one ``.xodr`` among ``paths`` when there is exactly
    one, else the ``.xodr`` found next to it (``lanelet2_csv.find_map``: the
    folder, its parent, ``../../maps/<folder>.xodr``). An ``.xodr`` alone
    gives its map and no scenario.
    """
    paths = [Path(p) for p in paths]
    xodrs = [p for p in paths if p.suffix == ".xodr"]
    result = ImportResult(maps={}, scenarios=[], skipped=[], notes=[], meta={"source_format": "opendrive"})
    maps: dict[Path, MapRecord] = {}

    def get_map(xodr: Path) -> MapRecord:
        if xodr not in maps:
            m, notes = read_map(xodr)
            if m.map_id in result.maps:
                raise DriveE2EError(f"{xodr}: map id {m.map_id!r} comes from two .xodr files; expected unique names")
            maps[xodr] = result.maps[m.map_id] = m
            result.notes += notes
        return maps[xodr]

    for x in xodrs:
        get_map(x)
    n_recs = 0
    for p in paths:
        if p.suffix == ".xodr":
            continue
        recs = recordings_of(p)
        if len(xodrs) == 1:
            xodr = xodrs[0]
        else:
            xodr = find_map(p.parent if p.is_file() else p, ".xodr")
            if xodr is None:
                raise DriveE2EError(f"{p}: expected an .xodr map given with it, or in its folder, its parent or "
                                    "../../maps/; found none")
        m = get_map(xodr)
        for rec in recs:
            if options.max_scenarios is not None and len(result.scenarios) >= options.max_scenarios:
                break
            import_recording(rec, m, options, result)
            n_recs += 1
    if not n_recs:
        result.notes.append(f"{', '.join(str(x) for x in xodrs)}: map only (OpenDRIVE has no traffic; scenarios "
                            "come from INTERACTION-format track CSVs given with it or stored next to it)")
    return result
