"""Random-error sigmas of a radar from its residuals against ADS-B.

Each plot minus the ADS-B position of its aircraft interpolated to its time
(:func:`graphcal.data.align.align_adsb`), in polar: range [m], azimuth and
elevation [rad].  The radar's biases are removed by robust (L1) fits (range
residual ``= offset + gain * range``, :func:`graphcal.noise.variance.fit_line_irls`;
azimuth and elevation residuals constant), and the ADS-B error mapped into
polar (horizontal ``sigma_m``, vertical
:data:`graphcal.data.align.ADSB_VERTICAL_SIGMA_RATIO` times it; the interpolation
weights included) is removed in quadrature, plot by plot.  Linear
interpolation between reports 1 s apart adds at most ``a dt^2 / 8`` (about
1 m in a 3 deg/s turn at 250 m/s), negligible against radar noise.  A
time-stamping bias would move every plot along its track and inflate the
sigmas many times (a 2 s offset at 250 m/s: 500 m): it is estimated first, by
least squares of the residuals on the ADS-B track's polar rates
(:func:`estimate_time_offset`), and when the data show one, ADS-B is
interpolated again at the corrected times (``details["time_offset_s"]``).

This is independent of paper 000, whose method is :mod:`graphcal.noise.line_fit`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.data.align import AdsbAlignment, align_adsb
from graphcal.data.dataset import Dataset
from graphcal.noise.result import MAD_SE_FACTOR, NoiseEstimate, not_estimated
from graphcal.noise.variance import MAD_TO_SIGMA, fit_line_irls

FloatArray = NDArray[np.float64]

#: Below this many usable plots (ADS-B method) a radar is not estimated.
MIN_ADSB_PLOTS = 30


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


#: A time offset is removed when it exceeds this many of its sigmas ...
TIME_OFFSET_SIGNIFICANCE = 6.0
#: ... and this size [s] (well below a scan, above the ADS-B timing error).
TIME_OFFSET_MIN_S = 0.05


def estimate_time_offset(site: Any, aligned: AdsbAlignment, *,
                         min_significance: float = TIME_OFFSET_SIGNIFICANCE
                         ) -> tuple[float, float] | None:
    """A radar's time-stamping bias from its residuals against ADS-B, when they show one.

    A plot stamped ``tau`` late is compared with ADS-B ``tau`` further along the
    track: its residual is ``e = -rate * tau`` plus the biases and noise, with
    ``rate`` the polar rate (range [m/s], azimuth [rad/s]) of the ADS-B track.
    Range residuals are regressed on ``[1, range, -range_rate]`` and azimuth
    residuals on ``[1, -azimuth_rate]`` (least squares, after dropping residuals
    beyond 5 MAD-sigmas); the two estimates of ``tau`` are combined by inverse
    variance.

    Parameters
    ----------
    site : Site
        The radar.
    aligned : AdsbAlignment
        Its plots aligned with ADS-B (with track velocities).
    min_significance : float
        ``|tau|`` must exceed this many sigmas (and :data:`TIME_OFFSET_MIN_S`, unless 0).

    Returns
    -------
    (tau_s, sigma_s) or None
        ``None`` when the velocities are unknown, too few plots, or no significant offset.
    """
    velocity = aligned.reference_velocity_ecef_m_s
    plots = aligned.plots
    if velocity is None or len(plots.range_m) < MIN_ADSB_PLOTS:
        return None
    ok = (np.isfinite(plots.range_m) & np.isfinite(plots.azimuth_rad)
          & np.all(np.isfinite(velocity), axis=1))
    if int(ok.sum()) < MIN_ADSB_PLOTS:
        return None
    ref = aligned.reference_polar[ok]
    enu = site.enu_from_ecef(aligned.reference_ecef_m[ok])
    enu_velocity = site.enu_from_ecef(aligned.reference_ecef_m[ok] + velocity[ok]) - enu
    rates = np.einsum("nij,nj->ni", frames.enu_to_polar_jacobian(enu), enu_velocity)
    e_r = plots.range_m[ok] - ref[:, 0]
    e_a = frames.wrap_to_pi(plots.azimuth_rad[ok] - ref[:, 1])
    parts = []
    for design, e in (
            (np.column_stack([np.ones(len(e_r)), ref[:, 0], -rates[:, 0]]), e_r),
            (np.column_stack([np.ones(len(e_a)), -rates[:, 1]]), e_a)):
        keep = np.abs(e - np.median(e)) <= 5.0 * MAD_TO_SIGMA * np.median(
            np.abs(e - np.median(e))) + 1e-12
        if int(keep.sum()) <= design.shape[1] + 2:
            continue
        x, *_ = np.linalg.lstsq(design[keep], e[keep], rcond=None)
        residual = e[keep] - design[keep] @ x
        dof = int(keep.sum()) - design.shape[1]
        variance = float(residual @ residual) / dof
        try:
            cov = variance * np.linalg.inv(design[keep].T @ design[keep])
        except np.linalg.LinAlgError:
            continue
        if np.isfinite(cov[-1, -1]) and cov[-1, -1] > 0:
            parts.append((float(x[-1]), float(cov[-1, -1])))
    if not parts:
        return None
    weights = np.array([1.0 / v for _, v in parts])
    tau = float(np.sum(weights * np.array([t for t, _ in parts])) / np.sum(weights))
    sigma = float(1.0 / math.sqrt(np.sum(weights)))
    if min_significance > 0 and (abs(tau) < TIME_OFFSET_MIN_S
                                 or abs(tau) < min_significance * sigma):
        return None
    return tau, sigma


def estimate_noise_adsb(
    dataset: Dataset,
    radar_id: str,
    *,
    robust: bool = True,
    min_plots: int = MIN_ADSB_PLOTS,
    aligned: AdsbAlignment | None = None,
) -> NoiseEstimate:
    """Polar sigmas of one radar from its residuals against interpolated ADS-B.

    For every plot matched to ADS-B (:func:`graphcal.data.align.align_adsb`):
    ``e = (range, azimuth, elevation)_measured - polar(ADS-B at the plot time)``.
    The biases are removed by L1 fits (range: ``offset + gain * range``,
    :func:`graphcal.noise.variance.fit_line_irls`; azimuth, elevation: the median).  The ADS-B error
    variance in polar, ``v_i = diag(Jp C_i Jp^T)`` with ``Jp``
    (:func:`graphcal.core.frames.enu_to_polar_jacobian`) at the ADS-B position and
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
        The radar's :func:`graphcal.data.align.align_adsb` result, when already computed.

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
    offset = estimate_time_offset(site, aligned)
    if offset is not None:  # a time-stamping bias: ADS-B again at the corrected times
        aligned = align_adsb(dataset, radar_id, time_offset_s=offset[0])
        again = estimate_time_offset(site, aligned, min_significance=0.0)
        offset = (offset[0] + (again[0] if again is not None else 0.0), offset[1])
        if again is not None and abs(again[0]) > 0.01:
            aligned = align_adsb(dataset, radar_id, time_offset_s=offset[0])
    plots = aligned.plots
    ok = np.isfinite(plots.range_m) & np.isfinite(plots.azimuth_rad)
    if site.is_3d:
        ok &= np.isfinite(plots.elevation_rad)
    n = int(ok.sum())
    if n < min_plots:
        return not_estimated(radar_id, "adsb", site.is_3d,
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
    if offset is not None:
        details["time_offset_s"], details["time_offset_sigma_s"] = offset
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
