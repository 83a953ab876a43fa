"""A dataset folder's windows, read ahead: by a forked child for a large folder.

:func:`open_folder_windows` gives the windows of a folder as
:func:`graphcal.io.window_reader.iter_windows` reads them.  A folder whose tables
hold at least :data:`CHILD_READER_MIN_BYTES` is read and cleaned by a forked child
process (:func:`graphcal.pipeline.schedulers.read_in_child`) while this process
calibrates; a smaller one in this process.

:func:`start_reading` forks that child early: the command line calls it as soon as
its options say a folder will be read in windows, before it imports the solvers,
so the child scans the tables and reads the first window while this process
imports and prepares (on 1 M plots it saves about half a second of a seven-second
run).  The next :func:`open_folder_windows` of the same folder and options takes
that child's windows; a child never taken is stopped when the process ends.  This
module imports no solver, so starting costs the caller nothing.

A folder of CSV tables is read as if its rows were in time order
(``order="sorted"``), without the reader's first pass over their times.  The reader
checks the order as it reads; a row out of order means that the windows taken so far
may lack late rows: :class:`FolderReadAgain` tells the caller to drop them and read
the folder again with ``order="auto"`` (:func:`open_folder_windows`).  The caller
takes the span meanwhile, in a thread (:class:`SpanCheck`), for its progress and
for the time-overlap check (:func:`graphcal.io.window_reader.check_span_overlap`):
of such a folder from its files' first and last rows
(:func:`graphcal.io.dataset_span.end_times_span`), which the reader's check makes
the span.  A folder with Parquet tables is read with ``order="auto"``, whose first
pass is cheap there.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from graphcal.pipeline.schedulers import child_reading_available, read_in_child

if TYPE_CHECKING:
    from graphcal.io.dataset_span import DatasetSpan

#: Tables (plots and ADS-B files together) at least this large [bytes] are read by a
#: forked child (:func:`graphcal.pipeline.schedulers.read_in_child`), which reads
#: and cleans the next windows on a second core while this process calibrates;
#: smaller ones in this process.
CHILD_READER_MIN_BYTES = 32 * 1024 * 1024

#: Readers started by :func:`start_reading`, not yet taken.
_STARTED: dict[tuple[str, float, bool, bool, str], Iterator[Any]] = {}


def read_folder_windows(folder: Path, window_s: float, clean: bool, force: bool,
                        order: str = "auto") -> Iterator[Any]:
    """:func:`~graphcal.io.window_reader.iter_windows` of the folder (module-level, so a
    child process can run it), without the time-overlap check, which is the
    caller's (module docstring).  Read as if in time order (``order="sorted"``), a row
    out of order raises :class:`FolderReadAgain`."""
    from graphcal.core.errors import RowsOutOfOrderError
    from graphcal.io.window_reader import iter_windows

    try:
        yield from iter_windows(folder, window_s, clean=clean, force=force, order=order,
                                time_overlap=False)
    except RowsOutOfOrderError as exc:
        if order != "sorted":
            raise
        raise FolderReadAgain(f"{folder}: a table's rows are not in time order ({exc})"
                              ) from None


def reading_order(folder: Path) -> str:
    """``"sorted"`` for a folder whose tables are all CSV files, else ``"auto"``
    (module docstring)."""
    return _order_of(_table_files(folder))


def table_bytes(folder: Path) -> int:
    """Bytes of the folder's plots and ADS-B table files, on disk."""
    return _bytes_of(_table_files(folder))


def _table_files(folder: Path) -> list[Path]:
    """The folder's plots and ADS-B table files
    (:func:`graphcal.io.folder.dataset_tables`)."""
    from graphcal.io.folder import dataset_tables

    plot_files, adsb_files = dataset_tables(folder)
    return [*plot_files, *(adsb_files or [])]


def _order_of(files: list[Path]) -> str:
    return "sorted" if all(path.suffix == ".csv" for path in files) else "auto"


def _bytes_of(files: list[Path]) -> int:
    return sum(path.stat().st_size for path in files)


def _key(folder: Path, window_s: float, clean: bool, force: bool, order: str
         ) -> tuple[str, float, bool, bool, str]:
    return str(Path(folder).resolve()), float(window_s), bool(clean), bool(force), order


def reads_in_child(folder: Path) -> bool:
    """Whether the folder's windows are read by a forked child (its tables hold at least
    :data:`CHILD_READER_MIN_BYTES`, and forking is available here)."""
    try:
        return _reads_in_child(_table_files(folder))
    except (OSError, ValueError):
        return False


def _reads_in_child(files: list[Path]) -> bool:
    return _bytes_of(files) >= CHILD_READER_MIN_BYTES and child_reading_available()


def start_reading(folder: str | Path, window: str | float, *, clean: bool = True,
                  force: bool = False) -> bool:
    """Start reading a large folder's windows in a child process now (module docstring).

    A head start only: when anything is wrong (no such folder, a bad duration, a
    table missing) nothing is started and ``False`` is returned, so that the
    calibration itself reports the problem as it would have.

    Parameters
    ----------
    folder : str or Path
        The dataset folder.
    window : str or float
        The window length (``"1h"``, ``900``; :func:`graphcal.core.durations.parse_duration`).
    clean, force : bool
        As the calibration will read the folder
        (:func:`graphcal.io.window_reader.iter_windows`).

    Returns
    -------
    bool
        Whether a child was started (or had been, for the same folder and options).
    """
    from graphcal.core.durations import parse_duration
    from graphcal.core.errors import DatasetError

    try:
        window_s = parse_duration(window)
        folder = Path(folder)
        files = _table_files(folder)
        order = _order_of(files)
        key = _key(folder, window_s, clean, force, order)
        if key in _STARTED:
            return True
        if not _reads_in_child(files):
            return False
        # Imported before the fork, which the child would otherwise do on its own.
        import graphcal.io.window_reader  # noqa: F401
    except (DatasetError, OSError, ValueError):
        return False
    _STARTED[key] = read_in_child(read_folder_windows, (folder, window_s, clean, force, order))
    return True


def open_folder_windows(folder: Path, window_s: float, clean: bool, force: bool,
                        order: str | None = None) -> tuple[Iterator[Any], bool, str]:
    """The folder's windows, whether a child process reads them, and in which order.

    A reader started by :func:`start_reading` for the same folder and options is
    taken (once); else a child is started for a large folder, and a small one is
    read here, window by window as they are asked for.  ``order`` defaults to
    :func:`reading_order`.
    """
    files = _table_files(folder)
    order = _order_of(files) if order is None else order
    started = _STARTED.pop(_key(folder, window_s, clean, force, order), None)
    if started is not None:
        return started, True, order
    recipe = (folder, window_s, clean, force, order)
    if _reads_in_child(files):
        return read_in_child(read_folder_windows, recipe), True, order
    return iter(read_folder_windows(*recipe)), False, order


class FolderReadAgain(Exception):  # noqa: N818 - a signal to the caller, not an error
    """A folder read as if its rows were in time order is not in order: the windows taken
    may lack late rows; read it again from the start with ``order="auto"``."""


class SpanCheck:
    """A folder's span, measured in a thread while its windows are read and calibrated,
    and checked when asked (module docstring): :func:`~graphcal.io.dataset_span.dataset_span`,
    or :func:`~graphcal.io.dataset_span.end_times_span` when read in time order.

    Parameters
    ----------
    folder : Path
        The dataset folder.
    force : bool
        Leave out the time-overlap check (``--force``).
    order : str
        The order the windows are read in: ``"sorted"`` takes the files' time order
        for granted (the reader checks it; :meth:`result` confirms it too when the
        span was measured from every row).
    """

    def __init__(self, folder: Path, *, force: bool, order: str) -> None:
        self._folder = Path(folder)
        self._force = force
        self._order = order
        self._span: DatasetSpan | None = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._measure, name="graphcal-span",
                                        daemon=True)
        self._thread.start()

    def _measure(self) -> None:
        from graphcal.io.dataset_span import dataset_span, end_times_span

        try:
            # Read in time order, the reader checks the order: the ends give the span.
            quick = end_times_span(self._folder) if self._order == "sorted" else None
            self._span = (quick if quick is not None and self._overlaps(quick)
                          else dataset_span(self._folder))
        except BaseException as exc:  # noqa: BLE001 - raised by result(), in the caller
            self._error = exc

    def _overlaps(self, span: DatasetSpan) -> bool:
        """Whether ``span`` passes the time-overlap check (or it is not made): the ends
        of a file out of order may not, which its full span then decides."""
        from graphcal.core.errors import ImplausibleDataError
        from graphcal.io.window_reader import check_span_overlap

        if self._force:
            return True
        try:
            check_span_overlap(span)
        except ImplausibleDataError:
            return False
        return True

    @property
    def done(self) -> bool:
        """Whether the span is measured (:meth:`result` then does not wait)."""
        return not self._thread.is_alive()

    def result(self) -> DatasetSpan:
        """The span, once measured and checked.

        Raises
        ------
        DatasetError
            The measurement's own (a table missing, unreadable, without rows).
        ImplausibleDataError
            The plots and the ADS-B do not overlap in time (unless ``force``).
        FolderReadAgain
            The windows were read as if in time order and a file is not.
        """
        from graphcal.io.window_reader import check_span_overlap

        self._thread.join()
        if self._error is not None:
            raise self._error
        span = self._span
        assert span is not None
        if not self._force:
            check_span_overlap(span)
        in_order = span.plots.files_in_order and (span.adsb is None
                                                  or span.adsb.files_in_order)
        if self._order == "sorted" and not in_order:
            raise FolderReadAgain(f"{self._folder}: a table's rows are not in time order")
        return span


def stop_started() -> None:
    """Stop every reader started and not taken."""
    while _STARTED:
        _, reader = _STARTED.popitem()
        close = getattr(reader, "close", None)
        if close is not None:
            close()


__all__ = ["CHILD_READER_MIN_BYTES", "FolderReadAgain", "SpanCheck", "open_folder_windows",
           "read_folder_windows", "reading_order", "start_reading", "stop_started",
           "table_bytes"]
