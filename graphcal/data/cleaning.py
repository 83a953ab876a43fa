"""Detection and removal of bad data before a calibration.

Real recordings carry defects that a least-squares calibration would absorb
into confidently wrong biases.  Each function here finds one kind of defect,
returns the cleaned table and a :class:`CleaningReport` with the number of rows
it removed or changed (per reason) and plain-English warnings for what the
user should know about.  :func:`clean_dataset` runs them all, in this order:

1. rows with NaN or infinite values in required columns (plots and ADS-B), and plots
   whose range is negative or beyond :data:`MAX_PLOT_RANGE_M` (2,000 km: a corrupt
   value, with a warning naming the first such row); ADS-B reports whose only missing
   value is ``alt_m`` (a source without a geometric height, such as CAT021 without
   I021/140) are counted apart, with a warning; a table none of whose reports has a
   geometric height leaves the calibration without ADS-B, with a warning;
2. exact duplicate rows (plots and ADS-B);
3. stale ADS-B reports: the previous horizontal position of the same aircraft
   repeated at a later time;
4. ADS-B kinematic gating per aircraft and flight: isolated wild reports are
   dropped; a flight whose positions jump and stay offset (spoofing, two
   aircraft under one address) loses all its ADS-B reports, with a warning;
5. identity check: per radar, an aircraft whose plots sit far from its ADS-B
   positions while the radar's other aircraft agree (after removing what the
   radar's biases can explain) carries a wrong address or a second transponder;
   those plots lose their ``target_id``;
6. coverage checks that only warn: radars without plots, 2-D radars whose
   plots carry no altitude when there is no ADS-B, and groups of radars with
   no aircraft in common when there is no ADS-B;
7. time-stamp checks that only warn (:func:`time_stamp_warnings`): a table whose
   times are quantised (whole seconds, or multiples of a step of at least
   0.1 s: timing noise the stated sigmas leave out), and times of the day that
   wrap at midnight in both tables alike.

Tables keep the contract's columns and units (degrees, metres, seconds); the
rows kept are in their original order with a fresh ``RangeIndex``.  Nothing is
written anywhere.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from graphcal.core import frames
from graphcal.core.grouped import group_medians, group_order, group_rows
from graphcal.core.rows import take_rows

if TYPE_CHECKING:
    from graphcal.data.dataset import Dataset, Site

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Fastest credible ground speed of an aircraft [m/s] for the ADS-B speed gate.
DEFAULT_MAX_SPEED_MPS = 700.0
#: Largest credible acceleration of an aircraft [m/s^2] (about 2 g) for single wild reports.
DEFAULT_MAX_ACCEL_MPS2 = 20.0
#: A gap longer than this [s] between an aircraft's ADS-B reports starts a new flight.
DEFAULT_FLIGHT_GAP_S = 600.0
#: Noise allowance of the speed gate, in 1-sigma ADS-B position errors.
DEFAULT_GATE_SIGMAS = 5.0
#: A run of at most this many reports between two jumps is treated as wild reports.
DEFAULT_MAX_WILD_RUN = 3
#: Aircraft with fewer ADS-B reports are not judged by the kinematic gate.
DEFAULT_MIN_TRACK_REPORTS = 10
#: Identity check: smallest per-aircraft offset [m] from the radar's consensus to flag.
DEFAULT_IDENTITY_FLOOR_M = 3000.0
#: Identity check: robust z-score above which an aircraft's offset is flagged.
DEFAULT_IDENTITY_Z = 6.0
#: Identity check: aircraft needed per radar to form a consensus.
DEFAULT_IDENTITY_MIN_AIRCRAFT = 4
#: Identity check: plots an aircraft needs (on one radar) to be judged.
DEFAULT_IDENTITY_MIN_PLOTS = 5
#: Longest gap [s] between two ADS-B reports bridged when interpolating to plot times.
DEFAULT_MAX_GAP_S = 10.0
#: Longest slant range [m] a plot may have: beyond any radar's reach (a radar 9 km up
#: sees a target 30 km up at under 1,000 km; paper 002's scenario, without earth
#: masking, reaches 1,111 km).  A larger range is a corrupt value or another unit.
MAX_PLOT_RANGE_M = 2_000_000.0
#: ADS-B horizontal sigma [m] used when the table has no ``sigma_m`` column.
_FALLBACK_SIGMA_M = 30.0

#: Plot columns that must be finite (``elevation_deg`` only for 3-D radars).
_PLOT_REQUIRED = ("time_s", "range_m", "azimuth_deg")
#: ADS-B columns that must be finite (``alt_m`` is counted apart when only it is missing).
_ADSB_REQUIRED = ("time_s", "lat_deg", "lon_deg")
#: Columns that identify a plot (exact duplicates agree on all of them).
_PLOT_KEY = ("radar_id", "time_s", "range_m", "azimuth_deg", "elevation_deg", "target_id")
#: Columns that identify an ADS-B report.
_ADSB_KEY = ("target_id", "time_s", "lat_deg", "lon_deg", "alt_m")

#: Plain-English description of each count, for :meth:`CleaningReport.summary`.
REASONS: dict[str, str] = {
    "plots_non_finite": "plots with a missing or infinite required value dropped",
    "plots_out_of_range": "plots with a range beyond any radar's reach (or negative) dropped",
    "plots_duplicate": "exact duplicate plots dropped",
    "plots_identity_cleared": "plots whose target_id disagrees with its ADS-B: id cleared",
    "adsb_non_finite": "ADS-B reports with a missing or infinite required value dropped",
    "adsb_no_height": "ADS-B reports without a geometric height (alt_m) not used",
    "adsb_duplicate": "exact duplicate ADS-B reports dropped",
    "adsb_stale": "stale ADS-B reports (previous horizontal position repeated) dropped",
    "adsb_wild": "isolated wild ADS-B reports (impossible speed or turn) dropped",
    "adsb_jumping_aircraft": "ADS-B reports of flights whose positions jump and stay off dropped",
}


@dataclass
class CleaningReport:
    """What cleaning removed or changed, and why.

    Attributes
    ----------
    counts : dict of str to int
        Rows removed (or changed, for ``plots_identity_cleared``) per reason;
        keys from :data:`REASONS`, every key present.
    warnings : list of str
        Plain-English warnings, one line each (an aircraft's ADS-B dropped, a
        mislabelled aircraft, a radar without plots, ...).
    jumping_aircraft : list of str
        Addresses whose ADS-B was dropped by the kinematic gate.
    mislabelled : list of tuple
        ``(radar_id, target_id, offset_m)`` of each aircraft whose plots had
        their ``target_id`` cleared; ``offset_m`` is its distance from the
        radar's consensus [m].
    notes : list of str
        Warnings that :meth:`summary` repeats after the counts, because they change
        what the calibration can do (no ADS-B left); also in ``warnings``.
    """

    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REASONS, 0))
    warnings: list[str] = field(default_factory=list)
    jumping_aircraft: list[str] = field(default_factory=list)
    mislabelled: list[tuple[str, str, float]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def merge(self, other: CleaningReport) -> None:
        """Add ``other``'s counts, warnings and findings to this report."""
        for key, value in other.counts.items():
            self.counts[key] = self.counts.get(key, 0) + value
        self.warnings.extend(other.warnings)
        self.jumping_aircraft.extend(other.jumping_aircraft)
        self.mislabelled.extend(other.mislabelled)
        self.notes.extend(other.notes)

    @property
    def n_changed(self) -> int:
        """Total rows removed or changed."""
        return int(sum(self.counts.values()))

    def summary(self) -> list[str]:
        """One plain-English line per non-zero count, e.g. ``"12 exact duplicate plots dropped"``,
        then the :attr:`notes`.

        Returns
        -------
        list of str
        """
        counts = [f"{n} {REASONS.get(key, key)}" for key, n in self.counts.items() if n]
        return counts + list(self.notes)

    def to_dict(self) -> dict[str, object]:
        """JSON-ready form (for a result's ``info``)."""
        return {
            "counts": {key: int(n) for key, n in self.counts.items()},
            "warnings": list(self.warnings),
            "jumping_aircraft": list(self.jumping_aircraft),
            "mislabelled": [
                {"radar_id": r, "target_id": t, "offset_m": float(o)}
                for r, t, o in self.mislabelled
            ],
        }


def _report(**counts: int) -> CleaningReport:
    report = CleaningReport()
    report.counts.update(counts)
    return report


def _keep(table: pd.DataFrame, keep: BoolArray) -> pd.DataFrame:
    """Rows of ``table`` where ``keep``, in their order, with a fresh ``RangeIndex``."""
    if keep.all():
        return table.reset_index(drop=True)
    return table.loc[keep].reset_index(drop=True)


def _column(table: pd.DataFrame, name: str) -> FloatArray:
    """A column as floats, NaN where missing or not a number (a read-only view of a
    ``float64`` column, which ``pd.to_numeric`` would give back as it is)."""
    values = table[name]
    if values.dtype == np.float64:
        return values.to_numpy(dtype=float, na_value=np.nan)
    return pd.to_numeric(values, errors="coerce").to_numpy(dtype=float, na_value=np.nan)


@dataclass(frozen=True)
class _Text:
    """A text column as integer codes, found once and kept through the cleaning.

    Attributes
    ----------
    codes : ndarray of int
        ``pd.factorize(column.astype(str))`` of the column as it was read (-1 where
        missing), then the codes of the rows kept by each step.
    names : pandas.Index
        The text of each code (some unused once rows are dropped).
    fresh : bool
        No row has been dropped since: the codes are still in order of first
        appearance, without unused ones, as ``pd.factorize`` gives them.
    exact : bool
        The column holds text (a string dtype), which ``astype(str)`` leaves as it
        is: equal codes are equal values of the column itself, not only of its text.
    """

    codes: NDArray[np.intp]
    names: pd.Index
    fresh: bool
    exact: bool

    @classmethod
    def of(cls, column: pd.Series) -> _Text:
        """The codes of a column (``pd.factorize`` of its text)."""
        codes, names = pd.factorize(column.astype(str))
        exact = pd.api.types.is_string_dtype(column.dtype) and column.dtype != object
        return cls(codes, pd.Index(names), True, exact)

    def kept(self, keep: BoolArray) -> _Text:
        """The codes of the rows where ``keep``."""
        if keep.all():
            return self
        return _Text(self.codes[keep], self.names, False, self.exact)

    def where(self, of_name: BoolArray) -> BoolArray:
        """Per row, ``of_name`` of its text (one value per name); ``False`` where missing."""
        return np.append(np.asarray(of_name, dtype=bool), False)[self.codes]

    def counts(self) -> dict[str, int]:
        """Rows per text (as ``column.astype(str).value_counts()``, zeros included)."""
        present = self.codes[self.codes >= 0]
        sizes = np.bincount(present, minlength=len(self.names))
        return {str(name): int(size) for name, size in zip(self.names, sizes, strict=True)}


# --------------------------------------------------------------------------- non-finite
def drop_non_finite_plots(
    plots: pd.DataFrame, sites: Mapping[str, Site] | None = None
) -> tuple[pd.DataFrame, CleaningReport]:
    """Drop plots with a NaN or infinite time, range or azimuth (or elevation of a 3-D radar).

    An infinite ``altitude_m`` (optional column) is set to NaN, i.e. "not
    given"; the plot is kept.

    Parameters
    ----------
    plots : pandas.DataFrame
        Plots table (contract columns; degrees, metres, seconds).
    sites : mapping of str to Site, optional
        Sites by id, to know which radars are 3-D.

    Returns
    -------
    plots : pandas.DataFrame
        The plots kept.
    report : CleaningReport
        ``counts["plots_non_finite"]``.
    """
    bad = _non_finite_plots(plots, sites, None)
    return _infinite_to_nan(_keep(plots, ~bad)), _report(plots_non_finite=int(bad.sum()))


def _non_finite_plots(plots: pd.DataFrame, sites: Mapping[str, Site] | None,
                      radar: _Text | None) -> BoolArray:
    """:func:`drop_non_finite_plots`'s rows to drop (``radar``: the ``radar_id`` codes,
    when known)."""
    bad = np.zeros(len(plots), dtype=bool)
    for name in _PLOT_REQUIRED:
        bad |= ~np.isfinite(_column(plots, name))
    if sites is not None and "elevation_deg" in plots:
        three_d = [rid for rid, site in sites.items() if site.is_3d]
        if radar is not None and radar.exact:
            is_3d = radar.where(radar.names.isin(three_d))
        else:
            is_3d = plots["radar_id"].isin(three_d).to_numpy(dtype=bool)
        bad |= is_3d & ~np.isfinite(_column(plots, "elevation_deg"))
    return bad


def _infinite_to_nan(plots: pd.DataFrame) -> pd.DataFrame:
    """The plots with an infinite ``altitude_m`` or ``elevation_deg`` set to NaN (in place)."""
    for name in ("altitude_m", "elevation_deg"):
        if name in plots:
            values = _column(plots, name)
            if np.isinf(values).any():
                plots[name] = np.where(np.isinf(values), np.nan, values)
    return plots


def drop_out_of_range_plots(
    plots: pd.DataFrame, max_range_m: float = MAX_PLOT_RANGE_M
) -> tuple[pd.DataFrame, CleaningReport]:
    """Drop plots whose range is negative or beyond ``max_range_m`` (beyond any radar).

    Loading a folder refuses such rows (:mod:`graphcal.io.table_checks`); a dataset
    built in memory may still have them, and one range of 1e300 m would overflow
    every sum it enters.  The warning names the first such row (its position in
    ``plots``), its radar and its value.

    Returns
    -------
    plots : pandas.DataFrame
        The plots kept.
    report : CleaningReport
        ``counts["plots_out_of_range"]`` and one warning when any were dropped.
    """
    bad, report = _out_of_range_plots(plots, max_range_m)
    return _keep(plots, ~bad), report


def _out_of_range_plots(plots: pd.DataFrame, max_range_m: float
                        ) -> tuple[BoolArray, CleaningReport]:
    """:func:`drop_out_of_range_plots`'s rows to drop, and its report."""
    r = _column(plots, "range_m")
    bad = np.isfinite(r) & ((r < 0.0) | (r > max_range_m))
    report = _report(plots_out_of_range=int(bad.sum()))
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        report.warnings.append(
            f"{int(bad.sum())} plot(s) with a range beyond any radar's reach "
            f"({max_range_m / 1e3:,.0f} km) or negative dropped, the first row "
            f"{plots.index[first]} of radar {plots['radar_id'].iloc[first]} "
            f"(range_m {r[first]:.6g}): corrupt values?")
    return bad, report


def drop_non_finite_adsb(adsb: pd.DataFrame) -> tuple[pd.DataFrame, CleaningReport]:
    """Drop ADS-B reports with a NaN or infinite time, position or height, or no ``target_id``.

    A non-finite or non-positive ``sigma_m`` also drops the report.  A report whose
    only missing value is its geometric height ``alt_m`` (NaN: a source that carries
    none, such as a CAT021 report without I021/140) is dropped too, but counted apart
    and explained in a warning that says how many of them carry a pressure altitude
    (``baro_alt_m``): a calibration places an ADS-B report by its height above the
    ellipsoid, which a flight level is not.

    Returns
    -------
    adsb : pandas.DataFrame
        The reports kept.
    report : CleaningReport
        ``counts["adsb_non_finite"]``, ``counts["adsb_no_height"]`` and, when the
        latter is not zero, one warning.
    """
    drop, report = _non_finite_adsb(adsb, _Text.of(adsb["target_id"]))
    return _keep(adsb, ~drop), report


def _non_finite_adsb(adsb: pd.DataFrame, target: _Text) -> tuple[BoolArray, CleaningReport]:
    """:func:`drop_non_finite_adsb`'s rows to drop, and its report (``target``: the
    ``target_id`` codes)."""
    bad = np.zeros(len(adsb), dtype=bool)
    for name in _ADSB_REQUIRED:
        bad |= ~np.isfinite(_column(adsb, name))
    if "sigma_m" in adsb:
        sigma = _column(adsb, "sigma_m")
        bad |= ~(np.isfinite(sigma) & (sigma > 0.0))
    bad |= target.where(target.names.str.strip() == "")
    alt = _column(adsb, "alt_m")
    bad |= np.isinf(alt)
    no_height = np.isnan(alt) & ~bad
    report = _report(adsb_non_finite=int(bad.sum()), adsb_no_height=int(no_height.sum()))
    if no_height.any():
        baro = (np.isfinite(_column(adsb, "baro_alt_m")) & no_height if "baro_alt_m" in adsb
                else np.zeros(len(adsb), dtype=bool))
        report.warnings.append(
            f"{int(no_height.sum())} ADS-B reports without a geometric height (alt_m) not "
            "used: a calibration needs the height above the ellipsoid to place a report "
            "(a source such as CAT021 without I021/140 gives none, and a pressure altitude "
            f"is not one); {int(baro.sum())} of them carry baro_alt_m")
    return bad | no_height, report


# --------------------------------------------------------------------------- duplicates
def drop_duplicate_plots(plots: pd.DataFrame) -> tuple[pd.DataFrame, CleaningReport]:
    """Drop exact duplicate plots: same radar, target, time, range, azimuth and elevation.

    The first of each set of duplicates is kept.  Two plots of the same radar,
    target and time with different values are both kept (they are not
    duplicates of one record).

    Returns
    -------
    plots : pandas.DataFrame
    report : CleaningReport
        ``counts["plots_duplicate"]``.
    """
    key = [name for name in _PLOT_KEY if name in plots]
    duplicate = _duplicated(plots, key)
    return _keep(plots, ~duplicate), _report(plots_duplicate=int(duplicate.sum()))


def drop_duplicate_adsb(adsb: pd.DataFrame) -> tuple[pd.DataFrame, CleaningReport]:
    """Drop exact duplicate ADS-B reports: same target, time, latitude, longitude and height.

    Returns
    -------
    adsb : pandas.DataFrame
    report : CleaningReport
        ``counts["adsb_duplicate"]``.
    """
    duplicate = _duplicated(adsb, list(_ADSB_KEY))
    return _keep(adsb, ~duplicate), _report(adsb_duplicate=int(duplicate.sum()))


def _key_values(table: pd.DataFrame, name: str) -> NDArray:
    """A key column as floats (numbers) or codes (anything else; -1 where missing)."""
    column = table[name]
    if pd.api.types.is_numeric_dtype(column) and not pd.api.types.is_bool_dtype(column):
        return column.to_numpy(dtype=float, na_value=np.nan)
    return pd.factorize(column)[0]


def _same(a: NDArray, b: NDArray) -> BoolArray:
    """Element-wise equality, NaN equal to NaN (as ``DataFrame.duplicated``)."""
    if a.dtype.kind == "f":
        return (a == b) | (np.isnan(a) & np.isnan(b))
    return a == b


def _duplicated(table: pd.DataFrame, key: list[str],
                texts: Mapping[str, _Text] | None = None) -> BoolArray:
    """``table.duplicated(subset=key, keep="first")`` by sorting instead of hashing.

    Rows are ordered by the first two key columns; only rows in runs of equal values
    there are compared on the whole key (NaN equal to NaN, ``-0.0`` to ``0.0``, as
    pandas), in their original order, so the first of each set of duplicates is kept.
    ``texts`` gives the codes of text columns already found (used when exact: which
    rows are duplicates does not depend on how the codes are numbered).
    """
    n = len(table)
    duplicate = np.zeros(n, dtype=bool)
    if n < 2 or not key:
        return duplicate
    texts = texts or {}
    values = [texts[name].codes if name in texts and texts[name].exact
              else _key_values(table, name) for name in key]
    order = group_order(values[0], values[1]) if len(values) > 1 else np.lexsort(values[:1])
    same = np.ones(n - 1, dtype=bool)
    for v in values[:2]:
        sorted_v = v[order]
        same &= _same(sorted_v[1:], sorted_v[:-1])
    if not same.any():
        return duplicate
    in_run = np.zeros(n, dtype=bool)
    in_run[1:] |= same
    in_run[:-1] |= same
    candidates = np.sort(order[in_run])
    rows = candidates[np.lexsort([v[candidates] for v in values[::-1]])]
    equal = np.ones(len(rows) - 1, dtype=bool)
    for v in values:
        equal &= _same(v[rows][1:], v[rows][:-1])
    duplicate[rows[1:][equal]] = True
    return duplicate


# --------------------------------------------------------------------------- ADS-B order
@dataclass(frozen=True)
class _Tracks:
    """An ADS-B table's rows by aircraft, then time: found once, kept through the cleaning.

    Attributes
    ----------
    codes : ndarray of int
        Each row's aircraft code, in order of first appearance (``pd.factorize`` of
        ``target_id`` as text); codes of aircraft whose rows were all dropped are
        unused.
    names : pandas.Index
        The address of each code.
    order : ndarray of int
        The rows by (code, time), ties by row.
    """

    codes: NDArray[np.int64]
    names: pd.Index
    order: NDArray[np.int64]

    @classmethod
    def of(cls, adsb: pd.DataFrame, target: _Text | None = None) -> _Tracks:
        """The track order of ``adsb`` (``target``: its ``target_id`` codes, when known)."""
        if target is None or not target.fresh:
            target = _Text.of(adsb["target_id"])
        return cls(target.codes, target.names,
                   group_order(target.codes, _column(adsb, "time_s")))

    def kept(self, keep: BoolArray, adsb_kept: pd.DataFrame) -> _Tracks:
        """The same for ``adsb_kept``, the rows where ``keep`` (as :func:`_keep` gives them).

        Without sorting again, unless an aircraft's first row was dropped and the
        codes are no longer in order of first appearance.
        """
        if keep.all():
            return self
        codes = self.codes[keep]
        if np.any(np.diff(pd.unique(codes)) < 0):
            return _Tracks.of(adsb_kept)
        new_row = np.cumsum(keep) - 1
        return _Tracks(codes, self.names, new_row[self.order[keep[self.order]]])


def _keep_tracks(adsb: pd.DataFrame, tracks: _Tracks, keep: BoolArray
                 ) -> tuple[pd.DataFrame, _Tracks]:
    """The rows of ``adsb`` where ``keep`` (:func:`_keep`) and their track order."""
    kept = _keep(adsb, keep)
    return kept, tracks.kept(keep, kept)


def drop_stale_adsb(
    adsb: pd.DataFrame, columns: tuple[str, ...] = ("lat_deg", "lon_deg")
) -> tuple[pd.DataFrame, CleaningReport]:
    """Drop ADS-B reports that repeat the previous position of the same aircraft.

    A report is stale when its ``columns`` (by default latitude and longitude)
    are exactly those of the aircraft's previous report (in time order) and its
    time is later: the position was not updated, only its time stamp.  The
    height is not compared by default because recorders often update the
    (barometric) height while repeating an old horizontal position; an
    airborne aircraft does not keep exactly the same latitude and longitude
    from one report to the next.  The first report of each repeated run is kept.

    Parameters
    ----------
    adsb : pandas.DataFrame
        ADS-B table (contract columns).
    columns : tuple of str
        Columns that must all repeat.

    Returns
    -------
    adsb : pandas.DataFrame
    report : CleaningReport
        ``counts["adsb_stale"]``.
    """
    stale = _stale(adsb, _Tracks.of(adsb), columns)
    return _keep(adsb, ~stale), _report(adsb_stale=int(stale.sum()))


def _stale(adsb: pd.DataFrame, tracks: _Tracks, columns: tuple[str, ...]) -> BoolArray:
    """:func:`drop_stale_adsb`'s rows to drop."""
    stale = np.zeros(len(adsb), dtype=bool)
    if len(adsb) < 2:
        return stale
    order, codes = tracks.order, tracks.codes
    c = codes[order]
    t = _column(adsb, "time_s")[order]
    same = c[1:] == c[:-1]
    same &= t[1:] > t[:-1]
    for name in columns:
        v = _column(adsb, name)[order]
        same &= v[1:] == v[:-1]
    stale[order[1:][same]] = True
    return stale


def _ecef(adsb: pd.DataFrame) -> FloatArray:
    return frames.geodetic_to_ecef(
        np.deg2rad(_column(adsb, "lat_deg")),
        np.deg2rad(_column(adsb, "lon_deg")),
        _column(adsb, "alt_m"),
    )


def _sigma(adsb: pd.DataFrame) -> FloatArray:
    if "sigma_m" in adsb:
        return _column(adsb, "sigma_m")
    return np.full(len(adsb), _FALLBACK_SIGMA_M)


#: 3-D position sigma per unit of horizontal sigma (two horizontal axes, vertical 1.5x).
_SIGMA_3D = float(np.sqrt(2.0 + 1.5**2))


def _jumps(
    flight: NDArray[np.int64],
    time_s: FloatArray,
    ecef_m: FloatArray,
    sigma_m: FloatArray,
    max_speed_mps: float,
    gate_sigmas: float,
) -> tuple[BoolArray, FloatArray]:
    """Steps between consecutive rows (in track order) that no aircraft can fly.

    Returns ``(jump, distance_m)`` of length ``n - 1``: step ``k`` goes from row
    ``k`` to row ``k + 1`` and is a jump when both rows belong to the same
    flight and the distance exceeds ``max_speed * dt`` plus ``gate_sigmas``
    times the combined 3-D position sigma.
    """
    if len(flight) < 2:
        return np.zeros(0, dtype=bool), np.zeros(0)
    same = flight[1:] == flight[:-1]
    dt = np.abs(np.diff(time_s))
    distance = frames.row_norm(np.diff(ecef_m, axis=0))
    slack = gate_sigmas * _SIGMA_3D * np.hypot(sigma_m[1:], sigma_m[:-1])
    return same & (distance > max_speed_mps * dt + slack), distance


def _isolated_outliers(
    flight: NDArray[np.int64],
    time_s: FloatArray,
    ecef_m: FloatArray,
    sigma_m: FloatArray,
    max_speed_mps: float,
    max_accel_mps2: float,
    gate_sigmas: float,
) -> BoolArray:
    """Single reports off the chord of their two neighbours by more than an aircraft can turn.

    Report ``i`` (with a neighbour on each side in its flight) is an outlier
    when its distance from the straight line between reports ``i - 1`` and
    ``i + 1``, interpolated to its time, exceeds ``max_accel * dt1 * dt2 / 2``
    (constant acceleration) plus the noise allowance, when that distance is
    larger than the neighbours' own, and when the neighbours are consistent
    with each other (the track goes on where it was: not a jump that stays).
    """
    n = len(flight)
    out = np.zeros(n, dtype=bool)
    if n < 3:
        return out
    inner = (flight[1:-1] == flight[:-2]) & (flight[1:-1] == flight[2:])
    t0, t1, t2 = time_s[:-2], time_s[1:-1], time_s[2:]
    span = t2 - t0
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(span > 0, (t1 - t0) / span, 0.5)
    off_chord, bypass = _chord_distances(ecef_m, w)
    deviation = np.where(inner, off_chord, 0.0)
    sigma = np.maximum(sigma_m[1:-1], np.maximum(sigma_m[:-2], sigma_m[2:]))
    slack = gate_sigmas * _SIGMA_3D * sigma * np.sqrt(1.5)
    allowed = 0.5 * max_accel_mps2 * (t1 - t0) * (t2 - t1) + slack
    consistent = bypass <= max_speed_mps * span + gate_sigmas * _SIGMA_3D * np.hypot(
        sigma_m[:-2], sigma_m[2:])
    padded = np.concatenate([[0.0], deviation, [0.0]])
    local_max = (deviation >= padded[:-2]) & (deviation >= padded[2:])
    out[1:-1] = inner & (deviation > allowed) & local_max & consistent
    return out


def _chord_distances(ecef_m: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each inner report's distance [m] from the chord of its two neighbours, and the
    chord's length [m].

    ``frames.row_norm`` of ``ecef_m[1:-1] - (ecef_m[:-2] + w * across)`` and of ``across
    = ecef_m[2:] - ecef_m[:-2]`` (from each report's predecessor to its successor), the
    same arithmetic coordinate by coordinate (the same bits, without broadcasting
    ``w`` over rows of three).

    Parameters
    ----------
    ecef_m : ndarray, shape (n, 3)
        Positions in track order [m].
    w : ndarray, shape (n - 2,)
        Each inner report's time as a fraction of its neighbours' interval.

    Returns
    -------
    off_chord, chord : ndarray, shape (n - 2,)
        Distances [m].
    """
    off_sq = chord_sq = np.zeros(len(w))  # 0 + a square is the square, to the bit
    for k in range(ecef_m.shape[1]):
        e = ecef_m[:, k]
        across = e[2:] - e[:-2]
        off = e[1:-1] - (e[:-2] + w * across)
        off_sq = off_sq + off * off
        chord_sq = chord_sq + across * across
    return np.sqrt(off_sq), np.sqrt(chord_sq)


def gate_adsb_kinematics(
    adsb: pd.DataFrame,
    *,
    max_speed_mps: float = DEFAULT_MAX_SPEED_MPS,
    max_accel_mps2: float = DEFAULT_MAX_ACCEL_MPS2,
    gate_sigmas: float = DEFAULT_GATE_SIGMAS,
    max_wild_run: int = DEFAULT_MAX_WILD_RUN,
    min_track_reports: int = DEFAULT_MIN_TRACK_REPORTS,
    flight_gap_s: float = DEFAULT_FLIGHT_GAP_S,
) -> tuple[pd.DataFrame, CleaningReport]:
    """Drop ADS-B positions no aircraft can have flown, per aircraft and flight.

    An aircraft's reports (time order) are cut into *flights* at gaps longer
    than ``flight_gap_s``.  Within a flight:

    1. a single report off the chord between its two neighbours by more than
       ``max_accel_mps2`` allows (plus the noise allowance), while the
       neighbours agree with each other, is dropped (``adsb_wild``);
    2. consecutive reports are a *jump* when the distance between them is more
       than ``max_speed_mps`` times the time between them plus ``gate_sigmas``
       times their combined position sigma (so noise does not trigger it).
       Runs of at most ``max_wild_run`` reports cut off by jumps next to a
       longer stretch (a few wild reports, also at the ends of a flight) are
       dropped (``adsb_wild``);
    3. if jumps remain, the positions jump and stay offset (a spoofed stretch,
       or two aircraft under one address): which stretch is true cannot be
       told from ADS-B alone, so every report of that flight is dropped
       (``adsb_jumping_aircraft``) with a warning naming the address, the time
       span and the size of the jumps.  The aircraft's radar plots are still
       used between radars.

    Flights with fewer than ``min_track_reports`` reports are not judged.

    Parameters
    ----------
    adsb : pandas.DataFrame
        ADS-B table (contract columns); ``sigma_m`` [m] if present, else 30 m.
    max_speed_mps : float
        Fastest credible ground speed [m/s].
    max_accel_mps2 : float
        Largest credible acceleration [m/s^2] (for single wild reports).
    gate_sigmas : float
        Noise allowance, in position sigmas.
    max_wild_run : int
        Longest run of reports [count] treated as wild reports.
    min_track_reports : int
        Flights with fewer reports [count] are not judged (too few to tell
        which reports are wild).
    flight_gap_s : float
        A gap longer than this [s] starts a new flight.

    Returns
    -------
    adsb : pandas.DataFrame
    report : CleaningReport
    """
    keep, report = _gate_keep(adsb, _Tracks.of(adsb), _ecef(adsb), max_speed_mps,
                              max_accel_mps2, gate_sigmas, max_wild_run, min_track_reports,
                              flight_gap_s)
    return _keep(adsb, keep), report


def _gate_keep(
    adsb: pd.DataFrame,
    tracks: _Tracks,
    ecef_all: FloatArray,
    max_speed_mps: float,
    max_accel_mps2: float,
    gate_sigmas: float,
    max_wild_run: int,
    min_track_reports: int,
    flight_gap_s: float,
) -> tuple[BoolArray, CleaningReport]:
    """:func:`gate_adsb_kinematics`'s rows to keep, with the track order and the reports'
    ECEF positions given."""
    report = _report()
    if len(adsb) < 2:
        return np.ones(len(adsb), dtype=bool), report
    order = tracks.order
    codes = tracks.codes[order]
    time_s = _column(adsb, "time_s")[order]
    gap = np.concatenate([[True], (codes[1:] != codes[:-1]) | (np.diff(time_s) > flight_gap_s)])
    flight = np.cumsum(gap) - 1
    size = np.bincount(flight)
    judged = size[flight] >= min_track_reports
    ecef = take_rows(ecef_all, order)
    sigma = _sigma(adsb)[order]
    wild = judged & _isolated_outliers(flight, time_s, ecef, sigma, max_speed_mps,
                                       max_accel_mps2, gate_sigmas)
    if wild.any():
        rest = np.flatnonzero(~wild)
        jump, _ = _jumps(flight[rest], time_s[rest], take_rows(ecef, rest), sigma[rest],
                         max_speed_mps, gate_sigmas)
        jump &= judged[rest][1:]
    else:  # the same, without copying every array
        rest = np.arange(len(flight))
        jump, _ = _jumps(flight, time_s, ecef, sigma, max_speed_mps, gate_sigmas)
        jump &= judged[1:]
    whole = np.zeros(len(codes), dtype=bool)
    if jump.any():
        f = flight[rest]
        starts = np.concatenate([[True], (f[1:] != f[:-1]) | jump])
        segment = np.cumsum(starts) - 1
        seg_size = np.bincount(segment)
        seg_flight = f[starts]
        longest = np.zeros(int(flight.max()) + 1, dtype=np.int64)
        np.maximum.at(longest, seg_flight, seg_size)
        # Short runs are wild only next to a longer stretch that is taken as the track.
        short = (seg_size <= max_wild_run) & (longest[seg_flight] > max_wild_run)
        wild[rest[short[segment]]] = True
        kept = np.flatnonzero(~wild)
        jump2, distance2 = _jumps(flight[kept], time_s[kept], take_rows(ecef, kept), sigma[kept],
                                  max_speed_mps, gate_sigmas)
        jump2 &= judged[kept][1:]
        bad_flights = np.unique(flight[kept][:-1][jump2])
        whole = np.isin(flight, bad_flights)
        for bad in bad_flights:
            steps = np.flatnonzero(jump2 & (flight[kept][:-1] == bad))
            first, last = kept[steps[0]], kept[steps[-1] + 1]
            address = str(adsb["target_id"].iloc[order[first]])
            if address not in report.jumping_aircraft:
                report.jumping_aircraft.append(address)
            mine = flight == bad
            report.warnings.append(
                f"ADS-B of aircraft {address}: positions jump by up to "
                f"{distance2[steps].max() / 1e3:.1f} km between t = {time_s[first]:.1f} s and "
                f"t = {time_s[last]:.1f} s ({len(steps)} jump{'s' if len(steps) > 1 else ''}: "
                "a spoofed stretch or two aircraft under one address); its "
                f"{int(mine.sum())} reports from t = {time_s[mine].min():.1f} s to "
                f"{time_s[mine].max():.1f} s are left out"
            )
    report.counts["adsb_wild"] = int((wild & ~whole).sum())
    report.counts["adsb_jumping_aircraft"] = int(whole.sum())
    keep = np.ones(len(codes), dtype=bool)
    keep[order[wild | whole]] = False
    return keep, report


# --------------------------------------------------------------------------- identities
def _interpolate_adsb(
    adsb: pd.DataFrame, tracks: _Tracks, ecef_all: FloatArray, target_code: NDArray[np.int64],
    target_names: pd.Index, time_s: FloatArray, max_gap_s: float,
) -> tuple[FloatArray, BoolArray]:
    """ADS-B ECEF position [m] of each (target, time), linear in time; ``ok`` where bridged.

    The targets are ``target_names[target_code]``; ``ecef_all`` the reports' ECEF
    positions.  Vectorised over all aircraft: rows are keyed by ``code * span + time``
    so that one ``searchsorted`` finds every bracket (:func:`_brackets`).
    """
    n = len(time_s)
    ref = np.full((n, 3), np.nan)
    ok = np.zeros(n, dtype=bool)
    if len(adsb) < 2 or n == 0:
        return ref, ok
    a_code = tracks.codes
    to_category = tracks.names.get_indexer(target_names.astype(str))
    q_code = np.where(target_code >= 0, to_category[np.maximum(target_code, 0)], -1)
    a_time = _column(adsb, "time_s")
    t0 = min(a_time.min(), time_s.min())
    span = max(a_time.max(), time_s.max()) - t0 + 4.0 * max_gap_s + 1.0
    order = tracks.order  # the keys' order, which they keep after rounding
    a_code_s, a_time_s = a_code[order], a_time[order]
    a_key = a_code_s * span + (a_time_s - t0)
    q_key = q_code * span + (time_s - t0)
    j = _brackets(a_key, q_key, group_rows(q_code))  # by aircraft: close keys
    valid = (q_code >= 0) & (j >= 0) & (j < len(a_key) - 1)
    j = np.clip(j, 0, len(a_key) - 2)
    same = (a_code_s[j] == q_code) & (a_code_s[j + 1] == q_code)
    dt = a_time_s[j + 1] - a_time_s[j]
    with np.errstate(invalid="ignore", divide="ignore"):
        w = (time_s - a_time_s[j]) / dt
    ok = valid & same & (dt > 0) & (dt <= max_gap_s) & (w >= 0.0) & (w <= 1.0)
    w = np.where(ok, w, 0.0)
    ref = ((1.0 - w)[:, None] * take_rows(ecef_all, order[j])
           + w[:, None] * take_rows(ecef_all, order[j + 1]))
    ref[~ok] = np.nan
    return ref, ok


def _brackets(keys: FloatArray, queries: FloatArray, by_query: NDArray[np.intp]
              ) -> NDArray[np.intp]:
    """Per query, the last of the sorted ``keys`` at or before it (-1: none).

    ``np.searchsorted(keys, queries, side="right") - 1``, the queries searched in
    the order ``by_query`` (any permutation: one that brings close queries together
    keeps the searches' memory accesses close, several times faster than random
    order).  ``keys`` and ``queries`` are in the same unit (here ``code * span +
    time`` [s]).
    """
    found = np.empty(len(queries), dtype=np.intp)
    found[by_query] = np.searchsorted(keys, queries[by_query], side="right")
    found -= 1
    return found


def _robust_line(x: FloatArray, y: FloatArray) -> FloatArray:
    """Residuals of ``y`` about a Theil-Sen line in ``x`` (robust to 29 % outliers).

    The slope is the median of the pairwise slopes (of at most 200 000 pairs,
    a fixed sample when there are more) and the intercept the median of
    ``y - slope * x``.  A constant (the median) when ``x`` hardly varies.
    """
    if len(x) < 3 or np.ptp(x) < 1e-6 * max(float(np.abs(x).max()), 1.0):
        return y - np.median(y)
    i, j = np.triu_indices(len(x), k=1)
    if len(i) > 200_000:
        pick = np.random.default_rng(0).choice(len(i), 200_000, replace=False)
        i, j = i[pick], j[pick]
    dx = x[j] - x[i]
    usable = np.abs(dx) > 0
    slope = float(np.median((y[j] - y[i])[usable] / dx[usable]))
    return y - slope * x - np.median(y - slope * x)


def check_identities(
    plots: pd.DataFrame,
    adsb: pd.DataFrame,
    sites: Mapping[str, Site],
    *,
    floor_m: float = DEFAULT_IDENTITY_FLOOR_M,
    z_limit: float = DEFAULT_IDENTITY_Z,
    min_aircraft: int = DEFAULT_IDENTITY_MIN_AIRCRAFT,
    min_plots: int = DEFAULT_IDENTITY_MIN_PLOTS,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
) -> tuple[pd.DataFrame, CleaningReport]:
    """Clear the ``target_id`` of plots whose aircraft is not the one the ADS-B describes.

    For every radar and aircraft, each plot (taken at face value, zero bias)
    is compared with the ADS-B position of the same address interpolated to
    the plot time, in the radar's own measurement space: range difference [m]
    and azimuth difference [rad].  Per aircraft, the medians of both are
    taken.  A radar's biases are common to all its aircraft: its range
    differences lie on a line ``offset + gain * range`` and its azimuth
    differences are one constant, whatever their size (a 160 mrad azimuth bias
    at 80 km is a 13 km offset, shared by every aircraft).  That common part is
    fitted robustly over the radar's aircraft and removed; what is left,
    converted to metres (azimuth times range), is each aircraft's offset from
    the radar's consensus.  An aircraft is flagged when its offset is more than
    ``floor_m`` and more than ``z_limit`` robust standard deviations of the
    radar's offsets: its plots carry another aircraft's address (wrong
    address, or a second transponder).  Its plots on that radar get an empty
    ``target_id``, so they are matched neither to that ADS-B nor to other
    radars' plots of the address, and a warning names the radar, the address
    and the offset.

    Parameters
    ----------
    plots, adsb : pandas.DataFrame
        Plots and ADS-B tables (contract columns).
    sites : mapping of str to Site
        Radar sites by id.
    floor_m : float
        Smallest offset [m] that is flagged.
    z_limit : float
        Robust z-score [-] above which an offset is flagged.
    min_aircraft : int
        Aircraft with ADS-B a radar needs for a consensus; radars with fewer
        are not checked.
    min_plots : int
        Matched plots an aircraft needs on a radar to be judged.
    max_gap_s : float
        Longest ADS-B gap bridged by interpolation [s].

    Returns
    -------
    plots : pandas.DataFrame
        The plots, with the flagged ``target_id`` cleared.
    report : CleaningReport
        ``counts["plots_identity_cleared"]`` and :attr:`CleaningReport.mislabelled`.
    """
    return _check_identities(plots, adsb, _Tracks.of(adsb), _ecef(adsb), sites, floor_m,
                             z_limit, min_aircraft, min_plots, max_gap_s, None)


def _check_identities(
    plots: pd.DataFrame,
    adsb: pd.DataFrame,
    tracks: _Tracks,
    adsb_ecef: FloatArray,
    sites: Mapping[str, Site],
    floor_m: float,
    z_limit: float,
    min_aircraft: int,
    min_plots: int,
    max_gap_s: float,
    texts: tuple[_Text, _Text] | None,
) -> tuple[pd.DataFrame, CleaningReport]:
    """:func:`check_identities`, with the ADS-B track order and ECEF positions given, and
    the plots' ``radar_id`` and ``target_id`` codes when known (``texts``)."""
    report = _report()
    out = plots.reset_index(drop=True)
    if len(out) == 0 or len(adsb) < 2:
        return out, report
    # Identities and radars as integer codes (how they are numbered changes nothing).
    radar_text, target_text = texts or (_Text.of(out["radar_id"]), _Text.of(out["target_id"]))
    target, names = target_text.codes, target_text.names
    has_id = target_text.where(names != "")  # -1: missing
    time_s = _column(out, "time_s")
    ref, ok = _interpolate_adsb(adsb, tracks, adsb_ecef, np.where(has_id, target, -1), names,
                                time_s, max_gap_s)
    ok &= has_id
    radar = radar_text.codes
    radar_code = {str(name): code for code, name in enumerate(radar_text.names)}
    range_m = _column(out, "range_m")
    azimuth = np.deg2rad(_column(out, "azimuth_deg"))
    clear = np.zeros(len(out), dtype=bool)
    for rid, site in sites.items():
        mine = radar == radar_code.get(rid, -2)
        rows = np.flatnonzero(ok & mine)
        if len(rows) == 0:
            continue
        r_ref, az_ref, _ = site.polar_from_ecef(take_rows(ref, rows))
        d_range = range_m[rows] - r_ref
        d_az = frames.wrap_to_pi(azimuth[rows] - az_ref)
        codes, counts, (dr, da, r) = group_medians(target[rows], [d_range, d_az, r_ref])
        enough = counts >= min_plots
        codes, dr, da, r = codes[enough], dr[enough], da[enough], r[enough]
        if len(codes) < min_aircraft:
            continue
        range_resid = _robust_line(r, dr)
        az_resid = frames.wrap_to_pi(da - _circular_median(da))
        offset = np.hypot(range_resid, az_resid * r)
        centre = np.median(offset)
        scale = 1.4826 * np.median(np.abs(offset - centre))
        z = (offset - centre) / max(scale, 1.0)
        flagged = (offset > floor_m) & (z > z_limit)
        if not flagged.any():
            continue
        agree = float(np.max(offset[~flagged]))
        for code, off in zip(codes[flagged], offset[flagged], strict=True):
            address = names[code]
            sel = rows[target[rows] == code]
            all_rows = np.flatnonzero(mine & (target == code))
            clear[all_rows] = True
            report.mislabelled.append((rid, str(address), float(off)))
            report.warnings.append(
                f"radar {rid}: the plots labelled {address} are {off / 1e3:.1f} km from that "
                f"aircraft's ADS-B positions, while the radar's other aircraft agree within "
                f"{_distance(agree)} (after its common bias): a wrong address or a second "
                f"transponder; the target_id of its {len(all_rows)} plots on {rid} is cleared "
                f"({len(sel)} had ADS-B)"
            )
    if clear.any():
        out = out.copy()
        out.loc[clear, "target_id"] = ""
    report.counts["plots_identity_cleared"] = int(clear.sum())
    return out, report


def _distance(metres: float) -> str:
    """``"850 m"`` or ``"13.2 km"``."""
    return f"{metres:.0f} m" if metres < 1000.0 else f"{metres / 1e3:.1f} km"


def _circular_median(angle_rad: FloatArray) -> float:
    """Median of angles [rad] taken about their circular mean (robust to wrap-around)."""
    mean = float(np.arctan2(np.sin(angle_rad).mean(), np.cos(angle_rad).mean()))
    return mean + float(np.median(frames.wrap_to_pi(angle_rad - mean)))


# --------------------------------------------------------------------------- coverage
def coverage_warnings(
    plots: pd.DataFrame, sites: Mapping[str, Site], has_adsb: bool
) -> list[str]:
    """Warnings about what the data cannot calibrate (nothing is removed).

    * a radar of ``sites.toml`` with no plots is not calibrated;
    * without ADS-B, a 2-D radar whose plots carry no altitude cannot be
      paired with other radars (its plots cannot be placed in height);
    * without ADS-B, radars are linked only by the aircraft they share; groups
      of radars with no aircraft in common are calibrated separately, and a
      radar that shares no aircraft with any other is not calibrated.

    Parameters
    ----------
    plots : pandas.DataFrame
        Plots table.
    sites : mapping of str to Site
        Radar sites.
    has_adsb : bool
        Whether the dataset has ADS-B reports.

    Returns
    -------
    list of str
    """
    return _coverage_warnings(plots, sites, has_adsb, _Text.of(plots["radar_id"]).counts())


def _coverage_warnings(plots: pd.DataFrame, sites: Mapping[str, Site], has_adsb: bool,
                       counts: Mapping[str, int]) -> list[str]:
    """:func:`coverage_warnings`, with the plots per radar given (:meth:`_Text.counts`)."""
    warnings: list[str] = []
    with_plots = [rid for rid in sites if counts.get(rid, 0) > 0]
    for rid in sites:
        if counts.get(rid, 0) == 0:
            warnings.append(f"radar {rid} has no plots; not calibrated")
    if has_adsb:
        return warnings
    radar = plots["radar_id"].astype(str)
    altitude = _column(plots, "altitude_m") if "altitude_m" in plots else None
    for rid in with_plots:
        if sites[rid].is_3d:
            continue
        mine = (radar == rid).to_numpy(dtype=bool)
        if altitude is None or not np.isfinite(altitude[mine]).any():
            warnings.append(
                f"radar {rid} is 2-D and none of its plots carries an altitude: without ADS-B "
                "it cannot be compared with other radars; not calibrated"
            )
    groups = traffic_groups(plots, with_plots)
    if len(groups) > 1:
        described = " and ".join("{" + ", ".join(g) + "}" for g in groups)
        warnings.append(
            f"radars {described} have no aircraft in common: without ADS-B each group is "
            "calibrated on its own traffic and nothing ties one group to another"
        )
        for group in groups:
            if len(group) == 1:
                warnings.append(
                    f"radar {group[0]} shares no aircraft with any other radar and there is "
                    "no ADS-B; not calibrated"
                )
    return warnings


def traffic_groups(plots: pd.DataFrame, radar_ids: list[str]) -> list[list[str]]:
    """Groups of radars linked (directly or through others) by aircraft seen in common.

    Two radars are linked when both have plots with the same non-empty
    ``target_id``.  Returns the connected groups, each in ``radar_ids`` order.
    """
    parent = {rid: rid for rid in radar_ids}

    def root(rid: str) -> str:
        while parent[rid] != rid:
            parent[rid] = parent[parent[rid]]
            rid = parent[rid]
        return rid

    labelled = plots.loc[plots["target_id"].astype(str) != "", ["radar_id", "target_id"]]
    pairs = labelled.drop_duplicates()
    pairs = pairs[pairs["radar_id"].isin(radar_ids)]
    for _, seen_by in pairs.groupby("target_id", sort=False)["radar_id"]:
        radars = list(seen_by)
        for other in radars[1:]:
            a, b = root(radars[0]), root(other)
            if a != b:
                parent[b] = a
    groups: dict[str, list[str]] = {}
    for rid in radar_ids:
        groups.setdefault(root(rid), []).append(rid)
    return list(groups.values())


# --------------------------------------------------------------------------- time stamps
#: Steps [s] of quantised time stamps that are warned about, largest first.
TIME_QUANTA_S: tuple[float, ...] = (1.0, 0.5, 0.25, 0.2, 0.1)
#: Fraction of a table's (a radar's) times on a multiple of the step that means quantised.
TIME_QUANTUM_FRACTION = 0.95
#: Times judged per table (a block from its middle).
TIME_QUANTUM_ROWS = 20_000
#: Fraction of one interval among an aircraft's ADS-B reports that makes a regular grid.
ADSB_GRID_FRACTION = 0.8
#: Ground speed [m/s] of the along-track error a warning quotes.
TYPICAL_SPEED_MPS = 250.0


def _time_quanta(time_s: FloatArray, groups: pd.Series | NDArray | None = None
                 ) -> tuple[float | None, dict[object, float]]:
    """The largest step of :data:`TIME_QUANTA_S` that nearly all ``time_s`` are multiples
    of (:data:`TIME_QUANTUM_FRACTION`), or ``None``; without one, the same per group
    (``groups`` a label per time; groups of fewer than 50 times are not judged)."""
    ok = np.isfinite(time_s)
    t = time_s[ok]
    if t.size < 50:
        return None, {}
    codes, labels = (None, []) if groups is None else pd.factorize(
        groups if ok.all() else groups[ok])
    size = np.bincount(codes, minlength=len(labels)) if codes is not None else None
    per_group: dict[object, float] = {}
    for step in TIME_QUANTA_S:
        q = t / step
        on = np.abs(q - np.rint(q)) < 1e-3
        if float(on.mean()) >= TIME_QUANTUM_FRACTION:
            return step, {}
        if codes is None or size is None:
            continue
        fraction = np.bincount(codes, weights=on, minlength=len(labels)) / np.maximum(size, 1)
        for k in np.flatnonzero((fraction >= TIME_QUANTUM_FRACTION) & (size >= 50)):
            per_group.setdefault(labels[k], step)
    return None, per_group


def _regular(adsb: pd.DataFrame, time_s: FloatArray) -> bool:
    """Whether the successive reports of one aircraft lie on a regular grid (as a source
    resampled onto whole seconds gives): at least :data:`ADSB_GRID_FRACTION` of the
    intervals the same, and no two different positions at one time (a rounded stamp)."""
    code = adsb["target_id"].factorize()[0]
    order = np.lexsort((time_s, code))
    same = code[order][1:] == code[order][:-1]
    dt = np.diff(time_s[order])[same]
    lat = _column(adsb, "lat_deg")[order]
    lon = _column(adsb, "lon_deg")[order]
    moved = ((lat[1:] != lat[:-1]) | (lon[1:] != lon[:-1]))[same]
    if dt.size < 50 or float(np.mean((dt == 0) & moved)) > 1.0 - ADSB_GRID_FRACTION:
        return False
    dt = dt[dt > 0]
    if dt.size < 50:
        return False
    return float(np.mean(np.abs(dt - np.median(dt)) < 1e-6)) >= ADSB_GRID_FRACTION


def _quantum_warning(what: str, step: float) -> str:
    noise = step / np.sqrt(12.0)
    unit = "whole seconds" if step == 1.0 else f"multiples of {step:g} s"
    return (f"{what} time_s are {unit}: quantised time stamps add up to {noise:.2g} s "
            f"({step:g}/sqrt(12) s) of timing noise, about {noise * TYPICAL_SPEED_MPS:.0f} m "
            f"along track at {TYPICAL_SPEED_MPS:.0f} m/s, which the stated sigmas do not "
            "include; biases and time offsets may be off by several sigma")


def time_stamp_warnings(plots: pd.DataFrame, adsb: pd.DataFrame | None) -> list[str]:
    """Warnings about time stamps (nothing is removed).

    * quantised times (:data:`TIME_QUANTA_S`): per table, and for the plots per
      radar when only some radars' are; ADS-B reports on a regular grid of whole
      seconds (a resampled source: exact there) only when the plots are quantised
      too;
    * times of the day that wrap at midnight in both tables (or in the plots
      without ADS-B; one table wrapping alone is refused by
      :mod:`graphcal.data.plausibility`).

    Looks at a block of :data:`TIME_QUANTUM_ROWS` rows from each table's middle.
    """
    from graphcal.data.plausibility import midnight_wrap, wrap_text

    warnings: list[str] = []
    start = max(0, (len(plots) - TIME_QUANTUM_ROWS) // 2)
    block = plots.iloc[start:start + TIME_QUANTUM_ROWS]
    step, per_radar = _time_quanta(_column(block, "time_s"), block["radar_id"])
    if step is not None:
        warnings.append(_quantum_warning("the plots'", step))
    for name, radar_step in per_radar.items():
        warnings.append(_quantum_warning(f"radar {name}'s plots'", radar_step))
    if adsb is not None and len(adsb):
        start = max(0, (len(adsb) - TIME_QUANTUM_ROWS) // 2)
        part = adsb.iloc[start:start + TIME_QUANTUM_ROWS]
        t = _column(part, "time_s")
        adsb_step, _ = _time_quanta(t)
        # Reports resampled onto a regular grid of whole seconds are exact there; only
        # rounded ones (irregular, or the plots' rounded too) are warned about.
        if adsb_step is not None and (warnings or not _regular(part, t)):
            warnings.append(_quantum_warning("the ADS-B reports'", adsb_step))
    parts = midnight_wrap(_column(plots, "time_s"))
    if parts is not None and (adsb is None or not len(adsb)
                              or midnight_wrap(_column(adsb, "time_s")) is not None):
        warnings.append(
            f"time_s wrap at midnight (plots {wrap_text(parts)}): seconds of the day over a "
            "recording across midnight; aircraft seen across "
            "it are split in two and biases over time (--window) run out of order: add "
            "86,400 s to the times after midnight")
    return warnings


# --------------------------------------------------------------------------- everything
def clean_dataset(
    dataset: Dataset,
    *,
    max_speed_mps: float = DEFAULT_MAX_SPEED_MPS,
    max_accel_mps2: float = DEFAULT_MAX_ACCEL_MPS2,
    gate_sigmas: float = DEFAULT_GATE_SIGMAS,
    max_wild_run: int = DEFAULT_MAX_WILD_RUN,
    identity_floor_m: float = DEFAULT_IDENTITY_FLOOR_M,
    identity_z: float = DEFAULT_IDENTITY_Z,
    max_gap_s: float = DEFAULT_MAX_GAP_S,
    check_identity: bool = True,
) -> tuple[Dataset, CleaningReport]:
    """Run every check of this module on a dataset (see the module docstring for the order).

    Parameters
    ----------
    dataset : Dataset
        The dataset; it is not modified.
    max_speed_mps, max_accel_mps2, gate_sigmas, max_wild_run
        See :func:`gate_adsb_kinematics`.
    identity_floor_m, identity_z, max_gap_s
        See :func:`check_identities` (``floor_m``, ``z_limit``, ``max_gap_s``).
    check_identity : bool
        Run :func:`check_identities`.

    Returns
    -------
    dataset : Dataset
        A new dataset with the cleaned tables; its ``cleaning`` attribute
        holds the report.
    report : CleaningReport
    """
    report = CleaningReport()
    report.warnings.extend(time_stamp_warnings(dataset.plots, dataset.adsb))
    plots, radar, target = _clean_plots(dataset.plots, dataset.sites, report)
    adsb = dataset.adsb
    if adsb is not None:
        adsb, tracks, ecef = _clean_adsb(adsb, report, max_speed_mps, max_accel_mps2,
                                         gate_sigmas, max_wild_run)
        if check_identity:
            plots, step = _check_identities(
                plots, adsb, tracks, ecef, dataset.sites, identity_floor_m, identity_z,
                DEFAULT_IDENTITY_MIN_AIRCRAFT, DEFAULT_IDENTITY_MIN_PLOTS, max_gap_s,
                None if target is None else (radar, target))
            report.merge(step)
    if adsb is not None and len(adsb) == 0:
        if dataset.adsb is not None and len(dataset.adsb):
            if not np.isfinite(_column(dataset.adsb, "alt_m")).any():
                note = ("no ADS-B report has a geometric height (alt_m): the calibration "
                        "proceeds as without ADS-B (ls, fl and fl-ls cannot run)")
            else:
                note = ("every ADS-B report was dropped; calibrating without ADS-B (ls, fl "
                        "and fl-ls cannot run)")
            report.warnings.append(note)
            report.notes.append(note)
        adsb = None
    has_adsb = adsb is not None
    report.warnings.extend(_coverage_warnings(plots, dataset.sites, has_adsb, radar.counts()))
    return dataclasses.replace(dataset, plots=plots, adsb=adsb, cleaning=report), report


def _clean_plots(plots: pd.DataFrame, sites: Mapping[str, Site], report: CleaningReport
                 ) -> tuple[pd.DataFrame, _Text, _Text | None]:
    """:func:`drop_non_finite_plots`, :func:`drop_out_of_range_plots` and
    :func:`drop_duplicate_plots`, their reports merged into ``report``.

    Returns
    -------
    plots : pandas.DataFrame
        The plots kept.
    radar, target : _Text
        Their ``radar_id`` and ``target_id`` codes, found once (``target`` ``None``
        without such a column).
    """
    radar = _Text.of(plots["radar_id"])
    target = _Text.of(plots["target_id"]) if "target_id" in plots else None
    texts = {"radar_id": radar} if target is None else {"radar_id": radar, "target_id": target}
    bad = _non_finite_plots(plots, sites, radar)
    plots = _infinite_to_nan(_keep(plots, ~bad))
    report.merge(_report(plots_non_finite=int(bad.sum())))
    texts = {name: text.kept(~bad) for name, text in texts.items()}
    bad, step = _out_of_range_plots(plots, MAX_PLOT_RANGE_M)
    plots = _keep(plots, ~bad)
    report.merge(step)
    texts = {name: text.kept(~bad) for name, text in texts.items()}
    duplicate = _duplicated(plots, [name for name in _PLOT_KEY if name in plots], texts)
    plots = _keep(plots, ~duplicate)
    report.merge(_report(plots_duplicate=int(duplicate.sum())))
    texts = {name: text.kept(~duplicate) for name, text in texts.items()}
    return plots, texts["radar_id"], texts.get("target_id")


def _clean_adsb(adsb: pd.DataFrame, report: CleaningReport, max_speed_mps: float,
                max_accel_mps2: float, gate_sigmas: float, max_wild_run: int
                ) -> tuple[pd.DataFrame, _Tracks, FloatArray]:
    """Steps 1 to 4 on the ADS-B reports (:func:`drop_non_finite_adsb`,
    :func:`drop_duplicate_adsb`, :func:`drop_stale_adsb`, :func:`gate_adsb_kinematics`),
    their reports merged into ``report``.

    Returns
    -------
    adsb : pandas.DataFrame
        The reports kept.
    tracks : _Tracks
        Their track order.
    ecef : ndarray, shape (n, 3)
        Their ECEF positions [m].
    """
    target = _Text.of(adsb["target_id"])
    drop, step = _non_finite_adsb(adsb, target)
    adsb, target = _keep(adsb, ~drop), target.kept(~drop)
    report.merge(step)
    duplicate = _duplicated(adsb, list(_ADSB_KEY), {"target_id": target})
    adsb, target = _keep(adsb, ~duplicate), target.kept(~duplicate)
    report.merge(_report(adsb_duplicate=int(duplicate.sum())))
    # The track order and the ECEF positions: found once, for the stale reports, the
    # gate and the identity check.
    tracks = _Tracks.of(adsb, target)
    stale = _stale(adsb, tracks, ("lat_deg", "lon_deg"))
    adsb, tracks = _keep_tracks(adsb, tracks, ~stale)
    report.merge(_report(adsb_stale=int(stale.sum())))
    ecef = _ecef(adsb)
    keep, step = _gate_keep(adsb, tracks, ecef, max_speed_mps, max_accel_mps2, gate_sigmas,
                            max_wild_run, DEFAULT_MIN_TRACK_REPORTS, DEFAULT_FLIGHT_GAP_S)
    (adsb, tracks), ecef = _keep_tracks(adsb, tracks, keep), take_rows(ecef, keep)
    report.merge(step)
    return adsb, tracks, ecef


def ensure_clean(dataset: Dataset) -> Dataset:
    """``dataset`` if it was already cleaned (loaded with cleaning), else a cleaned copy.

    For estimators that may receive datasets built in memory (simulations,
    scripts): the report is on the returned dataset's ``cleaning`` attribute.
    """
    if getattr(dataset, "cleaning", None) is not None:
        return dataset
    return clean_dataset(dataset)[0]
