"""Linear algebra over stacks of small matrices, one per plot.

numpy handles a stack of ``n`` 2x2 or 3x3 matrices one LAPACK call at a time
(``numpy.linalg.inv``, ``cholesky``) and sums of three-factor products over the
stack through :func:`numpy.einsum`'s generic loops; at hundreds of thousands of
plots both cost far more than the arithmetic.  The functions here do the same
with whole-array operations (closed forms for the small matrices, one matrix
product for the sums).  They agree with the numpy forms to rounding.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def cholesky_inverse(cov: FloatArray) -> FloatArray:
    """``L^-1`` for every matrix of a stack, with ``L L^T = cov`` (lower triangular).

    Closed form for 1x1, 2x2 and 3x3 matrices, else ``inv(cholesky(cov))``.

    Parameters
    ----------
    cov : ndarray (..., m, m)
        Symmetric positive-definite matrices.

    Returns
    -------
    ndarray (..., m, m)
        Lower triangular; ``||L^-1 r||^2 = r^T cov^-1 r``.

    Raises
    ------
    numpy.linalg.LinAlgError
        If a matrix is not positive definite (as :func:`numpy.linalg.cholesky`).
    """
    cov = np.asarray(cov, dtype=float)
    m = cov.shape[-1]
    if m > 3:
        return np.linalg.inv(np.linalg.cholesky(cov))
    out = np.zeros_like(cov)
    with np.errstate(invalid="ignore", divide="ignore"):
        l11 = np.sqrt(cov[..., 0, 0])
        pivots = [cov[..., 0, 0]]
        out[..., 0, 0] = 1.0 / l11
        if m >= 2:
            l21 = cov[..., 1, 0] / l11
            d2 = cov[..., 1, 1] - l21 * l21
            pivots.append(d2)
            l22 = np.sqrt(d2)
            out[..., 1, 1] = 1.0 / l22
            out[..., 1, 0] = -l21 / (l11 * l22)
        if m == 3:
            l31 = cov[..., 2, 0] / l11
            l32 = (cov[..., 2, 1] - l31 * l21) / l22
            d3 = cov[..., 2, 2] - l31 * l31 - l32 * l32
            pivots.append(d3)
            l33 = np.sqrt(d3)
            out[..., 2, 2] = 1.0 / l33
            out[..., 2, 1] = -l32 / (l22 * l33)
            out[..., 2, 0] = (l21 * l32 - l22 * l31) / (l11 * l22 * l33)
    if not all(np.all(p > 0) for p in pivots):
        raise np.linalg.LinAlgError("Matrix is not positive definite")
    return out


def sum_of_products(a: FloatArray, middle: FloatArray | None, b: FloatArray) -> FloatArray:
    """``sum_n a_n^T middle_n b_n`` over a stack (``middle`` the identity when ``None``).

    Parameters
    ----------
    a : ndarray (n, i, p)
    middle : ndarray (n, i, j) or None
    b : ndarray (n, j, q)

    Returns
    -------
    ndarray (p, q)
        ``einsum("nip,nij,njq->pq", a, middle, b)``, as one matrix product.
    """
    if middle is not None:
        b = middle @ b
    p, q = a.shape[-1], b.shape[-1]
    return a.reshape(-1, p).T @ b.reshape(-1, q)


def congruent_diagonal(jac: FloatArray, diagonal: FloatArray) -> FloatArray:
    """``J_n diag(d_n) J_n^T`` for every matrix of a stack: a diagonal covariance mapped
    through a Jacobian.

    Parameters
    ----------
    jac : ndarray (..., m, k)
    diagonal : ndarray (..., k) or (k,)
        The diagonal ``d_n`` (one for all when 1-D).

    Returns
    -------
    ndarray (..., m, m)
        Symmetric; the same sums as ``(jac * diagonal[..., None, :]) @ jac^T``, term by
        term over ``k`` (numpy's stacked matrix product goes matrix by matrix).
    """
    jac = np.asarray(jac, dtype=float)
    scaled = jac * np.asarray(diagonal, dtype=float)[..., None, :]
    m = jac.shape[-2]
    out = np.empty(jac.shape[:-1] + (m,))
    for a in range(m):
        for b in range(a, m):
            value = _congruent_entry(scaled, jac, a, b)
            out[..., a, b] = value
            out[..., b, a] = value
    return out


def congruent_diagonal_variances(jac: FloatArray, diagonal: FloatArray) -> FloatArray:
    """The diagonal ``(..., m)`` of :func:`congruent_diagonal`, the same values, without
    its other entries."""
    jac = np.asarray(jac, dtype=float)
    scaled = jac * np.asarray(diagonal, dtype=float)[..., None, :]
    out = np.empty(jac.shape[:-1])
    for a in range(jac.shape[-2]):
        out[..., a] = _congruent_entry(scaled, jac, a, a)
    return out


def _congruent_entry(scaled: FloatArray, jac: FloatArray, a: int, b: int) -> FloatArray:
    """Entry ``(a, b)`` of ``J diag(d) J^T`` for a stack, ``scaled`` being ``J diag(d)``:
    the sum over ``k`` term by term."""
    value = scaled[..., a, 0] * jac[..., b, 0]
    for c in range(1, jac.shape[-1]):
        value = value + scaled[..., a, c] * jac[..., b, c]
    return value


__all__ = ["cholesky_inverse", "congruent_diagonal", "congruent_diagonal_variances",
           "sum_of_products"]
