"""Calibration with plots that carry no address: associate, calibrate, associate again.

A radar whose plots have an empty ``target_id`` (primary radars, Mode A/C SSRs) cannot be
tied to ADS-B or to the other radars by identity.  :func:`calibrate_associated` gives its
plots the addresses of the aircraft they measure (:mod:`graphcal.tracking.association`),
calibrates the network on the addressed plots (clutter and ambiguous plots left out),
and associates again with the new biases and their covariance, until at most
:data:`MAX_CHANGED_FRACTION` of the associations change (at most :data:`MAX_ROUNDS`
calibrations).  The first association starts from a coarse search for each such radar's
range offset and azimuth bias (:func:`~graphcal.tracking.association.coarse_bias`), and a
quick closed-form estimate on it (``ls`` with ADS-B, ``wls`` without) narrows the gates
before the first full calibration.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from graphcal.core.errors import EstimationError
from graphcal.core.solve_options import SolveOptions
from graphcal.data.align import plot_arrays
from graphcal.data.bias import RadarBias
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset
from graphcal.data.windows import Window
from graphcal.model.problem import Problem, build_problem
from graphcal.solvers.registry import solve
from graphcal.tracking.association import (
    ASSOCIATED,
    UNADDRESSED_FRACTION,
    Association,
    associate,
    coarse_bias,
    reference_tracks,
    unaddressed_radars,
    unaddressed_share,
)

#: At most this many calibrations, each followed by an association.
MAX_ROUNDS = 3
#: The associations have settled when at most this fraction of the plots without an
#: address changes from one round to the next.
MAX_CHANGED_FRACTION = 1e-3
#: The first association's bias uncertainty around the coarse search's start:
#: (range offset m, range gain, azimuth rad, elevation rad) 1-sigma.
COARSE_SIGMA = (300.0, 1e-3, 2e-3, 2e-3)
#: The terms the association's gate widens by, in the calibration's names.
GATED_TERMS = ("range_offset", "range_gain", "azimuth_bias", "elevation_bias")


def needs_association(dataset: Dataset) -> bool:
    """Whether some plot lacks an address (contract v3: ``info.association`` is then
    recorded)."""
    return bool(unaddressed_radars(dataset))


def calibrate_associated(dataset: Dataset, method: str, options: SolveOptions, **run: Any
                         ) -> tuple[Calibration, Problem, Association]:
    """Associate the plots without an address, calibrate, and repeat (module docstring).

    ``run``: how the estimator runs (:func:`graphcal.solvers.registry.solve`); its
    ``progress`` also reporting the association.  Returns the calibration, the problem of
    the associated dataset it was solved on (for the bound, the checks and the verdict)
    and the last association.
    """
    start = time.perf_counter()
    progress: Callable[..., None] | None = run.get("progress")
    radars = unaddressed_radars(dataset)
    if progress is not None:
        progress("association", 0, MAX_ROUNDS)
    association, coarse_notes = first_association(dataset, options, radars)
    cal = problem = None
    rounds = 0
    for rounds in range(1, MAX_ROUNDS + 1):  # noqa: B007 - the count is reported
        problem = build_problem(association.applied(dataset), options)
        cal = solve(problem, method, **run)
        biases = {rid: cal.bias(rid) for rid in cal.radar_ids}
        covariances = gate_covariances(cal)
        again = associate(dataset, biases, covariances, use_adsb=options.use_adsb,
                          radars=radars)
        if progress is not None:
            progress("association", rounds, MAX_ROUNDS)
        if _changed(again, association) <= MAX_CHANGED_FRACTION:
            break
        association = again
    if cal is None or problem is None:
        raise EstimationError("nothing to calibrate")
    info = association.to_dict()
    cal.info["association"] = {"radars": info, "rounds": rounds,
                               "seconds": time.perf_counter() - start}
    cal.warnings.extend(coarse_notes)
    for figures in association.radars.values():
        warning = figures.warning()
        if warning is not None:
            cal.warnings.append(warning)
    for rid, figures in info.items():
        if figures["associated"] == 0 and rid in biases:
            cal.warnings.append(f"{rid}: no plot without an address associated with a known "
                                "aircraft; not calibrated")
    return cal, problem, association


def first_association(dataset: Dataset, options: SolveOptions,
                      radars: list[str] | None = None) -> tuple[Association, list[str]]:
    """The association before any full calibration: a coarse search for each radar's
    range offset and azimuth bias, an association, a quick closed-form estimate on it
    (``ls`` with ADS-B, ``wls`` without) and an association with that estimate.  Returns
    the association and a note per radar the coarse search found nothing for."""
    radars = unaddressed_radars(dataset) if radars is None else radars
    refs = reference_tracks(dataset, {}, use_adsb=options.use_adsb)
    biases: dict[str, RadarBias] = {}
    covariances: dict[str, np.ndarray] = {}
    notes = []
    share = unaddressed_share(dataset)
    for rid in radars:
        if share.get(rid, 0.0) < UNADDRESSED_FRACTION:
            # Mostly addressed: the quick estimate finds its biases from those plots.
            covariances[rid] = np.diag(np.square(COARSE_SIGMA))
            continue
        plots = plot_arrays(dataset, rid)
        plots = plots.subset(np.isin(plots.target_id.astype(str), ["", "nan"]))
        found = coarse_bias(dataset.sites[rid], refs, plots)
        covariances[rid] = np.diag(np.square(COARSE_SIGMA))
        if found is None:
            if len(refs.tracks.targets):
                notes.append(f"{rid}: no plot near any known aircraft; associated only "
                             "with the other radars without addresses")
            continue
        biases[rid] = found
    # Paths of their own wait for the quick estimate, the coarse gates being too wide,
    # unless there is no reference at all: then they are all there is.
    association = associate(dataset, biases, covariances, use_adsb=options.use_adsb,
                            radars=radars, own_paths=not len(refs.tracks.targets))
    # A quick estimate on the first association narrows the gates before the full one.
    quick = "ls" if options.use_adsb and dataset.adsb is not None and len(dataset.adsb) else "wls"
    try:
        first = solve(build_problem(association.applied(dataset), options), quick)
    except (EstimationError, ValueError, np.linalg.LinAlgError):
        return association, notes
    biases.update({rid: first.bias(rid) for rid in first.radar_ids})
    covariances.update(gate_covariances(first))
    return associate(dataset, biases, covariances, use_adsb=options.use_adsb,
                     radars=radars), notes


def associated_window(window: Window, options: SolveOptions
                      ) -> tuple[Window, Association | None]:
    """A time window with its plots without an address associated (:func:`first_association`;
    the window's own calibration then refines its biases) and the association; the window
    as it is and ``None`` when no radar lacks addresses."""
    if not needs_association(window.dataset):
        return window, None
    association, _ = first_association(window.dataset, options)
    return replace(window, dataset=association.applied(window.dataset)), association


def merged_figures(per_window: list[dict[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """The windows' association figures (:meth:`RadarAssociation.to_dict`) as one set per
    radar: counts summed, rates weighted by the plots they count."""
    out: dict[str, dict[str, Any]] = {}
    for figures in per_window:
        for rid, f in figures.items():
            total = out.setdefault(rid, {"plots": 0, "associated": 0, "own_paths": 0,
                                         "ambiguous": 0, "left_out": 0, "scans": 0,
                                         "_detected": 0.0,
                                         "_coded": 0.0, "_tail": 0.0, "_coded_n": 0})
            for key in ("plots", "associated", "own_paths", "ambiguous", "left_out", "scans"):
                total[key] += int(f.get(key, 0))
            n = int(f["associated"])
            total["_detected"] += (f["detection_probability"] or 0.0) * n
            total["_tail"] += (f["tail_fraction"] or 0.0) * n
            if f["mode_3a_consistency"] is not None:
                total["_coded"] += f["mode_3a_consistency"] * n
                total["_coded_n"] += n
    for total in out.values():
        n = total["associated"]
        total["detection_probability"] = total.pop("_detected") / n if n else None
        total["tail_fraction"] = total.pop("_tail") / n if n else None
        coded, coded_n = total.pop("_coded"), total.pop("_coded_n")
        total["mode_3a_consistency"] = coded / coded_n if coded_n else None
        total["false_plots_per_scan"] = (total["left_out"] / total["scans"]
                                         if total["scans"] else None)
    return out


def association_notes(association: Association) -> dict[str, str]:
    """Per radar with associated plots, a phrase on them for the model checks' and the fit
    verdict's warnings: how many, and their share beyond the chi-square's 99.9 % point."""
    notes = {}
    for rid, figures in association.radars.items():
        if figures.n_associated == 0:
            continue
        text = f"{figures.n_associated:,} of {figures.n_plots:,} plots"
        if figures.tail_fraction is not None:
            text += (f", {100 * figures.tail_fraction:.2f} % of them beyond the chi-square's "
                     "99.9 % point where 0.1 % is expected")
        notes[rid] = text
    return notes


def checks_association_warnings(model_checks: dict[str, Any], notes: dict[str, str]
                                ) -> list[str]:
    """Warnings for the radars whose model checks fired and whose plots were associated:
    wrong associations would show in their residuals so (``model_checks``: the checks'
    :meth:`~graphcal.analysis.model_checks.ModelChecks.to_dict`)."""
    out = []
    for rid, note in notes.items():
        fired = model_checks.get("radars", {}).get(rid, {}).get("fired") or []
        if fired:
            out.append(f"{rid}: its plots carry no address and were associated by gating "
                       f"({note}); the model checks that fired ({', '.join(fired)}) may be "
                       "wrong associations (another aircraft, false plots) as well as a bias "
                       "the model lacks")
    return out


def gate_covariances(cal: Calibration) -> dict[str, np.ndarray]:
    """Each radar's covariance over :data:`GATED_TERMS` (SI; zero where not estimated)."""
    out = {}
    labels = list(cal.labels)
    cov = np.asarray(cal.covariance, dtype=float)
    for rid in cal.radar_ids:
        block = np.zeros((4, 4))
        index = {name: labels.index((rid, name)) for name in GATED_TERMS
                 if (rid, name) in labels}
        for a, na in enumerate(GATED_TERMS):
            for b, nb in enumerate(GATED_TERMS):
                if na in index and nb in index:
                    block[a, b] = cov[index[na], index[nb]]
        out[rid] = block
    return out


def _changed(a: Association, b: Association) -> float:
    """The fraction of the plots without an address whose association differs."""
    ta = a.target_id.where(a.status == ASSOCIATED, "")
    tb = b.target_id.where(b.status == ASSOCIATED, "").reindex(ta.index, fill_value="")
    return float(np.mean(ta.to_numpy() != tb.to_numpy())) if len(ta) else 0.0


__all__ = ["MAX_ROUNDS", "associated_window", "association_notes", "calibrate_associated",
           "checks_association_warnings", "first_association", "gate_covariances",
           "merged_figures", "needs_association"]
