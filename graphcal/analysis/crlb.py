"""Cramér-Rao lower bound (CRLB) of the radar bias parameters of a dataset.

The bound comes from the same measurement model as the estimators
(:mod:`graphcal.data.bias`, CONTRACT.md): a plot of radar ``s`` of a target at
``x`` measures ``h_s(x) + J(r) beta_s + noise``, with ``h_s`` the polar
coordinates ``(range, azimuth[, elevation])`` in the radar's frame, ``J``
:meth:`graphcal.model.measurement.RadarMeasurementModel.bias_jacobian` and ``beta_s`` the radar's
free bias terms (the same selection as the graph calibrator,
:func:`graphcal.model.parameters.radar_terms`).  The Fisher information is
additive over two kinds of observations:

* **ADS-B-matched plots** (``use_adsb``): the target is known up to the
  ADS-B noise.  As in the graph's ADS-B factor
  (:class:`graphcal.model.factors.AdsbFactor`), each plot contributes
  ``J_k^T S_k^-1 J_k`` with ``S_k`` the radar's polar noise plus the
  interpolated ADS-B position covariance mapped through the polar Jacobian.
  Approximation: the interpolated ADS-B errors of different plots are taken
  as independent (plots of two radars that share ADS-B reports are in fact
  slightly correlated); the graph makes the same assumption.
* **Cross-radar events** (``cross``; the plots *not* matched to ADS-B when
  ``use_adsb``, as the graph's pairwise factors): the plots of one aircraft
  (``target_id``) in a time window of ``event_s`` seconds form an event whose
  trajectory is an unknown straight line ``x(t) = x_e + v_e (t - t_e)``
  (6 nuisance parameters).  A 2-D radar's plot measures range and azimuth;
  its reported (Mode C) height, when given, is an extra measurement of the
  target's height with 1-sigma
  :data:`graphcal.model.cross_radar.ALTITUDE_SIGMA_M` (2-D plots without
  height are left out, as in the graph).  The nuisance parameters are
  eliminated per event (Schur complement of its 6x6 block, pseudo-inverse
  where an event does not determine them).  Only events seen by two or more
  radars are kept: a single radar's information about its own biases through
  the straightness of a track is real under this model but not used by any
  estimator.  Approximations: constant velocity within an event; the
  geometry (Jacobians) is taken at the measured plots (the biases move it by
  a negligible amount).

Geometry of the ADS-B terms: the Jacobians and ``S_k`` are evaluated at the
ADS-B positions interpolated to the plot times (what the graph uses), or at
the true positions when a ``truth`` trajectory table is given.

Pressure altitudes (``dataset.plot_altitude == "pressure"``, contract v2): the
graph estimates the height model ``h = (1 + k) p + d`` beside the biases, so
the bound carries ``(d, k)`` as two more unknowns and reports the radar terms'
bound with them eliminated (a nuisance), plus their own bound
(:attr:`CrlbResult.atmosphere_sigma`).  A 2-D plot's reported pressure
altitude ``p`` is then a measurement of ``(h - d) / (1 + k)``: its height row
gains ``d/d(d, k) = -(1, p) / sigma`` (to first order in ``k``), the plot is
placed at the height of ``height_model``, and the ADS-B reports with both
heights add the information of their segment means
(:func:`graphcal.model.height.adsb_height_segments`), as in the graph.

Without ADS-B a network has gauge freedoms (e.g. a common rotation of all
azimuths); its Fisher matrix is singular.  :func:`crlb` then returns the
pseudo-inverse, its ``rank`` and the undetermined directions, whose
``sigma`` is infinite.  ``priors`` adds the graph's weak priors (or any
others) so that the bound is comparable with the graph's posterior.

Everything is vectorised; 40 000 plots take well under a second.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.batched import cholesky_inverse, sum_of_products
from graphcal.core.refraction import apparent_elevation_from_height, target_from_refracted
from graphcal.data.align import DEFAULT_ADSB_MAX_GAP_S, align_adsb
from graphcal.data.bias import CONTRACT_KEYS, NAME_FROM_KEY
from graphcal.data.calibration import Calibration
from graphcal.data.dataset import Dataset, Site
from graphcal.data.height import HEIGHT_MODEL_KEYS, HeightModel, height_jacobian
from graphcal.model.cross_radar import ALTITUDE_SIGMA_M, MAX_2D_ELEVATION_RAD
from graphcal.model.height import HEIGHT_PRIOR_SIGMA, adsb_height_segments
from graphcal.model.information import pseudo_inverse
from graphcal.model.measurement import RadarMeasurementModel, measurement_model
from graphcal.model.parameters import TERM_NAMES, prior_sigmas, radar_terms
from graphcal.model.problem import Problem, as_problem

FloatArray = NDArray[np.float64]
Label = tuple[str, str]

#: Default event window, in scan periods of the slowest radar.
EVENT_SCANS = 3.0
#: Default event window [s] when no radar gives a scan period.
DEFAULT_EVENT_S = 12.0


@dataclass
class CrlbResult:
    """The Cramér-Rao bound of the bias parameters.

    Attributes
    ----------
    labels : list of (radar_id, parameter name)
        Parameter order, as a graph :class:`~graphcal.data.calibration.Calibration`'s ``labels``.
    fisher : ndarray (p, p)
        Fisher information in SI units (priors included when given).
    covariance : ndarray (p, p)
        Its (pseudo-)inverse: the bound on the covariance of any unbiased estimator [SI].
    rank : int
        Numerical rank of ``fisher``.
    null_space : ndarray (p, p - rank)
        Undetermined directions (columns, in the diagonally scaled parameters).
    undetermined : list of labels
        Parameters with a component in the null space; their ``sigma`` is infinite.
    info : dict
        Counts: ADS-B plots, cross-radar events and plots, timing.
    atmosphere_sigma : dict or None
        With pressure altitudes, the bound's 1-sigma of ``height_offset_m`` [m] and
        ``height_scale``; ``fisher`` and ``covariance`` are then the radar terms'
        with the height model eliminated.  ``None`` otherwise.
    """

    labels: list[Label]
    fisher: FloatArray
    covariance: FloatArray
    rank: int
    null_space: FloatArray
    undetermined: list[Label] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    atmosphere_sigma: dict[str, float] | None = None

    def _index(self, radar_id: str, name: str) -> int | None:
        try:
            return self.labels.index((radar_id, name))
        except ValueError:
            return None

    def sigma_si(self, radar_id: str, name: str) -> float | None:
        """CRLB 1-sigma [SI] of a parameter by internal name; ``None`` if not a label."""
        i = self._index(radar_id, name)
        if i is None:
            return None
        if (radar_id, name) in self.undetermined:
            return float("inf")
        return float(np.sqrt(max(self.covariance[i, i], 0.0)))

    def sigma(self, radar_id: str, key: str) -> float | None:
        """CRLB 1-sigma in contract units (``key`` e.g. ``azimuth_bias_mrad``).

        ``inf`` for an undetermined parameter, ``None`` when it is not a label.
        """
        name = NAME_FROM_KEY.get(key, key)
        s = self.sigma_si(radar_id, name)
        return None if s is None else s * CONTRACT_KEYS[name][1]

    def sigmas(self) -> dict[tuple[str, str], float]:
        """``{(radar_id, contract key): CRLB sigma in contract units}`` for every label."""
        return {
            (rid, CONTRACT_KEYS[name][0]): self.sigma(rid, CONTRACT_KEYS[name][0])
            for rid, name in self.labels
        }

    def efficiency(self, cal: Calibration) -> dict[tuple[str, str], float]:
        """Reported sigma / CRLB sigma for every parameter both estimate.

        1 is an efficient estimator whose covariance is honest; below 1 the
        reported sigma is optimistic (no unbiased estimator can do better than
        the bound).  Keys are ``(radar_id, contract key)``.
        """
        out: dict[tuple[str, str], float] = {}
        for i, (rid, name) in enumerate(cal.labels):
            bound = self.sigma_si(rid, name)
            if bound is None:
                continue
            reported = float(np.sqrt(max(cal.covariance[i, i], 0.0)))
            out[(rid, CONTRACT_KEYS[name][0])] = (
                reported / bound if bound > 0 and np.isfinite(bound) else float("nan")
            )
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly summary: labels, sigmas (contract units), rank."""
        return {
            "labels": [f"{rid}.{CONTRACT_KEYS[name][0]}" for rid, name in self.labels],
            "sigma": [
                self.sigma(rid, CONTRACT_KEYS[name][0]) for rid, name in self.labels
            ],
            "rank": self.rank,
            "n_parameters": len(self.labels),
            "undetermined": [f"{rid}.{CONTRACT_KEYS[n][0]}" for rid, n in self.undetermined],
        }


# --------------------------------------------------------------------------- helpers
def _free_terms(site: Site, time_offset: bool = False) -> tuple[str, ...]:
    return radar_terms(site, {}, time_offset).free


def _check_sigmas(site: Site) -> None:
    sig = site.measurement_sigmas()[: 3 if site.is_3d else 2]
    if not np.all(np.isfinite(sig) & (sig > 0)):
        raise ValueError(
            f"radar {site.id}: the CRLB needs its random-error sigmas (sites.toml gives none; "
            "estimate them first)"
        )


def _truth_reference(
    dataset: Dataset, radar_id: str, truth: pd.DataFrame, max_gap_s: float
) -> pd.Series:
    """True ECEF position per plot row (index: plot row label), from a trajectory table."""
    table = truth.copy()
    if "sigma_m" not in table:
        table["sigma_m"] = 0.0
    al = align_adsb(Dataset(dataset.sites, dataset.plots, table), radar_id, max_gap_s)
    return pd.Series(list(al.reference_ecef_m), index=al.plots.index, dtype=object)


# --------------------------------------------------------------------------- contributions
def _adsb_information(
    problem: Problem,
    columns: dict[str, list[tuple[int, int]]],
    p: int,
    truth: pd.DataFrame | None,
    max_gap_s: float,
) -> tuple[FloatArray, NDArray[np.int64], dict[str, int]]:
    """Fisher information of the ADS-B-matched plots; the matched plot rows; counts."""
    fisher = np.zeros((p, p))
    matched: list[NDArray[np.int64]] = []
    counts: dict[str, int] = {}
    dataset = problem.dataset
    for rid, site in dataset.sites.items():
        al = problem.alignment(rid, max_gap_s)
        if len(al) == 0:
            continue
        matched.append(al.plots.index)
        counts[rid] = len(al)
        if not columns.get(rid):
            continue
        ref = al.reference_ecef_m
        if truth is not None:
            true_pos = _truth_reference(dataset, rid, truth, max_gap_s)
            have = np.isin(al.plots.index, true_pos.index)
            ref = ref.copy()
            ref[have] = np.stack(true_pos.loc[al.plots.index[have]].to_list())
        polar, d_polar = measurement_model(site).position_jacobian(ref)
        m = 3 if site.is_3d else 2
        enu_rot = site.ecef_to_enu
        # ADS-B covariance is given in the radar's ENU; map ENU -> polar.
        d_polar_enu = d_polar @ enu_rot.T
        cov = d_polar_enu @ al.reference_enu_cov_m2 @ np.swapaxes(d_polar_enu, -1, -2)
        cov = cov[:, :m, :m]
        cov[:, np.arange(m), np.arange(m)] += site.measurement_sigmas()[:m] ** 2
        pos, glob = zip(*columns[rid], strict=True)
        jac = np.zeros((len(polar), m, len(TERM_NAMES)))
        jac[:, :, :4] = RadarMeasurementModel.bias_jacobian(polar[:, 0])[:, :m, :]
        # Time offset: the plot was made at t - tau, so d h / d tau = -(d polar/dt).
        jac[:, :, 4] = -np.einsum("nij,nj->ni", d_polar, al.reference_velocity_ecef_m_s)[:, :m]
        # Azimuth eccentricity: d az / d (s, c) = (sin az, cos az).
        jac[:, 1, 5] = np.sin(polar[:, 1])
        jac[:, 1, 6] = np.cos(polar[:, 1])
        whitened = cholesky_inverse(cov) @ jac[:, :, list(pos)]
        info = sum_of_products(whitened, None, whitened)
        fisher[np.ix_(glob, glob)] += info
    return fisher, np.concatenate(matched) if matched else np.zeros(0, np.int64), counts


def _cross_information(
    problem: Problem,
    columns: dict[str, list[tuple[int, int]]],
    p: int,
    exclude: NDArray[np.int64],
    event_s: float,
    height: tuple[HeightModel, list[int]] | None = None,
) -> tuple[FloatArray, dict[str, Any]]:
    """Fisher information of the cross-radar events, trajectories eliminated.

    ``height``: pressure altitudes, with the height model that places the 2-D plots
    and the two columns of ``(d, k)``.
    """
    dataset = problem.dataset
    blocks = []  # per radar: event key parts and whitened Jacobians
    for r_index, (rid, site) in enumerate(dataset.sites.items()):
        plots = problem.plots(rid)
        keep = (plots.target_id.astype(str) != "") & ~np.isin(plots.index, exclude)
        plots = plots.subset(keep)
        if len(plots) == 0:
            continue
        r, az = plots.range_m, plots.azimuth_rad
        pressure_m = plots.altitude_m
        if height is not None:
            plots.altitude_m = height[0].geometric(pressure_m)
        if site.is_3d:
            el = plots.elevation_rad
            usable = np.isfinite(el) & np.isfinite(r) & np.isfinite(az)
        else:
            el = apparent_elevation_from_height(site.atmosphere, site.lat_rad, site.alt_m, r,
                                                plots.altitude_m)
            with np.errstate(invalid="ignore"):
                usable = (np.isfinite(el) & np.isfinite(plots.altitude_m)
                          & (np.abs(el) < MAX_2D_ELEVATION_RAD))
        plots = plots.subset(usable)
        r, az, el, pressure_m = r[usable], az[usable], el[usable], pressure_m[usable]
        n = len(plots)
        if n == 0:
            continue
        ecef = site.ecef_from_enu(target_from_refracted(site.atmosphere, site.lat_rad,
                                                        site.alt_m, r, az, el))
        _, d_polar = measurement_model(site).position_jacobian(ecef)
        m = 3 if site.is_3d else 2
        sig = site.measurement_sigmas()[:m]
        # Rows: polar measurements (whitened), plus the reported height for 2-D radars.
        rows = m if site.is_3d else 3
        hx = np.zeros((n, rows, 3))
        hb = np.zeros((n, rows, p))
        hx[:, :m, :] = d_polar[:, :m, :] / sig[None, :, None]
        # The time offsets are taken as known in the cross-radar events (zero column).
        bias_jac = np.zeros((n, m, len(TERM_NAMES)))
        bias_jac[:, :, :4] = RadarMeasurementModel.bias_jacobian(r)[:, :m, :] / sig[None, :, None]
        bias_jac[:, 1, 5] = np.sin(az) / sig[1]
        bias_jac[:, 1, 6] = np.cos(az) / sig[1]
        for pos, glob in columns.get(rid, []):
            hb[:, :m, glob] = bias_jac[:, :, pos]
        if not site.is_3d:
            lat, lon, _ = frames.ecef_to_geodetic(ecef)
            up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)],
                          axis=-1)
            # p measures (h - d) / (1 + k) with 1-sigma ALTITUDE_SIGMA_M (the trajectory
            # formulation's measurement of the reported altitude).
            per_metre = 1.0 / ALTITUDE_SIGMA_M
            if height is not None:
                per_metre /= 1.0 + height[0].height_scale
            hx[:, 2, :] = up * per_metre
            if height is not None:
                hb[:, 2, height[1]] = -height_jacobian(pressure_m) * per_metre
        blocks.append((r_index, plots.target_id.astype(str), plots.time_s, hx, hb))
    empty = {"n_events": 0, "n_event_plots": 0}
    if not blocks:
        return np.zeros((p, p)), empty
    radar = np.concatenate([np.full(len(b[1]), b[0]) for b in blocks])
    target = np.concatenate([b[1] for b in blocks])
    time_s = np.concatenate([b[2] for b in blocks])
    # Every block has 3 rows: 3-D polar, or 2-D polar plus the reported height.
    hx = np.concatenate([b[3] for b in blocks])
    hb = np.concatenate([b[4] for b in blocks])
    bins = np.floor(time_s / event_s).astype(np.int64)
    _, event = np.unique(
        np.rec.fromarrays([pd.factorize(target)[0], bins]), return_inverse=True
    )
    event = event.ravel()
    n_events = int(event.max()) + 1
    # Keep the events seen by two radars or more.
    radar_count = np.zeros(n_events, dtype=np.int64)
    pairs = np.unique(np.stack([event, radar], axis=1), axis=0)
    np.add.at(radar_count, pairs[:, 0], 1)
    keep = radar_count[event] >= 2
    if not np.any(keep):
        return np.zeros((p, p)), empty
    event, time_s, hx, hb = event[keep], time_s[keep], hx[keep], hb[keep]
    _, event = np.unique(event, return_inverse=True)
    n_events = int(event.max()) + 1
    # Nuisance: position at the event's mean time and velocity.
    t_mean = np.bincount(event, time_s) / np.bincount(event)
    dt = (time_s - t_mean[event])[:, None, None]
    hn = np.concatenate([hx, hx * dt], axis=2)  # (n, 3, 6)
    fisher = np.einsum("nip,niq->pq", hb, hb)
    order = np.argsort(event, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(event[order]) != 0])
    a_nn = np.add.reduceat(np.einsum("nia,nib->nab", hn[order], hn[order]), starts, axis=0)
    a_bn = np.add.reduceat(np.einsum("nip,nia->npa", hb[order], hn[order]), starts, axis=0)
    # Scale position/velocity columns for a well-conditioned pseudo-inverse.
    scale = 1.0 / np.sqrt(np.maximum(np.einsum("eaa->ea", a_nn), 1e-300))
    a_nn_s = a_nn * scale[:, :, None] * scale[:, None, :]
    a_bn_s = a_bn * scale[:, None, :]
    inv = np.linalg.pinv(a_nn_s, rcond=1e-10, hermitian=True)
    fisher -= np.einsum("epa,eab,eqb->pq", a_bn_s, inv, a_bn_s)
    fisher = 0.5 * (fisher + fisher.T)
    return fisher, {"n_events": n_events, "n_event_plots": int(len(event))}


# --------------------------------------------------------------------------- main
def crlb(
    data: Dataset | Problem,
    *,
    use_adsb: bool = True,
    cross: bool = True,
    labels: list[Label] | None = None,
    truth: pd.DataFrame | None = None,
    priors: Mapping[Label, float] | str | None = None,
    max_gap_s: float = DEFAULT_ADSB_MAX_GAP_S,
    event_s: float | None = None,
    time_offset: bool = False,
    height_model: HeightModel | None = None,
) -> CrlbResult:
    """Cramér-Rao lower bound of the bias parameters (see the module docstring).

    Parameters
    ----------
    data : Dataset or Problem
        Sites (with their random-error sigmas), plots and optionally ADS-B; or the
        calibration problem holding them, whose alignments with ADS-B are reused.
    use_adsb : bool
        Use the ADS-B-matched plots (targets known up to the ADS-B noise).
    cross : bool
        Use the cross-radar events (targets unknown, eliminated).
    labels : list of (radar_id, parameter name), optional
        The parameters, e.g. a graph calibration's ``labels``; any other term is
        held known.  Default: every free term (graph's ``radar_terms``) of every
        radar with an observation, in dataset order - the graph's labels.
    truth : DataFrame, optional
        True trajectories in the ADS-B table format (``time_s``, ``target_id``,
        ``lat_deg``, ``lon_deg``, ``alt_m``), interpolated to the plot times
        for the ADS-B Jacobians; default: the ADS-B positions.
    priors : mapping, "graph" or None
        Prior 1-sigma [SI] per label, added as ``1 / sigma^2`` to the
        information; ``"graph"`` uses :func:`graphcal.model.parameters.prior_sigmas`.
    max_gap_s : float
        Longest ADS-B gap bridged by interpolation [s] (as the graph).
    event_s : float, optional
        Cross-radar event window [s]; default :data:`EVENT_SCANS` scans of the
        slowest radar (:data:`DEFAULT_EVENT_S` without scan periods).
    time_offset : bool
        With the default labels, also bound each radar's time-stamping bias
        (``graph(..., time_offset=True)``'s labels).  A time offset is informed
        by the ADS-B-matched plots (``d h / d tau = -d polar / dt`` along the ADS-B
        track); the cross-radar events take it as known.
    height_model : HeightModel, optional
        With pressure altitudes: the model that places the 2-D plots (e.g. the
        graph's estimate); default the identity.  The height model is an unknown
        of the bound whenever the dataset's plots carry pressure altitudes, with
        the graph's weak priors when ``priors`` is given.

    Returns
    -------
    CrlbResult
    """
    import time

    start = time.perf_counter()
    problem = as_problem(data)
    dataset = problem.dataset
    have_adsb = bool(use_adsb and dataset.adsb is not None and len(dataset.adsb) > 0)
    for site in dataset.sites.values():
        _check_sigmas(site)
    with_time = set()
    if time_offset and have_adsb:
        from graphcal.model.factor_set import radars_with_adsb

        with_time = radars_with_adsb(dataset)
    all_labels = [
        (rid, name) for rid, site in dataset.sites.items()
        for name in _free_terms(site, rid in with_time)
    ]
    candidate = list(labels) if labels is not None else all_labels
    for rid, name in candidate:
        if rid not in dataset.sites or name not in TERM_NAMES:
            raise ValueError(f"unknown parameter label ({rid!r}, {name!r})")
    p = len(candidate)
    columns: dict[str, list[tuple[int, int]]] = {}
    for i, (rid, name) in enumerate(candidate):
        columns.setdefault(rid, []).append((TERM_NAMES.index(name), i))
    # Pressure altitudes: the height model (d, k) takes the last two columns.
    height_cols = [p, p + 1] if dataset.pressure_altitudes else []
    size = p + len(height_cols)
    fisher = np.zeros((size, size))
    info: dict[str, Any] = {}
    matched = np.zeros(0, np.int64)
    if have_adsb:
        f_adsb, matched, counts = _adsb_information(problem, columns, size, truth, max_gap_s)
        fisher += f_adsb
        info["n_adsb_plots"] = counts
        if height_cols:
            segments = adsb_height_segments(dataset.adsb)
            jac = height_jacobian(segments.pressure_m) / segments.sigma_m[:, None]
            fisher[np.ix_(height_cols, height_cols)] += jac.T @ jac
            info["n_adsb_height_segments"] = len(segments)
    if cross:
        if event_s is None:
            periods = [s.scan_period_s for s in dataset.sites.values() if s.scan_period_s]
            event_s = EVENT_SCANS * max(periods) if periods else DEFAULT_EVENT_S
        height = (height_model or HeightModel(), height_cols) if height_cols else None
        f_cross, counts = _cross_information(problem, columns, size, matched, event_s, height)
        fisher += f_cross
        info.update(counts)
        info["event_s"] = event_s
    keep = list(range(p))
    if labels is None:
        # Drop the radars without any observation, as the graph does.
        radars_seen = {
            rid for rid, cols in columns.items() if any(fisher[j, j] > 0.0 for _, j in cols)
        }
        keep = [i for i, (rid, _) in enumerate(candidate) if rid in radars_seen]
        candidate = [candidate[i] for i in keep]
        p = len(candidate)
    fisher = fisher[np.ix_(keep + height_cols, keep + height_cols)]
    if priors is not None:
        prior_information = _prior_information(dataset, candidate, priors)
        if height_cols:
            prior_information = np.concatenate([prior_information,
                                                np.array(HEIGHT_PRIOR_SIGMA) ** -2.0])
        fisher = fisher + np.diag(prior_information)
    atmosphere_sigma = None
    if height_cols:
        fisher, atmosphere_sigma = _eliminate_height(fisher, p)
    covariance, rank, null_space, undetermined = _invert(fisher, candidate)
    info["timing_s"] = time.perf_counter() - start
    return CrlbResult(candidate, fisher, covariance, rank, null_space, undetermined, info,
                      atmosphere_sigma)


def _eliminate_height(fisher: FloatArray, p: int) -> tuple[FloatArray, dict[str, float]]:
    """The radar terms' information with the height model (last two columns) eliminated,
    ``F_rr - F_rh F_hh^+ F_hr``, and the height model's own bound (inf where undetermined)."""
    f_rr, f_rh, f_hh = fisher[:p, :p], fisher[:p, p:], fisher[p:, p:]
    reduced = f_rr - f_rh @ pseudo_inverse(f_hh).covariance @ f_rh.T
    inverse = pseudo_inverse(fisher)
    variance = np.where(inverse.undetermined[p:], np.inf, np.diag(inverse.covariance)[p:])
    sigma = dict(zip(HEIGHT_MODEL_KEYS, (float(np.sqrt(max(v, 0.0))) for v in variance),
                     strict=True))
    return 0.5 * (reduced + reduced.T), sigma


def _prior_information(
    dataset: Dataset, labels: list[Label], priors: Mapping[Label, float] | str
) -> FloatArray:
    if isinstance(priors, str):
        if priors != "graph":
            raise ValueError(f"unknown priors {priors!r}; give a mapping, 'graph' or None")
        sigma: dict[Label, float] = {}
        for rid, site in dataset.sites.items():
            terms = radar_terms(site, {})
            sigma.update(zip([(rid, n) for n in terms.free], prior_sigmas(site, terms),
                             strict=True))
    else:
        sigma = dict(priors)
    return np.array([
        1.0 / sigma[label] ** 2 if label in sigma and sigma[label] > 0 else 0.0
        for label in labels
    ])


def _invert(
    fisher: FloatArray, labels: list[Label]
) -> tuple[FloatArray, int, FloatArray, list[Label]]:
    """(Pseudo-)inverse, rank, null space and undetermined labels of a Fisher matrix."""
    inverse = pseudo_inverse(fisher)
    undetermined = [labels[i] for i in np.flatnonzero(inverse.undetermined)]
    return inverse.covariance, inverse.rank, inverse.null_space, undetermined
