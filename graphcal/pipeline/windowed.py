"""One calibration over time windows (``graphcal calibrate --window``, contract v2).

The dataset is cut into windows; each window is reduced to a Gaussian summary on its
biases (:func:`graphcal.solvers.windows.summarise_window`) by the chosen scheduler
(:mod:`graphcal.pipeline.schedulers`); the summaries are chained and smoothed
(:func:`graphcal.solvers.windows.smooth_windows`), with each term's random-walk rate
estimated or given (``--drift``), steps searched for and known changes declared
(``--break``).  The result is a :class:`~graphcal.data.calibration.Calibration` whose
``radars`` block, covariance and atmosphere are the last window's (the correction to
apply from now on) and which carries the contract's ``series`` and ``events``.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from itertools import chain
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from graphcal.core.errors import EstimationError
from graphcal.data.bias import CONTRACT_KEYS, ECCENTRICITY_NAMES, NAME_FROM_KEY, PARAMETER_NAMES
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset, Site
from graphcal.data.windows import Window, split_window, split_windows, window_index
from graphcal.model import path_kernels
from graphcal.model.information import observability
from graphcal.model.parameters import RadarTerms, prior_sigmas
from graphcal.noise import filled_with_notes
from graphcal.pipeline.associate import associated_window, merged_figures
from graphcal.pipeline.schedulers import (
    ForkedHelper,
    check_scheduler,
    child_reading_available,
    map_windows,
)
from graphcal.pipeline.window_feed import (
    FolderReadAgain,
    SpanCheck,
    open_folder_windows,
    read_folder_windows,
    reads_in_child,
)
from graphcal.solvers.drift import DEFAULT_STEP_FALSE_ALARM
from graphcal.solvers.windows import (
    WindowedCalibration,
    WindowEstimate,
    WindowOptions,
    WindowSummary,
    smooth_windows,
    summarise_window,
)

if TYPE_CHECKING:
    from graphcal.analysis.fit_verdict import FitVerdict, SigmaInflation

Progress = Callable[..., None]

#: A step inside a window is located to within this [s] (_locate_step) ...
STEP_TIME_TOLERANCE_S = 30.0

#: ... starting from a grid of this many candidate times over the window.
STEP_GRID_POINTS = 7

#: Windows calibrated with NumPy's sums before the compiled loops may be loaded
#: (:class:`_CompiledLoopsWhenWorthIt`) ...
COMPILED_LOOPS_AFTER_WINDOWS = 3
#: ... when they took at least this long each [s] (a one-hour window of a four-radar
#: network with 30,000 plots and 80,000 ADS-B reports takes 0.4 s, of which the compiled
#: loops save 0.15 s).
COMPILED_LOOPS_MIN_WINDOW_S = 0.25
#: A smoothed window further than this from its summary's linearisation point, in
#: that window's own sigmas, is worth a warning (the summaries are not re-linearised).
LARGEST_MOVE_WARNING_SIGMA = 10.0


def parse_drift(items: Mapping[str, float]) -> dict[str, float]:
    """``{"azimuth_bias_mrad": 0.5}`` (contract units per sqrt(hour)) -> SI per sqrt(s).

    Raises
    ------
    ValueError
        For an unknown key or a negative or non-finite rate.
    """
    rates = {}
    for key, value in items.items():
        name = NAME_FROM_KEY.get(key)
        if name is None:
            known = ", ".join(CONTRACT_KEYS[n][0] for n in CONTRACT_KEYS)
            raise ValueError(f"--drift {key}: unknown bias key; use one of {known}")
        value = float(value)
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"--drift {key}={value}: a rate must be finite and >= 0")
        rates[name] = value / CONTRACT_KEYS[name][1] / 60.0
    return rates


# One BLAS thread: the linear algebra of a window is small, and the folder's reader
# works on the other core (BLAS threads waiting for a core cost a third of the time).
@threadpool_limits.wrap(limits=1, user_api="blas")
def calibrate_windows(
    dataset: Dataset | str | os.PathLike[str],
    window_s: float,
    *,
    clean: bool = True,
    scheduler: str | None = None,
    drift: Mapping[str, float] | None = None,
    breaks: Mapping[str, Sequence[float]] | None = None,
    detect_steps: bool = True,
    step_false_alarm: float = DEFAULT_STEP_FALSE_ALARM,
    options: WindowOptions | None = None,
    progress: Progress | None = None,
    force: bool = False,
    check_fit: bool = True,
    constant: bool = False,
) -> Calibration:
    """Calibrate ``dataset`` in windows of ``window_s`` seconds (module docstring).

    Parameters
    ----------
    dataset : Dataset or path
        A loaded dataset, or a dataset folder, which is then read window by window
        (:func:`graphcal.io.window_reader.iter_windows`): memory is bounded by a
        window, not by the recording.  Sigmas missing from ``sites.toml`` are then
        estimated from the first window.
    window_s : float
        Window length [s]; windows are aligned on multiples of it.
    clean : bool
        With a folder: clean each window (:mod:`graphcal.io.window_reader`).
    scheduler : str, optional
        ``synchronous`` (default), ``threads``, ``processes`` or a Dask address.
    drift : mapping, optional
        Random-walk rates in contract units per sqrt(hour) (``{"range_offset_m": 2}``),
        used as given; the other rates are estimated.
    breaks : mapping, optional
        Radar id -> times [s] of known changes.
    detect_steps : bool
        Search for steps beyond the random walk.
    step_false_alarm : float
        Chance of one false step per radar and recording.
    options : WindowOptions, optional
        How each window is calibrated (default: :class:`WindowOptions`'s defaults).
    progress : callable, optional
        ``progress(stage, done, total)``.
    force : bool
        With a folder: skip the unit and frame heuristics on the rows read
        (:mod:`graphcal.data.plausibility`).
    check_fit : bool
        Raise :class:`~graphcal.analysis.fit_verdict.ModelMisfitError` when the fit
        verdict over the windows fails (:func:`_judge`); else it becomes a warning.
        The verdict is recorded in ``info["fit_verdict"]`` either way.
    constant : bool
        Constant biases over the whole recording instead of biases over time: the
        windows' summaries combined with no random walk between them
        (:func:`graphcal.solvers.windows.constant_biases`), in the memory of one window.
        ``drift``, ``breaks`` and step detection do not apply.

    Raises
    ------
    ValueError
        Bad option (unknown radar in ``breaks``, unknown drift key, bad scheduler).
    EstimationError
        No window has anything to calibrate.
    ModelMisfitError
        (an :class:`EstimationError`) With ``check_fit``: a radar's residuals are far
        beyond their sigmas in some window (or its range gain beyond reason); the
        exception's ``calibration`` holds the result.
    """
    start = time.perf_counter()
    scheduler = check_scheduler(scheduler)
    rates = parse_drift(drift or {})
    options = options or WindowOptions()
    first_pass = (dataset, window_s, clean, force, breaks, options, scheduler, progress)
    try:
        source, summaries, scheduler = _first_pass(*first_pass)
    except FolderReadAgain:
        # Read as if in time order, and it is not: the windows may lack late rows.
        source, summaries, scheduler = _first_pass(*first_pass, order="auto")
    # Residuals beyond their sigmas (pooled over the windows) widen every window's.
    widened = _sigma_inflation(summaries)
    summaries = [_widened(s, widened) for s in summaries]
    elapsed = time.perf_counter() - start
    if constant:
        cal = _constant_calibration(summaries, source.sites, window_s, source.cleaning_warnings)
        cal.info["timing_s"] = {"summaries_s": elapsed, "total_s": time.perf_counter() - start}
        return _concluded(cal, summaries, source, scheduler, dataset, widened, check_fit)
    if progress is not None:
        progress("smoothing the chain", 0, 1)
    chain = {"random_walk_per_sqrt_s": rates, "breaks": breaks,
             "detect_steps": detect_steps, "step_false_alarm": step_false_alarm}
    result = smooth_windows(summaries, source.sites, window_s, **chain)
    changes = _changes(result, breaks or {})
    if changes:
        # A bias that changes inside a window does not fit one value there.  Each step
        # found is located (_locate_step, over its window or the two windows around the
        # boundary where it was found); a window holding a change is cut there and its
        # parts calibrated; then the chain is smoothed again.
        t0 = time.perf_counter()
        # Read again only the windows around the changes.
        needed = {i for when, _, _ in changes
                  for i in (int(np.floor(when / window_s)), int(np.ceil(when / window_s)) - 1)}
        # A misfit in a window away from the changes is not cured by cutting windows:
        # judged now, before locating steps in data that do not fit the model.
        early = _judge(summaries)
        if check_fit and early is not None and _misfit_away_from(early, summaries, needed):
            cal = to_calibration(result, source.sites, source.cleaning_warnings)
            _finish(cal, source, scheduler, dataset)
            _stop(early, cal)
        windows = {w.index: w for w in source.windows() if w.index in needed}
        located = []
        for when, rid, statistic in changes:
            if statistic is not None:
                span = _span_around(windows, when, window_s)
                if span is not None:
                    span = _radar_only(span, rid, options)
                    others = [t for t, r, _ in changes if r != rid
                              and span.t_start_s < t < span.t_end_s]
                    when = _snap(_locate_step(span, others, options), window_s)
            located.append((when, rid, statistic))
        cuts: dict[int, list[tuple[float, str, float | None]]] = {}
        for when, rid, statistic in located:
            index = int(np.floor(when / window_s))
            if index * window_s < when < (index + 1) * window_s and index in windows:
                cuts.setdefault(index, []).append((when, rid, statistic))
        located_steps: dict[str, list[tuple[float, float | None]]] = {}
        for when, rid, statistic in located:
            if statistic is not None:
                located_steps.setdefault(rid, []).append((when, statistic))
        parts = [part for index in sorted(cuts)
                 for part in split_window(windows[index], [t for t, _, _ in cuts[index]])]
        # A few parts: in this process rather than a copy forked now (threads run here).
        again = "synchronous" if scheduler == "forked" else scheduler
        part_summaries = [s for s in map_windows(summarise_associated, parts, scheduler=again,
                                                 args=(options,), progress=progress,
                                                 total=len(parts),
                                                 stage="windows holding a step, in parts")
                          if s is not None]
        part_summaries = [_widened(s, widened) for s in part_summaries]
        summaries = sorted([s for s in summaries if s.index not in cuts] + part_summaries,
                           key=lambda s: (s.t_start_s, s.t_end_s))
        result = smooth_windows(summaries, source.sites, window_s,
                                found_steps=located_steps, **chain)
        elapsed += time.perf_counter() - t0
    result.timing_s["summaries_s"] = elapsed
    result.timing_s["total_s"] = time.perf_counter() - start
    cal = to_calibration(result, source.sites, source.cleaning_warnings)
    return _concluded(cal, summaries, source, scheduler, dataset, widened, check_fit)


def summarise_associated(window: Window, options: WindowOptions) -> WindowSummary | None:
    """:func:`~graphcal.solvers.windows.summarise_window` of the window with its plots
    without an address associated first (:func:`graphcal.pipeline.associate.associated_window`:
    radars without Mode S calibrated window by window)."""
    window, association = associated_window(window, options)
    summary = summarise_window(window, options)
    if summary is not None and association is not None:
        summary.association = association.to_dict()
    return summary


def _concluded(cal: Calibration, summaries: Sequence[WindowSummary], source: _Source,
               scheduler: str, dataset: Dataset | str | os.PathLike[str],
               widened: Mapping[str, SigmaInflation], check_fit: bool) -> Calibration:
    """``cal`` with the run's sigmas and scheduler, its widening and the fit verdict over
    the windows (raised with ``check_fit`` when it fails)."""
    _finish(cal, source, scheduler, dataset)
    _record_inflation(cal, widened)
    associated = [s.association for s in summaries if s.association is not None]
    if associated:
        cal.info["association"] = {"radars": merged_figures(associated),
                                   "windows": len(associated)}
    verdict = _judge(summaries)
    if verdict is not None:
        if not verdict.passed and check_fit:
            _stop(verdict, cal)
        _record_verdict(cal, verdict)
    return cal


def _first_pass(dataset: Dataset | str | os.PathLike[str], window_s: float, clean: bool,
                force: bool, breaks: Mapping[str, Sequence[float]] | None,
                options: WindowOptions, scheduler: str, progress: Progress | None,
                order: str | None = None) -> tuple[_Source, list[WindowSummary], str]:
    """The windows' source, every window's summary, in order (the first pass), and the
    scheduler that made them (``auto`` resolved).

    Raises what the folder's span shows to be wrong before any other error, as when
    it was measured before the first window; :class:`FolderReadAgain` when the
    folder was read as if in time order and is not.
    """
    source = helper = None
    prepare = _CompiledLoopsWhenWorthIt()
    if scheduler == "auto":  # forked for a large folder on two cores or more
        scheduler = ("forked" if not isinstance(dataset, Dataset) and reads_in_child(
            Path(dataset)) and (os.cpu_count() or 1) >= 2 else "synchronous")
    if scheduler == "forked" and child_reading_available():
        # The compiled loops loaded once, here, for both processes (while the reader
        # reads the first windows); the copy forked now, before the folder's span is
        # measured in a thread.
        path_kernels.enable()
        # The solvers too (imported at the first window otherwise), so that the copy
        # has them: imported once, not twice.
        import graphcal.model.trajectory  # noqa: F401
        import graphcal.solvers.adsb_reference  # noqa: F401
        import graphcal.solvers.graph  # noqa: F401
        import graphcal.solvers.registry  # noqa: F401

        helper = ForkedHelper(summarise_associated, (options,), prepare)
    try:
        source = (_memory_source(dataset, window_s) if isinstance(dataset, Dataset)
                  else _folder_source(Path(dataset), window_s, clean, force, order))
        for rid in breaks or {}:
            if rid not in source.sites:
                raise ValueError(f"--break {rid}@...: unknown radar; known: "
                                 f"{', '.join(source.sites)}")

        def report(stage: str, done: int, total: int | None) -> None:
            # The folder's window count is known once its span is measured.
            assert progress is not None and source is not None
            progress(stage, done, source.total)

        summaries = [s for s in map_windows(summarise_associated, source.windows(),
                                            scheduler=scheduler, args=(options,),
                                            progress=None if progress is None else report,
                                            total=source.total,
                                            prefetch=not source.read_ahead,
                                            prepare=prepare, helper=helper)
                     if s is not None]
    except Exception:
        if helper is not None:
            helper.stop()
        if source is not None:
            source.close()
            source.settle()
        raise
    source.settle()
    return source, summaries, scheduler


def _finish(cal: Calibration, source: _Source, scheduler: str,
            dataset: Dataset | str | os.PathLike[str]) -> None:
    """The run's estimated sigmas and the scheduler, in ``cal``."""
    if source.sigma_info is not None:
        cal.info["estimated_sigmas"] = source.sigma_info
        cal.warnings.extend(source.sigma_warnings)
    cal.info["windows"]["scheduler"] = scheduler
    cal.info["windows"]["streamed"] = not isinstance(dataset, Dataset)


class _CompiledLoopsWhenWorthIt:
    """``prepare`` of the window map: after :data:`COMPILED_LOOPS_AFTER_WINDOWS` windows
    (not counting the first, which also pays for loading the solvers), the process
    calibrating them switches to the paths' compiled loops
    (:mod:`graphcal.model.path_kernels`) if they took at least
    :data:`COMPILED_LOOPS_MIN_WINDOW_S` each: loading the loops (about 0.4 s, a few
    seconds the first time on a machine) then pays back within a few windows."""

    def __init__(self) -> None:
        self._started: float | None = None
        self._timed = -1  # windows done since the first one ended

    def __call__(self, number: int) -> None:
        now = time.perf_counter()
        if self._timed == 0:
            self._started = now
        elif (self._started is not None and self._timed >= COMPILED_LOOPS_AFTER_WINDOWS
              and not path_kernels.enabled()
              and (now - self._started) / self._timed >= COMPILED_LOOPS_MIN_WINDOW_S):
            path_kernels.enable()
        self._timed += 1


def _judge(summaries: Sequence[WindowSummary]) -> FitVerdict | None:
    """The fit verdict over the windows' own fits (None when no summary carries one)."""
    from graphcal.analysis.fit_verdict import windows_verdict

    fits = [(s.t_start_s, s.t_end_s, s.fit) for s in summaries if s.fit is not None]
    return windows_verdict(fits) if fits else None


def _sigma_inflation(summaries: Sequence[WindowSummary]) -> dict[str, SigmaInflation]:
    """The radars whose residuals, pooled over the windows, exceed their sigmas beyond
    chance (:func:`graphcal.analysis.fit_verdict.sigma_inflation`)."""
    from graphcal.analysis.fit_verdict import pooled_verdict, sigma_inflation

    fits = [s.fit for s in summaries if s.fit is not None]
    return sigma_inflation(pooled_verdict(fits)) if fits else {}


def _widened(summary: WindowSummary, widened: Mapping[str, SigmaInflation]) -> WindowSummary:
    """``summary`` with its data's information on each widened term divided by the term's
    variance factor (``L' = D^-1 L D^-1``, ``D = diag(sqrt(f))``; the weak priors kept), so
    that the chain weighs the window as its residuals say; the estimate is kept."""
    scale = np.array([np.sqrt(widened[rid].parameter_factor(name)) if rid in widened
                      else 1.0 for rid, name in summary.labels])
    if not len(scale) or np.all(scale == 1.0):
        return summary
    information, _ = summary.data_information()
    covariance = np.linalg.inv(information / np.outer(scale, scale)
                               + np.diag(summary.prior_sigma ** -2.0))
    atmosphere = summary.atmosphere
    if atmosphere is not None and len(atmosphere.cross_labels):
        by_label = {f"{rid}.{CONTRACT_KEYS[name][0]}": value
                    for (rid, name), value in zip(summary.labels, scale, strict=True)}
        rows = np.array([by_label.get(label, 1.0) for label in atmosphere.cross_labels])
        atmosphere = replace(atmosphere, cross_covariance=np.asarray(
            atmosphere.cross_covariance) * rows[:, None])
    return replace(summary, covariance=0.5 * (covariance + covariance.T), atmosphere=atmosphere)


def _record_inflation(cal: Calibration, widened: Mapping[str, SigmaInflation]) -> None:
    """``info["sigma_inflation"]`` and one warning per widened radar."""
    if not widened:
        return
    cal.info["sigma_inflation"] = {
        rid: {**w.to_dict(name for r, name in cal.labels if r == rid), "pooled_windows": True}
        for rid, w in widened.items()}
    cal.warnings.extend(w.message() + " (residuals pooled over the windows)"
                        for w in widened.values())


def _misfit_away_from(verdict: FitVerdict, summaries: Sequence[WindowSummary],
                      indices: set[int]) -> bool:
    """Whether a radar failed in a window whose index is not in ``indices``."""
    spans = {(s.t_start_s, s.t_end_s) for s in summaries if s.index not in indices}
    return any((w.t_start_s, w.t_end_s) in spans
               for rid in verdict.failed for w in verdict.failed_windows(rid))


def _record_verdict(cal: Calibration, verdict: FitVerdict) -> None:
    """``info["fit_verdict"]``; a failed verdict as a warning, a run judged on no
    window's residuals (without ADS-B) said so."""
    cal.info["fit_verdict"] = verdict.to_dict()
    if not verdict.passed:
        cal.warnings.append(verdict.message())
    elif verdict.reference == "none":
        cal.warnings.append(
            "fit verdict: no window's residuals were judged (without ADS-B a window carries "
            "only its range gains and negative ranges); see docs/model-checks.md")


def _stop(verdict: FitVerdict, cal: Calibration) -> NoReturn:
    """Raise :class:`~graphcal.analysis.fit_verdict.ModelMisfitError` for ``cal``, the
    verdict recorded in its ``info["fit_verdict"]``."""
    from graphcal.analysis.fit_verdict import ModelMisfitError

    cal.info["fit_verdict"] = verdict.to_dict()
    raise ModelMisfitError(verdict, cal)


@dataclass
class _Source:
    """Where the windows come from: a dataset in memory, or a folder read window by window."""

    sites: dict[str, Site]
    windows: Callable[[], Iterator[Window]]  # a fresh pass over the windows at each call
    total: int | None  # windows; None until known
    cleaning_warnings: list[str] = field(default_factory=list)
    sigma_info: Any = None
    sigma_warnings: list[str] = field(default_factory=list)
    read_ahead: bool = False  # the first pass's windows are already read ahead (a child)
    #: Raises what the folder's span shows to be wrong (FolderReadAgain among it).
    settle: Callable[[], None] = lambda: None
    #: Stops the first pass's reader.
    close: Callable[[], None] = lambda: None


def _memory_source(dataset: Dataset, window_s: float) -> _Source:
    dataset, info, warnings = filled_with_notes(dataset)
    total = len(np.unique(window_index(dataset.plots["time_s"].to_numpy(float), window_s)))
    cleaning = list(dataset.cleaning.warnings) if dataset.cleaning is not None else []
    return _Source(dataset.sites, lambda: split_windows(dataset, window_s), total, cleaning,
                   info, warnings)


def _folder_source(folder: Path, window_s: float, clean: bool, force: bool,
                   order: str | None = None) -> _Source:
    """The folder's windows, read as they are calibrated.

    The first pass reads every window once, in a forked child process for a large
    folder (:mod:`graphcal.pipeline.window_feed`; the command line starts it before
    this is called), whose first window also gives the sigmas missing from
    ``sites.toml``; a later pass (the windows around a step) reads the folder again
    in this process.  Meanwhile a thread measures the folder's span: for the
    progress, the time-overlap check the reader leaves to us, and the time order it
    may have taken for granted; the source's ``settle`` raises what it finds
    (:class:`~graphcal.pipeline.window_feed.SpanCheck`), the first pass's windows
    check it as soon as it is measured.
    """
    stream, in_child, order = open_folder_windows(folder, window_s, clean, force, order)
    span = SpanCheck(folder, force=force, order=order)
    close = getattr(stream, "close", lambda: None)
    try:
        first = next(stream, None)
    except Exception:
        close()
        span.result()  # the span's findings first
        raise
    if first is None:
        span.result()
        raise EstimationError(f"{folder}: no plots to calibrate")
    filled, info, warnings = filled_with_notes(first.dataset)
    sites = filled.sites
    first_pass = [chain([first], stream)]  # taken by the first call of windows()

    def windows() -> Iterator[Window]:
        recipe = (folder, window_s, clean, force, order)
        checking = bool(first_pass)
        source = first_pass.pop() if first_pass else read_folder_windows(*recipe)
        for window in source:
            if checking and span.done:
                checking = False
                _settle(made, span, window_s)
            yield replace(window, dataset=replace(window.dataset, sites=sites))

    made = _Source(sites, windows, None, [], info, warnings, read_ahead=in_child,
                   settle=lambda: _settle(made, span, window_s), close=close)
    return made


def _settle(source: _Source, span: SpanCheck, window_s: float) -> None:
    """``span`` measured and checked, and the window count in ``source.total``."""
    source.total = len(span.result().window_indices(window_s))


def _radar_only(window: Window, radar_id: str, options: WindowOptions) -> Window:
    """``window`` reduced to ``radar_id``'s plots and the ADS-B of the aircraft it saw,
    for locating that radar's step.

    Against ADS-B a radar's biases are determined by its own plots: the cost of a cut
    then only weighs the data that can see the step, and a step of one radar in a
    network of twenty is located in a twentieth of the time and memory.  Without
    ADS-B the radar needs its neighbours, and the window is kept whole.
    """
    dataset = window.dataset
    adsb = dataset.adsb
    if not options.use_adsb or adsb is None or adsb.empty:
        return window
    plots = dataset.plots[dataset.plots["radar_id"] == radar_id]
    if plots.empty:
        return window
    seen = adsb["target_id"].isin(plots["target_id"].unique())
    if not seen.any():  # it saw no aircraft with ADS-B: its neighbours are needed
        return window
    reduced = replace(dataset, plots=plots.reset_index(drop=True),
                      adsb=adsb[seen.to_numpy()].reset_index(drop=True),
                      sites={radar_id: dataset.sites[radar_id]})
    return replace(window, dataset=reduced)


def _split_cost(window: Window, times: Sequence[float], options: WindowOptions) -> float:
    """The window's total cost when cut at ``times`` and each part calibrated alone."""
    total = 0.0
    for part in split_window(window, list(times)):
        summary = summarise_window(part, options, judge=False)
        total += summary.cost if summary is not None else 0.0
    return total


def _locate_step(window: Window, others: Sequence[float], options: WindowOptions) -> float:
    """The time of a step inside ``window``: where cutting it fits its data best.

    The window is cut at a candidate time (and at the ``others`` changes inside it),
    each part calibrated on its own, and the parts' costs added: plots on the wrong
    side of the cut misfit by the step, so the total is least at the step.  A grid of
    :data:`STEP_GRID_POINTS` times, then a golden-section search between the best
    point's neighbours, down to :data:`STEP_TIME_TOLERANCE_S`.  Each part is calibrated
    by the pairwise formulation (comment below), whatever ``options.cross`` says.
    """
    a, b = window.t_start_s, window.t_end_s
    # The cuts are compared by the pairwise formulation's cost, which varies smoothly with
    # the cut: the trajectory formulation estimates each part's process noise on a grid,
    # and its cost jumps where a part's choice changes.  (Also a fifth of the time.)
    options = replace(options, cross="pairwise")
    grid = np.linspace(a, b, STEP_GRID_POINTS + 2)[1:-1]
    costs = [_split_cost(window, [t, *others], options) for t in grid]
    best = int(np.argmin(costs))
    low = grid[best - 1] if best > 0 else a + 1.0
    high = grid[best + 1] if best + 1 < len(grid) else b - 1.0
    golden = (np.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = high - golden * (high - low), low + golden * (high - low)
    f1 = _split_cost(window, [x1, *others], options)
    f2 = _split_cost(window, [x2, *others], options)
    while high - low > STEP_TIME_TOLERANCE_S:
        if f1 <= f2:
            high, x2, f2 = x2, x1, f1
            x1 = high - golden * (high - low)
            f1 = _split_cost(window, [x1, *others], options)
        else:
            low, x1, f1 = x1, x2, f2
            x2 = low + golden * (high - low)
            f2 = _split_cost(window, [x2, *others], options)
    candidates = [(costs[best], float(grid[best])), (f1, float(x1)), (f2, float(x2))]
    return min(candidates)[1]


def _changes(result: WindowedCalibration, breaks: Mapping[str, Sequence[float]]
             ) -> list[tuple[float, str, float | None]]:
    """``(time, radar, statistic)`` of the steps found and the breaks declared
    (``statistic`` is ``None`` for a declared break)."""
    changes = [(e.time_s, e.radar_id, e.statistic) for e in result.events if e.kind == "step"]
    return changes + [(float(t), rid, None) for rid, times in breaks.items() for t in times]


def _span_around(windows: Mapping[int, Window], when: float, window_s: float
                 ) -> Window | None:
    """The window holding ``when``, or both windows around it when it is a boundary."""
    index = int(np.floor(when / window_s))
    if index * window_s < when:
        return windows.get(index)
    before, after = windows.get(index - 1), windows.get(index)
    if before is None or after is None:
        return before or after
    adsb = None
    if before.dataset.adsb is not None and after.dataset.adsb is not None:
        both = pd.concat([before.dataset.adsb, after.dataset.adsb])
        adsb = both[~both.index.duplicated()]
    plots = pd.concat([before.dataset.plots, after.dataset.plots])
    return Window(before.index, before.t_start_s, after.t_end_s,
                  replace(before.dataset, plots=plots, adsb=adsb))


def _snap(when: float, window_s: float) -> float:
    """A time within :data:`STEP_TIME_TOLERANCE_S` of a window boundary, on it."""
    boundary = round(when / window_s) * window_s
    return float(boundary) if abs(when - boundary) < STEP_TIME_TOLERANCE_S else when


def series_entry(window: WindowEstimate, terms: RadarTerms, eccentric: bool) -> dict[str, Any]:
    """One window of the contract's ``series``: values and sigmas in contract units."""
    entry: dict[str, Any] = {"t_start_s": window.t_start_s, "t_end_s": window.t_end_s,
                             "n_plots": int(window.n_plots)}
    names = [*PARAMETER_NAMES, "time_offset", *(ECCENTRICITY_NAMES if eccentric else ())]
    for name in names:
        key, factor = CONTRACT_KEYS[name]
        if name in terms.free:
            entry[key] = window.bias.value(name) * factor
        elif name != "time_offset":  # null where not estimated (2-D elevation, ...)
            entry[key] = None
    entry["sigma"] = dict(window.sigma)
    return entry


def _window_warnings(summaries: Sequence[WindowSummary], n_windows: int,
                     cleaning_warnings: Sequence[str]) -> list[str]:
    """The cleaning's warnings, then each window warning once with the windows it came
    from counted."""
    counted = Counter(w for s in summaries for w in s.warnings)
    return list(cleaning_warnings) + [
        f"{text} (in {count} of {n_windows} windows)" if n_windows > 1 else text
        for text, count in counted.items()]


def _constant_calibration(summaries: Sequence[WindowSummary], sites: Mapping[str, Site],
                          window_s: float, cleaning_warnings: Sequence[str]) -> Calibration:
    """Constant biases from the windows' summaries, as one batch's :class:`Calibration`."""
    from graphcal.solvers.windows import constant_biases

    combined = constant_biases(summaries, sites)
    radar_ids = [rid for rid in sites if any(r == rid for r, _ in combined.labels)]
    n = combined.n_windows
    warnings = _window_warnings(summaries, n, cleaning_warnings)
    info: dict[str, Any] = {
        "windows": {"window_s": window_s, "n_windows": n, "constant": True},
        "cross": "from windows",
    }
    return Calibration(
        method="graph", radar_ids=radar_ids,
        is_3d={rid: sites[rid].is_3d for rid in radar_ids},
        labels=list(combined.labels), estimate=combined.estimate,
        covariance=combined.covariance,
        n_plots={rid: combined.n_plots.get(rid, 0) for rid in radar_ids},
        observability=observability(combined.information), warnings=warnings, info=info,
        information=combined.information, atmosphere=combined.atmosphere)


def to_calibration(result: WindowedCalibration, sites: Mapping[str, Site],
                   cleaning_warnings: Sequence[str] = ()) -> Calibration:
    """The windowed result as a :class:`Calibration`: the last window, plus ``series``
    and ``events``; ``cleaning_warnings`` come first among its warnings."""
    radar_ids = list(result.series)
    labels = list(result.last_labels)
    prior = np.concatenate([
        prior_sigmas(sites[rid], RadarTerms(rid, (name,), {})) for rid, name in labels])
    information = np.linalg.inv(result.last_covariance)
    data_information = 0.5 * (information + information.T) - np.diag(prior ** -2.0)
    eccentric = any(name in ECCENTRICITY_NAMES for _, name in labels)
    series = {
        "window_s": result.window_s,
        "radars": {rid: [series_entry(w, result.terms[rid], eccentric)
                         for w in windows] for rid, windows in result.series.items()},
    }
    n = len({s.index for s in result.summaries})
    warnings = _window_warnings(result.summaries, n, cleaning_warnings)
    for event in result.events:
        sizes = ", ".join(f"{key} {event.size[key]:+.4g} ± {event.sigma[key]:.2g}"
                          for key in event.parameters)
        what = "declared change" if event.kind == "break" else "step"
        warnings.append(f"{event.radar_id}: {what} at {event.time_s:.0f} s: {sizes}")
    if result.largest_move > LARGEST_MOVE_WARNING_SIGMA:
        warnings.append(
            f"the smoothed chain moved a window's biases {result.largest_move:.0f} sigma from "
            "where its summary was linearised; shorter windows or --drift may fit better")
    last = {rid: windows[-1] for rid, windows in result.series.items()}
    last_summary = result.summaries[-1]
    info: dict[str, Any] = {
        "windows": {
            "window_s": result.window_s,
            "n_windows": n,
            "random_walk_per_sqrt_h": {
                rid: {CONTRACT_KEYS[name][0]: rate * 60.0 * CONTRACT_KEYS[name][1]
                      for name, rate in terms.items()}
                for rid, terms in result.rates.items()},
            "step_false_alarm_per_radar": result.step_false_alarm,
            "largest_move_sigma": result.largest_move,
        },
        "timing_s": dict(result.timing_s),
    }
    cal = Calibration(
        method="graph",
        radar_ids=radar_ids,
        is_3d={rid: sites[rid].is_3d for rid in radar_ids},
        labels=labels,
        estimate=np.asarray(result.last_estimate, dtype=float),
        covariance=np.asarray(result.last_covariance, dtype=float),
        n_plots={rid: int(w.n_plots) for rid, w in last.items()},
        observability=observability(data_information),
        warnings=warnings,
        info=info,
        information=data_information,
        atmosphere=last_summary.atmosphere,
        series=series,
        events=[event.to_dict() for event in result.events],
    )
    return cal


__all__ = ["LARGEST_MOVE_WARNING_SIGMA", "calibrate_windows",
           "parse_drift", "series_entry", "to_calibration"]
