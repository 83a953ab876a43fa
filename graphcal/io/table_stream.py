"""A table read by time span, in bounded memory: the rows between two times, window after window.

Two ways to read a table (its files validated chunk by chunk,
:mod:`graphcal.io.table_checks`) so that the rows of a time span can be taken out
without holding the table:

* :class:`OrderedTable`, for files whose rows come in time order (to within a
  tolerance, ``max_lateness_s``): each file is read once, only as far as the span
  asked for needs, and rows are forgotten once they are behind.  Several files
  (parts) may overlap in time (one part per radar, say): they are read side by
  side, each opened when the span reaches its first time.  Memory: the span's rows,
  plus a chunk and the tolerance per open file.  A row that comes later than the
  tolerance allows is a :class:`~graphcal.core.errors.DatasetError` naming its file
  and row.
* :class:`SpilledTable`, for rows in any order: one pass reads every file and
  writes its rows, grouped by window, to a private temporary folder; each span then
  reads back the windows it covers.  Memory: a bounded buffer during the pass, then
  the span's rows; the cost is writing and reading the table once more.

Either gives the rows of a span in the order of the files (files in their order,
rows in file order), as :func:`graphcal.io.folder.load_dataset` then
:func:`graphcal.data.windows.split_windows` would, with a fresh ``RangeIndex``.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core.errors import RowsOutOfOrderError
from graphcal.data.windows import window_index
from graphcal.io.table_checks import ExtraCheck, FirstProblem
from graphcal.io.table_files import RawRows, read_rows, table_columns

#: ``validate(rows, extra)``: a table's validation (:mod:`graphcal.io.table_checks`).
Validator = Callable[[RawRows, ExtraCheck | None], pd.DataFrame]
#: Rows buffered by :class:`SpilledTable` before they are written out.
DEFAULT_SPILL_ROWS = 500_000
#: Column that keeps the file order of spilled rows.
_SEQUENCE = "__graphcal_row__"


def _times(frame: pd.DataFrame) -> NDArray[np.float64]:
    return frame["time_s"].to_numpy(dtype=float)


def rows_where(frame: pd.DataFrame, times: NDArray[np.float64], mask: NDArray[np.bool_]
               ) -> tuple[pd.DataFrame, NDArray[np.float64]]:
    """``frame.loc[mask]`` and ``times[mask]``: the same rows, as a slice (no copy) when
    they are one run, as the rows of a chunk in time order are on either side of a time.

    Parameters
    ----------
    frame : pandas.DataFrame
        A chunk of rows.
    times : ndarray of float, shape (n,)
        Its ``time_s`` [s].
    mask : ndarray of bool, shape (n,)
        The rows wanted.

    Returns
    -------
    frame : pandas.DataFrame
        The rows wanted, with their index labels.
    times : ndarray of float
        Their times [s].
    """
    hits = np.flatnonzero(mask)
    if hits.size and hits[-1] - hits[0] + 1 == hits.size:
        run = slice(int(hits[0]), int(hits[-1]) + 1)
        return frame.iloc[run], times[run]
    return frame.loc[mask], times[mask]


def empty_table(files: Sequence[Path], required: tuple[str, ...],
                validate: Validator) -> pd.DataFrame:
    """The table's columns without rows: what a span without rows holds."""
    path = files[0]
    columns = table_columns(path)
    raw = RawRows(path, pd.DataFrame({c: pd.Series([], dtype=object) for c in columns}),
                  np.zeros(0, dtype=np.int64))
    return validate(raw, None)


class TableSource:
    """One file, or several read one after the other, validated chunk by chunk.

    Parameters
    ----------
    files : sequence of Path
        The files, read in this order.
    required : tuple of str
        Their required columns.
    validate : callable
        ``validate(rows, extra)`` (:data:`Validator`).
    chunk_rows : int
        Rows read at a time.
    max_lateness_s : float or None
        With a number, a row more than this [s] earlier than a row above it (in
        these files) is an error (:class:`~graphcal.core.errors.RowsOutOfOrderError`);
        ``None`` checks no order.
    t_min_s : float, optional
        The earliest time in the files, when known (:func:`graphcal.io.dataset_span.scan_times`):
        the source is not read before a span reaches it.
    """

    def __init__(self, files: Sequence[Path], required: tuple[str, ...], validate: Validator,
                 chunk_rows: int, max_lateness_s: float | None,
                 t_min_s: float = -math.inf) -> None:
        self.files = list(files)
        self.t_min_s = t_min_s
        self.latest_s = -math.inf
        self.done = False
        self._required = required
        self._validate = validate
        self._chunk_rows = chunk_rows
        self._lateness = max_lateness_s
        self._chunks: Iterator[pd.DataFrame] | None = None

    def lower_bound_s(self) -> float:
        """No row still to be read is earlier than this [s] (``inf`` once read to the end)."""
        if self.done:
            return math.inf
        if self._chunks is None or self._lateness is None:
            return self.t_min_s
        return max(self.t_min_s, self.latest_s - self._lateness)

    def read_chunk(self) -> pd.DataFrame | None:
        """The next validated chunk (possibly without rows), ``None`` at the end."""
        if self._chunks is None:
            self._chunks = self._generate()
        frame = next(self._chunks, None)
        if frame is None:
            self.done = True
        return frame

    def _generate(self) -> Iterator[pd.DataFrame]:
        for path in self.files:
            for raw in read_rows(path, self._required, chunk_rows=self._chunk_rows):
                check = None if self._lateness is None else self._order_check
                frame = self._validate(raw, check)
                times = _times(frame)
                if times.size:
                    self.latest_s = max(self.latest_s, float(np.nanmax(times)))
                yield frame

    def _order_check(self, problems: FirstProblem, time_s: NDArray[np.float64]) -> None:
        """Flag rows more than the tolerance earlier than a row above them."""
        lateness = float(self._lateness or 0.0)
        before = np.fmax.accumulate(np.concatenate([[self.latest_s], time_s]))[:-1]
        with np.errstate(invalid="ignore"):
            late = before - time_s > lateness
        problems.flag(late, "time_s", lambda pos: (
            f"{time_s[pos]:g} s is {before[pos] - time_s[pos]:g} s earlier than a row read "
            f"before it ({before[pos]:g} s); read window by window in one pass, a table's "
            f"rows must be in time order to within {lateness:g} s: sort it by time_s, or let "
            "the reader sort it by window first (order \"auto\" or \"any\")"),
            kind=RowsOutOfOrderError)


class OrderedTable:
    """Rows of time-ordered sources, read as far as a span needs (module docstring).

    Parameters
    ----------
    sources : sequence of TableSource
        Each in time order (to within its tolerance); their order is the output
        order of rows of the same span.
    empty : pandas.DataFrame
        The table's columns without rows (:func:`empty_table`).
    """

    def __init__(self, sources: Sequence[TableSource], empty: pd.DataFrame) -> None:
        self._sources = list(sources)
        self._frames: list[tuple[int, int, pd.DataFrame, NDArray[np.float64]]] = []
        self._sequence = 0
        self._floor_s = -math.inf
        self._empty = empty

    def _read_next(self, before_s: float = math.inf) -> bool:
        """Read a chunk from the source that may hold the earliest rows below ``before_s``."""
        bounds = [source.lower_bound_s() for source in self._sources]
        i = int(np.argmin(bounds)) if bounds else 0
        if not bounds or not bounds[i] < before_s:
            return False
        frame = self._sources[i].read_chunk()
        if frame is not None and len(frame):
            times = _times(frame)
            keep = times >= self._floor_s
            if keep.any():
                if not keep.all():
                    frame, times = rows_where(frame, times, keep)
                self._frames.append((i, self._sequence, frame, times))
                self._sequence += 1
        return True

    def next_window(self, window_s: float) -> int | None:
        """Index of the earliest window with rows not yet forgotten, ``None`` when none is left.

        On return every row of that window has been read.
        """
        while True:
            if not self._frames:
                if not self._read_next():
                    return None
                continue
            earliest = min(float(times.min()) for _, _, _, times in self._frames)
            k = int(window_index(np.array([earliest]), window_s)[0])
            if not self._read_next((k + 1) * window_s):
                return k

    def take(self, t0_s: float, t1_s: float) -> pd.DataFrame:
        """Rows with ``t0_s <= time_s < t1_s``; rows earlier than ``t0_s`` are forgotten.

        Successive calls must not go back in time (``t0_s`` never decreases).
        """
        while self._read_next(t1_s):
            pass
        self.forget_before(t0_s)
        parts = []
        for _, _, frame, times in sorted(self._frames, key=lambda item: item[:2]):
            inside = times < t1_s
            if inside.all():
                parts.append(frame)
            elif inside.any():
                parts.append(rows_where(frame, times, inside)[0])
        if not parts:
            return self._empty.iloc[:0]
        return pd.concat(parts, ignore_index=True)

    def forget_before(self, t_s: float) -> None:
        """Drop the rows earlier than ``t_s``; later reads drop them as they come."""
        self._floor_s = max(self._floor_s, t_s)
        kept = []
        for source, sequence, frame, times in self._frames:
            keep = times >= self._floor_s
            if keep.all():
                kept.append((source, sequence, frame, times))
            elif keep.any():
                kept.append((source, sequence, *rows_where(frame, times, keep)))
        self._frames = kept

    def close(self) -> None:
        """Nothing to release (the files are closed as they are read to the end)."""
        self._frames = []


class SpilledTable:
    """Rows in any order, grouped by window in a temporary folder (module docstring).

    Parameters
    ----------
    source : TableSource
        All the table's files (read once, without an order check).
    window_s : float
        The windows the rows are grouped by [s].
    empty : pandas.DataFrame
        The table's columns without rows (:func:`empty_table`).
    spill_dir : str or Path, optional
        Where the temporary folder goes (default: the system's temporary folder).
    spill_rows : int, optional
        Rows buffered in memory before they are written out.
    """

    def __init__(self, source: TableSource, window_s: float, empty: pd.DataFrame, *,
                 spill_dir: str | Path | None = None,
                 spill_rows: int = DEFAULT_SPILL_ROWS) -> None:
        self.window_s = window_s
        self._empty = empty
        self._folder = Path(tempfile.mkdtemp(prefix="graphcal-windows-", dir=spill_dir))
        self._files: dict[int, list[Path]] = {}
        self._next = -math.inf
        try:
            self._spill(source, spill_rows)
        except BaseException:
            self.close()
            raise

    def _spill(self, source: TableSource, spill_rows: int) -> None:
        buffers: dict[int, list[pd.DataFrame]] = {}
        held = sequence = 0
        while (frame := source.read_chunk()) is not None:
            if not len(frame):
                continue
            frame = frame.assign(**{_SEQUENCE: np.arange(sequence, sequence + len(frame))})
            sequence += len(frame)
            index = window_index(_times(frame), self.window_s)
            order = np.argsort(index, kind="stable")
            cuts = np.flatnonzero(np.diff(index[order])) + 1
            for rows in np.split(order, cuts):
                buffers.setdefault(int(index[rows[0]]), []).append(frame.iloc[np.sort(rows)])
            held += len(frame)
            if held >= spill_rows:
                self._flush(buffers)
                held = 0
        self._flush(buffers)

    def _flush(self, buffers: dict[int, list[pd.DataFrame]]) -> None:
        for k, frames in buffers.items():
            files = self._files.setdefault(k, [])
            path = self._folder / f"{k:+013d}-{len(files):06d}.pkl"
            pd.concat(frames, ignore_index=True).to_pickle(path)
            files.append(path)
        buffers.clear()

    def next_window(self, window_s: float) -> int | None:
        """Index of the next window with rows (after the last one asked), ``None`` at the end."""
        if window_s != self.window_s:
            raise ValueError(f"the rows were grouped by {self.window_s} s windows, "
                             f"not {window_s} s")
        later = [k for k in self._files if k > self._next]
        if not later:
            return None
        self._next = min(later)
        return self._next

    def take(self, t0_s: float, t1_s: float) -> pd.DataFrame:
        """Rows with ``t0_s <= time_s < t1_s``, in file order."""
        first = math.floor(t0_s / self.window_s)
        last = math.ceil(t1_s / self.window_s) - 1
        parts = []
        for k in range(first, last + 1):
            for path in self._files.get(k, []):
                frame = pd.read_pickle(path)  # written above by this object
                times = _times(frame)
                inside = (times >= t0_s) & (times < t1_s)
                if inside.any():
                    parts.append(frame.loc[inside])
        if not parts:
            return self._empty.iloc[:0]
        rows = pd.concat(parts, ignore_index=True)
        if last > first:
            rows = rows.sort_values(_SEQUENCE, kind="stable", ignore_index=True)
        return rows.drop(columns=_SEQUENCE)

    def forget_before(self, t_s: float) -> None:
        """Delete the windows that end before ``t_s``."""
        for k in [k for k in self._files if (k + 1) * self.window_s <= t_s]:
            for path in self._files.pop(k):
                path.unlink(missing_ok=True)

    def close(self) -> None:
        """Delete the temporary folder."""
        shutil.rmtree(self._folder, ignore_errors=True)


__all__ = [
    "DEFAULT_SPILL_ROWS",
    "OrderedTable",
    "SpilledTable",
    "TableSource",
    "Validator",
    "empty_table",
    "rows_where",
]
