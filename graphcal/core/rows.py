"""Rows of arrays, selected along the first axis."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def take_rows(array: NDArray, rows: NDArray) -> NDArray:
    """``array[rows]`` along the first axis, ``rows`` indices or a boolean mask: the same
    rows, in a new array.

    numpy's fancy and boolean indexing of an array of two or more dimensions goes
    element by element (about 1 ms for 80,000 rows of 3); :func:`numpy.take` and
    :func:`numpy.compress` copy whole rows, four to five times faster.
    """
    rows = np.asarray(rows)
    if rows.dtype == bool:
        return np.compress(rows, array, axis=0)
    return np.take(array, rows, axis=0)
