"""Biases over time: each window's data reduced to a summary, the summaries chained.

Contract v2's ``--window``.  The recording is cut into windows
(:func:`graphcal.data.windows.split_windows`, or read window by window from files).

1. **Summaries** (:func:`summarise_window`, independent work that can run anywhere).
   Each window is calibrated on its own by the :func:`~graphcal.solvers.graph.graph`
   estimator: aligned, paired, solved with weak priors, its nuisance variables (the
   height model of pressure altitudes, target states) eliminated, its covariance
   corrected for plots shared between pairs.  What is kept is a Gaussian on the
   window's bias variables: its estimate ``y_k`` and covariance ``P_k``.  A radar
   with fewer than :data:`MIN_WINDOW_PLOTS` plots in a window is left out of it.  With the
   weak priors ``Pi`` (mean 0) taken out again, the window's data say
   ``1/2 d^T L_k d - d^T eta_k`` about ``d = x - y_k``, with ``L_k = P_k^-1 - Pi^-1``
   and ``eta_k = Pi^-1 y_k`` (the gradient the priors balanced).  The time offsets
   are estimated in every window with ADS-B where its traffic determines them
   (the ``graph`` estimator's automatic choice); the chain pools them.
2. **Rates and steps** (:func:`graphcal.solvers.drift.analyse_chain`).  From each
   radar's chain of independent window estimates: each term's random-walk rate
   (maximum likelihood), and the steps beyond it.
3. **The chain** (:func:`smooth_windows`).  One bias vector per radar and window;
   the summaries; one weak prior at the start of each radar's chain and after each
   step; and random-walk factors between consecutive windows of a radar::

       x_{k+1} - x_k ~ N(0, diag(q^2) (t_{k+1} - t_k))

   with ``t_k`` the windows' middles.  Everything is linear, so one solve gives the
   smoothed chain (each window's estimate uses every window's data) and GTSAM's
   marginals each window's 1-sigma.  A window's estimate is of the radar's mean
   bias over the window.

Each summary is linearised at its own window's estimate.  The measurement model is
nearly linear in the biases (the largest second-order term, range x gain x azimuth,
is below a millimetre for a 1 mrad, 1e-4 move at 200 km), so the summaries are not
re-linearised; :attr:`WindowedCalibration.largest_move` reports how far the smoothed
chain moved each summary's variables from their linearisation point, in that
window's own sigmas.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graphcal.core.errors import EstimationError
from graphcal.core.solve_options import SolveOptions
from graphcal.data.bias import CONTRACT_KEYS, RadarBias
from graphcal.data.dataset import Dataset, Site
from graphcal.data.height import HeightModelEstimate
from graphcal.data.windows import Window, split_windows
from graphcal.model.parameters import TERM_NAMES, RadarTerms, prior_sigmas
from graphcal.model.problem import build_problem
from graphcal.solvers.drift import DEFAULT_STEP_FALSE_ALARM, ChainAnalysis, analyse_chain
from graphcal.solvers.gtsam_adapter import FactorGraph, symbol
from graphcal.solvers.window_fit import WindowFit, window_fit

FloatArray = NDArray[np.float64]

#: Default random-walk rates per term [SI unit per sqrt(s)], from a change of this
#: size per sqrt(hour): range offset 2 m, range gain 2e-6, azimuth and elevation
#: 0.05 mrad, eccentricity 0.02 mrad, time offset 5 ms.  Used where a rate is
#: neither given nor estimated (``estimate_rates=False``); an estimated rate is
#: never below 1 % of these (a constant is held by a tight but finite walk).
DEFAULT_RANDOM_WALK_PER_SQRT_S: dict[str, float] = {
    "range_offset": 2.0 / 60.0,
    "range_gain": 2e-6 / 60.0,
    "azimuth_bias": 0.05e-3 / 60.0,
    "elevation_bias": 0.05e-3 / 60.0,
    "time_offset": 5e-3 / 60.0,
    "azimuth_sin": 0.02e-3 / 60.0,
    "azimuth_cos": 0.02e-3 / 60.0,
}

#: A radar with fewer plots in a window is left out of that window: so few plots
#: do not determine its biases (and a time offset from them is far from Gaussian).
MIN_WINDOW_PLOTS = 100

#: Floor of an estimated rate, as a fraction of the default.
RATE_FLOOR_FRACTION = 1e-2

#: Largest whitening of a random-walk factor between neighbouring windows, in units of
#: the chain's scale (:func:`chain_scale`, a window's sigma): a walk of a hundredth of
#: a window's sigma per window holds a bias as constant as any slower one would (over
#: 100 windows it allows 0.1 sigma), while stiffer links make the chain's information
#: matrix too ill-conditioned for GTSAM's multifrontal Cholesky factorisation
#: (``IndeterminateLinearSystemException`` on a two-window recording).
MAX_RANDOM_WALK_STIFFNESS = 100.0


# --------------------------------------------------------------------------- summaries
#: How each window is calibrated: the estimators' option table (graph's options).
WindowOptions = SolveOptions
#: The command line's options (frozen: shared as a default argument).
DEFAULT_OPTIONS = SolveOptions()


@dataclass
class WindowSummary:
    """One window's data reduced to a Gaussian on its bias variables (module docstring).

    Plain numbers only, so it travels between processes and machines.

    Attributes
    ----------
    index, t_start_s, t_end_s : int, float, float
        The window (:class:`graphcal.data.windows.Window`).
    labels : list of (radar_id, term name)
        The window's free terms, in the order of ``estimate``.
    estimate : ndarray
        The window's own estimate ``y_k`` (SI), with the weak priors.
    covariance : ndarray
        Its covariance ``P_k`` (SI).
    prior_sigma : ndarray
        The weak priors' sigmas (SI, mean 0).
    n_plots : dict
        Plots of each radar used in the window.
    warnings : list of str
        The window's own warnings.
    atmosphere : HeightModelEstimate or None
        The window's height model of pressure altitudes.
    elapsed_s : float
        Time the summary took.
    cost : float
        The window's final robust cost ``1/2 sum e^2`` (whitened errors, priors included).
    fit : WindowFit or None
        What the fit verdict needs of the window's own fit
        (:func:`graphcal.solvers.window_fit.window_fit`); ``None`` when not asked for.
    """

    index: int
    t_start_s: float
    t_end_s: float
    labels: list[tuple[str, str]]
    estimate: FloatArray
    covariance: FloatArray
    prior_sigma: FloatArray
    n_plots: dict[str, int]
    warnings: list[str] = field(default_factory=list)
    atmosphere: HeightModelEstimate | None = None
    elapsed_s: float = 0.0
    cost: float = 0.0
    fit: WindowFit | None = None
    #: Plots without an address associated before the window's calibration: radar id ->
    #: :meth:`graphcal.tracking.association.RadarAssociation.to_dict` (None: none lacked one).
    association: dict[str, dict[str, Any]] | None = None

    @property
    def middle_s(self) -> float:
        """Middle of the window [s]."""
        return 0.5 * (self.t_start_s + self.t_end_s)

    def data_information(self) -> tuple[FloatArray, FloatArray]:
        """``(L_k, eta_k)``: what the window's data alone say about ``x - estimate``."""
        prior_information = self.prior_sigma ** -2.0
        information = np.linalg.inv(self.covariance)
        information = 0.5 * (information + information.T) - np.diag(prior_information)
        return information, prior_information * self.estimate


def summarise_window(window: Window, options: WindowOptions = DEFAULT_OPTIONS, *,
                     judge: bool = True) -> WindowSummary | None:
    """Calibrate one window on its own and keep its Gaussian summary.

    With ``judge``, the summary also carries what the fit verdict needs of the
    window's fit (:attr:`WindowSummary.fit`, :mod:`graphcal.solvers.window_fit`).
    Returns ``None`` when the window has nothing to calibrate (no plot matched
    ADS-B and no two radars saw the same aircraft).
    """
    return _summarise_window(window, options, judge)


def _summarise_window(window: Window, options: WindowOptions, judge: bool
                      ) -> WindowSummary | None:
    from graphcal.solvers.graph import graph

    start = time.perf_counter()
    dataset = window.dataset
    have_adsb = bool(options.use_adsb and dataset.adsb is not None and len(dataset.adsb))
    counts = dataset.plots["radar_id"].value_counts()
    few = set(counts.index[counts < MIN_WINDOW_PLOTS])
    if few:
        dataset = replace(dataset, plots=dataset.plots[~dataset.plots["radar_id"].isin(few)])
    if dataset.plots.empty:
        return None
    # One problem for the estimate and its fit numbers: the alignments with ADS-B are
    # made once.
    problem = build_problem(dataset, options)
    try:
        cal = graph(problem, cross=options.cross, robust=options.robust,
                    robust_scale=options.robust_scale, use_adsb=options.use_adsb,
                    fixed=dict(options.fixed), max_iterations=options.max_iterations,
                    max_gap_s=options.adsb_max_gap_s, pair_max_gap_s=options.pair_max_gap_s,
                    time_offset=None if have_adsb and options.cross != "target-state"
                    else False, bound=False, summarise_residuals=False, fit_on_paths=judge)
    except EstimationError:
        return None
    labels = list(cal.labels)
    prior = np.concatenate([
        prior_sigmas(dataset.sites[rid], RadarTerms(rid, (name,), {})) for rid, name in labels
    ]) if labels else np.zeros(0)
    fit = (window_fit(problem, cal, use_adsb=options.use_adsb,
                      max_gap_s=options.adsb_max_gap_s)
           if judge else None)
    return WindowSummary(
        window.index, window.t_start_s, window.t_end_s, labels,
        np.asarray(cal.estimate, dtype=float), np.asarray(cal.covariance, dtype=float),
        prior, {rid: int(cal.n_plots.get(rid, 0)) for rid in cal.radar_ids},
        list(cal.warnings), cal.atmosphere, time.perf_counter() - start,
        float(cal.info.get("final_error", 0.0)), fit)


# --------------------------------------------------------------------------- the chain
@dataclass
class WindowEstimate:
    """One radar's biases in one window: the smoothed mean over the window."""

    t_start_s: float
    t_end_s: float
    n_plots: int
    bias: RadarBias
    sigma: dict[str, float]  # contract key -> 1-sigma, contract units
    covariance: FloatArray  # over the radar's chain terms, SI


@dataclass
class BiasEvent:
    """A change of a radar's biases beyond the random walk (contract ``events``).

    ``kind`` is ``"step"`` (found in the data) or ``"break"`` (declared by the user).
    ``size`` and ``sigma`` are in contract units, over the terms that moved.
    """

    radar_id: str
    time_s: float
    kind: str
    parameters: list[str]
    size: dict[str, float]
    sigma: dict[str, float]
    statistic: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The contract's ``events`` entry."""
        entry: dict[str, Any] = {"radar_id": self.radar_id, "time_s": self.time_s,
                                 "kind": self.kind, "parameters": list(self.parameters),
                                 "size": dict(self.size), "sigma": dict(self.sigma)}
        if self.statistic is not None:
            entry["statistic"] = self.statistic
        return entry


@dataclass
class WindowedCalibration:
    """The chain's result: per radar, its windows in time order.

    Attributes
    ----------
    window_s : float
    terms : dict
        Each radar's chain terms (:class:`~graphcal.model.parameters.RadarTerms`).
    series : dict
        Radar id -> its :class:`WindowEstimate` per window.
    events : list of BiasEvent
    rates : dict
        Radar id -> term -> random-walk rate used [SI per sqrt(s)].
    last_labels, last_estimate, last_covariance
        Every radar's last window, jointly: ``(radar, term)`` labels, the smoothed
        estimate (SI) and the joint covariance (SI).
    largest_move : float
        How far the smoothed chain moved a summary's variables from its
        linearisation point, in that window's own sigmas (largest over windows).
    summaries : list of WindowSummary
    timing_s : dict
    """

    window_s: float
    terms: dict[str, RadarTerms]
    series: dict[str, list[WindowEstimate]]
    events: list[BiasEvent]
    rates: dict[str, dict[str, float]]
    last_labels: list[tuple[str, str]]
    last_estimate: FloatArray
    last_covariance: FloatArray
    largest_move: float
    summaries: list[WindowSummary]
    timing_s: dict[str, float] = field(default_factory=dict)
    step_false_alarm: float = DEFAULT_STEP_FALSE_ALARM

    def last(self, radar_id: str) -> WindowEstimate:
        """The radar's last window: the correction to apply from now on."""
        return self.series[radar_id][-1]


@dataclass
class _Chain:
    """One radar's windows: which summaries, and where its terms sit in each."""

    radar_id: str
    names: tuple[str, ...]
    entries: list[tuple[int, list[int | None]]]  # (summary number, position per name)

    def independent(self, summaries: Sequence[WindowSummary]
                    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Middles, estimates and variances of each window alone (nan where absent)."""
        n, m = len(self.entries), len(self.names)
        middles = np.empty(n)
        values = np.full((n, m), np.nan)
        variances = np.full((n, m), np.nan)
        for row, (s, positions) in enumerate(self.entries):
            middles[row] = summaries[s].middle_s
            for col, pos in enumerate(positions):
                if pos is not None:
                    values[row, col] = summaries[s].estimate[pos]
                    variances[row, col] = summaries[s].covariance[pos, pos]
        return middles, values, variances


def _chains(summaries: Sequence[WindowSummary]) -> dict[str, _Chain]:
    names: dict[str, set[str]] = {}
    for summary in summaries:
        for rid, name in summary.labels:
            names.setdefault(rid, set()).add(name)
    chains = {rid: _Chain(rid, tuple(n for n in TERM_NAMES if n in found), [])
              for rid, found in names.items()}
    for s, summary in enumerate(summaries):
        where = {label: i for i, label in enumerate(summary.labels)}
        for rid in dict.fromkeys(rid for rid, _ in summary.labels):
            chain = chains[rid]
            chain.entries.append((s, [where.get((rid, name)) for name in chain.names]))
    return chains


def declared_cuts(middles: FloatArray, starts: FloatArray, ends: FloatArray,
                  break_times_s: Sequence[float]) -> list[int]:
    """Links of a chain cut by declared change times.

    A time on a window boundary (or in a gap between windows) cuts the link there;
    a time inside a window isolates that window (cuts on both sides).
    """
    cuts: set[int] = set()
    for when in break_times_s:
        inside = np.flatnonzero((starts < when) & (when < ends))
        if len(inside):
            k = int(inside[0])
            cuts.update(c for c in (k - 1, k) if 0 <= c < len(middles) - 1)
            continue
        after = int(np.searchsorted(starts, when, side="left"))
        if 0 < after < len(middles):
            cuts.add(after - 1)
    return sorted(cuts)


def chain_scale(summary: WindowSummary, radar_id: str, names: Sequence[str],
                prior: FloatArray) -> FloatArray:
    """Units of a radar's chain variables: its first window's sigmas, per term.

    The chain is solved for ``bias / scale`` so that every variable is of order one:
    in SI units a range gain (1e-5) and a range offset (10 m) differ by six orders
    of magnitude, and a slow random walk on the gain then makes the information
    matrix too ill-conditioned for GTSAM's Cholesky factorisation.  ``prior`` (the
    weak prior's sigmas) stands in for a term the window did not estimate.
    """
    where = {label: i for i, label in enumerate(summary.labels)}
    scale = np.array(prior, dtype=float)
    for col, name in enumerate(names):
        pos = where.get((radar_id, name))
        if pos is not None and summary.covariance[pos, pos] > 0:
            scale[col] = np.sqrt(summary.covariance[pos, pos])
    return scale


def random_walk_block(rates_per_sqrt_s: FloatArray, dt_s: float,
                      scale: FloatArray) -> FloatArray:
    """Whitened Jacobian block of a random-walk factor between two scaled chain variables:
    ``diag(scale / (rate sqrt(dt)))`` (:func:`chain_scale`), at most
    :data:`MAX_RANDOM_WALK_STIFFNESS`."""
    stiffness = scale / (rates_per_sqrt_s * np.sqrt(max(dt_s, 1e-9)))
    return np.diag(np.minimum(stiffness, MAX_RANDOM_WALK_STIFFNESS))


@dataclass
class _ChainSolution:
    """The solved chain in SI units: GTSAM's values and marginals, scaled back."""

    fg: FactorGraph
    solved: Any  # the OptimizationResult of FactorGraph.solve_linear
    scale: Mapping[int, FloatArray]

    def vector(self, key: int) -> FloatArray:
        return self.scale[key] * self.solved.vector(key)

    def joint_covariance(self, keys: Sequence[int]) -> FloatArray:
        d = np.concatenate([self.scale[k] for k in keys])
        return self.fg.joint_covariance(self.solved.values, keys) * np.outer(d, d)

    def marginal_covariances(self, keys: Sequence[int]) -> list[FloatArray]:
        return [c * np.outer(self.scale[k], self.scale[k])
                for k, c in zip(keys, self.fg.marginal_covariances(self.solved.values, keys),
                                strict=True)]


def smooth_windows(
    summaries: Sequence[WindowSummary],
    sites: Mapping[str, Site],
    window_s: float,
    *,
    random_walk_per_sqrt_s: Mapping[str, float] | None = None,
    estimate_rates: bool = True,
    breaks: Mapping[str, Sequence[float]] | None = None,
    detect_steps: bool = True,
    step_false_alarm: float = DEFAULT_STEP_FALSE_ALARM,
    found_steps: Mapping[str, Sequence[tuple[float, float | None]]] | None = None,
) -> WindowedCalibration:
    """Chain the windows' summaries and smooth them (module docstring).

    The parts of a split window are merged back in the series (the duration-weighted
    mean of the parts, with its covariance from their joint marginal), except in
    the last window, whose last part is what applies from now on.

    Parameters
    ----------
    summaries : sequence of WindowSummary
        In time order (``None`` entries already dropped).
    sites : mapping
        The radars' sites (for the weak priors).
    window_s : float
        Window length [s].
    random_walk_per_sqrt_s : mapping, optional
        Rate per term name [SI per sqrt(s)] for every radar; these are not estimated.
    estimate_rates : bool
        Estimate the other rates from the data (else
        :data:`DEFAULT_RANDOM_WALK_PER_SQRT_S`).
    breaks : mapping, optional
        Radar id -> times [s] of known changes (maintenance): the chain is cut there.
    detect_steps : bool
        Search for steps beyond the random walk.
    step_false_alarm : float
        Chance of one false step per radar and recording.
    found_steps : mapping, optional
        Radar id -> ``(time_s, statistic)`` of steps found by an earlier pass, whose
        window has since been split at that time (parts of one window share its
        ``index``): the chain is cut there and the event keeps kind ``"step"``.


    Raises
    ------
    EstimationError
        When no window has anything to calibrate.
    """
    if not summaries:
        raise EstimationError("nothing to calibrate in any window: no plot matched ADS-B and "
                              "no two radars saw the same aircraft")
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    given = dict(random_walk_per_sqrt_s or {})
    breaks = dict(breaks or {})
    known: dict[str, list[tuple[float, str, float | None]]] = {}
    for rid, times in breaks.items():
        known.setdefault(rid, []).extend((float(t), "break", None) for t in times)
    for rid, steps in (found_steps or {}).items():
        known.setdefault(rid, []).extend((float(t), "step", stat) for t, stat in steps)
    chains = _chains(summaries)
    analyses: dict[str, ChainAnalysis] = {}
    rates: dict[str, dict[str, float]] = {}
    for rid, chain in chains.items():
        middles, values, variances = chain.independent(summaries)
        starts = np.array([summaries[s].t_start_s for s, _ in chain.entries])
        ends = np.array([summaries[s].t_end_s for s, _ in chain.entries])
        given_rates = np.array([
            given.get(name, np.nan if estimate_rates else DEFAULT_RANDOM_WALK_PER_SQRT_S[name])
            for name in chain.names])
        analysis = analyse_chain(
            middles, values, variances, given_rates=given_rates,
            declared_cuts=declared_cuts(middles, starts, ends,
                                        [t for t, _, _ in known.get(rid, ())]),
            detect_steps=detect_steps, false_alarm=step_false_alarm)
        floor = RATE_FLOOR_FRACTION * np.array(
            [DEFAULT_RANDOM_WALK_PER_SQRT_S[n] for n in chain.names])
        is_given = np.isfinite(given_rates)
        analysis.rates = np.where(is_given, analysis.rates, np.maximum(analysis.rates, floor))
        analyses[rid] = analysis
        rates[rid] = dict(zip(chain.names, analysis.rates.tolist(), strict=True))
    timing["rates_and_steps_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fg, keys, scale = _chain_graph(summaries, chains, analyses, sites)
    result = _ChainSolution(fg, fg.solve_linear(), scale)
    timing["smoothing_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    every_key = [key for chain_keys in keys.values() for key in chain_keys]
    marginals = dict(zip(every_key, result.marginal_covariances(every_key), strict=True))
    terms = {rid: RadarTerms(rid, chain.names, {}) for rid, chain in chains.items()}
    series = {rid: _series(rid, chains[rid], keys[rid], terms[rid], summaries, result,
                           marginals)
              for rid in chains}
    events = [event for rid in chains
              for event in _events(rid, chains[rid], keys[rid], analyses[rid], summaries,
                                   result, known.get(rid, ()))]
    last_keys = [keys[rid][-1] for rid in chains]
    last_labels = [(rid, name) for rid in chains for name in chains[rid].names]
    last_covariance = result.joint_covariance(last_keys)
    last_estimate = np.concatenate([result.vector(k) for k in last_keys])
    timing["marginals_s"] = time.perf_counter() - t0
    return WindowedCalibration(
        window_s, terms, series, sorted(events, key=lambda e: (e.time_s, e.radar_id)), rates,
        last_labels, last_estimate, last_covariance,
        _largest_move(summaries, chains, keys, result), list(summaries), timing,
        step_false_alarm)


def _chain_graph(summaries: Sequence[WindowSummary], chains: Mapping[str, _Chain],
                 analyses: Mapping[str, ChainAnalysis], sites: Mapping[str, Site]
                 ) -> tuple[FactorGraph, dict[str, list[int]], dict[int, FloatArray]]:
    """Variables, summaries, priors and random walks of every chain, in the units of
    :func:`chain_scale` (returned per key)."""
    fg = FactorGraph()
    keys: dict[str, list[int]] = {}
    counter = 0
    key_of: dict[tuple[int, str], int] = {}
    scales: dict[str, FloatArray] = {}
    scale_of: dict[int, FloatArray] = {}
    for rid, chain in chains.items():
        keys[rid] = []
        prior = prior_sigmas(sites[rid], RadarTerms(rid, chain.names, {}))
        scale = scales[rid] = chain_scale(summaries[chain.entries[0][0]], rid, chain.names,
                                          prior)
        analysis = analyses[rid]
        for row, (s, positions) in enumerate(chain.entries):
            key = symbol("w", counter)
            counter += 1
            keys[rid].append(key)
            key_of[(s, rid)] = key
            scale_of[key] = scale
            start = np.array([summaries[s].estimate[p] if p is not None else 0.0
                              for p in positions])
            fg.add_variable(key, start / scale)
            if row == 0 or (row - 1) in analysis.cuts:
                fg.add_prior(key, np.zeros(len(chain.names)), prior / scale)
            else:
                dt = summaries[s].middle_s - summaries[chain.entries[row - 1][0]].middle_s
                block = random_walk_block(analysis.rates, dt, scale)
                fg.add_linear([keys[rid][row - 1], key], [-block, block],
                              np.zeros(len(chain.names)))
    for s, summary in enumerate(summaries):
        if not summary.labels:
            continue
        radars, big, big_vector, points = embed_summary(
            summary, {rid: chains[rid].names for rid in
                      dict.fromkeys(rid for rid, _ in summary.labels)}, scales)
        fg.add_gaussian([key_of[(s, rid)] for rid in radars], big, big_vector, points)
    return fg, keys, scale_of


def embed_summary(summary: WindowSummary, names: Mapping[str, Sequence[str]],
                  scales: Mapping[str, FloatArray] | None = None
                  ) -> tuple[list[str], FloatArray, FloatArray, list[FloatArray]]:
    """A summary laid out on its radars' chain vectors, ready for ``add_gaussian``.

    ``names`` gives each of the summary's radars its chain terms (in order); terms
    the window did not estimate get no information from it.  Returns the radars,
    the information matrix and vector over their stacked vectors, and each radar's
    linearisation point (the window's estimate, 0 where not estimated); with
    ``scales`` (radar id -> :func:`chain_scale`), all of them for the scaled
    variables ``bias / scale``.
    """
    radars = list(names)
    where = {label: i for i, label in enumerate(summary.labels)}
    edges = np.concatenate([[0], np.cumsum([len(names[rid]) for rid in radars])])
    index = np.empty(len(summary.labels), dtype=int)
    points = []
    for r, rid in enumerate(radars):
        point = np.zeros(len(names[rid]))
        for col, name in enumerate(names[rid]):
            pos = where.get((rid, name))
            if pos is not None:
                index[pos] = edges[r] + col
                point[col] = summary.estimate[pos]
        points.append(point)
    information, vector = summary.data_information()
    big = np.zeros((edges[-1], edges[-1]))
    big[np.ix_(index, index)] = information
    big_vector = np.zeros(edges[-1])
    big_vector[index] = vector
    if scales is not None:
        d = np.concatenate([scales[rid] for rid in radars])
        big *= np.outer(d, d)
        big_vector *= d
        points = [point / scales[rid] for rid, point in zip(radars, points, strict=True)]
    return radars, big, big_vector, points


def window_estimate(summary: WindowSummary, rid: str, terms: RadarTerms, value: FloatArray,
                    covariance: FloatArray, reported: Sequence[str] | None = None
                    ) -> WindowEstimate:
    """One radar's :class:`WindowEstimate` from its chain value and covariance (SI);
    sigmas of the terms in ``reported`` (default: all)."""
    sd = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    sigma = {CONTRACT_KEYS[name][0]: float(v) * CONTRACT_KEYS[name][1]
             for name, v in zip(terms.free, sd, strict=True)
             if reported is None or name in reported}
    return WindowEstimate(summary.t_start_s, summary.t_end_s, summary.n_plots.get(rid, 0),
                          terms.bias(value), sigma, covariance)


def _series(rid: str, chain: _Chain, keys: list[int], terms: RadarTerms,
            summaries: Sequence[WindowSummary], result: _ChainSolution,
            marginals: Mapping[int, FloatArray]) -> list[WindowEstimate]:
    """The radar's windows; the parts of a split window merged (not in the last window)."""
    groups: list[list[int]] = []
    for row, (s, _) in enumerate(chain.entries):
        if groups and summaries[chain.entries[groups[-1][-1]][0]].index == summaries[s].index:
            groups[-1].append(row)
        else:
            groups.append([row])
    out = []
    for g, rows in enumerate(groups):
        parts = [summaries[chain.entries[row][0]] for row in rows]
        if len(rows) == 1 or g == len(groups) - 1:
            row = rows[-1]
            out.append(window_estimate(parts[-1], rid, terms, result.vector(keys[row]),
                                        marginals[keys[row]]))
            continue
        durations = np.array([p.t_end_s - p.t_start_s for p in parts])
        weights = durations / durations.sum()
        m = len(chain.names)
        joint = result.joint_covariance([keys[row] for row in rows])
        mix = np.kron(weights[None, :], np.eye(m))
        value = mix @ np.concatenate([result.vector(keys[row]) for row in rows])
        merged = replace(parts[0], t_end_s=parts[-1].t_end_s,
                         n_plots={rid: sum(p.n_plots.get(rid, 0) for p in parts)})
        out.append(window_estimate(merged, rid, terms, value, mix @ joint @ mix.T))
    return out


def _events(rid: str, chain: _Chain, keys: list[int], analysis: ChainAnalysis,
            summaries: Sequence[WindowSummary], result: _ChainSolution,
            known: Sequence[tuple[float, str, float | None]]) -> list[BiasEvent]:
    """One event per cut (an isolated window, cut on both sides, is one step in it)."""
    events: list[BiasEvent] = []
    cuts = list(analysis.cuts)
    middles = np.array([summaries[s].middle_s for s, _ in chain.entries])
    starts = np.array([summaries[s].t_start_s for s, _ in chain.entries])
    ends = np.array([summaries[s].t_end_s for s, _ in chain.entries])
    by_link: dict[int, tuple[float, str, float | None]] = {}
    for entry in known:
        for link in declared_cuts(middles, starts, ends, [entry[0]]):
            by_link[link] = entry
    i = 0
    while i < len(cuts):
        link = cuts[i]
        isolated = i + 1 < len(cuts) and cuts[i + 1] == link + 1
        before, after = link, link + (2 if isolated else 1)
        a, b = keys[before], keys[after]
        joint = result.joint_covariance([a, b])
        m = len(chain.names)
        change = result.vector(b) - result.vector(a)
        change_cov = joint[:m, :m] + joint[m:, m:] - joint[:m, m:] - joint[m:, :m]
        change_sd = np.sqrt(np.clip(np.diag(change_cov), 1e-300, None))
        z = np.abs(change) / change_sd
        moved = [j for j in range(m) if z[j] > 3.0] or [int(np.argmax(z))]
        if isolated:
            middle = result.vector(keys[link + 1])
            j = moved[int(np.argmax(z[moved]))]
            fraction = float(np.clip((middle[j] - result.vector(a)[j]) / change[j], 0.0, 1.0))
            window = summaries[chain.entries[link + 1][0]]
            when = window.t_end_s - fraction * (window.t_end_s - window.t_start_s)
        else:
            when = 0.5 * (ends[link] + starts[link + 1])
        kind, statistic = "step", analysis.statistics.get(link)
        if link in by_link:
            when, kind, statistic = by_link[link]
        names = [chain.names[j] for j in moved]
        events.append(BiasEvent(
            rid, float(when), kind, [CONTRACT_KEYS[n][0] for n in names],
            {CONTRACT_KEYS[n][0]: float(change[chain.names.index(n)]) * CONTRACT_KEYS[n][1]
             for n in names},
            {CONTRACT_KEYS[n][0]: float(change_sd[chain.names.index(n)]) * CONTRACT_KEYS[n][1]
             for n in names},
            statistic))
        i += 2 if isolated else 1
    return events


def _largest_move(summaries: Sequence[WindowSummary], chains: Mapping[str, _Chain],
                  keys: Mapping[str, list[int]], result: _ChainSolution) -> float:
    largest = 0.0
    for rid, chain in chains.items():
        for (s, positions), key in zip(chain.entries, keys[rid], strict=True):
            value = result.vector(key)
            summary = summaries[s]
            for col, pos in enumerate(positions):
                if pos is not None:
                    sd = np.sqrt(summary.covariance[pos, pos])
                    largest = max(largest, abs(value[col] - summary.estimate[pos]) / sd)
    return float(largest)


def windowed_graph(
    dataset: Dataset,
    window_s: float,
    *,
    options: WindowOptions = DEFAULT_OPTIONS,
    **chain_options: Any,
) -> WindowedCalibration:
    """Calibrate biases per time window, in memory and in this process.

    :func:`summarise_window` on each of :func:`~graphcal.data.windows.split_windows`,
    then :func:`smooth_windows` (``chain_options`` are its keyword arguments).
    """
    t0 = time.perf_counter()
    summaries = [s for w in split_windows(dataset, window_s)
                 if (s := summarise_window(w, options)) is not None]
    elapsed = time.perf_counter() - t0
    result = smooth_windows(summaries, dataset.sites, window_s, **chain_options)
    result.timing_s["summaries_s"] = elapsed
    return result


# --------------------------------------------------------------------------- constant biases
@dataclass
class ConstantBiases:
    """Constant biases over a whole recording, from its windows' summaries.

    Attributes
    ----------
    labels : list of (radar_id, term name)
        Every term some window estimates, radars in the dataset's order.
    estimate, covariance : ndarray
        The joint estimate and covariance (SI), the weak priors counted once.
    information : ndarray
        The data's information (the priors taken out).
    n_plots : dict
        Plots of each radar, summed over the windows.
    n_windows : int
    atmosphere : HeightModelEstimate or None
        The windows' height models combined (inverse-variance weighted).
    """

    labels: list[tuple[str, str]]
    estimate: FloatArray
    covariance: FloatArray
    information: FloatArray
    n_plots: dict[str, int]
    n_windows: int
    atmosphere: HeightModelEstimate | None


def constant_biases(summaries: Sequence[WindowSummary], sites: Mapping[str, Site]
                    ) -> ConstantBiases:
    """The chain with no random walk: one bias vector for the whole recording.

    Window ``k``'s data say ``1/2 (x - y_k)^T L_k (x - y_k) - (x - y_k)^T eta_k``
    (:meth:`WindowSummary.data_information`); the sum over the windows plus the weak
    priors ``1/2 x^T Pi^-1 x`` is minimised by

        (sum_k L_k + Pi^-1) x = sum_k (L_k y_k + eta_k),

    whose inverse matrix is the covariance.  Each summary is linearised at its own
    window's estimate; the model is nearly linear in the biases, so the result is
    that of one batch over every window to first order, in the memory of one window.
    A term a window does not estimate (a time offset its traffic does not determine)
    takes its information from the other windows.
    """
    if not summaries:
        raise EstimationError("no window had anything to calibrate")
    order = {rid: i for i, rid in enumerate(sites)}
    labels = sorted({label for s in summaries for label in s.labels},
                    key=lambda lab: (order.get(lab[0], len(order)), TERM_NAMES.index(lab[1])))
    index = {label: i for i, label in enumerate(labels)}
    p = len(labels)
    prior = np.zeros(p)
    information = np.zeros((p, p))
    vector = np.zeros(p)
    n_plots: dict[str, int] = {}
    for summary in summaries:
        cols = [index[label] for label in summary.labels]
        data, eta = summary.data_information()
        information[np.ix_(cols, cols)] += data
        vector[cols] += data @ summary.estimate + eta
        prior[cols] = summary.prior_sigma
        for rid, n in summary.n_plots.items():
            n_plots[rid] = n_plots.get(rid, 0) + int(n)
    total = information + np.diag(prior ** -2.0)
    scale = np.sqrt(np.diag(total))
    covariance = np.linalg.inv(total / np.outer(scale, scale)) / np.outer(scale, scale)
    covariance = 0.5 * (covariance + covariance.T)
    return ConstantBiases(labels, covariance @ vector, covariance, information, n_plots,
                          len({s.index for s in summaries}),
                          _combined_atmosphere([s.atmosphere for s in summaries]))


def _combined_atmosphere(models: list[HeightModelEstimate | None]) -> HeightModelEstimate | None:
    """Inverse-variance weighted height models of the windows (their cross-covariances
    with the radar terms left out)."""
    models = [m for m in models if m is not None and m.determined]
    if not models:
        return None
    weights = [np.linalg.inv(np.asarray(m.covariance)) for m in models]
    total = sum(weights)
    covariance = np.linalg.inv(total)
    value = covariance @ sum(w @ np.array([m.height_offset_m, m.height_scale])
                             for w, m in zip(weights, models, strict=True))
    first = models[0]
    return replace(first, height_offset_m=float(value[0]), height_scale=float(value[1]),
                   covariance=covariance, cross_labels=[],
                   cross_covariance=np.zeros((0, 2)),
                   n_adsb_segments=sum(m.n_adsb_segments for m in models),
                   n_pressure_pairs=sum(m.n_pressure_pairs for m in models))


__all__ = ["DEFAULT_RANDOM_WALK_PER_SQRT_S", "MIN_WINDOW_PLOTS", "RATE_FLOOR_FRACTION", "BiasEvent",
           "ConstantBiases", "WindowEstimate", "WindowOptions", "WindowSummary",
           "WindowedCalibration", "constant_biases", "declared_cuts", "embed_summary",
           "smooth_windows", "summarise_window",
           "window_estimate", "windowed_graph"]
