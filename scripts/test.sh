#!/usr/bin/env bash
# The README's test command: install the package with its test extras, run pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --quiet -e ".[test]"
# Two workers by default (PYTEST_WORKERS=0 runs in one process): compiling
# dominates test time and XLA compiles on one thread.
python -m pytest -n "${PYTEST_WORKERS:-2}" "$@"
