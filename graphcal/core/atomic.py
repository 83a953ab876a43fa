"""Atomic writes: a reader sees either the old file or the complete new one.

Every output of graphcal goes through these functions: the content is written
to a temporary file in the destination folder and renamed into place
(``os.replace``), so an error or an interruption leaves any previous file
untouched.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd


def atomic_write_stream(path: str | Path, write: Callable[[Any], None]) -> None:
    """Write a file atomically through ``write(stream)`` (a binary stream).

    ``write`` fills a temporary file in the same folder, which then replaces
    ``path`` (``os.replace``), so a reader never sees a half-written file and an
    error leaves any previous file untouched.

    Parameters
    ----------
    path : str or Path
        Destination file; its folder must exist.
    write : callable
        Called once with the open binary stream.
    """
    path = Path(path)
    handle, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(handle, "wb") as stream:
            write(stream)
            stream.flush()
            os.fsync(stream.fileno())
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise


def atomic_write_text(path: str | Path, text: str, *, encoding: str = "utf-8") -> None:
    """Write a text file atomically (:func:`atomic_write_stream`).

    Parameters
    ----------
    path : str or Path
        Destination file; its folder must exist.
    text : str
        Content.
    encoding : str, optional
        Text encoding, UTF-8 by default.
    """
    data = text.encode(encoding)
    atomic_write_stream(path, lambda stream: stream.write(data))


def atomic_write_table(frame: pd.DataFrame, path: str | Path) -> None:
    """Write one table atomically, CSV or Parquet by the suffix of ``path``.

    Raises
    ------
    ValueError
        If the suffix is neither ``.csv`` nor ``.parquet``.
    """
    path = Path(path)
    if path.suffix not in (".csv", ".parquet"):
        raise ValueError(f"{path}: the table format comes from the suffix: .csv or .parquet")
    handle, temporary = tempfile.mkstemp(
        prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent
    )
    os.close(handle)
    try:
        write_table(frame, Path(temporary))
        os.chmod(temporary, 0o644)
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temporary)
        raise


def write_table(frame: pd.DataFrame, path: Path) -> None:
    """Write one table as CSV (empty cells for NaN) or Parquet, by suffix."""
    if path.suffix == ".csv":
        frame.to_csv(path, index=False, na_rep="")
    else:
        frame.to_parquet(path, index=False)
