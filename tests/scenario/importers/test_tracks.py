"""importers.tracks.repaired_size: source boxes too small to collide get the
category's default footprint, so imported scenarios pass validation."""

from __future__ import annotations

import numpy as np
import pytest

from drivee2e_jax.scenario.importers.tracks import DEFAULT_SIZES, repaired_size
from drivee2e_jax.scenario.validate import MIN_BOX_SIZE_M


@pytest.mark.parametrize("bad", [[0.0, 0.0, 0.0], [4.0, 0.05, 1.5], [np.nan, 2.0, 1.5], [4.0, np.inf, 1.5]])
def test_degenerate_footprints_take_the_category_default(bad):
    got = repaired_size(bad, "pedestrian")
    assert got[:2].tolist() == list(DEFAULT_SIZES["pedestrian"][:2])
    assert (got[:2] >= MIN_BOX_SIZE_M).all()


def test_a_real_box_is_kept_and_per_sample_sizes_take_the_median():
    assert repaired_size([4.2, 1.8, 1.5], "car").tolist() == [4.2, 1.8, 1.5]
    # One zero sample among good ones does not pull the median below the bound.
    per_sample = [[4.0, 2.0, 1.5], [4.2, 2.0, 1.5], [0.0, 0.0, 0.0]]
    assert repaired_size(per_sample, "car").tolist() == [4.0, 2.0, 1.5]


def test_a_missing_height_takes_the_default_height_only():
    assert repaired_size([4.0, 2.0, np.nan], "van").tolist() == [4.0, 2.0, DEFAULT_SIZES["van"][2]]
