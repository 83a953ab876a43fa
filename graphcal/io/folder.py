"""Dataset folders: reading and writing sites, plots and ADS-B reports (CONTRACT.md).

A dataset is a folder with ``sites.toml``, ``plots.csv|parquet`` and optionally
``adsb.csv|parquet``.  Tables keep the contract's column names and units
(degrees, metres, seconds); :class:`Site` holds SI values (radians).

Reading (:func:`load_dataset`, :func:`load_sites`) validates everything and
raises one :class:`~graphcal.core.errors.DatasetError` for the first problem found,
naming the file, the row and the field:

* In a table, "row N" is the N-th data row as a user counts it in the file.
  In a CSV file the header is line 1 and row N is line N + 1 (the message
  repeats the line number); blank lines are skipped but keep this numbering,
  so without blank lines row N is exactly the N-th data row.  In a Parquet
  file row N is the N-th row.  When several rows are bad, the first one in the
  file is reported.
* In ``sites.toml``, "row N" is the N-th ``[[radar]]`` table.

Normalisation of the tables read:

* ``radar_id`` and ``target_id`` are strings with surrounding blanks removed;
  ``target_id`` is lower-cased and is ``""`` when missing.
* Numeric cells may be empty (or ``nan``, ``NA``, ``null``) where a value is
  optional; text that is not a number is an error.  Infinite values are always
  an error.
* ``elevation_deg`` is required for a 3-D radar's plots; for a 2-D radar it may
  be empty.  A 2-D radar's plot that carries an elevation keeps it in the
  table, but graphcal ignores it (a 2-D radar does not measure elevation).
* ``altitude_m`` is NaN where absent (the column is added when missing).
* ADS-B ``sigma_m`` is always filled: the given value, else the value of the
  report's ``nacp`` (:func:`graphcal.data.sensor_models.adsb_sigma_from_nacp`), else
  :data:`ADSB_DEFAULT_SIGMA_M`.  ``nacp``, when the column exists, is kept as a
  nullable integer (``Int64``) and must be within 0..11.
* ADS-B ``baro_alt_m`` (contract v2, optional): the reported pressure altitude
  [m], NaN where a report has none.
* ``sites.toml`` may hold a top-level ``[dataset]`` table (contract v2) whose
  ``plot_altitude`` (``"geometric"``, the default, or ``"pressure"``) says what the
  plots' ``altitude_m`` is; it becomes :attr:`Dataset.plot_altitude`
  (:func:`load_plot_altitude`).
* Columns beyond the contract's are kept unchanged after the contract columns.

Reading never writes anything.  Writing (:func:`write_dataset`,
:func:`write_sites`, :func:`atomic_write_text`) is atomic: a reader sees either
the old content or the complete new one.
"""


from __future__ import annotations

import math
import os
import re
import shutil
import tempfile
import tomllib
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import tomli_w
from numpy.typing import NDArray

from graphcal.core.atomic import atomic_write_text, write_table
from graphcal.core.errors import DatasetError, SensorModelError
from graphcal.core.refraction import DEFAULT_N_S, DEFAULT_SCALE_HEIGHT_M, Atmosphere
from graphcal.data.bias import ESTIMATE_NAMES
from graphcal.data.dataset import (
    ADSB_COLUMNS,
    ADSB_DEFAULT_SIGMA_M,
    PLOT_COLUMNS,
    REFRACTION_MODELS,
    REFRACTIVITY_N_S_RANGE,
    SITE_KEYS,
    SITES_FILE,
    TABLE_FORMATS,
    Dataset,
    Site,
)
from graphcal.data.height import GEOMETRIC, PLOT_ALTITUDE_CHOICES
from graphcal.data.sensor_models import SensorModel, adsb_sigma_from_nacp, load_sensor_model

#: Text read as "no value" in a numeric column (compared after removing blanks).
_MISSING_TEXT: tuple[str, ...] = ("", "nan", "NaN", "NAN", "NA", "N/A", "n/a", "null", "NULL",
                                  "None", "none")
#: Columns read as text; every other contract column is numeric.
_TEXT_COLUMNS: tuple[str, ...] = ("radar_id", "target_id")



# --------------------------------------------------------------------------- sites.toml


@dataclass(frozen=True)
class _Where:
    """Location of a ``[[radar]]`` table, for error messages."""

    path: Path
    row: int
    label: str

    def error(self, key: str | None, message: str) -> DatasetError:
        """A :class:`DatasetError` for this table and key."""
        return DatasetError(f"{self.label}: {message}", path=self.path, row=self.row, field=key)


def _site_number(
    entry: Mapping[str, Any],
    key: str,
    where: _Where,
    *,
    low: float = -math.inf,
    high: float = math.inf,
    positive: bool = False,
) -> float | None:
    """A finite number from a ``[[radar]]`` table, or ``None`` when the key is absent."""
    if key not in entry:
        return None
    value = entry[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise where.error(key, f"must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise where.error(key, f"must be finite, got {value}")
    if positive and value <= 0.0:
        raise where.error(key, f"must be positive, got {value}")
    if not low <= value <= high:
        raise where.error(key, f"{value} is outside [{low:g}, {high:g}]")
    return value


def _site_id(entry: Mapping[str, Any], where: _Where) -> str:
    """The non-empty ``id`` of a ``[[radar]]`` table, without surrounding blanks."""
    if "id" not in entry:
        raise where.error("id", "missing radar id")
    value = entry["id"]
    if not isinstance(value, str):
        raise where.error("id", f"must be a string, got {value!r}")
    if not value.strip():
        raise where.error("id", "radar id is empty")
    return value.strip()


def _site_model(entry: Mapping[str, Any], where: _Where) -> SensorModel | None:
    """The sensor model a ``[[radar]]`` table names, or ``None``."""
    if "model" not in entry:
        return None
    name = entry["model"]
    if not isinstance(name, str) or not name.strip():
        raise where.error("model", f"must be a non-empty string, got {name!r}")
    try:
        return load_sensor_model(name.strip())
    except SensorModelError as exc:
        raise where.error("model", str(exc)) from None


def _site_estimate(entry: Mapping[str, Any], where: _Where) -> tuple[str, ...] | None:
    """The ``estimate`` list of a ``[[radar]]`` table, or ``None`` when absent."""
    if "estimate" not in entry:
        return None
    value = entry["estimate"]
    if not isinstance(value, list) or not all(isinstance(name, str) for name in value):
        raise where.error("estimate", f"must be a list of parameter names, got {value!r}")
    if not value:
        raise where.error("estimate", "must name at least one parameter")
    for name in value:
        if name not in ESTIMATE_NAMES:
            known = ", ".join(ESTIMATE_NAMES)
            raise where.error("estimate", f"unknown parameter {name!r}; known: {known}")
    if len(set(value)) != len(value):
        raise where.error("estimate", "names a parameter twice")
    return tuple(value)


def _site_refraction(entry: Mapping[str, Any], where: _Where) -> tuple[str, float, float]:
    """``(refraction, refractivity_n_s, refractivity_scale_height_m)`` of a ``[[radar]]`` table.

    Contract v2: ``refraction`` is one of :data:`REFRACTION_MODELS` (default
    ``"none"``), ``N_s`` within :data:`REFRACTIVITY_N_S_RANGE` (default 313), ``H``
    positive (default 7000 m); an ``"exponential"`` atmosphere must also be one
    :class:`~graphcal.core.refraction.Atmosphere` accepts (no super-refraction).
    """
    model = entry.get("refraction", "none")
    if not isinstance(model, str):
        raise where.error("refraction", f"must be a string, got {model!r}")
    if model not in REFRACTION_MODELS:
        known = ", ".join(f'"{m}"' for m in REFRACTION_MODELS)
        raise where.error("refraction", f"unknown refraction model {model!r}; known: {known}")
    low, high = REFRACTIVITY_N_S_RANGE
    n_s = _site_number(entry, "refractivity_n_s", where, low=low, high=high)
    height = _site_number(entry, "refractivity_scale_height_m", where, positive=True)
    n_s = DEFAULT_N_S if n_s is None else n_s
    height = DEFAULT_SCALE_HEIGHT_M if height is None else height
    if model != "none":
        try:
            Atmosphere(n_s, height)
        except ValueError as exc:
            key = "refractivity_scale_height_m" if "refractivity_scale_height_m" in entry \
                else "refractivity_n_s"
            raise where.error(key, str(exc)) from None
    return model, n_s, height


def _required(value: Any, key: str, where: _Where) -> Any:
    """``value`` unless it is ``None`` (given neither by the site nor by its model)."""
    if value is None:
        raise where.error(key, "missing (give it, or name a sensor model that supplies it)")
    return value


def _parse_site(entry: Any, where: _Where) -> Site:
    """Validate one ``[[radar]]`` table and build its :class:`Site` (SI units).

    Values given by the table win over the defaults of its sensor model.
    """
    if not isinstance(entry, dict):
        raise where.error("radar", "each [[radar]] entry must be a table")
    site_id = _site_id(entry, where)
    where = _Where(where.path, where.row, f"radar {site_id!r}")
    for key in entry:
        if key not in SITE_KEYS:
            raise where.error(key, f"unknown key; known keys: {', '.join(SITE_KEYS)}")
    model = _site_model(entry, where)
    lat_deg = _site_number(entry, "lat_deg", where, low=-90.0, high=90.0)
    lon_deg = _site_number(entry, "lon_deg", where, low=-180.0, high=180.0)
    alt_m = _site_number(entry, "alt_m", where)
    sigma_range_m = _site_number(entry, "sigma_range_m", where, positive=True)
    sigma_az_mrad = _site_number(entry, "sigma_azimuth_mrad", where, positive=True)
    sigma_el_mrad = _site_number(entry, "sigma_elevation_mrad", where, positive=True)
    scan_period_s = _site_number(entry, "scan_period_s", where, positive=True)
    estimate = _site_estimate(entry, where)
    sigma_az = None if sigma_az_mrad is None else sigma_az_mrad / 1e3
    sigma_el = None if sigma_el_mrad is None else sigma_el_mrad / 1e3
    if model is not None:
        sigma_range_m = model.sigma_range_m if sigma_range_m is None else sigma_range_m
        sigma_az = model.sigma_azimuth_rad if sigma_az is None else sigma_az
        sigma_el = model.sigma_elevation_rad if sigma_el is None else sigma_el
        scan_period_s = model.scan_period_s if scan_period_s is None else scan_period_s
        estimate = model.estimate if estimate is None else estimate
    no_sigma = sigma_range_m is None and sigma_az is None and sigma_el is None
    if estimate is not None and "elevation_bias" in estimate and sigma_el is None and not no_sigma:
        raise where.error("estimate", "elevation_bias needs a 3-D radar (sigma_elevation_mrad)")
    sac, sic = _site_code(entry, "sac", where), _site_code(entry, "sic", where)
    if (sac is None) != (sic is None):
        raise where.error("sac" if sac is None else "sic", "give both sac and sic, or neither")
    refraction, n_s, scale_height = _site_refraction(entry, where)
    return Site(
        id=site_id,
        lat_rad=math.radians(_required(lat_deg, "lat_deg", where)),
        lon_rad=math.radians(_required(lon_deg, "lon_deg", where)),
        alt_m=_required(alt_m, "alt_m", where),
        sigma_range_m=math.nan if sigma_range_m is None else sigma_range_m,
        sigma_azimuth_rad=math.nan if sigma_az is None else sigma_az,
        sigma_elevation_rad=sigma_el,
        scan_period_s=scan_period_s,
        model=None if model is None else model.name,
        estimate=() if estimate is None else estimate,
        sac=sac,
        sic=sic,
        refraction=refraction,
        refractivity_n_s=n_s,
        refractivity_scale_height_m=scale_height,
    )


def _site_code(entry: Mapping[str, Any], key: str, where: _Where) -> int | None:
    """An optional ASTERIX SAC or SIC: an integer in 0..255."""
    value = entry.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 255:
        raise where.error(key, f"must be an integer in 0..255, got {value!r}")
    return int(value)


def load_sites(path: str | Path) -> dict[str, Site]:
    """Read ``sites.toml``.

    Parameters
    ----------
    path : str or Path
        The ``sites.toml`` file: one ``[[radar]]`` table per radar with ``id``,
        ``lat_deg``, ``lon_deg`` [deg], ``alt_m`` [m], and optionally
        ``sigma_range_m`` [m], ``sigma_azimuth_mrad`` [mrad] (absent: NaN, to be
        estimated from the data, see :attr:`Site.missing_sigmas`),
        ``sigma_elevation_mrad`` [mrad] (absent: a 2-D radar; a table with no
        sigma at all is made 3-D by :func:`load_dataset` when all its plots carry
        an elevation), ``scan_period_s`` [s], ``model`` (a sensor
        model from :mod:`graphcal.data.sensor_models` that supplies the sigmas, scan
        period and ``estimate`` the table does not give) and ``estimate`` (the
        bias parameters to estimate, names from
        :data:`graphcal.data.bias.PARAMETER_NAMES`; ``elevation_bias`` only for a
        3-D radar; default: all the radar has), and (contract v2) ``refraction``
        (``"none"``, the default, or ``"exponential"``), ``refractivity_n_s``
        [N-units, 0-500, default 313] and ``refractivity_scale_height_m`` [m,
        default 7000].

    Returns
    -------
    dict of str to Site
        Sites by id, in file order, in SI units (radians).

    Raises
    ------
    DatasetError
        If the file is missing or not TOML, or any table is invalid (missing or
        unknown key, empty or duplicate id, latitude outside [-90, 90] deg,
        longitude outside [-180, 180] deg, a non-positive sigma, an unknown
        refraction model, a refractivity outside [0, 500] N-units, a
        non-positive scale height, ...).  "row N" in the message is the N-th
        ``[[radar]]`` table.
    """
    path = Path(path)
    document = _read_toml(path)
    entries = document.get("radar")
    if not isinstance(entries, list) or not entries:
        raise DatasetError("no [[radar]] tables", path=path, field="radar")
    sites: dict[str, Site] = {}
    first_row: dict[str, int] = {}
    for row, entry in enumerate(entries, start=1):
        site = _parse_site(entry, _Where(path, row, "radar"))
        if site.id in sites:
            raise DatasetError(
                f"duplicate radar id {site.id!r} (first in row {first_row[site.id]})",
                path=path,
                row=row,
                field="id",
            )
        sites[site.id] = site
        first_row[site.id] = row
    return sites


def _read_toml(path: Path) -> dict[str, Any]:
    """The parsed ``sites.toml``, or a :class:`DatasetError` naming the file."""
    try:
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise DatasetError("file not found", path=path) from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise DatasetError(f"cannot read TOML: {exc}", path=path) from None


#: Keys of the top-level ``[dataset]`` table of ``sites.toml`` (contract v2).
DATASET_KEYS: tuple[str, ...] = ("plot_altitude",)


def load_plot_altitude(path: str | Path) -> str:
    """What the plots' ``altitude_m`` is, from ``sites.toml``'s ``[dataset]`` table.

    Parameters
    ----------
    path : str or Path
        The ``sites.toml`` file.

    Returns
    -------
    str
        ``"geometric"`` (a height above the ellipsoid; the default, also without a
        ``[dataset]`` table) or ``"pressure"`` (a pressure altitude, see
        :mod:`graphcal.data.height`).

    Raises
    ------
    DatasetError
        If ``[dataset]`` is not a table, has an unknown key, or ``plot_altitude`` is
        not one of the choices; the message names the file, the table and the field.
    """
    path = Path(path)
    table = _read_toml(path).get("dataset")
    if table is None:
        return GEOMETRIC
    if not isinstance(table, dict):
        raise DatasetError("[dataset] must be a table", path=path, field="dataset")
    for key in table:
        if key not in DATASET_KEYS:
            raise DatasetError(f"[dataset]: unknown key; known keys: {', '.join(DATASET_KEYS)}",
                               path=path, field=f"dataset.{key}")
    value = table.get("plot_altitude", GEOMETRIC)
    if not isinstance(value, str) or value not in PLOT_ALTITUDE_CHOICES:
        choices = " or ".join(f'"{c}"' for c in PLOT_ALTITUDE_CHOICES)
        raise DatasetError(f"[dataset]: plot_altitude must be {choices}, got {value!r}",
                           path=path, field="dataset.plot_altitude")
    return value


def _to_file_units(value: float, to_file: Callable[[float], float],
                   from_file: Callable[[float], float]) -> float:
    """``to_file(value)``, nudged by a few ulp so that ``from_file`` gives ``value`` back.

    Keeps ``load_sites(write_sites(sites))`` exact for values that were read
    from a file (degrees and milliradians do not convert exactly to radians).
    """
    guess = to_file(value)
    candidates = [guess]
    up = down = guess
    for _ in range(4):
        up, down = math.nextafter(up, math.inf), math.nextafter(down, -math.inf)
        candidates += [up, down]
    for candidate in candidates:
        if from_file(candidate) == value:
            return candidate
    return guess


def _deg(angle_rad: float) -> float:
    """Radians to degrees for writing (see :func:`_to_file_units`)."""
    return _to_file_units(float(angle_rad), math.degrees, math.radians)


def _mrad(angle_rad: float) -> float:
    """Radians to milliradians for writing (see :func:`_to_file_units`)."""
    return _to_file_units(float(angle_rad), lambda x: x * 1e3, lambda x: x / 1e3)


def _site_to_toml(site: Site) -> dict[str, Any]:
    """One ``[[radar]]`` table for ``site``, in contract units.

    The sigmas are always written (except those not known, NaN), so the file
    does not depend on the sensor model; ``estimate`` is written when it differs
    from the radar's default or when a model is named (whose own ``estimate``
    would otherwise apply); the refraction keys only when the radar's rays are
    refracted (so that a version-1 file is written as it was).
    """
    entry: dict[str, Any] = {
        "id": site.id,
        "lat_deg": _deg(site.lat_rad),
        "lon_deg": _deg(site.lon_rad),
        "alt_m": float(site.alt_m),
    }
    missing = site.missing_sigmas
    if "sigma_range_m" not in missing:
        entry["sigma_range_m"] = float(site.sigma_range_m)
    if "sigma_azimuth_mrad" not in missing:
        entry["sigma_azimuth_mrad"] = _mrad(site.sigma_azimuth_rad)
    if site.sigma_elevation_rad is not None and "sigma_elevation_mrad" not in missing:
        entry["sigma_elevation_mrad"] = _mrad(site.sigma_elevation_rad)
    if site.scan_period_s is not None:
        entry["scan_period_s"] = float(site.scan_period_s)
    if site.model is not None:
        entry["model"] = site.model
    default_estimate = replace(site, estimate=()).estimate
    if site.model is not None or tuple(site.estimate) != default_estimate:
        entry["estimate"] = list(site.estimate)
    if site.sac is not None and site.sic is not None:
        entry["sac"], entry["sic"] = int(site.sac), int(site.sic)
    if site.refraction != "none":
        entry["refraction"] = site.refraction
        entry["refractivity_n_s"] = float(site.refractivity_n_s)
        entry["refractivity_scale_height_m"] = float(site.refractivity_scale_height_m)
    return entry


def write_sites(
    sites: Mapping[str, Site], path: str | Path, *, plot_altitude: str = GEOMETRIC
) -> None:
    """Write ``sites.toml`` atomically; :func:`load_sites` reads it back.

    Parameters
    ----------
    sites : mapping of str to Site
        The sites, written in iteration order.
    path : str or Path
        Destination file.  Angles are written in degrees (positions) and
        milliradians (sigmas), chosen so that reading them back gives the same
        radians.
    plot_altitude : {"geometric", "pressure"}, optional
        Written as ``[dataset] plot_altitude`` when not the default, so that a
        version-1 file is written exactly as before (:func:`load_plot_altitude`).
    """
    if plot_altitude not in PLOT_ALTITUDE_CHOICES:
        raise ValueError(f"plot_altitude must be one of {', '.join(PLOT_ALTITUDE_CHOICES)}, "
                         f"got {plot_altitude!r}")
    document: dict[str, Any] = {}
    if plot_altitude != GEOMETRIC:
        document["dataset"] = {"plot_altitude": plot_altitude}
    document["radar"] = [_site_to_toml(site) for site in sites.values()]
    atomic_write_text(path, _SITES_HEADER + tomli_w.dumps(document))


_SITES_HEADER = "# Radar sites. Units are in the key names (deg, m, mrad, s).\n\n"


# --------------------------------------------------------------------------- tables


@dataclass
class _Table:
    """A table as read from disk, before validation.

    Attributes
    ----------
    path : Path
        The file.
    frame : pandas.DataFrame
        Its rows (blank CSV lines removed), with a fresh ``RangeIndex``.
    rows : ndarray of int
        The 1-based data-row number of each frame row, as reported to users.
    """

    path: Path
    frame: pd.DataFrame
    rows: NDArray[np.int64]

    def error(self, message: str, *, pos: int | None = None, column: str | None = None
              ) -> DatasetError:
        """A :class:`DatasetError` for frame row ``pos`` (0-based) and ``column``."""
        row = None if pos is None else int(self.rows[pos])
        if row is not None and self.path.suffix == ".csv":
            message = f"{message} (line {row + 1})"
        return DatasetError(message, path=self.path, row=row, field=column)


class _FirstProblem:
    """Collects bad rows of several checks and keeps the earliest one.

    On a tie (two problems in the same row) the check made first wins.
    """

    def __init__(self, table: _Table) -> None:
        self._table = table
        self._first: tuple[int, str, str] | None = None

    def flag(self, bad: NDArray[np.bool_], column: str, describe: Callable[[int], str]) -> None:
        """Record the first row where ``bad`` holds; ``describe(pos)`` makes its message."""
        hits = np.flatnonzero(np.asarray(bad, dtype=bool))
        if hits.size and (self._first is None or hits[0] < self._first[0]):
            pos = int(hits[0])
            self._first = (pos, column, describe(pos))

    def raise_first(self) -> None:
        """Raise the earliest recorded problem, if any."""
        if self._first is not None:
            pos, column, message = self._first
            raise self._table.error(message, pos=pos, column=column)


def _find_table(folder: Path, stem: str) -> Path | None:
    """``folder/stem.csv`` or ``folder/stem.parquet``, ``None`` if neither; an error if both."""
    candidates = [folder / f"{stem}.{fmt}" for fmt in TABLE_FORMATS]
    found = [path for path in candidates if path.is_file()]
    if len(found) > 1:
        raise DatasetError(
            f"both {stem}.csv and {stem}.parquet exist; keep only one", path=folder, field=stem
        )
    return found[0] if found else None


def _blank_rows(frame: pd.DataFrame) -> NDArray[np.bool_]:
    """Rows in which every cell is empty (blank CSV lines)."""
    blank = np.ones(len(frame), dtype=bool)
    for column in frame.columns:
        values = frame[column]
        empty = values.isna()
        if not pd.api.types.is_numeric_dtype(values):
            empty |= values.astype("string").str.strip().eq("").fillna(True)
        blank &= empty.to_numpy(dtype=bool)
    return blank


def _csv_parser_error(path: Path, exc: pd.errors.ParserError) -> DatasetError:
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


def _read_csv(path: Path) -> tuple[pd.DataFrame, NDArray[np.int64]]:
    """Read a CSV table: text columns as text, empty cells of the others as NaN."""
    try:
        header = pd.read_csv(path, nrows=0, encoding="utf-8-sig").columns
        frame = pd.read_csv(
            path,
            encoding="utf-8-sig",
            dtype={column: str for column in _TEXT_COLUMNS if column in header},
            keep_default_na=False,
            na_values={c: list(_MISSING_TEXT) for c in header if c not in _TEXT_COLUMNS},
            skip_blank_lines=False,
            index_col=False,
        )
    except pd.errors.EmptyDataError:
        raise DatasetError("the file is empty (no header line)", path=path) from None
    except pd.errors.ParserError as exc:
        raise _csv_parser_error(path, exc) from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DatasetError(f"cannot read CSV: {exc}", path=path) from None
    keep = ~_blank_rows(frame)
    rows = np.arange(1, len(frame) + 1)[keep]
    return frame.loc[keep].reset_index(drop=True), rows


def _read_parquet(path: Path) -> tuple[pd.DataFrame, NDArray[np.int64]]:
    """Read a Parquet table."""
    try:
        frame = pd.read_parquet(path)
    except (OSError, ValueError, ImportError) as exc:
        raise DatasetError(f"cannot read Parquet: {exc}", path=path) from None
    return frame.reset_index(drop=True), np.arange(1, len(frame) + 1)


def _read_table(path: Path, required: tuple[str, ...]) -> _Table:
    """Read a CSV or Parquet table and check its columns and that it has rows."""
    reader = _read_csv if path.suffix == ".csv" else _read_parquet
    frame, rows = reader(path)
    table = _Table(path, frame, rows)
    for column in required:
        if column not in frame.columns:
            found = ", ".join(map(str, frame.columns)) or "none"
            raise table.error(f"missing required column (columns found: {found})", column=column)
    if frame.empty:
        raise table.error("the table has no data rows")
    return table


def _numeric(table: _Table, problems: _FirstProblem, column: str) -> NDArray[np.float64]:
    """A numeric column as floats (NaN where empty); flags cells that are not numbers."""
    values = table.frame[column]
    if pd.api.types.is_bool_dtype(values):
        problems.flag(np.ones(len(values), dtype=bool), column,
                      lambda pos: f"{values.iloc[pos]!r} is not a number")
        return np.full(len(values), np.nan)
    if pd.api.types.is_numeric_dtype(values):
        return values.to_numpy(dtype=float, na_value=np.nan)
    text = values.astype("string").str.strip()
    missing = (text.isna() | text.isin(_MISSING_TEXT)).to_numpy(dtype=bool)
    parsed = pd.to_numeric(text.mask(missing), errors="coerce")
    parsed = parsed.to_numpy(dtype=float, na_value=np.nan)
    problems.flag(np.isnan(parsed) & ~missing, column,
                  lambda pos: f"{values.iloc[pos]!r} is not a number")
    return parsed


def _text(table: _Table, column: str, *, lower: bool = False) -> pd.Series:
    """A text column without surrounding blanks, ``""`` where missing."""
    text = table.frame[column].astype("string").fillna("").str.strip()
    if lower:
        text = text.str.lower()
    return text.astype(str)


def _flag_not_finite(
    problems: _FirstProblem, values: NDArray[np.float64], column: str, *, required: bool
) -> None:
    """Flag infinite values, and missing ones when ``required``."""
    bad = np.isinf(values) | (np.isnan(values) if required else False)
    problems.flag(bad, column, lambda pos: "missing value" if np.isnan(values[pos])
                  else f"{values[pos]} is not finite")


def _flag_outside(
    problems: _FirstProblem,
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


def _assemble(table: _Table, columns: dict[str, Any]) -> pd.DataFrame:
    """The normalised columns, followed by the table's extra columns unchanged."""
    out = pd.DataFrame(columns, index=pd.RangeIndex(len(table.frame)))
    for column in table.frame.columns:
        if column not in out.columns:
            out[column] = table.frame[column]
    return out


# --------------------------------------------------------------------------- plots


def _load_plots(path: Path, sites: Mapping[str, Site]) -> pd.DataFrame:
    """Read, validate and normalise the plots table (see the module docstring)."""
    table = _read_table(path, PLOT_COLUMNS)
    problems = _FirstProblem(table)
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
    problems.raise_first()
    return _assemble(table, {
        "radar_id": radar_id,
        "time_s": time_s,
        "range_m": range_m,
        "azimuth_deg": azimuth_deg,
        "elevation_deg": elevation_deg,
        "target_id": target_id,
        "altitude_m": altitude_m,
    })


# --------------------------------------------------------------------------- ADS-B


def _adsb_nacp(table: _Table, problems: _FirstProblem) -> NDArray[np.float64] | None:
    """The ``nacp`` column as floats (NaN where empty), or ``None`` when absent."""
    if "nacp" not in table.frame.columns:
        return None
    nacp = _numeric(table, problems, "nacp")
    given = ~np.isnan(nacp)
    invalid = given & ((nacp != np.round(nacp)) | (nacp < 0) | (nacp > 11))
    problems.flag(invalid, "nacp", lambda pos: f"{nacp[pos]} is not an integer in 0..11")
    return nacp


def _adsb_sigma(
    table: _Table, problems: _FirstProblem, nacp: NDArray[np.float64] | None
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


def _load_adsb(path: Path) -> pd.DataFrame:
    """Read, validate and normalise the ADS-B table (see the module docstring)."""
    table = _read_table(path, ADSB_COLUMNS)
    problems = _FirstProblem(table)
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
    _flag_not_finite(problems, alt_m, "alt_m", required=True)
    nacp = _adsb_nacp(table, problems)
    sigma_m = _adsb_sigma(table, problems, nacp)
    baro_alt_m = None
    if "baro_alt_m" in table.frame.columns:
        baro_alt_m = _numeric(table, problems, "baro_alt_m")
        _flag_not_finite(problems, baro_alt_m, "baro_alt_m", required=False)
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
    return _assemble(table, columns)


# --------------------------------------------------------------------------- dataset


def load_dataset(folder: str | Path, *, clean: bool = True) -> Dataset:
    """Read and validate a dataset folder.

    Parameters
    ----------
    folder : str or Path
        Folder with ``sites.toml``, ``plots.csv`` or ``plots.parquet`` and
        optionally ``adsb.csv`` or ``adsb.parquet`` (not both formats of one
        table).
    clean : bool, optional
        After validation, remove bad data (duplicates, stale and impossible
        ADS-B reports, mislabelled aircraft, see :mod:`graphcal.data.cleaning`) from
        the tables in memory; the files are not touched.  The report is kept in
        :attr:`Dataset.cleaning`.

    Returns
    -------
    Dataset
        Validated and normalised (see the module docstring); ``adsb`` is
        ``None`` when the folder has no ADS-B table.  When cleaned, the tables
        have a fresh ``RangeIndex`` (row labels no longer follow the file).

    Raises
    ------
    DatasetError
        For the first problem found, naming the file, the row and the field.
    """
    folder = Path(folder)
    if not folder.exists():
        raise DatasetError("dataset folder not found", path=folder)
    if not folder.is_dir():
        raise DatasetError("not a folder", path=folder)
    sites = load_sites(folder / SITES_FILE)
    plots_path = _find_table(folder, "plots")
    if plots_path is None:
        raise DatasetError("missing plots.csv or plots.parquet", path=folder, field="plots")
    plots = _load_plots(plots_path, sites)
    sites = _three_d_without_sigmas(sites, plots, folder / SITES_FILE)
    adsb_path = _find_table(folder, "adsb")
    adsb = None if adsb_path is None else _load_adsb(adsb_path)
    plot_altitude = load_plot_altitude(folder / SITES_FILE)
    dataset = Dataset(sites=sites, plots=plots, adsb=adsb, path=folder,
                      plot_altitude=plot_altitude)
    if clean:
        from graphcal.data.cleaning import clean_dataset

        dataset, _ = clean_dataset(dataset)
    return dataset


def _three_d_without_sigmas(
    sites: dict[str, Site], plots: pd.DataFrame, sites_path: Path
) -> dict[str, Site]:
    """Sites whose table gives no sigma at all, made 3-D when all their plots have elevation.

    ``sites.toml`` says a radar is 3-D by giving ``sigma_elevation_mrad``; a
    table without any sigma cannot say it, so the plots do.  The elevation
    sigma is then NaN (to be estimated); ``estimate`` gains ``elevation_bias``
    when the table left it to the default.
    """
    updated = dict(sites)
    for radar_id, site in sites.items():
        if site.missing_sigmas != ("sigma_range_m", "sigma_azimuth_mrad") or site.model:
            continue
        elevation = plots.loc[plots["radar_id"] == radar_id, "elevation_deg"].to_numpy()
        if len(elevation) and np.isfinite(elevation).all():
            default_2d = replace(site, estimate=()).estimate
            estimate = () if site.estimate == default_2d else site.estimate
            updated[radar_id] = replace(site, sigma_elevation_rad=math.nan, estimate=estimate)
        elif "elevation_bias" in site.estimate:
            raise DatasetError(
                f"radar {radar_id!r}: elevation_bias needs a 3-D radar, and not all of its "
                "plots carry an elevation", path=sites_path, field="estimate")
    return updated


def _is_empty_folder(path: Path) -> bool:
    """True for an existing folder without entries."""
    return path.is_dir() and not path.is_symlink() and not any(path.iterdir())


def _check_target(target: Path, overwrite: bool) -> None:
    """Refuse a target that is a file, or a non-empty folder without ``overwrite``."""
    if not target.exists() and not target.is_symlink():
        return
    if not target.is_dir() or target.is_symlink():
        raise DatasetError("exists and is not a folder", path=target)
    if not overwrite and not _is_empty_folder(target):
        raise DatasetError("folder exists and is not empty (pass overwrite=True)", path=target)


def _move_into_place(staging: Path, target: Path, overwrite: bool) -> None:
    """Rename the complete ``staging`` folder to ``target``.

    An existing ``target`` is first renamed to a hidden backup, which is
    deleted once the new folder is in place (and restored if that fails).
    """
    _check_target(target, overwrite)
    if _is_empty_folder(target):
        target.rmdir()
    if not target.exists():
        os.rename(staging, target)
        return
    backup = target.with_name(f".{target.name}.old-{uuid.uuid4().hex[:12]}")
    os.rename(target, backup)
    try:
        os.rename(staging, target)
    except BaseException:
        os.rename(backup, target)
        raise
    shutil.rmtree(backup, ignore_errors=True)


def write_dataset(
    dataset: Dataset, folder: str | Path, *, fmt: str = "csv", overwrite: bool = False
) -> Path:
    """Write a dataset folder atomically.

    Everything (``sites.toml``, ``plots.<fmt>``, ``adsb.<fmt>`` when the dataset
    has ADS-B) is written into a temporary sibling folder, which is then renamed
    to ``folder``.  If writing fails, nothing is left behind and an existing
    ``folder`` is untouched.  Callers add further files (``truth.json``) with
    :func:`atomic_write_text`.

    Parameters
    ----------
    dataset : Dataset
        The dataset; its tables are written as they are.
    folder : str or Path
        Destination folder.  Its parent is created when missing.
    fmt : {"csv", "parquet"}, optional
        Table format.
    overwrite : bool, optional
        Replace an existing non-empty ``folder`` (atomically: the old folder is
        renamed away, the new one renamed into place, then the old one deleted).

    Returns
    -------
    Path
        ``folder``.

    Raises
    ------
    ValueError
        If ``fmt`` is not a known format.
    DatasetError
        If ``folder`` exists and is a file, or is a non-empty folder and
        ``overwrite`` is false.
    """
    if fmt not in TABLE_FORMATS:
        raise ValueError(f"fmt must be one of {', '.join(TABLE_FORMATS)}, got {fmt!r}")
    target = Path(folder)
    _check_target(target, overwrite)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.tmp-", dir=target.parent))
    try:
        os.chmod(staging, 0o755)
        write_sites(dataset.sites, staging / SITES_FILE, plot_altitude=dataset.plot_altitude)
        write_table(dataset.plots, staging / f"plots.{fmt}")
        if dataset.adsb is not None:
            write_table(dataset.adsb, staging / f"adsb.{fmt}")
        _move_into_place(staging, target, overwrite)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return target
