"""Random-error sigmas of a radar: error propagation and statistical estimation (paper 000).

Paper 000 (Gao, Dong and Zhang, "Two methods for calculating the variance of
radar measurements in the Cartesian coordinate") gives two methods; graphcal
implements both, derived again because the printed formulas carry misprints,
and adds a third, independent estimate from ADS-B.

1. **Error propagation** (eq. 1-2, :func:`propagate_sigmas`): the per-plot
   Cartesian sigmas of a radar with known polar sigmas are the square roots of
   the diagonal of ``J diag(s_r^2, s_az^2, s_el^2) J^T`` with ``J`` the polar ->
   ENU Jacobian (:func:`graphcal.frames.polar_to_enu_jacobian`), and the
   position RMS is ``sigma_p = sqrt((s_x^2 + s_y^2 + s_z^2) / 3)`` (eq. 2).
   The printed eq. 1 closes its square roots too early and drops the sign of
   ``dx/del = -r sin(el) sin(az)``; squared, the signs do not matter.

2. **Straight-line statistics** (eq. 3-10, :func:`line_fit_residuals`,
   :func:`estimate_noise_line_fit`): a target flying a straight constant-velocity
   leg is fitted by a straight line in time; the scatter of the plots about the
   line is the radar's noise.  Departures from the printed text:

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
   * The paper fits ``x(t)`` and ``y(t)`` of 2-D plots (elevation 0).  graphcal
     fits in 3-D, in the coordinates ``(east, north, height)`` of the radar: east
     and north of its ENU frame and the height above the radar's local sphere
     (the sphere of :func:`graphcal.frames.elevation_from_height`), in which a
     level flight is a straight line (in plain ENU its height would sag by
     ``L^2 / 8R``, 70 m over a 60 km window).  3-D radars place plots with
     the measured elevation; 2-D radars at the reported (Mode C) height when
     present (like :mod:`graphcal.estimators.cross_radar`), else on the
     horizontal plane (elevation 0, the paper's choice).
   * What graphcal needs are the polar sigmas, so the residuals are evaluated
     in polar space: the measured ``(range, azimuth, elevation)`` minus the
     polar coordinates of the fitted line at the plot time.  Each residual
     carries ``(1 - h_ii)`` of its own noise (``h`` the hat matrix of the line
     fit) plus a little of the other components' noise, since the line mixes
     plots seen from slightly different directions; the expected square of
     every residual is computed exactly under the linearised model (see
     :class:`LineFitResiduals`), which both corrects the degrees of freedom
     and removes this leakage.
   * Eq. 8-10 give ``sigma_x``, ``sigma_y`` (now dof-corrected) and
     ``sigma_p = sqrt((s_x^2 + s_y^2) / 2)`` (eq. 10, horizontal); they are
     kept, per range/azimuth bin, in :func:`variance_table` (the paper's
     "variance lookup table").

   Legs: a radar's plots are split by ``target_id`` (plots without one are not
   used) and at time gaps longer than 2.5 scans, cut into windows of
   ``window_plots`` consecutive plots, and a window is kept only when a
   straight constant-velocity line fits it: the IRLS (L1) fit flags outlying
   plots (more than 5 robust sigmas), the remaining plots are fitted by
   ordinary least squares (the same hat matrix for every coordinate), a
   quadratic term that is significant against the window's own scatter
   (``|t| > 3.5`` in any coordinate) marks a turn or an acceleration, and a
   window whose residuals are too large for the radar's pooled sigmas
   (chi-square, ``p < 1e-3``) is dropped in a second pass.

3. **ADS-B** (:func:`estimate_noise_adsb`): each plot minus the ADS-B position
   of its aircraft interpolated to its time (:func:`graphcal.align.align_adsb`),
   in polar.  The radar's biases are removed by robust (L1) fits (range residual
   ``= offset + gain * range``; azimuth and elevation residuals constant), and
   the ADS-B error mapped into polar (horizontal ``sigma_m``, vertical
   :data:`graphcal.align.ADSB_VERTICAL_SIGMA_RATIO` times it; the interpolation
   weights included) is removed in quadrature, plot by plot.  Linear
   interpolation between reports 1 s apart adds at most ``a dt^2 / 8`` (about
   1 m in a 3 deg/s turn at 250 m/s), negligible against radar noise.  A
   time-stamping bias is not removed and would inflate the sigmas.

Estimates are robust by default (median absolute deviation) and come with
their own standard errors: ``sigma / sqrt(2 n_dof)`` for the root mean square,
``1.166 sigma / sqrt(n_dof)`` for the MAD (its asymptotic efficiency is 37 %).
A radar that cannot be estimated (too few usable plots or windows) gets a
:class:`NoiseEstimate` with ``estimated=False``, NaN sigmas and the reason, so
that one radar does not stop the others; :func:`sites_with_estimated_sigmas`
leaves such radars unchanged.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy import stats

from graphcal import frames
from graphcal.align import AdsbAlignment, align_adsb, plot_arrays
from graphcal.covariance import polar_covariance, polar_to_enu_covariance
from graphcal.dataset import Dataset, Site
from graphcal.errors import DatasetError

if TYPE_CHECKING:
    from graphcal.calibration import Calibration

FloatArray = NDArray[np.float64]

#: ``sigma = MAD_TO_SIGMA * MAD`` for Gaussian data (``1 / Phi^-1(3/4)``).
MAD_TO_SIGMA = 1.0 / stats.norm.ppf(0.75)
#: Standard error of a MAD-based sigma is ``MAD_SE_FACTOR * sigma / sqrt(n)``
#: (asymptotic variance ``1.3605 sigma^2 / n``, efficiency 37 % of the standard deviation).
MAD_SE_FACTOR = math.sqrt(
    0.25 / (2.0 * stats.norm.pdf(stats.norm.ppf(0.75))) ** 2 / stats.norm.ppf(0.75) ** 2
)
#: ``use_adsb="auto"`` uses ADS-B for a radar with at least this many ADS-B-matched plots.
DEFAULT_MIN_ADSB_PLOTS = 200
#: Below this many usable plots (ADS-B method) a radar is not estimated.
MIN_ADSB_PLOTS = 30
#: 2-D plots above this elevation [rad] are not placed from their reported height.
MAX_2D_ELEVATION_RAD = np.deg2rad(70.0)

#: Placement of a plot in the fit frame (see :func:`line_fit_residuals`).
_MODE_3D, _MODE_HEIGHT, _MODE_PLANE = 0, 1, 2


# --------------------------------------------------------------------------- results


@dataclass(frozen=True)
class NoiseEstimate:
    """Estimated random-error sigmas of one radar.

    Attributes
    ----------
    radar_id : str
        The radar.
    sigma_range_m : float
        1-sigma random range error [m]; NaN when not estimated.
    sigma_azimuth_mrad : float
        1-sigma random azimuth error [mrad]; NaN when not estimated.
    sigma_elevation_mrad : float or None
        1-sigma random elevation error [mrad] (3-D radars); ``None`` for 2-D radars.
    n_plots_used : int
        Plots whose residuals entered the estimate.
    n_legs : int
        Straight-leg windows used (line fit); 0 for the ADS-B method.
    method : str
        ``"line-fit"`` or ``"adsb"``.
    se_range_m, se_azimuth_mrad : float
        Standard errors of the two sigmas, same units.
    se_elevation_mrad : float or None
        Standard error of the elevation sigma [mrad].
    estimated : bool
        False when the radar had too little usable data; then the sigmas are NaN.
    reason : str
        Why the radar was not estimated (empty when it was).
    details : dict
        Diagnostics: the non-robust (root-mean-square) estimates, the paper's pooled
        ``sigma_x_m``, ``sigma_y_m``, ``sigma_p_m`` (line fit), the Mode C height sigma
        of 2-D radars, the removed biases (ADS-B), ...
    """

    radar_id: str
    sigma_range_m: float
    sigma_azimuth_mrad: float
    sigma_elevation_mrad: float | None
    n_plots_used: int
    n_legs: int
    method: str
    se_range_m: float = math.nan
    se_azimuth_mrad: float = math.nan
    se_elevation_mrad: float | None = None
    estimated: bool = True
    reason: str = ""
    details: dict[str, float] = field(default_factory=dict)

    @property
    def sigma_azimuth_rad(self) -> float:
        """1-sigma azimuth error [rad]."""
        return self.sigma_azimuth_mrad * 1e-3

    @property
    def sigma_elevation_rad(self) -> float | None:
        """1-sigma elevation error [rad], ``None`` for 2-D radars."""
        return None if self.sigma_elevation_mrad is None else self.sigma_elevation_mrad * 1e-3


def _not_estimated(radar_id: str, method: str, is_3d: bool, reason: str) -> NoiseEstimate:
    return NoiseEstimate(
        radar_id, math.nan, math.nan, math.nan if is_3d else None, 0, 0, method,
        se_elevation_mrad=math.nan if is_3d else None, estimated=False, reason=reason,
    )


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
    (:func:`graphcal.covariance.polar_to_enu_covariance`, paper 002 eq. 23), whose
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


def _irls_lines(
    t: FloatArray,
    y: FloatArray,
    valid: NDArray[np.bool_],
    *,
    max_iter: int = 50,
    eps_rel: float = 1e-6,
    tol: float = 1e-6,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, NDArray[np.int64]]:
    """Batched IRLS L1 lines (see :func:`fit_line_irls`); ``t (W, L)``, ``y (W, L, K)``.

    Returns ``(intercept, slope, residuals, weights, n_iter)``; residuals for
    every plot (also invalid ones), weights normalised over the valid plots.
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
    a, b, res, w, n_iter = _irls_lines(
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


# --------------------------------------------------------------------------- fit frame


def _sphere_radius_m(lat_rad: float) -> float:
    """Gaussian radius of curvature [m], the sphere of ``frames.elevation_from_height``."""
    sin2 = math.sin(lat_rad) ** 2
    return frames.WGS84_A_M * math.sqrt(1.0 - frames.WGS84_E2) / (1.0 - frames.WGS84_E2 * sin2)


def _to_fit_frame(site: Site, mode: NDArray[np.int64], m: FloatArray) -> FloatArray:
    """Measurements ``m = (range, azimuth, q)`` -> fit-frame ``(east, north, height)`` [m].

    ``q`` is the elevation [rad] (3-D), the reported height [m] (2-D with
    height) or 0 (2-D on the horizontal plane, where the third coordinate is
    ``q`` itself).
    """
    radius = _sphere_radius_m(site.lat_rad)
    r, az, q = m[:, 0], m[:, 1], m[:, 2]
    el = np.where(mode == _MODE_3D, q, 0.0)
    height_mode = mode == _MODE_HEIGHT
    if height_mode.any():
        el = np.where(
            height_mode, frames.elevation_from_height(r, q, site.lat_rad, site.alt_m), el
        )
    ground = r * np.cos(el)
    up = r * np.sin(el)
    height = np.sqrt(ground**2 + (radius + site.alt_m + up) ** 2) - radius
    third = np.where(mode == _MODE_3D, height, q)
    return np.column_stack([ground * np.sin(az), ground * np.cos(az), third])


def _from_fit_frame(site: Site, mode: NDArray[np.int64], f: FloatArray) -> FloatArray:
    """Inverse of :func:`_to_fit_frame`: ``(east, north, height)`` -> ``(range, azimuth, q)``."""
    radius = _sphere_radius_m(site.lat_rad)
    e, n, h = f[:, 0], f[:, 1], f[:, 2]
    ground = np.hypot(e, n)
    az = frames.wrap_to_2pi(np.arctan2(e, n))
    with np.errstate(invalid="ignore"):
        up = np.sqrt((radius + h) ** 2 - ground**2) - (radius + site.alt_m)
    plane = mode == _MODE_PLANE
    up = np.where(plane, 0.0, up)
    r = np.hypot(ground, up)
    el = np.arctan2(up, ground)
    q = np.where(mode == _MODE_3D, el, h)
    return np.column_stack([r, az, q])


#: Central-difference steps for d(fit frame)/d(range [m], azimuth [rad], q).
_STEP_RANGE_M = 1.0
_STEP_ANGLE_RAD = 1e-6
_STEP_HEIGHT_M = 0.5


def _fit_frame_jacobian(site: Site, mode: NDArray[np.int64], m: FloatArray) -> FloatArray:
    """``d(east, north, height) / d(range, azimuth, q)`` by central differences, ``(n, 3, 3)``."""
    steps = np.empty((len(m), 3))
    steps[:, 0] = _STEP_RANGE_M
    steps[:, 1] = _STEP_ANGLE_RAD
    steps[:, 2] = np.where(mode == _MODE_3D, _STEP_ANGLE_RAD, _STEP_HEIGHT_M)
    jac = np.empty((len(m), 3, 3))
    for k in range(3):
        d = np.zeros_like(m)
        d[:, k] = steps[:, k]
        plus = _to_fit_frame(site, mode, m + d)
        minus = _to_fit_frame(site, mode, m - d)
        jac[:, :, k] = (plus - minus) / (2.0 * steps[:, k : k + 1])
    return jac


# --------------------------------------------------------------------------- line-fit residuals


@dataclass(frozen=True)
class LineFitOptions:
    """Settings of the straight-leg (line-fit) method.

    Attributes
    ----------
    window_plots : int
        Plots per window (one straight-line fit); about 15-30 scans.
    max_gap_scans : float
        A gap longer than this many scan periods between two plots of a target
        starts a new leg.
    outlier_threshold : float
        A plot whose IRLS residual exceeds this many robust sigmas of its window
        (in any coordinate) is an outlier and left out of the fit.
    min_inlier_fraction : float
        Windows with fewer inliers are dropped.
    curvature_t_max : float
        A window whose quadratic term has ``|t|`` above this in any coordinate
        (a turn, an acceleration, a change of climb rate) is dropped.
    curvature_floor_m : float
        Floor [m] of the scatter used in the curvature test (exact or nearly
        exact reported heights would otherwise flag centimetre curvature).
    max_azimuth_span_rad : float
        Windows spanning more azimuth than this [rad] (close passes) are dropped.
    min_range_m : float
        Windows with a plot closer than this [m] are dropped.
    window_p_value : float
        Second pass: windows whose residuals reject the pooled sigmas at this
        level (chi-square) are dropped.
    min_windows : int
        Fewer usable windows: the radar is not estimated.
    irls_max_iter : int
        Maximum IRLS reweighting steps.
    """

    window_plots: int = 20
    max_gap_scans: float = 2.5
    outlier_threshold: float = 5.0
    min_inlier_fraction: float = 0.8
    curvature_t_max: float = 3.5
    curvature_floor_m: float = 5.0
    max_azimuth_span_rad: float = 0.35
    min_range_m: float = 2000.0
    window_p_value: float = 1e-3
    min_windows: int = 5
    irls_max_iter: int = 20

    def __post_init__(self) -> None:
        if self.window_plots < 5:
            raise ValueError(f"window_plots must be at least 5, got {self.window_plots}")
        if not 0.0 < self.min_inlier_fraction <= 1.0:
            raise ValueError("min_inlier_fraction must be in (0, 1]")
        if self.max_gap_scans <= 0 or self.outlier_threshold <= 0 or self.curvature_t_max <= 0:
            raise ValueError("max_gap_scans, outlier_threshold and curvature_t_max must be > 0")


@dataclass
class LineFitResiduals:
    """Residuals of one radar's plots about straight-leg line fits.

    Every row is an inlier plot of a kept window.  For row ``i`` and polar
    component ``k`` (range [m], azimuth [rad], third: elevation [rad] for
    3-D radars, reported height [m] for 2-D radars), the linearised model gives
    the residual ``e_i = eps_i - J_i^-1 sum_j H_ij J_j eps_j``, with ``eps``
    the polar noise, ``J`` the Jacobian of the fit frame w.r.t. the
    measurements and ``H`` the hat matrix of the window's least-squares line.
    Hence::

        E[e_ik^2] = sum_m coef[i, k, m] sigma_m^2,
        coef[i, k, m] = (1 - 2 H_ii) delta_km + sum_j H_ij^2 (J_i^-1 J_j)_km^2

    which reduces to ``(1 - H_ii) sigma_k^2`` (the dof correction,
    ``sum_i (1 - H_ii) = n - 2``) when the geometry does not change across the
    window.

    Attributes
    ----------
    radar_id : str
    is_3d : bool
    plot_index : ndarray (n,) of int
        Row labels of the plots in ``dataset.plots``.
    range_m, azimuth_rad : ndarray (n,)
        Measured position of each plot.
    time_s : ndarray (n,)
    window : ndarray (n,) of int
        Window number of each plot.
    polar_residual : ndarray (n, 3)
        Measured minus fitted ``(range [m], azimuth [rad], third)``.
    coef : ndarray (n, 3, 3)
        Variance coefficients as above.
    component_valid : ndarray (n, 3) of bool
        Third component: False for 2-D plots on the horizontal plane.
    cartesian_residual : ndarray (n, 3)
        Residuals in the fit frame ``(east, north, height)`` [m].
    leverage : ndarray (n,)
        ``H_ii``.
    n_windows_total : int
        Windows formed before the straightness checks.
    """

    radar_id: str
    is_3d: bool
    plot_index: NDArray[np.int64]
    range_m: FloatArray
    azimuth_rad: FloatArray
    time_s: FloatArray
    window: NDArray[np.int64]
    polar_residual: FloatArray
    coef: FloatArray
    component_valid: NDArray[np.bool_]
    cartesian_residual: FloatArray
    leverage: FloatArray
    n_windows_total: int

    def __len__(self) -> int:
        return len(self.time_s)

    @property
    def n_windows(self) -> int:
        """Windows kept."""
        return int(np.unique(self.window).size)

    def subset(self, mask: NDArray[np.bool_]) -> LineFitResiduals:
        """Rows selected by ``mask``."""
        arrays = {
            name: getattr(self, name)[mask]
            for name in ("plot_index", "range_m", "azimuth_rad", "time_s", "window",
                         "polar_residual", "coef", "component_valid", "cartesian_residual",
                         "leverage")
        }
        return LineFitResiduals(self.radar_id, self.is_3d, n_windows_total=self.n_windows_total,
                                **arrays)


def _plot_modes(site: Site, plots) -> tuple[NDArray[np.int64], FloatArray, NDArray[np.bool_]]:
    """Fit-frame placement of each plot: mode, third measurement ``q`` and usability."""
    n = len(plots)
    if site.is_3d:
        q = plots.elevation_rad
        return np.full(n, _MODE_3D), q, np.isfinite(q)
    has_height = np.isfinite(plots.altitude_m)
    el = frames.elevation_from_height(
        plots.range_m, np.where(has_height, plots.altitude_m, 0.0), site.lat_rad, site.alt_m
    )
    with np.errstate(invalid="ignore"):
        placeable = np.isfinite(el) & (np.abs(el) < MAX_2D_ELEVATION_RAD)
    mode = np.where(has_height, _MODE_HEIGHT, _MODE_PLANE)
    q = np.where(has_height, plots.altitude_m, 0.0)
    usable = np.where(has_height, placeable, True)
    return mode, q, usable


def _scan_period_s(site: Site, time_s: FloatArray, target: NDArray[np.object_]) -> float:
    """The site's scan period, else the median time step between plots of one target."""
    if site.scan_period_s:
        return float(site.scan_period_s)
    order = np.lexsort((time_s, target))
    dt = np.diff(time_s[order])
    same = target[order][1:] == target[order][:-1]
    dt = dt[same & (dt > 0)]
    return float(np.median(dt)) if dt.size else 4.0


def _window_rows(
    time_s: FloatArray, target: NDArray[np.object_], mode: NDArray[np.int64], length: int,
    max_gap_s: float,
) -> NDArray[np.int64]:
    """Row indices ``(W, length)`` of consecutive plots of one target, no gap or mode change."""
    n = len(time_s)
    if n == 0:
        return np.zeros((0, length), dtype=np.int64)
    order = np.lexsort((time_s, target))
    t, tg, md = time_s[order], target[order], mode[order]
    start = np.ones(n, dtype=bool)
    start[1:] = (tg[1:] != tg[:-1]) | (np.diff(t) > max_gap_s) | (md[1:] != md[:-1])
    seg = np.cumsum(start) - 1
    seg_start = np.flatnonzero(start)
    seg_len = np.diff(np.append(seg_start, n))
    pos = np.arange(n) - seg_start[seg]
    keep = pos // length < seg_len[seg] // length
    return order[keep].reshape(-1, length)


def _variance_coefficients(
    hat: FloatArray, jac: FloatArray, jac_inv: FloatArray, chunk: int = 1024
) -> FloatArray:
    """``coef[w, i, k, m]`` of :class:`LineFitResiduals`, computed in chunks of windows."""
    n_win, length = hat.shape[:2]
    out = np.empty((n_win, length, 3, 3))
    eye = np.eye(3)
    for lo in range(0, n_win, chunk):
        hi = min(lo + chunk, n_win)
        mix = np.einsum("wikp,wjpm->wijkm", jac_inv[lo:hi], jac[lo:hi])
        h = hat[lo:hi]
        diag = np.einsum("wii->wi", h)
        out[lo:hi] = (1.0 - 2.0 * diag)[..., None, None] * eye + np.einsum(
            "wij,wijkm->wikm", h**2, mix**2
        )
    return out


def line_fit_residuals(
    dataset: Dataset, radar_id: str, options: LineFitOptions | None = None
) -> LineFitResiduals:
    """Straight-leg windows of one radar, fitted, checked, with polar residuals.

    Steps (module docstring, item 2): split the plots by ``target_id`` and
    gaps, cut windows of ``options.window_plots`` plots, place them in the fit
    frame ``(east, north, height)``, fit each coordinate against time by IRLS
    (:func:`fit_line_irls`, batched) to flag outliers, refit the inliers by
    least squares, drop windows with a significant quadratic term, a large
    azimuth span or a plot too close to the radar, and evaluate the residuals
    in polar space with their variance coefficients.

    Parameters
    ----------
    dataset : Dataset
    radar_id : str
    options : LineFitOptions, optional

    Returns
    -------
    LineFitResiduals
        Possibly empty (no usable window).

    Raises
    ------
    ValueError
        If ``radar_id`` is not a radar of the dataset.
    """
    opt = LineFitOptions() if options is None else options
    if radar_id not in dataset.sites:
        raise ValueError(f"unknown radar {radar_id!r}; radars: {', '.join(dataset.sites)}")
    site = dataset.sites[radar_id]
    plots = plot_arrays(dataset, radar_id)
    target = plots.target_id.astype(str)
    mode, q, usable = _plot_modes(site, plots)
    usable &= (target != "") & np.isfinite(plots.range_m) & np.isfinite(plots.azimuth_rad)
    idx = np.flatnonzero(usable)
    length = opt.window_plots
    max_gap = opt.max_gap_scans * _scan_period_s(site, plots.time_s[idx], target[idx])
    rows = idx[_window_rows(plots.time_s[idx], target[idx], mode[idx], length, max_gap)]
    n_total = len(rows)
    # Window geometry limits.
    az = plots.azimuth_rad[rows]
    span = np.ptp(np.unwrap(az, axis=1), axis=1) if n_total else np.zeros(0)
    near = plots.range_m[rows].min(axis=1) if n_total else np.zeros(0)
    rows = rows[(span <= opt.max_azimuth_span_rad) & (near >= opt.min_range_m)]
    n_win = len(rows)
    flat = rows.ravel()
    md = mode[flat]
    meas = np.column_stack([plots.range_m[flat], plots.azimuth_rad[flat], q[flat]])
    f = _to_fit_frame(site, md, meas).reshape(n_win, length, 3)
    t_raw = plots.time_s[rows]
    t_mid = 0.5 * (t_raw.max(axis=1, initial=-np.inf) + t_raw.min(axis=1, initial=np.inf))
    t_half = 0.5 * np.ptp(t_raw, axis=1) if n_win else np.zeros(0)
    good = t_half > 0
    t = np.where(good[:, None], (t_raw - t_mid[:, None]) / np.where(good, t_half, 1.0)[:, None],
                 0.0)
    f_mean = f.mean(axis=1, keepdims=True)
    y = f - f_mean
    # 1) IRLS L1 lines per coordinate: outliers.
    valid = np.broadcast_to(good[:, None], (n_win, length))
    _, _, res_l1, _, _ = _irls_lines(t, y, valid, max_iter=opt.irls_max_iter)
    scale = MAD_TO_SIGMA * np.median(np.abs(res_l1), axis=1) * math.sqrt(length / (length - 2))
    with np.errstate(invalid="ignore"):
        outlier = np.any((np.abs(res_l1) > opt.outlier_threshold * scale[:, None, :])
                         & (scale[:, None, :] > 0), axis=2)
    inlier = valid & ~outlier
    n_in = inlier.sum(axis=1)
    # 2) Least squares on the inliers: line, hat matrix, quadratic term.
    w = inlier.astype(float)
    s0 = np.maximum(w.sum(axis=1), 1.0)
    t_bar = (w * t).sum(axis=1) / s0
    tc = t - t_bar[:, None]
    sxx = (w * tc**2).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        hat = w[:, None, :] * (1.0 / s0[:, None, None]
                               + tc[:, :, None] * tc[:, None, :] / sxx[:, None, None])
        y_bar = (w[..., None] * y).sum(axis=1) / s0[:, None]
        slope = (w[..., None] * tc[..., None] * y).sum(axis=1) / sxx[:, None]
    fit = y_bar[:, None, :] + slope[:, None, :] * tc[..., None]
    res = y - fit
    # Quadratic term by Frisch-Waugh: t^2 made orthogonal to (1, t) over the inliers.
    t2 = tc**2
    t2_bar = (w * t2).sum(axis=1) / s0
    c1 = (w * tc * (t2 - t2_bar[:, None])).sum(axis=1) / np.where(sxx > 0, sxx, 1.0)
    u = t2 - t2_bar[:, None] - c1[:, None] * tc
    suu = (w * u**2).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c2 = (w[..., None] * u[..., None] * res).sum(axis=1) / suu[:, None]
        rss_q = np.maximum((w[..., None] * res**2).sum(axis=1) - c2**2 * suu[:, None], 0.0)
        s2 = np.maximum(rss_q / (n_in - 3)[:, None], opt.curvature_floor_m**2)
        t_quad = np.abs(c2) * np.sqrt(suu)[:, None] / np.sqrt(s2)
    straight = np.all(np.nan_to_num(t_quad, nan=np.inf) <= opt.curvature_t_max, axis=1)
    keep = (good & (n_in >= max(opt.min_inlier_fraction * length, 4)) & (suu > 0) & straight)
    rows, inlier, hat, res, fit = rows[keep], inlier[keep], hat[keep], res[keep], fit[keep]
    f_mean, meas_w = f_mean[keep], meas.reshape(n_win, length, 3)[keep]
    md_w = md.reshape(n_win, length)[keep]
    n_win = len(rows)
    # 3) Polar residuals of the fitted line and their variance coefficients.
    f_fit = (fit + f_mean).reshape(-1, 3)
    m_fit = _from_fit_frame(site, md_w.ravel(), f_fit).reshape(n_win, length, 3)
    e = meas_w - m_fit
    e[..., 1] = frames.wrap_to_pi(e[..., 1])
    jac = _fit_frame_jacobian(site, md_w.ravel(), meas_w.reshape(-1, 3)).reshape(
        n_win, length, 3, 3)
    jac_inv = np.linalg.inv(jac)
    coef = _variance_coefficients(hat, jac, jac_inv)
    plane = md_w == _MODE_PLANE
    coef[..., 2] = np.where(plane[..., None], 0.0, coef[..., 2])
    comp_valid = np.ones((n_win, length, 3), dtype=bool)
    comp_valid[..., 2] = ~plane
    sel = inlier.ravel()
    window = np.repeat(np.arange(n_win), length)
    return LineFitResiduals(
        radar_id=radar_id,
        is_3d=site.is_3d,
        plot_index=plots.index[rows].ravel()[sel],
        range_m=meas_w[..., 0].ravel()[sel],
        azimuth_rad=meas_w[..., 1].ravel()[sel],
        time_s=plots.time_s[rows].ravel()[sel],
        window=window[sel],
        polar_residual=e.reshape(-1, 3)[sel],
        coef=coef.reshape(-1, 3, 3)[sel],
        component_valid=comp_valid.reshape(-1, 3)[sel],
        cartesian_residual=res.reshape(-1, 3)[sel],
        leverage=np.einsum("wii->wi", hat).ravel()[sel],
        n_windows_total=n_total,
    )


def _moment_sigmas(lf: LineFitResiduals) -> FloatArray:
    """Method of moments: ``sum_i e_ik^2 = sum_m (sum_i coef_ikm) sigma_m^2``, sigmas >= 0."""
    valid = lf.component_valid
    lhs = np.einsum("ik,ikm->km", valid.astype(float), lf.coef)
    rhs = np.sum(np.where(valid, lf.polar_residual, 0.0) ** 2, axis=0)
    used = valid.any(axis=0)
    var = np.zeros(3)
    if used.any():
        sub = np.ix_(used, used)
        var[used] = np.linalg.lstsq(lhs[sub], rhs[used], rcond=None)[0]
    return np.sqrt(np.clip(var, 0.0, None))


def _standardised(lf: LineFitResiduals, sigma: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Residuals divided by ``sqrt(E[e^2]) / sigma_k`` (variance ``sigma_k^2``), and ``E[e^2]``."""
    var = np.einsum("ikm,m->ik", lf.coef, sigma**2)
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = np.where(sigma > 0, var / sigma**2, 1.0)
        z = lf.polar_residual / np.sqrt(factor)
    return z, var


def _robust_sigmas(lf: LineFitResiduals, start: FloatArray, n_iter: int = 6) -> FloatArray:
    """``sigma_k = 1.4826 median |z_ik|`` with ``z`` standardised by the current sigmas."""
    sigma = start.copy()
    valid = lf.component_valid
    for _ in range(n_iter):
        z, _ = _standardised(lf, sigma)
        new = sigma.copy()
        for k in range(3):
            if valid[:, k].any() and sigma[k] > 0:
                new[k] = MAD_TO_SIGMA * np.median(np.abs(z[valid[:, k], k]))
        sigma = new
    return sigma


def _window_chi2_keep(lf: LineFitResiduals, sigma: FloatArray, p_value: float) -> NDArray:
    """Rows of windows whose residuals are consistent with ``sigma`` (chi-square test)."""
    _, var = _standardised(lf, sigma)
    valid = lf.component_valid & (sigma > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        contrib = np.where(valid, lf.polar_residual**2 / var * (1.0 - lf.leverage)[:, None], 0.0)
    q = np.bincount(lf.window, weights=contrib.sum(axis=1))
    dof = np.bincount(lf.window, weights=(valid * (1.0 - lf.leverage)[:, None]).sum(axis=1))
    limit = stats.chi2.isf(p_value, np.maximum(dof, 1.0))
    bad = q > limit
    return ~bad[lf.window]


def _line_fit_sigmas(
    lf: LineFitResiduals, robust: bool, p_value: float
) -> tuple[FloatArray, FloatArray, LineFitResiduals]:
    """Robust and moment sigmas after the second-pass window check; also the rows used."""
    sigma = _moment_sigmas(lf)
    sigma = _robust_sigmas(lf, sigma)
    keep = _window_chi2_keep(lf, sigma, p_value)
    lf = lf.subset(keep)
    moment = _moment_sigmas(lf)
    rob = _robust_sigmas(lf, moment)
    return (rob if robust else moment), moment, lf


def estimate_noise_line_fit(
    dataset: Dataset,
    radar_id: str,
    *,
    robust: bool = True,
    options: LineFitOptions | None = None,
) -> NoiseEstimate:
    """Polar sigmas of one radar from straight-leg line fits (paper 000 sec. 2, corrected).

    Parameters
    ----------
    dataset : Dataset
    radar_id : str
    robust : bool
        MAD-based sigmas (default) or the method of moments (root mean square).
    options : LineFitOptions, optional

    Returns
    -------
    NoiseEstimate
        ``method="line-fit"``; ``estimated=False`` when fewer than
        ``options.min_windows`` straight windows were found.
    """
    opt = LineFitOptions() if options is None else options
    site = dataset.sites.get(radar_id)
    if site is None:
        raise ValueError(f"unknown radar {radar_id!r}; radars: {', '.join(dataset.sites)}")
    lf = line_fit_residuals(dataset, radar_id, opt)
    if lf.n_windows < opt.min_windows:
        return _not_estimated(
            radar_id, "line-fit", site.is_3d,
            f"{lf.n_windows} straight windows of {opt.window_plots} plots "
            f"(of {lf.n_windows_total} formed); need {opt.min_windows}",
        )
    sigma, moment, lf = _line_fit_sigmas(lf, robust, opt.window_p_value)
    n_dof = np.einsum("ik,ikk->k", lf.component_valid.astype(float), lf.coef)
    n_dof = np.maximum(n_dof, 1.0)
    se_factor = MAD_SE_FACTOR if robust else math.sqrt(0.5)
    se = se_factor * sigma / np.sqrt(n_dof)
    # The paper's Cartesian sigmas (eq. 8-10 corrected), pooled over the radar.
    dof_cart = np.sum(1.0 - lf.leverage)
    sx, sy = np.sqrt(np.sum(lf.cartesian_residual[:, :2] ** 2, axis=0) / dof_cart)
    details = {
        "sigma_range_m_rms": float(moment[0]),
        "sigma_azimuth_mrad_rms": float(moment[1] * 1e3),
        "sigma_x_m": float(sx),
        "sigma_y_m": float(sy),
        "sigma_p_m": float(math.sqrt((sx**2 + sy**2) / 2.0)),
        "n_windows_formed": float(lf.n_windows_total),
    }
    if site.is_3d:
        details["sigma_elevation_mrad_rms"] = float(moment[2] * 1e3)
    elif lf.component_valid[:, 2].any():
        details["sigma_height_m"] = float(sigma[2])
    return NoiseEstimate(
        radar_id=radar_id,
        sigma_range_m=float(sigma[0]),
        sigma_azimuth_mrad=float(sigma[1] * 1e3),
        sigma_elevation_mrad=float(sigma[2] * 1e3) if site.is_3d else None,
        n_plots_used=len(lf),
        n_legs=lf.n_windows,
        method="line-fit",
        se_range_m=float(se[0]),
        se_azimuth_mrad=float(se[1] * 1e3),
        se_elevation_mrad=float(se[2] * 1e3) if site.is_3d else None,
        details=details,
    )


# --------------------------------------------------------------------------- ADS-B


def _scale_with_known_variance(
    e: FloatArray, v: FloatArray, n_params: int, robust: bool
) -> tuple[float, float]:
    """Sigma ``s >= 0`` of ``e_i ~ N(0, s^2 + v_i)``; also the total sigma ``sqrt(s^2 + mean v)``.

    Robust: ``1.4826 median(|e_i| / sqrt(s^2 + v_i)) sqrt(n / (n - p)) = 1`` solved
    by bisection (the left side decreases with ``s``).  Otherwise
    ``s^2 = sum e^2 / (n - p) - mean v``.
    """
    n = e.size
    dof_factor = math.sqrt(n / (n - n_params))
    if not robust:
        s2 = np.sum(e**2) / (n - n_params) - np.mean(v)
        s = math.sqrt(max(s2, 0.0))
        return s, math.sqrt(s**2 + float(np.mean(v)))

    def g(s: float) -> float:
        return MAD_TO_SIGMA * float(np.median(np.abs(e) / np.sqrt(s**2 + v))) * dof_factor

    if g(0.0) <= 1.0:
        return 0.0, math.sqrt(float(np.mean(v)))
    lo, hi = 0.0, MAD_TO_SIGMA * float(np.median(np.abs(e))) * dof_factor * 2.0 + 1e-12
    while g(hi) > 1.0:
        hi *= 2.0
    while hi - lo > 1e-7 * hi:
        mid = 0.5 * (lo + hi)
        if g(mid) > 1.0:
            lo = mid
        else:
            hi = mid
    s = 0.5 * (lo + hi)
    return s, math.sqrt(s**2 + float(np.mean(v)))


def estimate_noise_adsb(
    dataset: Dataset,
    radar_id: str,
    *,
    robust: bool = True,
    min_plots: int = MIN_ADSB_PLOTS,
    aligned: AdsbAlignment | None = None,
) -> NoiseEstimate:
    """Polar sigmas of one radar from its residuals against interpolated ADS-B.

    For every plot matched to ADS-B (:func:`graphcal.align.align_adsb`):
    ``e = (range, azimuth, elevation)_measured - polar(ADS-B at the plot time)``.
    The biases are removed by L1 fits (range: ``offset + gain * range``,
    :func:`fit_line_irls`; azimuth, elevation: the median).  The ADS-B error
    variance in polar, ``v_i = diag(Jp C_i Jp^T)`` with ``Jp``
    (:func:`graphcal.frames.enu_to_polar_jacobian`) at the ADS-B position and
    ``C_i`` the interpolated ADS-B covariance, is removed plot by plot:
    ``e_ik ~ N(0, sigma_k^2 + v_ik)`` is solved for ``sigma_k``
    (:func:`_scale_with_known_variance`; dof: 2 for range, 1 for the angles).
    The standard error follows by the delta method,
    ``se(sigma) = (sigma_total / sigma) se(sigma_total)``.

    Parameters
    ----------
    dataset : Dataset
        Must have ADS-B.
    radar_id : str
    robust : bool
        MAD-based (default) or root-mean-square.
    min_plots : int
        Fewer matched plots: not estimated.
    aligned : AdsbAlignment, optional
        The radar's :func:`graphcal.align.align_adsb` result, when already computed.

    Returns
    -------
    NoiseEstimate
        ``method="adsb"``.  A sigma that the ADS-B error fully explains is 0
        (``details["unresolved_<component>"] = 1``).

    Raises
    ------
    ValueError
        If the dataset has no ADS-B or the radar is unknown.
    """
    site = dataset.sites.get(radar_id)
    if site is None:
        raise ValueError(f"unknown radar {radar_id!r}; radars: {', '.join(dataset.sites)}")
    if dataset.adsb is None:
        raise ValueError("the dataset has no ADS-B table: use the line-fit method")
    if aligned is None:
        aligned = align_adsb(dataset, radar_id)
    plots = aligned.plots
    ok = np.isfinite(plots.range_m) & np.isfinite(plots.azimuth_rad)
    if site.is_3d:
        ok &= np.isfinite(plots.elevation_rad)
    n = int(ok.sum())
    if n < min_plots:
        return _not_estimated(radar_id, "adsb", site.is_3d,
                              f"{n} plots matched to ADS-B; need {min_plots}")
    ref = aligned.reference_polar[ok]
    enu = site.enu_from_ecef(aligned.reference_ecef_m[ok])
    jp = frames.enu_to_polar_jacobian(enu)
    cov = jp @ aligned.reference_enu_cov_m2[ok] @ np.swapaxes(jp, 1, 2)
    v = np.einsum("ikk->ik", cov)
    e_r = plots.range_m[ok] - ref[:, 0]
    e_a = frames.wrap_to_pi(plots.azimuth_rad[ok] - ref[:, 1])
    line = fit_line_irls(ref[:, 0], e_r)
    details = {"range_offset_m": float(line.intercept), "range_gain": float(line.slope)}
    e_r = line.residuals
    az_bias = float(np.median(e_a))
    e_a = frames.wrap_to_pi(e_a - az_bias)
    details["azimuth_bias_mrad"] = az_bias * 1e3
    comps = [(e_r, v[:, 0], 2), (e_a, v[:, 1], 1)]
    if site.is_3d:
        e_e = plots.elevation_rad[ok] - ref[:, 2]
        el_bias = float(np.median(e_e))
        details["elevation_bias_mrad"] = el_bias * 1e3
        comps.append((e_e - el_bias, v[:, 2], 1))
    names = ("range", "azimuth", "elevation")
    rms_keys = ("sigma_range_m_rms", "sigma_azimuth_mrad_rms", "sigma_elevation_mrad_rms")
    sig, se = [], []
    for k, (e, var, p) in enumerate(comps):
        s, total = _scale_with_known_variance(e, var, p, robust)
        s_rms, _ = _scale_with_known_variance(e, var, p, robust=False)
        details[rms_keys[k]] = s_rms * (1.0 if k == 0 else 1e3)
        factor = MAD_SE_FACTOR if robust else math.sqrt(0.5)
        se_total = factor * total / math.sqrt(n - p)
        if s > 0:
            se.append(total / s * se_total)
        else:
            se.append(math.nan)
            details[f"unresolved_{names[k]}"] = 1.0
        sig.append(s)
    return NoiseEstimate(
        radar_id=radar_id,
        sigma_range_m=sig[0],
        sigma_azimuth_mrad=sig[1] * 1e3,
        sigma_elevation_mrad=sig[2] * 1e3 if site.is_3d else None,
        n_plots_used=n,
        n_legs=0,
        method="adsb",
        se_range_m=se[0],
        se_azimuth_mrad=se[1] * 1e3,
        se_elevation_mrad=se[2] * 1e3 if site.is_3d else None,
        details=details,
    )


# --------------------------------------------------------------------------- front end


def estimate_noise(
    dataset: Dataset,
    *,
    use_adsb: bool | Literal["auto"] = "auto",
    radar_ids: Sequence[str] | None = None,
    robust: bool = True,
    min_adsb_plots: int = DEFAULT_MIN_ADSB_PLOTS,
    options: LineFitOptions | None = None,
) -> dict[str, NoiseEstimate]:
    """Random-error sigmas of every radar (paper 000, corrected; or ADS-B).

    Parameters
    ----------
    dataset : Dataset
    use_adsb : bool or "auto"
        True: ADS-B residuals (:func:`estimate_noise_adsb`); False: straight-leg
        line fits (:func:`estimate_noise_line_fit`); ``"auto"``: ADS-B for a
        radar with at least ``min_adsb_plots`` ADS-B-matched plots, else line fits.
    radar_ids : sequence of str, optional
        Radars to estimate (default: all, in ``sites.toml`` order).
    robust : bool
        MAD-based sigmas (default) or root-mean-square.
    min_adsb_plots : int
        Threshold of ``"auto"``.
    options : LineFitOptions, optional
        Settings of the line-fit method.

    Returns
    -------
    dict of str to NoiseEstimate
        One entry per radar; radars without enough data have ``estimated=False``.

    Raises
    ------
    ValueError
        If ``use_adsb`` is not True, False or "auto", ``use_adsb=True`` on a
        dataset without ADS-B, or a radar id is unknown.
    """
    if use_adsb not in (True, False, "auto"):
        raise ValueError(f"use_adsb must be True, False or 'auto', got {use_adsb!r}")
    if use_adsb is True and dataset.adsb is None:
        raise ValueError("use_adsb=True but the dataset has no ADS-B table")
    ids = list(dataset.sites) if radar_ids is None else list(radar_ids)
    for rid in ids:
        if rid not in dataset.sites:
            raise ValueError(f"unknown radar {rid!r}; radars: {', '.join(dataset.sites)}")
    out: dict[str, NoiseEstimate] = {}
    for rid in ids:
        aligned = None
        if use_adsb == "auto":
            if dataset.adsb is not None:
                aligned = align_adsb(dataset, rid)
            adsb = aligned is not None and len(aligned) >= min_adsb_plots
        else:
            adsb = bool(use_adsb)
        if adsb:
            out[rid] = estimate_noise_adsb(dataset, rid, robust=robust, aligned=aligned)
        else:
            out[rid] = estimate_noise_line_fit(dataset, rid, robust=robust, options=options)
    return out


def _missing(value: float | None) -> bool:
    return value is None or not math.isfinite(value) or value <= 0.0


def sites_with_estimated_sigmas(
    sites: Mapping[str, Site],
    estimates: Mapping[str, NoiseEstimate],
    only_missing: bool = True,
) -> dict[str, Site]:
    """New :class:`Site` objects carrying estimated sigmas (``dataclasses.replace``).

    Parameters
    ----------
    sites : mapping of str to Site
    estimates : mapping of str to NoiseEstimate
        From :func:`estimate_noise`; radars absent or not estimated keep their sigmas.
    only_missing : bool
        True: replace only sigmas that are missing (``None``, NaN or not
        positive; an elevation sigma only for a 3-D site).  False: replace all
        estimated sigmas (the elevation sigma of a 2-D site stays ``None``).

    Returns
    -------
    dict of str to Site
        Same keys and order as ``sites``.
    """
    out: dict[str, Site] = {}
    for rid, site in sites.items():
        est = estimates.get(rid)
        if est is None or not est.estimated:
            out[rid] = site
            continue
        changes: dict[str, float] = {}
        if not only_missing or _missing(site.sigma_range_m):
            changes["sigma_range_m"] = est.sigma_range_m
        if not only_missing or _missing(site.sigma_azimuth_rad):
            changes["sigma_azimuth_rad"] = est.sigma_azimuth_rad
        if site.is_3d and est.sigma_elevation_rad is not None and (
            not only_missing or _missing(site.sigma_elevation_rad)
        ):
            changes["sigma_elevation_rad"] = est.sigma_elevation_rad
        out[rid] = replace(site, **changes) if changes else site
    return out


# --------------------------------------------------------------------------- lookup table


def variance_table(
    dataset: Dataset,
    radar_id: str,
    *,
    range_bin_m: float = 50_000.0,
    azimuth_bin_deg: float = 45.0,
    robust: bool = True,
    min_plots: int = 30,
    options: LineFitOptions | None = None,
) -> pd.DataFrame:
    """The paper's variance lookup table: sigmas per range and azimuth bin (sec. 2).

    From the line-fit residuals (:func:`line_fit_residuals`): per bin of the
    measured range and azimuth, the Cartesian sigmas of eq. 8-10 (corrected:
    residual RMS over ``sum (1 - h_ii)``; ``sigma_p = sqrt((s_x^2 + s_y^2)/2)``,
    eq. 10) and the polar sigmas (residuals standardised by their variance
    coefficients with the radar-wide sigma ratios, then MAD or RMS).

    Parameters
    ----------
    dataset : Dataset
    radar_id : str
    range_bin_m : float
        Width of the range bins [m], from 0.
    azimuth_bin_deg : float
        Width of the azimuth bins [deg], from north; must divide into 360 or
        the last bin is narrower.
    robust : bool
        MAD (default) or RMS per bin.
    min_plots : int
        Bins with fewer plots get NaN sigmas (their counts are kept).
    options : LineFitOptions, optional

    Returns
    -------
    pandas.DataFrame
        One row per non-empty bin: ``radar_id``, ``range_min_m``,
        ``range_max_m``, ``azimuth_min_deg``, ``azimuth_max_deg``, ``n_plots``,
        ``n_legs``, ``sigma_x_m``, ``sigma_y_m``, ``sigma_p_m``,
        ``sigma_range_m``, ``sigma_azimuth_mrad`` and, for 3-D radars,
        ``sigma_z_m`` and ``sigma_elevation_mrad``.

    Raises
    ------
    ValueError
        For non-positive bin widths, an unknown radar, or a radar without
        enough straight windows.
    """
    if range_bin_m <= 0 or azimuth_bin_deg <= 0:
        raise ValueError("range_bin_m and azimuth_bin_deg must be positive")
    opt = LineFitOptions() if options is None else options
    lf = line_fit_residuals(dataset, radar_id, opt)
    if lf.n_windows < opt.min_windows:
        raise ValueError(
            f"radar {radar_id!r}: {lf.n_windows} straight windows, need {opt.min_windows}"
        )
    sigma, _, lf = _line_fit_sigmas(lf, robust, opt.window_p_value)
    z, _ = _standardised(lf, sigma)
    cart = lf.cartesian_residual / np.sqrt(1.0 - lf.leverage)[:, None]
    r_bin = np.floor(lf.range_m / range_bin_m).astype(np.int64)
    a_bin = np.floor(np.degrees(lf.azimuth_rad) / azimuth_bin_deg).astype(np.int64)

    def scale(x: FloatArray) -> float:
        if robust:
            return float(MAD_TO_SIGMA * np.median(np.abs(x)))
        return float(np.sqrt(np.mean(x**2)))

    rows = []
    frame = pd.DataFrame({"r": r_bin, "a": a_bin})
    for (rb, ab), idx in frame.groupby(["r", "a"], sort=True).indices.items():
        n = len(idx)
        row: dict[str, float | int | str] = {
            "radar_id": radar_id,
            "range_min_m": rb * range_bin_m,
            "range_max_m": (rb + 1) * range_bin_m,
            "azimuth_min_deg": ab * azimuth_bin_deg,
            "azimuth_max_deg": min((ab + 1) * azimuth_bin_deg, 360.0),
            "n_plots": n,
            "n_legs": int(np.unique(lf.window[idx]).size),
        }
        enough = n >= min_plots
        sx = scale(cart[idx, 0]) if enough else math.nan
        sy = scale(cart[idx, 1]) if enough else math.nan
        row["sigma_x_m"] = sx
        row["sigma_y_m"] = sy
        row["sigma_p_m"] = math.sqrt((sx**2 + sy**2) / 2.0)
        row["sigma_range_m"] = scale(z[idx, 0]) if enough else math.nan
        row["sigma_azimuth_mrad"] = scale(z[idx, 1]) * 1e3 if enough else math.nan
        if lf.is_3d:
            row["sigma_z_m"] = scale(cart[idx, 2]) if enough else math.nan
            row["sigma_elevation_mrad"] = scale(z[idx, 2]) * 1e3 if enough else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


def fill_missing_sigmas(
    dataset: Dataset, *, use_adsb: bool | Literal["auto"] = "auto"
) -> tuple[Dataset, dict[str, NoiseEstimate]]:
    """The dataset with every sigma that ``sites.toml`` left out estimated from the data.

    Only radars with :attr:`graphcal.dataset.Site.missing_sigmas` are estimated
    (:func:`estimate_noise`); a dataset without missing sigmas is returned as it
    is, with no estimate.

    Returns
    -------
    dataset : Dataset
        A copy with the filled-in sites (the plots and ADS-B tables are shared).
    estimates : dict of str to NoiseEstimate
        The estimates used, by radar.

    Raises
    ------
    DatasetError
        If a radar's missing sigmas cannot be estimated (too few usable plots),
        naming the radar, the missing keys and the reason.
    """
    missing = [rid for rid, site in dataset.sites.items() if site.missing_sigmas]
    if not missing:
        return dataset, {}
    if use_adsb is True and dataset.adsb is None:
        use_adsb = False
    estimates = estimate_noise(dataset, use_adsb=use_adsb, radar_ids=missing)
    for rid in missing:
        if not estimates[rid].estimated:
            keys = ", ".join(dataset.sites[rid].missing_sigmas)
            raise DatasetError(
                f"radar {rid!r} has no {keys} and the data cannot give them "
                f"({estimates[rid].reason}); write them in sites.toml",
                path=None if dataset.path is None else dataset.path / "sites.toml",
                field=keys.split(", ")[0],
            )
    sites = sites_with_estimated_sigmas(dataset.sites, estimates, only_missing=True)
    return replace(dataset, sites=sites), estimates


def estimated_sigmas_info(estimates: Mapping[str, NoiseEstimate]) -> dict[str, dict]:
    """``{radar: {sigma key: value, "method": ..., "n_plots": ...}}`` for a result's ``info``."""
    out: dict[str, dict] = {}
    for rid, est in estimates.items():
        entry: dict = {"sigma_range_m": est.sigma_range_m,
                       "sigma_azimuth_mrad": est.sigma_azimuth_mrad}
        if est.sigma_elevation_mrad is not None:
            entry["sigma_elevation_mrad"] = est.sigma_elevation_mrad
        entry.update(method=est.method, n_plots=est.n_plots_used)
        out[rid] = entry
    return out


def fills_missing_sigmas(estimator: Callable[..., Calibration]) -> Callable[..., Calibration]:
    """Decorate an estimator ``f(dataset, **options)`` to fill missing site sigmas first.

    The sigmas ``sites.toml`` leaves out are estimated by :func:`fill_missing_sigmas`
    (ADS-B where there is enough, else straight-leg line fits); the result then
    carries them in ``info["estimated_sigmas"]`` and says so in a warning.
    """

    @functools.wraps(estimator)
    def run(dataset: Dataset, *args: Any, **options: Any) -> Calibration:
        missing = {rid: site.missing_sigmas for rid, site in dataset.sites.items()}
        dataset, estimates = fill_missing_sigmas(dataset)
        cal = estimator(dataset, *args, **options)
        if estimates:
            cal.info["estimated_sigmas"] = estimated_sigmas_info(estimates)
            cal.warnings.extend(
                f"{rid}: sites.toml gives no {', '.join(missing[rid])}; used "
                f"{describe_estimate(est)}" for rid, est in estimates.items()
            )
        return cal

    return run


def describe_estimate(est: NoiseEstimate) -> str:
    """One line: the estimated sigmas of a radar, the method and the plots behind them."""
    values = f"range {est.sigma_range_m:.1f} m, azimuth {est.sigma_azimuth_mrad:.2f} mrad"
    if est.sigma_elevation_mrad is not None:
        values += f", elevation {est.sigma_elevation_mrad:.2f} mrad"
    return f"sigmas estimated from {est.n_plots_used} plots ({est.method}): {values}"
