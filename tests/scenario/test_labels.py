"""The shared behaviour-label thresholds (``scenario.labels``)."""

from __future__ import annotations

import pytest

from drivee2e_jax.scenario.labels import TURN_MIN_DEG, UTURN_MIN_DEG, turn_label


@pytest.mark.parametrize("turn, label", [
    (0.0, "STR"), (TURN_MIN_DEG, "STR"), (-TURN_MIN_DEG, "STR"), (41.0, "LFT"), (-41.0, "RT"),
    (UTURN_MIN_DEG, "LFT"), (151.0, "UT"), (-151.0, "UT"), (-179.0, "UT"),
])
def test_turn_label(turn, label):
    assert turn_label(turn) == label


def test_twin15_counts_only_left_uturns():
    assert turn_label(170.0, left_uturns_only=True) == "UT"
    assert turn_label(-170.0, left_uturns_only=True) == "RT"
    assert turn_label(-170.0) == "UT"
