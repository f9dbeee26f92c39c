"""Per-route score: route completion, infraction score, Driving Score, status.

``route_score(outcome, config)`` is a pure JAX function of one route's event
counts and values (``RouteOutcome``; ``vmap`` it over a batch). It reproduces
``StatisticsManager.compute_route_statistics`` of the CARLA leaderboard
(``shared/reference/METRICS.md`` section 1) and its forks (sections 2, 3):

* IS = product of one factor per recorded event (LB 2.0), or
  prod(1 - p/100) / (1 + sum of weights) (LB 2.1);
* DS = round(max(RC * IS, 0), 6) with the *unrounded* IS; RC and IS are
  reported rounded to 6 decimals;
* status: RC >= 100 -> ``Perfect`` (no infraction entry at all) or
  ``Completed``; otherwise ``Failed - <reason>`` with the last reason that
  applies of: tick cap (``TickRuntime``, the crash message passed in), route
  timeout, route deviation, blocked;
* success (Bench2Drive / DriveE2E): Perfect or Completed and no infraction
  entry other than min-speed ones.

Precision: inside the simulator everything is float32 (DS good to ~1e-5). For
the reference-exact numbers run the same function on float64 inputs under
``jax.enable_x64(True)`` (``aggregate`` and the tests do).
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Literal

import jax.numpy as jnp
import numpy as np
from flax import struct

from drivee2e_jax.metrics import criteria

Array = jnp.ndarray


class Status(enum.IntEnum):
    """Route status code; ``STATUS_NAMES[code]`` is the leaderboard string."""

    PERFECT = 0
    COMPLETED = 1
    FAILED = 2
    FAILED_TIMEOUT = 3
    FAILED_DEVIATED = 4
    FAILED_BLOCKED = 5
    FAILED_TICK_RUNTIME = 6


STATUS_NAMES = (
    "Perfect",
    "Completed",
    "Failed",
    "Failed - Agent timed out",
    "Failed - Agent deviated from the route",
    "Failed - Agent got blocked",
    "Failed - TickRuntime",
)


def status_name(code) -> str:
    """Host-side: the leaderboard status string of a status code."""
    return STATUS_NAMES[int(code)]


#: Record keys of the per-route infraction lists, in the order of
#: ``RouteScore.infractions`` (Bench2Drive/LB 2.0 ``PENALTY_NAME_DICT`` + route_timeout).
INFRACTION_KEYS = (
    "collisions_layout",
    "collisions_pedestrian",
    "collisions_vehicle",
    "red_light",
    "stop_infraction",
    "outside_route_lanes",
    "min_speed_infractions",
    "yield_emergency_vehicle_infractions",
    "scenario_timeouts",
    "route_dev",
    "vehicle_blocked",
    "route_timeout",
)


@dataclasses.dataclass(frozen=True)
class Penalty:
    """One row of the penalty table.

    Attributes:
      key:    record key (``INFRACTION_KEYS``).
      event:  scenario_runner ``TrafficEventType`` name.
      lb20:   LB 2.0 factor per event; for min speed / outside lanes the
              formula is given in ``kind``.
      lb21:   LB 2.1 weight w per event (IS = prod(1 - p/100) / (1 + sum w)).
      kind:   "fixed", "min_speed" (LB 2.0: 1 - 0.3 (1 - v/100); LB 2.1:
              w = 0.4 (1 - v/100)), "outside_lanes" (factor 1 - p/100 in both),
              or "terminal" (no penalty, ends the route).
    """

    key: str
    event: str
    lb20: float
    lb21: float
    kind: str = "fixed"


#: The penalty coefficients (METRICS.md section 1 table and LB 2.1 variant).
PENALTIES: tuple[Penalty, ...] = (
    Penalty("collisions_pedestrian", "COLLISION_PEDESTRIAN", 0.50, 1.00),
    Penalty("collisions_vehicle", "COLLISION_VEHICLE", 0.60, 0.70),
    Penalty("collisions_layout", "COLLISION_STATIC", 0.65, 0.60),
    Penalty("red_light", "TRAFFIC_LIGHT_INFRACTION", 0.70, 0.40),
    Penalty("stop_infraction", "STOP_INFRACTION", 0.80, 0.25),
    Penalty("scenario_timeouts", "SCENARIO_TIMEOUT", 0.70, 0.40),
    Penalty("yield_emergency_vehicle_infractions", "YIELD_TO_EMERGENCY_VEHICLE", 0.70, 0.40),
    Penalty("min_speed_infractions", "MIN_SPEED_INFRACTION", 0.70, 0.40, "min_speed"),
    Penalty("outside_route_lanes", "OUTSIDE_ROUTE_LANES_INFRACTION", 0.0, 0.0, "outside_lanes"),
    Penalty("route_dev", "ROUTE_DEVIATION", 1.0, 0.0, "terminal"),
    Penalty("vehicle_blocked", "VEHICLE_BLOCKED", 1.0, 0.0, "terminal"),
    Penalty("route_timeout", "(RouteTimeoutBehavior)", 1.0, 0.0, "terminal"),
)
_PEN = {p.key: p for p in PENALTIES}

ScoreFormula = Literal["lb20", "lb21"]

#: ``ScoreConfig.collision_mode`` choices (``--collisions``); "all" is the paper's protocol.
COLLISION_MODES = ("all", "at_fault")


@dataclasses.dataclass(frozen=True)
class ScoreConfig:
    """Which criteria run and how a route is scored (static under jit).

    Attributes:
      name: preset name.
      formula: "lb20" (product of factors) or "lb21" (1 / (1 + sum of weights)).
      rc_threshold: route completed when RC > this (strict), %.
      rc_distance_m: ... and the ego is closer than this to the last point.
      min_speed_checkpoints: MinimumSpeedRouteTest ``checkpoints``.
      min_speed_penalised: min-speed events reduce IS.
      min_speed_record_all: every closed checkpoint is a recorded event (B2D),
        not only those < 100 % (LB 2.0, DriveE2E). Recorded events count as
        infraction entries (Perfect vs Completed) either way.
      blocked_max_time_s: ActorBlockedTest ``max_time``.
      time_cap_s: simulated time after which the route is cut with
        ``Failed - TickRuntime`` (None: no cap). The caller evaluates ticks
        while ``t <= time_cap_s`` (see ``max_ticks``).
      collisions, red_light, stop_sign, outside_lanes, min_speed, in_route,
        blocked, route_timeout: each criterion on/off. A disabled criterion
        records nothing (as if absent from the criteria tree).
      collision_mode: which collisions the headline DS / IS / success count
        (``COLLISION_MODES``): "all" (every contact with a logged agent or
        the layout: the paper's protocol) or "at_fault" (nuPlan's attribution,
        ``infractions.at_fault``). Both views are always computed
        (``metrics.episode.EpisodeResult``); this picks the headline.
      vru_at_fault: a contact with a pedestrian or cyclist is always the
        ego's fault (as V-Max scores it), whatever its nuPlan type.
    """

    name: str = "lb20"
    formula: ScoreFormula = "lb20"
    rc_threshold: float = criteria.RC_THRESHOLD_LB
    rc_distance_m: float = criteria.RC_DISTANCE_M
    min_speed_checkpoints: int = 4
    min_speed_penalised: bool = True
    min_speed_record_all: bool = False
    blocked_max_time_s: float = 180.0
    time_cap_s: float | None = None
    collisions: bool = True
    red_light: bool = True
    stop_sign: bool = True
    outside_lanes: bool = True
    min_speed: bool = True
    in_route: bool = True
    blocked: bool = True
    route_timeout: bool = True
    collision_mode: str = "all"
    vru_at_fault: bool = False

    def __post_init__(self):
        if self.collision_mode not in COLLISION_MODES:
            raise ValueError(f"unknown collision mode {self.collision_mode!r}; expected one of {', '.join(COLLISION_MODES)}")
        if self.formula not in ("lb20", "lb21"):
            raise ValueError(f"ScoreConfig.formula must be 'lb20' or 'lb21', got {self.formula!r}")
        if not 0.0 <= self.rc_threshold < 100.0:
            raise ValueError(f"ScoreConfig.rc_threshold must be in [0, 100), got {self.rc_threshold}")
        if not self.rc_distance_m > 0:
            raise ValueError(f"ScoreConfig.rc_distance_m must be > 0, got {self.rc_distance_m}")
        if int(self.min_speed_checkpoints) != self.min_speed_checkpoints or self.min_speed_checkpoints < 1:
            raise ValueError(f"ScoreConfig.min_speed_checkpoints must be an int >= 1, got {self.min_speed_checkpoints}")
        if not self.blocked_max_time_s > 0:
            raise ValueError(f"ScoreConfig.blocked_max_time_s must be > 0, got {self.blocked_max_time_s}")
        if self.time_cap_s is not None and not self.time_cap_s > 0:
            raise ValueError(f"ScoreConfig.time_cap_s must be > 0 or None, got {self.time_cap_s}")

    def max_ticks(self, dt: float) -> int | None:
        """Number of ticks of ``dt`` whose criteria are evaluated before the cap
        cuts the route (the next tick is the ``TickRuntime`` one); None if no cap."""
        if self.time_cap_s is None:
            return None
        return int(round(self.time_cap_s / dt))

    # -- presets -------------------------------------------------------------
    @classmethod
    def lb20(cls) -> ScoreConfig:
        """CARLA Leaderboard 2.0.

        Source: ``statistics_manager.py`` + ``route_scenario.py``: every
        criterion; RC threshold 99 %; MinSpeed 4 checkpoints, events only
        < 100 %, factor 1 - 0.3 (1 - v/100); blocked 180 s; RouteTimeout
        300 s + arc / (0.1 limit). We: the same.
        """
        return cls(name="lb20")

    @classmethod
    def lb21(cls) -> ScoreConfig:
        """CARLA Leaderboard 2.1 (branch ``leaderboard-2.1``).

        Source: the LB 2.0 criteria with IS = prod(1 - p/100) / (1 + sum w).
        We: the same (``PENALTIES[*].lb21`` weights).
        """
        return cls(name="lb21", formula="lb21")

    @classmethod
    def b2d(cls) -> ScoreConfig:
        """Bench2Drive 0.0.4.

        Source: LB 2.0 fork; MinSpeed with 20 checkpoints, every checkpoint
        recorded (also >= 100 %) with penalty type ``unused``; blocked 60 s;
        routes cut after 4000 ticks at 20 Hz (200 s) with ``Failed -
        TickRuntime``; success = Perfect/Completed without any infraction
        entry but min speed. We: the same, with the cap as 200 s of simulated
        time (2000 ticks at our 10 Hz).
        """
        return cls(
            name="b2d",
            min_speed_checkpoints=20,
            min_speed_penalised=False,
            min_speed_record_all=True,
            blocked_max_time_s=60.0,
            time_cap_s=200.0,
        )

    @classmethod
    def drivee2e(cls) -> ScoreConfig:
        """DriveE2E (the source benchmark's code, blindpub/DriveE2E).

        Source: LB 2.0 scoring (min speed penalised, events only < 100 %,
        4 checkpoints); RouteCompletionTest threshold 97 %; OutsideRouteLanes
        and RunningRedLight commented out of ``route_scenario.py``; blocked
        60 s; 10 Hz with ``simulation_time_thd`` = 12 s, checked as
        ``tick_count > 120`` *before* the tick is counted, so 121 ticks are
        evaluated and the 122nd is ``Failed - TickRuntime``. We: the same
        (red light and outside lanes off; cap 12.1 s = 121 ticks at 10 Hz).
        BackgroundActivity is removed in the source, so its min-speed
        checkpoints only get samples from replayed actors with role
        ``background``; we count replayed vehicles near the ego (see
        ``infractions.background_speed``).
        """
        return cls(
            name="drivee2e",
            rc_threshold=97.0,
            blocked_max_time_s=60.0,
            time_cap_s=12.1,
            red_light=False,
            outside_lanes=False,
        )

    @classmethod
    def preset(cls, name: str) -> ScoreConfig:
        """A preset by name: lb20, lb21, b2d, drivee2e."""
        try:
            return {"lb20": cls.lb20, "lb21": cls.lb21, "b2d": cls.b2d, "drivee2e": cls.drivee2e}[name]()
        except KeyError:
            raise ValueError(f"unknown score preset {name!r}; expected one of lb20, lb21, b2d, drivee2e") from None


# ---------------------------------------------------------------------------
# Per-route inputs and outputs
# ---------------------------------------------------------------------------


@struct.dataclass
class RouteOutcome:
    """What the criteria recorded for one route (unbatched).

    Attributes:
      route_completion: () float RC, % (100 when completed).
      collisions_pedestrian, collisions_vehicle, collisions_layout, red_light,
      stop_infraction, scenario_timeouts, yield_emergency_vehicle:
        () int32 event counts.
      outside_lanes_m:   () float distance driven off-lane, m (0: no event).
      outside_lanes_pct: () float its percentage of the traversed route.
      min_speed_pct:     (K,) float every closed checkpoint's value, %.
      min_speed_valid:   (K,) bool.
      route_deviation, vehicle_blocked, route_timeout: () bool terminal events.
      tick_runtime:      () bool, the route was cut by the time cap or by the
                         end of the replay log (``Failed - TickRuntime``).
    """

    route_completion: Array
    collisions_pedestrian: Array
    collisions_vehicle: Array
    collisions_layout: Array
    red_light: Array
    stop_infraction: Array
    scenario_timeouts: Array
    yield_emergency_vehicle: Array
    outside_lanes_m: Array
    outside_lanes_pct: Array
    min_speed_pct: Array
    min_speed_valid: Array
    route_deviation: Array
    vehicle_blocked: Array
    route_timeout: Array
    tick_runtime: Array

    @classmethod
    def empty(cls, checkpoints: int, dtype=jnp.float32) -> RouteOutcome:
        """An outcome with nothing recorded (RC 0); fill it with ``replace``."""
        i = jnp.zeros((), jnp.int32)
        f = jnp.zeros((), dtype)
        b = jnp.zeros((), bool)
        return cls(
            route_completion=f,
            collisions_pedestrian=i,
            collisions_vehicle=i,
            collisions_layout=i,
            red_light=i,
            stop_infraction=i,
            scenario_timeouts=i,
            yield_emergency_vehicle=i,
            outside_lanes_m=f,
            outside_lanes_pct=f,
            min_speed_pct=jnp.zeros((checkpoints,), dtype),
            min_speed_valid=jnp.zeros((checkpoints,), bool),
            route_deviation=b,
            vehicle_blocked=b,
            route_timeout=b,
            tick_runtime=b,
        )


@struct.dataclass
class RouteScore:
    """The per-route record (unbatched).

    Attributes:
      route_completion:   () float score_route, %, rounded to 6.
      infraction_penalty: () float score_penalty (IS), rounded to 6.
      driving_score:      () float score_composed (DS), %, rounded to 6.
      status:             () int32 ``Status``.
      success:            () bool (Bench2Drive / DriveE2E rule).
      infractions:        (12,) int32 entries per ``INFRACTION_KEYS``.
      num_infractions:    () int32 total entries.
      outside_lanes_m:    () float off-lane distance, m (aggregation uses km).
      min_speed_pct:      (K,) float checkpoint values.
      min_speed_recorded: (K,) bool which of them are recorded events.
    """

    route_completion: Array
    infraction_penalty: Array
    driving_score: Array
    status: Array
    success: Array
    infractions: Array
    num_infractions: Array
    outside_lanes_m: Array
    min_speed_pct: Array
    min_speed_recorded: Array


def _round6(x: Array) -> Array:
    return criteria.round_decimals(x, 6)


def _on(flag: bool, x: Array) -> Array:
    return x if flag else jnp.zeros_like(x)


def route_score(outcome: RouteOutcome, cfg: ScoreConfig) -> RouteScore:
    """Score one route (pure, jittable; ``vmap`` over routes)."""
    o = outcome
    fdt = jnp.result_type(o.route_completion, jnp.float32)
    rc = o.route_completion.astype(fdt)
    counts = {
        "collisions_pedestrian": _on(cfg.collisions, o.collisions_pedestrian),
        "collisions_vehicle": _on(cfg.collisions, o.collisions_vehicle),
        "collisions_layout": _on(cfg.collisions, o.collisions_layout),
        "red_light": _on(cfg.red_light, o.red_light),
        "stop_infraction": _on(cfg.stop_sign, o.stop_infraction),
        "scenario_timeouts": o.scenario_timeouts,
        "yield_emergency_vehicle_infractions": o.yield_emergency_vehicle,
    }
    outside_m = _on(cfg.outside_lanes, o.outside_lanes_m).astype(fdt)
    outside = outside_m > 0
    outside_factor = jnp.where(outside, 1.0 - o.outside_lanes_pct.astype(fdt) / 100.0, 1.0)
    v = o.min_speed_pct.astype(fdt)
    recorded = o.min_speed_valid & cfg.min_speed & (cfg.min_speed_record_all | (v < 100.0))
    penalised = recorded & cfg.min_speed_penalised
    deviated = _on(cfg.in_route, o.route_deviation)
    blocked = _on(cfg.blocked, o.vehicle_blocked)
    timeout = _on(cfg.route_timeout, o.route_timeout)
    # Set by whatever cut the route: the preset's cap or, in replay, the end
    # of the log (no traffic exists past it), so honoured for every preset.
    tick_cap = o.tick_runtime

    if cfg.formula == "lb20":
        ips = jnp.ones((), fdt)
        for key, n in counts.items():
            ips = ips * jnp.power(jnp.asarray(_PEN[key].lb20, fdt), n.astype(fdt))
        ips = ips * outside_factor
        ms_factor = 1.0 - (1.0 - _PEN["min_speed_infractions"].lb20) * (1.0 - v / 100.0)
        ips = ips * jnp.prod(jnp.where(penalised, ms_factor, 1.0))
    else:
        w = sum(_PEN[key].lb21 * n.astype(fdt) for key, n in counts.items())
        w = w + jnp.sum(jnp.where(penalised, _PEN["min_speed_infractions"].lb21 * (1.0 - v / 100.0), 0.0))
        ips = outside_factor * (1.0 / (1.0 + w))

    entries = {
        **counts,
        "outside_route_lanes": outside.astype(jnp.int32),
        "min_speed_infractions": jnp.sum(recorded.astype(jnp.int32)),
        "route_dev": deviated.astype(jnp.int32),
        "vehicle_blocked": blocked.astype(jnp.int32),
        "route_timeout": timeout.astype(jnp.int32),
    }
    infractions = jnp.stack([jnp.asarray(entries[k], jnp.int32) for k in INFRACTION_KEYS])
    num = jnp.sum(infractions)
    reached = rc >= 100.0
    # Failure reason: the last that applies, in the source's overwrite order.
    reason = jnp.int32(Status.FAILED)
    for flag, code in ((tick_cap, Status.FAILED_TICK_RUNTIME), (timeout, Status.FAILED_TIMEOUT),
                       (deviated, Status.FAILED_DEVIATED), (blocked, Status.FAILED_BLOCKED)):
        reason = jnp.where(flag, jnp.int32(code), reason)
    status = jnp.where(reached, jnp.where(num > 0, jnp.int32(Status.COMPLETED), jnp.int32(Status.PERFECT)), reason)
    non_min_speed = num - entries["min_speed_infractions"]
    return RouteScore(
        route_completion=_round6(rc),
        infraction_penalty=_round6(ips),
        driving_score=_round6(jnp.maximum(rc * ips, 0.0)),
        status=status,
        success=(status <= Status.COMPLETED) & (non_min_speed == 0),
        infractions=infractions,
        num_infractions=num,
        outside_lanes_m=outside_m,
        min_speed_pct=v,
        min_speed_recorded=recorded,
    )


# ---------------------------------------------------------------------------
# Host-side: leaderboard event lists -> RouteOutcome
# ---------------------------------------------------------------------------

_COUNT_FIELD = {
    "COLLISION_PEDESTRIAN": "collisions_pedestrian",
    "COLLISION_VEHICLE": "collisions_vehicle",
    "COLLISION_STATIC": "collisions_layout",
    "TRAFFIC_LIGHT_INFRACTION": "red_light",
    "STOP_INFRACTION": "stop_infraction",
    "SCENARIO_TIMEOUT": "scenario_timeouts",
    "YIELD_TO_EMERGENCY_VEHICLE": "yield_emergency_vehicle",
}
_FLAG_FIELD = {"ROUTE_DEVIATION": "route_deviation", "VEHICLE_BLOCKED": "vehicle_blocked"}


def outcome_from_events(
    events, route_timeout: bool = False, tick_runtime: bool = False, checkpoints: int | None = None
) -> RouteOutcome:
    """Host-side: a ``RouteOutcome`` (float64 numpy leaves) from a list of
    scenario_runner traffic events, e.g. to score a CARLA record with
    ``route_score``.

    Each event is a dict with ``type`` (a ``TrafficEventType`` name) and, by
    type: ``route_completed`` (ROUTE_COMPLETION; the last one wins),
    ``percentage`` (MIN_SPEED_INFRACTION, OUTSIDE_ROUTE_LANES_INFRACTION),
    ``distance`` m (OUTSIDE_ROUTE_LANES_INFRACTION). ``checkpoints`` sizes
    the min-speed arrays (default: the number of min-speed events, >= 1).
    """
    counts = {f: 0 for f in _COUNT_FIELD.values()}
    flags = {f: False for f in _FLAG_FIELD.values()}
    rc, outside_m, outside_pct, speeds = 0.0, 0.0, 0.0, []
    seen_outside = False
    for i, ev in enumerate(events):
        kind = ev.get("type")
        if kind == "ROUTE_COMPLETION":
            rc = float(ev["route_completed"])
        elif kind in _COUNT_FIELD:
            counts[_COUNT_FIELD[kind]] += 1
        elif kind in _FLAG_FIELD:
            flags[_FLAG_FIELD[kind]] = True
        elif kind == "MIN_SPEED_INFRACTION":
            speeds.append(float(ev["percentage"]))
        elif kind == "OUTSIDE_ROUTE_LANES_INFRACTION":
            if seen_outside:
                raise ValueError(f"events[{i}]: a route has at most one OUTSIDE_ROUTE_LANES_INFRACTION")
            seen_outside = True
            outside_m, outside_pct = float(ev["distance"]), float(ev["percentage"])
        else:
            raise ValueError(f"events[{i}].type: unknown traffic event {kind!r}")
    k = max(len(speeds), 1) if checkpoints is None else checkpoints
    if len(speeds) > k:
        raise ValueError(f"{len(speeds)} MIN_SPEED_INFRACTION events but checkpoints={k}")
    pct = np.zeros((k,), np.float64)
    pct[: len(speeds)] = speeds
    i32 = lambda x: np.asarray(x, np.int32)  # noqa: E731
    return RouteOutcome(
        route_completion=np.asarray(rc, np.float64),
        **{f: i32(n) for f, n in counts.items()},
        outside_lanes_m=np.asarray(outside_m, np.float64),
        outside_lanes_pct=np.asarray(outside_pct, np.float64),
        min_speed_pct=pct,
        min_speed_valid=np.arange(k) < len(speeds),
        route_deviation=np.asarray(flags["route_deviation"]),
        vehicle_blocked=np.asarray(flags["vehicle_blocked"]),
        route_timeout=np.asarray(bool(route_timeout)),
        tick_runtime=np.asarray(bool(tick_runtime)),
    )


#: Scoring presets by name (``--preset``); ``paper`` is the default.
SCORE_PRESETS = ("paper", "drivee2e", "lb20", "lb21", "b2d", "nuplan", "navsim")
#: Presets whose headline is another benchmark's closed-loop score computed
#: beside the leaderboard criteria (``metrics.nuplan``, ``metrics.navsim``).
CLOSED_LOOP_SCORES = {"nuplan": "nuplan_score", "navsim": "epdms"}


def score_preset(name: str) -> ScoreConfig:
    """A scoring preset by name.

    ``paper`` (default) is DriveE2E as its paper defines it (App. A): Driving
    Score with Leaderboard 2.0 penalties, RC threshold 97 % as in its code,
    blocked after 60 s, and Success = route completed "without collisions or
    traffic violations", so red light and outside-route-lanes are ON (its code
    comments them out; see ``drivee2e``). The time cap is the scenario's log
    length (the source's 12 s cap is its clip length; twin15 logs are 20 s).
    Minimum speed is OFF: under non-reactive replay the surrounding traffic
    includes cross traffic moving on its green, which would penalise the
    correct stop at a red light; the source's replayed actors carry no
    ``background`` role, so its checkpoints get no samples either (v = 100).
    ``nuplan`` and ``navsim`` run the ``paper`` criteria (so RC / DS stay
    comparable) and add nuPlan's closed-loop score (``metrics.nuplan``) or
    NAVSIM's EPDMS (``metrics.navsim``) with every sub-metric as a column.
    The other names are ``ScoreConfig`` presets (``drivee2e`` = the source
    code's exact rules incl. its 12.1 s cap).
    """
    if name in ("paper", "nuplan", "navsim"):
        return dataclasses.replace(
            ScoreConfig.drivee2e(), name=name, time_cap_s=None, red_light=True, outside_lanes=True, min_speed=False
        )
    if name not in SCORE_PRESETS:
        raise ValueError(f"unknown score preset {name!r}; expected one of {', '.join(SCORE_PRESETS)}")
    return ScoreConfig.preset(name)
