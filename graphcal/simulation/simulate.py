"""Simulate a radar network and ADS-B from a scenario: scenario + Generator -> Dataset + truth.

Radar plots follow each antenna's sweep.  The beam turns clockwise at
``omega = 2 pi / scan_period`` from ``antenna_phase`` at time 0, so its azimuth
is ``beta(t) = phase + omega t``.  A target is hit when the beam passes its true
azimuth ``alpha(t)``: ``g(t) = phase + omega t - alpha(t) = 2 pi m`` for an
integer ``m``.  ``g`` increases (the beam turns faster than any aircraft moves
across it), so each ``m`` gives one hit: the simulator samples ``g`` on a grid
of a quarter of the shortest scan period, brackets every multiple of ``2 pi``,
and refines the time by the fixed-point iteration
``t <- t + (2 pi m - g(t)) / omega`` (it contracts by ``|alpha'| / omega``, so
two or three steps reach micro-second accuracy; it runs to 1e-9 s).

At each hit the true position (WGS-84, straight line of sight) gives the true
polar coordinates; the target is in coverage when within ``max_range_m``, above
``min_elevation_deg`` and, unless the radar's ``horizon_check`` is off, when the
line of sight clears the Earth (:func:`earth_blocks`); it is then detected with
the radar's probability.  The
plot is :func:`graphcal.data.bias.apply_bias` of the true polar coordinates plus
Gaussian noise, azimuth wrapped to ``[0, 360)`` deg; 2-D radars write NaN
elevation.  The reported time is the true time plus ``time_offset_s``.
``altitude_m`` is the true height above the ellipsoid plus Gaussian noise,
quantised (Mode C style); with ``[dataset] plot_altitude = "pressure"`` the
height is first turned into its pressure altitude by the scenario's true height
model (:meth:`graphcal.data.height.HeightModel.pressure`,
``p = (h - height_offset_m) / (1 + height_scale)``).

A radar with ``refraction = "exponential"`` (contract v2) sees its targets
along rays refracted by its atmosphere (:func:`graphcal.core.refraction.refracted_ray`):
the true polar coordinates are then the ray's electrical length, the
straight-line azimuth and the ray's apparent elevation at the antenna, the
biases and noise apply on top as above, and the coverage tests use them
(``max_range_m`` the electrical length, ``min_elevation_deg`` the apparent
elevation, the horizon the ray's lowest point, which sees beyond the straight
line's horizon).  ``altitude_m`` stays the geometric height.  Without
refraction nothing changes: the same scenario and seed give the same files as
before.

ADS-B reports come every ``period_s`` from a random phase per aircraft, with
Gaussian noise per axis in the ENU frame at the aircraft, optional outliers and
dropouts.  With ``equipped_fraction < 1`` only a random subset of the aircraft
broadcasts (:func:`adsb_equipage`).  When the scenario simulates pressure
altitudes, each report also carries ``baro_alt_m``: the pressure altitude of the
true height, quantised to 25 ft (no random draw, so the random stream is that
of the same scenario without it).

Contract v3 adds what a plot tells of its aircraft.  A radar's ``identity`` is
``"mode_s"`` (the address as ``target_id``), ``"mode_ac"`` (no address; the
Mode 3/A code and the Mode C altitude) or ``"psr"`` (no address, no code, no
altitude); a radar with ``track_numbers`` numbers its tracks
(:class:`TrackNumbers`); ``clutter_per_scan`` adds false plots
(:func:`clutter_plots`).  Mode 3/A codes (:func:`draw_mode_3a_codes`) are
simulated with a ``[mode_3a]`` table or a ``"mode_ac"`` radar; plots and ADS-B
reports then carry ``mode_3a``.  :attr:`SimulationResult.plot_truth` says for
every plot which aircraft made it (``truth_target_id``, ``"clutter"`` for a
false plot).

Every random number is drawn from the one :class:`numpy.random.Generator`
passed in, in a fixed order (traffic, antenna phases, radars in file order,
ADS-B: equipage when ``equipped_fraction < 1``, then phases and noise; then, only
when the scenario asks for them, the Mode 3/A codes and each radar's clutter in
file order), so one seed reproduces a dataset exactly, and a scenario without
the contract v3 keys draws exactly what it drew before them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray

from graphcal.core import frames
from graphcal.core.errors import ScenarioError
from graphcal.core.refraction import Atmosphere, refracted_ray
from graphcal.data.bias import (
    CONTRACT_KEYS,
    ECCENTRICITY_NAMES,
    PARAMETER_NAMES,
    RadarBias,
    apply_bias,
)
from graphcal.data.dataset import PLOT_COLUMNS, Dataset
from graphcal.data.height import HeightModel
from graphcal.io.folder import write_dataset
from graphcal.simulation.chunks import TimeSpan, chunk_edges, true_span
from graphcal.simulation.scenario import AdsbSpec, Mode3aSpec, RadarSpec, Scenario
from graphcal.simulation.trajectories import (
    ReplayStats,
    Trajectory,
    generate_traffic,
    replay_opensky,
)

Array = NDArray[np.float64]

#: ``progress(stage, done, total)``: called after each step of a simulation.
ProgressCallback = Callable[[str, int, int], None]

#: Convergence tolerance of the beam-crossing time [s].
CROSSING_TOLERANCE_S = 1e-9
#: Maximum fixed-point iterations per beam crossing.
CROSSING_MAX_ITER = 30

#: ``truth_target_id`` of a false plot (clutter).
CLUTTER = "clutter"
#: Scans a radar keeps a track without a plot: a longer gap starts a new track number.
TRACK_COAST_SCANS = 3
#: Track numbers wrap modulo this (12 bits, ASTERIX I048/161).
TRACK_NUMBER_MODULUS = 4096
#: Upper edge [deg] of the elevations of a 3-D radar's clutter (drawn uniformly from
#: the radar's ``min_elevation_deg`` up to this).
CLUTTER_MAX_ELEVATION_DEG = 20.0
#: Mode 3/A codes never given as discrete codes: 0000, VFR 1200 and 7000, 2000,
#: the emergency codes 7500, 7600, 7700, and 7777.
SPECIAL_CODES: tuple[int, ...] = (0o0000, 0o1200, 0o2000, 0o7000, 0o7500, 0o7600, 0o7700,
                                  0o7777)
#: Number of Mode 3/A codes (4 octal digits).
N_CODES = 4096

_OCTAL = np.array([f"{code:04o}" for code in range(N_CODES)], dtype=object)

_TRUTH_COLUMNS = (
    "time_true_s",
    "x_m",
    "y_m",
    "z_m",
    "range_true_m",
    "azimuth_true_deg",
    "elevation_true_deg",
    "height_true_m",
    "truth_target_id",
)


@dataclass
class SimulationResult:
    """A simulated dataset and the truth behind it.

    Attributes
    ----------
    scenario : Scenario
        The scenario simulated.
    dataset : Dataset
        Sites, plots (contract columns, sorted by time) and ADS-B (``None``
        when ADS-B is off or produced no report).
    biases : dict of str to RadarBias
        True biases per radar.
    plot_truth : pandas.DataFrame
        One row per plot, same order as ``dataset.plots``: ``time_true_s``,
        true ECEF position ``x_m, y_m, z_m``, true ``range_true_m``,
        ``azimuth_true_deg``, ``elevation_true_deg`` and ``height_true_m``, and
        ``truth_target_id``: the address of the aircraft that made the plot, or
        :data:`CLUTTER` for a false plot (whose other truth columns are NaN but
        ``time_true_s``).  For a refracted radar the true range and elevation are
        the contract's: the electrical length and the apparent elevation.
    adsb_truth : pandas.DataFrame or None
        One row per ADS-B report, same order: ``x_m, y_m, z_m`` true ECEF
        position and ``outlier`` (bool).
    trajectories : list of Trajectory
        Every simulated flight.
    antenna_phase_rad : dict of str to float
        Beam azimuth at time 0 of each radar [rad].
    replay_stats : ReplayStats or None
        Cleaning statistics of an ``[opensky]`` replay.
    n_candidates : dict of str to int
        Per radar, the beam hits in coverage before the detection draw (the
        plots are a Bernoulli thinning of them).
    adsb_equipped : tuple of str
        Addresses of the aircraft that broadcast ADS-B, in the order of
        ``trajectories`` (every aircraft unless ``[adsb] equipped_fraction`` is
        below 1; empty when ADS-B is off).  An equipped aircraft can still
        have no report (dropouts, or no report time inside the scenario).
    mode_3a : Mode3aCodes or None
        The aircraft's Mode 3/A codes, ``None`` when the scenario simulates none.
    n_clutter : dict of str to int
        Per radar, the false plots among its plots.
    """

    scenario: Scenario
    dataset: Dataset
    biases: dict[str, RadarBias]
    plot_truth: pd.DataFrame
    adsb_truth: pd.DataFrame | None
    trajectories: list[Trajectory]
    antenna_phase_rad: dict[str, float]
    replay_stats: ReplayStats | None = None
    n_candidates: dict[str, int] = field(default_factory=dict)
    adsb_equipped: tuple[str, ...] = ()
    mode_3a: Mode3aCodes | None = None
    n_clutter: dict[str, int] = field(default_factory=dict)

    @property
    def truth(self) -> dict[str, RadarBias]:
        """The true biases per radar (the same as :attr:`biases`)."""
        return self.biases

    def n_plots(self) -> dict[str, int]:
        """Number of plots per radar."""
        counts = self.dataset.plots["radar_id"].value_counts()
        return {rid: int(counts.get(rid, 0)) for rid in self.dataset.sites}


# --------------------------------------------------------------------------- trajectories


def build_trajectories(
    scenario: Scenario, rng: np.random.Generator
) -> tuple[list[Trajectory], ReplayStats | None]:
    """All flights of a scenario: explicit aircraft, random traffic, replayed tracks.

    Raises
    ------
    ScenarioError
        If the ``[opensky]`` file cannot be read.
    """
    flights: list[Trajectory] = list(scenario.aircraft)
    stats = None
    if scenario.traffic is not None and scenario.origin is not None:
        taken = {f.target_id for f in flights}
        flights += generate_traffic(
            scenario.traffic, scenario.origin, scenario.duration_s, rng, taken
        )
    if scenario.opensky is not None:
        try:
            replayed, stats = replay_opensky(scenario.opensky)
        except FileNotFoundError:
            raise ScenarioError(
                f"OpenSky table not found: {scenario.opensky.file}",
                path=scenario.path,
                field="opensky.file",
            ) from None
        except (OSError, ValueError) as exc:
            raise ScenarioError(
                f"cannot use OpenSky table {scenario.opensky.file}: {exc}",
                path=scenario.path,
                field="opensky.file",
            ) from None
        taken = {f.target_id for f in flights}
        flights += [f for f in replayed if f.target_id not in taken]
    return flights, stats


# --------------------------------------------------------------------------- sweep


def _azimuth(radar_ecef: Array, rotation: Array, positions: Array) -> Array:
    """True azimuth [rad] of ECEF positions from a radar (``rotation``: ECEF -> ENU)."""
    enu = (positions - radar_ecef) @ rotation.T
    return np.arctan2(enu[..., 0], enu[..., 1])


def beam_crossings(
    trajectory: Trajectory,
    radar_ecef_m: Array,
    ecef_to_enu: Array,
    scan_period_s: float,
    antenna_phase_rad: float,
    t_begin: float,
    t_end: float,
    grid_step_s: float | None = None,
) -> Array:
    """Times [s] at which a clockwise-turning beam passes a moving target's azimuth.

    Parameters
    ----------
    trajectory : Trajectory
        The target.
    radar_ecef_m : ndarray, shape (3,)
        Antenna position [m].
    ecef_to_enu : ndarray, shape (3, 3)
        Rotation ECEF -> the radar's ENU frame.
    scan_period_s : float
        Antenna rotation period [s].
    antenna_phase_rad : float
        Beam azimuth at time 0 [rad].
    t_begin, t_end : float
        Time window [s].
    grid_step_s : float, optional
        Bracketing grid step [s]; default a quarter of the scan period.

    Returns
    -------
    ndarray
        Sorted crossing times within the window and the trajectory's segments.
    """
    omega = 2.0 * np.pi / scan_period_s
    step = scan_period_s / 4.0 if grid_step_s is None else grid_step_s
    out = []
    for seg0, seg1 in trajectory.segments():
        a, b = max(seg0, t_begin), min(seg1, t_end)
        if not b > a:
            continue
        n = max(int(math.ceil((b - a) / step)), 1)
        grid = np.linspace(a, b, n + 1)
        pos = trajectory.position_ecef(grid)
        alpha = np.unwrap(_azimuth(radar_ecef_m, ecef_to_enu, pos))
        g = antenna_phase_rad + omega * grid - alpha
        g = np.maximum.accumulate(g)  # guards the rare non-monotonic step near the zenith
        m = np.arange(math.ceil(g[0] / (2 * np.pi)), math.floor(g[-1] / (2 * np.pi)) + 1)
        if m.size == 0:
            continue
        level = 2.0 * np.pi * m
        t = np.interp(level, g, grid)
        alpha_ref = np.interp(t, grid, alpha)
        for _ in range(CROSSING_MAX_ITER):
            az = _azimuth(radar_ecef_m, ecef_to_enu, trajectory.position_ecef(t))
            alpha_t = alpha_ref + frames.wrap_to_pi(az - alpha_ref)
            dt = (level - (antenna_phase_rad + omega * t - alpha_t)) / omega
            t = t + dt
            alpha_ref = alpha_t
            # NaN: the iterate left the segment; such a crossing is dropped below.
            if np.all((np.abs(dt) < CROSSING_TOLERANCE_S) | np.isnan(dt)):
                break
        keep = (t >= a) & (t <= b) & (np.abs(dt) < 1e-6)
        out.append(t[keep])
    if not out:
        return np.empty(0)
    return np.sort(np.concatenate(out))


# --------------------------------------------------------------------------- radar plots


def earth_blocks(enu_m: Array, lat_rad: float, alt_m: float) -> NDArray[np.bool_]:
    """True where the straight line from the antenna to an ENU point passes below the Earth.

    The Earth is the sphere of the local Gaussian radius of curvature ``R`` at
    the radar (within metres of the ellipsoid over a radar's coverage), centred
    at ``(0, 0, -(R + alt_m))`` in the radar's ENU frame.  The segment ``s v``,
    ``0 <= s <= 1``, comes closest to the centre ``c`` at
    ``s* = clip(v.c / |v|^2, 0, 1)``; it is blocked when ``|s* v - c| < R``.
    Targets above the antenna's horizontal plane are never blocked.

    Parameters
    ----------
    enu_m : ndarray, shape (n, 3)
        Target positions in the radar's ENU frame [m].
    lat_rad : float
        Radar latitude [rad].
    alt_m : float
        Antenna height above the ellipsoid [m].
    """
    enu = np.asarray(enu_m, dtype=float)
    radius = frames.gaussian_radius_m(lat_rad)
    centre = np.array([0.0, 0.0, -(radius + alt_m)])
    norm2 = np.einsum("ij,ij->i", enu, enu)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.clip((enu @ centre) / norm2, 0.0, 1.0)
    s = np.where(norm2 > 0, s, 0.0)
    closest = np.linalg.norm(s[:, None] * enu - centre, axis=1)
    return closest < radius


def refracted_coverage(
    radar: RadarSpec, atmosphere: Atmosphere, enu_m: Array
) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
    """Refracted true polar coordinates of ENU targets and whether the radar covers them.

    Returns the electrical range [m], azimuth [rad] and apparent elevation [rad]
    (:func:`graphcal.core.refraction.refracted_ray`) and a mask: within
    ``max_range_m`` (electrical), at or above ``min_elevation_rad`` (apparent)
    and, with ``horizon_check``, on a ray that stays above the Earth (its
    lowest height at least 0).  Targets the ray solver leaves unsolved (deep
    below the horizon) are not covered.
    """
    ray = refracted_ray(atmosphere, radar.lat_rad, radar.alt_m, enu_m)
    with np.errstate(invalid="ignore"):
        covered = (np.isfinite(ray.range_m) & (ray.range_m <= radar.max_range_m)
                   & (ray.elevation_rad >= radar.min_elevation_rad))
        if radar.horizon_check:
            covered &= ray.lowest_height_m >= 0.0
    return ray.range_m, ray.azimuth_rad, ray.elevation_rad, covered


def _antenna_phases(scenario: Scenario, rng: np.random.Generator) -> dict[str, float]:
    """Beam azimuth at time 0 per radar: configured, else uniform from ``rng``."""
    draws = rng.uniform(0.0, 2.0 * np.pi, size=len(scenario.radars))
    return {
        r.id: (float(draws[i]) if r.antenna_phase_rad is None else r.antenna_phase_rad)
        for i, r in enumerate(scenario.radars)
    }


def _radar_plots(
    radar: RadarSpec,
    phase: float,
    flights: list[Trajectory],
    span: TimeSpan,
    rng: np.random.Generator,
    pressure: HeightModel | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame, int]:
    """Plots of one radar whose true times fall in ``span``, their truth, and the in-coverage hits.

    ``pressure``: report the pressure altitude of the true height through this
    height model instead of the height itself.
    """
    site = radar.site()
    radar_ecef, rotation = site.ecef_m, site.ecef_to_enu
    times, ids = [], []
    for flight in flights:
        t = span.keep(beam_crossings(
            flight, radar_ecef, rotation, radar.scan_period_s, phase, span.t0_s, span.t1_s
        ))
        times.append(t)
        ids.append(np.full(t.size, flight.target_id, dtype=object))
    positions = [f.position_ecef(t) for f, t in zip(flights, times, strict=True) if t.size]
    t_true = np.concatenate(times) if times else np.empty(0)
    target = np.concatenate(ids) if ids else np.empty(0, dtype=object)
    pos = np.concatenate(positions) if positions else np.empty((0, 3))
    order = np.argsort(t_true, kind="stable")
    t_true, target, pos = t_true[order], target[order], pos[order]
    atmosphere = site.atmosphere
    if atmosphere is None:
        rng_m, az, el = frames.enu_to_polar((pos - radar_ecef) @ rotation.T)
        covered = (rng_m <= radar.max_range_m) & (el >= radar.min_elevation_rad)
        if radar.horizon_check:
            covered &= ~earth_blocks((pos - radar_ecef) @ rotation.T, radar.lat_rad, radar.alt_m)
    else:
        rng_m, az, el, covered = refracted_coverage(
            radar, atmosphere, (pos - radar_ecef) @ rotation.T)
    t_true, target, pos = t_true[covered], target[covered], pos[covered]
    rng_m, az, el = rng_m[covered], az[covered], el[covered]
    n = t_true.size
    # Fixed draw shapes, independent of which hits are detected.
    detect_u = rng.uniform(size=n)
    noise = rng.standard_normal(size=(n, 3))
    alt_noise = rng.standard_normal(size=n)
    detected = detect_u < radar.detection_probability
    schedule = radar.schedule
    bias = radar.bias if schedule.constant else RadarBias(**schedule.at(t_true))
    r_meas, az_meas, el_meas = apply_bias(rng_m, az, el, bias)
    r_meas = r_meas + radar.sigma_range_m * noise[:, 0]
    az_meas = frames.wrap_to_2pi(az_meas + radar.sigma_azimuth_rad * noise[:, 1])
    if radar.sigma_elevation_rad is None:
        el_meas = np.full(n, np.nan)
    else:
        el_meas = el_meas + radar.sigma_elevation_rad * noise[:, 2]
    height = frames.ecef_to_geodetic(pos)[2]
    reported = height if pressure is None else pressure.pressure(height)
    altitude = reported + radar.altitude_sigma_m * alt_noise
    if radar.altitude_quantum_m > 0:
        altitude = np.round(altitude / radar.altitude_quantum_m) * radar.altitude_quantum_m
    az_deg = np.degrees(az_meas)
    az_deg = np.where(az_deg >= 360.0, 0.0, az_deg)
    plots = pd.DataFrame(
        {
            "radar_id": np.full(n, radar.id, dtype=object),
            "time_s": t_true + radar.bias.time_offset_s,
            "range_m": r_meas,
            "azimuth_deg": az_deg,
            "elevation_deg": np.degrees(el_meas),
            "target_id": target,
            "altitude_m": altitude,
        }
    )[detected]
    truth = pd.DataFrame(
        {
            "time_true_s": t_true,
            "x_m": pos[:, 0],
            "y_m": pos[:, 1],
            "z_m": pos[:, 2],
            "range_true_m": rng_m,
            "azimuth_true_deg": np.degrees(az),
            "elevation_true_deg": np.degrees(el),
            "height_true_m": height,
            "truth_target_id": target,
        }
    )[detected]
    return plots, truth, n


# --------------------------------------------------------------------------- ADS-B


def adsb_equipage(
    equipped_fraction: float, n_flights: int, rng: np.random.Generator
) -> NDArray[np.bool_]:
    """Which of ``n_flights`` aircraft broadcast ADS-B (boolean mask).

    ``round(equipped_fraction * n_flights)`` aircraft (halves round up) are
    drawn without replacement.  A fraction of 1 equips every aircraft and
    draws nothing from ``rng``, so scenarios without the key keep their
    random stream.
    """
    if equipped_fraction >= 1.0:
        return np.ones(n_flights, dtype=bool)
    n_equipped = min(int(math.floor(equipped_fraction * n_flights + 0.5)), n_flights)
    mask = np.zeros(n_flights, dtype=bool)
    mask[rng.choice(n_flights, size=n_equipped, replace=False)] = True
    return mask


def _adsb_schedule(
    spec: AdsbSpec, flights: list[Trajectory], rng: np.random.Generator
) -> tuple[NDArray[np.bool_], Array]:
    """Which flights broadcast ADS-B and the phase of each flight's reports [s]."""
    equipped = adsb_equipage(spec.equipped_fraction, len(flights), rng)
    # One phase per flight, equipped or not: fixed draw shapes.
    phases = rng.uniform(0.0, spec.period_s, size=len(flights))
    return equipped, phases


def _adsb_reports(
    spec: AdsbSpec, flights: list[Trajectory], equipped: NDArray[np.bool_], phases: Array,
    span: TimeSpan, rng: np.random.Generator, baro: HeightModel | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """ADS-B reports of the equipped flights whose times fall in ``span``, and their truth.

    ``baro``: add ``baro_alt_m``, the pressure altitude of the true height through this
    height model, quantised to ``spec.baro_quantum_m``.
    """
    times, ids, positions = [], [], []
    for flight, phase, has_adsb in zip(flights, phases, equipped, strict=True):
        if not has_adsb:
            continue
        for seg0, seg1 in flight.segments():
            a, b = max(seg0, span.t0_s), min(seg1, span.t1_s)
            if not b >= a:
                continue
            k0 = math.ceil((a - phase) / spec.period_s)
            k1 = math.floor((b - phase) / spec.period_s)
            if k1 < k0:
                continue
            t = span.keep(phase + spec.period_s * np.arange(k0, k1 + 1))
            times.append(t)
            ids.append(np.full(t.size, flight.target_id, dtype=object))
            positions.append(flight.position_ecef(t))
    t = np.concatenate(times) if times else np.empty(0)
    target = np.concatenate(ids) if ids else np.empty(0, dtype=object)
    pos = np.concatenate(positions) if positions else np.empty((0, 3))
    order = np.lexsort((target.astype(str), t)) if t.size else np.empty(0, dtype=int)
    t, target, pos = t[order], target[order], pos[order]
    n = t.size
    keep_u = rng.uniform(size=n)
    noise = rng.standard_normal(size=(n, 3))
    outlier_u = rng.uniform(size=n)
    outlier_dir = rng.uniform(0.0, 2.0 * np.pi, size=n)
    lat, lon, _ = frames.ecef_to_geodetic(pos)
    sigma_h, sigma_v = spec.horizontal_sigma_m, spec.vertical_sigma_m
    enu = np.column_stack([sigma_h * noise[:, 0], sigma_h * noise[:, 1], sigma_v * noise[:, 2]])
    outlier = outlier_u < spec.outlier_fraction
    enu[:, 0] += np.where(outlier, spec.outlier_distance_m * np.sin(outlier_dir), 0.0)
    enu[:, 1] += np.where(outlier, spec.outlier_distance_m * np.cos(outlier_dir), 0.0)
    rot = frames.ecef_to_enu_rotation(lat, lon)  # (n, 3, 3), rows E, N, U
    reported = pos + np.einsum("nij,ni->nj", rot, enu)
    r_lat, r_lon, r_alt = frames.ecef_to_geodetic(reported)
    kept = keep_u >= spec.dropout_probability
    columns: dict[str, object] = {
        "time_s": t,
        "target_id": target,
        "lat_deg": np.degrees(r_lat),
        "lon_deg": np.degrees(r_lon),
        "alt_m": r_alt,
        "sigma_m": np.full(n, sigma_h),
    }
    if spec.nacp is not None:
        columns["nacp"] = np.full(n, spec.nacp, dtype=np.int64)
    if baro is not None:
        pressure = baro.pressure(frames.ecef_to_geodetic(pos)[2])
        if spec.baro_quantum_m > 0:
            pressure = np.round(pressure / spec.baro_quantum_m) * spec.baro_quantum_m
        columns["baro_alt_m"] = pressure
    reports = pd.DataFrame(columns)[kept].reset_index(drop=True)
    truth = pd.DataFrame(
        {"x_m": pos[:, 0], "y_m": pos[:, 1], "z_m": pos[:, 2], "outlier": outlier}
    )[kept].reset_index(drop=True)
    return reports, truth


# --------------------------------------------------------------------------- identity (v3)


def _share(fraction: float, n: int, rng: np.random.Generator) -> NDArray[np.bool_]:
    """A mask of ``round(fraction * n)`` (halves up) of ``n`` items, drawn without replacement.

    Draws one permutation of ``n`` whatever the fraction (fixed draw shapes).
    """
    order = rng.permutation(n)
    mask = np.zeros(n, dtype=bool)
    mask[order[:min(int(math.floor(fraction * n + 0.5)), n)]] = True
    return mask


def mode_3a_strings(codes: ArrayLike) -> NDArray[np.object_]:
    """Mode 3/A codes (integers 0-4095) as 4 octal digits (``0o413`` -> ``"0413"``)."""
    return _OCTAL[np.asarray(codes, dtype=np.int64)]


@dataclass(frozen=True)
class Mode3aCodes:
    """The Mode 3/A codes of the simulated aircraft (:func:`draw_mode_3a_codes`).

    Attributes
    ----------
    target_ids : tuple of str
        The aircraft's addresses, in the order of the simulation's trajectories.
    first_code : ndarray of int
        Each aircraft's code from its start (an integer, 0-4095; ``mode_3a_strings``
        writes it).
    change_time_s : ndarray of float
        True time [s] at which the code becomes ``second_code``; NaN: no change.
    second_code : ndarray of int
        The code after the change (drawn for every aircraft, used by those that change).
    vfr : ndarray of bool
        The aircraft that start with the VFR code.
    """

    target_ids: tuple[str, ...]
    first_code: NDArray[np.int64]
    change_time_s: Array
    second_code: NDArray[np.int64]
    vfr: NDArray[np.bool_]

    def at(self, target_id: ArrayLike, time_s: ArrayLike) -> NDArray[np.object_]:
        """The codes of aircraft ``target_id`` at true times ``time_s`` [s], as strings of 4
        octal digits; ``""`` for an address that is not one of :attr:`target_ids`."""
        index = pd.Index(self.target_ids).get_indexer(np.asarray(target_id, dtype=object))
        time = np.asarray(time_s, dtype=float)
        known = index >= 0
        which = np.where(known, index, 0)
        if not self.target_ids:
            return np.full(index.size, "", dtype=object)
        changed = time >= self.change_time_s[which]  # NaN: never
        codes = np.where(changed, self.second_code[which], self.first_code[which])
        return np.where(known, mode_3a_strings(codes), "").astype(object)


def draw_mode_3a_codes(
    spec: Mode3aSpec, flights: list[Trajectory], duration_s: float, rng: np.random.Generator
) -> Mode3aCodes:
    """Every aircraft's Mode 3/A code, drawn from ``rng``.

    Two discrete codes per aircraft (its first one and the one it may change to)
    are drawn without replacement from the codes that are not
    :data:`SPECIAL_CODES` nor the VFR code (with replacement when the aircraft
    outnumber them); then the VFR aircraft (:attr:`Mode3aSpec.vfr_fraction`) and
    those whose code changes (:attr:`Mode3aSpec.code_changes`, each a permutation
    of the aircraft), and a change time per aircraft, uniform within its flight
    clipped to ``[0, duration_s]`` [s].

    Parameters
    ----------
    spec : Mode3aSpec
        The ``[mode_3a]`` settings.
    flights : list of Trajectory
        The aircraft.
    duration_s : float
        The scenario's duration [s].
    rng : numpy.random.Generator
        The simulation's generator.

    Returns
    -------
    Mode3aCodes
    """
    n = len(flights)
    special = {*SPECIAL_CODES, spec.vfr_code}
    pool = np.array([c for c in range(N_CODES) if c not in special], dtype=np.int64)
    drawn = rng.choice(pool, size=2 * n, replace=2 * n > pool.size)
    vfr = _share(spec.vfr_fraction, n, rng)
    changes = _share(spec.code_changes, n, rng)
    u = rng.uniform(size=n)
    start = np.clip(np.array([f.start_s for f in flights], dtype=float), 0.0, duration_s)
    end = np.clip(np.array([f.end_s for f in flights], dtype=float), start, duration_s)
    return Mode3aCodes(
        target_ids=tuple(f.target_id for f in flights),
        first_code=np.where(vfr, spec.vfr_code, drawn[:n]).astype(np.int64),
        change_time_s=np.where(changes, start + u * (end - start), np.nan),
        second_code=drawn[n:].astype(np.int64),
        vfr=vfr,
    )


class TrackNumbers:
    """A radar's track numbers, carried from one chunk of plots to the next.

    Each aircraft the radar plots is one track with one number while the radar
    keeps seeing it; when the gap to its previous plot exceeds
    ``(coast_scans + 1.5)`` scan periods (more than ``coast_scans`` scans
    missed), the next plot starts a new track with a new number.  New tracks take
    consecutive numbers in the order of their first plot, from 0, modulo
    :data:`TRACK_NUMBER_MODULUS` (12 bits).  No random number is drawn.

    Parameters
    ----------
    scan_period_s : float
        The radar's scan period [s].
    coast_scans : int, optional
        Scans a track survives without a plot.
    """

    def __init__(self, scan_period_s: float, coast_scans: int = TRACK_COAST_SCANS) -> None:
        self.max_gap_s = (coast_scans + 1.5) * scan_period_s
        self.next_number = 0
        self._last_time: dict[str, float] = {}
        self._last_number: dict[str, int] = {}

    def number(self, target_id: ArrayLike, time_s: ArrayLike) -> pd.api.extensions.ExtensionArray:
        """Track numbers of the radar's next plots (aircraft ``target_id`` at true times
        ``time_s`` [s], after every plot numbered before), as a pandas ``Int64`` array."""
        target = np.asarray(target_id, dtype=object)
        time = np.asarray(time_s, dtype=float)
        n = target.size
        if n == 0:
            return pd.array(np.empty(0, dtype=np.int64), dtype="Int64")
        codes, uniques = pd.factorize(target)
        order = np.lexsort((time, codes))
        c, t = codes[order], time[order]
        first = np.ones(n, dtype=bool)
        first[1:] = c[1:] != c[:-1]
        last_time = np.array([self._last_time.get(u, -np.inf) for u in uniques])
        last_number = np.array([self._last_number.get(u, -1) for u in uniques], dtype=np.int64)
        previous = np.empty(n)
        previous[1:] = t[:-1]
        previous[first] = last_time[c[first]]
        new = t - previous > self.max_gap_s
        number = np.full(n, -1, dtype=np.int64)
        starts = np.flatnonzero(new)
        starts = starts[np.argsort(t[starts], kind="stable")]
        number[starts] = (self.next_number + np.arange(starts.size)) % TRACK_NUMBER_MODULUS
        self.next_number = (self.next_number + starts.size) % TRACK_NUMBER_MODULUS
        carried = first & ~new
        number[carried] = last_number[c[carried]]
        # Every group starts with a number: fill each row with its group's latest one.
        number = number[np.maximum.accumulate(np.where(number >= 0, np.arange(n), 0))]
        last = np.ones(n, dtype=bool)
        last[:-1] = c[:-1] != c[1:]
        for code, when, value in zip(c[last], t[last], number[last], strict=True):
            self._last_time[uniques[code]] = float(when)
            self._last_number[uniques[code]] = int(value)
        out = np.empty(n, dtype=np.int64)
        out[order] = number
        return pd.array(out, dtype="Int64")


def clutter_plots(
    radar: RadarSpec, phase: float, span: TimeSpan, rng: np.random.Generator
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """False plots of one radar whose true times fall in ``span``, and their truth.

    Their number is Poisson with mean ``clutter_per_scan`` times the scans in the
    span; each has a uniform true time in the span, the beam's azimuth at that
    time (so the azimuths are uniform), a range uniform in ``(0, max_range_m]``
    and, for a 3-D radar, an elevation uniform from ``min_elevation_deg`` to
    :data:`CLUTTER_MAX_ELEVATION_DEG`.  They carry no ``target_id``, no
    ``mode_3a``, no altitude and no ``track_number``; their ``truth_target_id``
    is :data:`CLUTTER` and their other truth columns NaN but ``time_true_s``.

    Parameters
    ----------
    radar : RadarSpec
        The radar (its ``max_range_m`` finite).
    phase : float
        Beam azimuth at time 0 [rad].
    span : TimeSpan
        True times [s].
    rng : numpy.random.Generator
        The simulation's generator.

    Returns
    -------
    plots, truth : pandas.DataFrame
        Sorted by time; the plot columns with ``mode_3a`` and ``track_number``.
    """
    length = max(span.t1_s - span.t0_s, 0.0)
    n = int(rng.poisson(radar.clutter_per_scan * length / radar.scan_period_s))
    t_true = np.sort(span.t0_s + length * rng.uniform(size=n))
    range_m = radar.max_range_m * (1.0 - rng.uniform(size=n))
    if radar.is_3d:
        low = math.degrees(radar.min_elevation_rad)
        elevation_deg = rng.uniform(low, max(low, CLUTTER_MAX_ELEVATION_DEG), size=n)
    else:
        elevation_deg = np.full(n, np.nan)
    azimuth = frames.wrap_to_2pi(phase + 2.0 * np.pi / radar.scan_period_s * t_true)
    az_deg = np.degrees(azimuth)
    nothing = np.full(n, np.nan)
    plots = pd.DataFrame({
        "radar_id": np.full(n, radar.id, dtype=object),
        "time_s": t_true + radar.bias.time_offset_s,
        "range_m": range_m,
        "azimuth_deg": np.where(az_deg >= 360.0, 0.0, az_deg),
        "elevation_deg": elevation_deg,
        "target_id": np.full(n, "", dtype=object),
        "altitude_m": nothing,
        "mode_3a": np.full(n, "", dtype=object),
        "track_number": pd.array(np.full(n, pd.NA), dtype="Int64"),
    })
    truth = pd.DataFrame({
        "time_true_s": t_true,
        **{column: np.full(n, np.nan) for column in _TRUTH_COLUMNS[1:-1]},
        "truth_target_id": np.full(n, CLUTTER, dtype=object),
    })
    return plots, truth


def _identify(
    radar: RadarSpec, plots: pd.DataFrame, truth: pd.DataFrame, codes: Mode3aCodes | None,
    tracks: TrackNumbers | None, track_column: bool,
) -> pd.DataFrame:
    """A radar's plots as its ``identity`` reports them: ``mode_3a`` (with ``codes``),
    ``track_number`` (with ``track_column``: numbered by ``tracks``, else empty), and
    ``target_id`` or ``altitude_m`` emptied where the radar does not report them."""
    target = truth["truth_target_id"].to_numpy(dtype=object)
    time = truth["time_true_s"].to_numpy(dtype=float)
    n = target.size
    columns: dict[str, object] = {}
    if codes is not None:
        columns["mode_3a"] = (np.full(n, "", dtype=object) if radar.identity == "psr"
                              else codes.at(target, time))
    if track_column:
        columns["track_number"] = (tracks.number(target, time) if tracks is not None
                                   else pd.array(np.full(n, pd.NA), dtype="Int64"))
    if radar.identity != "mode_s":
        columns["target_id"] = np.full(n, "", dtype=object)
    if radar.identity == "psr":
        columns["altitude_m"] = np.full(n, np.nan)
    return plots.assign(**columns) if columns else plots



# --------------------------------------------------------------------------- simulate


@dataclass
class SimulationChunk:
    """The plots and ADS-B reports of one chunk of a scenario (:mod:`graphcal.simulation.chunks`).

    Attributes
    ----------
    index : int
        Chunk number, from 0.
    t_start_s, t_end_s : float
        Its span of reported time ``[t_start_s, t_end_s)`` [s] (``-inf`` and ``inf``
        at the ends of the scenario).
    plots : pandas.DataFrame
        Contract columns, sorted by time.
    plot_truth : pandas.DataFrame
        Row for row with ``plots`` (:attr:`SimulationResult.plot_truth`).
    adsb, adsb_truth : pandas.DataFrame or None
        The reports (possibly none) and their truth; ``None`` when ADS-B is off.
    n_candidates : dict of str to int
        Per radar, the beam hits in coverage before the detection draw.
    n_clutter : dict of str to int
        Per radar, the false plots among ``plots``.
    """

    index: int
    t_start_s: float
    t_end_s: float
    plots: pd.DataFrame
    plot_truth: pd.DataFrame
    adsb: pd.DataFrame | None
    adsb_truth: pd.DataFrame | None
    n_candidates: dict[str, int]
    n_clutter: dict[str, int] = field(default_factory=dict)


class ChunkedSimulation:
    """A scenario simulated one chunk of time after the other.

    The traffic and the antenna phases are drawn when it is made; :meth:`chunks`
    then simulates chunk after chunk, each radar in file order and then the ADS-B
    (the equipage and the report phases are drawn before the first chunk's
    ADS-B), then the Mode 3/A codes (after the first chunk's ADS-B, when the
    scenario has codes) and each radar's clutter (when it has any), so one seed
    and one chunk length give one dataset.  Track numbers carry over from chunk
    to chunk.  With a single
    chunk (``chunk_s`` ``None``) every draw comes in the order :func:`simulate`
    has always used, so its output does not change.  With several chunks the
    radars' hits (times and true positions) are the same, as the chunks partition
    them, but the detection and noise draws, and the ADS-B equipage and report
    phases (drawn after the first chunk's plots), are others: the output is
    statistically equivalent to the one-chunk simulation, not identical.

    Parameters
    ----------
    scenario : Scenario
        From :func:`graphcal.simulation.scenario.load_scenario`.
    rng : numpy.random.Generator
        The only source of randomness.
    chunk_s : float, optional
        Chunk length [s] of reported time (:func:`graphcal.simulation.chunks.chunk_edges`);
        ``None``: one chunk.
    progress : callable, optional
        ``progress(stage, done, total)`` after the traffic, each radar of each chunk
        and each chunk's ADS-B.

    Raises
    ------
    ScenarioError
        If an ``[opensky]`` table is missing or unreadable.
    ValueError
        If ``chunk_s`` is not a positive duration.
    """

    def __init__(self, scenario: Scenario, rng: np.random.Generator, *,
                 chunk_s: float | None = None, progress: ProgressCallback | None = None
                 ) -> None:
        self.scenario = scenario
        self.edges = chunk_edges(scenario.duration_s, chunk_s)
        self._rng = rng
        self._progress = progress
        self._done = 0
        self._total = 1 + (len(scenario.radars) + 1) * self.n_chunks
        self._equipped: NDArray[np.bool_] | None = None
        self._adsb_phases: Array | None = None
        self._codes: Mode3aCodes | None = None
        self._tracks = {r.id: TrackNumbers(r.scan_period_s) for r in scenario.radars
                        if r.track_numbers}
        self._started = False
        self.flights, self.replay_stats = build_trajectories(scenario, rng)
        self._report(f"{len(self.flights)} flights")
        self.antenna_phase_rad = _antenna_phases(scenario, rng)

    @property
    def n_chunks(self) -> int:
        """Number of chunks."""
        return len(self.edges) - 1

    @property
    def adsb_equipped(self) -> tuple[str, ...]:
        """Addresses of the aircraft that broadcast ADS-B (empty before the first chunk)."""
        if self._equipped is None:
            return ()
        return tuple(f.target_id for f, e in zip(self.flights, self._equipped, strict=True)
                     if e)

    @property
    def mode_3a(self) -> Mode3aCodes | None:
        """The aircraft's Mode 3/A codes (``None`` before the first chunk, or without codes)."""
        return self._codes

    def _report(self, stage: str) -> None:
        self._done += 1
        if self._progress is not None:
            self._progress(stage, self._done, self._total)

    def chunks(self) -> Iterator[SimulationChunk]:
        """Simulate the chunks in time order (once: the draws are consumed).

        Raises
        ------
        RuntimeError
            When called a second time.
        """
        if self._started:
            raise RuntimeError("the chunks of a simulation can be drawn only once")
        self._started = True
        for k in range(self.n_chunks):
            yield self._chunk(k)

    def _chunk(self, k: int) -> SimulationChunk:
        scenario, rng = self.scenario, self._rng
        prefix = f"chunk {k + 1}/{self.n_chunks}: " if self.n_chunks > 1 else ""
        duration = scenario.duration_s
        pressure = scenario.height_model if scenario.plot_altitude == "pressure" else None
        radar_frames, candidates = [], {}
        for radar in scenario.radars:
            span = true_span(self.edges, k, duration, radar.bias.time_offset_s)
            plots, truth, n_hits = _radar_plots(
                radar, self.antenna_phase_rad[radar.id], self.flights, span, rng, pressure)
            radar_frames.append((radar, span, plots, truth))
            candidates[radar.id] = n_hits
            self._report(f"{prefix}radar {radar.id}: {len(plots)} plots")
        adsb = adsb_truth = None
        if scenario.adsb.enabled:
            if self._equipped is None:
                self._equipped, self._adsb_phases = _adsb_schedule(
                    scenario.adsb, self.flights, rng)
            assert self._adsb_phases is not None
            adsb, adsb_truth = _adsb_reports(
                scenario.adsb, self.flights, self._equipped, self._adsb_phases,
                true_span(self.edges, k, duration), rng,
                scenario.height_model if scenario.adsb_baro else None,
            )
        code_spec = scenario.codes
        if code_spec is not None and self._codes is None:
            self._codes = draw_mode_3a_codes(code_spec, self.flights, duration, rng)
        if adsb is not None and self._codes is not None:
            adsb = adsb.assign(mode_3a=self._codes.at(adsb["target_id"].to_numpy(dtype=object),
                                                      adsb["time_s"].to_numpy(dtype=float)))
        plots, truth, n_clutter = self._plots(radar_frames)
        self._report(f"{prefix}ADS-B: {0 if adsb is None else len(adsb)} reports")
        return SimulationChunk(k, self.edges[k], self.edges[k + 1], plots, truth, adsb,
                               adsb_truth, candidates, n_clutter)

    def _plots(
        self, radar_frames: list[tuple[RadarSpec, TimeSpan, pd.DataFrame, pd.DataFrame]]
    ) -> tuple[pd.DataFrame, pd.DataFrame, dict[str, int]]:
        """A chunk's plots and truth, sorted by time, from each radar's aircraft plots:
        their identity columns, and each radar's clutter (drawn here, in file order)."""
        scenario = self.scenario
        columns = list(PLOT_COLUMNS) + ["altitude_m"]
        columns += ["mode_3a"] if self._codes is not None else []
        columns += ["track_number"] if scenario.track_numbers else []
        plot_frames, truth_frames, n_clutter = [], [], {}
        for radar, span, plots, truth in radar_frames:
            plot_frames.append(_identify(radar, plots, truth, self._codes,
                                         self._tracks.get(radar.id), scenario.track_numbers))
            truth_frames.append(truth)
            n_clutter[radar.id] = 0
            if radar.clutter_per_scan > 0.0:
                false_plots, false_truth = clutter_plots(
                    radar, self.antenna_phase_rad[radar.id], span, self._rng)
                plot_frames.append(false_plots[columns])
                truth_frames.append(false_truth)
                n_clutter[radar.id] = len(false_plots)
        plots = pd.concat(plot_frames, ignore_index=True)
        truth = pd.concat(truth_frames, ignore_index=True)
        order = np.argsort(plots["time_s"].to_numpy(), kind="stable")
        plots = plots.iloc[order].reset_index(drop=True)[columns]
        truth = truth.iloc[order].reset_index(drop=True)[list(_TRUTH_COLUMNS)]
        return plots, truth, n_clutter


def simulate(
    scenario: Scenario,
    rng: np.random.Generator,
    *,
    chunk_s: float | None = None,
    progress: ProgressCallback | None = None,
) -> SimulationResult:
    """Simulate the radar plots and ADS-B reports of a scenario.

    Parameters
    ----------
    scenario : Scenario
        From :func:`graphcal.simulation.scenario.load_scenario`.
    rng : numpy.random.Generator
        The only source of randomness (``numpy.random.default_rng(seed)``).
    chunk_s : float, optional
        Simulate in chunks of this much reported time [s] (:class:`ChunkedSimulation`):
        the same dataset :func:`graphcal.simulation.stream.simulate_to_folder` writes
        with this chunk.  Default: one chunk, the draws as they have always been.
    progress : callable, optional
        ``progress(stage, done, total)`` after each step (traffic, each radar,
        ADS-B); e.g. to drive a progress bar.

    Returns
    -------
    SimulationResult
        The dataset and its truth.

    Raises
    ------
    ScenarioError
        If an ``[opensky]`` table is missing or unreadable.
    """
    run = ChunkedSimulation(scenario, rng, chunk_s=chunk_s, progress=progress)
    chunks = list(run.chunks())
    plots = pd.concat([c.plots for c in chunks], ignore_index=True)
    truth = pd.concat([c.plot_truth for c in chunks], ignore_index=True)
    adsb = adsb_truth = None
    if scenario.adsb.enabled:
        adsb = pd.concat([c.adsb for c in chunks], ignore_index=True)
        adsb_truth = pd.concat([c.adsb_truth for c in chunks], ignore_index=True)
        if adsb.empty:
            # No report at all (e.g. equipped_fraction = 0): no table, as a
            # dataset's ADS-B file must have rows to be read back.
            adsb = adsb_truth = None
    candidates = {r.id: sum(c.n_candidates[r.id] for c in chunks) for r in scenario.radars}
    n_clutter = {r.id: sum(c.n_clutter[r.id] for c in chunks) for r in scenario.radars}
    sites = {r.id: r.site() for r in scenario.radars}
    dataset = Dataset(sites=sites, plots=plots, adsb=adsb,
                      plot_altitude=scenario.plot_altitude, epoch_utc=scenario.epoch_utc)
    return SimulationResult(
        scenario=scenario,
        dataset=dataset,
        biases={r.id: r.bias for r in scenario.radars},
        plot_truth=truth,
        adsb_truth=adsb_truth,
        trajectories=run.flights,
        antenna_phase_rad=run.antenna_phase_rad,
        replay_stats=run.replay_stats,
        n_candidates=candidates,
        adsb_equipped=run.adsb_equipped,
        mode_3a=run.mode_3a,
        n_clutter=n_clutter,
    )


# --------------------------------------------------------------------------- output


def truth_document(result: SimulationResult) -> dict:
    """The true biases of a simulation in the contract's result schema, with the plots'
    truth when some plots lack an address (:func:`scenario_truth`)."""
    return scenario_truth(result.scenario, result.n_plots(),
                          result.plot_truth["truth_target_id"], result.n_clutter)


def scenario_truth(
    scenario: Scenario,
    n_plots: Mapping[str, int],
    plot_targets: Sequence[str] | pd.Series | None = None,
    n_clutter: Mapping[str, int] | None = None,
) -> dict:
    """The true biases in the contract's result schema (``method = "truth"``).

    Every radar gets the four bias keys in contract units
    (``elevation_bias_mrad`` null for a 2-D radar), ``time_offset_s`` when it
    is not zero, ``azimuth_sin_mrad`` and ``azimuth_cos_mrad`` when the radar
    has an azimuth eccentricity, an empty ``sigma`` and ``n_plots``.  A scenario
    that simulates pressure altitudes adds the ``atmosphere`` block: the true
    ``height_offset_m`` and ``height_scale`` (contract v2).  A scenario whose biases
    change over time adds the ``drift`` block, per such radar: ``per_h`` (each
    drifting term's rate per hour, contract units) and ``steps`` (``time_s`` and each
    changed term); ``radars`` then holds the biases at t = 0
    (:class:`graphcal.data.bias_schedule.BiasSchedule`).

    A scenario some of whose plots carry no address (a radar whose ``identity``
    is not ``"mode_s"``, or clutter; contract v3) adds, given ``plot_targets``,
    the ``plot_truth`` block: ``truth_target_id``, one entry per plot in the
    order of the plots table (the address of the aircraft that made it, or
    ``"clutter"``), and ``radars``: per radar its ``identity``,
    ``track_numbers``, ``detection_probability``, ``clutter_per_scan`` and
    ``n_clutter`` (its false plots).

    Parameters
    ----------
    scenario : Scenario
        The scenario simulated.
    n_plots : mapping of str to int
        Plots simulated per radar.
    plot_targets : sequence of str, optional
        Each plot's ``truth_target_id``, in the order of the plots table.
    n_clutter : mapping of str to int, optional
        False plots per radar (default: none).
    """
    radars = {}
    for radar in scenario.radars:
        bias = radar.bias
        values = dict(zip(PARAMETER_NAMES, bias.as_vector(), strict=True))
        entry: dict[str, object] = {}
        for name in PARAMETER_NAMES:
            key, factor = CONTRACT_KEYS[name]
            if name == "elevation_bias" and not radar.is_3d:
                entry[key] = None
            else:
                entry[key] = float(values[name]) * factor
        if bias.time_offset_s != 0.0:
            key, factor = CONTRACT_KEYS["time_offset"]
            entry[key] = float(bias.time_offset_s) * factor
        if bias.has_eccentricity:
            for name in ECCENTRICITY_NAMES:
                key, factor = CONTRACT_KEYS[name]
                entry[key] = float(bias.value(name)) * factor
        entry["sigma"] = {}
        entry["n_plots"] = int(n_plots[radar.id])
        radars[radar.id] = entry
    document: dict[str, object] = {
        "method": "truth", "scenario": scenario.name, "radars": radars,
    }
    if scenario.has_pressure:
        model = scenario.height_model
        document["atmosphere"] = {"height_offset_m": float(model.height_offset_m),
                                  "height_scale": float(model.height_scale), "sigma": {}}
    drift = {radar.id: _drift_entry(radar) for radar in scenario.radars
             if not radar.schedule.constant}
    if drift:
        document["drift"] = drift
    if plot_targets is not None and not scenario.addressed:
        clutter = n_clutter or {}
        document["plot_truth"] = {
            "truth_target_id": [str(v) for v in plot_targets],
            "radars": {radar.id: {"identity": radar.identity,
                                  "track_numbers": radar.track_numbers,
                                  "detection_probability": radar.detection_probability,
                                  "clutter_per_scan": radar.clutter_per_scan,
                                  "n_clutter": int(clutter.get(radar.id, 0))}
                       for radar in scenario.radars},
        }
    return document


def _contract_terms(change: RadarBias, scale: float = 1.0) -> dict[str, float]:
    """The non-zero terms of a bias change, by contract key in contract units."""
    out = {}
    for name in (*PARAMETER_NAMES, *ECCENTRICITY_NAMES):
        value = change.value(name)
        if value != 0.0:
            key, factor = CONTRACT_KEYS[name]
            out[key] = float(value) * factor * scale
    return out


def _drift_entry(radar) -> dict[str, object]:
    """A radar's ``drift`` entry of ``truth.json``: rates per hour and steps."""
    return {"per_h": _contract_terms(radar.drift_per_s, 3600.0),
            "steps": [{"time_s": float(step.time_s), **_contract_terms(step.change)}
                      for step in radar.steps]}


def write_simulation(
    result: SimulationResult,
    out_dir: str | Path,
    fmt: str = "csv",
    *,
    overwrite: bool = False,
) -> Path:
    """Write the dataset folder with its ``truth.json``, atomically (one folder renamed
    into place with every file in it, so an interruption never leaves a folder without
    ``truth.json``).

    Parameters
    ----------
    result : SimulationResult
        From :func:`simulate`.
    out_dir : str or Path
        Destination folder (see :func:`graphcal.io.folder.write_dataset`).
    fmt : {"csv", "parquet"}, optional
        Table format.
    overwrite : bool, optional
        Replace an existing non-empty folder.

    Returns
    -------
    Path
        ``out_dir``.
    """
    text = json.dumps(truth_document(result), indent=2) + "\n"
    folder = write_dataset(result.dataset, out_dir, fmt=fmt, overwrite=overwrite,
                           files={"truth.json": text})
    return Path(folder)
