"""The radar bias model and its sign convention ("measured minus true").

Contract, per radar::

    range_measured     = (1 + range_gain) * range_true + range_offset_m + noise
    azimuth_measured   = azimuth_true + azimuth_bias + noise      (wrapped to [0, 2 pi))
    elevation_measured = elevation_true + elevation_bias + noise  (3-D radars only)
    time_reported      = time_true + time_offset_s

and, for a radar that estimates its azimuth eccentricity (contract v2; an
antenna or encoder mounted off the turning axis), an azimuth error that varies
with azimuth::

    azimuth_measured  += s * sin(azimuth_true) + c * cos(azimuth_true)

This is paper 001 eq. 1-2 (azimuth bias, range offset ``delta_rb`` and range
gain ``delta_rg``) with the elevation bias of a 3-D radar added.  Correcting a
plot applies the inverse map.  Inside the code angles are radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from graphcal.core.frames import wrap_to_2pi

#: Internal parameter names, in the order used by every estimator's state vector.
PARAMETER_NAMES: tuple[str, ...] = ("range_offset", "range_gain", "azimuth_bias", "elevation_bias")

#: The azimuth eccentricity terms ``s`` and ``c`` [rad] (contract v2).
ECCENTRICITY_NAMES: tuple[str, ...] = ("azimuth_sin", "azimuth_cos")
#: The name in a site's ``estimate`` list that asks for both eccentricity terms.
ECCENTRICITY = "azimuth_eccentricity"
#: Every name a site's ``estimate`` list may hold.
ESTIMATE_NAMES: tuple[str, ...] = (*PARAMETER_NAMES, ECCENTRICITY)

#: Contract (JSON/CSV) key of each parameter and the factor from SI to that unit.
CONTRACT_KEYS: dict[str, tuple[str, float]] = {
    "range_offset": ("range_offset_m", 1.0),
    "range_gain": ("range_gain", 1.0),
    "azimuth_bias": ("azimuth_bias_mrad", 1e3),
    "elevation_bias": ("elevation_bias_mrad", 1e3),
    "time_offset": ("time_offset_s", 1.0),
    "azimuth_sin": ("azimuth_sin_mrad", 1e3),
    "azimuth_cos": ("azimuth_cos_mrad", 1e3),
}

#: Contract key -> internal name.
NAME_FROM_KEY: dict[str, str] = {key: name for name, (key, _) in CONTRACT_KEYS.items()}


def contract_unit(key: str) -> str:
    """The unit of a contract key, from its suffix: ``m``, ``mrad``, ``s``, or ``fraction``
    (``range_gain``, a plain fraction: 0.005 is 0.5 %)."""
    for suffix, unit in (("_mrad", "mrad"), ("_m", "m"), ("_s", "s")):
        if key.endswith(suffix):
            return unit
    return "fraction"


def to_contract_units(name: str, value_si: float) -> float:
    """Convert a parameter value from SI (m, fraction, rad, s) to its contract unit."""
    return value_si * CONTRACT_KEYS[name][1]


def from_contract_units(name: str, value: float) -> float:
    """Convert a parameter value from its contract unit to SI."""
    return value / CONTRACT_KEYS[name][1]


@dataclass(frozen=True)
class RadarBias:
    """Systematic errors of one radar, SI units.

    Attributes
    ----------
    range_offset_m : float
        Range offset [m].
    range_gain : float
        Range gain, a plain fraction (0.005 is 0.5 %).
    azimuth_bias_rad : float
        Azimuth bias [rad], clockwise positive.
    elevation_bias_rad : float
        Elevation bias [rad]; 0 for 2-D radars.
    time_offset_s : float
        Time-stamping bias [s]: ``time_reported = time_true + time_offset_s``.
    azimuth_sin_rad, azimuth_cos_rad : float
        Azimuth eccentricity [rad]: the azimuth error ``s sin(az) + c cos(az)``.
    """

    range_offset_m: float = 0.0
    range_gain: float = 0.0
    azimuth_bias_rad: float = 0.0
    elevation_bias_rad: float = 0.0
    time_offset_s: float = 0.0
    azimuth_sin_rad: float = 0.0
    azimuth_cos_rad: float = 0.0

    def as_vector(self) -> NDArray[np.float64]:
        """The four spatial biases in :data:`PARAMETER_NAMES` order."""
        return np.array(
            [self.range_offset_m, self.range_gain, self.azimuth_bias_rad, self.elevation_bias_rad]
        )

    def value(self, name: str) -> float:
        """One bias by its name (:data:`PARAMETER_NAMES`, ``time_offset``,
        :data:`ECCENTRICITY_NAMES`), SI units."""
        if name == "time_offset":
            return self.time_offset_s
        if name == "azimuth_sin":
            return self.azimuth_sin_rad
        if name == "azimuth_cos":
            return self.azimuth_cos_rad
        return float(self.as_vector()[PARAMETER_NAMES.index(name)])

    @property
    def has_eccentricity(self) -> bool:
        """Whether either azimuth eccentricity term is non-zero (anywhere, when the
        terms are arrays of per-plot values, as for biases over time)."""
        return bool(np.any(np.asarray(self.azimuth_sin_rad) != 0.0)
                    or np.any(np.asarray(self.azimuth_cos_rad) != 0.0))

    @classmethod
    def from_vector(cls, values: ArrayLike, time_offset_s: float = 0.0) -> RadarBias:
        """Build from a vector in :data:`PARAMETER_NAMES` order."""
        v = np.asarray(values, dtype=float)
        return cls(float(v[0]), float(v[1]), float(v[2]), float(v[3]), time_offset_s)


def apply_bias(
    range_true_m: ArrayLike,
    azimuth_true_rad: ArrayLike,
    elevation_true_rad: ArrayLike,
    bias: RadarBias,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Map true polar coordinates to biased (noise-free) measurements.

    Returns ``(range_m, azimuth_rad, elevation_rad)``; azimuth wrapped to
    ``[0, 2 pi)``.  NaN elevations (2-D radars) stay NaN.
    """
    r = (1.0 + bias.range_gain) * np.asarray(range_true_m, dtype=float) + bias.range_offset_m
    az_true = np.asarray(azimuth_true_rad, dtype=float)
    az = az_true + bias.azimuth_bias_rad
    if bias.has_eccentricity:
        az = az + bias.azimuth_sin_rad * np.sin(az_true) + bias.azimuth_cos_rad * np.cos(az_true)
    el = np.asarray(elevation_true_rad, dtype=float) + bias.elevation_bias_rad
    return r, wrap_to_2pi(az), el


#: Newton steps of the eccentricity inverse; each multiplies the error by about
#: ``(|s| + |c|)^2``, so three reach round-off for any plausible eccentricity.
ECCENTRICITY_INVERSE_STEPS = 3


def true_azimuth(azimuth_measured_rad: ArrayLike, bias: RadarBias) -> NDArray[np.float64]:
    """Invert the azimuth model: ``az_t + b + s sin(az_t) + c cos(az_t) = az_m`` for ``az_t``.

    Newton's method from ``az_m - b``; without eccentricity the exact ``az_m - b``.
    Wrapped to ``[0, 2 pi)``.
    """
    az_m = np.asarray(azimuth_measured_rad, dtype=float) - bias.azimuth_bias_rad
    if not bias.has_eccentricity:
        return wrap_to_2pi(az_m)
    s, c = bias.azimuth_sin_rad, bias.azimuth_cos_rad
    az = az_m.copy()
    for _ in range(ECCENTRICITY_INVERSE_STEPS):
        f = az + s * np.sin(az) + c * np.cos(az) - az_m
        az = az - f / (1.0 + s * np.cos(az) - c * np.sin(az))
    return wrap_to_2pi(az)


def correct_bias(
    range_measured_m: ArrayLike,
    azimuth_measured_rad: ArrayLike,
    elevation_measured_rad: ArrayLike,
    bias: RadarBias,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Inverse of :func:`apply_bias`: remove the biases from measurements.

    ``range_true = (range_measured - range_offset) / (1 + range_gain)``; the
    azimuth by :func:`true_azimuth`.
    """
    r = (np.asarray(range_measured_m, dtype=float) - bias.range_offset_m) / (1.0 + bias.range_gain)
    az = true_azimuth(azimuth_measured_rad, bias)
    el = np.asarray(elevation_measured_rad, dtype=float) - bias.elevation_bias_rad
    return r, az, el


def count_non_positive_ranges(range_measured_m: ArrayLike, bias: RadarBias) -> int:
    """How many plots ``bias`` corrects to a range ``(r - offset) / (1 + gain)`` that is not
    positive (NaN counts too): an estimate no geometry allows."""
    with np.errstate(divide="ignore", invalid="ignore"):
        corrected = ((np.asarray(range_measured_m, dtype=float) - bias.range_offset_m)
                     / (1.0 + bias.range_gain))
    return int(np.sum(~(corrected > 0)))


def correct_time(time_reported_s: ArrayLike, bias: RadarBias) -> NDArray[np.float64]:
    """True plot time from the reported one: ``time_true = time_reported - time_offset_s``."""
    return np.asarray(time_reported_s, dtype=float) - bias.time_offset_s


def measurement_bias_jacobian(range_true_m: ArrayLike) -> NDArray[np.float64]:
    """d(range, azimuth, elevation)_measured / d(offset, gain, az_bias, el_bias).

    Shape ``(..., 3, 4)``: ``[[1, r, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]`` with
    ``r`` the true range (paper 001 eq. 2).
    """
    r = np.asarray(range_true_m, dtype=float)
    jac = np.zeros(r.shape + (3, 4))
    jac[..., 0, 0] = 1.0
    jac[..., 0, 1] = r
    jac[..., 1, 2] = 1.0
    jac[..., 2, 3] = 1.0
    return jac


def compose_bias(first: RadarBias, increment: RadarBias) -> RadarBias:
    """The single bias equivalent to ``first`` followed by ``increment``.

    If plots corrected with ``first`` still carry ``increment``, the measured
    plots carry the returned bias: ``gain = (1 + g1)(1 + dg) - 1``,
    ``offset = o1 + (1 + g1) do``; angles and time offsets add.
    """
    return RadarBias(
        range_offset_m=first.range_offset_m + (1.0 + first.range_gain) * increment.range_offset_m,
        range_gain=(1.0 + first.range_gain) * (1.0 + increment.range_gain) - 1.0,
        azimuth_bias_rad=first.azimuth_bias_rad + increment.azimuth_bias_rad,
        elevation_bias_rad=first.elevation_bias_rad + increment.elevation_bias_rad,
        time_offset_s=first.time_offset_s + increment.time_offset_s,
    )
