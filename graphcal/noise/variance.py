"""Paper 000's formulas for a radar's random errors (eq. 1-10).

Paper 000 (Gao, Dong and Zhang, "Two methods for calculating the variance of
radar measurements in the Cartesian coordinate") gives two methods; this module
holds their formulas, derived again because the printed ones carry misprints.
The estimation of a radar's sigmas from its data, built on them (straight legs,
ADS-B, the variance lookup table), is :mod:`graphcal.noise`.

Units: metres, radians and seconds, as in the argument names.

1. **Error propagation** (eq. 1-2, :func:`propagate_sigmas`): the per-plot
   Cartesian sigmas of a radar with known polar sigmas are the square roots of
   the diagonal of ``J diag(s_r^2, s_az^2, s_el^2) J^T`` with ``J`` the polar ->
   ENU Jacobian (:func:`graphcal.core.frames.polar_to_enu_jacobian`), and the
   position RMS is ``sigma_p = sqrt((s_x^2 + s_y^2 + s_z^2) / 3)`` (eq. 2).
   The printed eq. 1 closes its square roots too early and drops the sign of
   ``dx/del = -r sin(el) sin(az)``; squared, the signs do not matter.

2. **Straight-line statistics** (eq. 3-10, :func:`fit_line_irls`,
   :func:`residual_sigma`): a target flying a straight constant-velocity leg is
   fitted by a straight line in time; the scatter of the plots about the line
   is the radar's noise (applied to radar data by
   :func:`graphcal.noise.estimate_noise_line_fit`).  Departures from the
   printed text:

   * Eq. 3-4 fit ``x(t)`` with the *perpendicular* distance in the ``(t, x)``
     plane, ``l = (x - k t - d) / sqrt(1 + k^2)``.  Time and position have
     different units and the time is exact, so only the vertical residual
     ``l_i = x_i - (k t_i + d)`` is meaningful (with ``k`` ~ 200 m/s the printed
     distance would shrink the residuals ~200 times).
   * Eq. 5 minimises ``sum (v_i l_i)^2`` with ``v_i`` proportional to
     ``1 / |l_i|`` of the previous fit; squaring ``v_i`` gives weights
     ``1 / l_i^2``, whose fixed point is a line through two plots.  The
     reweighting that matches the intent (down-weight far plots) is
     iteratively re-weighted least squares with weights ``1 / max(|l_i|, eps)``
     in ``sum w_i l_i^2``: a majorise-minimise algorithm for the
     least-absolute-deviation (L1) line, robust to outliers
     (:func:`fit_line_irls`).  Its criterion, the L1 norm ``sum |l_i|`` (eq. 7
     with the reweighting folded in), never increases; iteration stops when it
     stops decreasing.
   * Eq. 9 as printed is the standard deviation of ``|l_i|`` about its mean
     ``d_av`` (eq. 8).  For Gaussian residuals ``|l|`` is half-normal:
     ``E|l| = sigma sqrt(2/pi)`` and ``sd|l| = sigma sqrt(1 - 2/pi)`` = 0.603
     sigma, so eq. 9 underestimates the sigma by 40 % (:func:`printed_eq9_sigma`).
     graphcal uses the residual standard deviation with the degrees-of-freedom
     correction ``sqrt(sum l_i^2 / (n - 2))`` (:func:`residual_sigma`) or its
     robust counterpart ``1.4826 MAD sqrt(n / (n - 2))``
     (:func:`robust_residual_sigma`).
   * Eq. 8-10 give ``sigma_x``, ``sigma_y`` (with the dof correction above) and
     ``sigma_p = sqrt((s_x^2 + s_y^2) / 2)`` (eq. 10, horizontal); the paper
     keeps them per range/azimuth bin in a "variance lookup table"
     (:func:`graphcal.noise.variance_table`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from graphcal.core.covariance import polar_covariance, polar_to_enu_covariance

FloatArray = NDArray[np.float64]

#: ``sigma = MAD_TO_SIGMA * MAD`` for Gaussian data (``1 / Phi^-1(3/4)``, the value of
#: ``1 / scipy.stats.norm.ppf(0.75)``).
MAD_TO_SIGMA = 1.482602218505602


# --------------------------------------------------------------------------- eq. 1-2


@dataclass(frozen=True)
class CartesianSigmas:
    """Per-plot 1-sigma errors in the radar's ENU frame [m] (paper 000 eq. 1-2)."""

    sigma_x_m: FloatArray
    sigma_y_m: FloatArray
    sigma_z_m: FloatArray
    sigma_p_m: FloatArray


def propagate_sigmas(
    range_m: ArrayLike,
    azimuth_rad: ArrayLike,
    elevation_rad: ArrayLike,
    sigma_range_m: float,
    sigma_azimuth_rad: float,
    sigma_elevation_rad: float | None = None,
) -> CartesianSigmas:
    """Cartesian sigmas of plots from the radar's polar sigmas (paper 000 eq. 1-2).

    ``x = r cos(el) sin(az)``, ``y = r cos(el) cos(az)``, ``z = r sin(el)``
    (azimuth from north, eq. 1); with independent polar errors the ENU
    covariance is ``J diag(s_r^2, s_az^2, s_el^2) J^T``
    (:func:`graphcal.core.covariance.polar_to_enu_covariance`, paper 002 eq. 23), whose
    diagonal is::

        s_x^2 = (cos el sin az)^2 s_r^2 + (r cos el cos az)^2 s_az^2 + (r sin el sin az)^2 s_el^2
        s_y^2 = (cos el cos az)^2 s_r^2 + (r cos el sin az)^2 s_az^2 + (r sin el cos az)^2 s_el^2
        s_z^2 = (sin el)^2 s_r^2 + (r cos el)^2 s_el^2

    and ``s_p = sqrt((s_x^2 + s_y^2 + s_z^2) / 3)`` (eq. 2, the "true error"
    RMS of the three components).

    Parameters
    ----------
    range_m, azimuth_rad, elevation_rad : array_like
        Plot positions (slant range [m], azimuth from north [rad], elevation
        [rad]).  For a 2-D radar pass the elevation of the reported height, or 0.
    sigma_range_m, sigma_azimuth_rad : float
        The radar's polar sigmas [m], [rad].
    sigma_elevation_rad : float, optional
        [rad]; ``None`` (2-D radar) means no elevation error, as in the paper.

    Returns
    -------
    CartesianSigmas
    """
    cov_polar = polar_covariance(sigma_range_m, sigma_azimuth_rad, sigma_elevation_rad)
    cov_enu = polar_to_enu_covariance(range_m, azimuth_rad, elevation_rad, cov_polar)
    var = np.diagonal(cov_enu, axis1=-2, axis2=-1)
    s = np.sqrt(var)
    return CartesianSigmas(s[..., 0], s[..., 1], s[..., 2], np.sqrt(var.mean(axis=-1)))


# --------------------------------------------------------------------------- eq. 3-9


@dataclass(frozen=True)
class LineFit:
    """An IRLS (least-absolute-deviation) straight line ``y = slope * t + intercept``.

    Attributes
    ----------
    slope, intercept : float
        Line parameters (units of ``y`` per unit of ``t``, units of ``y``).
    residuals : ndarray
        Vertical residuals ``y_i - (slope t_i + intercept)``.
    weights : ndarray
        Normalised weights ``v_i = P_i / sum P`` of the last reweighting,
        ``P_i = 1 / max(|l_i|, eps)`` (paper 000 eq. 5, corrected).
    n_iter : int
        Reweighting steps that decreased the L1 criterion.
    l1_norm : float
        ``sum |residuals|`` at the solution (the criterion of eq. 7, corrected).
    """

    slope: float
    intercept: float
    residuals: FloatArray
    weights: FloatArray
    n_iter: int
    l1_norm: float


def _weighted_lines(t: FloatArray, y: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Weighted least-squares lines, batched: ``t (W, L)``, ``y, w (W, L, K)`` -> ``(a, b)``.

    Returns intercepts and slopes of shape ``(W, K)`` minimising
    ``sum_i w_i (y_i - a - b t_i)^2``; NaN where fewer than two distinct times carry weight.
    """
    tt = t[..., None]
    s0 = w.sum(axis=1)
    s1 = (w * tt).sum(axis=1)
    s2 = (w * tt**2).sum(axis=1)
    b0 = (w * y).sum(axis=1)
    b1 = (w * tt * y).sum(axis=1)
    det = s0 * s2 - s1**2
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = det > 1e-12 * np.maximum(s0 * s2, 1e-300)
        det = np.where(ok, det, np.nan)
        slope = (s0 * b1 - s1 * b0) / det
        intercept = (s2 * b0 - s1 * b1) / det
    return intercept, slope


def irls_lines(
    t: FloatArray,
    y: FloatArray,
    valid: NDArray[np.bool_],
    *,
    max_iter: int = 50,
    eps_rel: float = 1e-6,
    tol: float = 1e-6,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, NDArray[np.int64]]:
    """Batched IRLS L1 lines (see :func:`fit_line_irls`); ``t (W, L)``, ``y (W, L, K)``.

    The engine of :func:`fit_line_irls`, also run on all the windows of
    :func:`graphcal.noise.line_fit.line_fit_residuals` at once.  Returns
    ``(intercept, slope, residuals, weights, n_iter)``; residuals for every plot (also
    invalid ones), weights normalised over the valid plots.
    """
    v = valid[..., None].astype(float) * np.ones_like(y)
    a, b = _weighted_lines(t, y, v)
    res = y - (a[:, None, :] + b[:, None, :] * t[..., None])
    l1 = np.nansum(np.abs(res) * v, axis=1)
    n_valid = np.maximum(v.sum(axis=1), 1.0)
    eps = eps_rel * l1 / n_valid + 1e-12 * (1.0 + np.nanmax(np.abs(y), axis=1, initial=0.0))
    weights = v.copy()
    n_iter = np.zeros(a.shape, dtype=np.int64)
    active = np.isfinite(l1)
    for _ in range(max_iter):
        rows = np.flatnonzero(active.any(axis=1))
        if rows.size == 0:
            break
        # Only the windows still improving are refitted.
        tr, yr, vr = t[rows], y[rows], v[rows]
        w = vr / np.maximum(np.abs(res[rows]), eps[rows][:, None, :])
        a_new, b_new = _weighted_lines(tr, yr, w)
        res_new = yr - (a_new[:, None, :] + b_new[:, None, :] * tr[..., None])
        l1_new = np.sum(np.abs(res_new) * vr, axis=1)
        accept = active[rows] & np.isfinite(l1_new) & (l1_new < l1[rows])
        a[rows] = np.where(accept, a_new, a[rows])
        b[rows] = np.where(accept, b_new, b[rows])
        res[rows] = np.where(accept[:, None, :], res_new, res[rows])
        weights[rows] = np.where(accept[:, None, :], w, weights[rows])
        active[rows] = accept & (l1_new < l1[rows] * (1.0 - tol))
        l1[rows] = np.where(accept, l1_new, l1[rows])
        n_iter[rows] += accept
    with np.errstate(invalid="ignore", divide="ignore"):
        weights = weights / weights.sum(axis=1, keepdims=True)
    return a, b, res, weights, n_iter


def fit_line_irls(
    t: ArrayLike, y: ArrayLike, *, max_iter: int = 50, eps_rel: float = 1e-6
) -> LineFit:
    """Robust straight line ``y = k t + d`` by iteratively re-weighted least squares.

    Paper 000 eq. 3-7, corrected (see the module docstring): vertical residuals
    ``l_i = y_i - k t_i - d`` (``t`` is exact), a first ordinary least-squares
    fit (eq. 4), then repeated weighted fits minimising ``sum w_i l_i^2`` with
    ``w_i = 1 / max(|l_i|, eps)`` from the previous fit (eq. 5-6).  This is a
    majorise-minimise algorithm for the least-absolute-deviation line: the L1
    norm ``sum |l_i|`` (eq. 7) never increases, and iteration stops when it
    stops decreasing (relative decrease below 1e-6) or after ``max_iter`` steps.

    Parameters
    ----------
    t : array_like
        Abscissae (times [s]); at least two distinct values.
    y : array_like
        Ordinates (positions [m]).
    max_iter : int
        Maximum reweighting steps.
    eps_rel : float
        ``eps`` as a fraction of the mean absolute residual of the first fit.

    Returns
    -------
    LineFit

    Raises
    ------
    ValueError
        If ``t`` and ``y`` differ in length, contain non-finite values or have
        fewer than two distinct ``t``.
    """
    t_arr = np.asarray(t, dtype=float).ravel()
    y_arr = np.asarray(y, dtype=float).ravel()
    if t_arr.shape != y_arr.shape:
        raise ValueError(f"t and y must have the same length, got {t_arr.size} and {y_arr.size}")
    if not (np.all(np.isfinite(t_arr)) and np.all(np.isfinite(y_arr))):
        raise ValueError("t and y must be finite")
    if np.unique(t_arr).size < 2:
        raise ValueError("a line needs at least two distinct t values")
    centre = 0.5 * (t_arr.max() + t_arr.min())
    half = 0.5 * (t_arr.max() - t_arr.min())
    ts = (t_arr - centre) / half
    a, b, res, w, n_iter = irls_lines(
        ts[None, :], y_arr[None, :, None], np.ones((1, t_arr.size), dtype=bool),
        max_iter=max_iter, eps_rel=eps_rel,
    )
    slope = float(b[0, 0]) / half
    intercept = float(a[0, 0]) - slope * centre
    residuals = res[0, :, 0]
    return LineFit(slope, intercept, residuals, w[0, :, 0], int(n_iter[0, 0]),
                   float(np.abs(residuals).sum()))


def printed_eq9_sigma(residuals: ArrayLike) -> float:
    """Paper 000 eq. 8-9 as printed: the standard deviation of ``|l_i|`` about ``d_av``.

    ``d_av = mean |l_i|`` (eq. 8), ``sigma^2 = sum (|l_i| - d_av)^2 / (n - 1)``
    (eq. 9).  For Gaussian residuals this tends to ``sigma sqrt(1 - 2/pi)``
    = 0.603 sigma; kept to show the difference, not used.
    """
    a = np.abs(np.asarray(residuals, dtype=float))
    return float(np.std(a, ddof=1))


def residual_sigma(residuals: ArrayLike, n_params: int = 2) -> float:
    """Residual standard deviation with dof correction, ``sqrt(sum l^2 / (n - p))``.

    The corrected eq. 9 for a least-squares fit with ``n_params`` parameters
    (2 for a line).

    Raises
    ------
    ValueError
        If there are not more residuals than parameters.
    """
    r = np.asarray(residuals, dtype=float).ravel()
    if r.size <= n_params:
        raise ValueError(f"need more than {n_params} residuals, got {r.size}")
    return float(np.sqrt(np.sum(r**2) / (r.size - n_params)))


def robust_residual_sigma(residuals: ArrayLike, n_params: int = 2) -> float:
    """Robust residual sigma ``1.4826 median|l| sqrt(n / (n - p))``.

    The median absolute residual (the residuals of a fit with an intercept
    are centred) scaled to a Gaussian sigma, with the same dof factor as
    :func:`residual_sigma`.

    Raises
    ------
    ValueError
        If there are not more residuals than parameters.
    """
    r = np.asarray(residuals, dtype=float).ravel()
    if r.size <= n_params:
        raise ValueError(f"need more than {n_params} residuals, got {r.size}")
    return float(MAD_TO_SIGMA * np.median(np.abs(r)) * np.sqrt(r.size / (r.size - n_params)))
