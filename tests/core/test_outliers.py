"""Gross outliers by the median absolute deviation (graphcal.core.outliers)."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.core.outliers import MIN_FINITE, OUTLIER_SIGMAS, outlier_rows


def test_rows_beyond_eight_robust_sigmas_in_any_coordinate_are_flagged() -> None:
    rng = np.random.default_rng(4)
    range_z, azimuth_z = rng.normal(0.0, 2.0, 500), rng.normal(1.0, 0.5, 500)
    range_z[[7, 300]] = [40.0, -30.0]  # 20 and 15 sigma (sigma 2)
    azimuth_z[42] = 1.0 + 6.0  # 12 sigma of 0.5
    bad = outlier_rows([range_z, azimuth_z])
    assert np.flatnonzero(bad).tolist() == [7, 42, 300]


def test_the_threshold_is_relative_to_the_robust_scale() -> None:
    """Median 0 and median absolute deviation 3 (robust sigma 4.45): a value at 7.5 robust
    sigmas stays, one at 8.5 goes."""
    scale = 1.4826 * 3.0
    z = np.concatenate([np.tile([-3.0, 3.0], 500), [0.0, 7.5 * scale, -8.5 * scale]])
    assert np.median(z) == 0.0 and np.median(np.abs(z)) == 3.0
    assert np.flatnonzero(outlier_rows([z])).tolist() == [1002]
    assert OUTLIER_SIGMAS == 8.0


def test_nan_rows_few_values_and_no_spread_flag_nothing() -> None:
    z = np.full(50, 2.0)
    z[3] = 1e6  # a zero MAD: no scale, no outlier
    assert not outlier_rows([z]).any()
    few = np.array([0.0] * (MIN_FINITE - 2) + [1e6, np.nan])
    assert not outlier_rows([few]).any()
    with_nan = np.concatenate([np.linspace(-1.0, 1.0, 100), [np.nan, 1e3]])
    assert outlier_rows([with_nan]).tolist() == [False] * 101 + [True]
    with pytest.raises(ValueError, match="at least one"):
        outlier_rows([])
