# %% [markdown]
# # Sweeps: many policies x suites x settings from one config
#
# `drivee2e sweep experiments/<name>.toml` runs every combination of an
# experiment config headless and resumably; this notebook does the same from
# Python and reads the combined tables. It is a plain Python file in the
# "percent" cell format (run it with `python notebooks/sweep.py`, or open it
# with jupytext). The tests execute it on a tiny config so it stays true.
#
# `DRIVEE2E_SWEEP_CONFIG` picks the config (default `experiments/smoke.toml`),
# `DRIVEE2E_SWEEP_OUT` the output folder (default: the config's).

# %%
import csv
import os
from pathlib import Path

import drivee2e_jax as de
from drivee2e_jax.sweep import expand, load_config, run_sweep
from drivee2e_jax.sweep.config import out_dir, with_out

de.enable_compile_cache()  # a rerun reuses compiled rollouts from disk

ROOT = Path(__file__).resolve().parents[1] if "__file__" in globals() else Path.cwd().parent
CONFIG = Path(os.environ.get("DRIVEE2E_SWEEP_CONFIG", ROOT / "experiments" / "smoke.toml"))
OUT = os.environ.get("DRIVEE2E_SWEEP_OUT")

# %% [markdown]
# ## 1. A config is frozen dataclasses
# Each TOML table maps onto one dataclass; unknown keys and bad values are
# one-line errors naming the file, the table and the key.

# %%
cfg = with_out(load_config(CONFIG), OUT)
print("policies:", [p.name or p.path for p in cfg.policies])
print("data:", cfg.data)
print("repetitions:", cfg.repetitions)

# %% [markdown]
# ## 2. The grid: one run per suite x split x variant x task x [sim] setting

# %%
runs = expand(cfg)
for r in runs:
    print(f"{r.run_id:<32} suite={r.suite} split={r.split} dt={r.dt} latency={r.latency}")

# %% [markdown]
# ## 3. Run it (complete runs are skipped on a rerun)

# %%
rows = run_sweep(cfg, progress=False)
print(f"{len(rows)} run x policy rows")

# %% [markdown]
# ## 4. Combined tables: policies side by side
# `combined.csv` has one row per run x policy (mean and std over
# repetitions); `combined.md` pivots the compared metrics.

# %%
out = out_dir(cfg)
with open(out / "combined.csv", newline="") as f:
    table = list(csv.DictReader(f))
policies = list(dict.fromkeys(r["policy"] for r in table))
print("driving score per run:")
print(f"{'run':<32}" + "".join(f"{p:>14}" for p in policies))
for run_id in dict.fromkeys(r["run_id"] for r in table):
    cells = {r["policy"]: float(r["driving_score"]) for r in table if r["run_id"] == run_id}
    print(f"{run_id:<32}" + "".join(f"{cells.get(p, float('nan')):>14.2f}" for p in policies))
print()
print((out / "combined.md").read_text())
