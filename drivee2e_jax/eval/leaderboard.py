"""A run's results as a CARLA Leaderboard 2.0 / Bench2Drive ``results.json``.

``leaderboard_results(rows, events, run_info, policy)`` turns one policy's
per-scenario rows and infraction events (``policies/<policy>.json``) into the
JSON the leaderboard's ``StatisticsManager`` writes (Bench2Drive's fork of it,
``leaderboard/leaderboard/utils/statistics_manager.py``), so Bench2Drive's
own tools (``tools/merge_route_json.py``, ``tools/ability_benchmark.py``, the
efficiency half of ``tools/efficiency_smoothness_benchmark.py``) read it::

    {"_checkpoint": {"global_record": {...}, "progress": [n, n], "records": [...]},
     "entry_status": "Finished", "eligible": true, "sensors": [...],
     "values": [...15 strings...], "labels": [...15 names...],
     "drivee2e": {...provenance: policy, run.json...}}

One file holds one agent (policy). ``write_leaderboard_results`` writes it
atomically. Host side, plain Python.

Per route record (one per row, i.e. per scenario and repetition):

* ``route_id`` ``RouteScenario_<n>_rep<r>``: ``n`` is the number the
  scenario id ends with (``twin15_0017`` -> 17) when every scenario id of the
  run ends with a distinct number, else the scenario's position in the run;
  ``r`` the row's ``repetition``. Records are sorted by (n, r) and ``index``
  numbers them, as ``sort_records`` does. ``scenario_id`` (ours) is kept.
* ``scores``: ``score_route`` = RC %, ``score_penalty`` = IS, ``score_composed``
  = DS % (the row's values, rounded to 6 decimals as the leaderboard does).
* ``status``: the row's status; ours are already the leaderboard strings
  (``Perfect``, ``Completed``, ``Failed``, ``Failed - Agent timed out``,
  ``Failed - Agent deviated from the route``, ``Failed - Agent got blocked``,
  ``Failed - TickRuntime``, Bench2Drive's wording for its tick cap).
* ``infractions``: every key of ``INFRACTION_KEYS``, one message per
  recorded entry, worded as scenario_runner's criteria word them
  (``INFRACTION_MESSAGES``). The number of entries per key is the row's count
  (what was scored); messages take time-ordered events of that type for
  their location, and a count without (enough) events gets the message
  without a place.
* ``meta``: ``route_length`` (m, 3 decimals), ``duration_game`` (simulated
  episode time, s), ``duration_system`` (the run's wall time per scenario,
  s: one batched rollout serves every scenario).
* ``scenario_name`` / ``town_name`` / ``weather_id`` / ``save_name``
  (Bench2Drive's extra fields): behaviour group, intersection id, weather,
  and ``<route_id>_<town>_<behaviour>_<weather>``; ``timestamp`` (the
  LB 1.0 forks' field): when the file was made (UTC) unless given.

The ``global_record`` is ``compute_global_statistics`` over the records, as
``metrics.aggregate.lb_global`` computes it (means over the routes of the
file, std, per-km rates, status downgrade, exceptions), plus the summed
durations; ``values`` / ``labels`` list its 15 numbers as the leaderboard
does; ``entry_status`` is ``Finished`` (``eligible`` true).

What differs from a CARLA file:

* no z: locations are 2-D, messages say ``z=0.0``;
* collisions name the other actor ``walker.<category>`` /
  ``vehicle.<category>`` with its log track id (``static.layout`` and id -1
  for layout); the location is the ego's at contact, as in CARLA;
* red lights give our stop-line index as the light id and the ego's position
  where it crossed, not the light actor's location;
* min-speed entries: rows keep the route's mean ego/traffic speed ratio
  (``efficiency_pct``), not each checkpoint's value, so every entry of a
  route carries that mean (Bench2Drive's efficiency, the mean of the entries,
  is then the same number); presets that record no min-speed entry (``paper``,
  ``drivee2e`` when all checkpoints reach 100 %) leave the list empty, and
  Bench2Drive's efficiency script, which skips such routes, differs from our
  ``efficiency_pct`` (averaged over every route with a checkpoint);
* ``sensors`` lists the policy's ``required_sensors`` (our sensor names, not
  CARLA sensor ids); no CARLA sensor set is validated;
* times are simulated (``duration_game``) or our batched wall time;
* the ``drivee2e`` key (provenance) is ours; CARLA tools ignore it.
"""

from __future__ import annotations

import datetime
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from drivee2e_jax.eval.results import event_key
from drivee2e_jax.files import atomic_write_json
from drivee2e_jax.metrics.aggregate import ROUND_DIGITS, ROUND_DIGITS_SCORE, RouteResult, lb_global
from drivee2e_jax.metrics.driving_score import INFRACTION_KEYS, STATUS_NAMES

#: Record key -> message template (scenario_runner ``atomic_criteria.py`` /
#: ``statistics_manager.py`` wording). Fields: x, y (m, 3 decimals), other
#: (actor type id), id, meters, pct, value.
INFRACTION_MESSAGES = {
    "collisions_pedestrian": "Agent collided against object with type={other} and id={id} at (x={x}, y={y}, z=0.0)",
    "collisions_vehicle": "Agent collided against object with type={other} and id={id} at (x={x}, y={y}, z=0.0)",
    "collisions_layout": "Agent collided against object with type={other} and id={id} at (x={x}, y={y}, z=0.0)",
    "red_light": "Agent ran a red light {id} at (x={x}, y={y}, z=0.0)",
    "stop_infraction": "Agent ran a stop with id={id} at (x={x}, y={y}, z=0.0)",
    "outside_route_lanes": "Agent went outside its route lanes for about {meters} meters ({pct}% of the completed route)",
    "min_speed_infractions": "Average speed is {value}% of the surrounding traffic's one",
    "yield_emergency_vehicle_infractions": "Agent failed to yield to an emergency vehicle",
    "scenario_timeouts": "Agent timed out a scenario",
    "route_dev": "Agent deviated from the route at (x={x}, y={y}, z=0.0)",
    "vehicle_blocked": "Agent got blocked at (x={x}, y={y}, z=0.0)",
    "route_timeout": "Route timeout.",
}

#: Leaderboard ``labels`` and the ``global_record`` entry behind each ``values`` item.
LABELS = (
    ("Avg. driving score", ("scores_mean", "score_composed")),
    ("Avg. route completion", ("scores_mean", "score_route")),
    ("Avg. infraction penalty", ("scores_mean", "score_penalty")),
    ("Collisions with pedestrians", ("infractions", "collisions_pedestrian")),
    ("Collisions with vehicles", ("infractions", "collisions_vehicle")),
    ("Collisions with layout", ("infractions", "collisions_layout")),
    ("Red lights infractions", ("infractions", "red_light")),
    ("Stop sign infractions", ("infractions", "stop_infraction")),
    ("Off-road infractions", ("infractions", "outside_route_lanes")),
    ("Route deviations", ("infractions", "route_dev")),
    ("Route timeouts", ("infractions", "route_timeout")),
    ("Agent blocked", ("infractions", "vehicle_blocked")),
    ("Yield emergency vehicles infractions", ("infractions", "yield_emergency_vehicle_infractions")),
    ("Scenario timeouts", ("infractions", "scenario_timeouts")),
    ("Min speed infractions", ("infractions", "min_speed_infractions")),
)

_COLLISION_KIND = {"collisions_pedestrian": "walker", "collisions_vehicle": "vehicle", "collisions_layout": "static"}
_LOCATED = ("collisions_pedestrian", "collisions_vehicle", "collisions_layout", "red_light", "stop_infraction",
            "route_dev", "vehicle_blocked")
_TRAILING_NUMBER = re.compile(r"(\d+)$")


def leaderboard_results(
    rows: Sequence[Mapping],
    events: Mapping[str, Sequence[Mapping]],
    run_info: Mapping,
    policy,
    timestamp: str | None = None,
) -> dict:
    """The leaderboard ``results.json`` content of one policy's results.

    Args:
      rows: the policy's per-scenario rows (``policies/<policy>.json``
        ``rows``; every row of the run, all repetitions).
      events: its infraction events by ``results.event_key(row)``.
      run_info: ``run.json`` (kept under ``drivee2e.run``).
      policy: the policy (its ``name`` and ``required_sensors`` are used) or
        its name.
      timestamp: each record's ``timestamp`` (default: now, UTC).

    Raises ValueError for a row of another policy, an unknown status or a
    repeated (scenario, repetition).
    """
    name = policy if isinstance(policy, str) else str(policy.name)
    sensors = [] if isinstance(policy, str) else [str(s) for s in getattr(policy, "required_sensors", ())]
    if timestamp is None:
        timestamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")
    numbers = _route_numbers([r["scenario_id"] for r in rows])
    keyed = []
    for r in rows:
        if r.get("policy", name) != name:
            raise ValueError(f"leaderboard_results: row {r['scenario_id']} is of policy {r['policy']!r}, not {name!r}")
        if r["status"] not in STATUS_NAMES:
            raise ValueError(f"leaderboard_results: row {r['scenario_id']}: unknown status {r['status']!r}")
        rep = int(r.get("repetition") or 0)
        keyed.append(((numbers[r["scenario_id"]], rep), r))
    keyed.sort(key=lambda kr: kr[0])
    seen = [k for k, _ in keyed]
    if len(set(seen)) != len(seen):
        raise ValueError("leaderboard_results: a (scenario, repetition) appears twice in the rows")
    records = [
        _record(index, f"RouteScenario_{num}_rep{rep}", r, events.get(event_key(r), ()), timestamp)
        for index, ((num, rep), r) in enumerate(keyed)
    ]
    glob = _global_record(records)
    values = [str(glob[group][key]) for _, (group, key) in LABELS]
    return {
        "_checkpoint": {"global_record": glob, "progress": [len(records), len(records)], "records": records},
        "entry_status": "Finished",
        "eligible": True,
        "sensors": sensors,
        "values": values,
        "labels": [label for label, _ in LABELS],
        "drivee2e": {"policy": name, "run": dict(run_info)},
    }


def write_leaderboard_results(path: str | Path, rows, events, run_info, policy, timestamp: str | None = None) -> Path:
    """Write ``leaderboard_results(...)`` to ``path`` atomically; returns the path."""
    path = Path(path)
    atomic_write_json(path, leaderboard_results(rows, events, run_info, policy, timestamp=timestamp))
    return path


def route_results(data: Mapping) -> list[RouteResult]:
    """``RouteResult``s (for ``metrics.aggregate``) read back from a
    leaderboard results dict, as the leaderboard's global statistics read
    its records (off-lane km parsed from the message's 9th word)."""
    out = []
    for rec in data["_checkpoint"]["records"]:
        inf = rec["infractions"]
        off = inf.get("outside_route_lanes") or []
        speeds = []
        for msg in inf.get("min_speed_infractions") or []:
            m = re.search(r"\b\d+\.?\d*%", msg)
            if m:
                speeds.append(float(m.group().rstrip("%")))
        out.append(
            RouteResult(
                route_id=rec["route_id"],
                route_length_m=rec["meta"]["route_length"],
                score_route=rec["scores"]["score_route"],
                score_penalty=rec["scores"]["score_penalty"],
                score_composed=rec["scores"]["score_composed"],
                status=rec["status"],
                infractions={k: len(v) for k, v in inf.items() if k in INFRACTION_KEYS and v},
                outside_lanes_m=float(off[0].split(" ")[8]) if off else 0.0,
                min_speed_pct=tuple(speeds),
                category=rec.get("scenario_name"),
            )
        )
    return out


# ---------------------------------------------------------------------------


def _route_numbers(scenario_ids: Sequence[str]) -> dict[str, int]:
    """Scenario id -> route number (see the module docstring)."""
    order = list(dict.fromkeys(scenario_ids))
    found = [_TRAILING_NUMBER.search(s) for s in order]
    nums = [int(m.group(1)) if m else None for m in found]
    if None not in nums and len(set(nums)) == len(nums):
        return dict(zip(order, nums))
    return {s: i for i, s in enumerate(order)}


def _xy(ev: Mapping | None) -> dict:
    if ev is None or "x" not in ev:
        return {"x": "nan", "y": "nan"}
    return {"x": round(float(ev["x"]), 3), "y": round(float(ev["y"]), 3)}


def _message(key: str, row: Mapping, ev: Mapping | None) -> str:
    fields: dict = {**_xy(ev), "id": -1}
    if key in _COLLISION_KIND:
        kind = _COLLISION_KIND[key]
        cat = (ev or {}).get("other_category")
        fields["other"] = "static.layout" if kind == "static" else f"{kind}.{cat or 'unknown'}"
        fields["id"] = int((ev or {}).get("other_track_id", -1))
    elif key == "red_light":
        fields["id"] = int((ev or {}).get("stop_line", -1))
    elif key == "stop_infraction":
        fields["id"] = int((ev or {}).get("stop_sign", -1))
    elif key == "outside_route_lanes":
        fields["meters"] = round(float(row.get("outside_route_lanes_m") or 0.0), 3)
        fields["pct"] = round(float(row.get("outside_route_lanes_pct") or 0.0), 2)
    elif key == "min_speed_infractions":
        eff = row.get("efficiency_pct")
        # Fixed-point (no exponent): Bench2Drive parses it with r"\b\d+\.?\d*%".
        fields["value"] = f"{float(eff):.6f}".rstrip("0").rstrip(".") if _finite(eff) else "nan"
    return INFRACTION_MESSAGES[key].format(**fields)


def _finite(v) -> bool:
    return v is not None and v != "" and math.isfinite(float(v))


def _infractions(row: Mapping, evs: Sequence[Mapping]) -> dict[str, list[str]]:
    by_type: dict[str, list[Mapping]] = {}
    for ev in sorted(evs, key=lambda e: e.get("t", 0.0)):
        by_type.setdefault(ev.get("type"), []).append(ev)
    out = {}
    for key in INFRACTION_KEYS:
        got = by_type.get(key, [])
        n = int(row[key]) if row.get(key) not in (None, "") else len(got)
        out[key] = [_message(key, row, got[i] if i < len(got) and key in _LOCATED else None) for i in range(n)]
    return out


def _record(index: int, route_id: str, row: Mapping, evs, timestamp: str) -> dict:
    infractions = _infractions(row, evs)
    town, scenario, weather = str(row.get("intersection_id", "")), str(row.get("behavior", "")), str(row.get("weather", ""))
    return {
        "index": index,
        "route_id": route_id,
        "scenario_id": row["scenario_id"],
        "scenario_name": scenario,
        "weather_id": weather,
        "save_name": f"{route_id}_{town}_{scenario}_{weather}",
        "town_name": town,
        "timestamp": timestamp,
        "status": row["status"],
        "num_infractions": sum(len(v) for v in infractions.values()),
        "infractions": infractions,
        "scores": {
            "score_route": round(float(row["route_completion"]), ROUND_DIGITS_SCORE),
            "score_penalty": round(float(row["infraction_score"]), ROUND_DIGITS_SCORE),
            "score_composed": round(float(row["driving_score"]), ROUND_DIGITS_SCORE),
        },
        "meta": {
            "route_length": round(float(row["route_length_m"]), ROUND_DIGITS),
            "duration_game": round(float(row.get("episode_s") or 0.0), ROUND_DIGITS),
            "duration_system": round(float(row.get("eval_time_s") or 0.0), ROUND_DIGITS),
        },
    }


def _global_record(records: list[dict]) -> dict:
    """LB 2.0 ``GlobalRecord`` of the records (``aggregate.lb_global``)."""
    if not records:
        zeros = {"score_composed": 0, "score_route": 0, "score_penalty": 0}
        return {"index": -1, "route_id": -1, "status": "Perfect", "infractions": {k: 0 for k in INFRACTION_KEYS},
                "scores_mean": dict(zeros), "scores_std_dev": dict(zeros),
                "meta": {"total_length": 0, "duration_game": 0, "duration_system": 0, "exceptions": []}}
    g = lb_global(route_results({"_checkpoint": {"records": records}}), planned_routes=len(records))
    return {
        "index": -1,
        "route_id": -1,
        "status": g["status"],
        "infractions": g["infractions"],
        "scores_mean": g["scores_mean"],
        "scores_std_dev": g["scores_std_dev"],
        "meta": {
            "total_length": g["meta"]["total_length"],
            "duration_game": sum(r["meta"]["duration_game"] for r in records),
            "duration_system": sum(r["meta"]["duration_system"] for r in records),
            "exceptions": [(r["route_id"], r["index"], r["status"]) for r in records if "Failed" in r["status"]],
        },
    }


__all__ = ["INFRACTION_MESSAGES", "LABELS", "leaderboard_results", "route_results", "write_leaderboard_results"]
