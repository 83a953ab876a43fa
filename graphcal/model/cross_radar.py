"""Cross-radar observations of paper 001 (no ADS-B needed).

For every pair of radars ``(a, b)`` that see the same aircraft, each plot
of ``b`` is paired with ``a``'s track interpolated to its time
(:func:`graphcal.data.align.pair_plots`).  Both are converted to ECEF with the
measured (biased) values; the difference is the observation of paper 001
eq. 8 (there with radar 1 as the reference; here every pair)::

    z_k = P_b Z_b(k) + Z_cr_b - (P_a Z_a(k) + Z_cr_a)          (eq. 8)
        = H_k X + M_k V(k)                                    (eq. 9)

with ``H_k = dz/dX`` at ``X = 0`` (the measured values), i.e. the
polar -> ECEF Jacobian times the bias Jacobian of each radar (``-`` for
``a``, ``+`` for ``b``; the ``a`` rows blend its two bracketing plots with
the interpolation weights), and ``M_k cov(V) M_k^T`` the converted
measurement covariance (paper 002).  A 2-D radar has no elevation: its plot
is placed at the reported (Mode C) height, and the range column includes
the change of elevation with range at that height; the height carries a
1-sigma error of :data:`ALTITUDE_SIGMA_M` in the covariance (without it two
2-D radars would compare heights they both took from the same report as if
they were exact); 2-D plots without an altitude are left out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.covariance import convert_covariance
from graphcal.core.refraction import (
    apparent_elevation_from_height_jacobian,
    target_from_refracted_jacobian,
)
from graphcal.data.align import (
    PlotArrays,
    PlotPairs,
    neighbour_plots,
    overlapping_pairs,
    pair_plots,
)
from graphcal.data.bias import ECCENTRICITY_NAMES, PARAMETER_NAMES
from graphcal.data.dataset import Dataset, Site
from graphcal.data.height import height_jacobian
from graphcal.model.measurement import RadarMeasurementModel, corrected_polar
from graphcal.model.parameters import TERM_NAMES, ParameterLayout

FloatArray = NDArray[np.float64]

#: Where :func:`cross_observations` evaluates the Jacobians.
LINEARISE_CHOICES: tuple[str, ...] = ("plots", "neighbours")
#: 1-sigma error [m] of a reported (Mode C) height used to place a 2-D radar's plot:
#: 25 ft quantisation plus barometric-versus-geometric height differences.
ALTITUDE_SIGMA_M = 30.0
#: 2-D plots above this elevation [rad] (70 deg) are not placed from their reported height.
MAX_2D_ELEVATION_RAD = np.deg2rad(70.0)


@dataclass
class ConvertedPlots:
    """Plots converted to ECEF with the Jacobian w.r.t. the radar's biases."""

    ecef_m: FloatArray  # (n, 3)
    bias_jacobian: FloatArray  # (n, 3, 4): d ecef / d (offset, gain, az, el)
    cov_m2: FloatArray  # (n, 3, 3): measurement noise in ECEF
    usable: NDArray[np.bool_]


def convert_plots(
    site: Site, plots: PlotArrays, linearise_at: PlotArrays | None = None,
    refraction: RayExcess | None = None,
) -> ConvertedPlots:
    """Measured plots -> ECEF with d(ECEF)/d(bias) and the converted noise covariance.

    For a 2-D radar the elevation comes from the reported height via
    :func:`graphcal.core.frames.elevation_from_height` and
    ``d el / d r = -(R_t^2 - R_r^2 + r^2) / (2 r^2 R_r cos el)`` enters the range
    column.  With ``linearise_at`` (e.g. :func:`graphcal.data.align.neighbour_plots`),
    the Jacobian and the covariance are evaluated there instead of at the plots.
    ``refraction``: the plots' :class:`RayExcess` traced at the measured plots, so
    that their rays are not traced again.
    """
    geometry = _plot_geometry(site, plots.range_m, plots.azimuth_rad, plots,
                              refraction=refraction)
    bias_jac = geometry.ecef_jacobian @ RadarMeasurementModel.bias_jacobian(plots.range_m)
    cov = geometry.cov_m2
    if linearise_at is not None:
        at = _plot_geometry(site, linearise_at.range_m, linearise_at.azimuth_rad, linearise_at)
        at_jac = at.ecef_jacobian @ RadarMeasurementModel.bias_jacobian(linearise_at.range_m)
        bias_jac = np.where(at.usable[:, None, None], at_jac, bias_jac)
        cov = np.where(at.usable[:, None, None], at.cov_m2, cov)
    if not site.is_3d:
        bias_jac[:, :, 3] = 0.0
    return ConvertedPlots(geometry.ecef_m, bias_jac, cov, geometry.usable)


def corrected_ecef(
    site: Site,
    plots: PlotArrays,
    bias: FloatArray,
    eccentricity: tuple[float, float] | None = None,
    height_model: tuple[float, float] | None = None,
    refraction: RayExcess | None = None,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Plots corrected by ``bias`` -> ECEF, with the Jacobian w.r.t. the bias.

    The correction is the inverse bias model
    (:func:`graphcal.model.measurement.corrected_polar`): ``r = (r_m - offset) /
    (1 + gain)``, ``az`` from ``az_m = az + az_bias + s sin(az) + c cos(az)``,
    ``el = el_m - el_bias`` (3-D), with its Jacobian in the terms ``d (r, az, el) /
    d terms = -slope^-1 d_terms`` of the forward model
    (:func:`graphcal.model.measurement.biased_polar`) at the corrected point; the
    plot is then placed at ``(r, az, el)`` and ``d ecef / d terms = (d ecef / d (r,
    az, el)) (d (r, az, el) / d terms)``.  A 2-D radar measures no elevation: its
    plot's elevation is that of the reported height at the corrected range, which
    ``d ecef / d r`` carries, so the elevation row of the correction's Jacobian is
    not used.

    With pressure altitudes, a 2-D plot is placed at the height ``h = (1 + k) p + d``
    of its reported pressure altitude ``p`` (``height_model = (d, k)``,
    :mod:`graphcal.data.height`), and ``d ecef / d (d, k) = (d ecef / d el)
    (d el / d h) (1, p)`` with ``d el / d h = R_t / (r R_r cos el)``.

    Parameters
    ----------
    site : Site
    plots : PlotArrays
    bias : ndarray (4,)
        ``(range_offset_m, range_gain, azimuth_bias_rad, elevation_bias_rad)``.
    eccentricity : (float, float), optional
        The azimuth eccentricity ``(s, c)`` [rad]; when given, the Jacobian gains
        its two columns.
    height_model : (float, float), optional
        ``(height_offset_m, height_scale)`` when ``plots.altitude_m`` is a pressure
        altitude; the Jacobian then gains two last columns (zero for a 3-D radar).
    refraction : RayExcess, optional
        :func:`ray_excess` of ``plots``, for a radar with refraction: the rays are
        then not traced again (iterative solvers call this at every step).

    Returns
    -------
    ecef_m : ndarray (n, 3)
    jacobian : ndarray (n, 3, 4), or (n, 3, 6) with ``eccentricity``, plus 2 with ``height_model``
        ``d ecef / d (bias[, s, c][, d, k])`` [m per unit of each term].
    usable : ndarray (n,) of bool
        False for 2-D plots without a reported height or 3-D plots without elevation.
    """
    terms = _terms(bias, eccentricity)
    free = PARAMETER_NAMES if eccentricity is None else (*PARAMETER_NAMES, *ECCENTRICITY_NAMES)
    true, d_polar = corrected_polar(_measured_polar(plots), terms, free)
    r, az = true[:, 0], true[:, 1]
    pressure_m = plots.altitude_m
    if height_model is not None and not site.is_3d:
        offset_m, scale = (float(v) for v in height_model)
        plots = replace(plots, altitude_m=(1.0 + scale) * pressure_m + offset_m)
    geometry = _plot_geometry(site, r, az, plots, true[:, 2] if site.is_3d else None,
                              refraction, covariance=False)
    if not site.is_3d:
        d_polar[:, 2, :] = 0.0  # the elevation follows the range, in ecef_jacobian
    jacobian = geometry.ecef_jacobian @ d_polar
    if height_model is not None:
        d_height = geometry.height_jacobian[:, :, None] * height_jacobian(
            np.nan_to_num(pressure_m))[:, None, :]
        jacobian = np.concatenate([jacobian, d_height], axis=2)
    return geometry.ecef_m, jacobian, geometry.usable


def _measured_polar(plots: PlotArrays) -> FloatArray:
    """The plots' measured ``(range_m, azimuth_rad, elevation_rad)`` ``(n, 3)``, held
    coordinate by coordinate (each column contiguous)."""
    return np.stack([plots.range_m, plots.azimuth_rad, plots.elevation_rad]).T


def _terms(bias: FloatArray, eccentricity: tuple[float, float] | None = None) -> FloatArray:
    """The full vector of :data:`~graphcal.model.parameters.TERM_NAMES` of the four
    biases and the eccentricity ``(s, c)`` (time offset 0: it does not move a plot)."""
    terms = np.zeros(len(TERM_NAMES))
    terms[:4] = bias
    if eccentricity is not None:
        terms[5:] = eccentricity
    return terms


@dataclass
class _Geometry:
    ecef_m: FloatArray  # (n, 3)
    ecef_jacobian: FloatArray  # (n, 3, 3) d ecef / d (r, az, el); 2-D: el follows r
    cov_m2: FloatArray | None  # (n, 3, 3) measurement noise in ECEF (None: not asked)
    usable: NDArray[np.bool_]
    height_jacobian: FloatArray  # (n, 3) d ecef / d reported height (2-D; 0 for 3-D)


def _plot_geometry(
    site: Site, r: FloatArray, az: FloatArray, plots: PlotArrays,
    elevation: FloatArray | None = None, refraction: RayExcess | None = None,
    covariance: bool = True,
) -> _Geometry:
    """ECEF position, d ecef / d polar and converted noise of plots at ``(r, az)``.

    ``elevation``: a 3-D radar's (corrected) elevations [rad]; by default as measured.

    With refraction (``site.atmosphere``), ``r`` is the electrical length and the
    elevation the apparent one: the plot is placed along the refracted ray
    (:func:`graphcal.core.refraction.target_from_refracted_jacobian`) and a 2-D
    plot's elevation comes from its height along it
    (:func:`graphcal.core.refraction.apparent_elevation_from_height_jacobian`).
    Given ``refraction`` (:func:`ray_excess` of these plots), the rays are not traced
    again: the straight-line placement plus the refracted ray's excess over it,
    linearised about the measured plots.  ``covariance=False`` leaves the converted
    noise out (``cov_m2`` is then ``None``): an iterative solver's residuals do not
    need it, and it is a third of the work.
    """
    if site.atmosphere is not None and refraction is None:
        return _refracted_plot_geometry(site, r, az, plots, elevation, covariance)
    n = len(r)
    cov_polar = np.zeros((n, 3, 3))
    cov_polar[:, 0, 0] = site.sigma_range_m**2
    cov_polar[:, 1, 1] = site.sigma_azimuth_rad**2
    if site.is_3d:
        el = plots.elevation_rad if elevation is None else elevation
        usable = np.isfinite(el)
        cov_polar[:, 2, 2] = site.sigma_elevation_rad**2
        d_el_d_r = np.zeros(n)
        d_el_d_h = np.zeros(n)
    else:
        el, d_el_d_r, d_el_d_h = _straight_elevation(site, r, plots.altitude_m)
        if refraction is not None:  # the refracted ray's excess, linearised
            step = np.stack([r - refraction.range_m,
                             np.nan_to_num(plots.altitude_m) - refraction.height_m], axis=1)
            el = el + refraction.elevation_excess_rad + np.einsum(
                "nj,nj->n", refraction.elevation_excess_jacobian, step)
            d_el_d_r = d_el_d_r + refraction.elevation_excess_jacobian[:, 0]
            d_el_d_h = d_el_d_h + refraction.elevation_excess_jacobian[:, 1]
        # Near the zenith (or where noise puts the reported height out of reach of
        # the slant range) the height says nothing usable about the elevation.
        with np.errstate(invalid="ignore"):
            usable = np.isfinite(el) & np.isfinite(plots.altitude_m) & (
                np.abs(el) < MAX_2D_ELEVATION_RAD
            )
        # The reported height's error enters through the elevation.
        cov_polar[:, 2, 2] = np.nan_to_num(d_el_d_h) ** 2 * ALTITUDE_SIGMA_M**2
    el = np.where(usable, el, 0.0)
    enu_jac = frames.polar_to_enu_jacobian(r, az, el)  # (n, 3, 3)
    if refraction is not None:
        enu, enu_jac = _add_ray_excess(refraction, r, az, el, enu_jac)
        usable = usable & refraction.usable
    if not site.is_3d:
        # Range moves the point along the slant direction and, at fixed height, in elevation.
        enu_jac = enu_jac.copy()
        enu_jac[:, :, 0] += enu_jac[:, :, 2] * np.nan_to_num(d_el_d_r)[:, None]
    rot = site.ecef_to_enu.T  # d ecef / d enu
    ecef_jac = rot @ enu_jac
    ecef = (site.ecef_from_polar(r, az, el) if refraction is None
            else site.ecef_from_enu(np.where(usable[:, None], enu, 0.0)))
    cov = convert_covariance(cov_polar, ecef_jac) if covariance else None
    # A reported height moves the plot in elevation, at fixed range and azimuth.
    d_ecef_d_h = ecef_jac[:, :, 2] * np.nan_to_num(d_el_d_h)[:, None]
    return _Geometry(ecef, ecef_jac, cov, usable, np.where(usable[:, None], d_ecef_d_h, 0.0))


def _straight_elevation(site: Site, r: FloatArray, height_m: FloatArray
                        ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Straight-line elevation of a reported height at slant range ``r`` and
    ``d el / d r = -(R_t^2 - R_r^2 + r^2) / (2 r^2 R_r cos el)``,
    ``d el / d h = R_t / (r R_r cos el)`` (:func:`graphcal.core.frames.elevation_from_height`)."""
    el = frames.elevation_from_height(r, height_m, site.lat_rad, site.alt_m)
    radius = float(frames.gaussian_radius_m(site.lat_rad))
    rt = radius + np.nan_to_num(height_m)
    rr = radius + site.alt_m
    with np.errstate(invalid="ignore", divide="ignore"):
        d_el_d_r = -(rt**2 - rr**2 + r**2) / (2.0 * r**2 * rr * np.cos(el))
        d_el_d_h = rt / (r * rr * np.cos(el))
    return el, d_el_d_r, d_el_d_h


@dataclass
class RayExcess:
    """The refracted rays' excess over straight lines at a set of plots, linearised.

    Refraction bends a ray in the vertical plane of its azimuth, so the refracted
    placement of a plot at electrical range ``L``, azimuth ``az`` and apparent
    elevation ``e`` is the straight-line one plus ``(g sin az, g cos az, u)`` with
    ``(g, u)`` the excess in ground distance and height of the ray, a smooth
    function of ``(L, e)`` only.  Bias corrections move ``(L, e)`` by at most a
    few hundred metres and milliradians, so ``(g, u)`` is taken to first order
    about the measured plots: ``(g, u) = (g0, u0) + G (dL, de)``.  Its neglected
    second-order term is measured (``tests/model/test_cross_radar.py``) at well
    under a centimetre for such corrections; the azimuth stays exact.  A 2-D
    plot's apparent elevation is likewise the straight-line elevation of its
    height plus an excess linear in ``(dL, dh)``.

    Attributes
    ----------
    range_m, height_m : ndarray (n,)
        The plots' measured range and reported height (0 for 3-D radars).
    elevation_rad : ndarray (n,)
        Their apparent elevation (3-D: measured; 2-D: of the reported height).
    plane_m : ndarray (n, 2)
        ``(g0, u0)`` [m].
    plane_jacobian : ndarray (n, 2, 2)
        ``d (g, u) / d (L, e)`` [m/m, m/rad].
    elevation_excess_rad : ndarray (n,)
        2-D: refracted minus straight-line elevation of the reported height (0 for 3-D).
    elevation_excess_jacobian : ndarray (n, 2)
        Its derivatives ``d / d (L, h)`` [rad/m].
    usable : ndarray (n,) of bool
        False where no ray reaches the plot.
    """

    range_m: FloatArray
    height_m: FloatArray
    elevation_rad: FloatArray
    plane_m: FloatArray
    plane_jacobian: FloatArray
    elevation_excess_rad: FloatArray
    elevation_excess_jacobian: FloatArray
    usable: NDArray[np.bool_]

    def subset(self, keep: NDArray) -> RayExcess:
        """The rows ``keep`` (a boolean mask or indices)."""
        return RayExcess(*(getattr(self, f)[keep] for f in (
            "range_m", "height_m", "elevation_rad", "plane_m", "plane_jacobian",
            "elevation_excess_rad", "elevation_excess_jacobian", "usable")))


def ray_excess(site: Site, plots: PlotArrays) -> RayExcess | None:
    """:class:`RayExcess` of ``plots`` as measured; ``None`` for a radar without refraction."""
    atmosphere = site.atmosphere
    if atmosphere is None:
        return None
    n = len(plots.range_m)
    r = np.where(np.isfinite(plots.range_m), plots.range_m, 0.0)
    excess = np.zeros(n)
    excess_jac = np.zeros((n, 2))
    height = np.zeros(n)
    if site.is_3d:
        el = np.nan_to_num(plots.elevation_rad)
    else:
        height = np.nan_to_num(plots.altitude_m)
        el, d_r, d_h = apparent_elevation_from_height_jacobian(
            atmosphere, site.lat_rad, site.alt_m, r, height)
        straight, s_r, s_h = _straight_elevation(site, r, height)
        excess = el - straight
        excess_jac = np.stack([d_r - s_r, d_h - s_h], axis=1)
        el = np.nan_to_num(el)
    zero = np.zeros(n)
    enu, jac = target_from_refracted_jacobian(atmosphere, site.lat_rad, site.alt_m, r, zero, el)
    straight_enu = frames.polar_to_enu(r, zero, el)
    straight_jac = frames.polar_to_enu_jacobian(r, zero, el)
    # At azimuth 0 the vertical plane is (north, up); columns (L, e) of d enu / d (L, az, e).
    plane = (enu - straight_enu)[:, 1:]
    plane_jac = (jac - straight_jac)[:, 1:, :][:, :, [0, 2]]
    usable = (np.all(np.isfinite(plane), axis=1) & np.all(np.isfinite(plane_jac), axis=(1, 2))
              & np.isfinite(excess) & np.all(np.isfinite(excess_jac), axis=1))
    return RayExcess(r, height, el, np.where(usable[:, None], plane, 0.0),
                     np.where(usable[:, None, None], plane_jac, 0.0),
                     np.where(usable, excess, 0.0), np.where(usable[:, None], excess_jac, 0.0),
                     usable)


#: How far [m] the corrected ranges (or a 2-D radar's heights) may move from where a
#: :class:`RayExcess` was traced before :func:`ray_excess_near` traces it again.
RAY_EXCESS_RANGE_TOLERANCE_M = 25.0
#: How far [rad] the corrected elevations may move (0.1 mrad: the linearisation's
#: error, which grows as the square of the step, stays under 3 mm up to 300 km).
RAY_EXCESS_ELEVATION_TOLERANCE_RAD = 1e-4


def _corrected_plots(site: Site, plots: PlotArrays, bias: FloatArray,
                     height_model: tuple[float, float] | None) -> PlotArrays:
    """``plots`` with the bias corrections that move a refracted ray: range, elevation
    (3-D; :func:`graphcal.model.measurement.corrected_polar`) and, with pressure
    altitudes, a 2-D radar's height."""
    true, _ = corrected_polar(_measured_polar(plots), _terms(bias))
    r = true[:, 0]
    if site.is_3d:
        return replace(plots, range_m=r, elevation_rad=true[:, 2])
    if height_model is not None:
        height_offset, scale = (float(v) for v in height_model)
        return replace(plots, range_m=r,
                       altitude_m=(1.0 + scale) * plots.altitude_m + height_offset)
    return replace(plots, range_m=r)


def _traced_near(excess: RayExcess, site: Site, corrected: PlotArrays) -> bool:
    """Whether every corrected plot is within the tolerances of where ``excess`` was traced."""
    near = np.abs(np.nan_to_num(corrected.range_m) - excess.range_m
                  ) <= RAY_EXCESS_RANGE_TOLERANCE_M
    if site.is_3d:
        near &= np.abs(np.nan_to_num(corrected.elevation_rad) - excess.elevation_rad
                       ) <= RAY_EXCESS_ELEVATION_TOLERANCE_RAD
    else:
        near &= np.abs(np.nan_to_num(corrected.altitude_m) - excess.height_m
                       ) <= RAY_EXCESS_RANGE_TOLERANCE_M
    return bool(near.all())


def ray_excess_near(
    excess: RayExcess | None, site: Site, plots: PlotArrays, bias: FloatArray,
    height_model: tuple[float, float] | None = None,
) -> RayExcess | None:
    """``excess`` when it was traced near the plots corrected by ``bias``, else traced again there.

    The linearised excess is exact at its centre and its error grows as the square of
    the distance from it (measured: 1 cm at 0.2 mrad and 7 cm at 0.5 mrad of elevation,
    300 km, N_s = 320), so an iterative solver keeps it centred on its current
    estimate within :data:`RAY_EXCESS_RANGE_TOLERANCE_M` and
    :data:`RAY_EXCESS_ELEVATION_TOLERANCE_RAD`; near convergence no ray is traced again.
    """
    if site.atmosphere is None:
        return None
    corrected = _corrected_plots(site, plots, bias, height_model)
    if excess is not None and _traced_near(excess, site, corrected):
        return excess
    return ray_excess(site, corrected)


def _rows_by_label(labels: NDArray[np.int64], order: NDArray[np.int64],
                   wanted: NDArray[np.int64]) -> tuple[NDArray[np.int64], bool]:
    """Positions in ``labels`` (sorted by ``order``) of the ``wanted`` labels, and whether
    all of them are there."""
    if not len(order):
        return np.zeros(len(wanted), dtype=np.int64), not len(wanted)
    found = np.searchsorted(labels, wanted, sorter=order)
    rows = order[np.minimum(found, len(order) - 1)]
    return rows, bool(np.all(labels[rows] == wanted))


class RayExcessCache:
    """One radar's :class:`RayExcess`, shared by every factor that places its plots.

    A radar's plot enters the pairwise factors of several partners; tracing its ray
    once per bias estimate for all of them, rather than once per factor, is what this
    is for.  It keeps the excess traced at the measured plots (for the noise
    conversion) and the one traced nearest the latest biases asked for
    (:func:`ray_excess_near`); :meth:`rows` maps dataset row labels to its rows.

    Parameters
    ----------
    site : Site
        A radar with refraction.
    plots : PlotArrays
        Every plot of it that a factor may use, any order.
    """

    def __init__(self, site: Site, plots: PlotArrays) -> None:
        self.site = site
        self.plots = plots
        self._order = np.argsort(plots.index, kind="stable")
        self._measured: RayExcess | None = None
        self._latest: RayExcess | None = None

    def covers(self, plots: PlotArrays) -> bool:
        """Whether every plot of ``plots`` (by row label) is in the cache."""
        return bool(len(self._order)) and _rows_by_label(self.plots.index, self._order,
                                                          plots.index)[1]

    def rows(self, index: NDArray[np.int64]) -> NDArray[np.int64]:
        """Positions in the cache of the plots with these dataset row labels."""
        return self._order[np.searchsorted(self.plots.index, index, sorter=self._order)]

    def measured(self) -> RayExcess:
        """The excess traced at the measured plots."""
        if self._measured is None:
            self._measured = ray_excess(self.site, self.plots)
        assert self._measured is not None
        return self._measured

    def near(self, bias: FloatArray, height_model: tuple[float, float] | None = None
             ) -> RayExcess:
        """The excess traced within tolerance of the plots corrected by ``bias``."""
        corrected = _corrected_plots(self.site, self.plots, bias, height_model)
        for excess in (self._latest, self._measured):
            if excess is not None and _traced_near(excess, self.site, corrected):
                return excess
        self._latest = ray_excess(self.site, corrected)
        assert self._latest is not None
        return self._latest


class CorrectedPlotsCache:
    """One radar's plots corrected by its biases (:func:`corrected_ecef`), computed once
    per bias value for every pairwise factor that uses them.

    In a network each radar pairs with several partners, and a solver evaluates every
    factor at the same values before it moves: without this each factor would convert
    its share of the radar's plots again.  The cache holds the union of the plots its
    factors use and the last result; a factor takes its rows (:meth:`rows`).  The
    result is the same as converting each factor's plots on its own (the conversion
    is plot by plot).

    Parameters
    ----------
    site : Site
        The radar.
    plots : PlotArrays
        Every plot of it that a factor uses, any order, each once.
    rays : RayExcessCache, optional
        The radar's refracted rays (a radar with an atmosphere), holding every plot
        of ``plots``.
    """

    def __init__(self, site: Site, plots: PlotArrays, rays: RayExcessCache | None = None
                 ) -> None:
        self.site = site
        self.plots = plots
        self.rays = rays
        self._order = np.argsort(plots.index, kind="stable")
        self._ray_rows = None if rays is None else rays.rows(plots.index)
        self._key: tuple | None = None
        self._value: tuple[FloatArray, FloatArray, NDArray[np.bool_]] | None = None

    def rows(self, index: NDArray[np.int64]) -> NDArray[np.int64]:
        """Positions in the cache of the plots with these dataset row labels.

        Raises
        ------
        ValueError
            If a label is not in the cache.
        """
        rows, found = _rows_by_label(self.plots.index, self._order, index)
        if not found:
            raise ValueError("plots missing from the radar's corrected-plot cache")
        return rows

    def corrected(self, bias: FloatArray, eccentricity: tuple[float, float] | None = None,
                  height_model: tuple[float, float] | None = None
                  ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
        """:func:`corrected_ecef` of every plot of the cache (the same arguments)."""
        key = (np.asarray(bias, dtype=float).tobytes(),
               None if eccentricity is None else tuple(float(v) for v in eccentricity),
               None if height_model is None else tuple(float(v) for v in height_model))
        if key != self._key or self._value is None:
            rays = (None if self.rays is None
                    else self.rays.near(bias, height_model).subset(self._ray_rows))
            self._value = corrected_ecef(self.site, self.plots, bias, eccentricity,
                                         height_model, rays)
            self._key = key
        return self._value


def _add_ray_excess(refraction: RayExcess, r: FloatArray, az: FloatArray, el: FloatArray,
                    straight_jac: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Straight-line ENU of ``(r, az, el)`` plus the linearised ray excess, and
    ``d enu / d (r, az, el)``."""
    step = np.stack([r - refraction.range_m, el - refraction.elevation_rad], axis=1)
    plane = refraction.plane_m + np.einsum("nij,nj->ni", refraction.plane_jacobian, step)
    sin_az, cos_az = np.sin(az), np.cos(az)
    enu = frames.polar_to_enu(r, az, el)
    enu[:, 0] += plane[:, 0] * sin_az
    enu[:, 1] += plane[:, 0] * cos_az
    enu[:, 2] += plane[:, 1]
    jac = straight_jac.copy()
    g_jac, u_jac = refraction.plane_jacobian[:, 0, :], refraction.plane_jacobian[:, 1, :]
    for column, k in ((0, 0), (2, 1)):
        jac[:, 0, column] += g_jac[:, k] * sin_az
        jac[:, 1, column] += g_jac[:, k] * cos_az
        jac[:, 2, column] += u_jac[:, k]
    jac[:, 0, 1] += plane[:, 0] * cos_az
    jac[:, 1, 1] -= plane[:, 0] * sin_az
    return enu, jac


def _refracted_plot_geometry(
    site: Site, r: FloatArray, az: FloatArray, plots: PlotArrays,
    elevation: FloatArray | None = None, covariance: bool = True,
) -> _Geometry:
    """:func:`_plot_geometry` along refracted rays (contract v2)."""
    atmosphere = site.atmosphere
    n = len(r)
    cov_polar = np.zeros((n, 3, 3))
    cov_polar[:, 0, 0] = site.sigma_range_m**2
    cov_polar[:, 1, 1] = site.sigma_azimuth_rad**2
    if site.is_3d:
        el = plots.elevation_rad if elevation is None else elevation
        usable = np.isfinite(el) & np.isfinite(r)
        cov_polar[:, 2, 2] = site.sigma_elevation_rad**2
        d_el_d_r = np.zeros(n)
        d_el_d_h = np.zeros(n)
    else:
        height = plots.altitude_m
        el, d_el_d_r, d_el_d_h = apparent_elevation_from_height_jacobian(
            atmosphere, site.lat_rad, site.alt_m, np.where(np.isfinite(r), r, 0.0),
            np.nan_to_num(height))
        with np.errstate(invalid="ignore"):
            usable = np.isfinite(el) & np.isfinite(height) & (np.abs(el) < MAX_2D_ELEVATION_RAD)
        cov_polar[:, 2, 2] = np.nan_to_num(d_el_d_h) ** 2 * ALTITUDE_SIGMA_M**2
    el = np.where(usable, el, 0.0)
    r_safe = np.where(usable, r, 0.0)
    enu, enu_jac = target_from_refracted_jacobian(atmosphere, site.lat_rad, site.alt_m, r_safe,
                                                  az, el)
    bad = ~np.all(np.isfinite(enu), axis=1) | ~np.all(np.isfinite(enu_jac), axis=(1, 2))
    usable = usable & ~bad
    enu = np.where(usable[:, None], enu, 0.0)
    enu_jac = np.where(usable[:, None, None], enu_jac, 0.0)
    if not site.is_3d:
        enu_jac[:, :, 0] += enu_jac[:, :, 2] * np.nan_to_num(d_el_d_r)[:, None]
    ecef_jac = site.ecef_to_enu.T @ enu_jac
    ecef = site.ecef_from_enu(enu)
    cov = convert_covariance(cov_polar, ecef_jac) if covariance else None
    # A reported height moves the plot in elevation, at fixed range and azimuth.
    d_ecef_d_h = ecef_jac[:, :, 2] * np.nan_to_num(d_el_d_h)[:, None]
    return _Geometry(ecef, ecef_jac, cov, usable, np.where(usable[:, None], d_ecef_d_h, 0.0))


@dataclass(frozen=True)
class PlotCovariances:
    """ECEF noise covariance [m^2] of plots, by plot-table row label.

    Attributes
    ----------
    labels : ndarray (n,) of int
        Row labels, sorted and unique.
    cov_m2 : ndarray (n, 3, 3)
        Each label's covariance.
    """

    labels: NDArray[np.int64]
    cov_m2: FloatArray

    @classmethod
    def collect(cls, labels: Sequence[NDArray[np.int64]], cov_m2: Sequence[FloatArray]
                ) -> PlotCovariances:
        """From parts (a label appearing in several parts has the same covariance in each)."""
        if not labels:
            return cls(np.zeros(0, np.int64), np.zeros((0, 3, 3)))
        every, first = np.unique(np.concatenate(labels), return_index=True)
        return cls(every, np.concatenate(cov_m2)[first])

    def of(self, labels: NDArray[np.int64]) -> FloatArray:
        """The covariances of ``labels`` (each must be known)."""
        at = np.searchsorted(self.labels, labels)
        if np.any(at >= len(self.labels)) or np.any(self.labels[np.minimum(
                at, len(self.labels) - 1)] != labels):
            raise KeyError("a plot label without a covariance")
        return self.cov_m2[at]


@dataclass
class CrossObservations:
    """Stacked paper-001 observations ``z_k = H_k X + noise`` for all radar pairs.

    Attributes
    ----------
    z : ndarray (m, 3)
        Position differences [m] (radar b minus radar a), ECEF.
    h : ndarray (m, 3, p)
        ``dz/dX`` over the layout's parameters.
    cov : ndarray (m, 3, 3)
        Converted measurement covariance of each ``z_k`` [m^2].
    time_s : ndarray (m,)
        Time of radar b's plot.
    pair : ndarray (m, 2) of int
        Radar indices (a, b) in the layout's radar order.
    n_plots : dict
        Plots of each radar that entered at least one observation.
    plot_rows : ndarray (m, 3) of int
        Row labels in ``dataset.plots`` of the plots behind ``z_k``: radar b's
        plot and radar a's two bracketing plots.
    plot_coefficients : ndarray (m, 3)
        ``z_k``'s noise is ``sum_j plot_coefficients[k, j] * e[plot_rows[k, j]]``
        with ``e`` a plot's ECEF noise: ``(1, -(1 - w), -w)``.
    plot_cov : PlotCovariances
        ECEF noise covariance [m^2] of each plot row used.
    """

    z: FloatArray
    h: FloatArray
    cov: FloatArray
    time_s: FloatArray
    pair: NDArray[np.int64]
    n_plots: dict[str, int]
    plot_rows: NDArray[np.int64]
    plot_coefficients: FloatArray
    plot_cov: PlotCovariances

    def subset(self, keep: NDArray[np.bool_]) -> CrossObservations:
        """The observations selected by ``keep``."""
        return CrossObservations(
            self.z[keep], self.h[keep], self.cov[keep], self.time_s[keep], self.pair[keep],
            self.n_plots, self.plot_rows[keep], self.plot_coefficients[keep], self.plot_cov,
        )

    def __len__(self) -> int:
        return len(self.z)


def cross_observations(
    dataset: Dataset,
    layout: ParameterLayout,
    max_gap_s: float | None = None,
    linearise: str = "plots",
) -> CrossObservations:
    """Build the paper-001 observations for every pair of radars ``a < b``.

    ``linearise="plots"`` evaluates ``H_k`` and the covariance at the measured
    plots, as the paper; ``"neighbours"`` at each plot's track neighbours
    (:func:`graphcal.data.align.neighbour_plots`), whose noise is independent of
    ``z_k``'s: the errors-in-variables bias of the paper's choice, which grows
    as ``sqrt(m)`` standard deviations along poorly observed directions, goes.
    """
    if linearise not in LINEARISE_CHOICES:
        raise ValueError(f"linearise must be one of {', '.join(LINEARISE_CHOICES)}, "
                         f"not '{linearise}'")
    radar_ids = list(dataset.radar_ids)
    p = len(layout)
    zs, hs, covs, times, pairs, rows, coefficients = [], [], [], [], [], [], []
    cov_labels: list[NDArray[np.int64]] = []
    cov_parts: list[FloatArray] = []
    used: dict[str, set[int]] = {rid: set() for rid in radar_ids}
    index_of = {rid: i for i, rid in enumerate(radar_ids)}
    for ra, rb in overlapping_pairs(dataset, radar_ids):
        ia, ib = index_of[ra], index_of[rb]
        pairs_ab = pair_plots(dataset, ra, rb, max_gap_s)
        if len(pairs_ab) == 0:
            continue
        z, h, cov, ok, conv_a, conv_b = _pair_rows(dataset, layout, pairs_ab,
                                                    linearise == "neighbours")
        if not np.any(ok):
            continue
        a_idx, b_idx = pairs_ab.a_plots.index, pairs_ab.b_plots.index
        i0, jb, w = pairs_ab.a_index0[ok], pairs_ab.b_index[ok], pairs_ab.weight[ok]
        rows.append(np.stack([b_idx[jb], a_idx[i0], a_idx[i0 + 1]], axis=1))
        coefficients.append(np.stack([np.ones_like(w), -(1.0 - w), -w], axis=1))
        cov_labels.extend([np.asarray(a_idx), np.asarray(b_idx)])
        cov_parts.extend([conv_a.cov_m2, conv_b.cov_m2])
        zs.append(z[ok])
        hs.append(h[ok])
        covs.append(cov[ok])
        times.append(pairs_ab.b_plots.time_s[pairs_ab.b_index[ok]])
        pairs.append(np.tile([ia, ib], (int(ok.sum()), 1)))
        used[ra].update(a_idx[pairs_ab.a_index0[ok]].tolist())
        used[ra].update(a_idx[pairs_ab.a_index0[ok] + 1].tolist())
        used[rb].update(pairs_ab.b_plots.index[pairs_ab.b_index[ok]].tolist())
    if not zs:
        return CrossObservations(
            np.zeros((0, 3)), np.zeros((0, 3, p)), np.zeros((0, 3, 3)), np.zeros(0),
            np.zeros((0, 2), np.int64), {rid: 0 for rid in radar_ids},
            np.zeros((0, 3), np.int64), np.zeros((0, 3)), PlotCovariances.collect([], []),
        )
    return CrossObservations(
        np.concatenate(zs), np.concatenate(hs), np.concatenate(covs), np.concatenate(times),
        np.concatenate(pairs), {rid: len(v) for rid, v in used.items()},
        np.concatenate(rows), np.concatenate(coefficients),
        PlotCovariances.collect(cov_labels, cov_parts),
    )


def shared_noise_middle(obs: CrossObservations) -> FloatArray:
    """``M = sum_plots G_p Sigma_p G_p^T`` with ``G_p = sum_k H_k^T Q_k c_kp``.

    A plot enters several observations (as radar b's plot of one pair, as a
    bracketing plot of another, with several other radars), so the ``z_k`` are
    correlated.  ``A^-1 M A^-1`` is the exact covariance of the linear WLS
    solution under that shared noise, where ``A^-1`` alone would be
    over-confident.
    """
    p = obs.h.shape[2]
    if len(obs) == 0:
        return np.zeros((p, p))
    ht_q = np.swapaxes(obs.h, 1, 2) @ np.linalg.inv(obs.cov)  # (m, p, 3)
    return gradient_noise_middle(ht_q, obs.plot_rows, obs.plot_coefficients, obs.plot_cov)


def gradient_noise_middle(
    ht_q: FloatArray,
    plot_rows: NDArray[np.int64],
    coefficients: FloatArray,
    plot_cov: PlotCovariances,
) -> FloatArray:
    """``sum_plots G_p Sigma_p G_p^T`` with ``G_p = sum_k c_kp (H_k^T Q_k)``.

    Parameters
    ----------
    ht_q : ndarray (m, p, 3)
        Each observation's ``H_k^T Q_k`` (times its weight, for a re-weighted fit).
    plot_rows : ndarray (m, j) of int
        Plot-table row labels of the plots behind each observation.
    coefficients : ndarray (m, j)
        Observation ``k``'s noise is ``sum_j coefficients[k, j] e[plot_rows[k, j]]``.
    plot_cov : PlotCovariances
        ECEF noise covariance [m^2] of each plot row label.
    """
    m, p = ht_q.shape[:2]
    labels, position = np.unique(plot_rows, return_inverse=True)
    position = position.reshape(plot_rows.shape)
    flat = ht_q.reshape(m, 3 * p)
    g = np.zeros((len(labels), 3 * p))
    for j in range(plot_rows.shape[1]):
        # Sum each plot's terms by one sort and np.add.reduceat (np.add.at is slow).
        used = np.flatnonzero(coefficients[:, j] != 0.0)
        if used.size == 0:
            continue
        used = used[np.argsort(position[used, j], kind="stable")]
        where = position[used, j]
        starts = np.flatnonzero(np.r_[True, where[1:] != where[:-1]])
        g[where[starts]] += np.add.reduceat(coefficients[used, j, None] * flat[used], starts,
                                            axis=0)
    g = g.reshape(len(labels), p, 3)
    cov = plot_cov.of(labels)
    gc = np.matmul(g, cov)  # (n, p, 3)
    return np.swapaxes(gc, 0, 1).reshape(p, -1) @ np.swapaxes(g, 0, 1).reshape(p, -1).T


def gradient_noise_middle_of_blocks(
    blocks: Sequence[tuple[Sequence[int], FloatArray, NDArray[np.int64], FloatArray]],
    plot_cov: PlotCovariances,
    p: int,
) -> FloatArray:
    """:func:`gradient_noise_middle` of observation blocks each on a few of ``p`` columns.

    ``blocks`` holds ``(columns, ht_q, plot_rows, coefficients)``: ``ht_q`` ``(m, k,
    3)`` over the block's own ``k`` columns (of the ``p``), ``plot_rows`` and
    ``coefficients`` ``(m, j)`` as in :func:`gradient_noise_middle`.  Each plot's
    terms are summed block by block over the block's columns only, the blocks' sums
    stacked side by side (``n_plots x sum k x 3``), and ``M`` assembled from one
    product of that stack: the work grows with the blocks' own columns, not with
    ``p`` times the observations (a network of 20 radars has ``p`` of about 100 and
    pairs of 12 columns).
    """
    middle = np.zeros((p, p))
    blocks = [b for b in blocks if len(b[1])]
    if not blocks:
        return middle
    labels = np.unique(np.concatenate([rows[coef != 0.0] for _, _, rows, coef in blocks]))
    widths = [len(cols) for cols, _, _, _ in blocks]
    offsets = np.concatenate([[0], np.cumsum(widths)])
    stack = np.zeros((len(labels), int(offsets[-1]), 3))
    for (_, ht_q, rows, coef), start, k in zip(blocks, offsets, widths, strict=False):
        flat = ht_q.reshape(len(ht_q), 3 * k)
        for j in range(rows.shape[1]):
            used = np.flatnonzero(coef[:, j] != 0.0)
            if used.size == 0:
                continue
            where = np.searchsorted(labels, rows[used, j])
            order = np.argsort(where, kind="stable")
            used, where = used[order], where[order]
            starts = np.flatnonzero(np.r_[True, where[1:] != where[:-1]])
            sums = np.add.reduceat(coef[used, j, None] * flat[used], starts, axis=0)
            stack[where[starts], start:start + k, :] += sums.reshape(-1, k, 3)
    weighted = np.matmul(stack, plot_cov.of(labels))  # (n, K, 3)
    total = int(offsets[-1])
    stacked = (np.swapaxes(weighted, 0, 1).reshape(total, -1)
               @ np.swapaxes(stack, 0, 1).reshape(total, -1).T)
    columns = np.concatenate([np.asarray(cols, dtype=np.int64) for cols, _, _, _ in blocks])
    np.add.at(middle, (columns[:, None], columns[None, :]), stacked)
    return middle


def _pair_rows(
    dataset: Dataset,
    layout: ParameterLayout,
    pairs: PlotPairs,
    instrumented: bool = False,
) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_], ConvertedPlots, ConvertedPlots]:
    site_a, site_b = dataset.sites[pairs.radar_a], dataset.sites[pairs.radar_b]
    at_a = neighbour_plots(pairs.a_plots) if instrumented else None
    at_b = neighbour_plots(pairs.b_plots) if instrumented else None
    conv_a = convert_plots(site_a, pairs.a_plots, at_a)
    conv_b = convert_plots(site_b, pairs.b_plots, at_b)
    i0, i1, w, ib = pairs.a_index0, pairs.a_index0 + 1, pairs.weight, pairs.b_index
    w0, w1 = (1.0 - w)[:, None], w[:, None]
    pos_a = w0 * conv_a.ecef_m[i0] + w1 * conv_a.ecef_m[i1]
    z = conv_b.ecef_m[ib] - pos_a
    m = len(ib)
    h = np.zeros((m, 3, len(layout)))
    cols_a, positions_a = layout.columns(pairs.radar_a)
    cols_b, positions_b = layout.columns(pairs.radar_b)
    jac_a = w0[:, :, None] * conv_a.bias_jacobian[i0] + w1[:, :, None] * conv_a.bias_jacobian[i1]
    h[:, :, cols_a] = -jac_a[:, :, positions_a]
    h[:, :, cols_b] = conv_b.bias_jacobian[ib][:, :, positions_b]
    w0c, w1c = (1.0 - w)[:, None, None], w[:, None, None]
    cov = conv_b.cov_m2[ib] + w0c**2 * conv_a.cov_m2[i0] + w1c**2 * conv_a.cov_m2[i1]
    ok = conv_b.usable[ib] & conv_a.usable[i0] & conv_a.usable[i1]
    return z, h, cov, ok, conv_a, conv_b
