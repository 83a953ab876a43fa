"""Statistics of numpy arrays per group, without pandas' groupby machinery."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def group_medians(group: IntArray, columns: list[FloatArray]
                  ) -> tuple[IntArray, IntArray, list[FloatArray]]:
    """Per group, in order of first appearance: its code, its size and each column's median.

    Per column, one sort by value and then :func:`group_order` of the sorted values
    (a radix sort on 16-bit codes when there are fewer than 32,767 groups), which is
    the order by group, then value; the median of a group of even size is the mean of its two
    middle values, as in pandas.  About twenty times faster than
    ``DataFrame.groupby(...).agg("median")`` on the identity check's tables.

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
    codes, first, inverse, counts = group_runs(group)
    order = np.argsort(first, kind="stable")
    starts = np.cumsum(counts) - counts
    low, high = starts + (counts - 1) // 2, starts + counts // 2
    medians = []
    for values in columns:
        values = np.asarray(values, dtype=float)
        by_value = np.argsort(values)
        ranked = values[by_value[group_order(inverse[by_value], values[by_value])]]
        medians.append((0.5 * (ranked[low] + ranked[high]))[order])
    return codes[order], counts[order], medians


def group_runs(group: NDArray) -> tuple[NDArray, IntArray, IntArray, IntArray]:
    """The groups of ``group``: ``np.unique(group, return_index=True, return_inverse=True,
    return_counts=True)``, faster.

    When the codes fit in 16 bits (:func:`_fits_16_bits`), one stable radix sort of the
    codes orders the rows by group, ties by row, so that each run's first row is its
    group's first appearance; otherwise ``np.unique`` runs.

    Parameters
    ----------
    group : ndarray of int, shape (n,)
        Each row's group code.

    Returns
    -------
    codes : ndarray, shape (g,)
        The distinct codes, in increasing order.
    first : ndarray of int, shape (g,)
        The row of each one's first appearance.
    inverse : ndarray of int, shape (n,)
        Each row's position in ``codes``.
    counts : ndarray of int, shape (g,)
        Each one's rows.
    """
    group = np.asarray(group)
    if not _fits_16_bits(group):
        return np.unique(group, return_index=True, return_inverse=True, return_counts=True)
    n = len(group)
    order = np.argsort((group + 1).astype(np.int16), kind="stable")
    ordered = group[order]
    starts = np.flatnonzero(np.concatenate([[True], ordered[1:] != ordered[:-1]]))
    counts = np.diff(np.append(starts, n))
    inverse = np.empty(n, dtype=np.intp)
    inverse[order] = np.repeat(np.arange(len(starts)), counts)
    return ordered[starts], order[starts], inverse, counts


def _fits_16_bits(group: NDArray) -> bool:
    """Whether ``group`` holds (at least two) integer codes from -1 to 32,766, a radix
    sort's range (``group + 1`` in ``int16``)."""
    return bool(len(group) > 1 and group.dtype.kind in "iu" and group.min() >= -1
                and group.max() < np.iinfo(np.int16).max)


def group_order(group: NDArray, values: FloatArray) -> IntArray:
    """Row order by group code, then value: ``np.lexsort((values, group))``, faster.

    When ``values`` are already in non-decreasing order (times of a table written in
    time order) and the codes fit in 16 bits, one stable radix sort of the codes
    gives the same order (ties by row, as ``lexsort``); otherwise ``lexsort`` runs.

    Parameters
    ----------
    group : ndarray of int, shape (n,)
        Each row's group code (``-1`` allowed, as ``pandas.factorize`` gives for a
        missing value).
    values : ndarray of float, shape (n,)
        The second key (NaN sorts last within its group, as in ``lexsort``).

    Returns
    -------
    ndarray of int, shape (n,)
        The row indices in order.
    """
    group = np.asarray(group)
    values = np.asarray(values)
    if (_fits_16_bits(group) and values.dtype.kind == "f"
            and bool(np.all(values[1:] >= values[:-1]))):
        return group_rows(group)
    return np.lexsort((values, group))


def group_rows(group: NDArray) -> IntArray:
    """Row order by group code, ties by row: ``np.argsort(group, kind="stable")``,
    faster.

    When the codes fit in 16 bits (:func:`_fits_16_bits`), one stable radix sort of
    the codes (as ``int16``); otherwise numpy's stable sort of the codes.

    Parameters
    ----------
    group : ndarray of int, shape (n,)
        Each row's group code (``-1`` allowed).

    Returns
    -------
    ndarray of int, shape (n,)
        The row indices in order.
    """
    group = np.asarray(group)
    if _fits_16_bits(group):
        return np.argsort((group + 1).astype(np.int16), kind="stable")
    return np.argsort(group, kind="stable")


__all__ = ["group_medians", "group_order", "group_rows", "group_runs"]
