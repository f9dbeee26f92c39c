"""One ``eval.traces.EpisodeTrace`` -> the episode record the HTML player reads.

Host side only. An episode record (all coordinates in the scenario's local
frame, the one the simulator computes in, m, rounded to 1 cm; ``origin`` is
the world (x, y) of its (0, 0), so world = local + origin (``scenario.origin``:
drawing a UTM frame's 4e6 m directly would jitter in the browser's float32
canvas); ``flat`` = ``[x0, y0, x1, y1, ...]``; frame ``k`` is ``trace.times[k]``)::

    id, policy, status, ds, rc (stored Driving Score / route completion, %),
    ds_all, ds_at_fault (stored DS with every collision counted / with only
    the at-fault ones; null for rows of older runs),
    behavior, split, map_id, reproduced,
    dt (s per frame), t0 (s at frame 0), n (frames),
    route:   flat route polyline,
    ego:     {l, w, x: [n], y: [n], yaw: [n] (rad), wp: [n] flat world waypoints or null},
    agents:  [{id, cat, l, w, f0, x, y, yaw}]  samples from frame f0 on, null where absent,
    signals: [S][n] ``SignalState`` values, one row per map stop line,
    metrics: [{name, label, unit, values: [n], range?: [lo, hi], color?}],
    origin:  [x, y] world m of the local frame (float64; 0, 0 for a suite near its origin),
    events:  [{type, t, x, y, frame, ...}]  the stored infraction events, x, y local
             (the results folder's world x, y minus ``origin``)
             (collisions also carry collision_type, at_fault and ``fault``,
             a short label such as "active_front, at fault": ``collision_label``),
    bev:     {stride, channels, colors, h, w, count, sheet: PNG data URI} or null:
             ``count`` frames of h x w pixels stacked top to bottom in one
             palette PNG (frame k = rows k*h .. (k+1)*h),
    lidar:   {stride, range, scale, frames: [{xy, c}]} or null  (``encode``),
    sensors: [{name, display: "image", stride, frames: [PNG data URI]} or
              {name, display: "pointcloud", stride, range, scale, frames: [{xy, c}]}]
             the trace's other registered sensors (``trace.sensors``, shown as
             their ``observe.registry`` entry's ``display`` says; "none" left out).

Sensor frames are kept every ``stride`` frames (the player shows the latest
one at or before the current frame) to keep the file small; a trace that
holds only every s-th instant's frames (``EpisodeTrace.sensor_stride``) gets
a stride rounded to a multiple of s.
"""

from __future__ import annotations

import jax
import numpy as np

from drivee2e_jax.observe import registry
from drivee2e_jax.observe.raycast import HIT_AGENT
from drivee2e_jax.types import Category, Marking, SignalState
from drivee2e_jax.viz import encode

#: Timelines drawn under the scene: (name, label, unit, source, scale, range, colour).
#: ``source`` is a ``trace.timeline`` key or ``controls[i]``.
TIMELINES = (
    ("speed", "speed", "km/h", "speed", 3.6, None, "#74c0fc"),
    ("route_completion", "route completion", "%", "route_completion", 1.0, (0.0, 100.0), "#69db7c"),
    ("throttle", "throttle", "", "controls[0]", 1.0, (0.0, 1.0), "#8ce99a"),
    ("brake", "brake", "", "controls[1]", 1.0, (0.0, 1.0), "#ff8787"),
    ("steer", "steer", "", "controls[2]", 1.0, (-1.0, 1.0), "#ffd43b"),
    ("front_distance", "front gap", "m", "facts.front_distance", 1.0, (0.0, 50.0), "#b197fc"),
    ("lane_offset", "lane offset", "m", "facts.lane_offset", 1.0, None, "#ffa94d"),
)
#: Cap of the front-gap timeline (inf = nobody ahead), m.
FRONT_GAP_CAP_M = 50.0


def enum_meta() -> dict:
    """Enum names by value, so the page needs no copy of ``types``."""

    def names(enum):
        return [m.name.lower() for m in sorted(enum, key=int)]

    cats = names(Category)
    assert [int(c) for c in sorted(Category, key=int)] == list(range(len(cats)))
    hits = ["none", "ground", "static"]
    assert len(hits) == HIT_AGENT
    return {"categories": cats, "signal_states": names(SignalState), "markings": names(Marking),
            "hit_classes": hits + cats}


def map_payload(smap) -> dict:
    """``eval.traces.StaticMap`` -> the player's map record."""
    flat = lambda polys: [f for f in (encode.flat_points(p) for p in polys) if len(f) >= 4]  # noqa: E731
    return {
        "drivable": flat(smap.drivable),
        "obstacles": flat(smap.obstacles),
        "crosswalks": flat(smap.crosswalks),
        "lanes": flat(smap.lanes),
        "boundaries": [[int(m), encode.flat_points(p)] for m, p in zip(smap.boundary_marking, smap.boundaries)
                       if len(p) >= 2],
        "stop_lines": np.round(np.asarray(smap.stop_lines, np.float64).reshape(-1, 4), 2).tolist(),
    }


def agents_payload(agents) -> list[dict]:
    """``eval.traces.AgentsTrace`` -> one compact record per agent seen at least once."""
    out = []
    for a in range(agents.track_id.shape[0]):
        ok = np.asarray(agents.valid[:, a], bool)
        idx = np.flatnonzero(ok)
        if idx.size == 0:
            continue
        f0, f1 = int(idx[0]), int(idx[-1]) + 1
        v = ok[f0:f1]
        out.append({
            "id": int(agents.track_id[a]), "cat": int(agents.category[a]),
            "l": round(float(agents.size[a, 0]), 2), "w": round(float(agents.size[a, 1]), 2), "f0": f0,
            "x": encode.round_list(agents.xy[f0:f1, a, 0], 2, v),
            "y": encode.round_list(agents.xy[f0:f1, a, 1], 2, v),
            "yaw": encode.round_list(agents.yaw[f0:f1, a], 3, v),
        })
    return out


def _series(trace, source: str) -> np.ndarray | None:
    if source.startswith("controls["):
        return np.asarray(trace.controls[:, int(source[9:-1])], np.float64)
    v = trace.timeline.get(source)
    return None if v is None else np.asarray(v, np.float64)


def metrics_payload(trace) -> list[dict]:
    """The ``TIMELINES`` present in ``trace``; the last frame's action (none)
    repeats the one before so the curves do not drop to zero at the end."""
    out = []
    for name, label, unit, source, scale, rng, colour in TIMELINES:
        v = _series(trace, source)
        if v is None:
            continue
        v = v * scale
        if source.startswith("controls[") and len(v) > 1:
            v[-1] = v[-2]
        if name == "front_distance":
            v = np.minimum(v, FRONT_GAP_CAP_M)
        rec = {"name": name, "label": label, "unit": unit, "values": encode.round_list(v, 2), "color": colour}
        if rng is not None:
            rec["range"] = list(rng)
        out.append(rec)
    return out


def collision_label(event: dict) -> str | None:
    """The collision type and fault of a stored collision event in words
    (``"active_front, at fault"``, ``"active_rear, not at fault"``,
    ``"static, at fault"``); None for an event without them (other types,
    rows of older runs). Types: nuPlan ``collision_utils.CollisionType``
    in lower case, ``static`` for a layout object."""
    kind, fault = event.get("collision_type"), event.get("at_fault")
    if kind is None and fault is None:
        return None
    parts = [str(kind)] if kind is not None else []
    if fault is not None:
        parts.append("at fault" if bool(fault) else "not at fault")
    return ", ".join(parts)


def events_payload(events: list[dict], times: np.ndarray, origin=(0.0, 0.0)) -> list[dict]:
    """Stored events with the frame (nearest traced instant) each happened
    at, for collisions ``fault`` (``collision_label``), and x, y moved from
    the world frame to the local one (minus ``origin``, world m)."""
    ox, oy = (float(v) for v in np.asarray(origin, np.float64).reshape(2))
    out = []
    for e in events:
        k = int(np.clip(np.searchsorted(times, float(e.get("t", 0.0)) - 1e-6), 0, len(times) - 1))
        label = collision_label(e)
        local = {}
        if isinstance(e.get("x"), int | float) and isinstance(e.get("y"), int | float):
            local = {"x": round(e["x"] - ox, 3), "y": round(e["y"] - oy, 3)}
        out.append({**e, **local, "frame": k, **({"fault": label} if label else {})})
    return sorted(out, key=lambda e: e["frame"])


def _sensor_step(trace, stride: int, attr: str = "sensor_stride") -> tuple[int, int]:
    """(take every ``step``-th stored sensor frame, the effective stride in
    instants): ``stride`` instants rounded up to a multiple of the trace's own
    ``sensor_stride`` / ``lidar_stride`` (``attr``: a trace may hold only
    every s-th instant's frames)."""
    s = max(1, int(getattr(trace, attr, 1) or 1))
    step = max(1, -(-int(stride) // s))  # rounded up: never more frames than asked for
    return step, step * s


def bev_payload(trace, stride: int) -> dict | None:
    """The BEV as ONE sprite sheet per episode: its kept frames stacked
    top to bottom in a palette PNG (``encode.bev_sheet_uri``); frame k is rows
    ``k * h .. (k + 1) * h``. A few large PNGs encode and load much faster
    than one per frame."""
    if not trace.bev:
        return None
    step, eff = _sensor_step(trace, stride)
    channels = list(trace.bev)
    bits = getattr(trace.bev, "bits", None)  # ``eval.traces.PackedBev``: straight from the packed bits
    if bits is not None:
        index = encode.bev_index_from_bits(np.asarray(bits)[::step], len(channels))
    else:
        index = encode.bev_index([np.asarray(trace.bev[c])[::step] for c in channels])
    count, h, w = index.shape
    colours = ["rgb({},{},{})".format(*encode.BEV_COLORS.get(c.partition("@")[0], (128, 128, 128)))
               for c in channels]
    return {"stride": eff, "channels": channels, "colors": colours, "h": int(h), "w": int(w), "count": int(count),
            "sheet": encode.bev_sheet_uri(index, channels)}


def lidar_payload(trace, stride: int, max_points: int, seed: int = 0) -> dict | None:
    if trace.lidar_points is None:
        return None
    rng = np.random.default_rng(seed)
    step, eff = _sensor_step(trace, stride, "lidar_stride")
    pts, cls, ok = trace.lidar_points, trace.lidar_class, trace.lidar_valid
    frames = [encode.encode_lidar_points(pts[k, ok[k], :2], cls[k, ok[k]], max_points, rng)
              for k in range(0, len(pts), step)]
    reach = np.abs(pts[..., :2][ok]).max() if ok.any() else 1.0
    return {"stride": eff, "range": float(np.ceil(min(reach, 100.0))), "scale": encode.LIDAR_SCALE,
            "frames": frames}


def sensor_panes(trace, image_stride: int, points_stride: int, max_points: int, seed: int = 0) -> list[dict]:
    """One pane per sensor of ``trace.sensors`` (``observe.sensor_api.SensorFrames``)
    with a display: "image" frames as PNG data URIs of ``Sensor.image``,
    "pointcloud" frames as ``encode.encode_lidar_points`` of ``Sensor.points``
    (x, y of the ego frame). Sensors no longer registered are skipped."""
    panes = []
    for name, sf in (getattr(trace, "sensors", None) or {}).items():
        if name not in registry.names():
            continue
        sensor = registry.get(name)
        n = len(jax.tree_util.tree_leaves(sf.frames)[0])  # stored frames (every ``trace.sensor_stride``-th instant)
        if sensor.display == "image":
            step, eff = _sensor_step(trace, image_stride)
            frames = [encode.png_data_uri(sensor.image(sf.frame(k), sf.config)) for k in range(0, n, step)]
            panes.append({"name": name, "display": "image", "stride": eff, "frames": frames})
        elif sensor.display == "pointcloud":
            step, points_stride = _sensor_step(trace, points_stride)  # other sensors follow ``sensor_stride``
            rng = np.random.default_rng(seed)
            frames, reach = [], 1.0
            for k in range(0, n, step):
                xyz, cls = sensor.points(sf.frame(k), sf.config)
                xy = np.asarray(xyz, np.float64)[:, :2]
                if len(xy):
                    reach = max(reach, float(np.abs(xy).max()))
                frames.append(encode.encode_lidar_points(xy, cls, max_points, rng))
            panes.append({"name": name, "display": "pointcloud", "stride": points_stride,
                          "range": float(np.ceil(min(reach, 100.0))), "scale": encode.LIDAR_SCALE, "frames": frames})
    return panes


def index_entry(ep: dict, key: str) -> dict:
    """The index row of an episode record (what the page lists, filters and
    sorts before any episode file is loaded): ``key`` (its file stem), id,
    policy, status, ds, ds_all, ds_at_fault (null when the record has none),
    rc, behavior, split, map_id, n, reproduced, and ``infractions``:
    {event type: count} of its stored events."""
    counts: dict[str, int] = {}
    for e in ep["events"]:
        counts[str(e.get("type"))] = counts.get(str(e.get("type")), 0) + 1
    keep = ("id", "policy", "status", "ds", "rc", "behavior", "split", "map_id", "n", "reproduced")
    both = {k: ep.get(k) for k in ("ds_all", "ds_at_fault")}
    return {"key": key, **{k: ep[k] for k in keep}, **both, "infractions": counts}


def _score(v) -> float | None:
    """A stored per-scenario score rounded to 2 decimals; None when missing or not finite."""
    if v is None or v == "" or isinstance(v, bool):
        return None
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return round(v, 2) if np.isfinite(v) else None


def _stride(dt: float, period_s: float) -> int:
    return max(1, int(round(period_s / dt)))


def episode_payload(trace, *, sensors: bool = True, bev_period_s: float = 0.2, lidar_period_s: float = 0.5,
                    lidar_max_points: int = 1500) -> tuple[dict, str, dict]:
    """One trace -> (episode record, its map id, the map record).

    Args:
      trace: ``eval.traces.EpisodeTrace``.
      sensors: embed the BEV / LiDAR / other sensors' frames the trace carries.
      bev_period_s, lidar_period_s: keep one sensor frame per this many
        seconds (other sensors: image ones as the BEV, point clouds as the LiDAR).
      lidar_max_points: random subset of returns kept per LiDAR frame.
    """
    times = np.asarray(trace.times, np.float64)
    n = len(times)
    row = trace.row or {}
    ds = row.get("driving_score", trace.driving_score)
    plan = None
    if trace.plan_xy is not None:
        plan = [encode.flat_points(trace.plan_xy[k]) if trace.plan_valid[k] else [] for k in range(n)]
    map_id = str(trace.meta.get("map_id", trace.scenario_id))
    ep = {
        "id": trace.scenario_id, "policy": trace.policy, "status": str(row.get("status", "?")),
        "ds": None if ds is None or not np.isfinite(ds) else round(float(ds), 2),
        "ds_all": _score(row.get("driving_score_all")), "ds_at_fault": _score(row.get("driving_score_at_fault")),
        "rc": row.get("route_completion"), "behavior": trace.meta.get("behavior"),
        "split": trace.meta.get("split"), "map_id": map_id, "reproduced": bool(trace.reproduced),
        "dt": float(trace.dt), "t0": float(times[0]), "n": n,
        "route": encode.flat_points(trace.route_xy),
        "ego": {"l": round(float(trace.ego_size[0]), 2), "w": round(float(trace.ego_size[1]), 2),
                "x": encode.round_list(trace.ego_xy[:, 0]), "y": encode.round_list(trace.ego_xy[:, 1]),
                "yaw": encode.round_list(trace.ego_yaw, 3), "wp": plan},
        "agents": agents_payload(trace.agents),
        "signals": np.asarray(trace.signals, np.int64).T.tolist(),
        "metrics": metrics_payload(trace),
        "origin": [float(v) for v in getattr(trace, "origin", (0.0, 0.0))],
        "events": events_payload(trace.events, times, getattr(trace, "origin", (0.0, 0.0))),
        "bev": bev_payload(trace, _stride(trace.dt, bev_period_s)) if sensors else None,
        "lidar": lidar_payload(trace, _stride(trace.dt, lidar_period_s), lidar_max_points) if sensors else None,
        "sensors": sensor_panes(trace, _stride(trace.dt, bev_period_s), _stride(trace.dt, lidar_period_s),
                                lidar_max_points) if sensors else [],
    }
    return ep, map_id, map_payload(trace.map)
