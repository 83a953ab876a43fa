"""Validation and normalisation of plots and ADS-B rows (CONTRACT.md), a whole table or a chunk.

:func:`validate_plots` and :func:`validate_adsb` take the rows of one table file as
read (:class:`~graphcal.io.table_files.RawRows`: a whole file, or a chunk of one with
each row's number in its file) and return the normalised table, or raise one
:class:`~graphcal.core.errors.DatasetError` for the earliest bad row, naming the
file, the row (its number in the file) and the field.  The rules are those of
:mod:`graphcal.io.folder` (its module docstring lists them): the same functions serve
:func:`graphcal.io.folder.load_dataset` and the window-by-window reader
(:mod:`graphcal.io.window_reader`), so that both accept and reject the same rows
with the same message.

A caller may add its own row check (``extra``): it is given the problem collector
and the parsed ``time_s`` and flags rows like the built-in checks, so that the
earliest problem in the file is still the one reported.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
from numpy.typing import NDArray

from graphcal.core.errors import DatasetError
from graphcal.data.cleaning import MAX_PLOT_RANGE_M
from graphcal.data.dataset import ADSB_DEFAULT_SIGMA_M, MODE_3A_PATTERN, Site
from graphcal.data.sensor_models import adsb_sigma_from_nacp
from graphcal.io.table_files import MISSING_TEXT, RawRows


class FirstProblem:
    """Collects bad rows of several checks and keeps the earliest one.

    On a tie (two problems in the same row) the check made first wins.
    """

    def __init__(self, table: RawRows) -> None:
        self._table = table
        self._first: tuple[int, str, str, type[DatasetError]] | None = None

    def flag(self, bad: NDArray[np.bool_], column: str, describe: Callable[[int], str],
             kind: type[DatasetError] = DatasetError) -> None:
        """Record the first row where ``bad`` holds; ``describe(pos)`` makes its message,
        raised as ``kind``."""
        hits = np.flatnonzero(np.asarray(bad, dtype=bool))
        if hits.size and (self._first is None or hits[0] < self._first[0]):
            pos = int(hits[0])
            self._first = (pos, column, describe(pos), kind)

    def raise_first(self) -> None:
        """Raise the earliest recorded problem, if any."""
        if self._first is not None:
            pos, column, message, kind = self._first
            raise self._table.error(message, pos=pos, column=column, kind=kind)


#: ``extra(problems, time_s)``: a caller's own check of a chunk's rows (module docstring).
ExtraCheck = Callable[[FirstProblem, NDArray[np.float64]], None]


def _numeric(table: RawRows, problems: FirstProblem, column: str) -> NDArray[np.float64]:
    """A numeric column as floats (NaN where empty); flags cells that are not numbers."""
    values = table.frame[column]
    if pd.api.types.is_bool_dtype(values):
        problems.flag(np.ones(len(values), dtype=bool), column,
                      lambda pos: f"{values.iloc[pos]!r} is not a number")
        return np.full(len(values), np.nan)
    if pd.api.types.is_numeric_dtype(values):
        return values.to_numpy(dtype=float, na_value=np.nan)
    text = values.astype("string").str.strip()
    missing = (text.isna() | text.isin(MISSING_TEXT)).to_numpy(dtype=bool)
    parsed = pd.to_numeric(text.mask(missing), errors="coerce")
    parsed = parsed.to_numpy(dtype=float, na_value=np.nan)
    problems.flag(np.isnan(parsed) & ~missing, column,
                  lambda pos: f"{values.iloc[pos]!r} is not a number")
    return parsed


#: The dtype of :func:`_text`'s columns: pandas' default for ``str`` (``astype(str)``).
TEXT_DTYPE = pd.api.types.pandas_dtype(str)


def _printable_ascii(chunk: pa.Array, *, lower: bool) -> bool:
    """Whether every byte of a pyarrow (large) string array's cells is printable ASCII
    other than the blank (0x21-0x7e), and no upper-case letter when ``lower``; no
    cell may be missing."""
    large = pa.types.is_large_string(chunk.type)
    if chunk.null_count or not (large or pa.types.is_string(chunk.type)):
        return False
    _, offsets_buffer, data_buffer = chunk.buffers()
    width = np.int64 if large else np.int32
    offsets = np.frombuffer(offsets_buffer, dtype=width)
    start, end = offsets[chunk.offset], offsets[chunk.offset + len(chunk)]
    if start == end:
        return True
    data = np.frombuffer(data_buffer, dtype=np.uint8)[start:end]
    # Unsigned wrap-around: one comparison tests a byte range.
    if ((data - np.uint8(0x21)) >= 0x5E).any():
        return False
    return not (lower and ((data - np.uint8(0x41)) < 26).any())


def _text_unchanged(values: pd.Series, *, lower: bool) -> bool:
    """Whether :func:`_text` would give ``values`` back as they are: a column of
    :data:`TEXT_DTYPE` stored by pyarrow, no cell missing, and no blank, non-ASCII
    byte or (``lower``) upper-case letter in any cell, so that stripping and
    lower-casing change nothing."""
    if values.dtype != TEXT_DTYPE or getattr(values.dtype, "storage", None) != "pyarrow":
        return False
    array = pa.array(values.array)
    chunks = array.chunks if isinstance(array, pa.ChunkedArray) else [array]
    return all(_printable_ascii(chunk, lower=lower) for chunk in chunks)


def _text(table: RawRows, column: str, *, lower: bool = False) -> pd.Series:
    """A text column without surrounding blanks, ``""`` where missing."""
    values = table.frame[column]
    if _text_unchanged(values, lower=lower):
        return values
    text = values.astype("string").fillna("").str.strip()
    if lower:
        text = text.str.lower()
    return text.astype(str)


def _flag_not_finite(
    problems: FirstProblem, values: NDArray[np.float64], column: str, *, required: bool
) -> None:
    """Flag infinite values, and missing ones when ``required``."""
    bad = np.isinf(values) | (np.isnan(values) if required else False)
    problems.flag(bad, column, lambda pos: "missing value" if np.isnan(values[pos])
                  else f"{values[pos]} is not finite")


def _flag_outside(
    problems: FirstProblem,
    values: NDArray[np.float64],
    column: str,
    low: float,
    high: float,
    *,
    high_open: bool = False,
) -> None:
    """Flag values outside ``[low, high]`` (``[low, high)`` when ``high_open``); NaN passes."""
    above = values >= high if high_open else values > high
    interval = f"[{low:g}, {high:g}{')' if high_open else ']'}"
    problems.flag((values < low) | above, column,
                  lambda pos: f"{values[pos]} is outside {interval}")


#: Largest track number accepted: the largest integer a float holds exactly.
MAX_TRACK_NUMBER = 2**53


def _mode_3a(table: RawRows, problems: FirstProblem) -> pd.Series | None:
    """The ``mode_3a`` column (contract v3) as 4 octal digits, ``""`` where missing;
    ``None`` when the table has no such column.

    A cell is missing when empty (or one of :data:`MISSING_TEXT`); any other value
    must be 4 octal digits, as text: a numeric column (a Parquet integer column)
    has lost the leading zeros of its codes, so its values are flagged.
    """
    if "mode_3a" not in table.frame.columns:
        return None
    values = table.frame["mode_3a"]
    if pd.api.types.is_bool_dtype(values) or pd.api.types.is_numeric_dtype(values):
        given = values.notna().to_numpy(dtype=bool)
        problems.flag(given, "mode_3a",
                      lambda pos: f"{values.iloc[pos]!r} is a number: write the Mode 3/A "
                      "code as text, 4 octal digits (\"0413\"), so that its leading zeros "
                      "stay")
        return pd.Series([""] * len(values), dtype=object)
    text = values.astype("string").str.strip()
    missing = (text.isna() | text.isin(MISSING_TEXT)).to_numpy(dtype=bool)
    text = text.mask(missing, "")
    valid = text.str.fullmatch(MODE_3A_PATTERN).fillna(False).to_numpy(dtype=bool)
    problems.flag(~missing & ~valid, "mode_3a",
                  lambda pos: f"{text.iloc[pos]!r} is not a Mode 3/A code: 4 octal digits "
                  "(0-7), such as \"7000\" or \"0413\"")
    return text.astype(str)


def _track_number(table: RawRows, problems: FirstProblem) -> pd.arrays.IntegerArray | None:
    """The ``track_number`` column (contract v3) as ``Int64`` (missing where empty);
    ``None`` when the table has no such column.  A value must be a non-negative integer."""
    if "track_number" not in table.frame.columns:
        return None
    number = _numeric(table, problems, "track_number")
    given = ~np.isnan(number)
    with np.errstate(invalid="ignore"):
        invalid = given & ((number != np.round(number)) | (number < 0))
    problems.flag(invalid, "track_number",
                  lambda pos: f"{number[pos]:g} is not a non-negative integer")
    problems.flag(given & ~invalid & (number > MAX_TRACK_NUMBER), "track_number",
                  lambda pos: f"{number[pos]:g} is too large for a track number "
                  f"(at most {MAX_TRACK_NUMBER})")
    bad = ~given | invalid | (number > MAX_TRACK_NUMBER)
    return pd.arrays.IntegerArray(np.where(bad, 0, number).astype(np.int64), ~given | bad)


def _assemble(table: RawRows, columns: dict[str, Any]) -> pd.DataFrame:
    """The normalised columns, followed by the table's extra columns unchanged."""
    out = pd.DataFrame(columns, index=pd.RangeIndex(len(table.frame)))
    for column in table.frame.columns:
        if column not in out.columns:
            out[column] = table.frame[column]
    return out


# --------------------------------------------------------------------------- plots


def validate_plots(table: RawRows, sites: Mapping[str, Site], *,
                   extra: ExtraCheck | None = None) -> pd.DataFrame:
    """Validate and normalise plot rows (see :mod:`graphcal.io.folder`).

    Parameters
    ----------
    table : RawRows
        Rows of a plots file (whole or a chunk); it has the required columns.
    sites : mapping of str to Site
        The dataset's radars (an unknown ``radar_id`` is an error; a 3-D radar's
        plot needs an elevation).
    extra : callable, optional
        A further row check (module docstring).

    Returns
    -------
    pandas.DataFrame
        The contract columns normalised (``altitude_m`` added as NaN when
        absent; contract v3, when present: ``mode_3a`` as 4 octal digits, ``""``
        where empty, and ``track_number`` as ``Int64``), then the extra columns
        unchanged; a fresh ``RangeIndex``.

    Raises
    ------
    DatasetError
        For the earliest bad row, naming the file, its row and the field.
    """
    problems = FirstProblem(table)
    radar_id = _text(table, "radar_id")
    known = ", ".join(sites)
    problems.flag(~radar_id.isin(list(sites)).to_numpy(dtype=bool), "radar_id",
                  lambda pos: "missing radar id" if not radar_id.iloc[pos]
                  else f"unknown radar {radar_id.iloc[pos]!r}; sites.toml defines: {known}")
    time_s = _numeric(table, problems, "time_s")
    _flag_not_finite(problems, time_s, "time_s", required=True)
    range_m = _numeric(table, problems, "range_m")
    _flag_not_finite(problems, range_m, "range_m", required=True)
    problems.flag(range_m < 0.0, "range_m", lambda pos: f"negative range {range_m[pos]}")
    problems.flag(range_m > MAX_PLOT_RANGE_M, "range_m",
                  lambda pos: f"{range_m[pos]:.6g} is beyond any radar's reach "
                  f"({MAX_PLOT_RANGE_M / 1e3:,.0f} km): a corrupt value or another unit?")
    azimuth_deg = _numeric(table, problems, "azimuth_deg")
    _flag_not_finite(problems, azimuth_deg, "azimuth_deg", required=True)
    _flag_outside(problems, azimuth_deg, "azimuth_deg", 0.0, 360.0, high_open=True)
    elevation_deg = _numeric(table, problems, "elevation_deg")
    _flag_not_finite(problems, elevation_deg, "elevation_deg", required=False)
    three_d = radar_id.isin([s.id for s in sites.values() if s.is_3d]).to_numpy(dtype=bool)
    problems.flag(three_d & np.isnan(elevation_deg), "elevation_deg",
                  lambda pos: f"missing elevation for 3-D radar {radar_id.iloc[pos]!r}")
    _flag_outside(problems, elevation_deg, "elevation_deg", -90.0, 90.0)
    if "altitude_m" in table.frame.columns:
        altitude_m = _numeric(table, problems, "altitude_m")
        _flag_not_finite(problems, altitude_m, "altitude_m", required=False)
    else:
        altitude_m = np.full(len(table.frame), np.nan)
    target_id = _text(table, "target_id", lower=True)
    mode_3a = _mode_3a(table, problems)
    track_number = _track_number(table, problems)
    if extra is not None:
        extra(problems, time_s)
    problems.raise_first()
    columns: dict[str, Any] = {
        "radar_id": radar_id,
        "time_s": time_s,
        "range_m": range_m,
        "azimuth_deg": azimuth_deg,
        "elevation_deg": elevation_deg,
        "target_id": target_id,
        "altitude_m": altitude_m,
    }
    if mode_3a is not None:
        columns["mode_3a"] = mode_3a
    if track_number is not None:
        columns["track_number"] = track_number
    return _assemble(table, columns)


# --------------------------------------------------------------------------- ADS-B


def _adsb_nacp(table: RawRows, problems: FirstProblem) -> NDArray[np.float64] | None:
    """The ``nacp`` column as floats (NaN where empty), or ``None`` when absent."""
    if "nacp" not in table.frame.columns:
        return None
    nacp = _numeric(table, problems, "nacp")
    given = ~np.isnan(nacp)
    invalid = given & ((nacp != np.round(nacp)) | (nacp < 0) | (nacp > 11))
    problems.flag(invalid, "nacp", lambda pos: f"{nacp[pos]} is not an integer in 0..11")
    return nacp


def _adsb_sigma(
    table: RawRows, problems: FirstProblem, nacp: NDArray[np.float64] | None
) -> NDArray[np.float64]:
    """``sigma_m`` filled in: given value, else from NACp, else the default [m]."""
    n = len(table.frame)
    if "sigma_m" in table.frame.columns:
        sigma = _numeric(table, problems, "sigma_m")
        _flag_not_finite(problems, sigma, "sigma_m", required=False)
        problems.flag(sigma <= 0.0, "sigma_m", lambda pos: f"must be positive, got {sigma[pos]}")
    else:
        sigma = np.full(n, np.nan)
    if nacp is not None:
        usable = np.isfinite(nacp) & (nacp == np.round(nacp)) & (nacp >= 0) & (nacp <= 11)
        from_nacp = adsb_sigma_from_nacp(np.where(usable, nacp, np.nan))
        sigma = np.where(np.isnan(sigma), from_nacp, sigma)
    return np.where(np.isnan(sigma), ADSB_DEFAULT_SIGMA_M, sigma)


def validate_adsb(table: RawRows, *, extra: ExtraCheck | None = None) -> pd.DataFrame:
    """Validate and normalise ADS-B rows (see :mod:`graphcal.io.folder`).

    Parameters
    ----------
    table : RawRows
        Rows of an ADS-B file (whole or a chunk); it has the required columns.
    extra : callable, optional
        A further row check (module docstring).

    Returns
    -------
    pandas.DataFrame
        The contract columns normalised (``sigma_m`` filled in, ``nacp`` as
        ``Int64`` when present, ``baro_alt_m`` when present, ``mode_3a`` as 4
        octal digits (``""`` where empty) when present, ``alt_m`` NaN where
        empty: a report without a geometric height), then the extra columns
        unchanged; a fresh ``RangeIndex``.

    Raises
    ------
    DatasetError
        For the earliest bad row, naming the file, its row and the field.
    """
    problems = FirstProblem(table)
    time_s = _numeric(table, problems, "time_s")
    _flag_not_finite(problems, time_s, "time_s", required=True)
    target_id = _text(table, "target_id", lower=True)
    problems.flag((target_id == "").to_numpy(dtype=bool), "target_id",
                  lambda pos: "missing target id (ICAO address)")
    lat_deg = _numeric(table, problems, "lat_deg")
    _flag_not_finite(problems, lat_deg, "lat_deg", required=True)
    _flag_outside(problems, lat_deg, "lat_deg", -90.0, 90.0)
    lon_deg = _numeric(table, problems, "lon_deg")
    _flag_not_finite(problems, lon_deg, "lon_deg", required=True)
    _flag_outside(problems, lon_deg, "lon_deg", -180.0, 180.0)
    alt_m = _numeric(table, problems, "alt_m")
    # May be empty: a source without a geometric height (CAT021 without I140); such a
    # report is kept here and left out of a calibration by the cleaning, with a warning
    # (graphcal.data.cleaning.drop_non_finite_adsb).  Infinite is still an error.
    _flag_not_finite(problems, alt_m, "alt_m", required=False)
    nacp = _adsb_nacp(table, problems)
    sigma_m = _adsb_sigma(table, problems, nacp)
    baro_alt_m = None
    if "baro_alt_m" in table.frame.columns:
        baro_alt_m = _numeric(table, problems, "baro_alt_m")
        _flag_not_finite(problems, baro_alt_m, "baro_alt_m", required=False)
    mode_3a = _mode_3a(table, problems)
    if extra is not None:
        extra(problems, time_s)
    problems.raise_first()
    columns: dict[str, Any] = {
        "time_s": time_s,
        "target_id": target_id,
        "lat_deg": lat_deg,
        "lon_deg": lon_deg,
        "alt_m": alt_m,
        "sigma_m": sigma_m,
    }
    if nacp is not None:
        missing = np.isnan(nacp)  # the others are integers 0..11 (checked above)
        columns["nacp"] = pd.arrays.IntegerArray(
            np.where(missing, 0, nacp).astype(np.int64), missing)
    if baro_alt_m is not None:
        columns["baro_alt_m"] = baro_alt_m
    if mode_3a is not None:
        columns["mode_3a"] = mode_3a
    return _assemble(table, columns)


__all__ = ["ExtraCheck", "FirstProblem", "validate_adsb", "validate_plots"]
