"""MCAP episode logs with Foxglove's well-known schemas (host side).

``write_mcap(traces, path)`` writes one MCAP file holding every
``io.episodes.EpisodeTrace``: JSON-encoded messages (``message_encoding
"json"``) whose schemas are JSON Schemas (``encoding "jsonschema"``) named as
Foxglove's (``foxglove.SceneUpdate``, ``foxglove.FrameTransform``,
``foxglove.CompressedImage``, ``foxglove.PointCloud``, ``foxglove.Log``), so
Foxglove's 3D, Image, Plot, Raw Messages and Log panels show them as is.

Topics, per episode ``/<scenario_id>/...`` (T = the trace's steps + 1):

=================  ========================  =====================================
topic              schema                    messages
=================  ========================  =====================================
``tf``             foxglove.FrameTransform   T: ``world`` -> ``ego`` (ego box centre)
``scene``          foxglove.SceneUpdate      T: ego, agents, signals at stop lines, plan
``map``            foxglove.SceneUpdate      1: lanes, boundaries, crosswalks, stop
                                             lines, drivable area, obstacles, route
``bev``            foxglove.CompressedImage  T: the BEV as a PNG (``observe.palette``)
``lidar``          foxglove.PointCloud       T: LiDAR returns, frame ``ego`` (x, y, z, class)
``metrics``        drivee2e.EpisodeMetrics   T: speed, route completion, controls, the
                                             StepLog facts and events of the step
``infractions``    foxglove.Log              one per stored infraction event
``<sensor>``       foxglove.CompressedImage  T: every other traced sensor
                   or foxglove.PointCloud    (``trace.sensors``) as its
                                             ``observe.registry`` display says
                                             ("image": PNG of ``Sensor.image``;
                                             "pointcloud": ``Sensor.points``,
                                             frame ``ego``; "none": no topic)
=================  ========================  =====================================

Time: log time = the sim clock plus the episode's offset; episodes follow one
another (each starts 1 s after the previous one ends), so the timeline plays
them in turn and the map of one never overlaps another's. The offsets are in
the file's ``drivee2e.episode`` metadata records (scenario_id, policy,
offset_ns, steps, driving_score). Every entity has a lifetime (one step for
the moving ones, the episode for the map) so nothing lingers.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from mcap.writer import Writer

from drivee2e_jax.files import atomic_write
from drivee2e_jax.observe import registry
from drivee2e_jax.observe.palette import bev_rgb
from drivee2e_jax.observe.png import png_bytes

#: Gap between consecutive episodes on the file's timeline, ns.
EPISODE_GAP_NS = 1_000_000_000
#: Profile string of the file (no ROS profile: plain JSON messages).
PROFILE = ""

# --------------------------------------------------------------------------
# Foxglove schemas (JSON Schema; same titles, fields and enums as Foxglove's)
# --------------------------------------------------------------------------


def _num(desc: str) -> dict:
    return {"type": "number", "description": desc}


def _obj(title: str, desc: str, props: dict) -> dict:
    return {"title": title, "description": desc, "type": "object", "properties": props}


def _arr(item: dict, desc: str) -> dict:
    return {"type": "array", "items": item, "description": desc}


def _enum(title: str, desc: str, names: Sequence[str]) -> dict:
    return {"title": title, "description": desc, "oneOf": [{"title": n, "const": i} for i, n in enumerate(names)]}


def _time(desc: str) -> dict:
    return {"type": "object", "title": "time", "description": desc, "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}


def _duration(desc: str) -> dict:
    return {"type": "object", "title": "duration", "description": desc, "properties": {
        "sec": {"type": "integer"},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}}


def _xyz(title: str, desc: str) -> dict:
    unit = "coordinate length" if title.endswith("Vector3") else "coordinate"
    return _obj(title, desc, {a: _num(f"{a} {unit}") for a in "xyz"})


def _quat(desc: str = "Quaternion denoting orientation in 3D space") -> dict:
    return _obj("foxglove.Quaternion", desc, {a: _num(f"{a} value") for a in "xyzw"})


def _pose(desc: str) -> dict:
    return _obj("foxglove.Pose", desc, {
        "position": _xyz("foxglove.Vector3", "Point denoting position in 3D space"),
        "orientation": _quat()})


def _color(desc: str) -> dict:
    return _obj("foxglove.Color", desc, {c: _num(f"{n} value between 0 and 1")
                                         for c, n in zip("rgba", ("Red", "Green", "Blue", "Alpha"))})


_POINT3 = _xyz("foxglove.Point3", "A point representing a position in 3D space")
_INDICES = _arr({"type": "integer", "minimum": 0}, "Indices into the `points` and `colors` attribute arrays")

CUBE = _obj("foxglove.CubePrimitive", "A primitive representing a cube or rectangular prism", {
    "pose": _pose("Position of the center of the cube and orientation of the cube"),
    "size": _xyz("foxglove.Vector3", "Size of the cube along each axis"),
    "color": _color("Color of the cube")})
LINE = _obj("foxglove.LinePrimitive", "A primitive representing a series of points connected by lines", {
    "type": _enum("foxglove.LineType", "An enumeration indicating how input points should be interpreted to "
                  "create lines", ("LINE_STRIP", "LINE_LOOP", "LINE_LIST")),
    "pose": _pose("Origin of lines relative to reference frame"),
    "thickness": {"type": "number", "minimum": 0, "description": "Line thickness"},
    "scale_invariant": {"type": "boolean", "description": "Indicates whether `thickness` is a fixed size in screen "
                        "pixels (true), or specified in world coordinates and scales with distance from the camera "
                        "(false)"},
    "points": _arr(_POINT3, "Points along the line"),
    "color": _color("Solid color to use for the whole line. One of `color` or `colors` must be provided."),
    "colors": _arr(_color("A color in RGBA format"), "Per-point colors (if specified, must have the same length as "
                   "`points`). One of `color` or `colors` must be provided."),
    "indices": _INDICES})
TEXT = _obj("foxglove.TextPrimitive", "A primitive representing a text label", {
    "pose": _pose("Position of the center of the text box and orientation of the text. Identity orientation means "
                  "the text is oriented in the xy-plane and flows from -x to +x."),
    "billboard": {"type": "boolean", "description": "Whether the text should respect `pose.orientation` (false) or "
                  "always face the camera (true)"},
    "font_size": {"type": "number", "minimum": 0, "description": "Font size (height of one line of text)"},
    "scale_invariant": {"type": "boolean", "description": "Indicates whether `font_size` is a fixed size in screen "
                        "pixels (true), or specified in world coordinates and scales with distance from the camera "
                        "(false)"},
    "color": _color("Color of the text"),
    "text": {"type": "string", "description": "Text"}})
TRIANGLES = _obj("foxglove.TriangleListPrimitive", "A primitive representing a set of triangles or a surface tiled "
                 "by triangles", {
                     "pose": _pose("Origin of triangles relative to reference frame"),
                     "points": _arr(_POINT3, "Vertices to use for triangles, interpreted as a list of triples "
                                    "(0-1-2, 3-4-5, ...)"),
                     "color": _color("Solid color to use for the whole shape. One of `color` or `colors` must be "
                                     "provided."),
                     "colors": _arr(_color("A color in RGBA format"), "Per-vertex colors (if specified, must have "
                                    "the same length as `points`). One of `color` or `colors` must be provided."),
                     "indices": _INDICES})
ENTITY = _obj("foxglove.SceneEntity", "A visual element in a 3D scene. An entity may be composed of multiple "
              "primitives which all share the same frame of reference.", {
                  "timestamp": _time("Timestamp of the entity"),
                  "frame_id": {"type": "string", "description": "Frame of reference"},
                  "id": {"type": "string", "description": "Identifier for the entity. A entity will replace any "
                         "prior entity on the same topic with the same `id`."},
                  "lifetime": _duration("Length of time (relative to `timestamp`) after which the entity should be "
                                        "automatically removed. Zero value indicates the entity should remain "
                                        "visible until it is replaced or deleted."),
                  "frame_locked": {"type": "boolean", "description": "Whether the entity should keep its location "
                                   "in the fixed frame (false) or follow the frame specified in `frame_id` as it "
                                   "moves relative to the fixed frame (true)"},
                  "metadata": _arr(_obj("foxglove.KeyValuePair", "A key with its associated value", {
                      "key": {"type": "string", "description": "Key"},
                      "value": {"type": "string", "description": "Value"}}),
                      "Additional user-provided metadata associated with the entity. Keys must be unique."),
                  "cubes": _arr(CUBE, "Cube primitives"),
                  "lines": _arr(LINE, "Line primitives"),
                  "triangles": _arr(TRIANGLES, "Triangle list primitives"),
                  "texts": _arr(TEXT, "Text primitives")})
DELETION = _obj("foxglove.SceneEntityDeletion", "Command to remove previously published entities", {
    "timestamp": _time("Timestamp of the deletion. Only matching entities earlier than this timestamp will be "
                       "deleted."),
    "type": _enum("foxglove.SceneEntityDeletionType", "Type of deletion action to perform", ("MATCHING_ID", "ALL")),
    "id": {"type": "string", "description": "Identifier which must match if `type` is `MATCHING_ID`."}})

SCHEMAS: dict[str, dict] = {
    "foxglove.SceneUpdate": _obj("foxglove.SceneUpdate", "An update to the entities displayed in a 3D scene", {
        "deletions": _arr(DELETION, "Scene entities to delete"),
        "entities": _arr(ENTITY, "Scene entities to add or replace")}),
    "foxglove.FrameTransform": _obj("foxglove.FrameTransform", "A transform between two reference frames in 3D "
                                    "space", {
                                        "timestamp": _time("Timestamp of transform"),
                                        "parent_frame_id": {"type": "string", "description": "Name of the parent "
                                                            "frame"},
                                        "child_frame_id": {"type": "string", "description": "Name of the child "
                                                           "frame"},
                                        "translation": _xyz("foxglove.Vector3", "Translation component of the "
                                                            "transform"),
                                        "rotation": _quat("Rotation component of the transform")}),
    "foxglove.CompressedImage": _obj("foxglove.CompressedImage", "A compressed image", {
        "timestamp": _time("Timestamp of image"),
        "frame_id": {"type": "string", "description": "Frame of reference for the image. The origin of the frame is "
                     "the optical center of the camera. +x points to the right in the image, +y points down, and "
                     "+z points into the plane of the image."},
        "data": {"type": "string", "contentEncoding": "base64", "description": "Compressed image data"},
        "format": {"type": "string", "description": "Image format. Supported values: `jpeg`, `png`, `webp`, "
                   "`avif`"}}),
    "foxglove.PointCloud": _obj("foxglove.PointCloud", "A collection of N-dimensional points, which may contain "
                                "additional fields with information like normals, intensity, etc.", {
                                    "timestamp": _time("Timestamp of point cloud"),
                                    "frame_id": {"type": "string", "description": "Frame of reference"},
                                    "pose": _pose("The origin of the point cloud relative to the frame of "
                                                  "reference"),
                                    "point_stride": {"type": "integer", "minimum": 0,
                                                     "description": "Number of bytes between points in the `data`"},
                                    "fields": _arr(_obj("foxglove.PackedElementField", "A field present within "
                                                        "each element in a byte array of packed elements.", {
                                                            "name": {"type": "string",
                                                                     "description": "Name of the field"},
                                                            "offset": {"type": "integer", "minimum": 0,
                                                                       "description": "Byte offset from start of "
                                                                       "data buffer"},
                                                            "type": _enum("foxglove.NumericType", "Type of data in "
                                                                          "the field. Integers are stored using "
                                                                          "little-endian byte order.",
                                                                          ("UNKNOWN", "UINT8", "INT8", "UINT16",
                                                                           "INT16", "UINT32", "INT32", "FLOAT32",
                                                                           "FLOAT64"))}),
                                                   "Fields in `data`. At least 2 coordinate fields from `x`, `y`, "
                                                   "and `z` are required for each point's position; `red`, "
                                                   "`green`, `blue`, and `alpha` are optional for customizing each "
                                                   "point's color."),
                                    "data": {"type": "string", "contentEncoding": "base64",
                                             "description": "Point data, interpreted using `fields`"}}),
    "foxglove.Log": _obj("foxglove.Log", "A log message", {
        "timestamp": _time("Timestamp of log message"),
        "level": _enum("foxglove.LogLevel", "Log level", ("UNKNOWN", "DEBUG", "INFO", "WARNING", "ERROR", "FATAL")),
        "message": {"type": "string", "description": "Log message"},
        "name": {"type": "string", "description": "Process or node name"},
        "file": {"type": "string", "description": "Filename"},
        "line": {"type": "integer", "minimum": 0, "description": "Line number in the file"}}),
}

#: The plain JSON metrics message (not a Foxglove type: Plot / Raw Messages panels read it).
METRICS_SCHEMA_NAME = "drivee2e.EpisodeMetrics"
LOG_WARNING = 3
FLOAT32 = 7
UINT8 = 1


def metrics_schema(timeline_keys: Sequence[str]) -> dict:
    """JSON Schema of the metrics message: time, controls and every timeline value."""
    props = {"timestamp": _time("Sim time (with the episode offset)"),
             "scenario_id": {"type": "string", "description": "Scenario id"},
             "t": _num("Sim time since the episode start, s"),
             "throttle": _num("Applied throttle from this state, [0, 1]"),
             "brake": _num("Applied brake from this state, [0, 1]"),
             "steer": _num("Applied steer from this state, [-1, 1], +1 = full left")}
    for k in timeline_keys:
        props[k] = {"type": ["number", "null"], "description": f"StepLog timeline {k} (null = inf/NaN)"}
    return {"title": METRICS_SCHEMA_NAME, "description": "Per-step metrics of a drivee2e episode",
            "type": "object", "properties": props}


# --------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------


def _stamp(ns: int) -> dict:
    return {"sec": int(ns // 1_000_000_000), "nsec": int(ns % 1_000_000_000)}


def _v3(x, y, z=0.0) -> dict:
    return {"x": float(x), "y": float(y), "z": float(z)}


def _yaw_quat(yaw) -> dict:
    return {"x": 0.0, "y": 0.0, "z": math.sin(float(yaw) / 2), "w": math.cos(float(yaw) / 2)}


def _pose_msg(x=0.0, y=0.0, z=0.0, yaw=0.0) -> dict:
    return {"position": _v3(x, y, z), "orientation": _yaw_quat(yaw)}


def _rgba(r, g, b, a=1.0) -> dict:
    return {"r": float(r), "g": float(g), "b": float(b), "a": float(a)}


_IDENTITY = _pose_msg()
#: Category -> colour of agent boxes (types.Category order).
_AGENT_RGBA = (_rgba(1, .6, .1), _rgba(.8, .4, .1), _rgba(.9, .3, .1), _rgba(1, .7, .3), _rgba(.6, .3, 1),
               _rgba(.5, .4, .9), _rgba(.9, .2, .8), _rgba(0, .8, .8))
_SIGNAL_RGBA = (_rgba(.5, .5, .5), _rgba(.9, .15, .15), _rgba(.95, .8, 0), _rgba(.15, .8, .25))
#: Marking -> colour of boundary lines (types.Marking order).
_MARKING_RGBA = (_rgba(.4, .4, .4, .6), _rgba(.9, .9, .9), _rgba(1, 1, 1), _rgba(1, .85, .2), _rgba(.6, .6, .6))


def _line(points: np.ndarray, rgba: dict, kind: int = 0, width: float = 0.15, z: float = 0.0) -> dict:
    return {"type": kind, "pose": _IDENTITY, "thickness": width, "scale_invariant": False,
            "points": [_v3(x, y, z) for x, y in np.asarray(points, np.float64)], "color": rgba, "colors": [],
            "indices": []}


def _cube(x, y, yaw, size, rgba: dict) -> dict:
    return {"pose": _pose_msg(x, y, size[2] / 2, yaw), "size": _v3(*size), "color": rgba}


def _entity(ns: int, eid: str, lifetime_ns: int, frame: str = "world", **prims) -> dict:
    ent = {"timestamp": _stamp(ns), "frame_id": frame, "id": eid, "lifetime": _stamp(lifetime_ns),
           "frame_locked": False, "metadata": [], "cubes": [], "lines": [], "triangles": [], "texts": []}
    ent.update(prims)
    return ent


def map_update(trace, ns: int, lifetime_ns: int) -> dict:
    """The static map and route of ``trace`` as one SceneUpdate."""
    m = trace.map
    ents = [
        _entity(ns, "drivable", lifetime_ns, lines=[_line(p, _rgba(.3, .3, .3), 1, .1) for p in m.drivable]),
        _entity(ns, "lanes", lifetime_ns, lines=[_line(p, _rgba(.35, .55, .85, .5), 0, .08, .01) for p in m.lanes]),
        _entity(ns, "boundaries", lifetime_ns, lines=[
            _line(p, _MARKING_RGBA[int(k) % len(_MARKING_RGBA)], 0, .15, .02)
            for p, k in zip(m.boundaries, m.boundary_marking)]),
        _entity(ns, "crosswalks", lifetime_ns, lines=[_line(p, _rgba(.85, .85, .85), 1, .2, .02) for p in m.crosswalks]),
        _entity(ns, "stop_lines", lifetime_ns, lines=[_line(s, _rgba(1, 1, 1), 0, .3, .03) for s in m.stop_lines]),
        _entity(ns, "obstacles", lifetime_ns, cubes=[], lines=[
            _line(p, _rgba(.55, .35, .25), 1, .2, float(h)) for p, h in zip(m.obstacles, m.obstacle_height)]),
        _entity(ns, "route", lifetime_ns, lines=[_line(trace.route_xy, _rgba(.2, .5, 1, .8), 0, .4, .04)]),
    ]
    return {"deletions": [], "entities": ents}


def scene_update(trace, k: int, ns: int, step_ns: int) -> dict:
    """Moving things at step ``k``: ego, agents, signal states, the plan."""
    a = trace.agents
    ego = _cube(trace.ego_xy[k, 0], trace.ego_xy[k, 1], trace.ego_yaw[k], trace.ego_size, _rgba(1, 1, .3))
    label = {"pose": _pose_msg(trace.ego_xy[k, 0], trace.ego_xy[k, 1], 3.0), "billboard": True, "font_size": 14.0,
             "scale_invariant": True, "color": _rgba(1, 1, 1),
             "text": f"{trace.scenario_id} t={trace.times[k]:.1f}s v={trace.ego_speed[k] * 3.6:.0f}km/h"}
    ok = np.flatnonzero(a.valid[k])
    agents = [_cube(a.xy[k, i, 0], a.xy[k, i, 1], a.yaw[k, i], a.size[i],
                    _AGENT_RGBA[int(a.category[i]) % len(_AGENT_RGBA)]) for i in ok]
    signals = [_line(s, _SIGNAL_RGBA[int(st) % 4], 0, .5, .05) for s, st in zip(trace.map.stop_lines, trace.signals[k])]
    ents = [_entity(ns, "ego", step_ns, cubes=[ego], texts=[label]),
            _entity(ns, "agents", step_ns, cubes=agents,
                    metadata=[{"key": "track_ids", "value": ",".join(str(int(a.track_id[i])) for i in ok)}]),
            _entity(ns, "signals", step_ns, lines=signals)]
    if trace.plan_xy is not None and trace.plan_valid[k]:
        pts = np.concatenate([trace.ego_xy[k][None], trace.plan_xy[k]])
        ents.append(_entity(ns, "plan", step_ns, lines=[_line(pts, _rgba(0, 1, .4), 0, .25, .1)]))
    return {"deletions": [], "entities": ents}


def transform(trace, k: int, ns: int) -> dict:
    return {"timestamp": _stamp(ns), "parent_frame_id": "world", "child_frame_id": "ego",
            "translation": _v3(trace.ego_xy[k, 0], trace.ego_xy[k, 1]), "rotation": _yaw_quat(trace.ego_yaw[k])}


def bev_image(trace, k: int, ns: int) -> dict:

    return {"timestamp": _stamp(ns), "frame_id": "ego", "format": "png",
            "data": base64.b64encode(png_bytes(bev_rgb(trace.bev, k))).decode("ascii")}


#: LiDAR point layout: x, y, z float32 + class uint8 (13 bytes, packed little-endian).
_POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("class", "u1")])


def point_cloud(trace, k: int, ns: int) -> dict:
    ok = trace.lidar_valid[k]
    return _cloud(trace.lidar_points[k][ok], trace.lidar_class[k][ok], ns)


def _cloud(xyz: np.ndarray, hit_class: np.ndarray, ns: int) -> dict:
    """foxglove.PointCloud of (N, 3) ego-frame points, m, with (N,) hit classes."""
    pts = np.zeros(len(xyz), _POINT_DTYPE)
    pts["x"], pts["y"], pts["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    pts["class"] = hit_class
    fields = [{"name": n, "offset": _POINT_DTYPE.fields[n][1], "type": UINT8 if n == "class" else FLOAT32}
              for n in _POINT_DTYPE.names]
    return {"timestamp": _stamp(ns), "frame_id": "ego", "pose": _IDENTITY, "point_stride": _POINT_DTYPE.itemsize,
            "fields": fields, "data": base64.b64encode(pts.tobytes()).decode("ascii")}


#: Foxglove schema of each drawable ``Sensor.display``.
DISPLAY_SCHEMA = {"image": "foxglove.CompressedImage", "pointcloud": "foxglove.PointCloud"}


def _shown_sensors(trace) -> dict:
    """{name: Sensor} of the trace's other sensors that are registered and drawable."""
    out = {}
    for name in (getattr(trace, "sensors", None) or {}):
        if name in registry.names() and registry.get(name).display in DISPLAY_SCHEMA:
            out[name] = registry.get(name)
    return out


def sensor_message(trace, name: str, k: int, ns: int) -> dict:
    """Step ``k`` of the trace's sensor ``name`` (``trace.sensors``) as a
    CompressedImage (PNG of ``Sensor.image``) or a PointCloud (``Sensor.points``)."""
    sensor, sf = registry.get(name), trace.sensors[name]
    if sensor.display == "image":
        return {"timestamp": _stamp(ns), "frame_id": "ego", "format": "png",
                "data": base64.b64encode(png_bytes(sensor.image(sf.frame(k), sf.config))).decode("ascii")}
    xyz, cls = sensor.points(sf.frame(k), sf.config)
    return _cloud(np.asarray(xyz, np.float32).reshape(-1, 3), np.asarray(cls).reshape(-1), ns)


def _finite_or_none(v):
    v = float(v)
    return v if math.isfinite(v) else None


def metrics(trace, k: int, ns: int) -> dict:
    c = trace.controls[k]
    out = {"timestamp": _stamp(ns), "scenario_id": trace.scenario_id, "t": round(float(trace.times[k]), 6),
           "throttle": float(c[0]), "brake": float(c[1]), "steer": float(c[2])}
    out.update({key: _finite_or_none(v[k]) for key, v in trace.timeline.items()})
    return out


def infraction_log(trace, event: dict, ns: int) -> dict:
    detail = ", ".join(f"{k}={v}" for k, v in event.items() if k not in ("type", "t"))
    return {"timestamp": _stamp(ns), "level": LOG_WARNING, "message": f"{event['type']} at t={event['t']} s ({detail})",
            "name": f"drivee2e/{trace.scenario_id}", "file": "", "line": 0}


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------


def topics(trace) -> dict[str, str]:
    """topic -> schema name of one trace's channels."""
    p = f"/{trace.scenario_id}"
    out = {f"{p}/tf": "foxglove.FrameTransform", f"{p}/scene": "foxglove.SceneUpdate",
           f"{p}/map": "foxglove.SceneUpdate", f"{p}/metrics": METRICS_SCHEMA_NAME,
           f"{p}/infractions": "foxglove.Log"}
    if trace.bev is not None:
        out[f"{p}/bev"] = "foxglove.CompressedImage"
    if trace.lidar_points is not None:
        out[f"{p}/lidar"] = "foxglove.PointCloud"
    for name, sensor in _shown_sensors(trace).items():
        out[f"{p}/{name}"] = DISPLAY_SCHEMA[sensor.display]
    return out


def episode_offsets(traces) -> list[int]:
    """Log-time offset of each episode, ns: each starts EPISODE_GAP_NS after the previous ends."""
    out, t = [], 0
    for tr in traces:
        out.append(t)
        t += int(round(float(tr.times[-1]) * 1e9)) + EPISODE_GAP_NS
    return out


def write_mcap(traces, path: str | Path) -> Path:
    """Write ``traces`` to ``path`` (atomically: a temp file, then rename). Returns the path."""
    path = Path(path)
    atomic_write(path, lambda f: _write(traces, f), binary=True)
    return path


def _write(traces, stream) -> None:
    w = Writer(stream)
    w.start(profile=PROFILE, library="drivee2e-jax")
    schema_ids: dict[str, int] = {}

    def channel(topic: str, schema_name: str, schema: dict) -> int:
        if schema_name not in schema_ids:
            schema_ids[schema_name] = w.register_schema(name=schema_name, encoding="jsonschema",
                                                        data=json.dumps(schema).encode())
        return w.register_channel(topic=topic, message_encoding="json", schema_id=schema_ids[schema_name])

    for tr, offset in zip(traces, episode_offsets(traces)):
        names = topics(tr)
        ch = {t.rsplit("/", 1)[1]: channel(t, s, SCHEMAS.get(s) or metrics_schema(list(tr.timeline)))
              for t, s in names.items()}
        step_ns = int(round(tr.dt * 1e9))
        stamps = [offset + int(round(float(t) * 1e9)) for t in tr.times]
        seq = {name: 0 for name in ch}

        def put(name: str, ns: int, msg: dict, ch: dict = ch, seq: dict = seq) -> None:
            w.add_message(channel_id=ch[name], log_time=ns, publish_time=ns, sequence=seq[name],
                          data=json.dumps(msg, allow_nan=False, separators=(",", ":")).encode())
            seq[name] += 1

        events = sorted(tr.events, key=lambda e: float(e["t"]))
        ei = 0
        duration_ns = stamps[-1] - stamps[0] + step_ns
        put("map", stamps[0], map_update(tr, stamps[0], duration_ns))
        for k, ns in enumerate(stamps):
            put("tf", ns, transform(tr, k, ns))
            put("scene", ns, scene_update(tr, k, ns, step_ns))
            if "bev" in ch:
                put("bev", ns, bev_image(tr, k, ns))
            if "lidar" in ch:
                put("lidar", ns, point_cloud(tr, k, ns))
            for name in _shown_sensors(tr):
                put(name, ns, sensor_message(tr, name, k, ns))
            put("metrics", ns, metrics(tr, k, ns))
            while ei < len(events) and offset + int(round(float(events[ei]["t"]) * 1e9)) <= ns:
                put("infractions", ns, infraction_log(tr, events[ei], ns))
                ei += 1
        for e in events[ei:]:  # an event stamped after the last traced step (should not happen)
            put("infractions", stamps[-1], infraction_log(tr, e, stamps[-1]))
        w.add_metadata("drivee2e.episode", {
            "scenario_id": tr.scenario_id, "policy": tr.policy, "offset_ns": str(offset), "steps": str(tr.num_steps),
            "driving_score": f"{tr.driving_score:.4f}", "stored_driving_score": f"{tr.stored_driving_score:.4f}"})
    w.finish()
