"""The calibration's parameters: which bias of which radar is free, fixed or a prior.

A radar's variable holds only its *free* bias terms; :class:`RadarTerms`
expands it to the full ``(range_offset_m, range_gain, azimuth_bias_rad,
elevation_bias_rad)`` vector with fixed terms at their known values, and gives
the radar's time-stamping bias ``time_offset_s`` (a fifth term, free only when
time offsets are estimated).  :func:`radar_terms` decides the free terms from a
site's ``estimate`` list, :func:`prior_sigmas` the weak priors that keep them
physically plausible, and :class:`ParameterLayout` the columns of the joint
state vector of the closed-form estimators.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from graphcal.data.bias import (
    CONTRACT_KEYS,
    ECCENTRICITY,
    ECCENTRICITY_NAMES,
    PARAMETER_NAMES,
    RadarBias,
    from_contract_units,
)
from graphcal.data.dataset import Site
from graphcal.data.sensor_models import load_sensor_model

FloatArray = NDArray[np.float64]

#: Every term a radar variable can hold: the four biases, the time-stamping bias, then
#: the azimuth eccentricity terms ``s`` and ``c`` (contract v2).
TERM_NAMES: tuple[str, ...] = (*PARAMETER_NAMES, "time_offset", *ECCENTRICITY_NAMES)


#: Prior 1-sigma of each term [SI] when the radar's sensor model gives no typical size.
DEFAULT_PRIOR_SIGMA: dict[str, float] = {
    "range_offset": 2000.0,
    "range_gain": 0.02,
    "azimuth_bias": 0.05,
    "elevation_bias": 0.02,
    "time_offset": 10.0,
    "azimuth_sin": 0.02,
    "azimuth_cos": 0.02,
}
#: With a sensor model, the prior sigma is at least this multiple of its typical bias.
PRIOR_TYPICAL_MULTIPLE = 25.0

@dataclass(frozen=True)
class RadarTerms:
    """Which of a radar's biases are estimated, and the known values of the others.

    Attributes
    ----------
    radar_id : str
    free : tuple of str
        Estimated terms, in :data:`TERM_NAMES` order.
    fixed : dict of str to float
        Terms held at a known value (SI); terms neither free nor fixed are 0.
    """

    radar_id: str
    free: tuple[str, ...]
    fixed: dict[str, float] = field(default_factory=dict, hash=False)

    @property
    def positions(self) -> list[int]:
        """Positions of the free terms in the full vector of :data:`TERM_NAMES`."""
        return [TERM_NAMES.index(name) for name in self.free]

    def full_terms(self, free_values: FloatArray) -> FloatArray:
        """Every term of :data:`TERM_NAMES` from the free values (fixed and zero terms filled)."""
        values = np.zeros(len(TERM_NAMES))
        for name, value in self.fixed.items():
            values[TERM_NAMES.index(name)] = value
        values[self.positions] = free_values
        return values

    def full(self, free_values: FloatArray) -> FloatArray:
        """The full bias 4-vector from the free values (SI)."""
        return self.full_terms(free_values)[:4]

    def time_offset(self, free_values: FloatArray) -> float:
        """The time-stamping bias [s]: free, fixed, or 0."""
        return float(self.full_terms(free_values)[4])

    def eccentricity(self, free_values: FloatArray) -> tuple[float, float]:
        """The azimuth eccentricity ``(s, c)`` [rad]: free, fixed, or 0."""
        values = self.full_terms(free_values)
        return float(values[5]), float(values[6])

    def bias(self, free_values: FloatArray) -> RadarBias:
        """Every term as a :class:`~graphcal.data.bias.RadarBias`."""
        v = self.full_terms(free_values)
        return RadarBias(*(float(x) for x in v[:5]), azimuth_sin_rad=float(v[5]),
                         azimuth_cos_rad=float(v[6]))

    def select(self, jacobian_full: FloatArray) -> FloatArray:
        """Columns of a Jacobian over the first k :data:`TERM_NAMES` that belong to the free terms.

        Missing trailing columns (a Jacobian over the four biases only, or without
        the eccentricity terms) are zero: the measurement does not depend on them.
        """
        missing = len(TERM_NAMES) - jacobian_full.shape[-1]
        if missing > 0:
            pad = np.zeros((*jacobian_full.shape[:-1], missing))
            jacobian_full = np.concatenate([jacobian_full, pad], axis=-1)
        return jacobian_full[..., self.positions]


def radar_terms(
    site: Site, fixed: dict[tuple[str, str], float], time_offset: bool = False
) -> RadarTerms:
    """Free and fixed terms of one radar: its ``estimate`` list minus the fixed ones.

    ``time_offset``: also estimate its time-stamping bias (unless fixed).
    """
    own_fixed = {name: value for (rid, name), value in fixed.items() if rid == site.id}
    for name in own_fixed:
        if name == "elevation_bias" and not site.is_3d:
            raise ValueError(f"radar {site.id} is 2-D: it has no elevation bias to fix")
    free = tuple(
        name for name in PARAMETER_NAMES
        if name in site.estimate and name not in own_fixed
        and (site.is_3d or name != "elevation_bias")
    )
    if time_offset and "time_offset" not in own_fixed:
        free = (*free, "time_offset")
    if ECCENTRICITY in site.estimate:
        free = (*free, *(name for name in ECCENTRICITY_NAMES if name not in own_fixed))
    return RadarTerms(site.id, free, own_fixed)


def terms_vector(bias: RadarBias) -> FloatArray:
    """A :class:`~graphcal.data.bias.RadarBias` as the full vector of :data:`TERM_NAMES`."""
    return np.array([bias.value(name) for name in TERM_NAMES])


def prior_sigmas(site: Site, terms: RadarTerms) -> FloatArray:
    """Prior 1-sigma [SI] of each free term.

    ``max(DEFAULT_PRIOR_SIGMA, PRIOR_TYPICAL_MULTIPLE x typical bias)``, the
    typical bias coming from the radar's sensor model when it names one.
    """
    typical: dict[str, float] = {}
    if site.model is not None:
        for key, value in load_sensor_model(site.model).typical_bias.items():
            for name, (contract_key, _) in CONTRACT_KEYS.items():
                if contract_key == key:
                    typical[name] = from_contract_units(name, value)
    return np.array([
        max(DEFAULT_PRIOR_SIGMA[name], PRIOR_TYPICAL_MULTIPLE * typical.get(name, 0.0))
        for name in terms.free
    ])


@dataclass(frozen=True)
class ParameterLayout:
    """Columns of the joint state vector: one block per radar, its estimated biases."""

    labels: tuple[tuple[str, str], ...]

    @classmethod
    def for_sites(cls, sites: list[Site], allowed: tuple[str, ...] = PARAMETER_NAMES):
        """Layout for ``sites``, keeping each site's ``estimate`` list within ``allowed``."""
        labels = []
        for site in sites:
            for name in PARAMETER_NAMES:
                if name in site.estimate and name in allowed:
                    if name == "elevation_bias" and not site.is_3d:
                        continue
                    labels.append((site.id, name))
        return cls(tuple(labels))

    def __len__(self) -> int:
        return len(self.labels)

    def columns(self, radar_id: str) -> tuple[list[int], list[int]]:
        """``(state columns, bias-vector positions)`` of one radar.

        Bias-vector positions index :data:`graphcal.data.bias.PARAMETER_NAMES`.
        """
        cols, positions = [], []
        for i, (rid, name) in enumerate(self.labels):
            if rid == radar_id:
                cols.append(i)
                positions.append(PARAMETER_NAMES.index(name))
        return cols, positions
