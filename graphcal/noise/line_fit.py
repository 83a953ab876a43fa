"""Random-error sigmas of a radar from straight-leg line fits (paper 000 sec. 2, corrected).

A target flying a straight constant-velocity leg is fitted by a straight line
in time; the scatter of the plots about the line is the radar's noise (paper
000 eq. 3-10; the corrected formulas and their departures from the printed
paper are in :mod:`graphcal.noise.variance`).  No ADS-B is needed.  Units: metres,
radians and seconds inside; the :class:`~graphcal.noise.result.NoiseEstimate`
gives angles in mrad.

Departures from the paper besides the corrected formulas:

* The paper fits ``x(t)`` and ``y(t)`` of 2-D plots (elevation 0).  graphcal
  fits in 3-D, in the coordinates ``(east, north, height)`` of the radar (the
  *fit frame*): east and north of its ENU frame and the height above the
  radar's local sphere (the sphere of :func:`graphcal.core.frames.elevation_from_height`),
  in which a level flight is a straight line (in plain ENU its height would
  sag by ``L^2 / 8R``, 70 m over a 60 km window).  3-D radars place plots with
  the measured elevation; 2-D radars at the reported (Mode C) height when
  present (like :mod:`graphcal.model.cross_radar`), else on the
  horizontal plane (elevation 0, the paper's choice).
* What graphcal needs are the polar sigmas, so the residuals are evaluated in
  polar space: the measured ``(range, azimuth, elevation)`` minus the polar
  coordinates of the fitted line at the plot time.  Each residual carries
  ``(1 - h_ii)`` of its own noise (``h`` the hat matrix of the line fit) plus a
  little of the other components' noise, since the line mixes plots seen from
  slightly different directions; the expected square of every residual is
  computed exactly under the linearised model (see :class:`LineFitResiduals`),
  which both corrects the degrees of freedom and removes this leakage.
* Eq. 8-10 give ``sigma_x``, ``sigma_y`` (now dof-corrected) and
  ``sigma_p = sqrt((s_x^2 + s_y^2) / 2)`` (eq. 10, horizontal); they are
  reported pooled over the radar in ``NoiseEstimate.details`` and per
  range/azimuth bin by :func:`graphcal.noise.variance_table`.

Legs: a radar's plots are split by ``target_id`` (plots without one are not
used) and at time gaps longer than 2.5 scans, cut into windows of
``window_plots`` consecutive plots, and a window is kept only when a straight
constant-velocity line fits it: the IRLS (L1) fit
(:func:`graphcal.noise.variance.fit_line_irls`, batched) flags outlying plots (more
than 5 robust sigmas), the remaining plots are fitted by ordinary least
squares (the same hat matrix for every coordinate), a quadratic term that is
significant against the window's own scatter (``|t| > 3.5`` in any coordinate)
marks a turn or an acceleration, and a window whose residuals are too large
for the radar's pooled sigmas (chi-square, ``p < 1e-3``) is dropped in a
second pass.  All settings are in :class:`LineFitOptions`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.data.align import plot_arrays
from graphcal.data.dataset import Dataset, Site
from graphcal.noise.result import MAD_SE_FACTOR, NoiseEstimate, not_estimated
from graphcal.noise.variance import MAD_TO_SIGMA, irls_lines

FloatArray = NDArray[np.float64]

#: 2-D plots above this elevation [rad] are not placed from their reported height.
MAX_2D_ELEVATION_RAD = np.deg2rad(70.0)

#: Placement of a plot in the fit frame (see :func:`line_fit_residuals`).
_MODE_3D, _MODE_HEIGHT, _MODE_PLANE = 0, 1, 2


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

    Steps (see the module docstring): split the plots by ``target_id`` and
    gaps, cut windows of ``options.window_plots`` plots, place them in the fit
    frame ``(east, north, height)``, fit each coordinate against time by IRLS
    (:func:`graphcal.noise.variance.irls_lines`) to flag outliers, refit the inliers by
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
    _, _, res_l1, _, _ = irls_lines(t, y, valid, max_iter=opt.irls_max_iter)
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


def standardised_residuals(
    lf: LineFitResiduals, sigma: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Residuals divided by ``sqrt(E[e^2]) / sigma_k`` (variance ``sigma_k^2``), and ``E[e^2]``.

    Also used per bin by :func:`graphcal.noise.variance_table`.
    """
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
        z, _ = standardised_residuals(lf, sigma)
        new = sigma.copy()
        for k in range(3):
            if valid[:, k].any() and sigma[k] > 0:
                new[k] = MAD_TO_SIGMA * np.median(np.abs(z[valid[:, k], k]))
        sigma = new
    return sigma


def _window_chi2_keep(lf: LineFitResiduals, sigma: FloatArray, p_value: float) -> NDArray:
    """Rows of windows whose residuals are consistent with ``sigma`` (chi-square test)."""
    _, var = standardised_residuals(lf, sigma)
    valid = lf.component_valid & (sigma > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        contrib = np.where(valid, lf.polar_residual**2 / var * (1.0 - lf.leverage)[:, None], 0.0)
    q = np.bincount(lf.window, weights=contrib.sum(axis=1))
    dof = np.bincount(lf.window, weights=(valid * (1.0 - lf.leverage)[:, None]).sum(axis=1))
    from scipy import stats

    limit = stats.chi2.isf(p_value, np.maximum(dof, 1.0))
    bad = q > limit
    return ~bad[lf.window]


def line_fit_sigmas(
    lf: LineFitResiduals, robust: bool, p_value: float
) -> tuple[FloatArray, FloatArray, LineFitResiduals]:
    """Robust and moment sigmas after the second-pass window check; also the rows used.

    Returns ``(sigma, moment, lf)``: the sigmas (robust or moment, by ``robust``), the
    moment sigmas, and the residuals of the windows kept; sigmas are ``(range [m],
    azimuth [rad], third)`` as in :class:`LineFitResiduals`.
    """
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
        return not_estimated(
            radar_id, "line-fit", site.is_3d,
            f"{lf.n_windows} straight windows of {opt.window_plots} plots "
            f"(of {lf.n_windows_total} formed); need {opt.min_windows}",
        )
    sigma, moment, lf = line_fit_sigmas(lf, robust, opt.window_p_value)
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
