"""A radar's random-error sigmas estimated from its data.

The sigmas are the 1-sigma random errors of a radar's polar measurements:
range [m], azimuth and elevation [rad] (reported in mrad by
:class:`NoiseEstimate`).  Two independent methods:

1. **Straight legs** (:func:`estimate_noise_line_fit`,
   :mod:`graphcal.noise.line_fit`): paper 000's statistical method (eq. 3-10,
   corrected; the formulas are in :mod:`graphcal.noise.variance`), a straight line
   fitted in time to each straight constant-velocity leg of a target; the
   scatter of the plots about it is the noise.  No ADS-B is needed.  The paper's
   variance lookup table (sigmas per range/azimuth bin) is
   :func:`variance_table` (:mod:`graphcal.noise.lookup_table`).
2. **ADS-B** (:func:`estimate_noise_adsb`, :mod:`graphcal.noise.adsb`): each
   plot minus the interpolated ADS-B position of its aircraft, biases and the
   ADS-B error removed.

This module is the front end: :func:`estimate_noise` estimates every radar
(ADS-B where a radar has enough matched plots, else straight legs),
:func:`sites_with_estimated_sigmas` writes estimates into sites, and
:func:`fill_missing_sigmas` / the decorator :func:`fills_missing_sigmas` (used
by the estimators of :mod:`graphcal.solvers.registry`) fill the sigmas that
``sites.toml`` leaves out.  Estimates are robust by default and carry their own
standard errors; a radar that cannot be estimated gets a
:class:`NoiseEstimate` with ``estimated=False`` (:mod:`graphcal.noise.result`),
which :func:`sites_with_estimated_sigmas` leaves unchanged.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Literal

from graphcal.core.errors import DatasetError
from graphcal.data.align import align_adsb
from graphcal.data.dataset import Dataset, Site
from graphcal.noise.adsb import MIN_ADSB_PLOTS, estimate_noise_adsb
from graphcal.noise.line_fit import (
    LineFitOptions,
    LineFitResiduals,
    estimate_noise_line_fit,
    line_fit_residuals,
)
from graphcal.noise.lookup_table import variance_table
from graphcal.noise.result import MAD_SE_FACTOR, NoiseEstimate

if TYPE_CHECKING:
    from graphcal.data.calibration import Calibration

__all__ = [
    "DEFAULT_MIN_ADSB_PLOTS",
    "MAD_SE_FACTOR",
    "MIN_ADSB_PLOTS",
    "LineFitOptions",
    "LineFitResiduals",
    "NoiseEstimate",
    "describe_estimate",
    "filled_with_notes",
    "estimate_noise",
    "estimate_noise_adsb",
    "estimate_noise_line_fit",
    "estimated_sigmas_info",
    "fill_missing_sigmas",
    "fills_missing_sigmas",
    "line_fit_residuals",
    "sites_with_estimated_sigmas",
    "variance_table",
]

#: ``use_adsb="auto"`` uses ADS-B for a radar with at least this many ADS-B-matched plots.
DEFAULT_MIN_ADSB_PLOTS = 200


def estimate_noise(
    dataset: Dataset,
    *,
    use_adsb: bool | Literal["auto"] = "auto",
    radar_ids: Sequence[str] | None = None,
    robust: bool = True,
    min_adsb_plots: int = DEFAULT_MIN_ADSB_PLOTS,
    options: LineFitOptions | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, NoiseEstimate]:
    """Random-error sigmas of every radar (paper 000, corrected; or ADS-B).

    Parameters
    ----------
    dataset : Dataset
    use_adsb : bool or "auto"
        True: ADS-B residuals (:func:`estimate_noise_adsb`); False: straight-leg
        line fits (:func:`estimate_noise_line_fit`); ``"auto"``: ADS-B for a
        radar with at least ``min_adsb_plots`` ADS-B-matched plots, else line fits.
    radar_ids : sequence of str, optional
        Radars to estimate (default: all, in ``sites.toml`` order).
    robust : bool
        MAD-based sigmas (default) or root-mean-square.
    min_adsb_plots : int
        Threshold of ``"auto"``.
    options : LineFitOptions, optional
        Settings of the line-fit method.
    progress : callable, optional
        ``progress(radar_id, done, total)`` before each radar (and once at the end).

    Returns
    -------
    dict of str to NoiseEstimate
        One entry per radar; radars without enough data have ``estimated=False``.

    Raises
    ------
    ValueError
        If ``use_adsb`` is not True, False or "auto", ``use_adsb=True`` on a
        dataset without ADS-B, or a radar id is unknown.
    """
    if use_adsb not in (True, False, "auto"):
        raise ValueError(f"use_adsb must be True, False or 'auto', got {use_adsb!r}")
    if use_adsb is True and dataset.adsb is None:
        raise ValueError("use_adsb=True but the dataset has no ADS-B table")
    ids = list(dataset.sites) if radar_ids is None else list(radar_ids)
    for rid in ids:
        if rid not in dataset.sites:
            raise ValueError(f"unknown radar {rid!r}; radars: {', '.join(dataset.sites)}")
    out: dict[str, NoiseEstimate] = {}
    for done, rid in enumerate(ids):
        if progress is not None:
            progress(rid, done, len(ids))
        aligned = None
        if use_adsb == "auto":
            if dataset.adsb is not None:
                aligned = align_adsb(dataset, rid)
            adsb = aligned is not None and len(aligned) >= min_adsb_plots
        else:
            adsb = bool(use_adsb)
        if adsb:
            out[rid] = estimate_noise_adsb(dataset, rid, robust=robust, aligned=aligned)
        else:
            out[rid] = estimate_noise_line_fit(dataset, rid, robust=robust, options=options)
    if progress is not None:
        progress("done", len(ids), len(ids))
    return out


def _missing(value: float | None) -> bool:
    return value is None or not math.isfinite(value) or value <= 0.0


def sites_with_estimated_sigmas(
    sites: Mapping[str, Site],
    estimates: Mapping[str, NoiseEstimate],
    only_missing: bool = True,
) -> dict[str, Site]:
    """New :class:`Site` objects carrying estimated sigmas (``dataclasses.replace``).

    Parameters
    ----------
    sites : mapping of str to Site
    estimates : mapping of str to NoiseEstimate
        From :func:`estimate_noise`; radars absent or not estimated keep their sigmas.
    only_missing : bool
        True: replace only sigmas that are missing (``None``, NaN or not
        positive; an elevation sigma only for a 3-D site).  False: replace all
        estimated sigmas (the elevation sigma of a 2-D site stays ``None``).

    Returns
    -------
    dict of str to Site
        Same keys and order as ``sites``.
    """
    out: dict[str, Site] = {}
    for rid, site in sites.items():
        est = estimates.get(rid)
        if est is None or not est.estimated:
            out[rid] = site
            continue
        changes: dict[str, float] = {}
        if not only_missing or _missing(site.sigma_range_m):
            changes["sigma_range_m"] = est.sigma_range_m
        if not only_missing or _missing(site.sigma_azimuth_rad):
            changes["sigma_azimuth_rad"] = est.sigma_azimuth_rad
        if site.is_3d and est.sigma_elevation_rad is not None and (
            not only_missing or _missing(site.sigma_elevation_rad)
        ):
            changes["sigma_elevation_rad"] = est.sigma_elevation_rad
        out[rid] = replace(site, **changes) if changes else site
    return out


def fill_missing_sigmas(
    dataset: Dataset, *, use_adsb: bool | Literal["auto"] = "auto"
) -> tuple[Dataset, dict[str, NoiseEstimate]]:
    """The dataset with every sigma that ``sites.toml`` left out estimated from the data.

    Only radars with :attr:`graphcal.data.dataset.Site.missing_sigmas` are estimated
    (:func:`estimate_noise`); a dataset without missing sigmas is returned as it
    is, with no estimate.

    Returns
    -------
    dataset : Dataset
        A copy with the filled-in sites (the plots and ADS-B tables are shared).
    estimates : dict of str to NoiseEstimate
        The estimates used, by radar.

    Raises
    ------
    DatasetError
        If a radar's missing sigmas cannot be estimated (too few usable plots),
        naming the radar, the missing keys and the reason.
    """
    missing = [rid for rid, site in dataset.sites.items() if site.missing_sigmas]
    if not missing:
        return dataset, {}
    if use_adsb is True and dataset.adsb is None:
        use_adsb = False
    estimates = estimate_noise(dataset, use_adsb=use_adsb, radar_ids=missing)
    for rid in missing:
        if not estimates[rid].estimated:
            keys = ", ".join(dataset.sites[rid].missing_sigmas)
            raise DatasetError(
                f"radar {rid!r} has no {keys} and the data cannot give them "
                f"({estimates[rid].reason}); write them in sites.toml",
                path=None if dataset.path is None else dataset.path / "sites.toml",
                field=keys.split(", ")[0],
            )
    sites = sites_with_estimated_sigmas(dataset.sites, estimates, only_missing=True)
    return replace(dataset, sites=sites), estimates


def estimated_sigmas_info(estimates: Mapping[str, NoiseEstimate]) -> dict[str, dict]:
    """``{radar: {sigma key: value, "method": ..., "n_plots": ...}}`` for a result's ``info``."""
    out: dict[str, dict] = {}
    for rid, est in estimates.items():
        entry: dict = {"sigma_range_m": est.sigma_range_m,
                       "sigma_azimuth_mrad": est.sigma_azimuth_mrad}
        if est.sigma_elevation_mrad is not None:
            entry["sigma_elevation_mrad"] = est.sigma_elevation_mrad
        entry.update(method=est.method, n_plots=est.n_plots_used)
        out[rid] = entry
    return out


def filled_with_notes(dataset: Dataset) -> tuple[Dataset, dict[str, Any] | None, list[str]]:
    """:func:`fill_missing_sigmas`, with the record and warnings a calibration carries.

    Returns
    -------
    dataset : Dataset
        The dataset with every missing sigma estimated (unchanged if none is missing).
    info : dict or None
        ``info["estimated_sigmas"]`` of the calibration, ``None`` when nothing was estimated.
    warnings : list of str
        One line per radar whose sigmas were estimated.
    """
    missing = {rid: site.missing_sigmas for rid, site in dataset.sites.items()}
    dataset, estimates = fill_missing_sigmas(dataset)
    if not estimates:
        return dataset, None, []
    warnings = [
        f"{rid}: sites.toml gives no {', '.join(missing[rid])}; used {describe_estimate(est)}"
        for rid, est in estimates.items()
    ]
    return dataset, estimated_sigmas_info(estimates), warnings


def fills_missing_sigmas(estimator: Callable[..., Calibration]) -> Callable[..., Calibration]:
    """Decorate an estimator ``f(dataset or problem, **options)`` to fill missing site
    sigmas first.

    The sigmas ``sites.toml`` leaves out are estimated by :func:`fill_missing_sigmas`
    (ADS-B where there is enough, else straight-leg line fits); the result then
    carries them in ``info["estimated_sigmas"]`` and says so in a warning
    (:func:`filled_with_notes`).
    """

    @functools.wraps(estimator)
    def run(data: Any, *args: Any, **options: Any) -> Calibration:
        # ``data``: a Dataset, or a calibration problem (graphcal.model.problem, a layer
        # above) holding one, which is given the filled dataset when a sigma is filled.
        dataset = getattr(data, "dataset", data)
        filled, info, warnings = filled_with_notes(dataset)
        if info is not None:
            data = data.with_dataset(filled) if data is not dataset else filled
        cal = estimator(data, *args, **options)
        if info is not None:
            cal.info["estimated_sigmas"] = info
            cal.warnings.extend(warnings)
        return cal

    return run


def describe_estimate(est: NoiseEstimate) -> str:
    """One line: the estimated sigmas of a radar, the method and the plots behind them."""
    values = f"range {est.sigma_range_m:.1f} m, azimuth {est.sigma_azimuth_mrad:.2f} mrad"
    if est.sigma_elevation_mrad is not None:
        values += f", elevation {est.sigma_elevation_mrad:.2f} mrad"
    return f"sigmas estimated from {est.n_plots_used} plots ({est.method}): {values}"
