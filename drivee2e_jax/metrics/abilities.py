"""Bench2Drive multi-ability scores (``tools/ability_benchmark.py``), host side.

``b2d_abilities`` reproduces Bench2Drive's ``ability_benchmark.py`` (0.0.4,
and the 0.0.3 junction rule with ``version="0.0.3"``) on per-route records:
each of the five abilities (``B2D_ABILITIES``) is the fraction of successful
routes among the routes whose scenario type is in its list (a type may be in
several lists); ``mean`` averages the five. Routes without a record (crashed)
are simply not passed in, as B2D skips them.

Traffic_Signs junction credit (the route at 1 m resolution, ``c`` = 1-based
index of its first junction waypoint, ``n`` = number of waypoints): a route
"passes the junction" iff ``RC / 100 > (c + 8) / n`` and it has no stop-sign
and no red-light infraction.

* 0.0.4: a *failed* Traffic_Signs route that passes the junction adds 1 to the
  Traffic_Signs numerator (the denominator is unchanged).
* 0.0.3: *every* Traffic_Signs route is judged once more: +1 to the
  denominator, and +1 to the numerator if it passes the junction.

``BEHAVIOR_SCENARIO_TYPES`` maps the twin15 behaviour groups to B2D scenario
types (docs/metrics.md, "Bench2Drive abilities"); ``first_junction_index``
finds ``c - 1`` on a packed 1 m route. Plain Python; nothing is traced.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np

from drivee2e_jax.metrics.aggregate import RouteResult
from drivee2e_jax.types import Command

#: Bench2Drive ``tools/ability_benchmark.py`` (0.0.3 and 0.0.4 hold the same
#: table) ``Ability``: the scenario types of each ability, verbatim (the
#: source's Traffic_Signs list repeats six types; membership is what counts).
B2D_ABILITIES: dict[str, tuple[str, ...]] = {
    "Overtaking": (
        "Accident", "AccidentTwoWays", "ConstructionObstacle", "ConstructionObstacleTwoWays",
        "HazardAtSideLaneTwoWays", "HazardAtSideLane", "ParkedObstacleTwoWays", "ParkedObstacle",
        "VehicleOpensDoorTwoWays",
    ),
    "Merging": (
        "CrossingBicycleFlow", "EnterActorFlow", "HighwayExit", "InterurbanActorFlow", "HighwayCutIn",
        "InterurbanAdvancedActorFlow", "MergerIntoSlowTrafficV2", "MergerIntoSlowTraffic",
        "NonSignalizedJunctionLeftTurn", "NonSignalizedJunctionRightTurn", "NonSignalizedJunctionLeftTurnEnterFlow",
        "ParkingExit", "SequentialLaneChange", "SignalizedJunctionLeftTurn", "SignalizedJunctionRightTurn",
        "SignalizedJunctionLeftTurnEnterFlow",
    ),
    "Emergency_Brake": (
        "BlockedIntersection", "DynamicObjectCrossing", "HardBreakRoute", "OppositeVehicleTakingPriority",
        "OppositeVehicleRunningRedLight", "ParkingCutIn", "PedestrianCrossing", "ParkingCrossingPedestrian",
        "StaticCutIn", "VehicleTurningRoute", "VehicleTurningRoutePedestrian", "ControlLoss",
    ),
    "Give_Way": ("InvadingTurn", "YieldToEmergencyVehicle"),
    "Traffic_Signs": (
        "BlockedIntersection", "OppositeVehicleTakingPriority", "OppositeVehicleRunningRedLight",
        "PedestrianCrossing", "VehicleTurningRoute", "VehicleTurningRoutePedestrian", "EnterActorFlow",
        "CrossingBicycleFlow", "NonSignalizedJunctionLeftTurn", "NonSignalizedJunctionRightTurn",
        "NonSignalizedJunctionLeftTurnEnterFlow", "OppositeVehicleTakingPriority", "OppositeVehicleRunningRedLight",
        "PedestrianCrossing", "SignalizedJunctionLeftTurn", "SignalizedJunctionRightTurn",
        "SignalizedJunctionLeftTurnEnterFlow", "T_Junction", "VanillaNonSignalizedTurn",
        "VanillaSignalizedTurnEncounterGreenLight", "VanillaSignalizedTurnEncounterRedLight",
        "VanillaNonSignalizedTurnEncounterStopsign", "VehicleTurningRoute", "VehicleTurningRoutePedestrian",
    ),
}
ABILITY_NAMES = tuple(B2D_ABILITIES)
#: The ability whose failed routes can earn the junction credit.
TRAFFIC_SIGNS = "Traffic_Signs"
#: Junction waypoints the ego must be past (B2D: "+8 to ensure the ego pass the trigger volume").
JUNCTION_MARGIN_WP = 8
VERSIONS = ("0.0.3", "0.0.4")

#: twin15 behaviour group -> the B2D scenario type it stands for (one type per
#: group, as every B2D route has one). All twin15 routes cross a signalised
#: junction. "Vanilla" = no adversary: STR / LFT / RT / UT cross on green and
#: YLW crosses on a yellow (its logged ego passes: GreenLight); STP stops at a
#: red light, then crosses (RedLight); COV is a turn that must give way to a
#: conflicting vehicle stream at a signalised junction (SignalizedJunctionLeftTurn:
#: Merging + Traffic_Signs); IPC turns across a crosswalk that people are
#: crossing (VehicleTurningRoutePedestrian: Emergency_Brake + Traffic_Signs).
#: No group stands for Overtaking or Give_Way.
BEHAVIOR_SCENARIO_TYPES: dict[str, str] = {
    "COV": "SignalizedJunctionLeftTurn",
    "IPC": "VehicleTurningRoutePedestrian",
    "UT": "VanillaSignalizedTurnEncounterGreenLight",
    "YLW": "VanillaSignalizedTurnEncounterGreenLight",
    "STR": "VanillaSignalizedTurnEncounterGreenLight",
    "LFT": "VanillaSignalizedTurnEncounterGreenLight",
    "RT": "VanillaSignalizedTurnEncounterGreenLight",
    "STP": "VanillaSignalizedTurnEncounterRedLight",
}


@dataclasses.dataclass(frozen=True)
class AbilityRoute:
    """One route's record as ``ability_benchmark.py`` reads it.

    Attributes:
      scenario_types: B2D scenario type(s) of the route (B2D: exactly one; with
        several, the route counts once in each ability listing any of them).
      success: B2D's success test (status Completed / Perfect and no
        infraction entry besides min-speed ones; ``RouteResult.success``).
      route_completion_pct: RC, % (the record's ``score_route``).
      first_junction_index: 0-based index of the route's first junction
        waypoint at 1 m resolution (B2D's ``count`` - 1); None if unknown or
        the route has none (needed only for the junction credit).
      num_waypoints: number of 1 m route waypoints (B2D's ``len(waypoint_route)``).
      stop_infractions, red_light_infractions: infraction entries of the route.
      route_id: for error messages.
    """

    scenario_types: tuple[str, ...]
    success: bool
    route_completion_pct: float = 0.0
    first_junction_index: int | None = None
    num_waypoints: int | None = None
    stop_infractions: int = 0
    red_light_infractions: int = 0
    route_id: str = ""

    def in_ability(self, ability: str) -> bool:
        """Whether any of the route's scenario types is in ``ability``'s list."""
        return any(t in B2D_ABILITIES[ability] for t in self.scenario_types)


def passes_junction(route: AbilityRoute, strict: bool = True) -> bool:
    """B2D's junction test: RC/100 > (c + 8) / n, c = first junction index + 1,
    and no stop-sign or red-light infraction.

    A route without a junction waypoint or a waypoint count raises ValueError
    when ``strict`` (B2D raises "No junction found in route"), else fails.
    """
    c, n = route.first_junction_index, route.num_waypoints
    if c is None or c < 0 or not n or c >= n:
        if not strict:
            return False
        raise ValueError(f"b2d_abilities: route {route.route_id or '?'} has no junction waypoint "
                         f"(first_junction_index={c}, num_waypoints={n}); Bench2Drive raises here")
    junction_completion = float(c + 1 + JUNCTION_MARGIN_WP) / n
    record_completion = route.route_completion_pct / 100.0
    return record_completion > junction_completion and not route.stop_infractions and not route.red_light_infractions


def ability_counts(routes: Sequence[AbilityRoute], version: Literal["0.0.3", "0.0.4"] = "0.0.4",
                   junction_credit: bool = True, strict: bool = True) -> dict[str, list[int]]:
    """[successes, routes] per ability, as ``Ability_Statistic`` ends up.

    ``junction_credit=False`` skips the Traffic_Signs junction test (not B2D:
    for runs whose routes carry no junction information); ``strict``: see
    ``passes_junction``.
    """
    if version not in VERSIONS:
        raise ValueError(f"b2d_abilities: version must be one of {VERSIONS}, got {version!r}")
    stat = {a: [0, 0] for a in ABILITY_NAMES}
    for r in routes:
        for a in ABILITY_NAMES:
            if r.in_ability(a):
                stat[a][1] += 1
                stat[a][0] += int(bool(r.success))
        if not junction_credit or not r.in_ability(TRAFFIC_SIGNS):
            continue
        if version == "0.0.4":
            if not r.success and passes_junction(r, strict):
                stat[TRAFFIC_SIGNS][0] += 1
        else:
            stat[TRAFFIC_SIGNS][1] += 1
            stat[TRAFFIC_SIGNS][0] += int(passes_junction(r, strict))
    return stat


def b2d_abilities(routes: Sequence[AbilityRoute], version: Literal["0.0.3", "0.0.4"] = "0.0.4", *,
                  junction_credit: bool = True, strict: bool = True,
                  skip_empty: bool = False) -> dict[str, float]:
    """Bench2Drive ``ability_benchmark.py``: per-ability success fractions and their mean.

    Args:
      routes: one ``AbilityRoute`` per route that produced a record.
      version: "0.0.4" (credit for failed Traffic_Signs routes) or "0.0.3"
        (every Traffic_Signs route judged again, in the denominator too).
      junction_credit: apply the Traffic_Signs junction test (B2D always does).
      strict: a Traffic_Signs route that needs the test but has no junction
        waypoint raises ValueError (B2D's RuntimeError); False: it fails the test.
      skip_empty: leave out abilities without a route and average the others
        (not B2D, which divides by zero); False raises ZeroDivisionError naming
        the ability, as the source fails.

    Returns:
      ``{ability: fraction in [0, 1]}`` for the five ``ABILITY_NAMES`` (those
      with routes when ``skip_empty``) and ``mean`` (B2D: sum of the five / 5);
      {} when ``skip_empty`` and no route belongs to any ability.
    """
    stat = ability_counts(routes, version, junction_credit, strict)
    res = {}
    for a, (s, n) in stat.items():
        if n == 0:
            if skip_empty:
                continue
            raise ZeroDivisionError(f"b2d_abilities: no route of ability {a} (Bench2Drive divides by zero)")
        res[a] = float(s) / float(n)
    if res:
        res["mean"] = sum(res.values()) / len(res)
    return res


def first_junction_index(command, valid) -> np.ndarray:
    """0-based index of each route's first junction waypoint, -1 if none.

    A packed route (``types.Route``, 1 m spacing) marks the points inside the
    map's junction area (its connector lanes) with a LEFT / RIGHT / STRAIGHT
    command (``scenario.routes.route_commands``); B2D's ``wp.is_junction``
    is taken to be the first such valid point. Maps without connector lanes
    get LEFT / RIGHT only on sharp curves, which then stand in for the junction.

    Args:
      command: (..., R) int ``Command`` per route point.
      valid: (..., R) bool, valid points (a prefix).

    Returns: (...,) int64.
    """
    cmd = np.asarray(command)
    ok = np.asarray(valid, bool) & np.isin(cmd, (int(Command.LEFT), int(Command.RIGHT), int(Command.STRAIGHT)))
    return np.where(ok.any(axis=-1), ok.argmax(axis=-1), -1).astype(np.int64)


def route_from_result(r: RouteResult, first_junction_index: int | None = None,
                      num_waypoints: int | None = None) -> AbilityRoute:
    """``AbilityRoute`` of a leaderboard record (``category`` = its B2D scenario type)."""
    return AbilityRoute(
        scenario_types=() if r.category is None else (r.category,),
        success=r.success,
        route_completion_pct=r.score_route,
        first_junction_index=first_junction_index,
        num_waypoints=num_waypoints,
        stop_infractions=r.count("stop_infraction"),
        red_light_infractions=r.count("red_light"),
        route_id=r.route_id,
    )


def routes_from_rows(rows: Sequence[Mapping], types: Mapping[str, str] = BEHAVIOR_SCENARIO_TYPES) -> list[AbilityRoute]:
    """``AbilityRoute``s of per-scenario result rows whose ``behavior`` is in ``types``.

    Rows give ``success``, ``route_completion`` (%; only the junction test
    reads it), ``red_light``, ``stop_infraction`` (0 when absent) and, when the run recorded them,
    ``route_junction_index`` / ``route_waypoints`` (else None: no credit).
    """
    out = []
    for r in rows:
        if r.get("behavior") not in types:
            continue
        j, n = r.get("route_junction_index"), r.get("route_waypoints")
        out.append(AbilityRoute(
            scenario_types=(types[r["behavior"]],),
            success=bool(r["success"]),
            route_completion_pct=float(r.get("route_completion") or 0.0),
            first_junction_index=None if j is None or j == "" or int(j) < 0 else int(j),
            num_waypoints=None if n is None or n == "" else int(n),
            stop_infractions=int(r.get("stop_infraction") or 0),
            red_light_infractions=int(r.get("red_light") or 0),
            route_id=str(r.get("scenario_id", "")),
        ))
    return out


__all__ = [
    "ABILITY_NAMES",
    "AbilityRoute",
    "B2D_ABILITIES",
    "BEHAVIOR_SCENARIO_TYPES",
    "ability_counts",
    "b2d_abilities",
    "first_junction_index",
    "passes_junction",
    "route_from_result",
    "routes_from_rows",
]
