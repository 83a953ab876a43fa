"""Turn decoded ASTERIX reports into contract tables (sites, plots, adsb).

Radar identity
    A radar is identified in ASTERIX by its data source identifier SAC/SIC
    (I048/010, I034/010).  Its ``radar_id`` is the ``id`` of the ``[[radar]]``
    table of a user ``sites.toml`` that carries the extra keys ``sac`` and
    ``sic`` (integers 0..255) with those values; otherwise it is
    ``"SAC025_SIC201"`` (:func:`default_radar_id`, three decimal digits each).
    A ``[[radar]]`` table without ``sac``/``sic`` matches the radar whose default
    id equals its ``id``.

Radar position
    From the user ``sites.toml`` when it has the radar (it wins; its sigmas may
    be left out, they are then estimated from the data), else from the first
    CAT034 message of that SAC/SIC carrying I034/120 (3-D position of the data
    source; sigmas left out).  A radar with plots and no position is an error.

Time base
    ASTERIX times are times of day [s since 00:00 UTC] that wrap at 86400 s.
    ``time_s`` of both tables is seconds since 00:00 UTC of *day 0*:

    - with capture times (pcap/pcapng), day 0 is the UTC date of the earliest
      packet (:attr:`TimeBase.epoch_unix_s` is its midnight) and each report
      is put on the day that brings its time of day closest to its packet's
      capture time (so a report stamped 23:59:59.9 captured at 00:00:00.2 stays
      on the earlier day, and the reverse);
    - without (raw files), day 0 is the day of the first report and each
      report is put on the day that brings it closest to the previous report
      of the sequence (all categories, all files in the given order): a drop of
      more than 12 h is a midnight wrap.  :attr:`TimeBase.epoch_unix_s` is then
      ``None`` (the date is unknown).

    A time of day beyond 86 401 s (the items hold up to 131 072 s: a corrupted
    value) is left out of this placing, and its report is skipped and counted
    (:data:`SKIP_TOD_048`, :data:`SKIP_TOD_021`); so is a report placed before day 0
    (a negative ``time_s``: a time of day more than 12 h before its neighbour's
    or its capture time, :data:`SKIP_BEFORE_DAY_0_048`, :data:`SKIP_BEFORE_DAY_0_021`).

Plots (CAT048)
    ``time_s`` from I048/140; ``range_m`` = I048/040 RHO [NM] * 1852;
    ``azimuth_deg`` = I048/040 THETA; ``elevation_deg`` NaN (2-D radar);
    ``target_id`` = I048/220 as six lower-case hex digits ("" when absent);
    ``altitude_m`` = I048/090 flight level * 100 ft * 0.3048 m/ft (barometric
    pressure altitude, not a height above the ellipsoid; NaN when absent, not
    validated or garbled: declare it with ``[dataset] plot_altitude = "pressure"``
    in the user ``sites.toml``, which the dataset then carries); ``mode_3a`` =
    I048/070 as 4 octal digits ("" when absent, not validated (V=1) or garbled
    (G=1); a code not extracted during the last scan, L=1, is kept: it is the
    code the radar holds for that target); ``track_number`` = I048/161 (empty
    when absent; contract v3); extra column ``callsign`` from I048/240 ("" when
    absent).  Reports without I048/040 or I048/140 are skipped and counted.

ADS-B (CAT021)
    ``time_s`` from I021/071 (time of applicability for position), else
    I021/073 (time of message reception for position; within about a second
    of it), else I021/030 (editions 0.23 to 0.26); reports with none are skipped.
    ``target_id`` from I021/080; ``lat_deg``/``lon_deg`` from I021/131 (high
    resolution), else I021/130 (editions 0.2x: their only position, 180/2^23 deg
    in 0.23 and 180/2^25 deg in 0.24 to 0.26); ``alt_m`` = I021/140 geometric
    height [ft] * 0.3048 (height above the WGS-84 ellipsoid); ``nacp`` from
    I021/090 NACp (edition 2.x; the I021/090 of editions 0.2x is a figure of merit
    and is not read), else the NUCp of a DO-260 (version 0) transponder mapped to
    the NACp whose 95 % bound is not tighter (:data:`NUCP_TO_NACP`), else empty;
    ``baro_alt_m`` = I021/145 flight level * 100 ft * 0.3048 (the reported
    pressure altitude, contract v2; NaN when absent); ``mode_3a`` = I021/070 as 4
    octal digits (contract v3; "" when absent, as in editions 0.23 to 0.25, which
    have no I070, or, in edition 0.26, whose I070 has validity bits, not validated
    or garbled).  Reports without a
    position or address are skipped and counted.  A report without I021/140
    (old ground stations, edition 0.23, often send only I021/145) is kept with
    ``alt_m`` NaN and its ``baro_alt_m``: its position can be inspected, but a
    calibration does not use it (:func:`graphcal.data.cleaning.drop_non_finite_adsb`);
    one with neither I021/140 nor I021/145 is skipped and counted.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from graphcal.core.errors import DatasetError
from graphcal.data.dataset import Dataset, Site
from graphcal.data.epoch import epoch_from_unix
from graphcal.io.asterix.decode import (
    MAX_TIME_OF_DAY_S,
    AsterixError,
    Cat034Message,
    Cat048Report,
    Decoded,
    Report,
)
from graphcal.io.folder import load_plot_altitude, load_sites

#: Metres per nautical mile.
NM_M = 1852.0
#: Metres per foot.
FOOT_M = 0.3048
#: Seconds per day: ASTERIX times of day wrap here.
DAY_S = 86400.0
#: Plot table columns written (the contract columns, then ``callsign``).
PLOT_COLUMNS: tuple[str, ...] = (
    "radar_id", "time_s", "range_m", "azimuth_deg", "elevation_deg", "target_id",
    "altitude_m", "mode_3a", "track_number", "callsign",
)
#: ADS-B table columns written.
ADSB_COLUMNS: tuple[str, ...] = ("time_s", "target_id", "lat_deg", "lon_deg", "alt_m", "nacp",
                                 "baro_alt_m", "mode_3a")
#: NUCp (DO-260, 95 % horizontal error bound) -> NACp with a bound at least as large.
#: NUCp 0 means "unknown" and maps to no NACp.
NUCP_TO_NACP: dict[int, int] = {9: 11, 8: 10, 7: 8, 6: 7, 5: 6, 4: 5, 3: 4, 2: 1, 1: 1}


def default_radar_id(sac: int, sic: int) -> str:
    """The radar id used for a SAC/SIC not named by a ``sites.toml``: ``"SAC025_SIC201"``."""
    return f"SAC{sac:03d}_SIC{sic:03d}"


# --------------------------------------------------------------------------- time base


@dataclass(frozen=True)
class TimeBase:
    """The time base of the tables.

    Attributes
    ----------
    epoch_unix_s : float or None
        Unix time [s] of 00:00 UTC of day 0 (``time_s`` = 0); ``None`` when the
        recording has no capture times (the date is then unknown).
    wrapped : int
        Reports put on a day other than day 0.
    """

    epoch_unix_s: float | None
    wrapped: int = 0

    @property
    def date(self) -> str | None:
        """Day 0 as ``YYYY-MM-DD``, when known."""
        if self.epoch_unix_s is None:
            return None
        return pd.Timestamp(self.epoch_unix_s, unit="s", tz="UTC").strftime("%Y-%m-%d")


def midnight_utc(unix_s: float) -> float:
    """Unix time [s] of 00:00 UTC of the day that contains ``unix_s``."""
    return math.floor(unix_s / DAY_S) * DAY_S


def _report_time_of_day(report: Report) -> float | None:
    """The time of day [s] a report is placed with, per the module's rules."""
    if isinstance(report, Cat048Report | Cat034Message):
        return report.time_of_day_s
    if report.time_position_s is not None:
        return report.time_position_s
    return report.time_reception_s


def unwrap_times(
    sequence: Sequence[Report], epoch_unix_s: float | None = None
) -> tuple[list[float | None], TimeBase]:
    """Continuous times [s since 00:00 UTC of day 0] for reports in input order.

    Parameters
    ----------
    sequence : sequence of report
        Decoded reports in input order (:attr:`Decoded.sequence`).
    epoch_unix_s : float, optional
        Force day 0 to start at this unix time [s] (a midnight UTC); by default
        the midnight before the earliest capture time, if any.

    Returns
    -------
    times : list of float or None
        One entry per report (``None`` when it has no time of day).
    time_base : TimeBase
    """
    tod = np.array([np.nan if (t := _report_time_of_day(r)) is None else t for r in sequence],
                   dtype=float)
    capture = np.array([np.nan if r.capture_s is None else r.capture_s for r in sequence],
                       dtype=float)
    times, time_base = unwrap_time_array(tod, capture, epoch_unix_s)
    return [None if math.isnan(t) else float(t) for t in times.tolist()], time_base


def unwrap_time_array(tod_s: np.ndarray, capture_s: np.ndarray,
                      epoch_unix_s: float | None = None) -> tuple[np.ndarray, TimeBase]:
    """:func:`unwrap_times` on arrays: times of day and capture times of reports in input order.

    Parameters
    ----------
    tod_s : numpy.ndarray
        Time of day of each report [s]; NaN for none.
    capture_s : numpy.ndarray
        Capture time of each report [unix s]; NaN for none.
    epoch_unix_s : float, optional
        As for :func:`unwrap_times`.

    Returns
    -------
    times : numpy.ndarray
        Seconds since 00:00 UTC of day 0 (NaN where ``tod_s`` is NaN).
    time_base : TimeBase

    Notes
    -----
    A report with a capture time is put on the day closest to it; one without
    on the day closest to the previous report's time, i.e. its day is the
    previous report's day plus ``round((tod_prev - tod) / 86400)``: a cumulative
    sum, restarted at each report placed by its capture time.
    """
    tod_s = np.asarray(tod_s, dtype=float)
    capture_s = np.asarray(capture_s, dtype=float)
    has_capture = np.isfinite(capture_s)
    if epoch_unix_s is None and has_capture.any():
        epoch_unix_s = midnight_utc(float(capture_s[has_capture].min()))
    times = np.full(len(tod_s), np.nan)
    valid = np.flatnonzero(np.isfinite(tod_s))
    if not len(valid):
        return times, TimeBase(epoch_unix_s, 0)
    tod = tod_s[valid]
    anchored = has_capture[valid] & (epoch_unix_s is not None)
    step = np.zeros(len(valid))
    step[1:] = np.round((tod[:-1] - tod[1:]) / DAY_S)
    absolute = np.zeros(len(valid))
    if epoch_unix_s is not None:
        absolute[anchored] = np.round(
            (capture_s[valid][anchored] - epoch_unix_s - tod[anchored]) / DAY_S)
    step[anchored] = 0.0
    group = np.cumsum(anchored)  # reports after the k-th anchored report
    running = np.cumsum(step)
    start = np.concatenate([[0.0], running[anchored]])  # running sum at each anchor
    base = np.concatenate([[0.0], absolute[anchored]])
    day = base[group] + running - start[group]
    times[valid] = tod + DAY_S * day
    return times, TimeBase(epoch_unix_s, int(np.count_nonzero(day)))


# --------------------------------------------------------------------------- sites


@dataclass(frozen=True)
class UserSites:
    """A user ``sites.toml`` with optional ``sac``/``sic`` keys per radar."""

    sites: dict[str, Site]
    #: Radar id by (SAC, SIC), for tables that give them.
    by_source: dict[tuple[int, int], str]
    path: Path
    #: The file's ``[dataset] plot_altitude``: what the plots' altitudes (I048/090) are.
    plot_altitude: str = "geometric"


def load_user_sites(path: str | Path) -> UserSites:
    """Read a ``sites.toml`` whose ``[[radar]]`` tables may carry ``sac`` and ``sic``.

    Parameters
    ----------
    path : str or Path
        The file, as :func:`graphcal.io.folder.load_sites` reads it (the optional
        integer keys ``sac`` and ``sic``, both or neither, name the radar's ASTERIX
        data source).

    Returns
    -------
    UserSites

    Raises
    ------
    DatasetError
        If the file is missing, not TOML, or a table is invalid (including a
        ``sac`` without ``sic``, a value outside 0..255, or a SAC/SIC used twice).
    """
    path = Path(path)
    sites = load_sites(path)
    by_source: dict[tuple[int, int], str] = {}
    for row, site in enumerate(sites.values(), start=1):
        if site.sac is None or site.sic is None:
            continue
        source = (site.sac, site.sic)
        if source in by_source:
            raise DatasetError(f"SAC {site.sac} / SIC {site.sic} already belongs to radar "
                               f"{by_source[source]!r}", path=path, row=row, field="sic")
        by_source[source] = site.id
    return UserSites(sites, by_source, path, load_plot_altitude(path))


def _cat034_site(radar_id: str, message: Cat034Message) -> Site:
    """A 2-D site at the CAT034 I120 position, sigmas to be estimated."""
    assert message.lat_deg is not None and message.lon_deg is not None
    return Site(
        id=radar_id,
        lat_rad=math.radians(message.lat_deg),
        lon_rad=math.radians(message.lon_deg),
        alt_m=float(message.height_m or 0.0),
        sigma_range_m=math.nan,
        sigma_azimuth_rad=math.nan,
    )


# --------------------------------------------------------------------------- tables


@dataclass
class TableStats:
    """What the table builder kept and skipped.

    Attributes
    ----------
    plots_by_radar : dict
        Plots kept per radar id.
    sources : dict
        ``(SAC, SIC)`` of each radar id.
    site_origin : dict
        Where each radar's position came from: ``"sites.toml"`` or ``"CAT034"``.
    skipped : Counter
        Reports skipped, by reason.
    adsb_reports, aircraft : int
        ADS-B rows kept; distinct addresses among them.
    adsb_without_height : int
        Of the ADS-B rows kept, those without a geometric height (no I021/140):
        ``alt_m`` is NaN.
    adsb_without_height_baro : int
        Of those, rows that carry a flight level (I021/145) as ``baro_alt_m``.
    """

    plots_by_radar: dict[str, int] = field(default_factory=dict)
    sources: dict[str, tuple[int, int]] = field(default_factory=dict)
    site_origin: dict[str, str] = field(default_factory=dict)
    skipped: Counter[str] = field(default_factory=Counter)
    adsb_reports: int = 0
    aircraft: int = 0
    adsb_without_height: int = 0
    adsb_without_height_baro: int = 0


@dataclass
class AsterixTables:
    """Contract tables built from a recording."""

    dataset: Dataset
    time_base: TimeBase
    stats: TableStats
    decode: Decoded


def _with_sigma(adsb: pd.DataFrame | None) -> pd.DataFrame | None:
    """``sigma_m`` filled in as :func:`graphcal.io.folder.load_dataset` does: from NACp, else
    the default, so that the in-memory dataset is the one a reader of the folder gets."""
    if adsb is None or "sigma_m" in adsb:
        return adsb
    from graphcal.data.dataset import ADSB_DEFAULT_SIGMA_M
    from graphcal.data.sensor_models import adsb_sigma_from_nacp

    adsb = adsb.copy()
    nacp = (pd.to_numeric(adsb["nacp"], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
            if "nacp" in adsb else np.full(len(adsb), np.nan))
    sigma = adsb_sigma_from_nacp(nacp) if len(adsb) else np.zeros(0)
    adsb["sigma_m"] = np.where(np.isfinite(sigma), sigma, ADSB_DEFAULT_SIGMA_M)
    return adsb


def _radar_ids(sources: Iterable[tuple[int, int]], user: UserSites | None
               ) -> dict[tuple[int, int], str]:
    out = {}
    for source in sources:
        if user is not None and source in user.by_source:
            out[source] = user.by_source[source]
        else:
            out[source] = default_radar_id(*source)
    return out


def mode_3a_text(code: np.ndarray) -> np.ndarray:
    """Mode 3/A codes as 4 octal digits (``0o413`` -> ``"0413"``); ``""`` where absent (-1).

    Parameters
    ----------
    code : numpy.ndarray
        The 12-bit codes (bits A4 A2 A1 B4 B2 B1 C4 C2 C1 D4 D2 D1), -1 for none.

    Returns
    -------
    numpy.ndarray
        Strings, one per code.
    """
    code = np.asarray(code, dtype=np.int64)
    digits = np.stack([(code >> shift) & 7 for shift in (9, 6, 3, 0)], axis=1)
    text = np.ascontiguousarray((digits + ord("0")).astype(np.uint8)).view("S4").ravel()
    return np.where(code >= 0, text.astype(str), "")


def _nullable_int(values: np.ndarray) -> pd.arrays.IntegerArray:
    """Integers as ``Int64``, missing where negative (-1: absent)."""
    values = np.asarray(values, dtype=np.int64)
    return pd.arrays.IntegerArray(np.where(values >= 0, values, 0), values < 0)


def _hex_addresses(address: np.ndarray) -> list[str]:
    """Six lower-case hex digits per address; "" where absent (-1)."""
    return ["" if a < 0 else f"{a:06x}" for a in address.tolist()]


def _nacp(columns: Mapping[str, np.ndarray]) -> np.ndarray:
    """NACp, else a DO-260 NUCp mapped (:data:`NUCP_TO_NACP`), else -1."""
    nacp = columns["nacp"].astype(np.int64)
    mapped = np.full(16, -1, dtype=np.int64)
    for nucp, value in NUCP_TO_NACP.items():
        mapped[nucp] = value
    nucp = columns["nucp"].astype(np.int64)
    from_nucp = np.where((columns["mops_version"] == 0) & (nucp >= 0),
                         mapped[np.clip(nucp, 0, 15)], -1)
    return np.where(nacp >= 0, nacp, from_nucp)


def _skip_first(reasons: Sequence[tuple[str, np.ndarray]], skipped: Counter[str]
                ) -> np.ndarray:
    """Rows kept: those where no ``(reason, bad)`` mask holds; each dropped row is counted
    under the first reason that holds for it."""
    n = len(reasons[0][1]) if reasons else 0
    keep = np.ones(n, dtype=bool)
    for reason, bad in reasons:
        hit = keep & bad
        if hit.any():
            skipped[reason] += int(hit.sum())
        keep &= ~bad
    return keep


#: Reasons for skipping a report whose time of day is out of range: more than
#: :data:`~graphcal.io.asterix.decode.MAX_TIME_OF_DAY_S` (86 400 s and a leap second;
#: the items hold up to 131 072 s), so a corrupted value.  Such a time is also left out
#: when the day of every report is found (:func:`build_tables`).
SKIP_TOD_048 = "CAT048 time of day (I140) beyond 86400 s"
SKIP_TOD_021 = "CAT021 time of day beyond 86400 s"
#: Reasons for skipping a report put on a day before day 0, i.e. a negative ``time_s``:
#: a time of day more than 12 h before the previous report's (raw files) or its
#: capture time's (pcap), a corrupted value far more often than a report stamped
#: before the midnight that starts the recording.
SKIP_BEFORE_DAY_0_048 = "CAT048 time before 00:00 of day 0 (negative time_s)"
SKIP_BEFORE_DAY_0_021 = "CAT021 time before 00:00 of day 0 (negative time_s)"


def _bad_time_of_day(tod: np.ndarray) -> np.ndarray:
    """True where a time of day [s] is given but out of range (negative, or beyond
    :data:`~graphcal.io.asterix.decode.MAX_TIME_OF_DAY_S`)."""
    with np.errstate(invalid="ignore"):
        return np.isfinite(tod) & ((tod < 0.0) | (tod >= MAX_TIME_OF_DAY_S))


def _time_of_position(columns: Mapping[str, np.ndarray]) -> np.ndarray:
    """A CAT021 report's time of day [s]: of applicability for position, else of reception."""
    t = columns["time_position_s"]
    return np.where(np.isfinite(t), t, columns["time_reception_s"])


def plots_frame(columns: Mapping[str, np.ndarray], times: np.ndarray,
                radar_ids: Mapping[tuple[int, int], str], skipped: Counter[str],
                elevation_deg: np.ndarray | None = None,
                three_d: Iterable[tuple[int, int]] = ()) -> pd.DataFrame:
    """The plots table of CAT048 columns (module docstring for the columns).

    Parameters
    ----------
    columns : mapping
        CAT048 columns (:attr:`Decoded.columns` ``[48]``).
    times : numpy.ndarray
        Unwrapped times [s] of those reports (NaN: none).
    radar_ids : mapping
        Radar id of each SAC/SIC.
    skipped : Counter
        Counts reports without I040, without a time, or (a 3-D radar) without I110.
    elevation_deg : numpy.ndarray, optional
        Elevation of each report [deg] (NaN: none), for 3-D radars.
    three_d : iterable of (SAC, SIC)
        3-D radars: their reports without an elevation are skipped.
    """
    sac, sic = columns["sac"], columns["sic"]
    n = len(sac)
    elevation = np.full(n, np.nan) if elevation_deg is None else elevation_deg
    codes = sac * 256 + sic
    wanted = np.array([s * 256 + c for s, c in three_d], dtype=np.int64)
    is_3d = np.isin(codes, wanted)
    keep = _skip_first([
        ("CAT048 without I040 (polar position)",
         ~np.isfinite(columns["rho_nm"]) | ~np.isfinite(columns["theta_deg"])),
        (SKIP_TOD_048, _bad_time_of_day(columns["time_of_day_s"])),
        ("CAT048 without I140 (time of day)", ~np.isfinite(times)),
        (SKIP_BEFORE_DAY_0_048, times < 0.0),
        ("CAT048 of a 3-D radar without I110 (height)", is_3d & ~np.isfinite(elevation)),
    ], skipped)
    code_ids = {s * 256 + c: rid for (s, c), rid in radar_ids.items()}
    level = columns["flight_level"][keep]
    callsign = columns["callsign"][keep]
    frame = pd.DataFrame({
        "radar_id": [code_ids[k] for k in codes[keep].tolist()],
        "time_s": times[keep].astype(float),
        "range_m": columns["rho_nm"][keep] * NM_M,
        "azimuth_deg": columns["theta_deg"][keep] % 360.0,
        "elevation_deg": np.where(is_3d[keep], elevation[keep], np.nan),
        "target_id": _hex_addresses(columns["address"][keep]),
        "altitude_m": level * 100.0 * FOOT_M,
        "mode_3a": mode_3a_text(columns["mode_3a"][keep]),
        "track_number": _nullable_int(columns["track_number"][keep]),
        "callsign": ["" if c is None else c for c in callsign.tolist()],
    }, columns=list(PLOT_COLUMNS))
    return frame


def adsb_frame(columns: Mapping[str, np.ndarray], times: np.ndarray,
               skipped: Counter[str]) -> pd.DataFrame:
    """The ADS-B table of CAT021 columns (module docstring for the columns)."""
    lat, lon = columns["lat_deg"], columns["lon_deg"]
    with np.errstate(invalid="ignore"):
        keep = _skip_first([
            ("CAT021 without position", ~np.isfinite(lat) | ~np.isfinite(lon)),
            ("CAT021 position out of range", ~((np.abs(lat) <= 90.0) & (np.abs(lon) <= 180.0))),
            ("CAT021 without target address", columns["address"] < 0),
            # Without I140 the report is kept (alt_m NaN) when it has a flight level.
            ("CAT021 without geometric height (I140) or flight level (I145)",
             ~np.isfinite(columns["geo_height_ft"]) & ~np.isfinite(columns["flight_level"])),
            (SKIP_TOD_021, _bad_time_of_day(_time_of_position(columns))),
            ("CAT021 without time of position", ~np.isfinite(times)),
            (SKIP_BEFORE_DAY_0_021, times < 0.0),
        ], skipped)
    nacp = _nacp(columns)[keep]
    frame = pd.DataFrame({
        "time_s": times[keep].astype(float),
        "target_id": _hex_addresses(columns["address"][keep]),
        "lat_deg": lat[keep],
        "lon_deg": lon[keep],
        "alt_m": columns["geo_height_ft"][keep] * FOOT_M,
        "nacp": pd.array(np.where(nacp >= 0, nacp, 0), dtype="Int64"),
        "baro_alt_m": columns["flight_level"][keep] * 100.0 * FOOT_M,
        "mode_3a": mode_3a_text(columns["mode_3a"][keep]),
    }, columns=list(ADSB_COLUMNS))
    frame.loc[nacp < 0, "nacp"] = pd.NA
    return frame


@dataclass(frozen=True)
class RadarInventory:
    """What a recording holds of one radar (one SAC/SIC with CAT048 reports).

    Attributes
    ----------
    sac, sic : int
        Data source identifier.
    radar_id : str
        Its id (from the user sites, else :func:`default_radar_id`).
    plots : int
        CAT048 reports.
    polar_reports : int
        Of them, reports with a polar position (I048/040).
    height_reports : int
        Of those, reports that also carry I048/110 (height measured by a 3-D radar).
    cat034 : Cat034Message or None
        The first CAT034 message with a position (I034/120), if any.
    """

    sac: int
    sic: int
    radar_id: str
    plots: int
    polar_reports: int
    height_reports: int
    cat034: Cat034Message | None

    @property
    def is_3d(self) -> bool:
        """True when every report with a polar position carries a 3-D height (I048/110),
        as a dataset's radar is 3-D when every plot has an elevation."""
        return 0 < self.height_reports == self.polar_reports


def radar_inventory(decoded: Decoded, user_sites: UserSites | None = None
                    ) -> list[RadarInventory]:
    """One entry per SAC/SIC with CAT048 reports, in order of first appearance."""
    columns = decoded.columns[48]
    codes = columns["sac"] * 256 + columns["sic"]
    unique, first, counts = np.unique(codes, return_index=True, return_counts=True)
    index = np.searchsorted(unique, codes)
    polar = np.isfinite(columns["rho_nm"]) & np.isfinite(columns["theta_deg"])
    polars = np.bincount(index, weights=polar, minlength=len(unique))
    heights = np.bincount(index, weights=polar & np.isfinite(columns["height_ft"]),
                          minlength=len(unique))
    positions: dict[tuple[int, int], Cat034Message] = {}
    c034 = decoded.columns[34]
    has = np.isfinite(c034["lat_deg"]) & np.isfinite(c034["lon_deg"])
    for index in np.flatnonzero(has).tolist():
        source = (int(c034["sac"][index]), int(c034["sic"][index]))
        if source not in positions:
            positions[source] = decoded.cat034[index]
    sources = [divmod(int(code), 256) for code in unique]
    radar_ids = _radar_ids(sources, user_sites)
    out = [RadarInventory(s, c, radar_ids[(s, c)], int(n), int(p), int(h), positions.get((s, c)))
           for (s, c), n, p, h in zip(sources, counts.tolist(), polars.tolist(),
                                      heights.tolist(), strict=True)]
    order = np.argsort(first, kind="stable")
    return [out[i] for i in order.tolist()]


def sites_template(inventory: Sequence[RadarInventory], recordings: Sequence[str] = ()) -> str:
    """A ``sites.toml`` with one ``[[radar]]`` table per radar of a recording, to fill in.

    Each table has ``id``, ``sac``, ``sic``, a comment with the radar's plot counts
    (and whether its plots carry a 3-D height, I048/110) and the position keys
    ``lat_deg``, ``lon_deg``, ``alt_m``: the CAT034 I034/120 position when the
    recording has one, else ``nan``, which the reader refuses until it is replaced.
    The sigma keys are left out: graphcal then estimates them (a table without any
    sigma is a 3-D radar when all its plots carry an elevation).

    Parameters
    ----------
    inventory : sequence of RadarInventory
        From :func:`radar_inventory`.
    recordings : sequence of str
        Named in the header comment.
    """
    lines = [
        "# Radar sites of " + (", ".join(recordings) or "an ASTERIX recording")
        + f": {len(inventory)} radar{'s' if len(inventory) != 1 else ''} (SAC/SIC of CAT048).",
        "# Replace every nan by the antenna position: lat_deg, lon_deg [deg, WGS-84] and",
        "# alt_m [m above the ellipsoid]; ids may be renamed. Then:",
        "#   graphcal import-asterix RECORDING... --sites THIS_FILE --out DIR",
        "",
    ]
    for radar in inventory:
        kind = ("3-D: every plot carries a height (I048/110)" if radar.is_3d else
                f"2-D ({radar.height_reports} plots with a height, I048/110)"
                if radar.height_reports else "2-D")
        lines += [
            "[[radar]]",
            f'id = "{radar.radar_id}"',
            f"sac = {radar.sac}",
            f"sic = {radar.sic}",
            f"# {radar.plots} CAT048 reports, {radar.polar_reports} with a polar position; {kind}",
        ]
        message = radar.cat034
        if message is not None and message.lat_deg is not None and message.lon_deg is not None:
            lines += [
                "# position from CAT034 I034/120 (check it)",
                f"lat_deg = {message.lat_deg!r}",
                f"lon_deg = {message.lon_deg!r}",
                f"alt_m = {float(message.height_m or 0.0)!r}",
            ]
        else:
            lines += ["lat_deg = nan", "lon_deg = nan", "alt_m = nan"]
        lines.append("")
    return "\n".join(lines)


#: A source with no position and at most this many plots ...
STRAY_MAX_PLOTS = 20
#: ... and at most this share of the recording's plots is a corrupted SAC/SIC, not a radar.
STRAY_MAX_SHARE = 1e-3
#: How its plots are counted among the skipped reports.
STRAY_REASON = "CAT048 of a SAC/SIC with a handful of plots and no position (a corrupted SAC/SIC?)"


def stray_sources(missing: Sequence[RadarInventory],
                   inventory: Sequence[RadarInventory]) -> list[RadarInventory]:
    """Sources without a position whose few plots (at most :data:`STRAY_MAX_PLOTS` and
    :data:`STRAY_MAX_SHARE` of all) are a corrupted data source identifier: a radar of a
    real recording sends thousands.  They are left out, not asked a position for."""
    total = sum(r.plots for r in inventory)
    return [r for r in missing
            if r.plots <= STRAY_MAX_PLOTS and r.plots <= STRAY_MAX_SHARE * total]


def _position_help(missing: Sequence[RadarInventory]) -> str:
    names = ", ".join(f"SAC {r.sac} / SIC {r.sic} ({r.radar_id}, {r.plots} plots)"
                      for r in missing)
    return (
        f"{len(missing)} radar{'s' if len(missing) > 1 else ''} with plots but no known "
        f"position (no CAT034 I120): {names}; pass --sites with a sites.toml holding a "
        "[[radar]] table for each (id, sac, sic, lat_deg, lon_deg, alt_m): "
        "--write-sites-template FILE writes one to fill in"
    )


def check_dimensions(inventory: Sequence[RadarInventory], sites: Mapping[str, Site],
                     source: str | Path | None = None) -> None:
    """Refuse a radar that ``sites`` declares 3-D while its reports carry no height
    (I048/110), or the reverse.

    Raises
    ------
    AsterixError
        Naming the first such radar.
    """
    for radar in inventory:
        site = sites.get(radar.radar_id)
        if site is None:
            continue
        if site.is_3d and not radar.is_3d:
            raise AsterixError(
                f"radar {radar.radar_id} (SAC {radar.sac} / SIC {radar.sic}) is 3-D in the "
                f"sites.toml (sigma_elevation_mrad) but {radar.height_reports} of its "
                f"{radar.polar_reports} CAT048 plots carry a 3-D height (I048/110), not all: "
                "a 2-D radar; remove sigma_elevation_mrad from its table", path=source)
        undetermined = (site.missing_sigmas == ("sigma_range_m", "sigma_azimuth_mrad")
                        and not site.model)  # no sigma at all: the plots decide
        if radar.is_3d and not site.is_3d and not undetermined:
            raise AsterixError(
                f"radar {radar.radar_id} (SAC {radar.sac} / SIC {radar.sic}) is 2-D in the "
                "sites.toml (no sigma_elevation_mrad) but all its "
                f"{radar.polar_reports} CAT048 plots carry a 3-D height (I048/110): a 3-D "
                "radar; give its sigma_elevation_mrad", path=source)


def _elevations(columns: Mapping[str, np.ndarray], sites: Mapping[tuple[int, int], Site]
                ) -> np.ndarray:
    """Elevation [deg] of each CAT048 report with a 3-D height, from the height, the slant
    range and its radar's position (:func:`graphcal.core.frames.elevation_from_height`)."""
    from graphcal.core.frames import elevation_from_height

    elevation = np.full(len(columns["sac"]), np.nan)
    codes = columns["sac"] * 256 + columns["sic"]
    height_m = columns["height_ft"] * FOOT_M
    range_m = columns["rho_nm"] * NM_M
    for (sac, sic), site in sites.items():
        rows = (codes == sac * 256 + sic) & np.isfinite(height_m) & np.isfinite(range_m)
        if rows.any():
            elevation[rows] = np.degrees(elevation_from_height(
                range_m[rows], height_m[rows], site.lat_rad, site.alt_m))
    return elevation


def records_time_of_day(decoded: Decoded) -> tuple[np.ndarray, np.ndarray]:
    """Time of day [s] (NaN: none, or out of range) and capture time [unix s] of every
    report in input order."""
    n = len(decoded.order)
    tod, capture = np.full(n, np.nan), np.full(n, np.nan)
    for category, columns in decoded.columns.items():
        rows = decoded.order == category
        tod[rows] = (_time_of_position(columns) if category == 21
                     else columns["time_of_day_s"])
        capture[rows] = columns["capture_s"]
    # An out-of-range time of day is not used to place the reports after it.
    tod[_bad_time_of_day(tod)] = np.nan
    return tod, capture


def build_tables(
    decoded: Decoded,
    *,
    user_sites: UserSites | None = None,
    adsb: pd.DataFrame | None = None,
    epoch_unix_s: float | None = None,
    source: str | Path | None = None,
) -> AsterixTables:
    """Build the dataset (sites, plots, adsb) of a decoded recording.

    Parameters
    ----------
    decoded : Decoded
        Output of :func:`graphcal.io.asterix.decode.decode_files`.
    user_sites : UserSites, optional
        Sites that win over CAT034 positions (:func:`load_user_sites`).
    adsb : pandas.DataFrame, optional
        An ADS-B table already on this recording's time base (for instance from
        :func:`graphcal.io.opensky.read_opensky_adsb` with the epoch of
        :func:`recording_epoch`); replaces CAT021 reports when given.
    epoch_unix_s : float, optional
        Force day 0 (see :func:`unwrap_times`).
    source : str or Path, optional
        Named in error messages.

    Returns
    -------
    AsterixTables
        Its dataset's ``epoch_utc`` is day 0's midnight when known (capture times,
        or ``epoch_unix_s``), else ``None``.

    Raises
    ------
    AsterixError
        If there is no usable CAT048 plot, if radars with plots have no known
        position (all of them named in one message), or if the user sites say a
        radar is 3-D while its reports carry no height (I048/110), or the reverse
        (:func:`check_dimensions`).
    """
    if not decoded.count(48):
        raise AsterixError("no CAT048 target reports (plots) in the recording", path=source)
    inventory = radar_inventory(decoded, user_sites)
    user = {} if user_sites is None else user_sites.sites
    columns = decoded.columns[48]
    usable = (np.isfinite(columns["rho_nm"]) & np.isfinite(columns["theta_deg"])
              & np.isfinite(columns["time_of_day_s"]))
    usable_codes = set((columns["sac"] * 256 + columns["sic"])[usable].tolist())
    missing = [r for r in inventory if r.radar_id not in user and r.cat034 is None
               and r.sac * 256 + r.sic in usable_codes]
    stray = stray_sources(missing, inventory)
    missing = [r for r in missing if r not in stray]
    if missing:
        raise AsterixError(_position_help(missing), path=source)
    for radar in stray:  # a corrupted SAC/SIC: its few plots left out, counted
        usable_codes.discard(radar.sac * 256 + radar.sic)
    check_dimensions(inventory, user, source)

    stats = TableStats()
    sites: dict[str, Site] = {}
    by_source: dict[tuple[int, int], Site] = {}
    for radar in inventory:
        if radar.radar_id in sites or radar.sac * 256 + radar.sic not in usable_codes:
            continue
        if radar.radar_id in user:
            site = user[radar.radar_id]
            stats.site_origin[radar.radar_id] = "sites.toml"
        else:
            assert radar.cat034 is not None
            site = _cat034_site(radar.radar_id, radar.cat034)
            if radar.is_3d:
                site = replace(site, sigma_elevation_rad=math.nan)
            stats.site_origin[radar.radar_id] = "CAT034"
        # The radar keeps its SAC/SIC (sites.toml sac/sic keys) for the CAT063 export.
        sites[radar.radar_id] = replace(site, sac=radar.sac, sic=radar.sic)
        by_source[(radar.sac, radar.sic)] = sites[radar.radar_id]
        stats.sources[radar.radar_id] = (radar.sac, radar.sic)

    tod, capture = records_time_of_day(decoded)
    times, time_base = unwrap_time_array(tod, capture, epoch_unix_s)
    radar_ids = {(r.sac, r.sic): r.radar_id for r in inventory}
    three_d = [(r.sac, r.sic) for r in inventory if r.is_3d]
    plots = plots_frame(columns, times[decoded.order == 48], radar_ids, stats.skipped,
                        _elevations(columns, by_source) if three_d else None, three_d)
    if plots.empty:
        raise AsterixError(
            "no usable CAT048 plot (every report lacks I040 polar position or I140 time)",
            path=source)
    if stray:
        gone = plots["radar_id"].isin([r.radar_id for r in stray]).to_numpy()
        stats.skipped[STRAY_REASON] += int(gone.sum())
        plots = plots[~gone].reset_index(drop=True)
    counts = plots["radar_id"].value_counts()
    for radar_id in list(sites):
        if radar_id not in counts.index:
            del sites[radar_id]
            stats.sources.pop(radar_id)
            stats.site_origin.pop(radar_id)
        else:
            stats.plots_by_radar[radar_id] = int(counts[radar_id])

    if adsb is None and decoded.count(21):
        adsb = adsb_frame(decoded.columns[21], times[decoded.order == 21], stats.skipped)
    if adsb is not None and adsb.empty:
        adsb = None
    if adsb is not None:
        stats.adsb_reports = len(adsb)
        stats.aircraft = int(adsb["target_id"].nunique())
        no_height = ~np.isfinite(adsb["alt_m"].to_numpy(dtype=float, na_value=np.nan))
        stats.adsb_without_height = int(no_height.sum())
        if "baro_alt_m" in adsb:
            baro = adsb["baro_alt_m"].to_numpy(dtype=float, na_value=np.nan)
            stats.adsb_without_height_baro = int((no_height & np.isfinite(baro)).sum())
    epoch = None if time_base.epoch_unix_s is None else epoch_from_unix(time_base.epoch_unix_s)
    dataset = Dataset(sites=sites, plots=plots, adsb=_with_sigma(adsb),
                      plot_altitude="geometric" if user_sites is None else user_sites.plot_altitude,
                      epoch_utc=epoch)
    return AsterixTables(dataset=dataset, time_base=time_base, stats=stats, decode=decoded)


def recording_epoch(decoded: Decoded) -> float | None:
    """Midnight UTC [unix s] before the earliest capture time, ``None`` without captures."""
    captures = np.concatenate([c["capture_s"] for c in decoded.columns.values()])
    captures = captures[np.isfinite(captures)]
    return midnight_utc(float(captures.min())) if len(captures) else None


def sorted_by_time(frame: pd.DataFrame, keys: Sequence[str]) -> pd.DataFrame:
    """``frame`` sorted by ``keys`` (stable), with a fresh index."""
    return frame.sort_values(list(keys), kind="stable").reset_index(drop=True)


def time_span(frames: Iterable[pd.DataFrame | None]) -> tuple[float, float] | None:
    """``(first, last)`` ``time_s`` [s] over the given tables, ``None`` when all are empty."""
    values = [f["time_s"].to_numpy(dtype=float) for f in frames if f is not None and len(f)]
    if not values:
        return None
    joined = np.concatenate(values)
    return float(joined.min()), float(joined.max())
