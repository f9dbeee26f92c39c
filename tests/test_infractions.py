"""Per-tick infraction facts not covered through whole episodes in test_sim."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point

from drivee2e_jax import geometry as geo
from drivee2e_jax import infractions as inf
from drivee2e_jax.dynamics import ego_from_log
from drivee2e_jax.eval.closedloop import evaluate
from drivee2e_jax.policy import load_policy, resolve_policy_path
from drivee2e_jax.records import TrackRecord
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import CollisionType as CT
from drivee2e_jax.types import Marking, Tracks
from tests.helpers import lanes as lane_helpers
from tests.helpers import sim_scenarios as ss

LW = jnp.array([4.6, 2.0])


def _ego(x, y, yaw):
    return ego_from_log(jnp.array([x, y]), jnp.asarray(yaw), jnp.zeros(2), jnp.zeros(()))


def _lines(*polys, n=8):
    """Pad polylines to (M, n, 2) + point masks."""
    xy = np.zeros((len(polys), n, 2), np.float32)
    pv = np.zeros((len(polys), n), bool)
    for i, p in enumerate(polys):
        xy[i, : len(p)] = p
        pv[i, : len(p)] = True
    return jnp.asarray(xy), jnp.asarray(pv)


DASHED_Y0 = np.array([[-50.0, 0.0], [0.0, 0.0], [50.0, 0.0]])
EDGE_Y5 = np.array([[-50.0, 5.0], [50.0, 5.0]])

@jax.jit
def invasion(prev, ego, lw, xy, pv, valid, marking):
    return inf.lane_invasion(prev, ego, lw, inf.marking_segments(xy, pv, valid, marking))


def _call(prev, ego, polys, markings, valid=None):
    xy, pv = _lines(*polys)
    valid = jnp.ones(len(polys), bool) if valid is None else jnp.asarray(valid)
    hit, mark = invasion(prev, ego, LW, xy, pv, valid, jnp.asarray(markings, jnp.int32))
    return bool(hit), int(mark)


def test_driving_along_a_lane_invades_nothing():
    assert _call(_ego(0, -1.75, 0.0), _ego(1.5, -1.75, 0.0), [DASHED_Y0], [Marking.DASHED]) == (False, Marking.NONE)


def test_a_corner_crossing_a_dashed_line_is_an_invasion():
    # Ego drifting left: its left corners move from y = -0.1 to y = +0.3.
    assert _call(_ego(0, -1.1, 0.0), _ego(1.0, -0.7, 0.0), [DASHED_Y0], [Marking.DASHED]) == (True, Marking.DASHED)


def test_strictest_marking_is_reported_and_road_edges_do_not_count():
    solid_y0 = DASHED_Y0.copy()
    prev, ego = _ego(0, -1.1, 0.0), _ego(1.0, -0.7, 0.0)
    assert _call(prev, ego, [DASHED_Y0, solid_y0], [Marking.DASHED, Marking.SOLID]) == (True, Marking.SOLID)
    assert _call(prev, ego, [DASHED_Y0], [Marking.ROAD_EDGE])[0] is False
    assert _call(prev, ego, [DASHED_Y0], [Marking.NONE])[0] is False
    assert _call(prev, ego, [DASHED_Y0], [Marking.DASHED], valid=[False])[0] is False
    # A kerb far away changes nothing.
    assert _call(prev, ego, [DASHED_Y0, EDGE_Y5], [Marking.DASHED, Marking.ROAD_EDGE]) == (True, Marking.DASHED)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-3, 3), st.floats(-3, 3), st.floats(-np.pi, np.pi),
    st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.floats(-0.3, 0.3),
    st.floats(-4, 4), st.floats(-4, 4), st.floats(-np.pi, np.pi),
)
def test_matches_shapely_corner_paths(x, y, yaw, dx, dy, dyaw, lx, ly, lang):
    """Oracle: some corner's straight path crosses the marking segment (shapely)."""
    a = np.array([lx, ly]) - 6 * np.array([np.cos(lang), np.sin(lang)])
    b = np.array([lx, ly]) + 6 * np.array([np.cos(lang), np.sin(lang)])
    prev, ego = _ego(x, y, yaw), _ego(x + dx, y + dy, yaw + dyaw)
    c0 = np.asarray(geo.box_corners(prev.xy, prev.yaw, LW[0], LW[1]))
    c1 = np.asarray(geo.box_corners(ego.xy, ego.yaw, LW[0], LW[1]))
    line = LineString([a, b])
    paths = [LineString([p, q]) for p, q in zip(c0, c1)]
    # Proper crossings only: skip near-touching cases (float32 vs float64).
    ends = [Point(c) for c in (*c0, *c1)]
    if any(line.distance(e) < 1e-3 for e in ends) or any(p.distance(Point(e)) < 1e-3 for p in paths for e in (a, b)):
        return
    want = any(p.crosses(line) for p in paths)
    got, _ = _call(prev, ego, [np.stack([a, b])], [Marking.SOLID])
    assert got == want


# ---------------------------------------------------------------- overlaps already in the log


def _tracks(xs, valid=None):
    """Cars on y = 0 heading +x: xs (A, T) centre x, m; row 0 is the ego (4.6 x 2.0 m)."""
    xs = np.asarray(xs, np.float32)
    a, t = xs.shape
    valid = np.ones((a, t), bool) if valid is None else np.asarray(valid, bool)
    size = np.tile(np.array([[4.6, 2.0, 1.5]], np.float32), (a, 1))
    return Tracks(xy=jnp.asarray(np.stack([xs, np.zeros_like(xs)], -1)), yaw=jnp.zeros((a, t)),
                  vel=jnp.zeros((a, t, 2)), size=jnp.asarray(size), category=jnp.zeros(a, jnp.int32),
                  valid=jnp.asarray(valid), visible=jnp.asarray(valid), quality=jnp.asarray(valid),
                  track_id=jnp.arange(a, dtype=jnp.int32))


def test_logged_overlap_spans_only_exempt_overlaps_present_when_first_seen_together():
    t = 12
    ego = np.arange(t, dtype=float)  # 1 m per step
    far = ego + 10.0
    touching = ego + 3.0  # 3 m apart, boxes 4.6 m long: overlapping
    born = np.where(np.arange(t) < 5, touching, far)  # overlapping at steps 0..4, then apart
    runs_in = np.where(np.arange(t) >= 6, touching, far)  # apart, then overlapping from step 6: a collision
    flicker = np.where(np.isin(np.arange(t), [0, 1, 3, 4]), touching, far)  # first run 0..1 only
    late = touching  # overlapping, but present only from step 4 (appears inside the ego's box)
    late_valid = np.arange(t) >= 4
    valid = np.ones((6, t), bool)
    valid[5] = late_valid
    tr = _tracks([ego, born, runs_in, far, flicker, late], valid)
    spans = np.asarray(jax.jit(inf.logged_overlap_spans)(tr, 0, jnp.array([4.6, 2.0])))
    assert spans.tolist() == [[t, -1], [0, 4], [t, -1], [t, -1], [0, 1], [4, t - 1]]
    # the same rows with the ego elsewhere: nothing overlaps
    assert np.asarray(inf.logged_overlap_spans(_tracks([ego + 50, born, runs_in]), 0, jnp.array([4.6, 2.0]))).tolist() \
        == [[t, -1]] * 3


def test_at_most_max_logged_overlaps_agents_are_exempt():
    t, n = 6, inf.MAX_LOGGED_OVERLAPS + 2
    ego = np.arange(t, dtype=float)
    tr = _tracks([ego] + [ego + 0.1 * i for i in range(1, n + 1)])  # all inside the ego's box throughout
    spans = np.asarray(inf.logged_overlap_spans(tr, 0, jnp.array([4.6, 2.0])))
    assert sorted(map(tuple, spans[1:].tolist())).count((0, t - 1)) == inf.MAX_LOGGED_OVERLAPS
    assert int(inf.logged_overlap_count(jnp.asarray(spans), jnp.float32(0.5), jnp.float32(1.0))) \
        == inf.MAX_LOGGED_OVERLAPS


def test_logged_overlap_exempt_brackets_the_time_and_count_stops_at_the_end():
    spans = jnp.array([[0, 4], [12, -1], [4, 11]], jnp.int32)
    dt = jnp.float32(0.1)
    assert np.asarray(inf.logged_overlap_exempt(spans, jnp.float32(0.4), dt)).tolist() == [True, False, True]
    assert np.asarray(inf.logged_overlap_exempt(spans, jnp.float32(0.45), dt)).tolist() == [True, False, True]
    assert np.asarray(inf.logged_overlap_exempt(spans, jnp.float32(0.5), dt)).tolist() == [False, False, True]
    assert np.asarray(inf.logged_overlap_exempt(spans, jnp.float32(0.35), dt)).tolist() == [True, False, True]
    assert np.asarray(inf.logged_overlap_exempt(spans, jnp.float32(0.3), dt)).tolist() == [True, False, False]
    assert int(inf.logged_overlap_count(spans, jnp.float32(0.3), dt)) == 1
    assert int(inf.logged_overlap_count(spans, jnp.float32(0.4), dt)) == 2


def _car(k, x_of_k):
    k = np.asarray(k)
    return TrackRecord(track_id=9, category="car", size=np.array([4.5, 1.9, 1.5]), t=np.round(k * ss.DT, 6),
                       xy=np.stack([x_of_k(k), np.full(len(k), -1.75)], 1), yaw=np.zeros(len(k)),
                       vel=np.zeros((len(k), 2)))


def test_log_replay_is_not_charged_for_an_overlap_the_log_starts_with():
    ego_x = lambda k: -40.0 + ss.EGO_SPEED * k * ss.DT  # noqa: E731  (ss.ego_track's path)
    # Appears at t = 0.3 s 2 m ahead of the ego (boxes overlap), pulls away from t = 1.0 s.
    born = _car(np.arange(3, 40), lambda k: ego_x(k) + 2.0 + np.maximum(k - 10, 0) * 0.5)
    # Present from t = 0 s 8 m ahead, the ego runs into it from t = 0.3 s: a collision in the log.
    runs_in = _car(np.arange(0, 40), lambda k: ego_x(k) + np.where(k < 3, 8.0, 2.0 + np.maximum(k - 10, 0) * 0.5))
    recs = [ss.scenario("born_overlapping", [ss.ego_track(), born]), ss.scenario("runs_in", [ss.ego_track(), runs_in]),
            ss.clean()]
    out = evaluate(load_policy(resolve_policy_path("log_replay")), ss.build(recs), split=None)
    rows = {r["scenario_id"]: r for r in out.rows}
    assert (rows["born_overlapping"]["collisions_vehicle"], rows["born_overlapping"]["log_overlaps"]) == (0, 1)
    assert rows["born_overlapping"]["driving_score"] == 100.0
    assert (rows["runs_in"]["collisions_vehicle"], rows["runs_in"]["log_overlaps"]) == (1, 0)
    assert (rows["clean"]["collisions_vehicle"], rows["clean"]["log_overlaps"], rows["clean"]["driving_score"]) \
        == (0, 0, 100.0)


# ---------------------------------------------------------------- at-fault collision attribution
# Expected values follow nuPlan (motional/nuplan-devkit):
#   nuplan/planning/metrics/evaluation_metrics/common/no_ego_at_fault_collisions.py
#     ``_get_collision_type`` (order: ego stopped, track stopped, behind, front bumper, lateral)
#     and ``classify_at_fault_collisions`` (the at-fault rule);
#   nuplan/planning/simulation/observation/idm/utils.py ``is_agent_behind`` (150 deg from the rear axle).

_type = jax.jit(inf.collision_type)
REAR = 1.4  # m, rear axle behind the box centre
CAR = jnp.array([4.5, 1.9])


def _moving(x, y, yaw, speed):
    """Ego box at (x, y) heading ``yaw`` with ``speed`` m/s along it (float32)."""
    return ego_from_log(jnp.array([x, y]), jnp.asarray(yaw), jnp.float32(speed) * jnp.array([np.cos(yaw), np.sin(yaw)]),
                        jnp.zeros(()))


def _kind(ego_speed, xy, yaw, speed, ego_lw=LW):
    ego = _moving(0.0, 0.0, 0.0, ego_speed)
    return CT(int(_type(ego, ego_lw, REAR, jnp.asarray(xy, jnp.float32), jnp.float32(yaw), CAR, jnp.float32(speed))))


def test_collision_type_constants_are_nuplans():
    # stopped_speed_threshold = 5e-02 (``_get_collision_type``), angle_tolerance = 150 (``is_agent_behind``).
    assert inf.STOPPED_SPEED == 0.05
    assert inf.BEHIND_ANGLE == pytest.approx(np.deg2rad(150.0))


def test_stopped_ego_boundary_is_inclusive():
    # A moving car 3 m ahead on the ego's lane: the ego's front bumper is in it.
    assert _kind(0.05, (3.0, 0.0), 0.0, 5.0) == CT.STOPPED_EGO  # speed <= threshold: stopped
    assert _kind(0.0, (-3.0, 0.0), 0.0, 5.0) == CT.STOPPED_EGO  # even when hit from behind
    assert _kind(0.051, (3.0, 0.0), 0.0, 5.0) == CT.ACTIVE_FRONT  # above: not stopped


def test_stopped_track_comes_before_geometry():
    # Ego moving; the track is at or below 0.05 m/s (nuPlan ``is_track_stopped``), wherever it is.
    assert _kind(5.0, (3.0, 0.0), 0.0, 0.05) == CT.STOPPED_TRACK
    assert _kind(5.0, (-4.0, 0.0), 0.0, 0.0) == CT.STOPPED_TRACK  # behind, but stopped first
    assert _kind(5.0, (-4.0, 0.0), 0.0, 0.051) == CT.ACTIVE_REAR


def test_car_hitting_the_ego_from_behind_is_active_rear():
    # Track centre 4.5 m behind the box centre: 3.1 m behind the rear axle, angle 180 deg > 150.
    assert _kind(5.0, (-4.5, 0.0), 0.0, 8.0) == CT.ACTIVE_REAR


def test_behind_is_150_degrees_from_the_rear_axle():
    # A track centre 3 m from the rear axle (-1.4, 0) at 151 deg is behind; at 149 deg it is not,
    # and it is clear of the front bumper (x = 2.3), so lateral.
    for deg, want in ((151.0, CT.ACTIVE_REAR), (149.0, CT.ACTIVE_LATERAL)):
        a = np.deg2rad(deg)
        assert _kind(5.0, (-REAR + 3.0 * np.cos(a), 3.0 * np.sin(a)), 0.0, 6.0) == want


def test_front_bumper_into_a_moving_cars_side_is_active_front():
    # Crossing car (heading +y) centred 3 m ahead: its box spans x in [2.05, 3.95], y in [-2.25, 2.25];
    # the ego's front edge x = 2.3, y in [-1, 1] lies inside it.
    assert _kind(5.0, (3.0, 0.0), np.pi / 2, 6.0) == CT.ACTIVE_FRONT
    # 3.5 m ahead the box starts at x = 2.55: the front edge misses it -> lateral.
    assert _kind(5.0, (3.5, 0.0), np.pi / 2, 6.0) == CT.ACTIVE_LATERAL


def test_side_swipe_is_active_lateral():
    # Car alongside on the left (x in [-3.75, 0.75], y in [0.95, 2.85]) overlapping the ego's left side;
    # from the rear axle it is at ~93 deg (not behind) and the front edge (x = 2.3) misses it.
    assert _kind(5.0, (-1.5, 1.9), 0.0, 6.0) == CT.ACTIVE_LATERAL
    # Moved forward so the ego's front-left corner (2.3, 1.0) is inside its box: front.
    assert _kind(5.0, (0.5, 1.9), 0.0, 6.0) == CT.ACTIVE_FRONT


def test_at_fault_truth_table():
    """``classify_at_fault_collisions``: STOPPED_TRACK, ACTIVE_FRONT always; ACTIVE_LATERAL only
    in several lanes or off the drivable area; STOPPED_EGO, ACTIVE_REAR and no contact (-1) never."""
    fault = jax.jit(inf.at_fault)
    for kind in (-1, *CT):
        for multi in (False, True):
            for excess in (0.0, 0.2):
                got = bool(fault(jnp.int32(kind), jnp.asarray(multi), jnp.float32(excess)))
                if kind in (CT.STOPPED_TRACK, CT.ACTIVE_FRONT):
                    want = True
                elif kind == CT.ACTIVE_LATERAL:
                    want = multi or excess > 0.0
                else:
                    want = False
                assert got == want, (kind, multi, excess)


# Straight two-lane road along +x: eastbound centre y = -1.75, westbound y = +1.75 (drawn the other way),
# both 3.5 m wide; the road spans y in [-3.5, 3.5]. Ego box 4.6 x 2.0 m (half 2.3 x 1.0).
_ROAD = [np.array([[-50.0, -1.75], [0.0, -1.75], [50.0, -1.75]]), np.array([[50.0, 1.75], [-50.0, 1.75]])]


def _multi(x, y, yaw, lane_valid=(True, True)):
    el = lane_helpers.ego_lanes(_ego(x, y, yaw), LW, lane_helpers.lane_map(_ROAD, valid=np.asarray(lane_valid)))
    return bool(el.multi_lane)


def test_multi_lane_centred_in_a_lane():
    assert not _multi(0.0, -1.75, 0.0)  # corners at |dy| = 1.0 <= 1.75
    assert not _multi(10.0, 1.75, np.pi)  # westbound lane, heading west


def test_multi_lane_straddling_the_centre_line():
    # Corners at y = +-1: each inside one lane, no lane holds all four.
    assert _multi(0.0, 0.0, 0.0)


def test_multi_lane_yawed_past_the_lane_edge():
    # Yawed 0.5 rad in the eastbound lane: the farthest corner is 2.3 sin 0.5 + 1.0 cos 0.5 = 1.980 m
    # from the centre line (> 1.75): no lane holds all four. At 0.3 rad it stays inside (1.635 m).
    assert _multi(0.0, -1.75, 0.5)
    assert not _multi(0.0, -1.75, 0.3)


def test_multi_lane_ignores_invalid_lanes():
    assert _multi(0.0, -1.75, 0.0, lane_valid=(False, True))
    assert _multi(0.0, -1.75, 0.0, lane_valid=(False, False))  # no lane holds the ego at all


def test_multi_lane_on_a_curved_connector():
    # A quarter circle of radius 12 m: a car on the arc, heading along it, lies in the lane;
    # the straight-over-a-car-length approximation put its front corners 0.3 m off.
    a = np.linspace(0.0, np.pi / 2, 40)
    arc = np.stack([12.0 * np.sin(a), 12.0 - 12.0 * np.cos(a)], 1)
    lmap = lane_helpers.lane_map([arc], widths=3.0, types=[lane_helpers.CONNECTOR])
    th = np.pi / 4
    on = _ego(12.0 * np.sin(th), 12.0 - 12.0 * np.cos(th), th)
    el = lane_helpers.ego_lanes(on, LW, lmap)
    assert not bool(el.multi_lane) and bool(el.centre_in[0]) and bool(el.connector[0])
    np.testing.assert_allclose(np.asarray(el.tangent[0]), [np.cos(th), np.sin(th)], atol=0.05)
    corners = np.asarray(geo.box_corners(on.xy, on.yaw, LW[0], LW[1]))
    assert np.all(np.abs(np.hypot(corners[:, 0], corners[:, 1] - 12.0) - 12.0) < 1.5)  # inside by geometry too


def test_contact_set_keeps_every_overlapping_track():
    """nuplan-devkit ``no_ego_at_fault_collisions.py``, ``find_new_collisions``: every
    tracked object whose box intersects the ego's is registered, each with its own
    ``_get_collision_type``. Worked case, ego moving 5 m/s: car 0 rear-ends it
    (centre 2.9 m behind the box centre, 1.5 m behind the rear axle: ACTIVE_REAR,
    not at fault) and is the nearest; car 1 crosses 3 m ahead with the ego's front
    bumper in its side (ACTIVE_FRONT, at fault). ``agent_contacts`` reports only
    the nearest (no fault); ``contact_set`` both, car 1 at fault. Obstacle rows
    pass through as the obstacle identity."""
    ego = _moving(0.0, 0.0, 0.0, 5.0)
    ag = AgentStates(xy=jnp.array([[-2.9, 0.0], [3.0, 0.0]]), yaw=jnp.array([0.0, np.pi / 2]),
                         vel=jnp.array([[8.0, 0.0], [0.0, 6.0]]), valid=jnp.ones(2, bool))
    size = jnp.array([[4.5, 1.9, 1.5], [4.5, 1.9, 1.5]])
    cat, tid = jnp.zeros(2, jnp.int32), jnp.array([70, 80], jnp.int32)
    near, ok = inf.nearest_rows(ego, ag)
    assert np.asarray(near).tolist() == [0, 1]
    overlap = inf.candidate_overlaps(ego, LW, ag, size, near)
    hit, hit_id, _, _, row = inf.agent_contacts(ego, LW, ag, size, cat, tid, near, ok, overlap=overlap)
    assert bool(hit) and int(hit_id) == 70
    kind = inf.collision_type(ego, LW, REAR, ag.xy[row], ag.yaw[row], size[row, :2], jnp.float32(8.0))
    assert not bool(inf.at_fault(kind, False, 0.0))
    cs = inf.contact_set(ego, LW, REAR, ag, size, cat, tid, near, overlap & ok, jnp.asarray(False), jnp.float32(0.0),
                         jnp.array([False, True, False]))
    assert np.asarray(cs.hit).tolist() == [True, True]
    assert np.asarray(cs.track_id).tolist() == [70, 80]
    assert np.asarray(cs.at_fault).tolist() == [False, True]
    assert np.asarray(cs.obstacle_hit).tolist() == [False, True, False]
