"""The one numerical-Jacobian helper of the test suite (central differences).

Analytic Jacobians (factors, frames, covariance conversion, the bias model)
are checked against it, as GTSAM's ``factorTesting.h`` checks its factors.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def numerical_jacobian(
    function: Callable[[FloatArray], ArrayLike],
    x: ArrayLike,
    steps: ArrayLike,
    *,
    difference: Callable[[FloatArray, FloatArray], FloatArray] | None = None,
) -> FloatArray:
    """Central-difference Jacobian ``d function / d x``.

    Parameters
    ----------
    function : callable
        ``function(x)`` with ``x`` of shape ``(..., n)`` returning ``(..., m)``
        (or anything ``numpy.asarray`` turns into that, e.g. a tuple of ``m``
        arrays of shape ``(...)``, which is stacked on the last axis).
    x : array_like (..., n)
        Point(s) of evaluation; leading axes are a batch.
    steps : array_like (n,) or (..., n)
        Step of each component (per point when batched).
    difference : callable, optional
        ``difference(plus, minus)`` of two outputs, e.g. with the azimuth
        component wrapped to ``[-pi, pi)``; default ``plus - minus``.

    Returns
    -------
    ndarray (..., m, n)
        ``(function(x + h e_k) - function(x - h e_k)) / 2h`` in column ``k``.
    """
    x = np.asarray(x, dtype=float)
    steps = np.broadcast_to(np.asarray(steps, dtype=float), x.shape)
    columns = []
    for k in range(x.shape[-1]):
        dx = np.zeros_like(x)
        dx[..., k] = steps[..., k]
        plus, minus = _as_output(function(x + dx)), _as_output(function(x - dx))
        delta = plus - minus if difference is None else difference(plus, minus)
        columns.append(delta / (2.0 * steps[..., k, None]))
    return np.stack(columns, axis=-1)


def _as_output(value: ArrayLike) -> FloatArray:
    if isinstance(value, tuple):
        return np.stack([np.asarray(v, dtype=float) for v in value], axis=-1)
    return np.asarray(value, dtype=float)
