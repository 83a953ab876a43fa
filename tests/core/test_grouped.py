"""Grouped medians (graphcal.core.grouped) against pandas' groupby median."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from graphcal.core.grouped import group_medians, group_order


def test_grouped_medians_agree_with_pandas() -> None:
    """Groups in order of first appearance, odd and even sizes, two columns."""
    rng = np.random.default_rng(5)
    group = rng.integers(0, 40, 5000)
    a, b = rng.normal(size=5000), rng.exponential(size=5000)
    codes, counts, (ma, mb) = group_medians(group, [a, b])
    expected = pd.DataFrame({"g": group, "a": a, "b": b}).groupby("g", sort=False).agg(
        a=("a", "median"), b=("b", "median"), n=("a", "size"))
    np.testing.assert_array_equal(codes, expected.index.to_numpy())
    np.testing.assert_array_equal(counts, expected["n"].to_numpy())
    np.testing.assert_allclose(ma, expected["a"].to_numpy(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(mb, expected["b"].to_numpy(), rtol=0, atol=1e-15)


def test_one_group_of_two_is_their_mean() -> None:
    codes, counts, (m,) = group_medians(np.array([7, 7]), [np.array([1.0, 4.0])])
    assert codes.tolist() == [7] and counts.tolist() == [2] and m.tolist() == [2.5]


def test_more_groups_than_16_bit_codes_hold_and_ties() -> None:
    """40,000 groups (the 64-bit path) and values with many ties, against pandas."""
    rng = np.random.default_rng(6)
    group = rng.integers(0, 40_000, 100_000) * 3 - 7
    a = rng.integers(0, 5, 100_000).astype(float)
    codes, counts, (ma,) = group_medians(group, [a])
    expected = pd.DataFrame({"g": group, "a": a}).groupby("g", sort=False)["a"].agg(
        ["median", "size"])
    assert len(codes) > np.iinfo(np.int16).max
    np.testing.assert_array_equal(codes, expected.index.to_numpy())
    np.testing.assert_array_equal(counts, expected["size"].to_numpy())
    np.testing.assert_array_equal(ma, expected["median"].to_numpy())


@pytest.mark.parametrize("case", ["sorted values", "unsorted values", "nan", "wide codes",
                                  "missing codes"])
def test_group_order_is_lexsort(case: str) -> None:
    """The radix path (sorted values, 16-bit codes) and the fallback give lexsort's order,
    ties by row included."""
    rng = np.random.default_rng(7)
    n = 20_000
    group = rng.integers(0, 300, n)
    values = np.sort(np.round(rng.uniform(0, 100, n), 1))  # many ties
    if case == "unsorted values":
        values = rng.permutation(values)
    elif case == "nan":
        values[[5, 900]] = np.nan
    elif case == "wide codes":
        group = group * 1000
    elif case == "missing codes":
        group[::7] = -1
    np.testing.assert_array_equal(group_order(group, values), np.lexsort((values, group)))
