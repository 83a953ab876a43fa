"""What the fit verdict needs of one time window, from the window's own fit.

``graphcal calibrate --window`` judges every window's fit as a calibration without
windows is judged (:mod:`graphcal.analysis.fit_verdict`): a radar whose residuals
are far beyond their sigmas, whose range gain is beyond reason or whose estimate
corrects plots to a negative range fails.  Each window's summary
(:func:`graphcal.solvers.windows.summarise_window`) carries the numbers, as a
:class:`WindowFit` of plain numbers (it travels between processes), and the
pipeline combines the windows into the run's verdict
(:func:`graphcal.analysis.fit_verdict.windows_verdict`).

The residuals are those of the model checks against ADS-B
(:func:`graphcal.analysis.check_residuals.adsb_radar_residuals`), computed cheaply
from what the window's fit already holds: each radar's plots aligned with ADS-B at
zero time offset (the estimator's, held by the calibration problem both are given, so
not aligned again), corrected with the
window's biases, the reference moved to the estimated time offset ``tau`` to first
order (``reference - rate * tau``, as the estimator's own ADS-B factors do); per
coordinate ``sum e^2 / v`` and the count over the plots that are not gross outliers
(:func:`graphcal.core.outliers.outlier_rows`), ``v`` the radar's variance plus the
ADS-B position's mapped to polar.  The rate comes from two consecutive ADS-B reports,
whose noise makes it uncertain by some 10 % (20 m for an aircraft moved 200 m by
``tau`` = 0.8 s): beyond :data:`FIRST_ORDER_MAX_S` the plots are aligned again at
``tau`` instead, as the estimator does; below :data:`NEGLIGIBLE_TIME_OFFSET_S` the
reference is not moved.

Without ADS-B (``--no-adsb``, or a window without any aligned report) the trajectory
formulation's own residuals are used: each radar's plots on the aircraft's paths, which
the window's estimator summed (``info["target_state"]["fit"]``,
:meth:`graphcal.model.trajectory.TrajectoryBlock.residual_fit`; ``reference``
``"paths"``, :func:`sums_on_paths`).  Without those either (``--cross pairwise``), the
residuals would be cross-radar pairs, whose computation costs a quarter of a window's
calibration: such a window carries only its range gains and negative-range counts
(``reference`` ``"none"``), which still catch ranges in another unit.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from graphcal.core import frames
from graphcal.core.outliers import outlier_rows
from graphcal.data.bias import count_non_positive_ranges
from graphcal.data.calibration import Calibration
from graphcal.model.factor_set import polar_rate
from graphcal.model.measurement import (
    measured_polar,
    measurement_model,
    polar_noise_variances,
)
from graphcal.model.problem import Problem

#: Largest estimated time offset [s] for which the ADS-B reference is moved to it to first
#: order; beyond it the plots are aligned again.  The first order's error, the rate's
#: noise (some 40 m/s from 1 Hz reports) times the offset, is then at most 4 m in range,
#: a 2 % increase of chi2/dof for a sigma of 30 m.
FIRST_ORDER_MAX_S = 0.1
#: Estimated time offsets below this [s] leave the reference where it is: an airliner
#: (250 m/s) moves 2.5 m, which adds under 1 % to chi2/dof for a range sigma of 30 m.
NEGLIGIBLE_TIME_OFFSET_S = 0.01


@dataclass
class WindowFit:
    """One window's fit, per radar, in plain numbers.

    Attributes
    ----------
    reference : {"adsb", "paths", "none"}
        What the residuals were measured against (``"paths"``: the aircraft's estimated
        paths; ``"none"``: no residuals).
    sums : dict
        Radar id -> coordinate (``range``, ``azimuth``, ``elevation``) ->
        ``(sum e^2 / v, count)`` over the residuals kept.
    n_terms : dict
        Radar id -> its estimated terms in the window (the residuals' lost dof).
    range_gain : dict
        Radar id -> its range gain in the window (fraction), as
        :meth:`Calibration.value <graphcal.data.calibration.Calibration.value>` gives it
        (``None`` when not in the radar's model).
    negative_ranges : dict
        Radar id -> its plots the window's estimate corrects to a non-positive range.
    n_outliers : dict
        Radar id -> residuals left out as gross outliers.
    """

    reference: str
    sums: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    n_terms: dict[str, int] = field(default_factory=dict)
    range_gain: dict[str, float | None] = field(default_factory=dict)
    negative_ranges: dict[str, int] = field(default_factory=dict)
    n_outliers: dict[str, int] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"reference": self.reference,
                "sums": {rid: {c: [chi2, n] for c, (chi2, n) in by.items()}
                         for rid, by in self.sums.items()},
                "n_terms": dict(self.n_terms), "range_gain": dict(self.range_gain),
                "negative_ranges": dict(self.negative_ranges),
                "n_outliers": dict(self.n_outliers)}


def window_fit(problem: Problem, cal: Calibration, *, use_adsb: bool, max_gap_s: float
               ) -> WindowFit:
    """The fit numbers of ``cal``, the calibration of the window's ``problem`` (module doc).

    Given the problem ``cal`` was estimated from, the alignments with ADS-B are reused.

    Parameters
    ----------
    problem : Problem
        The window's calibration problem, as calibrated (sigmas filled in).
    cal : Calibration
        Its calibration.
    use_adsb : bool
        Whether the calibration used ADS-B (else no residuals are formed).
    max_gap_s : float
        Longest ADS-B gap bridged [s], as for the calibration.
    """
    dataset = problem.dataset
    have_adsb = bool(use_adsb and dataset.adsb is not None and len(dataset.adsb))
    fit = WindowFit("none")
    for rid in cal.radar_ids:
        if rid not in dataset.sites:
            continue
        bias = cal.bias(rid)
        fit.n_terms[rid] = sum(1 for r, _ in cal.labels if r == rid)
        fit.range_gain[rid] = cal.value(rid, "range_gain")
        r = problem.plots(rid).range_m  # the estimator's
        fit.negative_ranges[rid] = count_non_positive_ranges(r, bias)
        if have_adsb and not fit.negative_ranges[rid]:
            sums = _adsb_sums(problem, rid, bias, max_gap_s)
            if sums is not None:
                fit.sums[rid], fit.n_outliers[rid] = sums
                fit.reference = "adsb"
    on_paths = sums_on_paths(cal.info) if fit.reference == "none" else None
    if on_paths:
        fit.reference = "paths"
        fit.sums = {rid: by for rid, by in on_paths.items()
                    if rid in fit.n_terms and not fit.negative_ranges.get(rid)}
    return fit


def sums_on_paths(info: dict[str, Any]) -> dict[str, dict[str, tuple[float, float]]] | None:
    """Each radar's ``{coordinate: (chi2, count)}`` on the aircraft's paths, from a
    calibration's ``info`` when the trajectory formulation summed them
    (``info["target_state"]["fit"]``, without ADS-B residuals), else ``None``.

    ``count`` is the residuals' number less the paths' share of their degrees of freedom
    (:meth:`graphcal.model.trajectory.TrajectoryBlock.residual_fit`); the verdict then
    subtracts the radar's estimated terms.
    """
    fit = (info.get("target_state") or {}).get("fit")
    if not fit:
        return None
    return {rid: {c: (float(e["chi2"]), float(e["n"]) - float(e["paths_dof"]))
                  for c, e in by.items()}
            for rid, by in fit.items()}


def _adsb_sums(problem: Problem, rid: str, bias: Any, max_gap_s: float
               ) -> tuple[dict[str, tuple[float, int]], int] | None:
    """One radar's ``{coordinate: (sum e^2 / v, count)}`` against ADS-B and its outliers."""
    site = problem.sites[rid]
    tau = bias.time_offset_s
    exact = abs(tau) > FIRST_ORDER_MAX_S
    # At zero time offset: the estimator's alignment, the problem's.
    al = problem.alignment(rid, max_gap_s, time_offset_s=tau if exact else 0.0)
    if len(al) == 0:
        return None
    model = measurement_model(site)
    corrected = model.inverse_function(measured_polar(al), bias)
    reference = al.reference_polar
    if abs(tau) > NEGLIGIBLE_TIME_OFFSET_S and not exact:
        reference = reference - polar_rate(site, al) * tau
    noise = polar_noise_variances(al, site)
    residuals = {"range": corrected[:, 0] - reference[:, 0],
                 "azimuth": frames.wrap_to_pi(corrected[:, 1] - reference[:, 1])}
    variances = {"range": noise[:, 0], "azimuth": noise[:, 1]}
    if site.is_3d:
        residuals["elevation"] = corrected[:, 2] - reference[:, 2]
        variances["elevation"] = noise[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        z = {c: residuals[c] / np.sqrt(variances[c]) for c in residuals}
    keep = ~outlier_rows(z.values())
    sums = {}
    for coordinate, values in z.items():
        ok = keep & np.isfinite(values)
        if ok.any():
            sums[coordinate] = (float(np.sum(values[ok] ** 2)), int(ok.sum()))
    return sums, int(np.sum(~keep))


__all__ = ["FIRST_ORDER_MAX_S", "NEGLIGIBLE_TIME_OFFSET_S", "WindowFit", "window_fit"]
