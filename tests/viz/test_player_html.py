"""`viz.player.write_player` without a browser: one valid, self-contained HTML
file whose embedded JSON decodes back to the trace (oracle: the input arrays)."""

from __future__ import annotations

import base64
import io
import json
import re

import numpy as np
import pytest

from drivee2e_jax.eval.traces import AgentsTrace, EpisodeTrace, StaticMap
from drivee2e_jax.viz import encode
from drivee2e_jax.viz.player import write_player

T, DT = 21, 0.1
BEV_CH = ("drivable", "route", "vehicle", "ego")


def _trace(sid="s0", map_id="m0", events=None, lidar_n=400):
    rng = np.random.default_rng(0)
    t = np.arange(T) * DT
    ego_xy = np.stack([-20 + 8 * t, np.full(T, -1.75)], 1)
    ag_xy = rng.normal(0, 10, (T, 2, 2))
    ag_valid = np.ones((T, 2), bool)
    ag_valid[:5, 1] = False
    ag_valid[12, 1] = False
    bev = {c: np.zeros((T, 8, 8), bool) for c in BEV_CH}
    bev["drivable"][:] = True
    bev["ego"][:, 6, 4] = True
    bev["vehicle"][:, 1, 1] = True
    bev["ego"][:, 1, 1] = True  # the later channel wins
    pts = rng.uniform(-40, 40, (T, lidar_n, 3)).astype(np.float32)
    smap = StaticMap(
        lanes=[np.array([[-60.0, -1.75], [60.0, -1.75]])], lane_type=np.zeros(1, int),
        lane_speed_limit=np.full(1, 13.9), boundaries=[np.array([[-60.0, 0.0], [60.0, 0.0]])],
        boundary_marking=np.array([1]), crosswalks=[np.array([[-8.0, -7], [-4, -7], [-4, 7], [-8, 7]])],
        stop_lines=np.array([[[-12.0, -3.5], [-12.0, 0.0]]]), stop_line_row=np.array([0]),
        stop_line_lane=np.array([0]), drivable=[np.array([[-60.0, -10], [60, -10], [60, 10], [-60, 10]])],
        obstacles=[], obstacle_height=np.zeros(0),
    )
    return EpisodeTrace(
        scenario_id=sid, policy="expert", meta={"map_id": map_id, "behavior": "STR", "split": "val"},
        row={"driving_score": 60.0, "route_completion": 100.0, "status": "Completed"},
        dt=DT, times=t, ego_size=np.array([4.5, 1.9, 1.5]), ego_xy=ego_xy, ego_yaw=np.zeros(T),
        ego_speed=np.full(T, 8.0), ego_accel=np.zeros(T), ego_steer=np.zeros(T), ego_yaw_rate=np.zeros(T),
        controls=np.tile([0.5, 0.0, 0.1], (T, 1)), plan_xy=ego_xy[:, None, :] + np.array([[[2.0, 0], [4, 0]]]),
        plan_valid=np.arange(T) < T - 1,
        agents=AgentsTrace(track_id=np.array([3, 12]), category=np.array([1, 6]),
                           size=np.array([[9.0, 2.5, 3.5], [0.6, 0.6, 1.7]]), xy=ag_xy,
                           yaw=rng.uniform(-3, 3, (T, 2)), vel=np.zeros((T, 2, 2)), valid=ag_valid),
        signals=np.r_[np.full(10, 3), np.full(11, 1)][:, None], map=smap, route_xy=ego_xy,
        route_arc=8 * t, route_command=np.full(T, 4), route_length=16.0,
        timeline={"speed": np.full(T, 8.0), "route_completion": np.linspace(0, 100, T),
                  "facts.front_distance": np.full(T, np.inf), "facts.lane_offset": np.zeros(T)},
        events=events if events is not None else [{"type": "red_light", "t": 1.5, "x": -8.0, "y": -1.75}],
        resim_events=[], driving_score=60.0, stored_driving_score=60.0, reproduced=True,
        bev=bev, bev_resolution=0.5, lidar_points=pts, lidar_class=np.full((T, lidar_n), 4, np.int8),
        lidar_valid=np.ones((T, lidar_n), bool),
    )


def _document(path):
    page = path.read_text(encoding="utf-8")
    m = re.search(r'<script type="application/json" id="episode-data">(.*?)</script>', page, re.S)
    assert m, "no embedded episode data"
    return page, json.loads(m.group(1))


def test_embedded_json_decodes_to_the_trace(tmp_path):
    tr, other = _trace(), _trace("s1")  # same map: stored once
    out = write_player([tr, other], tmp_path / "p.html", title="t <b>", lidar_max_points=100)
    page, doc = _document(out)
    assert page.startswith("<!doctype html>") and "<title>t &lt;b&gt;</title>" in page
    assert not re.search(r"(src|href)=\"https?:", page), "the page must not load anything from the network"
    assert list(doc["maps"]) == ["m0"] and [e["id"] for e in doc["episodes"]] == ["s0", "s1"]
    ep = doc["episodes"][0]
    assert ep["n"] == T and ep["ds"] == 60.0 and ep["status"] == "Completed"
    np.testing.assert_allclose(ep["ego"]["x"], np.round(tr.ego_xy[:, 0], 2))
    # agent 12 appears at frame 5 and is absent at frame 12
    ped = next(a for a in ep["agents"] if a["id"] == 12)
    assert ped["f0"] == 5 and ped["x"][12 - 5] is None and ped["cat"] == 6
    np.testing.assert_allclose(ped["y"][0], round(tr.agents.xy[5, 1, 1], 2))
    assert ep["signals"] == [[3] * 10 + [1] * 11]
    assert ep["ego"]["wp"][0] == pytest.approx([-18.0, -1.75, -16.0, -1.75]) and ep["ego"]["wp"][-1] == []
    assert ep["events"][0]["frame"] == 15
    metrics = {m["name"]: m["values"] for m in ep["metrics"]}
    assert metrics["speed"][0] == pytest.approx(8.0 * 3.6) and max(metrics["front_distance"]) == 50.0
    assert doc["meta"]["categories"][6] == "pedestrian" and doc["meta"]["hit_classes"][4] == "truck"


def test_bev_png_and_lidar_roundtrip(tmp_path):
    from PIL import Image

    out = write_player([_trace()], tmp_path / "p.html", bev_period_s=0.2, lidar_period_s=0.5, lidar_max_points=100)
    ep = _document(out)[1]["episodes"][0]
    bev, lidar = ep["bev"], ep["lidar"]
    assert bev["stride"] == 2 and len(bev["frames"]) == 11 and bev["channels"] == list(BEV_CH)
    img = np.asarray(Image.open(io.BytesIO(base64.b64decode(bev["frames"][3].split(",", 1)[1]))).convert("RGB"))
    assert img.shape == (8, 8, 3)
    assert tuple(img[6, 4]) == encode.BEV_COLORS["ego"] and tuple(img[1, 1]) == encode.BEV_COLORS["ego"]
    assert tuple(img[0, 0]) == encode.BEV_COLORS["drivable"]
    assert lidar["stride"] == 5 and len(lidar["frames"]) == 5
    fr = lidar["frames"][1]
    xy = np.frombuffer(base64.b64decode(fr["xy"]), "<i2").reshape(-1, 2) * lidar["scale"]
    cls = np.frombuffer(base64.b64decode(fr["c"]), np.uint8)
    assert len(xy) == len(cls) == 100 and set(cls) == {4}
    src = _trace().lidar_points[5, :, :2]
    dist = np.abs(xy[:, None, :] - src[None]).max(-1).min(1)  # every point is one of the frame's returns
    assert dist.max() <= 0.006


def test_script_breakout_is_escaped_and_no_sensors_is_small(tmp_path):
    evil = "</script><script>alert(1)</script>"
    out = write_player([_trace(sid=evil)], tmp_path / "p.html", title=evil, sensors=False)
    page, doc = _document(out)
    assert doc["episodes"][0]["id"] == evil and page.count("</script>") == 2
    assert doc["episodes"][0]["bev"] is None and doc["episodes"][0]["lidar"] is None
    with_sensors = write_player([_trace()], tmp_path / "q.html").stat().st_size
    assert out.stat().st_size < with_sensors < 200_000


def test_round_list_marks_invalid_and_non_finite():
    assert encode.round_list([1.234, np.inf, 3.0], 1) == [1.2, None, 3.0]
    assert encode.round_list([[1.0, 2.0], [3.0, 4.0]], 0, valid=[True, False]) == [[1, 2], [None, None]]
    assert encode.flat_points([[0.0, 1.0], [np.nan, 2.0], [3.0, 4.0]]) == [0.0, 1.0, 3.0, 4.0]
