"""Host-side aggregation over routes (plain Python / numpy, never traced).

* ``lb_global``: CARLA Leaderboard 2.0 ``compute_global_statistics`` (also
  what Bench2Drive's and DriveE2E's statistics managers write).
* ``b2d_merge`` / ``b2d_efficiency``: Bench2Drive ``merge_route_json.py`` and
  the efficiency half of ``efficiency_smoothness_benchmark.py``.
* ``drivee2e_merge`` / ``drivee2e_ability``: DriveE2E ``merge_reoute_json.py``
  and ``ability_benchmark_batch.py``.

Inputs are ``RouteResult``s, one per route that produced a record (a crashed
route simply has none). ``records_from_scores`` builds them from the batched
``driving_score.RouteScore`` the rollout returns. Arithmetic follows the
sources operation by operation (Python floats), so results match them to the
last digit given float64 per-route scores.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

from drivee2e_jax.metrics.driving_score import INFRACTION_KEYS, status_name

ROUND_DIGITS = 3
ROUND_DIGITS_SCORE = 6

#: DriveE2E ``ability_benchmark_batch.py``: behaviour groups and the fixed
#: per-group route counts its ability percentages divide by (175 routes).
DRIVEE2E_ABILITIES = ("COV", "IPC", "UT", "YLW", "STR", "LFT", "RT", "STP")
DRIVEE2E_ABILITY_COUNTS = {"RT": 21, "STR": 33, "LFT": 23, "STP": 18, "YLW": 15, "COV": 32, "IPC": 28, "UT": 5}


@dataclasses.dataclass(frozen=True)
class RouteResult:
    """One route's record, as the leaderboard's JSON holds it.

    Attributes:
      route_id: e.g. ``RouteScenario_3001_rep0`` or a scenario id.
      route_length_m: route length, m (the leaderboard rounds it to 3 decimals).
      score_route, score_penalty, score_composed: RC %, IS, DS %.
      status: leaderboard status string (``driving_score.STATUS_NAMES``).
      infractions: number of entries per ``INFRACTION_KEYS`` (missing = 0).
      outside_lanes_m: off-lane distance of the outside-lanes entry, m.
      min_speed_pct: values of the recorded min-speed entries, %.
      category: scenario type / behaviour group (for abilities).
    """

    route_id: str
    route_length_m: float
    score_route: float
    score_penalty: float
    score_composed: float
    status: str
    infractions: Mapping[str, int] = dataclasses.field(default_factory=dict)
    outside_lanes_m: float = 0.0
    min_speed_pct: tuple[float, ...] = ()
    category: str | None = None

    def count(self, key: str) -> int:
        if key not in INFRACTION_KEYS:
            raise KeyError(f"unknown infraction key {key!r}")
        return int(self.infractions.get(key, 0))

    @property
    def num_infractions(self) -> int:
        return sum(self.count(k) for k in INFRACTION_KEYS)

    @property
    def success(self) -> bool:
        """Bench2Drive / DriveE2E: Perfect or Completed, and no infraction
        entry except min-speed ones."""
        if self.status not in ("Completed", "Perfect"):
            return False
        return all(self.count(k) == 0 for k in INFRACTION_KEYS if k != "min_speed_infractions")


def records_from_scores(scores, route_ids: Sequence[str], route_lengths_m, categories=None) -> list[RouteResult]:
    """``RouteResult``s from a batched ``RouteScore`` (leading axis = routes).

    Route lengths are rounded to 3 decimals and the off-lane distance to 3
    (as the leaderboard's message does).
    """
    s = {f.name: np.asarray(getattr(scores, f.name)) for f in dataclasses.fields(scores)}
    n = len(route_ids)
    if s["status"].shape[:1] != (n,):
        raise ValueError(f"records_from_scores: scores have batch {s['status'].shape[:1]}, got {n} route ids")
    lengths = np.broadcast_to(np.asarray(route_lengths_m, np.float64), (n,))
    out = []
    for i in range(n):
        counts = {k: int(c) for k, c in zip(INFRACTION_KEYS, s["infractions"][i]) if int(c)}
        out.append(
            RouteResult(
                route_id=str(route_ids[i]),
                route_length_m=round(float(lengths[i]), ROUND_DIGITS),
                score_route=float(s["route_completion"][i]),
                score_penalty=float(s["infraction_penalty"][i]),
                score_composed=float(s["driving_score"][i]),
                status=status_name(s["status"][i]),
                infractions=counts,
                outside_lanes_m=round(float(s["outside_lanes_m"][i]), ROUND_DIGITS),
                min_speed_pct=tuple(float(v) for v, r in zip(s["min_speed_pct"][i], s["min_speed_recorded"][i]) if r),
                category=None if categories is None else categories[i],
            )
        )
    return out


# ---------------------------------------------------------------------------
# CARLA Leaderboard 2.0 global record
# ---------------------------------------------------------------------------

_SCORES = ("score_composed", "score_route", "score_penalty")


def lb_global(records: Sequence[RouteResult], planned_routes: int) -> dict:
    """LB 2.0 ``compute_global_statistics``.

    Means divide by ``planned_routes`` (missing routes count 0), rounded to
    6; sample std over the present records around the rounded mean with
    divisor ``planned_routes - 1`` (0 if ``planned_routes == 1``), rounded to
    3; km_driven = sum(length_km * RC / 100) floored at 0.001; every
    infraction column is entries / km_driven, except ``outside_route_lanes``,
    the km driven off-lane; rounded to 3. Status: Perfect -> Completed ->
    Failed, downgraded by each record.
    """
    if planned_routes < 1:
        raise ValueError(f"lb_global: planned_routes must be >= 1, got {planned_routes}")
    mean = {k: 0.0 for k in _SCORES}
    total_length = 0.0
    status = "Perfect"
    exceptions = []
    for r in records:
        for k in _SCORES:
            mean[k] += getattr(r, k) / planned_routes
        total_length += r.route_length_m
        result = "Failed" if "Failed" in r.status else r.status
        if result == "Failed":
            exceptions.append((r.route_id, r.status))
            status = result
        elif status == "Perfect" and result != "Perfect":
            status = result
    mean = {k: round(v, ROUND_DIGITS_SCORE) for k, v in mean.items()}
    std = {k: 0.0 for k in _SCORES}
    if planned_routes == 1:
        std = {k: 0 for k in std}
    else:
        for r in records:
            for k in _SCORES:
                std[k] += math.pow(getattr(r, k) - mean[k], 2)
        std = {k: round(math.sqrt(v / float(planned_routes - 1)), ROUND_DIGITS) for k, v in std.items()}
    km_driven = 0.0
    totals = {k: 0.0 if k == "outside_route_lanes" else 0 for k in INFRACTION_KEYS}
    for r in records:
        km_driven += r.route_length_m / 1000 * r.score_route / 100
        for k in INFRACTION_KEYS:
            if k == "outside_route_lanes":
                totals[k] += r.outside_lanes_m / 1000 if r.count(k) else 0.0
            else:
                totals[k] += r.count(k)
    km_driven = max(km_driven, 0.001)
    per_km = {}
    for k in INFRACTION_KEYS:
        v = totals[k] if k == "outside_route_lanes" else totals[k] / km_driven
        per_km[k] = round(v, ROUND_DIGITS)
    return {
        "scores_mean": mean,
        "scores_std_dev": std,
        "infractions": per_km,
        "status": status,
        "km_driven": km_driven,
        "meta": {"total_length": total_length, "exceptions": exceptions},
    }


# ---------------------------------------------------------------------------
# Bench2Drive
# ---------------------------------------------------------------------------


def b2d_merge(records: Sequence[RouteResult], planned_routes: int = 220) -> dict:
    """Bench2Drive ``merge_route_json.py``: DS = sum(DS_i) / planned, SR =
    successes / planned (a fraction; README tables show %)."""
    if planned_routes < 1:
        raise ValueError(f"b2d_merge: planned_routes must be >= 1, got {planned_routes}")
    successes = [r.success for r in records]
    return {
        "driving score": sum(r.score_composed for r in records) / planned_routes,
        "success rate": sum(successes) / planned_routes,
        "eval num": len(records),
        "success": successes,
    }


def b2d_efficiency(records: Sequence[RouteResult]) -> float:
    """Bench2Drive efficiency: mean over routes with >= 1 recorded min-speed
    entry of that route's mean percentage, ignoring values > 1000.

    As in the source, a route whose every value exceeds 1000 divides by zero
    (raised as ZeroDivisionError naming the route); no route with entries
    also divides by zero.
    """
    per_route = []
    for r in records:
        if not r.min_speed_pct:
            continue
        kept = [v for v in r.min_speed_pct if not v > 1000]
        if not kept:
            raise ZeroDivisionError(f"b2d_efficiency: route {r.route_id}: every min-speed value exceeds 1000 %")
        per_route.append(sum(kept) / len(kept))
    if not per_route:
        raise ZeroDivisionError("b2d_efficiency: no route has a min-speed entry")
    return sum(per_route) / len(per_route)


# ---------------------------------------------------------------------------
# DriveE2E
# ---------------------------------------------------------------------------


def drivee2e_merge(records: Sequence[RouteResult], route_nums: float = 175) -> dict:
    """DriveE2E ``merge_reoute_json.py``: DS = sum(DS_i) / route_nums, SR =
    100 * successes / route_nums (a percentage); both 0 without records."""
    if not route_nums > 0:
        raise ValueError(f"drivee2e_merge: route_nums must be > 0, got {route_nums}")
    successes = sum(r.success for r in records)
    ds = sum(r.score_composed for r in records) / route_nums if records else 0.0
    sr = successes / route_nums * 100 if records else 0.0
    return {"driving score": ds, "success rate": sr, "eval num": len(records), "success num": successes}


def drivee2e_ability(
    records: Sequence[RouteResult], counts: Mapping[str, int] = DRIVEE2E_ABILITY_COUNTS
) -> dict[str, float]:
    """DriveE2E per-behaviour "ability": 100 * successes / fixed count, for
    each of ``DRIVEE2E_ABILITIES`` (0 when no record of that group), and
    ``mean`` over the eight. ``counts`` defaults to the source's table (175
    routes); pass the suite's own counts for other splits. Records whose
    ``category`` is not a group are ignored, as in the source.
    """
    stat = {a: [0, 0] for a in DRIVEE2E_ABILITIES}
    for r in records:
        if r.category in stat:
            stat[r.category][1] += 1
            stat[r.category][0] += int(r.success)
    res = {a: (float(s) / counts[a] * 100 if n != 0 else 0) for a, (s, n) in stat.items()}
    res["mean"] = sum(res.values()) / len(DRIVEE2E_ABILITIES)
    return res
