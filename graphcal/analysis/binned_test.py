"""Binned means of residuals and a chi-square test of their structure.

One test takes residuals ``e_k`` of one measured coordinate, their expected
variances ``v_k``, a variable ``x_k`` to bin them by (range, azimuth, time, ...)
and the *segment* each belongs to (one aircraft's track cut into pieces of about
a minute), and asks: do the bin means vary with ``x`` more than chance allows,
beyond what the model's own terms (the regressors ``X``, e.g. ones for an
offset and the range for a gain) can absorb?

**Terms.**  The regressors are fitted to all the residuals once
(:func:`fit_terms`, weights ``w_k = 1 / v_k``): ``beta = A X^T W e`` with
``A = (X^T W X)^-1``; the corrected residuals are ``e - X beta``.

**Bins** hold roughly equal counts (quantiles of ``x``); bins with fewer than
:data:`MIN_BIN_PLOTS` plots or :data:`MIN_BIN_SEGMENTS` segments are dropped.
Bin mean ``m_b = sum w_k e_k / W_b`` (``W_b = sum w_k`` over the bin); its
*excess* is the same mean of the corrected residuals, ``m_b`` less what the
terms absorb.

**Noise model.**  The residuals of one aircraft are correlated (the ADS-B error
is smooth over tens of seconds; so are multipath and the track's geometry), so
the plots of a bin are not independent.  The model: ``e_k = s_k eps_k`` with
``s_k^2 = phi_b v_k`` (``phi_b`` rescales the expected variances, estimated per
bin from the scatter of the corrected residuals about their bin mean) and the
``eps`` of one segment sharing a correlation ``rho`` (exchangeable within the
segment, 0 between segments).  For statistics ``a = sum alpha_k e_k`` and
``b = sum beta_k e_k``::

    cov(a, b) = (1 - rho) sum_k alpha_k beta_k s_k^2
                + rho sum_segments (sum_k alpha_k s_k)(sum_k beta_k s_k)

``rho`` is the method-of-moments estimate over the pieces ``u`` of segments in
bins: ``E[Y_u^2] = n_u + rho n_u (n_u - 1)`` for ``Y_u`` the sum of the piece's
``n_u`` standardised deviations, less what taking out the bin mean removes
(see ``_segment_correlation`` in the source), clipped to ``[0, MAX_RHO]``.  The
segments are thus the independent units, as in a cluster-robust variance, with
``rho`` pooled over all bins so that a bin with few segments still has a well
determined variance.  ``sigma_b`` is the 1-sigma of ``m_b``; the covariance
``C`` of the excesses (linear in ``e``: the bin means less the fitted terms'
bin means) follows from the same formula, cross-bin terms and the fit included.

**The test**::

    chi2 = sum_b excess_b^2 / sigma_b^2

Without structure it is ``sum_i lambda_i chi2_1`` with ``lambda`` the
eigenvalues of ``D^-1/2 C D^-1/2`` (``D = diag sigma^2``): about one per bin,
less where the fitted terms take a share.  The effective degrees of freedom
``dof = sum lambda`` (the expected ``chi2``), and ``p`` is the Satterthwaite
approximation ``chi2 ~ g chi2_h`` (``g = sum lambda^2 / sum lambda``,
``h = dof / g``).  ``benchmarks/model_checks_study.py`` measures how closely
the p-values follow the uniform law on data without structure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pandas as pd
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Bins per test (roughly equal counts), when the plots allow.
N_BINS = 10
#: Fewest plots in a bin for it to enter a test.
MIN_BIN_PLOTS = 40
#: Fewest segments (independent units) in a bin for it to enter a test.
MIN_BIN_SEGMENTS = 4
#: Fewest degrees of freedom left for a test to be made.
MIN_DOF = 2
#: Largest within-segment correlation accepted from the moment estimate.
MAX_RHO = 0.95


@dataclass
class BinnedMeans:
    """Bin means of one coordinate's residuals against one variable, and their test.

    Attributes
    ----------
    centre : ndarray (K,)
        Mean of the variable in each bin (the variable's unit).
    lower, upper : ndarray (K,)
        Smallest and largest value of the variable in each bin.
    n_plots, n_segments : ndarray (K,) of int
        Plots and segment pieces in each bin.
    mean : ndarray (K,)
        Weighted mean residual per bin (the residual's unit).
    sigma : ndarray (K,)
        1-sigma of that mean (segment-correlated scatter, see the module doc).
    absorbed : ndarray (K,)
        The part of the bin means the regressors (the model's own terms) explain.
    chi2 : float
        Chi-square of ``mean - absorbed`` against ``sigma``.
    dof : float
        Effective degrees of freedom: the expected ``chi2`` without structure
        (``K`` less what the fitted terms take, see the module doc).
    p_value : float
        ``P(chi2_dof > chi2)``.
    log10_p : float
        ``log10`` of the p-value (finite where ``p_value`` underflows to 0).
    rho : float
        Within-segment correlation of the standardised residuals (pooled).
    """

    centre: FloatArray
    lower: FloatArray
    upper: FloatArray
    n_plots: IntArray
    n_segments: IntArray
    mean: FloatArray
    sigma: FloatArray
    absorbed: FloatArray
    chi2: float
    dof: float
    p_value: float
    log10_p: float
    rho: float

    @property
    def excess(self) -> FloatArray:
        """``mean - absorbed``: the structure the model's terms do not explain."""
        return self.mean - self.absorbed

    def __len__(self) -> int:
        return len(self.mean)


def quantile_bins(x: FloatArray, n_bins: int) -> IntArray:
    """Bin index ``0 .. n_bins - 1`` of each value, bins of roughly equal counts.

    Ties are kept in one bin, so bins can be uneven (or empty) where values repeat.
    """
    if n_bins < 1:
        raise ValueError("n_bins must be at least 1")
    inner = np.quantile(x, np.linspace(0.0, 1.0, n_bins + 1)[1:-1])
    return np.searchsorted(inner, x, side="right").astype(np.int64)


def plot_bins(x: FloatArray, rows: NDArray[np.bool_], n_bins: int = N_BINS
              ) -> IntArray | None:
    """Each plot's quantile bin of ``x`` (:func:`quantile_bins`), ``-1`` outside ``rows``.

    Only the plots of ``rows`` with a finite ``x`` are binned, into
    ``min(n_bins, count // MIN_BIN_PLOTS)`` bins; ``None`` when that leaves fewer
    than ``MIN_DOF + 1`` bins.  The bins depend on ``x`` and ``rows`` alone, so the
    tests of several coordinates binned by one variable can share them
    (``binned_test(..., bins=...)``).
    """
    x = np.asarray(x, dtype=float)
    ok = np.asarray(rows, dtype=bool) & np.isfinite(x)
    k = min(n_bins, int(ok.sum()) // MIN_BIN_PLOTS)
    if k < MIN_DOF + 1:
        return None
    bins = np.full(len(x), -1, dtype=np.int64)
    bins[ok] = quantile_bins(x[ok], k)
    return bins


def segment_codes(target: NDArray, time_s: FloatArray, segment_s: float) -> IntArray:
    """Segment number of each plot: its aircraft and ``floor((t - t_first) / segment_s)``.

    Plots of an unknown aircraft (empty or missing ``target``) each form their own
    segment.
    """
    codes, names = pd.factorize(target if isinstance(target, pd.Series) else np.asarray(target),
                                sort=False)
    codes = np.asarray(codes, dtype=np.int64)
    empty = np.flatnonzero(np.asarray(names, dtype=object) == "")
    unknown = (codes < 0) | (np.isin(codes, empty) if len(empty) else False)
    first = pd.Series(time_s).groupby(codes).transform("min").to_numpy(float)
    piece = np.floor((time_s - first) / segment_s).astype(np.int64)
    key = codes * (int(piece.max(initial=0)) + 1) + piece
    key = np.where(unknown, -1 - np.arange(len(key)), key)
    return pd.factorize(key)[0].astype(np.int64)


@dataclass
class TermsFit:
    """The model's own terms fitted to one coordinate's residuals over all plots.

    Weighted least squares of the residuals on the regressors (weights ``1 / v``),
    the same for every variable the residuals are then binned by.

    Attributes
    ----------
    regressors : ndarray (n, p)
        Zero on the rows left out of the fit.
    coefficients : ndarray (p,)
    normal_inverse : ndarray (p, p)
        ``(X^T W X)^-1`` (pseudo-inverse where the terms are degenerate).
    rows : ndarray (n,) of bool
        The residuals fitted (finite, with finite regressors).
    """

    regressors: FloatArray
    coefficients: FloatArray
    normal_inverse: FloatArray
    rows: NDArray[np.bool_]

    @cached_property
    def fitted(self) -> FloatArray:
        """What the terms explain, per plot (kept: the same for every test of the residuals)."""
        return self.regressors @ self.coefficients

    @cached_property
    def fitted_rows(self) -> IntArray:
        """Positions of :attr:`rows` (kept)."""
        return np.flatnonzero(self.rows)

    @cached_property
    def fitted_regressors(self) -> FloatArray:
        """The regressors of :attr:`fitted_rows` (kept)."""
        return self.regressors[self.fitted_rows]


def weights(variance: FloatArray) -> FloatArray:
    """``1 / variance``; equal weights where a variance is not positive and finite."""
    v = np.asarray(variance, dtype=float)
    good = np.isfinite(v) & (v > 0)
    if good.all():
        return 1.0 / v
    fill = float(np.median(v[good])) if good.any() else 1.0
    return 1.0 / np.where(good, v, fill)


def fit_terms(residual: FloatArray, variance: FloatArray, regressors: FloatArray | None
              ) -> TermsFit:
    """Weighted least-squares fit of the model's terms to the finite residuals."""
    e = np.asarray(residual, dtype=float)
    x = np.zeros((len(e), 0)) if regressors is None else np.asarray(regressors, dtype=float)
    x = x.reshape(len(e), -1)
    ok = np.isfinite(e) & np.all(np.isfinite(x), axis=1)
    x = np.where(ok[:, None], x, 0.0)
    w = weights(variance)
    if x.shape[1] == 0 or not ok.any():
        return TermsFit(x, np.zeros(x.shape[1]), np.zeros((x.shape[1], x.shape[1])), ok)
    scale = np.sqrt(np.sum(w[ok, None] * x[ok] ** 2, axis=0))
    scale = np.where(scale > 0, scale, 1.0)
    xs = x[ok] / scale
    normal = (xs * w[ok, None]).T @ xs
    inverse = np.linalg.pinv(normal, rcond=1e-10, hermitian=True)
    coef = inverse @ (xs * w[ok, None]).T @ e[ok]
    return TermsFit(x, coef / scale, inverse / np.outer(scale, scale), ok)


def log_chi2_sf(x: float, dof: float) -> float:
    """``log P(chi2_dof > x)``, finite far into the tail.

    ``scipy.special.chdtrc`` (scipy.special, not scipy.stats: a tenth of the import
    time), and where that underflows (``x`` of a few hundred and more)
    :func:`log_chi2_sf_series`.
    """
    from scipy import special

    value = float(special.chdtrc(dof, x))
    if value > 0.5:  # near 1: from the lower tail, for full relative accuracy
        return math.log1p(-float(special.chdtr(dof, x)))
    return math.log(value) if value > 0.0 else log_chi2_sf_series(x, dof)


def log_chi2_sf_series(x: float, dof: float, terms: int = 8) -> float:
    """``log P(chi2_dof > x)`` from the asymptotic series, for ``x`` well above ``dof``.

    The upper regularised incomplete gamma function with ``a = dof / 2``,
    ``y = x / 2``: ``Q(a, y) = y^(a-1) e^-y / Gamma(a) * (1 + (a-1)/y +
    (a-1)(a-2)/y^2 + ...)``.
    """
    a, y = 0.5 * dof, 0.5 * x
    series, term = 1.0, 1.0
    for k in range(1, terms):
        term *= (a - k) / y
        series += term
    return float((a - 1.0) * np.log(y) - y - math.lgamma(a) + np.log(max(series, 1e-300)))


def binned_test(
    x: FloatArray,
    residual: FloatArray,
    variance: FloatArray,
    segment: IntArray,
    terms: TermsFit | None = None,
    *,
    n_bins: int = N_BINS,
    bins: IntArray | None = None,
) -> BinnedMeans | None:
    """Bin ``residual`` by ``x`` and test the bin means for structure (module doc).

    Parameters
    ----------
    x : ndarray (n,)
        The variable to bin by; NaN leaves a plot out of the bins (it still
        counts in the terms' fit).
    residual : ndarray (n,)
        Residuals of one coordinate.
    variance : ndarray (n,)
        Their expected variances (same unit squared); non-positive or non-finite
        values get the median.
    segment : ndarray (n,) of int
        Segment of each plot (:func:`segment_codes`).
    terms : TermsFit, optional
        The model's own terms fitted to these residuals (:func:`fit_terms`):
        their part of each bin mean is removed before the test, and the test's
        null distribution accounts for the fit.  Default: none.
    n_bins : int
        Bins wanted; fewer when the plots do not fill them.
    bins : ndarray (n,) of int, optional
        The plots' bins as :func:`plot_bins` gives them for ``x``, ``terms.rows``
        and ``n_bins`` (computed when not given).

    Returns
    -------
    BinnedMeans or None
        ``None`` when too few plots or bins remain for :data:`MIN_DOF` degrees of
        freedom.
    """
    x = np.asarray(x, dtype=float)
    e = np.asarray(residual, dtype=float)
    segment = np.asarray(segment, dtype=np.int64)
    w = weights(variance)
    if terms is None:
        terms = fit_terms(e, variance, None)
    fit = terms.rows
    if bins is None:
        bins = plot_bins(x, fit, n_bins)
        if bins is None:
            return None
    ok = bins >= 0
    k = int(bins.max()) + 1
    # Keep bins with enough plots and segments; renumber them 0 .. K-1.
    n = np.bincount(bins[ok], minlength=k)
    pieces = _piece_codes(segment[ok], bins[ok], k)
    n_seg = np.bincount(_piece_bins(pieces, bins[ok]), minlength=k)
    keep = (n >= MIN_BIN_PLOTS) & (n_seg >= MIN_BIN_SEGMENTS)
    if keep.sum() < MIN_DOF + 1:
        return None
    bins = np.where(ok & keep[np.maximum(bins, 0)], (np.cumsum(keep) - 1)[np.maximum(bins, 0)],
                    -1)
    k = int(keep.sum())
    inside = bins >= 0
    b_in = bins[inside]
    corrected = np.where(fit, e - terms.fitted, 0.0)
    # Weighted bin means of the residuals and of the corrected residuals.
    n = np.bincount(b_in, minlength=k)
    big_w = np.bincount(b_in, w[inside], minlength=k)
    mean = np.bincount(b_in, (w * e)[inside], minlength=k) / big_w
    excess = np.bincount(b_in, (w * corrected)[inside], minlength=k) / big_w
    d = corrected[inside] - excess[b_in]
    phi = np.bincount(b_in, w[inside] * d * d, minlength=k) / np.maximum(n - 1, 1)
    phi = np.where(phi > 0, phi, 1.0)
    # The pooled within-segment correlation, from the pieces of segments in bins.
    pieces = _piece_codes(segment[inside], b_in, k)
    y = d * np.sqrt(w[inside] / phi[b_in])
    rho = _segment_correlation(np.bincount(pieces, y), np.bincount(pieces).astype(float),
                               _piece_bins(pieces, b_in), k)
    # sigma_b: each plot's share of m_b is w_k / W_b, its noise s_k = sqrt(phi_b / w_k).
    own = np.sqrt(phi[b_in] * w[inside]) / big_w[b_in]
    sigma = np.sqrt((1.0 - rho) * np.bincount(b_in, own**2, minlength=k)
                    + rho * np.bincount(_piece_bins(pieces, b_in),
                                        np.bincount(pieces, own) ** 2, minlength=k))
    # Covariance of the excesses: each fitted residual's share of them is
    # l_k = s_k (M_k - B w_k x_k), with M_k = (w_k / W_b) e_b its share of its bin's mean,
    # B = xb A (xb the terms' bin means) and s_k its noise.  The sums of l l^T, plain and
    # per segment, are formed from sums per bin and per segment, without the n x K shares.
    rows = terms.fitted_rows
    b_rows = bins[rows]
    in_rows = b_rows >= 0
    b_safe = np.maximum(b_rows, 0)
    m = np.where(in_rows, w[rows] / big_w[b_safe], 0.0)
    phi_mean = float(np.sum(phi * big_w) / np.sum(big_w))
    s = np.sqrt(np.where(in_rows, phi[b_safe], phi_mean) / w[rows])
    sm = s * m
    seg, n_seg = _dense_codes(segment[rows])
    cov_own = np.diag(np.bincount(b_safe, sm**2, minlength=k))
    per_segment = np.bincount(seg * k + b_safe, sm, minlength=n_seg * k).reshape(n_seg, k)
    cov_seg = per_segment.T @ per_segment
    x_fit = terms.fitted_regressors
    if x_fit.shape[1]:
        xb = _sum_by(b_safe, m[:, None] * x_fit, k)  # (K, p)
        b_mat = xb @ terms.normal_inverse
        sv = (s * w[rows])[:, None] * x_fit  # s_k w_k x_k
        cross = _sum_by(b_safe, sm[:, None] * sv, k)  # sum over a bin of s m (s w x)^T
        cov_own += b_mat @ (sv.T @ sv) @ b_mat.T - cross @ b_mat.T - b_mat @ cross.T
        y = _sum_by(seg, sv, n_seg)  # (segments, p)
        py = per_segment.T @ y
        cov_seg += b_mat @ (y.T @ y) @ b_mat.T - py @ b_mat.T - b_mat @ py.T
    cov = (1.0 - rho) * cov_own + rho * cov_seg
    normalised = cov / np.outer(sigma, sigma)
    lam = np.clip(np.linalg.eigvalsh(0.5 * (normalised + normalised.T)), 0.0, None)
    dof = float(np.sum(lam))
    if dof < MIN_DOF:
        return None
    # Satterthwaite: sum_i lam_i chi2_1 ~ g chi2_h with the same mean and variance.
    g = float(np.sum(lam**2)) / dof
    chi2 = float(np.sum((excess / sigma) ** 2))
    log_p = log_chi2_sf(chi2 / g, dof / g)
    x_in = x[inside]
    lower, upper = np.full(k, np.inf), np.full(k, -np.inf)
    np.minimum.at(lower, b_in, x_in)
    np.maximum.at(upper, b_in, x_in)
    centre = np.bincount(b_in, x_in, minlength=k) / n
    return BinnedMeans(
        centre=centre, lower=lower, upper=upper, n_plots=n.astype(np.int64),
        n_segments=np.bincount(_piece_bins(pieces, b_in), minlength=k).astype(np.int64),
        mean=mean, sigma=sigma, absorbed=mean - excess, chi2=chi2, dof=dof,
        p_value=float(np.exp(log_p)), log10_p=log_p / np.log(10.0), rho=rho,
    )


def _segment_correlation(big_y: FloatArray, n_u: FloatArray, piece_bin: IntArray, k: int
                         ) -> float:
    """Moment estimate of the within-segment correlation ``rho``, clipped to [0, MAX_RHO].

    ``big_y``: each piece's sum of standardised deviations from its bin mean; ``n_u``
    its plots.  Without the bin means, ``E[Y_u^2] = n_u + rho n_u (n_u - 1)``; taking
    the bin mean out lowers it, by a share that matters when a bin holds few pieces:
    with ``V_u = n_u + rho a_u``, ``a_u = n_u (n_u - 1)``, ``n_b`` the bin's plots and
    ``T_b = n_b + rho sum_u a_u`` the variance of its sum,
    ``E[Y_u^2] = V_u (1 - 2 n_u / n_b) + (n_u / n_b)^2 T_b``.  Summed over the pieces
    this is ``A0 + rho A1``, solved for ``rho``.
    """
    a_u = n_u * (n_u - 1.0)
    n_b = np.bincount(piece_bin, n_u, minlength=k)
    sum_a = np.bincount(piece_bin, a_u, minlength=k)
    share = n_u / n_b[piece_bin]
    a0 = float(np.sum(n_u * (1.0 - 2.0 * share) + share**2 * n_b[piece_bin]))
    a1 = float(np.sum(a_u * (1.0 - 2.0 * share) + share**2 * sum_a[piece_bin]))
    if a1 <= 0:
        return 0.0
    return float(np.clip((float(np.sum(big_y**2)) - a0) / a1, 0.0, MAX_RHO))


def _sum_by(codes: IntArray, values: FloatArray, size: int | None = None) -> FloatArray:
    """Row sums of ``values`` grouped by ``codes`` (0 .. size - 1), one row per code."""
    size = int(codes.max()) + 1 if size is None else size
    columns = np.ascontiguousarray(values.T)
    return np.stack([np.bincount(codes, column, minlength=size) for column in columns], axis=1)


def _dense_codes(segment: IntArray) -> tuple[IntArray, int]:
    """Segment numbers as codes ``0 .. n - 1`` and ``n``: as given when they already are
    small non-negative numbers (:func:`segment_codes`), else factorised."""
    if len(segment) and segment.min() >= 0 and segment.max() < 4 * len(segment) + 16:
        return segment, int(segment.max()) + 1
    codes, uniques = pd.factorize(segment)
    return codes.astype(np.int64), len(uniques)


def _piece_codes(segment: IntArray, bins: IntArray, k: int) -> IntArray:
    """A code per (segment, bin) piece present, ``0 .. pieces - 1`` (in key order)."""
    seg, n_seg = _dense_codes(segment)
    key = seg * k + bins
    present = np.zeros(n_seg * k, dtype=bool)
    present[key] = True
    return (np.cumsum(present) - 1)[key]


def _piece_bins(pieces: IntArray, bins: IntArray) -> IntArray:
    """The bin of each piece."""
    out = np.zeros(int(pieces.max()) + 1, dtype=np.int64)
    out[pieces] = bins
    return out


__all__ = ["MIN_BIN_PLOTS", "MIN_BIN_SEGMENTS", "N_BINS", "BinnedMeans", "TermsFit",
           "binned_test", "fit_terms", "log_chi2_sf", "log_chi2_sf_series",
           "plot_bins", "quantile_bins",
           "segment_codes", "weights"]
