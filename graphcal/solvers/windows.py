"""Biases over time: one set of bias variables per time window, chained by random walks.

Contract v2's ``--window``: the recording is cut into windows
(:func:`graphcal.data.windows.split_windows`); each window's plots give that window's
ADS-B and pairwise factors (:func:`graphcal.model.problem.build_factors`) on its own
bias variables ``x_k`` (one vector per radar and window, the radar's free terms); and
consecutive windows of a radar are tied by a random-walk factor::

    x_{k+1} - x_k ~ N(0, diag(q^2) (t_{k+1} - t_k))

with ``q`` each term's random-walk rate [unit per sqrt(s)] and ``t_k`` the windows'
middles.  The whole chain is solved at once (a batch smoother: every window's
estimate uses every window's data) and each window's marginal covariance is its
1-sigma band.  A window's estimate is of the radar's mean bias over the window.

First version: the time-stamping biases are not estimated (they are constant in
time anyway and need ADS-B), pressure altitudes are refused (their height model
per window comes later), and the cross-radar noise shared between pairs is not
corrected in the covariance (the single-batch ``graph`` does it).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from graphcal.core.errors import EstimationError
from graphcal.data.align import DEFAULT_ADSB_MAX_GAP_S
from graphcal.data.bias import CONTRACT_KEYS, RadarBias
from graphcal.data.dataset import Dataset
from graphcal.data.windows import Window, split_windows
from graphcal.model.parameters import RadarTerms, prior_sigmas, radar_terms
from graphcal.model.problem import Problem, build_factors
from graphcal.model.robust import RobustKernel
from graphcal.solvers.graph import add_factor
from graphcal.solvers.gtsam_adapter import FactorGraph, symbol

FloatArray = NDArray[np.float64]

#: Default random-walk rates per term [SI unit per sqrt(s)], from a change of this
#: size per sqrt(hour): range offset 2 m, range gain 2e-6, azimuth and elevation
#: 0.05 mrad, eccentricity 0.02 mrad.  Deliberately loose: they let a real drift be
#: followed, and the data of each window pin it down.
DEFAULT_RANDOM_WALK_PER_SQRT_S: dict[str, float] = {
    "range_offset": 2.0 / 60.0,
    "range_gain": 2e-6 / 60.0,
    "azimuth_bias": 0.05e-3 / 60.0,
    "elevation_bias": 0.05e-3 / 60.0,
    "azimuth_sin": 0.02e-3 / 60.0,
    "azimuth_cos": 0.02e-3 / 60.0,
}


@dataclass
class WindowEstimate:
    """One radar's biases in one window: the smoothed mean over the window."""

    t_start_s: float
    t_end_s: float
    n_plots: int
    bias: RadarBias
    sigma: dict[str, float]  # contract key -> 1-sigma, contract units
    covariance: FloatArray  # over the radar's free terms, SI


@dataclass
class WindowedCalibration:
    """The chain's result: per radar, its windows in time order."""

    window_s: float
    terms: dict[str, RadarTerms]
    series: dict[str, list[WindowEstimate]]
    iterations: int = 0
    timing_s: dict[str, float] = field(default_factory=dict)
    rates: dict[str, dict[str, float]] = field(default_factory=dict)  # per sqrt(s), SI

    def last(self, radar_id: str) -> WindowEstimate:
        """The radar's last window: the correction to apply from now on."""
        return self.series[radar_id][-1]


def random_walk_rate(time_s: FloatArray, estimate: FloatArray, variance: FloatArray) -> float:
    """Maximum-likelihood random-walk rate ``q`` [unit per sqrt(s)] of one term's chain.

    The windows' *independent* estimates ``y_k`` (each from its own window's data,
    variance ``R_k``) of a term following ``x_k = x_{k-1} + w_k``, ``w_k ~ N(0, q^2
    (t_k - t_{k-1}))``: the Kalman filter's innovations ``nu_k`` (variance ``S_k``)
    give ``log L(q) = -1/2 sum (log S_k + nu_k^2 / S_k)``, maximised over ``log q``
    (a grid, then a bounded scalar search).  0 when the windows agree within their
    noise (a constant bias).
    """
    from scipy.optimize import minimize_scalar

    t, y, r = (np.asarray(v, dtype=float) for v in (time_s, estimate, variance))
    keep = np.isfinite(y) & np.isfinite(r) & (r > 0)
    t, y, r = t[keep], y[keep], r[keep]
    if len(t) < 3:
        return 0.0
    dt = np.diff(t)

    def negative_log_likelihood(log_q: float) -> float:
        q2 = np.exp(2.0 * log_q)
        x, p, total = y[0], r[0], 0.0
        for k in range(1, len(y)):
            p_pred = p + q2 * dt[k - 1]
            s = p_pred + r[k]
            nu = y[k] - x
            total += 0.5 * (np.log(s) + nu * nu / s)
            gain = p_pred / s
            x, p = x + gain * nu, (1.0 - gain) * p_pred
        return float(total)

    # q from far below the noise (a constant) to far above the spread of the estimates.
    scale = np.sqrt(np.median(r) / np.median(dt))
    spread = np.sqrt(np.max(np.diff(y) ** 2 / dt) + np.median(r) / np.median(dt))
    grid = np.linspace(np.log(1e-4 * scale), np.log(10.0 * max(spread, scale)), 60)
    values = [negative_log_likelihood(g) for g in grid]
    best = int(np.argmin(values))
    if best == 0:
        return 0.0
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    found = minimize_scalar(negative_log_likelihood, bounds=(lo, hi), method="bounded")
    return float(np.exp(found.x))


def _build(windows: list[Window], dataset: Dataset, terms: dict[str, RadarTerms],
           priors: dict[str, FloatArray], have_adsb: bool, kernel: RobustKernel
           ) -> tuple[FactorGraph, dict[str, list[tuple[Window, int]]]]:
    """Every window's variables, weak priors and measurement factors; no chain yet."""
    radar_ids = list(dataset.radar_ids)
    fg = FactorGraph()
    chain: dict[str, list[tuple[Window, int]]] = {rid: [] for rid in radar_ids}
    for w_number, window in enumerate(windows):
        keys = {rid: symbol("w", w_number * len(radar_ids) + i)
                for i, rid in enumerate(radar_ids)}
        problem = Problem(terms, keys)
        build_factors(window.dataset, problem, have_adsb, "pairwise", kernel,
                      DEFAULT_ADSB_MAX_GAP_S, None, None)
        variable = set(problem.variable_radars())
        for rid in variable:
            fg.add_variable(keys[rid], np.zeros(len(terms[rid].free)))
            fg.add_prior(keys[rid], np.zeros(len(terms[rid].free)), priors[rid])
            chain[rid].append((window, keys[rid]))
        for factor in [*problem.adsb.values(), *problem.pairs]:
            add_factor(fg, factor, variable)
    return fg, chain


def windowed_graph(
    dataset: Dataset,
    window_s: float,
    *,
    use_adsb: bool = True,
    random_walk_per_sqrt_s: Mapping[str, float] | None = None,
    estimate_rates: bool = True,
    robust: str = "huber",
    max_iterations: int = 100,
) -> WindowedCalibration:
    """Calibrate biases per time window, smoothed along the chain (module docstring).

    The random-walk rate of each radar's term is, in this order: the one given in
    ``random_walk_per_sqrt_s``; with ``estimate_rates``, the maximum-likelihood rate
    of the windows' independent estimates (:func:`random_walk_rate`, a first solve
    without the chain), so that a real drift is followed rather than smoothed away;
    else :data:`DEFAULT_RANDOM_WALK_PER_SQRT_S`.  The rates used are in
    :attr:`WindowedCalibration.rates`.

    Parameters
    ----------
    dataset : Dataset
    window_s : float
        Window length [s].
    use_adsb : bool
        Use the ADS-B reports (else cross-radar pairs only).
    random_walk_per_sqrt_s : mapping, optional
        Rate per term name (``range_offset``, ...) [SI per sqrt(s)], for every radar.
    estimate_rates : bool
        Estimate the rates not given from the data.
    robust : str
        Robust kernel of the measurement factors.
    max_iterations : int
        Levenberg-Marquardt limit.

    Raises
    ------
    EstimationError
        When no window has data for any radar.
    ValueError
        For pressure altitudes (not yet windowed) or a bad window.
    """
    if dataset.pressure_altitudes:
        raise ValueError("pressure altitudes are not yet calibrated in windows; "
                         "calibrate without --window")
    given = dict(random_walk_per_sqrt_s or {})
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    have_adsb = use_adsb and dataset.adsb is not None and len(dataset.adsb) > 0
    terms = {rid: radar_terms(dataset.sites[rid], {}, False) for rid in dataset.radar_ids}
    priors = {rid: prior_sigmas(dataset.sites[rid], terms[rid]) for rid in dataset.radar_ids}
    kernel = RobustKernel(robust)
    windows = list(split_windows(dataset, window_s))
    fg, chain = _build(windows, dataset, terms, priors, have_adsb, kernel)
    timing["factors_s"] = time.perf_counter() - t0
    if not any(chain.values()):
        raise EstimationError("nothing to calibrate in any window: no plot matched ADS-B and "
                              "no two radars saw the same aircraft")
    rates = {rid: {name: given.get(name, DEFAULT_RANDOM_WALK_PER_SQRT_S[name])
                   for name in terms[rid].free} for rid in chain}
    iterations = 0
    if estimate_rates:
        t0 = time.perf_counter()
        independent = fg.optimize(max_iterations=max_iterations)
        iterations += independent.iterations
        keys = [key for links in chain.values() for _, key in links]
        covariances = dict(zip(keys, fg.marginal_covariances(independent.values, keys),
                               strict=True))
        for rid, links in chain.items():
            middles = np.array([w.middle_s for w, _ in links])
            values = np.array([independent.vector(key) for _, key in links])
            variances = np.array([np.diag(covariances[key]) for _, key in links])
            for j, name in enumerate(terms[rid].free):
                if name not in given and len(links) >= 3:
                    rates[rid][name] = random_walk_rate(middles, values[:, j], variances[:, j])
        timing["rates_s"] = time.perf_counter() - t0
    for rid, links in chain.items():
        n_free = len(terms[rid].free)
        # A rate of 0 (a constant term) is held by a tight but finite walk.
        floor = 1e-2 * np.array([DEFAULT_RANDOM_WALK_PER_SQRT_S[n] for n in terms[rid].free])
        q = np.maximum(np.array([rates[rid][name] for name in terms[rid].free]), floor)
        for (w_a, k_a), (w_b, k_b) in zip(links, links[1:], strict=False):
            sigma = q * np.sqrt(max(w_b.middle_s - w_a.middle_s, 1e-9))
            block = np.diag(1.0 / sigma)
            fg.add_linear([k_a, k_b], [-block, block], np.zeros(n_free))
    t0 = time.perf_counter()
    result = fg.optimize(max_iterations=max_iterations)
    iterations += result.iterations
    timing["optimisation_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    all_keys = [key for links in chain.values() for _, key in links]
    covariances = dict(zip(all_keys, fg.marginal_covariances(result.values, all_keys),
                           strict=True))
    series: dict[str, list[WindowEstimate]] = {}
    for rid, links in chain.items():
        entries = []
        for window, key in links:
            cov = covariances[key]
            bias = terms[rid].bias(result.vector(key))
            sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
            sigma = {CONTRACT_KEYS[name][0]: float(v) * CONTRACT_KEYS[name][1]
                     for name, v in zip(terms[rid].free, sd, strict=True)}
            n = int((window.dataset.plots["radar_id"] == rid).sum())
            entries.append(WindowEstimate(window.t_start_s, window.t_end_s, n, bias, sigma,
                                          cov))
        if entries:
            series[rid] = entries
    timing["marginals_s"] = time.perf_counter() - t0
    return WindowedCalibration(window_s, terms, series, iterations, timing,
                               {rid: rates[rid] for rid in series})


__all__ = ["DEFAULT_RANDOM_WALK_PER_SQRT_S", "WindowEstimate", "WindowedCalibration",
           "random_walk_rate", "windowed_graph"]
