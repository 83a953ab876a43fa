"""Grouped medians (graphcal.core.grouped) against pandas' groupby median."""

from __future__ import annotations

import numpy as np
import pandas as pd

from graphcal.core.grouped import group_medians


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
