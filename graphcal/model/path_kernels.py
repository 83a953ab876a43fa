"""Compiled inner loops of the paths' normal equations (Numba), for long recordings.

The paths' normal equations (:mod:`graphcal.model.paths`) are sums over measurements
of small blocks spread over four spline coefficients: ``(B B^T) kron M`` into the
band, ``B kron g`` into the gradient, ``B kron K`` into the bias columns.  NumPy forms
them with sparse products (a few arrays of the measurements' size per sum, about
10 ms for 30,000 plots); the loops here form them in one pass, ten times faster,
with the same sums in another order (equal to rounding, tested).  The band's
Cholesky factor too (its half-bandwidth unrolled: three times LAPACK's ``dpbtrf``,
whose unblocked loop of level-2 calls is slow for so narrow a band), each grid point
of the process-noise search in one pass, and the ADS-B reports' chi-square on the
paths.  And the measurements themselves: each radar's plots linearised on the paths
(positions, polar coordinates and Jacobians, the bias model, for a radar without
refraction or azimuth eccentricity), the reported heights' verticals, the first fit's
plots, the B-spline basis and the band's product with a vector.

Compiling costs about 0.6 s in each process that uses them (loading Numba and its
cached machine code; the first run on a machine also compiles, a few seconds, and
caches the result beside the package or in the user's cache folder), so they are
used only where they pay: :func:`enabled` says whether this process uses them
(:func:`enable` switches them on, e.g. for a recording of many windows), and
``GRAPHCAL_KERNELS=numpy`` keeps NumPy's sums everywhere.  Without Numba installed,
NumPy's sums are used.

Band convention: ``band[d, i] = A[i + d, i]`` (lower band, half-bandwidth 11);
unknown ``3 k + x`` is coefficient ``k``, axis ``x``.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graphcal.model.kernel_codes import TERM_ADDITIVE, TERM_RANGE_GAIN, TERM_TIME_OFFSET

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Environment variable: ``numpy`` keeps the NumPy sums, ``numba`` uses the compiled
#: loops wherever possible (also for small problems).
KERNELS_ENV = "GRAPHCAL_KERNELS"

_state: dict[str, Any] = {"enabled": False, "module": None}


def available() -> bool:
    """Numba is installed and not switched off by ``GRAPHCAL_KERNELS=numpy``."""
    if os.environ.get(KERNELS_ENV, "").strip().lower() == "numpy":
        return False
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def forced() -> bool:
    """``GRAPHCAL_KERNELS=numba``: the compiled loops for every problem."""
    return os.environ.get(KERNELS_ENV, "").strip().lower() == "numba"


def enable() -> bool:
    """Use the compiled loops in this process from now on (when :func:`available`);
    returns whether they are used.  Loads (or, on a machine's first run, compiles)
    them now, so that the cost is not paid in the middle of a solve."""
    if not available():
        return False
    if _state["module"] is None:
        _state["module"] = _compile()
    _state["enabled"] = True
    return True


def enabled() -> bool:
    """Whether the compiled loops are used (:func:`enable`, or ``GRAPHCAL_KERNELS=numba``)."""
    if not _state["enabled"] and forced():
        enable()
    return bool(_state["enabled"])


def compiled() -> Any:
    """The namespace of compiled loops (:func:`enable` first)."""
    if _state["module"] is None:
        enable()
    return _state["module"]


def _compile() -> Any:
    """Import the loops (:mod:`graphcal.model.path_loops`, which compiles or loads them)
    and warm them on tiny inputs."""
    from graphcal.model import path_loops

    _warm(path_loops)
    return path_loops


def _warm(kernels: Any) -> None:
    """Call every loop once on tiny inputs of the types used (loads the cache)."""
    first = np.zeros(1, dtype=np.int64)
    weights = np.full((1, 4), 0.25)
    band = np.zeros((12, 12), order="F")  # as paths.band_zeros makes it
    kernels.add_blocks(band, first, weights, np.eye(3)[None])
    kernels.scatter_vectors(np.zeros(12), first, weights, np.ones((1, 3)))
    kernels.evaluate(np.zeros((4, 3)), first, weights)
    kernels.band_forward(np.ones((12, 4), order="F"), np.ones((4, 2)))
    kernels.band_cholesky(np.ones((12, 4), order="F"))
    kernels.noise_likelihood_terms(np.eye(12, 4, order="F"), np.eye(12, 4, order="F"), 1.0,
                                   np.ones(4), np.ones(4), 1e-12, np.zeros(4, dtype=np.int64), 1,
                                   np.zeros((12, 4), order="F"))
    kernels.weighted_squares(np.zeros((4, 3)), first, weights, np.ones((1, 3)),
                             np.eye(3)[None])
    position, information = kernels.adsb_reports(np.ones((1, 3)), np.ones(1), np.zeros(3),
                                                 np.eye(3), 1.5, np.ones(3))
    kernels.adsb_sums(band, np.zeros(12), first, weights, position, information)
    kernels.motion_prior(band, first, np.ones((1, 3)), np.eye(4))
    kernels.accumulate(band, np.zeros(12), np.zeros((12, 1)), np.zeros((1, 1)), np.zeros(1),
                       first, weights, np.ones((1, 2, 3)), np.ones((1, 2, 1)), np.ones((1, 2)),
                       np.ones(1), np.zeros(1, dtype=np.int64))
    for ndim, rates in ((3, np.zeros((0, 4))), (2, weights)):
        kernels.plot_linearisation(np.ones((4, 3)), first, weights, rates, np.eye(3),
                                   np.ones(3), np.zeros((1, 3)), ndim, np.zeros(4), np.ones(ndim),
                                   np.zeros(2, dtype=np.int64), np.array([0, 2]))
    kernels.heights_and_up(np.ones((1, 3)), np.eye(3), np.full(3, 6.4e6))
    kernels.band_matvec(band, np.ones(12))
    kernels.basis(np.full(2, 0.5))
    kernels.add_plot_positions(band, np.zeros(12), first, weights, np.ones(1), np.zeros(1),
                               np.zeros(1), np.ones(1), np.eye(3), np.zeros(3))
    # The bias columns as a view of a wider array (the trajectory's stacked right side).
    kernels.accumulate(band, np.zeros(12), np.zeros((12, 2))[:, :1], np.zeros((1, 1)),
                       np.zeros(1), first, weights, np.ones((1, 2, 3)), np.ones((1, 2, 1)),
                       np.ones((1, 2)), np.ones(1), np.zeros(1, dtype=np.int64))


__all__ = ["KERNELS_ENV", "TERM_ADDITIVE", "TERM_RANGE_GAIN", "TERM_TIME_OFFSET", "available",
           "compiled", "enable", "enabled", "forced"]
