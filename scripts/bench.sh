#!/usr/bin/env bash
# The README's main command: install the package, run the benchmark sweep on the
# built-in twin15 suite (val split, the reference policies).
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --quiet -e .
drivee2e bench "$@"
