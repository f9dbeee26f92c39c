"""MCAP episode logs in Foxglove's published schemas (host side).

``write_mcap(traces, path)`` writes one MCAP file holding every
``eval.traces.EpisodeTrace``. The ``foxglove.*`` channels are protobuf
(``message_encoding "protobuf"``): each message is the official class of
``foxglove-schemas-protobuf`` serialized, and each schema record carries that
class's ``FileDescriptorSet`` (``io.foxglove_schemas``, which says why this
package), so Foxglove's 3D, Image, Plot, Raw Messages and Log panels read them
as is. The ``drivee2e.EpisodeMetrics`` channel is ours: JSON with a JSON Schema
(its fields follow the trace's ``timeline`` keys, which Foxglove's Plot panel
reads by name with no descriptor to build).

Topics, per episode ``/<scenario_id>/...`` (T = the trace's steps + 1):

=================  ========================  =====================================
topic              schema                    messages
=================  ========================  =====================================
``tf``             foxglove.FrameTransform   T: ``map`` -> ``ego`` (ego box centre)
``origin``         foxglove.FrameTransform   T: ``world`` -> ``map`` (the scenario's origin)
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

Frames: everything is drawn in ``map``, the scenario's local frame the
simulator computes in (``scenario.origin``: world minus the map's origin, a
multiple of 1 km), so a source in UTM (4e6 m) renders without float32
jitter; ``world`` -> ``map`` carries the origin (float64), so the 3D panel's
display frame ``world`` shows world coordinates and ``map`` / ``ego`` the
local ones. Infraction log lines give world x, y (as the results folder).

Time, integer nanoseconds from the step index, never from the float time
arrays: step ``k`` of an episode is at ``offset_ns + k * step_ns(dt)`` with
``step_ns(dt) = round(dt * 1e9)``; a message's log time, publish time and
``timestamp`` field are that one integer, and an infraction event is stamped
at its step ``round(t / dt)``. Episodes follow one another (each starts 1 s
after the previous one ends), so the timeline plays them in turn and the map
of one never overlaps another's. The offsets are in the file's
``drivee2e.episode`` metadata records (scenario_id, policy, offset_ns, steps,
driving_score; driving_score_all / driving_score_at_fault / collisions_at_fault
when the stored row has them). A collision event's log line names its nuPlan
collision type and fault right after its time (``collisions_vehicle at t=3.6 s
[active_front, at fault] (...)``; ``fault_text``), so "type at t=" stays the
start of every line. Every entity has a lifetime (one step for the moving ones,
the episode for the map) so nothing lingers.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.Point3_pb2 import Point3
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.TextPrimitive_pb2 import TextPrimitive
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.message import Message
from mcap.writer import Writer

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.files import ForeignFiles, atomic_write, check_own_file
from drivee2e_jax.io import foxglove_schemas as fs
from drivee2e_jax.io.foxglove_schemas import CompressedImage, FrameTransform, Log, PointCloud, SceneUpdate
from drivee2e_jax.observe import registry
from drivee2e_jax.observe.palette import bev_rgb
from drivee2e_jax.observe.png import png_bytes

#: Gap between consecutive episodes on the file's timeline, ns.
EPISODE_GAP_NS = 1_000_000_000
#: Profile string of the file (no ROS profile: Foxglove protobuf + one JSON channel).
PROFILE = ""
#: The header's library string: how ``check_overwrite`` tells a file drivee2e wrote.
LIBRARY = "drivee2e-jax"

# --------------------------------------------------------------------------
# The metrics channel (ours: JSON with a JSON Schema)
# --------------------------------------------------------------------------

#: The per-step metrics message (not a Foxglove type: Plot / Raw Messages panels read it).
METRICS_SCHEMA_NAME = "drivee2e.EpisodeMetrics"
_JSON_TIME = {"type": "object", "title": "time", "description": "Log time of the step (with the episode offset)",
              "properties": {"sec": {"type": "integer", "minimum": 0},
                             "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
              "required": ["sec", "nsec"], "additionalProperties": False}


def metrics_schema(timeline_keys: Sequence[str]) -> dict:
    """JSON Schema of the metrics message: time, controls and every timeline value (all required)."""
    num = lambda desc: {"type": "number", "description": desc}
    props = {"timestamp": _JSON_TIME,
             "scenario_id": {"type": "string", "description": "Scenario id"},
             "t": num("Sim time since the episode start, s (step * dt)"),
             "throttle": num("Applied throttle from this state, [0, 1]"),
             "brake": num("Applied brake from this state, [0, 1]"),
             "steer": num("Applied steer from this state, [-1, 1], +1 = full left")}
    for k in timeline_keys:
        props[k] = {"type": ["number", "null"], "description": f"StepLog timeline {k} (null = inf/NaN)"}
    return {"title": METRICS_SCHEMA_NAME, "description": "Per-step metrics of a drivee2e episode",
            "type": "object", "properties": props, "required": list(props), "additionalProperties": False}


# --------------------------------------------------------------------------
# Time: integer nanoseconds from the step index
# --------------------------------------------------------------------------


def step_ns(dt: float) -> int:
    """The sim step ``dt`` (s) as integer nanoseconds, ``round(dt * 1e9)``."""
    return int(round(float(dt) * 1e9))


def episode_stamps(trace, offset_ns: int) -> list[int]:
    """Log time of each of the trace's T states, ns: ``offset_ns + k * step_ns(trace.dt)``."""
    d = step_ns(trace.dt)
    return [int(offset_ns) + k * d for k in range(trace.num_steps)]


def episode_offsets(traces) -> list[int]:
    """Log-time offset of each episode, ns: each starts EPISODE_GAP_NS after the previous one's last state."""
    out, t = [], 0
    for tr in traces:
        out.append(t)
        t += (tr.num_steps - 1) * step_ns(tr.dt) + EPISODE_GAP_NS
    return out


def event_step(event: dict, dt: float, num_steps: int) -> int:
    """Index of the state that ends the step an infraction event (time ``event["t"]``, s) happened in:
    ``round(t / dt)``, clipped to ``[0, num_steps - 1]``."""
    return min(max(int(round(float(event["t"]) / float(dt))), 0), num_steps - 1)


# --------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------


def _json_stamp(ns: int) -> dict:
    """Foxglove's JSON time ``{"sec", "nsec"}`` of integer nanoseconds (the metrics channel)."""
    return {"sec": ns // fs.NS_PER_S, "nsec": ns % fs.NS_PER_S}


def _v3(x, y, z=0.0) -> Vector3:
    return Vector3(x=float(x), y=float(y), z=float(z))


def _p3(x, y, z=0.0) -> Point3:
    return Point3(x=float(x), y=float(y), z=float(z))


def _yaw_quat(yaw) -> Quaternion:
    """Rotation by ``yaw`` rad about +z (unit quaternion)."""
    return Quaternion(x=0.0, y=0.0, z=math.sin(float(yaw) / 2), w=math.cos(float(yaw) / 2))


def _pose(x=0.0, y=0.0, z=0.0, yaw=0.0) -> Pose:
    return Pose(position=_v3(x, y, z), orientation=_yaw_quat(yaw))


def _rgba(r, g, b, a=1.0) -> Color:
    return Color(r=float(r), g=float(g), b=float(b), a=float(a))


_IDENTITY = _pose()
#: Category -> colour of agent boxes (types.Category order).
_AGENT_RGBA = (_rgba(1, .6, .1), _rgba(.8, .4, .1), _rgba(.9, .3, .1), _rgba(1, .7, .3), _rgba(.6, .3, 1),
               _rgba(.5, .4, .9), _rgba(.9, .2, .8), _rgba(0, .8, .8))
_SIGNAL_RGBA = (_rgba(.5, .5, .5), _rgba(.9, .15, .15), _rgba(.95, .8, 0), _rgba(.15, .8, .25))
#: Marking -> colour of boundary lines (types.Marking order).
_MARKING_RGBA = (_rgba(.4, .4, .4, .6), _rgba(.9, .9, .9), _rgba(1, 1, 1), _rgba(1, .85, .2), _rgba(.6, .6, .6))
_STRIP, _LOOP = LinePrimitive.LINE_STRIP, LinePrimitive.LINE_LOOP


def _line(points: np.ndarray, rgba: Color, kind: int = _STRIP, width: float = 0.15, z: float = 0.0) -> LinePrimitive:
    """A line through (N, 2) world points, m, at height ``z`` m, ``width`` m thick, one colour."""
    return LinePrimitive(type=kind, pose=_IDENTITY, thickness=width, scale_invariant=False,
                         points=[_p3(x, y, z) for x, y in np.asarray(points, np.float64)], color=rgba)


def _cube(x, y, yaw, size, rgba: Color) -> CubePrimitive:
    """A box standing on the ground, centre (x, y) m, heading yaw rad, size (length, width, height) m."""
    return CubePrimitive(pose=_pose(x, y, size[2] / 2, yaw), size=_v3(*size), color=rgba)


def _entity(ns: int, eid: str, lifetime_ns: int, frame: str = "map", **prims) -> SceneEntity:
    return SceneEntity(timestamp=fs.timestamp(ns), frame_id=frame, id=eid, lifetime=fs.duration(lifetime_ns),
                       frame_locked=False, **prims)


def map_update(trace, ns: int, lifetime_ns: int) -> SceneUpdate:
    """The static map and route of ``trace`` as one SceneUpdate stamped ``ns``, shown for ``lifetime_ns``."""
    m = trace.map
    ents = [
        _entity(ns, "drivable", lifetime_ns, lines=[_line(p, _rgba(.3, .3, .3), _LOOP, .1) for p in m.drivable]),
        _entity(ns, "lanes", lifetime_ns, lines=[_line(p, _rgba(.35, .55, .85, .5), _STRIP, .08, .01) for p in m.lanes]),
        _entity(ns, "boundaries", lifetime_ns, lines=[
            _line(p, _MARKING_RGBA[int(k) % len(_MARKING_RGBA)], _STRIP, .15, .02)
            for p, k in zip(m.boundaries, m.boundary_marking)]),
        _entity(ns, "crosswalks", lifetime_ns, lines=[_line(p, _rgba(.85, .85, .85), _LOOP, .2, .02)
                                                      for p in m.crosswalks]),
        _entity(ns, "stop_lines", lifetime_ns, lines=[_line(s, _rgba(1, 1, 1), _STRIP, .3, .03) for s in m.stop_lines]),
        _entity(ns, "obstacles", lifetime_ns, lines=[
            _line(p, _rgba(.55, .35, .25), _LOOP, .2, float(h)) for p, h in zip(m.obstacles, m.obstacle_height)]),
        _entity(ns, "route", lifetime_ns, lines=[_line(trace.route_xy, _rgba(.2, .5, 1, .8), _STRIP, .4, .04)]),
    ]
    return SceneUpdate(entities=ents)


def scene_update(trace, k: int, ns: int, dt_ns: int) -> SceneUpdate:
    """Moving things at step ``k`` (stamped ``ns``, shown for one step of ``dt_ns``): ego, agents, signals, plan."""
    a = trace.agents
    ego = _cube(trace.ego_xy[k, 0], trace.ego_xy[k, 1], trace.ego_yaw[k], trace.ego_size, _rgba(1, 1, .3))
    label = TextPrimitive(pose=_pose(trace.ego_xy[k, 0], trace.ego_xy[k, 1], 3.0), billboard=True, font_size=14.0,
                          scale_invariant=True, color=_rgba(1, 1, 1),
                          text=f"{trace.scenario_id} t={k * dt_ns / fs.NS_PER_S:.1f}s "
                               f"v={trace.ego_speed[k] * 3.6:.0f}km/h")
    ok = np.flatnonzero(a.valid[k])
    agents = [_cube(a.xy[k, i, 0], a.xy[k, i, 1], a.yaw[k, i], a.size[i],
                    _AGENT_RGBA[int(a.category[i]) % len(_AGENT_RGBA)]) for i in ok]
    signals = [_line(s, _SIGNAL_RGBA[int(st) % 4], _STRIP, .5, .05)
               for s, st in zip(trace.map.stop_lines, trace.signals[k])]
    track_ids = KeyValuePair(key="track_ids", value=",".join(str(int(a.track_id[i])) for i in ok))
    ents = [_entity(ns, "ego", dt_ns, cubes=[ego], texts=[label]),
            _entity(ns, "agents", dt_ns, cubes=agents, metadata=[track_ids]),
            _entity(ns, "signals", dt_ns, lines=signals)]
    if trace.plan_xy is not None and trace.plan_valid[k]:
        pts = np.concatenate([trace.ego_xy[k][None], trace.plan_xy[k]])
        ents.append(_entity(ns, "plan", dt_ns, lines=[_line(pts, _rgba(0, 1, .4), _STRIP, .25, .1)]))
    return SceneUpdate(entities=ents)


def map_transform(trace, ns: int) -> FrameTransform:
    """``world`` -> ``map``: the scenario's local frame sits at ``trace.origin`` (float64 m)."""
    ox, oy = (float(v) for v in np.asarray(getattr(trace, "origin", (0.0, 0.0)), np.float64).reshape(2))
    return FrameTransform(timestamp=fs.timestamp(ns), parent_frame_id="world", child_frame_id="map",
                          translation=_v3(ox, oy), rotation=_yaw_quat(0.0))


def transform(trace, k: int, ns: int) -> FrameTransform:
    """``map`` -> ``ego`` at step ``k``: the ego box centre and heading."""
    return FrameTransform(timestamp=fs.timestamp(ns), parent_frame_id="map", child_frame_id="ego",
                          translation=_v3(trace.ego_xy[k, 0], trace.ego_xy[k, 1]),
                          rotation=_yaw_quat(trace.ego_yaw[k]))


def _png(data: bytes, ns: int) -> CompressedImage:
    return CompressedImage(timestamp=fs.timestamp(ns), frame_id="ego", format="png", data=data)


def bev_image(trace, k: int, ns: int) -> CompressedImage:
    """The BEV of step ``k`` as a PNG (``observe.palette`` colours)."""
    return _png(png_bytes(bev_rgb(trace.bev, k)), ns)


#: LiDAR point layout: x, y, z float32 + class uint8 (13 bytes, packed little-endian).
_POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("class", "u1")])


def point_cloud(trace, k: int, ns: int) -> PointCloud:
    """The valid LiDAR returns of step ``k``."""
    ok = trace.lidar_valid[k]
    return _cloud(trace.lidar_points[k][ok], trace.lidar_class[k][ok], ns)


def _cloud(xyz: np.ndarray, hit_class: np.ndarray, ns: int) -> PointCloud:
    """foxglove.PointCloud of (N, 3) ego-frame points, m, with (N,) hit classes."""
    pts = np.zeros(len(xyz), _POINT_DTYPE)
    pts["x"], pts["y"], pts["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    pts["class"] = hit_class
    fields = [PackedElementField(name=n, offset=_POINT_DTYPE.fields[n][1],
                                 type=PackedElementField.UINT8 if n == "class" else PackedElementField.FLOAT32)
              for n in _POINT_DTYPE.names]
    return PointCloud(timestamp=fs.timestamp(ns), frame_id="ego", pose=_IDENTITY, point_stride=_POINT_DTYPE.itemsize,
                      fields=fields, data=pts.tobytes())


#: Foxglove schema of each drawable ``Sensor.display``.
DISPLAY_SCHEMA = {"image": "foxglove.CompressedImage", "pointcloud": "foxglove.PointCloud"}


def _shown_sensors(trace) -> dict:
    """{name: Sensor} of the trace's other sensors that are registered and drawable."""
    out = {}
    for name in (getattr(trace, "sensors", None) or {}):
        if name in registry.names() and registry.get(name).display in DISPLAY_SCHEMA:
            out[name] = registry.get(name)
    return out


def sensor_message(trace, name: str, k: int, ns: int) -> CompressedImage | PointCloud:
    """Step ``k`` of the trace's sensor ``name`` (``trace.sensors``) as a
    CompressedImage (PNG of ``Sensor.image``) or a PointCloud (``Sensor.points``)."""
    sensor, sf = registry.get(name), trace.sensors[name]
    if sensor.display == "image":
        return _png(png_bytes(sensor.image(sf.frame(k), sf.config)), ns)
    xyz, cls = sensor.points(sf.frame(k), sf.config)
    return _cloud(np.asarray(xyz, np.float32).reshape(-1, 3), np.asarray(cls).reshape(-1), ns)


def _finite_or_none(v):
    v = float(v)
    return v if math.isfinite(v) else None


def metrics(trace, k: int, ns: int, dt_ns: int) -> dict:
    """The metrics message of step ``k`` (plain JSON, ``metrics_schema``); ``t`` = k * dt_ns, s."""
    c = trace.controls[k]
    out = {"timestamp": _json_stamp(ns), "scenario_id": trace.scenario_id, "t": k * dt_ns / fs.NS_PER_S,
           "throttle": float(c[0]), "brake": float(c[1]), "steer": float(c[2])}
    out.update({key: _finite_or_none(v[k]) for key, v in trace.timeline.items()})
    return out


def fault_text(event: dict) -> str:
    """`` [<collision_type>, at fault]`` / `` [<collision_type>, not at fault]``
    for a collision event that carries them (nuPlan ``collision_utils``
    CollisionType in lower case, ``static`` for a layout object), "" for
    any other event or one of an older run."""
    kind, fault = event.get("collision_type"), event.get("at_fault")
    parts = ([str(kind)] if kind is not None else []) + (
        [] if fault is None else ["at fault" if bool(fault) else "not at fault"])
    return f" [{', '.join(parts)}]" if parts else ""


def infraction_log(trace, event: dict, ns: int) -> Log:
    """A WARNING log line of one stored infraction event (type, t s, the
    collision type and fault when it has them, and its other fields)."""
    detail = ", ".join(f"{k}={v}" for k, v in event.items() if k not in ("type", "t"))
    return Log(timestamp=fs.timestamp(ns), level=Log.WARNING,
               message=f"{event['type']} at t={event['t']} s{fault_text(event)} ({detail})",
               name=f"drivee2e/{trace.scenario_id}", file="", line=0)


def episode_metadata(trace, offset_ns: int) -> dict[str, str]:
    """The ``drivee2e.episode`` metadata record of one trace (strings only):
    scenario_id, policy, offset_ns, steps, driving_score (re-simulated),
    stored_driving_score, origin_x / origin_y (world m of the ``map`` frame), and the stored row's driving_score_all /
    driving_score_at_fault / collisions_at_fault when it has them."""
    out = {"scenario_id": trace.scenario_id, "policy": trace.policy, "offset_ns": str(offset_ns),
           "steps": str(trace.num_steps), "driving_score": f"{trace.driving_score:.4f}",
           "stored_driving_score": f"{trace.stored_driving_score:.4f}"}
    ox, oy = (float(v) for v in np.asarray(getattr(trace, "origin", (0.0, 0.0)), np.float64).reshape(2))
    out["origin_x"], out["origin_y"] = repr(ox), repr(oy)
    row = getattr(trace, "row", None) or {}
    for key in ("driving_score_all", "driving_score_at_fault"):
        v = row.get(key)
        if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
            out[key] = f"{float(v):.4f}"
    v = row.get("collisions_at_fault")
    if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v):
        out["collisions_at_fault"] = str(int(v))
    return out


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------


def topics(trace) -> dict[str, str]:
    """topic -> schema name of one trace's channels."""
    p = f"/{trace.scenario_id}"
    out = {f"{p}/tf": "foxglove.FrameTransform", f"{p}/origin": "foxglove.FrameTransform",
           f"{p}/scene": "foxglove.SceneUpdate",
           f"{p}/map": "foxglove.SceneUpdate", f"{p}/metrics": METRICS_SCHEMA_NAME,
           f"{p}/infractions": "foxglove.Log"}
    if trace.bev is not None:
        out[f"{p}/bev"] = "foxglove.CompressedImage"
    if trace.lidar_points is not None:
        out[f"{p}/lidar"] = "foxglove.PointCloud"
    for name, sensor in _shown_sensors(trace).items():
        out[f"{p}/{name}"] = DISPLAY_SCHEMA[sensor.display]
    return out


def channel_schema(schema_name: str, timeline_keys: Sequence[str]) -> tuple[str, bytes, str]:
    """(schema encoding, schema data, message encoding) of a channel: a Foxglove type's FileDescriptorSet
    and protobuf messages, or the metrics channel's JSON Schema and JSON messages."""
    if schema_name in fs.CLASSES:
        return fs.ENCODING, fs.file_descriptor_set(schema_name), fs.ENCODING
    return "jsonschema", json.dumps(metrics_schema(timeline_keys)).encode(), "json"


def encode(msg: Message | dict) -> bytes:
    """Message bytes: serialized protobuf, or compact JSON (no NaN/inf) for the metrics dict."""
    if isinstance(msg, Message):
        return msg.SerializeToString()
    return json.dumps(msg, allow_nan=False, separators=(",", ":")).encode()


def check_overwrite(path: str | Path) -> None:
    """Before ``--force`` rewrites ``path``: DriveE2EError (one line) when it
    exists but is not an MCAP file drivee2e wrote (its header names
    ``LIBRARY``): drivee2e never overwrites a user's file."""
    try:
        check_own_file(path, LIBRARY.encode(), "MCAP file", head=256)
    except ForeignFiles as e:
        raise DriveE2EError(str(e)) from None


def write_mcap(traces, path: str | Path) -> Path:
    """Write ``traces`` to ``path`` (atomically: a temp file, then rename). Returns the path."""
    path = Path(path)
    atomic_write(path, lambda f: _write(traces, f), binary=True)
    return path


def _write(traces, stream) -> None:
    w = Writer(stream)
    w.start(profile=PROFILE, library=LIBRARY)
    schema_ids: dict[tuple[str, bytes], int] = {}

    def channel(topic: str, schema_name: str, timeline_keys: Sequence[str]) -> int:
        schema_encoding, data, message_encoding = channel_schema(schema_name, timeline_keys)
        if (schema_name, data) not in schema_ids:
            schema_ids[schema_name, data] = w.register_schema(name=schema_name, encoding=schema_encoding, data=data)
        return w.register_channel(topic=topic, message_encoding=message_encoding,
                                  schema_id=schema_ids[schema_name, data])

    for tr, offset in zip(traces, episode_offsets(traces)):
        ch = {t.rsplit("/", 1)[1]: channel(t, s, list(tr.timeline)) for t, s in topics(tr).items()}
        dt_ns = step_ns(tr.dt)
        stamps = episode_stamps(tr, offset)
        seq = {name: 0 for name in ch}

        def put(name: str, ns: int, msg: Message | dict, ch: dict = ch, seq: dict = seq) -> None:
            w.add_message(channel_id=ch[name], log_time=ns, publish_time=ns, sequence=seq[name], data=encode(msg))
            seq[name] += 1

        events_at: dict[int, list[dict]] = {}  # state index -> the events of the step that ended there, in time order
        for e in sorted(tr.events, key=lambda e: float(e["t"])):
            events_at.setdefault(event_step(e, tr.dt, len(stamps)), []).append(e)
        put("map", stamps[0], map_update(tr, stamps[0], len(stamps) * dt_ns))
        for k, ns in enumerate(stamps):
            put("tf", ns, transform(tr, k, ns))
            put("origin", ns, map_transform(tr, ns))
            put("scene", ns, scene_update(tr, k, ns, dt_ns))
            if "bev" in ch:
                put("bev", ns, bev_image(tr, k, ns))
            if "lidar" in ch:
                put("lidar", ns, point_cloud(tr, k, ns))
            for name in _shown_sensors(tr):
                put(name, ns, sensor_message(tr, name, k, ns))
            put("metrics", ns, metrics(tr, k, ns, dt_ns))
            for e in events_at.get(k, ()):
                put("infractions", ns, infraction_log(tr, e, ns))
        w.add_metadata("drivee2e.episode", episode_metadata(tr, offset))
    w.finish()
