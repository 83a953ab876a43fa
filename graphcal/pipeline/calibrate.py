"""One calibration run: load -> select -> solve -> bound -> checks -> warnings.

:func:`calibrate` is what ``graphcal calibrate`` and the Python API call.  The
solvers estimate and nothing else; the analyses that judge an estimate (the
Cramér-Rao bound, the parameters the traffic hardly excites, the model checks
for structure left in the residuals) run here, once per calibration.

Options are keyword arguments named as on the command line.  An option that
the chosen method does not use, given a value other than its default, is an
error rather than silently ignored.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from graphcal.analysis.crlb import crlb
from graphcal.analysis.observability import report_from_information
from graphcal.core.solve_options import SolveOptions, method_defaults, option_methods
from graphcal.data.bias import CONTRACT_KEYS, NAME_FROM_KEY, from_contract_units
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset
from graphcal.io.folder import SITES_FILE, load_dataset, load_sites
from graphcal.model.problem import Problem, build_problem
from graphcal.noise import filled_with_notes
from graphcal.pipeline.associate import (
    association_notes,
    calibrate_associated,
    checks_association_warnings,
    needs_association,
)
from graphcal.solvers.registry import METHODS, get_estimator, solve

Progress = Callable[..., None]

#: ``time_offset`` choices (``graphcal calibrate --time-offset``) and graph's argument.
TIME_OFFSET_CHOICES: dict[str, bool | None] = {"auto": None, "on": True, "off": False}

#: Options of each method, with their defaults (those of the command line), from the one
#: option table (:class:`~graphcal.core.solve_options.SolveOptions`).
METHOD_OPTIONS: dict[str, dict[str, Any]] = {
    method: method_defaults(method) for method in METHODS
}


def parse_fixed(
    fixed: Mapping[str, float] | None, sites: Mapping[str, Any]
) -> dict[tuple[str, str], float]:
    """Contract-keyed fixed values -> the solver's ``{(radar, parameter): value SI}``.

    Parameters
    ----------
    fixed : mapping of str to float
        ``{"RADAR.key": value}`` in contract units, e.g. ``{"NORD.range_gain": 0.0,
        "SUD.azimuth_bias_mrad": 1.5}``.
    sites : mapping
        The dataset's sites (to check the radar ids).

    Raises
    ------
    ValueError
        For an unknown radar or key, naming the entry and the valid keys.
    """
    out: dict[tuple[str, str], float] = {}
    for target, value in (fixed or {}).items():
        rid, dot, key = str(target).rpartition(".")
        if not dot:
            raise ValueError(f"fixed {target!r}: expected RADAR.KEY, e.g. NORD.range_gain")
        if rid not in sites:
            raise ValueError(f"fixed {target!r}: unknown radar '{rid}'")
        if key not in NAME_FROM_KEY or key == "time_offset_s":
            keys = ", ".join(k for k in NAME_FROM_KEY if k != "time_offset_s")
            raise ValueError(f"fixed {target!r}: unknown key '{key}'; use one of: {keys}")
        name = NAME_FROM_KEY[key]
        out[(rid, name)] = from_contract_units(name, float(value))
    return out


def solve_options(method: str, given: Mapping[str, Any], sites: Mapping[str, Any]
                  ) -> SolveOptions:
    """The options of one calibration, as given to :func:`calibrate`.

    ``time_offset`` may be ``"auto"``, ``"on"`` or ``"off"`` and ``fixed`` is keyed
    ``"RADAR.key"`` in contract units (:func:`parse_fixed`).  An option that ``method``
    does not use, given at other than its default, is an error.
    """
    values = dict(given)
    if isinstance(values.get("time_offset"), str):
        choice = values["time_offset"]
        if choice not in TIME_OFFSET_CHOICES:
            raise ValueError(f"time_offset must be auto, on or off, not '{choice}'")
        values["time_offset"] = TIME_OFFSET_CHOICES[choice]
    values["fixed"] = parse_fixed(values.get("fixed"), sites)
    defaults = SolveOptions()
    for name, value in values.items():
        users = option_methods(name)
        if method not in users and value != getattr(defaults, name):
            raise ValueError(f"option {name} applies to {' and '.join(users)}, "
                             f"not to method '{method}'")
    return SolveOptions(**values)


def calibrate(
    dataset: Dataset | str | os.PathLike[str],
    method: str = "graph",
    *,
    max_gap_s: float | None = None,
    clean: bool = True,
    cross: str = "trajectory",
    robust: str = "huber",
    robust_scale: float = 1.0,
    use_adsb: bool = True,
    init: str = "auto",
    fixed: Mapping[str, float] | None = None,
    max_iterations: int = 100,
    time_offset: str | bool | None = "auto",
    iterations: int = 1,
    linearise: str = "plots",
    select: str | None = None,
    budget: int | None = None,
    select_unit: str = "segment",
    segment_s: float = 60.0,
    select_seed: int = 0,
    bound: bool | None = None,
    model_checks: bool = True,
    window: float | str | None = None,
    scheduler: str | None = None,
    drift: Mapping[str, float] | None = None,
    breaks: Mapping[str, list[float]] | None = None,
    detect_steps: bool = True,
    progress: Progress | None = None,
    force: bool = False,
    check_fit: bool = True,
) -> Calibration:
    """Estimate every radar's biases: select, solve, bound and judge, once.

    Parameters
    ----------
    dataset : Dataset or path
        A loaded :class:`~graphcal.data.dataset.Dataset`, or a dataset folder
        (read with :func:`graphcal.io.folder.load_dataset`).
    method : str
        An estimator of :data:`graphcal.solvers.registry.METHODS`: ``graph``
        (default), ``ls``, ``fl``, ``fl-ls``, ``wls``, ``wls-pruned``.
    max_gap_s : float, optional
        Longest time gap bridged by interpolation [s] (every method).
    clean : bool
        With a folder: drop duplicate, non-finite, stale and jumping records
        first (:func:`graphcal.data.cleaning.clean_dataset`; files untouched).
    cross, robust, robust_scale, use_adsb, init, max_iterations
        ``graph``: cross-radar formulation (``pairwise``, ``target-state``,
        ``none``), robust kernel (``huber``, ``cauchy``, ``none``) and the
        multiple of its threshold, whether to use ADS-B, initial values
        (``auto``, ``zero`` or a closed-form method), Levenberg-Marquardt
        iteration limit (see :func:`graphcal.solvers.graph.graph`).
    fixed : mapping of str to float, optional
        ``graph``: biases held at known values, contract keys and units:
        ``{"NORD.range_gain": 0.0}``.
    time_offset : {"auto", "on", "off"}
        ``graph``: estimate each radar's time-stamping bias ``time_offset_s``.
    iterations, linearise
        ``wls``/``wls-pruned``: re-linearisations (1 = paper 001) and where the
        Jacobians are evaluated (``plots`` or ``neighbours``).
    select : {"greedy", "e-optimal", "d-optimal", "random"}, optional
        Estimate on a selected part of the data
        (:func:`graphcal.analysis.selection.select_for_calibration`).
    budget : int, optional
        Observations to keep with ``select``.
    select_unit : {"segment", "track", "observation"}
        What ``select`` chooses.
    segment_s : float
        Segment length [s] with ``select_unit="segment"``.
    select_seed : int
        Seed of the random draw with ``select="random"``.
    bound : bool, optional
        Compute the Cramér-Rao bound of the estimated parameters and record,
        per parameter, ``info["crlb_sigma"]`` and ``info["efficiency"]`` (sigma
        over bound).  Default: for ``graph``.
    model_checks : bool
        Check each radar's corrected residuals for structure the model leaves
        out (refraction, pressure altitudes, antenna eccentricity, a bias
        drifting in time; :func:`graphcal.analysis.model_checks.model_checks`),
        against ADS-B or, without it (or with ``use_adsb=False``), against the
        other radars' plots.  Records ``info["model_checks"]`` and adds one
        warning per radar whose residuals show structure beyond chance.
    window : float or str, optional
        Biases over time (contract v2 ``--window``): a window length in seconds or
        as ``"15min"``, ``"1h"``; ``graph`` only, see
        :func:`graphcal.pipeline.windowed.calibrate_windows`, which also takes
        ``scheduler``, ``drift`` (contract units per sqrt(hour)), ``breaks``
        (radar id -> times [s]) and ``detect_steps``.  The bound, the model checks
        and a selection are not computed per window.
    progress : callable, optional
        ``progress(stage, done, total)``.
    force : bool
        With a folder: skip the unit and frame heuristics of the loaded data
        (:mod:`graphcal.data.plausibility`; ``--force``).
    check_fit : bool
        Raise :class:`~graphcal.analysis.fit_verdict.ModelMisfitError` when the
        fit verdict fails: a radar's residuals far beyond their sigmas, or a range
        gain beyond 1 % (:mod:`graphcal.analysis.fit_verdict`); with ``window``,
        in any window's own fit (against ADS-B).  The verdict is recorded in
        ``info["fit_verdict"]`` either way, and becomes a warning when not raised.

    Returns
    -------
    Calibration
        With ``info["selection"]`` when selecting, the bound when asked and
        ``info["model_checks"]`` unless turned off; with ``window``, the last
        window's biases and the ``series`` and ``events``.

    Raises
    ------
    GraphcalInputError
        Bad dataset folder.
    EstimationError
        The data do not allow an estimate.
    ModelMisfitError
        (an :class:`EstimationError`) With ``check_fit``: the fit verdict failed;
        the exception's ``calibration`` holds the result.
    ValueError
        Unknown method or option value, or an option the method does not use.
    """
    start = time.perf_counter()
    for name, value in (("max_gap_s", max_gap_s), ("segment_s", segment_s),
                        ("robust_scale", robust_scale)):
        if value is not None and not (isinstance(value, int | float)
                                      and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive, finite number, not {value}")
    folder = None
    constant_windows = (
        not isinstance(dataset, Dataset) and window is None and method == "graph"
        and select is None and not bound and init == "auto" and time_offset in ("auto", None)
        and not (scheduler or drift or breaks) and is_long_recording(dataset))
    if constant_windows:
        # A long recording: constant biases from its windows' summaries, read window by
        # window (memory bounded by a window, whatever the recording's length).
        folder = dataset
        sites = load_sites(Path(folder) / SITES_FILE)
    elif not isinstance(dataset, Dataset):
        if window is not None:  # read window by window, not loaded whole
            folder = dataset
            sites = load_sites(Path(folder) / SITES_FILE)
        else:
            dataset = load_dataset(dataset, clean=clean, force=force)
    if folder is None:
        sites = dataset.sites
    get_estimator(method)  # an unknown method is refused before any data is read
    given = {
        "cross": cross, "robust": robust, "robust_scale": robust_scale, "use_adsb": use_adsb,
        "init": init, "fixed": fixed or None, "max_iterations": max_iterations,
        "time_offset": time_offset, "iterations": iterations, "linearise": linearise,
    }
    options = solve_options(method, {**given, "max_gap_s": max_gap_s}, sites)
    if constant_windows:
        cal = _calibrate_windows(folder, method, CONSTANT_BATCH_WINDOW_S, options, clean=clean,
                                 select=None, bound=None, progress=progress, force=force,
                                 check_fit=check_fit, constant=True)
        cal.warnings.append(
            f"a recording longer than {CONSTANT_BATCH_MIN_SPAN_S / 3600:g} h: constant biases "
            f"from {cal.info['windows']['n_windows']} windows of "
            f"{CONSTANT_BATCH_WINDOW_S / 3600:g} h read one at a time (the Cramér-Rao bound "
            "and the model checks are not computed over windows)")
        return cal
    if window is not None:
        return _calibrate_windows(folder if folder is not None else dataset, method, window,
                                  options, clean=clean, select=select,
                                  bound=bound, scheduler=scheduler, drift=drift,
                                  breaks=breaks, detect_steps=detect_steps, progress=progress,
                                  force=force, check_fit=check_fit)
    windowed_only = {"scheduler": scheduler, "drift": drift, "breaks": breaks}
    for name, value in windowed_only.items():
        if value:
            raise ValueError(f"{name} applies to calibrations over time: give window as well")
    if not detect_steps:
        raise ValueError("detect_steps applies to calibrations over time: give window as well")
    if budget is not None and select is None:
        raise ValueError("budget applies to a selection: give select as well")
    selection = None
    if select is not None:
        from graphcal.analysis.selection import select_for_calibration

        if method == "wls-pruned":
            raise ValueError("selecting for wls-pruned would prune twice; use method wls")
        dataset, selection = select_for_calibration(
            dataset, method, select, budget, unit=select_unit, segment_s=segment_s,
            use_adsb=use_adsb, rng=np.random.default_rng(select_seed), progress=progress,
        )
    extra: dict[str, Any] = {}
    if method in ("graph", "wls", "wls-pruned"):
        extra["progress"] = progress
    if method == "graph":
        # The trajectory formulation computes the bound of its own model (one more
        # elimination of the paths) only when it is reported.
        extra["bound"] = bool(bound is None or bound)
    dataset, sigma_info, sigma_warnings = filled_with_notes(dataset)
    # One problem for the estimate, its bound, its checks and its verdict: the plots'
    # arrays and their alignments with ADS-B are made once.
    associated: dict[str, str] = {}
    if needs_association(dataset):  # radars without addresses: associate, then calibrate
        cal, problem, association = calibrate_associated(dataset, method, options, **extra)
        dataset = problem.dataset
        associated = association_notes(association)
    else:
        problem = build_problem(dataset, options)
        cal = solve(problem, method, **extra)
    if sigma_info is not None:
        cal.info["estimated_sigmas"] = sigma_info
        cal.warnings.extend(sigma_warnings)
    if selection is not None:
        summary = selection.to_dict()
        full = selection.units.information.sum(axis=0)
        summary["degree_all"] = report_from_information(selection.units.labels, full).degree
        cal.info["selection"] = summary
    if cal.information is not None:
        cal.warnings.extend(_poorly_excited(cal.labels, cal.information))
    if (method == "graph" if bound is None else bound) and cal.labels:
        t0 = time.perf_counter()
        if progress is not None:
            progress("Cramér-Rao bound", 0, 1)
        have_adsb = bool(use_adsb and dataset.adsb is not None and len(dataset.adsb) > 0)
        cal.info.update(bound_info(problem, cal, use_adsb=have_adsb,
                                   cross=cross != "none" or method != "graph",
                                   max_gap_s=options.max_gap_s))
        timing = cal.info.setdefault("timing_s", {})
        # Added to the solver's own (the trajectory formulation's bound is the solver's).
        timing["crlb_s"] = timing.get("crlb_s", 0.0) + time.perf_counter() - t0
        timing["total_s"] = time.perf_counter() - start
    checks = None
    if model_checks and cal.radar_ids and not _impossible(cal, dataset):
        if progress is not None:
            progress("model checks", 0, 1)
        checks = _check_model(problem, cal, use_adsb=use_adsb,
                              max_gap_s=options.max_gap_s)
        timing = cal.info.setdefault("timing_s", {})
        timing["model_checks_s"] = cal.info["model_checks"]["seconds"]
        timing["total_s"] = time.perf_counter() - start
        found = checks_association_warnings(cal.info["model_checks"], associated)
        cal.info["model_checks"]["warnings"] = [*cal.info["model_checks"].get("warnings", []),
                                                *found]
        cal.warnings.extend(found)
    _warn_shared_time_offset(cal, dataset.sites)
    if cal.radar_ids:
        _judge_fit(problem, cal, checks, use_adsb=use_adsb, max_gap_s=options.max_gap_s,
                   raise_on_failure=check_fit, associated=associated)
    return cal


def _warn_shared_time_offset(cal: Calibration, sites: Mapping[str, Any]) -> None:
    """Warn when every radar's time offset is one and the same, far beyond a sensor's:
    the ADS-B clock (:func:`graphcal.analysis.fit_verdict.shared_time_offset_warning`)."""
    from graphcal.analysis.fit_verdict import shared_time_offset_warning

    warning = shared_time_offset_warning(cal, sites)
    if warning is not None:
        cal.warnings.append(warning)


def _impossible(cal: Calibration, dataset: Dataset) -> bool:
    """Whether the estimate corrects plots to negative ranges (no residuals can be formed:
    the model checks are skipped, the fit verdict fails)."""
    from graphcal.analysis.fit_verdict import negative_ranges

    return any(negative_ranges(dataset, cal).values())


def _judge_fit(problem: Problem, cal: Calibration, checks: Any, *, use_adsb: bool,
               max_gap_s: float | None, raise_on_failure: bool,
               associated: dict[str, str] | None = None) -> None:
    """Record the fit verdict in ``info["fit_verdict"]``; raise when it failed and asked to.
    ``associated``: the radars whose plots were associated, each with its phrase
    (:func:`~graphcal.pipeline.associate.association_notes`)."""
    from graphcal.analysis.fit_verdict import ModelMisfitError, fit_verdict

    verdict = fit_verdict(problem, cal, checks=checks, use_adsb=use_adsb,
                          adsb_max_gap_s=max_gap_s)
    verdict.associated = dict(associated or {})
    cal.info["fit_verdict"] = verdict.to_dict()
    if not verdict.passed:
        if raise_on_failure:
            raise ModelMisfitError(verdict, cal)
        cal.warnings.append(verdict.message())
    if cal.method == "graph":
        _widen_sigmas(cal, verdict)


def _widen_sigmas(cal: Calibration, verdict: Any) -> None:
    """Widen the sigmas of the radars whose residuals exceed them beyond chance.

    :func:`graphcal.analysis.fit_verdict.sigma_inflation` gives each term of such a
    radar a variance factor ``f`` (the ``chi2/dof`` of the coordinate that measures it,
    when beyond chance; the largest for the time offset); the term's row and column of
    the joint covariance (and its row of the height model's cross-covariance) are
    multiplied by ``sqrt(f)``, which keeps the matrix positive semi-definite and the
    result's sigmas its diagonal's square roots.  Records ``info["sigma_inflation"]``
    (per radar: largest factor, coordinates, per-term factors) and scales
    ``info["efficiency"]`` (sigma over the bound) alike; one warning per radar.
    """
    from graphcal.analysis.fit_verdict import sigma_inflation

    widened = sigma_inflation(verdict)
    widened = {rid: w for rid, w in widened.items() if rid in cal.radar_ids}
    if not widened:
        return
    scale = np.array([math.sqrt(widened[rid].parameter_factor(name)) if rid in widened
                      else 1.0 for rid, name in cal.labels])
    cal.covariance = cal.covariance_si * np.outer(scale, scale)
    by_label = dict(zip(cal.contract_labels(), scale, strict=True))
    atmosphere = cal.atmosphere
    if atmosphere is not None and len(atmosphere.cross_labels):
        rows = np.array([by_label.get(label, 1.0) for label in atmosphere.cross_labels])
        cal.atmosphere = dataclasses.replace(
            atmosphere, cross_covariance=np.asarray(atmosphere.cross_covariance) * rows[:, None])
    efficiency = cal.info.get("efficiency") or {}
    for label, factor in by_label.items():
        if efficiency.get(label) is not None:
            efficiency[label] = efficiency[label] * float(factor)
    cal.info["sigma_inflation"] = {
        rid: w.to_dict(name for r, name in cal.labels if r == rid) for rid, w in widened.items()}
    for rid, w in widened.items():
        text = w.message()
        if rid in verdict.associated:
            text += (f"; its plots carry no address and were associated by gating "
                     f"({verdict.associated[rid]}): wrong associations show so too")
        cal.warnings.append(text)


#: A recording read from a folder that spans more than this [s] is calibrated for
#: constant biases from windows of :data:`CONSTANT_BATCH_WINDOW_S`, one at a time.
CONSTANT_BATCH_MIN_SPAN_S = 2.0 * 3600.0
#: As long as the longest recording calibrated whole, so that memory does not grow
#: beyond its; a window's fixed costs (initial values, the fit numbers) are then
#: shared by more plots than in one-hour windows (1 M plots: a seventh less time).
CONSTANT_BATCH_WINDOW_S = 2.0 * 3600.0


def is_long_recording(folder: str | os.PathLike[str]) -> bool:
    """Whether the dataset folder's plots span more than :data:`CONSTANT_BATCH_MIN_SPAN_S`
    (from the Parquet statistics or the ``time_s`` column alone); ``False`` when that
    cannot be told (the full load then reports the problem)."""
    from graphcal.io.dataset_span import csv_end_times, dataset_span
    from graphcal.io.folder import dataset_tables

    try:  # two rows of a CSV file this far apart in time settle it without reading it
        ends = [csv_end_times(path) for path in dataset_tables(Path(folder))[0]]
        if any(e is not None and abs(e[1] - e[0]) > CONSTANT_BATCH_MIN_SPAN_S for e in ends):
            return True
    except Exception:  # noqa: BLE001 - the span below, or the full load, tells what is wrong
        pass
    try:
        span = dataset_span(folder)
    except Exception:  # noqa: BLE001 - the full load names what is wrong with the folder
        return False
    if not (math.isfinite(span.t_start_s) and math.isfinite(span.t_end_s)):
        return False
    return span.t_end_s - span.t_start_s > CONSTANT_BATCH_MIN_SPAN_S


def _calibrate_windows(dataset: Dataset | str | os.PathLike[str], method: str,
                       window: float | str, options: SolveOptions, *, clean: bool,
                       select: str | None, bound: bool | None, progress: Progress | None,
                       force: bool = False, check_fit: bool = True, **chain: Any
                       ) -> Calibration:
    """``calibrate(window=...)``: the graph per window, chained (pipeline.windowed)."""
    from graphcal.core.durations import parse_duration
    from graphcal.pipeline.windowed import calibrate_windows

    if method != "graph":
        raise ValueError(f"window applies to the graph method, not {method}")
    if select is not None:
        raise ValueError("select is not available with window: each window uses all its data")
    if bound:
        raise ValueError("the Cramér-Rao bound is not computed per window; drop bound")
    if options.init != "auto":
        raise ValueError("init applies to one batch; each window starts from its own "
                         "closed-form estimate")
    if options.time_offset is not None:
        raise ValueError("time_offset: with window, time offsets are estimated in every "
                         "window with ADS-B")
    cal = calibrate_windows(dataset, parse_duration(window), clean=clean,
                            options=options, progress=progress, force=force,
                            check_fit=check_fit, **chain)
    if isinstance(dataset, Dataset):
        sites = dataset.sites
    else:
        sites = load_sites(Path(dataset) / SITES_FILE)
    _warn_shared_time_offset(cal, sites)
    return cal


def _check_model(problem: Problem, cal: Calibration, *, use_adsb: bool,
                 max_gap_s: float | None) -> Any:
    """Run the model checks on the data the estimator used; record them and their warnings.

    Returns the :class:`~graphcal.analysis.model_checks.ModelChecks`.
    """
    from graphcal.analysis.model_checks import model_checks

    checks = model_checks(problem, cal, use_adsb=use_adsb, adsb_max_gap_s=max_gap_s)
    cal.info["model_checks"] = checks.to_dict()
    cal.warnings.extend(checks.warnings())
    return checks


def _poorly_excited(labels: list[tuple[str, str]], data_information: np.ndarray) -> list[str]:
    """Plain-words warnings for parameters the traffic hardly excites on their own
    (variance inflation above :data:`graphcal.analysis.observability.VIF_WARNING`)."""
    if not labels or np.any(np.diag(data_information) <= 0):
        return []
    return report_from_information(labels, data_information).confounded()


def bound_info(
    data: Dataset | Problem,
    cal: Calibration,
    *,
    use_adsb: bool,
    cross: bool,
    max_gap_s: float | None = None,
) -> dict[str, Any]:
    """``crlb_sigma``, ``efficiency`` (reported sigma / CRLB sigma) and ``crlb_model``.

    The bound is computed for the calibration's own labels, with the weak priors
    the estimator recorded in ``info["priors"]`` (contract units), so that the
    two are comparable.  With pressure altitudes the height model is an unknown of
    the bound too (its 2-D plots placed at the calibration's estimate), and its two
    parameters get entries ``atmosphere.height_offset_m`` and ``atmosphere.height_scale``.
    """
    if cal.bound is not None:
        return _own_bound_info(cal)
    priors: dict[tuple[str, str], float] = {}
    for rid, entries in (cal.info.get("priors") or {}).items():
        for key, value in entries.items():
            name = NAME_FROM_KEY[key]
            priors[(rid, name)] = from_contract_units(name, value)
    options: dict[str, Any] = {"use_adsb": use_adsb, "cross": cross, "labels": cal.labels,
                               "priors": priors or None}
    if max_gap_s is not None:
        options["max_gap_s"] = max_gap_s
    if cal.atmosphere is not None:
        options["height_model"] = cal.atmosphere.model
    result = crlb(data, **options)
    sigma, efficiency = {}, {}
    for i, (rid, name) in enumerate(cal.labels):
        key, scale = CONTRACT_KEYS[name]
        bound_sigma = result.sigma(rid, key)
        sigma[f"{rid}.{key}"] = float(bound_sigma)
        reported = float(np.sqrt(cal.covariance_si[i, i])) * scale
        efficiency[f"{rid}.{key}"] = float(reported / bound_sigma) if bound_sigma > 0 else None
    if cal.atmosphere is not None and result.atmosphere_sigma is not None:
        for key, bound_sigma in result.atmosphere_sigma.items():
            sigma[f"atmosphere.{key}"] = bound_sigma
            reported = cal.atmosphere.sigma[key]
            efficiency[f"atmosphere.{key}"] = (
                reported / bound_sigma if 0 < bound_sigma < np.inf else None)
    note = "targets from ADS-B" if use_adsb else "targets estimated"
    if cross:
        note += ", cross-radar events with straight-line target segments"
    return {"crlb_sigma": sigma, "efficiency": efficiency, "crlb_model": note}


def _own_bound_info(cal: Calibration) -> dict[str, Any]:
    """:func:`bound_info` from the bound the estimator computed of its own model."""
    assert cal.bound is not None
    bound_sd = np.sqrt(np.maximum(np.diag(cal.bound["covariance"]), 0.0))
    sigma, efficiency = {}, {}
    for i, (rid, name) in enumerate(cal.labels):
        key, scale = CONTRACT_KEYS[name]
        bound_sigma = float(bound_sd[i] * scale)
        sigma[f"{rid}.{key}"] = bound_sigma
        reported = float(np.sqrt(cal.covariance_si[i, i])) * scale
        efficiency[f"{rid}.{key}"] = reported / bound_sigma if bound_sigma > 0 else None
    atmosphere_sigma = cal.bound.get("atmosphere_sigma")
    if cal.atmosphere is not None and atmosphere_sigma:
        for key, bound_sigma in atmosphere_sigma.items():
            sigma[f"atmosphere.{key}"] = bound_sigma
            reported = cal.atmosphere.sigma[key]
            efficiency[f"atmosphere.{key}"] = (
                reported / bound_sigma if 0 < bound_sigma < np.inf else None)
    return {"crlb_sigma": sigma, "efficiency": efficiency, "crlb_model": cal.bound["model"]}


__all__ = ["CONSTANT_BATCH_MIN_SPAN_S", "CONSTANT_BATCH_WINDOW_S", "METHODS", "METHOD_OPTIONS",
           "solve_options",
           "TIME_OFFSET_CHOICES", "bound_info", "calibrate", "is_long_recording",
           "parse_fixed"]
