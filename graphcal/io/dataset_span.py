"""What a dataset's tables span in time, cheaply: Parquet statistics, else the ``time_s`` column.

:func:`dataset_span` answers "from when to when, how many rows, which radars"
without reading a recording: for a Parquet file its footer holds the row count and
each row group's smallest and largest ``time_s``; only a CSV file (or a Parquet file
written without statistics) has its ``time_s`` column read, in chunks.

:func:`scan_times` reads the ``time_s`` column of every file of a table and also
says whether its rows come in time order (within a tolerance): what the
window-by-window reader (:mod:`graphcal.io.window_reader`) needs to choose between
reading the files once in order and sorting their rows by window first;
:func:`first_time` says when a file in time order starts, from its statistics or its
first rows.  :func:`end_times_span` reads only the first and last rows of CSV files:
the span of tables whose reader checks their time order itself.

Times that are missing or not numbers are left out here (the validation of the
full rows reports them); spans and counts are of data rows (blank CSV lines are
not rows).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from numpy.typing import NDArray

from graphcal.core.errors import DatasetError
from graphcal.data.dataset import ADSB_COLUMNS, PLOT_COLUMNS, SITES_FILE
from graphcal.io.folder import check_folder, dataset_tables, load_sites
from graphcal.io.table_files import (
    DEFAULT_CHUNK_ROWS,
    MISSING_TEXT,
    parquet_columns,
    parquet_file,
    read_rows,
    require_columns,
)

#: A row may come this much [s] earlier than a row above it and still count as in order.
DEFAULT_MAX_LATENESS_S = 60.0


@dataclass(frozen=True)
class FileTimes:
    """The times of one table file.

    Attributes
    ----------
    path : Path
        The file.
    n_rows : int or None
        Its data rows; ``None`` when not counted (:func:`end_times_span`).
    t_min_s, t_max_s : float
        Smallest and largest ``time_s`` [s]; NaN when no row has a time.
    late_row : int or None
        The first row (numbered as in :class:`~graphcal.io.table_files.RawRows`)
        whose time is more than the tolerance earlier than a row above it;
        ``None`` when the rows are in time order, or when the order was not
        looked at (:func:`dataset_span` on Parquet statistics).
    late_by_s : float
        How much earlier [s] (NaN when ``late_row`` is ``None``).
    """

    path: Path
    n_rows: int | None
    t_min_s: float
    t_max_s: float
    late_row: int | None = None
    late_by_s: float = math.nan


@dataclass(frozen=True)
class TableSpan:
    """The times of a table: its files (one, or its parts in name order)."""

    files: tuple[FileTimes, ...]

    @property
    def n_rows(self) -> int | None:
        """Data rows in all files (``None`` when not counted)."""
        counts = [f.n_rows for f in self.files]
        return None if any(n is None for n in counts) else sum(n for n in counts if n)

    @property
    def t_min_s(self) -> float:
        """Earliest time [s] (NaN when none)."""
        values = [f.t_min_s for f in self.files if not math.isnan(f.t_min_s)]
        return min(values) if values else math.nan

    @property
    def t_max_s(self) -> float:
        """Latest time [s] (NaN when none)."""
        values = [f.t_max_s for f in self.files if not math.isnan(f.t_max_s)]
        return max(values) if values else math.nan

    @property
    def files_in_order(self) -> bool:
        """Whether every file's rows are in time order (within the tolerance scanned with)."""
        return all(f.late_row is None for f in self.files)


@dataclass(frozen=True)
class DatasetSpan:
    """What a dataset folder spans (:func:`dataset_span`).

    Attributes
    ----------
    folder : Path
        The dataset folder.
    radar_ids : tuple of str
        The radars of ``sites.toml``, in file order.
    plots : TableSpan
        The plots table.
    adsb : TableSpan or None
        The ADS-B table, ``None`` when the folder has none.
    """

    folder: Path
    radar_ids: tuple[str, ...]
    plots: TableSpan
    adsb: TableSpan | None

    @property
    def t_start_s(self) -> float:
        """Time of the first plot [s]."""
        return self.plots.t_min_s

    @property
    def t_end_s(self) -> float:
        """Time of the last plot [s]."""
        return self.plots.t_max_s

    @property
    def n_plots(self) -> int | None:
        """Plots in the dataset (before validation and cleaning; ``None`` when not
        counted)."""
        return self.plots.n_rows

    @property
    def n_adsb(self) -> int | None:
        """ADS-B reports (0 without an ADS-B table; ``None`` when not counted)."""
        return 0 if self.adsb is None else self.adsb.n_rows

    def window_indices(self, window_s: float) -> range:
        """Indices of the aligned windows (:mod:`graphcal.data.windows`) the plots reach.

        Some of them may hold no plot (and are then not yielded by the reader).
        """
        if math.isnan(self.t_start_s):
            return range(0)
        first = math.floor(self.t_start_s / window_s)
        return range(first, math.floor(self.t_end_s / window_s) + 1)


def _parse_times(values: pd.Series) -> NDArray[np.float64]:
    """``time_s`` cells as floats, NaN where missing or not a number."""
    if pd.api.types.is_bool_dtype(values):
        return np.full(len(values), np.nan)
    if pd.api.types.is_numeric_dtype(values):
        return values.to_numpy(dtype=float, na_value=np.nan)
    text = values.astype("string").str.strip()
    text = text.mask(text.isin(MISSING_TEXT))
    return pd.to_numeric(text, errors="coerce").to_numpy(dtype=float, na_value=np.nan)


def first_time(path: Path, required: tuple[str, ...], *, max_lateness_s: float,
               chunk_rows: int = 1000) -> float:
    """No row of a file in time order (to within ``max_lateness_s``) is earlier than this [s].

    From a Parquet file's statistics when it has them (its smallest time), else its
    first time less the tolerance; ``-inf`` when the first rows have no time.
    """
    if path.suffix == ".parquet":
        found = parquet_times(path, required)
        if found is not None:
            return -math.inf if math.isnan(found.t_min_s) else found.t_min_s
    for raw in read_rows(path, required, chunk_rows=chunk_rows, usecols=["time_s"]):
        t = _parse_times(raw.frame["time_s"])
        finite = t[np.isfinite(t)]
        return float(finite[0]) - max_lateness_s if finite.size else -math.inf
    return -math.inf


def csv_end_times(path: Path) -> tuple[float, float] | None:
    """The ``time_s`` of a CSV file's first and last data rows [s], read from its two ends
    (the header, the first line, the last 64 KiB); ``None`` when they cannot be told
    (not CSV, no such column, blank or bad values).  Whatever the rows' order, the
    file spans at least their difference: a cheap lower bound of its span."""
    import csv

    if path.suffix != ".csv":
        return None
    try:
        with path.open("rb") as handle:
            head = [handle.readline() for _ in range(2)]
            size = handle.seek(0, 2)
            handle.seek(max(size - 65536, 0))
            tail = handle.read().splitlines()
    except OSError:
        return None
    lines = [line.decode("utf-8-sig", errors="replace") for line in head]
    last = next((line for line in reversed(tail) if line.strip()), b"")
    try:
        header, first = next(csv.reader([lines[0]])), next(csv.reader([lines[1]]))
        final = next(csv.reader([last.decode("utf-8", errors="replace")]))
        column = [name.strip() for name in header].index("time_s")
        times = float(first[column]), float(final[column])
    except (StopIteration, ValueError, IndexError):
        return None
    return times if all(math.isfinite(t) for t in times) else None


def scan_times(files: Iterable[Path], required: tuple[str, ...], *, max_lateness_s: float,
               chunk_rows: int = DEFAULT_CHUNK_ROWS) -> TableSpan:
    """Read the ``time_s`` column of a table's files: span, count and time order.

    A file's scan is remembered (:data:`SCAN_CACHE_FILES` files, keyed by path,
    inode, size, change times and the options), so a table scanned again in one run (for
    its span, for the first window, then for all of them) is read once.

    Parameters
    ----------
    files : iterable of Path
        The table's files (:func:`graphcal.io.table_files.find_table_files`).
    required : tuple of str
        The table's required columns (each file's header is checked).
    max_lateness_s : float
        A row may come up to this much [s] earlier than a row above it and still
        count as in order.
    chunk_rows : int, optional
        Rows read at a time.

    Returns
    -------
    TableSpan

    Raises
    ------
    DatasetError
        If a file cannot be read or lacks a required column.
    """
    spans = []
    for path in files:
        try:
            stat = Path(path).stat()
        except OSError as exc:
            raise DatasetError(f"cannot read: {exc.strerror}", path=path) from None
        key = (str(path), stat.st_ino, stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns,
               tuple(required), max_lateness_s, chunk_rows)
        found = _SCANS.get(key)
        if found is None:
            found = _scan_file(Path(path), required, max_lateness_s, chunk_rows)
            _SCANS[key] = found
            while len(_SCANS) > SCAN_CACHE_FILES:
                _SCANS.pop(next(iter(_SCANS)))
        spans.append(found)
    return TableSpan(tuple(spans))


#: Files whose scan :func:`scan_times` remembers.
SCAN_CACHE_FILES = 256
_SCANS: dict[tuple, FileTimes] = {}


def _scan_file(path: Path, required: tuple[str, ...], max_lateness_s: float,
               chunk_rows: int) -> FileTimes:
    """One file's :class:`FileTimes`, from its ``time_s`` column read in chunks."""
    chunks = ((raw.rows, _parse_times(raw.frame["time_s"]))
              for raw in read_rows(path, required, chunk_rows=chunk_rows, usecols=["time_s"]))
    return _times_of(path, chunks, max_lateness_s)


def _times_of(path: Path, chunks: Iterable[tuple[NDArray[np.int64], NDArray[np.float64]]],
              max_lateness_s: float) -> FileTimes:
    """Count, span and first late row of ``(rows, times)`` blocks in file order."""
    n_rows, t_min, t_max, latest = 0, math.inf, -math.inf, -math.inf
    late_row, late_by = None, math.nan
    for rows, t in chunks:
        n_rows += len(t)
        if not np.isfinite(t).any():
            continue
        t_min = min(t_min, float(np.nanmin(t)))
        t_max = max(t_max, float(np.nanmax(t)))
        before = np.fmax.accumulate(np.concatenate([[latest], t]))[:-1]
        with np.errstate(invalid="ignore"):
            late = np.flatnonzero(before - t > max_lateness_s)
        if late_row is None and late.size:
            late_row, late_by = int(rows[late[0]]), float(before[late[0]] - t[late[0]])
        latest = float(np.fmax(before[-1], t[-1]))
    if t_min > t_max:
        t_min = t_max = math.nan
    return FileTimes(path, n_rows, t_min, t_max, late_row, late_by)


def parquet_times(path: Path, required: tuple[str, ...]) -> FileTimes | None:
    """A Parquet file's row count and time span from its footer, ``None`` without statistics.

    Raises
    ------
    DatasetError
        If the file cannot be read or lacks a required column.
    """
    handle: pq.ParquetFile = parquet_file(path)
    require_columns(path, parquet_columns(handle), required)
    metadata = handle.metadata
    column = handle.schema_arrow.get_field_index("time_s")
    t_min, t_max = math.inf, -math.inf
    for group in range(metadata.num_row_groups):
        chunk = metadata.row_group(group)
        if chunk.num_rows == 0:
            continue
        statistics = chunk.column(column).statistics
        if statistics is None or not statistics.has_min_max:
            return None
        if not isinstance(statistics.min, int | float):
            return None
        t_min, t_max = min(t_min, float(statistics.min)), max(t_max, float(statistics.max))
    if t_min > t_max:
        t_min = t_max = math.nan
    return FileTimes(path, metadata.num_rows, t_min, t_max)


def table_span(files: list[Path], required: tuple[str, ...]) -> TableSpan:
    """A table's times: statistics where a Parquet file has them, else its ``time_s`` column."""
    spans = []
    for path in files:
        found = parquet_times(path, required) if path.suffix == ".parquet" else None
        if found is None:
            # The window reader's tolerance: its scan of the same file is then reused.
            found = scan_times([path], required,
                               max_lateness_s=DEFAULT_MAX_LATENESS_S).files[0]
        spans.append(found)
    return TableSpan(tuple(spans))


def dataset_span(folder: str | Path) -> DatasetSpan:
    """The time span, radars and row counts of a dataset folder, without reading it whole.

    Parameters
    ----------
    folder : str or Path
        A dataset folder (any table layout :func:`graphcal.io.folder.load_dataset`
        reads).

    Returns
    -------
    DatasetSpan
        ``t_start_s``, ``t_end_s`` (first and last plot [s]), ``n_plots``, ``n_adsb``,
        ``radar_ids`` and per table its files' spans.  Counts and times are of the
        rows as stored, before validation and cleaning; the time order of the
        rows is not looked at (:func:`scan_times` does).

    Raises
    ------
    DatasetError
        If the folder, ``sites.toml`` or a table file is missing or unreadable, or
        a table lacks a required column.
    """
    folder = Path(folder)
    check_folder(folder)
    sites = load_sites(folder / SITES_FILE)
    plot_files, adsb_files = dataset_tables(folder)
    key = _files_key(folder, [folder / SITES_FILE, *plot_files, *(adsb_files or [])])
    with _SPANS_LOCK:
        known = _SPANS.get(key)
    if known is not None:
        return known
    plots = table_span(plot_files, PLOT_COLUMNS)
    if plots.n_rows == 0:
        raise DatasetError("the table has no data rows",
                           path=plot_files[0] if len(plot_files) == 1 else folder / "plots")
    adsb = None if adsb_files is None else table_span(adsb_files, ADSB_COLUMNS)
    span = DatasetSpan(folder, tuple(sites), plots, adsb)
    with _SPANS_LOCK:
        if len(_SPANS) >= 8:
            _SPANS.clear()
        _SPANS[key] = span
    return span


def end_times_span(folder: str | Path) -> DatasetSpan | None:
    """A folder's span from its CSV files' first and last rows (:func:`csv_end_times`),
    without reading them.

    For a reader that takes the rows' time order for granted and checks it as it reads
    (:class:`~graphcal.io.table_stream.TableSource` raises
    :class:`~graphcal.core.errors.RowsOutOfOrderError`): in time order to within that
    tolerance, a file spans its first to its last row, give or take the tolerance.  The
    rows are not counted (``n_rows`` is ``None``) and their order not looked at
    (``late_row`` is ``None``).  ``None`` when a table file is not CSV or a file's ends
    cannot be read (:func:`dataset_span` then measures the folder).

    Raises
    ------
    DatasetError
        If the folder or ``sites.toml`` is missing or unreadable.
    """
    folder = Path(folder)
    check_folder(folder)
    sites = load_sites(folder / SITES_FILE)
    plot_files, adsb_files = dataset_tables(folder)
    tables = []
    for files in (plot_files, adsb_files):
        if files is None:
            tables.append(None)
            continue
        spans = []
        for path in files:
            ends = csv_end_times(path)
            if ends is None:
                return None
            spans.append(FileTimes(path, None, min(ends), max(ends)))
        tables.append(TableSpan(tuple(spans)))
    plots, adsb = tables
    assert plots is not None
    return DatasetSpan(folder, tuple(sites), plots, adsb)


#: Spans measured in this process, by folder and its files' sizes and modification
#: times: a run asks several times (is it long? the windows' progress and checks), and a
#: CSV table's span costs a read of its time column.
_SPANS: dict[tuple, DatasetSpan] = {}
_SPANS_LOCK = threading.Lock()


def _files_key(folder: Path, files: list[Path]) -> tuple:
    stats = []
    for path in files:
        stat = path.stat()
        stats.append((str(path), stat.st_size, stat.st_mtime_ns))
    return (str(folder.resolve()), tuple(stats))


__all__ = [
    "DatasetSpan",
    "FileTimes",
    "TableSpan",
    "csv_end_times",
    "dataset_span",
    "end_times_span",
    "first_time",
    "parquet_times",
    "scan_times",
    "table_span",
]
