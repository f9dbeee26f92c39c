# %% [markdown]
# # drivee2e-jax quickstart
#
# Evaluate driving policies in **ego-closed-loop replay**: the ego is driven by
# the policy, every other agent replays its log. This notebook is a plain
# Python file in the "percent" cell format: run it with `python
# notebooks/quickstart.py`, or open it as a notebook in VS Code / JupyterLab
# with jupytext. The tests execute it (on a small suite) so it stays true.
#
# `DRIVEE2E_QUICKSTART_SUITE` / `_SPLIT` / `_LIMIT` pick the suite, split and
# number of scenarios (defaults: `twin15`, `val`, 16).

# %%
import os
from pathlib import Path

import numpy as np

import drivee2e_jax as de
from drivee2e_jax.policy import load_policy

de.enable_compile_cache()  # reruns reuse compiled rollouts from disk (drivee2e_jax/compile_cache.py)

ROOT = Path(__file__).resolve().parents[1] if "__file__" in globals() else Path.cwd().parent
SUITE = os.environ.get("DRIVEE2E_QUICKSTART_SUITE", "twin15")
SPLIT = os.environ.get("DRIVEE2E_QUICKSTART_SPLIT", "val")
LIMIT = int(os.environ.get("DRIVEE2E_QUICKSTART_LIMIT", "16"))

# %% [markdown]
# ## 1. A suite is scenarios packed into padded arrays
# `load_suite` reads (or generates and caches) the suite; `pack(split)` gives
# one `Scenario` pytree with a leading batch axis plus a host-side meta table.

# %%
suite = de.load_suite(SUITE)
packed = suite.pack(SPLIT)
print(f"{suite.name}: {len(packed.meta)} scenarios in split {SPLIT!r}")
print("agent tracks (batch, agents, log steps):", packed.scenario.tracks.xy.shape[:3])
first = next(iter(packed.meta.rows()))
print("first scenario:", {k: first[k] for k in ("scenario_id", "intersection_id", "behavior", "weather")})

# %% [markdown]
# ## 2. Evaluate reference policies
# Each policy is a Python file with a pure `act(params, obs, state, key)` that
# runs inside the jitted, vmapped rollout. `evaluate` rolls it out on every
# scenario of the split at once and scores each episode.

# %%
results = {}
for name in ("log_replay", "expert", "stop"):
    policy = load_policy(ROOT / "drivee2e_jax" / "zoo" / f"{name}.py")
    res = de.evaluate(policy, packed, None, limit=LIMIT)
    results[name] = res
    ds = np.mean([r["driving_score"] for r in res.rows])
    sr = 100 * np.mean([r["success"] for r in res.rows])
    print(f"{name:<11} DS {ds:6.2f}  SR {sr:5.1f} %  ({len(res.rows)} episodes, rollout {res.wall_s:.2f} s)")

# %% [markdown]
# ## 3. Per-scenario records and infraction events
# Every row has route completion, infraction score, Driving Score, status and
# a count per infraction type; events carry time and place.

# %%
row = results["expert"].rows[0]
print({k: row[k] for k in ("scenario_id", "route_completion", "infraction_score", "driving_score", "status")})
events = results["expert"].events[row["scenario_id"]]
print("events:", events[:3])

# %% [markdown]
# ## 4. The episode log
# `res.logs` is the stacked per-step `StepLog` (numpy, `(B, T, ...)`): the
# ego's simulated pose, speed and controls, the infraction facts per tick.

# %%
logs = results["expert"].logs
speed = np.where(logs.active, logs.speed, np.nan)
print("expert mean speed per episode, m/s:", np.round(np.nanmean(speed, axis=1)[:8], 2))

# %% [markdown]
# ## 5. The main job, and looking at an episode
# `run_bench` is what `drivee2e bench` runs: it writes a resumable results
# folder (per-scenario CSV/JSON, summary, report with plots). From that folder
# `trace_episodes` re-simulates chosen episodes exactly (checking the stored
# Driving Score) and `write_player` turns them into one self-contained HTML
# player (`drivee2e view` on the command line; `drivee2e export-mcap` writes
# the same episodes for Foxglove).

# %%
import tempfile

from drivee2e_jax.eval.bench import BenchConfig, run_bench
from drivee2e_jax.eval.traces import trace_episodes
from drivee2e_jax.viz.player import write_player

out = Path(tempfile.mkdtemp()) / "results"
summary = run_bench(BenchConfig(suite=SUITE, split=SPLIT, policies=(str(ROOT / "drivee2e_jax" / "zoo" / "expert.py"),),
                                out=out, limit=LIMIT, progress=False), print_fn=lambda line: None)
print("results folder:", sorted(p.name for p in out.iterdir()))
first_id = row["scenario_id"]
traces = trace_episodes(out, "expert", [first_id], sensors=("bev",))
tr = traces[0]
print(f"trace of {first_id}: {tr.times.shape[0]} states, ego at t=0 {np.round(tr.ego_xy[0], 2).tolist()}")
player = write_player(traces, out / "player.html")
print(f"player: {player} ({player.stat().st_size // 1024} KiB) - open it in a browser")
