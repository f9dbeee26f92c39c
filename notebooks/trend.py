# %% [markdown]
# # The checkpoint-trend study: does lower open-loop L2 mean better driving?
#
# The source benchmark found that across checkpoints of one model the
# open-loop L2 keeps falling while closed-loop success and Driving Score do
# not follow (its Figure 5). This notebook runs that study end to end:
# record demonstrations with `log_replay`, imitation-train AD-MLP with one
# Orbax checkpoint per epoch, then score every checkpoint open-loop (L2,
# collision rate on the logged demonstrations) and closed-loop (SR, DS) in
# one sweep. The command-line equivalent:
#
# ```bash
# drivee2e dataset build --suite twin15 --split train --out data/demos-train
# drivee2e train --model ad_mlp --data data/demos-train --epochs 10 --out runs/ad_mlp
# drivee2e trend runs/ad_mlp --split val --out results/trend-ad_mlp
# ```
#
# The measured twin15 result (10 epochs, val) is in `docs/results.md` and
# `docs/img/trend_ad_mlp.png`. The tests execute this notebook on the tiny
# example suite: `DRIVEE2E_TREND_SUITE` / `_TRAIN_SPLIT` / `_EVAL_SPLIT` /
# `_LIMIT` / `_EPOCHS` pick the suite, splits, scenarios and epochs
# (defaults: twin15, train, val, 40 scenarios, 4 epochs).

# %%
import csv
import os
import tempfile
from pathlib import Path

import drivee2e_jax as de
from drivee2e_jax.train.dataset import DatasetConfig, DemoDataset, build_dataset
from drivee2e_jax.train.loop import TrainConfig, train
from drivee2e_jax.train.trend import run_trend

de.enable_compile_cache()  # every checkpoint reuses one compiled rollout

SUITE = os.environ.get("DRIVEE2E_TREND_SUITE", "twin15")
TRAIN_SPLIT = os.environ.get("DRIVEE2E_TREND_TRAIN_SPLIT", "train")
EVAL_SPLIT = os.environ.get("DRIVEE2E_TREND_EVAL_SPLIT", "val")
LIMIT = int(os.environ.get("DRIVEE2E_TREND_LIMIT", "40"))
EPOCHS = int(os.environ.get("DRIVEE2E_TREND_EPOCHS", "4"))
WORK = Path(tempfile.mkdtemp(prefix="drivee2e-trend-"))

# %% [markdown]
# ## 1. Demonstrations
# `log_replay` drives every scenario exactly as logged; every 5th step (2 Hz)
# the observation the policy would get and the logged future (6 waypoints,
# 0.5 s apart) are stored in compressed shards with a manifest.

# %%
data = WORK / "demos"
manifest = build_dataset(SUITE, TRAIN_SPLIT, data, DatasetConfig(), limit=LIMIT)
ds = DemoDataset(data)
print(f"demonstrations: {manifest['count']} samples from {TRAIN_SPLIT!r}, digest {ds.digest[:12]}")

# %% [markdown]
# ## 2. Imitation training, one checkpoint per epoch
# AdamW with warmup + cosine decay, a masked L1 loss on the waypoints; the run
# folder holds `config.json`, `log.jsonl` and `checkpoints/<epoch>`.

# %%
run = WORK / "run"
batch = min(64, len(ds))  # the tiny test suite has only a few samples
cfg = TrainConfig(model="ad_mlp", data=str(data), epochs=EPOCHS, batch_size=batch, warmup_steps=2, log_every=5)
info = train(cfg, run, print_fn=lambda line: None)
print(f"trained {info['epochs']} epochs, {info['steps']} steps, final loss {info['loss']:.3f}")
print("checkpoints:", sorted(p.name for p in (run / "checkpoints").iterdir()))

# %% [markdown]
# ## 3. Every checkpoint, open- and closed-loop
# `run_trend` writes `trend.csv` (a row per checkpoint) and `trend.png`
# (open-loop left, closed-loop right); a rerun reuses finished rows.

# %%
out = WORK / "trend"
rows = run_trend(run, out, suite=SUITE, split=EVAL_SPLIT, limit=LIMIT, print_fn=lambda line: None)
print(f"{'epoch':>5} {'L2 1s':>7} {'L2 2s':>7} {'SR %':>6} {'DS':>6}")
for r in rows:
    l2_1 = "-" if r["l2_1s"] is None else f"{r['l2_1s']:.3f}"
    l2_2 = "-" if r["l2_2s"] is None else f"{r['l2_2s']:.3f}"
    print(f"{r['epoch']:>5} {l2_1:>7} {l2_2:>7} {r['success_rate']:>6.1f} {r['driving_score']:>6.2f}")
with open(out / "trend.csv") as f:
    print("trend.csv columns:", next(csv.reader(f))[:6], "...")
print("plot:", out / "trend.png")

# %% [markdown]
# ## 4. Reading it
# Compare the two panels: if the checkpoint with the lowest L2 is not the one
# with the highest DS, open-loop L2 is not a reliable model-selection signal
# for closed-loop driving. On twin15 (`docs/results.md`), AD-MLP's L2 at 2 s
# falls from 4.02 to 0.42 m over 10 epochs while DS moves between 19.8 and
# 40.4 without following it.

# %%
best_l2 = min((r for r in rows if r["l2_2s"] is not None), key=lambda r: r["l2_2s"], default=None)
best_ds = max(rows, key=lambda r: r["driving_score"])
if best_l2 is not None:
    print(f"lowest L2@2s at epoch {best_l2['epoch']}, highest DS at epoch {best_ds['epoch']}")
