# %% [markdown]
# # A PyTorch policy: in process and served
#
# A JAX policy runs inside the jitted rollout; a **host policy**
# (`drivee2e_jax.hostapi.HostPolicy`) runs outside it, in any framework, on
# numpy arrays: once per control step the simulator hands it the observation
# of every scenario of the batch (leading batch axis `B`) and takes back `B`
# actions (`docs/host_policies.md`).
#
# This notebook uses the PyTorch example `docs/examples/torch_policy.py`:
#
# 1. its deterministic `route_follow` mode (waypoints along the route at a
#    safe speed, in torch ops, no training) against the `stop` lower bound;
# 2. its `mlp` mode: a small `torch.nn` MLP trained here to imitate the route
#    follower, saved and loaded back with `weights=PATH`;
# 3. the same file served by `drivee2e serve-policy` in another process (which
#    imports no JAX) and evaluated as `remote://127.0.0.1:PORT`.
#
# It needs PyTorch (`pip install torch`; the CPU wheel is enough), which is not
# a dependency of drivee2e-jax. Run it with `python notebooks/torch_policy.py`
# or open it with jupytext; the tests execute it on a tiny suite when torch is
# installed. `DRIVEE2E_TORCH_SUITE` / `_SPLIT` / `_LIMIT` / `_STEPS` pick the
# suite, split, number of scenarios and MLP training steps (defaults:
# `twin15`, `val`, 8, 300).

# %%
import importlib.util
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

import drivee2e_jax as de
from drivee2e_jax.hostapi import HostPolicy
from drivee2e_jax.policy import load_policy

de.enable_compile_cache()  # reruns reuse compiled rollouts from disk (drivee2e_jax/compile_cache.py)
torch.manual_seed(0)

ROOT = Path(__file__).resolve().parents[1] if "__file__" in globals() else Path.cwd().parent
EXAMPLE = ROOT / "docs" / "examples" / "torch_policy.py"
SUITE = os.environ.get("DRIVEE2E_TORCH_SUITE", "twin15")
SPLIT = os.environ.get("DRIVEE2E_TORCH_SPLIT", "val")
LIMIT = int(os.environ.get("DRIVEE2E_TORCH_LIMIT", "8"))
STEPS = int(os.environ.get("DRIVEE2E_TORCH_STEPS", "300"))
print("torch", torch.__version__)

# %% [markdown]
# ## 1. Load the policy file and evaluate it
# `load_policy(FILE)` calls the file's `make_policy()` (here `mode="route_follow"`);
# `load_policy(FILE, mode="mlp", weights=...)` passes arguments, as
# `--policy FILE:mode=mlp,weights=...` does on the command line. A host policy
# goes to `evaluate` like a JAX one: the rollout stays compiled and calls it
# once per control step for the whole batch.

# %%
suite = de.load_suite(SUITE)
packed = suite.pack(SPLIT)
route_follow = load_policy(EXAMPLE)
print("loaded", route_follow.name, "->", route_follow.action_type, f"({route_follow.num_waypoints} waypoints,",
      f"{route_follow.waypoint_dt} s apart)")

COLUMNS = ("scenario_id", "behavior", "route_completion", "infraction_score", "driving_score", "status")
HEAD = {"route_completion": "RC %", "infraction_score": "IS", "driving_score": "DS"}


def show(res) -> None:
    """The per-scenario rows, then the means."""
    print("  " + "  ".join(f"{HEAD.get(c, c):>7}" if c in HEAD else f"{c:<12}" for c in COLUMNS))
    for r in res.rows:
        print("  " + "  ".join(f"{r[c]:<12}" if isinstance(r[c], str) else f"{r[c]:7.2f}" for c in COLUMNS))
    ds = np.mean([r["driving_score"] for r in res.rows])
    rc = np.mean([r["route_completion"] for r in res.rows])
    print(f"{res.rows[0]['policy']:<20} DS {ds:6.2f}  RC {rc:6.2f} %  ({len(res.rows)} episodes)")


results = {}
for policy in (route_follow, load_policy(ROOT / "drivee2e_jax" / "zoo" / "stop.py")):
    results[policy.name] = de.evaluate(policy, packed, None, limit=LIMIT)
    show(results[policy.name])

# %% [markdown]
# ## 2. Train the MLP by imitating the route follower
# Record `(features, waypoints)` pairs while the route follower drives (a
# host policy that wraps it and keeps what it sees), fit `TorchMLP` to them
# with Adam, save it with `save_weights` and load it back through the policy
# file with `mode="mlp", weights=PATH`. The example module's helpers
# (`features`, `TorchMLP`, `save_weights`) are imported from the file.

# %%
spec = importlib.util.spec_from_file_location("torch_policy_example", EXAMPLE)
tp = importlib.util.module_from_spec(spec)
spec.loader.exec_module(tp)


class Recorder(HostPolicy):
    """Drives like ``teacher`` and records its inputs and outputs (a notebook
    shortcut: data on ``self``; a policy keeps per-batch data in ``state``)."""

    def __init__(self, teacher):
        self.teacher, self.inputs, self.targets = teacher, [], []
        self.name, self.action_type = "recorder", teacher.action_type
        self.waypoint_dt, self.num_waypoints = teacher.waypoint_dt, teacher.num_waypoints

    def reset(self, meta):
        return self.teacher.reset(meta)

    def act(self, obs, state):
        action, state = self.teacher.act(obs, state)
        self.inputs.append(tp.features(obs))
        self.targets.append(torch.from_numpy(np.array(action.xy)))
        return action, state


recorder = Recorder(route_follow)
de.evaluate(recorder, packed, None, limit=LIMIT)
x, y = torch.cat(recorder.inputs), torch.cat(recorder.targets)
print(f"recorded {x.shape[0]} (features, waypoints) pairs: {tuple(x.shape)} -> {tuple(y.shape)}")

net = tp.TorchMLP()
opt = torch.optim.Adam(net.parameters(), lr=1e-3)
for step in range(STEPS + 1):
    batch = torch.randint(0, x.shape[0], (256,))
    loss = torch.nn.functional.mse_loss(net(x[batch]), y[batch])
    opt.zero_grad()
    loss.backward()
    opt.step()
    if step % max(STEPS // 3, 1) == 0:
        print(f"step {step:4d}  mse {loss.item():8.4f} m^2")

weights = tp.save_weights(net, Path(tempfile.mkdtemp()) / "torch_mlp.pt")
mlp = load_policy(EXAMPLE, mode="mlp", weights=str(weights))
print("loaded", mlp.name, "from", weights.name)
results[mlp.name] = de.evaluate(mlp, packed, None, limit=LIMIT)
show(results[mlp.name])

# %% [markdown]
# ## 3. Serve it from another process
# `drivee2e serve-policy FILE --port N` loads the file and serves it over
# ZeroMQ; its environment needs numpy, pyzmq and torch, not JAX
# (`DRIVEE2E_JAX_CACHE=off` keeps the CLI from even enabling JAX's compilation
# cache). Where the simulator runs, `remote://127.0.0.1:N` names the served
# policy. Same file, same inputs: the same rows as in process.
#
# ```bash
# drivee2e serve-policy docs/examples/torch_policy.py --port 5555          # terminal 1 (torch env)
# drivee2e bench --policy remote://127.0.0.1:5555 --split val              # terminal 2 (JAX env)
# ```

# %%
with socket.socket() as s:  # a free port (the server could also take --port 0 and print the one it got)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
server = subprocess.Popen(
    [sys.executable, "-m", "drivee2e_jax.cli", "serve-policy", str(EXAMPLE), "--port", str(port)],
    stdout=subprocess.PIPE, text=True, env=dict(os.environ, DRIVEE2E_JAX_CACHE="off"))
try:
    line = server.stdout.readline()  # "serving NAME (waypoints) from FILE on tcp://127.0.0.1:PORT" once it listens
    assert "serving" in line, f"serve-policy did not start (rc={server.poll()})"
    print(line.strip())
    t0 = time.perf_counter()
    remote = de.evaluate(load_policy(f"remote://127.0.0.1:{port}"), packed, None, limit=LIMIT)
    print(f"remote evaluation: {time.perf_counter() - t0:.1f} s")
finally:
    server.terminate()
    server.wait(timeout=30)
show(remote)
skip = {"policy", "eval_time_s"}
same = all({k: v for k, v in a.items() if k not in skip} == {k: v for k, v in b.items() if k not in skip}
           for a, b in zip(results[route_follow.name].rows, remote.rows))
print("remote rows == in-process rows:", same)

# %% [markdown]
# ## 4. From the command line
# The same file in the main job, with tables, plots and resumable results:
#
# ```bash
# drivee2e bench --policy docs/examples/torch_policy.py --policy stop --split val
# drivee2e bench --policy docs/examples/torch_policy.py:mode=mlp,weights=torch_mlp.pt,device=cuda
# ```
