#!/usr/bin/env bash
# The README's test command: install the package with its test extras, check
# lint and the import layers, run pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
python -m pip install --quiet -e ".[test]"
# ruff: pyflakes, isort, bugbear, pyupgrade, module-level imports (pyproject.toml [tool.ruff]).
python -m ruff check drivee2e_jax tests experiments notebooks scripts
# import-linter: the layers contract of docs/architecture.md (pyproject.toml [tool.importlinter]).
lint-imports --no-cache
# Two workers by default (PYTEST_WORKERS=0 runs in one process): compiling
# dominates test time and XLA compiles on one thread. The 25 slowest tests
# are listed at the end, to keep the suite's time in view.
python -m pytest -n "${PYTEST_WORKERS:-2}" --durations=25 "$@"
