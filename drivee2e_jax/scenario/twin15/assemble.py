"""Verified logs -> ``ScenarioRecord``s (tracks, signals, route)."""

from __future__ import annotations

import numpy as np

from drivee2e_jax.polyline import arc_length
from drivee2e_jax.records import CATEGORIES, RouteRecord, ScenarioRecord, TrackRecord
from drivee2e_jax.scenario.routes import TWIN15_ROUTE_SPACING_M

from .labels import LOG_STEPS, Cut
from .plan import DT, Plan


def route_of(xy: np.ndarray) -> RouteRecord:
    """The ego's logged path decimated to 1.5-2 m (logged points kept where
    the next one would open a gap over 2 m), with its exact ends."""
    arc = arc_length(xy)
    keep, last = [0], 0.0
    for j in range(1, len(xy) - 1):
        if arc[j] - last >= TWIN15_ROUTE_SPACING_M or arc[j + 1] - last > 2.0:
            keep.append(j)
            last = arc[j]
    if arc[-1] - last < 0.5 and len(keep) > 1:
        keep.pop()  # no tiny last step
    pts = np.concatenate([xy[keep], xy[-1:]])
    return RouteRecord(waypoints=pts, source=xy[0].copy(), destination=xy[-1].copy())


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles to [-pi, pi). Not ``polyline.wrap_angle`` on purpose: this is the
    generator's own arithmetic, and the twin15 suite (``VERSION``) is pinned to
    its bits; ``pack`` wraps every yaw to (-pi, pi] (``polyline.wrap_angle``)."""
    return (a + np.pi) % (2 * np.pi) - np.pi


def scenario_record(plan: Plan, c: Cut, scenario_id: str, split: str, weather: str, map_id: str,
                    groups: list[int]) -> ScenarioRecord:
    local = c.rows - c.rows[0]
    ag = plan.agents
    tracks = []
    k_all = np.arange(LOG_STEPS)
    for a, li in enumerate(local):
        k = k_all[c.valid[a]]
        yaw = _wrap(c.yaw[a, k])
        speed = c.v[a, k]
        tracks.append(TrackRecord(
            track_id=int(li) + 1, category=CATEGORIES[int(ag["cat"][li])],
            size=np.array([ag["length"][li], ag["width"][li], ag["height"][li]]),
            t=np.round(k * DT, 6), xy=c.xy[a, k].copy(), yaw=yaw,
            vel=np.stack([speed * np.cos(yaw), speed * np.sin(yaw)], axis=1),
            visible=np.ones(len(k), bool), quality=np.ones(len(k), bool)))
    ego_xy = c.xy[0, c.valid[0]]
    return ScenarioRecord(
        scenario_id=scenario_id, split=split, intersection_id=map_id, map_id=map_id, behavior=plan.label,
        weather=weather, time_of_day=plan.time_of_day, ego_track_id=1, route=route_of(ego_xy), dt=DT,
        num_steps=LOG_STEPS, tracks=tracks,
        signals={int(g): c.signals[g].astype(np.int8) for g in groups},
    )
