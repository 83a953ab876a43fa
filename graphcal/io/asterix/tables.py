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

Plots (CAT048)
    ``time_s`` from I048/140; ``range_m`` = I048/040 RHO [NM] * 1852;
    ``azimuth_deg`` = I048/040 THETA; ``elevation_deg`` NaN (2-D radar);
    ``target_id`` = I048/220 as six lower-case hex digits ("" when absent);
    ``altitude_m`` = I048/090 flight level * 100 ft * 0.3048 m/ft (barometric
    pressure altitude, not a height above the ellipsoid; NaN when absent, not
    validated or garbled: declare it with ``[dataset] plot_altitude = "pressure"``
    in the user ``sites.toml``, which the dataset then carries); extra column
    ``callsign`` from I048/240 ("" when absent).  Reports without I048/040 or
    I048/140 are skipped and counted.

ADS-B (CAT021)
    ``time_s`` from I021/071 (time of applicability for position), else
    I021/073 (time of message reception for position; within about a second
    of it), else I021/030 (edition 0.x); reports with none are skipped.
    ``target_id`` from I021/080; ``lat_deg``/``lon_deg`` from I021/131 (high
    resolution), else I021/130; ``alt_m`` = I021/140 geometric height [ft] *
    0.3048 (height above the WGS-84 ellipsoid); ``nacp`` from I021/090 NACp,
    else the NUCp of a DO-260 (version 0) transponder mapped to the NACp whose
    95 % bound is not tighter (:data:`NUCP_TO_NACP`), else empty;
    ``baro_alt_m`` = I021/145 flight level * 100 ft * 0.3048 (the reported
    pressure altitude, contract v2; NaN when absent).  Reports without a
    position, address or geometric height are skipped and counted.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from graphcal.core.errors import DatasetError
from graphcal.data.dataset import Dataset, Site
from graphcal.io.asterix.decode import (
    AsterixError,
    Cat021Report,
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
    "altitude_m", "callsign",
)
#: ADS-B table columns written.
ADSB_COLUMNS: tuple[str, ...] = ("time_s", "target_id", "lat_deg", "lon_deg", "alt_m", "nacp",
                                 "baro_alt_m")
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
    captures = [r.capture_s for r in sequence if r.capture_s is not None]
    if epoch_unix_s is None and captures:
        epoch_unix_s = midnight_utc(min(captures))
    times: list[float | None] = []
    reference: float | None = None
    wrapped = 0
    for report in sequence:
        tod = _report_time_of_day(report)
        if tod is None:
            times.append(None)
            continue
        if report.capture_s is not None and epoch_unix_s is not None:
            anchor: float | None = report.capture_s - epoch_unix_s
        else:
            anchor = reference
        day = 0 if anchor is None else round((anchor - tod) / DAY_S)
        value = tod + DAY_S * day
        wrapped += day != 0
        times.append(value)
        reference = value
    return times, TimeBase(epoch_unix_s, wrapped)


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
    """

    plots_by_radar: dict[str, int] = field(default_factory=dict)
    sources: dict[str, tuple[int, int]] = field(default_factory=dict)
    site_origin: dict[str, str] = field(default_factory=dict)
    skipped: Counter[str] = field(default_factory=Counter)
    adsb_reports: int = 0
    aircraft: int = 0


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


def _hex_address(address: int | None) -> str:
    return "" if address is None else f"{address:06x}"


def _nacp(report: Cat021Report) -> int | None:
    if report.nacp is not None:
        return report.nacp
    if report.mops_version == 0 and report.nucp is not None:
        return NUCP_TO_NACP.get(report.nucp)
    return None


def plots_frame(reports: Sequence[Cat048Report], times: Sequence[float | None],
                radar_ids: Mapping[tuple[int, int], str], skipped: Counter[str]
                ) -> pd.DataFrame:
    """The plots table of CAT048 reports (module docstring for the columns).

    ``times`` are the unwrapped times [s] of ``reports``; ``skipped`` counts
    reports without I040 or without a time.
    """
    rows: dict[str, list[Any]] = {name: [] for name in PLOT_COLUMNS}
    for report, time_s in zip(reports, times, strict=True):
        if report.rho_nm is None or report.theta_deg is None:
            skipped["CAT048 without I040 (polar position)"] += 1
            continue
        if time_s is None:
            skipped["CAT048 without I140 (time of day)"] += 1
            continue
        rows["radar_id"].append(radar_ids[(report.sac, report.sic)])
        rows["time_s"].append(time_s)
        rows["range_m"].append(report.rho_nm * NM_M)
        rows["azimuth_deg"].append(report.theta_deg % 360.0)
        rows["elevation_deg"].append(math.nan)
        rows["target_id"].append(_hex_address(report.address))
        level = report.flight_level
        rows["altitude_m"].append(math.nan if level is None else level * 100.0 * FOOT_M)
        rows["callsign"].append(report.callsign or "")
    frame = pd.DataFrame(rows, columns=list(PLOT_COLUMNS))
    for column in ("time_s", "range_m", "azimuth_deg", "elevation_deg", "altitude_m"):
        frame[column] = frame[column].astype(float)
    return frame


def adsb_frame(reports: Sequence[Cat021Report], times: Sequence[float | None],
               skipped: Counter[str]) -> pd.DataFrame:
    """The ADS-B table of CAT021 reports (module docstring for the columns)."""
    rows: dict[str, list[Any]] = {name: [] for name in ADSB_COLUMNS}
    for report, time_s in zip(reports, times, strict=True):
        if report.lat_deg is None or report.lon_deg is None:
            skipped["CAT021 without position"] += 1
            continue
        if not (-90.0 <= report.lat_deg <= 90.0 and -180.0 <= report.lon_deg <= 180.0):
            skipped["CAT021 position out of range"] += 1
            continue
        if report.address is None:
            skipped["CAT021 without target address"] += 1
            continue
        if report.geo_height_ft is None:
            skipped["CAT021 without geometric height (I140)"] += 1
            continue
        if time_s is None:
            skipped["CAT021 without time of position"] += 1
            continue
        rows["time_s"].append(time_s)
        rows["target_id"].append(_hex_address(report.address))
        rows["lat_deg"].append(report.lat_deg)
        rows["lon_deg"].append(report.lon_deg)
        rows["alt_m"].append(report.geo_height_ft * FOOT_M)
        rows["nacp"].append(_nacp(report))
        level = report.flight_level
        rows["baro_alt_m"].append(math.nan if level is None else level * 100.0 * FOOT_M)
    frame = pd.DataFrame(rows, columns=list(ADSB_COLUMNS))
    for column in ("time_s", "lat_deg", "lon_deg", "alt_m", "baro_alt_m"):
        frame[column] = frame[column].astype(float)
    frame["nacp"] = pd.array(frame["nacp"].tolist(), dtype="Int64")
    return frame


def _position_help(sac: int, sic: int, radar_id: str) -> str:
    return (
        f"radar SAC {sac} / SIC {sic} ({radar_id}) has plots but no known position (the "
        "recording has no CAT034 I120 for it); pass --sites with a sites.toml whose radar "
        f"table has id = \"{radar_id}\", sac = {sac}, sic = {sic}, lat_deg, lon_deg, alt_m"
    )


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

    Raises
    ------
    AsterixError
        If there is no usable CAT048 plot, or a radar with plots has no
        known position.
    """
    times, time_base = unwrap_times(decoded.sequence, epoch_unix_s)
    time_of = {id(report): t for report, t in zip(decoded.sequence, times, strict=True)}
    stats = TableStats()
    if not decoded.cat048:
        raise AsterixError("no CAT048 target reports (plots) in the recording", path=source)
    sources = list(dict.fromkeys((r.sac, r.sic) for r in decoded.cat048))
    radar_ids = _radar_ids(sources, user_sites)
    plots = plots_frame(decoded.cat048, [time_of[id(r)] for r in decoded.cat048], radar_ids,
                        stats.skipped)
    if plots.empty:
        raise AsterixError(
            "no usable CAT048 plot (every report lacks I040 polar position or I140 time)",
            path=source)

    cat034_positions: dict[tuple[int, int], Cat034Message] = {}
    for message in decoded.cat034:
        if message.lat_deg is not None and message.lon_deg is not None:
            cat034_positions.setdefault((message.sac, message.sic), message)
    sites: dict[str, Site] = {}
    counts = plots["radar_id"].value_counts()
    for sac_sic in sources:
        radar_id = radar_ids[sac_sic]
        if radar_id not in counts.index or radar_id in sites:
            continue
        if user_sites is not None and radar_id in user_sites.sites:
            sites[radar_id] = user_sites.sites[radar_id]
            stats.site_origin[radar_id] = "sites.toml"
        elif sac_sic in cat034_positions:
            sites[radar_id] = _cat034_site(radar_id, cat034_positions[sac_sic])
            stats.site_origin[radar_id] = "CAT034"
        else:
            raise AsterixError(_position_help(*sac_sic, radar_id), path=source)
        # The radar keeps its SAC/SIC (sites.toml sac/sic keys) for the CAT063 export.
        sites[radar_id] = replace(sites[radar_id], sac=int(sac_sic[0]), sic=int(sac_sic[1]))
        stats.sources[radar_id] = sac_sic
        stats.plots_by_radar[radar_id] = int(counts[radar_id])

    if adsb is None and decoded.cat021:
        adsb = adsb_frame(decoded.cat021, [time_of[id(r)] for r in decoded.cat021],
                          stats.skipped)
    if adsb is not None and adsb.empty:
        adsb = None
    if adsb is not None:
        stats.adsb_reports = len(adsb)
        stats.aircraft = int(adsb["target_id"].nunique())
    dataset = Dataset(sites=sites, plots=plots, adsb=_with_sigma(adsb),
                      plot_altitude="geometric" if user_sites is None else user_sites.plot_altitude)
    return AsterixTables(dataset=dataset, time_base=time_base, stats=stats, decode=decoded)


def recording_epoch(decoded: Decoded) -> float | None:
    """Midnight UTC [unix s] before the earliest capture time, ``None`` without captures."""
    captures = [r.capture_s for r in decoded.sequence if r.capture_s is not None]
    return midnight_utc(min(captures)) if captures else None


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
