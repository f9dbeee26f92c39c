#!/usr/bin/env bash
# The same host-policy bench twice, each in a new process, with a fresh JAX
# cache folder: the second run shows what the persistent compilation cache
# saves (docs/performance.md, "Host policies").
#   bash experiments/perf/second_run.sh [CHECKOUT] [LABEL]
# CHECKOUT: the code to time (default: this checkout; e.g. a `git worktree`
# of an older commit); LABEL names the cache and results folders under /tmp.
set -u
root="$(cd "$(dirname "$0")/../.." && pwd)"
code="${1:-$root}"
label="${2:-now}"
work="/tmp/drivee2e-second-run-$label"
rm -rf "$work" && mkdir -p "$work"
for i in 1 2; do
  start=$(date +%s.%N)
  DRIVEE2E_JAX_CACHE="$work/cache" PYTHONPATH="$code" python -m drivee2e_jax.cli bench \
    --policy "$root/docs/examples/numpy_constant_velocity.py" --split val --limit 20 \
    --out "$work/out-$i" --no-progress >/dev/null 2>&1
  rc=$?
  end=$(date +%s.%N)
  echo "$label run $i: exit $rc, $(python -c "print(f'{$end - $start:.1f} s')")"
done
