"""A PyTorch host policy: a kinematic route follower and a small MLP, in torch.

    drivee2e bench --policy docs/examples/torch_policy.py                                  # mode=route_follow
    drivee2e bench --policy docs/examples/torch_policy.py:mode=mlp,weights=mlp.pt
    drivee2e serve-policy docs/examples/torch_policy.py --port 5555                         # no JAX needed
    drivee2e bench --policy remote://127.0.0.1:5555

PyTorch is not a dependency of drivee2e-jax: ``pip install torch`` (the CPU
wheel is enough) in the environment that runs this file -- the simulator's, or
only the serving one's with ``drivee2e serve-policy``. This file imports numpy,
torch and ``drivee2e_jax.hostapi`` (numpy only), never JAX.

The policy gets the observation of the WHOLE batch each control step
(``drivee2e_jax.hostapi.Observation``: numpy, leading batch axis B, float32 /
int32 / bool; units in ``drivee2e_jax/types.py``) and returns ``Waypoints``:
``(B, 6, 2)`` future ego positions 0.5 s apart, in the current ego frame
(x forward, y left, m), which the simulator's PID + pure-pursuit controller
follows. Numpy -> torch is ``torch.from_numpy`` (zero-copy on the CPU) and
back ``.numpy()``; everything runs under ``torch.no_grad()``.

Two modes (``make_policy(mode=...)``):

``route_follow`` (default; needs no training, deterministic)
    Places the waypoints along ``obs.route`` at a target speed: the speed limit
    (``obs.speed_limit``), lowered so that the ego can still stop -- at
    ``DECEL`` m/s^2 -- ``STOP_MARGIN`` m before a red / yellow stop line
    (``obs.signal_state``, ``obs.signal_distance``) and behind the nearest
    agent in a 2 m-wide corridor ahead (``obs.agents``, ``obs.agents_valid``).
    Uses ego-frame inputs only (no ``obs.privileged``).

``mlp``
    ``TorchMLP``: a 3-layer ``torch.nn`` MLP from a 117-number feature vector
    (``features``: ego speed / accel / yaw rate / steer, speed limit, the first
    10 route points with their validity, the command one-hot, the stop-line
    state and distance, the 8 nearest agents with their validity; scaled to
    O(1)) to the 6 x 2 waypoints. ``weights=PATH`` loads a checkpoint written
    by :func:`save_weights` (``torch.save({"config": ..., "state_dict": ...})``,
    read back with ``torch.load(..., weights_only=True)``); without one the
    net is randomly initialised from ``seed`` (it drives badly: train it
    first, e.g. by imitating ``route_follow`` as ``notebooks/torch_policy.py``
    does).

``device="cuda"`` runs the net on a GPU (the inputs are moved there and the
waypoints back). The policy keeps no state between steps (``reset`` returns
None).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from drivee2e_jax.hostapi import HostPolicy, Waypoints

WAYPOINT_DT = 0.5  # s between waypoints
NUM_WAYPOINTS = 6
DECEL = 2.5  # comfortable deceleration, m/s^2
STOP_MARGIN = 3.0  # stop this far before a stop line / the lead agent, m
CORRIDOR = 2.0  # |y| < CORRIDOR m: an agent ahead is in the ego's way

# drivee2e_jax.types values, repeated here so that this file never imports JAX.
RED, YELLOW = 1, 2  # types.SignalState
NUM_COMMANDS = 8  # types.Command: VOID = -1, LEFT = 1 ... CHANGELANERIGHT = 6 -> one-hot of command + 1

# The MLP's inputs: the first ROUTE_POINTS route points and the first AGENTS agents (zero-padded if fewer).
ROUTE_POINTS = 10
AGENTS = 8
NUM_FEATURES = 4 + 1 + 3 * ROUTE_POINTS + NUM_COMMANDS + 2 + 9 * AGENTS  # = 117


def _tensor(a: np.ndarray, device: str, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """numpy -> torch without a copy when it can (CPU, C-contiguous, same dtype)."""
    return torch.from_numpy(np.ascontiguousarray(a)).to(device=device, dtype=dtype)


def _pad(t: torch.Tensor, n: int) -> torch.Tensor:
    """Keep the first ``n`` entries of axis 1, zero-padded to ``n``."""
    t = t[:, :n]
    if t.shape[1] < n:
        t = torch.cat([t, t.new_zeros((t.shape[0], n - t.shape[1], *t.shape[2:]))], dim=1)
    return t


def features(obs, device: str = "cpu") -> torch.Tensor:
    """(B, NUM_FEATURES) float32: the MLP's input, from the vector observation (no privileged data)."""
    b = obs.ego.shape[0]
    ego = _tensor(obs.ego, device) / torch.tensor([10.0, 5.0, 1.0, 1.0], device=device)  # m/s, m/s^2, rad/s, rad
    limit = _tensor(obs.speed_limit, device)[:, None] / 10.0  # m/s
    route_ok = _pad(_tensor(obs.route_valid, device), ROUTE_POINTS)  # (B, 10)
    route = _pad(_tensor(obs.route, device), ROUTE_POINTS) / 20.0 * route_ok[..., None]  # (B, 10, 2), m
    command = torch.nn.functional.one_hot(
        (_tensor(obs.command, device, torch.int64) + 1).clamp(0, NUM_COMMANDS - 1), NUM_COMMANDS).float()
    signal = _tensor(obs.signal_state, device, torch.int64)
    stop = ((signal == RED) | (signal == YELLOW)).float()[:, None]
    stop_distance = _tensor(obs.signal_distance, device)[:, None].clamp(max=100.0) / 100.0  # m
    agents_ok = _pad(_tensor(obs.agents_valid, device), AGENTS)  # (B, 8)
    scale = torch.tensor([20.0, 20.0, 1.0, 1.0, 10.0, 10.0, 5.0, 5.0], device=device)  # m, -, -, m/s, m
    agents = _pad(_tensor(obs.agents, device), AGENTS) / scale * agents_ok[..., None]  # (B, 8, 8)
    return torch.cat([ego, limit, route.reshape(b, -1), route_ok, command, stop, stop_distance,
                      agents.reshape(b, -1), agents_ok], dim=1)


def along_route(route: torch.Tensor, valid: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """Ego-frame points (B, K, 2) at arc lengths ``dist`` (B, K) m along each
    route polyline ``route`` (B, P, 2), ``valid`` (B, P) bool (a prefix),
    measured from the ego at the origin; past the last valid point the
    polyline goes on straight along its last segment (the observed route
    reaches only ``ObsConfig.route_points`` x ``route_spacing`` = 20 m ahead)."""
    b = route.shape[0]
    pts = torch.cat([route.new_zeros((b, 1, 2)), route], dim=1)  # (B, P+1, 2), the ego first
    ok = torch.cat([valid.new_ones((b, 1)), valid], dim=1)
    last = (ok.sum(dim=1) - 1).clamp(min=1)  # (B,) index of the last valid point (>= 1: a segment)
    end = pts.gather(1, last[:, None, None].expand(b, 1, 2))  # (B, 1, 2)
    pts = torch.where(ok[..., None], pts, end)  # invalid points collapse onto the last valid one
    s = torch.cat([route.new_zeros((b, 1)), torch.cumsum(torch.linalg.norm(pts.diff(dim=1), dim=-1), dim=1)], dim=1)
    s_end = s.gather(1, last[:, None])  # (B, 1) route length seen
    d = torch.minimum(dist, s_end)
    i = torch.searchsorted(s, d, right=True).clamp(1, s.shape[1] - 1)  # s[i-1] <= d < s[i]
    s0, s1 = s.gather(1, i - 1), s.gather(1, i)
    t = ((d - s0) / (s1 - s0).clamp(min=1e-6)).clamp(0.0, 1.0)[..., None]
    p0 = pts.gather(1, (i - 1)[..., None].expand(-1, -1, 2))
    p1 = pts.gather(1, i[..., None].expand(-1, -1, 2))
    before = pts.gather(1, (last - 1)[:, None, None].expand(b, 1, 2))
    u = end - before
    u = u / torch.linalg.norm(u, dim=-1, keepdim=True).clamp(min=1e-6)  # (B, 1, 2) direction of the last segment
    return p0 + t * (p1 - p0) + (dist - s_end).clamp(min=0.0)[..., None] * u


def route_follow(obs, device: str = "cpu") -> torch.Tensor:
    """(B, NUM_WAYPOINTS, 2) waypoints along the route at a safe target speed (see the module docstring)."""
    signal = _tensor(obs.signal_state, device, torch.int64)
    free = torch.where((signal == RED) | (signal == YELLOW), _tensor(obs.signal_distance, device),
                       torch.tensor(1e3, device=device))  # (B,) free distance ahead, m
    agents = _tensor(obs.agents, device)  # (B, K, 8): x, y, cos, sin, vx, vy, length, width
    x, y, length = agents[..., 0], agents[..., 1], agents[..., 6]
    ahead = _tensor(obs.agents_valid, device, torch.bool) & (x > 0.0) & (y.abs() < CORRIDOR)
    lead = torch.where(ahead, x - 0.5 * length, torch.tensor(1e3, device=device)).amin(dim=1)
    room = (torch.minimum(free, lead) - STOP_MARGIN).clamp(min=0.0)
    target = torch.minimum(_tensor(obs.speed_limit, device), torch.sqrt(2.0 * DECEL * room))  # (B,) m/s
    times = WAYPOINT_DT * torch.arange(1, NUM_WAYPOINTS + 1, device=device, dtype=torch.float32)
    return along_route(_tensor(obs.route, device), _tensor(obs.route_valid, device, torch.bool),
                       target[:, None] * times[None])


class TorchMLP(nn.Module):
    """features (B, NUM_FEATURES) -> waypoints (B, num_waypoints, 2), m."""

    def __init__(self, hidden: int = 128, num_waypoints: int = NUM_WAYPOINTS, scale: float = 10.0):
        super().__init__()
        self.config = {"hidden": hidden, "num_waypoints": num_waypoints, "scale": scale}
        self.net = nn.Sequential(nn.Linear(NUM_FEATURES, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                                 nn.Linear(hidden, 2 * num_waypoints))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.config["scale"] * self.net(x).reshape(x.shape[0], self.config["num_waypoints"], 2)


def save_weights(net: TorchMLP, path: str | Path) -> Path:
    """Write ``net``'s architecture and weights; ``make_policy(mode="mlp", weights=path)`` reads them."""
    torch.save({"config": dict(net.config), "state_dict": net.state_dict()}, path)
    return Path(path)


def load_weights(path: str | Path, device: str = "cpu") -> TorchMLP:
    """A :class:`TorchMLP` from a :func:`save_weights` file (``weights_only``: no pickled code runs)."""
    ckpt = torch.load(path, map_location=device, weights_only=True)
    net = TorchMLP(**ckpt["config"])
    net.load_state_dict(ckpt["state_dict"])
    return net.to(device)


class TorchPolicy(HostPolicy):
    action_type = "waypoints"
    waypoint_dt = WAYPOINT_DT
    num_waypoints = NUM_WAYPOINTS
    required_sensors = ()  # vector observation only: no BEV / LiDAR rendering

    def __init__(self, mode: str = "route_follow", net: TorchMLP | None = None, device: str = "cpu"):
        if mode not in ("route_follow", "mlp"):
            raise ValueError(f"mode={mode!r}: expected 'route_follow' or 'mlp'")
        if mode == "mlp" and net is None:
            raise ValueError("mode='mlp' needs a TorchMLP")
        self.name = f"torch_{mode}"
        self.mode, self.device = mode, device
        self.net = net.to(device).eval() if net is not None else None
        if self.net is not None:
            self.num_waypoints = self.net.config["num_waypoints"]

    def reset(self, meta):
        return None  # stateless

    def act(self, obs, state):
        # The simulator hands over read-only arrays; torch warns that it cannot protect them, but nothing here
        # writes into its inputs, so the zero-copy views are safe.
        with torch.no_grad(), warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="The given NumPy array is not writable", category=UserWarning)
            xy = route_follow(obs, self.device) if self.mode == "route_follow" else self.net(features(obs, self.device))
        return Waypoints(xy=xy.to(device="cpu", dtype=torch.float32).numpy()), state


def make_policy(mode: str = "route_follow", weights: str | None = None, seed: int = 0, device: str = "cpu"):
    """``mode="route_follow"`` (no net) or ``"mlp"`` (``weights``: a :func:`save_weights` file; none: a random
    net from ``seed``). ``device``: where torch computes ("cpu", "cuda", ...)."""
    if mode != "mlp":
        return TorchPolicy(mode, device=device)
    if weights is not None:
        return TorchPolicy("mlp", load_weights(weights, device), device)
    with torch.random.fork_rng(devices=[]):  # a seeded init that leaves the global RNG alone
        torch.manual_seed(int(seed))
        net = TorchMLP()
    return TorchPolicy("mlp", net, device)
