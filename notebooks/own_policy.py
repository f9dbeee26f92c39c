# %% [markdown]
# # Writing your own policy
#
# A policy is three pure functions that run **inside** the jitted, vmapped
# rollout, once per control step, for one scenario:
#
# ```python
# params = policy.init(key, obs)                    # any pytree (None here)
# pstate = policy.initial_state(obs)                # recurrent state (None here)
# action, pstate = policy.act(params, obs, pstate, key)
# ```
#
# `obs` is a `types.Observation` rendered from the ego's *simulated* state:
# ego speed / accel / yaw rate / steer, the route ahead in the ego frame, the
# high-level command, the nearest agents, nearby lanes, the next signal and
# the speed limit (plus a BEV raster and LiDAR when the policy declares
# `required_sensors`). The action is either `Controls(throttle, brake, steer)`
# or `Waypoints(xy)` in the ego frame, which the simulator's PID +
# pure-pursuit controller follows (as TCP / Bench2Drive agents do).
#
# This notebook writes a small rule-based waypoint policy, checks that it is
# pure and jit/vmap compatible, evaluates it against the reference policies
# and saves it as a file that `drivee2e bench --policy` loads. Run it with
# `python notebooks/own_policy.py`; the tests execute it on a tiny suite.
# `DRIVEE2E_OWN_POLICY_SUITE` / `_SPLIT` / `_LIMIT` pick the suite, split and
# number of scenarios (defaults: `twin15`, `val`, 16).

# %%
import os
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import drivee2e_jax as de
from drivee2e_jax.policy import load_policy

de.enable_compile_cache()  # reruns reuse compiled rollouts from disk (drivee2e_jax/compile_cache.py)

ROOT = Path(__file__).resolve().parents[1] if "__file__" in globals() else Path.cwd().parent
SUITE = os.environ.get("DRIVEE2E_OWN_POLICY_SUITE", "twin15")
SPLIT = os.environ.get("DRIVEE2E_OWN_POLICY_SPLIT", "val")
LIMIT = int(os.environ.get("DRIVEE2E_OWN_POLICY_LIMIT", "16"))

# %% [markdown]
# ## 1. The policy
# `RouteFollower` places 6 waypoints 0.5 s apart along the route ahead, at a
# target speed that is the speed limit, lowered to stop before a red light and
# behind the nearest agent in a 2 m-wide corridor ahead. Everything is
# `jax.numpy` on fixed shapes: no Python `if` on values, no host calls.

# %%
POLICY_SOURCE = '''
import jax.numpy as jnp

from drivee2e_jax.policy import StatelessPolicy
from drivee2e_jax.types import SignalState, Waypoints

DT = 0.5                     # waypoint spacing, s
TIMES = DT * jnp.arange(1, 7, dtype=jnp.float32)
STOP_MARGIN = 3.0            # stop this far before the stop line / lead agent, m
DECEL = 2.5                  # comfortable deceleration, m/s^2


def along_route(route, valid, dist):
    """Ego-frame points (K, 2) at arc lengths ``dist (K,)`` m along the route
    polyline ``route (P, 2)`` (``valid (P,)``), measured from the ego; past the
    last valid point the polyline is extended straight along its last segment
    (the observed route reaches only ``ObsConfig.route_points`` x
    ``route_spacing`` = 20 m ahead by default)."""
    pts = jnp.concatenate([jnp.zeros((1, 2)), route])           # the ego at the origin
    ok = jnp.concatenate([jnp.ones(1, bool), valid])
    seg = jnp.linalg.norm(jnp.diff(pts, axis=0), axis=-1) * (ok[1:] & ok[:-1])
    s = jnp.concatenate([jnp.zeros(1), jnp.cumsum(seg)])
    last = jnp.maximum(jnp.sum(ok) - 1, 1)
    s = jnp.where(ok, s, s[last] + 1e-3 * jnp.arange(s.shape[0]))  # keep s increasing
    x = jnp.interp(dist, s, jnp.where(ok, pts[:, 0], pts[last, 0]))
    y = jnp.interp(dist, s, jnp.where(ok, pts[:, 1], pts[last, 1]))
    d = pts[last] - pts[last - 1]
    u = d / jnp.maximum(jnp.linalg.norm(d), 1e-6)
    beyond = jnp.maximum(dist - s[last], 0.0)[:, None]
    return jnp.stack([x, y], axis=-1) + beyond * u


class RouteFollower(StatelessPolicy):
    name = "route_follower"
    action_type = "waypoints"
    waypoint_dt = DT

    def act(self, params, obs, policy_state, key):
        # Free distance ahead: the red/yellow stop line and agents in the corridor.
        stop = (obs.signal_state == SignalState.RED) | (obs.signal_state == SignalState.YELLOW)
        free = jnp.where(stop, obs.signal_distance, 1e3)
        ax, ay = obs.agents[:, 0], obs.agents[:, 1]
        ahead = obs.agents_valid & (ax > 0.0) & (jnp.abs(ay) < 2.0)
        free = jnp.minimum(free, jnp.min(jnp.where(ahead, ax - 0.5 * obs.agents[:, 6], 1e3)))
        # The speed that can still stop in the free distance, capped by the limit.
        room = jnp.maximum(free - STOP_MARGIN, 0.0)
        target = jnp.minimum(obs.speed_limit, jnp.sqrt(2.0 * DECEL * room))
        xy = along_route(obs.route, obs.route_valid, target * TIMES)
        return Waypoints(xy=xy.astype(jnp.float32)), policy_state


policy = RouteFollower()
'''
policy_file = Path(tempfile.mkdtemp()) / "route_follower.py"
policy_file.write_text(POLICY_SOURCE)
mine = load_policy(policy_file)
print("loaded", mine.name, "->", mine.action_type)

# %% [markdown]
# ## 2. Pure and jit/vmap compatible
# Take the initial observations of a few scenarios (`Simulator.reset`, vmapped)
# and call `act` under `jit(vmap(...))` twice: the same inputs must give the
# same outputs, and the shapes must be fixed.

# %%
suite = de.load_suite(SUITE)
packed = suite.pack(SPLIT)
batch = jax.tree_util.tree_map(lambda a: jnp.asarray(a[: min(LIMIT, len(packed.meta))]), packed.scenario)
n = int(batch.ego_index.shape[0])
sim = de.Simulator(de.SimConfig())
keys = jax.random.split(jax.random.PRNGKey(0), n)
_, obs = jax.jit(jax.vmap(sim.reset))(keys, batch)
act = jax.jit(jax.vmap(lambda o, k: mine.act(None, o, None, k)[0]))
a1, a2 = act(obs, keys), act(obs, keys)
assert np.array_equal(np.asarray(a1.xy), np.asarray(a2.xy)), "act is not deterministic"
print("waypoints", a1.xy.shape, "first scenario:", np.round(np.asarray(a1.xy[0]), 2).tolist())

# %% [markdown]
# ## 3. Evaluate it next to the reference policies
# `evaluate` rolls each policy out on every scenario at once. `log_replay`
# replays the logged ego (the upper bound), `expert` is the rule-based
# reference driver, `stop` never moves (the lower bound).

# %%
rows = {}
for policy in (mine, *(load_policy(ROOT / "drivee2e_jax" / "zoo" / f"{n_}.py") for n_ in ("expert", "stop"))):
    res = de.evaluate(policy, packed, None, limit=LIMIT)
    rows[policy.name] = res.rows
    ds = np.mean([r["driving_score"] for r in res.rows])
    sr = 100 * np.mean([r["success"] for r in res.rows])
    rc = np.mean([r["route_completion"] for r in res.rows])
    print(f"{policy.name:<15} DS {ds:6.2f}  SR {sr:5.1f} %  RC {rc:6.2f} %  ({len(res.rows)} episodes)")

# %% [markdown]
# ## 4. Where does it lose points?
# Each row carries a count per infraction type (`COUNT_COLUMNS`) and the
# episode status; sum them over the episodes.

# %%
from drivee2e_jax.metrics.episode import COUNT_COLUMNS

counts = {c: sum(int(r[c]) for r in rows[mine.name]) for c in COUNT_COLUMNS}
print("infractions of", mine.name, ":", {c: v for c, v in counts.items() if v} or "none")
statuses = {}
for r in rows[mine.name]:
    statuses[r["status"]] = statuses.get(r["status"], 0) + 1
print("episode status:", statuses)

# %% [markdown]
# ## 5. From the command line
# The same file runs in the main job, with tables, plots and resumable results:
#
# ```bash
# drivee2e check-policy path/to/route_follower.py   # types, shapes, state, NaN, jit / vmap (docs/policies.md)
# drivee2e bench --policy path/to/route_follower.py --policy expert --split val
# ```
