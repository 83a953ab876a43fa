"""Association and time alignment of radar plots with ADS-B and with other radars.

* Plots are associated with ADS-B reports by ``target_id`` (the ICAO address).
* ADS-B positions are interpolated linearly to each plot time, paper 003
  eq. 6-7 with its misprint corrected: ``x = x_j + v_x (t_R - t_j)`` with
  ``v_x = (x_{j+1} - x_j) / (t_{j+1} - t_j)``.  Interpolation is done in ECEF,
  which is equivalent to the paper's radar-local Cartesian frame because the
  two differ by an affine map.
* Gaps between the two bracketing reports longer than ``max_gap_s`` are not
  bridged: such plots are left out.
* Cross-radar pairs: each plot of radar *b* is paired with the two plots of
  radar *a* of the same target that bracket its time (no more than
  ``max_gap_s`` apart), with the interpolation weight.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.grouped import group_order, group_rows
from graphcal.core.refraction import refracted_polar_jacobian
from graphcal.core.rows import take_rows
from graphcal.core.solve_options import DEFAULT_ADSB_MAX_GAP_S
from graphcal.data.dataset import Dataset, Site

#: Longest gap between a radar's bracketing plots, in scan periods, for cross-radar pairs.
DEFAULT_PAIR_MAX_GAP_SCANS = 2.5
#: Fallback gap limit [s] for cross-radar pairs when the scan period is unknown.
DEFAULT_PAIR_MAX_GAP_S = 15.0
#: ADS-B vertical sigma as a multiple of the horizontal one (GNSS geometry).
ADSB_VERTICAL_SIGMA_RATIO = 1.5

FloatArray = NDArray[np.float64]


@dataclass
class PlotArrays:
    """One radar's plots as SI arrays (azimuth and elevation in radians)."""

    index: NDArray[np.int64]
    time_s: FloatArray
    range_m: FloatArray
    azimuth_rad: FloatArray
    elevation_rad: FloatArray
    altitude_m: FloatArray
    target_id: NDArray[np.object_]

    def __len__(self) -> int:
        return len(self.index)

    def subset(self, mask: NDArray[np.bool_]) -> PlotArrays:
        """The plots selected by ``mask``."""
        return PlotArrays(
            *(getattr(self, name)[mask] for name in self.__dataclass_fields__)
        )


def plot_arrays(dataset: Dataset, radar_id: str, table: PlotTable | None = None
                ) -> PlotArrays:
    """The plots of ``radar_id`` in time order, as SI arrays.

    ``table``: the plots table already converted (:func:`plot_table`), when the caller
    keeps it (:class:`graphcal.model.problem.Problem` does, for all its radars).
    """
    # The rows of Dataset.plots_of (a stable sort by time), without building its table.
    table = plot_table(dataset.plots) if table is None else table
    code = table.radar_codes.get(radar_id)
    rows = (table.order[table.start[code]:table.start[code + 1]] if code is not None
            else np.zeros(0, dtype=np.int64))
    return PlotArrays(*(getattr(table.columns, name)[rows]
                        for name in PlotArrays.__dataclass_fields__))


@dataclass(frozen=True)
class PlotTable:
    """A plots table as SI arrays, its rows grouped by radar and in time order."""

    columns: PlotArrays  # every row, in table order
    radar_codes: dict[str, int]
    order: NDArray[np.int64]  # rows by (radar code, time), ties by row
    start: NDArray[np.int64]  # radar code k's rows are order[start[k]:start[k + 1]]


def plot_table(plots: pd.DataFrame) -> PlotTable:
    """A plots table as SI arrays, grouped by radar and in time order."""
    def column(name: str) -> NDArray[np.float64]:
        if name not in plots:
            return np.full(len(plots), np.nan)
        return plots[name].to_numpy(dtype=float)

    codes, names = pd.factorize(plots["radar_id"].astype(str))
    time_s = column("time_s")
    order = group_order(codes, time_s)
    start = np.searchsorted(codes[order], np.arange(len(names) + 1)).astype(np.int64)
    columns = PlotArrays(
        index=plots.index.to_numpy(dtype=np.int64),
        time_s=time_s,
        range_m=column("range_m"),
        azimuth_rad=np.deg2rad(column("azimuth_deg")),
        elevation_rad=np.deg2rad(column("elevation_deg")),
        altitude_m=column("altitude_m"),
        target_id=plots["target_id"].to_numpy(dtype=object),
    )
    return PlotTable(columns, {str(name): k for k, name in enumerate(names)}, order, start)


def neighbour_plots(plots: PlotArrays, skip: int = 1, half_width: int = 4) -> PlotArrays:
    """Each plot replaced by the mean of its track neighbours, the plot itself left out.

    For plot ``k`` of a target's time-ordered track, the mean of the plots
    ``k +- (skip + 1) ... k +- (skip + half_width)`` of the same target (range,
    altitude and elevation arithmetic, azimuth circular); a plot without such
    neighbours keeps its own values.  Their noise is independent of the plots
    ``k - skip ... k + skip``, which makes them instruments: a Jacobian evaluated
    at them carries no noise correlated with an observation built from those
    plots (the errors-in-variables bias of evaluating it at the plots themselves).
    """
    n = len(plots)
    # Aircraft as codes (-1: unknown), so that tracks are sorted and compared as integers.
    codes, names = pd.factorize(plots.target_id.astype(str))
    unknown = np.asarray(names == "", dtype=bool)
    codes = np.where((codes < 0) | unknown[np.maximum(codes, 0)], -1, codes)
    order = np.lexsort((plots.time_s, codes))
    codes = codes[order]
    values = {
        "range_m": plots.range_m[order],
        "elevation_rad": plots.elevation_rad[order],
        "altitude_m": plots.altitude_m[order],
    }
    finite = {name: np.isfinite(v) for name, v in values.items()}
    sums = {name: np.zeros(n) for name in values}
    counts = {name: np.zeros(n) for name in values}
    east = np.zeros(n)
    north = np.zeros(n)
    az = plots.azimuth_rad[order]
    sin_az, cos_az = np.sin(az), np.cos(az)
    n_neighbours = np.zeros(n)
    index = np.arange(n)
    for step in range(skip + 1, skip + half_width + 1):
        for shift in (step, -step):
            # Plot k takes plot k + shift of the same aircraft; masked sums add 0.0, which
            # leaves every sum as the gathered additions would (in the same order).
            src = np.clip(index + shift, 0, max(n - 1, 0))
            ok = (index + shift >= 0) & (index + shift < n) & (codes >= 0)
            ok &= codes[src] == codes
            for name, v in values.items():
                use = ok & finite[name][src]
                sums[name] += np.where(use, v[src], 0.0)
                counts[name] += use
            east += np.where(ok, sin_az[src], 0.0)
            north += np.where(ok, cos_az[src], 0.0)
            n_neighbours += ok
    out = {}
    for name, v in values.items():
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = sums[name] / counts[name]
        out[name] = np.where(counts[name] > 0, mean, v)
    out["azimuth_rad"] = np.where(n_neighbours > 0, np.mod(np.arctan2(east, north), 2 * np.pi),
                                  az)
    inverse = np.empty(n, dtype=np.int64)
    inverse[order] = np.arange(n)
    return PlotArrays(
        index=plots.index, time_s=plots.time_s, range_m=out["range_m"][inverse],
        azimuth_rad=out["azimuth_rad"][inverse], elevation_rad=out["elevation_rad"][inverse],
        altitude_m=out["altitude_m"][inverse], target_id=plots.target_id,
    )


@dataclass
class AdsbAlignment:
    """Plots of one radar with the ADS-B position of the same aircraft at each plot time.

    Attributes
    ----------
    plots : PlotArrays
        The aligned plots (a subset of the radar's plots).
    reference_ecef_m : ndarray, shape (n, 3)
        Interpolated ADS-B position at each plot time [m].
    reference_polar : ndarray, shape (n, 3)
        That position in the radar's polar coordinates (range m, azimuth rad,
        elevation rad).
    reference_enu_cov_m2 : ndarray, shape (n, 3, 3)
        Covariance of the interpolated ADS-B position in the radar's ENU [m^2].
    n_unmatched : int
        Plots with no ADS-B of their aircraft within the gap limit.
    reference_velocity_ecef_m_s : ndarray, shape (n, 3)
        Velocity of the ADS-B track at each plot time [m/s]: the slope between the
        reports just outside the bracketing pair (``j - 1`` and ``j + 2``), whose noise
        is independent of the interpolated position; the bracketing segment's slope
        where those do not exist.
    time_offset_s : float
        The radar's time-stamping bias assumed in the alignment: ADS-B is
        interpolated at ``time_s - time_offset_s`` (CONTRACT.md:
        ``time_reported = time_true + time_offset_s``).
    reference_polar_jacobian : ndarray, shape (n, 3, 3), or None
        ``d reference_polar / d enu`` (radar ENU) along the refracted rays, for a
        radar with refraction (traced once here, used by the noise conversion and
        the time-offset rates); ``None`` for straight lines.
    target_code : ndarray, shape (n,), of int, or None
        Each plot's aircraft as its position among the ADS-B aircraft sorted by
        identity (:attr:`AdsbTrackTable.targets`): the identities' order, as integers.
    """

    radar_id: str
    plots: PlotArrays
    reference_ecef_m: FloatArray
    reference_polar: FloatArray
    reference_enu_cov_m2: FloatArray
    n_unmatched: int
    reference_velocity_ecef_m_s: FloatArray | None = None
    time_offset_s: float = 0.0
    reference_polar_jacobian: FloatArray | None = None
    target_code: NDArray[np.int64] | None = None
    #: Arrays computed from this alignment alone, once (e.g. the reference's polar
    #: covariance, :func:`graphcal.model.measurement.reference_polar_covariance`).
    derived: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)

    def __len__(self) -> int:
        return len(self.plots)


def tracks_by_target(
    time_s: FloatArray, target_id: pd.Series, *columns: FloatArray, skip_empty: bool = True
) -> dict[str, tuple[FloatArray, ...]]:
    """Rows grouped per aircraft: ``(time_s, *columns)``, time-sorted, repeated times dropped.

    Rows with an empty ``target_id`` are left out when ``skip_empty``.
    """
    tracks: dict[str, tuple[FloatArray, ...]] = {}
    for target, rows in target_id.groupby(target_id, sort=False).indices.items():
        if skip_empty and not target:
            continue
        order = rows[np.argsort(time_s[rows], kind="stable")]
        keep = np.concatenate([[True], np.diff(time_s[order]) > 0])
        order = order[keep]
        tracks[str(target)] = (time_s[order], *(c[order] for c in columns))
    return tracks


def adsb_tracks(adsb: pd.DataFrame) -> dict[str, tuple[FloatArray, FloatArray, FloatArray]]:
    """ADS-B per aircraft: (time_s, ecef_m, sigma_m), time-sorted, duplicate times removed."""
    ecef = frames.geodetic_to_ecef(
        np.deg2rad(adsb["lat_deg"].to_numpy(float)),
        np.deg2rad(adsb["lon_deg"].to_numpy(float)),
        adsb["alt_m"].to_numpy(float),
    )
    return tracks_by_target(  # type: ignore[return-value]
        adsb["time_s"].to_numpy(float), adsb["target_id"], ecef,
        adsb["sigma_m"].to_numpy(float),
    )


def bracket(
    track_time_s: FloatArray, query_time_s: FloatArray, max_gap_s: float
) -> tuple[NDArray[np.int64], FloatArray, NDArray[np.bool_]]:
    """Bracketing samples for linear interpolation.

    Returns ``(j, w, ok)`` such that the value at ``query_time_s`` is
    ``(1 - w) * v[j] + w * v[j + 1]``; ``ok`` is False where the query lies
    outside the track or the bracketing samples are more than ``max_gap_s``
    apart (a query exactly at a sample time is always accepted).
    """
    n = len(track_time_s)
    if n < 2:
        zeros = np.zeros(len(query_time_s), dtype=np.int64)
        return zeros, np.zeros(len(query_time_s)), np.zeros(len(query_time_s), dtype=bool)
    j = np.searchsorted(track_time_s, query_time_s, side="right") - 1
    j = np.clip(j, 0, n - 2)
    t0, t1 = track_time_s[j], track_time_s[j + 1]
    w = (query_time_s - t0) / (t1 - t0)
    on_sample = (w == 0.0) | (w == 1.0)
    ok = (w >= 0.0) & (w <= 1.0) & ((t1 - t0 <= max_gap_s) | on_sample)
    return j, np.clip(w, 0.0, 1.0), ok


@dataclass
class AdsbTrackTable:
    """Every aircraft's ADS-B reports in one set of arrays, by aircraft then time.

    The reports of :func:`adsb_tracks`' tracks (time-sorted per aircraft, repeated
    times and empty identities dropped), concatenated in the order of
    :attr:`targets`, so that plots of any aircraft are aligned by one vectorised
    search instead of one per aircraft.

    Attributes
    ----------
    targets : pandas.Index
        Aircraft identities; aircraft ``k``'s reports are rows
        ``start[k]:start[k + 1]``.
    start : ndarray (k + 1,) of int
    time_s : ndarray (m,)
    ecef_m : ndarray (m, 3)
    sigma_m : ndarray (m,)
    key : ndarray (m,) of complex
        ``k + 1j * time_s``: numpy orders complex numbers by real then imaginary
        part, so this is sorted and searchable by (aircraft, time).
    """

    targets: pd.Index
    start: NDArray[np.int64]
    time_s: FloatArray
    ecef_m: FloatArray
    sigma_m: FloatArray
    key: NDArray[np.complex128]

    def codes(self, target_id: NDArray[np.object_]) -> NDArray[np.int64]:
        """Position in :attr:`targets` of each identity, ``-1`` where it has no track."""
        return self.targets.get_indexer(pd.Index(target_id, dtype=object)).astype(np.int64)

    def bracket(
        self, code: NDArray[np.int64], query_time_s: FloatArray, max_gap_s: float
    ) -> tuple[NDArray[np.int64], FloatArray, NDArray[np.bool_]]:
        """:func:`bracket` of each query in its aircraft's track, row indices global.

        ``code`` from :meth:`codes`; ``ok`` is False also where ``code`` is -1 or
        the track has fewer than two reports.
        """
        known = code >= 0
        if not len(self.targets):  # no track at all (an empty ADS-B table)
            n = len(query_time_s)
            return np.zeros(n, dtype=np.int64), np.zeros(n), np.zeros(n, dtype=bool)
        c = np.where(known, code, 0)
        j, w, ok = bracket_in_blocks(self.time_s, self.key, c, self.start[c],
                                     self.start[c + 1], query_time_s, max_gap_s)
        return j, w, ok & known


def bracket_in_blocks(
    time_s: FloatArray, key: NDArray[np.complex128], code: NDArray[np.int64],
    lo: NDArray[np.int64], hi: NDArray[np.int64], query_time_s: FloatArray, max_gap_s: float,
) -> tuple[NDArray[np.int64], FloatArray, NDArray[np.bool_]]:
    """:func:`bracket` of each query within its own block of a blocked, sorted series.

    The series holds blocks (tracks) one after the other, each sorted by time;
    ``key`` is ``block number + 1j * time_s`` (sorted, as numpy orders complex
    numbers by real then imaginary part).  Query ``i`` is bracketed in block
    ``code[i]``, rows ``lo[i]:hi[i]``, exactly as :func:`bracket` would on that
    block alone; the returned ``j`` are global rows.  The queries are searched
    block by block (:func:`~graphcal.core.grouped.group_rows`): close keys keep the
    search's memory accesses close, a fifth of the time of the plots' time order.
    """
    order = group_rows(code)
    position = np.empty(len(code), dtype=np.intp)
    position[order] = np.searchsorted(key, code[order] + 1j * query_time_s[order],
                                      side="right")
    j = np.clip(position - 1, lo, np.maximum(hi - 2, lo))
    last = max(len(time_s) - 1, 0)
    t0, t1 = time_s[j], time_s[np.minimum(j + 1, last)]
    with np.errstate(invalid="ignore", divide="ignore"):
        w = (query_time_s - t0) / (t1 - t0)
    on_sample = (w == 0.0) | (w == 1.0)
    ok = (hi - lo >= 2) & (w >= 0.0) & (w <= 1.0) & ((t1 - t0 <= max_gap_s) | on_sample)
    return j, np.clip(w, 0.0, 1.0), ok


def adsb_track_table(adsb: pd.DataFrame) -> AdsbTrackTable:
    """The ADS-B table as an :class:`AdsbTrackTable`."""
    target = adsb["target_id"]
    valid = (target.notna() & (target.astype(str) != "")).to_numpy(dtype=bool)
    valid = valid & np.isfinite(adsb["alt_m"].to_numpy(float))  # no geometric height: not used
    codes, names = pd.factorize(target[valid].astype(str), sort=True)
    time_s = adsb["time_s"].to_numpy(float)[valid]
    # As tracks_by_target: per aircraft in time order (stable), repeated times dropped.
    order = group_order(codes, time_s)
    codes, time_s = codes[order], time_s[order]
    keep = np.ones(len(order), dtype=bool)
    keep[1:] = (codes[1:] != codes[:-1]) | (np.diff(time_s) > 0)
    rows = np.flatnonzero(valid)[order[keep]]
    codes, time_s = codes[keep].astype(np.int64), time_s[keep]
    ecef = frames.geodetic_to_ecef(
        np.deg2rad(adsb["lat_deg"].to_numpy(float)[rows]),
        np.deg2rad(adsb["lon_deg"].to_numpy(float)[rows]),
        adsb["alt_m"].to_numpy(float)[rows],
    )
    start = np.searchsorted(codes, np.arange(len(names) + 1)).astype(np.int64)
    return AdsbTrackTable(pd.Index(names, dtype=object), start, time_s, ecef,
                          adsb["sigma_m"].to_numpy(float)[rows], codes + 1j * time_s)


def align_adsb(
    dataset: Dataset,
    radar_id: str,
    max_gap_s: float = DEFAULT_ADSB_MAX_GAP_S,
    time_offset_s: float = 0.0,
    *,
    plots: PlotArrays | None = None,
    tracks: AdsbTrackTable | None = None,
) -> AdsbAlignment:
    """Associate one radar's plots with ADS-B and interpolate ADS-B to the plot times.

    Parameters
    ----------
    dataset : Dataset
        Must have an ADS-B table.
    radar_id : str
        The radar.
    max_gap_s : float
        Longest gap between two ADS-B reports that is bridged [s].
    time_offset_s : float
        The radar's time-stamping bias [s]: ADS-B is interpolated at the true plot
        times ``time_s - time_offset_s``.

    plots, tracks : optional
        The radar's :func:`plot_arrays` and the :func:`adsb_track_table`, when the
        caller keeps them (:class:`graphcal.model.problem.Problem` does, and keeps
        each radar's alignment at zero time offset).

    Returns
    -------
    AdsbAlignment
    """
    if dataset.adsb is None:
        raise ValueError("the dataset has no ADS-B table")
    plots = plot_arrays(dataset, radar_id) if plots is None else plots
    tracks = adsb_track_table(dataset.adsb) if tracks is None else tracks
    return _align_adsb(dataset, radar_id, max_gap_s, time_offset_s, plots, tracks)


def align_adsb_thinned(
    full: AdsbAlignment,
    dataset: Dataset,
    keep: NDArray[np.bool_],
    radar_plots: PlotArrays,
) -> AdsbAlignment:
    """The zero-offset alignment of ``dataset`` thinned to the plot rows ``keep``, cut out
    of ``full``, ``dataset``'s alignment of the same radar.

    The thinned dataset is ``dataset`` with the plot rows ``keep`` only (renumbered from
    0, the same ADS-B table and sites).  A plot's alignment depends only on its own
    time and aircraft and on the ADS-B, so the thinned alignment is the full one's
    rows of the kept plots: this gives the same arrays as :func:`align_adsb` on the
    thinned dataset, without bracketing and converting the plots again.
    ``radar_plots``: the radar's :func:`plot_arrays` in ``dataset``.
    """
    if full.time_offset_s != 0.0:
        raise ValueError("a thinned alignment is cut from one at zero time offset")
    new_row = np.cumsum(keep) - 1  # a kept row's number in the thinned table
    labels = dataset.plots.index

    def position(index: NDArray[np.int64]) -> NDArray[np.int64]:
        """Row positions in ``dataset.plots`` of the row labels ``index``."""
        if isinstance(labels, pd.RangeIndex) and labels.start == 0 and labels.step == 1:
            return index
        return labels.get_indexer(index)

    rows = position(full.plots.index)
    mine = keep[rows]
    plots = full.plots.subset(mine)
    plots.index = new_row[rows[mine]]
    optional = {
        name: None if (value := getattr(full, name)) is None else take_rows(value, mine)
        for name in ("reference_velocity_ecef_m_s", "reference_polar_jacobian",
                     "target_code")
    }
    n_radar_plots = int(np.count_nonzero(keep[position(radar_plots.index)]))
    return AdsbAlignment(
        full.radar_id, plots, take_rows(full.reference_ecef_m, mine),
        take_rows(full.reference_polar, mine), take_rows(full.reference_enu_cov_m2, mine),
        n_radar_plots - len(plots), time_offset_s=0.0, **optional,
    )


def _align_adsb(
    dataset: Dataset, radar_id: str, max_gap_s: float, time_offset_s: float,
    plots: PlotArrays, tracks: AdsbTrackTable,
) -> AdsbAlignment:
    site = dataset.sites[radar_id]
    n = len(plots)
    code = tracks.codes(plots.target_id)
    j, w, matched = tracks.bracket(code, plots.time_s - time_offset_s, max_gap_s)
    j, w = j[matched], w[matched]
    lo, hi = tracks.start[code[matched]], tracks.start[code[matched] + 1]
    t, ecef, sigma = tracks.time_s, tracks.ecef_m, tracks.sigma_m
    ref = (1.0 - w)[:, None] * take_rows(ecef, j) + w[:, None] * take_rows(ecef, j + 1)
    # Velocity from the reports around the bracketing pair, not from the pair itself:
    # the pair's noise is in the interpolated position, and a velocity sharing it
    # would correlate the time-offset Jacobian with the residual.
    before = np.clip(j - 1, lo, hi - 1)
    after = np.clip(j + 2, lo, hi - 1)
    outer = (after - before >= 3) & (t[after] - t[before] <= 3.0 * max_gap_s)
    before = np.where(outer, before, j)
    after = np.where(outer, after, j + 1)
    vel = (take_rows(ecef, after) - take_rows(ecef, before)) / (t[after] - t[before])[:, None]
    # Independent reports: the interpolated variance is w0^2 s0^2 + w1^2 s1^2.
    var_h = (1.0 - w) ** 2 * sigma[j] ** 2 + w**2 * sigma[j + 1] ** 2
    plots = plots.subset(matched)
    cov = np.zeros((len(plots), 3, 3))
    cov[:, 0, 0] = var_h
    cov[:, 1, 1] = var_h
    cov[:, 2, 2] = ADSB_VERTICAL_SIGMA_RATIO**2 * var_h
    jacobian = None
    if not len(plots):
        polar = np.zeros((0, 3))
    elif site.atmosphere is not None:  # contract v2: electrical length, apparent elevation
        polar, jacobian = refracted_polar_jacobian(site.atmosphere, site.lat_rad, site.alt_m,
                                                   site.enu_from_ecef(ref))
    else:
        polar = np.stack(site.polar_from_ecef(ref), axis=-1)
    return AdsbAlignment(radar_id, plots, ref, polar, cov, int(n - matched.sum()), vel,
                         float(time_offset_s), jacobian, code[matched])


@dataclass
class PlotPairs:
    """Plots of radar ``b`` paired with radar ``a``'s track interpolated to their times.

    For pair ``k`` the radar-``a`` position is
    ``(1 - weight[k]) * a[a_index0[k]] + weight[k] * a[a_index0[k] + 1]`` in
    terms of positions in :attr:`a_plots` (linear interpolation).

    :attr:`a_index2` and :attr:`quadratic_weights` give the quadratic
    interpolation through a third plot of the same track: ``sum_j
    quadratic_weights[k, j] * a[(a_index0[k], a_index0[k] + 1, a_index2[k])[j]]``.
    A straight chord between two plots cuts inside a turn, by ``a w (1 - w) dt^2 / 2``
    (``a`` the aircraft's acceleration, ``dt`` the scan): 16 m at 2 m/s² and 8 s,
    a systematic error that linear interpolation leaves in every pair of a turning
    aircraft.  The third plot (the track's next plot on the side nearer ``b``'s
    time, within the gap limit) takes it out to second order; where the track has
    none, ``a_index2`` is ``-1`` and the weights are the linear ones.
    """

    radar_a: str
    radar_b: str
    a_plots: PlotArrays
    b_plots: PlotArrays
    a_index0: NDArray[np.int64]
    weight: FloatArray
    b_index: NDArray[np.int64]
    a_index2: NDArray[np.int64] | None = None
    quadratic_weights: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.b_index)


def pairing_order(dataset: Dataset, radar_ids: list[str] | None = None) -> list[str]:
    """The radars in the order that orients every pair, whatever their order in the file.

    In a pair ``(a, b)`` radar ``a``'s track is interpolated to ``b``'s plot times, so
    ``a`` is the radar with the shorter scan period (its track is the denser, its
    interpolation the more accurate); radars without a known period come last, and
    ties go by radar id.  The pairs, and every answer built on them, are then the same
    for any order of the ``[[radar]]`` tables.
    """
    ids = list(dataset.radar_ids if radar_ids is None else radar_ids)

    def key(rid: str) -> tuple[float, str]:
        period = dataset.sites[rid].scan_period_s if rid in dataset.sites else None
        return (float(period) if period else float("inf"), rid)

    return sorted(ids, key=key)


def overlapping_pairs(dataset: Dataset, radar_ids: list[str] | None = None
                      ) -> list[tuple[str, str]]:
    """The radar pairs ``(a, b)``, ``a`` before ``b`` in :func:`pairing_order`, that saw
    a common aircraft (a non-empty ``target_id`` in both radars' plots).

    Only these can give :func:`pair_plots` anything: a network of many radars, most
    of them far apart (or without plots), is paired in the time its overlaps take,
    not in the square of its size.

    Parameters
    ----------
    dataset : Dataset
        The plots.
    radar_ids : list of str, optional
        The radars to pair (default ``dataset.radar_ids``); their order does not matter.
    """
    order = pairing_order(dataset, radar_ids)
    rank = {rid: i for i, rid in enumerate(order)}
    plots = dataset.plots
    target = plots["target_id"].astype(str).to_numpy()
    radar = plots["radar_id"].astype(str).to_numpy()
    keep = (target != "") & pd.Series(radar).isin(rank).to_numpy()
    if not keep.any():
        return []
    seen = pd.DataFrame({"t": target[keep], "r": radar[keep]}).drop_duplicates()
    found: set[tuple[int, int]] = set()
    for radars in seen.groupby("t", sort=False)["r"]:
        ranks = sorted(rank[rid] for rid in radars[1])
        found.update((a, b) for i, a in enumerate(ranks) for b in ranks[i + 1:])
    return [(order[a], order[b]) for a, b in sorted(found)]


def pair_max_gap_s(site: Site) -> float:
    """Gap limit [s] for interpolating ``site``'s plots: 2.5 scans, or 15 s if unknown."""
    if site.scan_period_s:
        return DEFAULT_PAIR_MAX_GAP_SCANS * site.scan_period_s
    return DEFAULT_PAIR_MAX_GAP_S


def pair_plots(
    dataset: Dataset,
    radar_a: str,
    radar_b: str,
    max_gap_s: float | None = None,
    shift_s: float = 0.0,
    plots: Mapping[str, PlotArrays] | None = None,
) -> PlotPairs:
    """Match radar ``b``'s plots to radar ``a``'s plots of the same target and time.

    Plots with an empty ``target_id`` are not paired.  Positions within a
    track of radar ``a`` are ordered by time; ``a_index0`` indexes that order.
    ``shift_s`` is added to ``b``'s times before they are looked up in ``a``'s
    track: with time-stamping biases it is ``time_offset_a - time_offset_b``,
    so that both plots of a pair refer to the same true time.  ``plots``: the radars'
    :func:`plot_arrays`, when the caller keeps them.
    """
    if max_gap_s is None:
        max_gap_s = pair_max_gap_s(dataset.sites[radar_a])
    a = plots[radar_a] if plots is not None else plot_arrays(dataset, radar_a)
    b = plots[radar_b] if plots is not None else plot_arrays(dataset, radar_b)
    # Sort a by (target, time) so that each target's plots are contiguous.
    a_targets = a.target_id.astype(str)
    # By aircraft (codes in sorted order, the order of the text) then time.
    order = np.lexsort((a.time_s, pd.factorize(a_targets, sort=True)[0]))
    a = a.subset(order)
    a_targets = a_targets[order]
    # a's tracks: block k holds target names[k], rows start[k]:end[k].
    boundaries = np.flatnonzero(a_targets[1:] != a_targets[:-1]) + 1
    start = np.r_[0, boundaries].astype(np.int64) if len(a) else np.zeros(0, np.int64)
    end = np.r_[boundaries, len(a)].astype(np.int64) if len(a) else np.zeros(0, np.int64)
    block = np.repeat(np.arange(len(start)), end - start)
    b_targets = b.target_id.astype(str)
    code = pd.Index(a_targets[start], dtype=object).get_indexer(b_targets).astype(np.int64)
    rows_b = np.flatnonzero((code >= 0) & (b_targets != ""))
    code = code[rows_b]
    lo, hi = start[code], end[code]
    query = b.time_s[rows_b] + shift_s
    j, w, ok = bracket_in_blocks(a.time_s, block + 1j * a.time_s, code, lo, hi, query,
                                 max_gap_s)
    ia, ww, ib = j[ok], w[ok], rows_b[ok]
    i2, q = quadratic_third_in_blocks(a.time_s, query[ok], ia, ww, lo[ok], hi[ok], max_gap_s)
    # In time order; ties as in one pass over b's targets by first appearance.
    rank = pd.factorize(b_targets)[0]
    order_b = np.lexsort((ib, rank[ib], b.time_s[ib]))
    return PlotPairs(radar_a, radar_b, a, b, ia[order_b], ww[order_b], ib[order_b],
                     i2[order_b], q[order_b])


def quadratic_third(
    track_time_s: FloatArray, query_time_s: FloatArray, j: NDArray[np.int64], w: FloatArray,
    max_gap_s: float,
) -> tuple[NDArray[np.int64], FloatArray]:
    """The third plot and the quadratic (Lagrange) weights of :class:`PlotPairs`.

    For a query between samples ``j`` and ``j + 1`` (:func:`bracket`), the third
    sample is ``j - 1`` or ``j + 2``, whichever is nearer the query in time, when
    it exists and lies within ``max_gap_s`` of its neighbour.  The weights of
    ``(j, j + 1, third)`` at time ``t`` are the Lagrange basis polynomials
    ``L_i(t) = prod_{m != i} (t - t_m) / (t_i - t_m)``; without a third sample
    they are ``(1 - w, w, 0)``.

    Returns
    -------
    third : ndarray (m,) of int
        Index of the third sample in ``track_time_s``, ``-1`` where there is none.
    weights : ndarray (m, 3)
        Weights of samples ``j``, ``j + 1`` and ``third``; they sum to 1.
    """
    n = len(track_time_s)
    if n < 3 or len(j) == 0:
        linear = np.stack([1.0 - w, w, np.zeros_like(w)], axis=1)
        return np.full(len(j), -1, dtype=np.int64), linear
    zero = np.zeros(len(j), dtype=np.int64)
    return quadratic_third_in_blocks(track_time_s, query_time_s, j, w, zero, zero + n,
                                     max_gap_s)


def quadratic_third_in_blocks(
    time_s: FloatArray, query_time_s: FloatArray, j: NDArray[np.int64], w: FloatArray,
    lo: NDArray[np.int64], hi: NDArray[np.int64], max_gap_s: float,
) -> tuple[NDArray[np.int64], FloatArray]:
    """:func:`quadratic_third` of each query within its own block ``lo[i]:hi[i]``.

    ``j`` are global rows (as :func:`bracket_in_blocks` returns them); so is the third.
    """
    linear = np.stack([1.0 - w, w, np.zeros_like(w)], axis=1)
    if len(j) == 0:
        return np.full(0, -1, dtype=np.int64), linear
    t0, t1 = time_s[j], time_s[np.minimum(j + 1, hi - 1)]
    before = j - 1
    after = j + 2
    ok_before = before >= lo
    ok_after = after < hi
    t_before = time_s[np.maximum(before, lo)]
    t_after = time_s[np.minimum(after, hi - 1)]
    ok_before &= (t0 - t_before) <= max_gap_s
    ok_after &= (t_after - t1) <= max_gap_s
    use_after = ok_after & (~ok_before | (t_after - query_time_s < query_time_s - t_before))
    third = np.where(use_after, after, np.where(ok_before, before, -1))
    has = third >= 0
    t2 = time_s[np.clip(third, lo, hi - 1)]
    t = query_time_s
    with np.errstate(invalid="ignore", divide="ignore"):
        l0 = (t - t1) * (t - t2) / ((t0 - t1) * (t0 - t2))
        l1 = (t - t0) * (t - t2) / ((t1 - t0) * (t1 - t2))
        l2 = (t - t0) * (t - t1) / ((t2 - t0) * (t2 - t1))
    weights = np.stack([l0, l1, l2], axis=1)
    good = has & np.all(np.isfinite(weights), axis=1) & (t1 > t0)
    return (np.where(good, third, -1).astype(np.int64),
            np.where(good[:, None], weights, linear))
