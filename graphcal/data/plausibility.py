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
``time_s`` (ADS-B)    the ADS-B reports and the plots do not overlap in time
                      (:func:`check_time_overlap`; another time base: the ADS-B
                      would go unused)
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
    """Per radar: plots, aircraft named (0: none), largest azimuth [deg] and range [m]."""
    named = plots["target_id"].where(plots["target_id"] != "")
    return plots.assign(_named=named).groupby("radar_id", sort=False).agg(
        n=("range_m", "size"), aircraft=("_named", "nunique"),
        az_max=("azimuth_deg", "max"), r_max=("range_m", "max"))


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


def _median_height(frame: pd.DataFrame, column: str) -> pd.Series:
    """Median height per aircraft (``target_id``), finite values of named aircraft only."""
    values = frame[column].to_numpy(dtype=float, na_value=np.nan)
    ok = np.isfinite(values) & (frame["target_id"].to_numpy() != "")
    return pd.Series(values[ok]).groupby(frame["target_id"].to_numpy()[ok]).median()


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
    rid_col = plots["radar_id"].to_numpy()
    height = plots["altitude_m"].to_numpy(dtype=float, na_value=np.nan)
    slant = plots["range_m"].to_numpy(dtype=float)
    antenna = pd.Series({rid: s.alt_m for rid, s in sites.items()})
    site_alt = antenna.reindex(rid_col).to_numpy(dtype=float)
    ok = np.isfinite(height) & np.isfinite(site_alt) & ~np.isin(rid_col, list(skip))
    if not ok.any():
        return None
    beyond = np.abs(height[ok] - site_alt[ok]) > slant[ok] + GEOMETRY_MARGIN_M
    counts = pd.DataFrame({"rid": rid_col[ok], "beyond": beyond}).groupby("rid")["beyond"].agg(
        ["size", "mean"])
    bad = counts[(counts["size"] >= MIN_PLOTS) & (counts["mean"] > GEOMETRY_FRACTION)]
    if bad.empty:
        return None
    names = ", ".join(f"{rid} ({_fmt(sites[str(rid)].alt_m)} m: {frac:.0%} of its plots)"
                      for rid, frac in zip(bad.index, bad["mean"], strict=True))
    return Finding("sites", "alt_m",
                   f"antenna height of radar {names} differs from the plots' altitude_m by more "
                   "than their slant range, which no geometry allows: alt_m wrong (another "
                   "unit, a typing error)?", tuple(str(r) for r in bad.index))


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
    named = plots[plots["radar_id"].isin(list(reach)) & (plots["target_id"] != "")]
    spans = (named.groupby(["radar_id", "target_id"], sort=False)["time_s"]
             .agg(t0="min", t1="max").reset_index())
    reports = adsb[["target_id", "time_s", "lat_deg", "lon_deg"]]
    joined = reports.merge(spans, on="target_id")
    joined = joined[(joined["time_s"] >= joined["t0"]) & (joined["time_s"] <= joined["t1"])]
    covered: dict[str, tuple[float, float]] = {}
    for rid, group in joined.groupby("radar_id", sort=False):
        if len(group) < MIN_REPORTS:
            continue
        site = sites[str(rid)]
        d = ground_distance_m(group["lat_deg"].to_numpy(dtype=float),
                              group["lon_deg"].to_numpy(dtype=float), site.lat_rad, site.lon_rad)
        covered[str(rid)] = (float(np.mean(d <= reach[str(rid)])), float(np.median(d)))
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
    plots_sample = _thinned(plots)
    stats = _per_radar(plots)
    azimuth, ranges = _azimuth_radians(stats), _range_km(stats)
    findings += [azimuth, ranges]
    skip = set(ranges.radars) if ranges is not None else set()
    plot_feet = (_heights_feet(plots["altitude_m"], "plots", "altitude_m")
                 if "altitude_m" in plots else None)
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
        if time_overlap:
            a = adsb["time_s"]
            findings.append(check_time_overlap(
                (float(plots["time_s"].min()), float(plots["time_s"].max())),
                (float(a.min()), float(a.max()))))
        findings.append(_coverage(sites, plots_sample, _thinned(adsb, COVERAGE_SAMPLE_ROWS),
                                  stats, skip))
    if plot_feet is None:
        findings.append(_site_altitude(sites, plots, skip))
    else:
        findings.append(_site_altitude(sites, plots.iloc[:0], skip))
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
    "MIN_PLOTS",
    "SITE_ALT_RANGE_M",
    "Finding",
    "check_tables",
    "check_time_overlap",
    "ground_distance_m",
    "raise_if_implausible",
]
