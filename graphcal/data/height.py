"""Pressure altitudes and the height model (contract v2).

A Mode C / Mode S altitude and an ADS-B barometric altitude are *pressure
altitudes*: the height at which the International Standard Atmosphere has the
pressure the aircraft measures, in metres here (flight level x 100 ft x
0.3048).  On a day whose sea-level pressure and temperature are not the
standard ones, the pressure altitude ``p`` of an aircraft differs from its
height above the ellipsoid ``h`` by an offset (the sea-level pressure, and the
geoid) and by a scale (a warmer column of air is taller).  Over one region and
one calibration the contract models the difference with one pair::

    h = (1 + height_scale) * p + height_offset_m                (height model)
    p = (h - height_offset_m) / (1 + height_scale)              (its inverse)

A dataset's ``sites.toml`` says what its plots' ``altitude_m`` is
(``[dataset] plot_altitude``): ``"geometric"`` (version 1: a height above the
ellipsoid) or ``"pressure"``.  The ADS-B table's optional ``baro_alt_m`` is the
aircraft's reported pressure altitude beside its geometric ``alt_m``.

:class:`HeightModel` is the pair; :class:`HeightModelEstimate` is what a
calibration reports about it (the result JSON's ``atmosphere`` block).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: Meanings of the plots' ``altitude_m`` (``sites.toml`` ``[dataset] plot_altitude``).
PLOT_ALTITUDE_CHOICES: tuple[str, ...] = ("geometric", "pressure")
#: Version-1 meaning: a height above the ellipsoid.
GEOMETRIC = "geometric"
#: Contract v2: a pressure altitude (standard atmosphere) in metres.
PRESSURE = "pressure"
#: The height model's parameters, in the order of its variable and covariance, with
#: their result-JSON keys (SI units are the contract units: metres and a fraction).
HEIGHT_MODEL_NAMES: tuple[str, ...] = ("height_offset", "height_scale")
HEIGHT_MODEL_KEYS: tuple[str, ...] = ("height_offset_m", "height_scale")
#: Metres per foot.
FOOT_M = 0.3048
#: Metres per flight level (100 ft).
FLIGHT_LEVEL_M = 100.0 * FOOT_M


@dataclass(frozen=True)
class HeightModel:
    """``h = (1 + height_scale) * p + height_offset_m`` (module docstring).

    Attributes
    ----------
    height_offset_m : float
        Height above the ellipsoid of pressure altitude 0 [m].
    height_scale : float
        Fractional scale of pressure altitude to height (0.02: 2 % taller).
    """

    height_offset_m: float = 0.0
    height_scale: float = 0.0

    def geometric(self, pressure_altitude_m: ArrayLike) -> FloatArray:
        """Height above the ellipsoid [m] of a pressure altitude [m]."""
        p = np.asarray(pressure_altitude_m, dtype=float)
        return (1.0 + self.height_scale) * p + self.height_offset_m

    def pressure(self, height_m: ArrayLike) -> FloatArray:
        """Pressure altitude [m] of a height above the ellipsoid [m] (the inverse)."""
        h = np.asarray(height_m, dtype=float)
        return (h - self.height_offset_m) / (1.0 + self.height_scale)

    def as_vector(self) -> FloatArray:
        """``(height_offset_m, height_scale)``."""
        return np.array([self.height_offset_m, self.height_scale])

    @property
    def is_identity(self) -> bool:
        """Whether pressure altitude equals height (the standard atmosphere on the ellipsoid)."""
        return self.height_offset_m == 0.0 and self.height_scale == 0.0


def height_jacobian(pressure_altitude_m: ArrayLike) -> FloatArray:
    """``d h / d (height_offset_m, height_scale)`` ``(..., 2)``: ``(1, p)``."""
    p = np.asarray(pressure_altitude_m, dtype=float)
    return np.stack([np.ones_like(p), p], axis=-1)


def check_plot_altitude(value: Any) -> str:
    """``value`` if it is one of :data:`PLOT_ALTITUDE_CHOICES`, else ``ValueError``."""
    if not isinstance(value, str) or value not in PLOT_ALTITUDE_CHOICES:
        raise ValueError(
            f"plot_altitude must be one of {', '.join(repr(c) for c in PLOT_ALTITUDE_CHOICES)}, "
            f"got {value!r}"
        )
    return value


@dataclass
class HeightModelEstimate:
    """A calibration's estimate of the height model: the result JSON's ``atmosphere`` block.

    Attributes
    ----------
    height_offset_m, height_scale : float
        The estimates.
    covariance : ndarray (2, 2)
        Their joint covariance [m^2, m, 1] in :data:`HEIGHT_MODEL_KEYS` order.
    prior_sigma : ndarray (2,)
        The weak priors' 1-sigma [m, fraction].
    determined : bool
        False when the data do not determine the pair: a posterior variance above a
        quarter of the prior variance.  The estimate and sigma then come from the
        prior, and a warning says so.
    cross_labels : list of str
        ``RADAR.key`` labels of the calibration's ``covariance``; with
        ``cross_covariance`` the joint covariance of the radar terms and the pair.
    cross_covariance : ndarray (p, 2)
        Covariance of each radar term (row, in its contract unit) with the pair.
    n_adsb_segments : int
        ADS-B aircraft segments in the height factor (reports with both heights).
    n_pressure_pairs : int
        Observations that use a pressure altitude: cross-radar pairs whose 2-D plots
        were placed at a modelled height (``--cross pairwise``), or 2-D plots whose
        reported pressure altitude measures their aircraft's path (the trajectory
        formulation).
    """

    height_offset_m: float
    height_scale: float
    covariance: FloatArray
    prior_sigma: FloatArray
    determined: bool = True
    cross_labels: list[str] = field(default_factory=list)
    cross_covariance: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    n_adsb_segments: int = 0
    n_pressure_pairs: int = 0

    @property
    def model(self) -> HeightModel:
        """The estimate as a :class:`HeightModel`."""
        return HeightModel(self.height_offset_m, self.height_scale)

    @property
    def sigma(self) -> dict[str, float]:
        """1-sigma of each parameter, by result key."""
        diag = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return dict(zip(HEIGHT_MODEL_KEYS, (float(v) for v in diag), strict=True))

    def to_dict(self) -> dict[str, Any]:
        """The ``atmosphere`` block of the result JSON."""
        return {
            "height_offset_m": float(self.height_offset_m),
            "height_scale": float(self.height_scale),
            "sigma": self.sigma,
            "determined": bool(self.determined),
            "prior_sigma": dict(zip(HEIGHT_MODEL_KEYS, (float(v) for v in self.prior_sigma),
                                    strict=True)),
            "covariance": {"labels": list(HEIGHT_MODEL_KEYS),
                           "matrix": np.asarray(self.covariance, dtype=float).tolist()},
            "cross_covariance": {"labels": list(self.cross_labels),
                                 "matrix": np.asarray(self.cross_covariance,
                                                      dtype=float).tolist()},
            "n_adsb_segments": int(self.n_adsb_segments),
            "n_pressure_pairs": int(self.n_pressure_pairs),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> HeightModelEstimate:
        """Rebuild from the ``atmosphere`` block (``to_dict``'s form).

        Only ``height_offset_m``, ``height_scale`` and ``sigma`` are required; a
        block without ``covariance`` gets a diagonal one from the sigmas.

        Raises
        ------
        ValueError
            A missing or non-numeric value, naming the key.
        """

        def number(value: Any, where: str) -> float:
            if value is None:
                return float("nan")
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"atmosphere.{where}: {value!r} is not a number")
            return float(value)

        if not isinstance(data, Mapping):
            raise ValueError("atmosphere: not an object")
        for key in HEIGHT_MODEL_KEYS:
            if key not in data:
                raise ValueError(f"atmosphere.{key}: missing")
        sigma = data.get("sigma") or {}
        if not isinstance(sigma, Mapping):
            raise ValueError("atmosphere.sigma: not an object")
        cov_entry = data.get("covariance")
        if isinstance(cov_entry, Mapping) and cov_entry.get("matrix") is not None:
            covariance = np.array([[number(v, "covariance.matrix") for v in row]
                                   for row in cov_entry["matrix"]], dtype=float).reshape(2, 2)
        else:
            covariance = np.diag([number(sigma.get(k), f"sigma.{k}") ** 2
                                  for k in HEIGHT_MODEL_KEYS])
        prior = data.get("prior_sigma") or {}
        cross = data.get("cross_covariance") or {}
        labels = [str(v) for v in cross.get("labels") or []]
        matrix = np.array([[number(v, "cross_covariance.matrix") for v in row]
                           for row in cross.get("matrix") or []], dtype=float).reshape(-1, 2)
        return cls(
            height_offset_m=number(data["height_offset_m"], "height_offset_m"),
            height_scale=number(data["height_scale"], "height_scale"),
            covariance=covariance,
            prior_sigma=np.array([number(prior.get(k), f"prior_sigma.{k}")
                                  for k in HEIGHT_MODEL_KEYS]),
            determined=bool(data.get("determined", True)),
            cross_labels=labels,
            cross_covariance=matrix,
            n_adsb_segments=int(data.get("n_adsb_segments") or 0),
            n_pressure_pairs=int(data.get("n_pressure_pairs") or 0),
        )
