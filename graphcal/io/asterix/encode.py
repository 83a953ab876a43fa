"""Encode a graphcal dataset as EUROCONTROL ASTERIX data (CAT048, CAT021, CAT034).

This is the inverse of an ASTERIX import: every radar plot becomes a CAT048
(Monoradar Target Report) record, every ADS-B report a CAT021 (ADS-B Target
Report) record, and every radar one CAT034 (Monoradar Service Message) North
marker that gives the radar's position.  Records are built with the
``libasterix`` package (import name ``asterix``) in the latest editions it
ships: CAT048 ed. 1.32, CAT021 ed. 2.7 and CAT034 ed. 1.29.

Encoded quantities and their resolution (LSB); every value is rounded to the
nearest multiple of its LSB, so decoding gives it back within half an LSB:

==================  =========================  =====================================
quantity            item                       LSB
==================  =========================  =====================================
plot time           I048/140 Time of Day       1/128 s
plot range          I048/040 RHO               1/256 NM (1 NM = 1852 m), 0 .. 256 NM
plot azimuth        I048/040 THETA             360/2^16 deg
plot altitude       I048/090 Flight Level      1/4 FL (FL = altitude_m / 0.3048 / 100)
plot height (3-D)   I048/110 3-D Height        25 ft (3-D radars, from the elevation)
aircraft address    I048/220, I021/080         exact (24 bits)
callsign            I048/240                   exact (up to 8 characters A-Z 0-9 space)
plot mode_3a        I048/070 Mode-3/A Code     exact (4 octal digits; V, G, L sent as 0)
plot track_number   I048/161 Track Number      exact (0 .. 4095)
ADS-B time          I021/071 Time of Appl.     1/128 s
ADS-B lat, lon      I021/131 High-Res Pos.     180/2^30 deg
ADS-B height        I021/140 Geometric Height  6.25 ft (1 ft = 0.3048 m)
ADS-B baro_alt_m    I021/145 Flight Level      1/4 FL (when the column has a value)
ADS-B NACp          I021/090 NACP              exact (0 .. 11)
ADS-B mode_3a       I021/070 Mode 3/A Code     exact (4 octal digits)
radar lat, lon      I034/120 LAT, LON          180/2^23 deg
radar height        I034/120 HGT               1 m
North-marker time   I034/030 Time of Day       1/128 s
==================  =========================  =====================================

Times are carried as time of day: ``(time_s - day_start_s) mod 86400``, with
``day_start_s`` the value of ``time_s`` at the midnight that starts the day.
CAT048 has no elevation angle: a 3-D radar's plot carries the height its
elevation gives (I048/110, "height measured by a 3-D radar"), on the sphere of
the local Gaussian radius ``R`` (:func:`graphcal.core.frames.elevation_from_height`
is its inverse, which the import uses):
``h = sqrt((R + alt_m)^2 + r^2 + 2 r (R + alt_m) sin(el)) - R``.  Its 25 ft LSB
(7.62 m) gives the elevation back within ``3.81 m / r`` (0.04 mrad at 100 km).

Radars are identified by SAC/SIC (I048/010, I034/010).  They come from
``radar_codes`` or, when it is absent, from ids of the form ``SAC025_SIC201``
(see :func:`radar_sac_sic`).  ADS-B reports carry the SAC/SIC of the ADS-B
ground station, ``adsb_code``.

Data blocks hold records of one category and one data source, in time order,
and stay within the ASTERIX limit of 65535 bytes.  A value outside the range of
its item raises :class:`AsterixEncodeError` naming the table row, or, with
``on_range_error="skip"``, drops that record and counts it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import asterix.generated as gen
import numpy as np
import pandas as pd
from asterix.base import Record

from graphcal.core.atomic import atomic_write_stream
from graphcal.core.errors import DatasetError
from graphcal.data.dataset import Dataset

#: CAT048 edition used: Monoradar Target Reports, ed. 1.32.
CAT048 = gen.Cat_048_1_32
#: CAT021 edition used: ADS-B Target Reports, ed. 2.7.
CAT021 = gen.Cat_021_2_7
#: CAT034 edition used: Monoradar Service Messages, ed. 1.29.
CAT034 = gen.Cat_034_1_29

#: Largest ASTERIX data block [bytes] (the 16-bit LEN field, header included).
MAX_BLOCK_BYTES = 65535
#: Largest UDP payload in an IPv4 packet [bytes].
MAX_UDP_PAYLOAD = 65507
#: Seconds in a day; ASTERIX times are times of day.
SECONDS_PER_DAY = 86400.0
#: Metres per nautical mile.
METRES_PER_NM = 1852.0
#: Metres per foot.
METRES_PER_FT = 0.3048

#: LSB of every time of day (I048/140, I021/071, I034/030, I063/030) [s].
TIME_LSB_S = 1.0 / 128.0
#: LSB of I048/040 RHO [NM].
RHO_LSB_NM = 1.0 / 256.0
#: LSB of I048/040 THETA [deg].
THETA_LSB_DEG = 360.0 / 2**16
#: LSB of I048/090 flight level [FL, 100 ft].
FL_LSB = 0.25
#: LSB of I021/131 latitude and longitude [deg].
ADSB_LATLON_LSB_DEG = 180.0 / 2**30
#: LSB of I021/140 geometric height [ft].
ADSB_HEIGHT_LSB_FT = 6.25
#: LSB of I048/110 3-D height [ft].
HEIGHT_3D_LSB_FT = 25.0
#: LSB of I034/120 latitude and longitude [deg].
SITE_LATLON_LSB_DEG = 180.0 / 2**23
#: LSB of I034/120 height [m].
SITE_HEIGHT_LSB_M = 1.0

#: I048/020 TYP codes used.
TYP_PSR, TYP_SSR, TYP_MODE_S_ROLL_CALL = 1, 2, 5

_RADAR_ID = re.compile(r"^SAC(\d{1,3})_SIC(\d{1,3})$", re.IGNORECASE)
_ICAO_ADDRESS = re.compile(r"^[0-9a-fA-F]{6}$")
_CALLSIGN = re.compile(r"^[A-Z0-9 ]{1,8}$")
_MODE_3A = re.compile(r"^[0-7]{4}$")
#: Largest track number of I048/161 (12 bits).
MAX_TRACK_NUMBER = (1 << 12) - 1

RangeErrorPolicy = Literal["raise", "skip"]


class AsterixEncodeError(DatasetError):
    """A dataset value that an ASTERIX item cannot carry, or missing SAC/SIC codes."""


# --------------------------------------------------------------------------- SAC/SIC


def radar_sac_sic(radar_id: str) -> tuple[int, int] | None:
    """SAC and SIC from a radar id of the form ``SAC025_SIC201``; ``None`` otherwise.

    This is the naming an ASTERIX import gives radars (case is ignored).

    Raises
    ------
    AsterixEncodeError
        The id has that form but a code above 255.
    """
    match = _RADAR_ID.match(radar_id.strip())
    if match is None:
        return None
    sac, sic = int(match.group(1)), int(match.group(2))
    if sac > 255 or sic > 255:
        raise AsterixEncodeError(f"radar {radar_id!r}: SAC and SIC must be within 0..255")
    return sac, sic


def resolve_radar_codes(
    radar_ids: Iterable[str], radar_codes: Mapping[str, Sequence[int]] | None = None
) -> dict[str, tuple[int, int]]:
    """SAC/SIC of every radar: from ``radar_codes``, else parsed from the id.

    Parameters
    ----------
    radar_ids : iterable of str
        Radars that need a code.
    radar_codes : mapping, optional
        ``radar_id -> (SAC, SIC)``; radars missing here must be named like
        ``SAC025_SIC201``.

    Returns
    -------
    dict
        ``radar_id -> (SAC, SIC)``.

    Raises
    ------
    AsterixEncodeError
        A radar without a code (the message says how to give one), a code
        outside 0..255, or two radars with the same code.
    """
    codes: dict[str, tuple[int, int]] = {}
    given = dict(radar_codes or {})
    for rid in radar_ids:
        if rid in given:
            try:
                sac, sic = (int(v) for v in given[rid])
            except (TypeError, ValueError):
                raise AsterixEncodeError(
                    f"radar {rid!r}: code {given[rid]!r} is not a pair (SAC, SIC)") from None
            if not (0 <= sac <= 255 and 0 <= sic <= 255):
                raise AsterixEncodeError(
                    f"radar {rid!r}: SAC and SIC must be within 0..255, got ({sac}, {sic})")
            codes[rid] = (sac, sic)
            continue
        parsed = radar_sac_sic(rid)
        if parsed is None:
            raise AsterixEncodeError(
                f"radar {rid!r} has no SAC/SIC: give radar_codes={{{rid!r}: (SAC, SIC)}} "
                "or name the radar like 'SAC025_SIC201'")
        codes[rid] = parsed
    seen: dict[tuple[int, int], str] = {}
    for rid, code in codes.items():
        if code in seen:
            raise AsterixEncodeError(
                f"radars {seen[code]!r} and {rid!r} have the same SAC/SIC {code}")
        seen[code] = rid
    return codes


# --------------------------------------------------------------------------- encoded records


@dataclass(frozen=True)
class AsterixRecord:
    """One encoded record with the facts needed to order and block it.

    Attributes
    ----------
    time_s : float
        Record time on the dataset's time base [s] (not reduced to a day).
    category : int
        ASTERIX category (21, 34 or 48).
    source : tuple of int
        ``(SAC, SIC)`` of the data source (I0xx/010).
    record : asterix.base.Record
        The libasterix record.
    size : int
        Encoded length [bytes].
    """

    time_s: float
    category: int
    source: tuple[int, int]
    record: Record
    size: int


@dataclass
class EncodeSummary:
    """What an encoding produced.

    Attributes
    ----------
    n_records : dict
        Records written per category (``{48: ..., 21: ..., 34: ...}``).
    n_blocks : int
        Data blocks written.
    n_bytes : int
        Bytes of ASTERIX data (data blocks only, without pcap framing).
    skipped : list of str
        One message per row left out (``on_range_error="skip"``), naming the
        table, the row and the value.
    """

    n_records: dict[int, int] = field(default_factory=dict)
    n_blocks: int = 0
    n_bytes: int = 0
    skipped: list[str] = field(default_factory=list)


class _OutOfRange(Exception):
    """A value outside an item's range (internal, turned into a message)."""


def _count(value: float, lsb: float, bits: int, signed: bool, what: str) -> int:
    """``value`` in LSB counts, range-checked, as the item's raw unsigned bits."""
    if not math.isfinite(value):
        raise _OutOfRange(f"{what} is not finite")
    n = round(value / lsb)
    low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    if not low <= n <= high:
        raise _OutOfRange(
            f"{what} = {value:g} is outside the item's range {low * lsb:g} .. {high * lsb:g}")
    return n & ((1 << bits) - 1)


def time_of_day_count(time_s: float, day_start_s: float = 0.0) -> int:
    """Time of day in units of 1/128 s: ``round(((time_s - day_start_s) mod 86400) * 128)``.

    A time that rounds up to midnight gives 0.
    """
    tod = math.fmod(time_s - day_start_s, SECONDS_PER_DAY)
    if tod < 0.0:
        tod += SECONDS_PER_DAY
    return round(tod / TIME_LSB_S) % round(SECONDS_PER_DAY / TIME_LSB_S)


def _address(text: Any) -> int | None:
    """A 6-hex-digit ICAO address as an int; ``None`` for anything else."""
    if isinstance(text, str) and _ICAO_ADDRESS.match(text.strip()):
        return int(text.strip(), 16)
    return None


def _callsign(value: Any) -> str | None:
    """A callsign as I048/240 carries it (upper case, <= 8 chars), ``None`` when empty."""
    if value is None or (isinstance(value, float) and math.isnan(value)) or value is pd.NA:
        return None
    text = str(value).strip().upper()
    if not text:
        return None
    if not _CALLSIGN.match(text):
        raise _OutOfRange(f"callsign {value!r} is not 1..8 characters A-Z, 0-9, space")
    return text


def _is_missing(value: Any) -> bool:
    """``None``, NaN or ``pd.NA``: a cell without a value."""
    return value is None or value is pd.NA or (isinstance(value, float) and math.isnan(value))


def _mode_3a_code(value: Any) -> int | None:
    """A ``mode_3a`` cell (4 octal digits, ``"0413"``) as the 12 bits of I048/070 and
    I021/070 (A4 A2 A1 B4 B2 B1 C4 C2 C1 D4 D2 D1: ``0o413``); ``None`` when empty.

    Raises
    ------
    _OutOfRange
        For anything else than 4 octal digits (a number too: its leading zeros
        may be lost).
    """
    if _is_missing(value):
        return None
    if not isinstance(value, str):
        raise _OutOfRange(f"mode_3a {value!r} is not text of 4 octal digits")
    text = value.strip()
    if not text:
        return None
    if not _MODE_3A.match(text):
        raise _OutOfRange(f"mode_3a {value!r} is not 4 octal digits")
    return int(text, 8)


def _track_number(value: Any) -> int | None:
    """A ``track_number`` cell as I048/161's 12-bit number; ``None`` when empty."""
    if _is_missing(value):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise _OutOfRange(f"track_number {value!r} is not a number") from None
    if not math.isfinite(number) or number != round(number) or not 0 <= number <= MAX_TRACK_NUMBER:
        raise _OutOfRange(f"track_number {value!r} is not an integer in 0..{MAX_TRACK_NUMBER}")
    return int(number)


def _size(record: Record) -> int:
    return len(record.unparse().to_bytes())


def _row_problem(table: str, pos: int, detail: str, path: Path | None) -> str:
    where = f"{table} row {pos + 1}"
    if path is not None:
        where = f"{path}: {where}"
    return f"{where}: {detail}"


class _Rows:
    """Per-row error handling: raise, or skip and record."""

    def __init__(self, policy: RangeErrorPolicy, path: Path | None) -> None:
        if policy not in ("raise", "skip"):
            raise ValueError(f"on_range_error must be 'raise' or 'skip', not {policy!r}")
        self.policy = policy
        self.path = path
        self.skipped: list[str] = []

    def problem(self, table: str, pos: int, detail: str) -> None:
        if self.policy == "raise":
            error = AsterixEncodeError(
                f"{table} row {pos + 1}: cannot encode as ASTERIX: {detail}", path=self.path)
            error.row = pos + 1
            raise error
        self.skipped.append(_row_problem(table, pos, detail, self.path))


def height_from_elevation(range_m: np.ndarray, elevation_rad: np.ndarray, lat_rad: float,
                          alt_m: float) -> np.ndarray:
    """Height [m] of a target at slant range and elevation, on the local earth sphere.

    The inverse of :func:`graphcal.core.frames.elevation_from_height`:
    ``h = sqrt((R + alt_m)^2 + r^2 + 2 r (R + alt_m) sin(el)) - R``, ``R`` the
    Gaussian radius of curvature at the radar's latitude.
    """
    from graphcal.core.frames import gaussian_radius_m

    radius = float(gaussian_radius_m(lat_rad))
    rr = radius + alt_m
    r = np.asarray(range_m, dtype=float)
    return np.sqrt(rr**2 + r**2 + 2.0 * r * rr * np.sin(elevation_rad)) - radius


def _plot_heights(plots: pd.DataFrame, sites: Mapping[str, Any]) -> np.ndarray:
    """I048/110 height [ft] of every plot of a 3-D radar with an elevation; NaN elsewhere."""
    heights = np.full(len(plots), np.nan)
    if "elevation_deg" not in plots or not len(plots):
        return heights
    radar = plots["radar_id"].astype(str).to_numpy()
    elevation = np.radians(plots["elevation_deg"].to_numpy(dtype=float))
    range_m = plots["range_m"].to_numpy(dtype=float)
    for rid, site in sites.items():
        if not site.is_3d:
            continue
        rows = (radar == rid) & np.isfinite(elevation)
        heights[rows] = height_from_elevation(range_m[rows], elevation[rows], site.lat_rad,
                                              site.alt_m) / METRES_PER_FT
    return heights


def _plot_records(
    plots: pd.DataFrame, codes: Mapping[str, tuple[int, int]], three_d: set[str],
    day_start_s: float, rows: _Rows, heights: np.ndarray | None = None,
) -> Iterator[AsterixRecord]:
    """CAT048 records, one per plot (see the module docstring for items and LSBs)."""
    heights = np.full(len(plots), np.nan) if heights is None else heights
    radar = plots["radar_id"].astype(str).to_numpy()
    time_s = plots["time_s"].to_numpy(dtype=float)
    range_m = plots["range_m"].to_numpy(dtype=float)
    azimuth = plots["azimuth_deg"].to_numpy(dtype=float)
    target = plots["target_id"].to_numpy(dtype=object) if "target_id" in plots else None
    altitude = (plots["altitude_m"].to_numpy(dtype=float) if "altitude_m" in plots
                else np.full(len(plots), np.nan))
    callsigns = plots["callsign"].to_numpy(dtype=object) if "callsign" in plots else None
    codes_3a = plots["mode_3a"].to_numpy(dtype=object) if "mode_3a" in plots else None
    tracks = plots["track_number"].to_numpy(dtype=object) if "track_number" in plots else None
    for pos in range(len(plots)):
        rid = radar[pos]
        try:
            sac, sic = codes[rid]
            tod = time_of_day_count(time_s[pos], day_start_s)
            rho = _count(range_m[pos] / METRES_PER_NM, RHO_LSB_NM, 16, False,
                         f"range in NM (range_m / 1852, radar {rid!r})")
            theta = _count(azimuth[pos] % 360.0, THETA_LSB_DEG, 17, False, "azimuth_deg")
            theta %= 1 << 16  # 360 deg is 0 deg
            items: dict[str, Any] = {
                "010": (("SAC", sac), ("SIC", sic)),
                "140": tod,
                "040": (("RHO", rho), ("THETA", theta)),
            }
            address = None if target is None else _address(target[pos])
            has_alt = bool(np.isfinite(altitude[pos]))
            code_3a = None if codes_3a is None else _mode_3a_code(codes_3a[pos])
            if address is not None:
                typ = TYP_MODE_S_ROLL_CALL
            elif has_alt or code_3a is not None or rid not in three_d:
                typ = TYP_SSR
            else:
                typ = TYP_PSR
            items["020"] = ((("TYP", typ), 0, 0, 0, 0, None),)
            if code_3a is not None:
                # V 0: code validated; G 0: not garbled; L 0: from this scan's reply.
                items["070"] = (("V", 0), ("G", 0), ("L", 0), 0, ("MODE3A", code_3a))
            if has_alt:
                fl = altitude[pos] / METRES_PER_FT / 100.0
                items["090"] = (("V", 0), ("G", 0),
                                ("FL", _count(fl, FL_LSB, 14, True, "altitude_m as flight level")))
            if address is not None:
                items["220"] = address
            if np.isfinite(heights[pos]):
                items["110"] = (0, ("3DH", _count(heights[pos], HEIGHT_3D_LSB_FT, 14, True,
                                                  "3-D height from elevation_deg")))
            if callsigns is not None:
                callsign = _callsign(callsigns[pos])
                if callsign is not None:
                    items["240"] = callsign
            track = None if tracks is None else _track_number(tracks[pos])
            if track is not None:
                items["161"] = (0, ("TRN", track))
        except _OutOfRange as exc:
            rows.problem("plots", pos, str(exc))
            continue
        record = CAT048.cv_record.create(items)
        yield AsterixRecord(float(time_s[pos]), 48, (sac, sic), record, _size(record))


def _adsb_records(
    adsb: pd.DataFrame, code: tuple[int, int], day_start_s: float, rows: _Rows
) -> Iterator[AsterixRecord]:
    """CAT021 records, one per ADS-B report (see the module docstring)."""
    time_s = adsb["time_s"].to_numpy(dtype=float)
    target = adsb["target_id"].to_numpy(dtype=object)
    lat = adsb["lat_deg"].to_numpy(dtype=float)
    lon = adsb["lon_deg"].to_numpy(dtype=float)
    alt = adsb["alt_m"].to_numpy(dtype=float)
    baro = (adsb["baro_alt_m"].to_numpy(dtype=float) if "baro_alt_m" in adsb
            else np.full(len(adsb), np.nan))
    nacp = None
    if "nacp" in adsb:
        nacp = pd.to_numeric(adsb["nacp"], errors="coerce").to_numpy(dtype=float, na_value=np.nan)
    codes_3a = adsb["mode_3a"].to_numpy(dtype=object) if "mode_3a" in adsb else None
    track_numbers: dict[int, int] = {}
    for pos in range(len(adsb)):
        try:
            address = _address(target[pos])
            if address is None:
                raise _OutOfRange(f"target_id {target[pos]!r} is not a 24-bit ICAO address "
                                  "(6 hex digits)")
            track = track_numbers.setdefault(address, len(track_numbers) % 4096)
            items: dict[str, Any] = {
                "010": (("SAC", code[0]), ("SIC", code[1])),
                # ATP 0: 24-bit ICAO address; ARC 2: altitude reporting capability unknown.
                "040": ((("ATP", 0), ("ARC", 2), ("RC", 0), ("RAB", 0), None),),
                "161": (0, ("TRNUM", track)),
                "071": time_of_day_count(time_s[pos], day_start_s),
                "131": (("LAT", _count(lat[pos], ADSB_LATLON_LSB_DEG, 32, True, "lat_deg")),
                        ("LON", _count(lon[pos], ADSB_LATLON_LSB_DEG, 32, True, "lon_deg"))),
                "080": address,
                "140": _count(alt[pos] / METRES_PER_FT, ADSB_HEIGHT_LSB_FT, 16, True, "alt_m"),
            }
            if np.isfinite(baro[pos]):
                items["145"] = _count(baro[pos] / METRES_PER_FT / 100.0, FL_LSB, 16, True,
                                      "baro_alt_m")
            if nacp is not None and np.isfinite(nacp[pos]):
                value = _count(nacp[pos], 1.0, 4, False, "nacp")
                items["090"] = ((("NUCRNACV", 0), ("NUCPNIC", 0), None),
                                (("NICBARO", 0), ("SIL", 0), ("NACP", value), None))
            code_3a = None if codes_3a is None else _mode_3a_code(codes_3a[pos])
            if code_3a is not None:
                items["070"] = (0, ("MODE3A", code_3a))
        except _OutOfRange as exc:
            rows.problem("adsb", pos, str(exc))
            continue
        record = CAT021.cv_record.create(items)
        yield AsterixRecord(float(time_s[pos]), 21, code, record, _size(record))


def _site_records(
    dataset: Dataset, codes: Mapping[str, tuple[int, int]], day_start_s: float
) -> Iterator[AsterixRecord]:
    """One CAT034 North marker per radar, at its first plot, with I034/120."""
    first = dataset.plots.groupby("radar_id")["time_s"].min() if len(dataset.plots) else {}
    for rid, site in dataset.sites.items():
        sac, sic = codes[rid]
        time_s = float(first[rid]) if rid in first else float(day_start_s)
        try:
            position = (
                ("HGT", _count(site.alt_m, SITE_HEIGHT_LSB_M, 16, True, "alt_m")),
                ("LAT", _count(math.degrees(site.lat_rad), SITE_LATLON_LSB_DEG, 24, True,
                               "lat_deg")),
                ("LON", _count(math.degrees(site.lon_rad), SITE_LATLON_LSB_DEG, 24, True,
                               "lon_deg")),
            )
        except _OutOfRange as exc:
            raise AsterixEncodeError(f"radar {rid!r}: {exc}", path=dataset.path) from None
        record = CAT034.cv_record.create({
            "010": (("SAC", sac), ("SIC", sic)),
            "000": 1,  # North marker message
            "030": time_of_day_count(time_s, day_start_s),
            "120": position,
        })
        yield AsterixRecord(time_s, 34, (sac, sic), record, _size(record))


def encode_records(
    dataset: Dataset,
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    *,
    day_start_s: float = 0.0,
    adsb_code: tuple[int, int] = (0, 0),
    on_range_error: RangeErrorPolicy = "raise",
) -> tuple[list[AsterixRecord], list[str]]:
    """All records of a dataset, in time order (stable), and the rows left out.

    Parameters
    ----------
    dataset : Dataset
        Sites, plots and (optionally) ADS-B reports.
    radar_codes : mapping, optional
        ``radar_id -> (SAC, SIC)``; see :func:`resolve_radar_codes`.
    day_start_s : float, optional
        Value of ``time_s`` at the midnight (UTC) that starts the day [s].
    adsb_code : tuple of int, optional
        SAC/SIC of the ADS-B ground station, for I021/010.
    on_range_error : {"raise", "skip"}, optional
        What to do with a row whose value an item cannot carry.

    Returns
    -------
    records : list of AsterixRecord
        CAT034 North markers, CAT048 plots and CAT021 reports, sorted by time;
        at equal times North markers first.
    skipped : list of str
        One message per skipped row.

    Raises
    ------
    AsterixEncodeError
        Missing SAC/SIC, or (``on_range_error="raise"``) the first row with a
        value outside its item's range, naming the table and the row.
    """
    codes = resolve_radar_codes(dataset.radar_ids, radar_codes)
    sac, sic = (int(v) for v in adsb_code)
    if not (0 <= sac <= 255 and 0 <= sic <= 255):
        raise AsterixEncodeError(f"adsb_code must be (SAC, SIC) within 0..255, got {adsb_code}")
    rows = _Rows(on_range_error, dataset.path)
    three_d = {rid for rid, site in dataset.sites.items() if site.is_3d}
    records = list(_site_records(dataset, codes, day_start_s))
    records += _plot_records(dataset.plots, codes, three_d, day_start_s, rows,
                             _plot_heights(dataset.plots, dataset.sites))
    if dataset.adsb is not None and len(dataset.adsb):
        records += _adsb_records(dataset.adsb, (sac, sic), day_start_s, rows)
    order = {34: 0, 48: 1, 21: 2}
    records.sort(key=lambda r: (r.time_s, order[r.category]))
    return records, rows.skipped


_SPECS = {48: CAT048, 21: CAT021, 34: CAT034}


def blocks_of(
    records: Sequence[AsterixRecord], *, max_block_bytes: int = MAX_BLOCK_BYTES,
    max_records: int | None = None,
) -> Iterator[tuple[float, bytes, int]]:
    """Group consecutive records of one category and source into data blocks.

    Parameters
    ----------
    records : sequence of AsterixRecord
        Records in the order to send them.
    max_block_bytes : int, optional
        Largest block, 3-byte header (CAT, LEN) included; at most 65535.
    max_records : int, optional
        Largest number of records in a block.

    Yields
    ------
    time_s : float
        Time of the block's first record [s].
    block : bytes
        The encoded data block.
    n : int
        Records in the block.

    Raises
    ------
    ValueError
        ``max_block_bytes`` outside 4..65535, or a record that does not fit.
    """
    if not 4 <= max_block_bytes <= MAX_BLOCK_BYTES:
        raise ValueError(f"max_block_bytes must be within 4..{MAX_BLOCK_BYTES}")
    current: list[AsterixRecord] = []
    size = 3

    def flush() -> tuple[float, bytes, int]:
        spec = _SPECS[current[0].category]
        block = spec.create([r.record for r in current]).unparse().to_bytes()
        return current[0].time_s, block, len(current)

    for record in records:
        if 3 + record.size > max_block_bytes:
            raise ValueError(f"a CAT{record.category:03d} record of {record.size} bytes does not "
                             f"fit a block of {max_block_bytes} bytes")
        if current and (
            (record.category, record.source) != (current[0].category, current[0].source)
            or size + record.size > max_block_bytes
            or (max_records is not None and len(current) >= max_records)
        ):
            yield flush()
            current, size = [], 3
        current.append(record)
        size += record.size
    if current:
        yield flush()


def _summary(records: Sequence[AsterixRecord], skipped: list[str]) -> EncodeSummary:
    summary = EncodeSummary(skipped=skipped)
    for category in (48, 21, 34):
        summary.n_records[category] = sum(1 for r in records if r.category == category)
    return summary


def encode_dataset(
    dataset: Dataset,
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    *,
    day_start_s: float = 0.0,
    adsb_code: tuple[int, int] = (0, 0),
    on_range_error: RangeErrorPolicy = "raise",
    max_block_bytes: int = MAX_BLOCK_BYTES,
    summary: EncodeSummary | None = None,
) -> bytes:
    """Encode a dataset as concatenated ASTERIX data blocks.

    Plots become CAT048 records (I010, I140, I020, I040, I070 when ``mode_3a``
    has a value, I090 when the altitude is known, I110 for a 3-D radar's plot,
    I220 when ``target_id`` is an ICAO address, I240 when a ``callsign`` column
    has a value, I161 when ``track_number`` has a value), ADS-B reports CAT021
    records (I010, I040, I161, I071, I131, I080, I140, I145 when ``baro_alt_m``
    has a value, I090 with NACp when known, I070 when ``mode_3a`` has a value)
    and each radar one CAT034 North marker (I010, I000, I030, I120).
    Resolutions are listed in the module docstring.

    Parameters
    ----------
    dataset : Dataset
        The dataset.
    radar_codes : mapping, optional
        ``radar_id -> (SAC, SIC)``; radars missing here must be named like
        ``SAC025_SIC201``.
    day_start_s : float, optional
        Value of ``time_s`` at the midnight that starts the day [s]; times are
        sent as ``(time_s - day_start_s) mod 86400``.
    adsb_code : tuple of int, optional
        SAC/SIC of the ADS-B ground station (I021/010).
    on_range_error : {"raise", "skip"}, optional
        Raise on the first row an item cannot carry, or leave such rows out
        (listed in ``summary.skipped``).
    max_block_bytes : int, optional
        Largest data block [bytes], at most 65535.
    summary : EncodeSummary, optional
        Filled with counts and skipped rows when given.

    Returns
    -------
    bytes
        The data blocks, in time order.

    Raises
    ------
    AsterixEncodeError
        Missing SAC/SIC codes or an out-of-range value (with ``"raise"``).
    """
    records, skipped = encode_records(dataset, radar_codes, day_start_s=day_start_s,
                                      adsb_code=adsb_code, on_range_error=on_range_error)
    blocks = [block for _, block, _ in blocks_of(records, max_block_bytes=max_block_bytes)]
    if summary is not None:
        filled = _summary(records, skipped)
        filled.n_blocks = len(blocks)
        filled.n_bytes = sum(len(b) for b in blocks)
        summary.__dict__.update(filled.__dict__)
    return b"".join(blocks)


def write_asterix(
    dataset: Dataset,
    path: str | Path,
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    **options: Any,
) -> EncodeSummary:
    """Write :func:`encode_dataset`'s bytes to ``path`` atomically (a raw ``.ast`` file).

    Parameters
    ----------
    dataset, radar_codes
        As for :func:`encode_dataset`.
    path : str or Path
        Destination file; its folder must exist.
    **options
        Keyword options of :func:`encode_dataset` (``day_start_s``,
        ``adsb_code``, ``on_range_error``, ``max_block_bytes``).

    Returns
    -------
    EncodeSummary
    """
    summary = EncodeSummary()
    data = encode_dataset(dataset, radar_codes, summary=summary, **options)
    atomic_write_stream(path, lambda stream: stream.write(data))
    return summary


def _ipv4(address: str) -> bytes:
    parts = address.split(".")
    if len(parts) != 4 or not all(p.isdigit() and int(p) <= 255 for p in parts):
        raise ValueError(f"{address!r} is not an IPv4 address")
    return bytes(int(p) for p in parts)


def _multicast_mac(address: bytes) -> bytes:
    """Ethernet address of an IPv4 multicast group (RFC 1112), else broadcast."""
    if 224 <= address[0] <= 239:
        return bytes((0x01, 0x00, 0x5E, address[1] & 0x7F, address[2], address[3]))
    return b"\xff" * 6


def write_pcap(
    dataset: Dataset,
    path: str | Path,
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    *,
    epoch_s: float = 0.0,
    records_per_packet: int | None = 1,
    src_ip: str = "10.0.0.1",
    dst_ip: str = "239.0.0.1",
    dst_port: int = 8600,
    **options: Any,
) -> EncodeSummary:
    """Write the dataset as a pcap capture of UDP/IPv4/Ethernet packets, atomically.

    Each packet carries one data block; its capture time is
    ``epoch_s + time_s`` of the block's first record (with the default one
    record per packet: the record's own time).  Packets are in time order.

    Parameters
    ----------
    dataset, radar_codes
        As for :func:`encode_dataset`.
    path : str or Path
        Destination ``.pcap`` file; its folder must exist.
    epoch_s : float, optional
        Unix time [s] of ``time_s = 0`` (the pcap timestamps are Unix times).
    records_per_packet : int or None, optional
        Records per data block and packet; ``None``: as many as fit in one
        UDP payload (65507 bytes).
    src_ip, dst_ip : str, optional
        IPv4 source and destination (a multicast group gets its multicast
        Ethernet address).
    dst_port : int, optional
        UDP destination port (the source port is the same).
    **options
        ``day_start_s``, ``adsb_code``, ``on_range_error`` as for
        :func:`encode_dataset`.

    Returns
    -------
    EncodeSummary
    """
    import dpkt

    options.pop("max_block_bytes", None)
    records, skipped = encode_records(dataset, radar_codes, **options)
    blocks = list(blocks_of(records, max_block_bytes=MAX_UDP_PAYLOAD,
                            max_records=records_per_packet))
    src, dst = _ipv4(src_ip), _ipv4(dst_ip)
    src_mac = b"\x02\x00" + src
    dst_mac = _multicast_mac(dst)

    def write(stream: Any) -> None:
        writer = dpkt.pcap.Writer(stream, snaplen=65535, linktype=dpkt.pcap.DLT_EN10MB)
        for time_s, block, _ in blocks:
            udp = dpkt.udp.UDP(sport=dst_port, dport=dst_port, data=block)
            udp.ulen = len(udp)
            ip = dpkt.ip.IP(src=src, dst=dst, p=dpkt.ip.IP_PROTO_UDP, ttl=16, data=udp)
            ip.len = len(ip)
            eth = dpkt.ethernet.Ethernet(src=src_mac, dst=dst_mac,
                                         type=dpkt.ethernet.ETH_TYPE_IP, data=ip)
            writer.writepkt(bytes(eth), ts=epoch_s + time_s)

    atomic_write_stream(path, write)
    summary = _summary(records, skipped)
    summary.n_blocks = len(blocks)
    summary.n_bytes = sum(len(b) for _, b, _ in blocks)
    return summary
