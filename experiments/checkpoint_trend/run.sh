#!/usr/bin/env bash
# The checkpoint-trend study (source paper, Figure 5) for AD-MLP on twin15.
# Record the demonstrations, train 10 epochs (one checkpoint each), then score
# every checkpoint open-loop (L2, collision rate) and closed-loop (SR, DS) on val.
set -euo pipefail
cd "$(dirname "$0")/../.."
drivee2e dataset build --suite twin15 --split train --out data/demos-train
drivee2e train --model ad_mlp --data data/demos-train --epochs 10 --out runs/ad_mlp
python experiments/training/plot_log.py runs/ad_mlp
drivee2e trend runs/ad_mlp --split val --out results/trend-ad_mlp
cp results/trend-ad_mlp/trend.png docs/img/trend_ad_mlp.png
