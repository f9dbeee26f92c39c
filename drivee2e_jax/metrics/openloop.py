"""Open-loop planning metrics: L2 and collision rates of a predicted ego
trajectory against the logged one (``shared/reference/METRICS.md`` §5).

Pure JAX functions (numpy inputs work too) with fixed shapes. Symbols:

* ``N`` samples (planning queries), ``H`` future steps (default 6, ``STEP_S`` =
  0.5 s apart, the first at +0.5 s), ``A`` agents, ``F`` footprint cells.
* Leading ``...`` axes broadcast (e.g. a batch of scenarios).

Frames:

* project ego frame (``box_collisions``, the driver): x forward, y left, m;
* UniAD planning frame (the ``uniad_*`` and ``vad_*`` raster functions): the
  coordinates as UniAD's / VAD's ``PlanningMetric`` receives them, x lateral,
  y forward, m. UniAD's two x sign flips cancel, so x is used as passed in;
  ``ego_to_uniad`` maps a project ego-frame trajectory into it (x right = -y left).

Raster collision conventions (``raster_collisions(..., convention=)``), each
reading an occupancy grid in its own layout:

* ``"uniad"``: box row = trunc(y / 0.5 + r) (forward = increasing row), point
  row = trunc((y + 49.75) / 0.5);
* ``"vad"`` (VAD ``metric_stp3.PlanningMetric``): box row = trunc(200 -
  (y / 0.5 + r)) (forward = decreasing row, VAD's image frame), col as UniAD;
  point cell row = trunc((24.875 - y) / 0.5), col = trunc((24.875 + x) / 0.5):
  VAD halves the cell-centre offset, a ~25 m shift, so its ``obj_col`` is a
  documented quirk, not a meaningful metric (use ``obj_box_col``).

Conventions (METRICS.md §5):

* per-step L2 = ``sqrt(sum_xy((pred - gt)^2 * mask))``: a masked step gives 0
  and the sample still counts (UniAD); per-step values are averaged over the
  samples (``sample_mean``);
* UniAD reports the per-step value at step 2 / 4 / 6 for 1 / 2 / 3 s
  (``uniad_convention``); ST-P3 (and UniAD's "stp3" strategy) the mean of the
  per-step values over steps 1..2k (``stp3_convention``); VAD takes that mean
  per sample, then averages over the samples whose whole future is valid
  (``vad_l2``);
* collisions per step, a step where the GROUND-TRUTH trajectory's box
  collides adds 0 (the denominator is unchanged): rate = counts / samples.
"""

from __future__ import annotations

import math
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from drivee2e_jax import geometry
from drivee2e_jax.errors import DriveE2EError

Array = jnp.ndarray

#: Default horizon: 6 future steps 0.5 s apart (3 s).
HORIZON = 6
#: Spacing of the future steps, s.
STEP_S = 0.5
#: Reported horizons, s.
SECONDS = (1, 2, 3)

# UniAD's BEV raster: 200 x 200 cells of 0.5 m covering +-50 m; cell-centre
# offset bx = -49.75 m; the ego box 4.084 x 1.85 m, centre 0.5 m ahead of the
# trajectory point along the forward (y) axis.
BEV_SIZE = 200
BEV_RES = 0.5
BEV_BX = -49.75
UNIAD_EGO_LENGTH = 4.084
UNIAD_EGO_WIDTH = 1.85
UNIAD_EGO_OFFSET = 0.5
#: Raster collision conventions (``raster_collisions``).
RASTER_CONVENTIONS = ("uniad", "vad")
RasterConvention = Literal["uniad", "vad"]


# --------------------------------------------------------------------------
# Horizons and averaging
# --------------------------------------------------------------------------


def horizon_steps(seconds=SECONDS, step_s: float = STEP_S, horizon: int = HORIZON) -> tuple[int, ...]:
    """Number of future steps ``n_k = k / step_s`` covering each horizon ``k``
    (s) of ``seconds``: (2, 4, 6) by default. Static Python ints.

    Raises DriveE2EError when a horizon is not a whole number of steps or lies
    beyond ``horizon`` steps.
    """
    if not step_s > 0:
        raise DriveE2EError(f"open-loop step must be > 0 s, got {step_s}")
    out = []
    for k in seconds:
        n = int(round(k / step_s))
        if n < 1 or abs(n * step_s - k) > 1e-6 or n > horizon:
            raise DriveE2EError(
                f"open-loop horizon {k} s is not a whole number of {step_s} s steps within {horizon} steps"
            )
        out.append(n)
    return tuple(out)


def sample_mean(values: Array, sample_valid: Array | None = None) -> Array:
    """Per-step mean over the samples, as UniAD accumulates: the per-step sum
    over valid samples divided by the number of valid samples.

    Args:
      values: (..., N, H) per-sample per-step values (bool counts as 0/1).
      sample_valid: (..., N) bool, samples that count (None = all).

    Returns (..., H) float32; NaN where no sample is valid.
    """
    v = jnp.asarray(values).astype(jnp.float32)
    if sample_valid is None:
        sample_valid = jnp.ones(v.shape[:-1], bool)
    ok = jnp.asarray(sample_valid, bool)
    total = jnp.sum(jnp.where(ok[..., None], v, 0.0), axis=-2)
    n = jnp.sum(ok, axis=-1).astype(jnp.float32)[..., None]
    return jnp.where(n > 0, total / jnp.maximum(n, 1.0), jnp.nan)


def uniad_convention(per_step: Array, seconds=SECONDS, step_s: float = STEP_S) -> Array:
    """UniAD's ``planning_evaluation_strategy="uniad"``: the value at k s is the
    per-step value at step ``k / step_s`` (steps 2, 4, 6).

    Args: per_step (..., H). Returns (..., len(seconds)).
    """
    per_step = jnp.asarray(per_step)
    idx = horizon_steps(seconds, step_s, per_step.shape[-1])
    return jnp.stack([per_step[..., n - 1] for n in idx], axis=-1)


def stp3_convention(per_step: Array, seconds=SECONDS, step_s: float = STEP_S) -> Array:
    """ST-P3's convention (also VAD, UniAD ``"stp3"``): the value at k s is the
    mean of the per-step values over steps 1..k/step_s.

    Args: per_step (..., H). Returns (..., len(seconds)).
    """
    per_step = jnp.asarray(per_step)
    idx = horizon_steps(seconds, step_s, per_step.shape[-1])
    return jnp.stack([jnp.mean(per_step[..., :n], axis=-1) for n in idx], axis=-1)


# --------------------------------------------------------------------------
# L2
# --------------------------------------------------------------------------


def l2_per_step(pred: Array, gt: Array, mask: Array | None = None) -> Array:
    """UniAD's per-step L2 distance ``sqrt(sum_xy((pred - gt)^2 * mask))``, m.

    Args:
      pred, gt: (..., H, 2) (extra trailing columns such as yaw are ignored), m.
      mask: (..., H) or (..., H, 2) GT validity (bool or 0/1), None = all valid.
        A masked step gives 0; the sample itself still counts downstream.

    Returns (..., H) float32. The gradient at a zero distance is 0, not NaN.
    """
    d2 = (jnp.asarray(pred, jnp.float32)[..., :2] - jnp.asarray(gt, jnp.float32)[..., :2]) ** 2
    if mask is not None:
        m = jnp.asarray(mask).astype(jnp.float32)
        if m.ndim == d2.ndim - 1:
            m = m[..., None]
        d2 = d2 * m
    s = jnp.sum(d2, axis=-1)
    ok = s > 0
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, s, 1.0)), 0.0)


def l2_metrics(pred: Array, gt: Array, mask: Array | None = None, sample_valid: Array | None = None,
               seconds=SECONDS, step_s: float = STEP_S) -> dict[str, Array]:
    """L2 of N samples in both conventions.

    Args:
      pred, gt: (..., N, H, 2) m.  mask: (..., N, H) GT validity or None.
      sample_valid: (..., N) bool samples that count, or None.

    Returns dict ``per_step`` (..., H), ``uniad`` (..., 3), ``stp3`` (..., 3), m.
    """
    per_step = sample_mean(l2_per_step(pred, gt, mask), sample_valid)
    return {
        "per_step": per_step,
        "uniad": uniad_convention(per_step, seconds, step_s),
        "stp3": stp3_convention(per_step, seconds, step_s),
    }


def vad_l2(pred: Array, gt: Array, fut_valid: Array | None = None, seconds=SECONDS,
           step_s: float = STEP_S) -> Array:
    """VAD's planning L2 (``metric_stp3.compute_L2`` + the dataset's averaging):
    per sample, the mean L2 over steps 1..k/step_s; then the mean over the
    samples with ``fut_valid_flag`` (their whole future logged).

    Args:
      pred, gt: (..., N, H, 2) m.  fut_valid: (..., N) bool or None (all).

    Returns (..., len(seconds)) m; NaN when no sample is valid.
    """
    per = l2_per_step(pred, gt)  # (..., N, H), unmasked
    idx = horizon_steps(seconds, step_s, per.shape[-1])
    per_sample = jnp.stack([jnp.mean(per[..., :n], axis=-1) for n in idx], axis=-1)  # (..., N, K)
    return sample_mean(per_sample, fut_valid)


# --------------------------------------------------------------------------
# UniAD raster collision (obj_col / obj_box_col)
# --------------------------------------------------------------------------


def uniad_footprint(length: float = UNIAD_EGO_LENGTH, width: float = UNIAD_EGO_WIDTH,
                    offset: float = UNIAD_EGO_OFFSET, res: float = BEV_RES,
                    bx: float = BEV_BX) -> tuple[np.ndarray, np.ndarray]:
    """Raster cells of UniAD's ego box footprint (host-side, numpy int32).

    UniAD passes the rectangle with vertex rows ``(a - bx) / res``,
    a in {offset -+ length/2} (length along +y = forward) and vertex columns
    ``(b - bx) / res``, b = +-width/2, to ``skimage.draw.polygon``, which
    returns the cells whose centre lies inside. For an axis-aligned rectangle
    those are the integer rows / columns strictly between the edges (edges
    falling exactly on a cell centre do not occur for UniAD's values). The
    default gives 32 cells, rows 97..104 x cols 98..101.

    Returns (rows (F,), cols (F,)), row-major.
    """
    r0, r1 = sorted(((offset - length / 2 - bx) / res, (offset + length / 2 - bx) / res))
    c0, c1 = sorted(((-width / 2 - bx) / res, (width / 2 - bx) / res))
    rows = np.arange(math.floor(r0) + 1, math.ceil(r1))
    cols = np.arange(math.floor(c0) + 1, math.ceil(c1))
    rr, cc = np.meshgrid(rows, cols, indexing="ij")
    return rr.reshape(-1).astype(np.int32), cc.reshape(-1).astype(np.int32)


FOOTPRINT_ROWS, FOOTPRINT_COLS = uniad_footprint()


def ego_to_uniad(xy: Array) -> Array:
    """Project ego-frame points (..., 2) (x forward, y left) -> UniAD planning
    coordinates (x right, y forward), m."""
    xy = jnp.asarray(xy)
    return jnp.stack([-xy[..., 1], xy[..., 0]], axis=-1)


def _trunc_shift(q: Array, offset: Array) -> Array:
    """``trunc(q + offset)`` for float32 ``q`` and integer ``offset``, computed
    as UniAD does it (float32 q plus an int64 array in float64, then
    ``astype(int32)``): exact, no float32 rounding of the sum."""
    s_nonneg = q + offset >= 0  # sign of the exact sum (offset is small)
    return jnp.where(s_nonneg, jnp.floor(q) + offset, jnp.ceil(q) + offset).astype(jnp.int32)


def uniad_box_cells(traj: Array, rows: np.ndarray = FOOTPRINT_ROWS, cols: np.ndarray = FOOTPRINT_COLS,
                    res: float = BEV_RES, size: int = BEV_SIZE) -> tuple[Array, Array]:
    """Grid cells under UniAD's ego box at each trajectory point.

    ``row = trunc(y / res + r)``, ``col = trunc(x / res + c)`` for every
    footprint cell (r, c), then CLIPPED to [0, size - 1] (a far-away box lands
    on the border cells, as in UniAD).

    Args: traj (..., H, 2) UniAD coordinates, m.
    Returns (rows, cols), each (..., H, F) int32.
    """
    traj = jnp.asarray(traj, jnp.float32)
    qy = (traj[..., 1] / res)[..., None]
    qx = (traj[..., 0] / res)[..., None]
    r = _trunc_shift(qy, jnp.asarray(rows, jnp.float32))
    c = _trunc_shift(qx, jnp.asarray(cols, jnp.float32))
    return jnp.clip(r, 0, size - 1), jnp.clip(c, 0, size - 1)


def uniad_point_cells(traj: Array, res: float = BEV_RES, bx: float = BEV_BX,
                      size: int = BEV_SIZE) -> tuple[Array, Array, Array]:
    """The one grid cell under each trajectory point (UniAD's obj_col):
    ``row = trunc((y - bx) / res)``, ``col = trunc((x - bx) / res)`` in
    float32 (as torch computes it).

    Args: traj (..., H, 2) UniAD coordinates, m.
    Returns (rows, cols, inside), each (..., H); cells outside the grid have
    ``inside`` False (UniAD skips them) and indices clipped for safe gathers.
    """
    traj = jnp.asarray(traj, jnp.float32)
    r = jnp.trunc((traj[..., 1] - bx) / res).astype(jnp.int32)
    c = jnp.trunc((traj[..., 0] - bx) / res).astype(jnp.int32)
    inside = (r >= 0) & (r < size) & (c >= 0) & (c < size)
    return jnp.clip(r, 0, size - 1), jnp.clip(c, 0, size - 1), inside


def vad_box_cells(traj: Array, rows: np.ndarray = FOOTPRINT_ROWS, cols: np.ndarray = FOOTPRINT_COLS,
                  res: float = BEV_RES, size: int = BEV_SIZE) -> tuple[Array, Array]:
    """Grid cells under VAD's ego box at each trajectory point
    (``metric_stp3.PlanningMetric.evaluate_single_coll``).

    ``row = trunc(size - (y / res + r))`` (VAD's image rows: forward is up),
    ``col = trunc(x / res + c)`` for every footprint cell (r, c) (the same 32
    cells as UniAD), then CLIPPED to [0, size - 1]. Exact as VAD computes it
    (float32 y / 0.5, then the integer shift in float64).

    Args: traj (..., H, 2) UniAD / VAD coordinates (x lateral, y forward), m.
    Returns (rows, cols), each (..., H, F) int32.
    """
    traj = jnp.asarray(traj, jnp.float32)
    qy = (traj[..., 1] / res)[..., None]
    qx = (traj[..., 0] / res)[..., None]
    r = _trunc_shift(-qy, jnp.asarray(size - np.asarray(rows), jnp.float32))
    c = _trunc_shift(qx, jnp.asarray(cols, jnp.float32))
    return jnp.clip(r, 0, size - 1), jnp.clip(c, 0, size - 1)


def vad_point_cells(traj: Array, res: float = BEV_RES, bx: float = BEV_BX,
                    size: int = BEV_SIZE) -> tuple[Array, Array, Array]:
    """VAD's obj_col cell under each trajectory point (``evaluate_coll``):
    ``row = trunc((-bx / 2 - y) / res)``, ``col = trunc((-bx / 2 + x) / res)``
    in float32 (as torch computes it). The halved offset (24.875 m instead of
    49.75 m) puts the cell ~25 m off the point: a quirk kept for reproduction.

    Args: traj (..., H, 2) UniAD / VAD coordinates, m.
    Returns (rows, cols, inside), each (..., H); cells outside the grid have
    ``inside`` False (VAD skips them), indices clipped for safe gathers.
    """
    traj = jnp.asarray(traj, jnp.float32)
    half = jnp.float32(-bx / 2.0)
    r = jnp.trunc((half - traj[..., 1]) / jnp.float32(res)).astype(jnp.int32)
    c = jnp.trunc((half + traj[..., 0]) / jnp.float32(res)).astype(jnp.int32)
    inside = (r >= 0) & (r < size) & (c >= 0) & (c < size)
    return jnp.clip(r, 0, size - 1), jnp.clip(c, 0, size - 1), inside


def _raster_cells(convention: str):
    """(box-cell function, point-cell function) of a raster convention."""
    if convention == "uniad":
        return uniad_box_cells, uniad_point_cells
    if convention == "vad":
        return vad_box_cells, vad_point_cells
    raise DriveE2EError(f"open-loop raster convention must be one of {RASTER_CONVENTIONS}, got {convention!r}")


def raster_box_collisions(traj: Array, occupancy: Array, convention: RasterConvention = "uniad") -> Array:
    """obj_box_col facts: any occupied cell under the ego box footprint.

    Args:
      traj: (H, 2) UniAD / VAD coordinates, m.
      occupancy: (H, 200, 200) bool/0-1 occupancy of future step t, in the
        convention's raster layout.
      convention: "uniad" or "vad" (module docstring).

    Returns (H,) bool.
    """
    occupancy = jnp.asarray(occupancy)
    r, c = _raster_cells(convention)[0](traj)
    t = jnp.arange(r.shape[0])[:, None]
    return jnp.any(occupancy[t, r, c] > 0, axis=-1)


def raster_point_collisions(traj: Array, occupancy: Array, convention: RasterConvention = "uniad") -> Array:
    """obj_col facts: the one cell under the trajectory point is occupied
    (points outside the grid never collide).

    Args: traj (H, 2) m; occupancy (H, 200, 200); convention "uniad" / "vad".
    Returns (H,) bool.
    """
    occupancy = jnp.asarray(occupancy)
    r, c, inside = _raster_cells(convention)[1](traj)
    t = jnp.arange(r.shape[0])
    return inside & (occupancy[t, r, c] > 0)


def uniad_box_collisions(traj: Array, occupancy: Array) -> Array:
    """``raster_box_collisions`` with UniAD's raster."""
    return raster_box_collisions(traj, occupancy, "uniad")


def uniad_point_collisions(traj: Array, occupancy: Array) -> Array:
    """``raster_point_collisions`` with UniAD's raster."""
    return raster_point_collisions(traj, occupancy, "uniad")


def raster_collisions(pred: Array, gt: Array, occupancy: Array,
                      convention: RasterConvention = "uniad") -> dict[str, Array]:
    """UniAD's / VAD's per-sample collision facts with the GT exclusion applied.

    Args:
      pred, gt: (..., H, 2) UniAD / VAD coordinates, m.
      occupancy: (..., H, 200, 200) GT occupancy per future step, in the
        convention's raster layout.
      convention: "uniad" or "vad" (VAD's ``obj_col`` has the ~25 m quirk).

    Returns dict ``obj_col``, ``obj_box_col`` (..., H) bool: the prediction
    collides at that step AND the GT trajectory's box does not (a step where
    the GT box collides adds 0).
    """
    _raster_cells(convention)
    pred = jnp.asarray(pred, jnp.float32)
    gt = jnp.asarray(gt, jnp.float32)
    occupancy = jnp.asarray(occupancy)
    lead = pred.shape[:-2]
    h = pred.shape[-2]
    p = pred.reshape((-1, h, 2))
    g = jnp.broadcast_to(gt, pred.shape).reshape((-1, h, 2))
    occ = jnp.broadcast_to(occupancy, lead + occupancy.shape[-3:]).reshape((-1,) + occupancy.shape[-3:])
    box_fn = jax.vmap(lambda t, o: raster_box_collisions(t, o, convention))
    gt_box = box_fn(g, occ)
    box = box_fn(p, occ)
    point = jax.vmap(lambda t, o: raster_point_collisions(t, o, convention))(p, occ)
    return {
        "obj_col": (point & ~gt_box).reshape(lead + (h,)),
        "obj_box_col": (box & ~gt_box).reshape(lead + (h,)),
    }


def uniad_collisions(pred: Array, gt: Array, occupancy: Array) -> dict[str, Array]:
    """``raster_collisions`` with UniAD's raster."""
    return raster_collisions(pred, gt, occupancy, "uniad")


def raster_collision_rates(pred: Array, gt: Array, occupancy: Array, sample_valid: Array | None = None,
                           seconds=SECONDS, step_s: float = STEP_S,
                           convention: RasterConvention = "uniad") -> dict[str, dict[str, Array]]:
    """``PlanningMetric`` collision rates over N samples (UniAD's or VAD's raster).

    Args:
      pred, gt: (..., N, H, 2) UniAD / VAD coordinates, m.
      occupancy: (..., N, H, 200, 200) GT occupancy (the convention's layout).
      sample_valid: (..., N) bool or None (all samples count); VAD: its
        ``fut_valid_flag``.
      convention: "uniad" or "vad".

    Returns {"obj_col", "obj_box_col"} -> {"per_step" (..., H), "uniad"
    (..., 3), "stp3" (..., 3)}: per-step counts / number of samples. VAD
    reports "stp3" (its per-sample mean over steps 1..2k, averaged over the
    samples, is the same number).
    """
    facts = raster_collisions(pred, gt, occupancy, convention)
    out = {}
    for name, f in facts.items():
        per_step = sample_mean(f, sample_valid)
        out[name] = {
            "per_step": per_step,
            "uniad": uniad_convention(per_step, seconds, step_s),
            "stp3": stp3_convention(per_step, seconds, step_s),
        }
    return out


def uniad_collision_rates(pred: Array, gt: Array, occupancy: Array, sample_valid: Array | None = None,
                          seconds=SECONDS, step_s: float = STEP_S) -> dict[str, dict[str, Array]]:
    """UniAD's ``PlanningMetric`` collision rates (``raster_collision_rates``, UniAD raster)."""
    return raster_collision_rates(pred, gt, occupancy, sample_valid, seconds, step_s, "uniad")


# --------------------------------------------------------------------------
# Box-based open-loop collision (the project's default)
# --------------------------------------------------------------------------


def waypoint_headings(xy: Array, min_step: float = 0.05) -> Array:
    """Heading of the ego at each waypoint, rad, in the waypoints' frame.

    The heading at step k is the direction from point k-1 to point k (from the
    origin for k = 0). A step shorter than ``min_step`` m (a standing or
    creeping ego, whose direction is noise) keeps the previous heading; before
    any real motion the heading is 0 (the frame's +x, the ego's forward axis).

    Args: xy (..., H, 2), m. Returns (..., H).
    """
    xy = jnp.asarray(xy, jnp.float32)
    prev = jnp.concatenate([jnp.zeros_like(xy[..., :1, :]), xy[..., :-1, :]], axis=-2)
    d = xy - prev
    ok = jnp.sum(d * d, axis=-1) > min_step**2
    raw = jnp.arctan2(jnp.where(ok, d[..., 1], 0.0), jnp.where(ok, d[..., 0], 1.0))
    idx = jnp.arange(xy.shape[-2])
    last = jax.lax.cummax(jnp.where(ok, idx, -1), axis=ok.ndim - 1)
    held = jnp.take_along_axis(raw, jnp.maximum(last, 0), axis=-1)
    return jnp.where(last >= 0, held, 0.0)


def box_collisions(
    traj: Array,
    ego_lw: Array,
    agents_xy: Array,
    agents_yaw: Array,
    agents_lw: Array,
    agents_valid: Array,
    *,
    center_offset: float = 0.0,
    min_step: float = 0.05,
    eps: float = geometry.EPS,
) -> Array:
    """Whether the ego's oriented box at each waypoint overlaps an agent's box
    at that future time (``geometry.boxes_overlap``: shared interior deeper
    than ``eps`` m; touching does not count).

    The ego box (``ego_lw`` = length, width) is centred ``center_offset`` m
    ahead of the waypoint along its heading (``waypoint_headings``; 0 when
    the waypoint is the box centre, as in this simulator; UniAD uses 0.5).

    Args:
      traj: (H, 2) waypoints, m, in some frame (the ego frame at query time).
      ego_lw: (2,) m.
      agents_xy: (H, A, 2) agent box centres at each future step, same frame, m.
      agents_yaw: (H, A) agent headings in that frame, rad.
      agents_lw: (A, 2) agent length, width, m.
      agents_valid: (H, A) bool, the agent exists at that step.

    Returns (H,) bool.
    """
    traj = jnp.asarray(traj, jnp.float32)
    yaw = waypoint_headings(traj, min_step)
    centre = traj + center_offset * jnp.stack([jnp.cos(yaw), jnp.sin(yaw)], axis=-1)
    ego_lw = jnp.asarray(ego_lw, jnp.float32)

    def one_step(c, h, axy, ayaw, avalid):
        hit = jax.vmap(geometry.boxes_overlap, in_axes=(None, None, None, 0, 0, 0, None))(
            c, h, ego_lw, axy, ayaw, agents_lw, eps
        )
        return jnp.any(hit & avalid)

    return jax.vmap(one_step)(centre, yaw, agents_xy, agents_yaw, agents_valid)


def openloop_box_collisions(
    pred: Array,
    gt: Array,
    ego_lw: Array,
    agents_xy: Array,
    agents_yaw: Array,
    agents_lw: Array,
    agents_valid: Array,
    gt_mask: Array | None = None,
    **kwargs,
) -> tuple[Array, Array]:
    """Box-based collision facts of one sample with the reference's GT rule.

    The predicted and the GT trajectory are tested the same way
    (``box_collisions``), so a perfect prediction never counts.

    Args:
      pred, gt: (H, 2) m.  gt_mask: (H,) bool GT validity (an invalid GT step
        never counts as a GT collision), None = all valid.
      ego_lw, agents_*: as ``box_collisions``; kwargs passed on to it.

    Returns (counted (H,), gt_col (H,)) bool: ``counted`` = the prediction
    collides and the GT box does not (a GT-colliding step adds 0).
    """
    pred_col = box_collisions(pred, ego_lw, agents_xy, agents_yaw, agents_lw, agents_valid, **kwargs)
    gt_col = box_collisions(gt, ego_lw, agents_xy, agents_yaw, agents_lw, agents_valid, **kwargs)
    if gt_mask is not None:
        gt_col = gt_col & jnp.asarray(gt_mask, bool)
    return pred_col & ~gt_col, gt_col


def collision_rates(counted: Array, sample_valid: Array | None = None, seconds=SECONDS,
                    step_s: float = STEP_S) -> dict[str, Array]:
    """Collision rates from per-sample facts (``openloop_box_collisions``'s
    ``counted`` or ``uniad_collisions``'s): colliding samples per step divided
    by the number of samples.

    Args: counted (..., N, H) bool; sample_valid (..., N) bool or None.
    Returns dict ``per_step`` (..., H), ``uniad`` (..., 3), ``stp3`` (..., 3).
    """
    per_step = sample_mean(counted, sample_valid)
    return {
        "per_step": per_step,
        "uniad": uniad_convention(per_step, seconds, step_s),
        "stp3": stp3_convention(per_step, seconds, step_s),
    }
