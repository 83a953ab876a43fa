"""Biases that change over time: a linear drift and steps (contract v2, biases over time).

Radar biases are not constants: an azimuth alignment drifts with temperature, a
range offset jumps after maintenance.  A :class:`BiasSchedule` is one radar's
biases as a function of time::

    beta(t) = beta_0 + (t - t_ref) * drift + sum_{steps with t_k <= t} delta_k

in SI units per term (:class:`graphcal.data.bias.RadarBias` holds ``beta_0``,
the drift per second and each step's ``delta_k``).  The time-stamping bias is
kept constant (a drifting clock would move the plots' times themselves).

Over a window ``[t_a, t_b)`` the mean bias, what a windowed calibration estimates
(contract v2 ``series``), is exact: the drift averages to its value at the
window's middle, and a step at ``t_k`` inside the window counts with the share
``(t_b - t_k) / (t_b - t_a)`` of the window after it (:meth:`BiasSchedule.mean`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from graphcal.data.bias import CONTRACT_KEYS, RadarBias

FloatArray = NDArray[np.float64]

#: The terms that may drift or step (all but the time-stamping bias).
VARYING_TERMS: tuple[str, ...] = (
    "range_offset_m", "range_gain", "azimuth_bias_rad", "elevation_bias_rad",
    "azimuth_sin_rad", "azimuth_cos_rad",
)


def _scaled_sum(parts: list[tuple[float | FloatArray, RadarBias]], base: RadarBias
                ) -> dict[str, Any]:
    """``base + sum_k weight_k * bias_k`` term by term (weights scalar or arrays)."""
    out: dict[str, Any] = {f.name: getattr(base, f.name) for f in fields(RadarBias)}
    for weight, bias in parts:
        for name in VARYING_TERMS:
            value = getattr(bias, name)
            if value != 0.0:
                out[name] = out[name] + weight * value
    return out


@dataclass(frozen=True)
class BiasStep:
    """A change of the biases at one time.

    Attributes
    ----------
    time_s : float
        When it happens [s], on the dataset's time base.
    change : RadarBias
        The change of each term (SI); its time offset must be 0.
    """

    time_s: float
    change: RadarBias


@dataclass(frozen=True)
class BiasSchedule:
    """One radar's biases over time (module docstring).

    Attributes
    ----------
    initial : RadarBias
        The biases at ``reference_time_s`` (before any step).
    drift_per_s : RadarBias
        Rate of change of each term per second (SI per s); time offset 0.
    steps : tuple of BiasStep
        Sorted by time.
    reference_time_s : float
        Time [s] at which the biases are ``initial``.
    """

    initial: RadarBias
    drift_per_s: RadarBias = RadarBias()
    steps: tuple[BiasStep, ...] = ()
    reference_time_s: float = 0.0

    def __post_init__(self) -> None:
        if self.drift_per_s.time_offset_s != 0.0 or any(
                s.change.time_offset_s != 0.0 for s in self.steps):
            raise ValueError("the time-stamping bias cannot drift or step")
        times = [s.time_s for s in self.steps]
        if times != sorted(times):
            raise ValueError("bias steps must be in time order")

    @property
    def constant(self) -> bool:
        """True without drift and steps."""
        return not self.steps and all(
            getattr(self.drift_per_s, name) == 0.0 for name in VARYING_TERMS)

    def at(self, time_s: ArrayLike) -> dict[str, Any]:
        """Every term at the given times: ``{field name: array}`` (SI, RadarBias's names)."""
        t = np.asarray(time_s, dtype=float)
        parts: list[tuple[float | FloatArray, RadarBias]] = [
            (t - self.reference_time_s, self.drift_per_s)]
        parts += [((t >= s.time_s).astype(float), s.change) for s in self.steps]
        out = _scaled_sum(parts, self.initial)
        return {name: np.broadcast_to(np.asarray(value, dtype=float), t.shape).copy()
                for name, value in out.items()}

    def bias_at(self, time_s: float) -> RadarBias:
        """The biases at one time."""
        return RadarBias(**{name: float(v) for name, v in self.at(float(time_s)).items()})

    def mean(self, start_s: float, end_s: float) -> RadarBias:
        """The exact mean of the biases over ``[start_s, end_s)`` (module docstring)."""
        if not end_s > start_s:
            raise ValueError(f"empty window [{start_s}, {end_s})")
        parts: list[tuple[float | FloatArray, RadarBias]] = [
            (0.5 * (start_s + end_s) - self.reference_time_s, self.drift_per_s)]
        for s in self.steps:
            share = float(np.clip((end_s - s.time_s) / (end_s - start_s), 0.0, 1.0))
            parts.append((share, s.change))
        return RadarBias(**{name: float(v)
                            for name, v in _scaled_sum(parts, self.initial).items()})


#: Term name -> RadarBias field.
_FIELDS: dict[str, str] = {
    "range_offset": "range_offset_m", "range_gain": "range_gain",
    "azimuth_bias": "azimuth_bias_rad", "elevation_bias": "elevation_bias_rad",
    "time_offset": "time_offset_s", "azimuth_sin": "azimuth_sin_rad",
    "azimuth_cos": "azimuth_cos_rad",
}


def _bias_from_contract(entry: Mapping[str, Any], per: float = 1.0) -> RadarBias:
    """A RadarBias (SI) from contract-keyed values divided by ``per`` (null/missing: 0)."""
    values = {}
    for name, (key, factor) in CONTRACT_KEYS.items():
        value = entry.get(key)
        if value is not None:
            values[_FIELDS[name]] = float(value) / factor / per
    return RadarBias(**values)


def schedules_from_truth(truth: Mapping[str, Any]) -> dict[str, BiasSchedule]:
    """Each radar's :class:`BiasSchedule` from a simulation's ``truth.json`` document:
    its ``radars`` (the biases at time 0, contract units) and its ``drift`` block (rates
    per hour and steps), when present."""
    drift = truth.get("drift") or {}
    schedules = {}
    for rid, entry in (truth.get("radars") or {}).items():
        own = drift.get(rid) or {}
        rates = _bias_from_contract(own.get("per_h") or {}, per=3600.0)
        steps = tuple(BiasStep(float(step["time_s"]),
                               _bias_from_contract({k: v for k, v in step.items()
                                                    if k != "time_s"}))
                      for step in own.get("steps") or [])
        schedules[rid] = BiasSchedule(_bias_from_contract(entry), rates, steps)
    return schedules


def truth_over_windows(truth: Mapping[str, Any], spans: Mapping[str, tuple[float, float]]
                       ) -> dict[str, Any]:
    """``truth`` with each radar's biases replaced by their mean over its span
    ``(t_start_s, t_end_s)`` (contract units): what a windowed result's last window
    estimates.  Radars without a span keep their entry."""
    schedules = schedules_from_truth(truth)
    radars = {}
    for rid, entry in (truth.get("radars") or {}).items():
        if rid not in spans:
            radars[rid] = entry
            continue
        mean = schedules[rid].mean(*spans[rid])
        new = dict(entry)
        for name, (key, factor) in CONTRACT_KEYS.items():
            if entry.get(key) is not None:
                new[key] = mean.value(name) * factor
        radars[rid] = new
    return {**truth, "radars": radars}


__all__ = ["VARYING_TERMS", "BiasSchedule", "BiasStep", "schedules_from_truth",
           "truth_over_windows"]
