"""Plain words for a structure the model checks found: its shape, size and likely cause.

:func:`describe` reads the bin means a test left unexplained (``mean - absorbed``
of :class:`graphcal.analysis.binned_test.BinnedMeans`) and names:

* the **pattern**: against range, elevation or height, where the largest excess
  is: "growing with range", "growing towards the horizon", "bending with range"
  (both ends the same sign, e.g. a quadratic left after a range gain took the
  line), else "varying with range"; against azimuth, "sinusoidal in azimuth"
  when a fitted ``s sin(az) + c cos(az)`` explains at least
  :data:`PATTERN_SHARE` of the chi-square, else "varying with azimuth"; against
  time, "stepping near t = ..." or "drifting in time" when a step or a line
  explains that share, else "varying in time";
* its **magnitude** in the residual's unit (largest excess and where, the
  sinusoid's amplitude and peak, the step's size);
* the likely **cause**: elevation or range against elevation, range or height
  -> refraction (2-D radar against height without ADS-B -> pressure altitudes);
  reported altitude -> pressure altitudes (when the dataset declares them: ones the
  height model does not describe); azimuth sinusoidal in azimuth ->
  antenna eccentricity; elevation sinusoidal in azimuth -> the antenna not
  level; range against azimuth or azimuth against range -> the site position;
  anything against time -> a bias drifting or stepping in time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graphcal.analysis.binned_test import BinnedMeans

FloatArray = NDArray[np.float64]

#: A fitted sinusoid (azimuth), step or line (time) names the pattern when it
#: explains at least this fraction of the chi-square.
PATTERN_SHARE = 0.6

REFRACTION = "refraction not modelled"
PRESSURE = "pressure altitudes (Mode C heights taken as geometric)"
PRESSURE_MODEL = ("pressure altitudes that one height offset and scale do not describe "
                  "(a non-standard temperature profile, or altitudes of several sources)")
DRIFT = "a bias drifting or stepping in time"
SITE = "an error in the radar's surveyed position"

#: Words for the two ends of an ordered variable: (low end, high end).
_ENDS: dict[str, tuple[str, str]] = {
    "range": ("towards short range", "with range"),
    "elevation": ("towards the horizon", "with elevation"),
    "height": ("towards low heights", "with height"),
}


@dataclass(frozen=True)
class Description:
    """What :func:`describe` says about one test's structure."""

    pattern: str
    magnitude: str
    cause: str


def fraction_explained(excess: FloatArray, sigma: FloatArray, columns: list[FloatArray]
                       ) -> tuple[float, FloatArray, FloatArray]:
    """Share of ``sum (excess / sigma)^2`` a weighted fit of ``columns`` explains.

    Returns the share, the fitted values and the coefficients.
    """
    a = np.stack(columns, axis=1)
    coef, *_ = np.linalg.lstsq(a / sigma[:, None], excess / sigma, rcond=None)
    fit = a @ coef
    total = float(np.sum((excess / sigma) ** 2))
    left = float(np.sum(((excess - fit) / sigma) ** 2))
    return (1.0 - left / total if total > 0 else 0.0), fit, coef


def _ordered(var: str, b: BinnedMeans, u: str, vu: str) -> tuple[str, str]:
    """Pattern and magnitude against range, elevation or height."""
    excess = b.excess
    j = int(np.argmax(np.abs(excess)))
    last = len(b) - 1
    at = f"{excess[j]:+.2g} {u} at {b.centre[j]:.3g} {vu}"
    low, high = _ENDS[var]
    ends = excess[[0, last]]
    big = np.abs(ends) >= np.maximum(0.5 * abs(excess[j]), 2.0 * b.sigma[[0, last]])
    if np.all(big) and np.sign(ends[0]) == np.sign(ends[1]):
        return (f"bending with {var}",
                f"{ends[0]:+.2g} {u} at {b.centre[0]:.3g} {vu}, "
                f"{ends[1]:+.2g} {u} at {b.centre[last]:.3g} {vu}")
    if j == 0:
        return f"growing {low}", at
    if j == last:
        return f"growing {high}", at
    return f"varying with {var}", at


def _in_time(b: BinnedMeans, u: str) -> tuple[str, str]:
    """Pattern and magnitude against time: a step, a drift or neither."""
    excess, t = b.excess, b.centre
    ones = np.ones(len(b))
    line_share, line_fit, _ = fraction_explained(excess, b.sigma, [ones, t - t.mean()])
    step_share, split, step_fit = -1.0, 1, ones
    for k in range(1, len(b)):
        share, fit, _ = fraction_explained(excess, b.sigma,
                                           [ones, (np.arange(len(b)) >= k).astype(float)])
        if share > step_share:
            step_share, split, step_fit = share, k, fit
    if step_share >= PATTERN_SHARE and step_share >= line_share:
        when = 0.5 * (b.upper[split - 1] + b.lower[split])
        return (f"stepping near t = {when:.0f} s",
                f"step {step_fit[split] - step_fit[split - 1]:+.2g} {u}")
    if line_share >= PATTERN_SHARE:
        return ("drifting in time",
                f"{line_fit[-1] - line_fit[0]:+.2g} {u} over {t[-1] - t[0]:.0f} s")
    j = int(np.argmax(np.abs(excess)))
    return "varying in time", f"{excess[j]:+.2g} {u} at t = {t[j]:.0f} s"


def cause(coordinate: str, variable: str, *, is_3d: bool, reference: str,
          sinusoidal: bool = False, gain_modelled: bool = True, pressure: bool = False) -> str:
    """The likely cause of structure in ``coordinate`` against ``variable`` (module doc).

    ``pressure``: the dataset declares its plots' altitudes pressure altitudes
    (the height model is then part of the model).
    """
    if variable == "time":
        return DRIFT
    if coordinate == "altitude" or (not is_3d and variable == "height" and reference == "cross"):
        return PRESSURE_MODEL if pressure else PRESSURE
    if coordinate in ("range", "elevation") and variable in ("range", "elevation", "height"):
        if (coordinate, variable) == ("range", "range") and not gain_modelled:
            return REFRACTION + " (or a range gain, which this radar's model leaves out)"
        return REFRACTION
    if (coordinate, variable) == ("azimuth", "azimuth"):
        return ("antenna eccentricity not modelled" if sinusoidal
                else "an azimuth error that depends on the azimuth (encoder, antenna)")
    if (coordinate, variable) == ("elevation", "azimuth"):
        return ("the antenna not level (tilt)" if sinusoidal
                else "an elevation error that depends on the azimuth")
    if (coordinate, variable) in (("range", "azimuth"), ("azimuth", "range")):
        return SITE
    return "an error the model lacks"


def describe(
    coordinate: str,
    variable: str,
    bins: BinnedMeans,
    unit: str,
    variable_unit: str,
    *,
    is_3d: bool,
    reference: str,
    gain_modelled: bool = True,
    pressure: bool = False,
) -> Description:
    """Pattern, magnitude and likely cause of one test's structure (module doc).

    Parameters
    ----------
    coordinate, variable : str
        The residual and what it was binned against.
    bins : BinnedMeans
        The test's bins (centres in ``variable_unit``, means in ``unit``).
    unit, variable_unit : str
        Units, for the magnitude's text.
    is_3d : bool
        The radar measures elevation.
    reference : {"adsb", "cross"}
    gain_modelled : bool
        The radar's model has a range gain.
    pressure : bool
        The plots' altitudes are declared pressure altitudes.
    """
    sinusoidal = False
    if variable in _ENDS:
        pattern, magnitude = _ordered(variable, bins, unit, variable_unit)
    elif variable == "azimuth":
        az = np.deg2rad(bins.centre)
        share, _, (s, c) = fraction_explained(bins.excess, bins.sigma, [np.sin(az), np.cos(az)])
        sinusoidal = share >= PATTERN_SHARE
        if sinusoidal:
            # s sin(az) + c cos(az) = A sin(az + phase), largest at az = atan2(s, c).
            peak = math.degrees(math.atan2(s, c)) % 360.0
            pattern = "sinusoidal in azimuth"
            magnitude = f"amplitude {math.hypot(s, c):.2g} {unit}, peak near {peak:.0f} deg"
        else:
            j = int(np.argmax(np.abs(bins.excess)))
            pattern = "varying with azimuth"
            magnitude = f"{bins.excess[j]:+.2g} {unit} at {bins.centre[j]:.0f} deg"
    else:
        pattern, magnitude = _in_time(bins, unit)
    if coordinate == "altitude":
        # No model term absorbs a mean altitude offset: it is part of the finding.
        mean = float(np.sum(bins.mean * bins.n_plots) / np.sum(bins.n_plots))
        magnitude = f"mean {mean:+.3g} {unit}; {magnitude}"
    return Description(pattern, magnitude, cause(coordinate, variable, is_3d=is_3d,
                                                 reference=reference, sinusoidal=sinusoidal,
                                                 gain_modelled=gain_modelled, pressure=pressure))


__all__ = ["PATTERN_SHARE", "Description", "cause", "describe", "fraction_explained"]
