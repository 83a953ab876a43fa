"""ADS-B-referenced closed-form estimators of paper 003: ``ls``, ``fl`` and ``fl-ls``.

Each radar is calibrated on its own against the ADS-B positions of the same
aircraft interpolated to its plot times (:func:`graphcal.data.align.align_adsb`).

``ls`` -- paper 003 eq. 11-19.  With ``p(r, az, el)`` the polar -> ENU map
(paper 003 eq. 5 for a 2-D radar, i.e. the elevation taken as 0 and slant
range projected on the plane; the full 3-D map for a 3-D radar)::

    z_i = p(measured_i) - p(adsb_i) = H_i beta + noise,
    H_i = dp/d(r, az, el) at measured_i  @  d(measured)/d(beta)

which for a 2-D radar and ``beta = (range_offset, azimuth_bias)`` is exactly
eq. 15-16.  Extended (documented): a range-gain column ``r_i * d p/d r`` where
the radar estimates gain, and an elevation-bias column for 3-D radars.  The
solution is the paper's unweighted ``(H^T H)^-1 H^T z`` (eq. 19 corrected); its
covariance is the sandwich ``(H^T H)^-1 H^T Sigma H (H^T H)^-1`` with Sigma
the radar noise plus the ADS-B noise mapped through the same Jacobians
(paper 002's first-order conversion), so the reported sigma is honest for
an unweighted fit.  Like the paper, it linearises once at zero bias: with a
large azimuth bias it is biased (that is what FL-LS fixes).

``fl`` -- paper 003 eq. 8-10: straight lines are fitted to the radar track
and to the ADS-B track in the plane (orthogonal regression, so north-south
tracks work), and the azimuth bias is the signed angle between them (eq. 9
corrected: the sign is kept; measured minus true is ``alpha_adsb -
alpha_radar`` with ``alpha`` the counter-clockwise direction angle).  Tracks
are cut into windows of :data:`FL_WINDOW_PLOTS` plots; windows whose ADS-B
points are not straight to within :data:`FL_MAX_LINE_RMS_M` are skipped, the
rest are combined with inverse-variance weights, and the variance is inflated
by the Birge ratio when windows disagree more than their noise.  The range
offset is the mean of ``r_radar - r_adsb`` and, for a 3-D radar, the
elevation bias the mean elevation difference (extensions; FL in the paper
only yields an angle).  FL does not estimate range gain.

``fl-ls`` -- FL compensation of the azimuth (eq. 10, sign corrected:
``az' = az - fl_bias``) followed by LS on the compensated plots; the
azimuth estimate is the FL angle plus the LS correction.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.batched import congruent_diagonal, sum_of_products
from graphcal.core.errors import EstimationError
from graphcal.data.align import AdsbAlignment
from graphcal.data.bias import PARAMETER_NAMES
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset, Site
from graphcal.model.information import (
    describe_weak_directions,
    observability,
    solve_normal_equations,
)
from graphcal.model.measurement import (
    measured_polar,
    measurement_model,
    reference_polar_covariance,
    residual_stats,
)
from graphcal.model.parameters import ParameterLayout
from graphcal.model.problem import Problem, as_problem
from graphcal.noise import fills_missing_sigmas

#: Plots per FL window.
FL_WINDOW_PLOTS = 30
#: Fewest plots in an FL window.
FL_MIN_WINDOW_PLOTS = 6
#: Largest RMS perpendicular distance [m] of ADS-B points from their fitted line
#: for a window to count as straight flight.
FL_MAX_LINE_RMS_M = 150.0

FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------- helpers
def _plane_polar(site: Site, polar: FloatArray) -> FloatArray:
    """Elevation used in the Cartesian projection: measured for 3-D, 0 for 2-D (eq. 5)."""
    out = polar.copy()
    if not site.is_3d:
        out[:, 2] = 0.0
    return out


def _plane_reference(site: Site, al: AdsbAlignment) -> tuple[FloatArray, FloatArray]:
    """ENU of the ADS-B references in the plane projection and ``d enu / d polar`` there."""
    return frames.polar_to_enu_and_jacobian(*_plane_polar(site, al.reference_polar).T)


def _alignments(problem: Problem, max_gap_s: float) -> dict[str, AdsbAlignment]:
    if problem.dataset.adsb is None:
        raise EstimationError(
            "this method needs ADS-B reports (adsb.csv|parquet): use 'wls' for "
            "cross-radar calibration without ADS-B"
        )
    return {rid: problem.alignment(rid, max_gap_s) for rid in problem.radar_ids}


# --------------------------------------------------------------------------- LS
def ls_radar(
    site: Site, al: AdsbAlignment, names: list[str], azimuth_compensation_rad: float = 0.0,
    *, reference_plane: tuple[FloatArray, FloatArray] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Paper 003 LS for one radar.

    Returns ``(estimate, covariance, information, inflation)`` over ``names`` (SI
    units): the covariance is the formal sandwich, widened where the per-aircraft
    spread of the residuals shows it too small (:func:`_aircraft_robust`; ``inflation``
    its largest variance factor, 1.0 when none).
    ``azimuth_compensation_rad`` is subtracted from the measured azimuths first
    (FL-LS, eq. 10 corrected); the returned azimuth estimate excludes it.
    ``reference_plane``: the ADS-B references' plane ENU and its Jacobian, when
    already computed (FL-LS computes them once for FL and LS).
    """
    measured = _plane_polar(site, measured_polar(al))
    measured[:, 1] = measured[:, 1] - azimuth_compensation_rad
    reference_enu, reference_jac = reference_plane or _plane_reference(site, al)
    rows = 3 if site.is_3d else 2
    measured_enu, measured_jac = frames.polar_to_enu_and_jacobian(*measured.T)
    z = (measured_enu - reference_enu)[:, :rows]
    jac_r = np.ascontiguousarray(measured_jac[:, :rows, :])
    # h = jac_r @ RadarMeasurementModel.bias_jacobian(r)[:, :, positions]: the bias
    # Jacobian's columns are unit vectors, the gain's scaled by the range, so h is
    # made of jac_r's columns, exactly as that product gives them.
    columns = {"range_offset": jac_r[:, :, 0], "range_gain": jac_r[:, :, 0] * measured[:, :1],
               "azimuth_bias": jac_r[:, :, 1], "elevation_bias": jac_r[:, :, 2]}
    h = np.stack([columns[name] for name in names], axis=-1)
    # Noise of z: radar noise plus the ADS-B noise, both mapped to the plane; the radar's
    # is diagonal, so jac_r @ covar is jac_r with its columns scaled.
    jac_a = np.ascontiguousarray(reference_jac[:, :rows, :])
    ref_cov = reference_polar_covariance(al, site)
    if not site.is_3d:
        ref_cov = ref_cov.copy()  # shared: not to be changed in place
        ref_cov[:, 2, :] = 0.0
        ref_cov[:, :, 2] = 0.0
    variances = np.diagonal(measurement_model(site).covar(1)[0])
    sigma = congruent_diagonal(jac_r, variances)
    sigma += jac_a @ ref_cov @ np.swapaxes(jac_a, 1, 2)
    information = sum_of_products(h, None, h)
    rhs = h.reshape(-1, h.shape[-1]).T @ z.reshape(-1)
    middle = sum_of_products(h, sigma, h)
    sol = solve_normal_equations(information, rhs, middle)
    covariance, factor = sol.covariance, 1.0
    if al.target_code is not None and np.all(np.isfinite(covariance)):
        covariance, factor = _aircraft_robust(covariance, information, h, z - h @ sol.estimate,
                                              al.target_code)
    return sol.estimate, covariance, information, factor
#: Fewest aircraft for the per-aircraft (cluster-robust) covariance check.
MIN_AIRCRAFT_ROBUST = 5
#: The cluster-robust variance must exceed the formal one by this many of its chance
#: spreads (``sqrt(2 / K)`` for ``K`` aircraft) to replace it.
ROBUST_CHANCE_SIGMAS = 3.0


def _aircraft_robust(
    covariance: FloatArray, information: FloatArray, h: FloatArray, residual: FloatArray,
    aircraft: NDArray[np.int64],
) -> tuple[FloatArray, float]:
    """The formal covariance, widened where the residuals say it is too small.

    The formal sandwich assumes every plot's error independent with the stated noise.
    Errors shared by an aircraft's plots (an unmodelled time-stamping bias, ADS-B
    interpolation along a turn, a wrong ADS-B source) make it several times too
    small (``graphcal compare``: sigma-hat / std 0.14 with a 0.5 s time offset).  The
    cluster-robust (per-aircraft) sandwich ``A^-1 (sum_k g_k g_k^T) A^-1``, with
    ``g_k`` the sum of ``h_i^T e_i`` over aircraft ``k``'s plots, measures the spread
    the residuals show.  In the formal covariance's whitened frame its eigenvalues
    above ``1 + 3 sqrt(2 / K)`` (beyond the chance spread of ``K`` aircraft) replace
    the formal ones (1); the rest stay, so that data the noise model fits keep their
    formal sigmas.  Returns the covariance and the largest eigenvalue kept (1.0: none).
    """
    codes, cluster = np.unique(aircraft, return_inverse=True)
    k = len(codes)
    p = covariance.shape[0]
    if k < max(MIN_AIRCRAFT_ROBUST, p + 1):
        return covariance, 1.0
    scores = np.einsum("nrp,nr->np", h, residual)
    g = np.zeros((k, p))
    np.add.at(g, cluster, scores)
    try:
        a_inv = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        return covariance, 1.0
    robust = a_inv @ (g.T @ g) * (k / (k - 1)) @ a_inv
    values, vectors = np.linalg.eigh(covariance)
    if not np.all(values > 0):
        return covariance, 1.0
    half = vectors * np.sqrt(values)            # covariance = half @ half.T
    inv_half = vectors / np.sqrt(values)        # half^-1 = inv_half.T
    m = inv_half.T @ robust @ inv_half
    lam, u = np.linalg.eigh(0.5 * (m + m.T))
    limit = 1.0 + ROBUST_CHANCE_SIGMAS * np.sqrt(2.0 / k)
    kept = np.where(lam > limit, lam, 1.0)
    if np.all(kept == 1.0):
        return covariance, 1.0
    widened = half @ (u * kept) @ u.T @ half.T
    return 0.5 * (widened + widened.T), float(kept.max())


def _assemble(
    method: str,
    dataset: Dataset,
    per_radar: dict[str, tuple[list[str], FloatArray, FloatArray, FloatArray]],
    alignments: dict[str, AdsbAlignment],
    info: dict,
) -> Calibration:
    """Block-diagonal joint result from independent per-radar solutions."""
    radar_ids = [rid for rid in dataset.radar_ids if rid in per_radar]
    labels = [(rid, name) for rid in radar_ids for name in per_radar[rid][0]]
    p = len(labels)
    estimate = np.zeros(p)
    covariance = np.zeros((p, p))
    information = np.zeros((p, p))
    i = 0
    for rid in radar_ids:
        names, est, cov, inf = per_radar[rid]
        k = len(names)
        estimate[i : i + k] = est
        covariance[i : i + k, i : i + k] = cov
        information[i : i + k, i : i + k] = inf
        i += k
    obs = observability(information)
    cal = Calibration(
        method=method,
        radar_ids=radar_ids,
        is_3d={rid: dataset.sites[rid].is_3d for rid in radar_ids},
        labels=labels,
        estimate=estimate,
        covariance=covariance,
        n_plots={rid: len(alignments[rid]) for rid in radar_ids},
        observability=obs,
        info=info,
    )
    for rid in radar_ids:
        cal.residuals[rid] = residual_stats(dataset.sites[rid], alignments[rid], cal.bias(rid))
    cal.warnings.extend(info.pop("warnings", []))
    cal.warnings.extend(describe_weak_directions(labels, obs))
    return cal


def _skip_warning(rid: str, al: AdsbAlignment, needed: int) -> str:
    return (
        f"radar {rid}: only {len(al)} plots matched ADS-B ({al.n_unmatched} unmatched), "
        f"fewer than the {needed} needed; not calibrated"
    )


def _run_ls(
    method: str,
    problem: Problem,
    max_gap_s: float,
    azimuth_precompensation: Callable[[Site, AdsbAlignment, FloatArray], tuple[float, dict]]
    | None,
) -> Calibration:
    dataset = problem.dataset
    alignments = _alignments(problem, max_gap_s)
    layout = ParameterLayout.for_sites(list(dataset.sites.values()))
    per_radar, warnings, details = {}, [], {}
    for rid, al in alignments.items():
        site = dataset.sites[rid]
        names = [PARAMETER_NAMES[k] for k in layout.columns(rid)[1]]
        if len(al) < max(len(names), 3):
            warnings.append(_skip_warning(rid, al, max(len(names), 3)))
            continue
        compensation, detail = 0.0, {}
        plane = _plane_reference(site, al)  # for FL and LS
        if azimuth_precompensation is not None:
            try:
                compensation, detail = azimuth_precompensation(site, al, plane[0])
            except EstimationError as exc:
                warnings.append(f"radar {rid}: {exc}; LS without FL compensation")
        est, cov, inf, inflation = ls_radar(site, al, names, compensation,
                                            reference_plane=plane)
        if "azimuth_bias" in names:
            est[names.index("azimuth_bias")] += compensation
        per_radar[rid] = (names, est, cov, inf)
        details[rid] = {"fl_azimuth_mrad": compensation * 1e3, **detail} if detail else {}
        if inflation > 1.0:
            details[rid]["sigma_inflation"] = inflation
            warnings.append(
                f"radar {rid}: its residuals vary from aircraft to aircraft beyond the stated "
                f"noise (a time-stamping bias {method} does not model, refraction, ADS-B "
                "along turns?): "
                f"sigmas widened by up to {np.sqrt(inflation):.1f} times over the formal ones "
                "(the per-aircraft spread); use --method graph, which models more")
    if not per_radar:
        raise EstimationError("no radar has enough plots matched to ADS-B: " + "; ".join(warnings))
    info = {"max_gap_s": max_gap_s, "per_radar": details, "warnings": warnings,
            "sigma": LS_SIGMA_NOTE}
    return _assemble(method, dataset, per_radar, alignments, info)


#: ``info["sigma"]`` of ls and fl-ls: what their sigmas are.
LS_SIGMA_NOTE = ("formal (paper 003 eq. 19 sandwich: radar and ADS-B noise as stated), "
                 "widened where the residuals' per-aircraft spread shows it too small "
                 "(per_radar.sigma_inflation)")
#: ``info["sigma"]`` of fl: what its sigmas are.
FL_SIGMA_NOTE = ("formal (paper 003: the window angles' inverse-variance mean, inflated by "
                 "the Birge ratio when windows disagree); the range offset ignores the range "
                 "gain and the time offset, so its sigma holds only when they are zero")


@fills_missing_sigmas
def ls(data: Dataset | Problem, *, max_gap_s: float | None = None) -> Calibration:
    """Paper 003 LS (eq. 11-19) against ADS-B, every radar on its own."""
    problem = as_problem(data)
    return _run_ls("ls", problem, _gap(problem, max_gap_s), None)


def _gap(problem: Problem, max_gap_s: float | None) -> float:
    """The ADS-B gap limit [s]: the one given, else the problem's."""
    return problem.options.adsb_max_gap_s if max_gap_s is None else float(max_gap_s)


# --------------------------------------------------------------------------- FL
def _fit_lines(points: FloatArray, starts: NDArray[np.int64]) -> tuple[FloatArray, ...]:
    """Orthogonal-regression line through each window of 2-D points ordered in time.

    ``points`` holds the windows one after the other, window ``k`` from row
    ``starts[k]``.  Returns per window ``(direction angle [rad] counter-clockwise
    from east, oriented along the motion; its variance [rad^2]; RMS perpendicular
    residual [m])``.  The direction is the principal axis of the centred points
    (the first right singular vector of the centred window, from its 2x2 scatter
    matrix in closed form).
    """
    n = np.diff(np.r_[starts, len(points)])
    window = np.repeat(np.arange(len(starts)), n)
    centred = points - (np.add.reduceat(points, starts, axis=0) / n[:, None])[window]
    sxx = np.add.reduceat(centred[:, 0] ** 2, starts)
    syy = np.add.reduceat(centred[:, 1] ** 2, starts)
    sxy = np.add.reduceat(centred[:, 0] * centred[:, 1], starts)
    theta = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    direction = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    motion = points[starts + n - 1] - points[starts]
    direction[np.einsum("ki,ki->k", direction, motion) < 0] *= -1.0
    d = direction[window]
    along = centred[:, 0] * d[:, 0] + centred[:, 1] * d[:, 1]
    perp = centred[:, 1] * d[:, 0] - centred[:, 0] * d[:, 1]
    perp_var = np.add.reduceat(perp**2, starts) / np.maximum(n - 2, 1)
    spread = np.add.reduceat(along**2, starts)
    return np.arctan2(direction[:, 1], direction[:, 0]), perp_var / spread, np.sqrt(perp_var)


def _windows(al: AdsbAlignment, max_gap_s: float) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Windows of consecutive plots of one aircraft without long gaps.

    Each aircraft's plots in time order are cut where two are more than
    ``max_gap_s`` apart; each piece into ``max(1, len // FL_WINDOW_PLOTS)``
    windows of (almost) equal length (``numpy.array_split``); windows shorter
    than :data:`FL_MIN_WINDOW_PLOTS` are dropped.  Returns the rows of ``al``
    window after window (aircraft in sorted order) and each window's first position.
    """
    # Aircraft as codes in the order of their identities: sorting by them is sorting by
    # the text, much faster.
    targets = al.target_code
    if targets is None:
        targets = pd.factorize(al.plots.target_id.astype(str), sort=True)[0]
    time_s = al.plots.time_s
    order = np.lexsort((time_s, targets))
    n = len(order)
    if n == 0:
        return order, np.zeros(0, dtype=np.int64)
    t, g = time_s[order], targets[order]
    new = np.ones(n, dtype=bool)
    new[1:] = (g[1:] != g[:-1]) | (np.diff(t) > max_gap_s)
    piece_start = np.flatnonzero(new)
    piece_len = np.diff(np.r_[piece_start, n])
    piece = np.cumsum(new) - 1
    position = np.arange(n) - piece_start[piece]
    count = np.maximum(1, piece_len // FL_WINDOW_PLOTS)  # windows per piece
    size, extra = (piece_len // count)[piece], (piece_len % count)[piece]
    long_part = extra * (size + 1)  # array_split: the first `extra` windows one longer
    within = np.where(position < long_part, position // (size + 1),
                      extra + (position - long_part) // np.maximum(size, 1))
    window = (np.cumsum(count) - count)[piece] + within
    keep = np.bincount(window)[window] >= FL_MIN_WINDOW_PLOTS
    rows, window = order[keep], window[keep]
    starts = np.flatnonzero(np.r_[True, window[1:] != window[:-1]]) if len(rows) else window
    return rows, starts.astype(np.int64)


def fl_azimuth(
    site: Site, al: AdsbAlignment, max_gap_s: float = 60.0, *,
    reference_enu: FloatArray | None = None,
) -> tuple[float, float, dict]:
    """FL azimuth bias (paper 003 eq. 8-9, sign kept) with its variance [rad, rad^2].

    ``reference_enu``: the ADS-B references' plane ENU, when already computed.
    """
    radar_xy = frames.polar_to_enu(*_plane_polar(site, measured_polar(al)).T)[:, :2]
    if reference_enu is None:
        reference_enu = _plane_reference(site, al)[0]
    adsb_xy = reference_enu[:, :2]
    rows, starts = _windows(al, max_gap_s)
    alpha_a, var_a, rms_a = _fit_lines(adsb_xy[rows], starts)
    alpha_r, var_r, _ = _fit_lines(radar_xy[rows], starts)
    straight = ~(rms_a > FL_MAX_LINE_RMS_M)
    skipped = int(np.sum(~straight))
    if not np.any(straight):
        raise EstimationError("no straight track segment for the line fit (FL)")
    angles_arr = frames.wrap_to_pi(alpha_a - alpha_r)[straight]
    var_arr = (var_a + var_r)[straight]
    weights = 1.0 / var_arr
    mean = float(np.sum(weights * angles_arr) / np.sum(weights))
    variance = float(1.0 / np.sum(weights))
    birge = 1.0
    if len(angles_arr) > 1:
        birge = float(np.sum(weights * (angles_arr - mean) ** 2) / (len(angles_arr) - 1))
        variance *= max(1.0, birge)
    detail = {"fl_windows": len(angles_arr), "fl_windows_skipped": skipped, "fl_birge": birge}
    return mean, variance, detail


@fills_missing_sigmas
def fl(data: Dataset | Problem, *, max_gap_s: float | None = None) -> Calibration:
    """Paper 003 FL: line-fit azimuth bias, mean range (and elevation) difference."""
    problem = as_problem(data)
    dataset = problem.dataset
    max_gap_s = _gap(problem, max_gap_s)
    alignments = _alignments(problem, max_gap_s)
    allowed = ("range_offset", "azimuth_bias", "elevation_bias")
    layout = ParameterLayout.for_sites(list(dataset.sites.values()), allowed)
    per_radar, warnings, details = {}, [], {}
    for rid, al in alignments.items():
        site = dataset.sites[rid]
        names = [PARAMETER_NAMES[k] for k in layout.columns(rid)[1]]
        if len(al) < FL_MIN_WINDOW_PLOTS:
            warnings.append(_skip_warning(rid, al, FL_MIN_WINDOW_PLOTS))
            continue
        estimates, variances = {}, {}
        if "azimuth_bias" in names:
            try:
                az, var_az, detail = fl_azimuth(site, al)
            except EstimationError as exc:
                warnings.append(f"radar {rid}: {exc}; not calibrated")
                continue
            estimates["azimuth_bias"], variances["azimuth_bias"] = az, var_az
            details[rid] = detail
        measured = measured_polar(al)
        for name, k in (("range_offset", 0), ("elevation_bias", 2)):
            if name in names:
                diff = measured[:, k] - al.reference_polar[:, k]
                estimates[name] = float(np.mean(diff))
                variances[name] = _mean_variance(diff, al.target_code)
        est = np.array([estimates[n] for n in names])
        var = np.array([variances[n] for n in names])
        per_radar[rid] = (names, est, np.diag(var), np.diag(1.0 / var))
    if not per_radar:
        raise EstimationError("no radar could be calibrated by FL: " + "; ".join(warnings))
    info = {"max_gap_s": max_gap_s, "per_radar": details, "warnings": warnings,
            "sigma": FL_SIGMA_NOTE}
    return _assemble("fl", dataset, per_radar, alignments, info)


def _mean_variance(diff: FloatArray, aircraft: NDArray[np.int64] | None) -> float:
    """Variance of the mean of ``diff``: the plots' scatter over their number, or the
    per-aircraft (cluster-robust) spread when larger (errors an aircraft's plots share,
    such as an unestimated range gain at its ranges, do not average out)."""
    n = len(diff)
    iid = float(np.var(diff, ddof=1) / n)
    if aircraft is None:
        return iid
    codes, cluster = np.unique(aircraft, return_inverse=True)
    k = len(codes)
    if k < MIN_AIRCRAFT_ROBUST:
        return iid
    sums = np.bincount(cluster, weights=diff - diff.mean(), minlength=k)
    robust = float(np.sum(sums**2) / n**2 * k / (k - 1))
    return max(iid, robust) if robust > iid * (1.0 + ROBUST_CHANCE_SIGMAS *
                                               np.sqrt(2.0 / k)) else iid


@fills_missing_sigmas
def fl_ls(data: Dataset | Problem, *, max_gap_s: float | None = None) -> Calibration:
    """Paper 003 FL-LS: FL azimuth compensation (eq. 10, sign corrected), then LS."""

    def precompensate(site: Site, al: AdsbAlignment, enu: FloatArray) -> tuple[float, dict]:
        az, _, detail = fl_azimuth(site, al, reference_enu=enu)
        return az, detail

    problem = as_problem(data)
    return _run_ls("fl-ls", problem, _gap(problem, max_gap_s), precompensate)
