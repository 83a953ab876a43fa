"""Target-state formulation of the graph calibrator: aircraft trajectories in the graph.

Every aircraft (``target_id``) seen by two or more radars, or by one radar and
ADS-B, gets a trajectory of states ``x = (p, v)`` (position [m] and velocity
[m/s] in an ENU frame at the network's centre).  States sit at the plots'
times, merged into clusters no longer than ``state_spacing_s``; a trajectory
is cut where no plot arrives for ``max_state_gap_s``.  Factors:

* **plot factors** (:class:`PlotFactor`): a plot of radar ``r`` at time ``t``
  constrains ``r``'s biases and the state ``k`` nearest in time::

      p(t) = p_k + v_k (t - t_k)                       (constant velocity)
      e    = z - h(A_r p(t) + c_r, beta_r)

  with ``A_r, c_r`` the network-to-radar ENU map, ``h`` polar conversion
  followed by the bias model, azimuth wrapped.  A 2-D radar's plot also
  carries its reported (Mode C) height, compared with the state's height
  (linearised about the plot's own position, where the ellipsoid's curvature
  over the few hundred metres of correction is below 0.1 m).  No
  interpolation or synchronisation between radars is needed.
* **ADS-B factors** (:class:`AdsbTrackFactor`): each report at time ``t``
  is ``p(t)`` of the nearest state plus the report's noise (horizontal sigma,
  1.5 x vertically), robust like every measurement.
* **motion factors**: constant velocity with white acceleration of spectral
  density ``q`` between consecutive states (linear, added as GTSAM linear
  factors)::

      [p2 - p1 - v1 dt, v2 - v1] ~ N(0, q [[dt^3/3 I, dt^2/2 I], [dt^2/2 I, dt I]])

* a weak velocity prior (``VELOCITY_PRIOR_SIGMA_MPS``) so that a trajectory
  of one state stays solvable.

Each plot and each ADS-B report enters exactly one factor, so the marginal
covariance of the biases is exact; the price is one state per cluster and
Python factor calls for groups of ``chunk`` plots.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.data.align import ADSB_VERTICAL_SIGMA_RATIO, PlotArrays, plot_arrays
from graphcal.data.dataset import Dataset, Site
from graphcal.model.cross_radar import ALTITUDE_SIGMA_M, corrected_ecef
from graphcal.model.measurement import RadarMeasurementModel
from graphcal.model.parameters import RadarTerms
from graphcal.model.robust import RobustKernel
from graphcal.model.trajectory import NetworkFrame
from graphcal.solvers.gtsam_adapter import FactorGraph, symbol

FloatArray = NDArray[np.float64]

#: Default white-acceleration spectral density [m^2/s^3] of the motion factors
#: (sqrt(q) = 2 m/s^1.5 lets a 5 s prediction move by about 15 m, a moderate turn).
DEFAULT_PROCESS_NOISE_M2_S3 = 4.0
#: Longest time span [s] of the plots that share one state.
DEFAULT_STATE_SPACING_S = 1.0
#: A trajectory is cut where no plot arrives for this long [s].
DEFAULT_MAX_STATE_GAP_S = 60.0
#: Plots (or ADS-B states) per vectorised factor.
DEFAULT_CHUNK = 32
#: Weak prior on every state's velocity [m/s].
VELOCITY_PRIOR_SIGMA_MPS = 500.0
#: ADS-B reports farther than this from the nearest state [s] are not used.
MAX_ADSB_EXTRAPOLATION_S = 2.0


# --------------------------------------------------------------------------- factors
@dataclass
class PlotFactor:
    """A group of one radar's plots of one aircraft against that aircraft's states."""

    terms: RadarTerms
    bias_key: int
    state_keys: list[int]
    state_of_plot: NDArray[np.int64]  # (n,) index into state_keys
    dt_s: FloatArray  # (n,) plot time minus state time
    measured: FloatArray  # (n, 3) range, azimuth, elevation (2-D: height in column 2)
    sigmas: FloatArray  # (m,)
    a: FloatArray  # (3, 3) network ENU -> radar ENU
    c: FloatArray  # (3,)
    normal: FloatArray | None  # (n, 3) 2-D: height gradient in network ENU
    height0: FloatArray | None  # (n,) 2-D: height at p0
    p0: FloatArray | None  # (n, 3) 2-D: linearisation point of the height
    kernel: RobustKernel

    @property
    def rows(self) -> int:
        return len(self.sigmas)

    @property
    def dimension(self) -> int:
        return len(self.dt_s) * self.rows

    def whitened(
        self, bias_free: FloatArray, states: list[FloatArray]
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Whitened residual ``(n, m)``, d/d bias ``(n, m, k)``, d/d own state ``(n, m, 6)``."""
        bias = self.terms.full(bias_free)
        x = np.stack(states)[self.state_of_plot]  # (n, 6)
        p = x[:, :3] + x[:, 3:] * self.dt_s[:, None]
        enu = p @ self.a.T + self.c
        r, az, el = frames.enu_to_polar(enu)
        m = self.rows
        n = len(r)
        res = np.empty((n, m))
        res[:, 0] = self.measured[:, 0] - ((1.0 + bias[1]) * r + bias[0])
        res[:, 1] = frames.wrap_to_pi(self.measured[:, 1] - (az + bias[2]))
        d_polar = frames.enu_to_polar_jacobian(enu) @ self.a  # (n, 3, 3) d polar / d p
        d_polar[:, 0, :] *= 1.0 + bias[1]
        d_p = np.zeros((n, m, 3))
        d_p[:, :2] = -d_polar[:, :2]
        d_bias = np.zeros((n, m, 4))
        d_bias[:, :2] = -RadarMeasurementModel.bias_jacobian(r)[:, :2]
        if self.normal is None:
            res[:, 2] = self.measured[:, 2] - (el + bias[3])
            d_p[:, 2] = -d_polar[:, 2]
            d_bias[:, 2] = -RadarMeasurementModel.bias_jacobian(r)[:, 2]
        elif m == 3:
            height = self.height0 + np.einsum("ni,ni->n", self.normal, p - self.p0)
            res[:, 2] = self.measured[:, 2] - height
            d_p[:, 2] = -self.normal
        d_state = np.concatenate([d_p, d_p * self.dt_s[:, None, None]], axis=2)
        scale = 1.0 / self.sigmas
        return (
            res * scale,
            self.terms.select(d_bias) * scale[None, :, None],
            d_state * scale[None, :, None],
        )

    def error(self, values: list[FloatArray], want: bool, bias_is_variable: bool):
        if bias_is_variable:
            bias_free, states = values[0], values[1:]
        else:
            bias_free, states = np.zeros(0), values
        e, d_bias, d_state = self.whitened(bias_free, states)
        jac = [d_bias, d_state] if want else None
        e, jac = self.kernel.apply(e, jac)
        flat = e.reshape(-1)
        if jac is None:
            return flat, None
        blocks = [jac[0].reshape(flat.size, -1)] if bias_is_variable else []
        per_state = np.zeros((len(states), len(self.dt_s), self.rows, 6))
        per_state[self.state_of_plot, np.arange(len(self.dt_s))] = jac[1]
        blocks.extend(b.reshape(flat.size, 6) for b in per_state)
        return flat, blocks


@dataclass
class AdsbTrackFactor:
    """ADS-B reports of one aircraft against its nearest states (linear, robust)."""

    state_keys: list[int]
    state_of_report: NDArray[np.int64]
    dt_s: FloatArray
    position: FloatArray  # (n, 3) network ENU
    whitening: FloatArray  # (n, 3, 3)
    kernel: RobustKernel

    @property
    def dimension(self) -> int:
        return 3 * len(self.dt_s)

    def whitened(self, states: list[FloatArray]) -> tuple[FloatArray, FloatArray]:
        x = np.stack(states)[self.state_of_report]
        p = x[:, :3] + x[:, 3:] * self.dt_s[:, None]
        e = np.einsum("nij,nj->ni", self.whitening, p - self.position)
        d = np.concatenate([self.whitening, self.whitening * self.dt_s[:, None, None]], axis=2)
        return e, d

    def error(self, values: list[FloatArray], want: bool):
        e, d = self.whitened(values)
        e, jac = self.kernel.apply(e, [d] if want else None)
        flat = e.reshape(-1)
        if jac is None:
            return flat, None
        per_state = np.zeros((len(values), len(self.dt_s), 3, 6))
        per_state[self.state_of_report, np.arange(len(self.dt_s))] = jac[0]
        return flat, [b.reshape(flat.size, 6) for b in per_state]


# --------------------------------------------------------------------------- the problem
@dataclass
class TargetStateProblem:
    """States, motion factors and measurement factors of the target-state formulation."""

    frame: NetworkFrame
    state_keys: NDArray[np.int64]
    initial_states: FloatArray  # (N, 6)
    motion: list[tuple[int, int, FloatArray, FloatArray]]
    plot_factors: list[PlotFactor]
    adsb_factors: list[AdsbTrackFactor]
    n_aircraft: int
    radars_seen: set[str]
    n_plots: dict[str, int]
    process_noise_m2_s3: float
    state_spacing_s: float
    solution: object = field(default=None, repr=False)

    @property
    def dimension(self) -> int:
        return (
            sum(f.dimension for f in self.plot_factors)
            + sum(f.dimension for f in self.adsb_factors)
            + 6 * len(self.motion)
        )

    def add_to(self, fg: FactorGraph, variable: set[str], initial_free: dict) -> None:
        """Add states, motion factors, priors and measurement factors to ``fg``."""
        prior_sigmas = np.r_[np.full(3, 1e7), np.full(3, VELOCITY_PRIOR_SIGMA_MPS)]
        for key, x0 in zip(self.state_keys, self.initial_states, strict=True):
            fg.add_variable(int(key), x0)
            fg.add_prior(int(key), np.r_[x0[:3], np.zeros(3)], prior_sigmas)
        for k1, k2, a1, a2 in self.motion:
            fg.add_linear([k1, k2], [a1, a2], np.zeros(6))
        for f in self.plot_factors:
            is_var = f.terms.radar_id in variable
            keys = ([f.bias_key] if is_var else []) + f.state_keys
            fg.add_custom(keys, f.dimension, _bind_plot(f, is_var))
        for g in self.adsb_factors:
            fg.add_custom(g.state_keys, g.dimension, g.error)

    def summary(self) -> dict:
        return {
            "n_aircraft": self.n_aircraft,
            "n_states": int(len(self.state_keys)),
            "n_plot_factors": len(self.plot_factors),
            "n_adsb_factors": len(self.adsb_factors),
            "n_adsb_reports": int(sum(len(g.dt_s) for g in self.adsb_factors)),
            "process_noise_m2_s3": self.process_noise_m2_s3,
            "state_spacing_s": self.state_spacing_s,
        }

    def plots_per_radar(self) -> dict[str, int]:
        return dict(self.n_plots)

    def downweighted(self, bias_values: dict[str, FloatArray], result) -> dict[str, dict[str, int]]:
        """Plots and ADS-B reports with a final robust weight below 0.5, per radar."""
        out: dict[str, dict[str, int]] = {}
        for f in self.plot_factors:
            rid = f.terms.radar_id
            states = [result.vector(k) for k in f.state_keys]
            e, _, _ = f.whitened(bias_values.get(rid, np.zeros(0)), states)
            counts = out.setdefault(rid, {"plots": 0})
            counts["plots"] += int(f.kernel.downweighted(e).sum())
        n_adsb = 0
        for g in self.adsb_factors:
            e, _ = g.whitened([result.vector(k) for k in g.state_keys])
            n_adsb += int(g.kernel.downweighted(e).sum())
        for counts in out.values():
            counts["adsb_reports_all_radars"] = n_adsb
        return out


def _bind_plot(f: PlotFactor, is_var: bool):
    def error(values: list[FloatArray], want: bool):
        return f.error(values, want, is_var)

    return error


def motion_blocks(dt_s: float, q: float) -> tuple[FloatArray, FloatArray]:
    """Whitened blocks ``(A1, A2)`` of the constant-velocity factor ``A1 x1 + A2 x2``."""
    eye = np.eye(3)
    cov = q * np.block([[dt_s**3 / 3 * eye, dt_s**2 / 2 * eye], [dt_s**2 / 2 * eye, dt_s * eye]])
    whitening = np.linalg.inv(np.linalg.cholesky(cov))
    a1 = -np.block([[eye, dt_s * eye], [np.zeros((3, 3)), eye]])
    return whitening @ a1, whitening


def _cluster_times(times: FloatArray, spacing_s: float, max_gap_s: float):
    """State index of each (sorted) time, state times, and trajectory segment of each state."""
    state = np.zeros(len(times), dtype=np.int64)
    starts = [0]
    segment = [0]
    for i in range(1, len(times)):
        if times[i] - times[starts[-1]] > spacing_s:
            starts.append(i)
            segment.append(segment[-1] + (1 if times[i] - times[i - 1] > max_gap_s else 0))
        state[i] = len(starts) - 1
    sums = np.bincount(state, weights=times)
    counts = np.bincount(state)
    return state, sums / counts, np.array(segment)


def build_target_state(
    dataset: Dataset,
    terms: dict[str, RadarTerms],
    keys: dict[str, int],
    kernel: RobustKernel,
    *,
    use_adsb: bool,
    adsb_max_gap_s: float,
    process_noise_m2_s3: float | None = None,
    state_spacing_s: float = DEFAULT_STATE_SPACING_S,
    max_state_gap_s: float = DEFAULT_MAX_STATE_GAP_S,
    chunk: int = DEFAULT_CHUNK,
    initial_biases: dict | None = None,
    progress=None,
) -> TargetStateProblem:
    """Build trajectories and factors for every aircraft that links radars or ADS-B."""
    q = DEFAULT_PROCESS_NOISE_M2_S3 if process_noise_m2_s3 is None else process_noise_m2_s3
    if q <= 0:
        raise ValueError("process noise must be positive")
    sites = dataset.sites
    lat = float(np.mean([s.lat_rad for s in sites.values()]))
    lon = float(np.mean([s.lon_rad for s in sites.values()]))
    frame = NetworkFrame(lat, lon)
    # All usable plots, converted at zero bias for initial states.
    rows = []
    for rid in dataset.radar_ids:
        site = sites[rid]
        plots = plot_arrays(dataset, rid)
        ecef, _, usable = corrected_ecef(site, plots, np.zeros(4))
        keep = usable & (plots.target_id.astype(str) != "")
        if not np.any(keep):
            continue
        rows.append((rid, plots.subset(keep), frame.from_ecef(ecef[keep])))
    adsb_tracks = _adsb_by_target(dataset, frame) if use_adsb else {}
    by_target: dict[str, list[tuple[str, PlotArrays, FloatArray, NDArray[np.int64]]]] = {}
    for rid, plots, enu in rows:
        targets = plots.target_id.astype(str)
        for target, idx in pd.Series(np.arange(len(targets))).groupby(targets).indices.items():
            by_target.setdefault(str(target), []).append((rid, plots, enu, idx))
    state_keys: list[int] = []
    initial: list[FloatArray] = []
    motion: list[tuple[int, int, FloatArray, FloatArray]] = []
    plot_factors: list[PlotFactor] = []
    adsb_factors: list[AdsbTrackFactor] = []
    radars_seen: set[str] = set()
    n_plots: dict[str, int] = {}
    n_aircraft = 0
    radar_maps = {rid: frame.radar_map(sites[rid]) for rid in dataset.radar_ids}
    targets = sorted(by_target)
    for n_done, target in enumerate(targets):
        if progress is not None and (n_done % 50 == 0 or n_done == len(targets) - 1):
            progress("trajectories", n_done + 1, len(targets))
        parts = by_target[target]
        has_adsb = target in adsb_tracks
        if len({rid for rid, *_ in parts}) < 2 and not has_adsb:
            continue
        times = np.concatenate([p[1].time_s[p[3]] for p in parts])
        order = np.argsort(times, kind="stable")
        times = times[order]
        radar_of = np.concatenate([[i] * len(p[3]) for i, p in enumerate(parts)])[order]
        local = np.concatenate([p[3] for p in parts])[order]
        positions = np.concatenate([p[2][p[3]] for p in parts])[order]
        state_of, state_t, segment = _cluster_times(times, state_spacing_s, max_state_gap_s)
        n_states = len(state_t)
        base = len(state_keys)
        keys_here = [symbol("x", base + i) for i in range(n_states)]
        state_keys.extend(keys_here)
        # Initial states: mean converted position per cluster; velocity by differences.
        pos = np.zeros((n_states, 3))
        np.add.at(pos, state_of, positions)
        pos /= np.bincount(state_of, minlength=n_states)[:, None]
        vel = np.zeros((n_states, 3))
        for seg in np.unique(segment):
            idx = np.flatnonzero(segment == seg)
            if len(idx) > 1:
                vel[idx] = np.gradient(pos[idx], state_t[idx], axis=0)
        initial.extend(np.hstack([pos, vel]))
        for i in range(n_states - 1):
            if segment[i + 1] == segment[i]:
                a1, a2 = motion_blocks(state_t[i + 1] - state_t[i], q)
                motion.append((keys_here[i], keys_here[i + 1], a1, a2))
        # Plot factors, per radar, in chunks of consecutive plots.
        n_aircraft += 1
        for i, (rid, plots, _, _) in enumerate(parts):
            mine = np.flatnonzero(radar_of == i)
            site = sites[rid]
            radars_seen.add(rid)
            n_plots[rid] = n_plots.get(rid, 0) + len(mine)
            for start in range(0, len(mine), chunk):
                sel = mine[start:start + chunk]
                plot_factors.append(_plot_factor(
                    site, terms[rid], keys[rid], radar_maps[rid], plots, local[sel],
                    times[sel], state_of[sel], state_t, keys_here, positions[sel], frame, kernel,
                ))
        if has_adsb:
            t_a, p_a, w_a = adsb_tracks[target]
            nearest = np.clip(np.searchsorted(state_t, t_a), 1, max(n_states - 1, 1))
            if n_states > 1:
                left = nearest - 1
                nearest = np.where(
                    np.abs(t_a - state_t[left]) <= np.abs(t_a - state_t[nearest]), left, nearest
                )
            else:
                nearest = np.zeros(len(t_a), dtype=np.int64)
            dt = t_a - state_t[nearest]
            ok = np.abs(dt) <= MAX_ADSB_EXTRAPOLATION_S
            sel_all = np.flatnonzero(ok)
            for start in range(0, len(sel_all), chunk * 2):
                sel = sel_all[start:start + chunk * 2]
                used, local_state = np.unique(nearest[sel], return_inverse=True)
                adsb_factors.append(AdsbTrackFactor(
                    [keys_here[u] for u in used], local_state, dt[sel], p_a[sel], w_a[sel],
                    kernel,
                ))
    return TargetStateProblem(
        frame, np.array(state_keys, dtype=np.int64),
        np.array(initial) if initial else np.zeros((0, 6)), motion, plot_factors,
        adsb_factors, n_aircraft, radars_seen, n_plots, q, state_spacing_s,
    )


def _plot_factor(
    site: Site,
    terms: RadarTerms,
    bias_key: int,
    radar_map: tuple[FloatArray, FloatArray],
    plots: PlotArrays,
    local: NDArray[np.int64],
    times: FloatArray,
    state_of: NDArray[np.int64],
    state_t: FloatArray,
    keys_here: list[int],
    p0: FloatArray,
    frame: NetworkFrame,
    kernel: RobustKernel,
) -> PlotFactor:
    used, local_state = np.unique(state_of, return_inverse=True)
    measured = np.stack(
        [plots.range_m[local], plots.azimuth_rad[local], plots.elevation_rad[local]], axis=-1
    )
    normal = height0 = p0_used = None
    if site.is_3d:
        sigmas = np.array([site.sigma_range_m, site.sigma_azimuth_rad, site.sigma_elevation_rad])
    else:
        # Height of the state from the reported height, linearised at the plot's position.
        sigmas = np.array([site.sigma_range_m, site.sigma_azimuth_rad, ALTITUDE_SIGMA_M])
        measured[:, 2] = plots.altitude_m[local]
        ecef0 = frame.to_ecef(p0)
        lat, lon, height0 = frames.ecef_to_geodetic(ecef0)
        up_ecef = frames.ecef_to_enu_rotation(lat, lon)[..., 2, :]  # (n, 3)
        normal = up_ecef @ frame.rotation.T
        p0_used = p0
    return PlotFactor(
        terms, bias_key, [keys_here[u] for u in used], local_state,
        times - state_t[state_of], measured, sigmas, radar_map[0], radar_map[1],
        normal, height0, p0_used, kernel,
    )


def _adsb_by_target(
    dataset: Dataset, frame: NetworkFrame
) -> dict[str, tuple[FloatArray, FloatArray, FloatArray]]:
    """ADS-B per aircraft: times, network-ENU positions and whitening matrices."""
    adsb = dataset.adsb
    lat = np.deg2rad(adsb["lat_deg"].to_numpy(float))
    lon = np.deg2rad(adsb["lon_deg"].to_numpy(float))
    ecef = frames.geodetic_to_ecef(lat, lon, adsb["alt_m"].to_numpy(float))
    enu = frame.from_ecef(ecef)
    sigma = adsb["sigma_m"].to_numpy(float)
    # Local ENU (at the report) covariance rotated into the network frame.
    rot = frames.ecef_to_enu_rotation(lat, lon) @ frame.rotation.T  # local ENU <- network ENU
    scale = np.stack([sigma, sigma, ADSB_VERTICAL_SIGMA_RATIO * sigma], axis=1)
    whitening = rot / scale[:, :, None]  # diag(1/s) @ R
    times = adsb["time_s"].to_numpy(float)
    out = {}
    for target, idx in adsb.groupby("target_id", sort=False).indices.items():
        if not target:
            continue
        idx = idx[np.argsort(times[idx], kind="stable")]
        out[str(target)] = (times[idx], enu[idx], whitening[idx])
    return out
