"""Dataset types: radar sites, radar plots and ADS-B reports (CONTRACT.md).

:class:`Site` holds one radar's position, random-error sigmas (SI: metres and
radians) and the biases to estimate; :class:`Dataset` holds the sites and the
validated plots and ADS-B tables with the contract's column names and units
(degrees, metres, seconds).  Reading and writing dataset folders is
:mod:`graphcal.io.folder`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.refraction import DEFAULT_N_S, DEFAULT_SCALE_HEIGHT_M, Atmosphere
from graphcal.data.bias import PARAMETER_NAMES

if TYPE_CHECKING:
    from graphcal.data.cleaning import CleaningReport

#: Required plot columns, in contract order.
PLOT_COLUMNS: tuple[str, ...] = (
    "radar_id", "time_s", "range_m", "azimuth_deg", "elevation_deg", "target_id",
)
#: Optional plot columns (``mode_3a``, ``track_number``: contract v3).
PLOT_OPTIONAL_COLUMNS: tuple[str, ...] = ("altitude_m", "mode_3a", "track_number")
#: Required ADS-B columns.  A row's ``alt_m`` may be empty (a source without a geometric
#: height): it is read, and left out of a calibration by the cleaning, with a warning.
ADSB_COLUMNS: tuple[str, ...] = ("time_s", "target_id", "lat_deg", "lon_deg", "alt_m")
#: Optional ADS-B columns (``baro_alt_m``: the reported pressure altitude [m], contract v2;
#: ``mode_3a``: the Mode 3/A code broadcast, contract v3).
ADSB_OPTIONAL_COLUMNS: tuple[str, ...] = ("sigma_m", "nacp", "baro_alt_m", "mode_3a")
#: Pattern of a Mode 3/A code (contract v3 ``mode_3a``): 4 octal digits, "7000", "0413".
MODE_3A_PATTERN = r"[0-7]{4}"

#: 1-sigma horizontal error [m] of an ADS-B report that gives neither ``sigma_m``
#: nor ``nacp``.  A cautious figure, between NACp 8 (EPU < 92.6 m, sigma < 37.8 m) and
#: NACp 9 (sigma < 12.3 m), which most current transponders report or better.
ADSB_DEFAULT_SIGMA_M: float = 30.0

#: File name of the sites description.
SITES_FILE = "sites.toml"
#: Table formats, by file suffix.
TABLE_FORMATS: tuple[str, ...] = ("csv", "parquet")

#: Keys of a ``[[radar]]`` table in ``sites.toml``.
SITE_KEYS: tuple[str, ...] = (
    "id", "lat_deg", "lon_deg", "alt_m", "sigma_range_m", "sigma_azimuth_mrad",
    "sigma_elevation_mrad", "scan_period_s", "model", "estimate", "sac", "sic",
    "refraction", "refractivity_n_s", "refractivity_scale_height_m",
)

#: Propagation models of a radar's ``refraction`` key (contract v2): ``"none"``,
#: straight lines of sight (version 1); ``"exponential"``, rays refracted by an
#: exponential atmosphere (:mod:`graphcal.core.refraction`).
REFRACTION_MODELS: tuple[str, ...] = ("none", "exponential")
#: Accepted surface refractivities ``refractivity_n_s`` [N-units].
REFRACTIVITY_N_S_RANGE: tuple[float, float] = (0.0, 500.0)


@dataclass(frozen=True)
class Site:
    """One radar: position, random-error sigmas and which biases to estimate.

    Attributes
    ----------
    id : str
        Unique radar identifier.
    lat_rad, lon_rad : float
        WGS-84 antenna latitude and longitude [rad].
    alt_m : float
        Antenna height above the ellipsoid [m].
    sigma_range_m : float
        1-sigma random range error [m]; NaN when ``sites.toml`` does not give it
        (see :attr:`missing_sigmas`).
    sigma_azimuth_rad : float
        1-sigma random azimuth error [rad]; NaN when not given.
    sigma_elevation_rad : float or None
        1-sigma random elevation error [rad]; ``None`` for a 2-D radar, NaN for a
        3-D radar whose ``sites.toml`` table gives no sigma at all.
    scan_period_s : float or None
        Antenna rotation period [s], when known.
    model : str or None
        Name of the sensor model that supplied defaults.
    estimate : tuple of str
        Bias parameters (names from :data:`graphcal.data.bias.PARAMETER_NAMES`) to
        estimate; the others are held at zero.
    sac, sic : int or None
        ASTERIX System Area Code and System Identification Code of the radar
        (optional ``sites.toml`` keys, 0..255, both or neither), used to name it
        in ASTERIX imports and in the CAT063 export.
    refraction : str
        Propagation model, one of :data:`REFRACTION_MODELS`: ``"none"`` (straight
        lines of sight, the default) or ``"exponential"`` (contract v2: the true
        range is the ray's electrical length, the true elevation its apparent
        elevation at the antenna).
    refractivity_n_s : float
        Surface refractivity ``N_s`` of the exponential atmosphere [N-units].
    refractivity_scale_height_m : float
        Its scale height ``H`` [m].
    """

    id: str
    lat_rad: float
    lon_rad: float
    alt_m: float
    sigma_range_m: float
    sigma_azimuth_rad: float
    sigma_elevation_rad: float | None = None
    scan_period_s: float | None = None
    model: str | None = None
    estimate: tuple[str, ...] = field(default=())
    sac: int | None = None
    sic: int | None = None
    refraction: str = "none"
    refractivity_n_s: float = DEFAULT_N_S
    refractivity_scale_height_m: float = DEFAULT_SCALE_HEIGHT_M

    def __post_init__(self) -> None:
        if not self.estimate:
            names = PARAMETER_NAMES if self.is_3d else PARAMETER_NAMES[:3]
            object.__setattr__(self, "estimate", tuple(names))
        if self.refraction not in REFRACTION_MODELS:
            raise ValueError(f"refraction must be one of {', '.join(REFRACTION_MODELS)}, "
                             f"got {self.refraction!r}")

    @property
    def atmosphere(self) -> Atmosphere | None:
        """The atmosphere the radar's rays cross, or ``None`` for straight lines of sight.

        Raises
        ------
        ValueError
            If the refractivity values are not a valid :class:`Atmosphere`.
        """
        if self.refraction == "none":
            return None
        return Atmosphere(self.refractivity_n_s, self.refractivity_scale_height_m)

    @property
    def is_3d(self) -> bool:
        """True when the radar measures elevation."""
        return self.sigma_elevation_rad is not None

    @property
    def missing_sigmas(self) -> tuple[str, ...]:
        """``sites.toml`` keys of the random-error sigmas not given (NaN), in file order.

        They are estimated from the data (:func:`graphcal.noise.fill_missing_sigmas`)
        before a calibration.
        """
        values = {
            "sigma_range_m": self.sigma_range_m,
            "sigma_azimuth_mrad": self.sigma_azimuth_rad,
            "sigma_elevation_mrad": self.sigma_elevation_rad,
        }
        return tuple(
            key for key, value in values.items() if value is not None and math.isnan(value)
        )

    @cached_property
    def ecef_m(self) -> NDArray[np.float64]:
        """Antenna position in ECEF [m]."""
        return frames.geodetic_to_ecef(self.lat_rad, self.lon_rad, self.alt_m)

    @cached_property
    def ecef_to_enu(self) -> NDArray[np.float64]:
        """Rotation ECEF -> this radar's ENU frame."""
        return frames.ecef_to_enu_rotation(self.lat_rad, self.lon_rad)

    def enu_from_ecef(self, ecef_m: NDArray[np.float64]) -> NDArray[np.float64]:
        """ECEF points [m] to this radar's ENU frame [m]."""
        return frames.rotate(np.asarray(ecef_m, dtype=float) - self.ecef_m, self.ecef_to_enu)

    def ecef_from_enu(self, enu_m: NDArray[np.float64]) -> NDArray[np.float64]:
        """This radar's ENU [m] to ECEF [m]."""
        return frames.rotate(enu_m, self.ecef_to_enu.T) + self.ecef_m

    def polar_from_ecef(self, ecef_m: NDArray[np.float64]):
        """ECEF [m] to ``(range_m, azimuth_rad, elevation_rad)`` of this radar."""
        return frames.enu_to_polar(self.enu_from_ecef(ecef_m))

    def ecef_from_polar(self, range_m, azimuth_rad, elevation_rad) -> NDArray[np.float64]:
        """``(range_m, azimuth_rad, elevation_rad)`` of this radar to ECEF [m]."""
        return self.ecef_from_enu(frames.polar_to_enu(range_m, azimuth_rad, elevation_rad))

    def measurement_sigmas(self) -> NDArray[np.float64]:
        """``[sigma_range_m, sigma_azimuth_rad, sigma_elevation_rad or nan]``."""
        el = np.nan if self.sigma_elevation_rad is None else self.sigma_elevation_rad
        return np.array([self.sigma_range_m, self.sigma_azimuth_rad, el])


@dataclass
class Dataset:
    """Sites, plots and (optionally) ADS-B reports, validated.

    ``plots`` has the contract columns (``elevation_deg`` NaN for 2-D radars,
    ``target_id`` an empty string when unknown, ``altitude_m`` NaN when absent)
    and, when its files carry them (contract v3), ``mode_3a`` (4 octal digits, an
    empty string when none) and ``track_number`` (nullable ``Int64``);
    ``adsb`` has the contract columns with ``sigma_m`` always filled in, and
    ``mode_3a`` when its files carry it.
    ``cleaning`` is the report of :func:`graphcal.data.cleaning.clean_dataset` when
    the tables were cleaned (by :func:`load_dataset`), else ``None``.
    ``plot_altitude`` says what the plots' ``altitude_m`` is (``sites.toml``
    ``[dataset] plot_altitude``, :mod:`graphcal.data.height`): ``"geometric"``, a
    height above the ellipsoid (version 1), or ``"pressure"``, a pressure altitude.
    ``epoch_utc`` is the UTC time of 0 s on the tables' time base (``sites.toml``
    ``[dataset] epoch_utc``, :mod:`graphcal.data.epoch`), ``None`` when not known.
    """

    sites: dict[str, Site]
    plots: pd.DataFrame
    adsb: pd.DataFrame | None = None
    path: Path | None = None
    cleaning: CleaningReport | None = None
    plot_altitude: str = "geometric"
    epoch_utc: datetime | None = None

    @property
    def pressure_altitudes(self) -> bool:
        """Whether the plots' ``altitude_m`` is a pressure altitude."""
        return self.plot_altitude == "pressure"

    @property
    def radar_ids(self) -> list[str]:
        """Radar ids in ``sites.toml`` order."""
        return list(self.sites)

    def plots_of(self, radar_id: str) -> pd.DataFrame:
        """The plots of one radar, in time order."""
        sel = self.plots[self.plots["radar_id"] == radar_id]
        return sel.sort_values("time_s", kind="stable")
