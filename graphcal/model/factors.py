"""Vectorised factor error functions of the graph calibrator.

Each factor holds many measurements that share the same variables (all plots
of one radar matched to ADS-B; all plot pairs of two radars), so GTSAM calls
Python once per factor and iteration, not once per plot.  Every factor
exposes

* ``keys``: the GTSAM keys of its variables (radar bias vectors),
* ``dimension``: the length of its stacked error,
* ``error(values, want_jacobians)``: the stacked, whitened, robustified error
  and, when asked, its Jacobian blocks (one per key), the form
  :meth:`graphcal.solvers.gtsam_adapter.FactorGraph.add_custom` expects,
* ``whitened(values)``: the whitened residual ``(n, m)`` and Jacobians
  ``(n, m, k)`` before the robust kernel, for diagnostics.

A radar's variable holds only its *free* bias terms; :class:`RadarTerms`
expands it to the full ``(range_offset_m, range_gain, azimuth_bias_rad,
elevation_bias_rad)`` vector with fixed terms at their known values, and gives
the radar's time-stamping bias ``time_offset_s`` (a fifth term, free only when
time offsets are estimated).  Jacobians are ``(..., 5)`` over
:data:`TERM_NAMES` (factors that do not depend on the time offset may return
``(..., 4)``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.batched import cholesky_inverse
from graphcal.data.align import PlotArrays
from graphcal.data.dataset import Site
from graphcal.model.cross_radar import (
    CorrectedPlotsCache,
    RayExcessCache,
    convert_plots,
    corrected_ecef,
)
from graphcal.model.height import placeable_over_prior
from graphcal.model.measurement import ADDITIVE_TERMS, TERM_ROWS, biased_polar
from graphcal.model.parameters import TERM_NAMES, RadarTerms
from graphcal.model.robust import RobustKernel

FloatArray = NDArray[np.float64]

#: Columns of :data:`TERM_NAMES` that a plot's corrected position depends on: the four
#: biases and the eccentricity terms (:func:`~graphcal.model.cross_radar.corrected_ecef`).
SPATIAL: list[int] = [0, 1, 2, 3, 5, 6]


def whitening_matrices(cov: FloatArray) -> FloatArray:
    """``L^-1`` per measurement with ``L L^T = cov``, so ``||L^-1 r||^2 = r^T cov^-1 r``."""
    return cholesky_inverse(cov)


def _flatten(
    e: FloatArray, jacobians: list[FloatArray] | None
) -> tuple[FloatArray, list[FloatArray] | None]:
    flat = e.reshape(-1)
    if jacobians is None:
        return flat, None
    return flat, [j.reshape(flat.size, j.shape[-1]) for j in jacobians]


# --------------------------------------------------------------------------- ADS-B
@dataclass
class AdsbFactor:
    """All plots of one radar against the ADS-B position of their aircraft.

    Residual in the radar's measurement space, azimuth wrapped to ``[-pi, pi)``::

        e_i = z_i - h((r_i, az_i, el_i), beta)

    with ``h`` the bias model (:func:`~graphcal.model.measurement.biased_polar`:
    ``(1 + g) r + offset``, ``az + b_az + s sin az + c cos az``, ``el + b_el``),
    ``(r_i, az_i, el_i)`` the ADS-B position in the radar's polar frame
    and ``z_i`` the measured plot (2-D radars: range and azimuth only).  The
    noise is the radar's plus the ADS-B position noise mapped through the
    polar Jacobian (paper 002's first-order conversion, eq. 17-19), fixed at
    the ADS-B geometry.

    With a time-stamping bias ``tau`` the plot reported at ``t`` was made at
    ``t - tau``; the ADS-B reference, interpolated at ``t - tau0``, moves to
    ``reference + rate (tau0 - tau)`` (first order in ``tau - tau0``, which the
    graph keeps small by re-aligning ADS-B at its latest ``tau``), so
    ``d e / d tau = slope * rate = ((1 + g) dr/dt, (1 + s cos az - c sin az) daz/dt,
    del/dt)`` with ``slope`` the diagonal Jacobian of ``h`` in the polar coordinates.

    Attributes
    ----------
    measured, reference : ndarray (n, 3)
        Measured plot and ADS-B reference in polar coordinates [m, rad].
    whitening : ndarray (n, m, m)
        :func:`whitening_matrices` of the ``(n, m, m)`` noise covariance.
    plot_rows : ndarray (n,)
        Row labels of the plots in the dataset's plot table.
    rate : ndarray (n, 3) or None
        Time derivative of the reference in polar coordinates [m/s, rad/s].
    tau0 : float
        Time offset [s] at which the reference was interpolated.
    """

    terms: RadarTerms
    key: int
    measured: FloatArray
    reference: FloatArray
    whitening: FloatArray
    kernel: RobustKernel
    plot_rows: NDArray[np.int64]
    rate: FloatArray | None = None
    tau0: float = 0.0

    @property
    def keys(self) -> list[int]:
        return [self.key]

    @property
    def rows(self) -> int:
        """Measurement dimension ``m`` (2 or 3)."""
        return self.whitening.shape[1]

    @property
    def dimension(self) -> int:
        return len(self.measured) * self.rows

    def _residual_at(self, terms: FloatArray, free: tuple[str, ...]
                     ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Unwhitened residual ``(n, m)`` at ``terms`` (the full vector of
        :data:`TERM_NAMES`), and :func:`~graphcal.model.measurement.biased_polar`'s
        ``slope`` ``(n, 3)`` and ``d_terms`` ``(n, 3, len(free))`` at the reference (moved
        to the time offset ``terms[4]`` when there is a rate)."""
        reference = self.reference
        if self.rate is not None:
            reference = reference + self.rate * (self.tau0 - terms[4])
        predicted, slope, d_terms = biased_polar(reference, terms, free)
        measured = self.measured
        res = np.empty((len(predicted), self.rows))
        np.subtract(measured[:, 0], predicted[:, 0], out=res[:, 0])
        res[:, 1] = frames.wrap_to_pi(measured[:, 1] - predicted[:, 1])
        if self.rows == 3:
            np.subtract(measured[:, 2], predicted[:, 2], out=res[:, 2])
        return res, slope, d_terms

    def _time_column(self, slope: FloatArray) -> FloatArray:
        """``d e / d tau`` ``(n, m)``: the reference moves by ``-rate`` per unit of ``tau``,
        so the prediction by ``-slope * rate``."""
        assert self.rate is not None
        return (slope * self.rate)[:, :self.rows]

    def residual(
        self, bias: FloatArray, time_offset_s: float = 0.0,
        eccentricity: tuple[float, float] = (0.0, 0.0),
    ) -> tuple[FloatArray, FloatArray]:
        """Unwhitened residual ``(n, m)`` and its Jacobian ``(n, m, 7)`` (:data:`TERM_NAMES`).

        ``-d_terms`` of :func:`~graphcal.model.measurement.biased_polar` at the reference,
        with the time offset's column from the rate.  With an azimuth eccentricity
        ``(s, c)`` the predicted azimuth gains ``s sin(az) + c cos(az)`` at the reference
        azimuth ``az``.
        """
        terms = np.array([*bias, time_offset_s, *eccentricity], dtype=float)
        res, slope, d_terms = self._residual_at(terms, TERM_NAMES)
        jac = np.ascontiguousarray(-d_terms[:, :self.rows])
        if self.rate is not None:
            jac[:, :, TERM_NAMES.index("time_offset")] = self._time_column(slope)
        return res, jac

    def whitened(
        self, values: list[FloatArray], jacobians: bool = True
    ) -> tuple[FloatArray, list[FloatArray] | None]:
        """Whitened residual ``(n, m)`` and, with ``jacobians``, ``[(n, m, k)]`` over the free
        terms: ``W e`` and ``W J`` of :meth:`residual`.

        ``W J = -W d_terms`` (:func:`~graphcal.model.measurement.biased_polar`), plus the
        time offset's column ``W (slope * rate)``.  Only the free terms' columns are
        formed, each from the one row of ``d_terms`` where it is not zero
        (:data:`~graphcal.model.measurement.TERM_ROWS`): the column of ``W`` times that
        row's entry, the product's other terms being zeros; an additive term's entry is
        1 (:data:`~graphcal.model.measurement.ADDITIVE_TERMS`), its column ``-W``'s.
        """
        free = self.terms.free
        scaled = tuple(name for name in free if name not in ADDITIVE_TERMS
                       and TERM_ROWS[name] is not None) if jacobians else ()
        res, slope, d_terms = self._residual_at(self.terms.full_terms(values[0]), scaled)
        w = self.whitening
        e = np.einsum("nij,nj->ni", w, res)
        if not jacobians:
            return e, None
        m = self.rows
        jac = np.empty((len(res), m, len(free)))
        for k, name in enumerate(free):
            row = TERM_ROWS[name]
            if row is not None and row < m:
                if name in ADDITIVE_TERMS:
                    np.negative(w[:, :, row], out=jac[:, :, k])
                else:
                    entry = d_terms[:, row, scaled.index(name)]
                    np.multiply(w[:, :, row], -entry[:, None], out=jac[:, :, k])
            elif name == "time_offset" and self.rate is not None:
                jac[:, :, k] = np.einsum("nij,nj->ni", w, self._time_column(slope))
            else:  # a term the residual does not depend on (the time offset without a rate)
                jac[:, :, k] = 0.0
        return e, [jac]

    def error(
        self, values: list[FloatArray], want_jacobians: bool
    ) -> tuple[FloatArray, list[FloatArray] | None]:
        e, jac = self.whitened(values, want_jacobians)
        return _flatten(*self.kernel.apply(e, jac, in_place=True))  # arrays of this call


def adsb_factor(
    site: Site,
    terms: RadarTerms,
    key: int,
    plots: PlotArrays,
    reference_polar: FloatArray,
    reference_polar_cov: FloatArray,
    kernel: RobustKernel,
    reference_rate: FloatArray | None = None,
    tau0: float = 0.0,
) -> AdsbFactor:
    """Build the ADS-B factor of one radar.

    ``reference_polar_cov`` is the ADS-B position covariance mapped to the
    radar's polar coordinates ``(n, 3, 3)``; ``reference_rate`` the reference's
    time derivative in polar coordinates (needed when the time offset is free),
    interpolated at time offset ``tau0``.
    """
    m = 3 if site.is_3d else 2
    # Polar arrays held coordinate by coordinate (each column contiguous), as the
    # residual reads them.
    measured = np.stack([plots.range_m, plots.azimuth_rad, plots.elevation_rad]).T
    rate = None if reference_rate is None else np.asfortranarray(reference_rate)
    cov = reference_polar_cov[:, :m, :m].copy()
    sigmas = site.measurement_sigmas()[:m]
    cov[:, np.arange(m), np.arange(m)] += sigmas**2
    return AdsbFactor(
        terms, key, measured, np.asfortranarray(reference_polar), whitening_matrices(cov),
        kernel, plots.index.copy(), rate, float(tau0),
    )


# --------------------------------------------------------------------------- pairwise
@dataclass
class PairwiseFactor:
    """Paper 001's cross-radar differences for one radar pair, solved without linearising once.

    For pair ``k`` (radar b's plot ``ib[k]`` and radar a's two bracketing
    plots ``i0[k]``, ``i0[k] + 1`` with interpolation weight ``w``)::

        e_k = P_b(z_b, beta_b) - [(1 - w) P_a(z_a0, beta_a) + w P_a(z_a1, beta_a)]

    or, with a third plot ``i2[k]`` of a's track (``blend``: the quadratic weights
    of :class:`graphcal.data.align.PlotPairs`), ``e_k = P_b - sum_j c_j P_a(z_aj)``,
    which follows a turning aircraft where the straight chord cuts inside the turn.

    with ``P(z, beta)`` the plot corrected by the bias and converted to ECEF
    (:func:`graphcal.model.cross_radar.corrected_ecef`); paper 001 eq. 8
    evaluated exactly at every iteration rather than linearised at zero bias.
    The noise is both plots' converted covariance (paper 002), fixed at the
    measured values.

    Time-stamping biases ``tau_a``, ``tau_b``: the pairs were formed with
    ``b``'s times shifted by ``tau0_a - tau0_b``; a change of that difference
    moves ``a``'s interpolated position along its track,
    ``- v_a [(tau_a - tau_b) - (tau0_a - tau0_b)]`` with ``v_a`` the slope of
    ``a``'s bracketing segment.

    Pressure altitudes (``height_key`` set): the 2-D plots are placed at the
    height ``(1 + k) p + d`` of their pressure altitude ``p``, and the factor has a
    third variable, the height model ``(d, k)``
    (:func:`graphcal.model.cross_radar.corrected_ecef`).

    Refraction: the plots of a radar with an atmosphere are placed along their
    refracted rays through the radar's
    :class:`graphcal.model.cross_radar.RayExcessCache`, shared with its other pairs
    and traced again only when the biases move the corrected plots beyond its
    tolerance, not at every iteration.
    """

    terms_a: RadarTerms
    terms_b: RadarTerms
    key_a: int
    key_b: int
    site_a: Site
    site_b: Site
    a_plots: PlotArrays
    b_plots: PlotArrays
    i0: NDArray[np.int64]
    weight: FloatArray
    ib: NDArray[np.int64]
    whitening: FloatArray
    a_cov_m2: FloatArray
    b_cov_m2: FloatArray
    kernel: RobustKernel
    tau0_a: float = 0.0
    tau0_b: float = 0.0
    height_key: int | None = None
    a_rays: RayExcessCache | None = None
    b_rays: RayExcessCache | None = None
    a_rows: NDArray[np.int64] | None = None  # rows of a_plots in a_rays
    b_rows: NDArray[np.int64] | None = None
    i2: NDArray[np.int64] | None = None  # third plot of a (quadratic), a valid index
    blend: FloatArray | None = None  # (n, 3) weights of a's plots i0, i0 + 1, i2
    a_shared: CorrectedPlotsCache | None = None  # the radar's plots, corrected once
    b_shared: CorrectedPlotsCache | None = None  # for all its factors (share_corrections)
    a_shared_rows: NDArray[np.int64] | None = None  # rows of a_plots in a_shared
    b_shared_rows: NDArray[np.int64] | None = None

    def _a_weights(self) -> tuple[list[NDArray[np.int64]], FloatArray]:
        """a's plots behind each pair and their weights ``(n, 3)`` (linear: third 0)."""
        if self.blend is None or self.i2 is None:
            w = self.weight
            return [self.i0, self.i0 + 1, self.i0], np.stack(
                [1.0 - w, w, np.zeros_like(w)], axis=1)
        return [self.i0, self.i0 + 1, self.i2], self.blend

    @property
    def keys(self) -> list[int]:
        if self.height_key is not None:
            return [self.key_a, self.key_b, self.height_key]
        return [self.key_a, self.key_b]

    @property
    def dimension(self) -> int:
        return 3 * len(self.ib)

    def __len__(self) -> int:
        return len(self.ib)

    def residual(
        self, bias_a: FloatArray, bias_b: FloatArray, tau_a: float = 0.0, tau_b: float = 0.0,
        ecc_a: tuple[float, float] = (0.0, 0.0), ecc_b: tuple[float, float] = (0.0, 0.0),
        height: tuple[float, float] | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Unwhitened residual ``(n, 3)`` [m] and its Jacobians ``(n, 3, 7)`` for a and b
        (:data:`TERM_NAMES`; ``ecc_a``, ``ecc_b``: the radars' azimuth eccentricities).

        ``height``: the height model ``(d, k)`` of pressure altitudes; each Jacobian
        then has two more columns, the residual's dependence on ``(d, k)`` through
        that radar's plots (their sum is ``d e / d (d, k)``).
        """
        ecef_a, jac_a = self._corrected("a", bias_a, ecc_a, height)
        ecef_b, jac_b = self._corrected("b", bias_b, ecc_b, height)
        rows, c = self._a_weights()
        i0, i1 = self.i0, self.i0 + 1
        res = ecef_b[self.ib] - sum(c[:, j, None] * ecef_a[r] for j, r in enumerate(rows))
        n = len(self.ib)
        columns = len(TERM_NAMES) + (0 if height is None else 2)
        d_a = np.zeros((n, 3, columns))
        d_b = np.zeros((n, 3, columns))
        own = [*SPATIAL, *range(len(TERM_NAMES), columns)]  # jac_a's columns in d_a
        d_a[:, :, own] = -sum(c[:, j, None, None] * jac_a[r] for j, r in enumerate(rows))
        d_b[:, :, own] = jac_b[self.ib]
        dt = (self.a_plots.time_s[i1] - self.a_plots.time_s[i0])[:, None]
        dt = np.where(dt > 0.0, dt, np.inf)  # two plots at one time: no velocity
        velocity = (ecef_a[i1] - ecef_a[i0]) / dt
        shift = (tau_a - tau_b) - (self.tau0_a - self.tau0_b)
        if shift != 0.0:
            res = res - velocity * shift
            d_a[:, :, own] -= shift * (jac_a[i1] - jac_a[i0]) / dt[:, :, None]
        d_a[:, :, 4] = -velocity
        d_b[:, :, 4] = velocity
        return res, d_a, d_b

    def _corrected(self, side: str, bias: FloatArray, eccentricity: tuple[float, float],
                   height: tuple[float, float] | None) -> tuple[FloatArray, FloatArray]:
        """Side ``a`` or ``b``'s plots corrected by ``bias``, in ECEF, and the Jacobian."""
        shared = getattr(self, f"{side}_shared")
        if shared is not None:
            ecef, jacobian, _ = shared.corrected(bias, eccentricity, height)
            rows = getattr(self, f"{side}_shared_rows")
            return ecef[rows], jacobian[rows]
        rays_cache = getattr(self, f"{side}_rays")
        rays = (None if rays_cache is None
                else rays_cache.near(bias, height).subset(getattr(self, f"{side}_rows")))
        ecef, jacobian, _ = corrected_ecef(getattr(self, f"site_{side}"),
                                           getattr(self, f"{side}_plots"), bias, eccentricity,
                                           height, rays)
        return ecef, jacobian

    def whitened(self, values: list[FloatArray]) -> tuple[FloatArray, list[FloatArray]]:
        ta, tb = self.terms_a, self.terms_b
        height = None if self.height_key is None else (float(values[2][0]), float(values[2][1]))
        res, d_a, d_b = self.residual(
            ta.full(values[0]), tb.full(values[1]),
            ta.time_offset(values[0]), tb.time_offset(values[1]),
            ta.eccentricity(values[0]), tb.eccentricity(values[1]), height,
        )
        e = np.einsum("nij,nj->ni", self.whitening, res)
        n_terms = len(TERM_NAMES)
        jac_a = self.whitening @ self.terms_a.select(d_a[..., :n_terms])
        jacobians = [jac_a, self.whitening @ self.terms_b.select(d_b[..., :n_terms])]
        if height is not None:
            jacobians.append(self.whitening @ (d_a[..., n_terms:] + d_b[..., n_terms:]))
        return e, jacobians

    def error(
        self, values: list[FloatArray], want_jacobians: bool
    ) -> tuple[FloatArray, list[FloatArray] | None]:
        e, jac = self.whitened(values)
        return _flatten(*self.kernel.apply(e, jac if want_jacobians else None))

    def plot_noise(self) -> tuple[NDArray[np.int64], FloatArray]:
        """For the shared-noise sandwich: per pair, the plots behind it and their coefficients.

        Returns ``(positions (n, 4), coefficients (n, 4))`` with positions
        indexing the concatenation ``[a_plots, b_plots]`` and the residual
        noise ``sum_j c_j e_j`` of the plots' ECEF noise ``e_j`` (the third of a's
        plots has coefficient 0 for a linear pair).
        """
        na = len(self.a_plots)
        rows, c = self._a_weights()
        positions = np.stack([self.ib + na, *rows], axis=1)
        coefficients = np.column_stack([np.ones(len(c)), -c])
        return positions, coefficients


def pairwise_factor(
    site_a: Site,
    site_b: Site,
    terms_a: RadarTerms,
    terms_b: RadarTerms,
    key_a: int,
    key_b: int,
    a_plots: PlotArrays,
    b_plots: PlotArrays,
    i0: NDArray[np.int64],
    weight: FloatArray,
    ib: NDArray[np.int64],
    kernel: RobustKernel,
    tau0_a: float = 0.0,
    tau0_b: float = 0.0,
    height_key: int | None = None,
    a_rays: RayExcessCache | None = None,
    b_rays: RayExcessCache | None = None,
    i2: NDArray[np.int64] | None = None,
    quadratic_weights: FloatArray | None = None,
) -> PairwiseFactor | None:
    """Build the pairwise factor from :func:`graphcal.data.align.pair_plots` indices.

    Only the plots that enter a pair are kept; pairs with an unusable plot (a
    2-D plot without reported height) are dropped.  ``None`` when nothing is left.
    ``tau0_a``, ``tau0_b``: the time offsets [s] the pairs were formed with;
    ``height_key``: the height-model variable, for pairs with a 2-D radar whose
    plots carry pressure altitudes (the noise is converted at the reported heights);
    ``a_rays``, ``b_rays``: the radars' shared refracted rays, when they refract
    (made here for the factor alone when not given); ``i2``, ``quadratic_weights``:
    the third plot of a's track and the quadratic weights
    (:class:`graphcal.data.align.PlotPairs`; a pair whose third plot is unusable is
    interpolated linearly).
    """
    quadratic = i2 is not None and quadratic_weights is not None
    if not quadratic:
        i2 = np.full(len(i0), -1, dtype=np.int64)
        quadratic_weights = np.stack([1.0 - weight, weight, np.zeros_like(weight)], axis=1)
    assert i2 is not None and quadratic_weights is not None
    used_a = np.unique(np.concatenate([i0, i0 + 1, i2[i2 >= 0]]))
    used_b = np.unique(ib)
    a_sub = a_plots.subset(used_a)
    b_sub = b_plots.subset(used_b)
    i0 = np.searchsorted(used_a, i0)
    has_third = i2 >= 0
    i2 = np.where(has_third, np.searchsorted(used_a, np.maximum(i2, 0)), i0)
    ib = np.searchsorted(used_b, ib)
    a_rays = _rays_for(site_a, a_plots, a_rays)
    b_rays = _rays_for(site_b, b_plots, b_rays)
    a_rows = None if a_rays is None else a_rays.rows(a_sub.index)
    b_rows = None if b_rays is None else b_rays.rows(b_sub.index)
    conv_a = convert_plots(site_a, a_sub, refraction=None if a_rays is None
                           else a_rays.measured().subset(a_rows))
    conv_b = convert_plots(site_b, b_sub, refraction=None if b_rays is None
                           else b_rays.measured().subset(b_rows))
    ok = conv_b.usable[ib] & conv_a.usable[i0] & conv_a.usable[i0 + 1]
    if height_key is not None:  # pressure altitudes: the heights move with the model
        placeable_a = placeable_over_prior(site_a, a_sub)
        ok &= placeable_over_prior(site_b, b_sub)[ib] & placeable_a[i0] & placeable_a[i0 + 1]
    # used_a holds both bracketing plots and the third outside them, so i0 + 1 is
    # still the later bracketing plot.
    if not np.any(ok):
        return None
    third_ok = has_third & conv_a.usable[i2]
    if height_key is not None:
        third_ok &= placeable_a[i2]
    linear = np.stack([1.0 - weight, weight, np.zeros_like(weight)], axis=1)
    blend = np.where(third_ok[:, None], quadratic_weights, linear)[ok]
    i0, ib, weight, i2 = i0[ok], ib[ok], weight[ok], np.where(third_ok, i2, i0)[ok]
    cov = conv_b.cov_m2[ib] + sum(
        blend[:, j, None, None] ** 2 * conv_a.cov_m2[r] for j, r in enumerate((i0, i0 + 1, i2)))
    return PairwiseFactor(
        terms_a, terms_b, key_a, key_b, site_a, site_b, a_sub, b_sub, i0, weight, ib,
        whitening_matrices(cov), conv_a.cov_m2, conv_b.cov_m2, kernel, float(tau0_a),
        float(tau0_b), height_key, a_rays, b_rays, a_rows, b_rows,
        i2 if quadratic else None, blend if quadratic else None,
    )


def share_corrections(factors: list[PairwiseFactor]) -> None:
    """Give the factors of each radar that enters two or more of them one
    :class:`~graphcal.model.cross_radar.CorrectedPlotsCache` of its plots.

    A radar's plots are then corrected once per bias value for all its pairs instead
    of once per pair; the residuals are the same.  A radar whose factors place its
    plots through different ray caches is left as it is.
    """
    sides: dict[str, list[tuple[PairwiseFactor, str]]] = {}
    for factor in factors:
        sides.setdefault(factor.terms_a.radar_id, []).append((factor, "a"))
        sides.setdefault(factor.terms_b.radar_id, []).append((factor, "b"))
    for entries in sides.values():
        if len(entries) < 2:
            continue
        rays = {id(getattr(f, f"{side}_rays")) for f, side in entries}
        if len(rays) > 1:
            continue
        parts = [getattr(f, f"{side}_plots") for f, side in entries]
        union = PlotArrays(*(np.concatenate([getattr(p, name) for p in parts])
                             for name in PlotArrays.__dataclass_fields__))
        _, first = np.unique(union.index, return_index=True)
        first_factor, first_side = entries[0]
        cache = CorrectedPlotsCache(getattr(first_factor, f"site_{first_side}"),
                                    union.subset(first),
                                    getattr(first_factor, f"{first_side}_rays"))
        for factor, side in entries:
            setattr(factor, f"{side}_shared", cache)
            setattr(factor, f"{side}_shared_rows",
                    cache.rows(getattr(factor, f"{side}_plots").index))


def _rays_for(site: Site, plots: PlotArrays, rays: RayExcessCache | None
              ) -> RayExcessCache | None:
    """``rays`` when it holds ``plots``; a new cache of them for a refracting radar; else None."""
    if site.atmosphere is None:
        return None
    if rays is not None and rays.covers(plots):
        return rays
    return RayExcessCache(site, plots)
