"""Ctrl-C during a cold compile exits 130, every time (not SIGABRT 134 from
interpreter shutdown while XLA's compile threads run)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("delay_s", [0.5, 2.0, 4.0])
def test_ctrl_c_during_a_cold_compile_exits_130(tmp_path, delay_s):
    env = {**os.environ, "PYTHONPATH": str(REPO), "DRIVEE2E_JAX_CACHE": "off", "DRIVEE2E_LOWERED_CACHE": "off",
           "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "drivee2e_jax.cli", "bench", "--suite", "tiny", "--limit", "1", "--policy", "expert",
           "--out", str(tmp_path / "out"), "--no-progress"]
    proc = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # The run's header ("suite tiny ... -> OUT") comes right before the cold
    # compile: wait for it rather than for a fixed time (a loaded machine
    # may still be importing after several seconds).
    for line in proc.stdout:
        if " -> " in line:
            break
    time.sleep(delay_s)  # the rollout compiling (cold: no cache)
    if proc.poll() is not None:
        pytest.fail(f"finished before the interrupt: {proc.returncode} {proc.stderr.read()[-300:]}")
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (proc.returncode, err[-500:])
    assert "drivee2e: interrupted" in err
    assert "Traceback" not in err and "pure virtual" not in err
