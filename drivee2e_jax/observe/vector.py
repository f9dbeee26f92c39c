"""Vector observations: ego state, GPS, route ahead, command, nearest agents,
nearby lanes and the next signal on the route, all from the ego's SIMULATED
state. Pure functions of one scenario; the simulator vmaps them.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from drivee2e_jax import geometry
from drivee2e_jax.replay import AgentStates
from drivee2e_jax.types import Command, EgoState, Observation, Privileged, Route, SignalState

#: Signal distance reported when no stop line lies ahead on the route, m.
NO_SIGNAL_DISTANCE = 1000.0


@dataclasses.dataclass(frozen=True)
class ObsConfig:
    """Which observations the policy gets and how large they are.

    Attributes:
      route_points:   P, route points returned ahead of the ego.
      route_spacing:  metres between returned route points (route is 1 m dense).
      num_agents:     K nearest agents returned.
      agent_radius:   agents farther than this (m) are masked out.
      lane_points:    Q, points kept per lane polyline (strided subsample).
      gps_noise_std:  GPS position noise, m (0 = exact); seeded per step.
      compass_noise_std: heading noise, rad.
    """

    route_points: int = 10
    route_spacing: float = 2.0
    num_agents: int = 16
    agent_radius: float = 60.0
    lane_points: int = 16
    gps_noise_std: float = 0.0
    compass_noise_std: float = 0.0

    def __post_init__(self):
        for name in ("route_points", "num_agents", "lane_points"):
            if getattr(self, name) < 1:
                raise ValueError(f"ObsConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.route_spacing <= 0:
            raise ValueError(f"ObsConfig.route_spacing must be > 0 m, got {self.route_spacing}")


def route_ahead(route: Route, index, ego: EgoState, cfg: ObsConfig):
    """(P, 2) ego-frame route points starting at dense index ``index``."""
    step = max(1, int(round(cfg.route_spacing)))
    idx = index + step * (1 + jnp.arange(cfg.route_points))
    last = jnp.maximum(jnp.sum(route.valid) - 1, 0)
    valid = idx <= last
    idx = jnp.minimum(idx, last)
    pts = geometry.to_frame(route.xy[idx], ego.xy, ego.yaw)
    return pts, valid


def command_ahead(route: Route, index) -> jnp.ndarray:
    """The route command a few metres ahead (CARLA reports the next node's)."""
    last = jnp.maximum(jnp.sum(route.valid) - 1, 0)
    cmd = route.command[jnp.minimum(index + 5, last)]
    return jnp.where(route.valid[0], cmd, Command.LANEFOLLOW)


def nearest_agents(ego: EgoState, agents: AgentStates, size, category, cfg: ObsConfig):
    """Nearest ``K`` valid agents as ego-frame features (see ``Observation``)."""
    d = jnp.linalg.norm(agents.xy - ego.xy, axis=-1)
    ok = agents.valid & (d < cfg.agent_radius)
    k = min(cfg.num_agents, d.shape[0])
    _, idx = jax.lax.top_k(-jnp.where(ok, d, jnp.inf), k)
    rel = geometry.to_frame(agents.xy[idx], ego.xy, ego.yaw)
    dyaw = agents.yaw[idx] - ego.yaw
    vel = geometry.rotate(agents.vel[idx], -ego.yaw)
    feats = jnp.concatenate(
        [rel, jnp.cos(dyaw)[:, None], jnp.sin(dyaw)[:, None], vel, size[idx, :2]], axis=-1
    )
    valid = ok[idx]
    feats = jnp.where(valid[:, None], feats, 0.0)
    pad = cfg.num_agents - k
    if pad:
        feats = jnp.pad(feats, ((0, pad), (0, 0)))
        valid = jnp.pad(valid, (0, pad))
        idx = jnp.pad(idx, (0, pad))
    return feats, jnp.where(valid, category[idx], -1), valid


def lanes_near(ego: EgoState, lane_xy, lane_valid, cfg: ObsConfig):
    """Ego-frame lane polylines (M, Q, 2), strided to ``Q`` points."""
    n = lane_xy.shape[-2]
    stride = max(1, -(-n // cfg.lane_points))
    xy = lane_xy[:, ::stride][:, : cfg.lane_points]
    valid = lane_valid[:, ::stride][:, : cfg.lane_points]
    pad = cfg.lane_points - xy.shape[1]
    if pad:
        xy = jnp.pad(xy, ((0, 0), (0, pad), (0, 0)))
        valid = jnp.pad(valid, ((0, 0), (0, pad)))
    rel = geometry.to_frame(xy, ego.xy, ego.yaw)
    return jnp.where(valid[..., None], rel, 0.0), valid


def route_speed_limits(route: Route, lane_xy, lane_point_valid, lane_valid, lane_limit):
    """(R,) speed limit along the route: that of the nearest lane running its way.

    Computed once per episode (at reset) from the candidate lanes near the
    route. A route point with no aligned lane nearby takes the highest
    candidate limit (it is then inside a junction area the lanes do not cover).

    Args:
      route: the reference route (R points, 1 m apart).
      lane_xy: (M, N, 2) candidate lane centrelines; lane_point_valid (M, N);
      lane_valid: (M,) bool; lane_limit: (M,) m/s.
    """
    seg = route.xy[1:] - route.xy[:-1]
    heading = jnp.arctan2(seg[:, 1], seg[:, 0])
    heading = jnp.concatenate([heading, heading[-1:]])

    def at(p, h):
        d, lh = jax.vmap(geometry.nearest_segment, in_axes=(None, 0, 0))(p, lane_xy, lane_point_valid)
        ok = lane_valid & (jnp.abs(geometry.wrap_angle(lh - h)) < jnp.pi / 3)
        j = jnp.argmin(jnp.where(ok, d, jnp.inf))
        return jnp.where(ok[j], lane_limit[j], jnp.max(jnp.where(lane_valid, lane_limit, 0.0)))

    return jax.vmap(at)(route.xy, heading)


def next_signal(progress_arc, stop_arc, stop_state):
    """State and route distance of the next stop line on the route.

    Args:
      progress_arc: () route arc of the ego, m.
      stop_arc: (S,) arc of each stop line along the route (inf if off-route).
      stop_state: (S,) int32 current ``SignalState`` per stop line.
    """
    ahead = stop_arc - progress_arc
    # A line the ego is on top of (up to half a car length past) still counts.
    cand = jnp.where(ahead > -2.5, ahead, jnp.inf)
    i = jnp.argmin(cand)
    found = jnp.isfinite(cand[i])
    return (
        jnp.where(found, stop_state[i], SignalState.UNKNOWN).astype(jnp.int32),
        jnp.where(found, cand[i], NO_SIGNAL_DISTANCE),
    )


def observe(
    *,
    ego: EgoState,
    agents: AgentStates,
    size,
    category,
    route: Route,
    route_index,
    progress_arc,
    lane_xy,
    lane_valid,
    stop_arc,
    stop_state,
    speed_limit,
    privileged: Privileged,
    key,
    cfg: ObsConfig,
) -> Observation:
    """Assemble the vector ``Observation`` for one scenario at one step."""
    k_gps, k_cmp = jax.random.split(key)
    gps = ego.xy + cfg.gps_noise_std * jax.random.normal(k_gps, (2,))
    compass = ego.yaw + cfg.compass_noise_std * jax.random.normal(k_cmp, ())
    route_pts, route_valid = route_ahead(route, route_index, ego, cfg)
    feats, cats, valid = nearest_agents(ego, agents, size, category, cfg)
    lanes, lanes_valid = lanes_near(ego, lane_xy, lane_valid, cfg)
    sig_state, sig_dist = next_signal(progress_arc, stop_arc, stop_state)
    return Observation(
        ego=jnp.stack([ego.speed, ego.accel, ego.yaw_rate, ego.steer]),
        gps=gps,
        compass=compass,
        route=route_pts,
        route_valid=route_valid,
        command=command_ahead(route, route_index).astype(jnp.int32),
        agents=feats,
        agents_category=cats.astype(jnp.int32),
        agents_valid=valid,
        lanes=lanes,
        lanes_valid=lanes_valid,
        signal_state=sig_state,
        signal_distance=sig_dist,
        speed_limit=jnp.asarray(speed_limit, jnp.float32),
        privileged=privileged,
    )
