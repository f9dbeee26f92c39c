"""`viz.player` without a browser: a single-file page whose embedded JSON
decodes back to the trace (oracle: the input arrays), and the streaming
writer's index page plus one file per episode."""

from __future__ import annotations

import base64
import gc
import io
import json
import re
import weakref

import numpy as np
import pytest

from drivee2e_jax.viz import encode
from drivee2e_jax.viz.payload import episode_payload, events_payload
from drivee2e_jax.viz.player import CALLBACK, PlayerWriter, files_dir, write_player
from tests.helpers.fake_traces import BEV_CH, T, fake_trace

_trace = fake_trace


def _document(path):
    page = path.read_text(encoding="utf-8")
    m = re.search(r'<script type="application/json" id="episode-data">(.*?)</script>', page, re.S)
    assert m, "no embedded episode data"
    return page, json.loads(m.group(1))


def _episodes(doc):
    """The single-file page's episode records in index order."""
    return [doc["episodes"][r["key"]] for r in doc["index"]]


def test_embedded_json_decodes_to_the_trace(tmp_path):
    tr, other = _trace(), _trace("s1")  # same map: stored once
    out = write_player([tr, other], tmp_path / "p.html", title="t <b>", lidar_max_points=100)
    page, doc = _document(out)
    assert page.startswith("<!doctype html>") and "<title>t &lt;b&gt;</title>" in page
    assert not re.search(r"(src|href)=\"https?:", page), "the page must not load anything from the network"
    assert doc["map_files"] == {"m0": "m0"} and list(doc["maps"]) == ["m0"] and doc["files"] is None
    assert [e["id"] for e in _episodes(doc)] == ["s0", "s1"]
    ep = _episodes(doc)[0]
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
    ep = _episodes(_document(out)[1])[0]
    bev, lidar = ep["bev"], ep["lidar"]
    assert bev["stride"] == 2 and bev["count"] == 11 and bev["channels"] == list(BEV_CH)
    sheet = np.asarray(Image.open(io.BytesIO(base64.b64decode(bev["sheet"].split(",", 1)[1]))).convert("RGB"))
    assert sheet.shape == (11 * 8, 8, 3) and (bev["h"], bev["w"]) == (8, 8)
    img = sheet[3 * 8: 4 * 8]  # frame 3 of the sprite sheet = instant 6
    np.testing.assert_array_equal(img, encode.composite_bev(np.stack([_trace().bev[c][6] for c in BEV_CH], -1),
                                                            list(BEV_CH)))
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
    assert _episodes(doc)[0]["id"] == evil and page.count("</script>") == 2
    assert _episodes(doc)[0]["bev"] is None and _episodes(doc)[0]["lidar"] is None
    with_sensors = write_player([_trace()], tmp_path / "q.html").stat().st_size
    assert out.stat().st_size < with_sensors < 200_000


def test_round_list_marks_invalid_and_non_finite():
    assert encode.round_list([1.234, np.inf, 3.0], 1) == [1.2, None, 3.0]
    assert encode.round_list([[1.0, 2.0], [3.0, 4.0]], 0, valid=[True, False]) == [[1, 2], [None, None]]
    assert encode.flat_points([[0.0, 1.0], [np.nan, 2.0], [3.0, 4.0]]) == [0.0, 1.0, 3.0, 4.0]


def _data_call(path):
    """(kind, key, record) of an episode / map file: one drivee2e_data(...) call."""
    text = path.read_text(encoding="utf-8")
    assert text.startswith(f"{CALLBACK}(") and text.rstrip().endswith(");")
    kind, key, record = json.loads("[" + text.strip()[len(CALLBACK) + 1:-2] + "]")
    return kind, key, record


def test_streaming_writer_writes_an_index_and_one_file_per_episode(tmp_path):
    out = tmp_path / "view" / "p.html"
    (tmp_path / "view" / "p_files" / "episodes").mkdir(parents=True)
    stale = tmp_path / "view" / "p_files" / "episodes" / "e00009.js"
    stale.write_text("old")
    w = PlayerWriter(out, title="t")
    runs = [("s0", "m0", "expert", "Perfect", 100.0), ("s1", "m1", "expert", "Failed", 20.0),
            ("s0", "m0", "stop", "Failed - TickRuntime", 4.0)]
    for sid, mid, pol, status, ds in runs:
        w.add(_trace(sid, mid, policy=pol, status=status, ds=ds,
                     events=[{"type": "collisions_vehicle", "t": 0.5, "x": 0.0, "y": 0.0}] * (ds < 50)))
    assert w.close() == out and files_dir(out) == tmp_path / "view" / "p_files"
    page, doc = _document(out)
    assert doc["files"] == "p_files/" and "episodes" not in doc and doc["map_files"] == {"m0": "m0", "m1": "m1"}
    assert [(r["key"], r["id"], r["policy"], r["status"], r["ds"]) for r in doc["index"]] == [
        ("e00000", "s0", "expert", "Perfect", 100.0), ("e00001", "s1", "expert", "Failed", 20.0),
        ("e00002", "s0", "stop", "Failed - TickRuntime", 4.0)]
    assert doc["index"][1]["infractions"] == {"collisions_vehicle": 1} and doc["index"][0]["infractions"] == {}
    assert doc["index"][0]["n"] == T and doc["index"][0]["map_id"] == "m0"
    names = sorted(p.name for p in (out.parent / "p_files" / "episodes").iterdir())
    assert names == ["e00000.js", "e00001.js", "e00002.js"], "one file per episode; stale files removed"
    assert sorted(p.name for p in (out.parent / "p_files" / "maps").iterdir()) == ["m0.js", "m1.js"]
    kind, key, ep = _data_call(out.parent / "p_files" / "episodes" / "e00002.js")
    assert (kind, key, ep["id"], ep["policy"], ep["n"]) == ("episode", "e00002", "s0", "stop", T)
    kind, key, m = _data_call(out.parent / "p_files" / "maps" / "m1.js")
    assert (kind, key) == ("map", "m1") and m["lanes"]
    assert len(page) < 60_000, "the page holds the index only, not the episodes"
    assert w.bytes_written == len(page.encode()) + sum(p.stat().st_size for p in (out.parent / "p_files").rglob("*.js"))


def test_writer_keeps_no_trace(tmp_path):
    """The writer drops each trace once written: with a counting fake
    source, at most the trace being added is alive at any time."""
    refs, held = [], []
    live = lambda: sum(r() is not None for r in refs)  # noqa: E731

    def source(n):
        for i in range(n):
            tr = _trace(f"s{i}")
            refs.append(weakref.ref(tr))
            yield tr
            del tr  # back here once the writer has added it: what is still alive, the writer holds
            gc.collect()
            held.append(live())

    w = PlayerWriter(tmp_path / "p.html")
    for _ in map(w.add, source(4)):
        pass
    w.close()
    assert held == [0, 0, 0, 0] and len(w.index) == 4


def test_strided_sensor_frames_map_to_their_instants(tmp_path):
    """A trace holding every 2nd instant's sensor frames (``sensor_stride``):
    BEV every 0.2 s keeps all of them, LiDAR every 0.5 s rounds up to 0.6 s."""
    full = _trace()
    tr = _trace()
    tr.sensor_stride = tr.lidar_stride = 2
    tr.bev = {c: v[::2] for c, v in tr.bev.items()}
    tr.lidar_points, tr.lidar_class, tr.lidar_valid = tr.lidar_points[::2], tr.lidar_class[::2], tr.lidar_valid[::2]
    ep = _episodes(_document(write_player([tr], tmp_path / "p.html", lidar_max_points=10_000))[1])[0]
    ref = _episodes(_document(write_player([full], tmp_path / "q.html", lidar_max_points=10_000))[1])[0]
    assert ep["bev"]["stride"] == 2 and ep["bev"]["sheet"] == ref["bev"]["sheet"]
    assert ep["lidar"]["stride"] == 6 and len(ep["lidar"]["frames"]) == 4  # instants 0, 6, 12, 18
    xy = np.frombuffer(base64.b64decode(ep["lidar"]["frames"][1]["xy"]), "<i2").reshape(-1, 2) * encode.LIDAR_SCALE
    np.testing.assert_allclose(np.sort(xy[:, 0]), np.sort(full.lidar_points[6, :, 0]), atol=0.006)


def test_bev_palette_is_the_composite_colours():
    names = ["drivable", "vehicle", "vehicle@-1", "nonsense"]
    pal = encode.bev_palette(names)
    assert pal.shape == (5, 3) and tuple(pal[0]) == (0, 0, 0)
    assert tuple(pal[2]) == encode.BEV_COLORS["vehicle"] and tuple(pal[4]) == (128, 128, 128)
    assert tuple(pal[3]) == tuple(int(c * 0.5 + 0.5) for c in encode.BEV_COLORS["vehicle"])


@pytest.mark.parametrize("num", [1, 7, 16, 24, 30])
def test_palette_index_from_packed_bits_is_the_last_lit_channel(num):
    """Oracle: ``bev_index`` of the unpacked planes (last lit channel wins);
    bits above ``num`` are ignored."""
    bits = np.random.default_rng(num).integers(0, 2**31 - 1, (3, 6, 5)).astype(np.int32)
    bits[0, 0, 0] = 0
    planes = [((bits >> i) & 1).astype(bool) for i in range(num)]
    index = encode.bev_index_from_bits(bits, num)
    np.testing.assert_array_equal(index, encode.bev_index(planes))
    assert index[0, 0, 0] == 0 and index.max() <= num


def test_ds_both_ways_and_collision_type_and_fault_in_the_payload(tmp_path):
    """The index row and the episode carry DS with all / at-fault collisions
    (from the stored row); collision events carry their nuPlan type and
    fault as stored plus the label the event list shows; older rows / events
    without them give null / no label. The page shows both (template)."""
    from drivee2e_jax.viz.payload import collision_label, episode_payload, index_entry

    events = [{"type": "collisions_vehicle", "t": 0.5, "x": 0.0, "y": 0.0, "collision_type": "active_rear",
               "at_fault": False},
              {"type": "collisions_layout", "t": 1.0, "x": 1.0, "y": 0.0, "collision_type": "static",
               "at_fault": True},
              {"type": "red_light", "t": 1.5, "x": 2.0, "y": 0.0}]
    tr = _trace(events=events, ds=60.0)
    tr.row.update(driving_score_all=60.0, driving_score_at_fault=100.0)
    ep, _, _ = episode_payload(tr, sensors=False)
    assert (ep["ds"], ep["ds_all"], ep["ds_at_fault"]) == (60.0, 60.0, 100.0)
    row = index_entry(ep, "e00000")
    assert (row["ds_all"], row["ds_at_fault"]) == (60.0, 100.0)
    assert [e.get("fault") for e in ep["events"]] == ["active_rear, not at fault", "static, at fault", None]
    assert ep["events"][0]["collision_type"] == "active_rear" and ep["events"][0]["at_fault"] is False
    assert collision_label({"type": "collisions_vehicle"}) is None
    old, _, _ = episode_payload(_trace(), sensors=False)
    assert (old["ds_all"], old["ds_at_fault"]) == (None, None)
    assert index_entry({k: v for k, v in old.items() if k not in ("ds_all", "ds_at_fault")}, "e0")["ds_all"] is None
    page = write_player([tr], tmp_path / "p.html").read_text(encoding="utf-8")
    assert 'data-key="ds_at_fault"' in page and "e.fault" in page


def test_events_are_drawn_in_the_local_frame_of_the_trace():
    """Stored events are world x, y (results folder); the player draws the trace's local
    positions, so the payload moves each event by minus the trace's origin and names the origin."""
    times = np.arange(5) * 0.1
    ev = [{"type": "collisions_vehicle", "t": 0.2, "x": 4000012.5, "y": 499990.25}, {"type": "timeout", "t": 0.4}]
    got = events_payload(ev, times, (4e6, 5e5))
    assert (got[0]["x"], got[0]["y"], got[0]["frame"]) == (12.5, -9.75, 2) and "x" not in got[1]
    tr = fake_trace(events=[])
    tr.origin = np.array([4e6, 5e5])
    assert episode_payload(tr, sensors=False)[0]["origin"] == [4e6, 5e5]
