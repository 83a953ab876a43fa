"""Sensor models: typical accuracies of radar types and the ADS-B quality table.

A sensor model is a TOML file in the models folder, found in this order
(:func:`models_dir`):

1. the folder named by the environment variable ``GRAPHCAL_MODELS_DIR``, when set;
2. the package's own data, ``graphcal/models/`` read with :mod:`importlib.resources`:
   an installed (non-editable) package carries there a copy of the repository's
   ``models/`` made when the wheel is built (``setup.py``);
3. the ``models/`` folder at the top of the source tree (a checkout or an editable
   install), where the models are edited.

A radar model supplies defaults for the sites that name it in ``sites.toml``
(``model = "ssr-mode-s"``): random-error sigmas, scan period and which biases
exist.  File keys carry their units (``_m``, ``_s``, ``_deg``, ``_mrad``); the
:class:`SensorModel` holds SI values (radians), except :attr:`SensorModel.typical_bias`,
which keeps the contract's keys and units.

``adsb-nacp.toml`` is not a radar model: it is the table of the ADS-B
Navigation Accuracy Category for position (NACp) used by
:func:`adsb_sigma_from_nacp`.
"""

from __future__ import annotations

import atexit
import math
import os
import shutil
import tempfile
import tomllib
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from graphcal.core.errors import SensorModelError
from graphcal.data.bias import CONTRACT_KEYS, PARAMETER_NAMES

#: Environment variable that overrides the models folder.
MODELS_DIR_ENV = "GRAPHCAL_MODELS_DIR"
#: Name of the ADS-B NACp table file (without ``.toml``).
ADSB_NACP_TABLE = "adsb-nacp"
#: ``kind`` of a radar model file.
RADAR_KIND = "radar"
#: ``kind`` of the ADS-B NACp table file.
ADSB_NACP_KIND = "adsb-nacp"

_RADAR_REQUIRED_KEYS: tuple[str, ...] = (
    "kind",
    "description",
    "dimensions",
    "sigma_range_m",
    "sigma_azimuth_mrad",
    "scan_period_s",
    "detection_probability",
    "max_range_m",
    "min_elevation_deg",
    "estimate",
)
_RADAR_OPTIONAL_KEYS: tuple[str, ...] = ("sigma_elevation_mrad", "typical_bias")


@dataclass(frozen=True)
class SensorModel:
    """Typical performance of one type of radar.

    Attributes
    ----------
    name : str
        Model name: the file name without ``.toml``.
    kind : str
        Always ``"radar"``.
    description : str
        One-line human description.
    dimensions : int
        2 for a radar that measures range and azimuth, 3 when it also measures
        elevation.
    sigma_range_m : float
        1-sigma random range error [m].
    sigma_azimuth_rad : float
        1-sigma random azimuth error [rad].
    sigma_elevation_rad : float or None
        1-sigma random elevation error [rad]; ``None`` for a 2-D radar.
    scan_period_s : float
        Antenna rotation period [s].
    detection_probability : float
        Probability of a plot per scan of a target in coverage, in (0, 1].
    max_range_m : float
        Instrumented range [m].
    min_elevation_rad : float
        Lowest elevation of the coverage [rad].
    estimate : tuple of str
        Bias parameters (names from :data:`graphcal.data.bias.PARAMETER_NAMES`) this
        type of radar has and that are worth estimating.
    typical_bias : dict of str to float
        Typical magnitude (one standard deviation over a population of
        installations) of each bias, keyed and in units as in the result
        contract (``range_offset_m``, ``range_gain``, ``azimuth_bias_mrad``,
        ``elevation_bias_mrad``, ``time_offset_s``).  Meant for priors.
    """

    name: str
    kind: str
    description: str
    dimensions: int
    sigma_range_m: float
    sigma_azimuth_rad: float
    sigma_elevation_rad: float | None
    scan_period_s: float
    detection_probability: float
    max_range_m: float
    min_elevation_rad: float
    estimate: tuple[str, ...]
    typical_bias: dict[str, float] = field(default_factory=dict, hash=False)

    @property
    def is_3d(self) -> bool:
        """True when the radar measures elevation."""
        return self.dimensions == 3


#: The package that carries the sensor models as data once built, and their folder in it.
_DATA_PACKAGE = "graphcal"
_DATA_FOLDER = "models"
#: The ``models/`` folder at the top of the source tree (checkout, editable install).
_SOURCE_MODELS_DIR = Path(__file__).resolve().parents[2] / "models"


@lru_cache(maxsize=1)
def _packaged_models_dir() -> Path | None:
    """The package's own copy of the models (``graphcal/models/``), if it has one.

    A wheel carries the copy; a source tree does not (``None``).  A package
    imported from a zip file has no folder on disk: its model files are then
    copied once into a temporary folder, removed at exit.
    """
    try:
        folder = resources.files(_DATA_PACKAGE).joinpath(_DATA_FOLDER)
        if not folder.is_dir():
            return None
    except (ModuleNotFoundError, OSError):
        return None
    if isinstance(folder, Path):
        return folder
    return _materialise(folder)


def _materialise(folder: Traversable) -> Path:
    """A temporary on-disk copy of the ``*.toml`` files of a packaged folder."""
    target = Path(tempfile.mkdtemp(prefix="graphcal-models-"))
    atexit.register(shutil.rmtree, target, ignore_errors=True)
    for entry in folder.iterdir():
        if entry.is_file() and entry.name.endswith(".toml"):
            (target / entry.name).write_bytes(entry.read_bytes())
    return target


def models_dir() -> Path:
    """The folder holding the sensor model files.

    Returns
    -------
    Path
        ``$GRAPHCAL_MODELS_DIR`` when set (and not empty), else the package's own
        data (``graphcal/models/`` of an installed wheel), else the ``models/``
        folder at the top of the source tree.  The last is returned even when it
        does not exist; reading a model then fails with a message that names
        ``GRAPHCAL_MODELS_DIR``.
    """
    override = os.environ.get(MODELS_DIR_ENV)
    if override:
        return Path(override)
    packaged = _packaged_models_dir()
    if packaged is not None:
        return packaged
    return _SOURCE_MODELS_DIR


def _read_toml(path: Path) -> dict[str, Any]:
    """Parse one model file, turning every failure into :class:`SensorModelError`."""
    try:
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise SensorModelError("file not found", path=path) from None
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise SensorModelError(f"cannot read TOML: {exc}", path=path) from None


def _model_files() -> dict[str, Path]:
    """All ``*.toml`` files in the models folder, by name."""
    folder = models_dir()
    if not folder.is_dir():
        hint = "" if os.environ.get(MODELS_DIR_ENV) else (
            f"; set {MODELS_DIR_ENV} to a folder of sensor model files (*.toml)")
        raise SensorModelError(f"sensor model folder not found{hint}", path=folder)
    return {path.stem: path for path in sorted(folder.glob("*.toml"))}


def list_sensor_models() -> list[str]:
    """Names of the available radar sensor models, sorted.

    The ADS-B NACp table and any other non-radar file are not listed.
    """
    files = _model_files()
    return [name for name, path in files.items() if _read_toml(path).get("kind") == RADAR_KIND]


def _number(data: dict[str, Any], key: str, path: Path, *, positive: bool = True) -> float:
    """A finite (by default strictly positive) number from a model file."""
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SensorModelError(f"must be a number, got {value!r}", path=path, field=key)
    value = float(value)
    if not math.isfinite(value) or (positive and value <= 0.0):
        kind = "a positive finite number" if positive else "a finite number"
        raise SensorModelError(f"must be {kind}, got {value!r}", path=path, field=key)
    return value


def _check_keys(data: dict[str, Any], path: Path) -> None:
    """Reject missing and unknown keys of a radar model file."""
    for key in _RADAR_REQUIRED_KEYS:
        if key not in data:
            raise SensorModelError("missing required key", path=path, field=key)
    known = set(_RADAR_REQUIRED_KEYS) | set(_RADAR_OPTIONAL_KEYS)
    for key in data:
        if key not in known:
            raise SensorModelError(
                f"unknown key; known keys: {', '.join(sorted(known))}", path=path, field=key
            )


def _parse_estimate(value: Any, dimensions: int, path: Path) -> tuple[str, ...]:
    """The ``estimate`` list: known, distinct names; elevation only for 3-D radars."""
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise SensorModelError("must be a non-empty list of names", path=path, field="estimate")
    for name in value:
        if name not in PARAMETER_NAMES:
            raise SensorModelError(
                f"unknown parameter {name!r}; known: {', '.join(PARAMETER_NAMES)}",
                path=path,
                field="estimate",
            )
    if len(set(value)) != len(value):
        raise SensorModelError("names a parameter twice", path=path, field="estimate")
    if "elevation_bias" in value and dimensions != 3:
        raise SensorModelError(
            "elevation_bias needs a 3-D radar (dimensions = 3)", path=path, field="estimate"
        )
    return tuple(value)


def _parse_typical_bias(value: Any, path: Path) -> dict[str, float]:
    """The ``[typical_bias]`` table: contract keys to non-negative magnitudes."""
    if not isinstance(value, dict):
        raise SensorModelError("must be a table", path=path, field="typical_bias")
    known = [contract_key for contract_key, _ in CONTRACT_KEYS.values()]
    result = {}
    for key in value:
        if key not in known:
            raise SensorModelError(
                f"unknown bias key; known: {', '.join(known)}",
                path=path,
                field=f"typical_bias.{key}",
            )
        magnitude = _number(value, key, path, positive=False)
        if magnitude < 0.0:
            raise SensorModelError(
                "must be a non-negative magnitude", path=path, field=f"typical_bias.{key}"
            )
        result[key] = magnitude
    return result


def _parse_radar_model(name: str, data: dict[str, Any], path: Path) -> SensorModel:
    """Validate a radar model file and convert it to SI units."""
    _check_keys(data, path)
    dimensions = data["dimensions"]
    if dimensions not in (2, 3) or isinstance(dimensions, bool):
        raise SensorModelError(f"must be 2 or 3, got {dimensions!r}", path=path, field="dimensions")
    has_elevation = "sigma_elevation_mrad" in data
    if has_elevation != (dimensions == 3):
        raise SensorModelError(
            "sigma_elevation_mrad must be given for a 3-D radar and only for one",
            path=path,
            field="sigma_elevation_mrad",
        )
    description = data["description"]
    if not isinstance(description, str):
        raise SensorModelError("must be a string", path=path, field="description")
    pd_value = _number(data, "detection_probability", path)
    if pd_value > 1.0:
        raise SensorModelError(
            f"must be within (0, 1], got {pd_value}", path=path, field="detection_probability"
        )
    min_elevation_deg = _number(data, "min_elevation_deg", path, positive=False)
    if not -90.0 <= min_elevation_deg <= 90.0:
        raise SensorModelError("must be within [-90, 90]", path=path, field="min_elevation_deg")
    sigma_el = _number(data, "sigma_elevation_mrad", path) / 1e3 if has_elevation else None
    return SensorModel(
        name=name,
        kind=RADAR_KIND,
        description=description,
        dimensions=int(dimensions),
        sigma_range_m=_number(data, "sigma_range_m", path),
        sigma_azimuth_rad=_number(data, "sigma_azimuth_mrad", path) / 1e3,
        sigma_elevation_rad=sigma_el,
        scan_period_s=_number(data, "scan_period_s", path),
        detection_probability=pd_value,
        max_range_m=_number(data, "max_range_m", path),
        min_elevation_rad=math.radians(min_elevation_deg),
        estimate=_parse_estimate(data["estimate"], int(dimensions), path),
        typical_bias=_parse_typical_bias(data.get("typical_bias", {}), path),
    )


def load_sensor_model(name: str) -> SensorModel:
    """Load a radar sensor model by name.

    Parameters
    ----------
    name : str
        File name in the models folder without ``.toml``, e.g. ``"ssr-mode-s"``.

    Returns
    -------
    SensorModel
        The model, in SI units.

    Raises
    ------
    SensorModelError
        If no radar model has that name (the message lists the available ones)
        or the file is invalid.
    """
    path = models_dir() / f"{name}.toml"
    if Path(name).name != name or not path.is_file():  # not a file of the folder
        path = _model_files().get(name)
    if path is None:
        available = ", ".join(list_sensor_models()) or "none"
        raise SensorModelError(
            f"unknown sensor model {name!r}; available: {available}", path=models_dir()
        )
    try:
        stat = path.stat()
    except OSError:
        return _load_radar_model(name, path, -1, -1)
    return _load_radar_model(name, path, stat.st_mtime_ns, stat.st_size)


@lru_cache(maxsize=64)
def _load_radar_model(name: str, path: Path, mtime_ns: int, size: int) -> SensorModel:
    """The model in ``path``, parsed once per version of the file (its time and size:
    calibrating in windows asks for the same models again and again)."""
    data = _read_toml(path)
    if data.get("kind") != RADAR_KIND:
        available = ", ".join(list_sensor_models()) or "none"
        raise SensorModelError(
            f"{name!r} is not a radar sensor model; available: {available}", path=path
        )
    return _parse_radar_model(name, data, path)


# --------------------------------------------------------------------------- ADS-B NACp


@lru_cache(maxsize=4)
def _nacp_sigma_table(path: Path, mtime_ns: int) -> NDArray[np.float64]:
    """``sigma_m`` for NACp 0..11 (index = NACp) from the NACp table file.

    ``mtime_ns`` is only part of the cache key, so that an edited file is re-read.
    """
    data = _read_toml(path)
    if data.get("kind") != ADSB_NACP_KIND:
        raise SensorModelError(f"kind must be {ADSB_NACP_KIND!r}", path=path, field="kind")
    ratio = _number(data, "epu_per_sigma", path)
    rows = data.get("nacp")
    if not isinstance(rows, list) or not rows:
        raise SensorModelError("missing [[nacp]] rows", path=path, field="nacp")
    table = np.full(12, np.nan)
    for row in rows:
        value = row.get("value") if isinstance(row, dict) else None
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 11:
            raise SensorModelError(f"NACp must be 0..11, got {value!r}", path=path, field="value")
        if not np.isnan(table[value]):
            raise SensorModelError(f"NACp {value} given twice", path=path, field="value")
        table[value] = _number(row, "epu_m", path) / ratio
    missing = [str(i) for i in range(12) if np.isnan(table[i])]
    if missing:
        raise SensorModelError(f"no row for NACp {', '.join(missing)}", path=path, field="nacp")
    return table


def adsb_sigma_from_nacp(nacp: ArrayLike) -> NDArray[np.float64]:
    """1-sigma horizontal position error of an ADS-B report from its NACp [m].

    ``sigma_m = EPU / 2.4477`` with the EPU (Estimated Position Uncertainty, the
    radius containing the true position with 95 % probability) of the NACp
    category (DO-260B): for a circular 2-D Gaussian the 95 % radius is
    ``sqrt(-2 ln 0.05) sigma = 2.4477 sigma``.  The table is read from
    ``adsb-nacp.toml`` of the models folder (:func:`models_dir`).

    Parameters
    ----------
    nacp : array_like
        NACp values (integers 0..11); NaN, ``None`` or ``pandas.NA`` for unknown.

    Returns
    -------
    ndarray of float
        ``sigma_m`` [m], same shape as ``nacp``.  NACp 0 ("EPU >= 10 NM or
        unknown") gets the value of its table row; the bundled table gives it
        the bound of NACp 1 (about 7.6 km), a large value that leaves such
        reports almost no weight.  Unknown inputs (NaN, missing, or not an
        integer in 0..11) give NaN.
    """
    path = _model_files().get(ADSB_NACP_TABLE, models_dir() / f"{ADSB_NACP_TABLE}.toml")
    try:
        mtime_ns = path.stat().st_mtime_ns
    except OSError:
        raise SensorModelError("ADS-B NACp table not found", path=path) from None
    table = _nacp_sigma_table(path, mtime_ns)
    values = _as_float_array(nacp)
    valid = np.isfinite(values) & (values == np.round(values)) & (values >= 0) & (values <= 11)
    index = np.where(valid, values, 0).astype(int)
    return np.where(valid, table[index], np.nan)


def _as_float_array(values: ArrayLike) -> NDArray[np.float64]:
    """Numbers as a float array; missing markers (None, NaN, pandas.NA, text) become NaN."""
    try:
        return np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        flat = pd.Series(np.ravel(np.asarray(values, dtype=object)), dtype=object)
        numeric = pd.to_numeric(flat, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
        return numeric.reshape(np.shape(values))
