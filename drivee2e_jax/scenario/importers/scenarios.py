"""From converted tracks to scenarios (see ``importers.common``): windows of
a long log, their signal states, one ``ScenarioRecord`` per window with the
ego's route and behaviour label."""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from drivee2e_jax.errors import DriveE2EError
from drivee2e_jax.records import BEHAVIORS, MapRecord, ScenarioRecord, TrackRecord
from drivee2e_jax.scenario import curation
from drivee2e_jax.scenario.routes import build_route

from .behavior import PLAUSIBILITY_PREFIX, infer_behavior, select_ego
from .results import ImportOptions, Skipped

__all__ = [
    "windows", "cut_window", "SignalSource", "window_signals", "safe_id", "make_scenario", "windowed_scenarios",
]


def windows(num_steps: int, dt: float, window_s: float | None) -> list[tuple[int, int]]:
    """Non-overlapping ``[k0, k1)`` step ranges of ``window_s`` (the whole log if None).
    A last piece shorter than half a window is dropped."""
    if window_s is None:
        return [(0, num_steps)]
    w = max(1, int(round(window_s / dt)))
    out = [(k, min(k + w, num_steps)) for k in range(0, num_steps, w)]
    if len(out) > 1 and out[-1][1] - out[-1][0] < w / 2:
        out.pop()
    return out


def cut_window(tracks: Sequence[TrackRecord], k0: int, k1: int, dt: float) -> list[TrackRecord]:
    """The tracks' samples at steps ``[k0, k1)``, times shifted to start at 0; empty tracks dropped."""
    out = []
    for tr in tracks:
        k = np.rint(np.asarray(tr.t) / dt).astype(int)
        m = (k >= k0) & (k < k1)
        if not m.any():
            continue
        out.append(replace(
            tr, t=(k[m] - k0) * dt, xy=tr.xy[m], yaw=tr.yaw[m],
            vel=None if tr.vel is None else tr.vel[m],
            visible=None if tr.visible is None else tr.visible[m],
            quality=None if tr.quality is None else tr.quality[m],
        ))
    return out


#: Signal states of a whole log: a function of log times (k,) s -> {group: (k,)
#: SIGNAL_STATES index}, or full-log arrays {group: (num_steps,)}.
SignalSource = Callable[[np.ndarray], Mapping[int, np.ndarray]] | Mapping[int, np.ndarray]


def window_signals(signals: SignalSource | None, k0: int, k1: int, dt: float,
                   num_steps: int) -> dict[int, np.ndarray]:
    """The signal states at log steps ``[k0, k1)`` as {group: (k1 - k0,) int8}."""
    if signals is None:
        return {}
    if callable(signals):
        states = signals((k0 + np.arange(k1 - k0)) * dt)
    else:
        for g, v in signals.items():
            if len(v) != num_steps:
                raise ValueError(f"signals[{g}]: expected {num_steps} states (one per log step), got {len(v)}")
        states = {g: np.asarray(v)[k0:k1] for g, v in signals.items()}
    return {int(g): np.asarray(v, np.int8) for g, v in sorted(states.items())}


_UNSAFE = re.compile(r"[^A-Za-z0-9_.\-]+")


def safe_id(text: str) -> str:
    """A portable id (file name) from any text."""
    s = _UNSAFE.sub("_", str(text)).strip("_.-") or "x"
    return s if s[0].isalnum() else "x" + s


def make_scenario(scenario_id: str, map_rec: MapRecord, tracks: list[TrackRecord], ego_id: int, dt: float,
                  num_steps: int, options: ImportOptions, *, intersection_id: str | None = None,
                  weather: str = "clear", time_of_day: str = "day",
                  signals: Mapping[int, np.ndarray] | None = None) -> tuple[ScenarioRecord, str]:
    """A ScenarioRecord with the ego's route and the inferred behaviour; also the label's why.

    ``signals``: {group: (num_steps,) SIGNAL_STATES index} of this scenario.
    """
    ego = next((t for t in tracks if t.track_id == ego_id), None)
    if ego is None:
        raise DriveE2EError(f"{scenario_id}: no track {ego_id} to use as ego")
    s = ScenarioRecord(
        scenario_id=safe_id(scenario_id), split=options.split, intersection_id=intersection_id or map_rec.map_id,
        map_id=map_rec.map_id, behavior="STR", weather=weather, time_of_day=time_of_day, ego_track_id=ego_id,
        route=build_route(ego), dt=dt, num_steps=num_steps, tracks=sorted(tracks, key=lambda t: t.track_id),
        signals=dict(signals or {}),
    )
    label, why = infer_behavior(s, map_rec)
    assert label in BEHAVIORS
    s.behavior = label
    return s, why


def windowed_scenarios(base_id: str, map_rec: MapRecord, tracks: list[TrackRecord], ego_id: int | None, dt: float,
                       num_steps: int, options: ImportOptions, source: str, skipped: list[Skipped],
                       notes: list[str], *, limit: int | None = None, signals: SignalSource | None = None,
                       source_ids: Mapping[int, str] | None = None, **kwargs) -> list[ScenarioRecord]:
    """One scenario per window of the log (see the module docstring).

    ``limit``: at most this many scenarios (default ``options.max_scenarios``).
    ``source_ids``: track id -> source id (``TrackIds.table()``), to name
    tracks in notes and skip reasons as the user knows them (``--ego`` takes
    source ids).
    ``signals``: the whole log's signal states (``SignalSource``), cut to each
    window by ``window_signals``; None: no signals.
    A window whose scenario ``curation.fair_test_problems`` refuses (an ego
    that barely moves, a collision in the log) becomes a Skipped with why.
    ``kwargs`` go to ``make_scenario`` (intersection_id, weather, time_of_day).
    """
    limit = options.max_scenarios if limit is None else limit
    spans = windows(num_steps, dt, options.window_s)

    def name(i: int) -> str:
        return f"{i} (source {source_ids[i]})" if source_ids and i in source_ids else str(i)

    out = []
    for w, (k0, k1) in enumerate(spans):
        if limit is not None and len(out) >= limit:
            break
        sid = base_id if len(spans) == 1 else f"{base_id}_w{w:02d}"
        where = source if len(spans) == 1 else f"{source} window {k0 * dt:g}-{k1 * dt:g} s"
        cut = cut_window(tracks, k0, k1, dt)
        n = k1 - k0
        ego = ego_id
        if ego is None:
            chosen, reasons = select_ego(cut, map_rec, n, dt)
            if chosen is None:
                # the near misses (rejected only for their motion) first: they are what --ego could pick
                near = sorted(reasons.items(), key=lambda x: not x[1].startswith(PLAUSIBILITY_PREFIX))
                why = "; ".join(f"{name(i)}: {r}" for i, r in near[:3])
                motion_only = bool(near) and near[0][1].startswith(PLAUSIBILITY_PREFIX)
                hint = "; --ego SOURCE_ID uses one anyway" if motion_only else ""
                skipped.append(Skipped(where, f"no vehicle qualifies as ego ({why or 'no vehicles'}){hint}"))
                continue
            ego = chosen.track_id
            passed = [f"track {name(i)}: {r}" for i, r in reasons.items() if r.startswith(PLAUSIBILITY_PREFIX)]
            notes.append(f"{sid}: ego chosen automatically: track {name(ego)} (the longest qualifying path)"
                         + (f"; candidates passed over: {'; '.join(passed)}" if passed else ""))
        tr = next((t for t in cut if t.track_id == ego), None)
        k = np.rint(np.asarray(tr.t) / dt).astype(int) if tr is not None else np.zeros(0, int)
        if tr is None or len(np.unique(k)) < n:
            have = len(np.unique(k))
            skipped.append(Skipped(where, f"the ego (track {ego}) is present at {have} of {n} steps; "
                                          "expected every step"))
            continue
        s, why = make_scenario(sid, map_rec, cut, ego, dt, n, options,
                               signals=window_signals(signals, k0, k1, dt, num_steps), **kwargs)
        unfair = curation.fair_test_problems(s)
        if unfair:
            skipped.append(Skipped(where, f"not a fair closed-loop test (ego track {name(ego)}): "
                                          + "; ".join(unfair)))
            continue
        notes.append(f"{s.scenario_id}: behaviour {s.behavior} ({why})")
        out.append(s)
    return out
