#!/usr/bin/env bash
# The install that users get, checked: build the wheel, install it into a fresh
# virtual environment with every direct dependency at its LOWEST allowed
# version (pyproject.toml's lower bounds, resolved by uv), and from a folder
# outside the checkout run the README's main job (`drivee2e bench`, twin15 val,
# the default policies, 5 scenarios), `drivee2e dataset build` (2 scenarios) and
# `drivee2e check-policy stop` (on the example suite `tiny` inside the package).
# Fails if a command fails or its tables / summary line are missing.
#
# WHEEL_CHECK_RESOLUTION=highest checks the newest allowed versions instead;
# WHEEL_CHECK_KEEP=1 keeps the work folder (printed) for a look afterwards.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
resolution="${WHEEL_CHECK_RESOLUTION:-lowest-direct}"
work="$(mktemp -d "${TMPDIR:-/tmp}/drivee2e-wheel.XXXXXX")"
if [ "${WHEEL_CHECK_KEEP:-0}" = 1 ]; then
  echo "wheel check: work folder $work"
else
  trap 'rm -rf "$work"' EXIT
fi

step() { echo "wheel check: $*"; }
fail() { echo "wheel check FAILED: $*" >&2; exit 1; }

# Build from a copy of the files git knows (tracked + untracked, not ignored):
# a stale build/ folder in the checkout could otherwise leak into the wheel.
src="$repo"
if git -C "$repo" rev-parse --is-inside-work-tree >/dev/null 2>&1; then
  src="$work/src"
  mkdir -p "$src"
  # (--ignore-failed-read: a tracked file deleted in the work tree is skipped)
  (cd "$repo" && git ls-files -co --exclude-standard -z \
    | tar --null -T - --ignore-failed-read -cf - 2>/dev/null | tar -xf - -C "$src") \
    || fail "could not copy the checkout to $src"
fi
step "building the wheel"
python -m pip wheel --quiet --no-deps -w "$work/dist" "$src" || fail "pip wheel failed"
wheel="$(ls "$work"/dist/drivee2e_jax-*.whl)"

step "installing $(basename "$wheel") with --resolution $resolution into a fresh venv"
# The wheel's own requirements (its METADATA, extras left out) become direct
# requirements: uv's lowest-direct lowers only what is named on its command line.
python - "$wheel" > "$work/requirements.txt" <<'PY'
import sys, zipfile
from email.parser import Parser
with zipfile.ZipFile(sys.argv[1]) as z:
    meta = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
    reqs = Parser().parsestr(z.read(meta).decode()).get_all("Requires-Dist") or []
print("\n".join(r for r in reqs if "extra ==" not in r))
PY
[ -s "$work/requirements.txt" ] || fail "the wheel declares no dependencies"
python -m venv "$work/venv"
"$work/venv/bin/python" -m pip install --quiet uv || fail "could not install uv"
"$work/venv/bin/uv" pip install --quiet --python "$work/venv/bin/python" --resolution "$resolution" \
  "$wheel" -r "$work/requirements.txt" \
  || fail "uv could not install the wheel's dependencies at --resolution $resolution"
"$work/venv/bin/uv" pip freeze --python "$work/venv/bin/python" \
  | grep -iE '^(jax|jaxlib|numpy|scipy|flax|optax|chex|orbax-checkpoint|shapely|mcap|tqdm|matplotlib|gymnasium|pyzmq|foxglove-schemas-protobuf|protobuf)==' \
  | tr '\n' ' ' || true
echo

drivee2e="$work/venv/bin/drivee2e"
run_dir="$work/run"  # not the checkout: the wheel alone must find the suite and the zoo policies
mkdir -p "$run_dir"
cd "$run_dir"

step "import smoke: every module of the installed package"
"$work/venv/bin/python" - <<'PY' || fail "a module of the installed package does not import (a missing dependency?)"
import importlib, pkgutil
import drivee2e_jax
assert "site-packages" in drivee2e_jax.__file__, drivee2e_jax.__file__
names = [m.name for m in pkgutil.walk_packages(drivee2e_jax.__path__, "drivee2e_jax.") if not m.name.endswith("__main__")]
for name in names:
    importlib.import_module(name)
print(f"{len(names)} modules import")
PY

step "the lowered-program store serialises (jax.export needs flatbuffers)"
"$work/venv/bin/python" - <<'PY' || fail "jax.export cannot serialise here: the rollout's lowered programs would never be stored"
import jax, numpy as np
from jax import export
export.deserialize(export.export(jax.jit(lambda x: x + 1))(np.float32(1)).serialize())
print("ok")
PY

step "drivee2e bench --limit 5"
"$drivee2e" bench --limit 5 --no-progress --out "$work/results" | tee "$work/bench.log" \
  || fail "drivee2e bench exited non-zero"
for table in "Closed-loop results" "SR % by behaviour" "DS by behaviour"; do
  grep -q "$table" "$work/bench.log" || fail "drivee2e bench printed no '$table' table"
done
for policy in log_replay expert stop; do
  grep -qE "^$policy " "$work/bench.log" || fail "drivee2e bench printed no row for $policy"
done

step "drivee2e dataset build --limit 2"
"$drivee2e" dataset build --split val --limit 2 --no-progress --out "$work/demos" | tee "$work/dataset.log" \
  || fail "drivee2e dataset build exited non-zero"
grep -q "2 scenarios" "$work/dataset.log" || fail "drivee2e dataset build printed no summary line"
[ -f "$work/demos/manifest.json" ] || fail "drivee2e dataset build wrote no manifest.json"

step "drivee2e check-policy stop (on the example suite shipped in the package)"
"$drivee2e" check-policy stop | tee "$work/check.log" || fail "drivee2e check-policy exited non-zero"
grep -q "^ok: " "$work/check.log" || fail "drivee2e check-policy printed no 'ok:' line"

step "ok ($resolution)"
