"""BEV raster sensor: shapely oracles, frame convention, equivariance, signals,
soft-mode gradients and a real (tiny-suite) map.

Oracle tolerance: a BEV pixel may disagree with shapely containment of its
CENTRE only when an edge passes within (a) 0.02 m of that centre for boxes
drawn in-graph (float32 rounding), or (b) half a static-raster pixel diagonal
(0.25 m / sqrt(2) = 0.177 m) for static layers, since nearest-neighbour
resampling reads the fine raster pixel whose centre lies within that distance.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from shapely.geometry import Polygon

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.observe import bev as bevmod
from drivee2e_jax.observe.bev import BevConfig, pixel_centres, render_bev, unpack_bits
from drivee2e_jax.observe.raster import (
    Layer,
    layer_geometries,
    rasterize_map,
    rasterize_maps,
    stack_rasters,
    stop_line_geometries,
)
from drivee2e_jax.records import LaneRecord, MapRecord
from drivee2e_jax.types import Category, SignalState

CFG = BevConfig(height=64, width=64, resolution=0.5, num_agents=8)
EDGE_BOX = 0.02  # m
EDGE_STATIC = 0.25 * np.sqrt(0.5) + 1e-3  # m
A = 8  # agents per scene in these tests
P = 16  # route points


def _scene(**kw):
    """Default arrays for one scenario (nothing drawn but what is given)."""
    base = dict(
        ego_xy=jnp.zeros(2), ego_yaw=jnp.zeros(()), ego_lw=jnp.array([4.5, 1.9]),
        agents_xy=jnp.zeros((A, 2)), agents_yaw=jnp.zeros(A), agents_size=jnp.ones((A, 3)),
        agents_category=jnp.zeros(A, jnp.int32), agents_valid=jnp.zeros(A, bool),
        stop_state=jnp.zeros(4, jnp.int32), route_xy=jnp.zeros((P, 2)), route_valid=jnp.zeros(P, bool),
        map_index=jnp.zeros((), jnp.int32),
    )
    base.update({k: jnp.asarray(v) for k, v in kw.items()})
    return base


_RENDER = {}


def _render(table, cfg=CFG, **scene):
    """jit-cached render_bev (one compile per config/table shape)."""
    key = (cfg, table.words.shape, table.map_ids)
    if key not in _RENDER:
        _RENDER[key] = jax.jit(lambda t, s: render_bev(**s, table=t, cfg=cfg))
    return np.asarray(_RENDER[key](table, _scene(**scene)))


def _world_centres(cfg, ego_xy, ego_yaw):
    """(H, W, 2) float64 world positions of the BEV pixel centres."""
    loc = pixel_centres(cfg).astype(np.float64)
    c, s = np.cos(ego_yaw), np.sin(ego_yaw)
    return np.stack([ego_xy[0] + c * loc[..., 0] - s * loc[..., 1],
                     ego_xy[1] + s * loc[..., 0] + c * loc[..., 1]], -1)


def _box(xy, yaw, length, width):
    c, s = np.cos(yaw), np.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    loc = np.array([[hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw]])
    return Polygon(np.stack([xy[0] + c * loc[:, 0] - s * loc[:, 1], xy[1] + s * loc[:, 0] + c * loc[:, 1]], -1))


def _oracle(geoms, centres):
    """(inside (H, W) bool, distance to the nearest edge (H, W) m)."""
    geom = shapely.union_all(geoms) if geoms else shapely.Polygon()
    x, y = centres[..., 0], centres[..., 1]
    if geom.is_empty:
        return np.zeros(x.shape, bool), np.full(x.shape, np.inf)
    pts = shapely.points(x, y)
    return shapely.contains_xy(geom, x, y), shapely.distance(geom.boundary, pts)


def _check(channel, geoms, centres, tol):
    inside, edge = _oracle(geoms, centres)
    bad = (channel > 0.5) != inside
    assert not np.any(bad & (edge > tol)), (
        f"{int(np.sum(bad & (edge > tol)))} pixels disagree away from edges; first at "
        f"{np.argwhere(bad & (edge > tol))[:3].tolist()}")
    return inside


def _empty_table():
    m = MapRecord("empty", lanes=[LaneRecord(0, np.array([[1e3, 1e3], [1e3 + 1, 1e3]]))])
    return jax.device_put(rasterize_maps([m]))


EMPTY = _empty_table()


# --------------------------------------------------------------------------
# Frame convention
# --------------------------------------------------------------------------


def test_pixel_centres_convention():
    loc = pixel_centres(CFG)
    assert loc.shape == (64, 64, 2)
    assert loc[0, 0, 0] > loc[-1, 0, 0]  # row 0 farthest ahead
    assert loc[0, 0, 1] > loc[0, -1, 1]  # column 0 on the left
    u_e, v_e = CFG.ego_pixel
    assert (u_e, v_e) == (32.0, 48.0)  # centred, a quarter of the height from the bottom
    np.testing.assert_allclose(loc[48, 32], [-0.25, -0.25])
    np.testing.assert_allclose(loc[47, 31], [0.25, 0.25])


@settings(deadline=None, max_examples=25)
@given(x=st.floats(-500, 500), y=st.floats(-500, 500), yaw=st.floats(-np.pi, np.pi))
def test_agent_ahead_lands_above_and_agent_on_the_left_lands_left(x, y, yaw):
    ego = np.array([x, y])
    fwd, left = np.array([np.cos(yaw), np.sin(yaw)]), np.array([-np.sin(yaw), np.cos(yaw)])
    axy = np.zeros((A, 2))
    axy[0] = ego + 10.0 * fwd  # 10 m ahead
    axy[1] = ego + 8.0 * left  # 8 m to the left
    valid = np.zeros(A, bool)
    valid[:2] = True
    cat = np.full(A, int(Category.CAR))
    cat[1] = int(Category.PEDESTRIAN)
    size = np.tile([2.0, 1.0, 1.5], (A, 1))
    size[1, :2] = 1.0
    out = _render(EMPTY, ego_xy=ego, ego_yaw=yaw, agents_xy=axy, agents_yaw=np.full(A, yaw),
                  agents_size=size, agents_category=cat, agents_valid=valid)
    names = CFG.channel_names
    u_e, v_e = CFG.ego_pixel
    car = np.argwhere(out[..., names.index("vehicle")] > 0.5)
    ped = np.argwhere(out[..., names.index("pedestrian")] > 0.5)
    ego_px = np.argwhere(out[..., names.index("ego")] > 0.5)
    assert len(car) == 4 * 2 and len(ped) == 2 * 2 and len(ego_px) > 0  # 2x1 m car, 1x1 m "pedestrian"
    np.testing.assert_allclose(car.mean(0), [v_e - 20.5, u_e - 0.5])  # 10 m / 0.5 m = 20 rows up
    np.testing.assert_allclose(ped.mean(0), [v_e - 0.5, u_e - 16.5])  # 8 m / 0.5 m = 16 columns left
    np.testing.assert_allclose(ego_px.mean(0), [v_e - 0.5, u_e - 0.5])


# --------------------------------------------------------------------------
# Oracles
# --------------------------------------------------------------------------

_box_st = st.tuples(st.floats(-14, 14), st.floats(-14, 14), st.floats(-np.pi, np.pi),
                    st.floats(0.4, 12.0), st.floats(0.3, 3.0), st.sampled_from([0, 2, 4, 6, 7]))


@settings(deadline=None, max_examples=30)
@given(boxes=st.lists(_box_st, min_size=1, max_size=4), ex=st.floats(-300, 300), ey=st.floats(-300, 300),
       eyaw=st.floats(-np.pi, np.pi))
def test_agent_boxes_match_shapely_at_pixel_centres(boxes, ex, ey, eyaw):
    ego = np.array([ex, ey])
    rot = np.array([[np.cos(eyaw), -np.sin(eyaw)], [np.sin(eyaw), np.cos(eyaw)]])
    axy = np.zeros((A, 2))
    yaw, size, cat, valid = np.zeros(A), np.ones((A, 3)), np.zeros(A, int), np.zeros(A, bool)
    for i, (bx, by, byaw, length, width, c) in enumerate(boxes):
        axy[i] = ego + rot @ np.array([bx + 6.0, by])  # around the view centre (6 m ahead at 64 px)
        yaw[i], size[i, :2], cat[i], valid[i] = byaw, (length, width), c, True
    cfg = dataclasses.replace(CFG, agents_per_tile=4)
    out = _render(EMPTY, cfg, ego_xy=ego, ego_yaw=eyaw, agents_xy=axy, agents_yaw=yaw, agents_size=size,
                  agents_category=cat, agents_valid=valid)
    centres = _world_centres(cfg, ego, eyaw)
    names = cfg.channel_names
    groups = {"vehicle": [0, 2, 4], "pedestrian": [6], "cyclist": [7]}
    total = 0
    for name, cats in groups.items():
        geoms = [_box(axy[i], yaw[i], *size[i, :2]) for i in range(A) if valid[i] and cat[i] in cats]
        total += _check(out[..., names.index(name)], geoms, centres, EDGE_BOX).sum()
    # A box at least 1 m wide whose centre is in view always covers a pixel centre.
    assert total > 0 or all(min(b[3], b[4]) < 1.0 or b[0] < -7 for b in boxes)


def _star(rng, centre, n, r_lo, r_hi):
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(r_lo, r_hi, n)
    return np.stack([centre[0] + r * np.cos(ang), centre[1] + r * np.sin(ang)], -1)


@settings(deadline=None, max_examples=20)
@given(seed=st.integers(0, 2**31), eyaw=st.floats(-np.pi, np.pi), dx=st.floats(-8, 8), dy=st.floats(-8, 8))
def test_static_polygons_through_the_raster_match_shapely(seed, eyaw, dx, dy):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-50, 50, 2)
    area = _star(rng, centre, int(rng.integers(3, 12)), 3.0, 14.0)
    walk = _star(rng, centre + rng.uniform(-6, 6, 2), int(rng.integers(3, 8)), 1.0, 6.0)
    m = MapRecord("poly", lanes=[], drivable_areas=[area], crosswalks=[walk])
    table = jax.device_put(rasterize_maps([m], shape=(600, 600)))  # one shape: one compile
    ego = centre + np.array([dx, dy])
    out = _render(table, ego_xy=ego, ego_yaw=eyaw)
    centres = _world_centres(CFG, ego, eyaw)
    names = CFG.channel_names
    inside_area = _check(out[..., names.index("drivable")], [shapely.make_valid(Polygon(area))], centres,
                         EDGE_STATIC)
    _check(out[..., names.index("crosswalk")], [shapely.make_valid(Polygon(walk))], centres, EDGE_STATIC)
    # Not vacuous: where the polygon has room for a dozen pixels away from its
    # edges inside the view, they are checked.
    view = Polygon(centres[[0, 0, -1, -1], [0, -1, -1, 0]])
    core = shapely.make_valid(Polygon(area)).buffer(-EDGE_STATIC).intersection(view).area
    assert inside_area.sum() > 10 or core < 12 * CFG.resolution**2


def test_route_is_drawn_along_its_points():
    ego = np.array([5.0, -3.0])
    route = ego + np.stack([np.arange(P) * 1.0, 0.2 * np.arange(P)], -1)
    valid = np.arange(P) < 12
    out = _render(EMPTY, ego_xy=ego, route_xy=route, route_valid=valid)
    centres = _world_centres(CFG, ego, 0.0)
    w = CFG.route_width
    pts = route[::CFG.route_stride][valid[::CFG.route_stride]]  # the drawn points
    geoms = []
    for a, b in zip(pts[:-1], pts[1:]):
        d = b - a
        geoms.append(_box(0.5 * (a + b), np.arctan2(d[1], d[0]), np.hypot(*d) + w, w))
    inside = _check(out[..., CFG.channel_names.index("route")], geoms, centres, EDGE_BOX)
    assert inside.sum() > 30


# --------------------------------------------------------------------------
# Equivariance: ego + whole scene moved by one rigid transform
# --------------------------------------------------------------------------


def _moved_map(m: MapRecord, rot, shift) -> MapRecord:
    f = lambda p: np.asarray(p, float) @ rot.T + shift  # noqa: E731
    return dataclasses.replace(
        m, map_id=m.map_id + "_moved",
        lanes=[dataclasses.replace(lane, centerline=f(lane.centerline)) for lane in m.lanes],
        boundaries=[dataclasses.replace(b, points=f(b.points)) for b in m.boundaries],
        crosswalks=[f(c) for c in m.crosswalks],
        stop_lines=[dataclasses.replace(s, points=f(s.points)) for s in m.stop_lines],
        drivable_areas=[f(d) for d in m.drivable_areas],
        obstacles=[dataclasses.replace(o, polygon=f(o.polygon)) for o in m.obstacles])


@settings(deadline=None, max_examples=10, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(angle=st.floats(-np.pi, np.pi), tx=st.floats(-80, 80), ty=st.floats(-80, 80),
       ex=st.floats(-30, 30), eyaw=st.floats(-np.pi, np.pi))
def test_rigid_motion_of_ego_and_scene_leaves_the_bev_unchanged(tiny_suite, angle, tx, ty, ex, eyaw):
    m = tiny_suite.maps["m_cross"]
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    shift = np.array([tx, ty])
    moved = _moved_map(m, rot, shift)
    table = jax.device_put(rasterize_maps([m, moved], shape=(1400, 1400)))  # one shape: one compile
    rng = np.random.default_rng(0)
    ego = np.array([ex, -1.75])
    axy = ego + rng.uniform(-15, 15, (A, 2))
    ayaw = rng.uniform(-np.pi, np.pi, A)
    size = np.tile([4.5, 1.9, 1.5], (A, 1))
    route = ego + np.stack([np.arange(P), np.zeros(P)], -1)
    common = dict(agents_size=size, agents_category=np.arange(A) % 8, agents_valid=np.ones(A, bool),
                  stop_state=[1, 3, 2, 0], route_valid=np.ones(P, bool))
    a = _render(table, ego_xy=ego, ego_yaw=eyaw, agents_xy=axy, agents_yaw=ayaw, route_xy=route,
                map_index=0, **common)
    b = _render(table, ego_xy=rot @ ego + shift, ego_yaw=eyaw + angle, agents_xy=axy @ rot.T + shift,
                agents_yaw=ayaw + angle, route_xy=route @ rot.T + shift, map_index=1, **common)
    names = CFG.channel_names
    centres = _world_centres(CFG, ego, eyaw)  # in the ORIGINAL scene
    # Dynamic channels: exact up to float rounding at box edges.
    boxes = [_box(axy[i], ayaw[i], 4.5, 1.9) for i in range(A)]
    pts = route[::CFG.route_stride]
    segs = [_box(0.5 * (p + q), 0.0, np.hypot(*(q - p)) + CFG.route_width, CFG.route_width)
            for p, q in zip(pts[:-1], pts[1:])]
    _, edge_dyn = _oracle(boxes + segs, centres)
    for n in ("vehicle", "pedestrian", "cyclist", "route", "ego"):
        i = names.index(n)
        assert not np.any((a[..., i] != b[..., i]) & (edge_dyn > EDGE_BOX)), n
    # Static channels: each raster quantises its own (rotated) grid, so the two
    # may differ only where an edge passes within EDGE_STATIC of the pixel
    # centre in EITHER raster (2 x half-diagonal); count them honestly.
    geoms = layer_geometries(m)
    layers = {"drivable": Layer.DRIVABLE, "lane": Layer.LANE, "solid": Layer.SOLID, "dashed": Layer.DASHED,
              "crosswalk": Layer.CROSSWALK, "obstacle": Layer.OBSTACLE}
    differing = 0
    for n, layer in layers.items():
        i = names.index(n)
        _, edge = _oracle(geoms[layer], centres)
        diff = a[..., i] != b[..., i]
        assert not np.any(diff & (edge > 2 * EDGE_STATIC)), n
        differing += diff.sum()
    stops = stop_line_geometries(m)
    _, edge = _oracle(stops, centres)
    for n in ("stop_red", "stop_yellow", "stop_green"):
        i = names.index(n)
        assert not np.any((a[..., i] != b[..., i]) & (edge > 2 * EDGE_STATIC)), n
    # Near-edge disagreement stays a small fraction of the static pixels.
    assert differing <= 0.05 * a[..., :6].size


# --------------------------------------------------------------------------
# Stop lines follow the signal state
# --------------------------------------------------------------------------


@pytest.mark.parametrize("state", [SignalState.RED, SignalState.YELLOW, SignalState.GREEN, SignalState.UNKNOWN])
def test_stop_line_colour_follows_the_signal_state(tiny_suite, state):
    m = tiny_suite.maps["m_cross"]
    table = jax.device_put(rasterize_maps([m]))
    cfg = dataclasses.replace(CFG, channels=("stop_line", "stop_red", "stop_yellow", "stop_green"))
    ego = np.array([-20.0, -1.75])  # stop line 0 (x = -12) is 8 m ahead
    stop_state = [int(state), int(SignalState.RED), int(SignalState.GREEN)]
    out = _render(table, cfg, ego_xy=ego, ego_yaw=0.0, stop_state=stop_state)
    centres = _world_centres(cfg, ego, 0.0)
    lines = stop_line_geometries(m)
    _check(out[..., 0], lines, centres, EDGE_STATIC)  # every line, whatever its state
    drawn = out[..., 0] > 0.5
    near0 = shapely.distance(lines[0], shapely.points(centres[..., 0], centres[..., 1])) < 1.0
    line0 = drawn & near0
    assert line0.sum() >= 6  # 3.5 m line, 0.75 m wide at 0.5 m/px
    for k, colour in enumerate((SignalState.RED, SignalState.YELLOW, SignalState.GREEN), start=1):
        on = out[..., k][line0] > 0.5
        assert on.all() if state == colour else not on.any(), (state, colour)
    # line 1 (state RED) at (0..3.5, 12) is in view too and stays red.
    near1 = shapely.distance(lines[1], shapely.points(centres[..., 0], centres[..., 1])) < 1.0
    assert (out[..., 1][drawn & near1] > 0.5).all() and (out[..., 1][drawn & near1]).size >= 6


# --------------------------------------------------------------------------
# Soft mode, history frames, batching, the tiny suite map, errors
# --------------------------------------------------------------------------


def test_soft_mode_gradient_is_finite_and_nonzero():
    cfg = dataclasses.replace(CFG, soft=True, softness=0.2, channels=("vehicle", "pedestrian", "ego"))
    axy = np.zeros((A, 2))
    axy[0], axy[1] = [8.0, 1.0], [4.0, -6.0]
    valid = np.arange(A) < 2
    cat = np.where(np.arange(A) == 1, int(Category.PEDESTRIAN), int(Category.CAR))
    weights = jnp.asarray(np.random.default_rng(0).normal(size=(64, 64, 3)), jnp.float32)
    scene = _scene(agents_size=np.tile([4.5, 1.9, 1.5], (A, 1)), agents_category=cat, agents_valid=valid,
                   agents_yaw=np.full(A, 0.3))

    def loss(xy, yaw):
        s = {**scene, "agents_xy": xy, "agents_yaw": yaw}
        return jnp.sum(render_bev(**s, table=EMPTY, cfg=cfg) * weights)

    f = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))
    xy = jnp.asarray(axy, jnp.float32)
    yaw = scene["agents_yaw"]
    val, (gxy, gyaw) = f(xy, yaw)
    gxy, gyaw = np.asarray(gxy), np.asarray(gyaw)
    assert np.isfinite(gxy).all() and np.isfinite(gyaw).all()
    assert np.abs(gxy[:2]).min() > 0 and np.abs(gyaw[:2]).min() > 0
    assert np.all(gxy[2:] == 0)
    # The analytic derivative matches a central difference.
    eps = 1e-2
    dx = jnp.zeros_like(xy).at[0, 0].set(eps)
    fd = (f(xy + dx, yaw)[0] - f(xy - dx, yaw)[0]) / (2 * eps)
    assert float(fd) == pytest.approx(float(gxy[0, 0]), rel=0.05, abs=1e-2)
    # Soft occupancy is a smoothed version of the hard one.
    hard = _render(EMPTY, dataclasses.replace(cfg, soft=False), **{k: v for k, v in scene.items()
                                                                   if k != "agents_xy"}, agents_xy=axy)
    soft = np.asarray(jax.jit(lambda s: render_bev(**s, table=EMPTY, cfg=cfg))({**scene, "agents_xy": xy}))
    assert np.mean((soft > 0.5) == (hard > 0.5)) > 0.99


def test_history_frames_are_drawn_in_the_current_ego_frame():
    cfg = dataclasses.replace(CFG, history_frames=2, channels=("vehicle", "ego"))
    assert cfg.channel_names == ("vehicle", "ego", "vehicle@-1", "vehicle@-2")
    scene = _scene(agents_xy=np.tile([10.0, 0.0], (A, 1)), agents_size=np.tile([2.0, 1.0, 1.0], (A, 1)),
                   agents_valid=np.arange(A) == 0)
    hist_xy = np.tile(np.array([[[8.0, 0.0]], [[6.0, 0.0]]]), (1, A, 1))  # 1 and 2 frames back
    out = np.asarray(jax.jit(lambda s, h: render_bev(**s, table=EMPTY, cfg=cfg, history_xy=h,
                                                      history_yaw=jnp.zeros((2, A)),
                                                      history_valid=jnp.ones((2, A), bool)))(scene, hist_xy))
    assert out.shape == (64, 64, 4)
    _, v_e = cfg.ego_pixel
    for ch, ahead in ((0, 10.0), (2, 8.0), (3, 6.0)):
        rows = np.argwhere(out[..., ch] > 0.5)[:, 0]
        assert rows.mean() == pytest.approx(v_e - ahead / 0.5 - 0.5)
    # history agents use history_valid, not the current validity
    assert (out[..., 2] > 0.5).sum() == 8


def test_batched_over_maps_equals_one_at_a_time(tiny_suite):
    table = jax.device_put(rasterize_maps(tiny_suite.maps))
    assert table.map_ids == ("m_cross", "m_tee")
    idx = table.index_of(["m_tee", "m_cross"])
    np.testing.assert_array_equal(idx, [1, 0])
    scenes = [_scene(ego_xy=[0.0, -30.0], ego_yaw=np.pi / 2, map_index=idx[0]),
              _scene(ego_xy=[-30.0, -1.75], ego_yaw=0.0, map_index=idx[1])]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *scenes)
    out = np.asarray(jax.jit(jax.vmap(lambda s: render_bev(**s, table=table, cfg=CFG)))(batch))
    for b in range(2):
        one = _render(table, **{k: v for k, v in scenes[b].items()})
        np.testing.assert_array_equal(out[b], one)
    assert out[0, ..., 0].mean() > 0.1 and out[1, ..., 0].mean() > 0.1  # drivable area in view


def test_real_tiny_suite_scenario(tiny_suite):
    """s_straight at t = 0 through pack + replay: ego eastbound at (-40, -1.75)
    on lane 1; a 9 m truck 15 m behind; the crosswalk 28-32 m ahead; stop line
    0 (signal group 0: green) 28 m ahead."""
    from drivee2e_jax import replay
    from drivee2e_jax.scenario.pack import pack

    batch = pack(tiny_suite.scenarios[:1], tiny_suite.maps)
    scn = jax.tree_util.tree_map(lambda x: jnp.asarray(x[0]), batch.scenario)
    table = jax.device_put(rasterize_maps(tiny_suite.maps))
    cfg = BevConfig()  # the defaults: 128 x 128 at 0.5 m/px
    agents = replay.agents_at(scn.tracks, jnp.zeros(()), scn.dt_log)
    ego = int(scn.ego_index)
    valid = agents.valid & (jnp.arange(agents.valid.shape[0]) != ego)
    route_xy = scn.route.xy[:64]
    out = np.asarray(jax.jit(lambda: render_bev(
        ego_xy=agents.xy[ego], ego_yaw=agents.yaw[ego], ego_lw=scn.tracks.size[ego, :2],
        agents_xy=agents.xy, agents_yaw=agents.yaw, agents_size=scn.tracks.size,
        agents_category=scn.tracks.category, agents_valid=valid,
        stop_state=replay.signals_at(scn.signals, jnp.zeros(()), scn.dt_log),
        route_xy=route_xy, route_valid=scn.route.valid[:64],
        table=table, map_index=jnp.asarray(table.index_of([batch.meta.map_id[0]])[0]), cfg=cfg))())
    assert out.shape == (128, 128, len(DEFAULT := cfg.channel_names))
    ch = {n: out[..., i] > 0.5 for i, n in enumerate(DEFAULT)}
    u_e, v_e = cfg.ego_pixel
    r, c = int(v_e), int(u_e)  # the pixel just behind-right of the ego centre
    assert ch["drivable"][r, c] and ch["ego"][r, c] and ch["route"][r - 10, c]
    lane_cols = np.flatnonzero(ch["lane"][r - 5])
    assert np.any(np.abs(lane_cols + 0.5 - u_e) <= 1)  # lane 1's centreline under the ego
    walk_rows = np.flatnonzero(ch["crosswalk"][:, c])
    assert walk_rows.min() == pytest.approx(v_e - 32 / 0.5, abs=1) and walk_rows.max() == pytest.approx(
        v_e - 28 / 0.5, abs=1)
    green_rows = np.flatnonzero(ch["stop_green"][:, c - 2])
    assert len(green_rows) and abs(green_rows.mean() + 0.5 - (v_e - 28 / 0.5)) <= 1.5
    assert not ch["stop_red"][:, c - 2].any()
    truck = np.argwhere(ch["vehicle"])
    assert len(truck) and truck[:, 0].min() >= v_e + (15 - 4.5) / 0.5 - 1  # rows behind the ego
    assert not ch["pedestrian"].any()  # the pedestrian appears only from step 10


def test_raster_table_errors_and_out_of_map_reads(tiny_suite):
    table = rasterize_maps(tiny_suite.maps)
    with pytest.raises(DriveE2EError, match="nowhere"):
        table.index_of(["nowhere"])
    bad = MapRecord("bad", lanes=[], drivable_areas=[np.array([[0.0, 0.0], [1.0, 1.0]])])
    with pytest.raises(DriveE2EError, match="drivable_areas\\[0\\]"):
        rasterize_map(bad)
    with pytest.raises(DriveE2EError, match="too small"):
        stack_rasters([rasterize_map(tiny_suite.maps["m_tee"])], shape=(10, 10))
    with pytest.raises(DriveE2EError, match="resolution"):
        stack_rasters([rasterize_map(tiny_suite.maps["m_tee"]), rasterize_map(tiny_suite.maps["m_cross"], 0.5)])
    # Far outside every map: no static pixel at all.
    out = _render(jax.device_put(table), ego_xy=[5000.0, 5000.0], stop_state=[1, 1, 1, 1])
    assert out[..., :9].max() == 0
    r = rasterize_map(tiny_suite.maps["m_cross"])
    assert r.layer(Layer.DRIVABLE).mean() > 0.1 and r.stop_id.max() == 3


def test_config_validation():
    with pytest.raises(ValueError, match="channels"):
        BevConfig(channels=("drivable", "sky"))
    with pytest.raises(ValueError, match="tile"):
        BevConfig(height=100, tile=8)
    assert set(bevmod.DEFAULT_CHANNELS) <= set(bevmod.ALL_CHANNELS)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), num=st.integers(1, 31),
       cells=st.sampled_from([(1, 1), (2, 4), (4, 2), (8, 8), (16, 16)]))
def test_pool_bits_equals_unpacked_mean(seed, num, cells):
    from drivee2e_jax.observe.bev import pool_bits

    rng = np.random.default_rng(seed)
    # Dense and sparse words, every bit up to 31 set somewhere.
    words = rng.integers(0, 2**31, (16, 32), dtype=np.int64).astype(np.int32)
    words[rng.random((16, 32)) < 0.3] = 2**31 - 1
    ch, cw = cells
    got = np.asarray(pool_bits(jnp.asarray(words), num, ch, cw))
    img = np.asarray(unpack_bits(jnp.asarray(words), num))
    want = img.reshape(16 // ch, ch, 32 // cw, cw, num).mean(axis=(1, 3))
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_pool_bits_counts_a_full_cell():
    from drivee2e_jax.observe.bev import pool_bits

    words = jnp.full((256, 255), 2**31 - 1, jnp.int32)  # 65280 pixels, every bit: no field overflows
    np.testing.assert_array_equal(np.asarray(pool_bits(words, 31, 256, 255)), 1.0)
    with pytest.raises(ValueError, match="pool_bits"):
        pool_bits(words, 31, 7, 255)  # 7 rows do not tile 256
    with pytest.raises(ValueError, match="pool_bits"):
        pool_bits(words, 33, 256, 255)


def test_route_window_slices_around_the_route_index_and_clamps():
    from drivee2e_jax.observe.bev import route_window

    cfg = BevConfig(route_points=10, route_behind=3)
    xy = jnp.stack([jnp.arange(30.0), jnp.zeros(30)], -1)
    valid = jnp.arange(30) < 25
    # Starts on a multiple of route_stride (2).
    for index, first in [(0, 0), (2, 0), (3, 0), (12, 8), (13, 10), (25, 20), (29, 20)]:
        w_xy, w_valid = route_window(xy, valid, jnp.int32(index), cfg)
        np.testing.assert_array_equal(np.asarray(w_xy[:, 0]), np.arange(first, first + 10))
        np.testing.assert_array_equal(np.asarray(w_valid), np.arange(first, first + 10) < 25)
    whole = route_window(xy, valid, jnp.int32(7), BevConfig(route_points=0, route_behind=0))
    assert whole[0].shape == (30, 2)
    with pytest.raises(ValueError, match="route_points"):
        BevConfig(route_points=8, route_behind=8)


@settings(max_examples=10, deadline=None)
@given(index=st.integers(40, 150), yaw=st.floats(-3.1, 3.1))
def test_windowed_route_draws_the_same_image_as_the_whole_route(index, yaw):
    """A straight 1 m route: the default window (32 m behind, 64 m ahead of the
    ego's route point) covers everything of the route inside the 64 m view."""
    from drivee2e_jax.observe.bev import route_window

    cfg = BevConfig(height=64, width=64, resolution=1.0, channels=("route",))
    d = np.array([np.cos(yaw), np.sin(yaw)])
    route = (np.arange(200)[:, None] * d).astype(np.float32)
    valid = np.ones(200, bool)
    ego = route[index] + 0.3 * np.array([-d[1], d[0]])
    kw = {"ego_xy": ego, "ego_yaw": np.float32(yaw)}
    whole = _render(EMPTY, cfg, route_xy=route, route_valid=valid, **kw)
    w_xy, w_valid = route_window(jnp.asarray(route), jnp.asarray(valid), jnp.int32(index), cfg)
    win = _render(EMPTY, cfg, route_xy=np.asarray(w_xy), route_valid=np.asarray(w_valid), **kw)
    assert whole.sum() > 20
    np.testing.assert_array_equal(win, whole)


# --------------------------------------------------------------------------
# Hard-mode boxes: row spans -> bit masks
# --------------------------------------------------------------------------


@settings(deadline=None, max_examples=25)
@given(seed=st.integers(0, 2**31), axis_aligned=st.booleans())
def test_hard_boxes_draw_every_box_in_a_crowd_at_any_width(seed, axis_aligned):
    """A crowd (more boxes over one spot than ``agents_per_tile``) is drawn
    whole, boxes parallel to the image axes hit the closed-form spans' special
    case, and a width that is not a multiple of 32 splits the last bit word:
    every pixel still agrees with shapely away from edges."""
    rng = np.random.default_rng(seed)
    n = 12
    cfg = BevConfig(height=40, width=72, resolution=0.5, num_agents=n, agents_per_tile=1)
    xy = rng.uniform(-4.0, 4.0, (n, 2)) + np.array([3.0, 0.0])
    yaw = rng.choice([0.0, np.pi / 2, np.pi, -np.pi / 2], n) if axis_aligned else rng.uniform(-np.pi, np.pi, n)
    lw = np.stack([rng.uniform(0.5, 6.0, n), rng.uniform(0.3, 2.5, n)], -1)
    channel = rng.integers(-1, 3, n).astype(np.int32)  # -1: not drawn
    valid = rng.random(n) < 0.9
    draw = jax.jit(lambda *a: bevmod.draw_boxes(*a, num_channels=3, per_tile=1, cfg=cfg))
    out = np.asarray(draw(jnp.asarray(xy, jnp.float32), jnp.asarray(yaw, jnp.float32),
                          jnp.asarray(lw, jnp.float32), jnp.asarray(channel), jnp.asarray(valid)))
    assert out.shape == (40, 72, 3)
    centres = pixel_centres(cfg).astype(np.float64)  # ego at the origin: ego frame == world frame
    for c in range(3):
        geoms = [_box(xy[i], yaw[i], *lw[i]) for i in range(n) if valid[i] and channel[i] == c]
        _check(out[..., c], geoms, centres, EDGE_BOX)


def test_box_row_spans_are_empty_off_the_box_and_clipped_to_the_image():
    cfg = BevConfig(height=16, width=16, resolution=1.0, num_agents=2)
    # A box far left of the image and one covering all of it.
    xy = jnp.array([[0.0, 100.0], [0.0, 0.0]])
    first, last = bevmod.box_row_spans(xy, jnp.ones(2), jnp.zeros(2), jnp.array([[1.0, 1.0], [50.0, 50.0]]), cfg)
    first, last = np.asarray(first), np.asarray(last)
    # Box 0 covers no in-image column on any row (a span clipped to column -1 is off-image).
    assert np.all(np.maximum(first[0], 0) > np.minimum(last[0], cfg.width - 1))
    assert np.all(first[1] == -1) and np.all(last[1] == cfg.width)
