"""Read OpenSky-style state-vector tables into the contract ADS-B table.

Input columns (CSV or Parquet): ``timestamp`` (unix seconds, or a datetime;
naive datetimes are UTC), ``icao24``, ``latitude``, ``longitude`` [deg], and
a height: ``geoaltitude`` [m, GNSS height] when the column exists, else
``altitude`` [ft, barometric], else ``baroaltitude`` [m, barometric].
Optional: ``lastposupdate`` [unix s, time of the last position update],
``onground`` (bool) and ``squawk`` (the Mode 3/A code).

Cleaning, in this order (each step's drops are counted):

1. rows with a missing or out-of-range latitude/longitude, an unreadable time
   or an ``icao24`` that is not 6 hex digits;
2. *stale* rows, that only repeat an older position: with ``lastposupdate``,
   rows whose ``lastposupdate`` does not advance over the previous row of the
   same aircraft; without it, rows whose latitude and longitude both equal the
   previous row's of the same aircraft (OpenSky repeats the last position when
   no new one was received; the altitude comes from other messages and may
   change meanwhile, so it is not compared);
3. rows on the ground (``onground`` true);
4. rows without a height, or a height outside [-500, 20000] m;
5. repeated (aircraft, time) pairs.

Time base: ``time_s`` is seconds since ``epoch_unix_s``; by default the
midnight UTC before the first report, which puts ``time_s`` on the same scale
as ASTERIX times of day.  The time is ``lastposupdate`` when that column is
given (the time the position applies to), else ``timestamp``.

Heights: ``geoaltitude`` is a GNSS height, used as is.  Without it, the
barometric ``altitude`` [ft] is converted to metres and used as if it were a
height above the WGS-84 ellipsoid: pressure altitude and ellipsoidal height
differ by up to a few hundred metres (weather, geoid), which matters for 3-D
radars; ``frame.attrs["height_source"]`` says which was used.

Pressure altitudes (contract v2): when the height is ``geoaltitude`` and the table
also has a barometric altitude, ``baroaltitude`` [m] (OpenSky's historical
state vectors) or else ``altitude`` [ft], it becomes the column ``baro_alt_m``
[m] (NaN where missing or outside the plausible heights), from which the
calibration estimates the height model (:mod:`graphcal.data.height`);
``frame.attrs["baro_source"]`` names it (``None`` without one).  A table whose
only height is barometric gives no ``baro_alt_m``: its ``alt_m`` already is that
altitude, and the two would say nothing about the height model.

Mode 3/A codes (contract v3): a ``squawk`` column becomes ``mode_3a``, 4 octal
digits.  OpenSky gives the code as text ("0413") or, once a reader has parsed it,
as a number (413, 413.0): the digits are kept and zero-padded to four.  A missing
code, or one that is not 1 to 4 octal digits, becomes ``""``; the row is kept.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from graphcal.core.errors import DatasetError

#: Metres per foot.
FOOT_M = 0.3048
#: Heights outside this interval [m] are dropped as implausible.
HEIGHT_RANGE_M: tuple[float, float] = (-500.0, 20000.0)
#: Columns the input must have (plus ``geoaltitude`` or ``altitude``).
REQUIRED_COLUMNS: tuple[str, ...] = ("timestamp", "icao24", "latitude", "longitude")
#: Height columns, by preference, with the factor to metres.
HEIGHT_COLUMNS: dict[str, float] = {"geoaltitude": 1.0, "altitude": FOOT_M, "baroaltitude": 1.0}
#: Barometric altitude columns read into ``baro_alt_m`` beside ``geoaltitude``, by preference.
BARO_COLUMNS: dict[str, float] = {"baroaltitude": 1.0, "altitude": FOOT_M}
#: Unix times above this are taken as milliseconds (year 5138 in seconds).
_MILLISECONDS_ABOVE = 1e11

# Drop reasons (keys of ``attrs["dropped"]``).
DROP_NO_POSITION = "missing or invalid position"
DROP_BAD_TIME = "unreadable time"
DROP_BAD_ADDRESS = "icao24 not 6 hex digits"
DROP_STALE = "stale (repeated) position"
DROP_ON_GROUND = "on ground"
DROP_NO_HEIGHT = "missing or implausible height"
DROP_DUPLICATE = "repeated time"


def _read(path: Path) -> pd.DataFrame:
    if not path.is_file():
        raise DatasetError("file not found", path=path)
    try:
        if path.suffix.lower() in (".parquet", ".pq"):
            return pd.read_parquet(path)
        return pd.read_csv(path, dtype={"icao24": str, "squawk": str})
    except Exception as exc:  # noqa: BLE001 - any reader failure is a bad input file
        raise DatasetError(f"cannot read table: {exc}", path=path) from None


def _unix_seconds(values: pd.Series) -> np.ndarray:
    """Unix seconds [s] (NaN where unreadable) from epoch numbers or datetimes."""
    if pd.api.types.is_bool_dtype(values):
        return np.full(len(values), np.nan)
    if pd.api.types.is_numeric_dtype(values):
        seconds = values.to_numpy(dtype=float, na_value=np.nan)
        return np.where(np.abs(seconds) > _MILLISECONDS_ABOVE, seconds / 1e3, seconds)
    if not pd.api.types.is_datetime64_any_dtype(values):
        numbers = pd.to_numeric(values, errors="coerce")
        if numbers.notna().sum() >= values.notna().sum() and len(values):
            return _unix_seconds(numbers)
    times = pd.Series(pd.to_datetime(values, utc=True, errors="coerce"))
    seconds = (times - pd.Timestamp(0, tz="UTC")).dt.total_seconds()
    return seconds.to_numpy(dtype=float, na_value=np.nan)


def _numbers(frame: pd.DataFrame, column: str) -> np.ndarray:
    return pd.to_numeric(frame[column], errors="coerce").to_numpy(dtype=float, na_value=np.nan)


def squawk_codes(values: pd.Series) -> np.ndarray:
    """OpenSky ``squawk`` values as Mode 3/A codes: 4 octal digits, ``""`` where none.

    Parameters
    ----------
    values : pandas.Series
        Text ("0413", "7000") or numbers (413, 413.0) whose decimal digits are the
        code's octal digits.

    Returns
    -------
    numpy.ndarray
        One string per value: the code zero-padded to 4 digits (413 -> "0413"), or
        ``""`` when missing or not 1 to 4 octal digits.
    """
    if pd.api.types.is_bool_dtype(values):
        return np.full(len(values), "", dtype=object)
    if pd.api.types.is_numeric_dtype(values):
        number = values.to_numpy(dtype=float, na_value=np.nan)
        with np.errstate(invalid="ignore"):
            whole = (np.isfinite(number) & (number == np.round(number)) & (number >= 0)
                     & (number <= 7777))
        text = pd.Series(np.where(whole, number, -1.0)).astype(np.int64).astype("string")
        text = text.mask(~whole)
    else:
        text = values.astype("string").str.strip().str.replace(r"\.0*$", "", regex=True)
    valid = text.str.fullmatch(r"[0-7]{1,4}").fillna(False).to_numpy(dtype=bool)
    padded = text.str.zfill(4).fillna("").to_numpy(dtype=object)
    return np.where(valid, padded, "").astype(object)


def read_opensky_adsb(path: str | Path, *, epoch_unix_s: float | None = None) -> pd.DataFrame:
    """Read an OpenSky-style table as a contract ADS-B table.

    Parameters
    ----------
    path : str or Path
        CSV or Parquet (``.parquet``/``.pq``) table (module docstring for the columns).
    epoch_unix_s : float, optional
        Unix time [s] that becomes ``time_s`` = 0; default: 00:00 UTC of the day
        of the first report.  Pass the epoch of an ASTERIX recording to share
        its time base.

    Returns
    -------
    pandas.DataFrame
        Columns ``time_s`` [s since the epoch], ``target_id`` (lower-case hex),
        ``lat_deg``, ``lon_deg`` [deg], ``alt_m`` [m], ``baro_alt_m`` [m]
        when a barometric altitude accompanies ``geoaltitude``, and ``mode_3a``
        (4 octal digits, ``""`` where none) when the table has ``squawk``;
        sorted by time then target.  ``attrs``: ``epoch_unix_s`` (float), ``height_source``
        (``"geoaltitude"``, ``"altitude (barometric)"`` or ``"baroaltitude
        (barometric)"``), ``baro_source`` (column name or ``None``),
        ``rows_read`` (int) and ``dropped`` (dict of reason to row count, in
        cleaning order).

    Raises
    ------
    DatasetError
        If the file is missing or unreadable, a required column is missing, or
        no row survives the cleaning.
    """
    path = Path(path)
    table = _read(path)
    missing = [c for c in REQUIRED_COLUMNS if c not in table.columns]
    height_col = next((c for c in HEIGHT_COLUMNS if c in table.columns), None)
    if height_col is None:
        missing.append("geoaltitude or altitude (or baroaltitude)")
    if missing:
        found = ", ".join(map(str, table.columns)) or "none"
        raise DatasetError(f"missing column(s) {', '.join(missing)} (found: {found})", path=path)
    scale = HEIGHT_COLUMNS[height_col]
    baro_col = None
    if height_col == "geoaltitude":
        baro_col = next((c for c in BARO_COLUMNS if c in table.columns), None)
    baro = (_numbers(table, baro_col) * BARO_COLUMNS[baro_col] if baro_col is not None
            else np.full(len(table), np.nan))
    time_col = "lastposupdate" if "lastposupdate" in table.columns else "timestamp"
    df = pd.DataFrame({
        "unix": _unix_seconds(table[time_col]),
        "icao24": table["icao24"].astype("string").fillna("").str.strip().str.lower()
        .astype(str).to_numpy(),
        "lat": _numbers(table, "latitude"),
        "lon": _numbers(table, "longitude"),
        "h": _numbers(table, height_col) * scale,
        "baro": baro,
        "onground": (table["onground"].fillna(False).astype(bool).to_numpy()
                     if "onground" in table.columns else np.zeros(len(table), dtype=bool)),
        "squawk": (squawk_codes(table["squawk"]) if "squawk" in table.columns
                   else np.full(len(table), "", dtype=object)),
    })
    dropped: dict[str, int] = {}

    def drop(mask: np.ndarray, reason: str) -> None:
        nonlocal df
        dropped[reason] = int(mask.sum())
        df = df[~mask]

    lat, lon = df["lat"].to_numpy(), df["lon"].to_numpy()
    drop(~(np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90.0) & (np.abs(lon) <= 180.0)),
         DROP_NO_POSITION)
    drop(~np.isfinite(df["unix"].to_numpy()), DROP_BAD_TIME)
    drop(~df["icao24"].str.fullmatch(r"[0-9a-f]{6}").to_numpy(dtype=bool), DROP_BAD_ADDRESS)
    df = df.sort_values(["icao24", "unix"], kind="stable").reset_index(drop=True)
    same = df["icao24"].eq(df["icao24"].shift()).to_numpy()
    if time_col == "lastposupdate":
        latest = df.groupby("icao24", sort=False)["unix"].cummax().shift()
        stale = same & (df["unix"].to_numpy() <= latest.to_numpy(dtype=float, na_value=np.nan))
    else:
        stale = same & (df["lat"].eq(df["lat"].shift()) & df["lon"].eq(df["lon"].shift())
                        ).to_numpy()
    drop(stale, DROP_STALE)
    drop(df["onground"].to_numpy(dtype=bool), DROP_ON_GROUND)
    h = df["h"].to_numpy()
    drop(~(np.isfinite(h) & (h >= HEIGHT_RANGE_M[0]) & (h <= HEIGHT_RANGE_M[1])), DROP_NO_HEIGHT)
    drop((df["icao24"].eq(df["icao24"].shift()) & df["unix"].eq(df["unix"].shift())).to_numpy(),
         DROP_DUPLICATE)
    if df.empty:
        raise DatasetError(f"no usable ADS-B row (dropped: {dropped})", path=path)
    if epoch_unix_s is None:
        epoch_unix_s = math.floor(float(df["unix"].min()) / 86400.0) * 86400.0
    out = pd.DataFrame({
        "time_s": df["unix"].to_numpy() - epoch_unix_s,
        "target_id": df["icao24"].to_numpy(),
        "lat_deg": df["lat"].to_numpy(),
        "lon_deg": df["lon"].to_numpy(),
        "alt_m": df["h"].to_numpy(),
    })
    if baro_col is not None:
        baro = df["baro"].to_numpy()
        plausible = (baro >= HEIGHT_RANGE_M[0]) & (baro <= HEIGHT_RANGE_M[1])
        out["baro_alt_m"] = np.where(plausible, baro, np.nan)
    if "squawk" in table.columns:
        out["mode_3a"] = df["squawk"].to_numpy(dtype=object)
    out = out.sort_values(["time_s", "target_id"], kind="stable").reset_index(drop=True)
    out.attrs.update({
        "epoch_unix_s": float(epoch_unix_s),
        "height_source": ("geoaltitude" if height_col == "geoaltitude"
                          else f"{height_col} (barometric)"),
        "baro_source": baro_col,
        "rows_read": len(table),
        "dropped": dropped,
    })
    return out
