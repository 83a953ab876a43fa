"""Gross outliers among standardised residuals, by the median absolute deviation.

One rule, shared by the model checks
(:func:`graphcal.analysis.check_residuals.without_outliers`) and the fit numbers each
time window keeps (:mod:`graphcal.solvers.window_fit`), so that a window and a whole
calibration leave out the same plots: a residual ``z = e / sqrt(v)`` (standardised by
its expected variance) further than :data:`OUTLIER_SIGMAS` robust sigmas
(``1.4826`` median absolute deviations) from the median of its coordinate is an
outlier, and a row with an outlier in any coordinate is left out.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from numpy.typing import NDArray

#: Standardised residuals further than this many robust sigmas from their median are
#: gross outliers.
OUTLIER_SIGMAS = 8.0
#: Fewer finite residuals than this in a coordinate: no robust scale, no outlier.
MIN_FINITE = 10
#: Median absolute deviation -> sigma of a normal distribution.
MAD_TO_SIGMA = 1.4826


def outlier_rows(standardised: Iterable[NDArray[np.float64]],
                 sigmas: float = OUTLIER_SIGMAS) -> NDArray[np.bool_]:
    """The rows with a gross outlier in any coordinate (module docstring).

    Parameters
    ----------
    standardised : iterable of ndarray, each shape (n,)
        One array per coordinate: residual over its expected sigma (dimensionless);
        NaN where a row has none.  At least one array.
    sigmas : float
        The threshold, in robust sigmas.

    Returns
    -------
    ndarray of bool, shape (n,)
        True for the rows to leave out.  A coordinate with fewer than
        :data:`MIN_FINITE` finite values, or a zero median absolute deviation,
        marks none.
    """
    bad: NDArray[np.bool_] | None = None
    for z in standardised:
        z = np.asarray(z, dtype=float)
        if bad is None:
            bad = np.zeros(z.shape, dtype=bool)
        finite = np.isfinite(z)
        if finite.sum() < MIN_FINITE:
            continue
        centre = np.median(z[finite])
        scale = MAD_TO_SIGMA * np.median(np.abs(z[finite] - centre))
        if scale > 0:
            with np.errstate(invalid="ignore"):
                bad |= finite & (np.abs(z - centre) > sigmas * scale)
    if bad is None:
        raise ValueError("outlier_rows needs at least one coordinate")
    return bad


__all__ = ["MAD_TO_SIGMA", "MIN_FINITE", "OUTLIER_SIGMAS", "outlier_rows"]
