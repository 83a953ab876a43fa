"""The files of a dataset table, read whole or in chunks, each row with its number in its file.

A table (``plots`` or ``adsb``) of a dataset folder is one file, ``NAME.csv`` or
``NAME.parquet``, or (graphcal's extension of the contract) a folder ``NAME/`` of
*parts*: files ``*.csv`` or ``*.parquet``, all of one format, taken in the order of
their names; names starting with ``.`` or ``_`` are ignored (``_SUCCESS``, ``.crc``
and the like left by other writers).  The parts together are the table: each part
has a header (CSV) or a schema (Parquet) with the required columns; a part may be
empty, but not all of them.

Every chunk read comes as :class:`RawRows`: the cells as read, not yet validated
(:mod:`graphcal.io.table_checks` does that), and the number of each row *in its
file*: the N-th data row as a user counts it.  In a CSV file the header is line 1
and row N is line N + 1; blank lines are dropped but keep this numbering.  In a
Parquet file row N is the N-th row.  So an error found in the millionth row of a
file read in chunks names row 1000000, not a row of the chunk.

CSV files are read with pyarrow's parser when they can be (:func:`_iter_csv_arrow`: a
file whose columns are all contract columns, without malformed lines), else with
pandas' parser, which names a malformed line and infers the types of other
columns.  Either way a file read in chunks comes in chunks of
exactly ``chunk_rows`` rows (the last one shorter), with the same options as a whole
file (numbers parse to the same floats either way).  When pyarrow stops at a line
it cannot parse, pandas takes over from the chunk it stopped in, so the chunks are
those of a pandas read.
Parquet files are read record batch by record batch, without reading a whole row
group at once (``pre_buffer`` off), so even a file written as one huge row group is
read in bounded memory.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
from numpy.typing import NDArray

from graphcal.core.errors import DatasetError, os_error_cause
from graphcal.data.dataset import (
    ADSB_COLUMNS,
    ADSB_OPTIONAL_COLUMNS,
    PLOT_COLUMNS,
    PLOT_OPTIONAL_COLUMNS,
    TABLE_FORMATS,
)

#: Text read as "no value" in a numeric column (compared after removing blanks).
MISSING_TEXT: tuple[str, ...] = ("", "nan", "NaN", "NAN", "NA", "N/A", "n/a", "null", "NULL",
                                 "None", "none")
#: Columns read as text; every other contract column is numeric.  ``mode_3a`` (contract
#: v3) is text so that a code keeps its leading zeros ("0413").
TEXT_COLUMNS: tuple[str, ...] = ("radar_id", "target_id", "mode_3a")
#: Rows per chunk when a table is read in chunks.
DEFAULT_CHUNK_ROWS = 100_000
#: Read buffer of a Parquet file read in chunks [bytes].
PARQUET_BUFFER_BYTES = 1 << 20
#: Columns whose types pyarrow's CSV parser is told (text or float): a CSV file with
#: any other column is read by pandas, which infers the types of extra columns.
CONTRACT_COLUMNS: frozenset[str] = frozenset(
    PLOT_COLUMNS + PLOT_OPTIONAL_COLUMNS + ADSB_COLUMNS + ADSB_OPTIONAL_COLUMNS)
#: Bytes pyarrow's CSV parser reads at a time when a file is read in chunks.  Its
#: streaming reader holds some tens of blocks ahead: with 4 MiB blocks it held 150 MiB
#: per file, with 512 KiB 28 MiB, at the same speed.
ARROW_BLOCK_BYTES = 1 << 19


@dataclass
class RawRows:
    """Rows of one table file as read, before validation.

    Attributes
    ----------
    path : Path
        The file.
    frame : pandas.DataFrame
        The rows (blank CSV lines removed), with a fresh ``RangeIndex``.
    rows : ndarray of int
        The 1-based number of each frame row in the file, as reported to users.
    """

    path: Path
    frame: pd.DataFrame
    rows: NDArray[np.int64]

    def error(self, message: str, *, pos: int | None = None, column: str | None = None,
              kind: type[DatasetError] = DatasetError) -> DatasetError:
        """A :class:`DatasetError` (or its subclass ``kind``) for frame row ``pos``
        (0-based) and ``column``.

        A CSV file's line number is added to the message, after the row number.
        """
        row = None if pos is None else int(self.rows[pos])
        if row is not None and self.path.suffix == ".csv":
            message = f"{message} (line {row + 1})"
        return kind(message, path=self.path, row=row, field=column)


# --------------------------------------------------------------------------- locating


def find_table_files(folder: Path, stem: str) -> list[Path] | None:
    """The files of table ``stem`` in a dataset folder, ``None`` when it has none.

    Parameters
    ----------
    folder : Path
        The dataset folder.
    stem : str
        ``"plots"`` or ``"adsb"``.

    Returns
    -------
    list of Path or None
        ``[folder/stem.csv]``, ``[folder/stem.parquet]``, or the parts of the folder
        ``folder/stem/`` in name order (module docstring).

    Raises
    ------
    DatasetError
        If more than one of ``stem.csv``, ``stem.parquet`` and ``stem/`` exist, or
        the parts folder holds no part, parts of both formats, or a sub-folder.
    """
    candidates = [folder / f"{stem}.{fmt}" for fmt in TABLE_FORMATS]
    for path in candidates:
        if path.is_dir():
            raise DatasetError("is a folder, not a table file", path=path)
    found = [path for path in candidates if path.is_file()]
    parts_folder = folder / stem
    if parts_folder.is_dir():
        found.append(parts_folder)
    if len(found) > 1:
        names = " and ".join(path.name + ("/" if path.is_dir() else "") for path in found)
        raise DatasetError(f"both {names} exist; keep only one", path=folder, field=stem)
    if not found:
        return None
    if not found[0].is_dir():
        return found
    return _parts(found[0])


def _parts(folder: Path) -> list[Path]:
    """The part files of a table folder, in name order."""
    entries = sorted(p for p in folder.iterdir() if not p.name.startswith((".", "_")))
    for entry in entries:
        if entry.is_dir():
            raise DatasetError("a parts folder holds files only, not folders", path=entry)
    formats = {entry.suffix for entry in entries}
    unknown = formats - {f".{fmt}" for fmt in TABLE_FORMATS}
    if unknown:
        name = next(e.name for e in entries if e.suffix in unknown)
        raise DatasetError(f"{name}: a part must be a .csv or .parquet file", path=folder)
    if len(formats) > 1:
        raise DatasetError("parts of both formats (.csv and .parquet); keep one format",
                           path=folder)
    if not entries:
        raise DatasetError("the parts folder holds no .csv or .parquet part", path=folder)
    return entries


def require_columns(path: Path, columns: list[str], required: tuple[str, ...]) -> None:
    """Raise a :class:`DatasetError` naming the first required column not in ``columns``."""
    for column in required:
        if column not in columns:
            found = ", ".join(map(str, columns)) or "none"
            raise DatasetError(f"missing required column (columns found: {found})",
                               path=path, field=column)


# --------------------------------------------------------------------------- CSV


@contextmanager
def _csv_errors(path: Path) -> Iterator[None]:
    """pandas' CSV errors as a DatasetError naming the file."""
    try:
        yield
    except pd.errors.EmptyDataError:
        raise DatasetError("the file is empty (no header line)", path=path) from None
    except pd.errors.ParserError as exc:
        raise csv_parser_error(path, exc) from None
    except UnicodeDecodeError:
        raise not_utf8_error(path) from None
    except OSError as exc:
        raise DatasetError(os_error_cause(exc), path=path) from None
    except ValueError as exc:
        raise DatasetError(f"cannot read CSV: {exc}", path=path) from None


def not_utf8_error(path: Path) -> DatasetError:
    """A :class:`DatasetError` naming the first line and field of a CSV file that is not
    UTF-8 text: ``row 4, field 'range_m': not UTF-8 text (byte 0xff, line 5)``."""
    header: list[str] | None = None
    try:
        with path.open("rb") as stream:
            for number, raw in enumerate(stream, start=1):
                line = raw[3:] if number == 1 and raw.startswith(b"\xef\xbb\xbf") else raw
                try:
                    text = line.decode("utf-8")
                except UnicodeDecodeError as exc:
                    byte = line[exc.start]
                    what = f"not UTF-8 text (byte 0x{byte:02x}, line {number}); save the " \
                           "file as UTF-8"
                    if header is None:
                        return DatasetError(f"the header line is {what}", path=path)
                    column = line[:exc.start].count(b",")
                    field = header[column] if column < len(header) else None
                    return DatasetError(what, path=path, row=number - 1, field=field)
                if header is None:
                    header = [name.strip().strip('"') for name in text.rstrip("\r\n")
                              .split(",")]
    except OSError as exc:
        return DatasetError(os_error_cause(exc), path=path)
    return DatasetError("not UTF-8 text; save the file as UTF-8", path=path)


def csv_header(path: Path) -> list[str]:
    """The column names of a CSV table file.

    Raises
    ------
    DatasetError
        If the file is empty (no header line) or cannot be read.
    """
    with _csv_errors(path):
        return [str(c) for c in pd.read_csv(path, nrows=0, encoding="utf-8-sig").columns]


def _csv_options(header: list[str], usecols: list[str] | None = None) -> dict:
    """``pandas.read_csv`` options: text columns as text, empty cells of the others NaN."""
    return {
        "encoding": "utf-8-sig",
        "dtype": {column: str for column in TEXT_COLUMNS if column in header},
        "keep_default_na": False,
        "na_values": {c: list(MISSING_TEXT) for c in header if c not in TEXT_COLUMNS},
        "skip_blank_lines": False,
        "index_col": False,
        "usecols": usecols,
    }


def csv_parser_error(path: Path, exc: pd.errors.ParserError) -> DatasetError:
    """A :class:`DatasetError` for a malformed CSV line, with its row when known."""
    match = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
    if match is None:
        return DatasetError(f"cannot read CSV: {exc}", path=path)
    expected, line, seen = (int(group) for group in match.groups())
    return DatasetError(
        f"{seen} fields where the header has {expected} (line {line}; a decimal comma or "
        "an unquoted comma in a text?)",
        path=path,
        row=line - 1,
    )


def blank_rows(frame: pd.DataFrame) -> NDArray[np.bool_]:
    """Rows in which every cell is empty (blank CSV lines).

    Numeric columns are looked at first: text is stripped only in rows whose
    numbers are all missing.
    """
    blank = np.ones(len(frame), dtype=bool)
    text_columns = []
    for column in frame.columns:
        values = frame[column]
        if not pd.api.types.is_numeric_dtype(values):
            text_columns.append(column)
        elif blank.any():  # else no row is blank, whatever the other columns hold
            blank &= values.isna().to_numpy(dtype=bool)
    for column in text_columns:
        if not blank.any():
            break
        values = frame[column].iloc[np.flatnonzero(blank)]
        empty = values.isna() | values.astype("string").str.strip().eq("").fillna(True)
        blank[blank] = empty.to_numpy(dtype=bool)
    return blank


def _csv_rows(path: Path, frame: pd.DataFrame, first_row: int) -> RawRows:
    """``frame`` (file rows ``first_row``, ...) without its blank lines."""
    keep = ~blank_rows(frame)
    rows = np.arange(first_row, first_row + len(frame), dtype=np.int64)
    if keep.all():
        return RawRows(path, frame.reset_index(drop=True), rows)
    return RawRows(path, frame.loc[keep].reset_index(drop=True), rows[keep])


def _iter_csv(path: Path, header: list[str], chunk_rows: int | None,
              usecols: list[str] | None = None) -> Iterator[RawRows]:
    """A CSV file whole (``chunk_rows`` None) or in chunks: pyarrow's parser, else pandas'."""
    done = 0
    if _arrow_can_read(header, usecols):
        arrow = _iter_csv_arrow(path, header, chunk_rows, usecols)
        try:
            for frame in arrow:
                yield _csv_rows(path, frame, 1 + done * (chunk_rows or 0))
                done += 1
            return
        except pa.ArrowException:
            pass  # a line pyarrow cannot parse: pandas reads on, and names it if it is bad
    yield from _iter_csv_pandas(path, header, chunk_rows, usecols, skip_chunks=done)


def _iter_csv_pandas(path: Path, header: list[str], chunk_rows: int | None,
                     usecols: list[str] | None, *, skip_chunks: int = 0) -> Iterator[RawRows]:
    """A CSV file read by pandas, whole or in chunks, without its first ``skip_chunks``."""
    options = _csv_options(header, usecols)
    with _csv_errors(path):
        if chunk_rows is None:
            yield _csv_rows(path, pd.read_csv(path, **options), 1)
            return
        first_row = 1
        with pd.read_csv(path, chunksize=chunk_rows, **options) as reader:
            for chunk, frame in enumerate(reader):
                if chunk >= skip_chunks:
                    yield _csv_rows(path, frame, first_row)
                first_row += len(frame)


def _arrow_can_read(header: list[str], usecols: list[str] | None) -> bool:
    """Whether pyarrow may parse a file with this header: distinct contract columns only."""
    return len(set(header)) == len(header) and set(header) <= CONTRACT_COLUMNS and (
        usecols is None or set(usecols) <= set(header))


def _iter_csv_arrow(path: Path, header: list[str], chunk_rows: int | None,
                    usecols: list[str] | None) -> Iterator[pd.DataFrame]:
    """A CSV file parsed by pyarrow, as frames of exactly ``chunk_rows`` rows (or one frame).

    The options give what :func:`_csv_options` gives pandas: text columns as text
    (an empty cell ``""``), every other column as floats with the cells of
    :data:`MISSING_TEXT` missing.  An empty line comes as a row of empty cells (a
    blank row, dropped with its number kept).  A line with another number of fields
    (blanks only, too), a cell that is not a number and text that is not UTF-8 raise
    :class:`pyarrow.ArrowException` (the caller lets pandas read such a file), so the
    N-th row read is the file's row N.

    Raises
    ------
    pyarrow.ArrowException
        At the first block pyarrow cannot parse (frames before it were yielded).
    """
    columns = header if usecols is None else [c for c in header if c in usecols]
    types = {c: pa.string() if c in TEXT_COLUMNS else pa.float64() for c in columns}
    whole = chunk_rows is None
    read = pa_csv.ReadOptions(use_threads=whole, encoding="utf8",
                              block_size=(1 << 20) if whole else ARROW_BLOCK_BYTES)
    parse = pa_csv.ParseOptions(ignore_empty_lines=False)
    convert = pa_csv.ConvertOptions(column_types=types, include_columns=columns,
                                    null_values=list(MISSING_TEXT),
                                    strings_can_be_null=False,
                                    quoted_strings_can_be_null=False)
    try:
        if chunk_rows is None:
            table = pa_csv.read_csv(path, read_options=read, parse_options=parse,
                                    convert_options=convert)
            _check_arrow_header(table.schema.names, columns)
            yield _to_pandas(table)
            return
        reader = pa_csv.open_csv(path, read_options=read, parse_options=parse,
                                 convert_options=convert)
    except OSError:
        raise pa.ArrowInvalid("unreadable") from None  # pandas names the error
    _check_arrow_header(reader.schema.names, columns)
    held: list[pa.RecordBatch] = []
    n_held = 0
    with reader:
        for batch in reader:
            held.append(batch)
            n_held += batch.num_rows
            while n_held >= chunk_rows:
                table = pa.Table.from_batches(held, schema=reader.schema)
                yield _to_pandas(table.slice(0, chunk_rows))
                rest = table.slice(chunk_rows)
                held, n_held = rest.to_batches(), rest.num_rows
    if n_held:
        yield _to_pandas(pa.Table.from_batches(held, schema=reader.schema))


def _to_pandas(table: pa.Table) -> pd.DataFrame:
    """The rows as a frame, a block per column: not first copied into one 2-D block of
    floats, which validation takes apart column by column anyway."""
    return table.to_pandas(split_blocks=True)


def _check_arrow_header(names: list[str], columns: list[str]) -> None:
    """pyarrow read the columns pandas saw (a BOM or quoting read otherwise: pandas reads)."""
    if list(names) != list(columns):
        raise pa.ArrowInvalid(f"header read as {names}, not {columns}")


# --------------------------------------------------------------------------- Parquet


def parquet_file(path: Path) -> pq.ParquetFile:
    """An open Parquet file for chunked reading.

    Raises
    ------
    DatasetError
        If it is not a readable Parquet file.
    """
    try:
        return pq.ParquetFile(path, pre_buffer=False, buffer_size=PARQUET_BUFFER_BYTES)
    except (OSError, ValueError, pa.ArrowException) as exc:
        raise DatasetError(f"cannot read Parquet: {exc}", path=path) from None


def parquet_columns(handle: pq.ParquetFile) -> list[str]:
    """The data columns of a Parquet file (without a stored pandas index)."""
    index = set()
    metadata = handle.schema_arrow.pandas_metadata or {}
    for entry in metadata.get("index_columns", []):
        if isinstance(entry, str):
            index.add(entry)
    return [name for name in handle.schema_arrow.names if name not in index]


def _iter_parquet(path: Path, chunk_rows: int | None,
                  usecols: list[str] | None = None) -> Iterator[RawRows]:
    """A Parquet file whole (``chunk_rows`` None) or in record batches."""
    try:
        if chunk_rows is None:
            frame = pd.read_parquet(path, columns=usecols).reset_index(drop=True)
            yield RawRows(path, frame, np.arange(1, len(frame) + 1, dtype=np.int64))
            return
        handle = parquet_file(path)
        first_row = 1
        for batch in handle.iter_batches(batch_size=chunk_rows, columns=usecols):
            frame = pa.Table.from_batches([batch]).to_pandas().reset_index(drop=True)
            rows = np.arange(first_row, first_row + len(frame), dtype=np.int64)
            first_row += len(frame)
            yield RawRows(path, frame, rows)
    except (OSError, ValueError, ImportError, pa.ArrowException) as exc:
        raise DatasetError(f"cannot read Parquet: {exc}", path=path) from None


# --------------------------------------------------------------------------- both


def table_columns(path: Path) -> list[str]:
    """The column names of a CSV or Parquet table file (header or schema)."""
    if path.suffix == ".csv":
        return csv_header(path)
    return parquet_columns(parquet_file(path))


def read_rows(path: Path, required: tuple[str, ...], *, chunk_rows: int | None = None,
              usecols: list[str] | None = None) -> Iterator[RawRows]:
    """The rows of a CSV or Parquet table file, whole or in chunks.

    Parameters
    ----------
    path : Path
        The file; its suffix gives the format.
    required : tuple of str
        Columns the file must have (checked before any row is read).
    chunk_rows : int, optional
        Rows per chunk; ``None`` reads the whole file as one chunk.
    usecols : list of str, optional
        Read only these columns (all of them must be in ``required``).

    Yields
    ------
    RawRows
        The chunks in file order; a chunk may be empty (all its lines blank).

    Raises
    ------
    DatasetError
        If the file cannot be read, lacks a required column, or has a malformed
        line (naming the file, the row and the line).
    """
    columns = table_columns(path)
    require_columns(path, columns, required)
    if path.suffix == ".csv":
        yield from _iter_csv(path, columns, chunk_rows, usecols)
    else:
        yield from _iter_parquet(path, chunk_rows, usecols)


__all__ = [
    "ARROW_BLOCK_BYTES",
    "CONTRACT_COLUMNS",
    "DEFAULT_CHUNK_ROWS",
    "MISSING_TEXT",
    "TEXT_COLUMNS",
    "RawRows",
    "blank_rows",
    "csv_header",
    "csv_parser_error",
    "find_table_files",
    "parquet_columns",
    "parquet_file",
    "read_rows",
    "require_columns",
    "table_columns",
]
