"""Simulation scenarios: parse and validate a scenario TOML file.

The format is documented in ``scenarios/README.md``.  In short::

    [scenario]   name, description, duration_s, origin = {lat_deg, lon_deg, alt_m}
    [[radar]]    id, site (lat_deg/lon_deg/alt_m or ecef_m), model and/or sigmas,
                 dimensions, scan_period_s, detection_probability, max_range_m,
                 min_elevation_deg, horizon_check, estimate, antenna_phase_deg,
                 altitude_sigma_m, altitude_quantum_ft, refraction,
                 refractivity_n_s, refractivity_scale_height_m,
                 identity ("mode_s", "mode_ac", "psr"), track_numbers,
                 clutter_per_scan (contract v3),
                 [radar.bias] range_offset_m, range_gain, azimuth_bias_mrad,
                 elevation_bias_mrad, time_offset_s, azimuth_sin_mrad, azimuth_cos_mrad
                 [radar.drift] the same keys (but time_offset_s) with ``_per_h``
                 [[radar.step]] time_s and the same keys (but time_offset_s): a change
    [[aircraft]] piecewise legs from a start state, or constant ECEF velocity
    [traffic]    random waypoint traffic
    [opensky]    replay of an OpenSky-style state-vector table
    [adsb]       ADS-B reports of every equipped aircraft (equipped_fraction,
                 baro_altitude)
    [mode_3a]    Mode 3/A codes (contract v3): vfr_fraction, vfr_code, code_changes
    [dataset]    plot_altitude: "geometric" (default) or "pressure" (contract v2);
                 epoch_utc: the UTC time of 0 s, written to the dataset (v1.6;
                 default: an [opensky] replay's start, else none)
    [atmosphere] the true height model of pressure altitudes: height_offset_m,
                 height_scale (refraction is per radar)

File values carry their units in the key names (deg, mrad, m, s); the
dataclasses hold SI values (radians).  Every problem raises
:class:`graphcal.core.errors.ScenarioError` naming the file and the field, e.g.
``radar[1].scan_period_s``.  Unknown keys are errors (they are usually typos).
"""

from __future__ import annotations

import datetime as dt
import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from graphcal.core import frames
from graphcal.core.errors import ScenarioError, SensorModelError
from graphcal.core.refraction import DEFAULT_N_S, DEFAULT_SCALE_HEIGHT_M, Atmosphere
from graphcal.data.bias import ESTIMATE_NAMES, RadarBias
from graphcal.data.bias_schedule import BiasSchedule, BiasStep
from graphcal.data.dataset import REFRACTION_MODELS, REFRACTIVITY_N_S_RANGE, Site
from graphcal.data.epoch import parse_epoch_utc
from graphcal.data.height import GEOMETRIC, PLOT_ALTITUDE_CHOICES, PRESSURE, HeightModel
from graphcal.data.sensor_models import SensorModel, adsb_sigma_from_nacp, load_sensor_model
from graphcal.simulation.trajectories import (
    EcefTrajectory,
    Leg,
    LegTrajectory,
    LocalPlane,
    OpenSkySpec,
    TrafficSpec,
    Trajectory,
)

#: Feet to metres.
FOOT_M = 0.3048
#: Default 1-sigma noise of the reported (Mode C style) altitude [m].
DEFAULT_ALTITUDE_SIGMA_M = 10.0
#: Default quantum of the reported altitude [ft] (Mode C reports in 100 ft, Mode S in 25 ft).
DEFAULT_ALTITUDE_QUANTUM_FT = 25.0
#: Default ADS-B NACp when neither ``nacp`` nor ``sigma_m`` is given.
DEFAULT_NACP = 9
#: Ratio of the default ADS-B vertical sigma to the horizontal one.
VERTICAL_TO_HORIZONTAL_SIGMA = 1.5
#: Base of the ICAO addresses given to ``[[aircraft]]`` entries without ``id``.
GENERATED_ID_BASE = 0xF00000
#: What a radar's plots tell of the aircraft (``identity``, contract v3): ``"mode_s"``
#: the address (``target_id``), the Mode 3/A code when codes are simulated, and the
#: altitude; ``"mode_ac"`` the code and the altitude, no address; ``"psr"`` nothing.
IDENTITIES: tuple[str, ...] = ("mode_s", "mode_ac", "psr")
#: Default Mode 3/A code of VFR flights (Europe's conspicuity code 7000).
DEFAULT_VFR_CODE = "7000"

_ICAO_RE = re.compile(r"^[0-9a-f]{6}$")
_MODE_3A_RE = re.compile(r"^[0-7]{4}$")
_REQUIRED = object()


# --------------------------------------------------------------------------- dataclasses


@dataclass(frozen=True)
class RadarSpec:
    """One simulated radar, SI units.

    Attributes
    ----------
    id : str
        Radar identifier.
    lat_rad, lon_rad : float
        Antenna latitude and longitude [rad].
    alt_m : float
        Antenna height above the ellipsoid [m].
    sigma_range_m : float
        1-sigma random range error [m] (0: noise-free).
    sigma_azimuth_rad : float
        1-sigma random azimuth error [rad].
    sigma_elevation_rad : float or None
        1-sigma random elevation error [rad]; ``None`` for a 2-D radar.
    scan_period_s : float
        Antenna rotation period [s].
    detection_probability : float
        Probability of a plot each time the beam passes a target in coverage.
    max_range_m : float
        Maximum slant range of a detection [m] (may be ``inf``).
    min_elevation_rad : float
        Minimum elevation of a detection [rad], straight line of sight.
    horizon_check : bool
        Whether the line of sight must clear the Earth (off only to reproduce
        experiments that ignore the Earth's curvature).
    bias : RadarBias
        True systematic errors.
    estimate : tuple of str
        Biases to estimate, written to ``sites.toml``; empty: the radar's default.
    model : str or None
        Sensor model that supplied the defaults.
    antenna_phase_rad : float or None
        Beam azimuth at time 0 [rad]; ``None``: drawn from the generator.
    altitude_sigma_m : float
        1-sigma noise of the reported altitude [m].
    altitude_quantum_m : float
        Quantum of the reported altitude [m] (0: not quantised).
    refraction : str
        ``"none"`` (straight lines of sight) or ``"exponential"`` (contract v2:
        the plots measure the refracted ray's electrical length and apparent
        elevation), written to ``sites.toml``.
    refractivity_n_s : float
        Surface refractivity of the exponential atmosphere [N-units].
    refractivity_scale_height_m : float
        Its scale height [m].
    drift_per_s : RadarBias
        Rate of change of each bias [SI per s] (``[radar.drift]``, per hour in the file).
    steps : tuple of BiasStep
        Changes of the biases at given times (``[[radar.step]]``).
    identity : {"mode_s", "mode_ac", "psr"}
        What the plots carry of the aircraft (:data:`IDENTITIES`): ``"mode_s"``
        its address as ``target_id``; ``"mode_ac"`` no address (``target_id``
        empty), its Mode 3/A code and its altitude; ``"psr"`` neither address,
        code nor altitude.
    track_numbers : bool
        Whether the plots carry the radar's own ``track_number``.
    clutter_per_scan : float
        Mean number of false plots per antenna revolution (Poisson); 0: none.
    """

    id: str
    lat_rad: float
    lon_rad: float
    alt_m: float
    sigma_range_m: float
    sigma_azimuth_rad: float
    sigma_elevation_rad: float | None
    scan_period_s: float
    detection_probability: float = 1.0
    max_range_m: float = math.inf
    min_elevation_rad: float = 0.0
    horizon_check: bool = True
    bias: RadarBias = field(default_factory=RadarBias)
    estimate: tuple[str, ...] = ()
    model: str | None = None
    antenna_phase_rad: float | None = None
    altitude_sigma_m: float = DEFAULT_ALTITUDE_SIGMA_M
    altitude_quantum_m: float = DEFAULT_ALTITUDE_QUANTUM_FT * FOOT_M
    refraction: str = "none"
    refractivity_n_s: float = DEFAULT_N_S
    refractivity_scale_height_m: float = DEFAULT_SCALE_HEIGHT_M
    drift_per_s: RadarBias = field(default_factory=RadarBias)
    steps: tuple[BiasStep, ...] = ()
    identity: str = "mode_s"
    track_numbers: bool = False
    clutter_per_scan: float = 0.0

    @property
    def schedule(self) -> BiasSchedule:
        """The biases over time: ``bias`` at t = 0, ``drift_per_s`` and ``steps``."""
        return BiasSchedule(self.bias, self.drift_per_s, self.steps, 0.0)

    @property
    def is_3d(self) -> bool:
        """True when the radar measures elevation."""
        return self.sigma_elevation_rad is not None

    @property
    def addressed(self) -> bool:
        """True when every plot of the radar carries its aircraft's address: a Mode S
        radar without clutter."""
        return self.identity == "mode_s" and self.clutter_per_scan == 0.0

    @property
    def atmosphere(self) -> Atmosphere | None:
        """The atmosphere of the radar's rays, ``None`` for straight lines of sight."""
        return self.site().atmosphere

    def site(self) -> Site:
        """The :class:`graphcal.data.dataset.Site` written to ``sites.toml``."""
        return Site(
            id=self.id,
            lat_rad=self.lat_rad,
            lon_rad=self.lon_rad,
            alt_m=self.alt_m,
            sigma_range_m=self.sigma_range_m,
            sigma_azimuth_rad=self.sigma_azimuth_rad,
            sigma_elevation_rad=self.sigma_elevation_rad,
            scan_period_s=self.scan_period_s,
            model=self.model,
            estimate=self.estimate,
            refraction=self.refraction,
            refractivity_n_s=self.refractivity_n_s,
            refractivity_scale_height_m=self.refractivity_scale_height_m,
        )


@dataclass(frozen=True)
class AdsbSpec:
    """ADS-B reports of the simulated aircraft that are equipped.

    Attributes
    ----------
    enabled : bool
        Whether ADS-B reports are produced.
    equipped_fraction : float
        Fraction of the aircraft that broadcast ADS-B, in ``[0, 1]``: that
        many aircraft (rounded to the nearest whole number) are drawn without
        replacement from the simulation's generator; 1 (the default) equips
        every aircraft without drawing anything.
    period_s : float
        Report period [s]; each aircraft gets a random phase.
    nacp : int or None
        NACp written with each report (``None``: no ``nacp`` column).
    sigma_m : float or None
        1-sigma horizontal error per axis (east, north) [m]; ``None``: from
        ``nacp`` (:func:`graphcal.data.sensor_models.adsb_sigma_from_nacp`).
    sigma_vertical_m : float or None
        1-sigma height error [m]; ``None``: 1.5 times the horizontal sigma.
    outlier_fraction : float
        Probability that a report is displaced by ``outlier_distance_m``.
    outlier_distance_m : float
        Horizontal displacement of an outlier [m], in a random direction.
    dropout_probability : float
        Probability that a report is lost.
    baro_altitude : bool or None
        Write each report's pressure altitude ``baro_alt_m`` (the true height
        through the inverse height model, quantised to ``baro_quantum_m``);
        ``None``: when the scenario has an ``[atmosphere]`` table or pressure
        plot altitudes.
    baro_quantum_m : float
        Quantum of ``baro_alt_m`` [m] (25 ft; 0: not quantised).
    """

    enabled: bool = False
    equipped_fraction: float = 1.0
    period_s: float = 1.0
    nacp: int | None = DEFAULT_NACP
    sigma_m: float | None = None
    sigma_vertical_m: float | None = None
    outlier_fraction: float = 0.0
    outlier_distance_m: float = 5000.0
    dropout_probability: float = 0.0
    baro_altitude: bool | None = None
    baro_quantum_m: float = DEFAULT_ALTITUDE_QUANTUM_FT * FOOT_M

    @property
    def horizontal_sigma_m(self) -> float:
        """1-sigma horizontal error per axis [m], resolved from ``nacp`` when needed."""
        if self.sigma_m is not None:
            return self.sigma_m
        nacp = DEFAULT_NACP if self.nacp is None else self.nacp
        return float(adsb_sigma_from_nacp(nacp))

    @property
    def vertical_sigma_m(self) -> float:
        """1-sigma height error [m]."""
        if self.sigma_vertical_m is not None:
            return self.sigma_vertical_m
        return VERTICAL_TO_HORIZONTAL_SIGMA * self.horizontal_sigma_m


@dataclass(frozen=True)
class Mode3aSpec:
    """The Mode 3/A codes of the simulated aircraft (``[mode_3a]``, contract v3).

    Every aircraft gets a discrete code (4 octal digits, distinct while the
    4096-code space lasts, never a special code such as 7000, 7500, 7600 or 7700),
    or the VFR code.

    Attributes
    ----------
    vfr_fraction : float
        Fraction of the aircraft, in ``[0, 1]``, that fly VFR and share
        ``vfr_code``: that many (rounded to the nearest whole number, halves up)
        are drawn without replacement.
    vfr_code : int
        The VFR code, as an integer (``0o7000``).
    code_changes : float
        Fraction of the aircraft, in ``[0, 1]``, whose code changes once, at a time
        uniform within their flight (inside the scenario), to a new discrete code.
    """

    vfr_fraction: float = 0.0
    vfr_code: int = int(DEFAULT_VFR_CODE, 8)
    code_changes: float = 0.0


@dataclass(frozen=True)
class Scenario:
    """A parsed scenario.

    Attributes
    ----------
    name : str
        Short name.
    description : str
        Free text.
    duration_s : float
        Simulated time span ``[0, duration_s]`` [s].
    origin : LocalPlane or None
        Local origin of east/north positions and of the traffic disc.
    radars : tuple of RadarSpec
        The radars, in file order.
    aircraft : tuple of Trajectory
        Explicit ``[[aircraft]]`` flights.
    traffic : TrafficSpec or None
        Random traffic, drawn when simulating.
    opensky : OpenSkySpec or None
        Replayed real traffic, read when simulating.
    adsb : AdsbSpec
        ADS-B settings.
    path : Path or None
        The scenario file.
    plot_altitude : {"geometric", "pressure"}
        What the plots' ``altitude_m`` is (``[dataset] plot_altitude``): the true
        height above the ellipsoid, or the pressure altitude of that height
        through :attr:`height_model`; both with the radar's altitude noise and quantum.
    true_height_model : HeightModel or None
        The true height model ``h = (1 + height_scale) p + height_offset_m``
        (``[atmosphere]``); ``None``: none given (the standard atmosphere,
        pressure altitude = height).
    epoch_utc : datetime or None
        The UTC time of scenario time 0, written to the simulated dataset's
        ``sites.toml`` (``[dataset] epoch_utc``; default: an ``[opensky]``
        replay's ``start``, else ``None``: no epoch).
    mode_3a : Mode3aSpec or None
        The ``[mode_3a]`` table; ``None`` without it (codes are then simulated,
        with its defaults, only when a radar is ``"mode_ac"``).
    """

    name: str
    description: str
    duration_s: float
    origin: LocalPlane | None
    radars: tuple[RadarSpec, ...]
    aircraft: tuple[Trajectory, ...] = ()
    traffic: TrafficSpec | None = None
    opensky: OpenSkySpec | None = None
    adsb: AdsbSpec = field(default_factory=AdsbSpec)
    path: Path | None = None
    plot_altitude: str = GEOMETRIC
    true_height_model: HeightModel | None = None
    epoch_utc: dt.datetime | None = None
    mode_3a: Mode3aSpec | None = None

    @property
    def height_model(self) -> HeightModel:
        """The true height model (the identity without ``[atmosphere]``)."""
        return HeightModel() if self.true_height_model is None else self.true_height_model

    @property
    def has_pressure(self) -> bool:
        """Whether pressure altitudes are simulated: pressure plots or an ``[atmosphere]``."""
        return self.plot_altitude == PRESSURE or self.true_height_model is not None

    @property
    def adsb_baro(self) -> bool:
        """Whether the ADS-B reports carry ``baro_alt_m``."""
        if self.adsb.baro_altitude is None:
            return self.has_pressure
        return self.adsb.baro_altitude

    @property
    def codes(self) -> Mode3aSpec | None:
        """The Mode 3/A codes simulated: ``[mode_3a]``, or its defaults when a radar is
        ``"mode_ac"`` and the table is absent; ``None``: no codes (no ``mode_3a`` column)."""
        if self.mode_3a is not None:
            return self.mode_3a
        if any(r.identity == "mode_ac" for r in self.radars):
            return Mode3aSpec()
        return None

    @property
    def track_numbers(self) -> bool:
        """Whether the plots have a ``track_number`` column (a radar numbers its tracks)."""
        return any(r.track_numbers for r in self.radars)

    @property
    def addressed(self) -> bool:
        """True when every plot carries its aircraft's address (every radar Mode S, no
        clutter): the plots' ``target_id`` is then their whole truth."""
        return all(r.addressed for r in self.radars)

    def radar(self, radar_id: str) -> RadarSpec:
        """The radar with this id (``KeyError`` if there is none)."""
        for spec in self.radars:
            if spec.id == radar_id:
                return spec
        raise KeyError(radar_id)

    def with_radars(self, **changes: Any) -> Scenario:
        """A copy with the same field changes applied to every radar.

        Example: ``scenario.with_radars(sigma_range_m=0.0, sigma_azimuth_rad=0.0)``.
        Keys are :class:`RadarSpec` field names (SI units); ``sigma_elevation_rad``
        is only changed for 3-D radars.
        """
        radars = []
        for spec in self.radars:
            these = dict(changes)
            if not spec.is_3d:
                these.pop("sigma_elevation_rad", None)
            radars.append(replace(spec, **these))
        return replace(self, radars=tuple(radars))


# --------------------------------------------------------------------------- reader


class _Table:
    """A TOML table being read: typed getters, field paths, unknown-key check."""

    def __init__(self, data: Any, path: Path | None, prefix: str) -> None:
        self.path = path
        self.prefix = prefix
        if not isinstance(data, dict):
            raise ScenarioError("must be a table", path=path, field=prefix or None)
        self.data = data
        self.used: set[str] = set()

    def name(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def error(self, key: str | None, message: str) -> ScenarioError:
        where = self.name(key) if key else (self.prefix or None)
        return ScenarioError(message, path=self.path, field=where)

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = _REQUIRED) -> Any:
        self.used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                raise self.error(key, "missing required field")
            return default
        return self.data[key]

    def number(
        self,
        key: str,
        default: Any = _REQUIRED,
        *,
        low: float = -math.inf,
        high: float = math.inf,
        positive: bool = False,
        allow_inf: bool = False,
    ) -> Any:
        value = self.raw(key, default)
        if value is default and key not in self.data:
            return value
        return self._check_number(key, value, low, high, positive, allow_inf)

    def _check_number(
        self, key: str, value: Any, low: float, high: float, positive: bool, allow_inf: bool
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(key, f"must be a number, got {value!r}")
        value = float(value)
        if math.isnan(value) or (math.isinf(value) and not allow_inf):
            raise self.error(key, f"must be a finite number, got {value}")
        if positive and value <= 0.0:
            raise self.error(key, f"must be positive, got {value:g}")
        if not low <= value <= high:
            raise self.error(key, f"must be within [{low:g}, {high:g}], got {value:g}")
        return value

    def integer(
        self, key: str, default: Any = _REQUIRED, *, low: int = 0, high: int = 2**31
    ) -> Any:
        value = self.raw(key, default)
        if value is default and key not in self.data:
            return value
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be an integer, got {value!r}")
        if not low <= value <= high:
            raise self.error(key, f"must be within [{low}, {high}], got {value}")
        return value

    def string(self, key: str, default: Any = _REQUIRED) -> Any:
        value = self.raw(key, default)
        if value is default and key not in self.data:
            return value
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {value!r}")
        return value

    def boolean(self, key: str, default: Any = _REQUIRED) -> Any:
        value = self.raw(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {value!r}")
        return value

    def vector(self, key: str, size: int = 3) -> tuple[float, ...]:
        value = self.raw(key)
        if not isinstance(value, list) or len(value) != size:
            raise self.error(key, f"must be a list of {size} numbers, got {value!r}")
        return tuple(self._check_number(key, v, -math.inf, math.inf, False, False) for v in value)

    def bounds(
        self, key: str, default: tuple[float, float], *, low: float = -math.inf, integer=False
    ) -> tuple[float, float]:
        """A ``[low, high]`` pair (a single number means ``[x, x]``)."""
        value = self.raw(key, list(default))
        if isinstance(value, int | float) and not isinstance(value, bool):
            value = [value, value]
        if not isinstance(value, list) or len(value) != 2:
            raise self.error(key, f"must be a pair [low, high], got {value!r}")
        kind = int if integer else int | float
        if any(isinstance(v, bool) or not isinstance(v, kind) for v in value):
            what = "integers" if integer else "numbers"
            raise self.error(key, f"must be a pair of {what}, got {value!r}")
        lo, hi = (self._check_number(key, v, low, math.inf, False, False) for v in value)
        if lo > hi:
            raise self.error(key, f"low {lo:g} is above high {hi:g}")
        return (int(lo), int(hi)) if integer else (lo, hi)

    def table(self, key: str) -> _Table | None:
        if key not in self.data:
            self.used.add(key)
            return None
        return _Table(self.raw(key), self.path, self.name(key))

    def tables(self, key: str) -> list[_Table]:
        value = self.raw(key, [])
        if not isinstance(value, list):
            raise self.error(key, f"must be an array of tables ([[{key}]]), got {value!r}")
        return [_Table(v, self.path, f"{self.name(key)}[{i}]") for i, v in enumerate(value)]

    def finish(self) -> None:
        unknown = [k for k in self.data if k not in self.used]
        if unknown:
            raise self.error(unknown[0], "unknown field")


# --------------------------------------------------------------------------- radars


def _radar_site(t: _Table) -> tuple[float, float, float]:
    """``(lat_rad, lon_rad, alt_m)`` from lat_deg/lon_deg/alt_m or ecef_m."""
    geodetic = [k for k in ("lat_deg", "lon_deg", "alt_m") if t.has(k)]
    if t.has("ecef_m"):
        if geodetic:
            raise t.error(geodetic[0], "give the site as lat_deg/lon_deg/alt_m or ecef_m, not both")
        ecef = np.array(t.vector("ecef_m"))
        if np.linalg.norm(ecef) < 1e6:
            raise t.error("ecef_m", "is not near the Earth's surface")
        lat, lon, alt = frames.ecef_to_geodetic(ecef)
        return float(lat), float(lon), float(alt)
    if not geodetic:
        raise t.error("lat_deg", "missing radar site: give lat_deg, lon_deg and alt_m, or ecef_m")
    lat = t.number("lat_deg", low=-90.0, high=90.0)
    lon = t.number("lon_deg", low=-180.0, high=180.0)
    alt = t.number("alt_m", low=-1000.0, high=1e5)
    return math.radians(lat), math.radians(lon), alt


def _radar_model(t: _Table) -> SensorModel | None:
    name = t.string("model", None)
    if name is None:
        return None
    try:
        return load_sensor_model(name)
    except SensorModelError as exc:
        raise t.error("model", str(exc)) from None


def _radar_estimate(t: _Table, default: tuple[str, ...], is_3d: bool) -> tuple[str, ...]:
    value = t.raw("estimate", None)
    if value is None:
        names = default
    else:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise t.error("estimate", f"must be a list of parameter names, got {value!r}")
        if not value:
            raise t.error("estimate", "must name at least one parameter")
        for name in value:
            if name not in ESTIMATE_NAMES:
                known = ", ".join(ESTIMATE_NAMES)
                raise t.error("estimate", f"unknown parameter {name!r}; known: {known}")
        if len(set(value)) != len(value):
            raise t.error("estimate", "names a parameter twice")
        names = tuple(value)
    if "elevation_bias" in names and not is_3d:
        raise t.error("estimate", "elevation_bias needs a 3-D radar")
    return tuple(names)


def _radar_bias(t: _Table, is_3d: bool) -> RadarBias:
    b = t.table("bias")
    if b is None:
        return RadarBias()
    el = b.number("elevation_bias_mrad", 0.0)
    if el != 0.0 and not is_3d:
        raise b.error("elevation_bias_mrad", "a 2-D radar has no elevation bias")
    bias = RadarBias(
        range_offset_m=b.number("range_offset_m", 0.0),
        range_gain=b.number("range_gain", 0.0, low=-0.5, high=0.5),
        azimuth_bias_rad=b.number("azimuth_bias_mrad", 0.0, low=-1000.0, high=1000.0) * 1e-3,
        elevation_bias_rad=el * 1e-3,
        time_offset_s=b.number("time_offset_s", 0.0, low=-60.0, high=60.0),
        azimuth_sin_rad=b.number("azimuth_sin_mrad", 0.0, low=-100.0, high=100.0) * 1e-3,
        azimuth_cos_rad=b.number("azimuth_cos_mrad", 0.0, low=-100.0, high=100.0) * 1e-3,
    )
    b.finish()
    return bias


#: Bias terms that may drift or step: file key, RadarBias field, factor to SI.
_VARYING_KEYS: tuple[tuple[str, str, float], ...] = (
    ("range_offset_m", "range_offset_m", 1.0),
    ("range_gain", "range_gain", 1.0),
    ("azimuth_bias_mrad", "azimuth_bias_rad", 1e-3),
    ("elevation_bias_mrad", "elevation_bias_rad", 1e-3),
    ("azimuth_sin_mrad", "azimuth_sin_rad", 1e-3),
    ("azimuth_cos_mrad", "azimuth_cos_rad", 1e-3),
)


def _bias_change(t: _Table, suffix: str, scale: float, is_3d: bool) -> RadarBias:
    """A change of the bias terms from keys ``<contract key><suffix>``, times ``scale``."""
    values = {}
    for key, name, factor in _VARYING_KEYS:
        value = t.number(key + suffix, 0.0)
        if value != 0.0 and name == "elevation_bias_rad" and not is_3d:
            raise t.error(key + suffix, "a 2-D radar has no elevation bias")
        values[name] = value * factor * scale
    if t.has("time_offset_s" + suffix):
        raise t.error("time_offset_s" + suffix, "the time-stamping bias cannot drift or step")
    return RadarBias(**values)


def _radar_drift(t: _Table, is_3d: bool, duration_s: float | None
                 ) -> tuple[RadarBias, tuple[BiasStep, ...]]:
    """``[radar.drift]`` (per hour -> per second) and ``[[radar.step]]``."""
    d = t.table("drift")
    drift = RadarBias()
    if d is not None:
        drift = _bias_change(d, "_per_h", 1.0 / 3600.0, is_3d)
        d.finish()
    steps = []
    for st in t.tables("step"):
        time_s = st.number("time_s")
        if duration_s is not None and not 0.0 < time_s < duration_s:
            raise st.error("time_s", f"must lie inside the scenario (0 to {duration_s:g} s)")
        steps.append(BiasStep(time_s, _bias_change(st, "", 1.0, is_3d)))
        st.finish()
    steps.sort(key=lambda step: step.time_s)
    return drift, tuple(steps)


def _radar_refraction(t: _Table) -> tuple[str, float, float]:
    """``(refraction, refractivity_n_s, refractivity_scale_height_m)`` (contract v2 keys)."""
    model = t.string("refraction", "none")
    if model not in REFRACTION_MODELS:
        known = ", ".join(f'"{m}"' for m in REFRACTION_MODELS)
        raise t.error("refraction", f"unknown refraction model {model!r}; known: {known}")
    low, high = REFRACTIVITY_N_S_RANGE
    n_s = t.number("refractivity_n_s", DEFAULT_N_S, low=low, high=high)
    height = t.number("refractivity_scale_height_m", DEFAULT_SCALE_HEIGHT_M, positive=True)
    if model != "none":
        try:
            Atmosphere(n_s, height)
        except ValueError as exc:
            raise t.error("refractivity_scale_height_m", str(exc)) from None
    return model, n_s, height


def _radar_identity(t: _Table, max_range_m: float) -> tuple[str, bool, float]:
    """``(identity, track_numbers, clutter_per_scan)`` (contract v3 keys)."""
    identity = t.string("identity", "mode_s")
    if identity not in IDENTITIES:
        known = ", ".join(f'"{v}"' for v in IDENTITIES)
        raise t.error("identity", f"must be one of {known}, got {identity!r}")
    track_numbers = t.boolean("track_numbers", False)
    clutter = t.number("clutter_per_scan", 0.0, low=0.0, high=1e5)
    if clutter > 0.0 and not math.isfinite(max_range_m):
        raise t.error("clutter_per_scan",
                      "needs a finite max_range_m (clutter is spread over the range)")
    return identity, track_numbers, clutter


def _model_value(t: _Table, key: str, model_value: Any, **checks: Any) -> Any:
    """The file's value if given, else the model's, else a missing-field error."""
    if not t.has(key) and model_value is None:
        raise t.error(
            key, "missing: give it, or name a sensor model (model = ...) that supplies it"
        )
    value = t.number(key, None, **checks)
    return model_value if value is None else value


def _parse_radar(t: _Table, duration_s: float | None = None) -> RadarSpec:
    radar_id = t.string("id")
    if not radar_id.strip():
        raise t.error("id", "radar id is empty")
    lat, lon, alt = _radar_site(t)
    model = _radar_model(t)
    dims_default = None if model is None else model.dimensions
    dims = t.integer("dimensions", None, low=2, high=3)
    if dims is None:
        dims = (
            dims_default
            if dims_default is not None
            else (3 if t.has("sigma_elevation_mrad") else 2)
        )
    m = model
    sigma_r = _model_value(t, "sigma_range_m", m and m.sigma_range_m, low=0.0)
    sigma_az = (
        _model_value(t, "sigma_azimuth_mrad", m and m.sigma_azimuth_rad * 1e3, low=0.0) * 1e-3
    )
    sigma_el = None
    if dims == 3:
        model_el = None if m is None or m.sigma_elevation_rad is None else m.sigma_elevation_rad
        sigma_el = (
            _model_value(
                t, "sigma_elevation_mrad", None if model_el is None else model_el * 1e3, low=0.0
            )
            * 1e-3
        )
    elif t.has("sigma_elevation_mrad"):
        raise t.error("sigma_elevation_mrad", "a 2-D radar has no elevation sigma")
    scan = _model_value(t, "scan_period_s", m and m.scan_period_s, positive=True)
    p_d = t.number(
        "detection_probability", m.detection_probability if m else 1.0, low=0.0, high=1.0
    )
    max_range = t.number(
        "max_range_m", m.max_range_m if m else math.inf, positive=True, allow_inf=True
    )
    min_el_deg = t.number(
        "min_elevation_deg",
        math.degrees(m.min_elevation_rad) if m else 0.0,
        low=-90.0,
        high=90.0,
    )
    phase = t.number("antenna_phase_deg", None)
    identity, track_numbers, clutter = _radar_identity(t, max_range)
    refraction, n_s, scale_height = _radar_refraction(t)
    drift, steps = _radar_drift(t, dims == 3, duration_s)
    spec = RadarSpec(
        id=radar_id.strip(),
        lat_rad=lat,
        lon_rad=lon,
        alt_m=alt,
        sigma_range_m=sigma_r,
        sigma_azimuth_rad=sigma_az,
        sigma_elevation_rad=sigma_el,
        scan_period_s=scan,
        detection_probability=p_d,
        max_range_m=max_range,
        min_elevation_rad=math.radians(min_el_deg),
        horizon_check=t.boolean("horizon_check", True),
        bias=_radar_bias(t, dims == 3),
        estimate=_radar_estimate(t, m.estimate if m else (), dims == 3),
        model=None if m is None else m.name,
        antenna_phase_rad=None if phase is None else float(frames.wrap_to_2pi(math.radians(phase))),
        altitude_sigma_m=t.number("altitude_sigma_m", DEFAULT_ALTITUDE_SIGMA_M, low=0.0),
        altitude_quantum_m=t.number(
            "altitude_quantum_ft", DEFAULT_ALTITUDE_QUANTUM_FT, low=0.0, high=1000.0
        )
        * FOOT_M,
        refraction=refraction,
        refractivity_n_s=n_s,
        refractivity_scale_height_m=scale_height,
        drift_per_s=drift,
        steps=steps,
        identity=identity,
        track_numbers=track_numbers,
        clutter_per_scan=clutter,
    )
    t.finish()
    return spec


# --------------------------------------------------------------------------- aircraft


def _parse_leg(t: _Table) -> Leg:
    leg = Leg(
        duration_s=t.number("duration_s", positive=True),
        turn_rate_rad_s=math.radians(t.number("turn_rate_deg_s", 0.0, low=-30.0, high=30.0)),
        vertical_rate_mps=t.number("vertical_rate_mps", 0.0, low=-200.0, high=200.0),
        acceleration_mps2=t.number("acceleration_mps2", 0.0, low=-50.0, high=50.0),
    )
    t.finish()
    return leg


def _aircraft_id(t: _Table, index: int) -> str:
    value = t.string("id", None)
    if value is None:
        return f"{GENERATED_ID_BASE + index + 1:06x}"
    if not _ICAO_RE.match(value):
        raise t.error(
            "id", f"must be a 24-bit ICAO address as 6 lower-case hex digits, got {value!r}"
        )
    return value


def _parse_ecef_aircraft(t: _Table, target_id: str) -> EcefTrajectory:
    for key in ("legs", "leg", "speed_mps", "heading_deg", "east_m", "north_m", "lat_deg"):
        if t.has(key):
            raise t.error(key, "not allowed with start_ecef_m (constant ECEF velocity)")
    start = t.vector("start_ecef_m")
    if np.linalg.norm(start) < 1e6:
        raise t.error("start_ecef_m", "is not near the Earth's surface")
    return EcefTrajectory(
        target_id,
        start,
        t.vector("velocity_ecef_mps"),
        t.number("start_time_s", 0.0),
        t.number("duration_s", positive=True),
    )


def _parse_leg_aircraft(
    t: _Table, target_id: str, origin: LocalPlane | None, duration_s: float
) -> LegTrajectory:
    start_time = t.number("start_time_s", 0.0)
    if t.has("lat_deg") or t.has("lon_deg"):
        for key in ("east_m", "north_m"):
            if t.has(key):
                raise t.error(key, "give the start as east_m/north_m or lat_deg/lon_deg, not both")
        lat = math.radians(t.number("lat_deg", low=-90.0, high=90.0))
        lon = math.radians(t.number("lon_deg", low=-180.0, high=180.0))
        plane = origin if origin is not None else LocalPlane(lat, lon, 0.0)
        east, north = plane.from_geodetic(lat, lon)
    else:
        if not (t.has("east_m") or t.has("north_m")):
            raise t.error("east_m", "missing start position: east_m/north_m or lat_deg/lon_deg")
        if origin is None:
            raise t.error("east_m", "east_m/north_m need [scenario] origin")
        plane = origin
        east, north = t.number("east_m"), t.number("north_m")
    height = t.number("alt_m", low=-500.0, high=1e5)
    speed = t.number("speed_mps", low=0.0, high=2000.0)
    heading = math.radians(t.number("heading_deg", 0.0))
    leg_tables = t.tables("leg")
    if leg_tables:
        if t.has("duration_s"):
            raise t.error("duration_s", "give either [[aircraft.leg]] entries or duration_s")
        legs = [_parse_leg(lt) for lt in leg_tables]
    else:
        default = duration_s - start_time
        length = t.number("duration_s", default if default > 0 else _REQUIRED, positive=True)
        legs = [Leg(length)]
    try:
        return LegTrajectory(
            target_id, plane, start_time, east, north, height, speed, heading, legs
        )
    except ValueError as exc:
        raise t.error("leg", str(exc)) from None


def _parse_aircraft(
    t: _Table, index: int, origin: LocalPlane | None, duration_s: float
) -> Trajectory:
    target_id = _aircraft_id(t, index)
    if t.has("start_ecef_m"):
        trajectory: Trajectory = _parse_ecef_aircraft(t, target_id)
    else:
        trajectory = _parse_leg_aircraft(t, target_id, origin, duration_s)
    t.finish()
    return trajectory


# --------------------------------------------------------------------------- sections


def _parse_origin(t: _Table) -> LocalPlane | None:
    o = t.table("origin")
    if o is None:
        return None
    plane = LocalPlane(
        math.radians(o.number("lat_deg", low=-90.0, high=90.0)),
        math.radians(o.number("lon_deg", low=-180.0, high=180.0)),
        o.number("alt_m", 0.0, low=-1000.0, high=1e4),
    )
    o.finish()
    return plane


def _parse_traffic(t: _Table, origin: LocalPlane | None) -> TrafficSpec:
    if origin is None:
        raise t.error(None, "[traffic] needs [scenario] origin")
    spec = TrafficSpec(
        n_aircraft=t.integer("n_aircraft", low=0, high=100_000),
        radius_m=t.number("radius_m", positive=True),
        height_m=t.bounds("altitude_m", TrafficSpec.height_m, low=-500.0),
        speed_mps=t.bounds("speed_mps", TrafficSpec.speed_mps, low=0.0),
        legs=t.bounds("legs", TrafficSpec.legs, low=1, integer=True),
        turn_rate_rad_s=tuple(
            math.radians(v)
            for v in t.bounds(
                "turn_rate_deg_s",
                tuple(math.degrees(v) for v in TrafficSpec.turn_rate_rad_s),
                low=0.0,
            )
        ),
        vertical_rate_mps=t.bounds("vertical_rate_mps", TrafficSpec.vertical_rate_mps, low=0.0),
        level_probability=t.number(
            "level_probability", TrafficSpec.level_probability, low=0.0, high=1.0
        ),
        start_time_s=t.bounds("start_time_s", TrafficSpec.start_time_s),
    )
    t.finish()
    return spec


def _parse_start(t: _Table) -> pd.Timestamp:
    value = t.raw("start")
    try:
        if isinstance(value, dt.datetime):
            stamp = pd.Timestamp(value)
        elif isinstance(value, str):
            stamp = pd.Timestamp(value)
        else:
            raise ValueError
    except (ValueError, TypeError):
        raise t.error("start", f"must be an ISO date-time (UTC), got {value!r}") from None
    return stamp.tz_localize("UTC") if stamp.tzinfo is None else stamp.tz_convert("UTC")


def _parse_opensky(t: _Table, duration_s: float) -> OpenSkySpec:
    file = Path(t.string("file"))
    if not file.is_absolute():
        base = t.path.parent if t.path is not None else Path.cwd()
        file = (base / file).resolve()
    spec = OpenSkySpec(
        file=file,
        start=_parse_start(t),
        duration_s=t.number("duration_s", duration_s, positive=True),
        max_aircraft=t.integer("max_aircraft", OpenSkySpec.max_aircraft, low=1),
        min_points=t.integer("min_points", OpenSkySpec.min_points, low=2),
        max_gap_s=t.number("max_gap_s", OpenSkySpec.max_gap_s, positive=True),
        smoothing_s=t.number("smoothing_s", OpenSkySpec.smoothing_s, low=0.0, high=600.0),
        max_height_jump_m=t.number(
            "max_height_jump_m", OpenSkySpec.max_height_jump_m, positive=True
        ),
        max_position_jump_m=t.number(
            "max_position_jump_m", OpenSkySpec.max_position_jump_m, positive=True
        ),
    )
    t.finish()
    return spec


def _parse_adsb(t: _Table | None) -> AdsbSpec:
    if t is None:
        return AdsbSpec(enabled=False)
    enabled = t.boolean("enabled", True)
    period = t.number("period_s", 1.0, positive=True)
    nacp = t.integer("nacp", None, low=0, high=11)
    sigma = t.number("sigma_m", None, low=0.0)
    if nacp is None and sigma is None:
        nacp = DEFAULT_NACP
    spec = AdsbSpec(
        enabled=enabled,
        equipped_fraction=t.number("equipped_fraction", 1.0, low=0.0, high=1.0),
        period_s=period,
        nacp=nacp,
        sigma_m=sigma,
        sigma_vertical_m=t.number("sigma_vertical_m", None, low=0.0),
        outlier_fraction=t.number("outlier_fraction", 0.0, low=0.0, high=1.0),
        outlier_distance_m=t.number("outlier_distance_m", 5000.0, low=0.0),
        dropout_probability=t.number("dropout_probability", 0.0, low=0.0, high=1.0),
        baro_altitude=t.boolean("baro_altitude", None) if t.has("baro_altitude") else None,
        baro_quantum_m=t.number("baro_quantum_ft", DEFAULT_ALTITUDE_QUANTUM_FT, low=0.0,
                                high=1000.0) * FOOT_M,
    )
    t.finish()
    return spec


def _parse_mode_3a(t: _Table | None) -> Mode3aSpec | None:
    """``[mode_3a]``: ``vfr_fraction``, ``vfr_code`` (4 octal digits) and ``code_changes``."""
    if t is None:
        return None
    code = t.string("vfr_code", DEFAULT_VFR_CODE)
    if not _MODE_3A_RE.match(code):
        raise t.error("vfr_code", f"must be a Mode 3/A code of 4 octal digits, got {code!r}")
    spec = Mode3aSpec(
        vfr_fraction=t.number("vfr_fraction", 0.0, low=0.0, high=1.0),
        vfr_code=int(code, 8),
        code_changes=t.number("code_changes", 0.0, low=0.0, high=1.0),
    )
    t.finish()
    return spec


def _parse_dataset(t: _Table | None) -> tuple[str, dt.datetime | None]:
    """``[dataset]``: ``plot_altitude`` (``"geometric"``, the default, or ``"pressure"``)
    and ``epoch_utc`` (:func:`graphcal.data.epoch.parse_epoch_utc`; ``None`` when absent)."""
    if t is None:
        return GEOMETRIC, None
    value = t.string("plot_altitude", GEOMETRIC)
    if value not in PLOT_ALTITUDE_CHOICES:
        choices = " or ".join(f'"{c}"' for c in PLOT_ALTITUDE_CHOICES)
        raise t.error("plot_altitude", f"must be {choices}, got {value!r}")
    epoch = None
    if t.has("epoch_utc"):
        try:
            epoch = parse_epoch_utc(t.raw("epoch_utc"))
        except ValueError as exc:
            raise t.error("epoch_utc", str(exc)) from None
    t.finish()
    return value, epoch


def _parse_atmosphere(t: _Table | None) -> HeightModel | None:
    """``[atmosphere]``: the true height model (``height_offset_m`` [m], ``height_scale``)."""
    if t is None:
        return None
    model = HeightModel(
        height_offset_m=t.number("height_offset_m", 0.0, low=-5000.0, high=5000.0),
        height_scale=t.number("height_scale", 0.0, low=-0.5, high=0.5),
    )
    t.finish()
    return model


def _unique(items: list[Any], key: str, tables: list[_Table], what: str) -> None:
    seen: dict[str, int] = {}
    for i, item in enumerate(items):
        ident = getattr(item, key)
        if ident in seen:
            raise tables[i].error(
                "id", f"duplicate {what} id {ident!r} (first at index {seen[ident]})"
            )
        seen[ident] = i


def parse_scenario(document: Mapping[str, Any], path: str | Path | None = None) -> Scenario:
    """Validate a parsed scenario document (the TOML as a dict).

    Parameters
    ----------
    document : mapping
        The TOML content.
    path : str or Path, optional
        The file it came from: named in errors, and the base of relative paths.

    Returns
    -------
    Scenario

    Raises
    ------
    ScenarioError
        For the first problem found, naming the file and the field.
    """
    path = None if path is None else Path(path)
    root = _Table(dict(document), path, "")
    head = root.table("scenario")
    if head is None:
        raise root.error("scenario", "missing [scenario] table")
    default_name = path.stem if path is not None else "scenario"
    name = head.string("name", default_name)
    description = head.string("description", "")
    duration = head.number("duration_s", positive=True)
    origin = _parse_origin(head)
    head.finish()

    radar_tables = root.tables("radar")
    if not radar_tables:
        raise root.error("radar", "no [[radar]] tables: a scenario needs at least one radar")
    radars = [_parse_radar(rt, duration) for rt in radar_tables]
    _unique(radars, "id", radar_tables, "radar")

    aircraft_tables = root.tables("aircraft")
    aircraft = [_parse_aircraft(at, i, origin, duration) for i, at in enumerate(aircraft_tables)]
    _unique(aircraft, "target_id", aircraft_tables, "aircraft")

    traffic_table = root.table("traffic")
    traffic = None if traffic_table is None else _parse_traffic(traffic_table, origin)
    opensky_table = root.table("opensky")
    opensky = None if opensky_table is None else _parse_opensky(opensky_table, duration)
    adsb = _parse_adsb(root.table("adsb"))
    mode_3a = _parse_mode_3a(root.table("mode_3a"))
    plot_altitude, epoch_utc = _parse_dataset(root.table("dataset"))
    if epoch_utc is None and opensky is not None:
        epoch_utc = opensky.start.to_pydatetime()  # the replay's time 0 is real UTC
    true_height_model = _parse_atmosphere(root.table("atmosphere"))
    root.finish()
    if not aircraft and traffic is None and opensky is None:
        raise root.error("aircraft", "no aircraft: give [[aircraft]], [traffic] or [opensky]")
    return Scenario(
        name=name,
        description=description,
        duration_s=duration,
        origin=origin,
        radars=tuple(radars),
        aircraft=tuple(aircraft),
        traffic=traffic,
        opensky=opensky,
        adsb=adsb,
        path=path,
        plot_altitude=plot_altitude,
        true_height_model=true_height_model,
        epoch_utc=epoch_utc,
        mode_3a=mode_3a,
    )


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file.

    Parameters
    ----------
    path : str or Path
        The scenario file (format: ``scenarios/README.md``).

    Returns
    -------
    Scenario

    Raises
    ------
    ScenarioError
        If the file is missing or not TOML, or any field is invalid; the
        message names the file and the field.
    """
    path = Path(path)
    try:
        with path.open("rb") as handle:
            document = tomllib.load(handle)
    except FileNotFoundError:
        raise ScenarioError("file not found", path=path) from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ScenarioError(f"cannot read TOML: {exc}", path=path) from None
    return parse_scenario(document, path)
