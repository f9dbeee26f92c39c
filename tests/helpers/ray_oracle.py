"""Independent numpy / shapely oracle for the ray-casting sensors (test helper).

Scenes are drawn by ``scenes()`` (hypothesis): agent boxes with heights and
convex static obstacles around an ego at row 0. ``beam_oracle`` casts one 2-D
ray with shapely, sorts the faces it enters, keeps the nearest ``depth`` and
applies the documented height rule in numpy. ``ray_is_clean`` flags rays
where float32 and float64 may legitimately disagree (grazing a corner, two
faces at the same range, a beam grazing a top edge or the range limit).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from hypothesis import strategies as st
from shapely.geometry import LineString, MultiPoint, Point, Polygon

from drivee2e_jax.observe import raycast
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import Polylines

V = 6  # padded obstacle vertices


def f32(lo, hi):
    return st.floats(float(np.float32(lo)), float(np.float32(hi)), width=32)


def corners(xy, yaw, length, width):
    c, s = math.cos(yaw), math.sin(yaw)
    loc = np.array([[length / 2, -width / 2], [length / 2, width / 2], [-length / 2, width / 2], [-length / 2, -width / 2]])
    return loc @ np.array([[c, s], [-s, c]]) + np.asarray(xy, np.float64)


@st.composite
def scenes(draw, max_agents=6, max_obstacles=2, extent=40.0):
    """dict of float32 numpy arrays: row 0 is the ego."""
    n = draw(st.integers(1, max_agents))
    xy = [[draw(f32(-5, 5)), draw(f32(-5, 5))]]
    yaw = [draw(f32(-3.1, 3.1))]
    size = [[4.5, 1.9, 1.6]]
    cat = [0]
    for _ in range(n):
        xy.append([draw(f32(-extent, extent)), draw(f32(-extent, extent))])
        yaw.append(draw(f32(-3.1, 3.1)))
        size.append([draw(f32(0.5, 12)), draw(f32(0.5, 3)), draw(f32(0.3, 4))])
        cat.append(draw(st.integers(0, 7)))
    polys, heights = [], []
    for _ in range(draw(st.integers(0, max_obstacles))):
        cx, cy, r = draw(f32(-extent, extent)), draw(f32(-extent, extent)), draw(f32(1, 8))
        k = draw(st.integers(3, V))
        ang = sorted(draw(st.lists(f32(0, 6.28), min_size=k, max_size=k, unique=True)))
        pts = np.array([[cx + r * math.cos(a), cy + r * math.sin(a)] for a in ang], np.float32)
        hull = MultiPoint(pts).convex_hull
        if hull.geom_type != "Polygon" or hull.area < 0.5:
            continue
        polys.append(np.asarray(hull.exterior.coords, np.float32)[:-1])
        heights.append(draw(f32(0.5, 20)))
    return dict(xy=np.array(xy, np.float32), yaw=np.array(yaw, np.float32), size=np.array(size, np.float32),
                category=np.array(cat, np.int32), polys=polys, heights=np.array(heights, np.float32))


A_PAD, O_PAD = 8, 3  # fixed padded sizes: one compilation for every drawn scene


def jax_scene(sc, cfg=None, vel=None, valid=None):
    """The scene padded to A_PAD agents and O_PAD obstacles (ego = row 0); ``cfg``: a ``raycast.SceneConfig``."""
    cfg = raycast.SceneConfig() if cfg is None else cfg
    a = sc["xy"].shape[0]
    pad = max(A_PAD, a)

    def fill(x, n, dtype):
        out = np.zeros((n,) + x.shape[1:], dtype)
        out[: len(x)] = x
        return jnp.asarray(out)

    agents = AgentStates(xy=fill(sc["xy"], pad, np.float32), yaw=fill(sc["yaw"], pad, np.float32),
                         vel=fill(vel if vel is not None else np.zeros((a, 2)), pad, np.float32),
                         valid=fill(valid if valid is not None else np.ones(a, bool), pad, bool))
    size = np.ones((pad, 3), np.float32)
    size[:a] = sc["size"]
    o = max(O_PAD, len(sc["polys"]))
    pxy = np.zeros((o, V, 2), np.float32)
    pv = np.zeros((o, V), bool)
    for i, p in enumerate(sc["polys"]):
        pxy[i, : len(p)] = p
        pv[i, : len(p)] = True
    h = fill(np.asarray(sc["heights"], np.float32), o, np.float32)
    obs = Polylines(xy=jnp.asarray(pxy), point_valid=jnp.asarray(pv), valid=jnp.asarray(pv.any(1)))
    return raycast.select_scene(jnp.asarray(sc["xy"][0]), agents, jnp.asarray(size),
                                fill(sc["category"], pad, np.int32), obs, h, cfg, exclude=0)


def shapes(sc, skip_ego=True):
    """[(Polygon, top, code, agent_row)] in float64."""
    out = []
    for i in range(1 if skip_ego else 0, sc["xy"].shape[0]):
        length, w, h = (float(v) for v in sc["size"][i])
        out.append((Polygon(corners(sc["xy"][i], float(sc["yaw"][i]), length, w)), h, raycast.HIT_AGENT + int(sc["category"][i]), i))
    for p, h in zip(sc["polys"], sc["heights"]):
        out.append((Polygon(np.asarray(p, np.float64)), float(h), raycast.HIT_STATIC, -1))
    return out


def faces(origin, az, objs, max_range):
    """Sorted [(entry distance, top, code, row)] of the 2-D ray, and whether
    it is clean (no vertex within 2e-3 m of the ray, no near-equal ranges)."""
    d = np.array([math.cos(az), math.sin(az)])
    o = np.asarray(origin, np.float64)
    ray = LineString([o, o + (max_range + 5) * d])
    hits, clean = [], True
    for poly, top, code, row in objs:
        if poly.contains(Point(o)):
            continue
        for v in np.asarray(poly.exterior.coords):
            rel = v - o
            along = rel @ d
            if along > -1e-3 and abs(rel[0] * d[1] - rel[1] * d[0]) < 2e-3:
                clean = False
        inter = ray.intersection(poly.boundary)
        if inter.is_empty:
            continue
        hits.append((Point(o).distance(inter), top, code, row))
    hits.sort(key=lambda h: h[0])
    for a, b in zip(hits, hits[1:]):
        if b[0] - a[0] < 2e-3:
            clean = False
    return hits, clean


def beam(hits, tan, z0, max_range, depth):
    """(horizontal range or inf, code, row, clean) of one beam by the height rule."""
    slant = math.sqrt(1 + tan * tan)
    clean = True
    for r, top, code, row in hits[:depth]:
        if r >= max_range:
            break
        z = z0 + r * tan
        if abs(z) < 1e-3 or abs(z - top) < 1e-3 or abs(r * slant - max_range) < 1e-3:
            clean = False
        if 0 <= z <= top and r * slant <= max_range:
            return r, code, row, clean
    if tan < 0:
        rg = z0 / -tan
        if abs(rg * slant - max_range) < 1e-3:
            clean = False
        if rg * slant <= max_range:
            return rg, raycast.HIT_GROUND, -1, clean
    return math.inf, raycast.HIT_NONE, -1, clean


def clipped(sc, origin, spacing, cfg=None, z=None, need_spacing=None):
    """True if some object spans more rays than the window its rank gets.
    ``spacing``: the fan's mean ray spacing (sizes windows); ``need_spacing``:
    its smallest spacing (bounds how many rays an object covers)."""
    cfg = raycast.BufferConfig() if cfg is None else cfg
    cap = (z // 2 + 2) if z else 10**9
    need_spacing = need_spacing or spacing

    def span(pts):
        az = np.arctan2(pts[:, 1] - origin[1], pts[:, 0] - origin[0])
        dd = (az - az[0] + np.pi) % (2 * np.pi) - np.pi
        return (dd.max() - dd.min()) / need_spacing + 2

    def bad(needs, tiers):
        for rank, need in enumerate(sorted(needs, reverse=True)):
            win = max(min(cap, math.ceil(math.radians(deg) / spacing) + 1) for n, deg in tiers if n == 0 or rank < n)
            if need > win:
                return True
        return False

    boxes = [span(corners(sc["xy"][i], float(sc["yaw"][i]), *sc["size"][i][:2])) for i in range(1, len(sc["xy"]))]
    edges = [span(np.stack([p[j], p[(j + 1) % len(p)]]).astype(np.float64)) for p in sc["polys"] for j in range(len(p))]
    return bad(boxes, cfg.agent_tiers) or bad(edges, cfg.edge_tiers)
