"""Remove estimated (or known) biases from a dataset's plots.

Correcting a plot applies the inverse of the contract's bias model
(:func:`graphcal.data.bias.correct_bias`, :func:`graphcal.data.bias.correct_time`)::

    range_true     = (range_measured - range_offset_m) / (1 + range_gain)
    azimuth_true   = azimuth_measured - azimuth_bias        (wrapped to [0, 360) deg)
    elevation_true = elevation_measured - elevation_bias    (3-D radars only)
    time_true      = time_reported - time_offset_s

Only the plots of the radars the calibration covers change, and only in
``range_m``, ``azimuth_deg``, ``elevation_deg`` (3-D radars) and ``time_s``;
every other column, the sites and the ADS-B table are kept as they are.

A correction that would give a non-finite value or a negative range (a range gain
of -1, an offset larger than the ranges) raises
:class:`~graphcal.core.errors.ResultError` naming the radar and the first such plot,
instead of writing it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd

from graphcal.core.errors import ResultError
from graphcal.data.bias import RadarBias, correct_bias, correct_time
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset

#: What :func:`correct_dataset` accepts as biases.
Biases = Calibration | Mapping[str, RadarBias]


def biases_of(calibration: Biases) -> dict[str, RadarBias]:
    """Per-radar :class:`RadarBias` of a calibration (or a mapping of them, returned as a dict)."""
    if isinstance(calibration, Calibration):
        return {rid: calibration.bias(rid) for rid in calibration.radar_ids}
    return {str(rid): bias for rid, bias in calibration.items()}


def _wrap_deg(azimuth_deg: np.ndarray) -> np.ndarray:
    """Azimuth wrapped to [0, 360) deg (``np.mod`` may round a tiny negative up to 360)."""
    out = np.mod(azimuth_deg, 360.0)
    out[out >= 360.0] = 0.0
    return out


def correct_plots(plots: pd.DataFrame, sites: Mapping, biases: Mapping[str, RadarBias]
                  ) -> pd.DataFrame:
    """A copy of a plots table with the biases of ``biases`` removed (see module doc).

    Radars of ``biases`` that have no plots, and plots of radars not in
    ``biases``, are left alone.  The row order and the index are kept.
    """
    out = plots.copy()
    radar_col = out["radar_id"].to_numpy()
    for rid, bias in biases.items():
        rows = np.flatnonzero(radar_col == rid)
        if rows.size == 0:
            continue
        sel = out.index[rows]
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):  # checked below
            r, az, el = correct_bias(
                out.loc[sel, "range_m"].to_numpy(float),
                np.deg2rad(out.loc[sel, "azimuth_deg"].to_numpy(float)),
                np.deg2rad(out.loc[sel, "elevation_deg"].to_numpy(float)),
                bias,
            )
        _check_corrected(rid, sel, r, az, el, time_s=None)
        out.loc[sel, "range_m"] = r
        out.loc[sel, "azimuth_deg"] = _wrap_deg(np.rad2deg(az))
        site = sites.get(rid)
        if site is not None and site.is_3d:
            out.loc[sel, "elevation_deg"] = np.rad2deg(el)
        if bias.time_offset_s != 0.0:
            time_s = correct_time(out.loc[sel, "time_s"].to_numpy(float), bias)
            _check_corrected(rid, sel, None, None, None, time_s=time_s)
            out.loc[sel, "time_s"] = time_s
    return out


def _check_corrected(rid: str, index: pd.Index, range_m: np.ndarray | None,
                     azimuth_rad: np.ndarray | None, elevation_rad: np.ndarray | None,
                     *, time_s: np.ndarray | None) -> None:
    """Raise :class:`ResultError` when a corrected value is not finite or a range negative.

    Elevations that were missing (2-D radars) stay missing and pass.
    """
    checks: list[tuple[str, np.ndarray]] = []
    if range_m is not None:
        checks.append(("range_m", ~np.isfinite(range_m) | (range_m < 0.0)))
    if azimuth_rad is not None:
        checks.append(("azimuth_deg", ~np.isfinite(azimuth_rad)))
    if elevation_rad is not None:
        checks.append(("elevation_deg", np.isinf(elevation_rad)))
    if time_s is not None:
        checks.append(("time_s", ~np.isfinite(time_s)))
    for column, bad in checks:
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            values = {"range_m": range_m, "time_s": time_s}.get(column)
            shown = "" if values is None else f" ({values[first]:.6g})"
            raise ResultError(
                f"correcting radar {rid}'s plots with these biases gives {int(bad.sum())} "
                f"non-finite or negative {column} values (first at plot row "
                f"{index[first]}{shown}); nothing was written: the result does not fit this "
                "dataset")


def correct_dataset(dataset: Dataset, calibration: Biases) -> Dataset:
    """A new dataset whose plots have the calibration's biases removed.

    Parameters
    ----------
    dataset : Dataset
        The measured dataset; it is not modified.
    calibration : Calibration or mapping of radar id to RadarBias
        The biases (a :class:`Calibration`'s :meth:`~Calibration.bias`, which
        includes fixed terms; or e.g. :func:`graphcal.data.calibration.read_biases`
        of a result or ``truth.json``).

    Returns
    -------
    Dataset
        Same sites and ADS-B table (copied), corrected plots, ``path`` None.
    """
    biases = biases_of(calibration)
    plots = correct_plots(dataset.plots, dataset.sites, biases)
    adsb = None if dataset.adsb is None else dataset.adsb.copy()
    return Dataset(dict(dataset.sites), plots, adsb, None, plot_altitude=dataset.plot_altitude,
                   epoch_utc=dataset.epoch_utc)
