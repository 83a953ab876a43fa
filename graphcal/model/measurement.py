"""Each radar's measurement model: function, Jacobians and noise, in one place.

A radar measures its target in its polar frame (range, azimuth and, for a 3-D
radar, elevation), with the biases of the contract's model on top::

    range_measured     = (1 + range_gain) * range_true + range_offset_m
    azimuth_measured   = azimuth_true + azimuth_bias         (wrapped to [0, 2 pi))
    elevation_measured = elevation_true + elevation_bias     (3-D radars only)

:class:`RadarMeasurementModel` owns, as Stone Soup's measurement models do,
the ``function`` (target position -> measured polar), its Jacobians (in the
biases, paper 001 eq. 2, and in the target position), the ``covar`` of the
radar's random errors and the ``inverse_function`` (a plot corrected for the
biases).  One model per radar kind: a 2-D radar measures ``m = 2``
coordinates, a 3-D radar ``m = 3``.  The ADS-B and cross-radar observation
blocks, the closed-form solvers and the Cramér-Rao bound all evaluate their
radar measurements through it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.refraction import refracted_polar, refracted_polar_jacobian
from graphcal.data.align import AdsbAlignment
from graphcal.data.bias import RadarBias, apply_bias, correct_bias, measurement_bias_jacobian
from graphcal.data.calibration import ResidualStats
from graphcal.data.dataset import Site

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class RadarMeasurementModel:
    """The measurement model of one radar (2-D or 3-D), straight line of sight.

    Attributes
    ----------
    site : Site
        The radar: antenna position (its ENU frame), sigmas, 2-D or 3-D.
    """

    site: Site

    @property
    def ndim_meas(self) -> int:
        """Measured coordinates: 3 (range, azimuth, elevation) or 2 (no elevation)."""
        return 3 if self.site.is_3d else 2

    # ------------------------------------------------------------------ function
    def true_polar(self, ecef_m: FloatArray) -> FloatArray:
        """True ``(range_m, azimuth_rad, elevation_rad)`` ``(n, 3)`` of ECEF points ``(n, 3)``.

        With refraction (contract v2) the range is the ray's electrical length and
        the elevation its apparent elevation (:mod:`graphcal.core.refraction`).
        """
        site = self.site
        if site.atmosphere is not None:
            return np.stack(refracted_polar(site.atmosphere, site.lat_rad, site.alt_m,
                                            site.enu_from_ecef(ecef_m)), axis=-1)
        return np.stack(frames.enu_to_polar(site.enu_from_ecef(ecef_m)), axis=-1)

    def function(self, ecef_m: FloatArray, bias: RadarBias | None = None) -> FloatArray:
        """Measured polar coordinates ``(n, 3)`` [m, rad] of ECEF points, biases applied.

        A 2-D radar's third column is the true elevation (it does not measure it).
        """
        polar = self.true_polar(ecef_m)
        if bias is None:
            return polar
        r, az, el = apply_bias(polar[:, 0], polar[:, 1], polar[:, 2], bias)
        return np.stack([r, az, el], axis=-1)

    def inverse_function(self, measured_polar: FloatArray, bias: RadarBias) -> FloatArray:
        """The plots ``(n, 3)`` corrected for ``bias`` (the contract's inverse map)."""
        r, az, el = correct_bias(measured_polar[:, 0], measured_polar[:, 1],
                                 measured_polar[:, 2], bias)
        return np.stack([r, az, el], axis=-1)

    # ------------------------------------------------------------------ Jacobians
    @staticmethod
    def bias_jacobian(range_true_m: FloatArray) -> FloatArray:
        """``d measured / d (offset, gain, az_bias, el_bias)`` ``(n, 3, 4)`` (paper 001 eq. 2)."""
        return measurement_bias_jacobian(range_true_m)

    def position_jacobian(self, ecef_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        """True polar coordinates ``(n, 3)`` and ``d polar / d ecef`` ``(n, 3, 3)``."""
        polar, jac_enu = self.enu_jacobian(self.site.enu_from_ecef(ecef_m))
        return polar, jac_enu @ self.site.ecef_to_enu

    def enu_jacobian(self, enu_m: FloatArray) -> tuple[FloatArray, FloatArray]:
        """True polar coordinates ``(n, 3)`` and ``d polar / d enu`` ``(n, 3, 3)`` of ENU points.

        Refracted with an atmosphere
        (:func:`graphcal.core.refraction.refracted_polar_jacobian`).
        """
        site = self.site
        if site.atmosphere is not None:
            return refracted_polar_jacobian(site.atmosphere, site.lat_rad, site.alt_m, enu_m)
        polar = np.stack(frames.enu_to_polar(enu_m), axis=-1)
        return polar, frames.enu_to_polar_jacobian(enu_m)

    def measure(self, enu_m: FloatArray, terms: FloatArray, free: tuple[str, ...]
                ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The biased measurement of ENU points and its Jacobians in the position and in
        every free bias term: the model of the trajectory formulation.

        ``terms``: the full vector of :data:`~graphcal.model.parameters.TERM_NAMES`
        (offset, gain, azimuth bias, elevation bias, time offset, eccentricity ``s, c``).
        With ``(r, az, el)`` the true (refracted) polar coordinates::

            h = ((1 + g) r + o,  az + b + s sin az + c cos az,  el + e)
            d h / d enu = diag(1 + g, 1 + s cos az - c sin az, 1) d (r, az, el) / d enu
            d h / d (o, g, b, e, s, c) = (1, 0, 0), (r, 0, 0), (0, 1, 0), (0, 0, 1),
                                         (0, sin az, 0), (0, cos az, 0)

        The time offset's column is ``-(d h / d position) v``, the point's velocity times
        the position Jacobian, which the caller forms (it knows the velocity): here it is 0.

        Returns
        -------
        predicted : ndarray (n, 3)
            ``(range_m, azimuth_rad, elevation_rad)`` measured, azimuth not wrapped.
        d_enu : ndarray (n, 3, 3)
        d_terms : ndarray (n, 3, len(free))
            The free terms' columns, in ``free``'s order.
        """
        offset, gain, az_bias, el_bias, _, s_ecc, c_ecc = (float(v) for v in terms)
        polar, jac_enu = self.enu_jacobian(enu_m)
        r_t, az_t, el_t = polar[:, 0], polar[:, 1], polar[:, 2]
        sin_az, cos_az = np.sin(az_t), np.cos(az_t)
        predicted = np.stack([(1.0 + gain) * r_t + offset,
                              az_t + az_bias + s_ecc * sin_az + c_ecc * cos_az,
                              el_t + el_bias], axis=-1)
        slope = np.stack([np.full_like(r_t, 1.0 + gain),
                          1.0 + s_ecc * cos_az - c_ecc * sin_az, np.ones_like(r_t)], axis=-1)
        d_enu = slope[:, :, None] * jac_enu
        d_terms = np.zeros((len(r_t), 3, len(free)))
        for k, name in enumerate(free):
            if name == "range_offset":
                d_terms[:, 0, k] = 1.0
            elif name == "range_gain":
                d_terms[:, 0, k] = r_t
            elif name == "azimuth_bias":
                d_terms[:, 1, k] = 1.0
            elif name == "elevation_bias":
                d_terms[:, 2, k] = 1.0
            elif name == "azimuth_sin":
                d_terms[:, 1, k] = sin_az
            elif name == "azimuth_cos":
                d_terms[:, 1, k] = cos_az
        return predicted, d_enu, d_terms

    # ------------------------------------------------------------------ noise
    def covar(self, n: int) -> FloatArray:
        """The radar's random-error covariance ``(n, 3, 3)`` [m², rad²].

        A 2-D radar's elevation variance is 0 (it measures no elevation).
        """
        cov = np.zeros((n, 3, 3))
        cov[:, 0, 0] = self.site.sigma_range_m**2
        cov[:, 1, 1] = self.site.sigma_azimuth_rad**2
        if self.site.is_3d:
            cov[:, 2, 2] = self.site.sigma_elevation_rad**2
        return cov

    def sigmas(self) -> FloatArray:
        """1-sigma of the measured coordinates ``(m,)`` [m, rad]."""
        return self.site.measurement_sigmas()[: self.ndim_meas]


def measurement_model(site: Site) -> RadarMeasurementModel:
    """The measurement model of a radar (its kind from the site)."""
    return RadarMeasurementModel(site)


# --------------------------------------------------------------------------- ADS-B references
def measured_polar(al: AdsbAlignment) -> FloatArray:
    """The aligned plots as measured, ``(n, 3)`` [m, rad]."""
    p = al.plots
    return np.stack([p.range_m, p.azimuth_rad, p.elevation_rad], axis=-1)


def reference_polar_covariance(al: AdsbAlignment, site: Site | None = None) -> FloatArray:
    """ADS-B position covariance mapped to the radar's polar coordinates ``(n, 3, 3)``.

    ``J C J^T`` with ``J = d polar / d enu`` at the reference (paper 002's
    first-order conversion, eq. 17-19); along refracted rays when ``site`` has
    an atmosphere.  Computed once per alignment (kept in ``al.derived``): read-only.
    """
    refracted = site is not None and site.atmosphere is not None
    key = "reference_polar_covariance" + (" refracted" if refracted else "")
    if key not in al.derived:
        al.derived[key] = _reference_polar_covariance(al, site if refracted else None)
    return al.derived[key]


def _reference_polar_covariance(al: AdsbAlignment, site: Site | None) -> FloatArray:
    if site is not None and site.atmosphere is not None:
        jac = al.reference_polar_jacobian
        if jac is None:
            _, jac = measurement_model(site).enu_jacobian(site.enu_from_ecef(al.reference_ecef_m))
    else:
        enu = frames.polar_to_enu(*al.reference_polar.T)
        jac = frames.enu_to_polar_jacobian(enu)
    cov = al.reference_enu_cov_m2
    if cov.ndim == 3 and cov.shape[1:] == (3, 3) and not np.any(
            cov[:, [0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]]):
        # Diagonal (as align_adsb makes it): jac @ cov is jac with its columns scaled,
        # exactly, so one product is spared.
        return (jac * np.diagonal(cov, axis1=1, axis2=2)[:, None, :]) @ np.swapaxes(jac, -1, -2)
    return jac @ cov @ np.swapaxes(jac, -1, -2)


def residual_stats(site: Site, al: AdsbAlignment, bias: RadarBias) -> ResidualStats:
    """Polar residuals of one radar against ADS-B, before and after correction.

    Residual = corrected measurement minus ADS-B in the radar's polar
    coordinates; azimuth wrapped to [-pi, pi).  ``chi2_per_dof`` normalises the
    corrected residuals by the radar plus ADS-B noise.
    """
    model = measurement_model(site)
    measured = measured_polar(al)
    ref = al.reference_polar
    noise = model.covar(len(al)) + reference_polar_covariance(al, site)

    def stats(b: RadarBias) -> tuple[dict[str, dict[str, float]], float]:
        corrected = model.inverse_function(measured, b)
        parts = {
            "range_m": (corrected[:, 0] - ref[:, 0], 1.0, 0),
            "azimuth_mrad": (frames.wrap_to_pi(corrected[:, 1] - ref[:, 1]), 1e3, 1),
        }
        if site.is_3d:
            parts["elevation_mrad"] = (corrected[:, 2] - ref[:, 2], 1e3, 2)
        out, chi2 = {}, 0.0
        for key, (res, unit, k) in parts.items():
            out[key] = {
                "mean": float(np.mean(res) * unit),
                "mean_abs": float(np.mean(np.abs(res)) * unit),
                "rms": float(np.sqrt(np.mean(res**2)) * unit),
            }
            chi2 += float(np.sum(res**2 / noise[:, k, k]))
        return out, chi2

    before, _ = stats(RadarBias())
    after, chi2 = stats(bias)
    n_meas = len(al) * model.ndim_meas
    dof = max(n_meas - len(site.estimate), 1)
    return ResidualStats(n=len(al), before=before, after=after, chi2_per_dof=chi2 / dof)
