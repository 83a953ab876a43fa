"""Each radar's measurement model: function, Jacobians and noise, in one place.

A radar measures its target in its polar frame (range, azimuth and, for a 3-D
radar, elevation), with the biases of the contract's model on top::

    range_measured     = (1 + range_gain) * range_true + range_offset_m
    azimuth_measured   = azimuth_true + azimuth_bias         (wrapped to [0, 2 pi))
                         + s sin(azimuth_true) + c cos(azimuth_true)  (eccentricity)
    elevation_measured = elevation_true + elevation_bias     (3-D radars only)

:func:`biased_polar` is that model, with its Jacobians in the true coordinates
and in the terms of :data:`~graphcal.model.parameters.TERM_NAMES`, and
:func:`corrected_polar` its inverse (a plot corrected for the biases), whose
Jacobian in the terms follows from the model's by the implicit function
theorem.  The trajectory formulation (:meth:`RadarMeasurementModel.measure`),
the ADS-B factor and the cross-radar correction of plots
(:func:`graphcal.model.cross_radar.corrected_ecef`) evaluate the model through
these two functions.

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
from graphcal.core.batched import congruent_diagonal, congruent_diagonal_variances
from graphcal.core.refraction import refracted_polar, refracted_polar_jacobian
from graphcal.data.align import AdsbAlignment
from graphcal.data.bias import (
    RadarBias,
    apply_bias,
    correct_bias,
    measurement_bias_jacobian,
    true_azimuth,
)
from graphcal.data.calibration import ResidualStats
from graphcal.data.dataset import Site
from graphcal.model.parameters import TERM_NAMES

FloatArray = NDArray[np.float64]

#: The measured coordinate (0 range, 1 azimuth, 2 elevation) that each term of
#: :data:`~graphcal.model.parameters.TERM_NAMES` moves: the one non-zero row of its
#: column in :func:`biased_polar`'s ``d_terms``.  ``None`` for the time offset, which
#: moves the target along its path rather than the measurement.
TERM_ROWS: dict[str, int | None] = {
    "range_offset": 0,
    "range_gain": 0,
    "azimuth_bias": 1,
    "elevation_bias": 2,
    "time_offset": None,
    "azimuth_sin": 1,
    "azimuth_cos": 1,
}
assert tuple(TERM_ROWS) == TERM_NAMES

#: The additive terms: each adds itself to its coordinate, so its column of
#: :func:`biased_polar`'s ``d_terms`` is the unit vector of :data:`TERM_ROWS`.
ADDITIVE_TERMS: frozenset[str] = frozenset({"range_offset", "azimuth_bias", "elevation_bias"})


def biased_polar(true_polar: FloatArray, terms: FloatArray, free: tuple[str, ...] = ()
                 ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The bias model: the measurement of true polar coordinates, and its Jacobians.

    With ``(r, az, el)`` the true polar coordinates and ``(o, g, b, e, tau, s, c)``
    the terms of :data:`~graphcal.model.parameters.TERM_NAMES`::

        h(r, az, el) = ((1 + g) r + o,  az + b + s sin az + c cos az,  el + e)

    Its Jacobian in the true coordinates is diagonal::

        d h / d (r, az, el) = diag(1 + g,  1 + s cos az - c sin az,  1)

    and each column of its Jacobian in the terms has one non-zero row
    (:data:`TERM_ROWS`)::

        d h / d (o, g, b, e, tau, s, c) = (1, 0, 0), (r, 0, 0), (0, 1, 0), (0, 0, 1),
                                          (0, 0, 0), (0, sin az, 0), (0, cos az, 0)

    The time offset ``tau`` changes when the target is seen, not ``h``: its column
    here is 0, and the caller, who knows the target's motion, forms it (``slope``
    times the rate of the true coordinates, with the sign of the time shift).

    Parameters
    ----------
    true_polar : ndarray (n, 3)
        True ``(range_m, azimuth_rad, elevation_rad)`` (for a radar with refraction,
        the electrical range and the apparent elevation).
    terms : ndarray (7,)
        Every term of :data:`~graphcal.model.parameters.TERM_NAMES`: range offset [m],
        range gain [fraction], azimuth bias [rad], elevation bias [rad], time offset [s]
        (not used here), azimuth eccentricity ``s`` and ``c`` [rad].
    free : tuple of str
        The terms whose columns ``d_terms`` holds, in this order.

    Returns
    -------
    predicted : ndarray (n, 3)
        Measured ``(range_m, azimuth_rad, elevation_rad)``, azimuth not wrapped.
    slope : ndarray (n, 3)
        The diagonal of ``d predicted / d true_polar`` [m/m, rad/rad, rad/rad];
        read-only (one row repeated) when the eccentricity is zero.
    d_terms : ndarray (n, 3, len(free))
        ``d predicted / d term`` in ``free``'s order [m/m, m, rad/rad, rad/rad, -,
        rad/rad, rad/rad for the terms of ``TERM_NAMES``].

    The arrays are views of arrays laid out coordinate by coordinate, so that each
    coordinate's column (and each term's non-zero row) is contiguous.
    """
    offset, gain, az_bias, el_bias, _, s_ecc, c_ecc = np.asarray(terms, dtype=float).tolist()
    r_t, az_t, el_t = true_polar[:, 0], true_polar[:, 1], true_polar[:, 2]
    n = len(true_polar)
    eccentric = s_ecc != 0.0 or c_ecc != 0.0
    if eccentric or "azimuth_sin" in free or "azimuth_cos" in free:
        sin_az, cos_az = np.sin(az_t), np.cos(az_t)
    else:  # not used: no eccentricity, and neither of its terms is free
        sin_az = cos_az = az_t
    predicted = np.empty((3, n))
    np.multiply(r_t, 1.0 + gain, out=predicted[0])
    predicted[0] += offset
    np.add(az_t, az_bias, out=predicted[1])
    if eccentric:
        predicted[1] += s_ecc * sin_az
        predicted[1] += c_ecc * cos_az
    np.add(el_t, el_bias, out=predicted[2])
    if eccentric:
        slope = np.ones((3, n))
        slope[0] = 1.0 + gain
        slope[1] = 1.0 + s_ecc * cos_az - c_ecc * sin_az
        slope = slope.T
    else:  # every row the same: one row, repeated without copies (read-only)
        slope = np.ndarray((n, 3), buffer=np.array([1.0 + gain, 1.0, 1.0]), strides=(0, 8))
        slope.flags.writeable = False
    d_terms = np.zeros((3, len(free), n))
    for k, name in enumerate(free):
        row = TERM_ROWS[name]
        if row is None:
            continue
        if name in ADDITIVE_TERMS:
            d_terms[row, k] = 1.0
        elif name == "range_gain":
            d_terms[row, k] = r_t
        elif name == "azimuth_sin":
            d_terms[row, k] = sin_az
        else:  # azimuth_cos
            d_terms[row, k] = cos_az
    return predicted.T, slope, d_terms.transpose(2, 0, 1)


def corrected_polar(measured_polar: FloatArray, terms: FloatArray, free: tuple[str, ...] = ()
                    ) -> tuple[FloatArray, FloatArray]:
    """The inverse of :func:`biased_polar`: measured polar coordinates corrected for the
    biases, and the correction's Jacobian in the terms.

    With ``(r_m, az_m, el_m)`` the measured coordinates::

        r  = (r_m - o) / (1 + g)
        az : az + b + s sin az + c cos az = az_m     (wrapped to [0, 2 pi))
        el = el_m - e

    the azimuth by :func:`graphcal.data.bias.true_azimuth` (``az_m - b`` without
    eccentricity, Newton's method with it).  Differentiating ``h(true(z, beta), beta)
    = z`` in the terms ``beta`` (implicit function theorem), with ``slope``, the
    diagonal Jacobian of ``h`` in the true coordinates, and ``d_terms`` of
    :func:`biased_polar` at the corrected point::

        d true / d beta = -slope^-1 d_terms

    e.g. ``d r / d (o, g) = -(1, r) / (1 + g)`` and ``d az / d (b, s, c) =
    -(1, sin az, cos az) / (1 + s cos az - c sin az)``.

    Parameters
    ----------
    measured_polar : ndarray (n, 3)
        Measured ``(range_m, azimuth_rad, elevation_rad)``.
    terms : ndarray (7,)
        Every term of :data:`~graphcal.model.parameters.TERM_NAMES` (SI units).
    free : tuple of str
        The terms whose columns ``d_true`` holds, in this order.

    Returns
    -------
    true_polar : ndarray (n, 3)
        Corrected ``(range_m, azimuth_rad, elevation_rad)``, azimuth in ``[0, 2 pi)``.
    d_true : ndarray (n, 3, len(free))
        ``d true_polar / d term`` in ``free``'s order [m or rad per unit of the term].
    """
    offset, gain, az_bias, el_bias, _, s_ecc, c_ecc = np.asarray(terms, dtype=float).tolist()
    true = np.empty((3, len(measured_polar)))  # coordinate by coordinate; an (n, 3) view
    np.subtract(measured_polar[:, 0], offset, out=true[0])
    true[0] /= 1.0 + gain
    true[1] = true_azimuth(measured_polar[:, 1], RadarBias(
        azimuth_bias_rad=az_bias, azimuth_sin_rad=s_ecc, azimuth_cos_rad=c_ecc))
    np.subtract(measured_polar[:, 2], el_bias, out=true[2])
    d_true = np.zeros((len(measured_polar), 3, len(free)))
    if free:
        _, slope, d_terms = biased_polar(true.T, terms, free)
        # slope is diagonal and each column of d_terms has one non-zero row (TERM_ROWS):
        # the product's other entries are zeros.
        for k, name in enumerate(free):
            row = TERM_ROWS[name]
            if row is not None:
                d_true[:, row, k] = -d_terms[:, row, k] / slope[:, row]
    return true.T, d_true


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
        With ``(r, az, el)`` the true (refracted) polar coordinates and ``h`` the bias
        model of :func:`biased_polar`, whose Jacobian in ``(r, az, el)`` is the diagonal
        ``slope``::

            d h / d enu = diag(slope) d (r, az, el) / d enu

        and ``d h / d terms`` is :func:`biased_polar`'s.  The time offset's column is
        ``-(d h / d position) v``, the point's velocity times the position Jacobian,
        which the caller forms (it knows the velocity): here it is 0.

        Returns
        -------
        predicted : ndarray (n, 3)
            ``(range_m, azimuth_rad, elevation_rad)`` measured, azimuth not wrapped.
        d_enu : ndarray (n, 3, 3)
        d_terms : ndarray (n, 3, len(free))
            The free terms' columns, in ``free``'s order.
        """
        polar, jac_enu = self.enu_jacobian(enu_m)
        predicted, slope, d_terms = biased_polar(polar, terms, free)
        d_enu = slope[:, :, None] * jac_enu
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
    key, refracting = _covariance_key(site)
    if key not in al.derived:
        al.derived[key] = _reference_polar_covariance(al, refracting)
    return al.derived[key]


def _covariance_key(site: Site | None) -> tuple[str, Site | None]:
    """Where an alignment keeps its :func:`reference_polar_covariance`, and the site whose
    atmosphere it is computed along (``None``: straight lines of sight)."""
    if site is not None and site.atmosphere is not None:
        return "reference_polar_covariance refracted", site
    return "reference_polar_covariance", None


def _reference_polar_jacobian(al: AdsbAlignment, site: Site | None) -> FloatArray:
    """``d polar / d enu`` ``(n, 3, 3)`` at the ADS-B references (along refracted rays
    when ``site`` has an atmosphere)."""
    if site is not None and site.atmosphere is not None:
        jac = al.reference_polar_jacobian
        if jac is None:
            _, jac = measurement_model(site).enu_jacobian(site.enu_from_ecef(al.reference_ecef_m))
        return jac
    return frames.enu_to_polar_jacobian(frames.polar_to_enu(*al.reference_polar.T))


def _diagonal_enu_covariance(al: AdsbAlignment) -> FloatArray | None:
    """The ADS-B positions' ENU variances ``(n, 3)`` when their covariances are diagonal
    (as :func:`~graphcal.data.align.align_adsb` makes them), else ``None``."""
    cov = al.reference_enu_cov_m2
    if cov.ndim == 3 and cov.shape[1:] == (3, 3) and not np.any(
            cov[:, [0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]]):
        return np.diagonal(cov, axis1=1, axis2=2)
    return None


def _reference_polar_covariance(al: AdsbAlignment, site: Site | None) -> FloatArray:
    jac = _reference_polar_jacobian(al, site)
    diagonal = _diagonal_enu_covariance(al)
    if diagonal is not None:
        # jac @ cov is jac with its columns scaled, exactly, so one product is spared.
        return congruent_diagonal(jac, diagonal)
    cov = al.reference_enu_cov_m2
    return jac @ cov @ np.swapaxes(jac, -1, -2)


def polar_noise_variances(al: AdsbAlignment, site: Site) -> FloatArray:
    """The variances ``(n, 3)`` [m², rad²] of the aligned plots' residuals against ADS-B,
    coordinate by coordinate: the radar's own (:meth:`RadarMeasurementModel.covar`'s
    diagonal, 0 for a 2-D radar's elevation) plus the ADS-B position's in polar
    coordinates (the diagonal of :func:`reference_polar_covariance`, the same values;
    formed without its other entries when it has not been computed)."""
    key, refracting = _covariance_key(site)
    own = np.diagonal(measurement_model(site).covar(1)[0])
    diagonal = _diagonal_enu_covariance(al) if key not in al.derived else None
    if diagonal is None:  # computed already, or not diagonal in ENU
        return own + np.diagonal(reference_polar_covariance(al, site), axis1=1, axis2=2)
    return own + congruent_diagonal_variances(_reference_polar_jacobian(al, refracting),
                                              diagonal)


def residual_stats(site: Site, al: AdsbAlignment, bias: RadarBias) -> ResidualStats:
    """Polar residuals of one radar against ADS-B, before and after correction.

    Residual = corrected measurement minus ADS-B in the radar's polar
    coordinates; azimuth wrapped to [-pi, pi).  ``chi2_per_dof`` normalises the
    corrected residuals by the radar plus ADS-B noise.
    """
    model = measurement_model(site)
    measured = measured_polar(al)
    ref = al.reference_polar
    variances = polar_noise_variances(al, site)

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
            chi2 += float(np.sum(res**2 / variances[:, k]))
        return out, chi2

    before, _ = stats(RadarBias())
    after, chi2 = stats(bias)
    n_meas = len(al) * model.ndim_meas
    dof = max(n_meas - len(site.estimate), 1)
    return ResidualStats(n=len(al), before=before, after=after, chi2_per_dof=chi2 / dof)
