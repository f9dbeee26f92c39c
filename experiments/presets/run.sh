#!/usr/bin/env bash
# The log, the expert, constant velocity and the trained baselines on twin15 val under
# --preset nuplan and --preset navsim, then their sub-metric tables (docs/results.md,
# "The log, the expert and the baselines under the nuPlan and NAVSIM presets").
#   bash experiments/presets/run.sh [OUT_DIR]     (default /tmp/drivee2e-presets; ~20 min on 2 cores)
set -euo pipefail
out=${1:-/tmp/drivee2e-presets}
policies=(log_replay expert constant_velocity ad_mlp vector_mlp vector_transformer vector_transformer_ft tcp ppo)
args=()
for p in "${policies[@]}"; do args+=(--policy "$p"); done
for preset in nuplan navsim; do
  drivee2e bench --split val --preset "$preset" "${args[@]}" --no-progress --out "$out/$preset"
done
python "$(dirname "$0")/table.py" "$out/nuplan" "$out/navsim"
