"""The graph's factors of one calibration: its variables and its observation blocks.

:class:`FactorSet` holds, per radar, the free terms
(:class:`~graphcal.model.parameters.RadarTerms`) and the key of its bias
variable, and the observation blocks that :func:`build_factors` builds from a
calibration problem (:class:`~graphcal.model.problem.Problem`, whose alignments
with ADS-B it uses): one vectorised ADS-B factor per radar (plots against the ADS-B
position of their aircraft) and one pairwise factor per radar pair (paper
001's differences of converted positions).  With pressure altitudes
(``height_key`` set) it also holds the height-model variable: the pairs with a
2-D radar depend on it, and the ADS-B reports with both heights measure it
(:mod:`graphcal.model.height`).  The graph solver optimises it; the
observability analysis and the selection read its information.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.data.align import (
    AdsbAlignment,
    AdsbTrackTable,
    PlotArrays,
    adsb_track_table,
    overlapping_pairs,
    pair_plots,
)
from graphcal.data.dataset import Dataset, Site
from graphcal.model.cross_radar import RayExcessCache
from graphcal.model.factors import (
    AdsbFactor,
    PairwiseFactor,
    adsb_factor,
    pairwise_factor,
    share_corrections,
)
from graphcal.model.height import AdsbHeightFactor, adsb_height_factor
from graphcal.model.measurement import measurement_model, reference_polar_covariance
from graphcal.model.parameters import RadarTerms
from graphcal.model.problem import Problem, as_problem
from graphcal.model.robust import RobustKernel

FloatArray = NDArray[np.float64]
Progress = Callable[..., None]

#: Cross-radar formulations.
CROSS_MODES: tuple[str, ...] = ("trajectory", "pairwise", "target-state", "none")
#: Fastest plausible aircraft ground speed [m/s]; a faster ADS-B segment holds an outlier.
ADSB_MAX_SPEED_M_S = 600.0


@dataclass
class FactorSet:
    """Factors and variables of one calibration."""

    terms: dict[str, RadarTerms]
    keys: dict[str, int]
    adsb: dict[str, AdsbFactor] = field(default_factory=dict)
    alignments: dict[str, AdsbAlignment] = field(default_factory=dict)
    pairs: list[PairwiseFactor] = field(default_factory=list)
    target_state: Any = None
    height_key: int | None = None
    height: AdsbHeightFactor | None = None
    rays: dict[str, RayExcessCache] = field(default_factory=dict)

    def variable_radars(self) -> list[str]:
        """Radars with at least one factor and one free term, in dataset order."""
        seen = set(self.adsb)
        for f in self.pairs:
            seen.update([f.terms_a.radar_id, f.terms_b.radar_id])
        if self.target_state is not None:
            seen.update(self.target_state.radars_seen)
        return [rid for rid in self.terms if rid in seen and self.terms[rid].free]


def without_plots(dataset: Dataset, exclude_rows: NDArray[np.int64]) -> Dataset:
    """``dataset`` without the plot rows ``exclude_rows``."""
    if len(exclude_rows) == 0:
        return dataset
    plots = dataset.plots.drop(index=exclude_rows)
    return Dataset(dataset.sites, plots, dataset.adsb, dataset.path,
                   plot_altitude=dataset.plot_altitude)


def polar_rate(site: Site, al: AdsbAlignment) -> FloatArray:
    """Time derivative of the aligned ADS-B reference in the radar's polar frame ``(n, 3)``.

    A bracketing ADS-B segment faster than :data:`ADSB_MAX_SPEED_M_S` holds an
    outlier report; its plots get a zero rate (they do not inform the time offset),
    so that the outlier cannot lever the time offset through its Jacobian.
    """
    enu = site.enu_from_ecef(al.reference_ecef_m)
    velocity = al.reference_velocity_ecef_m_s
    plausible = frames.row_norm(velocity) <= ADSB_MAX_SPEED_M_S
    velocity_enu = frames.rotate(np.where(plausible[:, None], velocity, 0.0), site.ecef_to_enu)
    jac = al.reference_polar_jacobian
    if site.atmosphere is None:
        jac = frames.enu_to_polar_jacobian(enu)  # measurement_model(site).enu_jacobian's
    elif jac is None:
        _, jac = measurement_model(site).enu_jacobian(enu)
    return np.einsum("nij,nj->ni", jac, velocity_enu)


def build_factors(
    data: Dataset | Problem,
    blocks: FactorSet,
    use_adsb: bool,
    cross: str,
    kernel: RobustKernel,
    adsb_max_gap_s: float,
    pair_max_gap_s: float | None,
    progress: Progress | None,
    tau0: dict[str, float] | None = None,
) -> None:
    """ADS-B and pairwise factors, aligned at the time offsets ``tau0`` [s] (default 0), into
    ``blocks``; the alignments at zero time offset are the problem's."""
    problem = as_problem(data)
    dataset = problem.dataset
    radar_ids = list(dataset.radar_ids)
    tau0 = {rid: (tau0 or {}).get(rid, 0.0) for rid in radar_ids}
    blocks.adsb.clear()
    blocks.alignments.clear()
    blocks.pairs.clear()
    blocks.height = None
    if use_adsb and blocks.height_key is not None:
        blocks.height = adsb_height_factor(dataset.adsb, blocks.height_key, kernel)
    matched: list[NDArray[np.int64]] = []
    if use_adsb:
        for i, rid in enumerate(radar_ids):
            al = problem.alignment(rid, adsb_max_gap_s, time_offset_s=tau0[rid])
            if progress is not None:
                progress("ADS-B association", i + 1, len(radar_ids))
            if len(al) == 0:
                continue
            blocks.alignments[rid] = al
            site = dataset.sites[rid]
            rate = polar_rate(site, al) if "time_offset" in blocks.terms[rid].free else None
            blocks.adsb[rid] = adsb_factor(
                site, blocks.terms[rid], blocks.keys[rid], al.plots,
                al.reference_polar, reference_polar_covariance(al, site), kernel, rate, tau0[rid],
            )
            matched.append(al.plots.index)
    if cross != "pairwise":
        return
    rest = without_plots(dataset, np.concatenate(matched) if matched else np.zeros(0, np.int64))
    rest_plots = Problem(rest).all_plots  # the plots left for the pairs, converted once
    _share_rays(rest, rest_plots, blocks)
    todo = overlapping_pairs(rest, radar_ids)
    for n, (ra, rb) in enumerate(todo):
        pairs = pair_plots(rest, ra, rb, pair_max_gap_s, shift_s=tau0[ra] - tau0[rb],
                           plots=rest_plots)
        if progress is not None:
            progress("cross-radar pairs", n + 1, len(todo))
        if len(pairs) == 0:
            continue
        both_3d = dataset.sites[ra].is_3d and dataset.sites[rb].is_3d
        factor = pairwise_factor(
            dataset.sites[ra], dataset.sites[rb], blocks.terms[ra], blocks.terms[rb],
            blocks.keys[ra], blocks.keys[rb], pairs.a_plots, pairs.b_plots,
            pairs.a_index0, pairs.weight, pairs.b_index, kernel, tau0[ra], tau0[rb],
            None if both_3d else blocks.height_key, blocks.rays.get(ra), blocks.rays.get(rb),
            pairs.a_index2, pairs.quadratic_weights,
        )
        if factor is not None:
            blocks.pairs.append(factor)
    share_corrections(blocks.pairs)


def _share_rays(rest: Dataset, rest_plots: dict[str, PlotArrays], blocks: FactorSet) -> None:
    """One :class:`RayExcessCache` per refracting radar over the plots left for pairs,
    kept from an earlier build when it still holds them all."""
    for rid, site in rest.sites.items():
        if site.atmosphere is None:
            continue
        plots = rest_plots[rid]
        old = blocks.rays.get(rid)
        if old is None or len(old.plots) != len(plots) or not old.covers(plots):
            blocks.rays[rid] = RayExcessCache(site, plots)


def radars_with_adsb(dataset: Dataset, tracks: AdsbTrackTable | None = None) -> set[str]:
    """Radars with at least one plot whose ``target_id`` has ADS-B reports (``tracks``:
    the ADS-B table's tracks when the caller has them)."""
    if dataset.adsb is None or len(dataset.adsb) == 0:
        return set()
    targets = (adsb_track_table(dataset.adsb) if tracks is None else tracks).targets
    plots = dataset.plots
    seen = plots["radar_id"][plots["target_id"].astype(str).isin(targets)]
    return {str(rid) for rid in pd.unique(seen)}
