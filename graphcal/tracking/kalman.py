"""Constant-velocity Kalman filter in ECEF for radar tracks (paper 002, section 3.3).

State ``[x, y, z, vx, vy, vz]`` in ECEF [m, m/s]; measurement the plot's ECEF
position (a radar plot converted from polar), ``H = [I_3 0]``.  The motion model
is the continuous white-noise-acceleration model with spectral density
``q_m2_s3`` [m^2/s^3] per axis (:func:`cv_process_noise`)::

    x_k = F(dt) x_{k-1} + w_k,   F(dt) = [[I, dt I], [0, I]],   w_k ~ N(0, Q(dt))
    z_k = H x_k + v_k,           v_k ~ N(0, R_k)

Measurement noise ``R_k`` (:func:`measurement_noise`), the three choices of
paper 002:

* ``"fixed"``: a given constant matrix, eq. 31: ``R1 = diag(1e4, 1e4, 1e4)`` m^2
  (the range sigma on every ECEF axis, blind to the angular errors);
* ``"converted-first"``: ``R2``, the converted covariance ``J R_polar J^T`` of the
  track's first plot (eq. 19), held for the whole track ("computed at the first
  filtering time");
* ``"converted"``: every plot's own converted covariance.

Initialisation (``init``):

* ``"two-point"`` (default): from the first two plots,
  ``x = [z_1, (z_1 - z_0) / dt]`` with the exact covariance of that estimate,
  ``P = [[R_1, R_1 / dt], [R_1 / dt, (R_0 + R_1) / dt^2]]`` (process noise
  between the two plots neglected).  The first estimate is at the second plot;
  row 0 is marked not valid.  With ``q = 0`` the filter is then exactly
  recursive least squares: its estimate at the last plot equals the batch
  weighted line fit.
* ``"one-point"``: ``x = [z_0, 0]``, ``P = blockdiag(R_0, velocity_sigma^2 I)``
  with a large velocity sigma (default 500 m/s, above any aircraft's speed); the
  first estimate is at the first plot, but it knows nothing of the velocity.

Every function broadcasts over leading batch dimensions (Monte-Carlo runs,
several tracks padded to one length with a ``mask``), so a filter over ``B``
tracks of ``n`` plots is ``n`` vectorised steps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Paper 002 eq. 31: the fixed measurement-noise matrix R1 [m^2].
PAPER002_R1_M2: FloatArray = np.diag([1.0e4, 1.0e4, 1.0e4])
#: Measurement-noise modes of :func:`measurement_noise`.
NOISE_MODES: tuple[str, ...] = ("fixed", "converted-first", "converted")
#: Initialisations of :func:`kalman_filter`.
INIT_MODES: tuple[str, ...] = ("two-point", "one-point")
#: Default 1-sigma velocity [m/s] of a one-point initialisation.
DEFAULT_VELOCITY_SIGMA_MPS = 500.0

_H = np.hstack([np.eye(3), np.zeros((3, 3))])


def cv_transition(dt_s: ArrayLike) -> FloatArray:
    """Constant-velocity transition matrix ``F(dt) = [[I, dt I], [0, I]]``.

    Parameters
    ----------
    dt_s : float or array_like
        Time step(s) [s].

    Returns
    -------
    ndarray, shape ``dt_s.shape + (6, 6)``
    """
    dt = np.asarray(dt_s, dtype=float)
    f = np.broadcast_to(np.eye(6), dt.shape + (6, 6)).copy()
    for i in range(3):
        f[..., i, i + 3] = dt
    return f


def cv_process_noise(dt_s: ArrayLike, q_m2_s3: float) -> FloatArray:
    """Process noise of the continuous white-noise-acceleration model.

    ``Q(dt) = q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]]``: the covariance of
    ``int_0^dt F(dt - s) G w(s) ds`` with ``G = [0 I]^T`` and ``E[w w^T] = q I delta``.

    Parameters
    ----------
    dt_s : float or array_like
        Time step(s) [s], >= 0.
    q_m2_s3 : float
        Acceleration noise spectral density per axis [m^2/s^3], >= 0.

    Returns
    -------
    ndarray, shape ``dt_s.shape + (6, 6)`` [m^2, m^2/s, m^2/s^2]
    """
    if not q_m2_s3 >= 0.0:
        raise ValueError(f"process noise q_m2_s3 must be >= 0, got {q_m2_s3}")
    dt = np.asarray(dt_s, dtype=float)
    if np.any(dt < 0):
        raise ValueError("time steps must be >= 0 (times must be sorted)")
    q = np.zeros(dt.shape + (6, 6))
    for i in range(3):
        q[..., i, i] = q_m2_s3 * dt**3 / 3.0
        q[..., i, i + 3] = q[..., i + 3, i] = q_m2_s3 * dt**2 / 2.0
        q[..., i + 3, i + 3] = q_m2_s3 * dt
    return q


def measurement_noise(
    mode: str, converted_cov_m2: ArrayLike, fixed_m2: ArrayLike = PAPER002_R1_M2
) -> FloatArray:
    """Per-plot measurement noise ``R_k`` for one of paper 002's three choices.

    Parameters
    ----------
    mode : {"fixed", "converted-first", "converted"}
        ``"fixed"``: ``fixed_m2`` for every plot (eq. 31, ``R1``);
        ``"converted-first"``: the converted covariance of the first plot of each
        track, held (``R2``); ``"converted"``: each plot's converted covariance.
    converted_cov_m2 : array_like, shape (..., n, 3, 3)
        Converted polar -> ECEF covariance of each plot [m^2] (eq. 19), e.g.
        :attr:`graphcal.model.cross_radar.ConvertedPlots.cov_m2`.
    fixed_m2 : array_like, shape (3, 3)
        The fixed matrix [m^2]; default ``R1 = diag(1e4)``.

    Returns
    -------
    ndarray, shape (..., n, 3, 3) [m^2]
    """
    cov = np.asarray(converted_cov_m2, dtype=float)
    if cov.ndim < 3 or cov.shape[-2:] != (3, 3):
        raise ValueError(f"converted covariance must be (..., n, 3, 3), got {cov.shape}")
    if mode == "fixed":
        fixed = np.asarray(fixed_m2, dtype=float)
        if fixed.shape != (3, 3):
            raise ValueError(f"fixed measurement noise must be 3 x 3, got {fixed.shape}")
        return np.broadcast_to(fixed, cov.shape).copy()
    if mode == "converted-first":
        return np.broadcast_to(cov[..., :1, :, :], cov.shape).copy()
    if mode == "converted":
        return cov.copy()
    raise ValueError(f"unknown measurement-noise mode {mode!r}; use one of {NOISE_MODES}")


@dataclass
class TrackEstimate:
    """Filtered states of one or a batch of tracks at their measurement times.

    Attributes
    ----------
    time_s : ndarray (..., n)
        Measurement times [s].
    x : ndarray (..., n, 6)
        Filtered states ``[x, y, z, vx, vy, vz]`` ECEF [m, m/s].
    p : ndarray (..., n, 6, 6)
        Their covariances.
    valid : ndarray (..., n) of bool
        True where an estimate exists: False at the first plot of a two-point
        initialisation and on padding (``mask`` False).
    q_m2_s3 : float
        Process noise the filter ran with [m^2/s^3].
    """

    time_s: FloatArray
    x: FloatArray
    p: FloatArray
    valid: BoolArray
    q_m2_s3: float

    @property
    def position_m(self) -> FloatArray:
        """Filtered ECEF positions [m], (..., n, 3)."""
        return self.x[..., :3]


def _symmetrise(p: FloatArray) -> FloatArray:
    return 0.5 * (p + np.swapaxes(p, -1, -2))


def kalman_filter(
    time_s: ArrayLike,
    z_ecef_m: ArrayLike,
    r_m2: ArrayLike,
    *,
    q_m2_s3: float,
    init: str = "two-point",
    velocity_sigma_mps: float = DEFAULT_VELOCITY_SIGMA_MPS,
    mask: ArrayLike | None = None,
) -> TrackEstimate:
    """Constant-velocity Kalman filter over the plots of one track (or a batch of tracks).

    Prediction ``x- = F x``, ``P- = F P F^T + Q``; update with the Joseph form
    ``P = (I - K H) P- (I - K H)^T + K R K^T``, ``K = P- H^T (H P- H^T + R)^-1``.

    Parameters
    ----------
    time_s : array_like (..., n)
        Plot times [s], non-decreasing along the last axis (within the mask).
    z_ecef_m : array_like (..., n, 3)
        Plot positions in ECEF [m].
    r_m2 : array_like (3, 3) or (..., n, 3, 3)
        Measurement noise [m^2] (see :func:`measurement_noise`).
    q_m2_s3 : float
        Acceleration noise spectral density [m^2/s^3] (:func:`cv_process_noise`).
    init : {"two-point", "one-point"}
        Initialisation (module docstring).
    velocity_sigma_mps : float
        Velocity 1-sigma of the one-point initialisation [m/s].
    mask : array_like (..., n) of bool, optional
        False for padding: a batch of tracks of different lengths is given with
        each track's plots first and padding after (see :func:`pad_tracks`).

    Returns
    -------
    TrackEstimate

    Raises
    ------
    ValueError
        On inconsistent shapes, unsorted times, an unknown ``init``, a track with
        fewer plots than the initialisation needs, or two-point initialisation
        from two plots at the same time.
    """
    t = np.asarray(time_s, dtype=float)
    z = np.asarray(z_ecef_m, dtype=float)
    if t.ndim < 1 or z.shape != t.shape + (3,):
        raise ValueError(f"z_ecef_m must have shape {t.shape + (3,)}, got {z.shape}")
    n = t.shape[-1]
    batch = t.shape[:-1]
    r = np.asarray(r_m2, dtype=float)
    if r.shape == (3, 3):
        r = np.broadcast_to(r, t.shape + (3, 3))
    elif r.shape != t.shape + (3, 3):
        raise ValueError(f"r_m2 must be (3, 3) or {t.shape + (3, 3)}, got {r.shape}")
    m = np.ones(t.shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if m.shape != t.shape:
        raise ValueError(f"mask must have shape {t.shape}, got {m.shape}")
    if np.any(m[..., 1:] & ~m[..., :-1]):
        raise ValueError("mask must put each track's plots first and padding after")
    if init not in INIT_MODES:
        raise ValueError(f"unknown init {init!r}; use one of {INIT_MODES}")
    need = 2 if init == "two-point" else 1
    if n < need or not np.all(m[..., need - 1]):
        raise ValueError(f"every track needs at least {need} plot(s) for {init} initialisation")
    # Padding keeps the last real time: dt = 0 and no update leaves the state alone.
    t = _fill_padding(t, m)
    dt_all = np.diff(t, axis=-1)
    if np.any(dt_all < 0):
        raise ValueError("plot times must be sorted (non-decreasing) within each track")
    if not q_m2_s3 >= 0.0:
        raise ValueError(f"process noise q_m2_s3 must be >= 0, got {q_m2_s3}")

    x_out = np.full(batch + (n, 6), np.nan)
    p_out = np.full(batch + (n, 6, 6), np.nan)
    valid = m.copy()
    if init == "two-point":
        dt0 = dt_all[..., 0]
        if np.any(dt0 <= 0):
            raise ValueError(
                "two-point initialisation needs the first two plots at different times"
            )
        x = np.concatenate([z[..., 1, :], (z[..., 1, :] - z[..., 0, :]) / dt0[..., None]], axis=-1)
        r0, r1 = r[..., 0, :, :], r[..., 1, :, :]
        inv_dt = (1.0 / dt0)[..., None, None]
        p = np.zeros(batch + (6, 6))
        p[..., :3, :3] = r1
        p[..., :3, 3:] = r1 * inv_dt
        p[..., 3:, :3] = r1 * inv_dt
        p[..., 3:, 3:] = (r0 + r1) * inv_dt**2
        valid[..., 0] = False
        start = 1
    else:
        x = np.concatenate([z[..., 0, :], np.zeros(batch + (3,))], axis=-1)
        p = np.zeros(batch + (6, 6))
        p[..., :3, :3] = r[..., 0, :, :]
        p[..., 3:, 3:] = np.eye(3) * velocity_sigma_mps**2
        start = 0
    x_out[..., start, :] = x
    p_out[..., start, :, :] = p
    eye6 = np.eye(6)
    for k in range(start + 1, n):
        dt = dt_all[..., k - 1]
        f = cv_transition(dt)
        x = np.einsum("...ij,...j->...i", f, x)
        p = f @ p @ np.swapaxes(f, -1, -2) + cv_process_noise(dt, q_m2_s3)
        rk = r[..., k, :, :]
        s = p[..., :3, :3] + rk
        gain = np.swapaxes(np.linalg.solve(s, p[..., :3, :]), -1, -2)  # P H^T S^-1
        innov = z[..., k, :] - x[..., :3]
        x_new = x + np.einsum("...ij,...j->...i", gain, innov)
        ikh = eye6 - gain @ _H
        p_new = ikh @ p @ np.swapaxes(ikh, -1, -2) + gain @ rk @ np.swapaxes(gain, -1, -2)
        upd = m[..., k]
        x = np.where(upd[..., None], x_new, x)
        p = np.where(upd[..., None, None], _symmetrise(p_new), p)
        x_out[..., k, :] = x
        p_out[..., k, :, :] = p
    x_out[~valid] = np.nan
    p_out[~valid] = np.nan
    return TrackEstimate(t, x_out, p_out, valid, float(q_m2_s3))


def _fill_padding(t: FloatArray, mask: BoolArray) -> FloatArray:
    """Times with padding replaced by the track's last real time."""
    if mask.all():
        return t.copy()
    last = np.maximum(mask.sum(axis=-1) - 1, 0)
    last_time = np.take_along_axis(t, last[..., None], axis=-1)
    return np.where(mask, t, last_time)


def predict_to(
    track: TrackEstimate,
    query_time_s: ArrayLike,
    *,
    max_extrapolation_s: float = 0.0,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Track states at requested times: the last estimate at or before each time, predicted.

    ``x(t) = F(t - t_j) x_j``, ``P(t) = F P_j F^T + Q(t - t_j)`` with ``j`` the
    last valid estimate with ``t_j <= t``.  Used to bring asynchronous tracks to a
    common time grid before fusion.

    Parameters
    ----------
    track : TrackEstimate
        From :func:`kalman_filter`, batch shape ``B`` (possibly empty).
    query_time_s : array_like (m,) or B + (m,)
        Requested times [s]; the same for every track of the batch when 1-D.
    max_extrapolation_s : float
        How far past the track's last estimate a time is still served [s]; 0
        keeps to the track's span.

    Returns
    -------
    x : ndarray B + (m, 6)
    p : ndarray B + (m, 6, 6)
    ok : ndarray B + (m,) of bool
        False (and NaN states) before the first or after the last estimate
        (plus ``max_extrapolation_s``).
    """
    batch = track.time_s.shape[:-1]
    n = track.time_s.shape[-1]
    tq = np.asarray(query_time_s, dtype=float)
    if tq.ndim == 1:
        tq = np.broadcast_to(tq, batch + tq.shape)
    if tq.ndim < 1 or tq.shape[:-1] != batch:
        raise ValueError(f"query times must be (m,) or {batch + ('m',)}, got {tq.shape}")
    mq = tq.shape[-1]
    flat = TrackEstimate(
        track.time_s.reshape(-1, n), track.x.reshape(-1, n, 6), track.p.reshape(-1, n, 6, 6),
        track.valid.reshape(-1, n), track.q_m2_s3,
    )
    rows = np.repeat(np.arange(flat.time_s.shape[0]), mq)
    x, p, ok = predict_rows(
        flat, rows, tq.reshape(-1), max_extrapolation_s=max_extrapolation_s
    )
    return x.reshape(tq.shape + (6,)), p.reshape(tq.shape + (6, 6)), ok.reshape(tq.shape)


def predict_rows(
    track: TrackEstimate,
    row: ArrayLike,
    query_time_s: ArrayLike,
    *,
    max_extrapolation_s: float = 0.0,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Like :func:`predict_to` for a batch of tracks, one query per ``(row, time)`` pair.

    Parameters
    ----------
    track : TrackEstimate
        Batch of tracks, ``time_s`` of shape (B, n).
    row : array_like (m,) of int
        Track (batch row) of each query.
    query_time_s : array_like (m,)
        Requested times [s].
    max_extrapolation_s : float
        As for :func:`predict_to`.

    Returns
    -------
    x : ndarray (m, 6)
    p : ndarray (m, 6, 6)
    ok : ndarray (m,) of bool
    """
    if track.time_s.ndim != 2:
        raise ValueError("predict_rows needs a batch of tracks: time_s of shape (B, n)")
    rows = np.asarray(row, dtype=np.int64)
    tq = np.asarray(query_time_s, dtype=float)
    if rows.shape != tq.shape or rows.ndim != 1:
        raise ValueError("row and query_time_s must be 1-D arrays of the same length")
    n_batch = track.time_s.shape[0]
    if len(rows) and (rows.min() < 0 or rows.max() >= n_batch):
        raise ValueError(f"row indices must be in [0, {n_batch})")
    idx = np.zeros(len(rows), dtype=np.int64)
    ok = np.zeros(len(rows), dtype=bool)
    order = np.argsort(rows, kind="stable")
    bounds = np.searchsorted(rows[order], np.arange(n_batch + 1))
    for b in range(n_batch):
        sel = order[bounds[b] : bounds[b + 1]]
        if len(sel) == 0:
            continue
        kept = np.flatnonzero(track.valid[b])
        if len(kept) == 0:
            continue
        tv = track.time_s[b, kept]
        j = np.searchsorted(tv, tq[sel], side="right") - 1
        ok[sel] = (j >= 0) & (tq[sel] <= tv[-1] + max_extrapolation_s)
        idx[sel] = kept[np.clip(j, 0, len(kept) - 1)]
    xj = track.x[rows, idx]
    pj = track.p[rows, idx]
    dt = np.where(ok, tq - track.time_s[rows, idx], 0.0)
    f = cv_transition(dt)
    x = np.einsum("...ij,...j->...i", f, xj)
    p = f @ pj @ np.swapaxes(f, -1, -2) + cv_process_noise(dt, track.q_m2_s3)
    x[~ok] = np.nan
    p[~ok] = np.nan
    return x, p, ok


def pad_tracks(
    arrays: Sequence[ArrayLike], fill: float = 0.0
) -> tuple[FloatArray, BoolArray]:
    """Stack tracks of different lengths along a new first axis, padding at the end.

    Parameters
    ----------
    arrays : sequence of array_like, each (n_i, ...)
        Per-track arrays with the same trailing shape.
    fill : float
        Value of the padding.

    Returns
    -------
    stacked : ndarray (len(arrays), max n_i, ...)
    mask : ndarray (len(arrays), max n_i) of bool
        True on real entries.
    """
    if len(arrays) == 0:
        raise ValueError("no tracks to pad")
    items = [np.asarray(a, dtype=float) for a in arrays]
    tail = items[0].shape[1:]
    if any(a.shape[1:] != tail for a in items):
        raise ValueError("all tracks must have the same trailing shape")
    n = max(a.shape[0] for a in items)
    out = np.full((len(items), n) + tail, fill, dtype=float)
    mask = np.zeros((len(items), n), dtype=bool)
    for i, a in enumerate(items):
        out[i, : a.shape[0]] = a
        mask[i, : a.shape[0]] = True
    return out, mask
