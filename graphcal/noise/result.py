"""The result of a noise estimate: :class:`NoiseEstimate`, one radar's random-error sigmas.

Sigmas are 1-sigma random (zero-mean, plot-to-plot independent) errors of the
radar's polar measurements: range [m], azimuth and elevation [mrad] (the
attributes ``sigma_azimuth_rad`` and ``sigma_elevation_rad`` give radians).

Estimates are robust by default (median absolute deviation) and come with
their own standard errors: ``sigma / sqrt(2 n_dof)`` for the root mean square,
``1.166 sigma / sqrt(n_dof)`` for the MAD (:data:`MAD_SE_FACTOR`; its
asymptotic efficiency is 37 %).  A radar that cannot be estimated (too few
usable plots or windows) gets a :class:`NoiseEstimate` with ``estimated=False``,
NaN sigmas and the reason (:func:`not_estimated`), so that one radar does not
stop the others.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

#: Standard error of a MAD-based sigma is ``MAD_SE_FACTOR * sigma / sqrt(n)``
#: (asymptotic variance ``1.3605 sigma^2 / n``, efficiency 37 % of the standard deviation).
#: ``sqrt(0.25 / (2 phi(q))^2 / q^2)`` with ``q = Phi^-1(3/4)`` (the value scipy gives).
MAD_SE_FACTOR = 1.1663872874444212


@dataclass(frozen=True)
class NoiseEstimate:
    """Estimated random-error sigmas of one radar.

    Attributes
    ----------
    radar_id : str
        The radar.
    sigma_range_m : float
        1-sigma random range error [m]; NaN when not estimated.
    sigma_azimuth_mrad : float
        1-sigma random azimuth error [mrad]; NaN when not estimated.
    sigma_elevation_mrad : float or None
        1-sigma random elevation error [mrad] (3-D radars); ``None`` for 2-D radars.
    n_plots_used : int
        Plots whose residuals entered the estimate.
    n_legs : int
        Straight-leg windows used (line fit); 0 for the ADS-B method.
    method : str
        ``"line-fit"`` or ``"adsb"``.
    se_range_m, se_azimuth_mrad : float
        Standard errors of the two sigmas, same units.
    se_elevation_mrad : float or None
        Standard error of the elevation sigma [mrad].
    estimated : bool
        False when the radar had too little usable data; then the sigmas are NaN.
    reason : str
        Why the radar was not estimated (empty when it was).
    details : dict
        Diagnostics: the non-robust (root-mean-square) estimates, the paper's pooled
        ``sigma_x_m``, ``sigma_y_m``, ``sigma_p_m`` (line fit), the Mode C height sigma
        of 2-D radars, the removed biases (ADS-B), ...
    """

    radar_id: str
    sigma_range_m: float
    sigma_azimuth_mrad: float
    sigma_elevation_mrad: float | None
    n_plots_used: int
    n_legs: int
    method: str
    se_range_m: float = math.nan
    se_azimuth_mrad: float = math.nan
    se_elevation_mrad: float | None = None
    estimated: bool = True
    reason: str = ""
    details: dict[str, float] = field(default_factory=dict)

    @property
    def sigma_azimuth_rad(self) -> float:
        """1-sigma azimuth error [rad]."""
        return self.sigma_azimuth_mrad * 1e-3

    @property
    def sigma_elevation_rad(self) -> float | None:
        """1-sigma elevation error [rad], ``None`` for 2-D radars."""
        return None if self.sigma_elevation_mrad is None else self.sigma_elevation_mrad * 1e-3


def not_estimated(radar_id: str, method: str, is_3d: bool, reason: str) -> NoiseEstimate:
    """A :class:`NoiseEstimate` flagged ``estimated=False``: NaN sigmas, no plots, the reason.

    The elevation sigma is NaN for a 3-D radar and ``None`` for a 2-D radar.
    """
    return NoiseEstimate(
        radar_id, math.nan, math.nan, math.nan if is_3d else None, 0, 0, method,
        se_elevation_mrad=math.nan if is_3d else None, estimated=False, reason=reason,
    )
