"""Aircraft trajectories for the simulator: true positions as functions of time.

Every trajectory answers :meth:`Trajectory.position_ecef` for an array of times
[s] with WGS-84 ECEF positions [m], NaN where the aircraft is not flying (before
its start, after its end, inside a data gap of a replayed track).  Three kinds:

* :class:`LegTrajectory`: piecewise legs (straight, constant-rate turns, climbs,
  speed changes), integrated in closed form (exact, no time step).  Horizontal
  motion is integrated in the tangent plane of a local origin; each planar point
  is mapped to the ellipsoid along the ellipsoid normal through it and placed at
  the aircraft's height above the ellipsoid, so a level leg stays at constant
  height however far it goes (the planar map shortens ground distances by less
  than 0.1 % within 250 km of the origin).
* :class:`EcefTrajectory`: constant velocity in ECEF (paper 002's target).
* :class:`SplineTrajectory`: a replayed real track as smoothing cubic splines
  of ECEF position in time, one per gap-free segment; :func:`replay_opensky`
  builds them from an OpenSky-style state-vector table.

:func:`generate_traffic` draws random waypoint traffic from a
:class:`numpy.random.Generator`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import make_smoothing_spline

from graphcal.core import frames

Array = NDArray[np.float64]


# --------------------------------------------------------------------------- base


class Trajectory:
    """One aircraft's true motion.

    Attributes
    ----------
    target_id : str
        Lower-case hex ICAO 24-bit address.
    """

    target_id: str

    def segments(self) -> list[tuple[float, float]]:
        """Time intervals ``[(t0, t1), ...]`` [s] on which the position is defined."""
        raise NotImplementedError

    def position_ecef(self, time_s: ArrayLike) -> Array:
        """True ECEF positions [m], shape ``(n, 3)``; NaN outside :meth:`segments`."""
        raise NotImplementedError

    @property
    def start_s(self) -> float:
        """First time with a defined position [s]."""
        return min(t0 for t0, _ in self.segments())

    @property
    def end_s(self) -> float:
        """Last time with a defined position [s]."""
        return max(t1 for _, t1 in self.segments())

    def _inside(self, t: Array) -> NDArray[np.bool_]:
        mask = np.zeros(t.shape, dtype=bool)
        for t0, t1 in self.segments():
            mask |= (t >= t0) & (t <= t1)
        return mask


# --------------------------------------------------------------------------- local plane


@dataclass(frozen=True)
class LocalPlane:
    """Tangent plane at a local origin, for horizontal motion in east/north metres.

    Attributes
    ----------
    lat_rad, lon_rad : float
        Origin latitude and longitude [rad].
    alt_m : float
        Origin height above the ellipsoid [m]; the plane touches the ellipsoid's
        parallel surface at this height.
    """

    lat_rad: float
    lon_rad: float
    alt_m: float = 0.0

    def to_ecef(self, east_m: ArrayLike, north_m: ArrayLike, height_m: ArrayLike) -> Array:
        """Planar ``(east, north)`` [m] and ellipsoidal height [m] to ECEF [m].

        The planar point is dropped along the ellipsoid normal through it; the
        foot's latitude and longitude are kept and the height is set to
        ``height_m``.
        """
        e, n, h = np.broadcast_arrays(
            np.asarray(east_m, float), np.asarray(north_m, float), np.asarray(height_m, float)
        )
        enu = np.stack([e, n, np.zeros_like(e)], axis=-1)
        planar = frames.enu_to_ecef(enu, self.lat_rad, self.lon_rad, self.alt_m)
        lat, lon, _ = frames.ecef_to_geodetic(planar)
        return frames.geodetic_to_ecef(lat, lon, h)

    def from_geodetic(self, lat_rad: float, lon_rad: float) -> tuple[float, float]:
        """Inverse of :meth:`to_ecef` for the horizontal position: ``(east_m, north_m)``.

        The ellipsoid normal at ``(lat, lon)`` is a straight line; its
        intersection with the plane is found in closed form.
        """
        foot = frames.geodetic_to_ecef(lat_rad, lon_rad, 0.0)
        normal = frames.geodetic_to_ecef(lat_rad, lon_rad, 1.0) - foot
        rotation = frames.ecef_to_enu_rotation(self.lat_rad, self.lon_rad)
        enu_foot = frames.ecef_to_enu(foot, self.lat_rad, self.lon_rad, self.alt_m)
        up_rate = float(rotation[2] @ normal)
        s = -float(enu_foot[2]) / up_rate
        enu = enu_foot + s * (rotation @ normal)
        return float(enu[0]), float(enu[1])


# --------------------------------------------------------------------------- legs


@dataclass(frozen=True)
class Leg:
    """One leg of a piecewise trajectory; rates are constant within the leg.

    Attributes
    ----------
    duration_s : float
        Leg duration [s], > 0.
    turn_rate_rad_s : float
        Heading rate [rad/s]; positive turns clockwise (to the right).
    vertical_rate_mps : float
        Rate of change of the height [m/s]; positive climbs.
    acceleration_mps2 : float
        Rate of change of the ground speed [m/s^2].
    """

    duration_s: float
    turn_rate_rad_s: float = 0.0
    vertical_rate_mps: float = 0.0
    acceleration_mps2: float = 0.0


def _leg_displacement(
    speed: Array, heading: Array, leg_rates: tuple[Array, Array], tau: Array
) -> tuple[Array, Array]:
    """Closed-form planar displacement ``(d_east, d_north)`` [m] after ``tau`` s in a leg.

    With ground speed ``v(t) = v0 + a t`` and heading ``psi(t) = psi0 + w t``
    (clockwise from north), ``d_east = int v sin(psi) dt``, ``d_north = int v
    cos(psi) dt``.  For ``w != 0`` (integration by parts)::

        d_east  = [-(v0 + a t) cos(psi) / w + a sin(psi) / w^2]_0^tau
        d_north = [ (v0 + a t) sin(psi) / w + a cos(psi) / w^2]_0^tau

    and for ``w == 0`` ``(v0 tau + a tau^2 / 2) (sin psi0, cos psi0)``.
    """
    turn, accel = leg_rates
    straight = np.abs(turn) < 1e-12
    w = np.where(straight, 1.0, turn)
    psi1 = heading + turn * tau
    v1 = speed + accel * tau
    de_turn = (-v1 * np.cos(psi1) + speed * np.cos(heading)) / w + accel * (
        np.sin(psi1) - np.sin(heading)
    ) / w**2
    dn_turn = (v1 * np.sin(psi1) - speed * np.sin(heading)) / w + accel * (
        np.cos(psi1) - np.cos(heading)
    ) / w**2
    dist = speed * tau + 0.5 * accel * tau**2
    de = np.where(straight, dist * np.sin(heading), de_turn)
    dn = np.where(straight, dist * np.cos(heading), dn_turn)
    return de, dn


class LegTrajectory(Trajectory):
    """Piecewise-leg flight, integrated exactly in the tangent plane of ``plane``.

    Parameters
    ----------
    target_id : str
        ICAO address (lower-case hex).
    plane : LocalPlane
        Local origin of the east/north coordinates.
    start_time_s : float
        Time of the start state [s].
    east_m, north_m : float
        Start position in the plane [m].
    height_m : float
        Start height above the ellipsoid [m].
    speed_mps : float
        Start ground speed [m/s], >= 0.
    heading_rad : float
        Start heading [rad], clockwise from north.
    legs : sequence of Leg
        The legs, flown one after the other; the flight ends after the last.

    Raises
    ------
    ValueError
        If there is no leg, a duration is not positive, or the speed would
        become negative.
    """

    def __init__(
        self,
        target_id: str,
        plane: LocalPlane,
        start_time_s: float,
        east_m: float,
        north_m: float,
        height_m: float,
        speed_mps: float,
        heading_rad: float,
        legs: list[Leg] | tuple[Leg, ...],
    ) -> None:
        if not legs:
            raise ValueError("a leg trajectory needs at least one leg")
        if speed_mps < 0:
            raise ValueError("speed must be non-negative")
        self.target_id = target_id
        self.plane = plane
        self.legs = tuple(legs)
        n = len(self.legs)
        # Start state of each leg: time, east, north, height, speed, heading.
        state = np.zeros((n + 1, 6))
        state[0] = [start_time_s, east_m, north_m, height_m, speed_mps, heading_rad]
        for i, leg in enumerate(self.legs):
            if not leg.duration_s > 0:
                raise ValueError(f"leg {i}: duration must be positive")
            t, e, nn, h, v, psi = state[i]
            tau = np.array(leg.duration_s)
            rates = (np.array(leg.turn_rate_rad_s), np.array(leg.acceleration_mps2))
            de, dn = _leg_displacement(np.array(v), np.array(psi), rates, tau)
            v1 = v + leg.acceleration_mps2 * leg.duration_s
            if v1 < -1e-9:
                raise ValueError(f"leg {i}: the speed would become negative")
            state[i + 1] = [
                t + leg.duration_s,
                e + float(de),
                nn + float(dn),
                h + leg.vertical_rate_mps * leg.duration_s,
                max(v1, 0.0),
                psi + leg.turn_rate_rad_s * leg.duration_s,
            ]
        self._state = state
        self._rates = np.array(
            [
                [leg.turn_rate_rad_s, leg.vertical_rate_mps, leg.acceleration_mps2]
                for leg in self.legs
            ]
        )

    def segments(self) -> list[tuple[float, float]]:
        """The single interval from the start to the end of the last leg [s]."""
        return [(float(self._state[0, 0]), float(self._state[-1, 0]))]

    def local_state(self, time_s: ArrayLike) -> Array:
        """Planar state ``(east_m, north_m, height_m, speed_mps, heading_rad)``, ``(n, 5)``.

        NaN outside the flight.
        """
        t = np.atleast_1d(np.asarray(time_s, dtype=float))
        idx = np.searchsorted(self._state[:, 0], t, side="right") - 1
        idx = np.clip(idx, 0, len(self.legs) - 1)
        start = self._state[idx]
        turn, climb, accel = self._rates[idx].T
        tau = t - start[:, 0]
        de, dn = _leg_displacement(start[:, 4], start[:, 5], (turn, accel), tau)
        out = np.stack(
            [
                start[:, 1] + de,
                start[:, 2] + dn,
                start[:, 3] + climb * tau,
                start[:, 4] + accel * tau,
                start[:, 5] + turn * tau,
            ],
            axis=-1,
        )
        out[~self._inside(t)] = np.nan
        return out

    def position_ecef(self, time_s: ArrayLike) -> Array:
        """True ECEF positions [m], ``(n, 3)``; NaN outside the flight."""
        state = self.local_state(time_s)
        return self.plane.to_ecef(state[:, 0], state[:, 1], state[:, 2])


# --------------------------------------------------------------------------- ECEF


class EcefTrajectory(Trajectory):
    """Constant velocity in ECEF: ``p(t) = p0 + v (t - t0)`` for ``t0 <= t <= t0 + T``.

    Parameters
    ----------
    target_id : str
        ICAO address (lower-case hex).
    start_ecef_m : array_like, shape (3,)
        ECEF position at ``start_time_s`` [m].
    velocity_ecef_mps : array_like, shape (3,)
        ECEF velocity [m/s].
    start_time_s : float
        Start time [s].
    duration_s : float
        Flight duration [s], > 0.
    """

    def __init__(
        self,
        target_id: str,
        start_ecef_m: ArrayLike,
        velocity_ecef_mps: ArrayLike,
        start_time_s: float,
        duration_s: float,
    ) -> None:
        if not duration_s > 0:
            raise ValueError("duration must be positive")
        self.target_id = target_id
        self.start_ecef_m = np.asarray(start_ecef_m, dtype=float).reshape(3)
        self.velocity_ecef_mps = np.asarray(velocity_ecef_mps, dtype=float).reshape(3)
        self.start_time_s = float(start_time_s)
        self.duration_s = float(duration_s)

    def segments(self) -> list[tuple[float, float]]:
        """The single interval ``[t0, t0 + T]`` [s]."""
        return [(self.start_time_s, self.start_time_s + self.duration_s)]

    def position_ecef(self, time_s: ArrayLike) -> Array:
        """True ECEF positions [m], ``(n, 3)``; NaN outside the flight."""
        t = np.atleast_1d(np.asarray(time_s, dtype=float))
        pos = self.start_ecef_m + np.outer(t - self.start_time_s, self.velocity_ecef_mps)
        pos[~self._inside(t)] = np.nan
        return pos


# --------------------------------------------------------------------------- splines


class SplineTrajectory(Trajectory):
    """A replayed track: smoothing cubic splines of ECEF position, one per segment.

    Parameters
    ----------
    target_id : str
        ICAO address (lower-case hex).
    pieces : list of (times, ecef) pairs
        Gap-free segments of samples, times [s] strictly increasing, ECEF [m]
        shape ``(n, 3)``, ``n >= 2``.  Segments must not overlap.
    smoothing_s : float
        Smoothing time scale [s]: the spline minimises
        ``sum |p_i - p(t_i)|^2 + lam int |p''|^2 dt`` with
        ``lam = smoothing_s^4 * n / (t_last - t_first)``, which filters
        position jitter on time scales shorter than about ``smoothing_s``.
        0 interpolates (cubic, or linear below 4 samples).
    """

    MIN_POINTS_FOR_CUBIC: ClassVar[int] = 4

    def __init__(
        self,
        target_id: str,
        pieces: list[tuple[Array, Array]],
        smoothing_s: float = 5.0,
    ) -> None:
        if not pieces:
            raise ValueError("a spline trajectory needs at least one segment")
        self.target_id = target_id
        self._segments: list[tuple[float, float]] = []
        self._splines = []
        for times, ecef in sorted(pieces, key=lambda p: float(p[0][0])):
            t = np.asarray(times, dtype=float)
            p = np.asarray(ecef, dtype=float)
            if t.size < 2 or np.any(np.diff(t) <= 0):
                raise ValueError("segment times must be strictly increasing, at least 2 samples")
            self._segments.append((float(t[0]), float(t[-1])))
            self._splines.append(_fit_spline(t, p, smoothing_s))

    def segments(self) -> list[tuple[float, float]]:
        """The gap-free intervals of the replayed track [s]."""
        return list(self._segments)

    def position_ecef(self, time_s: ArrayLike) -> Array:
        """Smoothed ECEF positions [m], ``(n, 3)``; NaN outside the segments."""
        t = np.atleast_1d(np.asarray(time_s, dtype=float))
        out = np.full(t.shape + (3,), np.nan)
        for (t0, t1), spline in zip(self._segments, self._splines, strict=True):
            sel = (t >= t0) & (t <= t1)
            if np.any(sel):
                out[sel] = spline(t[sel])
        return out


def _fit_spline(t: Array, p: Array, smoothing_s: float):
    """Smoothing (or interpolating) spline ``t -> p`` fitted per segment."""
    if t.size < SplineTrajectory.MIN_POINTS_FOR_CUBIC:
        return _LinearInterpolant(t, p)
    if smoothing_s <= 0:
        from scipy.interpolate import CubicSpline

        return CubicSpline(t, p, axis=0)
    lam = smoothing_s**4 * t.size / (t[-1] - t[0])
    # Centre the data: the smoothing spline is translation invariant and the
    # ECEF magnitudes (6e6 m) would otherwise cost precision.
    centre = p.mean(axis=0)
    spline = make_smoothing_spline(t, p - centre, lam=lam)
    return lambda tq: spline(tq) + centre


class _LinearInterpolant:
    """Piecewise-linear interpolation of ``(n, 3)`` samples in time."""

    def __init__(self, t: Array, p: Array) -> None:
        self.t = t
        self.p = p

    def __call__(self, tq: Array) -> Array:
        return np.stack([np.interp(tq, self.t, self.p[:, k]) for k in range(3)], axis=-1)


# --------------------------------------------------------------------------- traffic


@dataclass(frozen=True)
class TrafficSpec:
    """Random waypoint traffic around a local origin.

    Each aircraft starts at a uniform random point of the disc of radius
    ``radius_m`` around the origin, at a uniform random time, height, ground
    speed and heading, and flies ``legs`` waypoints drawn uniformly in the same
    disc: for each waypoint it turns the shorter way at a random rate until it
    heads for the waypoint (as seen from the start of the turn), then flies
    straight to it.  On each straight leg, with probability ``1 -
    level_probability`` it changes height to a new random one at a random
    vertical rate, then flies level.  The flight ends at the last waypoint or at
    ``end_s``, whichever comes first.

    Attributes
    ----------
    n_aircraft : int
        Number of aircraft.
    radius_m : float
        Radius of the traffic disc [m].
    height_m : tuple of float
        Range ``(low, high)`` of heights above the ellipsoid [m].
    speed_mps : tuple of float
        Range of ground speeds [m/s].
    legs : tuple of int
        Range (inclusive) of the number of waypoints per aircraft.
    turn_rate_rad_s : tuple of float
        Range of turn-rate magnitudes [rad/s].
    vertical_rate_mps : tuple of float
        Range of climb/descent-rate magnitudes [m/s].
    level_probability : float
        Probability that a straight leg keeps the current height.
    start_time_s : tuple of float
        Range of start times [s].
    """

    n_aircraft: int
    radius_m: float
    height_m: tuple[float, float] = (3000.0, 11000.0)
    speed_mps: tuple[float, float] = (120.0, 250.0)
    legs: tuple[int, int] = (3, 6)
    turn_rate_rad_s: tuple[float, float] = (np.radians(1.5), np.radians(3.0))
    vertical_rate_mps: tuple[float, float] = (5.0, 15.0)
    level_probability: float = 0.5
    start_time_s: tuple[float, float] = (0.0, 0.0)


def random_icao(rng: np.random.Generator, n: int, exclude: set[str] | None = None) -> list[str]:
    """``n`` distinct random 24-bit ICAO addresses as lower-case hex, not in ``exclude``."""
    taken = set(exclude or ())
    out: list[str] = []
    while len(out) < n:
        code = f"{int(rng.integers(1, 2**24)):06x}"
        if code not in taken:
            taken.add(code)
            out.append(code)
    return out


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    lo, hi = bounds
    return float(lo if hi <= lo else rng.uniform(lo, hi))


def _waypoint_legs(
    spec: TrafficSpec,
    rng: np.random.Generator,
    east: float,
    north: float,
    height: float,
    speed: float,
    heading: float,
    max_duration_s: float,
) -> list[Leg]:
    """The legs of one random-waypoint flight, cut at ``max_duration_s``."""
    n_legs = int(rng.integers(spec.legs[0], spec.legs[1] + 1))
    legs: list[Leg] = []
    for _ in range(n_legs):
        r = spec.radius_m * np.sqrt(rng.uniform())
        theta = rng.uniform(0.0, 2.0 * np.pi)
        wp_e, wp_n = r * np.sin(theta), r * np.cos(theta)
        rate = _uniform(rng, spec.turn_rate_rad_s)
        level = rng.uniform() < spec.level_probability
        new_height = _uniform(rng, spec.height_m)
        v_rate = _uniform(rng, spec.vertical_rate_mps)
        # Turn the shorter way towards the bearing of the waypoint.
        bearing = np.arctan2(wp_e - east, wp_n - north)
        delta = float(frames.wrap_to_pi(bearing - heading))
        if abs(delta) > 1e-6 and rate > 0 and speed > 0:
            turn = Leg(abs(delta) / rate, turn_rate_rad_s=np.sign(delta) * rate)
            de, dn = _leg_displacement(
                np.array(speed),
                np.array(heading),
                (np.array(turn.turn_rate_rad_s), np.array(0.0)),
                np.array(turn.duration_s),
            )
            east, north, heading = east + float(de), north + float(dn), heading + delta
            legs.append(turn)
        distance = float(np.hypot(wp_e - east, wp_n - north))
        if speed <= 0 or distance < 1.0:
            continue
        straight_s = distance / speed
        climb_s = 0.0
        if not level and v_rate > 0:
            climb_s = min(abs(new_height - height) / v_rate, straight_s)
        if climb_s > 0:
            rate_signed = np.sign(new_height - height) * v_rate
            legs.append(Leg(climb_s, vertical_rate_mps=rate_signed))
            height += rate_signed * climb_s
        if straight_s - climb_s > 1e-6:
            legs.append(Leg(straight_s - climb_s))
        east += distance * np.sin(heading)
        north += distance * np.cos(heading)
    # Cut at the allowed duration.
    out: list[Leg] = []
    remaining = max_duration_s
    for leg in legs:
        if remaining <= 1e-9:
            break
        if leg.duration_s > remaining:
            leg = Leg(remaining, leg.turn_rate_rad_s, leg.vertical_rate_mps, leg.acceleration_mps2)
        out.append(leg)
        remaining -= leg.duration_s
    return out


def generate_traffic(
    spec: TrafficSpec,
    plane: LocalPlane,
    end_s: float,
    rng: np.random.Generator,
    exclude_ids: set[str] | None = None,
) -> list[LegTrajectory]:
    """Draw random waypoint traffic (see :class:`TrafficSpec`).

    Parameters
    ----------
    spec : TrafficSpec
        Traffic parameters.
    plane : LocalPlane
        Origin of the traffic disc.
    end_s : float
        Scenario end [s]: flights are cut there.
    rng : numpy.random.Generator
        The only source of randomness.
    exclude_ids : set of str, optional
        ICAO addresses already in use.

    Returns
    -------
    list of LegTrajectory
        ``spec.n_aircraft`` flights (fewer if a start time is at or after
        ``end_s`` or a flight has no leg).
    """
    ids = random_icao(rng, spec.n_aircraft, exclude_ids)
    out: list[LegTrajectory] = []
    for target_id in ids:
        start = _uniform(rng, spec.start_time_s)
        r = spec.radius_m * np.sqrt(rng.uniform())
        theta = rng.uniform(0.0, 2.0 * np.pi)
        east, north = r * np.sin(theta), r * np.cos(theta)
        height = _uniform(rng, spec.height_m)
        speed = _uniform(rng, spec.speed_mps)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        legs = _waypoint_legs(spec, rng, east, north, height, speed, heading, end_s - start)
        if legs:
            out.append(
                LegTrajectory(target_id, plane, start, east, north, height, speed, heading, legs)
            )
    return out


# --------------------------------------------------------------------------- OpenSky replay

#: Feet to metres.
FOOT_M = 0.3048


@dataclass(frozen=True)
class OpenSkySpec:
    """Replay of an OpenSky-style state-vector table.

    Attributes
    ----------
    file : pathlib.Path
        CSV or Parquet table with columns ``timestamp`` (datetime, naive is UTC,
        or epoch seconds), ``icao24``, ``latitude``, ``longitude`` [deg],
        ``altitude`` [ft, barometric] and optionally ``geoaltitude`` [m] and
        ``onground``.
    start : pandas.Timestamp
        UTC time that becomes scenario time 0.
    duration_s : float
        Window length [s].
    max_aircraft : int
        At most this many aircraft are replayed (those with the most points).
    min_points : int
        Aircraft with fewer clean points inside the window are skipped.
    max_gap_s : float
        A track is not interpolated across a gap between clean points longer
        than this [s].
    smoothing_s : float
        Smoothing time scale of the splines [s] (:class:`SplineTrajectory`).
    max_height_jump_m : float
        A point whose height differs from the running median of its 7
        neighbours by more than this is a glitch and dropped [m].
    max_position_jump_m : float
        Same for the ECEF position [m].
    """

    file: Path
    start: pd.Timestamp
    duration_s: float
    max_aircraft: int = 60
    min_points: int = 60
    max_gap_s: float = 20.0
    smoothing_s: float = 5.0
    max_height_jump_m: float = 300.0
    max_position_jump_m: float = 2000.0


@dataclass(frozen=True)
class ReplayStats:
    """Row counts of an OpenSky replay's cleaning steps, in order of application."""

    rows_in_window: int
    stale_dropped: int
    onground_dropped: int
    nan_dropped: int
    duplicate_time_dropped: int
    glitch_dropped: int
    aircraft_available: int
    aircraft_used: int


_REQUIRED_COLUMNS = ("timestamp", "icao24", "latitude", "longitude", "altitude")


def read_state_table(path: Path) -> pd.DataFrame:
    """Read an OpenSky-style table (``.parquet``/``.pq`` or CSV).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If a required column is missing.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(str(path))
    if path.suffix.lower() in (".parquet", ".pq"):
        table = pd.read_parquet(path)
    else:
        table = pd.read_csv(path)
    missing = [c for c in _REQUIRED_COLUMNS if c not in table.columns]
    if missing:
        raise ValueError(f"missing column(s): {', '.join(missing)}")
    return table


def _seconds_since(timestamps: pd.Series, start: pd.Timestamp) -> Array:
    """Seconds [s] from ``start`` (UTC) to each timestamp (datetime or epoch seconds)."""
    if pd.api.types.is_numeric_dtype(timestamps):
        return timestamps.to_numpy(dtype=float) - start.timestamp()
    times = pd.to_datetime(timestamps, utc=True)
    return (times - start).dt.total_seconds().to_numpy(dtype=float)


def _running_median(values: Array, groups: Array, window: int = 7) -> Array:
    """Centred running median of ``values`` within each group (rows sorted by group)."""
    frame = pd.DataFrame(values)
    med = frame.groupby(groups, sort=False).transform(
        lambda col: col.rolling(window, center=True, min_periods=1).median()
    )
    return med.to_numpy(dtype=float)


def replay_opensky(spec: OpenSkySpec) -> tuple[list[SplineTrajectory], ReplayStats]:
    """Clean an OpenSky-style table and turn its tracks into trajectories.

    Steps, per aircraft in time order: keep rows within ``max_gap_s`` of the
    window; drop *stale* rows (latitude and longitude both equal to the
    previous row's: OpenSky repeats the last position when no new one was
    received), rows on the ground, rows with a missing position or height, and
    repeated timestamps; drop glitches (jumps from the running median, see
    :class:`OpenSkySpec`); split at gaps longer than ``max_gap_s``; fit a
    smoothing spline in ECEF to each piece.  The height is ``geoaltitude`` [m]
    when that column exists, else the barometric ``altitude`` [ft] taken as
    height above the ellipsoid (pressure altitude and ellipsoidal height differ
    by up to a few hundred metres; for a simulation only consistency matters).

    Returns
    -------
    trajectories : list of SplineTrajectory
        Up to ``max_aircraft`` tracks with at least ``min_points`` clean points
        in ``[0, duration_s]``, most points first; times are seconds since
        ``spec.start``.
    stats : ReplayStats
        Row counts of each cleaning step.
    """
    table = read_state_table(spec.file)
    t = _seconds_since(table["timestamp"], spec.start)
    in_window = (t >= -spec.max_gap_s) & (t <= spec.duration_s + spec.max_gap_s)
    height_col = "geoaltitude" if "geoaltitude" in table.columns else "altitude"
    scale = 1.0 if height_col == "geoaltitude" else FOOT_M
    df = pd.DataFrame(
        {
            "icao24": table["icao24"].astype(str).str.strip().str.lower().to_numpy(),
            "t": t,
            "lat": pd.to_numeric(table["latitude"], errors="coerce").to_numpy(dtype=float),
            "lon": pd.to_numeric(table["longitude"], errors="coerce").to_numpy(dtype=float),
            "h": pd.to_numeric(table[height_col], errors="coerce").to_numpy(dtype=float) * scale,
            "onground": (
                table["onground"].fillna(False).astype(bool).to_numpy()
                if "onground" in table.columns
                else np.zeros(len(table), dtype=bool)
            ),
        }
    )[in_window]
    df = df.sort_values(["icao24", "t"], kind="stable").reset_index(drop=True)
    rows_in_window = len(df)

    same_craft = df["icao24"].eq(df["icao24"].shift())
    stale = same_craft & df["lat"].eq(df["lat"].shift()) & df["lon"].eq(df["lon"].shift())
    df = df[~stale.to_numpy()]
    onground = df["onground"].to_numpy()
    df = df[~onground]
    valid = np.isfinite(df[["lat", "lon", "h"]].to_numpy()).all(axis=1)
    valid &= (np.abs(df["lat"].to_numpy()) <= 90.0) & np.isfinite(df["t"].to_numpy())
    n_nan = int((~valid).sum())
    df = df[valid]
    dup = df["icao24"].eq(df["icao24"].shift()) & df["t"].eq(df["t"].shift())
    df = df[~dup.to_numpy()].reset_index(drop=True)

    ecef = frames.geodetic_to_ecef(
        np.radians(df["lat"].to_numpy()), np.radians(df["lon"].to_numpy()), df["h"].to_numpy()
    )
    groups = df["icao24"].to_numpy()
    glitch = np.zeros(len(df), dtype=bool)
    if len(df):
        med = _running_median(np.column_stack([ecef, df["h"].to_numpy()]), groups)
        glitch = np.abs(df["h"].to_numpy() - med[:, 3]) > spec.max_height_jump_m
        glitch |= np.linalg.norm(ecef - med[:, :3], axis=1) > spec.max_position_jump_m
    df, ecef = df[~glitch].reset_index(drop=True), ecef[~glitch]

    candidates: list[tuple[int, str, list[tuple[Array, Array]]]] = []
    times = df["t"].to_numpy()
    for craft, index in df.groupby("icao24", sort=True).indices.items():
        tt, pp = times[index], ecef[index]
        breaks = np.flatnonzero(np.diff(tt) > spec.max_gap_s) + 1
        pieces = [(tt[sl], pp[sl]) for sl in np.split(np.arange(tt.size), breaks) if sl.size >= 2]
        n_inside = int(np.sum((tt >= 0.0) & (tt <= spec.duration_s)))
        if pieces and n_inside >= spec.min_points:
            candidates.append((n_inside, str(craft), pieces))
    candidates.sort(key=lambda c: (-c[0], c[1]))
    chosen = candidates[: spec.max_aircraft]
    trajectories = [
        SplineTrajectory(craft, pieces, spec.smoothing_s) for _, craft, pieces in chosen
    ]
    stats = ReplayStats(
        rows_in_window=rows_in_window,
        stale_dropped=int(stale.sum()),
        onground_dropped=int(onground.sum()),
        nan_dropped=n_nan,
        duplicate_time_dropped=int(dup.sum()),
        glitch_dropped=int(glitch.sum()),
        aircraft_available=len(candidates),
        aircraft_used=len(trajectories),
    )
    return trajectories, stats
