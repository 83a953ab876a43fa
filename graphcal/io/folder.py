"""Dataset folders: reading and writing sites, plots and ADS-B reports (CONTRACT.md).

A dataset is a folder with ``sites.toml``, ``plots.csv|parquet`` and optionally
``adsb.csv|parquet``; graphcal also reads a table given as a folder of parts,
``plots/`` or ``adsb/`` holding ``*.csv`` or ``*.parquet`` files taken in name order
(:mod:`graphcal.io.table_files`).  Tables keep the contract's column names and units
(degrees, metres, seconds); :class:`Site` holds SI values (radians).

Reading (:func:`load_dataset`, :func:`load_sites`) validates everything and
raises one :class:`~graphcal.core.errors.DatasetError` for the first problem found,
naming the file, the row and the field:

* In a table, "row N" is the N-th data row as a user counts it in the file.
  In a CSV file the header is line 1 and row N is line N + 1 (the message
  repeats the line number); blank lines are skipped but keep this numbering,
  so without blank lines row N is exactly the N-th data row.  In a Parquet
  file row N is the N-th row.  When several rows are bad, the first one in the
  file is reported.  In a table of parts, the file is the part.
* In ``sites.toml``, "row N" is the N-th ``[[radar]]`` table.

Normalisation of the tables read (:mod:`graphcal.io.table_checks`):

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
* ``mode_3a`` (contract v3, optional, plots and ADS-B): the Mode 3/A code as 4
  octal digits ("7000", "0413"), read as text so that leading zeros stay; ``""``
  where a row has none.  Any other value is an error (a numeric column too: its
  leading zeros are lost).
* Plots ``track_number`` (contract v3, optional): the radar's own track number, a
  nullable integer (``Int64``) that must be a non-negative integer.
* The v3 columns are not added when a file lacks them: a table without them
  reads as in versions 1 and 2.
* ``sites.toml`` may hold a top-level ``[dataset]`` table (contract v2) whose
  ``plot_altitude`` (``"geometric"``, the default, or ``"pressure"``) says what the
  plots' ``altitude_m`` is; it becomes :attr:`Dataset.plot_altitude`
  (:func:`load_plot_altitude`).  Its ``epoch_utc`` (extension v1.6, optional) is the
  UTC time of 0 s on the tables' time base (:mod:`graphcal.data.epoch`); it becomes
  :attr:`Dataset.epoch_utc` (:func:`load_epoch_utc`).
* Columns beyond the contract's are kept unchanged after the contract columns.

:func:`load_dataset` holds the whole recording in memory;
:func:`graphcal.io.window_reader.iter_windows` reads the same folder window by window.

Reading never writes anything.  Writing (:func:`write_dataset`,
:class:`DatasetWriter`, :func:`write_sites`, :func:`atomic_write_text`) is atomic:
a reader sees either the old content or the complete new one.
"""


from __future__ import annotations

import math
import os
import shutil
import tempfile
import tomllib
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from datetime import datetime
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pandas as pd
import tomli_w

from graphcal.core.atomic import atomic_write_text, rename_no_replace, write_table
from graphcal.core.errors import (
    DatasetError,
    OutputExistsError,
    SensorModelError,
    fill_errno,
    os_error_cause,
)
from graphcal.core.refraction import DEFAULT_N_S, DEFAULT_SCALE_HEIGHT_M, Atmosphere
from graphcal.data.bias import ESTIMATE_NAMES
from graphcal.data.dataset import (
    ADSB_COLUMNS,
    PLOT_COLUMNS,
    REFRACTION_MODELS,
    REFRACTIVITY_N_S_RANGE,
    SITE_KEYS,
    SITES_FILE,
    TABLE_FORMATS,
    Dataset,
    Site,
)
from graphcal.data.epoch import format_epoch_utc, parse_epoch_utc
from graphcal.data.height import GEOMETRIC, PLOT_ALTITUDE_CHOICES
from graphcal.data.plausibility import check_tables, raise_if_implausible
from graphcal.data.sensor_models import SensorModel, load_sensor_model
from graphcal.io.table_checks import validate_adsb, validate_plots
from graphcal.io.table_files import find_table_files, read_rows
from graphcal.io.table_writer import TableWriter

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
    except IsADirectoryError:
        raise DatasetError("is a folder, not a TOML file", path=path) from None
    except UnicodeDecodeError:
        raise DatasetError("cannot read TOML: not UTF-8 text (a binary file?)",
                           path=path) from None
    except OSError as exc:
        raise DatasetError(os_error_cause(exc), path=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise DatasetError(f"cannot read TOML: {exc}", path=path) from None


#: Keys of the top-level ``[dataset]`` table of ``sites.toml`` (contract v2, v1.6).
DATASET_KEYS: tuple[str, ...] = ("plot_altitude", "epoch_utc")


@dataclass(frozen=True)
class DatasetSettings:
    """The top-level ``[dataset]`` table of ``sites.toml``, validated.

    Attributes
    ----------
    plot_altitude : {"geometric", "pressure"}
        What the plots' ``altitude_m`` is (:mod:`graphcal.data.height`).
    epoch_utc : datetime or None
        The UTC time of 0 s on the tables' time base (:mod:`graphcal.data.epoch`).
    """

    plot_altitude: str = GEOMETRIC
    epoch_utc: datetime | None = None


def load_dataset_settings(path: str | Path) -> DatasetSettings:
    """``sites.toml``'s ``[dataset]`` table (the defaults without one).

    Parameters
    ----------
    path : str or Path
        The ``sites.toml`` file.

    Raises
    ------
    DatasetError
        If ``[dataset]`` is not a table, has an unknown key, ``plot_altitude`` is
        not one of the choices, or ``epoch_utc`` is not an ISO 8601 date and time
        with a UTC designator; the message names the file, the table and the field.
    """
    path = Path(path)
    table = _read_toml(path).get("dataset")
    if table is None:
        return DatasetSettings()
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
    epoch = None
    if "epoch_utc" in table:
        try:
            epoch = parse_epoch_utc(table["epoch_utc"])
        except ValueError as exc:
            raise DatasetError(f"[dataset]: epoch_utc {exc}", path=path,
                               field="dataset.epoch_utc") from None
    return DatasetSettings(value, epoch)


def load_plot_altitude(path: str | Path) -> str:
    """What the plots' ``altitude_m`` is, from ``sites.toml``'s ``[dataset]`` table.

    ``"geometric"`` (a height above the ellipsoid; the default, also without a
    ``[dataset]`` table) or ``"pressure"`` (a pressure altitude, see
    :mod:`graphcal.data.height`).  The whole table is validated
    (:func:`load_dataset_settings`, whose errors it raises).
    """
    return load_dataset_settings(path).plot_altitude


def load_epoch_utc(path: str | Path) -> datetime | None:
    """The UTC time of 0 s on the dataset's time base, from ``sites.toml``'s
    ``[dataset] epoch_utc`` (``None`` without it); validated as
    :func:`load_dataset_settings` does."""
    return load_dataset_settings(path).epoch_utc


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
    sites: Mapping[str, Site], path: str | Path, *, plot_altitude: str = GEOMETRIC,
    epoch_utc: datetime | None = None,
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
    epoch_utc : datetime, optional
        Written as ``[dataset] epoch_utc = "2021-10-07T00:00:00Z"`` when given
        (:func:`load_epoch_utc`); must be an aware UTC time.
    """
    if plot_altitude not in PLOT_ALTITUDE_CHOICES:
        raise ValueError(f"plot_altitude must be one of {', '.join(PLOT_ALTITUDE_CHOICES)}, "
                         f"got {plot_altitude!r}")
    document: dict[str, Any] = {}
    settings: dict[str, Any] = {}
    if plot_altitude != GEOMETRIC:
        settings["plot_altitude"] = plot_altitude
    if epoch_utc is not None:
        settings["epoch_utc"] = format_epoch_utc(parse_epoch_utc(epoch_utc))
    if settings:
        document["dataset"] = settings
    document["radar"] = [_site_to_toml(site) for site in sites.values()]
    atomic_write_text(path, _SITES_HEADER + tomli_w.dumps(document))


_SITES_HEADER = "# Radar sites. Units are in the key names (deg, m, mrad, s).\n\n"



# --------------------------------------------------------------------------- tables


def _load_table(files: list[Path], required: tuple[str, ...],
                validate: Callable[[Any], pd.DataFrame]) -> pd.DataFrame:
    """Read and validate every file of a table (one file or its parts), in order.

    Raises
    ------
    DatasetError
        For the first problem (:mod:`graphcal.io.table_checks`), or when the table
        has no data row (naming the file, or the parts folder).
    """
    frames = [validate(rows) for path in files for rows in read_rows(path, required)]
    frames = [frame for frame in frames if len(frame)] or frames[:1]
    if not frames or not len(frames[0]):
        where = files[0] if len(files) == 1 else files[0].parent
        raise DatasetError("the table has no data rows", path=where)
    if len(frames) == 1:
        return frames[0]
    return pd.concat(frames, ignore_index=True)


def check_folder(folder: Path) -> None:
    """Raise a :class:`DatasetError` unless ``folder`` is an existing folder."""
    if not folder.exists():
        raise DatasetError("dataset folder not found", path=folder)
    if not folder.is_dir():
        raise DatasetError("not a folder", path=folder)


def dataset_tables(folder: Path) -> tuple[list[Path], list[Path] | None]:
    """The files of a dataset folder's plots table and of its ADS-B table (or ``None``).

    Raises
    ------
    DatasetError
        If the folder is missing or not a folder, has no plots table, or has a
        table in two forms (:func:`graphcal.io.table_files.find_table_files`).
    """
    check_folder(folder)
    plots = find_table_files(folder, "plots")
    if plots is None:
        raise DatasetError("missing plots.csv or plots.parquet", path=folder, field="plots")
    return plots, find_table_files(folder, "adsb")


# --------------------------------------------------------------------------- dataset


def load_dataset(folder: str | Path, *, clean: bool = True, force: bool = False) -> Dataset:
    """Read and validate a dataset folder.

    Parameters
    ----------
    folder : str or Path
        Folder with ``sites.toml``, ``plots.csv`` or ``plots.parquet`` (or a
        ``plots/`` folder of parts) and optionally ``adsb.csv`` or
        ``adsb.parquet`` (or ``adsb/``); one form per table.
    clean : bool, optional
        After validation, remove bad data (duplicates, stale and impossible
        ADS-B reports, mislabelled aircraft, see :mod:`graphcal.data.cleaning`) from
        the tables in memory; the files are not touched.  The report is kept in
        :attr:`Dataset.cleaning`.
    force : bool, optional
        Skip the unit and frame heuristics (:mod:`graphcal.data.plausibility`:
        azimuths in radians, ranges in km, heights in feet, swapped latitude and
        longitude, an implausible antenna height, ADS-B on another time base),
        which otherwise run on the validated tables, before cleaning.

    Returns
    -------
    Dataset
        Validated and normalised (see the module docstring); ``adsb`` is
        ``None`` when the folder has no ADS-B table.  The parts of a table are
        concatenated in name order.  When cleaned, the tables have a fresh
        ``RangeIndex`` (row labels no longer follow the file).

    Raises
    ------
    DatasetError
        For the first problem found, naming the file, the row and the field.
    ImplausibleDataError
        (a :class:`DatasetError`) Unless ``force``: the tables look like a unit or
        frame mistake; the message names the file, the field and the likely mistake.
    """
    folder = Path(folder)
    check_folder(folder)
    sites = load_sites(folder / SITES_FILE)
    plot_files, adsb_files = dataset_tables(folder)
    plots = _load_table(plot_files, PLOT_COLUMNS, lambda rows: validate_plots(rows, sites))
    if needs_elevation_scan(sites):
        sites = three_d_without_sigmas(sites, elevation_complete(plots), folder / SITES_FILE)
    adsb = None if adsb_files is None else _load_table(adsb_files, ADSB_COLUMNS, validate_adsb)
    settings = load_dataset_settings(folder / SITES_FILE)
    if not force:
        raise_if_implausible(check_tables(sites, plots, adsb),
                             table_paths(folder, plot_files, adsb_files))
    dataset = Dataset(sites=sites, plots=plots, adsb=adsb, path=folder,
                      plot_altitude=settings.plot_altitude, epoch_utc=settings.epoch_utc)
    if clean:
        from graphcal.data.cleaning import clean_dataset

        dataset, _ = clean_dataset(dataset)
    return dataset


def table_paths(folder: Path, plot_files: list[Path],
                adsb_files: list[Path] | None) -> dict[str, Path]:
    """The path naming each table in messages: its file, or its folder of parts."""
    def where(files: list[Path]) -> Path:
        return files[0] if len(files) == 1 else files[0].parent

    paths = {"sites": folder / SITES_FILE, "plots": where(plot_files)}
    if adsb_files:
        paths["adsb"] = where(adsb_files)
    return paths


def elevation_complete(plots: pd.DataFrame) -> dict[str, bool]:
    """Per radar with plots: whether every one of its plots carries a finite elevation."""
    finite = np.isfinite(plots["elevation_deg"].to_numpy(dtype=float))
    complete = pd.Series(finite).groupby(plots["radar_id"].to_numpy()).all()
    return {str(rid): bool(value) for rid, value in complete.items()}


def three_d_without_sigmas(
    sites: dict[str, Site], complete: Mapping[str, bool], sites_path: Path
) -> dict[str, Site]:
    """Sites whose table gives no sigma at all, made 3-D when all their plots have elevation.

    ``sites.toml`` says a radar is 3-D by giving ``sigma_elevation_mrad``; a
    table without any sigma cannot say it, so the plots do.  The elevation
    sigma is then NaN (to be estimated); ``estimate`` gains ``elevation_bias``
    when the table left it to the default.

    Parameters
    ----------
    sites : dict of str to Site
        As read from ``sites.toml``.
    complete : mapping of str to bool
        Per radar that has plots, whether all of them carry an elevation
        (:func:`elevation_complete`); a radar without plots is absent.
    sites_path : Path
        ``sites.toml``, for error messages.

    Raises
    ------
    DatasetError
        If such a radar's ``estimate`` names ``elevation_bias`` but not all of its
        plots carry an elevation.
    """
    updated = dict(sites)
    for radar_id, site in sites.items():
        if site.missing_sigmas != ("sigma_range_m", "sigma_azimuth_mrad") or site.model:
            continue
        if complete.get(radar_id, False):
            default_2d = replace(site, estimate=()).estimate
            estimate = () if site.estimate == default_2d else site.estimate
            updated[radar_id] = replace(site, sigma_elevation_rad=math.nan, estimate=estimate)
        elif "elevation_bias" in site.estimate:
            raise DatasetError(
                f"radar {radar_id!r}: elevation_bias needs a 3-D radar, and not all of its "
                "plots carry an elevation", path=sites_path, field="estimate")
    return updated


def needs_elevation_scan(sites: Mapping[str, Site]) -> bool:
    """Whether :func:`three_d_without_sigmas` may change a site (a table gives no sigma)."""
    return any(site.missing_sigmas == ("sigma_range_m", "sigma_azimuth_mrad")
               and not site.model for site in sites.values())


# --------------------------------------------------------------------------- writing


def _is_empty_folder(path: Path) -> bool:
    """True for an existing folder without entries."""
    return path.is_dir() and not path.is_symlink() and not any(path.iterdir())


def _check_target(target: Path, overwrite: bool) -> None:
    """Refuse a target that is a file, a non-empty folder without ``overwrite``, or (with
    ``overwrite``) a non-empty folder without ``sites.toml``: not a dataset, files of its
    user.  (The command line is stricter: it replaces only a folder that holds nothing
    but dataset files.)"""
    if not target.exists() and not target.is_symlink():
        return
    if not target.is_dir() or target.is_symlink():
        raise DatasetError("exists and is not a folder", path=target)
    if _is_empty_folder(target):
        return
    if not overwrite:
        raise DatasetError("folder exists and is not empty (pass overwrite=True)", path=target)
    if not (target / SITES_FILE).is_file():
        raise DatasetError(f"folder is not a graphcal dataset (no {SITES_FILE}); overwrite "
                           "replaces only a dataset folder", path=target)


def _name_write_error(exc: OSError, staging: Path, target: Path,
                      current: str | None = None) -> None:
    """Give an error of writing into ``staging`` the destination's name (in place):
    ``target/plots.csv``, not the hidden temporary folder."""
    if not fill_errno(exc):  # not an error of the system: its message stands
        return
    name = exc.filename
    if isinstance(name, str | os.PathLike):
        text = os.fspath(name)
        inside = os.fspath(staging)
        if text == inside or text.startswith(inside + os.sep):
            base = os.path.relpath(text, inside).split(os.sep)[0]
            base = base if base != "." else ""
            if base.startswith("."):  # a temporary file: name its table
                base = current or ""
            exc.filename = str(target / base) if base else str(target)
            exc.filename2 = None
    elif name is None:
        exc.filename = str(target / current) if current else str(target)


def _move_into_place(staging: Path, target: Path, overwrite: bool) -> None:
    """Rename the complete ``staging`` folder to ``target``.

    An existing ``target`` is first renamed to a hidden backup, which is
    deleted once the new folder is in place (and restored if that fails).
    Without ``overwrite`` a ``target`` that another process wrote meanwhile is never
    replaced (:class:`OutputExistsError`).
    """
    if not overwrite and (target.is_symlink()
                          or (target.exists() and not _is_empty_folder(target))):
        raise OutputExistsError(target)
    _check_target(target, overwrite)
    if _is_empty_folder(target):
        target.rmdir()
    if not target.exists():
        if overwrite:
            os.rename(staging, target)
            return
        try:
            rename_no_replace(staging, target)
        except FileExistsError as exc:
            raise OutputExistsError(target) from exc
        return
    backup = target.with_name(f".{target.name}.old-{uuid.uuid4().hex[:12]}")
    os.rename(target, backup)
    try:
        os.rename(staging, target)
    except BaseException:
        os.rename(backup, target)
        raise
    shutil.rmtree(backup, ignore_errors=True)


class DatasetWriter:
    """Write a dataset folder table piece by table piece, atomically.

    Everything (``sites.toml`` at once, then the plots and ADS-B tables piece by
    piece through :class:`~graphcal.io.table_writer.TableWriter`, then any further
    file such as ``truth.json``) goes into a temporary sibling folder, which
    :meth:`commit` renames to ``folder``.  If writing fails, or :meth:`abort` is
    called, nothing is left behind and an existing ``folder`` is untouched.  Used
    as a context manager it commits on success and aborts on an exception.

    Parameters
    ----------
    sites : mapping of str to Site
        The radars, written to ``sites.toml`` at once.
    folder : str or Path
        Destination folder; its parent is created when missing.
    fmt : {"csv", "parquet"}, optional
        Table format.
    overwrite : bool, optional
        Replace an existing non-empty ``folder`` (as :func:`write_dataset`).
    plot_altitude : {"geometric", "pressure"}, optional
        Written to ``sites.toml`` (:func:`write_sites`).
    epoch_utc : datetime, optional
        Written to ``sites.toml`` when given (:func:`write_sites`).
    row_group_rows : int, optional
        Largest Parquet row group [rows] (:class:`~graphcal.io.table_writer.TableWriter`).

    Raises
    ------
    ValueError
        If ``fmt`` is not a known format.
    DatasetError
        If ``folder`` exists and is a file, or is a non-empty folder and
        ``overwrite`` is false.
    """

    def __init__(self, sites: Mapping[str, Site], folder: str | Path, *, fmt: str = "csv",
                 overwrite: bool = False, plot_altitude: str = GEOMETRIC,
                 epoch_utc: datetime | None = None,
                 row_group_rows: int | None = None) -> None:
        if fmt not in TABLE_FORMATS:
            raise ValueError(f"fmt must be one of {', '.join(TABLE_FORMATS)}, got {fmt!r}")
        self.folder = Path(folder)
        self.fmt = fmt
        self.overwrite = overwrite
        _check_target(self.folder, overwrite)
        self.folder.parent.mkdir(parents=True, exist_ok=True)
        self._staging = Path(tempfile.mkdtemp(prefix=f".{self.folder.name}.tmp-",
                                              dir=self.folder.parent))
        self._options = {} if row_group_rows is None else {"row_group_rows": row_group_rows}
        self._tables: dict[str, TableWriter] = {}
        try:
            os.chmod(self._staging, 0o755)
            write_sites(sites, self._staging / SITES_FILE, plot_altitude=plot_altitude,
                        epoch_utc=epoch_utc)
        except BaseException as exc:
            self.abort()
            if isinstance(exc, OSError):
                _name_write_error(exc, self._staging, self.folder, SITES_FILE)
            raise

    def _table(self, stem: str) -> TableWriter:
        if stem not in self._tables:
            self._tables[stem] = TableWriter(self._staging / f"{stem}.{self.fmt}",
                                             **self._options)
        return self._tables[stem]

    def _writing(self, name: str, write: Callable[[], None]) -> None:
        """``write()``, an operating-system error named by the destination's file."""
        try:
            write()
        except OSError as exc:
            _name_write_error(exc, self._staging, self.folder, name)
            raise

    def write_plots(self, frame: pd.DataFrame) -> None:
        """Append rows to the plots table (the first piece sets its columns)."""
        self._writing(f"plots.{self.fmt}", lambda: self._table("plots").write(frame))

    def write_adsb(self, frame: pd.DataFrame) -> None:
        """Append rows to the ADS-B table; without any call there is no ADS-B table."""
        self._writing(f"adsb.{self.fmt}", lambda: self._table("adsb").write(frame))

    def write_text(self, name: str, text: str) -> None:
        """Add a text file (e.g. ``truth.json``) to the folder."""
        self._writing(name, lambda: atomic_write_text(self._staging / name, text))

    def rows_written(self, stem: str) -> int:
        """Rows written so far to table ``stem`` (``"plots"`` or ``"adsb"``)."""
        return self._tables[stem].n_rows if stem in self._tables else 0

    def commit(self) -> Path:
        """Finish every table and rename the folder into place; returns the folder."""
        current: str | None = None
        try:
            for stem, writer in self._tables.items():
                current = f"{stem}.{self.fmt}"
                writer.close()
            current = None
            _move_into_place(self._staging, self.folder, self.overwrite)
        except BaseException as exc:
            self.abort()
            if isinstance(exc, OSError):
                _name_write_error(exc, self._staging, self.folder, current)
            raise
        return self.folder

    def abort(self) -> None:
        """Drop everything written; an existing folder is left as it was."""
        for writer in self._tables.values():
            writer.abort()
        shutil.rmtree(self._staging, ignore_errors=True)

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if kind is None:
            self.commit()
        else:
            self.abort()


def write_dataset(
    dataset: Dataset, folder: str | Path, *, fmt: str = "csv", overwrite: bool = False,
    files: Mapping[str, str] | None = None,
) -> Path:
    """Write a dataset folder atomically.

    Everything (``sites.toml``, ``plots.<fmt>``, ``adsb.<fmt>`` when the dataset
    has ADS-B) is written into a temporary sibling folder, which is then renamed
    to ``folder``.  If writing fails, nothing is left behind and an existing
    ``folder`` is untouched.  Further text files (``truth.json``) given in
    ``files`` go into the temporary folder too, so the folder never appears
    without them.  :class:`DatasetWriter` does the same piece by piece.

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
    files : mapping of str to str, optional
        Further files of the folder: name -> text (UTF-8), e.g. ``{"truth.json": ...}``.

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
    current: str | None = SITES_FILE
    try:
        os.chmod(staging, 0o755)
        write_sites(dataset.sites, staging / SITES_FILE, plot_altitude=dataset.plot_altitude,
                    epoch_utc=dataset.epoch_utc)
        current = f"plots.{fmt}"
        write_table(dataset.plots, staging / current)
        if dataset.adsb is not None:
            current = f"adsb.{fmt}"
            write_table(dataset.adsb, staging / current)
        for name, text in (files or {}).items():
            current = name
            atomic_write_text(staging / name, text)
        current = None
        _move_into_place(staging, target, overwrite)
    except BaseException as exc:
        shutil.rmtree(staging, ignore_errors=True)
        if isinstance(exc, OSError):
            _name_write_error(exc, staging, target, current)
        raise
    return target
