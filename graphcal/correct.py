"""Remove estimated (or known) biases from a dataset's plots.

Correcting a plot applies the inverse of the contract's bias model
(:func:`graphcal.bias.correct_bias`, :func:`graphcal.bias.correct_time`)::

    range_true     = (range_measured - range_offset_m) / (1 + range_gain)
    azimuth_true   = azimuth_measured - azimuth_bias        (wrapped to [0, 360) deg)
    elevation_true = elevation_measured - elevation_bias    (3-D radars only)
    time_true      = time_reported - time_offset_s

Only the plots of the radars the calibration covers change, and only in
``range_m``, ``azimuth_deg``, ``elevation_deg`` (3-D radars) and ``time_s``;
every other column, the sites and the ADS-B table are kept as they are.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from graphcal.bias import RadarBias, correct_bias, correct_time
from graphcal.calibration import Calibration
from graphcal.dataset import Dataset, write_dataset

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
        r, az, el = correct_bias(
            out.loc[sel, "range_m"].to_numpy(float),
            np.deg2rad(out.loc[sel, "azimuth_deg"].to_numpy(float)),
            np.deg2rad(out.loc[sel, "elevation_deg"].to_numpy(float)),
            bias,
        )
        out.loc[sel, "range_m"] = r
        out.loc[sel, "azimuth_deg"] = _wrap_deg(np.rad2deg(az))
        site = sites.get(rid)
        if site is not None and site.is_3d:
            out.loc[sel, "elevation_deg"] = np.rad2deg(el)
        if bias.time_offset_s != 0.0:
            out.loc[sel, "time_s"] = correct_time(out.loc[sel, "time_s"].to_numpy(float), bias)
    return out


def correct_dataset(dataset: Dataset, calibration: Biases) -> Dataset:
    """A new dataset whose plots have the calibration's biases removed.

    Parameters
    ----------
    dataset : Dataset
        The measured dataset; it is not modified.
    calibration : Calibration or mapping of radar id to RadarBias
        The biases (a :class:`Calibration`'s :meth:`~Calibration.bias`, which
        includes fixed terms; or e.g. :func:`graphcal.calibration.read_biases`
        of a result or ``truth.json``).

    Returns
    -------
    Dataset
        Same sites and ADS-B table (copied), corrected plots, ``path`` None.
    """
    biases = biases_of(calibration)
    plots = correct_plots(dataset.plots, dataset.sites, biases)
    adsb = None if dataset.adsb is None else dataset.adsb.copy()
    return Dataset(dict(dataset.sites), plots, adsb, None)


def _table_format(folder: Path | None) -> str:
    """``parquet`` when the source dataset's plots are Parquet, else ``csv``."""
    if folder is not None and (Path(folder) / "plots.parquet").exists():
        return "parquet"
    return "csv"


def correct_folder(
    dataset_dir: str | Path, result: str | Path, out: str | Path, *, overwrite: bool = False
) -> Dataset:
    """Read a dataset folder and a result JSON, write the corrected dataset to ``out``.

    ``result`` may be a calibration result or a simulation's ``truth.json``
    (read with :func:`graphcal.calibration.read_biases`).  The output keeps the
    table format of the input and is written atomically
    (:func:`graphcal.dataset.write_dataset`); ``dataset_dir`` is only read.

    Raises
    ------
    DatasetError
        Bad input dataset, ``out`` is ``dataset_dir``, or ``out`` exists and is
        not empty without ``overwrite``.
    ResultError
        Bad result file.
    """
    from graphcal.calibration import read_biases
    from graphcal.dataset import load_dataset
    from graphcal.errors import DatasetError

    dataset_dir, out = Path(dataset_dir), Path(out)
    if out.exists() and dataset_dir.exists() and out.resolve() == dataset_dir.resolve():
        raise DatasetError("the output folder must differ from the input dataset", path=out)
    dataset = load_dataset(dataset_dir)
    biases = read_biases(result)
    corrected = correct_dataset(dataset, biases)
    write_dataset(corrected, out, fmt=_table_format(dataset_dir), overwrite=overwrite)
    corrected.path = out
    return corrected
