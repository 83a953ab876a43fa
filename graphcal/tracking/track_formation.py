"""Tracks formed from one radar's plots: which plots follow one aircraft from scan to scan.

A radar that reports no identity still sees an aircraft as a sequence of plots, one per
antenna turn, on a smooth path; false plots (clutter, reflections) do not line up.  This
module groups such plots into tracks by scan-to-scan gating, so that an aircraft that no
reference (ADS-B, a Mode S radar) covers can still be recognised and become a path of its
own (:mod:`graphcal.tracking.association`).

The plots are placed on the horizontal plane of the radar, ``x = g sin(theta)``,
``y = g cos(theta)`` with ``g = rho cos(eps)`` for a 3-D plot and ``g = rho`` for a 2-D
one: within one radar a bias moves every plot of a track alike, so tracks are formed on the
measured values.  Scan by scan (plots binned by the radar's scan period), every live track
is predicted to each plot's time (a plot whose Mode 3/A code differs from the track's last
one is not in its gate), and plots and tracks are paired by minimum total squared
distance (:func:`scipy.optimize.linear_sum_assignment`) within a gate of

* ``MAX_SPEED_M_S * dt + GATE_SIGMAS * sqrt(2) * sigma_xy`` for a track of one plot,
* ``GATE_SIGMAS * sqrt(3) * sigma_xy + MAX_ACCELERATION_M_S2 * dt^2 / 2`` after that,

``sigma_xy = sqrt(sigma_rho^2 + (g sigma_theta)^2)`` the plot's largest position sigma.  A
track's velocity follows an alpha-beta filter.  A plot no track takes starts a new one; a
track unseen for :data:`MAX_MISSED_SCANS` scans ends.  A track is kept when it has at least
:data:`MIN_TRACK_PLOTS` plots and an average ground speed of at least
:data:`MIN_SPEED_M_S` (ground clutter does not move).  Plots that carry the radar's own track
number are grouped by that number instead.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.data.dataset import Site
from graphcal.tracking.gating import MAX_SPEED_M_S, scan_period

FloatArray = NDArray[np.float64]

#: Fewest plots of a kept track.
MIN_TRACK_PLOTS = 6
#: Slowest average ground speed of a kept track [m/s].
MIN_SPEED_M_S = 30.0
#: Largest acceleration followed [m/s^2] (a 3 deg/s turn at 230 m/s is 12 m/s^2); the
#: fastest aircraft is the gates' :data:`~graphcal.tracking.gating.MAX_SPEED_M_S`.
MAX_ACCELERATION_M_S2 = 15.0
#: The gates' width in position sigmas.
GATE_SIGMAS = 4.0
#: A track unseen for more scans than this ends.
MAX_MISSED_SCANS = 3
#: The alpha-beta filter's gains.
ALPHA, BETA = 0.6, 0.3


def horizontal_positions(site: Site, plots: Any) -> tuple[FloatArray, FloatArray]:
    """The plots on the radar's horizontal plane, ``(x, y)`` [m] east and north, and each
    plot's position sigma ``sigma_xy`` [m] (module docstring)."""
    ground = np.asarray(plots.range_m, dtype=float).copy()
    if site.is_3d:
        elevation = np.asarray(plots.elevation_rad, dtype=float)
        ground = np.where(np.isfinite(elevation), ground * np.cos(elevation), ground)
    azimuth = np.asarray(plots.azimuth_rad, dtype=float)
    xy = np.stack([ground * np.sin(azimuth), ground * np.cos(azimuth)], axis=-1)
    sigmas = site.measurement_sigmas()
    sigma = np.sqrt(sigmas[0] ** 2 + (ground * sigmas[1]) ** 2)
    return xy, sigma


def form_tracks(site: Site, plots: Any, track_number: NDArray | None = None,
                codes: NDArray[np.object_] | None = None) -> NDArray[np.int64]:
    """Each plot's track (0, 1, ...) or -1 (module docstring).

    Parameters
    ----------
    site : Site
        The radar (scan period, noise sigmas, 2-D or 3-D).
    plots : PlotArrays
        Its plots (``time_s``, ``range_m``, ``azimuth_rad``, ``elevation_rad``), any order.
    track_number : array, optional
        The radar's own track numbers (``<NA>`` where none): plots that carry one are
        grouped by it; the others are tracked.
    codes : array of str, optional
        The plots' Mode 3/A codes ("" where none): a plot does not continue a track whose
        last code differs from its own (a code change starts a new track).

    Returns
    -------
    ndarray of int64
        The track of every plot, numbered in the order of the tracks' first plot; -1 for a
        plot in no kept track.
    """
    n = len(plots.time_s)
    label = np.full(n, -1, dtype=np.int64)
    if n == 0:
        return label
    xy, sigma = horizontal_positions(site, plots)
    time_s = np.asarray(plots.time_s, dtype=float)
    free = np.isfinite(xy).all(axis=1) & np.isfinite(time_s)
    raw = np.full(n, -1, dtype=np.int64)
    next_label = 0
    if track_number is not None:
        numbers = pd.array(track_number, dtype="Int64")
        numbered = ~np.asarray(pd.isna(numbers), dtype=bool) & free
        if numbered.any():
            tracks, _ = pd.factorize(np.asarray(numbers[numbered], dtype=np.int64))
            raw[numbered] = tracks
            next_label = int(tracks.max()) + 1
            free &= ~numbered
    code = (np.full(n, "", dtype=object) if codes is None
            else np.asarray(pd.Series(codes, dtype=object).fillna("").astype(str), dtype=object))
    rows = np.flatnonzero(free)
    raw[rows] = _scan_to_scan(site, time_s[rows], xy[rows], sigma[rows], code[rows]) + next_label
    raw[rows[raw[rows] < next_label]] = -1
    return _kept(raw, time_s, xy, label)


def _scan_to_scan(site: Site, time_s: FloatArray, xy: FloatArray, sigma: FloatArray,
                  code: NDArray[np.object_]) -> NDArray[np.int64]:
    """Scan-to-scan gating of plots into tracks (module docstring); every plot's track."""
    from scipy.optimize import linear_sum_assignment  # only when plots lack an address

    period = scan_period(site)
    n = len(time_s)
    label = np.full(n, -1, dtype=np.int64)
    if n == 0:
        return label
    scan = np.floor(time_s / period).astype(np.int64)
    order = np.lexsort((time_s, scan))
    bounds = np.flatnonzero(np.r_[True, scan[order][1:] != scan[order][:-1], True])
    # Live tracks: last time, position, velocity, plots so far, label.
    t_last = np.zeros(0)
    p_last = np.zeros((0, 2))
    v_last = np.zeros((0, 2))
    count = np.zeros(0, dtype=np.int64)
    ids = np.zeros(0, dtype=np.int64)
    c_last = np.zeros(0, dtype=object)
    next_id = 0
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        rows = order[lo:hi]
        t_now = time_s[rows].mean()
        alive = t_now - t_last <= (MAX_MISSED_SCANS + 1.5) * period
        t_last, p_last, v_last = t_last[alive], p_last[alive], v_last[alive]
        count, ids, c_last = count[alive], ids[alive], c_last[alive]
        taken = np.full(len(rows), -1, dtype=np.int64)
        if len(ids):
            dt = time_s[rows][:, None] - t_last[None, :]                      # (plots, tracks)
            predicted = p_last[None, :, :] + v_last[None, :, :] * dt[..., None]
            distance = np.linalg.norm(xy[rows][:, None, :] - predicted, axis=-1)
            s = sigma[rows][:, None]
            gate = np.where(count[None, :] == 1,
                            MAX_SPEED_M_S * np.abs(dt) + GATE_SIGMAS * np.sqrt(2.0) * s,
                            GATE_SIGMAS * np.sqrt(3.0) * s
                            + 0.5 * MAX_ACCELERATION_M_S2 * dt**2)
            mine = code[rows][:, None]
            inside = (distance <= gate) & (dt > 0) & (
                (mine == "") | (c_last[None, :] == "") | (mine == c_last[None, :]))
            if inside.any():
                cost = np.where(inside, (distance / gate) ** 2, 1e9)
                r, c = linear_sum_assignment(cost)
                good = cost[r, c] < 1e9
                taken[r[good]] = c[good]
        # Update the tracks that took a plot.
        hit = taken >= 0
        if hit.any():
            k, rr = taken[hit], rows[hit]
            dt = time_s[rr] - t_last[k]
            first = count[k] == 1
            predicted = p_last[k] + v_last[k] * dt[:, None]
            innovation = xy[rr] - predicted
            v_new = np.where(first[:, None], (xy[rr] - p_last[k]) / dt[:, None],
                             v_last[k] + BETA * innovation / dt[:, None])
            p_new = np.where(first[:, None], xy[rr], predicted + ALPHA * innovation)
            p_last[k], v_last[k], t_last[k] = p_new, v_new, time_s[rr]
            c_last[k] = np.where(code[rr] != "", code[rr], c_last[k])
            count[k] += 1
            label[rr] = ids[k]
        # Plots no track took start tracks.
        new = rows[~hit]
        if len(new):
            t_last = np.r_[t_last, time_s[new]]
            p_last = np.vstack([p_last, xy[new]])
            v_last = np.vstack([v_last, np.zeros((len(new), 2))])
            count = np.r_[count, np.ones(len(new), dtype=np.int64)]
            c_last = np.r_[c_last, code[new]]
            ids = np.r_[ids, np.arange(next_id, next_id + len(new))]
            label[new] = ids[-len(new):]
            next_id += len(new)
    return label


def _kept(raw: NDArray[np.int64], time_s: FloatArray, xy: FloatArray,
          label: NDArray[np.int64]) -> NDArray[np.int64]:
    """``label`` filled with the tracks of ``raw`` that are kept (enough plots, moving),
    renumbered from 0 in the order of their first plot."""
    rows = np.flatnonzero(raw >= 0)
    if len(rows) == 0:
        return label
    frame = pd.DataFrame({"track": raw[rows], "t": time_s[rows], "x": xy[rows, 0],
                          "y": xy[rows, 1]}).sort_values(["track", "t"], kind="stable")
    groups = frame.groupby("track", sort=True)
    size = groups.size()
    first, last = groups.first(), groups.last()
    span = (last["t"] - first["t"]).to_numpy()
    travel = np.hypot((last["x"] - first["x"]).to_numpy(), (last["y"] - first["y"]).to_numpy())
    with np.errstate(divide="ignore", invalid="ignore"):
        speed = np.where(span > 0, travel / span, 0.0)
    kept = size.index.to_numpy()[(size.to_numpy() >= MIN_TRACK_PLOTS) & (speed >= MIN_SPEED_M_S)]
    kept = kept[np.argsort(first.loc[kept, "t"].to_numpy(), kind="stable")]
    renumber = pd.Series(np.arange(len(kept), dtype=np.int64), index=kept)
    label[rows] = renumber.reindex(raw[rows]).fillna(-1).to_numpy(dtype=np.int64)
    return label


__all__ = ["MIN_TRACK_PLOTS", "form_tracks", "horizontal_positions"]
