"""Writing a table piece by piece into one CSV or Parquet file, renamed into place at the end.

:class:`TableWriter` takes a table in pieces (``write(frame)``, e.g. one per hour of
a simulation) and writes them as they come, so that a table of tens of millions of
rows is never held whole.  A Parquet file gets one or more row groups per piece (of
at most ``row_group_rows`` rows: each with its own statistics, which let a reader
find a time span without reading the rest); a CSV file gets the header once, then
the rows, formatted exactly as :func:`graphcal.core.atomic.write_table` formats a
whole table, so the pieces of a table give the same file as the table.

The file is written under a temporary name in the destination folder and renamed
into place (``os.replace``) by :meth:`TableWriter.close`; an error, or
:meth:`TableWriter.abort`, removes it, so a reader never sees a half-written table.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from types import TracebackType

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

#: Largest Parquet row group written [rows].
DEFAULT_ROW_GROUP_ROWS = 262_144


class TableWriter:
    """Write one table file in pieces, atomically (module docstring).

    Parameters
    ----------
    path : str or Path
        Destination file; ``.csv`` or ``.parquet`` gives the format.  Its folder
        must exist.
    row_group_rows : int, optional
        Largest Parquet row group [rows].

    Raises
    ------
    ValueError
        If the suffix is neither ``.csv`` nor ``.parquet``.

    Examples
    --------
    >>> with TableWriter(folder / "plots.parquet") as writer:   # doctest: +SKIP
    ...     for piece in pieces:
    ...         writer.write(piece)
    """

    def __init__(self, path: str | Path, *, row_group_rows: int = DEFAULT_ROW_GROUP_ROWS
                 ) -> None:
        self.path = Path(path)
        if self.path.suffix not in (".csv", ".parquet"):
            raise ValueError(f"{self.path}: the table format comes from the suffix: "
                             ".csv or .parquet")
        if row_group_rows < 1:
            raise ValueError(f"row_group_rows must be positive, got {row_group_rows}")
        self.row_group_rows = row_group_rows
        self.n_rows = 0
        handle, temporary = tempfile.mkstemp(prefix=f".{self.path.stem}.", suffix=".tmp",
                                             dir=self.path.parent)
        os.close(handle)
        self._temporary = Path(temporary)
        self._parquet: pq.ParquetWriter | None = None
        self._schema: pa.Schema | None = None
        self._columns: list[str] | None = None
        self._empty: pd.DataFrame | None = None
        self._started = False
        self._open = True

    @property
    def columns(self) -> list[str] | None:
        """The table's columns, set by the first piece (``None`` before)."""
        return None if self._columns is None else list(self._columns)

    def write(self, frame: pd.DataFrame) -> None:
        """Append the rows of ``frame`` (its index is not written).

        The first piece sets the columns (and, for Parquet, their types); every
        later piece must have the same columns, in the same order.

        Raises
        ------
        ValueError
            If the writer is closed or the columns differ from the first piece's.
        """
        if not self._open:
            raise ValueError(f"{self.path}: the table writer is closed")
        columns = [str(c) for c in frame.columns]
        if self._columns is None:
            self._columns = columns
            self._empty = frame.iloc[:0]
        elif columns != self._columns:
            raise ValueError(f"{self.path}: a piece has columns {columns}, the table "
                             f"{self._columns}")
        if self.path.suffix == ".csv":
            frame.to_csv(self._temporary, index=False, na_rep="", mode="a",
                         header=not self._started)
            self._started = True
        elif len(frame):
            self._write_parquet(frame)
        self.n_rows += len(frame)

    def _write_parquet(self, frame: pd.DataFrame) -> None:
        """Row groups of at most ``row_group_rows`` rows; the first rows fix the types."""
        if self._parquet is None:
            table = pa.Table.from_pandas(frame, preserve_index=False)
            self._schema = table.schema
            self._parquet = pq.ParquetWriter(self._temporary, self._schema)
        else:
            table = pa.Table.from_pandas(frame, schema=self._schema, preserve_index=False)
        self._parquet.write_table(table, row_group_size=self.row_group_rows)

    def close(self) -> Path:
        """Finish the file and rename it into place; returns :attr:`path`.

        A table that received no piece at all is not written (there are no
        columns to write); :meth:`close` then only removes the temporary file.
        """
        if not self._open:
            return self.path
        self._open = False
        try:
            if self._parquet is not None:
                self._parquet.close()
            elif self._empty is not None and self.path.suffix == ".parquet":
                self._empty.to_parquet(self._temporary, index=False)
            if self._columns is None:
                self._temporary.unlink(missing_ok=True)
                return self.path
            with open(self._temporary, "rb+") as stream:
                os.fsync(stream.fileno())
            os.chmod(self._temporary, 0o644)
            os.replace(self._temporary, self.path)
        except BaseException:
            self._temporary.unlink(missing_ok=True)
            raise
        return self.path

    def abort(self) -> None:
        """Drop what was written; the destination is left as it was."""
        self._open = False
        if self._parquet is not None:
            with contextlib.suppress(Exception):
                self._parquet.close()
        self._temporary.unlink(missing_ok=True)

    def __enter__(self) -> TableWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()


__all__ = ["DEFAULT_ROW_GROUP_ROWS", "TableWriter"]
