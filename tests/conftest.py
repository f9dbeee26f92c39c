"""Shared fixtures: a tiny hand-built suite (2 maps, 4 scenarios) for fast tests.

The suite itself is ``tests/helpers/tiny_suite.py`` (``build_tiny_suite``).

``tiny_suite`` is a fresh ``SuiteRecord`` per test (mutate it freely);
``tiny_suite_dir`` is that suite written as a folder under ``tmp_path``;
``drivee2e_cache`` points ``$DRIVEE2E_CACHE`` at a per-test folder.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from drivee2e_jax.records import SuiteRecord
from tests.helpers.tiny_suite import build_tiny_suite


def pytest_configure(config):
    """JAX's persistent compilation cache: reruns (and CI on the same machine)
    reuse compiled rollouts instead of recompiling every jit from scratch. The
    folder is pinned in ``$DRIVEE2E_JAX_CACHE`` so tests that move
    ``$DRIVEE2E_CACHE`` and the subprocesses they start keep sharing it."""
    from drivee2e_jax import compile_cache

    path = compile_cache.enable()
    os.environ[compile_cache.JAX_CACHE_ENV] = str(path) if path is not None else "off"


@pytest.fixture
def tiny_suite() -> SuiteRecord:
    """A fresh 4-scenario, 2-map suite (splits train 2 / val 1 / test 1)."""
    return build_tiny_suite()


@pytest.fixture
def tiny_suite_dir(tmp_path, tiny_suite):
    """``tiny_suite`` written as a suite folder; returns its path."""
    from drivee2e_jax.scenario.schema import write_suite

    return write_suite(tiny_suite, tmp_path / "tiny")


@pytest.fixture
def drivee2e_cache(tmp_path, monkeypatch):
    """A private ``$DRIVEE2E_CACHE`` folder for this test."""
    path = tmp_path / "cache"
    monkeypatch.setenv("DRIVEE2E_CACHE", str(path))
    return path


# --------------------------------------------------------------------------
# Training tests (tests/train, tests/models, tests/e2e): a tiny demonstration dataset and a 2-epoch
# AD-MLP run on it, built once per session (the recorder's compile dominates
# their cost). Kept here, not in tests/train/conftest.py, so that every folder
# of tests shares the one session-scoped run.
# --------------------------------------------------------------------------

_TINY_EXAMPLE = Path(__file__).resolve().parents[1] / "drivee2e_jax" / "scenario" / "examples" / "tiny"


@pytest.fixture(scope="session")
def tiny_demos(tmp_path_factory) -> Path:
    """The tiny suite's train split (2 scenarios) recorded at 2 Hz, one shard per scenario."""
    from drivee2e_jax.train.dataset import DatasetConfig, build_dataset

    out = tmp_path_factory.mktemp("demos")
    build_dataset(str(_TINY_EXAMPLE), "train", out, DatasetConfig(scenarios_per_shard=1))
    return out


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory, tiny_demos) -> Path:
    """AD-MLP trained 2 epochs (batch 4) on ``tiny_demos``: 2 checkpoints."""
    from drivee2e_jax.train.loop import train

    out = tmp_path_factory.mktemp("run")
    train(_small_config(tiny_demos), out, print_fn=lambda s: None)
    return out


@pytest.fixture(scope="session")
def small_config():
    """``small_config(data, **overrides)`` -> the TrainConfig of ``tiny_run``."""
    return _small_config


def _small_config(data, **kw):
    from drivee2e_jax.train.loop import TrainConfig

    base = dict(model="ad_mlp", model_config=(("hidden", (32,)),), data=str(data), epochs=2, batch_size=4,
                warmup_steps=2, log_every=1)
    return TrainConfig(**{**base, **kw})
