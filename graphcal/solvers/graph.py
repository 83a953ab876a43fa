"""The factor-graph calibrator (``graph``): every radar's biases estimated jointly with GTSAM.

One GTSAM variable per radar holds its free bias terms (range offset, range
gain, azimuth bias, and elevation bias for 3-D radars; which ones is set per
radar by its ``estimate`` list, and terms can be fixed at known values).  The
factors:

* **ADS-B factors** (:class:`~graphcal.model.factors.AdsbFactor`): each
  plot matched to an ADS-B position of its aircraft, residual in the radar's
  measurement space, noise = radar noise + ADS-B noise through the Jacobian.
* **Cross-radar factors**, in one of two formulations (``cross``):

  - ``pairwise`` (default, fast): paper 001's differences of converted
    positions of two radars' plots of the same aircraft, target eliminated,
    evaluated exactly at each iteration
    (:class:`~graphcal.model.factors.PairwiseFactor`).  Plots matched to
    ADS-B are not paired, so no plot's noise is counted twice; a plot still
    enters several pairs, and the covariance is corrected for that shared
    noise by a sandwich ``A^-1 (A - A_pair + M_pair) A^-1``.
  - ``target-state``: each aircraft's trajectory is in the graph
    (:mod:`graphcal.solvers.target_state`); every plot is a factor between
    its radar's biases and the trajectory at its own time, ADS-B reports are
    factors on the trajectory, and motion factors tie consecutive states.
    Exact and free of interpolation, and slower.
  - ``none``: ADS-B factors only.

* **Weak priors** ``N(0, sigma_prior)`` on every free term keep it in a
  physically plausible range (:func:`prior_sigmas`); they are reported, and a
  term whose posterior variance is more than a quarter of its prior variance
  is flagged as not determined by the data.
* **Pressure altitudes** (``dataset.plot_altitude == "pressure"``): one more
  variable, the height model ``(height_offset_m, height_scale)`` of
  :mod:`graphcal.data.height`, with weak priors
  (:data:`~graphcal.model.height.HEIGHT_PRIOR_SIGMA`).  The pairwise factors place
  2-D plots at its height, and the ADS-B reports with both heights measure it
  (:class:`~graphcal.model.height.AdsbHeightFactor`).  It is reported in the
  result's ``atmosphere`` block (:attr:`Calibration.atmosphere`), with the
  "not determined" rule of the radar terms.

Every measurement goes through a robust kernel (:mod:`graphcal.model.robust`).
The blocks is solved by Levenberg-Marquardt from the closed-form estimates
(``fl-ls``/``ls`` with ADS-B, ``wls`` without; zero if they fail), and the
joint covariance of all biases comes from GTSAM's marginals.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.errors import EstimationError
from graphcal.core.grouped import group_rows
from graphcal.data.align import DEFAULT_ADSB_MAX_GAP_S
from graphcal.data.bias import CONTRACT_KEYS, ECCENTRICITY, RadarBias
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset
from graphcal.data.height import HEIGHT_MODEL_KEYS, HeightModelEstimate
from graphcal.model.cross_radar import PlotCovariances, gradient_noise_middle_of_blocks
from graphcal.model.factor_set import CROSS_MODES, FactorSet, build_factors, radars_with_adsb
from graphcal.model.factors import AdsbFactor, PairwiseFactor
from graphcal.model.height import HEIGHT_PRIOR_SIGMA
from graphcal.model.information import describe_weak_directions, observability
from graphcal.model.measurement import residual_stats
from graphcal.model.parameters import (
    TERM_NAMES,
    RadarTerms,
    prior_sigmas,
    radar_terms,
    terms_vector,
)
from graphcal.model.problem import Problem, as_problem
from graphcal.model.robust import RobustKernel
from graphcal.noise import fills_missing_sigmas
from graphcal.solvers.gtsam_adapter import (
    FactorGraph,
    IndeterminateSystemError,
    OptimizationResult,
    symbol,
)

FloatArray = NDArray[np.float64]
Progress = Callable[..., None]

#: A term whose posterior variance exceeds this fraction of its prior variance is
#: reported as not determined by the data.
UNDETERMINED_VARIANCE_RATIO = 0.25

#: The closed-form initial values use at most this many plots of a radar
#: (:func:`thinned_for_initial_values`).
INIT_MAX_PLOTS_PER_RADAR = 5_000
#: ``time_offset=None`` (auto) keeps a radar's time offset only if its sigma is at most
#: this [s] ...
AUTO_TIME_OFFSET_MAX_SIGMA_S = 0.5
#: ... and it inflates no other parameter's sigma by more than this factor.
AUTO_TIME_OFFSET_MAX_INFLATION = 1.5
#: The ADS-B alignment is redone at the latest time offsets until they move less than
#: this [s], at most :data:`TIME_OFFSET_MAX_REALIGNMENTS` times.  The factors are first
#: order in the change ``d``: the reference they use is off by ``a d^2 / 2`` (0.01 m
#: at 10 m/s^2 and 0.05 s) and by the difference between the ADS-B segment's slope and
#: the velocity of the reports around it times ``d`` (with 40 m of ADS-B noise at
#: 1 s spacing about 50 m/s, so 2.5 m at 0.05 s, independent from plot to plot: a tenth
#: of a radar's range noise).  Measured on 36 one-hour windows of 1M plots, the
#: estimates then differ from those realigned to 0.001 s by at most 0.09 sigma (0.01 s:
#: the same 0.09 sigma), and no window needs a realignment, instead of half of them.
TIME_OFFSET_REALIGN_TOLERANCE_S = 0.05
TIME_OFFSET_MAX_REALIGNMENTS = 5


# --------------------------------------------------------------------------- set-up
# --------------------------------------------------------------------------- initial values
def initial_biases(
    data: Dataset | Problem, use_adsb: bool, cross: str, init: str
) -> tuple[dict[str, RadarBias], str, list[str]]:
    """Initial biases from the closed-form estimators, or zero.

    ``init``: ``auto`` (``fl-ls`` then ``ls`` with ADS-B; ``wls`` without),
    a method name, or ``zero``.  With ``auto`` the estimators see the problem thinned
    (with ADS-B :func:`thinned_for_initial_values`, without :func:`thinned_by_aircraft`).
    Returns the biases, the method used and notes on the methods that failed.
    """
    from graphcal.solvers.registry import METHODS

    if init == "zero":
        return {}, "zero", []
    if init == "auto":
        candidates = ["fl-ls", "ls"] if use_adsb else (["wls"] if cross != "none" else [])
    else:
        if init not in METHODS:
            raise ValueError(
                f"unknown initialisation '{init}'; use auto, zero or a closed-form method"
            )
        candidates = [init]
    notes = []
    problem = as_problem(data)
    if init == "auto":
        problem = (thinned_for_initial_values(problem) if use_adsb
                   else thinned_by_aircraft(problem))
    for method in candidates:
        try:
            cal = METHODS[method](problem)
        except (EstimationError, ValueError, np.linalg.LinAlgError) as exc:
            notes.append(f"initialisation by {method} failed ({exc}); trying the next")
            continue
        biases = {}
        for rid in cal.radar_ids:
            vector = np.nan_to_num(cal.bias(rid).as_vector(), nan=0.0, posinf=0.0, neginf=0.0)
            biases[rid] = RadarBias.from_vector(vector)
        return biases, method, notes
    return {}, "zero", notes


def thinned_for_initial_values(
    problem: Problem, max_plots_per_radar: int = INIT_MAX_PLOTS_PER_RADAR,
) -> Problem:
    """``problem`` with at most ``max_plots_per_radar`` plots of each radar, for the
    closed-form initial values.

    Every ``k``-th plot of a radar (in table order, ``k`` the smallest stride that
    brings it under the limit) is kept; radars under the limit keep all their plots,
    and a dataset with no radar over it is returned as it is.  The ADS-B table is
    kept whole.  An initial value only has to fall in the basin of the solution,
    which a few thousand plots give as well as a million: the closed forms then
    cost a fixed time per radar instead of growing with the recording.

    The alignments with ADS-B the problem already holds are cut for the thinned one
    (:meth:`~graphcal.model.problem.Problem.thinned`), not made again.
    """
    radar, _ = pd.factorize(problem.dataset.plots["radar_id"], use_na_sentinel=False)
    sizes = np.bincount(radar)
    if sizes.max(initial=0) <= max_plots_per_radar:
        return problem
    # Each row's rank among its radar's rows, in table order.
    order = group_rows(radar)
    rank = np.empty(len(radar), dtype=np.int64)
    rank[order] = np.arange(len(radar)) - np.repeat(np.cumsum(sizes) - sizes, sizes)
    stride = -(-sizes[radar] // max_plots_per_radar)  # ceil, per row: its radar's stride
    keep = rank % stride == 0
    return problem.thinned(keep)


def thinned_by_aircraft(
    problem: Problem, max_plots_per_radar: int = INIT_MAX_PLOTS_PER_RADAR,
) -> Problem:
    """``problem`` with the plots of every ``k``-th aircraft only, for the closed-form
    initial values without ADS-B.

    Without ADS-B the closed forms compare the radars' plots of one aircraft pair by
    pair, so an aircraft is kept or left out whole (thinning each radar's plots would
    leave the partner tracks too sparse to pair): the aircraft, in the order of their
    ``target_id``, are kept at the smallest stride ``k`` that brings every radar to at
    most ``max_plots_per_radar`` plots (at least one aircraft is kept); plots without a
    ``target_id`` pair with nothing and are left out.  A dataset with no radar over the
    limit, or without any identity, is returned as it is.  As with
    :func:`thinned_for_initial_values`, an initial value only has to fall in the basin of
    the solution.
    """
    plots = problem.dataset.plots
    radar, _ = pd.factorize(plots["radar_id"], use_na_sentinel=False)
    n_radars = int(radar.max(initial=-1)) + 1
    if np.bincount(radar, minlength=n_radars).max(initial=0) <= max_plots_per_radar:
        return problem
    # Plots without an identity pair with nothing: they are left out.
    target = plots["target_id"]
    has_id = (target.notna() & (target.astype(str) != "")).to_numpy()
    if not has_id.any():
        return problem
    aircraft = np.full(len(plots), -1, dtype=np.int64)
    aircraft[has_id], _ = pd.factorize(target[has_id].astype(str), sort=True)
    n_aircraft = int(aircraft.max()) + 1
    counts = np.bincount(radar[has_id] * n_aircraft + aircraft[has_id],
                         minlength=n_radars * n_aircraft).reshape(n_radars, n_aircraft)
    stride = next((k for k in range(1, n_aircraft + 1)
                   if counts[:, ::k].sum(axis=1).max() <= max_plots_per_radar), n_aircraft)
    return problem.thinned(has_id & (aircraft % stride == 0))


def _initial_free(terms: RadarTerms, bias: RadarBias | None, prior: FloatArray) -> FloatArray:
    if bias is None:
        return np.zeros(len(terms.free))
    values = terms_vector(bias)[terms.positions]
    # A closed-form estimate far outside the prior is not a useful start.
    return np.where(np.abs(values) <= 3.0 * prior, values, 0.0)


# --------------------------------------------------------------------------- covariance
def _pairwise_sandwich_terms(
    blocks: FactorSet, values: dict[str, FloatArray], columns: dict[str, list[int]], p: int
) -> tuple[FloatArray, FloatArray]:
    """``A_pair = sum w J^T J`` and the shared-noise ``M_pair`` over the pairwise factors.

    ``M_pair`` is :func:`~graphcal.model.cross_radar.gradient_noise_middle_of_blocks` of
    ``w_k J_k^T W_k = w_k H_k^T Q_k`` (``J = W H`` whitened, ``Q = W^T W``): every
    plot's share of the gradient noise across all the pairs it enters (paper
    001's observations share plots), with the robust weights ``w_k`` at the solution.
    """
    information = np.zeros((p, p))
    # Per radar, the pairs its plots enter: (the pair's columns, w J^T W, plot rows,
    # coefficients).  A plot belongs to one radar, so M is the sum over radars of the
    # middles of their own plots, each over the columns of that radar's pairs only:
    # memory and time grow with the pairs, not with the pairs times the whole network.
    by_radar: dict[str, list[tuple[list[int], FloatArray, NDArray[np.int64], FloatArray]]] = {}
    cov_labels: list[NDArray[np.int64]] = []
    cov_parts: list[FloatArray] = []
    for f in blocks.pairs:
        ra, rb = f.terms_a.radar_id, f.terms_b.radar_id
        e, jacobians = f.whitened(_pair_values(f, values))
        w = f.kernel.weight(frames.row_norm(e), 3)
        cols = columns[ra] + columns[rb]
        if f.height_key is not None:
            cols = cols + columns[HEIGHT]
        jac = np.concatenate(jacobians, axis=2)  # (n, 3, k): this pair's own columns
        information[np.ix_(cols, cols)] += np.einsum("nip,niq,n->pq", jac, jac, w)
        share = w[:, None, None] * np.swapaxes(jac, 1, 2) @ f.whitening  # (n, k, 3)
        positions, coefficient = f.plot_noise()  # column 0: b's plot; the others: a's
        labels = np.concatenate([f.a_plots.index, f.b_plots.index])[positions]
        by_radar.setdefault(rb, []).append((cols, share, labels[:, :1], coefficient[:, :1]))
        by_radar.setdefault(ra, []).append((cols, share, labels[:, 1:], coefficient[:, 1:]))
        cov_labels.extend([np.asarray(f.a_plots.index), np.asarray(f.b_plots.index)])
        cov_parts.extend([f.a_cov_m2, f.b_cov_m2])
    plot_cov = PlotCovariances.collect(cov_labels, cov_parts)
    middle = np.zeros((p, p))
    for entries in by_radar.values():
        middle += gradient_noise_middle_of_blocks(entries, plot_cov, p)
    return information, middle


#: Key of the height model in the value and column dictionaries (never a radar id:
#: radar ids are stripped, non-empty strings).
HEIGHT = ""


def _pair_values(f: PairwiseFactor, values: dict[str, FloatArray]) -> list[FloatArray]:
    """The current values of a pairwise factor's variables, in its key order."""
    current = [values[f.terms_a.radar_id], values[f.terms_b.radar_id]]
    if f.height_key is not None:
        current.append(values[HEIGHT])
    return current


# --------------------------------------------------------------------------- solving
@dataclass
class _Settings:
    """Options of one solve, passed unchanged to every (re-)solve."""

    have_adsb: bool
    cross: str
    kernel: RobustKernel
    max_gap_s: float
    pair_max_gap_s: float | None
    process_noise_m2_s3: float | None
    max_iterations: int
    progress: Progress | None
    height_key: int | None = None
    #: Trajectory formulation: the biases after the Gauss-Newton pre-solve.
    path_start: dict[str, FloatArray] | None = None
    #: Trajectory formulation: the paths of the first solve, for a solve with other terms.
    paths_block: Any = None
    #: Trajectory formulation: estimate the phases' process noise after the first step.
    estimate_process_noise: bool = False


@dataclass
class _Solved:
    """One Levenberg-Marquardt solution with its factors."""

    terms: dict[str, RadarTerms]
    blocks: FactorSet
    fg: FactorGraph
    result: Any
    radars: list[str]
    values: dict[str, FloatArray]
    priors: dict[str, FloatArray]
    variable: set[str]
    realignments: int
    height: FloatArray | None = None
    #: The joint covariance of some variables at the solution, once computed: (keys, matrix).
    joint: tuple[list[int], FloatArray] | None = None


def _solve(
    problem: Problem,
    fixed: dict[tuple[str, str], float],
    tau_radars: set[str],
    keys: dict[str, int],
    init_biases: dict[str, RadarBias],
    settings: _Settings,
    timing: dict[str, float],
) -> _Solved:
    """Build the factors and solve; with time offsets, re-align ADS-B at the estimates.

    The ADS-B reference and the cross-radar pairs are interpolated at the current
    time offsets ``tau0`` and the factors are first order in ``tau - tau0``, so
    the alignment is redone at the new estimates until they move less than
    :data:`TIME_OFFSET_REALIGN_TOLERANCE_S` (usually once or twice).
    """
    s = settings
    dataset = problem.dataset
    radar_ids = list(dataset.radar_ids)
    terms = {
        rid: radar_terms(dataset.sites[rid], fixed, rid in tau_radars) for rid in radar_ids
    }
    blocks = FactorSet(terms, keys, height_key=s.height_key)
    tau0 = {rid: terms[rid].time_offset(np.zeros(len(terms[rid].free))) for rid in radar_ids}
    start_values: dict[str, FloatArray] = {}
    iterations = realignments = 0
    for _ in range(TIME_OFFSET_MAX_REALIGNMENTS + 1):
        t0 = time.perf_counter()
        if s.cross == "target-state":
            from graphcal.solvers.target_state import build_target_state

            blocks.target_state = build_target_state(
                dataset, terms, keys, s.kernel, use_adsb=s.have_adsb,
                adsb_max_gap_s=s.max_gap_s, process_noise_m2_s3=s.process_noise_m2_s3,
                progress=s.progress,
            )
            if s.have_adsb:
                # Residual statistics against ADS-B, for the report only.
                for rid in radar_ids:
                    al = problem.alignment(rid, s.max_gap_s)
                    if len(al):
                        blocks.alignments[rid] = al
        elif s.cross == "trajectory":
            if blocks.target_state is None:
                _build_paths(problem, blocks, init_biases, s)
        else:
            build_factors(problem, blocks, s.have_adsb, s.cross, s.kernel, s.max_gap_s,
                           s.pair_max_gap_s, s.progress, tau0)
        timing["factors_s"] = timing.get("factors_s", 0.0) + time.perf_counter() - t0
        radars = blocks.variable_radars()
        if not radars:
            raise EstimationError(
                "nothing to calibrate: no plot matched ADS-B and no two radars saw the same "
                "target_id within the time-gap limit (2-D plots need an altitude to be paired)"
            )
        priors = {rid: prior_sigmas(dataset.sites[rid], terms[rid]) for rid in radars}
        fg = FactorGraph()
        initial_free: dict[str, FloatArray] = {}
        if s.cross == "trajectory" and s.path_start:
            start_values = dict(s.path_start)
        for rid in radars:
            start = start_values.get(rid)
            if start is None:
                start = _initial_free(terms[rid], init_biases.get(rid), priors[rid])
            initial_free[rid] = start
            fg.add_variable(keys[rid], start)
            fg.add_prior(keys[rid], np.zeros(len(terms[rid].free)), priors[rid])
        variable = set(radars)
        height_used = blocks.height is not None or any(
            f.height_key is not None for f in blocks.pairs) or bool(
            getattr(blocks.target_state, "height_key", None) is not None)
        if height_used:
            fg.add_variable(s.height_key, start_values.get(HEIGHT, np.zeros(2)))
            fg.add_prior(s.height_key, np.zeros(2), np.array(HEIGHT_PRIOR_SIGMA))
            variable.add(HEIGHT)
            if blocks.height is not None:
                fg.add_custom(blocks.height.keys, blocks.height.dimension,
                              blocks.height.error)
        for factor in [*blocks.adsb.values(), *blocks.pairs]:
            add_factor(fg, factor, variable)
        if blocks.target_state is not None and s.cross != "trajectory":
            blocks.target_state.add_to(fg, variable, initial_free)
        t0 = time.perf_counter()
        if s.progress is not None:
            s.progress("optimising", 0, 1)
        if s.cross == "trajectory":
            result = _solve_paths(blocks, fg, initial_free, priors, s)
        else:
            result = fg.optimize(max_iterations=s.max_iterations)
        iterations += result.iterations
        timing["optimisation_s"] = timing.get("optimisation_s", 0.0) + time.perf_counter() - t0
        values = {rid: result.vector(keys[rid]) for rid in radars}
        if height_used:
            values[HEIGHT] = result.vector(s.height_key)
        if s.cross == "trajectory":
            break  # time offsets are exact in the paths: no alignment to redo
        moved = [
            abs(terms[rid].time_offset(values[rid]) - tau0[rid])
            for rid in radars if "time_offset" in terms[rid].free
        ]
        if not moved or max(moved) < TIME_OFFSET_REALIGN_TOLERANCE_S:
            break
        tau0.update({rid: terms[rid].time_offset(values[rid]) for rid in radars})
        start_values = values
        realignments += 1
    result = dataclasses.replace(result, iterations=iterations)
    return _Solved(terms, blocks, fg, result, radars, values, priors, variable, realignments,
                   values.get(HEIGHT))


def _build_paths(problem: Problem, blocks: FactorSet, init_biases: dict[str, RadarBias],
                 s: _Settings) -> None:
    """The trajectory block (every aircraft's path, eliminated inside one factor), the
    ADS-B height factor and, for the report, the plots aligned with ADS-B."""
    from graphcal.model.height import adsb_height_factor
    from graphcal.model.trajectory import build_trajectory_block

    dataset = problem.dataset
    terms = blocks.terms
    free = [rid for rid in dataset.radar_ids if terms[rid].free]
    start = {rid: _initial_free(terms[rid], init_biases.get(rid),
                                prior_sigmas(dataset.sites[rid], terms[rid])) for rid in free}
    earlier = s.paths_block
    if earlier is not None:  # solved before with other free terms: same paths
        block = earlier.with_terms(terms, free)
        previous = s.path_start or {}
        start = {rid: (previous[rid] if rid in previous and len(previous[rid]) == len(v)
                       else v) for rid, v in start.items()}
    else:
        block = build_trajectory_block(
            dataset, terms, blocks.keys, free, s.kernel, use_adsb=s.have_adsb,
            initial_biases=start, height_key=s.height_key, progress=s.progress,
            plots=problem.all_plots,
            tracks=problem.adsb_tracks if s.have_adsb else None)
    blocks.target_state = block
    s.paths_block = block
    if block is None:
        return
    values = block.values_of(start)
    s.estimate_process_noise = earlier is None
    s.path_start = {name: v for (_, name, _), v in zip(block.variables, values, strict=True)}
    if s.have_adsb and s.height_key is not None:
        blocks.height = adsb_height_factor(dataset.adsb, s.height_key, s.kernel)
    if s.have_adsb:
        for rid in dataset.radar_ids:
            al = problem.alignment(rid, s.max_gap_s)
            if len(al):
                blocks.alignments[rid] = al


#: Trajectory formulation: Gauss-Newton on the biases stops when no step exceeds this
#: fraction of its parameter's sigma.  That last step is still taken (from the last
#: elimination, by GTSAM); what is left is the change of the robust weights over it:
#: within 0.035 sigma of the solution run to 0.001-sigma steps on the demo network
#: (three seeds), two or three eliminations.
PATHS_STEP_TOLERANCE_SIGMA = 0.1
#: ... or after this many eliminations of the paths.
PATHS_MAX_ITERATIONS = 20


def _solve_paths(blocks: FactorSet, fg: FactorGraph, initial_free: dict[str, FloatArray],
                 priors: dict[str, FloatArray], s: _Settings) -> OptimizationResult:
    """Gauss-Newton on the biases with the paths eliminated, then GTSAM's bias-level graph.

    Each iteration eliminates the paths at the current biases
    (:meth:`~graphcal.model.trajectory.TrajectoryBlock.reduced`, robust weights
    renewed), adds the weak priors and the ADS-B height factor, and steps; a step that
    raises the cost is halved.  The last elimination becomes a Gaussian factor on the
    biases in ``fg`` (beside the priors and the height factor already there): GTSAM takes
    the last step and gives the marginals of the same system.
    """
    block = blocks.target_state
    height = blocks.height
    layout = [(key, name, size) for key, name, size in block.variables]
    if height is not None and all(name != HEIGHT for _, name, _ in layout):
        layout.append((height.key, HEIGHT, 2))
    in_block = len(block.variables)
    prior = np.concatenate([
        priors[name] ** -2.0 if name != HEIGHT else np.array(HEIGHT_PRIOR_SIGMA) ** -2.0
        for _, name, _ in layout])
    sizes = [size for _, _, size in layout]
    edges = np.cumsum(sizes)[:-1]
    x = np.concatenate([
        initial_free[name] if name != HEIGHT else (s.path_start or {}).get(HEIGHT, np.zeros(2))
        for _, name, _ in layout]).astype(float)
    height_columns = next((np.arange(int(np.sum(sizes[:i])), int(np.sum(sizes[:i])) + 2)
                           for i, (_, name, _) in enumerate(layout) if name == HEIGHT), None)
    n_block = int(np.sum(sizes[:in_block]))

    def linearise(x: FloatArray, estimate_process_noise: bool
                  ) -> tuple[float, FloatArray, FloatArray, FloatArray, FloatArray]:
        parts = np.split(x, edges)
        cost, gradient, information = block.reduced(parts[:in_block], True,
                                                    estimate_process_noise)
        p = len(x)
        g_all, h_all = np.zeros(p), np.zeros((p, p))
        g_all[:n_block], h_all[:n_block, :n_block] = gradient, information
        if height is not None and height_columns is not None:
            e, jac = height.error([x[height_columns]], True)
            j = jac[0]
            h_all[np.ix_(height_columns, height_columns)] += j.T @ j
            g_all[height_columns] += j.T @ e
            cost += 0.5 * float(e @ e)
        total = cost + 0.5 * float(np.sum(prior * x * x))
        return total, g_all + prior * x, h_all + np.diag(prior), gradient, information

    first_total = None
    previous: tuple[float, FloatArray] | None = None
    iterations, converged = 0, False
    while iterations < PATHS_MAX_ITERATIONS:
        # After the first step (the biases near their solution, whatever the start), the
        # phases' process noise is estimated from the second linearisation's data and
        # the system is reduced with it; the model has changed, so the comparison of
        # costs starts again there.
        estimate = s.estimate_process_noise and iterations == 1
        total, grad, hessian, gradient, information = linearise(x, estimate)
        iterations += 1
        if estimate:
            s.estimate_process_noise = False
            previous = None
        first_total = total if first_total is None else first_total
        if previous is not None and total > previous[0] + 1e-9 * abs(previous[0]):
            x = 0.5 * (previous[1] + x)  # the step raised the cost: halve it
            continue
        previous = (total, x.copy())
        scale = np.sqrt(np.maximum(np.diag(hessian), 1e-300))
        scaled = hessian / np.outer(scale, scale)
        step = np.linalg.lstsq(scaled, -grad / scale, rcond=1e-12)[0] / scale
        sigma = np.sqrt(np.maximum(np.diag(np.linalg.pinv(scaled, rcond=1e-12)), 1e-300)) / scale
        if not s.estimate_process_noise and np.all(
                np.abs(step) <= PATHS_STEP_TOLERANCE_SIGMA * sigma):
            converged = True
            break
        x = x + step
    point = np.split(previous[1], edges) if previous is not None else np.split(x, edges)
    # The last elimination as a Gaussian factor at its point: GTSAM takes the last step.
    fg.add_gaussian(block.keys, information, -gradient, point[:in_block])
    for (key, _, _), value in zip(layout, point, strict=True):
        fg.set_initial(key, value)
    result = fg.solve_linear()
    data_cost = previous[0] if previous is not None else total
    return dataclasses.replace(
        result, iterations=iterations, converged=converged,
        initial_error=float(first_total if first_total is not None else total),
        final_error=float(data_cost + result.final_error - fg.error()))


def named_joint_covariance(fg: Any, values: Any, joint_keys: list[int],
                      radar_keys: Mapping[str, int]) -> np.ndarray:
    """``fg.joint_covariance``; an indeterminate system becomes an :class:`EstimationError`
    naming the radar whose biases the data leave undetermined (exit 3, not a defect)."""
    try:
        return fg.joint_covariance(values, joint_keys)
    except IndeterminateSystemError as exc:
        names = {int(k): rid for rid, k in radar_keys.items()}
        where = (f"{names[exc.key]}'s biases" if exc.key in names
                 else "the biases")
        raise EstimationError(
            f"the sigmas cannot be computed: near {where} the information of the data is "
            "singular or too poorly conditioned (GTSAM found the linear system "
            "indeterminate). The data do not determine these biases reliably: too few "
            "common observations, a geometry that cannot separate them, or a bias far "
            "beyond its prior (pairs of plots mismatched by kilometres or tens of mrad); "
            "calibrate with ADS-B, or check that radar's site and data") from None


def _poorly_determined_time_offsets(solved: _Solved) -> dict[str, str]:
    """Radars whose time offset the data do not determine well, with the reason.

    A time offset is kept when its sigma is at most
    :data:`AUTO_TIME_OFFSET_MAX_SIGMA_S` and estimating it inflates no other
    parameter's sigma by more than :data:`AUTO_TIME_OFFSET_MAX_INFLATION`
    (e.g. one straight flight: a time offset then looks like a range offset
    and an azimuth bias).
    """
    keys = [solved.blocks.keys[rid] for rid in solved.radars]
    marginal = named_joint_covariance(solved.fg, solved.result.values, keys, solved.blocks.keys)
    solved.joint = (keys, marginal)  # the marginals of the result, when nothing is re-solved
    labels = [(rid, name) for rid in solved.radars for name in solved.terms[rid].free]
    information = np.linalg.inv(marginal)
    sigma = np.sqrt(np.diag(marginal))
    poor: dict[str, str] = {}
    for i, (rid, name) in enumerate(labels):
        if name != "time_offset":
            continue
        if sigma[i] > AUTO_TIME_OFFSET_MAX_SIGMA_S:
            poor[rid] = f"its sigma would be {sigma[i]:.2f} s"
            continue
        others = [j for j in range(len(labels)) if j != i]
        fixed_sigma = np.sqrt(np.diag(np.linalg.inv(information[np.ix_(others, others)])))
        inflation = sigma[others] / fixed_sigma
        worst = int(np.argmax(inflation))
        if inflation[worst] > AUTO_TIME_OFFSET_MAX_INFLATION:
            other_rid, other_name = labels[others[worst]]
            poor[rid] = (
                f"this traffic cannot tell it from {other_rid} {other_name.replace('_', ' ')} "
                f"(whose sigma it would multiply by {inflation[worst]:.1f})"
            )
    return poor


# --------------------------------------------------------------------------- the estimator
@fills_missing_sigmas
def graph(
    data: Dataset | Problem,
    *,
    cross: str = "trajectory",
    robust: str = "huber",
    robust_scale: float = 1.0,
    use_adsb: bool = True,
    init: str = "auto",
    fixed: dict[tuple[str, str], float] | None = None,
    max_iterations: int = 100,
    max_gap_s: float = DEFAULT_ADSB_MAX_GAP_S,
    pair_max_gap_s: float | None = None,
    process_noise_m2_s3: float | None = None,
    time_offset: bool | None = None,
    progress: Progress | None = None,
    bound: bool = False,
    summarise_residuals: bool = True,
    fit_on_paths: bool = True,
) -> Calibration:
    """Joint calibration of every radar with a GTSAM factor graph.

    Parameters
    ----------
    data : Dataset or Problem
        The data, or the calibration problem built from them
        (:func:`~graphcal.model.problem.build_problem`), whose plots and alignments
        with ADS-B the stages share.
    cross : {"trajectory", "pairwise", "target-state", "none"}
        Cross-radar formulation (see the module docstring).
    robust : {"huber", "cauchy", "none"}
        Robust kernel on every measurement; ``robust_scale`` multiplies its
        default threshold (the chi 95 % point of the measurement dimension).
    use_adsb : bool
        Use the ADS-B table when the dataset has one.
    init : str
        ``auto``, ``zero`` or a closed-form method for the initial values.
    fixed : dict, optional
        ``{(radar_id, parameter_name): value_si}``: terms held at a known value.
    max_iterations : int
        Levenberg-Marquardt iteration limit.
    max_gap_s : float
        Longest ADS-B gap bridged by interpolation [s].
    pair_max_gap_s : float, optional
        Longest gap between a radar's bracketing plots in pairwise mode [s]
        (default 2.5 scans).
    process_noise_m2_s3 : float, optional
        Target-state mode: white-acceleration spectral density of the
        constant-velocity motion factors.
    time_offset : bool or None
        Estimate each radar's time-stamping bias ``time_offset_s`` (CONTRACT.md:
        ``time_reported = time_true + time_offset_s``) for the radars with ADS-B.
        ``None`` (default): yes when ADS-B is used and ``cross`` is not
        ``target-state``, but a radar whose time offset the traffic does not
        determine (sigma above :data:`AUTO_TIME_OFFSET_MAX_SIGMA_S`, or it would
        inflate another parameter's sigma more than
        :data:`AUTO_TIME_OFFSET_MAX_INFLATION` times) keeps 0, with a warning.
        ``True``: always (needs ADS-B, not in target-state mode); ``False``: never.
    progress : callable, optional
        ``progress(stage, done, total)``.
    bound : bool
        Trajectory formulation: also compute the Cramér-Rao bound of the model
        (:attr:`Calibration.bound`; one more elimination of the paths).
        :func:`graphcal.calibrate` asks for it when it reports the bound.
    summarise_residuals : bool
        Also summarise each radar's residuals against ADS-B (:attr:`Calibration.residuals`,
        for the report); a window of a calibration over time leaves them out.
    fit_on_paths : bool
        With the trajectory formulation and no plot aligned with ADS-B, also sum each
        radar's residuals on the paths for the fit verdict (``info["target_state"]["fit"]``,
        :meth:`~graphcal.model.trajectory.TrajectoryBlock.residual_fit`).

    Returns
    -------
    Calibration
        ``info`` holds the iterations, errors, convergence, priors, robust
        down-weighting per radar, the CRLB and timings.
    """
    if cross not in CROSS_MODES:
        raise ValueError(
            f"unknown cross-radar mode '{cross}'; use one of: {', '.join(CROSS_MODES)}"
        )
    problem = as_problem(data)
    dataset = problem.dataset
    if max_iterations < 1:
        raise ValueError("max_iterations must be at least 1")
    kernel = RobustKernel(robust, robust_scale)
    fixed = dict(fixed or {})
    for rid, name in fixed:
        if rid not in dataset.sites:
            raise ValueError(f"cannot fix a term of unknown radar '{rid}'")
        if name not in TERM_NAMES:
            raise ValueError(f"cannot fix unknown parameter '{name}'")
    timing: dict[str, float] = {}
    start = time.perf_counter()
    have_adsb = bool(use_adsb and dataset.adsb is not None and len(dataset.adsb) > 0)
    radar_ids = list(dataset.radar_ids)
    auto_time = time_offset is None
    if time_offset and not have_adsb:
        raise ValueError("time offsets need ADS-B: the dataset has none (or use_adsb=False)")
    if cross == "target-state" and any(ECCENTRICITY in s.estimate for s in dataset.sites.values()):
        raise ValueError(
            "azimuth eccentricity is estimated with the pairwise or no cross-radar factors, "
            "not in target-state mode"
        )
    if cross == "target-state" and any(s.atmosphere is not None for s in dataset.sites.values()):
        raise ValueError(
            "refraction is modelled with the pairwise or no cross-radar factors, "
            "not in target-state mode"
        )
    if time_offset and cross == "target-state":
        raise ValueError("time offsets are not estimated in target-state mode; use pairwise")
    if cross == "target-state" and dataset.pressure_altitudes:
        raise ValueError(
            "pressure altitudes (plot_altitude = \"pressure\") are modelled with the pairwise "
            "or no cross-radar factors, not in target-state mode"
        )
    want_time = have_adsb and cross != "target-state" if auto_time else bool(time_offset)
    # ---------------------------------------------------------------- ADS-B association
    if have_adsb and cross != "target-state":
        # Every radar's plots aligned with ADS-B at zero time offset, kept by the
        # problem for the initial values and the first factors.
        t0 = time.perf_counter()
        for i, rid in enumerate(radar_ids):
            problem.alignment(rid, max_gap_s)
            if progress is not None:
                progress("ADS-B association", i + 1, len(radar_ids))
        timing["association_s"] = time.perf_counter() - t0
    tau_radars = radars_with_adsb(dataset, problem.adsb_tracks) if want_time else set()
    keys = {rid: symbol("b", i) for i, rid in enumerate(radar_ids)}
    # ---------------------------------------------------------------- initial values
    t0 = time.perf_counter()
    if progress is not None:
        progress("initial values", 0, 1)
    init_biases, init_method, init_notes = initial_biases(
        problem, have_adsb, "none" if cross == "none" else cross, init)
    timing["initialisation_s"] = time.perf_counter() - t0
    settings = _Settings(have_adsb, cross, kernel, max_gap_s, pair_max_gap_s,
                         process_noise_m2_s3, max_iterations, progress,
                         symbol("h", 0) if dataset.pressure_altitudes else None)
    solved = _solve(problem, fixed, tau_radars, keys, init_biases, settings, timing)
    time_notes: list[str] = []
    if auto_time and tau_radars:
        t0 = time.perf_counter()
        poor = _poorly_determined_time_offsets(solved)  # computes the marginals
        timing["marginals_s"] = timing.get("marginals_s", 0.0) + time.perf_counter() - t0
        if poor:
            time_notes = [
                f"{rid} time offset not estimated: {why}; assumed 0 s"
                for rid, why in poor.items()
            ]
            tau_radars = tau_radars - set(poor)
            solved = _solve(problem, fixed, tau_radars, keys, init_biases, settings, timing)
    terms, blocks, fg, result = solved.terms, solved.blocks, solved.fg, solved.result
    radars, values, priors, variable = solved.radars, solved.values, solved.priors, solved.variable
    full_values = {
        rid: values[rid] if rid in values else np.zeros(0) for rid in radar_ids
    }
    if solved.height is not None:
        full_values[HEIGHT] = solved.height
    # ---------------------------------------------------------------- covariance
    t0 = time.perf_counter()
    if progress is not None:
        progress("marginals", 0, 1)
    joint_keys = [keys[rid] for rid in radars]
    if solved.height is not None:  # the height model joins the joint covariance last
        joint_keys.append(settings.height_key)
    if solved.joint is not None and solved.joint[0] == joint_keys:
        marginal = solved.joint[1]  # computed by the time-offset check, same graph and values
    else:
        marginal = named_joint_covariance(fg, result.values, joint_keys, keys)
    labels = [(rid, name) for rid in radars for name in terms[rid].free]
    p = len(labels)
    columns: dict[str, list[int]] = {rid: [] for rid in radar_ids}
    for i, (rid, _) in enumerate(labels):
        columns[rid].append(i)
    columns[HEIGHT] = list(range(p, len(marginal)))
    prior_information = np.diag(np.concatenate([priors[rid] for rid in radars]) ** -2.0)
    information = np.linalg.inv(marginal)
    information = 0.5 * (information + information.T)
    covariance = marginal
    covariance_note = "GTSAM marginals"
    if blocks.pairs:
        a_pair, m_pair = _pairwise_sandwich_terms(blocks, full_values, columns, len(marginal))
        covariance = marginal @ (information - a_pair + m_pair) @ marginal
        covariance = 0.5 * (covariance + covariance.T)
        covariance_note = "GTSAM marginals, corrected for plots shared between pairs"
    height_covariance, height_cross = covariance[p:, p:], covariance[:p, p:]
    if solved.height is not None:
        # The radar terms' information with the height model eliminated (a nuisance).
        covariance = covariance[:p, :p]
        information = np.linalg.inv(marginal[:p, :p])
        information = 0.5 * (information + information.T)
    timing["marginals_s"] = timing.get("marginals_s", 0.0) + time.perf_counter() - t0
    data_information = information - prior_information
    obs = observability(data_information)
    # ---------------------------------------------------------------- result
    estimate = np.concatenate([values[rid] for rid in radars])
    prior_vector = np.concatenate([priors[rid] for rid in radars])
    ratio = np.diag(covariance) / prior_vector**2
    undetermined = [labels[i] for i in np.flatnonzero(ratio > UNDETERMINED_VARIANCE_RATIO)]
    cleaning = getattr(dataset, "cleaning", None)
    warnings = (list(cleaning.warnings) if cleaning is not None else []) + init_notes + time_notes
    for rid, name in undetermined:
        warnings.append(
            f"{rid} {name.replace('_', ' ')} is not determined by the data: its estimate "
            "and sigma come from the weak prior"
        )
    atmosphere, height_undetermined = None, []
    if dataset.pressure_altitudes:
        atmosphere, height_undetermined, note = _height_model_estimate(
            solved, height_covariance, height_cross,
            [f"{rid}.{CONTRACT_KEYS[name][0]}" for rid, name in labels],
        )
        warnings.extend(note)
    warnings.extend(describe_weak_directions(labels, obs))
    if not result.converged:
        warnings.append(
            f"Levenberg-Marquardt stopped at the iteration limit ({max_iterations}) "
            "before converging"
        )
    for rid in radar_ids:
        if rid not in variable and terms[rid].free:
            warnings.append(f"radar {rid} has no usable observations; not calibrated")
    n_plots = _plots_used(blocks, radars)
    total_dimension = sum(f.dimension for f in [*blocks.adsb.values(), *blocks.pairs])
    if blocks.target_state is not None:
        total_dimension += blocks.target_state.dimension
    if solved.height is not None:
        total_dimension += (0 if blocks.height is None else blocks.height.dimension) - 2
    info: dict[str, Any] = {
        "cross": cross,
        "robust": {"kernel": kernel.name, "scale": kernel.scale,
                   "threshold_sigma_2d": kernel.threshold(2),
                   "threshold_sigma_3d": kernel.threshold(3)},
        "initialisation": init_method,
        "optimizer": ("Gauss-Newton on the biases, the paths eliminated (the last step and "
                      "the marginals in GTSAM)" if cross == "trajectory"
                      else "Levenberg-Marquardt (GTSAM)"),
        "iterations": result.iterations,
        "initial_error": result.initial_error,
        "final_error": result.final_error,
        "converged": result.converged,
        "chi2_per_dof": 2.0 * result.final_error / max(total_dimension - p, 1),
        "covariance": covariance_note,
        "n_factors": len(fg),
        "n_adsb_plots": int(sum(len(f.measured) for f in blocks.adsb.values())),
        "n_pairs": int(sum(len(f) for f in blocks.pairs)),
        "priors": {
            rid: {CONTRACT_KEYS[name][0]: float(s * CONTRACT_KEYS[name][1])
                  for name, s in zip(terms[rid].free, priors[rid], strict=True)}
            for rid in radars
        },
        "fixed": {
            rid: {CONTRACT_KEYS[name][0]: float(v * CONTRACT_KEYS[name][1])
                  for name, v in terms[rid].fixed.items()}
            for rid in radar_ids if terms[rid].fixed
        },
        "undetermined": [f"{rid}.{CONTRACT_KEYS[name][0]}" for rid, name in undetermined]
        + [f"atmosphere.{key}" for key in height_undetermined],
        "cleaning": cleaning.to_dict() if cleaning is not None else None,
        "time_offset": {
            "estimated": [rid for rid in radars if "time_offset" in terms[rid].free],
            "not_estimated": time_notes,
            "realignments": solved.realignments,
        },
        "downweighted": _downweighted(blocks, full_values, radars, result),
    }
    if blocks.target_state is not None:
        info["target_state"] = blocks.target_state.summary()
        if (fit_on_paths and cross == "trajectory"
                and not any(len(al) for al in blocks.alignments.values())):
            # Without ADS-B residuals the fit verdict judges the plots on the paths.
            info["target_state"]["fit"] = _paths_fit(blocks, full_values)
    if atmosphere is not None:
        info["plot_altitude"] = dataset.plot_altitude
    timing["total_s"] = time.perf_counter() - start
    info["timing_s"] = timing
    cal = Calibration(
        method="graph",
        radar_ids=radars,
        is_3d={rid: dataset.sites[rid].is_3d for rid in radars},
        labels=labels,
        estimate=estimate,
        covariance=covariance,
        n_plots=n_plots,
        observability=obs,
        warnings=warnings,
        info=info,
        fixed={(rid, name): v for rid in radars for name, v in terms[rid].fixed.items()},
        atmosphere=atmosphere,
    )
    cal.information = data_information
    if bound and cross == "trajectory" and blocks.target_state is not None:
        t0 = time.perf_counter()
        cal.bound = _trajectory_bound(blocks, full_values, labels, priors, radars, settings)
        timing["crlb_s"] = time.perf_counter() - t0
        timing["total_s"] = time.perf_counter() - start
    for rid, al in blocks.alignments.items() if summarise_residuals else ():
        if rid in radars:
            bias = terms[rid].bias(values[rid])
            cal.residuals[rid] = residual_stats(dataset.sites[rid], al, bias)
    return cal


def _paths_fit(blocks: FactorSet, values: dict[str, FloatArray]
               ) -> dict[str, dict[str, dict[str, float | int]]]:
    """Each radar's residuals on the paths at the estimate, by coordinate
    (:meth:`~graphcal.model.trajectory.TrajectoryBlock.residual_fit`: chi-square, count
    and the paths' share of the degrees of freedom), from a copy of the block."""
    block = blocks.target_state
    copy = dataclasses.replace(block, _reduced_cache=None)
    return copy.residual_fit(block.values_of(values))


def _trajectory_bound(blocks: FactorSet, values: dict[str, FloatArray],
                      labels: list[tuple[str, str]], priors: dict[str, FloatArray],
                      radars: list[str], settings: _Settings) -> dict[str, Any]:
    """The Cramér-Rao bound of the trajectory model at the estimate.

    The Fisher information of the biases with the paths eliminated
    (:meth:`~graphcal.model.trajectory.TrajectoryBlock.reduced` without the robust
    kernel: every plot and ADS-B report at full weight), plus the ADS-B height
    segments and the weak priors, inverted.  The paths and their process noise are the
    estimate's: the bound of this same model, evaluated where the data put it.
    """
    block = blocks.target_state
    fisher_block = dataclasses.replace(block, kernel=RobustKernel("none"), _reduced_cache=None)
    _, _, fisher = fisher_block.reduced(block.values_of(values), True)
    names = [name for _, name, _ in block.variables]
    sizes = [size for _, _, size in block.variables]
    has_height = HEIGHT in names or blocks.height is not None
    p = len(labels)
    size = p + (2 if has_height else 0)
    full = np.zeros((size, size))
    position: list[int] = []
    for name, n in zip(names, sizes, strict=True):
        if name == HEIGHT:
            position.extend([p, p + 1])
            continue
        start = sum(len(priors[rid]) for rid in radars[:radars.index(name)])
        position.extend(range(start, start + n))
    full[np.ix_(position, position)] += fisher
    if blocks.height is not None:
        e, jac = blocks.height.whitened([values.get(HEIGHT, np.zeros(2))])
        j = jac[0].reshape(len(e), 2)
        full[p:, p:] += j.T @ j
    prior = [priors[rid] for rid in radars]
    if has_height:
        prior.append(np.array(HEIGHT_PRIOR_SIGMA))
    full += np.diag(np.concatenate(prior) ** -2.0)
    scale = np.sqrt(np.diag(full))
    covariance = np.linalg.pinv(full / np.outer(scale, scale), rcond=1e-13) / np.outer(
        scale, scale)
    atmosphere = None
    if has_height:
        atmosphere = dict(zip(HEIGHT_MODEL_KEYS, np.sqrt(np.diag(covariance)[p:]).tolist(),
                              strict=True))
    del settings
    return {"covariance": covariance[:p, :p], "atmosphere_sigma": atmosphere,
            "model": "trajectory model at the estimate: every plot and ADS-B report on its "
                     "aircraft's path, the paths eliminated, no robust down-weighting"}


def _height_model_estimate(
    solved: _Solved, covariance: FloatArray, cross: FloatArray, cross_labels: list[str]
) -> tuple[HeightModelEstimate, list[str], list[str]]:
    """The ``atmosphere`` block, the undetermined height-model keys and the warnings.

    Without any factor on the height model (no ADS-B report with both heights and
    no pair with a 2-D radar) the estimate is the prior: 0 with the prior sigmas.
    A parameter whose variance exceeds :data:`UNDETERMINED_VARIANCE_RATIO` of its
    prior variance is not determined by the data, as for the radar terms.
    """
    prior = np.array(HEIGHT_PRIOR_SIGMA)
    blocks = solved.blocks
    if solved.height is None:
        value = np.zeros(2)
        covariance = np.diag(prior**2)
        cross = np.zeros((len(cross_labels), 2))
    else:
        value = solved.height
    undetermined = [key for key, variance, s in zip(
        HEIGHT_MODEL_KEYS, np.diag(covariance), prior, strict=True)
        if variance > UNDETERMINED_VARIANCE_RATIO * s**2]
    estimate = HeightModelEstimate(
        height_offset_m=float(value[0]), height_scale=float(value[1]),
        covariance=covariance, prior_sigma=prior, determined=not undetermined,
        cross_labels=cross_labels, cross_covariance=cross,
        n_adsb_segments=0 if blocks.height is None else len(blocks.height),
        n_pressure_pairs=int(sum(len(f) for f in blocks.pairs if f.height_key is not None))
        + (blocks.target_state.n_pressure_plots()
           if hasattr(blocks.target_state, "n_pressure_plots") else 0),
    )
    notes = []
    if undetermined:
        names = " and ".join(undetermined)
        why = ("no observation uses the pressure altitudes, so no radar estimate depends on it"
               if solved.height is None else
               "the 2-D radars' plots are placed with that uncertainty, which their sigmas include")
        notes.append(
            f"height model not determined by the data: {names} come from the weak prior "
            f"(1-sigma {prior[0]:g} m and {prior[1]:g}); {why}. ADS-B reports with baro_alt_m, "
            "or 2-D radars paired with 3-D radars, determine it"
        )
    return estimate, undetermined, notes


def add_factor(fg: FactorGraph, factor: AdsbFactor | PairwiseFactor, variable: set[str]) -> None:
    """Add a vectorised factor; radars without free terms enter as constants.

    A pairwise factor's height-model variable (pressure altitudes) is always a variable.
    """
    radar_ids = (
        [factor.terms.radar_id] if isinstance(factor, AdsbFactor)
        else [factor.terms_a.radar_id, factor.terms_b.radar_id]
    )
    is_variable = [rid in variable for rid in radar_ids]
    is_variable += [True] * (len(factor.keys) - len(radar_ids))
    if not any(is_variable):
        return
    keys = [k for k, v in zip(factor.keys, is_variable, strict=True) if v]

    def error(current: list[FloatArray], want: bool):
        it = iter(current)
        full = [next(it) if v else np.zeros(0) for v in is_variable]
        e, jac = factor.error(full, want)
        if jac is not None:
            jac = [j for j, v in zip(jac, is_variable, strict=True) if v]
        return e, jac

    fg.add_custom(keys, factor.dimension, error)


def _plots_used(blocks: FactorSet, radars: list[str]) -> dict[str, int]:
    used: dict[str, list[NDArray[np.int64]]] = {rid: [] for rid in blocks.terms}
    for rid, f in blocks.adsb.items():
        used[rid].append(f.plot_rows)
    for f in blocks.pairs:
        used[f.terms_a.radar_id].append(f.a_plots.index)
        used[f.terms_b.radar_id].append(f.b_plots.index)
    counts = {rid: len(np.unique(np.concatenate(used[rid]))) if used[rid] else 0
              for rid in radars}
    if blocks.target_state is not None:
        counts.update({
            rid: n for rid, n in blocks.target_state.plots_per_radar().items() if rid in counts
        })
    return counts


def _downweighted(
    blocks: FactorSet, values: dict[str, FloatArray], radars: list[str], result
) -> dict[str, dict[str, int]]:
    """Measurements with a final robust weight below 0.5, per radar and factor type."""
    out: dict[str, dict[str, int]] = {rid: {} for rid in radars}
    for rid, f in blocks.adsb.items():
        if rid in out:
            e, _ = f.whitened([values[rid]])
            out[rid]["adsb_plots"] = int(f.kernel.downweighted(e).sum())
    for f in blocks.pairs:
        ra, rb = f.terms_a.radar_id, f.terms_b.radar_id
        e, _ = f.whitened(_pair_values(f, values))
        n = int(f.kernel.downweighted(e).sum())
        for rid in (ra, rb):
            if rid in out:
                out[rid]["pairs"] = out[rid].get("pairs", 0) + n
    if blocks.target_state is not None:
        for rid, counts in blocks.target_state.downweighted(values, result).items():
            if rid in out:
                out[rid].update(counts)
    return out
