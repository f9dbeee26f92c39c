"""NAVSIM v2 EPDMS in closed loop (``metrics.navsim``): every sub-metric on
hand-built inputs, expected values derived from NAVSIM's code
(autonomousvision/navsim HEAD; S = navsim/planning/simulation/planner/
pdm_planner/scoring/pdm_scorer.py, C = .../scoring/pdm_comfort_metrics.py,
E = navsim/evaluate/pdm_score.py)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from shapely.geometry import LineString, Point

from drivee2e_jax.metrics import navsim
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import EgoState
from tests.helpers import lanes as lane_helpers
from tests.helpers.navsim_cases import straight_log, straight_scenario

LW = jnp.array([4.0, 2.0])


def _ego(x=0.0, y=0.0, yaw=0.0, speed=10.0) -> EgoState:
    f = jnp.float32
    return EgoState(
        xy=jnp.array([x, y], jnp.float32), yaw=f(yaw), speed=f(speed), accel=f(0), steer=f(0), yaw_rate=f(0), t=f(0)
    )


def _ttc(ego, ax, ay, vx=0.0, lax=False) -> bool:
    """One agent box 4 x 2 m at (ax, ay), heading 0, velocity (vx, 0)."""
    return bool(
        navsim.ttc_violation(
            ego,
            LW,
            jnp.array([[ax, ay]]),
            jnp.zeros(1),
            jnp.array([[vx, 0.0]]),
            jnp.array([[4.0, 2.0]]),
            jnp.array([True]),
            jnp.asarray(lax),
            2.9,
        )
    )


# --- TTC (S _calculate_ttc: projections at 0, 0.3, 0.6, 0.9 s) ----------------


def test_ttc_last_projection_at_0_9_s():
    # Stationary agent, ego 10 m/s: boxes touch once the centre gap <= 4 m,
    # i.e. from tau = (D - 4) / 10. D = 12.9 -> 0.89 s: the 0.9 s projection hits.
    assert _ttc(_ego(), 12.9, 0.0)
    # D = 13.1 -> 0.91 s: after the last projection (0.9 s) -> no violation.
    assert not _ttc(_ego(), 13.1, 0.0)


def test_ttc_samples_only_0_3_s_steps():
    # Ego 40 m/s passes through a stationary agent: overlap for tau in
    # [(D - 4) / 40, (D + 4) / 40]. D = 14 -> [0.25, 0.45] contains 0.3 s.
    assert _ttc(_ego(speed=40.0), 14.0, 0.0)
    # D = 16.8 -> [0.32, 0.52]: between the 0.3 and 0.6 s projections.
    assert not _ttc(_ego(speed=40.0), 16.8, 0.0)


def test_ttc_agents_move_at_constant_velocity():
    # Agent 13.1 m ahead driving away at 5 m/s: gap grows, never hit.
    assert not _ttc(_ego(), 13.1, 0.0, vx=5.0)
    # ... oncoming at -5 m/s: closing 15 m/s, touch at 9.1 / 15 = 0.61 s -> 0.9 s hits.
    assert _ttc(_ego(), 13.1, 0.0, vx=-5.0)


def test_ttc_stopped_ego_and_direction_rules():
    # Touching agent ahead, ego below 5e-3 m/s (stopped_speed_threshold) -> ignored.
    assert not _ttc(_ego(speed=0.004), 4.0, 0.0)
    assert _ttc(_ego(speed=0.006), 4.0, 0.0)
    # Agent touching the rear (relative angle from the rear axle 180 deg) never counts.
    assert not _ttc(_ego(speed=1.0), -4.0, 0.0)
    assert not _ttc(_ego(speed=1.0), -4.0, 0.0, lax=True)
    # Agent alongside: angle atan2(2, 1.45) = 54 deg from the rear axle: not
    # ahead (> 30 deg); counts only in the lax zone (multi-lane / off-road /
    # junction) where "not behind" (< 150 deg) suffices.
    assert not _ttc(_ego(speed=1.0), 0.0, 2.0)
    assert _ttc(_ego(speed=1.0), 0.0, 2.0, lax=True)


# --- tick: junction, oncoming ------------------------------------------------------


def _lanes():
    x = np.arange(-10.0, 31.0, 2.0)
    lane0 = np.stack([x, np.zeros_like(x)], -1)  # DRIVING along +x at y = 0
    lane1 = np.stack([x, np.full_like(x, 10.0)], -1)  # CONNECTOR along +x at y = 10
    return lane_helpers.lane_map([lane0, lane1], types=[lane_helpers.DRIVING, lane_helpers.CONNECTOR])


def _tick(ego, agent_xy=(100.0, 100.0)):
    agents = AgentStates(xy=jnp.array([agent_xy]), yaw=jnp.zeros(1), vel=jnp.zeros((1, 2)), valid=jnp.array([True]))
    el = lane_helpers.ego_lanes(ego, LW, _lanes(), rear_offset=1.45)
    return navsim.tick(ego, LW, agents, jnp.array([[4.0, 2.0, 1.5]]), jnp.array([0]), jnp.array([True]),
                       el.centre_in, el.rear_in, el.tangent, el.connector, centre_offset=el.centre_offset)


def test_tick_junction_and_oncoming():
    t = _tick(_ego(5.0, 0.0))
    assert not bool(t.in_junction) and not bool(t.oncoming) and not bool(t.ttc_violation)
    # Same place, heading reversed: the only lane there runs the other way.
    assert bool(_tick(_ego(5.0, 0.0, yaw=math.pi)).oncoming)
    # 1.6 m off the lane centre (< 3.5 / 2) is still inside; 1.9 m is not.
    assert not bool(_tick(_ego(5.0, 1.6)).oncoming)
    assert bool(_tick(_ego(5.0, 1.9)).oncoming)
    # On the connector lane: in a junction.
    assert bool(_tick(_ego(5.0, 10.0)).in_junction)
    # Agent 12.9 m ahead, stationary: TTC at 0.9 s (as above) through tick.
    assert bool(_tick(_ego(5.0, 0.0), agent_xy=(17.9, 0.0)).ttc_violation)


def test_tick_rear_axle_in_junction_is_lax_zone():
    # Agent alongside (54 deg from the rear axle): counts only because the
    # rear axle (1.45 m behind the centre) lies on the connector lane.
    assert bool(_tick(_ego(5.0, 10.0, speed=1.0), agent_xy=(5.0, 12.0)).ttc_violation)
    assert not bool(_tick(_ego(5.0, 0.0, speed=1.0), agent_xy=(5.0, 2.0)).ttc_violation)


# --- NC, DAC, TLC, TTC columns -------------------------------------------------------


def _hits(n, steps, ids, fault):
    hit, hid, af = np.zeros(n, bool), np.full(n, -1), np.zeros(n, bool)
    for s, i, f in zip(steps, ids, fault):
        hit[s], hid[s], af[s] = True, i, f
    return {"f_agent_hit": hit, "f_agent_hit_id": hid, "f_at_fault": af}


def test_nc_at_fault_ignored_and_objects():
    sc = straight_scenario()
    cols = lambda log: navsim.episode_columns(log, sc, 0.1)  # noqa: E731
    # S _calculate_no_at_fault_collision: a not-at-fault hit puts id 7 on the
    # ignore list, its later at-fault contact does not count.
    assert cols(straight_log(20, **_hits(20, [3, 5], [7, 7], [False, True])))["navsim_nc"] == 1.0
    assert cols(straight_log(20, **_hits(20, [3, 5], [7, 8], [False, True])))["navsim_nc"] == 0.0
    # Static object while moving: STOPPED_TRACK, at fault, 0.5; at 0.04 m/s
    # (<= 0.05, get_collision_type) it is STOPPED_EGO: ignored.
    lh = np.zeros(20, bool)
    lh[4] = True
    assert cols(straight_log(20, f_layout_hit=lh))["navsim_nc"] == 0.5
    assert cols(straight_log(20, speed=np.full(20, 0.04), f_layout_hit=lh))["navsim_nc"] == 1.0


def test_nc_every_track_at_once_and_obstacle_identity():
    """S ``_calculate_no_at_fault_collision`` loops over EVERY geometry intersecting the
    ego at a step (``query(..., predicate="intersects")``), and a static object first
    met while the ego stands (U ``get_collision_type``: STOPPED_EGO, not at fault)
    goes on ``proposal_collided_track_ids``: ignored afterwards.

    Worked case (arrays as ``infractions.ContactSet``): at step 3 track 7 (not at
    fault, the nearest) and track 8 (at fault) touch together -> 0 (keeping only
    the nearest gave 1). Obstacle 1 touched at 0.0 m/s (step 2), then again
    while moving (step 6): ignored -> 1 (without identity: 0.5)."""
    n = 10
    act = np.ones(n, bool)
    hit = np.zeros((n, 2), bool)
    hit[3] = True
    tid = np.tile([7, 8], (n, 1))
    fault = np.zeros((n, 2), bool)
    fault[3, 1] = True
    lay = np.zeros((n, 2), bool)
    speed = np.full(n, 3.0)
    assert navsim.no_at_fault_collision(act, hit, tid, fault, lay, speed) == 0.0
    assert navsim.no_at_fault_collision(act, hit[:, 0], tid[:, 0], fault[:, 0], lay[:, 0], speed) == 1.0
    none = (np.zeros((n, 2), bool), tid, np.zeros((n, 2), bool))
    lay[[2, 6], 1] = True
    speed[2] = 0.0
    assert navsim.no_at_fault_collision(act, *none, lay, speed) == 1.0
    assert navsim.no_at_fault_collision(act, *none[0:3], lay.any(1), speed) == 0.5
    lay[8, 0] = True  # another obstacle hit while moving: an object collision
    assert navsim.no_at_fault_collision(act, *none, lay, speed) == 0.5


def test_dac_tlc_ttc_any_active_step():
    sc = straight_scenario()
    flag = np.zeros(20, bool)
    flag[7] = True
    ex = np.where(flag, 0.01, 0.0)
    c = navsim.episode_columns(
        straight_log(20, f_drivable_excess_m=ex, f_red_light=flag, nv_ttc_violation=flag), sc, 0.1
    )
    assert (c["navsim_dac"], c["navsim_tlc"], c["navsim_ttc"]) == (0.0, 0.0, 0.0)
    inactive = ~flag
    c = navsim.episode_columns(
        straight_log(20, active=inactive, f_drivable_excess_m=ex, f_red_light=flag, nv_ttc_violation=flag), sc, 0.1
    )
    assert (c["navsim_dac"], c["navsim_tlc"], c["navsim_ttc"]) == (1.0, 1.0, 1.0)


# --- DDC (S _calculate_driving_direction_compliance) ---------------------------------


def _ddc(onc_steps, junction_steps=(), n=40, speed=12.0):
    """1.2 m per step at 12 m/s, dt 0.1; window = steps [t - 10, t]."""
    onc, jn = np.zeros(n, bool), np.zeros(n, bool)
    onc[list(onc_steps)] = True
    jn[list(junction_steps)] = True
    log = straight_log(n, speed=speed)
    return navsim.driving_direction_compliance(log.active, log.xy, onc, jn, 0.1)


def test_ddc_thresholds_and_window():
    assert _ddc([5]) == 1.0  # 1.2 m < 2
    assert _ddc([5, 6]) == 0.5  # 2.4 m in [2, 6)
    assert _ddc(range(5, 10)) == 0.0  # 6.0 m: not < 6 -> 0
    assert _ddc(range(5, 9)) == 0.5  # 4.8 m
    # Two 1.2 m bursts 10 steps apart share a window [t - 10, t]; 11 apart do not.
    assert _ddc([5, 15]) == 0.5
    assert _ddc([5, 16]) == 1.0
    # Oncoming inside a junction is not counted.
    assert _ddc(range(5, 12), junction_steps=range(5, 12)) == 1.0


# --- LK (S _calculate_lane_keeping: ceil(2 s / 0.1 s) = 20 consecutive steps) ---------


def _lk(offsets, junction=None):
    off = np.asarray(offsets, float)
    jn = np.zeros(len(off), bool) if junction is None else np.asarray(junction)
    return navsim.lane_keeping(np.ones(len(off), bool), off, jn, 0.1)


def test_lk_1_9_s_passes_2_1_s_fails():
    assert _lk([0.0] * 5 + [0.6] * 19 + [0.0] * 5) == 1.0  # 1.9 s
    assert _lk([0.0] * 5 + [0.6] * 20 + [0.0] * 5) == 0.0  # 2.0 s reaches the 20 steps
    assert _lk([0.0] * 5 + [0.6] * 21 + [0.0] * 5) == 0.0  # 2.1 s
    assert _lk([0.5] * 40) == 1.0  # strictly greater than 0.5 m


def test_lk_junction_skips_without_reset():
    # NAVSIM's `continue`: a junction step neither counts nor resets.
    off = [0.6] * 10 + [0.0] + [0.6] * 10
    assert _lk(off) == 1.0
    assert _lk(off, junction=[False] * 10 + [True] + [False] * 10) == 0.0
    assert _lk([0.6] * 25, junction=[True] * 25) == 1.0


# --- LK's deviation: the centre's distance to the centreline of the lane holding it ------


def _lk_offset(ego, centrelines, types=None):
    lmap = lane_helpers.lane_map(centrelines, types=types)
    el = lane_helpers.ego_lanes(ego, LW, lmap)
    agents = AgentStates(xy=jnp.array([[900.0, 900.0]]), yaw=jnp.zeros(1), vel=jnp.zeros((1, 2)),
                         valid=jnp.array([True]))
    t = navsim.tick(ego, LW, agents, jnp.array([[4.0, 2.0, 1.5]]), jnp.array([0]), jnp.array([True]),
                    el.centre_in, el.rear_in, el.tangent, el.connector, centre_offset=el.centre_offset)
    return float(t.lane_offset)


def test_lk_offset_worked_cases():
    x = np.arange(-10.0, 41.0, 2.0)
    a = np.stack([x, np.zeros_like(x)], -1)  # along +x at y = 0, 3.5 m wide
    b = np.stack([x, np.full_like(x, 3.5)], -1)  # its left neighbour
    # 1.2 m left of lane a's centreline, inside a (|y| < 1.75): 1.2 m.
    assert _lk_offset(_ego(5.0, 1.2), [a, b]) == pytest.approx(1.2, abs=1e-5)
    # 2.0 m left of a is inside b, 1.5 m right of b's centreline: 1.5 m (not a's 2.0).
    assert _lk_offset(_ego(5.0, 2.0), [a, b]) == pytest.approx(1.5, abs=1e-5)
    # Off every lane (y = -2.5): the nearest lane's centreline, 2.5 m.
    assert _lk_offset(_ego(5.0, -2.5), [a, b]) == pytest.approx(2.5, abs=1e-5)
    # A curve: an arc of radius 20 m sampled every 1 m (chord sagitta 6.25 mm);
    # the ego 0.6 m outside the arc at 30 deg, heading along it. Its distance
    # to the sampled centreline, as shapely measures it (NAVSIM's
    # Point.distance(linestring)): 20.6 - 20 cos(0.025) / cos(0.0014) = 0.6062 m.
    th = np.arange(0.0, math.pi / 2, 1.0 / 20.0)
    arc = 20.0 * np.stack([np.cos(th), np.sin(th)], -1)
    p = 20.6 * np.array([math.cos(math.pi / 6), math.sin(math.pi / 6)])
    got = _lk_offset(_ego(p[0], p[1], yaw=math.pi / 6 + math.pi / 2), [arc])
    assert got == pytest.approx(Point(p).distance(LineString(arc)), abs=1e-4)
    assert got == pytest.approx(0.6062, abs=1e-3)


def test_lk_offset_picks_the_holding_lane_with_the_lowest_heading_error():
    # Lane a along +x; lane c branches off at 21.8 deg (atan 0.4). The centre
    # (6, 1.5) lies in both: 1.5 m from a's centreline and
    # |1.5 - 2.4| cos(21.8 deg) = 0.8357 m from c's (NAVSIM's starting lane:
    # the lowest heading error among the lanes holding the ego).
    x = np.arange(0.0, 41.0, 2.0)
    a = np.stack([x, np.zeros_like(x)], -1)
    c = np.stack([x, 0.4 * x], -1)
    assert _lk_offset(_ego(6.0, 1.5), [a, c]) == pytest.approx(1.5, abs=1e-5)
    yaw_c = math.atan(0.4)
    assert _lk_offset(_ego(6.0, 1.5, yaw=yaw_c), [a, c]) == pytest.approx(0.9 * math.cos(yaw_c), abs=1e-5)


def test_lk_offset_equally_aligned_lanes_take_the_nearest_centreline():
    # A wide lane (10 m, centreline y = 3) listed first and a 3.5 m lane at y = 0,
    # both holding (5, 0.5) and both parallel to the ego: a tie, not the first
    # listed (2.5 m) but the nearest centreline, 0.5 m (nuScenes scene-0103: a
    # lane polygon reaching 9 m beside its own short centreline).
    x = np.arange(-10.0, 41.0, 2.0)
    wide = np.stack([x, np.full_like(x, 3.0)], -1)
    a = np.stack([x, np.zeros_like(x)], -1)
    lmap = lane_helpers.lane_map([wide, a], widths=[10.0, 3.5])
    ego = _ego(5.0, 0.5)
    el = lane_helpers.ego_lanes(ego, LW, lmap)
    assert int(np.sum(np.asarray(el.centre_in))) == 2
    got = navsim.lk_offset(el.centre_in, el.tangent, el.centre_offset, ego.yaw)
    assert float(got) == pytest.approx(0.5, abs=1e-5)


def test_lk_reads_the_navsim_lane_offset_not_the_strip_offset():
    sc = straight_scenario()
    n = 40
    # the LB 2.0 strip offset says 0.9 m throughout, the lane-polygon offset 0.1 m: LK passes
    log = straight_log(n, f_lane_offset=np.full(n, 0.9), nv_lane_offset=np.full(n, 0.1))
    assert navsim.episode_columns(log, sc, 0.1)["navsim_lk"] == 1.0
    log = straight_log(n, f_lane_offset=np.zeros(n), nv_lane_offset=np.full(n, 0.6))
    assert navsim.episode_columns(log, sc, 0.1)["navsim_lk"] == 0.0


# --- EP (S _calculate_progress, _aggregate_pdm_scores) -------------------------------------


def test_ep_against_logged_progress():
    sc = straight_scenario(log_speed=10.0)
    # 5 s at 5 m/s: 25 m; the log covers 50 m in the same 5 s -> 25 / 50.
    assert navsim.episode_columns(straight_log(50, speed=5.0), sc, 0.1)["navsim_ep"] == pytest.approx(0.5, abs=1e-6)
    # Faster than the log: clipped to 1.
    assert navsim.episode_columns(straight_log(50, speed=12.0), sc, 0.1)["navsim_ep"] == 1.0
    # Reference <= 5 m (progress_distance_threshold): 1 whatever the ego did.
    assert navsim.episode_columns(straight_log(4, speed=1.0), sc, 0.1)["navsim_ep"] == 1.0


def test_ep_function():
    assert navsim.ego_progress(25.0, 1.0, 50.0) == 0.5
    # Own progress counts in the normaliser only with a non-zero multiplier product.
    assert navsim.ego_progress(60.0, 1.0, 50.0) == 1.0
    assert navsim.ego_progress(60.0, 0.0, 50.0) == 1.0
    assert navsim.ego_progress(20.0, 0.5, 30.0) == pytest.approx(2 / 3)
    assert navsim.ego_progress(3.0, 1.0, 4.9) == 1.0


# --- HC (C ego_is_comfortable) -------------------------------------------------------------


def _hc(accel, yaw_rate=0.0, speed=10.0, n=30, dt=0.1):
    t = np.arange(n) * dt
    a = accel(t) if callable(accel) else np.full(n, accel)
    return navsim.history_comfort(a, np.full(n, speed * yaw_rate), yaw_rate * t, dt)


def test_hc_bounds():
    # S-G of a constant / linear signal is exact: lon accel 1 in (-4.05, 2.40) passes, 2.5 fails.
    assert _hc(1.0) == 1.0
    assert _hc(2.5) == 0.0
    assert _hc(-4.0) == 1.0
    assert _hc(-4.1) == 0.0
    # lat accel = v * yaw rate: 10 * 0.4 = 4 < 4.89 passes (yaw rate 0.4 < 0.95); 10 * 0.5 = 5 fails.
    assert _hc(0.0, yaw_rate=0.4) == 1.0
    assert _hc(0.0, yaw_rate=0.5) == 0.0
    # lon jerk = slope of the accel: -3 m/s^3 passes, -5 exceeds 4.13 (accel stays > -4.05).
    assert _hc(lambda t: -3.0 * t, n=8) == 1.0
    assert _hc(lambda t: -5.0 * t, n=8) == 0.0
    # Yaw rate 1.0 rad/s > 0.95 at walking speed (lat accel 1.0).
    assert _hc(0.0, yaw_rate=1.0, speed=1.0) == 0.0


# --- EC (C ego_is_two_frame_extended_comfort) ------------------------------------------------


def _straight_plan(v=10.0, n=8, dt=0.5, y=0.0):
    tau = (np.arange(n) + 1) * dt
    return np.stack([v * tau, np.full(n, y)], -1)


def _arc_plan(v=10.0, w=0.3, n=8, dt=0.5):
    tau = (np.arange(n) + 1) * dt
    r = v / w
    return np.stack([r * np.sin(w * tau), r * (1 - np.cos(w * tau))], -1)


def test_ec_identical_and_shifted_plans():
    pose = (np.zeros(2), 0.0)
    p = _straight_plan()
    assert navsim.two_frame_comfort(p, pose, p, pose, 0.1) == 1.0
    # Ego moved 1 m along the plan during the 0.1 s step and re-plans the same motion.
    assert navsim.two_frame_comfort(p, pose, p, (np.array([1.0, 0.0]), 0.0), 0.1) == 1.0
    # Plan shifted 1 m sideways from the same pose: it now swerves 1 m within
    # the first 0.5 s (the plan starts at the ego, E transform_trajectory), so
    # yaw rate / lateral accel differ -> 0. Shifted with the ego pose: identical -> 1.
    assert navsim.two_frame_comfort(p, pose, _straight_plan(y=1.0), pose, 0.1) == 0.0
    assert navsim.two_frame_comfort(p, pose, p, (np.array([1.0, 1.0]), 0.0), 0.1) == 1.0
    # Curving at 0.3 rad/s vs straight: RMS yaw-rate difference ~0.3 > 0.1 (and v w = 3 m/s^2 > 0.7).
    assert navsim.two_frame_comfort(p, pose, _arc_plan(), pose, 0.1) == 0.0
    # Decelerating plan (waypoints of v = 10 - 2 tau) vs constant speed: accel RMS 2 > 0.7.
    tau = (np.arange(8) + 1) * 0.5
    brake = np.stack([10 * tau - tau**2, np.zeros(8)], -1)
    assert navsim.two_frame_comfort(p, pose, brake, pose, 0.1) == 0.0


def test_ec_episode_mean_and_none():
    sc = straight_scenario(log_speed=0.0)
    log = straight_log(4, speed=0.0)
    plans = np.stack([_straight_plan(), _straight_plan(), _arc_plan(), _arc_plan()])
    # Pairs (0,1) pass, (1,2) fail, (2,3) pass -> 2 / 3.
    assert navsim.episode_columns(log, sc, 0.1, plans=plans)["navsim_ec"] == pytest.approx(2 / 3)
    assert navsim.episode_columns(log, sc, 0.1)["navsim_ec"] == 1.0


# --- human filter (E) and EPDMS --------------------------------------------------------------


def test_human_filter_flips_zero_only():
    sc = straight_scenario()
    red = np.zeros(30, bool)
    red[10] = True
    agent = straight_log(30, f_red_light=red)
    assert navsim.episode_columns(agent, sc, 0.1)["navsim_tlc"] == 0.0
    assert navsim.episode_columns(agent, sc, 0.1, human=straight_log(30))["navsim_tlc"] == 0.0
    # The human ran the same red light: TLC = 0 for the human -> agent's TLC counts 1.
    c = navsim.episode_columns(agent, sc, 0.1, human=straight_log(30, f_red_light=red))
    assert c["navsim_tlc"] == 1.0 and c["epdms"] == 1.0
    # Filter needs exactly 0: a human NC of 0.5 (object contact) leaves the agent's NC 0.
    lh = np.zeros(30, bool)
    lh[3] = True
    crash = straight_log(30, **_hits(30, [5], [9], [True]))
    c = navsim.episode_columns(crash, sc, 0.1, human=straight_log(30, f_layout_hit=lh))
    assert c["navsim_nc"] == 0.0 and c["epdms"] == 0.0
    assert navsim.apply_human_filter({"nc": 0.0, "ep": 0.3}, {"nc": 0.0, "ep": 1.0}) == {"nc": 1.0, "ep": 0.3}


def test_epdms_worked_case():
    # 5 s at 5 m/s vs the log's 10 m/s -> EP 0.5; one TTC violation -> 0;
    # 5 oncoming steps of 0.5 m = 2.5 m in a 1 s window -> DDC 0.5.
    # EPDMS = 1 * 1 * 0.5 * 1 * (5 * 0.5 + 5 * 0 + 2 + 2 + 2) / 16 = 0.265625.
    sc = straight_scenario(log_speed=10.0)
    ttc, onc = np.zeros(50, bool), np.zeros(50, bool)
    ttc[20] = True
    onc[30:35] = True
    c = navsim.episode_columns(straight_log(50, speed=5.0, nv_ttc_violation=ttc, nv_oncoming=onc), sc, 0.1)
    assert c["navsim_ddc"] == 0.5 and c["navsim_ttc"] == 0.0
    assert c["navsim_ep"] == pytest.approx(0.5, abs=1e-6)
    assert c["epdms"] == pytest.approx(0.265625, abs=1e-6)
    assert tuple(c) == navsim.COLUMNS
    sub = dict(nc=1.0, dac=1.0, ddc=1.0, tlc=1.0, ep=1.0, ttc=1.0, lk=0.0, hc=0.0, ec=1.0)
    assert navsim.epdms(sub) == pytest.approx(12 / 16)
    assert navsim.epdms({**sub, "nc": 0.5}) == pytest.approx(6 / 16)


def test_extended_comfort_of_a_whole_episode_is_the_mean_over_its_plan_pairs():
    """``extended_comfort`` scores every consecutive pair of an episode in one
    batch; it must equal the mean of ``two_frame_comfort`` taken pair by pair
    (plans of a car at 10 m/s with growing noise: pass rates between 0 and 1)."""
    rng = np.random.default_rng(1)
    t_len, n = 60, 8
    base = np.stack([5.0 * np.arange(1, n + 1), np.zeros(n)], -1)
    xy = np.stack([np.arange(t_len) * 1.0, np.zeros(t_len)], -1)
    yaw = np.zeros(t_len)
    active = np.ones(t_len, bool)
    active[30] = False  # no pair across an inactive step
    rates = []
    for noise in (0.0, 0.01, 0.02):
        plans = base[None] + rng.normal(0.0, noise, (t_len, n, 2))
        pairs = [navsim.two_frame_comfort(plans[k - 1], (xy[k - 1], yaw[k - 1]), plans[k], (xy[k], yaw[k]), 0.1)
                 for k in range(1, t_len) if active[k] and active[k - 1]]
        got = navsim.extended_comfort(active, plans, xy, yaw, 0.1)
        assert got == pytest.approx(float(np.mean(pairs)), abs=1e-12)
        rates.append(got)
    assert rates[0] == 1.0 and 0.0 < min(rates[1:]) < 1.0  # the case exercises both outcomes
