"""A dataset folder read window by window, in memory bounded by a window, not by the recording.

:func:`iter_windows` yields the time windows of a dataset folder
(:class:`graphcal.data.windows.Window`: index, span, the window's plots and the ADS-B
reports up to a margin beyond it) that
``split_windows(load_dataset(folder), window_s)`` gives, the same rows in the same
order, but reads the tables chunk by chunk (:mod:`graphcal.io.table_files`: CSV in
chunks of rows, Parquet record batch by record batch, a folder of parts part by
part) and holds about one window of rows at a time.

Rows are validated exactly as :func:`~graphcal.io.folder.load_dataset` validates them
(:mod:`graphcal.io.table_checks`); an error names the file, the row's number in that
file and the field.  A file is only read as far as the windows asked for need, so
an error in a late row is raised when its window is reached, after the earlier
windows were yielded.

Time order
    Reading each file once needs its rows in time order, to within
    ``max_lateness_s`` (recordings merged from several radars are, to a few
    seconds).  ``order`` says what to do:

    * ``"auto"`` (default): a first pass reads the ``time_s`` column of every file
      (:func:`graphcal.io.dataset_span.scan_times`; cheap for Parquet, a fraction
      of a full read for CSV).  Files in order are then read once, side by side
      (parts may overlap in time, e.g. one part per radar); a table with a file
      out of order is sorted by window through a temporary folder
      (:class:`~graphcal.io.table_stream.SpilledTable`: bounded memory, one more
      write and read of the table).
    * ``"sorted"``: no first pass: each file is taken to be in time order, and a
      row out of order is a :class:`~graphcal.core.errors.DatasetError` naming the
      file and the row.  Files may still overlap in time: each is opened when the
      windows reach its start (a Parquet file's statistics, else its first row).
    * ``"any"``: always sort by window through the temporary folder.

Cleaning (``clean=True``)
    :func:`graphcal.data.cleaning.clean_dataset` runs on each window: its plots and
    its ADS-B reports, read :data:`CLEANING_CONTEXT_S` beyond the margin on each
    side so that the reports near the margin's ends are judged with their
    neighbours, then cut to the margin.  What looks at single rows or at a
    report's neighbours gives what cleaning the whole dataset gives: missing
    values, exact duplicates (same time, so in the same window), stale ADS-B
    reports (the previous report of the aircraft within the context), isolated
    wild reports.  What looks at the whole recording is done per window instead:

    * the kinematic gate drops a flight whose positions jump and stay off for the
      part of it in the window (the whole flight when cleaned whole); flights
      with fewer than 10 reports in the window and its context are not judged;
    * the identity check forms each radar's consensus from the window's aircraft
      (the whole recording's when cleaned whole), so it follows biases that
      change over time;
    * a stale report whose aircraft's previous report lies before the context
      (a gap of more than :data:`CLEANING_CONTEXT_S`) is not recognised;
    * coverage warnings are about the window.

    ``window.dataset.cleaning`` holds the window's report (its ADS-B counts
    include the context).  On a recording without such defects the windows are
    those of cleaning the whole dataset.

Plausibility (unless ``force=True``)
    The unit and frame heuristics of :mod:`graphcal.data.plausibility` run on the
    validated rows, before cleaning, of the first window and then of every
    :data:`PLAUSIBILITY_EVERY_WINDOWS`-th (a unit or frame mistake is a property of a
    file, not of an hour; checking every window cost a third of a 1M-plot
    calibration); an error is raised when its window is reached.  The time overlap
    of the ADS-B and plot tables is checked on their spans before the first window
    (the first pass of ``order="auto"`` measures them; otherwise Parquet statistics
    or the ``time_s`` column).

Other differences from ``split_windows(load_dataset(...))``: each window's tables
have their own fresh ``RangeIndex``; a window whose ADS-B reports are all dropped
keeps an empty ADS-B table (``load_dataset`` drops the table only when every report
of the recording goes); columns beyond the contract's keep the type each chunk reads
them with.  A site without any sigma is made 3-D from its plots' elevations
(:func:`~graphcal.io.folder.three_d_without_sigmas`) by a first pass over the
``radar_id`` and ``elevation_deg`` columns, only when such a site exists.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from graphcal.data.cleaning import clean_dataset
from graphcal.data.dataset import ADSB_COLUMNS, PLOT_COLUMNS, SITES_FILE, Dataset, Site
from graphcal.data.plausibility import check_tables, check_time_overlap, raise_if_implausible
from graphcal.data.windows import DEFAULT_ADSB_MARGIN_S, Window, window_index
from graphcal.io.dataset_span import (
    DEFAULT_MAX_LATENESS_S,
    DatasetSpan,
    TableSpan,
    first_time,
    scan_times,
    table_span,
)
from graphcal.io.folder import (
    check_folder,
    dataset_tables,
    load_dataset_settings,
    load_sites,
    needs_elevation_scan,
    table_paths,
    three_d_without_sigmas,
)
from graphcal.io.table_checks import ExtraCheck, validate_adsb, validate_plots
from graphcal.io.table_files import DEFAULT_CHUNK_ROWS, MISSING_TEXT, RawRows, read_rows
from graphcal.io.table_stream import (
    DEFAULT_SPILL_ROWS,
    OrderedTable,
    SpilledTable,
    TableSource,
    Validator,
    empty_table,
    rows_where,
)

#: The plausibility heuristics run on the first window and then on every this many
#: (module docstring).
PLAUSIBILITY_EVERY_WINDOWS = 8
#: ADS-B read beyond the margin on each side for cleaning [s] (module docstring).
CLEANING_CONTEXT_S = 60.0
#: Accepted values of ``order``.
ORDERS: tuple[str, ...] = ("auto", "sorted", "any")

Table = OrderedTable | SpilledTable


def _open_table(files: list[Path], required: tuple[str, ...], validate: Validator, *,
                order: str, window_s: float, max_lateness_s: float, chunk_rows: int,
                spill_dir: str | Path | None, spill_rows: int) -> tuple[Table, TableSpan | None]:
    """The table read in order when it can be, else sorted by window (module docstring),
    and its span when the first pass of ``order="auto"`` measured it."""
    empty = empty_table(files, required, validate)
    span = None
    if order == "sorted":
        sources = [TableSource([path], required, validate, chunk_rows, max_lateness_s,
                               first_time(path, required, max_lateness_s=max_lateness_s))
                   for path in files]
        return OrderedTable(sources, empty), None
    if order == "auto":
        span = scan_times(files, required, max_lateness_s=max_lateness_s,
                          chunk_rows=chunk_rows)
        if span.files_in_order:
            sources = [TableSource([f.path], required, validate, chunk_rows, max_lateness_s,
                                   -math.inf if math.isnan(f.t_min_s) else f.t_min_s)
                       for f in span.files]
            return OrderedTable(sources, empty), span
    source = TableSource(files, required, validate, chunk_rows, None)
    return SpilledTable(source, window_s, empty, spill_dir=spill_dir,
                        spill_rows=spill_rows), span


def _check_overlap(plots: TableSpan | None, adsb: TableSpan | None, plot_files: list[Path],
                   adsb_files: list[Path], paths: dict[str, Path]) -> None:
    """Plausibility: the ADS-B table overlaps the plots in time (spans measured if needed)."""
    plots = plots if plots is not None else table_span(plot_files, PLOT_COLUMNS)
    adsb = adsb if adsb is not None else table_span(adsb_files, ADSB_COLUMNS)
    finding = check_time_overlap((plots.t_min_s, plots.t_max_s), (adsb.t_min_s, adsb.t_max_s))
    raise_if_implausible([finding] if finding is not None else [], paths)


def check_span_overlap(span: DatasetSpan) -> None:
    """Raise :class:`~graphcal.data.plausibility.ImplausibleDataError` when a folder's
    ADS-B table does not overlap its plots in time (another time base), from the
    spans :func:`graphcal.io.dataset_span.dataset_span` measured."""
    if span.adsb is None:
        return
    plot_files = [f.path for f in span.plots.files]
    adsb_files = [f.path for f in span.adsb.files]
    _check_overlap(span.plots, span.adsb, plot_files, adsb_files,
                   table_paths(span.folder, plot_files, adsb_files))


def _elevation_complete(files: Sequence[Path], chunk_rows: int) -> dict[str, bool]:
    """Per radar with plots: whether all its plots carry an elevation (one pass, two columns)."""
    complete: dict[str, bool] = {}
    for path in files:
        for raw in read_rows(path, PLOT_COLUMNS, chunk_rows=chunk_rows,
                             usecols=["radar_id", "elevation_deg"]):
            radar = raw.frame["radar_id"].astype("string").fillna("").str.strip()
            values = raw.frame["elevation_deg"]
            if not pd.api.types.is_numeric_dtype(values):
                text = values.astype("string").str.strip()
                values = pd.to_numeric(text.mask(text.isin(MISSING_TEXT)), errors="coerce")
            finite = pd.Series(np.isfinite(values.to_numpy(dtype=float, na_value=np.nan)))
            for rid, ok in finite.groupby(radar.to_numpy()).all().items():
                complete[str(rid)] = complete.get(str(rid), True) and bool(ok)
    return complete


def _plots_validator(sites: Mapping[str, Site]) -> Validator:
    def validate(rows: RawRows, extra: ExtraCheck | None) -> pd.DataFrame:
        return validate_plots(rows, sites, extra=extra)
    return validate


def _adsb_validator(rows: RawRows, extra: ExtraCheck | None) -> pd.DataFrame:
    return validate_adsb(rows, extra=extra)


def _between(adsb: pd.DataFrame, t0_s: float, t1_s: float) -> pd.DataFrame:
    """Rows with ``t0_s <= time_s < t1_s``, fresh ``RangeIndex``."""
    times = adsb["time_s"].to_numpy(dtype=float)
    inside = (times >= t0_s) & (times < t1_s)
    return rows_where(adsb, times, inside)[0].reset_index(drop=True)


def _window_dataset(dataset: Dataset, adsb_lo_s: float, adsb_hi_s: float,
                    clean: bool) -> Dataset:
    """The window's dataset: cleaned with its ADS-B context, then ADS-B cut to the margin."""
    if not clean:
        adsb = None if dataset.adsb is None else _between(dataset.adsb, adsb_lo_s, adsb_hi_s)
        return replace(dataset, adsb=adsb)
    cleaned, _ = clean_dataset(dataset)
    adsb = cleaned.adsb
    if dataset.adsb is not None:
        adsb = _between(dataset.adsb.iloc[:0] if adsb is None else adsb, adsb_lo_s, adsb_hi_s)
    return replace(cleaned, adsb=adsb)


def iter_windows(
    folder: str | Path,
    window_s: float,
    *,
    adsb_margin_s: float = DEFAULT_ADSB_MARGIN_S,
    clean: bool = True,
    order: str = "auto",
    max_lateness_s: float = DEFAULT_MAX_LATENESS_S,
    chunk_rows: int = DEFAULT_CHUNK_ROWS,
    spill_dir: str | Path | None = None,
    spill_rows: int = DEFAULT_SPILL_ROWS,
    force: bool = False,
    time_overlap: bool = True,
) -> Iterator[Window]:
    """The time windows of a dataset folder, read window by window (module docstring).

    Parameters
    ----------
    folder : str or Path
        A dataset folder (``sites.toml``; ``plots.csv``, ``plots.parquet`` or a
        ``plots/`` folder of parts; the same for an optional ADS-B table).
    window_s : float
        Window length [s]; windows are aligned on its multiples
        (:mod:`graphcal.data.windows`).
    adsb_margin_s : float, optional
        ADS-B reports kept beyond each end of a window [s].
    clean : bool, optional
        Clean each window (module docstring: what differs from cleaning the
        whole dataset).
    order : {"auto", "sorted", "any"}, optional
        How the rows' time order is handled (module docstring).
    max_lateness_s : float, optional
        Tolerance of the time order [s]: a row may come this much earlier than a
        row above it in its file.  More tolerance holds more rows in memory.
    chunk_rows : int, optional
        Rows read at a time from a file.
    spill_dir : str or Path, optional
        Where a table out of order is sorted by window (a temporary folder,
        deleted when the iteration ends); default the system's temporary folder.
    spill_rows : int, optional
        Rows held in memory while sorting by window.
    force : bool, optional
        Skip the unit and frame heuristics (:mod:`graphcal.data.plausibility`),
        which otherwise run on each window's validated rows before cleaning, and
        on the whole tables' time spans (ADS-B on another time base) before the
        first window.

    time_overlap : bool, optional
        Check that the ADS-B overlaps the plots in time before the first window
        (unless ``force``).  It needs the tables' spans: the first pass of
        ``order="auto"`` measures them; otherwise they are measured for it (Parquet
        statistics, or a pass over a CSV table's times).  ``False`` leaves the check
        to the caller (:func:`check_span_overlap`).

    Yields
    ------
    Window
        In time order; windows without plots (after cleaning) are left out.
        ``window.dataset`` has the folder's sites (made 3-D as
        :func:`~graphcal.io.folder.load_dataset` makes them), ``path``,
        ``plot_altitude`` and ``epoch_utc``, and ``cleaning`` the window's cleaning report (``None``
        when not cleaned).

    Raises
    ------
    ValueError
        If ``window_s`` is not a positive duration, ``adsb_margin_s`` or
        ``max_lateness_s`` is negative, or ``order`` is unknown.
    DatasetError
        For the first bad row of a file (naming the file, its row and the field),
        a row out of time order with ``order="sorted"``, or a missing or
        unreadable file.
    ImplausibleDataError
        (a :class:`DatasetError`) Unless ``force``: the ADS-B table does not
        overlap the plots in time (before the first window), or a window's rows
        look like a unit or frame mistake (when that window is reached).
    """
    window_index(np.zeros(0), window_s)
    if not adsb_margin_s >= 0.0:
        raise ValueError(f"adsb_margin_s must be at least 0, got {adsb_margin_s}")
    if not max_lateness_s >= 0.0:
        raise ValueError(f"max_lateness_s must be at least 0, got {max_lateness_s}")
    if order not in ORDERS:
        raise ValueError(f"order must be one of {', '.join(ORDERS)}, got {order!r}")
    folder = Path(folder)
    check_folder(folder)
    file_sites = load_sites(folder / SITES_FILE)
    plot_files, adsb_files = dataset_tables(folder)
    settings = load_dataset_settings(folder / SITES_FILE)
    sites = file_sites
    if needs_elevation_scan(file_sites):
        sites = three_d_without_sigmas(file_sites, _elevation_complete(plot_files, chunk_rows),
                                       folder / SITES_FILE)
    options = {"order": order, "window_s": window_s, "max_lateness_s": max_lateness_s,
               "chunk_rows": chunk_rows, "spill_dir": spill_dir, "spill_rows": spill_rows}
    reach = adsb_margin_s + (CLEANING_CONTEXT_S if clean else 0.0)
    paths = table_paths(folder, plot_files, adsb_files)
    with ExitStack() as stack:
        plots, plots_span = _open_table(plot_files, PLOT_COLUMNS, _plots_validator(file_sites),
                                        **options)
        stack.callback(plots.close)
        adsb = None
        if adsb_files is not None:
            adsb, adsb_span = _open_table(adsb_files, ADSB_COLUMNS, _adsb_validator, **options)
            stack.callback(adsb.close)
            if not force and time_overlap:
                _check_overlap(plots_span, adsb_span, plot_files, adsb_files, paths)
        read = 0
        while (k := plots.next_window(window_s)) is not None:
            start, end = k * window_s, (k + 1) * window_s
            window_plots = plots.take(start, end)
            plots.forget_before(end)
            window_adsb = None if adsb is None else adsb.take(start - reach, end + reach)
            read += 1
            if not force and (read - 1) % PLAUSIBILITY_EVERY_WINDOWS == 0:
                raise_if_implausible(check_tables(sites, window_plots, window_adsb,
                                                  time_overlap=False), paths)
            dataset = Dataset(sites=sites, plots=window_plots, adsb=window_adsb, path=folder,
                              plot_altitude=settings.plot_altitude,
                              epoch_utc=settings.epoch_utc)
            dataset = _window_dataset(dataset, start - adsb_margin_s, end + adsb_margin_s,
                                      clean)
            if len(dataset.plots):
                yield Window(k, float(start), float(end), dataset)


__all__ = [
    "CLEANING_CONTEXT_S",
    "DEFAULT_MAX_LATENESS_S",
    "ORDERS",
    "PLAUSIBILITY_EVERY_WINDOWS",
    "check_span_overlap",
    "iter_windows",
]
