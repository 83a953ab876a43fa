"""Statistics of numpy arrays per group, without pandas' groupby machinery."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def group_medians(group: IntArray, columns: list[FloatArray]
                  ) -> tuple[IntArray, IntArray, list[FloatArray]]:
    """Per group, in order of first appearance: its code, its size and each column's median.

    One stable sort per column (by group, then value); the median of a group of even
    size is the mean of its two middle values, as in pandas.  About ten times faster
    than ``DataFrame.groupby(...).agg("median")`` on the identity check's tables.

    Parameters
    ----------
    group : ndarray of int, shape (n,)
        Each row's group code.
    columns : list of ndarray, each shape (n,)
        Finite values (a NaN would sort last and shift its group's median).

    Returns
    -------
    codes : ndarray of int, shape (g,)
        The groups, in order of first appearance.
    counts : ndarray of int, shape (g,)
        Their sizes.
    medians : list of ndarray, each shape (g,)
        Each column's median per group.
    """
    codes, first, inverse, counts = np.unique(group, return_index=True, return_inverse=True,
                                              return_counts=True)
    order = np.argsort(first, kind="stable")
    starts = np.cumsum(counts) - counts
    low, high = starts + (counts - 1) // 2, starts + counts // 2
    medians = []
    for values in columns:
        ranked = np.asarray(values, dtype=float)[np.lexsort((values, inverse))]
        medians.append((0.5 * (ranked[low] + ranked[high]))[order])
    return codes[order], counts[order], medians


__all__ = ["group_medians"]
