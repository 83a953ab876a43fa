"""Paper 000's variance lookup table: a radar's sigmas per range and azimuth bin.

Paper 000 (sec. 2) keeps the straight-line statistics of eq. 8-10 per bin of
range and azimuth, so that the sigmas can be looked up where a plot is.
:func:`variance_table` builds it from the line-fit residuals of
:mod:`graphcal.noise.line_fit`: per bin, the Cartesian sigmas ``sigma_x``,
``sigma_y`` (and ``sigma_z`` for 3-D radars) [m] with the dof correction,
``sigma_p = sqrt((s_x^2 + s_y^2) / 2)`` (eq. 10, horizontal) [m], and the
polar sigmas (range [m], azimuth and elevation [mrad]).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.data.dataset import Dataset
from graphcal.noise.line_fit import (
    LineFitOptions,
    line_fit_residuals,
    line_fit_sigmas,
    standardised_residuals,
)
from graphcal.noise.variance import MAD_TO_SIGMA

FloatArray = NDArray[np.float64]


def variance_table(
    dataset: Dataset,
    radar_id: str,
    *,
    range_bin_m: float = 50_000.0,
    azimuth_bin_deg: float = 45.0,
    robust: bool = True,
    min_plots: int = 30,
    options: LineFitOptions | None = None,
) -> pd.DataFrame:
    """The paper's variance lookup table: sigmas per range and azimuth bin (sec. 2).

    From the line-fit residuals (:func:`line_fit_residuals`): per bin of the
    measured range and azimuth, the Cartesian sigmas of eq. 8-10 (corrected:
    residual RMS over ``sum (1 - h_ii)``; ``sigma_p = sqrt((s_x^2 + s_y^2)/2)``,
    eq. 10) and the polar sigmas (residuals standardised by their variance
    coefficients with the radar-wide sigma ratios, then MAD or RMS).

    Parameters
    ----------
    dataset : Dataset
    radar_id : str
    range_bin_m : float
        Width of the range bins [m], from 0.
    azimuth_bin_deg : float
        Width of the azimuth bins [deg], from north; must divide into 360 or
        the last bin is narrower.
    robust : bool
        MAD (default) or RMS per bin.
    min_plots : int
        Bins with fewer plots get NaN sigmas (their counts are kept).
    options : LineFitOptions, optional

    Returns
    -------
    pandas.DataFrame
        One row per non-empty bin: ``radar_id``, ``range_min_m``,
        ``range_max_m``, ``azimuth_min_deg``, ``azimuth_max_deg``, ``n_plots``,
        ``n_legs``, ``sigma_x_m``, ``sigma_y_m``, ``sigma_p_m``,
        ``sigma_range_m``, ``sigma_azimuth_mrad`` and, for 3-D radars,
        ``sigma_z_m`` and ``sigma_elevation_mrad``.

    Raises
    ------
    ValueError
        For non-positive bin widths, an unknown radar, or a radar without
        enough straight windows.
    """
    if range_bin_m <= 0 or azimuth_bin_deg <= 0:
        raise ValueError("range_bin_m and azimuth_bin_deg must be positive")
    opt = LineFitOptions() if options is None else options
    lf = line_fit_residuals(dataset, radar_id, opt)
    if lf.n_windows < opt.min_windows:
        raise ValueError(
            f"radar {radar_id!r}: {lf.n_windows} straight windows, need {opt.min_windows}"
        )
    sigma, _, lf = line_fit_sigmas(lf, robust, opt.window_p_value)
    z, _ = standardised_residuals(lf, sigma)
    cart = lf.cartesian_residual / np.sqrt(1.0 - lf.leverage)[:, None]
    r_bin = np.floor(lf.range_m / range_bin_m).astype(np.int64)
    a_bin = np.floor(np.degrees(lf.azimuth_rad) / azimuth_bin_deg).astype(np.int64)

    def scale(x: FloatArray) -> float:
        if robust:
            return float(MAD_TO_SIGMA * np.median(np.abs(x)))
        return float(np.sqrt(np.mean(x**2)))

    rows = []
    frame = pd.DataFrame({"r": r_bin, "a": a_bin})
    for (rb, ab), idx in frame.groupby(["r", "a"], sort=True).indices.items():
        n = len(idx)
        row: dict[str, float | int | str] = {
            "radar_id": radar_id,
            "range_min_m": rb * range_bin_m,
            "range_max_m": (rb + 1) * range_bin_m,
            "azimuth_min_deg": ab * azimuth_bin_deg,
            "azimuth_max_deg": min((ab + 1) * azimuth_bin_deg, 360.0),
            "n_plots": n,
            "n_legs": int(np.unique(lf.window[idx]).size),
        }
        enough = n >= min_plots
        sx = scale(cart[idx, 0]) if enough else math.nan
        sy = scale(cart[idx, 1]) if enough else math.nan
        row["sigma_x_m"] = sx
        row["sigma_y_m"] = sy
        row["sigma_p_m"] = math.sqrt((sx**2 + sy**2) / 2.0)
        row["sigma_range_m"] = scale(z[idx, 0]) if enough else math.nan
        row["sigma_azimuth_mrad"] = scale(z[idx, 1]) * 1e3 if enough else math.nan
        if lf.is_3d:
            row["sigma_z_m"] = scale(cart[idx, 2]) if enough else math.nan
            row["sigma_elevation_mrad"] = scale(z[idx, 2]) * 1e3 if enough else math.nan
        rows.append(row)
    return pd.DataFrame(rows)
