"""Track-to-track fusion of several radars' tracks (paper 002, section 3.3.3).

Each radar's plots of one aircraft are converted to ECEF with their converted
noise covariance (paper 002 eq. 19, :func:`graphcal.model.cross_radar.convert_plots`)
and filtered by the constant-velocity Kalman filter of :mod:`graphcal.tracking.kalman`;
the tracks are brought to a common time grid by prediction and fused there:

* covariance-weighted (information form, the paper's "converted covariance
  weighting")::

      P_f = (sum_i P_i^-1)^-1,    x_f = P_f sum_i P_i^-1 x_i

  This is the best linear fusion of *independent* estimates.  Tracks of the same
  aircraft share the process noise (the aircraft's true manoeuvres), so their
  errors are correlated (Bar-Shalom-Campo cross-covariance); the information
  form ignores that and its ``P_f`` is somewhat optimistic.  With small process
  noise the correlation is small.
* equal weights (the paper's "initial measurement accuracy" weighting, all
  radars alike): ``x_f = mean_i x_i``, with ``P_f = sum_i P_i / k^2`` the
  covariance of that mean for independent errors, for comparison.

:func:`fuse_dataset` runs this over a whole dataset, raw or corrected by a
calibration's biases, and scores every radar track and the fused tracks
against ADS-B (or a truth table); :func:`compare_fusion` runs it before and
after calibration.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from graphcal.core import frames
from graphcal.data.align import (
    DEFAULT_ADSB_MAX_GAP_S,
    adsb_tracks,
    bracket,
    plot_arrays,
    tracks_by_target,
)
from graphcal.data.bias import RadarBias
from graphcal.data.calibration import Calibration, read_biases, read_height_model
from graphcal.data.dataset import Dataset
from graphcal.model.cross_radar import convert_plots, corrected_ecef
from graphcal.tracking.kalman import kalman_filter, pad_tracks, predict_rows

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
ProgressCallback = Callable[[str, int, int], None]
#: A reference: ``f(target_id, time_s (m,)) -> ECEF (m, 3)`` [m], NaN where unknown.
ReferenceFunction = Callable[[str, FloatArray], FloatArray]

#: Default acceleration noise spectral density [m^2/s^3] of the dataset tracker: civil
#: traffic turns and changes level (accelerations of a few m/s^2 over tens of seconds,
#: ``q ~ a^2 T``); on the demo network (4-10 s scans) the fused RMSE is lowest for q
#: between about 30 and 300.  Use ~1 for straight constant-velocity flight (paper 002).
DEFAULT_Q_M2_S3 = 100.0
#: Default gap, in scan periods, above which a radar's track of an aircraft is restarted.
DEFAULT_TRACK_GAP_SCANS = 3.5
#: Track restart gap [s] for a radar without a scan period.
DEFAULT_TRACK_GAP_S = 30.0
#: Row labels of the fused results in :attr:`FusionResult.summary`.
FUSED_COV = "fused_cov"
FUSED_EQUAL = "fused_equal"


# --------------------------------------------------------------------------- fusion rules


def _check_sources(
    x: ArrayLike, p: ArrayLike, present: ArrayLike | None
) -> tuple[FloatArray, FloatArray, BoolArray]:
    xa = np.asarray(x, dtype=float)
    pa = np.asarray(p, dtype=float)
    if xa.ndim < 2 or pa.shape != xa.shape + (xa.shape[-1],):
        raise ValueError(
            f"x must be (k, ..., d) and p (k, ..., d, d); got {xa.shape} and {pa.shape}"
        )
    if present is None:
        mask = np.all(np.isfinite(xa), axis=-1) & np.all(np.isfinite(pa), axis=(-1, -2))
    else:
        mask = np.asarray(present, dtype=bool)
        if mask.shape != xa.shape[:-1]:
            raise ValueError(f"present must have shape {xa.shape[:-1]}, got {mask.shape}")
    return xa, pa, mask


def fuse_covariance_weighted(
    x: ArrayLike, p: ArrayLike, present: ArrayLike | None = None
) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """Covariance-weighted (information-form) fusion of ``k`` estimates.

    ``P_f = (sum_i P_i^-1)^-1``, ``x_f = P_f sum_i P_i^-1 x_i`` over the present
    sources: the BLUE of a common state from independent unbiased estimates.
    Cross-covariances (common process noise of tracks of one aircraft) are
    ignored.

    Parameters
    ----------
    x : array_like (k, ..., d)
        Estimates; sources along the first axis.
    p : array_like (k, ..., d, d)
        Their covariances (positive definite where present).
    present : array_like (k, ...) of bool, optional
        Which sources exist; default: those with finite ``x`` and ``p``.

    Returns
    -------
    x_f : ndarray (..., d)
    p_f : ndarray (..., d, d)
    n : ndarray (...) of int
        Number of sources fused; NaN estimates where it is 0.
    """
    xa, pa, mask = _check_sources(x, p, present)
    d = xa.shape[-1]
    eye = np.eye(d)
    safe_p = np.where(mask[..., None, None], pa, eye)
    info = np.linalg.inv(safe_p) * mask[..., None, None]
    info_x = np.einsum("k...ij,k...j->k...i", info, np.where(mask[..., None], xa, 0.0))
    n = mask.sum(axis=0)
    info_sum = info.sum(axis=0)
    some = n > 0
    p_f = np.linalg.inv(np.where(some[..., None, None], info_sum, eye))
    x_f = np.einsum("...ij,...j->...i", p_f, info_x.sum(axis=0))
    x_f[~some] = np.nan
    p_f[~some] = np.nan
    return x_f, p_f, n


def fuse_equal_weights(
    x: ArrayLike, p: ArrayLike, present: ArrayLike | None = None
) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """Equal-weight fusion: the mean of the present estimates.

    ``x_f = (1/k) sum_i x_i`` and, for comparison, ``P_f = (1/k^2) sum_i P_i``:
    the covariance of the mean if the errors are independent.  This is the
    paper's weighting by the radars' (identical) polar accuracies.

    Parameters and returns as :func:`fuse_covariance_weighted`.
    """
    xa, pa, mask = _check_sources(x, p, present)
    n = mask.sum(axis=0)
    some = n > 0
    k = np.where(some, n, 1).astype(float)
    x_f = np.where(mask[..., None], xa, 0.0).sum(axis=0) / k[..., None]
    p_f = np.where(mask[..., None, None], pa, 0.0).sum(axis=0) / (k**2)[..., None, None]
    x_f[~some] = np.nan
    p_f[~some] = np.nan
    return x_f, p_f, n


# --------------------------------------------------------------------------- calibration input


CalibrationLike = Calibration | Mapping[str, RadarBias] | str | Path


def height_model_of(calibration: CalibrationLike | None, dataset: Dataset
                  ) -> tuple[float, float] | None:
    """``(height_offset_m, height_scale)`` to place 2-D plots whose altitudes are pressure
    altitudes (contract v2), from the calibration's ``atmosphere`` block; ``None`` when
    the dataset's altitudes are geometric or the calibration has no height model."""
    if not dataset.pressure_altitudes or calibration is None:
        return None
    return read_height_model(calibration)


def _biases(calibration: CalibrationLike | None, radar_ids: list[str]) -> dict[str, RadarBias]:
    """Biases per radar of the dataset (radars the calibration lacks are not corrected)."""
    if calibration is None:
        return {}
    if isinstance(calibration, str | Path):
        return {rid: b for rid, b in read_biases(calibration).items() if rid in radar_ids}
    if isinstance(calibration, Calibration):
        return {rid: calibration.bias(rid) for rid in radar_ids if rid in calibration.radar_ids}
    if isinstance(calibration, Mapping):
        out = {}
        for rid, bias in calibration.items():
            if not isinstance(bias, RadarBias):
                raise ValueError(f"calibration entry for radar {rid!r} is not a RadarBias")
            if rid in radar_ids:
                out[rid] = bias
        return out
    raise ValueError(
        "calibration must be a Calibration, a mapping of radar id to RadarBias, or a path "
        f"to a result JSON; got {type(calibration).__name__}"
    )


# --------------------------------------------------------------------------- reference


def _adsb_reference(dataset: Dataset, max_gap_s: float) -> ReferenceFunction:
    """ADS-B positions interpolated linearly in ECEF (gaps above ``max_gap_s`` not bridged)."""
    if dataset.adsb is None or dataset.adsb.empty:
        return lambda target, t: np.full((len(t), 3), np.nan)
    tracks = {k: (t, pos) for k, (t, pos, _) in adsb_tracks(dataset.adsb).items()}
    return _interpolating_reference(tracks, max_gap_s)


def _table_reference(table: pd.DataFrame, max_gap_s: float) -> ReferenceFunction:
    missing = {"time_s", "target_id", "x_m", "y_m", "z_m"} - set(table.columns)
    if missing:
        raise ValueError(f"reference table lacks columns {sorted(missing)}")
    tracks = tracks_by_target(table["time_s"].to_numpy(float), table["target_id"],
                              table[["x_m", "y_m", "z_m"]].to_numpy(float), skip_empty=False)
    return _interpolating_reference(tracks, max_gap_s)


def _interpolating_reference(
    tracks: Mapping[str, tuple[FloatArray, ...]], max_gap_s: float
) -> ReferenceFunction:
    """``f(target, t)``: each track's ECEF positions interpolated linearly, NaN where unknown."""

    def reference(target: str, t: FloatArray) -> FloatArray:
        out = np.full((len(t), 3), np.nan)
        if target not in tracks:
            return out
        tt, pos = tracks[target]
        j, w, ok = bracket(tt, t, max_gap_s)
        out[ok] = (1.0 - w[ok])[:, None] * pos[j[ok]] + w[ok][:, None] * pos[j[ok] + 1]
        return out

    return reference


# --------------------------------------------------------------------------- dataset pipeline


@dataclass
class FusionResult:
    """Fused tracks of a dataset and their accuracy against the reference.

    Attributes
    ----------
    tracks : pandas.DataFrame
        Covariance-weighted fused tracks on the grid: ``time_s``, ``target_id``,
        ECEF ``x_m, y_m, z_m``, ``lat_deg, lon_deg, alt_m``, ``sigma_m``
        (``sqrt(trace(P_pos) / 3)``, the fused 1-sigma per axis [m]),
        ``sigma_equal_m`` (the same for the equal-weight mean), ``n_radars``, and
        the equal-weight position ``x_equal_m, y_equal_m, z_equal_m``.
    radar_tracks : pandas.DataFrame
        Every radar's filtered track on the grid: ``time_s``, ``target_id``,
        ``radar_id``, ``x_m, y_m, z_m``, ``sigma_m``.
    summary : pandas.DataFrame
        Index: radar ids, :data:`FUSED_COV`, :data:`FUSED_EQUAL`; columns
        ``rmse_m`` (3-D position RMSE against the reference [m]), ``n_points``
        (grid points with a reference), ``n_targets``.
    counts : dict
        ``targets`` (seen by >= 1 radar and tracked), ``targets_with_reference``,
        ``targets_without_reference``, ``grid_points``, ``grid_points_multi``
        (fused from >= 2 radars), ``segments`` (radar tracks),
        ``plots_used``, ``plots_unusable`` (no target id, unusable geometry or
        in a track too short to start).
    calibrated_radars : list of str
        Radars whose plots were corrected.
    settings : dict
        ``q_m2_s3``, ``grid_s``, ``reference``.
    timing_s : dict
        Seconds per stage.
    """

    tracks: pd.DataFrame
    radar_tracks: pd.DataFrame
    summary: pd.DataFrame
    counts: dict[str, int]
    calibrated_radars: list[str] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    timing_s: dict[str, float] = field(default_factory=dict)


@dataclass
class _RadarTracks:
    """Concatenated filtered tracks of one radar on the grid."""

    radar_id: str
    target: NDArray[np.object_]
    grid_index: NDArray[np.int64]
    x: FloatArray  # (m, 6)
    p: FloatArray  # (m, 6, 6)


def _segments(
    target: NDArray[np.object_], time_s: FloatArray, max_gap_s: float
) -> list[NDArray[np.int64]]:
    """Indices of each (target, continuous stretch) in time order; duplicate times dropped."""
    out = []
    order = np.lexsort((time_s, target.astype(str)))
    tgt = target[order].astype(str)
    t = time_s[order]
    breaks = np.flatnonzero(tgt[1:] != tgt[:-1]) + 1
    for chunk in np.split(np.arange(len(order)), breaks):
        if len(chunk) == 0:
            continue
        tc = t[chunk]
        keep = np.concatenate([[True], np.diff(tc) > 0])
        chunk, tc = chunk[keep], tc[keep]
        cuts = np.flatnonzero(np.diff(tc) > max_gap_s) + 1
        out.extend(order[piece] for piece in np.split(chunk, cuts) if len(piece) >= 2)
    return out


def _radar_tracks(
    dataset: Dataset,
    radar_id: str,
    bias: RadarBias | None,
    *,
    q_m2_s3: float,
    grid_s: float,
    max_gap_s: float | None,
    height_model: tuple[float, float] | None = None,
) -> tuple[_RadarTracks | None, dict[str, int]]:
    site = dataset.sites[radar_id]
    plots = plot_arrays(dataset, radar_id)
    converted = convert_plots(site, plots)
    if bias is None:
        ecef, usable, time_s = converted.ecef_m, converted.usable, plots.time_s
    else:
        eccentricity = None
        if bias.azimuth_sin_rad or bias.azimuth_cos_rad:
            eccentricity = (bias.azimuth_sin_rad, bias.azimuth_cos_rad)
        ecef, _, usable = corrected_ecef(site, plots, bias.as_vector(), eccentricity,
                                         None if site.is_3d else height_model)
        time_s = plots.time_s - bias.time_offset_s
    has_target = np.array([bool(t) for t in plots.target_id], dtype=bool)
    keep = usable & has_target & np.all(np.isfinite(ecef), axis=1)
    gap = max_gap_s
    if gap is None:
        gap = DEFAULT_TRACK_GAP_SCANS * site.scan_period_s if site.scan_period_s else (
            DEFAULT_TRACK_GAP_S
        )
    idx = np.flatnonzero(keep)
    segments = [idx[s] for s in _segments(plots.target_id[idx], time_s[idx], gap)]
    n_used = int(sum(len(s) for s in segments))
    counts = {"segments": len(segments), "plots_used": n_used,
              "plots_unusable": int(len(plots) - n_used)}
    if not segments:
        return None, counts
    t_pad, mask = pad_tracks([time_s[s] for s in segments])
    z_pad, _ = pad_tracks([ecef[s] for s in segments])
    eye = np.eye(3)
    r_pad, _ = pad_tracks([converted.cov_m2[s] for s in segments])
    r_pad[~mask] = eye  # padding: any positive-definite matrix, never used
    est = kalman_filter(t_pad, z_pad, r_pad, q_m2_s3=q_m2_s3, init="two-point", mask=mask)
    # Grid points of each segment: from its first estimate to its last plot.
    rows, grid = [], []
    for b, seg in enumerate(segments):
        t_first, t_last = time_s[seg[1]], time_s[seg[-1]]
        g = np.arange(np.ceil(t_first / grid_s), np.floor(t_last / grid_s) + 1, dtype=np.int64)
        rows.append(np.full(len(g), b, dtype=np.int64))
        grid.append(g)
    row = np.concatenate(rows)
    grid_index = np.concatenate(grid)
    x, p, ok = predict_rows(est, row, grid_index * grid_s)
    target = np.array([plots.target_id[s[0]] for s in segments], dtype=object)[row]
    return _RadarTracks(radar_id, target[ok], grid_index[ok], x[ok], p[ok]), counts


def _group_sum(values: FloatArray, starts: NDArray[np.int64]) -> FloatArray:
    """Sums of consecutive row groups beginning at ``starts`` (rows flattened for speed)."""
    flat = np.ascontiguousarray(values).reshape(len(values), -1)
    return np.add.reduceat(flat, starts, axis=0).reshape((len(starts),) + values.shape[1:])


def _sigma_per_axis(p: FloatArray) -> FloatArray:
    return np.sqrt(np.trace(p[..., :3, :3], axis1=-2, axis2=-1) / 3.0)


def _rmse(err: FloatArray) -> float:
    sq = np.sum(err**2, axis=-1)
    sq = sq[np.isfinite(sq)]
    return float(np.sqrt(np.mean(sq))) if len(sq) else float("nan")


def fuse_dataset(
    dataset: Dataset,
    calibration: CalibrationLike | None = None,
    *,
    q_m2_s3: float = DEFAULT_Q_M2_S3,
    grid_s: float = 1.0,
    max_gap_s: float | None = None,
    reference: str | pd.DataFrame | ReferenceFunction = "adsb",
    reference_max_gap_s: float = DEFAULT_ADSB_MAX_GAP_S,
    progress: ProgressCallback | None = None,
) -> FusionResult:
    """Track every aircraft with every radar, fuse the tracks on a time grid, score them.

    Per radar: plots with a ``target_id`` are converted to ECEF (raw, or
    corrected by the calibration's biases with
    :func:`graphcal.model.cross_radar.corrected_ecef` and the time offset
    removed; an azimuth eccentricity is removed too, and with pressure altitudes
    a 2-D plot is placed at the height the calibration's height model gives),
    each with its converted noise covariance ``J R_polar J^T`` from the site's
    sigmas (paper 002 eq. 19; calibration does not change the sigmas).
    Each aircraft's plots are split into tracks at gaps over ``max_gap_s`` and
    run through the CV Kalman filter (two-point start, per-plot converted ``R``).
    Each track is predicted to the grid times ``k * grid_s`` within its span
    (first estimate to last plot); at each (aircraft, grid time) the radars'
    states are fused covariance-weighted and with equal weights
    (:func:`fuse_covariance_weighted`, :func:`fuse_equal_weights`).  RMSE is the
    3-D position error against the reference at the grid times.

    Parameters
    ----------
    dataset : Dataset
    calibration : Calibration, mapping radar id -> RadarBias, or path, optional
        Biases to remove first (a path is read with :func:`read_biases`, which also
        takes a simulation's ``truth.json``).  Radars it does not cover stay raw.
    q_m2_s3 : float
        Acceleration noise spectral density of the tracker [m^2/s^3].
    grid_s : float
        Fusion interval [s] (paper 002: 1 s).
    max_gap_s : float, optional
        Gap [s] between two plots of an aircraft that restarts the radar's track;
        default :data:`DEFAULT_TRACK_GAP_SCANS` scan periods (or
        :data:`DEFAULT_TRACK_GAP_S`).
    reference : "adsb", DataFrame or callable
        ``"adsb"``: the dataset's ADS-B interpolated to the grid; a DataFrame with
        ``time_s, target_id, x_m, y_m, z_m`` (ECEF truth) interpolated likewise; or
        ``f(target_id, time_s) -> (m, 3)`` ECEF with NaN where unknown.  Aircraft
        without a reference get no RMSE (counted).
    reference_max_gap_s : float
        Longest gap of the reference samples that is interpolated over [s].
    progress : callable, optional
        ``progress(stage, done, total)`` after each radar and after fusion.

    Returns
    -------
    FusionResult

    Raises
    ------
    ValueError
        On a bad ``grid_s``, ``q_m2_s3``, ``max_gap_s``, reference or calibration.
    """
    if not grid_s > 0:
        raise ValueError(f"grid_s must be positive, got {grid_s}")
    if not q_m2_s3 >= 0:
        raise ValueError(f"q_m2_s3 must be >= 0, got {q_m2_s3}")
    if max_gap_s is not None and not max_gap_s > 0:
        raise ValueError(f"max_gap_s must be positive, got {max_gap_s}")
    if isinstance(reference, str):
        if reference != "adsb":
            raise ValueError(f"reference must be 'adsb', a table or a function, got {reference!r}")
        ref_fn = _adsb_reference(dataset, reference_max_gap_s)
        ref_name = "adsb"
    elif isinstance(reference, pd.DataFrame):
        ref_fn = _table_reference(reference, reference_max_gap_s)
        ref_name = "table"
    elif callable(reference):
        ref_fn = reference
        ref_name = "function"
    else:
        raise ValueError("reference must be 'adsb', a DataFrame or a callable")
    radar_ids = dataset.radar_ids
    biases = _biases(calibration, radar_ids)
    height_model = height_model_of(calibration, dataset)
    total = len(radar_ids) + 1
    timing: dict[str, float] = {}
    counts = {"segments": 0, "plots_used": 0, "plots_unusable": 0}
    per_radar: list[_RadarTracks] = []
    t0 = time.perf_counter()
    for i, rid in enumerate(radar_ids):
        tracks, c = _radar_tracks(
            dataset, rid, biases.get(rid), q_m2_s3=q_m2_s3, grid_s=grid_s, max_gap_s=max_gap_s,
            height_model=height_model,
        )
        for key in counts:
            counts[key] += c[key]
        if tracks is not None and len(tracks.grid_index):
            per_radar.append(tracks)
        if progress is not None:
            progress(f"radar {rid}: {c['segments']} tracks", i + 1, total)
    timing["tracking"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    fused_df, radar_df, summary, fuse_counts = _fuse_and_score(
        per_radar, radar_ids, ref_fn, grid_s
    )
    counts.update(fuse_counts)
    timing["fusion"] = time.perf_counter() - t1
    if progress is not None:
        progress(f"fused {len(fused_df)} grid points", total, total)
    return FusionResult(
        tracks=fused_df,
        radar_tracks=radar_df,
        summary=summary,
        counts=counts,
        calibrated_radars=sorted(biases),
        settings={"q_m2_s3": q_m2_s3, "grid_s": grid_s, "reference": ref_name,
                  "max_gap_s": max_gap_s},
        timing_s=timing,
    )


def _fuse_and_score(
    per_radar: list[_RadarTracks],
    radar_ids: list[str],
    ref_fn: ReferenceFunction,
    grid_s: float,
) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame, dict[str, int]]:
    empty_summary = pd.DataFrame(
        {"rmse_m": np.nan, "n_points": 0, "n_targets": 0},
        index=pd.Index([*radar_ids, FUSED_COV, FUSED_EQUAL], name="track"),
    )
    if not per_radar:
        cols = ["time_s", "target_id", "x_m", "y_m", "z_m", "lat_deg", "lon_deg", "alt_m",
                "sigma_m", "sigma_equal_m", "n_radars", "x_equal_m", "y_equal_m", "z_equal_m"]
        counts = {"targets": 0, "targets_with_reference": 0, "targets_without_reference": 0,
                  "grid_points": 0, "grid_points_multi": 0}
        radar_cols = ["time_s", "target_id", "radar_id", "x_m", "y_m", "z_m", "sigma_m"]
        return pd.DataFrame(columns=cols), pd.DataFrame(columns=radar_cols), empty_summary, counts
    target = np.concatenate([r.target for r in per_radar]).astype(str)
    grid = np.concatenate([r.grid_index for r in per_radar])
    x = np.concatenate([r.x for r in per_radar])
    p = np.concatenate([r.p for r in per_radar])
    radar = np.concatenate([np.full(len(r.grid_index), r.radar_id, dtype=object)
                            for r in per_radar])
    targets, target_code = np.unique(target, return_inverse=True)
    g0 = grid.min()
    span = int(grid.max() - g0 + 1)
    key = target_code.astype(np.int64) * span + (grid - g0)
    order = np.argsort(key, kind="stable")
    key_sorted = key[order]
    starts = np.flatnonzero(np.concatenate([[True], key_sorted[1:] != key_sorted[:-1]]))
    # Information-form fusion by sorted reduction.
    info = np.linalg.inv(p[order])
    info_x = np.einsum("mij,mj->mi", info, x[order])
    info_sum = _group_sum(info, starts)
    info_x_sum = _group_sum(info_x, starts)
    n_radars = np.diff(np.append(starts, len(order)))
    p_f = np.linalg.inv(info_sum)
    x_f = np.einsum("mij,mj->mi", p_f, info_x_sum)
    x_eq = _group_sum(x[order], starts) / n_radars[:, None]
    p_eq = _group_sum(p[order], starts) / (n_radars**2)[:, None, None]
    fused_key = key_sorted[starts]
    fused_target = targets[fused_key // span]
    fused_time = ((fused_key % span) + g0) * grid_s

    # Reference at every fused grid point (the radar points are a subset of them).
    ref = np.full((len(fused_key), 3), np.nan)
    bounds = np.flatnonzero(np.concatenate([[True], fused_target[1:] != fused_target[:-1]]))
    for a, b in zip(bounds, np.append(bounds[1:], len(fused_key)), strict=True):
        ref[a:b] = ref_fn(str(fused_target[a]), fused_time[a:b])
    has_ref = np.all(np.isfinite(ref), axis=1)
    group_of = np.repeat(np.arange(len(starts)), n_radars)  # sorted row -> fused row
    ref_radar = np.empty((len(order), 3))
    ref_radar[order] = ref[group_of]

    rows = []
    for rid in radar_ids:
        sel = radar == rid
        ok = sel & np.all(np.isfinite(ref_radar), axis=1)
        rows.append((rid, _rmse(x[ok, :3] - ref_radar[ok]), int(ok.sum()),
                     len(np.unique(target[ok]))))
    n_tgt_ref = len(np.unique(fused_target[has_ref]))
    rows.append((FUSED_COV, _rmse(x_f[has_ref, :3] - ref[has_ref]), int(has_ref.sum()),
                 n_tgt_ref))
    rows.append((FUSED_EQUAL, _rmse(x_eq[has_ref, :3] - ref[has_ref]), int(has_ref.sum()),
                 n_tgt_ref))
    summary = pd.DataFrame(rows, columns=["track", "rmse_m", "n_points", "n_targets"])
    summary = summary.set_index("track")

    lat, lon, alt = frames.ecef_to_geodetic(x_f[:, :3])
    fused_df = pd.DataFrame({
        "time_s": fused_time,
        "target_id": fused_target,
        "x_m": x_f[:, 0], "y_m": x_f[:, 1], "z_m": x_f[:, 2],
        "lat_deg": np.rad2deg(lat), "lon_deg": np.rad2deg(lon), "alt_m": alt,
        "sigma_m": _sigma_per_axis(p_f),
        "sigma_equal_m": _sigma_per_axis(p_eq),
        "n_radars": n_radars,
        "x_equal_m": x_eq[:, 0], "y_equal_m": x_eq[:, 1], "z_equal_m": x_eq[:, 2],
    })
    radar_df = pd.DataFrame({
        "time_s": grid * grid_s,
        "target_id": target,
        "radar_id": radar,
        "x_m": x[:, 0], "y_m": x[:, 1], "z_m": x[:, 2],
        "sigma_m": _sigma_per_axis(p),
    }).sort_values(["target_id", "time_s", "radar_id"], kind="stable", ignore_index=True)
    counts = {
        "targets": len(targets),
        "targets_with_reference": n_tgt_ref,
        "targets_without_reference": len(targets) - n_tgt_ref,
        "grid_points": len(fused_key),
        "grid_points_multi": int((n_radars >= 2).sum()),
    }
    return fused_df, radar_df, summary, counts


def compare_fusion(
    dataset: Dataset,
    calibration: CalibrationLike,
    **kwargs: Any,
) -> pd.DataFrame:
    """Fusion accuracy without and with a calibration.

    Runs :func:`fuse_dataset` on the raw plots and on the plots corrected by
    ``calibration`` (same keyword arguments).

    Returns
    -------
    pandas.DataFrame
        Index: each radar, :data:`FUSED_COV`, :data:`FUSED_EQUAL`; columns
        ``rmse_before_m``, ``rmse_after_m``, ``improvement_pct``
        (``100 (before - after) / before``) and ``n_points`` (grid points with a
        reference, after calibration).
    """
    if calibration is None:
        raise ValueError("compare_fusion needs a calibration to compare with")
    return fusion_comparison(
        fuse_dataset(dataset, None, **kwargs), fuse_dataset(dataset, calibration, **kwargs)
    )


def fusion_comparison(before: FusionResult, after: FusionResult) -> pd.DataFrame:
    """The table of :func:`compare_fusion` from two :func:`fuse_dataset` results."""
    before, after = before.summary, after.summary
    table = pd.DataFrame({
        "rmse_before_m": before["rmse_m"],
        "rmse_after_m": after["rmse_m"],
    })
    table["improvement_pct"] = 100.0 * (table["rmse_before_m"] - table["rmse_after_m"]) / (
        table["rmse_before_m"]
    )
    table["n_points"] = after["n_points"].astype(int)
    return table
