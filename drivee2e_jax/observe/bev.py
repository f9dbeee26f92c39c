"""Bird's-eye-view raster sensor, in-graph: one scenario, one step; callers vmap.

Frame convention (a top-down picture with the ego driving "up"):

* image row 0 is FARTHEST AHEAD, the last row is behind the ego;
* column 0 is on the ego's LEFT, the last column on its right;
* the ego reference point (box centre) sits at continuous image coordinates
  ``(u_e, v_e) = (W / 2, H - ego_from_bottom * H)`` (column, row; pixel
  ``(r, c)`` spans ``[c, c+1) x [r, r+1)``), i.e. horizontally centred and a
  quarter of the height above the bottom by default;
* pixel ``(r, c)``'s CENTRE is the ego-frame point (x forward, y left, m)
  ``x = (v_e - r - 0.5) * res``, ``y = (u_e - c - 0.5) * res``.

So with the defaults (128 x 128 at 0.5 m/px) the view covers 48 m ahead,
16 m behind and 32 m to each side.

What is drawn, per channel (``BevConfig.channels``, any order and subset):

* static layers, ``drivable lane solid dashed road_edge crosswalk obstacle``:
  the map's pre-rasterised world-frame layers (``observe.raster``) resampled
  through the ego's pose by NEAREST NEIGHBOUR (each BEV pixel centre reads the
  fine raster pixel it falls in: one uint16 gather per output pixel);
* stop lines, ``stop_red stop_yellow stop_green``: the stop-line pixels whose
  signal is currently in that state (one binary channel per colour, looked
  up from the per-pixel stop-line id); ``stop_line``: every stop line;
* ``route``: the route points ahead, drawn as ``route_width``-wide boxes along
  the segments between every ``route_stride``-th valid point;
* ``vehicle pedestrian cyclist``: the ``num_agents`` agents nearest to the
  view centre, as oriented boxes (vehicle = every ``Category`` except
  PEDESTRIAN and CYCLIST); ``ego``: the ego box.

Boxes (agents, route segments), hard mode: a pixel is occupied iff its
centre is inside the closed box. Each box is cut by every pixel ROW into the
interval of columns whose centres it contains (solved in closed form: two
slabs of a linear function of the column), turned into 32-column bit masks
and OR-ed over the boxes of each channel by one bitwise-OR reduction; the per-pixel
bit word is then one shift per channel. No box is ever tested against every
pixel, and nothing is dropped in crowds: the cost is ~ N boxes x H rows x
W / 32 words, plus H x W x channels for the final word (experiments/perf:
~70 CPU-us per scenario-step for 32 agents at 128 x 128, where a per-tile
candidate-list formulation cost ~260 and a per-agent-window scatter ~1 ms).

Soft mode (``BevConfig.soft``): occupancy ``sigmoid(-signed_distance /
softness)`` (signed distance to the box edge, positive outside, m),
differentiable w.r.t. box poses and sizes, evaluated per pixel through
per-TILE candidate lists: the image is cut into ``tile x tile`` pixel tiles,
each tile keeps the first ``per_tile`` boxes (nearest first) whose
axis-aligned extent overlaps it, and each pixel tests only those; soft tails
are cut ~3 softness beyond the box, and a tile touched by more than
``agents_per_tile`` agents drops the farther ones in that tile. The ego box
is tested densely (it is axis-aligned in its own frame).

Outputs: ``render_bev`` -> (H, W, C) float32; in hard mode every channel is
one bit of a per-pixel int32 word (``render_bev_packed`` -> (H, W) int32, 16x
smaller) and the float image is ``unpack_bits(word, C)``. Writing or reading
the float image costs more than rendering it on XLA:CPU (C floats a pixel),
so a policy that can take the packed word should (see experiments/perf/bev.py).

XLA:CPU notes (why the code looks the way it does): it runs gathers,
scatters, argmax and per-element concatenates one element at a time, and it
fuses producers into EVERY consumer element (``optimization_barrier`` is
stripped before fusion), so per-scenario values (cos/sin of a yaw, signal bit
sets) and per-pixel words are pinned with ``_materialize``; tile candidate
lists are built with a prefix-count matmul instead of top_k/argmax; outputs
are unpacked from bit words with one broadcast op.

History frames: ``draw_agents`` renders agents at any time in the CURRENT ego
frame; ``render_bev`` stacks ``history_frames`` of them after the channels.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import geometry
from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.observe.palette import composite_bev
from drivee2e_jax.observe.raster import Layer, RasterTable
from drivee2e_jax.observe.sensor_api import SensorBase, SensorContext
from drivee2e_jax.observe.xla_cpu import materialize
from drivee2e_jax.types import Category, SignalState

Array = jnp.ndarray

STATIC_CHANNELS = {"drivable": Layer.DRIVABLE, "lane": Layer.LANE, "solid": Layer.SOLID,
                   "dashed": Layer.DASHED, "road_edge": Layer.ROAD_EDGE, "crosswalk": Layer.CROSSWALK,
                   "obstacle": Layer.OBSTACLE}
STOP_CHANNELS = {"stop_line": None, "stop_red": SignalState.RED, "stop_yellow": SignalState.YELLOW,
                 "stop_green": SignalState.GREEN}
#: Agent channels, in the order ``draw_agents`` returns them.
AGENT_CHANNELS = ("vehicle", "pedestrian", "cyclist")
OTHER_CHANNELS = ("route", "ego")
ALL_CHANNELS = (*STATIC_CHANNELS, *STOP_CHANNELS, *AGENT_CHANNELS, *OTHER_CHANNELS)

DEFAULT_CHANNELS = ("drivable", "lane", "solid", "dashed", "crosswalk", "obstacle", "stop_red",
                    "stop_yellow", "stop_green", "route", "vehicle", "pedestrian", "cyclist", "ego")


@dataclasses.dataclass(frozen=True)
class BevConfig:
    """BEV raster configuration (static under jit).

    Attributes:
      height, width:   H, W output pixels.
      resolution:      m per output pixel.
      ego_from_bottom: ego centre's height above the image bottom, as a
                       fraction of H (0.25: a quarter of the image behind it).
      history_frames:  F past agent frames appended by ``render_bev`` (0: none).
      soft:            soft (differentiable) box occupancy instead of binary.
      softness:        m, the sigmoid's length scale in soft mode.
      channels:        output channel names (see the module docstring).
      num_agents:      K nearest agents drawn.
      route_width:     m, drawn width of the route.
      tile:            px, side of the square tiles boxes are binned into in
                       soft mode (must divide height and width).
      agents_per_tile: J, agents each tile tests at most (nearest first; soft mode).
      route_per_tile:  route segments each tile tests at most (soft mode).
      route_stride:    draw every ``route_stride``-th route point (segments of
                       2 m on the 1 m dense route: a chord off a 6 m radius
                       turn by < 0.1 m, and half the cost of 1 m segments).
      route_points:    in the rollout, draw only this window of route points
                       (0: the whole route) starting ``route_behind`` points
                       before the ego's route position: on the 1 m dense
                       route, 32 m behind to 64 m ahead (the view reaches 16 m
                       behind and 48 m ahead, 58 m to its far corners). The
                       tile candidate lists cost ~ segments^2 per tile: the
                       whole 208-point twin15 route drawn every step was 60 %
                       of the BEV's cost (docs/sensors.md).
      route_behind:    see ``route_points``.
    """

    height: int = 128
    width: int = 128
    resolution: float = 0.5
    ego_from_bottom: float = 0.25
    history_frames: int = 0
    soft: bool = False
    softness: float = 0.1
    channels: tuple[str, ...] = DEFAULT_CHANNELS
    num_agents: int = 32
    route_width: float = 1.0
    tile: int = 8
    agents_per_tile: int = 4
    route_per_tile: int = 4
    route_stride: int = 2
    route_points: int = 96
    route_behind: int = 32

    def __post_init__(self):
        for name in ("height", "width", "num_agents", "tile", "agents_per_tile", "route_per_tile", "route_stride"):
            if getattr(self, name) < 1:
                raise ValueError(f"BevConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.route_points < 0 or not 0 <= self.route_behind <= max(self.route_points - 1, 0):
            raise ValueError(f"BevConfig: route_points >= 0 and 0 <= route_behind < route_points, got "
                             f"{self.route_points}, {self.route_behind}")
        for name in ("resolution", "softness", "route_width"):
            if getattr(self, name) <= 0:
                raise ValueError(f"BevConfig.{name} must be > 0, got {getattr(self, name)}")
        if self.height % self.tile or self.width % self.tile:
            raise ValueError(f"BevConfig.tile ({self.tile} px) must divide height {self.height} and width {self.width}")
        if self.history_frames < 0:
            raise ValueError(f"BevConfig.history_frames must be >= 0, got {self.history_frames}")
        if not 0.0 <= self.ego_from_bottom <= 1.0:
            raise ValueError(f"BevConfig.ego_from_bottom must be in [0, 1], got {self.ego_from_bottom}")
        bad = [c for c in self.channels if c not in ALL_CHANNELS]
        if bad or len(set(self.channels)) != len(self.channels) or not self.channels:
            raise ValueError(f"BevConfig.channels: expected distinct names from {ALL_CHANNELS}, got {self.channels}")

    @property
    def ego_pixel(self) -> tuple[float, float]:
        """(u_e, v_e): the ego centre in continuous (column, row) image coordinates."""
        return 0.5 * self.width, self.height * (1.0 - self.ego_from_bottom)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """Names of the output channels, history ones as ``vehicle@-1`` (f frames back)."""
        hist = tuple(f"{c}@-{f}" for f in range(1, self.history_frames + 1)
                     for c in AGENT_CHANNELS if c in self.channels)
        return (*self.channels, *hist)


def _materialize(x: Array) -> Array:
    """``x``, computed once into a buffer (``xla_cpu.materialize``): e.g. a
    box's cos/sin would otherwise be re-evaluated for every (tile, box) or
    (pixel, box) pair."""
    return materialize(x)


# --------------------------------------------------------------------------
# Pixel <-> ego frame
# --------------------------------------------------------------------------


def pixel_centres(cfg: BevConfig) -> np.ndarray:
    """(H, W, 2) ego-frame (x forward, y left) pixel centres, m (host constant)."""
    u_e, v_e = cfg.ego_pixel
    r = np.arange(cfg.height, dtype=np.float64)[:, None]
    c = np.arange(cfg.width, dtype=np.float64)[None, :]
    x = np.broadcast_to((v_e - r - 0.5) * cfg.resolution, (cfg.height, cfg.width))
    y = np.broadcast_to((u_e - c - 0.5) * cfg.resolution, (cfg.height, cfg.width))
    return np.stack([x, y], -1).astype(np.float32)


def ego_to_pixel(xy_ego: Array, cfg: BevConfig) -> Array:
    """Ego-frame points ``(..., 2)`` (m) -> continuous (row, col) ``(..., 2)``;
    ``floor`` gives the pixel index."""
    u_e, v_e = cfg.ego_pixel
    return jnp.stack([v_e - xy_ego[..., 0] / cfg.resolution, u_e - xy_ego[..., 1] / cfg.resolution], -1)


# --------------------------------------------------------------------------
# Static layers
# --------------------------------------------------------------------------


def sample_static(ego_xy: Array, ego_yaw: Array, table: RasterTable, map_index: Array,
                  cfg: BevConfig) -> Array:
    """(H, W) int32 raster words (``bits | stop_id << 8``) under each BEV pixel.

    Nearest neighbour: the BEV pixel centre reads the fine raster pixel it lies
    in; outside the map's raster the word is 0 (nothing).

    Args:
      ego_xy: (2,) world position, m.  ego_yaw: () heading, rad.
      table: RasterTable with (M, Hm, Wm) words (unbatched under vmap: pass it
        with ``in_axes=None``).  map_index: () int32 row of this scenario's map.
    """
    centres = jnp.asarray(pixel_centres(cfg))
    c, s = _materialize(jnp.stack([jnp.cos(ego_yaw), jnp.sin(ego_yaw)]))
    origin = table.origin[map_index]
    # World point minus the raster origin, in raster pixels.
    off = (ego_xy - origin) / table.resolution
    px = off[0] + (c * centres[..., 0] - s * centres[..., 1]) / table.resolution
    py = off[1] + (s * centres[..., 0] + c * centres[..., 1]) / table.resolution
    ix = jnp.floor(px).astype(jnp.int32)
    iy = jnp.floor(py).astype(jnp.int32)
    h, w = table.shape[map_index, 0], table.shape[map_index, 1]
    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    hm, _ = table.raster_shape
    # Out-of-map reads go to the table's empty sentinel pixel (the last row is
    # padding, see ``stack_rasters``), so no per-pixel select follows the
    # gather (XLA:CPU would re-run the trig above for every output channel).
    # The words are stored in tiles (``raster.TILE``): the same pixel is read,
    # from fewer cache lines and pages than a row-major raster.
    flat = jnp.where(inside, table.flat_index(map_index, iy, ix), int(table.flat_index(0, hm - 1, 0)))
    flat = _materialize(flat)  # a vectorisable index loop, then a plain gather loop
    return table.words.reshape(-1).at[flat].get(mode="promise_in_bounds").astype(jnp.int32)


def _stop_channels(words: Array, stop_state: Array, names) -> dict[str, Array]:
    """Stop-line planes from the per-pixel stop id, without a per-pixel gather:
    each requested state becomes a bit set over stop lines (32 per uint32 word),
    and a pixel tests bit ``id - 1`` of it (elementwise shifts)."""
    sid = words >> 8
    bit = jnp.maximum(sid - 1, 0)
    num_words = max(1, -(-stop_state.shape[0] // 32))
    pad = jnp.full((num_words * 32 - stop_state.shape[0],), -1, jnp.int32)
    state = jnp.concatenate([stop_state.astype(jnp.int32), pad]).reshape(num_words, 32)
    weights = jnp.left_shift(jnp.uint32(1), jnp.arange(32, dtype=jnp.uint32))
    wanted = [STOP_CHANNELS[n] for n in names if STOP_CHANNELS[n] is not None]
    masks = {int(want): jnp.sum(jnp.where(state == int(want), weights, jnp.uint32(0)), axis=-1, dtype=jnp.uint32)
             for want in wanted}
    masks = {k: _materialize(v) for k, v in masks.items()}  # per scenario, not per pixel
    out = {}
    for name in names:
        want = STOP_CHANNELS[name]
        if want is None:
            out[name] = sid > 0
            continue
        mask = masks[int(want)]
        word = mask[0]
        for w in range(1, num_words):
            word = jnp.where(bit // 32 == w, mask[w], word)
        out[name] = (sid > 0) & (((word >> (bit % 32).astype(jnp.uint32)) & 1) > 0)
    return out


# --------------------------------------------------------------------------
# Boxes: row spans -> bit masks (hard), per-tile candidate lists (soft)
# --------------------------------------------------------------------------


def box_occupancy(d_xy: Array, cos: Array, sin: Array, half_lw: Array, soft: bool, softness: float) -> Array:
    """Occupancy of points at offsets ``d_xy (..., 2)`` (m, from the box centre)
    in a box of heading (cos, sin) and half length / width ``half_lw (..., 2)``
    (all broadcast). Hard: 1.0 iff inside the closed box. Soft:
    ``sigmoid(-signed_distance / softness)``, signed distance positive outside."""
    a = cos * d_xy[..., 0] + sin * d_xy[..., 1]
    b = -sin * d_xy[..., 0] + cos * d_xy[..., 1]
    qa, qb = jnp.abs(a) - half_lw[..., 0], jnp.abs(b) - half_lw[..., 1]
    if not soft:
        return ((qa <= 0) & (qb <= 0)).astype(jnp.float32)
    outside = geometry.safe_norm(jnp.stack([jnp.maximum(qa, 0.0), jnp.maximum(qb, 0.0)], -1))
    signed = outside + jnp.minimum(jnp.maximum(qa, qb), 0.0)
    return jax.nn.sigmoid(-signed / softness)


def box_row_spans(xy_ego: Array, cos: Array, sin: Array, half_lw: Array, cfg: BevConfig) -> tuple[Array, Array]:
    """(N, H) int32 first and last column whose pixel centre on each row lies
    in each box (empty: first > last; clipped to [-1, W]).

    On row r (ego-frame x fixed) the box test ``|a| <= hl, |b| <= hw`` is two
    slabs of the lateral offset: ``a = cos dx + sin dy``, ``b = -sin dx + cos dy``
    are linear in ``dy = y - box_y``, so the row's inside set is the
    intersection of two intervals of y, i.e. of columns. Boxes parallel to an
    image axis (sin or cos 0) use a 1e-6 stand-in, which moves only pixel
    centres exactly on an edge.

    Args:
      xy_ego: (N, 2) box centres, ego frame, m.  cos, sin: (N,) of the box
        heading in the ego frame.  half_lw: (N, 2) half length, half width, m.
    """
    u_e, v_e = cfg.ego_pixel
    res = cfg.resolution
    eps = 1e-6
    sn = jnp.where(sin >= 0, jnp.maximum(sin, eps), jnp.minimum(sin, -eps))
    cs = jnp.where(cos >= 0, jnp.maximum(cos, eps), jnp.minimum(cos, -eps))
    # Per-box values computed once (not per (box, row) pair; see _materialize).
    per = _materialize(jnp.stack([xy_ego[:, 0], xy_ego[:, 1], cos, sin, 1.0 / sn, 1.0 / cs,
                                  half_lw[:, 0], half_lw[:, 1]], -1))
    bx, by, c, s, inv_s, inv_c, hl, hw = (per[:, i, None] for i in range(8))
    dx = jnp.asarray(((v_e - np.arange(cfg.height) - 0.5) * res).astype(np.float32))[None, :] - bx  # (N, H)
    a0, b0 = c * dx, -s * dx
    t1, t2 = (-hl - a0) * inv_s, (hl - a0) * inv_s  # |a0 + sin dy| <= hl
    s1, s2 = (-hw - b0) * inv_c, (hw - b0) * inv_c  # |b0 + cos dy| <= hw
    y_lo = jnp.maximum(jnp.minimum(t1, t2), jnp.minimum(s1, s2)) + by
    y_hi = jnp.minimum(jnp.maximum(t1, t2), jnp.maximum(s1, s2)) + by
    # Column c's centre is at y = (u_e - c - 0.5) res.
    first = jnp.clip(jnp.ceil(u_e - 0.5 - y_hi / res), -1, cfg.width).astype(jnp.int32)
    last = jnp.clip(jnp.floor(u_e - 0.5 - y_lo / res), -1, cfg.width).astype(jnp.int32)
    return first, last


def span_masks(first: Array, last: Array, drawn: Array, width: int) -> Array:
    """(NW, N, H) uint32 32-column bit masks of row spans: bit b of word w is
    set iff column ``32 w + b`` is in ``[first, last]`` of that box and row
    and the box is ``drawn``; NW = ceil(width / 32).

    Args:
      first, last: (N, H) int32 column spans (``box_row_spans``; empty when
        first > last).  drawn: (N,) bool.  width: W, image columns.
    """
    words = -(-width // 32)
    base = jnp.asarray(np.arange(words) * 32, jnp.int32)[:, None, None]
    lo, hi = first - base, last - base + 1  # (NW, N, H): the span inside each word, [lo, hi)
    full = jnp.uint32(0xFFFFFFFF)

    def below(n):  # the n lowest bits set, n in any int range
        return jnp.where(n >= 32, full, jnp.left_shift(jnp.uint32(1), jnp.clip(n, 0, 31).astype(jnp.uint32))
                         - jnp.uint32(1))

    return jnp.where((hi <= 0) | (lo >= 32) | ~drawn[:, None], jnp.uint32(0), below(hi) & ~below(lo))


def _draw_boxes_bits(xy_ego: Array, yaw_ego: Array, lw: Array, channel: Array, valid: Array,
                     num_channels: int, cfg: BevConfig) -> Array:
    """Hard-mode ``draw_boxes``: (H, W) int32, bit c set iff the pixel centre
    is inside a valid box of channel c (row spans -> 32-column bit masks ->
    OR over boxes -> per-pixel word; see the module docstring)."""
    cos, sin = jnp.cos(yaw_ego), jnp.sin(yaw_ego)
    first, last = box_row_spans(xy_ego, cos, sin, 0.5 * lw, cfg)  # (N, H)
    drawn = valid & (channel >= 0) & (channel < num_channels)
    mask = _materialize(span_masks(first, last, drawn, cfg.width))  # (NW, N, H)
    words = mask.shape[0]
    of_channel = (channel[None, :] == jnp.arange(num_channels)[:, None])[:, None, :, None]  # (C, 1, N, 1)
    # One OR reduction over the boxes (a log-depth tree of elementwise ORs was
    # ~5x slower for 47 route boxes on XLA:CPU; experiments/perf/bev_boxes.py).
    planes = _materialize(jax.lax.reduce(jnp.where(of_channel, mask[None], jnp.uint32(0)), jnp.uint32(0),
                                         jax.lax.bitwise_or, (2,)))  # (C, NW, H)
    bit = jnp.arange(32, dtype=jnp.uint32)
    out = jnp.zeros((cfg.height, words, 32), jnp.int32)
    for ch in range(num_channels):  # (C, NW, H) -> per pixel bit ch
        out = out | (((planes[ch].T[:, :, None] >> bit) & 1).astype(jnp.int32) << ch)
    return out.reshape(cfg.height, words * 32)[:, : cfg.width]


def draw_boxes(xy_ego: Array, yaw_ego: Array, lw: Array, channel: Array, valid: Array,
               num_channels: int, per_tile: int, cfg: BevConfig, packed: bool = False) -> Array:
    """Draw N oriented boxes into an (H, W, num_channels) float32 canvas (max
    over overlapping boxes); with ``packed`` (hard mode only) an (H, W) int32
    whose bit c is channel c.

    Hard mode: exact pixel-centre containment of every valid box
    (``_draw_boxes_bits``). Soft mode: the image is cut into ``cfg.tile`` x
    ``cfg.tile`` pixel tiles; each tile keeps the first ``per_tile`` boxes (in
    input order: pass them nearest first) whose axis-aligned extent plus the
    soft tail overlaps it, and each pixel tests only its tile's boxes (a tile
    touched by more than ``per_tile`` boxes drops the later ones).

    Args:
      xy_ego: (N, 2) box centres in the EGO frame (x forward, y left), m.
      yaw_ego: (N,) headings relative to the ego, rad.  lw: (N, 2) length, width, m.
      channel: (N,) int32 canvas channel of each box (outside [0, num_channels): not drawn).
      valid: (N,) bool.  num_channels, per_tile: static ints (per_tile: soft mode).
    """
    if not cfg.soft:
        bits = _draw_boxes_bits(xy_ego, yaw_ego, lw, channel, valid, num_channels, cfg)
        return bits if packed else unpack_bits(bits, num_channels)
    t = cfg.tile
    ht, wt = cfg.height // t, cfg.width // t
    n = xy_ego.shape[0]
    cos, sin = _materialize(jnp.stack([jnp.cos(yaw_ego), jnp.sin(yaw_ego)]))
    half = 0.5 * lw
    tail = 3.0 * cfg.softness
    reach = 0.5 * t * cfg.resolution
    ext_x = jnp.abs(cos) * half[:, 0] + jnp.abs(sin) * half[:, 1] + tail + reach
    ext_y = jnp.abs(sin) * half[:, 0] + jnp.abs(cos) * half[:, 1] + tail + reach
    grid = pixel_centres(cfg)
    centres = jnp.asarray(grid.reshape(ht, t, wt, t, 2).mean(axis=(1, 3)).reshape(-1, 2))  # (T, 2)
    bx, by = xy_ego[:, 0], xy_ego[:, 1]
    onehot = jax.nn.one_hot(channel, num_channels, dtype=jnp.float32) * valid[:, None]  # (N, C)
    touch = ((jnp.abs(centres[:, 0, None] - bx) <= ext_x) & (jnp.abs(centres[:, 1, None] - by) <= ext_y)
             & (onehot.sum(-1) > 0)).astype(jnp.float32)  # (T, N)
    touch = _materialize(touch)
    # Rank of each touching box within its tile (1-based), by a prefix-count matmul.
    rank = touch @ jnp.asarray(np.triu(np.ones((n, n), np.float32)))
    j = min(per_tile, n)
    slot = (rank[:, None, :] == jnp.arange(1, j + 1, dtype=jnp.float32)[:, None]) & (touch[:, None, :] > 0)
    first = jnp.sum(jnp.where(slot, jnp.arange(n), 0), -1)  # (T, J) box index per tile slot
    has = jnp.any(slot, -1)
    params = jnp.concatenate([xy_ego, cos[:, None], sin[:, None], half, onehot], -1)  # (N, 6 + C)
    cand = _materialize(jnp.where(has[..., None], params[first], 0.0)).reshape(ht, 1, wt, 1, j, -1)
    pix = jnp.asarray(grid.reshape(ht, t, wt, t, 2))
    occ = [box_occupancy(pix - cand[..., k, 0:2], cand[..., k, 2], cand[..., k, 3], cand[..., k, 4:6],
                         cfg.soft, cfg.softness) for k in range(j)]  # J x (ht, t, wt, t)
    occ = list(_materialize(jnp.stack(occ)))
    planes = []
    for c in range(num_channels):
        plane = occ[0] * cand[..., 0, 6 + c]
        for k in range(1, j):
            plane = jnp.maximum(plane, occ[k] * cand[..., k, 6 + c])
        planes.append(plane.reshape(cfg.height, cfg.width))
    return jnp.stack(planes, -1)


def unpack_bits(bits: Array, num: int) -> Array:
    """(..., num) float32 bits 0..num-1 of the int32 ``bits (...)``. A single
    broadcast op: XLA:CPU emits a channel-by-channel ``stack`` as a slow
    per-element concatenate."""
    return ((bits[..., None] >> jnp.arange(num, dtype=jnp.int32)) & 1).astype(jnp.float32)


def pool_bits(bits: Array, num: int, cell_rows: int, cell_cols: int) -> Array:
    """(H / cell_rows, W / cell_cols, num) float32: the mean of channels
    0..num-1 over each cell of the bit-packed ``bits (H, W)`` int32 image,
    i.e. ``unpack_bits(bits, num)`` average-pooled, without unpacking.

    The fast path for a policy that pools the BEV (~17x cheaper on XLA:CPU
    than unpacking ``num`` floats a pixel): SWAR counting, 8 integer ops a
    pixel for up to 32 channels. ``(bits >> s) & 0x01010101`` holds channels
    s, s+8, s+16, s+24 in four 8-bit fields; summed along a cell row (<= 255
    pixels), split into 16-bit fields and summed over the cell's rows (<= 65535
    pixels a cell)."""
    h, w = bits.shape
    if h % cell_rows or w % cell_cols or cell_cols > 255 or cell_rows * cell_cols > 65535 or not 0 < num <= 32:
        raise ValueError(f"pool_bits: cells {cell_rows}x{cell_cols} must tile {h}x{w} (<= 255 columns, "
                         f"<= 65535 pixels) and 0 < num <= 32, got num={num}")
    x = bits.astype(jnp.uint32).reshape(h // cell_rows, cell_rows, w // cell_cols, cell_cols)
    shifts = jnp.arange(min(num, 8), dtype=jnp.uint32)
    fields = (x[..., None] >> shifts) & jnp.uint32(0x01010101)  # (h', r, w', c, S)
    rows = jnp.sum(fields, axis=3, dtype=jnp.uint32)  # 8-bit fields <= cell_cols
    even = jnp.sum(rows & jnp.uint32(0x00FF00FF), axis=1, dtype=jnp.uint32)  # channels s, s + 16
    odd = jnp.sum((rows >> 8) & jnp.uint32(0x00FF00FF), axis=1, dtype=jnp.uint32)  # channels s + 8, s + 24
    groups = [even & 0xFFFF, odd & 0xFFFF, even >> 16, odd >> 16][: -(-num // 8)]  # channel q * 8 + s
    counts = jnp.concatenate(groups, axis=-1)[..., :num]
    return counts.astype(jnp.float32) / float(cell_rows * cell_cols)


def _agent_channel(category: Array) -> Array:
    return jnp.where(category == Category.PEDESTRIAN, 1, jnp.where(category == Category.CYCLIST, 2, 0))


def draw_agents(ego_xy: Array, ego_yaw: Array, agents_xy: Array, agents_yaw: Array, agents_size: Array,
                agents_category: Array, agents_valid: Array, cfg: BevConfig, packed: bool = False) -> Array:
    """(H, W, 3) float32 [vehicle, pedestrian, cyclist] occupancy of the
    ``cfg.num_agents`` valid agents nearest to the view centre, drawn in the
    frame of the ego pose given (use the CURRENT ego pose for history frames).
    ``packed``: see ``draw_boxes``.

    Args:
      ego_xy: (2,) world, m.  ego_yaw: () rad.
      agents_xy: (A, 2) world box centres, m.  agents_yaw: (A,) rad.
      agents_size: (A, 2) or (A, 3) length, width[, height], m.
      agents_category: (A,) int32 ``Category``.  agents_valid: (A,) bool
        (mask the ego's own log row out, as the simulator does).
    """
    rel = geometry.to_frame(agents_xy, ego_xy, ego_yaw)
    u_e, v_e = cfg.ego_pixel
    view_centre = jnp.array([(v_e - 0.5 * cfg.height) * cfg.resolution, 0.0])
    dist = jnp.sum((rel - view_centre) ** 2, axis=-1)
    reach = 0.5 * math.hypot(cfg.height, cfg.width) * cfg.resolution + 0.5 * jnp.hypot(
        agents_size[:, 0], agents_size[:, 1])
    ok = agents_valid & (dist < reach**2)
    k = min(cfg.num_agents, agents_xy.shape[0])
    _, idx = jax.lax.top_k(-jnp.where(ok, jax.lax.stop_gradient(dist), jnp.inf), k)
    return draw_boxes(rel[idx], agents_yaw[idx] - ego_yaw, agents_size[idx, :2],
                      _agent_channel(agents_category[idx]), ok[idx], 3, cfg.agents_per_tile, cfg, packed)


def draw_route(ego_xy: Array, ego_yaw: Array, route_xy: Array, route_valid: Array, cfg: BevConfig,
               packed: bool = False) -> Array:
    """(H, W) float32 route: each segment between consecutive valid points
    (every ``cfg.route_stride``-th point) as a box ``cfg.route_width`` wide and
    ``route_width`` longer than the segment (so consecutive boxes overlap at
    the joints).

    Args:
      route_xy: (P, 2) world route points ahead of the ego, m.  route_valid: (P,) bool.
      packed: (hard mode) return (H, W) int32 0/1 instead.
    """
    centres, yaw, lw, valid = route_boxes(ego_xy, ego_yaw, route_xy, route_valid, cfg)
    out = draw_boxes(centres, yaw, lw, jnp.zeros(yaw.shape[0], jnp.int32), valid, 1, cfg.route_per_tile, cfg,
                     packed)
    return out if packed else out[..., 0]


def route_boxes(ego_xy: Array, ego_yaw: Array, route_xy: Array, route_valid: Array,
                cfg: BevConfig) -> tuple[Array, Array, Array, Array]:
    """The boxes ``draw_route`` draws, in the ego frame: (N, 2) centres (m),
    (N,) headings relative to the ego (rad), (N, 2) length and width (m) and
    (N,) valid, one per segment between consecutive ``cfg.route_stride``-th
    points (N = ceil(P / stride) - 1). Arguments as ``draw_route``."""
    rel = geometry.to_frame(route_xy[::cfg.route_stride], ego_xy, ego_yaw)
    route_valid = route_valid[::cfg.route_stride]
    a, b = rel[:-1], rel[1:]
    seg = b - a
    length = geometry.safe_norm(seg) + cfg.route_width
    lw = jnp.stack([length, jnp.full_like(length, cfg.route_width)], -1)
    yaw = jnp.arctan2(seg[:, 1], seg[:, 0])
    return 0.5 * (a + b), yaw, lw, route_valid[:-1] & route_valid[1:]


def route_window(route_xy: Array, route_valid: Array, route_index: Array, cfg: BevConfig) -> tuple[Array, Array]:
    """The ``cfg.route_points`` route points from ``cfg.route_behind`` before
    ``route_index`` (clamped to the route), as (N, 2) xy and (N,) valid; the
    whole route when ``route_points`` is 0 or covers it. ``route_index``: ()
    int32 the ego's progress point on the route. The window starts on a
    multiple of ``route_stride``, so it draws the same segments as the whole
    route does."""
    n = route_xy.shape[0]
    if cfg.route_points == 0 or cfg.route_points >= n:
        return route_xy, route_valid
    start = jnp.clip(route_index - cfg.route_behind, 0, n - cfg.route_points)
    start = start - start % cfg.route_stride
    return (jax.lax.dynamic_slice_in_dim(route_xy, start, cfg.route_points),
            jax.lax.dynamic_slice_in_dim(route_valid, start, cfg.route_points))


def draw_ego(ego_lw: Array, cfg: BevConfig) -> Array:
    """(H, W) float32 occupancy of the ego box (length, width ``ego_lw (2,)`` m),
    axis-aligned in its own frame, so tested densely (cheap)."""
    d = jnp.asarray(pixel_centres(cfg))
    return box_occupancy(d, jnp.ones(()), jnp.zeros(()), 0.5 * ego_lw[:2], cfg.soft, cfg.softness)


# --------------------------------------------------------------------------
# The sensor
# --------------------------------------------------------------------------


def _planes(ego_xy, ego_yaw, ego_lw, agents_xy, agents_yaw, agents_size, agents_category, agents_valid,
            stop_state, route_xy, route_valid, table, map_index, cfg, history_xy, history_yaw,
            history_valid) -> list[Array]:
    """The ``cfg.channel_names`` planes, (H, W) each: bool, or float32 for the
    boxes in soft mode."""
    names = cfg.channels
    packed = not cfg.soft
    planes: dict[str, Array] = {}
    if any(n in STATIC_CHANNELS or n in STOP_CHANNELS for n in names):
        words = _materialize(sample_static(ego_xy, ego_yaw, table, map_index, cfg))
        for n in names:
            if n in STATIC_CHANNELS:
                planes[n] = ((words >> int(STATIC_CHANNELS[n])) & 1) > 0
        planes.update(_stop_channels(words, stop_state, [n for n in names if n in STOP_CHANNELS]))

    def agent_planes(xy, yaw, valid):
        out = draw_agents(ego_xy, ego_yaw, xy, yaw, agents_size, agents_category, valid, cfg, packed)
        return [((out >> i) & 1) > 0 if packed else out[..., i] for i in range(len(AGENT_CHANNELS))]

    if any(n in AGENT_CHANNELS for n in names):
        planes.update(zip(AGENT_CHANNELS, agent_planes(agents_xy, agents_yaw, agents_valid)))
    if "route" in names:
        route = draw_route(ego_xy, ego_yaw, route_xy, route_valid, cfg, packed)
        planes["route"] = route > 0 if packed else route
    if "ego" in names:
        planes["ego"] = draw_ego(ego_lw, cfg) > 0.5 if packed else draw_ego(ego_lw, cfg)
    out = [planes[n] for n in names]
    if cfg.history_frames:
        if history_xy is None or history_yaw is None or history_valid is None:
            raise ValueError("render_bev: cfg.history_frames > 0 needs history_xy, history_yaw, history_valid")
        hist = [agent_planes(history_xy[f], history_yaw[f], history_valid[f]) for f in range(cfg.history_frames)]
        keep = [i for i, n in enumerate(AGENT_CHANNELS) if n in names]
        out += [hist[f][i] for f in range(cfg.history_frames) for i in keep]
    return out


def render_bev_packed(*, ego_xy: Array, ego_yaw: Array, ego_lw: Array, agents_xy: Array, agents_yaw: Array,
                      agents_size: Array, agents_category: Array, agents_valid: Array, stop_state: Array,
                      route_xy: Array, route_valid: Array, table: RasterTable, map_index: Array,
                      cfg: BevConfig, history_xy: Array | None = None, history_yaw: Array | None = None,
                      history_valid: Array | None = None) -> Array:
    """The hard-mode BEV bit-packed: (H, W) int32, bit i = channel
    ``cfg.channel_names[i]`` (at most 31 channels). 16x less memory than the
    float image; ``unpack_bits(packed, C)`` equals ``render_bev``. Arguments
    as ``render_bev``."""
    if cfg.soft or len(cfg.channel_names) > 31:
        raise ValueError(f"render_bev_packed: needs soft=False and <= 31 channels, got soft={cfg.soft}, "
                         f"{len(cfg.channel_names)} channels")
    planes = _planes(ego_xy, ego_yaw, ego_lw, agents_xy, agents_yaw, agents_size, agents_category,
                     agents_valid, stop_state, route_xy, route_valid, table, map_index, cfg, history_xy,
                     history_yaw, history_valid)
    return _materialize(sum(p.astype(jnp.int32) << i for i, p in enumerate(planes)))


def render_bev(*, ego_xy: Array, ego_yaw: Array, ego_lw: Array, agents_xy: Array, agents_yaw: Array,
               agents_size: Array, agents_category: Array, agents_valid: Array, stop_state: Array,
               route_xy: Array, route_valid: Array, table: RasterTable, map_index: Array, cfg: BevConfig,
               history_xy: Array | None = None, history_yaw: Array | None = None,
               history_valid: Array | None = None) -> Array:
    """The BEV of ONE scenario at one step: (H, W, C) float32 in [0, 1],
    channels ``cfg.channel_names`` (see the module docstring for the frame).

    Args:
      ego_xy: (2,) world ego centre, m.  ego_yaw: () rad.  ego_lw: (2,) ego length, width, m.
      agents_xy: (A, 2) world, m.  agents_yaw: (A,) rad.  agents_size: (A, 2|3) m
        (``Tracks.size``).  agents_category: (A,) int32.  agents_valid: (A,) bool
        (``replay.AgentStates`` with the ego row masked).
      stop_state: (S,) int32 current ``SignalState`` per stop line row.
      route_xy: (P, 2) world route points ahead, m.  route_valid: (P,) bool.
      table: RasterTable (M maps; unbatched).  map_index: () int32 table row.
      history_xy, history_yaw, history_valid: (F, A, 2), (F, A), (F, A): the
        agents 1..F frames back (row f-1 = f frames back); required iff
        ``cfg.history_frames`` = F > 0. Drawn in the CURRENT ego frame.
    """
    args = (ego_xy, ego_yaw, ego_lw, agents_xy, agents_yaw, agents_size, agents_category, agents_valid,
            stop_state, route_xy, route_valid, table, map_index, cfg, history_xy, history_yaw, history_valid)
    if not cfg.soft and len(cfg.channel_names) <= 31:
        # One bit per channel in a per-pixel word, unpacked by ONE broadcast op
        # (a channel-by-channel stack is a slow per-element concatenate on XLA:CPU).
        names = ("ego_xy", "ego_yaw", "ego_lw", "agents_xy", "agents_yaw", "agents_size", "agents_category",
                 "agents_valid", "stop_state", "route_xy", "route_valid", "table", "map_index", "cfg",
                 "history_xy", "history_yaw", "history_valid")
        return unpack_bits(render_bev_packed(**dict(zip(names, args))), len(cfg.channel_names))
    return jnp.stack([p.astype(jnp.float32) for p in _planes(*args)], axis=-1)


class BevSensor(SensorBase):
    """The BEV in the sensor registry (``observe.registry``).

    ``render(ctx, cfg)``: (H, W) int32 bit-packed hard-mode BEV
    (``render_bev_packed``; bit i = ``cfg.channel_names[i]``) of ``ctx``'s
    instant, the route cut to ``route_window`` around ``ctx.route_index``
    when given. Needs ``ctx.assets`` (the map rasters). ``image(frame, cfg)``:
    the ``observe.palette`` picture of one packed frame."""

    name = "bev"
    display = "image"
    needs_raster = True

    def default_config(self) -> BevConfig:
        return BevConfig()

    def render(self, ctx: SensorContext, cfg: BevConfig) -> Array:
        if ctx.assets is None:
            raise ValueError("SensorConfig.bev is on but no SensorAssets were given (observe.sensors.build_assets)")
        route_xy, route_valid = ctx.scenario.route.xy, ctx.scenario.route.valid
        if ctx.route_index is not None:
            route_xy, route_valid = route_window(route_xy, route_valid, ctx.route_index, cfg)
        return render_bev_packed(
            ego_xy=ctx.ego.xy, ego_yaw=ctx.ego.yaw, ego_lw=ctx.ego_lw, agents_xy=ctx.agents.xy,
            agents_yaw=ctx.agents.yaw, agents_size=ctx.size, agents_category=ctx.category,
            agents_valid=ctx.agents.valid, stop_state=ctx.stop_state, route_xy=route_xy, route_valid=route_valid,
            table=ctx.assets.raster, map_index=ctx.assets.map_index, cfg=cfg,
        )

    def image(self, frame, cfg: BevConfig) -> np.ndarray:
        names = cfg.channel_names
        return composite_bev(np.asarray(unpack_bits(jnp.asarray(frame), len(names))), names)


#: The BEV's registry entry.
SENSOR = BevSensor()


# --------------------------------------------------------------------------
# BEV sizes
# --------------------------------------------------------------------------


def bev_label(bev) -> str:
    """"HxW at R m/px" of an ``observe.bev.BevConfig``."""
    return f"{bev.height}x{bev.width} at {bev.resolution:g} m/px"


def bev_fits(rendered, wanted) -> bool:
    """Whether a model sized for the BEV ``wanted`` reads ``rendered``: the
    same BEV, or an integer multiple of its pixels covering the same ground
    (same extent, ego offset and channels), which it max-pools."""
    fh, fw = rendered.height // wanted.height, rendered.width // wanted.width
    return (fh >= 1 and fw >= 1 and rendered.height == fh * wanted.height and rendered.width == fw * wanted.width
            and abs(rendered.resolution * fh - wanted.resolution) <= 1e-6 * wanted.resolution
            and abs(rendered.resolution * fw - wanted.resolution) <= 1e-6 * wanted.resolution
            and rendered.ego_from_bottom == wanted.ego_from_bottom
            and tuple(rendered.channels) == tuple(wanted.channels))


def check_bev(rendered, model, source: str) -> None:
    """One-line DriveE2EError unless ``model`` (sized for ``model.bev``) can
    read the BEV ``rendered`` (``bev_fits``); models without a ``bev``
    attribute and ``rendered=None`` pass. ``source`` names where it came from."""
    wanted = getattr(model, "bev", None)
    if rendered is None or wanted is None or bev_fits(rendered, wanted):
        return
    raise DriveE2EError(
        f"{source}: BEV {bev_label(rendered)} does not fit model {model.name!r}, sized for {bev_label(wanted)} "
        f"(render that, or an integer multiple of it covering the same "
        f"{wanted.height * wanted.resolution:g} x {wanted.width * wanted.resolution:g} m)")
