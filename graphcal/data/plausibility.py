"""Unit and frame heuristics on a validated dataset: the mistakes validation cannot see.

Validation (:mod:`graphcal.io.table_checks`) rejects values that cannot be right
(an azimuth of 361 deg, a negative range).  Values in the wrong unit or frame are
often valid one by one, and a calibration on them gives confident nonsense
(azimuth biases of 3,000 mrad with sigmas of 0.1 mrad).  :func:`check_tables`
looks at a dataset's tables as a whole and returns one :class:`Finding` per field
that looks like such a mistake, naming the likely cause:

====================  ============================================================
field                 fires when (per radar with at least :data:`MIN_PLOTS` plots)
====================  ============================================================
``azimuth_deg``       every azimuth is below 2*pi: radians instead of degrees (with
                      at least :data:`MIN_AIRCRAFT` aircraft when the plots name them)
``range_m``           every range is below :data:`MAX_KM_RANGE_M` (1,000): km or NM
``alt_m`` (ADS-B),    more than half of the heights above :data:`FEET_HEIGHT_M`
``baro_alt_m``,       (15 km, above any airliner's ceiling in metres, FL490 is
``altitude_m``        14.9 km), or the aircraft seen in both tables are
                      :data:`FEET_RATIO` (2.8-3.8) times higher in one than in the
                      other (a foot is 0.3048 m: 3.28): feet instead of metres
``lat_deg``,          most ADS-B reports of the aircraft a radar sees, while it
``lon_deg``           sees them, lie farther than its largest range (plus
                      :data:`COVERAGE_MARGIN_M`) from it: for every radar, the
                      ADS-B positions are wrong (latitude and longitude swapped,
                      a sign lost); for some radars, their sites
``alt_m`` (site)      outside :data:`SITE_ALT_RANGE_M` (-500..9000 m), or more
                      than :data:`GEOMETRY_FRACTION` of the radar's plots have a
                      height (``altitude_m``) farther from the antenna's than
                      their slant range allows (plus :data:`GEOMETRY_MARGIN_M`;
                      a chord of the earth is never shorter than the difference
                      of its ends' heights)
``elevation_deg``     every elevation of a 3-D radar is below pi/2 and they are about
                      pi/180 (:data:`ELEVATION_RADIANS_RATIO`) times those its plots'
                      ``altitude_m`` (else the ADS-B of its aircraft) imply at their
                      ranges; without heights, 90 % of its plots at 10-150 km within
                      :data:`ELEVATION_FLAT_DEG` of the horizon: radians (this finding
                      replaces the antenna height one, which a radian elevation fakes)
``time_s``            the plots of one aircraft at a radar are :data:`MS_SCAN_RATIO`
                      (200) or more times its scan period apart (median); the ADS-B
                      reports of one moving aircraft over :data:`MS_ADSB_GAP_S` apart at
                      under :data:`MS_ADSB_SPEED_MPS` between them: milliseconds
``time_s``            one table's times of the day wrap at midnight
                      (:func:`midnight_wrap`), the other's do not: seconds of the day
                      against a time that runs on
``time_s`` (ADS-B)    the ADS-B reports and the plots do not overlap in time
                      (:func:`check_time_overlap`; another time base: the ADS-B
                      would go unused); or they overlap, but every radar's plots
                      match the ADS-B of their aircraft best when the ADS-B is
                      moved by the same :data:`TIME_BASE_LIMIT_S` (2 s) or more
                      (:func:`adsb_geometry`; another clock: a shared offset a
                      calibration would put into every radar's ``time_offset_s``)
``alt_m`` (site),     a 3-D radar's plots match the ADS-B best with its antenna
                      :data:`ANTENNA_LIMIT_M` (150 m) or more higher or lower than
                      ``alt_m`` says, beyond :data:`ANTENNA_SIGMAS` sigmas (the
                      elevation residual ``-dh cos(el) / range`` and range
                      residual ``-dh sin(el)`` of a wrong height; feet named
                      when ``alt_m`` is 2.8-3.8 times the height the plots
                      give)
====================  ============================================================

The thresholds leave real data far inside: on every scenario of ``scenarios/``
(simulated traffic and the replayed OpenSky trajectories) nothing fires
(``tests/data/test_plausibility.py``), while each mistake above, made on one of
them, does.

:func:`graphcal.io.folder.load_dataset` and :func:`graphcal.io.window_reader.iter_windows`
run these checks and raise :class:`~graphcal.core.errors.ImplausibleDataError`
(:func:`raise_if_implausible`) unless given ``force=True`` (``--force``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core.errors import ImplausibleDataError
from graphcal.core.grouped import group_medians
from graphcal.core.rows import take_rows
from graphcal.data.dataset import Site

#: Fewest plots (or reports) a heuristic judges a radar (or a column) on.
MIN_PLOTS = 50
#: Fewest aircraft (distinct non-empty ``target_id``) the azimuth heuristic judges a
#: radar on, when its plots name aircraft: one aircraft's radial track can stay
#: within a few degrees of north for minutes.
MIN_AIRCRAFT = 3
#: Every range of a radar below this [m]: the ranges are in km (or NM).
MAX_KM_RANGE_M = 1000.0
#: Heights above this [m] for more than :data:`FEET_FRACTION` of the reports: feet.
FEET_HEIGHT_M = 15000.0
#: Fraction of heights above :data:`FEET_HEIGHT_M` that fires.
FEET_FRACTION = 0.5
#: Median ratio of one table's heights to the other's, per aircraft, that means feet.
FEET_RATIO = (2.8, 3.8)
#: Plausible antenna heights above the ellipsoid [m] (the Dead Sea to above Everest).
SITE_ALT_RANGE_M = (-500.0, 9000.0)
#: Slack [m] of the height-versus-range test (pressure altitudes, geoid, noise).
GEOMETRY_MARGIN_M = 1000.0
#: Fraction of a radar's plots out of geometric reach that fires.
GEOMETRY_FRACTION = 0.2
#: ADS-B reports may lie this much [m] beyond a radar's largest range and count as covered.
COVERAGE_MARGIN_M = 50_000.0
#: A radar fires when fewer than this fraction of its aircraft's reports are covered.
COVERAGE_FRACTION = 0.5
#: Without a shared target_id: fires when fewer than this fraction of all reports
#: within the plots' time span lie within any radar's reach (an ADS-B export may
#: cover a much larger area than the radars).
COVERAGE_FRACTION_ANY = 0.05
#: ADS-B reports of an aircraft judged for coverage (at least this many per radar).
MIN_REPORTS = 20
#: Time margin [s] around the plots' span within which ADS-B counts as overlapping.
TIME_MARGIN_S = 60.0
#: Rows of a table the statistical heuristics (coverage, height ratio) look at: a larger
#: table is thinned to every k-th row (fractions and medians, not extremes).
SAMPLE_ROWS = 50_000
#: ADS-B reports the coverage heuristic looks at (every k-th row): it joins each
#: report to every radar that sees its aircraft, and a fraction to about a percent is
#: all it needs.
COVERAGE_SAMPLE_ROWS = 10_000
#: Mean earth radius [m] for ground distances.
EARTH_RADIUS_M = 6_371_008.8
#: Every radar's plots this far [s] from the ADS-B in time, all alike: another clock.
#: Sensor models give time-stamping biases of 0.05-0.1 s.
TIME_BASE_LIMIT_S = 2.0
#: Radars whose time offsets differ by more than this [s] (plus a fifth of their
#: mean) do not share one clock error.
TIME_BASE_SPREAD_S = 1.0
#: An antenna this far [m] from the height the plots give fires (a geoid height, the
#: mean sea level for the ellipsoid, is under 110 m anywhere).
ANTENNA_LIMIT_M = 150.0
#: ... and this many of its sigmas away.
ANTENNA_SIGMAS = 10.0
#: Named plots per radar the ADS-B geometry fit looks at (every k-th).
GEOMETRY_SAMPLE_PLOTS = 2000
#: Span [s] of a recording the geometry fit looks at (around its median plot time).
GEOMETRY_SPAN_S = 1800.0
#: Longest gap [s] between two ADS-B reports bridged by the geometry fit.
GEOMETRY_MAX_GAP_S = 20.0
#: Residuals beyond this many robust sigmas are left out of the geometry fit.
GEOMETRY_REJECT_SIGMAS = 5.0
#: Noise assumed when a site leaves its sigmas out (range m, azimuth rad, elevation rad).
GEOMETRY_DEFAULT_SIGMAS = (50.0, 2e-3, 3e-3)
#: A 3-D radar's elevations this many times those the geometry implies: radians (pi/180
#: is 0.0175).
ELEVATION_RADIANS_RATIO = (0.005, 0.06)
#: Elevations [deg] the geometry implies below this are not judged (near the horizon
#: the height error of a pressure altitude dominates).
ELEVATION_MIN_DEG = 1.0
#: Without heights to compare: plots at these slant ranges [m] ...
ELEVATION_RANGE_M = (10_000.0, 150_000.0)
#: ... 90 % of them within this many "degrees" of the horizon: radians (an aircraft 2 km
#: above the antenna at 150 km is 0.26 deg up, one at 10 km altitude 3.3 deg).
ELEVATION_FLAT_DEG = 0.2
#: Effective earth radius [m] of the elevation heuristic (the 4/3 earth of standard
#: refraction).
EFFECTIVE_EARTH_RADIUS_M = 4.0 / 3.0 * EARTH_RADIUS_M
#: Rows of a table (one contiguous block from its middle, so that successive plots of an
#: aircraft stay together) the time-unit heuristics look at.
TIME_SAMPLE_ROWS = 20_000
#: The plots of one aircraft at one radar this many times the scan period apart (median):
#: time_s in milliseconds.
MS_SCAN_RATIO = 200.0
#: Scan period [s] assumed when neither the site nor its sensor model gives one.
DEFAULT_SCAN_PERIOD_S = 5.0
#: The ADS-B reports of one moving aircraft this far apart [s] (median; reports come every
#: 0.5-10 s) ...
MS_ADSB_GAP_S = 100.0
#: ... at a median speed below this [m/s] between them (aircraft fly at 50-300 m/s): ms.
MS_ADSB_SPEED_MPS = 1.0
#: A step [m] between successive reports that counts as moving.
MS_ADSB_MOVE_M = 100.0
#: Seconds in a day.
DAY_S = 86_400.0
#: A table of seconds of the day wraps at midnight when it holds times this close [s] to
#: both ends of the day with an empty half day between them.
WRAP_EDGE_S = 3600.0


@dataclass(frozen=True)
class Finding:
    """One field that looks like a unit or frame mistake.

    Attributes
    ----------
    table : {"plots", "adsb", "sites"}
        Where the field is.
    field : str
        The column (or ``sites.toml`` key).
    message : str
        What was seen, with numbers, and the likely mistake.
    radars : tuple of str
        The radars concerned (empty when the whole table is).
    """

    table: str
    field: str
    message: str
    radars: tuple[str, ...] = ()


def _fmt(value: float) -> str:
    """A number for a message: thousands separated, at most 3 significant decimals."""
    if not math.isfinite(value):
        return str(value)
    if abs(value) >= 1000:
        return f"{value:,.0f}"
    return f"{value:.3g}"


# --------------------------------------------------------------------------- per field
def _per_radar(plots: pd.DataFrame) -> pd.DataFrame:
    """Per radar: plots, aircraft named (0: none), largest azimuth [deg] and range [m].

    As ``groupby("radar_id", sort=False).agg(n="size", aircraft="nunique", az_max="max",
    r_max="max")``: radars in order of first appearance, missing values skipped (a
    radar's maximum NaN when all are), on integer codes instead of pandas' groupby.
    """
    radar, names = pd.factorize(plots["radar_id"])
    mine = radar >= 0
    radar = radar[mine]
    n = np.bincount(radar, minlength=len(names))
    target, aircraft = pd.factorize(plots["target_id"])
    named = np.append(np.asarray(aircraft != "", dtype=bool), False)[target][mine]
    pairs = np.unique(radar[named] * np.int64(len(aircraft) + 1) + target[mine][named])
    stats = {"n": n, "aircraft": np.bincount(pairs // (len(aircraft) + 1),
                                             minlength=len(names))}
    for name, column in (("az_max", "azimuth_deg"), ("r_max", "range_m")):
        largest = np.full(len(names), np.nan)
        np.fmax.at(largest, radar, plots[column].to_numpy(dtype=float, na_value=np.nan)[mine])
        stats[name] = largest
    # The index as groupby gives it: of the column's type, inferred from the values
    # when that is object (text: str).
    index = pd.Index(names if names.dtype != object else np.asarray(names, dtype=object),
                     name="radar_id")
    return pd.DataFrame(stats, index=index)


def _azimuth_radians(stats: pd.DataFrame) -> Finding | None:
    enough = (stats["n"] >= MIN_PLOTS) & (
        (stats["aircraft"] == 0) | (stats["aircraft"] >= MIN_AIRCRAFT))
    bad = stats[enough & (stats["az_max"] < 2.0 * math.pi)]
    if bad.empty:
        return None
    names = ", ".join(f"{rid} (largest {v:.3g} of {n} plots)"
                      for rid, v, n in zip(bad.index, bad["az_max"], bad["n"], strict=True))
    return Finding("plots", "azimuth_deg",
                   f"every azimuth of radar {names} is below 2*pi: azimuths in radians "
                   "instead of degrees?", tuple(str(r) for r in bad.index))


def _range_km(stats: pd.DataFrame) -> Finding | None:
    bad = stats[(stats["n"] >= MIN_PLOTS) & (stats["r_max"] < MAX_KM_RANGE_M)]
    if bad.empty:
        return None
    names = ", ".join(f"{rid} (largest {v:.4g} of {n} plots)"
                      for rid, v, n in zip(bad.index, bad["r_max"], bad["n"], strict=True))
    return Finding("plots", "range_m",
                   f"every range of radar {names} is below {_fmt(MAX_KM_RANGE_M)}: ranges in "
                   "km (or NM) instead of metres?", tuple(str(r) for r in bad.index))


def _heights_feet(values: pd.Series, table: str, field: str) -> Finding | None:
    """Most heights above :data:`FEET_HEIGHT_M`."""
    h = values.to_numpy(dtype=float, na_value=np.nan)
    h = h[np.isfinite(h)]
    if h.size < MIN_PLOTS:
        return None
    above = float(np.mean(h > FEET_HEIGHT_M))
    if above <= FEET_FRACTION:
        return None
    return Finding(table, field,
                   f"{above:.0%} of the heights are above {FEET_HEIGHT_M / 1e3:.0f} km (median "
                   f"{_fmt(float(np.median(h)))}): heights in feet instead of metres?")


#: Flight levels given as altitude_m: nearly all values whole numbers below this ...
FLIGHT_LEVEL_MAX = 600.0
#: ... with aircraft seen at this median level or above (FL 50: 1,524 m; metres of real
#: heights that low would be a network of approach radars under 600 m, with decimals).
FLIGHT_LEVEL_MEDIAN_MIN = 50.0


def _flight_levels(values: pd.Series) -> Finding | None:
    """Mode C altitudes written as flight levels (hundreds of feet), not metres."""
    h = values.to_numpy(dtype=float, na_value=np.nan)
    h = h[np.isfinite(h)]
    if h.size < MIN_PLOTS:
        return None
    whole = float(np.mean(h == np.round(h)))
    if (float(np.max(np.abs(h))) > FLIGHT_LEVEL_MAX or whole < 0.95
            or float(np.median(h)) < FLIGHT_LEVEL_MEDIAN_MIN):
        return None
    return Finding("plots", "altitude_m",
                   f"every altitude is a whole number at most {_fmt(float(np.max(h)))} (median "
                   f"{_fmt(float(np.median(h)))}): flight levels (hundreds of feet) instead of "
                   "metres? (FL 350 is 10,668 m)")


def _median_height(frame: pd.DataFrame, column: str) -> pd.Series:
    """Median height per aircraft (``target_id``), finite values of named aircraft only.

    As ``Series.groupby(target_id).median()`` (aircraft in sorted order), by
    :func:`graphcal.core.grouped.group_medians`.
    """
    values = frame[column].to_numpy(dtype=float, na_value=np.nan)
    target, names = pd.factorize(frame["target_id"])
    named = np.append(np.asarray(names != "", dtype=bool), False)[target]
    ok = np.isfinite(values) & named
    codes, _, (medians,) = group_medians(target[ok], [values[ok]])
    aircraft = pd.Index(np.asarray(names, dtype=object)[codes])
    return pd.Series(medians, index=aircraft).sort_index()


def _height_ratio(plots: pd.DataFrame, adsb: pd.DataFrame) -> Finding | None:
    """The aircraft in both tables :data:`FEET_RATIO` times higher in one than the other."""
    if "altitude_m" not in plots or not np.isfinite(
            plots["altitude_m"].to_numpy(dtype=float, na_value=np.nan)).any():
        return None
    ours = _median_height(plots, "altitude_m")
    theirs = _median_height(adsb, "alt_m")
    both = ours.index.intersection(theirs.index)
    both = both[(ours[both] > 1000.0).to_numpy() & (theirs[both] > 1000.0).to_numpy()]
    if len(both) < 3:
        return None
    ratio = float(np.median(theirs[both].to_numpy() / ours[both].to_numpy()))
    low, high = FEET_RATIO
    if low <= ratio <= high:
        return Finding("adsb", "alt_m",
                       f"the aircraft are {ratio:.2f} times higher in the ADS-B table than "
                       f"in the plots' altitude_m ({len(both)} aircraft; a foot is 0.3048 m): "
                       "ADS-B heights in feet instead of metres?")
    if low <= 1.0 / ratio <= high:
        return Finding("plots", "altitude_m",
                       f"the aircraft are {1.0 / ratio:.2f} times higher in the plots' "
                       f"altitude_m than in the ADS-B table ({len(both)} aircraft; a foot is "
                       "0.3048 m): altitudes in feet instead of metres?")
    return None


def _site_altitude(sites: Mapping[str, Site], plots: pd.DataFrame,
                   skip: set[str]) -> Finding | None:
    """Antenna heights out of bounds, or out of geometric reach of the plots' heights."""
    low, high = SITE_ALT_RANGE_M
    out = [(rid, s.alt_m) for rid, s in sites.items() if not low <= s.alt_m <= high]
    if out:
        names = ", ".join(f"{rid} ({_fmt(alt)} m)" for rid, alt in out)
        return Finding("sites", "alt_m",
                       f"antenna height of radar {names} outside {_fmt(low)}..{_fmt(high)} m: "
                       "a typing error, or another unit (feet, mm)?",
                       tuple(rid for rid, _ in out))
    if "altitude_m" not in plots:
        return None
    radar, rids = pd.factorize(plots["radar_id"])
    height = plots["altitude_m"].to_numpy(dtype=float, na_value=np.nan)
    slant = plots["range_m"].to_numpy(dtype=float)
    antenna = pd.Series({rid: s.alt_m for rid, s in sites.items()})
    site_alt = np.append(antenna.reindex(rids).to_numpy(dtype=float), np.nan)[radar]
    skipped = np.append(np.asarray(rids.isin(list(skip)), dtype=bool), False)[radar]
    ok = np.isfinite(height) & np.isfinite(site_alt) & ~skipped
    if not ok.any():
        return None
    beyond = np.abs(height[ok] - site_alt[ok]) > slant[ok] + GEOMETRY_MARGIN_M
    size = np.bincount(radar[ok], minlength=len(rids))
    with np.errstate(invalid="ignore", divide="ignore"):
        fraction = np.bincount(radar[ok], weights=beyond, minlength=len(rids)) / size
    bad = sorted((str(rids[k]), float(fraction[k])) for k in
                 np.flatnonzero((size >= MIN_PLOTS) & (fraction > GEOMETRY_FRACTION)))
    if not bad:
        return None
    names = ", ".join(f"{rid} ({_fmt(sites[rid].alt_m)} m: {frac:.0%} of its plots)"
                      for rid, frac in bad)
    return Finding("sites", "alt_m",
                   f"antenna height of radar {names} differs from the plots' altitude_m by more "
                   "than their slant range, which no geometry allows: alt_m wrong (another "
                   "unit, a typing error)?", tuple(rid for rid, _ in bad))


def ground_distance_m(lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64],
                      site_lat_rad: NDArray[np.float64] | float,
                      site_lon_rad: NDArray[np.float64] | float) -> NDArray[np.float64]:
    """Great-circle distance [m] between points in degrees and sites in radians (mean sphere)."""
    lat = np.radians(lat_deg)
    dlat = lat - site_lat_rad
    dlon = np.radians(lon_deg) - site_lon_rad
    a = np.sin(dlat / 2) ** 2 + np.cos(site_lat_rad) * np.cos(lat) * np.sin(dlon / 2) ** 2
    return 2.0 * EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))


def _coverage(sites: Mapping[str, Site], plots: pd.DataFrame, adsb: pd.DataFrame,
              stats: pd.DataFrame, skip: set[str]) -> Finding | None:
    """ADS-B of the aircraft each radar sees, while it sees them, beyond the radar's reach."""
    reach = {str(rid): float(r) + COVERAGE_MARGIN_M for rid, r in stats["r_max"].items()
             if rid in sites and rid not in skip and stats.loc[rid, "n"] >= MIN_PLOTS}
    if not reach:
        return None
    covered = _covered(sites, plots, adsb, reach)
    if covered:
        bad = {rid: v for rid, v in covered.items() if v[0] < COVERAGE_FRACTION}
        if not bad:
            return None
        detail = ", ".join(f"{rid}: {frac:.0%} within its range, median {_fmt(med / 1e3)} km"
                           for rid, (frac, med) in bad.items())
        if len(bad) == len(covered):
            return Finding("adsb", "lat_deg",
                           f"the ADS-B reports of the aircraft the radars see lie mostly beyond "
                           f"every radar's range ({detail}): latitude and longitude swapped, "
                           "or a sign lost?")
        return Finding("sites", "lat_deg",
                       f"the ADS-B reports of the aircraft radar {', '.join(bad)} sees lie "
                       f"mostly beyond its range ({detail}), unlike the other radars': its "
                       "lat_deg/lon_deg wrong (swapped, a sign lost)?", tuple(bad))
    # No aircraft shared by name: all reports within the plots' time span.
    t = plots["time_s"].to_numpy(dtype=float)
    times = adsb["time_s"].to_numpy(dtype=float)
    inside = (times >= t.min() - TIME_MARGIN_S) & (times <= t.max() + TIME_MARGIN_S)
    if inside.sum() < MIN_REPORTS:
        return None
    lat = adsb["lat_deg"].to_numpy(dtype=float)[inside]
    lon = adsb["lon_deg"].to_numpy(dtype=float)[inside]
    near = np.zeros(lat.size, dtype=bool)
    for rid, max_m in reach.items():
        near |= ground_distance_m(lat, lon, sites[rid].lat_rad, sites[rid].lon_rad) <= max_m
    fraction = float(near.mean())
    if fraction >= COVERAGE_FRACTION_ANY:
        return None
    return Finding("adsb", "lat_deg",
                   f"only {fraction:.1%} of the ADS-B reports lie within any radar's range: "
                   "latitude and longitude swapped, or a sign lost?")


def _positions(values: pd.Series, among: pd.Index) -> NDArray[np.intp]:
    """Per value, its position in ``among`` (distinct values; -1: not there, or missing).

    ``among.get_indexer(values)``, looked up once per distinct value.
    """
    codes, uniques = pd.factorize(values)
    return np.append(among.get_indexer(uniques), -1)[codes]


@dataclass(frozen=True)
class _Spans:
    """Per radar and aircraft named in the plots, the time span of its plots there.

    As ``groupby(["radar_id", "target_id"], sort=False)["time_s"].agg(["min", "max"])``
    on the plots of the radars with a ``target_id`` other than ``""``, as arrays of
    shape ``(radars, aircraft)``.

    Attributes
    ----------
    names : pandas.Index
        The aircraft (``target_id``), in order of first appearance.
    t0, t1 : ndarray of float, shape (radars, aircraft)
        First and last plot time [s]; NaN for a pair without plots (or times).
    first : ndarray of int, shape (radars, aircraft)
        The row of the pair's first plot (``len(plots)`` for none): the order of
        the groups.
    """

    names: pd.Index
    t0: NDArray[np.float64]
    t1: NDArray[np.float64]
    first: NDArray[np.int64]

    @classmethod
    def of(cls, plots: pd.DataFrame, radars: list[str]) -> _Spans:
        """The spans of the plots of ``radars`` (in that order)."""
        radar = _positions(plots["radar_id"], pd.Index(radars))
        target, names = pd.factorize(plots["target_id"])
        named = (radar >= 0) & (target >= 0)
        named[named] = np.asarray(names != "", dtype=bool)[target[named]]
        rows = np.flatnonzero(named)
        key = radar[rows] * len(names) + target[rows]
        time_s = plots["time_s"].to_numpy(dtype=float)[rows]
        shape = (len(radars), len(names))
        t0, t1 = np.full(shape, np.nan), np.full(shape, np.nan)
        first = np.full(shape, len(plots), dtype=np.int64)
        np.fmin.at(t0.reshape(-1), key, time_s)  # min and max without the NaN, as pandas
        np.fmax.at(t1.reshape(-1), key, time_s)
        np.minimum.at(first.reshape(-1), key, rows)
        return cls(pd.Index(names), t0, t1, first)


def _covered(sites: Mapping[str, Site], plots: pd.DataFrame, adsb: pd.DataFrame,
             reach: Mapping[str, float]) -> dict[str, tuple[float, float]]:
    """Per radar of ``reach``: the fraction of the ADS-B reports of the aircraft it sees,
    while it sees them, within its reach [m], and their median distance [m].

    Radars with fewer than :data:`MIN_REPORTS` such reports are left out; the others
    come in the order of their first report (ties: in the order of their plots of
    its aircraft), as a join of the reports with the spans of :class:`_Spans`,
    grouped by radar, gives them.
    """
    radars = list(reach)
    spans = _Spans.of(plots, radars)
    if not len(spans.names):
        return {}
    code = _positions(adsb["target_id"], spans.names)
    time_s = adsb["time_s"].to_numpy(dtype=float)
    aircraft = np.where(code >= 0, code, 0)
    inside = (code >= 0) & (time_s >= spans.t0[:, aircraft]) & (time_s <= spans.t1[:, aircraft])
    seen = [(int(rows[0]), int(spans.first[r, aircraft[rows[0]]]), r, rows)
            for r, rows in enumerate(np.flatnonzero(row) for row in inside) if len(rows)]
    lat = adsb["lat_deg"].to_numpy(dtype=float)
    lon = adsb["lon_deg"].to_numpy(dtype=float)
    covered: dict[str, tuple[float, float]] = {}
    for _, _, r, rows in sorted(seen, key=lambda entry: entry[:2]):
        if len(rows) < MIN_REPORTS:
            continue
        rid = radars[r]
        site = sites[rid]
        d = ground_distance_m(lat[rows], lon[rows], site.lat_rad, site.lon_rad)
        covered[rid] = (float(np.mean(d <= reach[rid])), float(np.median(d)))
    return covered


@dataclass(frozen=True)
class GeometryFit:
    """One radar's plots against the ADS-B of their aircraft (:func:`adsb_geometry`).

    Attributes
    ----------
    n : int
        Plots used (aligned, outliers left out).
    time_offset_s, time_sigma_s : float
        The radar's time offset against the ADS-B clock (``time_reported = time_true +
        offset``, as ``time_offset_s`` of the contract) and its 1-sigma.
    antenna_dh_m, antenna_sigma_m : float
        What to add to the site's ``alt_m`` for the plots to fit the ADS-B best, and
        its 1-sigma (NaN when not judged: a 2-D radar).
    elevation_ratio : float
        Median ratio of the plots' elevations to those the ADS-B gives (at first
        alignment, elevations of at least :data:`ELEVATION_MIN_DEG`); NaN when not
        judged.  About pi/180 for elevations in radians.
    """

    n: int
    time_offset_s: float
    time_sigma_s: float
    antenna_dh_m: float = math.nan
    antenna_sigma_m: float = math.nan
    elevation_ratio: float = math.nan


#: An aircraft whose plots lie this far from its ADS-B (median range residual [m], or
#: azimuth residual [rad]) is another aircraft under its address, not a bias: even ADS-B
#: a minute off the radars' clock moves an aircraft by under 20 km.
GEOMETRY_FAR_RANGE_M = 20e3
GEOMETRY_FAR_AZIMUTH_RAD = 0.2


def _far_aircraft(code: NDArray[np.int64], res_r: NDArray[np.float64],
                  res_a: NDArray[np.float64]) -> NDArray[np.int64]:
    """Codes of aircraft whose plots lie beyond :data:`GEOMETRY_FAR_RANGE_M` or
    :data:`GEOMETRY_FAR_AZIMUTH_RAD` from their ADS-B (median over their plots): a
    mislabelled aircraft, which the cleaning clears later, must not read as an antenna
    height or a clock error."""
    if not len(code):
        return np.zeros(0, dtype=np.int64)
    r, a = np.abs(res_r), np.abs(res_a)
    if np.isnan(r).any() or np.isnan(a).any():  # skipped by pandas, not by group_medians
        medians = pd.DataFrame({"code": code, "r": r, "a": a}).groupby("code").median()
        codes = medians.index.to_numpy()
        median_r, median_a = medians["r"].to_numpy(), medians["a"].to_numpy()
    else:
        codes, _, (median_r, median_a) = group_medians(code, [r, a])
    far = (median_r > GEOMETRY_FAR_RANGE_M) | (median_a > GEOMETRY_FAR_AZIMUTH_RAD)
    return np.sort(codes[far]).astype(np.int64)


def _geometry_one(site: Site, time_s: NDArray[np.float64], range_m: NDArray[np.float64],
                  azimuth_rad: NDArray[np.float64], elevation_rad: NDArray[np.float64],
                  code: NDArray[np.int64], tracks: object) -> GeometryFit | None:
    """Fit one radar's biases, time offset and antenna height against ADS-B (linearised,
    robust, re-aligned at the time offset found)."""
    from graphcal.core import frames
    from graphcal.core.refraction import refracted_polar_jacobian

    three_d = site.is_3d and np.isfinite(elevation_rad).all()
    sigmas = np.where(np.isfinite(site.measurement_sigmas()), site.measurement_sigmas(),
                      np.array(GEOMETRY_DEFAULT_SIGMAS))
    scale = sigmas.copy()
    tau = 0.0
    keep = None
    result = None
    el_ratio = math.nan
    for iteration in range(6):
        j, w, ok = tracks.bracket(code, time_s - tau, GEOMETRY_MAX_GAP_S)  # type: ignore[attr-defined]
        if ok.sum() < MIN_PLOTS:
            return None
        j, w = j[ok], w[ok]
        ecef = tracks.ecef_m  # type: ignore[attr-defined]
        t = tracks.time_s  # type: ignore[attr-defined]
        before, after = take_rows(ecef, j), take_rows(ecef, j + 1)
        ref = (1.0 - w)[:, None] * before + w[:, None] * after
        vel = (after - before) / (t[j + 1] - t[j])[:, None]
        enu = site.enu_from_ecef(ref)
        v_enu = frames.rotate(vel, site.ecef_to_enu)
        ground = np.hypot(enu[:, 0], enu[:, 1])
        good = ground > 1000.0
        if site.atmosphere is not None:
            polar, jac = refracted_polar_jacobian(site.atmosphere, site.lat_rad, site.alt_m,
                                                  np.where(good[:, None], enu, [1e3, 1e3, 0.0]))
        else:
            polar = np.stack(frames.enu_to_polar(enu), axis=-1)
            jac = frames.enu_to_polar_jacobian(np.where(good[:, None], enu, [1e3, 1e3, 0.0]))
        rate = np.einsum("nij,nj->ni", jac, v_enu)
        up = jac[:, :, 2]
        res_r = range_m[ok] - polar[:, 0]
        res_a = frames.wrap_to_pi(azimuth_rad[ok] - polar[:, 1])
        n = int(ok.sum())
        if iteration == 0:  # aircraft labelled with another's address: left out
            far_codes = _far_aircraft(code[ok], res_r, res_a)
        good = good & ~np.isin(code[ok], far_codes)
        zero, one = np.zeros(n), np.ones(n)
        # Unknowns: range offset, gain, azimuth bias, [elevation bias, refraction
        # nuisance,] time-offset step, antenna height correction.
        rows_r = [one, polar[:, 0], zero]
        rows_a = [zero, zero, one]
        blocks = [(res_r, rows_r, -rate[:, 0], -up[:, 0], scale[0]),
                  (res_a, rows_a, -rate[:, 1], -up[:, 1], scale[1])]
        if three_d:
            el = polar[:, 2]
            if iteration == 0:
                judged = good & (np.abs(el) >= math.radians(ELEVATION_MIN_DEG))
                if judged.sum() >= MIN_PLOTS // 2:
                    el_ratio = float(np.median(elevation_rad[ok][judged] / el[judged]))
            bend = np.cos(el) / (np.sin(np.abs(el)) + 0.02)
            rows_r += [zero, zero]
            rows_a += [zero, zero]
            blocks.append((elevation_rad[ok] - el, [zero, zero, zero, one, bend],
                           -rate[:, 2], -up[:, 2], scale[2]))
        design, target, weight = [], [], []
        for res, rows, d_tau, d_h, sig in blocks:
            columns = [*rows, d_tau, d_h]
            design.append(np.stack(columns, axis=1))
            target.append(res)
            weight.append(np.full(n, 1.0 / sig))
        a_mat = np.concatenate(design)
        b_vec = np.concatenate(target)
        wts = np.concatenate(weight)
        use = np.concatenate([good] * len(blocks))
        if keep is not None and keep.shape == use.shape:
            use &= keep
        if use.sum() < a_mat.shape[1] * 5:
            return None
        aw = take_rows(a_mat, use) * wts[use, None]
        bw = b_vec[use] * wts[use]
        # Normal equations on unit-norm columns (an SVD of the tall matrix costs 10x).
        norm = np.sqrt(np.sum(aw**2, axis=0))
        if not np.all(norm > 0):
            return None
        an = aw / norm
        with np.errstate(all="ignore"):
            try:
                cov = np.linalg.inv(an.T @ an) / np.outer(norm, norm)
            except np.linalg.LinAlgError:
                return None
        x = cov @ (aw.T @ bw)
        if not np.all(np.isfinite(x)):
            return None
        z = (b_vec - a_mat @ x) * wts
        robust = []
        for k in range(len(blocks)):
            part = z[k * n:(k + 1) * n][use[k * n:(k + 1) * n]]
            mad = float(np.median(np.abs(part - np.median(part)))) * 1.4826 if part.size else 1.0
            robust.append(max(mad, 1e-9))
        # Rescale each coordinate's weight to its robust scatter, reject outliers.
        scale = scale * np.array(robust + [1.0] * (3 - len(robust)))
        keep = np.concatenate([np.abs(z[k * n:(k + 1) * n]) <= GEOMETRY_REJECT_SIGMAS * robust[k]
                               for k in range(len(blocks))])
        i_tau = 3 + (2 if three_d else 0)
        step = float(x[i_tau])
        tau += step
        chi2 = float(np.sum(z[use] ** 2) / max(use.sum() - len(x), 1))
        sig_tau = float(np.sqrt(cov[i_tau, i_tau] * chi2))
        dh = float(x[i_tau + 1])
        sig_h = float(np.sqrt(cov[i_tau + 1, i_tau + 1] * chi2))
        result = GeometryFit(int(use.sum() // len(blocks)), tau, sig_tau, dh, sig_h, el_ratio)
        if abs(step) < 0.01 and iteration >= 1:
            break
    return result


def adsb_geometry(sites: Mapping[str, Site], plots: pd.DataFrame,
                  adsb: pd.DataFrame) -> dict[str, GeometryFit]:
    """Each radar's time offset against the ADS-B clock and antenna height correction.

    A quick linearised fit of every radar's named plots (at most
    :data:`GEOMETRY_SAMPLE_PLOTS`) against the ADS-B of their aircraft, interpolated
    to the plot times: range offset and gain, azimuth bias, for a 3-D radar the
    elevation bias and a refraction-like term growing towards the horizon, the time
    offset (re-aligned at it, so that offsets of a minute converge), and for a 3-D
    radar the correction ``dh`` to its antenna height, whose signature is an
    elevation residual ``-dh cos(el) / range`` and a range residual ``-dh sin(el)``.

    Returns
    -------
    dict of str to GeometryFit
        Radars with at least :data:`MIN_PLOTS` plots aligned; empty without named
        plots.
    """
    from graphcal.data.align import adsb_track_table

    named = plots[plots["target_id"] != ""]
    if named.empty or adsb is None or adsb.empty:
        return {}
    # A long recording: the half hour around its median plot time is plenty.
    t = named["time_s"].to_numpy(dtype=float)
    middle = float(np.median(t))
    half = GEOMETRY_SPAN_S / 2.0
    named = named[(t >= middle - half) & (t <= middle + half)]
    a_t = adsb["time_s"].to_numpy(dtype=float)
    margin = half + TIME_MARGIN_S + GEOMETRY_MAX_GAP_S
    adsb = adsb[(a_t >= middle - margin) & (a_t <= middle + margin)]
    if named.empty or adsb.empty:
        return {}
    tracks = adsb_track_table(adsb)
    out: dict[str, GeometryFit] = {}
    for rid, rows in named.groupby("radar_id", sort=False).indices.items():
        site = sites.get(str(rid))
        if site is None or len(rows) < MIN_PLOTS:
            continue
        rows = rows[:: max(1, len(rows) // GEOMETRY_SAMPLE_PLOTS)]
        part = named.iloc[rows]
        code = tracks.codes(part["target_id"].to_numpy(dtype=object))
        if (code >= 0).sum() < MIN_PLOTS:
            continue
        fit = _geometry_one(
            site, part["time_s"].to_numpy(dtype=float), part["range_m"].to_numpy(dtype=float),
            np.radians(part["azimuth_deg"].to_numpy(dtype=float)),
            np.radians(part["elevation_deg"].to_numpy(dtype=float, na_value=np.nan)),
            code, tracks)
        if fit is not None:
            out[str(rid)] = fit
    return out


def _time_base(fits: Mapping[str, GeometryFit]) -> Finding | None:
    """Every radar's plots off the ADS-B clock by the same amount, beyond any sensor's."""
    judged = {rid: f for rid, f in fits.items() if f.time_sigma_s < 0.5}
    if not judged:
        return None
    offsets = np.array([f.time_offset_s for f in judged.values()])
    mean = float(np.median(offsets))
    if not (np.all(np.abs(offsets) >= TIME_BASE_LIMIT_S) and np.all(np.sign(offsets) ==
                                                                  np.sign(mean))):
        return None
    if float(np.ptp(offsets)) > TIME_BASE_SPREAD_S + 0.2 * abs(mean):
        return None
    detail = ", ".join(f"{rid} {f.time_offset_s:+.2f} s" for rid, f in judged.items())
    direction = "ahead of" if mean < 0 else "behind"
    who = ("every radar's plots" if len(judged) > 1 else f"radar {next(iter(judged))}'s plots")
    hint = (" (a time-zone, leap-second or GPS-UTC offset, time of reception instead of "
            "applicability?)")
    return Finding("adsb", "time_s",
                   f"the ADS-B reports run {abs(mean):.1f} s {direction} the plots: "
                   f"{who} match the ADS-B of their aircraft at a time offset of "
                   f"{mean:+.2f} s ({detail}; a radar's time-stamping bias is typically under "
                   f"0.1 s): the ADS-B time_s on another clock{hint}"
                   + ("" if len(judged) > 1 else ", or this radar's clock"))


def _antenna_height(sites: Mapping[str, Site], fits: Mapping[str, GeometryFit]
                    ) -> Finding | None:
    """A 3-D radar whose plots put its antenna far from its ``alt_m``."""
    bad = []
    for rid, f in fits.items():
        dh, sig = f.antenna_dh_m, f.antenna_sigma_m
        if not (math.isfinite(dh) and math.isfinite(sig)):
            continue
        if abs(dh) >= ANTENNA_LIMIT_M and abs(dh) >= ANTENNA_SIGMAS * sig:
            bad.append((rid, dh, sig))
    if not bad:
        return None
    shared = _shared_height_error(bad, fits)
    if shared is not None:
        return shared
    parts = []
    for rid, dh, sig in bad:
        given = sites[rid].alt_m
        implied = given + dh
        text = (f"the antenna height (alt_m) of {rid} looks wrong by about {abs(dh):,.0f} m "
                f"(± {sig:.0f}): its plots fit the ADS-B with the antenna at {implied:,.0f} m, "
                f"not {given:,.0f} m")
        if implied > 1.0 and 2.5 <= given / implied <= 4.0:  # near 3.28, with the fit's error
            text += (f" (alt_m is {given / implied:.2f} times that height: feet instead of "
                     "metres?)")
        parts.append(text)
    return Finding("sites", "alt_m",
                   "; ".join(parts) + ". An error of the antenna height would bias the "
                   "elevation and range offsets (elevation residual -dh cos(el)/range, range "
                   "residual -dh sin(el))", tuple(rid for rid, _, _ in bad))


def _shared_height_error(bad: list[tuple[str, float, float]],
                         fits: Mapping[str, GeometryFit]) -> Finding | None:
    """Every judged radar's antenna "wrong" by about the same height, the same way: the
    common reference, the ADS-B heights, is what is off (barometric altitudes, or heights
    above mean sea level, given as ``alt_m``), not every antenna's survey."""
    judged = [f for f in fits.values()
              if math.isfinite(f.antenna_dh_m) and math.isfinite(f.antenna_sigma_m)]
    if len(bad) < 3 or len(bad) < len(judged):
        return None
    values = np.array([dh for _, dh, _ in bad])
    if not (np.all(values > 0) or np.all(values < 0)):
        return None
    mean = float(np.mean(values))
    if float(np.ptp(values)) > 0.6 * abs(mean):
        return None
    detail = ", ".join(f"{rid} {dh:+,.0f} m" for rid, dh, _ in bad)
    return Finding(
        "adsb", "alt_m",
        f"every radar's plots fit the ADS-B only with its antenna about {abs(mean):,.0f} m "
        f"{'higher' if mean > 0 else 'lower'} than sites.toml says ({detail}): one error "
        "shared by every radar is the ADS-B heights' own. alt_m must be the geometric "
        "height above the WGS-84 ellipsoid (ADS-B 'geoaltitude', CAT021 I140); barometric "
        "altitudes (OpenSky 'baroaltitude', flight levels) or heights above mean sea level "
        "are not. Put barometric altitudes in baro_alt_m",
        tuple(rid for rid, _, _ in bad))


def elevation_radians(sites: Mapping[str, Site], plots: pd.DataFrame,
                       fits: Mapping[str, GeometryFit] | None = None) -> Finding | None:
    """A 3-D radar whose elevations look like radians (:data:`ELEVATION_RADIANS_RATIO`).

    With ``fits``, judged on the ADS-B's elevations (:attr:`GeometryFit.elevation_ratio`);
    else on the plots' ``altitude_m`` (or, without it, on how flat they lie).
    """
    three_d = [rid for rid, s in sites.items() if s.is_3d]
    if not three_d:
        return None
    low, high = ELEVATION_RADIANS_RATIO
    bad: list[tuple[str, str]] = []
    rid_code, rid_names = plots["radar_id"].factorize()
    elevation = plots["elevation_deg"].to_numpy(dtype=float, na_value=np.nan)
    for rid in three_d:
        where = np.flatnonzero(rid_names == rid)
        if not where.size:
            continue
        mine = rid_code == where[0]
        el = elevation[mine]
        el = el[np.isfinite(el)]
        if el.size < MIN_PLOTS or np.abs(el).max() >= math.pi / 2:
            continue
        if fits is not None:
            fit = fits.get(rid)
            ratio = math.nan if fit is None else fit.elevation_ratio
            if low <= ratio <= high:
                bad.append((rid, f"{ratio:.3g} times those the ADS-B positions of its "
                                 f"aircraft give"))
            continue
        slant = plots["range_m"].to_numpy(dtype=float)[mine]
        meas = elevation[mine]
        height = (plots["altitude_m"].to_numpy(dtype=float, na_value=np.nan)[mine]
                  if "altitude_m" in plots else np.full(int(mine.sum()), np.nan))
        ok = np.isfinite(height) & np.isfinite(meas) & (slant > 5000.0)
        if ok.sum() >= MIN_PLOTS:
            sin_el = ((height[ok] - sites[rid].alt_m) / slant[ok]
                      - slant[ok] / (2.0 * EFFECTIVE_EARTH_RADIUS_M))
            expected = np.degrees(np.arcsin(np.clip(sin_el, -1.0, 1.0)))
            judged = np.abs(expected) >= ELEVATION_MIN_DEG
            if judged.sum() >= MIN_PLOTS // 2:
                ratio = float(np.median(meas[ok][judged] / expected[judged]))
                if low <= ratio <= high:
                    bad.append((rid, f"{ratio:.3g} times those its plots' altitude_m give "
                                     "at their ranges"))
                continue
        near, far = ELEVATION_RANGE_M
        inside = np.isfinite(meas) & (slant >= near) & (slant <= far)
        if inside.sum() < MIN_PLOTS:
            continue
        flat = float(np.quantile(np.abs(meas[inside]), 0.9))
        if flat < ELEVATION_FLAT_DEG:
            bad.append((rid, f"within {flat:.2g} of the horizon for 90 % of its plots at "
                             f"{near / 1e3:.0f}-{far / 1e3:.0f} km (aircraft there are seen "
                             "at 0.3-30 deg)"))
    if not bad:
        return None
    detail = "; ".join(f"radar {rid} are {what}" for rid, what in bad)
    return Finding("plots", "elevation_deg",
                   f"the elevations of 3-D {detail}, and every |elevation| is below pi/2 "
                   "(pi/180 is 0.0175): elevation_deg in radians instead of degrees?",
                   tuple(rid for rid, _ in bad))


def _middle_block(table: pd.DataFrame, rows: int = TIME_SAMPLE_ROWS) -> pd.DataFrame:
    """At most ``rows`` successive rows from the middle of ``table`` (rows of one aircraft
    stay together, unlike :func:`_thinned`)."""
    if len(table) <= rows:
        return table
    start = (len(table) - rows) // 2
    return table.iloc[start:start + rows]


def _successive(key: NDArray[np.int64], time_s: NDArray[np.float64]
                ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Row pairs ``(i, j)``: ``j`` the next row in time with ``i``'s key (keys < 0: none)."""
    order = np.lexsort((time_s, key))
    ordered = key[order]
    same = (ordered[1:] == ordered[:-1]) & (ordered[1:] >= 0)
    return order[:-1][same], order[1:][same]


def _plot_time_unit(sites: Mapping[str, Site], plots: pd.DataFrame) -> Finding | None:
    """Plots of one aircraft at one radar :data:`MS_SCAN_RATIO` scan periods apart: ms."""
    block = _middle_block(plots)
    tid, aircraft = block["target_id"].factorize()
    rid, names = block["radar_id"].factorize()
    unnamed = np.flatnonzero(aircraft == "")
    key = rid.astype(np.int64) * (len(aircraft) + 1) + tid
    key[tid < 0] = -1
    if unnamed.size:
        key[tid == unnamed[0]] = -1
    if (key >= 0).sum() < MIN_PLOTS:
        return None
    t = block["time_s"].to_numpy(dtype=float)
    i, j = _successive(key, t)
    dt = t[j] - t[i]
    ok = dt > 0
    code, dt = rid[i][ok], dt[ok]
    bad = []
    for k, name in enumerate(names):
        site = sites.get(str(name))
        mine = dt[code == k]
        if site is None or mine.size < MIN_PLOTS:
            continue
        gap = float(np.median(mine))
        period = float(site.scan_period_s or DEFAULT_SCAN_PERIOD_S)
        if gap >= MS_SCAN_RATIO * period:
            bad.append((str(name), gap, period))
    if not bad:
        return None
    bad.sort()
    ratio = float(np.median([gap / period for _, gap, period in bad]))
    detail = ", ".join(f"{name} {_fmt(gap)} s (scan {period:g} s)"
                       for name, gap, period in bad)
    return Finding("plots", "time_s",
                   f"the successive plots of one aircraft at a radar are about {ratio:,.0f} "
                   f"times its scan period apart (median; {detail}): time_s in milliseconds "
                   "instead of seconds?", tuple(n for n, _, _ in bad))


def _adsb_time_unit(adsb: pd.DataFrame) -> Finding | None:
    """ADS-B reports of moving aircraft far apart in time, at a snail's pace: ms."""
    block = _middle_block(adsb)
    t = block["time_s"].to_numpy(dtype=float)
    i, j = _successive(block["target_id"].factorize()[0].astype(np.int64), t)
    dt = t[j] - t[i]
    lat = np.radians(block["lat_deg"].to_numpy(dtype=float))
    lon = np.radians(block["lon_deg"].to_numpy(dtype=float))
    step = EARTH_RADIUS_M * np.hypot(lat[j] - lat[i],
                                     (lon[j] - lon[i]) * np.cos(lat[i]))
    moving = (dt > 0) & (step > MS_ADSB_MOVE_M)
    if moving.sum() < MIN_PLOTS:
        return None
    gap = float(np.median(dt[moving]))
    speed = float(np.median(step[moving] / dt[moving]))
    if gap < MS_ADSB_GAP_S or speed >= MS_ADSB_SPEED_MPS:
        return None
    return Finding("adsb", "time_s",
                   f"the successive ADS-B reports of one moving aircraft are {_fmt(gap)} s "
                   f"apart (median; reports come every 0.5-10 s), and the aircraft move at "
                   f"{speed:.2g} m/s between them (aircraft fly at 50-300 m/s): time_s in "
                   "milliseconds instead of seconds?")


def midnight_wrap(time_s: NDArray[np.float64]) -> tuple[tuple[float, float],
                                                        tuple[float, float]] | None:
    """The two parts of times of the day that wrap at midnight, or ``None``.

    Times all within one day (0..86,400 s), some within :data:`WRAP_EDGE_S` of its
    start and some of its end, with no time at all in the half day between them: a
    recording across midnight stamped with seconds of the day.

    Returns
    -------
    ((float, float), (float, float)) or None
        The span before midnight and the span after it [s].
    """
    t = time_s[np.isfinite(time_s)]
    if t.size < 2:
        return None
    t0, t1 = float(t.min()), float(t.max())
    if t0 < 0.0 or t1 >= DAY_S or t0 > WRAP_EDGE_S or t1 < DAY_S - WRAP_EDGE_S:
        return None
    s = np.sort(t[:: max(1, t.size // SAMPLE_ROWS)])
    k = int(np.argmax(np.diff(s)))
    if s[k + 1] - s[k] < DAY_S / 2:
        return None
    return (float(s[k + 1]), t1), (t0, float(s[k]))


def wrap_text(parts: tuple[tuple[float, float], tuple[float, float]]) -> str:
    """The two parts of :func:`midnight_wrap` for a message (tenths, cut, not rounded)."""
    b0, b1, a0, a1 = (f"{math.floor(v * 10.0) / 10.0:,.1f}" for pair in parts for v in pair)
    return f"{b0}..{b1} s, then {a0}..{a1} s"


def _midnight(plots: pd.DataFrame, adsb: pd.DataFrame) -> Finding | None:
    """One table's seconds of the day wrap at midnight, the other's do not."""
    tp = plots["time_s"].to_numpy(dtype=float)
    ta = adsb["time_s"].to_numpy(dtype=float)
    wp, wa = midnight_wrap(tp), midnight_wrap(ta)
    if (wp is None) == (wa is None):
        return None
    wrapped, other, table = (("plots'", "ADS-B's", "plots") if wp is not None
                             else ("ADS-B's", "plots'", "adsb"))
    parts = wp if wp is not None else wa
    t = ta if wp is not None else tp
    if parts is None or not np.nanmax(t) >= DAY_S:  # the other does not run on past midnight
        return None
    return Finding(table, "time_s",
                   f"the {wrapped} time_s wrap at midnight ({wrap_text(parts)}), the "
                   f"{other} do not ({np.nanmin(t):,.1f}..{np.nanmax(t):,.1f} s): seconds "
                   "of the day in one table, a time that runs on in the other? "
                   f"(add {_fmt(DAY_S)} s to the {wrapped} times after midnight)")


def _thinned(table: pd.DataFrame, rows: int = SAMPLE_ROWS) -> pd.DataFrame:
    """Every k-th row, at most about ``rows`` rows (deterministic)."""
    step = max(1, len(table) // rows)
    return table if step == 1 else table.iloc[::step]


# --------------------------------------------------------------------------- public
def check_time_overlap(plots_span: tuple[float, float],
                       adsb_span: tuple[float, float] | None) -> Finding | None:
    """A finding when the ADS-B reports do not overlap the plots in time.

    Parameters
    ----------
    plots_span, adsb_span : (float, float)
        First and last time [s] of each table (``adsb_span`` ``None`` without ADS-B,
        or NaN when the table has no time).
    """
    if adsb_span is None or not all(map(math.isfinite, (*plots_span, *adsb_span))):
        return None
    (p0, p1), (a0, a1) = plots_span, adsb_span
    if a1 >= p0 - TIME_MARGIN_S and a0 <= p1 + TIME_MARGIN_S:
        return None
    offset = a0 - p0
    hint = ""
    hours = offset / 3600.0
    if abs(hours) < 48 and abs(hours - round(hours)) < 0.02:
        hint = f" ({round(hours):+d} h apart: local time against UTC?)"
    elif abs(offset) > 1e8:
        hint = " (UNIX time against seconds of the day?)"
    return Finding("adsb", "time_s",
                   f"the ADS-B reports ({_fmt(a0)}..{_fmt(a1)} s) do not overlap the plots "
                   f"({_fmt(p0)}..{_fmt(p1)} s) in time, so they would go unused: another "
                   f"time base{hint}")


def check_tables(sites: Mapping[str, Site], plots: pd.DataFrame,
                 adsb: pd.DataFrame | None, *, time_overlap: bool = True) -> list[Finding]:
    """Every unit and frame heuristic of the module docstring on validated tables.

    Parameters
    ----------
    sites : mapping of str to Site
        The radars.
    plots : pandas.DataFrame
        Validated plots (contract columns).
    adsb : pandas.DataFrame or None
        Validated ADS-B reports.
    time_overlap : bool, optional
        Also check that the two tables overlap in time (a reader of one time
        window at a time checks the whole tables' spans instead).

    Returns
    -------
    list of Finding
        Empty when nothing looks wrong; at most one finding per field.
    """
    if plots.empty:
        return []
    findings: list[Finding | None] = []
    antenna: Finding | None = None
    plots_sample = _thinned(plots)
    stats = _per_radar(plots)
    azimuth, ranges = _azimuth_radians(stats), _range_km(stats)
    findings += [azimuth, ranges]
    # Elevations in radians fake a wrong antenna height: judged first, and it replaces
    # that finding.  On the plots' heights here, on the ADS-B below when they have none.
    elevation = elevation_radians(sites, plots_sample)
    findings.append(elevation)
    time_unit = [_plot_time_unit(sites, plots)]
    if adsb is not None and len(adsb):
        time_unit.append(_adsb_time_unit(adsb))
        if time_overlap:
            time_unit.append(_midnight(plots, adsb))
    time_unit = [f for f in time_unit if f is not None]
    findings += time_unit
    skip = set(ranges.radars) if ranges is not None else set()
    plot_feet = (_heights_feet(plots["altitude_m"], "plots", "altitude_m")
                 or _flight_levels(plots["altitude_m"]) if "altitude_m" in plots else None)
    findings.append(plot_feet)
    if adsb is not None and len(adsb):
        adsb_feet = _heights_feet(adsb["alt_m"], "adsb", "alt_m")
        if adsb_feet is None and plot_feet is None:
            ratio = _height_ratio(plots_sample, _thinned(adsb))
            adsb_feet = ratio if ratio is not None and ratio.table == "adsb" else None
            plot_feet = ratio if ratio is not None and ratio.table == "plots" else None
            findings.append(plot_feet)
        findings.append(adsb_feet)
        if "baro_alt_m" in adsb:
            findings.append(_heights_feet(adsb["baro_alt_m"], "adsb", "baro_alt_m"))
        if time_overlap and not time_unit:
            a = adsb["time_s"]
            findings.append(check_time_overlap(
                (float(plots["time_s"].min()), float(plots["time_s"].max())),
                (float(a.min()), float(a.max()))))
        coverage = _coverage(sites, plots_sample, _thinned(adsb, COVERAGE_SAMPLE_ROWS),
                             stats, skip)
        findings.append(coverage)
        if coverage is None and azimuth is None and ranges is None and adsb_feet is None \
                and plot_feet is None and elevation is None and not time_unit:
            with np.errstate(all="ignore"):
                fits = adsb_geometry(sites, plots, adsb)
            elevation = elevation_radians(sites, plots_sample, fits)
            findings.append(elevation)
            findings.append(_time_base(fits))
            antenna = None if elevation is not None else _antenna_height(sites, fits)
    if plot_feet is None:
        site_altitude = _site_altitude(sites, plots, skip)
    else:
        site_altitude = _site_altitude(sites, plots.iloc[:0], skip)
    # One finding per field: the bounds and reach of alt_m first, then its fit to ADS-B.
    findings.append(site_altitude if site_altitude is not None else antenna)
    return [f for f in findings if f is not None]


#: What the error says to do about a finding.
FORCE_HINT = "check the data; --force, or force=True in Python, proceeds anyway"


def raise_if_implausible(findings: Sequence[Finding], paths: Mapping[str, Path | str]) -> None:
    """Raise one :class:`~graphcal.core.errors.ImplausibleDataError` for the findings.

    Parameters
    ----------
    findings : sequence of Finding
        From :func:`check_tables` (and :func:`check_time_overlap`); nothing is raised
        when empty.
    paths : mapping of str to Path
        The file (or folder of parts) of each table: ``"plots"``, ``"adsb"``,
        ``"sites"``.

    Raises
    ------
    ImplausibleDataError
        Naming the first finding's file and field, its message, the others after
        it, and what to do (:data:`FORCE_HINT`); ``findings`` holds them all.
    """
    if not findings:
        return
    first, rest = findings[0], findings[1:]
    message = first.message
    for other in rest:
        message += f"; also {paths.get(other.table, other.table)}, field '{other.field}': " \
                   f"{other.message}"
    raise ImplausibleDataError(f"{message} ({FORCE_HINT})", path=paths.get(first.table),
                               field=first.field, findings=list(findings))


__all__ = [
    "COVERAGE_MARGIN_M",
    "FEET_HEIGHT_M",
    "FEET_RATIO",
    "FORCE_HINT",
    "MAX_KM_RANGE_M",
    "ANTENNA_LIMIT_M",
    "TIME_BASE_LIMIT_S",
    "GeometryFit",
    "adsb_geometry",
    "MIN_PLOTS",
    "SITE_ALT_RANGE_M",
    "Finding",
    "check_tables",
    "elevation_radians",
    "check_time_overlap",
    "ground_distance_m",
    "midnight_wrap",
    "wrap_text",
    "raise_if_implausible",
]
