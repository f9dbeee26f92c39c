"""Source tracks onto the log grid (see ``importers.common``): ``RawTrack``,
``resample``, ``resample_track``, ``convert_tracks``, ``TrackIds``, static
obstacles and category mapping."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from drivee2e_jax.polyline import wrap_angle
from drivee2e_jax.records import CATEGORIES, ObstacleRecord, TrackRecord
from drivee2e_jax.scenario.validate import MIN_BOX_SIZE_M

from .results import Skipped

__all__ = [
    "DEFAULT_MAX_GAP_S", "GRID_SNAP_S", "STATIC_MAX_MOTION_M", "VEHICLES", "DEFAULT_SIZES",
    "RawTrack", "Resampled", "resample", "resample_track", "box_polygon", "static_obstacle", "static_or_skip",
    "Converted", "convert_tracks", "TrackIds", "map_category",
]

#: Gaps between samples longer than this are not interpolated across, s
#: (1.5 steps of a 10 Hz source; 2 Hz sources pass their own value).
DEFAULT_MAX_GAP_S = 0.15
#: A grid time within this of a source sample counts as measured, not interpolated, s.
GRID_SNAP_S = 1e-3
#: A "static" object that moves more than this over the log stays a track, m.
STATIC_MAX_MOTION_M = 0.5
#: Categories that can be an ego / count as vehicles for COV.
VEHICLES = ("car", "truck", "bus", "van")
#: Default box (length, width, height) per category for sources without sizes, m.
DEFAULT_SIZES = {
    "car": (4.5, 1.9, 1.6), "truck": (8.0, 2.5, 3.5), "bus": (12.0, 2.6, 3.2), "van": (5.2, 2.0, 2.2),
    "motorcycle": (2.1, 0.8, 1.5), "tricycle": (2.8, 1.2, 1.6), "pedestrian": (0.6, 0.6, 1.75),
    "cyclist": (1.8, 0.7, 1.7),
}


def repaired_size(size, category: str) -> np.ndarray:
    """A source box size (3,) or per-sample (T, 3), m -> one (3,) box: the
    median over samples, with a length or width below ``MIN_BOX_SIZE_M`` (or
    not finite) replaced by the category's ``DEFAULT_SIZES`` entry (a
    non-finite height too), since validation refuses such boxes (they would
    never collide)."""
    size = np.asarray(size, np.float64)
    if size.ndim == 2:
        size = np.median(size, axis=0)
    size = size.reshape(3).copy()
    default = DEFAULT_SIZES.get(category, DEFAULT_SIZES["car"])
    if not (np.isfinite(size[:2]).all() and (size[:2] >= MIN_BOX_SIZE_M).all()):
        size[:2] = default[:2]
    if not np.isfinite(size[2]):
        size[2] = default[2]
    return size


@dataclass
class RawTrack:
    """A source track before resampling (see the module docstring)."""

    source_id: str
    category: str
    t: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    size: np.ndarray
    vel: np.ndarray | None = None
    visible: np.ndarray | None = None


@dataclass
class Resampled:
    """Grid samples of one series: steps (m,), values (m, d), gaps [(t0, t1)], interpolated (m,)."""

    k: np.ndarray
    values: np.ndarray
    gaps: list[tuple[float, float]]
    interpolated: np.ndarray

def resample(t: np.ndarray, values: np.ndarray, dt: float, num_steps: int, *,
             max_gap_s: float = DEFAULT_MAX_GAP_S, angles: Sequence[int] = ()) -> Resampled:
    """Linear interpolation of ``values`` (n, d) sampled at ``t`` (n,) s onto
    ``k * dt`` (0 <= k < num_steps), never across a gap > ``max_gap_s``.

    Duplicate timestamps keep their first sample. Columns in ``angles`` are
    interpolated along the shorter arc (unwrapped) and wrapped to (-pi, pi].
    """
    t = np.asarray(t, np.float64)
    v = np.asarray(values, np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if t.ndim != 1 or v.shape[0] != t.shape[0]:
        raise ValueError(f"resample: t {t.shape} and values {v.shape} disagree")
    order = np.argsort(t, kind="stable")
    t, v = t[order], v[order]
    keep = np.concatenate([[True], np.diff(t) > 1e-9]) if t.size else np.zeros(0, bool)
    t, v = t[keep], v[keep].copy()
    for c in angles:
        v[:, c] = np.unwrap(v[:, c])
    empty = Resampled(np.zeros(0, np.int64), np.zeros((0, v.shape[1])), [], np.zeros(0, bool))
    if t.size == 0:
        return empty
    grid = np.arange(num_steps) * dt
    inside = (grid >= t[0] - GRID_SNAP_S) & (grid <= t[-1] + GRID_SNAP_S)
    gaps = [(float(a), float(b)) for a, b in zip(t[:-1], t[1:]) if b - a > max_gap_s + 1e-9]
    for a, b in gaps:
        inside &= ~((grid > a + GRID_SNAP_S) & (grid < b - GRID_SNAP_S))
    k = np.nonzero(inside)[0]
    g = np.clip(grid[k], t[0], t[-1])
    out = np.stack([np.interp(g, t, v[:, c]) for c in range(v.shape[1])], axis=1) if k.size else empty.values
    for c in angles:
        out[:, c] = wrap_angle(out[:, c])
    near = np.abs(t[np.clip(np.searchsorted(t, g), 0, t.size - 1)] - g)
    near = np.minimum(near, np.abs(t[np.clip(np.searchsorted(t, g) - 1, 0, t.size - 1)] - g))
    return Resampled(k.astype(np.int64), out, gaps, near > GRID_SNAP_S)


def resample_track(raw: RawTrack, track_id: int, dt: float, num_steps: int, *,
                   max_gap_s: float = DEFAULT_MAX_GAP_S) -> tuple[TrackRecord | None, Resampled | None]:
    """``raw`` on the grid as a TrackRecord with id ``track_id``; (None, None) if nothing is covered."""
    cols = [raw.xy[:, 0], raw.xy[:, 1], raw.yaw]
    if raw.vel is not None:
        cols += [raw.vel[:, 0], raw.vel[:, 1]]
    if raw.visible is not None:
        cols.append(np.asarray(raw.visible, np.float64))
    r = resample(raw.t, np.stack(cols, axis=1), dt, num_steps, max_gap_s=max_gap_s, angles=(2,))
    if r.k.size == 0:
        return None, None
    size = repaired_size(raw.size, raw.category)
    v = r.values
    vel = v[:, 3:5].copy() if raw.vel is not None else None
    visible = (v[:, -1] > 0.5) if raw.visible is not None else None
    track = TrackRecord(track_id=int(track_id), category=raw.category, size=size.reshape(3), t=r.k * dt,
                        xy=v[:, 0:2].copy(), yaw=v[:, 2].copy(), vel=vel, visible=visible)
    return track, r


def box_polygon(xy: np.ndarray, yaw: float, length: float, width: float) -> np.ndarray:
    """The (4, 2) counter-clockwise footprint of a box centred at ``xy`` (2,) m."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = length / 2.0, width / 2.0
    local = np.array([[hl, -hw], [hl, hw], [-hl, hw], [-hl, -hw]])
    rot = np.array([[c, -s], [s, c]])
    return local @ rot.T + np.asarray(xy, np.float64)


def static_obstacle(raw: RawTrack, kind: str) -> ObstacleRecord | None:
    """A static object as a static obstacle at its median pose; None if it moves."""
    xy = np.asarray(raw.xy, np.float64)
    if xy.shape[0] == 0:
        return None
    centre = np.median(xy, axis=0)
    if np.max(np.linalg.norm(xy - centre, axis=1)) > STATIC_MAX_MOTION_M:
        return None
    size = np.asarray(raw.size, np.float64)
    size = np.median(size, axis=0) if size.ndim == 2 else size
    yaw = float(np.angle(np.mean(np.exp(1j * np.asarray(raw.yaw)))))
    length, width = max(float(size[0]), 0.1), max(float(size[1]), 0.1)
    return ObstacleRecord(polygon=box_polygon(centre, yaw, length, width), height=max(float(size[2]), 0.1), kind=kind)


def static_or_skip(raw: RawTrack, kind: str | None, skip: Skipped, what: str) -> ObstacleRecord | Skipped:
    """A track without an agent category as a static obstacle of ``kind``, or why not.

    ``skip`` is the category's own Skipped, returned when ``kind`` is None (no
    static kind for it); a track that moves gives a Skipped at ``skip.source``
    saying ``what`` (e.g. "category 'SIGN'") moves.
    """
    if kind is None:
        return skip
    ob = static_obstacle(raw, kind)
    if ob is not None:
        return ob
    return Skipped(skip.source, f"{what} moves; no agent category for it")


@dataclass
class Converted:
    """Tracks on the grid: records, their ids, what was skipped, how many had gaps,
    and the fraction of written samples that are interpolated (not measured)."""

    tracks: list[TrackRecord]
    ids: TrackIds
    skipped: list[Skipped]
    gap_tracks: int
    interpolated_fraction: float


def convert_tracks(raws: Sequence[RawTrack], ego_source: str | None, dt: float, num_steps: int, source: str, *,
                   max_gap_s: float = DEFAULT_MAX_GAP_S) -> Converted:
    """Resample every raw track onto the grid (see ``resample_track``)."""
    ids = TrackIds([r.source_id for r in raws], ego_source)
    tracks, skipped, gap_tracks, interp, total = [], [], 0, 0, 0
    for raw in raws:
        if len(raw.t) == 0:
            skipped.append(Skipped(f"{source} track {raw.source_id}", "empty track (no samples)"))
            continue
        tr, r = resample_track(raw, ids[raw.source_id], dt, num_steps, max_gap_s=max_gap_s)
        if tr is None:
            skipped.append(Skipped(f"{source} track {raw.source_id}",
                                   f"no sample on the {dt:g} s grid within 0..{(num_steps - 1) * dt:g} s"))
            continue
        gap_tracks += bool(r.gaps)
        interp += int(r.interpolated.sum())
        total += len(r.k)
        tracks.append(tr)
    return Converted(tracks, ids, skipped, gap_tracks, interp / total if total else 0.0)


class TrackIds:
    """Deterministic integer ids: the ego is 0, the others 1.. in sorted source-id order."""

    def __init__(self, source_ids: Sequence[str], ego: str | None):
        others = sorted(s for s in set(source_ids) if s != ego)
        self._ids = {s: i + 1 for i, s in enumerate(others)}
        if ego is not None:
            self._ids[ego] = 0

    def __getitem__(self, source_id: str) -> int:
        return self._ids[source_id]

    def table(self) -> dict[int, str]:
        return {i: s for s, i in sorted(self._ids.items(), key=lambda x: x[1])}


def map_category(value: str, table: Mapping[str, str | None], source: str) -> tuple[str | None, Skipped | None]:
    """Source category -> records.CATEGORIES name, or (None, Skipped) when unusable/unknown."""
    if value in table and table[value] is not None:
        cat = table[value]
        assert cat in CATEGORIES, cat
        return cat, None
    if value in table:
        return None, Skipped(source, f"category {value!r} has no agent category (not a road user)")
    return None, Skipped(source, f"unknown category {value!r}; expected one of {', '.join(sorted(table))}")
