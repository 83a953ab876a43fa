"""Each radar's residuals against a reference, per plot, for the model checks.

Residual = corrected measurement minus reference, in the radar's polar frame,
with its expected variance and what the model's own terms would add to it (the
regressors the checks fit out, :func:`graphcal.analysis.binned_test.fit_terms`).

* :func:`adsb_radar_residuals`: each plot against its aircraft's ADS-B position
  interpolated to the plot's true time (:func:`graphcal.data.align.align_adsb`,
  as :func:`graphcal.model.measurement.residual_stats` does); variance the
  radar's plus the ADS-B covariance mapped to polar
  (:func:`graphcal.model.measurement.polar_noise_variances`).  Regressors:
  range ``1, r`` (``r`` when the radar's model has a range gain) and the range
  rate (time offset); azimuth and elevation ``1`` and their rates.  A 2-D radar's
  reported (Mode C) altitude is a residual too: altitude minus the ADS-B height,
  variance :data:`graphcal.model.cross_radar.ALTITUDE_SIGMA_M` squared plus the
  ADS-B vertical variance, no regressor (the model takes it as the geometric
  height).
* :func:`cross_radar_residuals`: each cross-radar pair of corrected plots
  (:func:`graphcal.data.align.pair_plots`,
  :func:`graphcal.model.cross_radar.corrected_ecef`), the difference expressed in
  the polar frame of each of the two radars (that radar's plot minus the
  other's) and given to both, variance both plots' covariances mapped into that
  frame; a 2-D radar's altitude against a 3-D partner's height.  Regressors:
  ``1`` (and ``r`` for the range, as above) and each partner's bias terms'
  effect on the rows against that partner, so that the partners' estimation
  errors are not taken for structure of this radar.

The variables the checks bin by (range, azimuth, elevation or height) come from
each plot's track neighbours (:func:`binning_geometry`), time from the plot; so
do the Jacobians of the regressors and the variances without ADS-B, whose noise
is then independent of the residual's (at the plot itself they would be
correlated with it and bias the fitted terms).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.analysis.binned_test import segment_codes
from graphcal.core import frames
from graphcal.core.outliers import OUTLIER_SIGMAS, outlier_rows
from graphcal.data.align import (
    DEFAULT_ADSB_MAX_GAP_S,
    PlotArrays,
    neighbour_plots,
    overlapping_pairs,
    pair_plots,
)
from graphcal.data.bias import ECCENTRICITY, RadarBias
from graphcal.data.dataset import Dataset, Site
from graphcal.data.height import HeightModel
from graphcal.model.cross_radar import ALTITUDE_SIGMA_M, convert_plots, corrected_ecef
from graphcal.model.factor_set import polar_rate
from graphcal.model.measurement import (
    measured_polar,
    measurement_model,
    polar_noise_variances,
)
from graphcal.model.problem import Problem, as_problem

FloatArray = NDArray[np.float64]

#: Length [s] of the track segments that count as independent units.
SEGMENT_S = 60.0


@dataclass
class RadarResiduals:
    """One radar's residuals against a reference, per plot, SI units.

    Attributes
    ----------
    radar_id : str
    reference : {"adsb", "cross"}
        ADS-B positions, or the other radars' plots of the same aircraft.
    variables : dict of str to ndarray (n,)
        ``range`` [m], ``azimuth`` [rad], ``elevation`` [rad] (3-D) or
        ``height`` [m] (2-D), ``time`` [s] of each plot.
    residuals : dict of str to ndarray (n,)
        Corrected measurement minus reference per coordinate (``range`` [m],
        ``azimuth`` and ``elevation`` [rad], ``altitude`` [m]); NaN where a plot
        has none (e.g. no reported altitude).
    variances : dict of str to ndarray (n,)
        Their expected variances [m^2, rad^2].
    regressors : dict of str to ndarray (n, p)
        What the model's own terms add to each coordinate, per unit of each term.
    segment : ndarray (n,) of int
        Track segment of each plot
        (:func:`~graphcal.analysis.binned_test.segment_codes`, :data:`SEGMENT_S`).
    n_outliers : int
        Plots left out as gross outliers.
    partners : tuple of str
        ``cross``: the radars it was paired with.
    partner : ndarray (n,) of int or None
        ``cross``: index in ``partners`` of each residual's other radar.
    """

    radar_id: str
    reference: str
    variables: dict[str, FloatArray]
    residuals: dict[str, FloatArray]
    variances: dict[str, FloatArray]
    regressors: dict[str, FloatArray]
    segment: NDArray[np.int64]
    n_outliers: int = 0
    partners: tuple[str, ...] = ()
    partner: NDArray[np.int64] | None = None

    def __len__(self) -> int:
        return len(self.segment)

    def subset(self, keep: NDArray[np.bool_]) -> RadarResiduals:
        """The residuals of the rows ``keep``."""
        return replace(
            self,
            variables={k: v[keep] for k, v in self.variables.items()},
            residuals={k: v[keep] for k, v in self.residuals.items()},
            variances={k: v[keep] for k, v in self.variances.items()},
            regressors={k: v[keep] for k, v in self.regressors.items()},
            segment=self.segment[keep],
            partner=None if self.partner is None else self.partner[keep],
        )


def binning_geometry(
    site: Site, near: PlotArrays, height_m: FloatArray | None = None
) -> dict[str, FloatArray]:
    """Where each plot is, for binning: from its track neighbours, not from itself.

    ``near`` holds, for each plot, the mean of its neighbours ``k +- 2 ... k +- 5``
    (:func:`graphcal.data.align.neighbour_plots` with ``skip=1``).  Returned:
    range [m], azimuth [rad] and elevation [rad] (3-D) or height [m] (2-D: the
    reported altitude, else ``height_m``).  Binning by a value that shares noise
    with the residual (the plot itself, or the ADS-B reports it is compared
    with) would sort that noise into the bins: an aircraft flying level on a bin
    edge would put its positive errors in one bin and its negative ones in the
    next.  The neighbours' noise is independent of the residual's.
    """
    out = {"range": near.range_m, "azimuth": near.azimuth_rad}
    if site.is_3d:
        out["elevation"] = near.elevation_rad
    else:
        height = near.altitude_m
        if height_m is not None:
            height = np.where(np.isfinite(height), height, height_m)
        out["height"] = height
    return out


def has_eccentricity(site: Site, bias: RadarBias) -> bool:
    """Whether the radar's model has the azimuth eccentricity terms (estimated or fixed)."""
    return ECCENTRICITY in site.estimate or bias.has_eccentricity


def adsb_radar_residuals(
    data: Dataset | Problem,
    radar_id: str,
    bias: RadarBias,
    max_gap_s: float = DEFAULT_ADSB_MAX_GAP_S,
    height_model: HeightModel | None = None,
) -> RadarResiduals | None:
    """One radar's corrected plots against ADS-B (module doc); None when none aligns.

    ADS-B is interpolated at the plots' true times (``time_s - bias.time_offset_s``),
    along refracted rays when the radar declares refraction.  With pressure
    altitudes (``dataset.plot_altitude``), a 2-D plot's altitude residual is its
    height by ``height_model`` (the calibration's estimate; identity if none) less
    the ADS-B height, and the height model's two terms are its regressors.
    """
    problem = as_problem(data)
    dataset = problem.dataset
    site = dataset.sites[radar_id]
    al = problem.alignment(radar_id, max_gap_s, time_offset_s=bias.time_offset_s)
    if len(al) == 0:
        return None
    model = measurement_model(site)
    corrected = model.inverse_function(measured_polar(al), bias)
    ref = al.reference_polar
    noise = polar_noise_variances(al, site)
    rate = polar_rate(site, al)
    ones = np.ones(len(al))
    range_terms = [ones, rate[:, 0]]
    if "range_gain" in site.estimate or bias.range_gain != 0.0:
        range_terms.insert(1, ref[:, 0])
    azimuth_terms = [ones, rate[:, 1]]
    if has_eccentricity(site, bias):
        azimuth_terms += [np.sin(ref[:, 1]), np.cos(ref[:, 1])]
    residuals = {
        "range": corrected[:, 0] - ref[:, 0],
        "azimuth": frames.wrap_to_pi(corrected[:, 1] - ref[:, 1]),
    }
    variances = {"range": noise[:, 0], "azimuth": noise[:, 1]}
    regressors = {
        "range": np.stack(range_terms, axis=1),
        "azimuth": np.stack(azimuth_terms, axis=1),
    }
    height = frames.ecef_to_geodetic(al.reference_ecef_m)[2]
    variables = binning_geometry(site, neighbour_plots(al.plots, skip=1), height)
    variables["time"] = al.plots.time_s
    if site.is_3d:
        residuals["elevation"] = corrected[:, 2] - ref[:, 2]
        variances["elevation"] = noise[:, 2]
        regressors["elevation"] = np.stack([ones, rate[:, 2]], axis=1)
    elif np.any(np.isfinite(al.plots.altitude_m)):
        reported = al.plots.altitude_m
        if dataset.pressure_altitudes:
            residuals["altitude"] = (height_model or HeightModel()).geometric(reported) - height
            regressors["altitude"] = np.column_stack([ones, np.nan_to_num(reported)])
        else:
            residuals["altitude"] = reported - height
            regressors["altitude"] = np.zeros((len(al), 0))
        variances["altitude"] = ALTITUDE_SIGMA_M**2 + al.reference_enu_cov_m2[:, 2, 2]
    segment = segment_codes(al.plots.target_id, al.plots.time_s, SEGMENT_S)
    return without_outliers(RadarResiduals(radar_id, "adsb", variables, residuals, variances,
                                           regressors, segment))


def cross_radar_residuals(
    data: Dataset | Problem, biases: Mapping[str, RadarBias],
    height_model: HeightModel | None = None,
) -> dict[str, RadarResiduals]:
    """Every radar's corrected plots against its partners' (module doc).

    For each pair ``(a, b)`` of radars in ``biases``, each plot of ``b`` against
    ``a``'s track interpolated to its time (2.5 scans at most,
    :func:`graphcal.data.align.pair_max_gap_s`), both corrected; the difference
    is expressed in ``b``'s polar frame (``b`` minus ``a``) and in ``a``'s (``a``
    minus ``b``), with the noise of both plots mapped into that frame.  With
    pressure altitudes, 2-D plots are placed at their heights by ``height_model``
    (the calibration's estimate; identity if none), whose two terms are then
    regressors too.
    """
    problem = as_problem(data)
    dataset = problem.dataset
    radar_ids = [rid for rid in dataset.radar_ids if rid in biases]
    heights = (height_model or HeightModel()) if dataset.pressure_altitudes else None
    geometry = {rid: _corrected_plots(dataset.sites[rid], problem.plots(rid), biases[rid],
                                      heights)
                for rid in radar_ids}
    parts: dict[str, list[dict[str, Any]]] = {rid: [] for rid in radar_ids}
    for ra, rb in overlapping_pairs(dataset, radar_ids):
        ba, bb = biases[ra], biases[rb]
        pairs = pair_plots(dataset, ra, rb, shift_s=ba.time_offset_s - bb.time_offset_s,
                           plots=problem.all_plots)
        if len(pairs) == 0:
            continue
        ga, gb = geometry[ra], geometry[rb]
        # Rows of each radar's corrected plots, in pair_plots' orders.
        rows_a = ga.rows.get_indexer(pairs.a_plots.index)
        rows_b = gb.rows.get_indexer(pairs.b_plots.index)
        i0, w, ib = rows_a[pairs.a_index0], pairs.weight, rows_b[pairs.b_index]
        i1 = rows_a[pairs.a_index0 + 1]
        ok = ga.usable[i0] & ga.usable[i1] & gb.usable[ib]
        if not np.any(ok):
            continue
        # The partner's track interpolated quadratically where a third plot is usable
        # (graphcal.data.align.PlotPairs), as the graph's pairwise factors do.
        linear = np.stack([1.0 - w, w, np.zeros_like(w)], axis=1)
        if pairs.a_index2 is not None and pairs.quadratic_weights is not None:
            i2 = np.where(pairs.a_index2 >= 0,
                          rows_a[np.maximum(pairs.a_index2, 0)], i0)
            third = (pairs.a_index2 >= 0) & ga.usable[i2]
            c = np.where(third[:, None], pairs.quadratic_weights, linear)
        else:
            i2, c = i0, linear
        i0, i1, i2, c, ib = i0[ok], i1[ok], np.broadcast_to(i2, ok.shape)[ok], c[ok], ib[ok]
        rows = (i0, i1, i2)
        own_a = (_blend(ga.ecef_m, rows, c), _blend(ga.cov_m2, rows, c**2),
                 _blend(ga.jacobian, rows, c), _blend(ga.near_ecef_m, rows, c))
        own_b = (gb.ecef_m[ib], gb.cov_m2[ib], gb.jacobian[ib], gb.near_ecef_m[ib])
        altitude_a = _blend(ga.altitude_m, rows, c)
        reported_a = _blend(ga.reported_m, rows, c)
        shared = {"time": gb.time_s[ib], "target": gb.target_id[ib]}
        for rid, site, other_site, own, other, where, altitude, reported in (
            (rb, gb.site, ga.site, own_b, own_a, gb.where(ib), gb.altitude_m[ib],
             gb.reported_m[ib]),
            (ra, ga.site, gb.site, own_a, own_b, ga.where(i0), altitude_a, reported_a),
        ):
            part = _pair_differences(site, own, other, altitude, other_site)
            part.update(where, **shared, partner=other_site.id, reported=reported)
            parts[rid].append(part)
    out: dict[str, RadarResiduals] = {}
    for rid in radar_ids:
        if parts[rid]:
            out[rid] = without_outliers(_joined(
                dataset.sites[rid], biases[rid], parts[rid], dataset.pressure_altitudes))
    return out


def _blend(values: FloatArray, rows: tuple[NDArray[np.int64], ...], weights: FloatArray
           ) -> FloatArray:
    """``sum_j weights[:, j] * values[rows[j]]`` over the leading axis."""
    shape = (-1,) + (1,) * (values.ndim - 1)
    return sum(weights[:, j].reshape(shape) * values[r] for j, r in enumerate(rows))


@dataclass
class _CorrectedPlots:
    """One radar's plots corrected, in ECEF, with what the pair differences need.

    ``altitude_m`` is the height of a 2-D plot (its reported altitude, or that
    altitude through the height model when it is a pressure altitude; the
    reported one is ``reported_m``).  ``jacobian`` (d ECEF / d the radar's model
    terms, :func:`_terms_of`) and ``cov_m2`` are evaluated at each plot's
    track neighbours (:func:`graphcal.data.align.neighbour_plots`), whose
    corrected position is ``near_ecef_m``: their noise is independent of the
    plot's, where at the plot itself they would be correlated with the residual
    and bias the fitted terms (errors in variables).
    """

    site: Site
    rows: pd.Index
    ecef_m: FloatArray
    near_ecef_m: FloatArray
    jacobian: FloatArray
    cov_m2: FloatArray
    usable: NDArray[np.bool_]
    altitude_m: FloatArray
    time_s: FloatArray
    target_id: NDArray[np.object_]
    geometry: dict[str, FloatArray]
    reported_m: FloatArray

    def where(self, rows: NDArray[np.int64]) -> dict[str, FloatArray]:
        """The binning variables of ``rows``."""
        return {key: value[rows] for key, value in self.geometry.items()}


def _corrected_plots(site: Site, plots: PlotArrays, bias: RadarBias,
                     heights: HeightModel | None) -> _CorrectedPlots:
    """``jacobian`` columns: the radar's model terms (:func:`_terms_of`)."""
    near = neighbour_plots(plots, skip=1)
    options: dict[str, Any] = {}
    if has_eccentricity(site, bias):
        options["eccentricity"] = (bias.azimuth_sin_rad, bias.azimuth_cos_rad)
    if heights is not None and not site.is_3d:
        options["height_model"] = (heights.height_offset_m, heights.height_scale)
    ecef, _, usable = corrected_ecef(site, plots, bias.as_vector(), **options)
    near_ecef, jacobian, near_usable = corrected_ecef(site, near, bias.as_vector(), **options)
    near_ecef = np.where(near_usable[:, None], near_ecef, ecef)
    altitude = plots.altitude_m
    if "height_model" in options:
        altitude = heights.geometric(altitude)
    return _CorrectedPlots(
        site, pd.Index(plots.index), ecef, near_ecef, jacobian[:, :, _terms_of(site, options)],
        convert_plots(site, plots, near).cov_m2, usable, altitude, plots.time_s,
        plots.target_id, binning_geometry(site, near), plots.altitude_m,
    )


def _pair_differences(
    site: Site,
    own: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    other: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    altitude_m: FloatArray,
    other_site: Site,
) -> dict[str, Any]:
    """``own`` minus ``other`` in ``site``'s polar frame.

    ``own`` and ``other`` are (ECEF position, its covariance, d ECEF / d bias,
    the neighbours' ECEF position) of the corrected plots.  Returns the
    differences ``d_*``, their variances ``v_*`` and the partner's bias terms'
    effect on them, ``other_terms`` ``(n, 3, 4)``: d(difference) / d(partner's
    range offset, gain, azimuth and elevation bias).  The polar Jacobian is taken
    at the own plot's neighbours (noise independent of the differences).
    """
    (own_ecef, own_cov, _, own_near), (other_ecef, other_cov, other_jac, _) = own, other
    own_enu, other_enu = site.enu_from_ecef(own_ecef), site.enu_from_ecef(other_ecef)
    r_own, az_own, el_own = frames.enu_to_polar(own_enu)
    r_other, az_other, el_other = frames.enu_to_polar(other_enu)
    near_enu = site.enu_from_ecef(own_near)
    ground = np.hypot(near_enu[:, 0], near_enu[:, 1])
    jac = frames.enu_to_polar_jacobian(np.where((ground > 0)[:, None], near_enu, [1.0, 0, 0]))
    jac = jac @ site.ecef_to_enu
    polar_cov = jac @ (own_cov + other_cov) @ np.swapaxes(jac, 1, 2)
    out = {
        "d_range": r_own - r_other, "d_azimuth": frames.wrap_to_pi(az_own - az_other),
        "d_elevation": el_own - el_other, "v_range": polar_cov[:, 0, 0],
        "v_azimuth": polar_cov[:, 1, 1], "v_elevation": polar_cov[:, 2, 2],
        "d_altitude": np.full(len(r_own), np.nan), "v_altitude": np.full(len(r_own), np.nan),
        "other_terms": -(jac @ other_jac),
    }
    if not site.is_3d and other_site.is_3d:
        # A 2-D plot's reported altitude against a 3-D radar's (measured) height.
        lat, lon, height = frames.ecef_to_geodetic(other_ecef)
        up = frames.ecef_to_enu_rotation(lat, lon)[:, 2, :]
        out["d_altitude"] = altitude_m - height
        out["v_altitude"] = ALTITUDE_SIGMA_M**2 + np.einsum("ni,nij,nj->n", up, other_cov, up)
        out["altitude_terms"] = -np.einsum("ni,nij->nj", up, other_jac)
    else:
        out["altitude_terms"] = np.zeros((len(r_own), other_jac.shape[2]))
    return out


def _terms_of(site: Site, options: Mapping[str, Any]) -> list[int]:
    """Columns of :func:`graphcal.model.cross_radar.corrected_ecef`'s Jacobian that are terms
    of the radar's model: offset, gain, azimuth and (3-D) elevation bias when in its
    ``estimate`` list, the eccentricity ``(s, c)`` and the height model ``(d, k)``
    when ``options`` asks for them."""
    names = ("range_offset", "range_gain", "azimuth_bias", "elevation_bias")
    columns = [k for k, name in enumerate(names) if name in site.estimate
               and (site.is_3d or name != "elevation_bias")]
    extra = 4
    if "eccentricity" in options:
        columns += [4, 5]
        extra = 6
    if "height_model" in options:
        columns += [extra, extra + 1]
    return columns


def _joined(site: Site, bias: RadarBias, parts: list[dict[str, Any]], pressure: bool
            ) -> RadarResiduals:
    """One radar's pair differences from every partner, as :class:`RadarResiduals`.

    Regressors of each coordinate: a constant (the radar's own offset or bias),
    the range ``r`` for the range when the radar's model has a range gain,
    ``sin az, cos az`` for the azimuth when it has an eccentricity, ``1, p`` for
    a pressure altitude ``p`` (the height model; none for a geometric one), and
    each partner's model terms' effect on the rows against that partner (zero on
    the others), so that the partners' estimates' errors are not taken for
    structure of this radar.
    """
    n_rows = [len(p["time"]) for p in parts]
    joined = {key: np.concatenate([np.broadcast_to(p[key], (n,) + np.shape(p[key])[1:])
                                   for p, n in zip(parts, n_rows, strict=True)])
              for key in parts[0] if key not in ("other_terms", "altitude_terms")}
    partners = tuple(sorted({str(p["partner"]) for p in parts}))
    partner = np.searchsorted(np.array(partners), joined["partner"].astype(str))
    n = len(joined["time"])
    coordinates = ["range", "azimuth"] + (["elevation"] if site.is_3d else [])
    if not site.is_3d and np.any(np.isfinite(joined["d_altitude"])):
        coordinates.append("altitude")
    # The partners' terms: one block of columns per partner, filled on its rows.
    blocks: dict[str, list[FloatArray]] = {c: [] for c in coordinates}
    for name in partners:
        width = next(p["other_terms"].shape[2] for p in parts if p["partner"] == name)
        for c in coordinates:
            effect = [(p["altitude_terms"] if c == "altitude"
                       else p["other_terms"][:, coordinates.index(c), :])
                      if p["partner"] == name else np.zeros((count, width))
                      for p, count in zip(parts, n_rows, strict=True)]
            block = np.concatenate(effect)
            blocks[c].append(block[:, np.any(block != 0.0, axis=0)])
    ones = np.ones((n, 1))
    own = {c: ones for c in coordinates}
    if "range_gain" in site.estimate or bias.range_gain != 0.0:
        own["range"] = np.column_stack([ones, joined["range"]])
    if has_eccentricity(site, bias):
        own["azimuth"] = np.column_stack([ones, np.sin(joined["azimuth"]),
                                          np.cos(joined["azimuth"])])
    if "altitude" in own:
        own["altitude"] = (np.column_stack([ones, np.nan_to_num(joined["reported"])])
                           if pressure else np.zeros((n, 0)))
    regressors = {c: np.column_stack([own[c], *blocks[c]]) for c in coordinates}
    variables = {k: joined[k] for k in ("range", "azimuth", "elevation", "height", "time")
                 if k in joined}
    segment = segment_codes(joined["target"], joined["time"], SEGMENT_S)
    return RadarResiduals(
        site.id, "cross", variables, {c: joined[f"d_{c}"] for c in coordinates},
        {c: joined[f"v_{c}"] for c in coordinates}, regressors, segment,
        partners=partners, partner=partner.astype(np.int64),
    )


def without_outliers(res: RadarResiduals) -> RadarResiduals:
    """``res`` without the plots beyond :data:`OUTLIER_SIGMAS` robust sigmas in any coordinate
    (:func:`graphcal.core.outliers.outlier_rows`)."""
    if len(res) == 0 or not res.residuals:
        return res
    with np.errstate(invalid="ignore", divide="ignore"):
        bad = outlier_rows(e / np.sqrt(res.variances[key]) for key, e in res.residuals.items())
    if not bad.any():
        return res
    out = res.subset(~bad)
    out.n_outliers = res.n_outliers + int(bad.sum())
    return out


__all__ = ["OUTLIER_SIGMAS", "SEGMENT_S", "RadarResiduals", "adsb_radar_residuals",
           "binning_geometry", "cross_radar_residuals", "without_outliers"]
