"""The fast paths of ``raycast`` against the formulas they replace.

* ``polar_buffer`` tests each (object, ray) pair of the tier windows once
  (disjoint window segments), excludes each round's winners by their
  candidate index and gathers the winners' ranges from their candidate:
  compared with a brute-force numpy reference of the documented
  window rule (an object of rank r by ray count is tested on the
  ``W(r)`` rays from its first ray; per ray the D smallest packed keys), in
  crowded scenes where the windows really clip.
* ``beam_ranges`` hoists the per-(layer, ray) terms (``_layer_terms``):
  compared bit-for-bit with the per-beam rule written out on the raw buffer
  (a finite face whose height span holds the beam, nearest layer, else the
  ground).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from drivee2e_jax import geometry as geo
from drivee2e_jax.observe import raycast
from tests.helpers.ray_oracle import f32, jax_scene, scenes

Z = 72
_CFG = raycast.BufferConfig(depth=3, agent_tiers=((0, 10.0), (3, 40.0), (1, 180.0)),
                            edge_tiers=((0, 10.0), (2, 60.0)))


def _fan(z):
    return (2 * np.pi / z) * np.arange(z)


def _widths(tiers, n, spacing, z):
    """W(rank) of the window rule, (n,) ints."""
    cap = z // 2 + 2
    w = np.zeros(n, int)
    for num, deg in tiers:
        rows = n if num == 0 else min(num, n)
        w[:rows] = np.maximum(w[:rows], min(cap, math.ceil(math.radians(deg) / spacing) + 1))
    return w


def _reference(scene, origin, heading, cfg, z):
    """(keys (Z, D), ranges (Z, D)) by the window rule, numpy selection."""
    az = _fan(z).astype(np.float32)
    dirs = jnp.stack([jnp.cos(heading + az), jnp.sin(heading + az)], -1)
    k, e = scene.num_agents, scene.num_edges
    id_bits = max(1, (k + e - 1).bit_length())
    over_rays = lambda f: jax.vmap(f, (None, 0) + (None,) * (f.__code__.co_argcount - 2))
    box = jax.vmap(over_rays(geo.ray_box_distance), (None, None, 0, 0, 0))(origin, dirs, scene.agent_xy,
                                                                           scene.agent_yaw, scene.agent_lw)
    box = jnp.where(scene.agent_valid[:, None], box, jnp.inf)
    groups = []
    corners = jax.vmap(geo.box_corners)(scene.agent_xy, scene.agent_yaw, scene.agent_lw[:, 0], scene.agent_lw[:, 1])
    groups.append((corners, scene.agent_valid, cfg.agent_tiers, 0, box))
    if e:
        a, b = scene.edge_a, scene.edge_b
        seg = jax.vmap(over_rays(geo.ray_segment_distance), (None, None, 0, 0))(origin, dirs, a, b)
        facing = geo.cross2(b - a, origin - a) * scene.edge_orient < 0
        seg = jnp.where((scene.edge_valid & facing)[:, None], seg, jnp.inf)
        groups.append((jnp.stack([a, b], 1), scene.edge_valid, cfg.edge_tiers, k, seg))
    cands = [set() for _ in range(z)]  # per ray: (key, range)
    for points, valid, tiers, id0, dist in groups:
        n = points.shape[0]
        lo, span = jax.vmap(raycast._angular_extent, (0, None))(points - origin, heading)
        start, count = jax.vmap(raycast._first_ray, (0, 0, None, None))(lo, span, az, True)
        count = np.where(np.asarray(valid), np.asarray(count), -1)
        keys = np.asarray(raycast.pack_key(dist, (id0 + jnp.arange(n))[:, None], id_bits, 85.0))
        dist = np.asarray(dist)
        order = sorted(range(n), key=lambda i: (-count[i], i))
        width = _widths(tiers, n, 2 * np.pi / z, z)
        for rank, i in enumerate(order):
            for off in range(width[rank]):
                j = (int(start[i]) + off) % z
                if keys[i, j] != raycast.MISS:
                    cands[j].add((int(keys[i, j]), float(dist[i, j])))
    keys = np.full((z, cfg.depth), raycast.MISS, np.int64)
    rng = np.full((z, cfg.depth), np.inf)
    for j in range(z):
        for d, (key, r) in enumerate(sorted(cands[j])[: cfg.depth]):
            keys[j, d], rng[j, d] = key, r
    return keys, rng


@settings(max_examples=12, deadline=None)
@given(scenes(max_agents=8, max_obstacles=2, extent=12.0))  # crowded: windows clip
def test_polar_buffer_equals_window_rule(sc):
    scene = jax_scene(sc, raycast.SceneConfig(num_agents=8, num_obstacles=2))
    origin, heading = jnp.asarray(sc["xy"][0]), jnp.asarray(sc["yaw"][0])
    buf = jax.jit(lambda s, o, h: raycast.polar_buffer(s, o, h, _fan(Z), 85.0, _CFG))(scene, origin, heading)
    keys, rng = _reference(scene, origin, heading, _CFG, Z)
    k = scene.num_agents
    id_bits = max(1, (k + scene.num_edges - 1).bit_length())
    want_obj = np.where(keys != raycast.MISS, keys & ((1 << id_bits) - 1), -1)
    np.testing.assert_array_equal(np.asarray(buf.object), want_obj)
    # Same formulas, compiled differently (jit vs op by op): float32 rounding only.
    np.testing.assert_allclose(np.asarray(buf.range), rng, rtol=2e-5, atol=2e-5)


def test_window_segments_cover_each_rank_once():
    """The disjoint segments give rank r exactly offsets [0, W(r))."""
    for tiers in (((0, 10.0), (6, 45.0), (2, 180.0)), ((2, 10.0), (6, 45.0)), ((0, 30.0), (4, 10.0)), ((0, 10.0),)):
        for n in (1, 3, 8, 32):
            for z in (72, 360):
                got = np.zeros(n, int)
                for rows, lo, hi in raycast._segments(tiers, 2 * np.pi / z, z, True, n):
                    assert (got[:rows] == lo).all(), (tiers, n, z)
                    got[:rows] = hi
                np.testing.assert_array_equal(got, _widths(tiers, n, 2 * np.pi / z, z))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), f32(0.5, 3.0), st.sampled_from([85.0, 30.0]))
def test_beam_ranges_equal_layer_rule(seed, z0, max_range):
    rng = np.random.default_rng(seed)
    z, depth = 40, 3
    tan = np.tan(np.radians(np.linspace(-30, 10, 16)))[:, None]
    r = rng.uniform(0.2, 90, (z, depth)).astype(np.float32)
    r[rng.random((z, depth)) < 0.3] = np.inf
    r = np.sort(r, -1)
    top = rng.uniform(0, 5, (z, depth)).astype(np.float32)
    # Boundary cases: a top exactly at some beam's height, a face exactly
    # where a beam meets the ground.
    c = rng.integers(0, 16, z)
    rs = np.where(np.isfinite(r[:, 1]), r[:, 1], 0).astype(np.float32)
    top[:, 1] = np.where(rng.random(z) < 0.5, np.float32(z0) + rs * tan[c, 0].astype(np.float32), top[:, 1])
    zeros = jnp.zeros(r.shape, jnp.int32)
    buf = raycast.PolarBuffer(range=jnp.asarray(r), top=jnp.asarray(top), code=zeros, agent=zeros, object=zeros)
    got = np.asarray(jax.jit(lambda b: raycast.beam_ranges(b, tan, float(z0), max_range))(buf))

    def rule(b):
        t = np.asarray(tan, np.float64)
        slant = np.sqrt(1.0 + t * t)
        r_ground = z0 / np.where(t < 0, -t, 1.0)
        ground = np.where((t < 0) & (r_ground * slant <= max_range), r_ground * slant, max_range)
        t32, s32 = jnp.asarray(t, jnp.float32), jnp.asarray(slant, jnp.float32)
        out = jnp.broadcast_to(jnp.asarray(ground, jnp.float32), (t.shape[0], z))
        for d in reversed(range(depth)):  # the per-beam rule, straight from the buffer
            r, top = b.range[:, d], b.top[:, d]
            finite = jnp.isfinite(r)
            rsd = jnp.where(finite, r, 0.0)
            h = float(z0) + rsd * t32
            hit = finite & (h >= 0.0) & (h <= top) & (rsd * s32 <= max_range)
            out = jnp.where(hit, rsd * s32, out)
        return out

    want = np.asarray(jax.jit(rule)(buf))
    np.testing.assert_array_equal(got, want)
    assert (got < max_range).any()
