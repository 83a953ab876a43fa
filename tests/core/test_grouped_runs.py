"""group_runs (graphcal.core.grouped, used by the cleaning's identity check and the
plausibility medians) against numpy's unique."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.core.grouped import group_runs


@pytest.mark.parametrize("low, high, scale, dtype", [
    (0, 40, 1, np.int64), (-1, 300, 1, np.int64), (0, 9, 1, np.int32),
    (0, 50_000, 1, np.int64), (-5, 40, 1000, np.int64)])
def test_the_groups_are_those_of_numpy_unique(low, high, scale, dtype) -> None:
    """16-bit codes (radix sort, -1 included), and wider ones or below -1 (numpy's unique)."""
    rng = np.random.default_rng(high)
    group = (rng.integers(low, high, 5000) * scale).astype(dtype)
    expected = np.unique(group, return_index=True, return_inverse=True, return_counts=True)
    for got, want in zip(group_runs(group), expected, strict=True):
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)


def test_none_or_one_row() -> None:
    for group in (np.zeros(0, dtype=np.int64), np.array([3])):
        expected = np.unique(group, return_index=True, return_inverse=True, return_counts=True)
        for got, want in zip(group_runs(group), expected, strict=True):
            np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("low, high", [(-1, 300), (0, 50_000), (-7, 5)])
def test_group_rows_is_numpy_stable_argsort(low, high) -> None:
    """Rows by group code, ties in row order: numpy's stable argsort, radix or not."""
    from graphcal.core.grouped import group_rows

    group = np.random.default_rng(high).integers(low, high, 5000)
    np.testing.assert_array_equal(group_rows(group), np.argsort(group, kind="stable"))
