"""ScenarioNet importer: ``sd_*.pkl`` scenario descriptions (nuScenes, Waymo, nuPlan conversions).

A pickle can run arbitrary code when it is loaded, so files are read with
:class:`SafeUnpickler`: it admits only plain containers and scalars and the
numpy globals needed to rebuild arrays, dtypes and numpy scalars
(:data:`ALLOWED_GLOBALS`), and refuses anything else with one line naming the
file and the refused global. A corrupt or hostile file declaring a huge array
or string is refused the same way, before anything is allocated
(:data:`ALLOC_FACTOR`, :func:`safe_load`). Nothing from metadrive or
scenarionet is needed.

Conversion:

* time: ``metadata.ts`` (s) gives the sample times; they are resampled onto the
  ``options.dt`` grid (a copy when they already are on it). A track exists
  where ``state.valid`` is set; gaps are not interpolated across.
* ego: ``metadata.sdc_id`` (the logging vehicle), or ``--ego``.
* tracks: ``type`` VEHICLE / PEDESTRIAN / CYCLIST, refined by the original
  nuScenes category in ``metadata.type`` where present (:data:`FINE_CATEGORIES`);
  TRAFFIC_CONE / TRAFFIC_BARRIER become static obstacles (when they do not
  move); other types are reported as Skipped. Sizes are the median of
  ``length/width/height`` over valid steps (missing, non-finite or below
  ``validate.MIN_BOX_SIZE_M``: the category's default). A vehicle whose width exceeds its
  length has the two swapped (the nuScenes conversion writes the ego as
  1.73 m long, 4.08 m wide) and a note says so.
* the ego position is the nuScenes ``ego_pose`` (midpoint of the rear axle);
  the written box centre is ``EGO_CENTER_OFFSET_M`` ahead of it (approximate,
  for the Renault Zoe of the nuScenes fleet).
* map: ``LANE_*`` features -> lanes (``polyline`` centreline; the lane's
  ``polygon``, where the source has one, as the lane's area
  (``LaneRecord.polygon``: nuScenes lanes and nuPlan lanes and connectors
  carry it; nuScenes lane connectors do not, and a self-intersecting one is
  dropped with a note); LANE_SURFACE_UNSTRUCTURE, and in a nuScenes
  conversion a lane without a polygon, is a junction ``connector``; width = polygon area / centreline length, clipped to
  2-6 m, else 3.5 m, which the lanes without a polygon use as centreline ±
  width/2; successors inferred from geometry when the source has no
  ``exit_lanes``), ``ROAD_LINE_*`` ->
  boundaries with markings, ``ROAD_EDGE_*`` -> ``road_edge`` boundaries,
  ``CROSSWALK`` -> crosswalks; other feature types are counted in a note.
* honesty about interpolation: nuScenes annotates at 2 Hz and ScenarioNet
  interpolates linearly to 10 Hz. The importer measures the fraction of agent
  samples that lie exactly on straight, evenly spaced segments (zero second
  difference) and reports it in the notes and ``suite.json`` meta.
"""

from __future__ import annotations

import codecs
import collections
import io
import math
import pickle
import pickletools
from pathlib import Path
from typing import Any

import numpy as np
from shapely.geometry import Polygon

try:  # numpy >= 2 (numpy 1.x pickles name numpy.core, 2.x numpy._core: admit both)
    from numpy._core import multiarray, numeric
except ImportError:  # numpy 1.x
    from numpy.core import multiarray, numeric

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.polyline import polyline_length
from drivee2e_jax.records import BoundaryRecord, LaneRecord, MapRecord
from drivee2e_jax.scenario.importers import common
from drivee2e_jax.scenario.importers.common import ImportOptions, ImportResult, RawTrack, Skipped
from drivee2e_jax.scenario.problems import FLOAT32_MAX
from drivee2e_jax.scenario.validate import MIN_BOX_SIZE_M

__all__ = ["load", "safe_load", "SafeUnpickler", "ALLOWED_GLOBALS", "TYPE_CATEGORIES", "FINE_CATEGORIES",
           "LINE_MARKINGS"]


def _codecs_encode(obj: Any, encoding: str = "utf-8", errors: str = "strict") -> bytes:
    """``_codecs.encode`` restricted to latin-1 (what numpy uses for array bytes under protocol 2)."""
    if encoding not in ("latin1", "latin-1", "iso-8859-1"):
        raise pickle.UnpicklingError(f"refused _codecs.encode with encoding {encoding!r}")

    return codecs.encode(obj, encoding, errors)


def _numpy_globals() -> dict[tuple[str, str], Any]:
    out = {}
    for mod in ("numpy.core", "numpy._core"):
        out[(f"{mod}.multiarray", "_reconstruct")] = multiarray._reconstruct
        out[(f"{mod}.multiarray", "scalar")] = multiarray.scalar
        # pickle protocol 5 rebuilds arrays from their bytes with _frombuffer(buffer, dtype, shape, order)
        out[(f"{mod}.numeric", "_frombuffer")] = numeric._frombuffer
    out[("numpy", "ndarray")] = np.ndarray
    out[("numpy", "dtype")] = np.dtype
    for name in ("float64", "float32", "float16", "int64", "int32", "int16", "int8", "uint8", "uint16",
                 "uint32", "uint64", "bool_", "str_", "bytes_"):
        out[("numpy", name)] = getattr(np, name)
    return out


def _allowed() -> dict[tuple[str, str], Any]:

    out = _numpy_globals()
    for name, obj in (("set", set), ("frozenset", frozenset), ("list", list), ("dict", dict), ("tuple", tuple),
                      ("complex", complex), ("bytearray", bytearray)):
        out[("builtins", name)] = obj
        out[("__builtin__", name)] = obj
    out[("collections", "OrderedDict")] = collections.OrderedDict
    out[("_codecs", "encode")] = _codecs_encode
    return out


#: (module, name) -> object: the only globals a ScenarioNet pickle may reference.
ALLOWED_GLOBALS: dict[tuple[str, str], Any] = {}


#: A pickle may declare at most ``ALLOC_FACTOR`` x its own size + ``ALLOC_SLACK_BYTES``
#: of numpy arrays and bytearrays in all. A genuine array's raw bytes are in the
#: file (protocols 2-5), and an object array's 8-byte slots each need at least one
#: opcode (>= 1 byte), so honest files stay under 8x; a larger declaration is a
#: corrupt or hostile file that would otherwise end in a MemoryError (or the OOM
#: killer) before anything could be checked.
ALLOC_FACTOR = 16
ALLOC_SLACK_BYTES = 1 << 20


class SafeUnpickler(pickle.Unpickler):
    """An unpickler that admits only ``ALLOWED_GLOBALS`` (containers, scalars, numpy arrays)
    and at most ``budget_bytes`` of declared array / bytearray memory (None: unbounded)."""

    def __init__(self, file, *, source: str = "<pickle>", budget_bytes: int | None = None):
        super().__init__(file)
        self.source = source
        self.budget_bytes = budget_bytes
        self.claimed_bytes = 0
        self._array_type = _bounded_array_type(self.claim)
        self._guards = {multiarray._reconstruct: self._reconstruct, np.ndarray: self._array_type,
                        multiarray.scalar: self._scalar, bytearray: self._bytearray}

    def find_class(self, module: str, name: str) -> Any:
        if not ALLOWED_GLOBALS:
            ALLOWED_GLOBALS.update(_allowed())
        obj = ALLOWED_GLOBALS.get((module, name))
        if obj is None:
            raise DriveE2EError(f"{self.source}: refused to load global {module}.{name}; a ScenarioNet pickle "
                                "may hold only dicts, lists, numbers, strings and numpy arrays")
        return self._guards.get(obj, obj)

    def claim(self, shape: Any, dtype: Any) -> None:
        """Count an allocation of ``shape`` x ``dtype`` bytes; one-line DriveE2EError beyond the budget."""
        try:
            dims = (int(shape),) if isinstance(shape, int | np.integer) else tuple(int(d) for d in shape)
            item = np.dtype(dtype).itemsize
        except (TypeError, ValueError) as e:
            raise DriveE2EError(f"{self.source}: not a readable pickle (array shape {shape!r}, dtype {dtype!r}: "
                                f"{e})") from None
        n = math.prod(max(d, 0) for d in dims) * item
        self.claimed_bytes += n
        if self.budget_bytes is not None and self.claimed_bytes > self.budget_bytes:
            raise DriveE2EError(f"{self.source}: refused an array of shape {dims} x {item} bytes ({n:.3g} bytes): "
                                f"the pickle declares more array memory than a {self.budget_bytes:.3g}-byte bound "
                                f"({ALLOC_FACTOR} x the file size + {ALLOC_SLACK_BYTES} bytes); the file is corrupt "
                                f"or not a ScenarioNet pickle")

    def _reconstruct(self, subtype, shape, dtype):
        self.claim(shape, dtype)
        return multiarray._reconstruct(self._array_type, shape, dtype)

    def _scalar(self, dtype, *args):
        self.claim((), dtype)
        return multiarray.scalar(dtype, *args)

    def _bytearray(self, *args):
        if args and isinstance(args[0], int):
            self.claim((args[0],), np.uint8)
        return bytearray(*args)


def _bounded_array_type(claim) -> type:
    """An ``np.ndarray`` subclass that ``claim``s its size when built or unpickled
    (``__setstate__`` allocates object arrays before filling them);
    :func:`_plain_arrays` turns its instances back into plain arrays."""

    def new(cls, shape, dtype=float, *args, **kwargs):
        claim(shape, dtype)
        return np.ndarray.__new__(cls, shape, dtype, *args, **kwargs)

    def setstate(self, state):
        if isinstance(state, tuple) and len(state) in (4, 5):  # ([version,] shape, dtype, fortran, data)
            claim(*state[-4:-2])
        np.ndarray.__setstate__(self, state)

    return type("ndarray", (np.ndarray,), {"__new__": new, "__setstate__": setstate, "__module__": __name__})


#: Deepest nesting of containers :func:`_plain_arrays` accepts (a ScenarioNet pickle nests ~5 deep).
MAX_PICKLE_DEPTH = 64
#: Most objects the loaded pickle may hold when every shared reference is
#: counted as a copy (what the importer's later walks will visit).
MAX_PICKLE_EXPANDED = 50_000_000


def _plain_arrays(obj: Any, kind: type, source: str = "<pickle>") -> Any:
    """``obj`` with every ``kind`` array (nested in dicts, lists, tuples) viewed as a plain ndarray.

    Linear in the number of distinct objects: each container is visited once
    (memo by ``id``, so shared references -- a "billion laughs" pickle of lists
    that all point to one list -- cost one visit, and the shared object stays
    shared), nesting deeper than ``MAX_PICKLE_DEPTH`` is a one-line
    DriveE2EError, as is a reference cycle through a tuple. The size the
    object would have with every shared reference copied is counted too (memo:
    linear) and refused above ``MAX_PICKLE_EXPANDED``, so the importer's later
    walks over the tree (``np.asarray`` on nested lists) stay bounded.
    """
    done: dict[int, Any] = {}
    expanded: dict[int, int] = {}  # id -> objects in the subtree, shared references counted as copies
    active: set[int] = set()

    def size(o: Any) -> int:
        return expanded.get(id(o), 1) if isinstance(o, (dict, list, tuple)) else 1

    def walk(o: Any, depth: int) -> Any:
        if isinstance(o, kind):
            key = id(o)
            if key not in done:
                done[key] = o.view(np.ndarray)
            return done[key]
        if not isinstance(o, (dict, list, tuple)):
            return o
        key = id(o)
        if key in done:
            return done[key]
        if depth > MAX_PICKLE_DEPTH:
            raise DriveE2EError(f"{source}: containers nested deeper than {MAX_PICKLE_DEPTH} levels "
                                f"(not a ScenarioNet pickle)")
        if key in active:  # a cycle: a list/dict reached again from inside itself
            if isinstance(o, tuple):
                raise DriveE2EError(f"{source}: a tuple that contains itself (not a ScenarioNet pickle)")
            return o  # fixed in place by the outer visit
        active.add(key)
        if isinstance(o, dict):
            done[key] = o
            for k, v in o.items():
                o[k] = walk(v, depth + 1)
            out = o
        elif isinstance(o, list):
            done[key] = o
            o[:] = [walk(v, depth + 1) for v in o]
            out = o
        else:
            out = tuple(walk(v, depth + 1) for v in o)
            done[key] = out
        active.discard(key)
        children = out.values() if isinstance(out, dict) else out
        n = 1 + sum(size(v) for v in children) + (len(out) if isinstance(out, dict) else 0)
        if n > MAX_PICKLE_EXPANDED:
            raise DriveE2EError(f"{source}: shared references expand to more than {MAX_PICKLE_EXPANDED} "
                                f"objects (a 'billion laughs' pickle, not a ScenarioNet pickle)")
        expanded[key] = expanded[id(out)] = n
        return out

    return walk(obj, 0)


def safe_load(path: Path) -> Any:
    """Unpickle ``path`` with :class:`SafeUnpickler` (one-line DriveE2EError on anything else).

    Every length an opcode declares is checked against the bytes that remain
    first (``pickletools.genops`` reads without allocating: a declared 10^15-byte
    string fails here, not in a MemoryError), then arrays are bounded by
    ``ALLOC_FACTOR`` x the file size (``SafeUnpickler.claim``).
    """
    try:
        data = Path(path).read_bytes()
        for _ in pickletools.genops(data):
            pass
        unpickler = SafeUnpickler(io.BytesIO(data), source=str(path),
                                  budget_bytes=ALLOC_FACTOR * len(data) + ALLOC_SLACK_BYTES)
        return _plain_arrays(unpickler.load(), unpickler._array_type, str(path))
    except DriveE2EError:
        raise
    except MemoryError:
        raise DriveE2EError(f"{path}: the pickle asks for more memory than there is (corrupt or not a "
                            f"ScenarioNet pickle)") from None
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError,
            OverflowError, RecursionError) as e:
        raise DriveE2EError(f"{path}: not a readable pickle ({type(e).__name__}: "
                            f"{' '.join(str(e).split())[:100]})") from None


#: ScenarioNet/MetaDrive object ``type`` -> CATEGORIES (None: known, not a road user).
TYPE_CATEGORIES: dict[str, str | None] = {
    "VEHICLE": "car", "PEDESTRIAN": "pedestrian", "CYCLIST": "cyclist", "TRAFFIC_CONE": None,
    "TRAFFIC_BARRIER": None, "TRAFFIC_OBJECT": None, "OTHER": None, "UNSET": None,
}
#: Types written as static obstacles (when they do not move), with their kind.
STATIC_KINDS = {"TRAFFIC_CONE": "cone", "TRAFFIC_BARRIER": "barrier", "TRAFFIC_OBJECT": "object"}
#: Original nuScenes category (``metadata.type``) prefix -> a finer CATEGORIES name.
FINE_CATEGORIES = (
    ("vehicle.bus", "bus"), ("vehicle.truck", "truck"), ("vehicle.construction", "truck"),
    ("vehicle.trailer", "truck"), ("vehicle.emergency.police", "car"), ("vehicle.emergency.ambulance", "van"),
    ("vehicle.motorcycle", "motorcycle"), ("vehicle.bicycle", "cyclist"), ("vehicle.car", "car"),
)
#: Map feature ``type`` -> MARKINGS for boundaries.
LINE_MARKINGS = {
    "ROAD_LINE_BROKEN_SINGLE_WHITE": "dashed", "ROAD_LINE_BROKEN_SINGLE_YELLOW": "dashed",
    "ROAD_LINE_BROKEN_DOUBLE_YELLOW": "dashed", "ROAD_LINE_SOLID_SINGLE_WHITE": "solid",
    "ROAD_LINE_SOLID_SINGLE_YELLOW": "solid", "ROAD_LINE_SOLID_DOUBLE_WHITE": "double_solid",
    "ROAD_LINE_SOLID_DOUBLE_YELLOW": "double_solid", "ROAD_LINE_PASSING_DOUBLE_YELLOW": "double_solid",
    "ROAD_LINE_UNKNOWN": "none", "ROAD_EDGE_BOUNDARY": "road_edge", "ROAD_EDGE_MEDIAN": "road_edge",
    "ROAD_EDGE_UNKNOWN": "road_edge", "ROAD_EDGE_SIDEWALK": "road_edge",
}
#: LANE_SURFACE_UNSTRUCTURE is what the nuScenes and nuPlan conversions write for junction
#: connectors (nuScenes lane_connector, nuPlan ROADBLOCK_CONNECTOR lanes): NAVSIM's INTERSECTION.
LANE_KINDS = {"LANE_SURFACE_STREET": "driving", "LANE_FREEWAY": "driving", "LANE_UNKNOWN": "driving",
              "LANE_SURFACE_UNSTRUCTURE": "connector", "LANE_BIKE_LANE": "bike"}
#: nuScenes ego: box centre ahead of the rear-axle pose, m (approximate).
EGO_CENTER_OFFSET_M = 1.3
MAP_RADIUS_M = 100.0
LICENSE = {"nuscenes": "nuScenes: CC BY-NC-SA 4.0 (cite Caesar et al., nuScenes, CVPR 2020; nuScenes terms of use)"}


def _get(obj: Any, key: str, where: str, kind: type | tuple = dict) -> Any:
    if not isinstance(obj, dict) or key not in obj:
        raise DriveE2EError(f"{where}: missing field {key!r}")
    v = obj[key]
    if kind is not None and not isinstance(v, kind):
        raise DriveE2EError(f"{where}.{key}: expected {getattr(kind, '__name__', kind)}, got {type(v).__name__}")
    return v


def _array(v: Any, where: str, cols: int | None = None, rows: np.ndarray | None = None) -> np.ndarray:
    """``v`` as a float64 array ((n, >= ``cols``) when given); DriveE2EError
    naming ``where`` when it is not numbers or holds a finite value outside
    the float32 range (:func:`_check_range`; only the rows ``rows`` selects
    when given: a track's invalid steps are never read)."""
    try:
        a = np.asarray(v, np.float64)
    except (TypeError, ValueError, OverflowError):
        raise DriveE2EError(f"{where}: expected an array of numbers") from None
    if cols is not None and (a.ndim != 2 or a.shape[1] < cols):
        raise DriveE2EError(f"{where}: expected an (n, >={cols}) array, got shape {a.shape}")
    if rows is None:
        _check_range(a, where)
    return a


def _check_range(a: np.ndarray, where: str, rows: np.ndarray | None = None) -> None:
    """DriveE2EError naming the first element of ``a`` (of the rows ``rows``
    selects) that is finite but beyond float32 (a position of 1e308): the
    importer's float64 arithmetic would overflow with warnings and the
    simulator computes in float32. NaN / inf stay to the callers (a track
    with them is skipped)."""
    with np.errstate(invalid="ignore"):
        big = np.isfinite(a) & (np.abs(a) > FLOAT32_MAX)
    if rows is not None and big.ndim and len(rows) == len(big):
        big &= rows.reshape((-1,) + (1,) * (big.ndim - 1))
    if big.any():
        at = tuple(int(i) for i in np.argwhere(big)[0])
        raise DriveE2EError(f"{where}[{', '.join(map(str, at))}]: expected finite numbers with |value| <= "
                            f"{FLOAT32_MAX:.6g} (the float32 range the simulator computes in), got {a[at]:.6g}")


# --------------------------------------------------------------------------
# Map
# --------------------------------------------------------------------------


def _polygon_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))


def _map(features: dict, map_id: str, source: str, notes: list[str], dataset: str = "") -> MapRecord:
    """The map features as a MapRecord. ``dataset`` "nuscenes": a lane without a
    polygon is a lane connector (ScenarioNet's nuScenes converter writes every
    lane's polygon and no connector's; before its commit 69a3d7a it typed both
    LANE_SURFACE_STREET)."""
    lanes, boundaries, crosswalks, other = [], [], [], {}
    has_links, bad_polygons = False, 0
    for i, (fid, feat) in enumerate(sorted(features.items(), key=lambda x: str(x[0]))):
        where = f"{source}: map_features[{fid!r}]"
        typ = str(_get(feat, "type", where, None))
        if typ in LANE_KINDS:
            c = _array(_get(feat, "polyline", where, None), f"{where}.polyline", 2)[:, :2]
            if len(c) < 2 or polyline_length(c) < 0.1:
                other[f"degenerate {typ}"] = other.get(f"degenerate {typ}", 0) + 1
                continue
            width, poly = 3.5, None
            if feat.get("polygon") is not None and len(feat["polygon"]) >= 3:
                poly = _array(feat["polygon"], f"{where}.polygon", 2)[:, :2]
                width = float(np.clip(_polygon_area(poly) / polyline_length(c), 2.0, 6.0))
                if not Polygon(poly).is_valid or _polygon_area(poly) <= 0.0:
                    bad_polygons += 1
                    poly = None
            succ = [int(s) for s in feat.get("exit_lanes", []) if str(s).lstrip("-").isdigit()]
            has_links |= bool(succ)
            kind = LANE_KINDS[typ]
            if dataset == "nuscenes" and kind == "driving" and feat.get("polygon") is None:
                kind = "connector"
            lanes.append(LaneRecord(id=i, centerline=c, width=width, type=kind, successors=succ,
                                    left_marking="none", right_marking="none", polygon=poly))
        elif typ in LINE_MARKINGS:
            p = _array(_get(feat, "polyline", where, None), f"{where}.polyline", 2)[:, :2]
            if len(p) >= 2:
                boundaries.append(BoundaryRecord(points=p, marking=LINE_MARKINGS[typ]))
        elif typ == "CROSSWALK":
            p = _array(_get(feat, "polygon", where, None), f"{where}.polygon", 2)[:, :2]
            if len(p) >= 3:
                crosswalks.append(p)
        else:
            other[typ] = other.get(typ, 0) + 1
    if bad_polygons:
        notes.append(f"{source}: {bad_polygons} lane polygon(s) self-intersect or have no area; those lanes' "
                     "areas are their centreline ± width/2")
    if other:
        notes.append(f"{source}: map features not used: "
                     + ", ".join(f"{k} x{v}" for k, v in sorted(other.items())))
    if not has_links:
        common.infer_successors(lanes)
    else:  # exit_lanes name feature ids; we number lanes by position, so drop the unresolvable ones
        for ln in lanes:
            ln.successors = []
        common.infer_successors(lanes)
    return MapRecord(map_id=map_id, lanes=lanes, boundaries=boundaries, crosswalks=crosswalks,
                     meta={"source": "scenarionet"})


# --------------------------------------------------------------------------
# Tracks
# --------------------------------------------------------------------------


def _category(track: dict, where: str) -> tuple[str | None, Skipped | None, str]:
    typ = str(track.get("type"))
    cat, skip = common.map_category(typ, TYPE_CATEGORIES, where)
    fine = str((track.get("metadata") or {}).get("type", ""))
    if cat in ("car", "cyclist"):
        for prefix, c in FINE_CATEGORIES:
            if fine.startswith(prefix):
                cat = c
                break
    return cat, skip, typ


def _interpolated_fraction(tracks: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Fraction of moving agent samples with zero second difference (on straight evenly spaced runs)."""
    hits = total = 0
    for t, xy in tracks:
        if len(t) < 3:
            continue
        ok = np.isclose(np.diff(t)[:-1], np.diff(t)[1:])
        step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        moving = (step[:-1] > 0.01) & (step[1:] > 0.01) & ok
        sd = np.linalg.norm(xy[:-2] - 2 * xy[1:-1] + xy[2:], axis=1)
        hits += int(np.sum(moving & (sd < 1e-6)))
        total += int(np.sum(moving))
    return hits / total if total else 0.0


def _one(path: Path, options: ImportOptions, limit: int | None) -> ImportResult:
    data = safe_load(path)
    src = path.name
    if not isinstance(data, dict):
        raise DriveE2EError(f"{path}: expected a ScenarioNet scenario dict at the top level, got {type(data).__name__}")
    meta = _get(data, "metadata", str(path))
    tracks = _get(data, "tracks", str(path))
    features = _get(data, "map_features", str(path))
    ts = _array(_get(meta, "ts", f"{path}: metadata", None), f"{path}: metadata.ts")
    if ts.ndim != 1 or len(ts) < 2 or np.any(np.diff(ts) <= 0):
        raise DriveE2EError(f"{path}: metadata.ts: expected increasing step times (s), got shape {ts.shape}")
    ts = ts - ts[0]
    ego_src = str(options.ego if options.ego is not None else _get(meta, "sdc_id", f"{path}: metadata", None))
    if ego_src not in {str(k) for k in tracks}:
        flag = "--ego" if options.ego is not None else "metadata.sdc_id"
        raise DriveE2EError(f"{path}: {flag} {ego_src!r} is not a track id")
    dataset = str(meta.get("dataset", "unknown"))
    sid = str(meta.get("scenario_id", data.get("id", path.stem)))
    label = common.safe_id(f"{dataset}_{sid}")
    notes: list[str] = []
    skipped: list[Skipped] = []
    raws, obstacles, swapped, samples = [], [], 0, []
    for tid, tr in sorted(tracks.items(), key=lambda x: str(x[0])):
        tid = str(tid)
        where = f"{src} track {tid}"
        state = _get(tr, "state", f"{path}: tracks[{tid!r}]")
        for key in ("position", "heading", "valid"):
            _get(state, key, f"{path}: tracks[{tid!r}].state", None)
        at = f"{path}: tracks[{tid!r}].state"
        valid = np.asarray(state["valid"]).reshape(-1).astype(bool)
        pos = _array(state["position"], f"{at}.position", 2, rows=valid)
        n = len(pos)
        if n != len(ts):
            raise DriveE2EError(f"{at}.position: expected {len(ts)} rows (one per ts), got {n}")
        heading = _array(state["heading"], f"{at}.heading", rows=valid).reshape(-1)
        vel = _array(state["velocity"], f"{at}.velocity", 2, rows=valid)[:, :2] \
            if state.get("velocity") is not None else None
        size = np.stack([_array(state.get(k, np.full(n, np.nan)), f"{at}.{k}", rows=valid).reshape(n)
                         for k in ("length", "width", "height")], axis=1)
        for key, a in (("position", pos[:, :2]), ("heading", heading), ("velocity", vel), ("size", size)):
            if a is not None:  # only the valid steps are read: what they hold must fit float32
                _check_range(a, f"{at}.{key}" if key != "size" else f"{at}.length/width/height", rows=valid)
        if not valid.any():
            skipped.append(Skipped(where, "empty track (no valid step)"))
            continue
        t, xy, yaw = ts[valid], pos[valid, :2], heading[valid]
        v = vel[valid] if vel is not None else None
        sz = np.nanmedian(size[valid], axis=0)
        if not np.all(np.isfinite(xy)) or not np.all(np.isfinite(yaw)):
            skipped.append(Skipped(where, "non-finite position or heading"))
            continue
        if tid == ego_src:
            cat = "car"
        else:
            cat, skip, typ = _category(tr, where)
            if cat is None:
                kind = STATIC_KINDS.get(typ) if np.all(np.isfinite(sz)) else None
                out = common.static_or_skip(RawTrack(tid, "car", t, xy, yaw, sz), kind, skip, f"type {typ!r}")
                (skipped if isinstance(out, Skipped) else obstacles).append(out)
                continue
        default = np.array(common.DEFAULT_SIZES[cat])
        sz = np.where(np.isfinite(sz) & (sz >= MIN_BOX_SIZE_M), sz, default)  # 0 = unknown in some conversions
        if cat in common.VEHICLES and sz[1] > sz[0]:
            sz = sz[[1, 0, 2]]
            swapped += 1
        if tid == ego_src and options.ego is None:
            xy = xy + EGO_CENTER_OFFSET_M * np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
        else:
            samples.append((t, xy))
        raws.append(RawTrack(tid, cat, t, xy, yaw, sz, v))
    if swapped:
        notes.append(f"{label}: {swapped} vehicle(s) had width > length; swapped (the source writes them crosswise)")
    frac = _interpolated_fraction(samples)
    if frac > 0.5:
        notes.append(f"{label}: {100 * frac:.0f}% of moving agent samples lie exactly on straight, evenly spaced "
                     "segments: they are interpolated between sparser keyframes by the converter "
                     "(nuScenes annotates at 2 Hz), not measured")
    dt = options.dt
    num_steps = int(math.floor(ts[-1] / dt + 1e-6)) + 1
    src_dt = float(np.median(np.diff(ts)))
    if abs(src_dt - dt) > 1e-6:
        notes.append(f"{label}: source step {src_dt:g} s resampled to {dt:g} s (linear interpolation)")
    conv = common.convert_tracks(raws, ego_src, dt, num_steps, src, max_gap_s=max(common.DEFAULT_MAX_GAP_S,
                                                                                  1.5 * src_dt))
    skipped += conv.skipped
    ego = next((tr for tr in conv.tracks if tr.track_id == conv.ids[ego_src]), None)
    if ego is None:
        raise DriveE2EError(f"{path}: the ego track {ego_src!r} has no samples on the grid")
    full = _map(features, common.safe_id(f"{label}_map"), src, notes, dataset)
    full.obstacles = obstacles
    map_rec = common.crop_map(full, ego.xy, MAP_RADIUS_M)
    if conv.gap_tracks:
        notes.append(f"{label}: {conv.gap_tracks} tracks have gaps (left as missing steps, not interpolated)")
    if obstacles:
        notes.append(f"{label}: {len(obstacles)} static objects written as static obstacles")
    scenarios = common.windowed_scenarios(label, map_rec, conv.tracks, conv.ids[ego_src], dt, num_steps, options,
                                          str(path), skipped, notes, limit=limit,
                                          intersection_id=common.safe_id(str(meta.get("map", label))))
    out_meta = {"source": f"scenarionet ({dataset})", "license": LICENSE.get(dataset, "see the source dataset"),
                "interpolated_fraction": {label: round(frac, 3)},
                "track_ids": {s.scenario_id: {str(k): v for k, v in conv.ids.table().items()} for s in scenarios}}
    return ImportResult(maps={map_rec.map_id: map_rec}, scenarios=scenarios, skipped=skipped, notes=notes,
                        meta=out_meta)


def _files(path: Path) -> list[Path]:
    if path.is_dir():
        found = sorted(path.rglob("sd_*.pkl")) or sorted(path.rglob("*.pkl"))
        if not found:
            raise DriveE2EError(f"{path}: no ScenarioNet sd_*.pkl files found")
        return found
    if path.suffix not in (".pkl", ".pickle"):
        raise DriveE2EError(f"{path}: expected a ScenarioNet .pkl file or a folder of them")
    return [path]


def load(paths: list[Path], options: ImportOptions) -> ImportResult:
    """Import ScenarioNet pickles (see the module docstring)."""
    results, count = [], 0
    for p in paths:
        for f in _files(Path(p)):
            limit = None if options.max_scenarios is None else options.max_scenarios - count
            if limit is not None and limit <= 0:
                break
            r = _one(f, options, limit)
            count += len(r.scenarios)
            results.append(r)
    return common.merge_results(results)
