"""Gates between plots without an address and the known aircraft's reference trajectories.

The aircraft are those with a reference trajectory (:func:`reference_tracks`): the ADS-B
reports, and the plots of the radars that do report addresses (Mode S), corrected with
their current biases and converted to positions.  For one radar, with its current bias
estimate ``b`` and covariance ``P_b``, :func:`gated_pairs` compares every plot with every
aircraft whose reference spans the plot's true time ``t - time_offset``: the reference
interpolated there is measured through the radar's model with ``b``
(:meth:`RadarMeasurementModel.function`), and the innovation ``e = z - h(x, b)`` is gated by
``e^T S^-1 e <= chi2_m(GATE_PROBABILITY)`` with ``S = R + J_b P_b J_b^T + (sigma_ref^2 in
polar)``: the radar's noise, the bias's uncertainty and the reference's.  A Mode 3/A code
the aircraft never reported, or a Mode C altitude more than :data:`ALTITUDE_GATE_M` from the
reference height, vetoes.

Before any bias is known, :func:`coarse_bias` finds a start by voting: the differences
between every plot and every aircraft within a window wide enough for km offsets and
10 mrad azimuth biases (:data:`COARSE_RANGE_M`, :data:`COARSE_AZIMUTH_RAD`) are histogrammed,
and the peak (refined by the median around it) is the range offset and azimuth bias.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from scipy.special import chdtri

from graphcal.core import frames
from graphcal.data.align import AdsbTrackTable, adsb_track_table, plot_arrays
from graphcal.data.bias import RadarBias
from graphcal.data.dataset import Dataset, Site
from graphcal.model.measurement import measurement_model

FloatArray = NDArray[np.float64]

#: Probability mass inside the association gate.
GATE_PROBABILITY = 0.9999
#: A Mode C altitude further than this from the reference height vetoes the pair [m]
#: (pressure and geometric heights differ by a few hundred metres).
ALTITUDE_GATE_M = 600.0
#: The coarse search's window: range [m] and azimuth [rad] differences voted on.
COARSE_RANGE_M = 6000.0
COARSE_AZIMUTH_RAD = 0.03
#: The coarse search's histogram bins.
COARSE_RANGE_BIN_M = 100.0
COARSE_AZIMUTH_BIN_RAD = 1e-3
#: Longest gap in a reference trajectory that is interpolated [s].
REFERENCE_MAX_GAP_S = 20.0
#: Fastest aircraft considered [m/s] (the candidates' window covers its motion in a scan).
MAX_SPEED_M_S = 350.0
#: Scan period assumed for a radar that declares none [s].
DEFAULT_SCAN_S = 5.0


@dataclass
class References:
    """Reference trajectories of the identified aircraft.

    ``tracks`` holds the positions (ADS-B, then radar-derived for aircraft without ADS-B);
    ``codes`` each aircraft's Mode 3/A codes seen (empty set when unknown).
    """

    tracks: AdsbTrackTable
    codes: dict[str, set[str]]


def codes_of(table: pd.DataFrame) -> dict[str, set[str]]:
    """Each aircraft's Mode 3/A codes in ``table`` (``target_id``, ``mode_3a``)."""
    if "mode_3a" not in table:
        return {}
    pairs = table[["target_id", "mode_3a"]].drop_duplicates()  # few rows from here on
    out: dict[str, set[str]] = {}
    for target, code in zip(pairs["target_id"].astype(str).tolist(),
                            pairs["mode_3a"].astype("string").fillna("").tolist(), strict=True):
        code = code.strip()
        if code and target:
            out.setdefault(target, set()).add(code)
    return out


def reference_tracks(dataset: Dataset, biases: Mapping[str, RadarBias], *,
                     use_adsb: bool = True) -> References:
    """The aircraft's reference trajectories: ADS-B, and the addressed plots of the radars,
    corrected by ``biases`` and converted to positions, for aircraft without ADS-B.

    A radar-derived position's ``sigma_m`` is its plot's largest converted standard
    deviation (range, or range times the azimuth sigma).
    """
    parts = []
    codes: dict[str, set[str]] = {}
    adsb = dataset.adsb if use_adsb else None
    with_adsb: set[str] = set()
    if adsb is not None and len(adsb):
        table = adsb[["time_s", "target_id", "lat_deg", "lon_deg", "alt_m"]].copy()
        table["sigma_m"] = adsb["sigma_m"] if "sigma_m" in adsb else 30.0
        table = table[np.isfinite(table["alt_m"].to_numpy(float))]
        parts.append(table)
        with_adsb = {str(t) for t in pd.unique(table["target_id"])}
        codes.update(codes_of(adsb))
    for rid, site in dataset.sites.items():
        plots = plot_arrays(dataset, rid)
        target = plots.target_id.astype(str)
        keep = (target != "") & ~np.isin(target, list(with_adsb)) & np.isfinite(plots.range_m)
        if site.is_3d:
            keep &= np.isfinite(plots.elevation_rad)
        else:
            keep &= np.isfinite(plots.altitude_m)
        if not np.any(keep):
            continue
        bias = biases.get(rid, RadarBias())
        sub = plots.subset(keep)
        ecef = plot_positions(site, sub, bias)
        lat, lon, h = frames.ecef_to_geodetic(ecef)
        sigmas = site.measurement_sigmas()
        sigma = np.maximum(sigmas[0], sub.range_m * sigmas[1])
        parts.append(pd.DataFrame({
            "time_s": sub.time_s - bias.time_offset_s, "target_id": target[keep],
            "lat_deg": np.rad2deg(lat), "lon_deg": np.rad2deg(lon), "alt_m": h,
            "sigma_m": sigma}))
    plot_codes = codes_of(dataset.plots[dataset.plots["target_id"].astype(str) != ""])
    for target, seen in plot_codes.items():
        codes.setdefault(target, set()).update(seen)
    if parts:
        table = pd.concat(parts, ignore_index=True)
        table = table.sort_values(["target_id", "time_s"], kind="stable")
        table = table.drop_duplicates(["target_id", "time_s"])
    else:
        table = pd.DataFrame({c: pd.Series(dtype=float) for c in
                              ("time_s", "lat_deg", "lon_deg", "alt_m", "sigma_m")})
        table["target_id"] = pd.Series(dtype=object)
    return References(adsb_track_table(table), codes)


def plot_positions(site: Site, plots: Any, bias: RadarBias) -> FloatArray:
    """ECEF positions of plots corrected by ``bias`` (2-D plots at their altitude)."""
    model = measurement_model(site)
    measured = np.stack([plots.range_m, plots.azimuth_rad,
                         plots.elevation_rad if site.is_3d else np.zeros(len(plots))], axis=-1)
    polar = model.inverse_function(measured, bias)
    if not site.is_3d:
        # The elevation that puts the plot at its reported altitude.
        polar[:, 2] = frames.elevation_from_height(polar[:, 0], plots.altitude_m, site.lat_rad,
                                                   site.alt_m)
    return site.ecef_from_polar(polar[:, 0], polar[:, 1], polar[:, 2])


# --------------------------------------------------------------------------- candidates
@dataclass
class Pairs:
    """Gated (plot, aircraft) pairs of one radar: plot rows, aircraft codes, chi-squares."""

    plot: NDArray[np.int64]
    aircraft: NDArray[np.int64]
    chi2: FloatArray
    residual: FloatArray  # (n, m): measured - predicted, azimuth wrapped


def _predicted(site: Site, refs: References, plots: Any, bias: RadarBias,
               plot_rows: NDArray[np.int64], aircraft: NDArray[np.int64]
               ) -> tuple[FloatArray, FloatArray, FloatArray, NDArray[np.bool_]]:
    """Each pair's predicted measurement, reference position and sigma, and validity."""
    tracks = refs.tracks
    t_true = plots.time_s[plot_rows] - bias.time_offset_s
    j, w, ok = tracks.bracket(aircraft, t_true, REFERENCE_MAX_GAP_S)
    ecef = (1.0 - w)[:, None] * tracks.ecef_m[j] + w[:, None] * tracks.ecef_m[j + 1]
    sigma = np.sqrt((1.0 - w) ** 2 * tracks.sigma_m[j] ** 2 + w**2 * tracks.sigma_m[j + 1] ** 2)
    predicted = measurement_model(site).function(ecef, bias)
    return predicted, ecef, sigma, ok


def gated_pairs(site: Site, refs: References, plots: Any, bias: RadarBias,
                 bias_covariance: FloatArray | None, window: tuple[float, float] | None,
                 codes: NDArray[np.object_] | None = None) -> Pairs:
    """Every (plot, aircraft) pair in the gate (or, with ``window``, within it);
    ``codes``: the plots' Mode 3/A codes ("" where none), evidence when given."""
    tracks = refs.tracks
    n_aircraft = len(tracks.targets)
    empty = Pairs(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)))
    if n_aircraft == 0 or len(plots) == 0:
        return empty
    plot_rows, aircraft = _candidates(site, refs, plots, bias, bias_covariance, window)
    predicted, ecef, sigma, ok = _predicted(site, refs, plots, bias, plot_rows, aircraft)
    m = 3 if site.is_3d else 2
    measured = np.stack([plots.range_m, plots.azimuth_rad, plots.elevation_rad],
                        axis=-1)[plot_rows]
    residual = measured - predicted
    residual[:, 1] = frames.wrap_to_pi(residual[:, 1])
    keep = ok & np.all(np.isfinite(residual[:, :m]), axis=1)
    if window is not None:
        keep &= (np.abs(residual[:, 0]) <= window[0]) & (np.abs(residual[:, 1]) <= window[1])
        return Pairs(plot_rows[keep], aircraft[keep], np.zeros(int(keep.sum())),
                      residual[keep])
    plot_rows, aircraft, residual = plot_rows[keep], aircraft[keep], residual[keep]
    predicted, ecef, sigma = predicted[keep], ecef[keep], sigma[keep]
    # Innovation covariance: radar noise + reference + bias uncertainty (polar).
    sigmas = site.measurement_sigmas()
    r = np.maximum(predicted[:, 0], 1.0)
    cov = np.zeros((len(r), 3, 3))
    cov[:, 0, 0] = sigmas[0] ** 2 + sigma**2
    cov[:, 1, 1] = sigmas[1] ** 2 + (sigma / r) ** 2
    cov[:, 2, 2] = sigmas[2] ** 2 + (sigma / r) ** 2
    if bias_covariance is not None:
        jac = np.zeros((len(r), 3, 4))  # d h / d (offset, gain, azimuth, elevation)
        jac[:, 0, 0], jac[:, 0, 1], jac[:, 1, 2], jac[:, 2, 3] = 1.0, r, 1.0, 1.0
        cov += jac @ bias_covariance[:4, :4] @ np.swapaxes(jac, 1, 2)
    cov = cov[:, :m, :m]
    e = residual[:, :m]
    chi2 = np.einsum("ni,ni->n", e, np.linalg.solve(cov, e[..., None])[..., 0])
    gate = chdtri(m, 1.0 - GATE_PROBABILITY)  # the chi-square quantile
    keep = chi2 <= gate
    # Evidence: Mode C altitude and Mode 3/A code.
    if not site.is_3d and np.isfinite(plots.altitude_m).any():
        _, _, h = frames.ecef_to_geodetic(ecef)
        alt = plots.altitude_m[plot_rows]
        keep &= ~(np.isfinite(alt) & (np.abs(alt - h) > ALTITUDE_GATE_M))
    if codes is not None and refs.codes:
        names = np.asarray(tracks.targets, dtype=object)[aircraft]
        plot_code = np.asarray(codes, dtype=object)[plot_rows]
        veto = np.array([bool(c) and bool(refs.codes.get(n)) and c not in refs.codes[n]
                         for c, n in zip(plot_code, names, strict=True)], dtype=bool)
        keep &= ~veto
    return Pairs(plot_rows[keep], aircraft[keep], chi2[keep], residual[keep])


def _candidates(site: Site, refs: References, plots: Any, bias: RadarBias,
                bias_covariance: FloatArray | None, window: tuple[float, float] | None
                ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(plot, aircraft) pairs worth gating: the aircraft's references, measured at the
    middle of each scan, within a window of the plot that covers the aircraft's motion
    in half a scan (:data:`MAX_SPEED_M_S`), the bias's uncertainty and the noise."""
    tracks = refs.tracks
    n_aircraft = len(tracks.targets)
    period = scan_period(site)
    first = tracks.time_s[tracks.start[:-1]]
    last = tracks.time_s[np.maximum(tracks.start[1:] - 1, tracks.start[:-1])]
    t_true = plots.time_s - bias.time_offset_s
    scan = np.floor(t_true / period).astype(np.int64)
    scans, scan_of_plot = np.unique(scan, return_inverse=True)
    middle = (scans + 0.5) * period
    # Every aircraft measured at every scan's middle (NaN where it has no reference).
    grid_scan = np.repeat(np.arange(len(scans)), n_aircraft)
    grid_aircraft = np.tile(np.arange(n_aircraft), len(scans))
    alive = (first[grid_aircraft] <= middle[grid_scan] + period) & (
        middle[grid_scan] - period <= last[grid_aircraft])
    grid_scan, grid_aircraft = grid_scan[alive], grid_aircraft[alive]
    t_mid = np.clip(middle[grid_scan], first[grid_aircraft], last[grid_aircraft])
    j, w, ok = tracks.bracket(grid_aircraft, t_mid, np.inf)
    ecef = (1.0 - w)[:, None] * tracks.ecef_m[j] + w[:, None] * tracks.ecef_m[j + 1]
    predicted = measurement_model(site).function(ecef, bias)
    range_grid = np.full((len(scans), n_aircraft), np.nan)
    azimuth_grid = np.full((len(scans), n_aircraft), np.nan)
    range_grid[grid_scan[ok], grid_aircraft[ok]] = predicted[ok, 0]
    azimuth_grid[grid_scan[ok], grid_aircraft[ok]] = predicted[ok, 1]
    # The window: the motion in a scan and the time to the scan's middle, the bias's
    # uncertainty and the noise (6 sigma), or the coarse search's window.
    sigmas = site.measurement_sigmas()
    motion = MAX_SPEED_M_S * period
    if window is not None:
        range_window, azimuth_window = window[0] + motion, window[1]
    else:
        spread = np.zeros(4) if bias_covariance is None else np.sqrt(
            np.clip(np.diag(bias_covariance)[:4], 0.0, None))
        range_window = motion + 6.0 * (sigmas[0] + spread[0]) + 6.0 * spread[1] * 5e5
        azimuth_window = 6.0 * (sigmas[1] + spread[2])
    rows, crafts = [], []
    block = max(1, 2_000_000 // max(n_aircraft, 1))
    for lo in range(0, len(plots), block):
        k = scan_of_plot[lo:lo + block]
        r = plots.range_m[lo:lo + block, None]
        with np.errstate(invalid="ignore"):
            dr = np.abs(r - range_grid[k])
            daz = np.abs(frames.wrap_to_pi(plots.azimuth_rad[lo:lo + block, None]
                                           - azimuth_grid[k]))
            near = (dr <= range_window) & (daz <= azimuth_window + motion / np.maximum(r, 1.0))
        i, a = np.nonzero(near)
        rows.append(i + lo)
        crafts.append(a)
    return (np.concatenate(rows).astype(np.int64) if rows else np.zeros(0, np.int64),
            np.concatenate(crafts).astype(np.int64) if crafts else np.zeros(0, np.int64))


# --------------------------------------------------------------------------- coarse search
def coarse_bias(site: Site, refs: References, plots: Any, time_offset_s: float = 0.0
                ) -> RadarBias | None:
    """A starting range offset and azimuth bias by voting (module docstring); ``None`` when
    no plot is near any aircraft."""
    start = RadarBias(time_offset_s=time_offset_s)
    pairs = gated_pairs(site, refs, plots, start, None, (COARSE_RANGE_M, COARSE_AZIMUTH_RAD))
    if len(pairs.plot) < 10:
        return None
    dr, daz = pairs.residual[:, 0], pairs.residual[:, 1]
    r_edges = np.arange(-COARSE_RANGE_M, COARSE_RANGE_M + COARSE_RANGE_BIN_M, COARSE_RANGE_BIN_M)
    a_edges = np.arange(-COARSE_AZIMUTH_RAD, COARSE_AZIMUTH_RAD + COARSE_AZIMUTH_BIN_RAD,
                        COARSE_AZIMUTH_BIN_RAD)
    counts, _, _ = np.histogram2d(dr, daz, bins=(r_edges, a_edges))
    i, k = np.unravel_index(int(np.argmax(counts)), counts.shape)
    near = ((np.abs(dr - 0.5 * (r_edges[i] + r_edges[i + 1])) <= 2 * COARSE_RANGE_BIN_M)
            & (np.abs(daz - 0.5 * (a_edges[k] + a_edges[k + 1])) <= 2 * COARSE_AZIMUTH_BIN_RAD))
    offset, azimuth = float(np.median(dr[near])), float(np.median(daz[near]))
    elevation = 0.0
    if site.is_3d:
        elevation = float(np.median(pairs.residual[near, 2]))
    return RadarBias(range_offset_m=offset, azimuth_bias_rad=azimuth,
                     elevation_bias_rad=elevation, time_offset_s=time_offset_s)


def scan_period(site: Site) -> float:
    return float(site.scan_period_s) if site.scan_period_s else DEFAULT_SCAN_S



__all__ = ["ALTITUDE_GATE_M", "GATE_PROBABILITY", "Pairs", "References", "coarse_bias",
           "codes_of", "gated_pairs", "plot_positions", "reference_tracks", "scan_period"]
