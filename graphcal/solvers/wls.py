"""Paper 001: weighted least squares on cross-radar observations, and greedy pruning.

``wls`` solves paper 001 eq. 10::

    X = [sum_k H_k^T Q_k H_k]^-1 [sum_k H_k^T Q_k z_k],   Q_k = (M_k cov(V) M_k^T)^-1

over the observations of :mod:`graphcal.model.cross_radar`, reporting
the rank and the observability degree ``Deg`` of ``A = sum H^T Q H``
(eq. 11).  Its covariance is not the paper's ``A^-1`` but the sandwich
``A^-1 M A^-1`` of :func:`~graphcal.model.cross_radar.shared_noise_middle`,
because one plot enters several observations and ``A^-1`` alone would be
over-confident.  Like the paper it linearises once at zero bias, which biases it
when the biases are large (paper 001 Table 1: 5.1 mrad estimated for a true
8.7 mrad); ``iterations > 1`` re-linearises at the current estimate
(Gauss-Newton), an option the paper does not have.

``wls-pruned`` first drops observations by the greedy rule of eq. 12:
visiting the observations in time order, observation ``m`` is removed when
``Deg`` of ``A - H_m^T Q_m H_m`` is larger than ``Deg`` of ``A`` (a
downdate of ``A``, not a recomputation), then solves eq. 10 on what is left.
``Deg`` is evaluated after Jacobi scaling by the full set's diagonal, so it
does not depend on the parameters' units.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from graphcal.core.errors import EstimationError
from graphcal.data.align import DEFAULT_ADSB_MAX_GAP_S
from graphcal.data.bias import RadarBias, compose_bias
from graphcal.data.calibration import Calibration
from graphcal.data.correct import correct_plots
from graphcal.data.dataset import Dataset
from graphcal.model.cross_radar import CrossObservations, cross_observations, shared_noise_middle
from graphcal.model.information import (
    describe_weak_directions,
    greedy_prune_information,
    jacobi_scale,
    observability,
    solve_normal_equations,
)
from graphcal.model.measurement import residual_stats
from graphcal.model.parameters import ParameterLayout
from graphcal.model.problem import Problem, as_problem
from graphcal.noise import fills_missing_sigmas

FloatArray = NDArray[np.float64]
Progress = Callable[[int, int], None]


def whiten(obs: CrossObservations) -> tuple[FloatArray, FloatArray]:
    """``(L^T H, L^T z)`` per observation with ``L L^T = Q = cov^-1``."""
    chol = np.linalg.cholesky(np.linalg.inv(obs.cov))  # (m, 3, 3), Q = L L^T
    lt = np.swapaxes(chol, 1, 2)
    return lt @ obs.h, np.einsum("mij,mj->mi", lt, obs.z)


def greedy_prune(
    h_white: FloatArray, progress: Progress | None = None
) -> tuple[NDArray[np.bool_], list[float]]:
    """Greedy data pruning of paper 001 eq. 12 by rank-3 downdates of ``A``.

    Parameters
    ----------
    h_white : ndarray (m, 3, p)
        Whitened Jacobians; observation ``k`` contributes ``h_k^T h_k`` to ``A``.
    progress : callable, optional
        Called as ``progress(done, total)``.

    Returns
    -------
    keep : ndarray of bool
        Observations kept.
    degree_trace : list of float
        ``Deg`` after each visit (length m).
    """

    information = np.einsum("mip,miq->pq", h_white, h_white)
    scaled_h = h_white * jacobi_scale(information)
    return greedy_prune_information(np.einsum("mip,miq->mpq", scaled_h, scaled_h), progress)


def _corrected(dataset: Dataset, biases: dict[str, RadarBias]) -> Dataset:
    """A copy of ``dataset`` with every radar's plots corrected by ``biases``
    (:func:`graphcal.data.correct.correct_plots`: azimuths wrapped to [0, 360) deg)."""
    plots = correct_plots(dataset.plots, dataset.sites, biases)
    return Dataset(dataset.sites, plots, dataset.adsb, dataset.path,
                   plot_altitude=dataset.plot_altitude)


def _bias_from_vector(layout: ParameterLayout, radar_id: str, x: FloatArray) -> RadarBias:
    values = np.zeros(4)
    cols, positions = layout.columns(radar_id)
    values[positions] = x[cols]
    return RadarBias.from_vector(values)


#: ``info["sigma"]`` of wls and wls-pruned: what their sigmas are.
WLS_SIGMA_NOTE = ("formal (paper 001: the weighted LS covariance from the stated noise, the "
                  "shared partner-plot noise included; not scaled by chi2_per_dof)")
#: chi2/dof above which wls warns that its formal sigmas are too small.
FORMAL_SIGMA_CHI2 = 1.5


def _run_wls(
    method: str,
    problem: Problem,
    prune: bool,
    iterations: int,
    max_gap_s: float | None,
    progress: Progress | None,
    linearise: str = "plots",
) -> Calibration:
    if iterations < 1:
        raise ValueError("iterations must be at least 1")
    dataset = problem.dataset
    layout = ParameterLayout.for_sites(list(dataset.sites.values()))
    biases = {rid: RadarBias() for rid in dataset.radar_ids}
    info: dict = {"iterations": iterations, "pruned": prune, "linearise": linearise}
    keep = None
    for _ in range(iterations):
        current = _corrected(dataset, biases) if any(
            b != RadarBias() for b in biases.values()
        ) else dataset
        obs = cross_observations(current, layout, max_gap_s, linearise)
        if len(obs) == 0:
            raise EstimationError(
                "no common observations: no two radars saw the same target_id within the "
                "time-gap limit, so cross-radar calibration is impossible"
            )
        if prune:
            if keep is None or len(keep) != len(obs):
                keep, trace = greedy_prune(whiten(obs)[0], progress)
                info["n_pruned"] = int((~keep).sum())
                info["degree_trace_final"] = trace[-1]
            obs = obs.subset(keep)
        h_white, z_white = whiten(obs)
        information = np.einsum("mip,miq->pq", h_white, h_white)
        rhs = np.einsum("mip,mi->p", h_white, z_white)
        sol = solve_normal_equations(information, rhs, shared_noise_middle(obs))
        increment = np.nan_to_num(sol.estimate)
        biases = {
            rid: compose_bias(biases[rid], _bias_from_vector(layout, rid, increment))
            for rid in dataset.radar_ids
        }
        residual = z_white - np.einsum("mip,p->mi", h_white, increment)
        dof = max(residual.size - sol.observability.rank, 1)
        info["chi2_per_dof"] = float(np.sum(residual**2) / dof)
    info["n_observations"] = int(len(h_white))
    info["singular_values"] = sol.singular_values
    info["sigma"] = WLS_SIGMA_NOTE
    estimate = np.array(
        [biases[rid].value(name) for rid, name in layout.labels], dtype=float
    )
    radar_ids = [rid for rid in dataset.radar_ids if obs.n_plots.get(rid, 0) > 0]
    cal = Calibration(
        method=method,
        radar_ids=radar_ids,
        is_3d={rid: dataset.sites[rid].is_3d for rid in radar_ids},
        labels=list(layout.labels),
        estimate=estimate,
        covariance=sol.covariance,
        n_plots={rid: obs.n_plots[rid] for rid in radar_ids},
        observability=sol.observability,
        info=info,
    )
    _drop_unseen(cal, layout, information)
    cal.warnings.extend(describe_weak_directions(cal.labels, cal.observability))
    chi2 = info.get("chi2_per_dof", 1.0)
    if chi2 > FORMAL_SIGMA_CHI2:
        cal.warnings.append(
            f"{method}: the residuals are {chi2:.2g} times their stated variance "
            f"(chi2/dof); its sigmas are paper 001's formal ones, from the stated noise, and "
            f"are then about {np.sqrt(chi2):.2g} times too small (or the noise model is "
            "wrong: estimate the sigmas with 'graphcal noise')")
    large = beyond_one_linearisation(cal)
    if large:
        cal.warnings.append(
            f"{method} linearises once, at the measured plots (paper 001 eq. 10): with biases "
            f"as large as {', '.join(large)} the linearisation error biases the estimates "
            "themselves, by several of their sigmas at a few km or tens of mrad; the graph "
            "method iterates to the solution")
    if dataset.pressure_altitudes and any(not dataset.sites[rid].is_3d for rid in radar_ids):
        cal.warnings.append(
            f"{method} places the 2-D plots at their pressure altitudes as if they were heights "
            "above the ellipsoid (it has no height model; graph estimates one): its range "
            "terms carry the difference"
        )
    _adsb_residuals(cal, problem)
    return cal


#: Biases beyond which one linearisation at the measured plots is not to be trusted
#: (contract key -> size in contract units): 1 km of range offset, 10 mrad of angle.
LINEARISATION_LIMITS: dict[str, float] = {
    "range_offset_m": 1000.0, "azimuth_bias_mrad": 10.0, "elevation_bias_mrad": 10.0}


def beyond_one_linearisation(cal: Calibration) -> list[str]:
    """``["NORD range_offset_m 3030"]``: the estimates beyond :data:`LINEARISATION_LIMITS`."""
    found = []
    for rid in cal.radar_ids:
        for key, limit in LINEARISATION_LIMITS.items():
            value = cal.value(rid, key)
            if value is not None and abs(value) > limit:
                found.append(f"{rid} {key} {value:,.0f}")
    return found


def _drop_unseen(
    cal: Calibration, layout: ParameterLayout, information: NDArray[np.float64]
) -> None:
    """Remove parameters of radars without any common observation (and from the
    observability, which is recomputed from the information of the others)."""
    keep = [i for i, (rid, _) in enumerate(layout.labels) if rid in cal.radar_ids]
    dropped = sorted({rid for rid, _ in layout.labels} - set(cal.radar_ids))
    for rid in dropped:
        cal.warnings.append(
            f"radar {rid} has no plots in common with another radar; not calibrated"
        )
    cal.labels = [layout.labels[i] for i in keep]
    cal.estimate = cal.estimate[keep]
    cal.covariance = cal.covariance_si[np.ix_(keep, keep)]
    if dropped:
        cal.observability = observability(information[np.ix_(keep, keep)])


def _adsb_residuals(cal: Calibration, problem: Problem) -> None:
    """Residuals against ADS-B, for information, when the dataset has ADS-B."""
    dataset = problem.dataset
    if dataset.adsb is None:
        return
    for rid in cal.radar_ids:
        al = problem.alignment(rid, DEFAULT_ADSB_MAX_GAP_S)
        if len(al) > 0:
            cal.residuals[rid] = residual_stats(dataset.sites[rid], al, cal.bias(rid))


@fills_missing_sigmas
def wls(
    data: Dataset | Problem,
    *,
    iterations: int = 1,
    max_gap_s: float | None = None,
    progress: Progress | None = None,
    linearise: str = "plots",
) -> Calibration:
    """Paper 001 WLS (eq. 8-11) over all radar pairs, no ADS-B needed.

    ``linearise="neighbours"`` evaluates ``H_k`` at each plot's track neighbours
    instead of the plot itself (:func:`~graphcal.model.cross_radar.cross_observations`),
    which removes the errors-in-variables bias of the paper's choice.
    """
    return _run_wls("wls", as_problem(data), False, iterations, max_gap_s, progress, linearise)


@fills_missing_sigmas
def wls_pruned(
    data: Dataset | Problem,
    *,
    iterations: int = 1,
    max_gap_s: float | None = None,
    progress: Progress | None = None,
    linearise: str = "plots",
) -> Calibration:
    """Paper 001 greedy pruning (eq. 12), then WLS (eq. 10) on the kept observations."""
    return _run_wls("wls-pruned", as_problem(data), True, iterations, max_gap_s, progress,
                    linearise)


__all__ = ["LINEARISATION_LIMITS", "beyond_one_linearisation", "greedy_prune", "whiten", "wls",
           "wls_pruned"]
