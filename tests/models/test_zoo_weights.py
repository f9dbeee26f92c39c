"""The trained weights the package ships reproduce the twin15 val scores their
json records (``drivee2e bench --policy NAME --split val`` on a fresh install).

The scores were measured on the machine that exported the weights. twin15's
generator is CPU-dependent in the last float bits (tests/eval/test_golden.py:
5 of the 200 val scenarios differ between an AVX2-only and an AVX-512
machine), so on another CPU type a policy's DS may move by a fraction of a
point; the tolerance below allows that and nothing like a wrong or random
set of weights (a random vector_transformer scores DS ~5, the trained 81).
"""

from __future__ import annotations

import json

import pytest

from drivee2e_jax.eval.bench import BenchConfig, run_bench
from drivee2e_jax.eval.summary import summary_of
from drivee2e_jax.policy import ZOO_WEIGHTS_ENV, reference_policy_dir, resolve_policy_path

SHIPPED = reference_policy_dir() / "weights"
INFOS = {p.stem: json.loads(p.read_text()) for p in sorted(SHIPPED.glob("*.json"))}
DS_TOL, SR_TOL = 1.5, 3.0


def test_every_shipped_pair_is_complete():
    for name, info in INFOS.items():
        assert (SHIPPED / f"{name}.npz").is_file(), name
        assert info["name"] == name and info["format"] == 1
        assert info["val"] is not None and info["training"]["command"], f"{name}: no val scores or training command"
        for variant, val in (info.get("variants") or {}).items():
            assert val is not None and variant.startswith(name), (name, variant)


def _expected() -> dict:
    """{zoo name: its json's val}: every shipped pair and the variants that
    drive the same weights in another mode (tcp_traj, tcp_ctrl on tcp)."""
    out = {}
    for name, info in INFOS.items():
        out[name] = info["val"]
        out.update(info.get("variants") or {})
    return out


@pytest.mark.slow
def test_shipped_weights_reproduce_their_val_scores(tmp_path, monkeypatch):
    if not INFOS:
        pytest.fail(f"no bundled weights in {SHIPPED}")
    monkeypatch.delenv(ZOO_WEIGHTS_ENV, raising=False)
    monkeypatch.delenv("DRIVEE2E_AD_MLP_CHECKPOINT", raising=False)
    expected = _expected()
    names = sorted(expected)
    cfg = BenchConfig(split="val", policies=tuple(str(resolve_policy_path(n)) for n in names), out=tmp_path / "b",
                      progress=False)
    run_bench(cfg, print_fn=lambda _line: None)
    for name in names:
        rows = json.loads((tmp_path / "b" / "policies" / f"{name}.json").read_text())["rows"]
        got, want = summary_of(rows), expected[name]
        assert len(rows) == 200, name
        assert got["driving_score"] == pytest.approx(want["driving_score"], abs=DS_TOL), name
        assert got["success_rate"] == pytest.approx(want["success_rate"], abs=SR_TOL), name
