"""Read ASTERIX recordings: split byte streams into data blocks and decode records.

Inputs are either *raw* files (ASTERIX data blocks written back to back, as
recorded by most ATC tools) or packet captures (pcap or pcapng) of the UDP
datagrams that carry them.  Each data block is ``CAT`` (1 byte), ``LEN``
(2 bytes, big-endian, the length of the whole block in bytes) and the records.
A UDP payload may hold several data blocks.

Categories decoded (item definitions from ``libasterix``, import name ``asterix``):

- CAT048 (monoradar target reports), edition 1.32,
- CAT021 (ADS-B target reports), editions 2.x (read with edition 2.6, whose
  user application profile (UAP) has the items of 2.1 to 2.5 at the same
  places), 0.26 (also read for 0.24 and 0.25, whose UAPs it extends) and 0.23
  (the one with a 6-byte I021/130), all still sent by ground stations; the
  edition is chosen per data block from its content ("Choosing the CAT021
  edition" below) unless forced (:func:`decoder_specs`; 2.7, whose I090 has
  more parts, only so),
- CAT034 (monoradar service messages), edition 1.29.

Every other category is counted and skipped.  Only the items graphcal needs are
kept (:class:`Cat048Report`, :class:`Cat021Report`, :class:`Cat034Message`), in
the units of the ASTERIX specification; :mod:`graphcal.io.asterix.tables` turns
them into contract tables.

How it decodes: each record's FSPEC is walked with the byte size of every item
of the edition's UAP, compiled once from ``libasterix``'s specifications
(:mod:`graphcal.io.asterix.layout`); the walk only notes where the items graphcal
reads start.  The fields are then extracted with numpy over all records at once
(``signed(raw bits) * LSB``, as ``libasterix`` computes them) into columns
(:class:`Decoded`).  The values are those of the item-by-item ``libasterix``
decoder (:mod:`graphcal.io.asterix.reference`, which the tests compare with),
at about 30-50 times its speed.

Choosing the CAT021 edition: the editions share no marker, and a block of one
edition may well parse, with other record boundaries, under another (a 0.26
record read as 2.6 splits into two records, the second without I010).  So each
block is walked with 2.6, then 0.26, then 0.23, and given a grade under each
edition that parses the whole block: *plausible* when every record has the data
source identifier I010, the target address I080 and a time of day (2.x: I071,
I073 or I077; 0.2x: I030), its times are below 86401 s, every position it
carries is within +-90 deg latitude and +-180 deg longitude (2.x: I130 and
I131; 0.2x: I130, whose size and LSB differ between 0.23 and 0.26), and its
geometric height (I140) and flight level (I145), when there, are within the
ranges of the specifications (-1500 to 150000 ft, -15 to 1500 FL); *with
source* when every record has I010 but some lack the rest; else *without
source*.  The first edition with the best grade is used (a block's values are
only read when they can change the choice, :func:`_choose`); a block whose best
grade is "without source" is rejected as :data:`REJECT_NO_SOURCE`.
:attr:`DecodeStats.editions` counts the blocks decoded with each edition.  A
forced edition (``cat021_edition``) is the only one tried.

Robustness: a block is rejected as a whole when its header is inconsistent with
the bytes that follow, when its records do not parse, or when the decoder
raises anything.  The rest of the input is kept; :class:`DecodeStats` counts
what was rejected and why.  A block's ``LEN`` is accepted only when the block
headers after it confirm it, and after a block whose ``LEN`` cannot be right the
splitter looks for the next offset where a plausible chain of block headers
starts (see :func:`split_blocks`), so one corrupted byte loses a block or a few,
not the rest of a raw file; ``DecodeStats.bytes_unsplit`` counts the bytes left
out of the blocks.  Nothing raises on arbitrary input bytes except :class:`AsterixError`
for a file that cannot be read at all.
"""

from __future__ import annotations

import functools
import io
import math
import re
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from collections.abc import Set as AbstractSet
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import Any

import dpkt
import numpy as np
from asterix import generated as gen

from graphcal.core.errors import GraphcalInputError
from graphcal.io.asterix.layout import (
    EXPLICIT,
    ExtendedLayout,
    FieldLayout,
    RepetitiveLayout,
    locate,
    record_layout,
)


class AsterixError(GraphcalInputError):
    """An ASTERIX recording that cannot be read (missing, empty, no usable data)."""


#: CAT021 editions that can be forced (``cat021_edition``), by name; ``"2.x"`` is 2.6,
#: which reads 2.1 to 2.5 too.
CAT021_EDITIONS: dict[str, Any] = {
    "0.23": gen.Cat_021_0_23, "0.24": gen.Cat_021_0_24, "0.25": gen.Cat_021_0_25,
    "0.26": gen.Cat_021_0_26, "2.x": gen.Cat_021_2_6, "2.1": gen.Cat_021_2_1,
    "2.2": gen.Cat_021_2_2,
    "2.3": gen.Cat_021_2_3, "2.4": gen.Cat_021_2_4, "2.5": gen.Cat_021_2_5,
    "2.6": gen.Cat_021_2_6, "2.7": gen.Cat_021_2_7,
}
#: The ``cat021_edition`` that chooses per block from the content.
CAT021_AUTO = "auto"
#: Values of ``cat021_edition`` (``graphcal import-asterix --cat021-edition``).
CAT021_EDITION_CHOICES: tuple[str, ...] = (CAT021_AUTO, *CAT021_EDITIONS)

#: Decoder specifications by category, in the order they are tried (module docstring,
#: "Choosing the CAT021 edition").
SPECS: dict[int, tuple[Any, ...]] = {
    48: (gen.Cat_048_1_32,),
    21: (gen.Cat_021_2_6, gen.Cat_021_0_26, gen.Cat_021_0_23),
    34: (gen.Cat_034_1_29,),
}
#: Categories that are decoded; others are counted in ``DecodeStats.skipped_categories``.
DECODED_CATEGORIES: tuple[int, ...] = tuple(SPECS)

#: Largest plausible time of day [s] (86400 s and a leap second).
MAX_TIME_OF_DAY_S = 86401.0
#: Range of I021/140 geometric height [ft] and of I021/145 flight level [FL] in the
#: CAT021 specifications (editions 0.23 to 2.7).
GEO_HEIGHT_RANGE_FT = (-1500.0, 150000.0)
FLIGHT_LEVEL_RANGE_FL = (-15.0, 1500.0)
#: Grades of a block walked with an edition (the higher the better).
GRADE_NO_SOURCE, GRADE_SOURCE, GRADE_PLAUSIBLE = 0, 1, 2


def decoder_specs(cat021_edition: str = CAT021_AUTO) -> dict[int, tuple[Any, ...]]:
    """The specifications tried, by category: :data:`SPECS`, or with CAT021 forced.

    Parameters
    ----------
    cat021_edition : str, optional
        ``"auto"`` (choose per block, the default) or a key of
        :data:`CAT021_EDITIONS` (``"0.23"``, ``"0.26"``, ``"2.x"``, ``"2.6"``, ...).

    Raises
    ------
    ValueError
        For an unknown edition.
    """
    if cat021_edition == CAT021_AUTO:
        return SPECS
    if cat021_edition not in CAT021_EDITIONS:
        raise ValueError(f"unknown CAT021 edition '{cat021_edition}'; use one of: "
                         + ", ".join(CAT021_EDITION_CHOICES))
    return {**SPECS, 21: (CAT021_EDITIONS[cat021_edition],)}


def edition_name(spec: Any) -> str:
    """``"0.26"``, ``"2.6"``, ... of a ``libasterix`` category edition."""
    major, minor = spec.cv_edition
    return f"{major}.{minor}"


#: Size of a data block header (CAT + LEN) [bytes].
HEADER_BYTES = 3
#: Categories ASTERIX defines (EUROCONTROL's list: those ``libasterix`` describes, and
#: 003, 022, 024, 030, 031, 252).  A block whose ``LEN`` the next headers do not confirm
#: is kept only when its category is one of these or was seen in the stream, and a
#: resynchronisation lands only on these or the categories seen (:func:`split_blocks`).
ASTERIX_CATEGORIES: frozenset[int] = frozenset({
    1, 2, 3, 4, 7, 8, 9, 10, 11, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 30, 31, 32,
    34, 48, 62, 63, 65, 150, 205, 240, 247, 252,
})
#: Headers after a block that confirm its ``LEN``, or after a header inside a block
#: that show the block's ``LEN`` corrupted (:func:`split_blocks`).
CHAIN_DEPTH = 3
#: Headers after a header where the splitter resynchronises (the first block after a
#: resynchronisation is then checked as one whose ``LEN`` is not confirmed).
RESYNC_DEPTH = 2
#: Smallest limit on the ``LEN`` of a header that confirms a block or starts a
#: resynchronisation [bytes]; the limit is twice the largest block accepted, when more.
MIN_LENGTH_LIMIT = 1024

# Rejection reasons (keys of DecodeStats.rejected).
#: Fewer than 3 bytes left where a block header should start.
REJECT_SHORT_HEADER = "short header"
#: ``LEN`` smaller than the 3-byte header.
REJECT_BAD_LENGTH = "LEN < 3"
#: ``LEN`` runs past the end of the payload or file (truncated block).
REJECT_TRUNCATED = "truncated (LEN past end)"
#: Bytes skipped while looking for the next plausible block header.
REJECT_RESYNC = "bytes skipped to resync"
#: A block whose ``LEN`` fits but is not confirmed by the headers after it, while a
#: plausible chain of headers starts inside it (its ``LEN`` is corrupted), or whose
#: category has not been seen in the stream (:func:`split_blocks`).
REJECT_UNCONFIRMED = "LEN not followed by a block header"
#: The records of a block do not parse (bad FSPEC, item past the end, trailing bytes).
REJECT_RECORDS = "records do not parse"
#: The decoder raised an exception on the block.
REJECT_DECODER = "decoder exception"
#: A decoded record lacks the mandatory data source identifier (I010).
REJECT_NO_SOURCE = "record without I010"
#: A packet that could not be read from the capture (bad frame, truncated file).
REJECT_PACKET = "unreadable packet"
#: IPv4 fragments (reassembly is not done).
REJECT_FRAGMENT = "IP fragment"

#: pcap magic numbers (both byte orders, micro- and nanosecond variants).
_PCAP_MAGICS = (b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d")
#: pcapng section header block type; the byte-order magic follows at offset 8.
_PCAPNG_MAGIC = b"\x0a\x0d\x0d\x0a"
_PCAPNG_BOM = (b"\x1a\x2b\x3c\x4d", b"\x4d\x3c\x2b\x1a")

#: Link types of captures that are understood.
_DLT_NULL, _DLT_EN10MB, _DLT_RAW, _DLT_LINUX_SLL, _DLT_IPV4, _DLT_LINUX_SLL2 = (
    0, 1, 101, 113, 228, 276)
_DLT_RAW_ALIASES = (12, 14)


# --------------------------------------------------------------------------- results


@dataclass(frozen=True, slots=True)
class Cat048Report:
    """The items of one CAT048 target report that graphcal uses.

    Attributes
    ----------
    sac, sic : int
        Data source identifier (I048/010).
    time_of_day_s : float or None
        Time of day (I048/140) [s since midnight UTC], resolution 1/128 s.
    rho_nm, theta_deg : float or None
        Measured slant range [NM] and azimuth [deg] (I048/040); ``None`` when absent.
    address : int or None
        Mode S 24-bit aircraft address (I048/220).
    flight_level : float or None
        Mode C flight level (I048/090) [FL, 100 ft, barometric]; ``None`` when
        absent, not validated (V=1) or garbled (G=1).
    callsign : str or None
        Aircraft identification (I048/240), blanks removed.
    capture_s : float or None
        Capture time of the packet that carried it [unix s]; ``None`` for raw files.
    height_ft : float or None
        Height measured by a 3-D radar (I048/110) [ft], resolution 25 ft; ``None``
        when absent (a 2-D radar sends none).
    mode_3a : int or None
        Mode-3/A code (I048/070), its 12 bits A4 A2 A1 B4 ... D1 as an integer
        (``0o7000`` for code 7000); ``None`` when absent, not validated (V=1) or
        garbled (G=1).  A code not extracted during the last scan (L=1, the
        code kept from earlier scans) is kept.
    track_number : int or None
        The radar's track number (I048/161, 12 bits), when present.
    """

    sac: int
    sic: int
    time_of_day_s: float | None
    rho_nm: float | None
    theta_deg: float | None
    address: int | None
    flight_level: float | None
    callsign: str | None
    capture_s: float | None
    height_ft: float | None = None
    mode_3a: int | None = None
    track_number: int | None = None


@dataclass(frozen=True, slots=True)
class Cat021Report:
    """The items of one CAT021 ADS-B report that graphcal uses.

    Attributes
    ----------
    sac, sic : int
        Data source identifier (I021/010) of the ground station.
    time_position_s : float or None
        Time of applicability for position (I021/071) [s of day]; edition 0.x:
        time of day (I021/030).
    time_reception_s : float or None
        Time of message reception for position (I021/073) [s of day].
    time_report_s : float or None
        Time of ASTERIX report transmission (I021/077) [s of day].
    address : int or None
        Target address (I021/080).
    lat_deg, lon_deg : float or None
        WGS-84 position [deg]: I021/131 (high resolution) when present, else I021/130.
    geo_height_ft : float or None
        Geometric height above the WGS-84 ellipsoid (I021/140) [ft].
    nacp : int or None
        Navigation Accuracy Category for position (I021/090 second extension, v2).
    nucp : int or None
        NUCp or NIC (I021/090 first part, v2), used when NACp is absent.
    mops_version : int or None
        ADS-B version number VN (I021/210): 0 DO-260 (the NUCp field is a
        NUCp), 1 DO-260A, 2 DO-260B (it is a NIC).
    capture_s : float or None
        Capture time of the packet [unix s].
    flight_level : float or None
        Barometric (pressure) altitude (I021/145) [FL, 100 ft], resolution 1/4 FL.
    mode_3a : int or None
        Mode 3/A code (I021/070), its 12 bits as an integer (``0o413`` for code
        0413); ``None`` when absent (editions 0.23 to 0.25 have no I070) or, in
        edition 0.26, whose I070 has validity bits, not validated (V=1) or garbled
        (G=1).
    """

    sac: int
    sic: int
    time_position_s: float | None
    time_reception_s: float | None
    time_report_s: float | None
    address: int | None
    lat_deg: float | None
    lon_deg: float | None
    geo_height_ft: float | None
    nacp: int | None
    nucp: int | None
    mops_version: int | None
    capture_s: float | None
    flight_level: float | None = None
    mode_3a: int | None = None


@dataclass(frozen=True, slots=True)
class Cat034Message:
    """One CAT034 service message.

    Attributes
    ----------
    sac, sic : int
        Data source identifier (I034/010).
    message_type : int or None
        I034/000 (1 north marker, 2 sector crossing, ...).
    time_of_day_s : float or None
        I034/030 [s of day].
    lat_deg, lon_deg, height_m : float or None
        3-D position of the data source (I034/120): WGS-84 latitude and
        longitude [deg] and height [m].
    capture_s : float or None
        Capture time of the packet [unix s].
    """

    sac: int
    sic: int
    message_type: int | None
    time_of_day_s: float | None
    lat_deg: float | None
    lon_deg: float | None
    height_m: float | None
    capture_s: float | None


Report = Cat048Report | Cat021Report | Cat034Message


@dataclass
class DecodeStats:
    """Counts of what a decode read, decoded and rejected.

    Attributes
    ----------
    files, packets : int
        Files read; packets (UDP datagrams) read from captures.
    bytes_read : int
        Bytes of ASTERIX payload seen.
    bytes_unsplit : int
        Of them, bytes in no data block: skipped to resynchronise, in rejected
        headers or unconfirmed blocks, or a short tail (:func:`split_blocks`).
    blocks : int
        Data blocks with a consistent header.
    blocks_decoded : int
        Blocks of a decoded category whose records all parsed.
    rejected : Counter
        Rejected blocks (or bytes, for :data:`REJECT_RESYNC`; or packets) by reason.
    records : Counter
        Records decoded, by category.
    skipped_categories : Counter
        Blocks of categories that are not decoded, by category.
    editions : Counter
        Blocks decoded, by ``(category, edition)`` (``(21, "0.26")``).
    """

    files: int = 0
    packets: int = 0
    bytes_read: int = 0
    bytes_unsplit: int = 0
    blocks: int = 0
    blocks_decoded: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    records: Counter[int] = field(default_factory=Counter)
    skipped_categories: Counter[int] = field(default_factory=Counter)
    editions: Counter[tuple[int, str]] = field(default_factory=Counter)

    @property
    def n_rejected(self) -> int:
        """Rejections of every reason, resync bytes excluded."""
        return sum(n for reason, n in self.rejected.items() if reason != REJECT_RESYNC)

    def merge(self, other: DecodeStats) -> None:
        """Add the counts of ``other`` to this one."""
        self.files += other.files
        self.packets += other.packets
        self.bytes_read += other.bytes_read
        self.bytes_unsplit += other.bytes_unsplit
        self.blocks += other.blocks
        self.blocks_decoded += other.blocks_decoded
        self.rejected.update(other.rejected)
        self.records.update(other.records)
        self.skipped_categories.update(other.skipped_categories)
        self.editions.update(other.editions)


#: Column kinds of each category: float (NaN for ``None``), int (-1 for ``None``), str.
_FLOAT, _INT, _STR = "float", "int", "str"
#: The columns of each category, in the order of its report's fields.
COLUMNS: dict[int, dict[str, str]] = {
    48: {"sac": _INT, "sic": _INT, "time_of_day_s": _FLOAT, "rho_nm": _FLOAT,
         "theta_deg": _FLOAT, "address": _INT, "flight_level": _FLOAT, "callsign": _STR,
         "capture_s": _FLOAT, "height_ft": _FLOAT, "mode_3a": _INT, "track_number": _INT},
    21: {"sac": _INT, "sic": _INT, "time_position_s": _FLOAT, "time_reception_s": _FLOAT,
         "time_report_s": _FLOAT, "address": _INT, "lat_deg": _FLOAT, "lon_deg": _FLOAT,
         "geo_height_ft": _FLOAT, "nacp": _INT, "nucp": _INT, "mops_version": _INT,
         "capture_s": _FLOAT, "flight_level": _FLOAT, "mode_3a": _INT},
    34: {"sac": _INT, "sic": _INT, "message_type": _INT, "time_of_day_s": _FLOAT,
         "lat_deg": _FLOAT, "lon_deg": _FLOAT, "height_m": _FLOAT, "capture_s": _FLOAT},
}
_REPORT_TYPES: dict[int, type] = {48: Cat048Report, 21: Cat021Report, 34: Cat034Message}


def empty_columns(category: int) -> dict[str, np.ndarray]:
    """Zero-length columns of a category (see :data:`COLUMNS`)."""
    dtypes = {_FLOAT: float, _INT: np.int64, _STR: object}
    return {name: np.zeros(0, dtype=dtypes[kind]) for name, kind in COLUMNS[category].items()}


def _materialise(category: int, columns: dict[str, np.ndarray]) -> list[Any]:
    """Report objects of columns (NaN and -1 back to ``None``)."""
    lists = []
    for name, kind in COLUMNS[category].items():
        values = columns[name].tolist()
        if kind == _FLOAT:
            values = [None if v != v else v for v in values]
        elif kind == _INT:
            values = [None if v < 0 else v for v in values]
        lists.append(values)
    report = _REPORT_TYPES[category]
    return [report(*fields) for fields in zip(*lists, strict=True)]


@dataclass
class Decoded:
    """Decoded reports, in input order, and the decode counts.

    The reports are held as columns, one numpy array per report field
    (:data:`COLUMNS`; ``NaN`` or ``-1`` where the report's field is ``None``);
    :attr:`cat048`, :attr:`cat021`, :attr:`cat034` and :attr:`sequence` give
    them as report objects (built on first use).

    Attributes
    ----------
    columns : dict
        Category (48, 21, 34) -> field name -> array, in input order.
    order : numpy.ndarray
        Category of every report, in input order (int16).
    stats : DecodeStats
        The decode counts.
    """

    columns: dict[int, dict[str, np.ndarray]] = field(
        default_factory=lambda: {c: empty_columns(c) for c in COLUMNS})
    order: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int16))
    stats: DecodeStats = field(default_factory=DecodeStats)
    _objects: dict[int, list[Any]] = field(default_factory=dict, repr=False, compare=False)

    def count(self, category: int) -> int:
        """Reports of ``category`` decoded."""
        return len(self.columns[category]["sac"])

    def _reports(self, category: int) -> list[Any]:
        if category not in self._objects:
            self._objects[category] = _materialise(category, self.columns[category])
        return self._objects[category]

    @property
    def cat048(self) -> list[Cat048Report]:
        """CAT048 reports in input order."""
        return self._reports(48)

    @property
    def cat021(self) -> list[Cat021Report]:
        """CAT021 reports in input order."""
        return self._reports(21)

    @property
    def cat034(self) -> list[Cat034Message]:
        """CAT034 messages in input order."""
        return self._reports(34)

    @property
    def sequence(self) -> list[Report]:
        """Every report in input order (the time base is built from this sequence)."""
        iterators = {c: iter(self._reports(c)) for c in COLUMNS}
        return [next(iterators[c]) for c in self.order.tolist()]

    def extend(self, other: Decoded) -> None:
        """Append the reports and counts of ``other``."""
        for category in COLUMNS:
            mine, theirs = self.columns[category], other.columns[category]
            self.columns[category] = {name: np.concatenate([mine[name], theirs[name]])
                                      for name in mine}
        self.order = np.concatenate([self.order, other.order])
        self._objects.clear()
        self.stats.merge(other.stats)



# --------------------------------------------------------------------------- block splitting


def _chain(data: bytes, pos: int, end: int, categories: AbstractSet[int], limit: int,
           bound: int, depth: int) -> bool:
    """True when ``depth`` block headers chain from ``pos``, each of a category
    in ``categories`` with a ``LEN`` from 3 to ``limit`` that fits, each starting before
    ``bound``; or fewer up to ``bound`` exactly, or to the end of the data (or a tail too
    short for a header, or a header of such a category whose ``LEN`` runs past the end:
    a block cut off at the end of a recording)."""
    for _ in range(depth):
        rest = end - pos
        if rest < HEADER_BYTES or pos == bound:
            return True
        if pos > bound:
            return False
        length = (data[pos + 1] << 8) | data[pos + 2]
        if not HEADER_BYTES <= length <= limit or data[pos] not in categories:
            return False
        if length > rest:
            return True
        pos += length
    return True


def _confirmed(data: bytes, pos: int, end: int, categories: AbstractSet[int], limit: int
               ) -> bool:
    """True when the headers from ``pos`` confirm the ``LEN`` that leads there: the end of
    the data (or a tail too short for a header), or :data:`CHAIN_DEPTH` headers as in
    :func:`_chain` with at most one more header among them of another category (a new
    category in the stream, or a corrupted ``CAT`` byte) whose ``LEN`` fits."""
    odd = False
    good = 0
    while good < CHAIN_DEPTH:
        rest = end - pos
        if rest < HEADER_BYTES:
            return True
        length = (data[pos + 1] << 8) | data[pos + 2]
        if not HEADER_BYTES <= length <= limit:
            return False
        if data[pos] in categories:
            if length > rest:
                return True
            good += 1
        elif odd or length > rest:
            return False
        else:
            odd = True
        pos += length
    return True


def _chain_start(data: bytes, lo: int, hi: int, end: int, categories: AbstractSet[int],
                 limit: int, depth: int = CHAIN_DEPTH) -> int:
    """The first offset in ``[lo, hi)`` where a plausible chain of headers starts: a
    header of a category in ``categories`` whose ``LEN`` (3 to ``limit``) fits, followed
    by ``depth`` more such headers that start before ``hi`` or chain to ``hi`` exactly
    (:func:`_chain`); ``hi`` when there is none."""
    search = _category_finder(frozenset(categories))
    last = min(hi, end - HEADER_BYTES + 1)  # a header starts before end - 2
    while lo < last:
        found = search(data, lo, last)
        if found is None:
            break
        pos = found.start()
        length = (data[pos + 1] << 8) | data[pos + 2]
        if HEADER_BYTES <= length <= min(limit, end - pos) and _chain(
                data, pos + length, end, categories, limit, hi, depth):
            return pos
        lo = pos + 1
    return hi


@functools.lru_cache(maxsize=64)
def _category_finder(categories: frozenset[int]) -> Callable[..., re.Match[bytes] | None]:
    """``search(data, lo, hi)``: the first byte in ``data[lo:hi]`` of ``categories``."""
    if not categories:
        return lambda data, lo, hi: None
    pattern = b"[" + b"".join(re.escape(bytes([c])) for c in sorted(categories)) + b"]"
    return re.compile(pattern).search


def split_blocks(
    data: bytes, stats: DecodeStats, *, start: int = 0, end: int | None = None
) -> Iterator[tuple[int, int, int]]:
    """Split bytes into ASTERIX data blocks.

    Parameters
    ----------
    data : bytes
        A UDP payload or a whole raw file.
    stats : DecodeStats
        Updated in place: ``blocks``, ``bytes_read``, ``bytes_unsplit`` and ``rejected``.
    start, end : int, optional
        Byte range of ``data`` to split (default: all of it).

    Yields
    ------
    (category, begin, stop) : tuple of int
        Category and byte range of each block with a consistent header
        (``data[begin:stop]`` includes the 3-byte header).

    Notes
    -----
    A ``LEN`` that fits is not enough: after a corrupted one, the bytes the splitter
    lands on are record bytes, which read as headers of random categories and
    lengths (up to 64 KiB each), and it would walk them to the end of a raw file.
    So a block is accepted when its ``LEN`` (3 or more, fitting in the data) is
    *confirmed* by what follows it (:func:`_confirmed`): the end of the data (or a
    tail too short for a header), or a chain of :data:`CHAIN_DEPTH` headers, each of
    a category already accepted in the stream or this block's (when ASTERIX defines
    it, :data:`ASTERIX_CATEGORIES`, or no block was accepted yet: a garbage ``CAT``
    byte such as 0 would otherwise confirm itself), and with a ``LEN`` that fits and
    is at most twice the largest accepted so far (at least
    :data:`MIN_LENGTH_LIMIT`).  One more header of another category may sit in the
    chain (a new category in the stream, or a corrupted ``CAT`` byte).

    A ``LEN`` that is not confirmed, or that exceeds that size limit, or that of the
    first block after skipped bytes, is checked against the block's own bytes: when
    a plausible chain of headers starts inside them and stays inside them (a header
    as above followed by :data:`CHAIN_DEPTH` more, found by a search for the
    categories' bytes, :func:`_chain_start`), the ``LEN`` is taken as corrupted, the
    block is rejected as :data:`REJECT_UNCONFIRMED` and the splitter resumes there:
    a corrupted ``LEN`` loses its own block and rarely more.  Otherwise the block is
    accepted when it was confirmed, or its category has been accepted before or is
    one ASTERIX defines (a block followed by garbage), and rejected as
    :data:`REJECT_UNCONFIRMED` when not.

    A header whose ``LEN`` is below 3 or runs past ``end`` is rejected
    (:data:`REJECT_BAD_LENGTH`, :data:`REJECT_TRUNCATED`).  The splitter then skips
    to the next offset where a plausible chain of headers starts: a header followed
    by :data:`RESYNC_DEPTH` more, of the categories accepted so far or of
    :data:`ASTERIX_CATEGORIES` (the block found there is checked as an unconfirmed
    one, above, so a false start that jumps over real blocks gives way to them).
    The bytes skipped are counted under :data:`REJECT_RESYNC` (up to the end of the
    data only in ``stats.bytes_unsplit``, which counts every byte left out of the
    blocks).
    Fewer than 3 bytes at the end are rejected as :data:`REJECT_SHORT_HEADER`.

    A valid stream (every ``LEN`` leading to the next header, the last to the end)
    splits into the blocks a check of ``LEN`` alone gives, but for two unlikely
    cases: a block of a category that ASTERIX does not define and the stream has not
    shown before, not confirmed by the headers after it (several new categories in a
    row), and a block larger than the size limit inside whose records a chain of
    headers happens to start and stay.  The work is linear in the input size.
    """
    end = len(data) if end is None else end
    stats.bytes_read += max(0, end - start)
    seen: set[int] = set()
    limit = MIN_LENGTH_LIMIT
    rejected = stats.rejected
    suspect = False  # the block at pos follows skipped bytes
    pos = start
    while pos < end:
        rest = end - pos
        if rest < HEADER_BYTES:
            rejected[REJECT_SHORT_HEADER] += 1
            stats.bytes_unsplit += rest
            return
        category = data[pos]
        length = (data[pos + 1] << 8) | data[pos + 2]
        if HEADER_BYTES <= length <= rest:
            nxt = pos + length
            if category in seen:
                categories: AbstractSet[int] = seen
            elif category in ASTERIX_CATEGORIES or not seen:
                categories = seen | {category}
            else:  # a garbage CAT byte would confirm itself
                categories = seen
            confirmed = _confirmed(data, nxt, end, categories, limit)
            if confirmed and length <= limit and not suspect:
                accept = True
            else:  # does a chain of headers start inside the block (a corrupted LEN)?
                resync = _chain_start(data, pos + 1, nxt, end, categories, limit)
                accept = resync >= nxt and (confirmed or category in seen
                                            or category in ASTERIX_CATEGORIES)
            if accept:
                seen.add(category)
                if length > limit >> 1:
                    limit = 2 * length
                suspect = False
                stats.blocks += 1
                yield category, pos, nxt
                pos = nxt
                continue
            rejected[REJECT_UNCONFIRMED] += 1
            if resync >= nxt:
                resync = _chain_start(data, nxt, end, end, seen | ASTERIX_CATEGORIES, limit,
                                      RESYNC_DEPTH)
        else:
            rejected[REJECT_BAD_LENGTH if length < HEADER_BYTES else REJECT_TRUNCATED] += 1
            resync = _chain_start(data, pos + 1, end, end, seen | ASTERIX_CATEGORIES, limit,
                                  RESYNC_DEPTH)
        if resync < end:
            rejected[REJECT_RESYNC] += resync - pos
        stats.bytes_unsplit += resync - pos
        suspect = True
        pos = resync


# --------------------------------------------------------------------------- record walking

#: Walk results: a record that does not parse; a flag past the end of the UAP
#: (``libasterix`` raises there, so the block counts as a decoder exception).
_BAD_RECORD, _DECODER_FAILURE = -1, -2

#: Fields read, by category: column -> (item, subfield) of the edition.
_FIELDS_048 = {
    "sac": ("010", "SAC"), "sic": ("010", "SIC"), "tod": ("140", None),
    "rho": ("040", "RHO"), "theta": ("040", "THETA"), "v": ("090", "V"), "g": ("090", "G"),
    "fl": ("090", "FL"), "address": ("220", None), "callsign": ("240", None),
    "height": ("110", "3DH"), "v070": ("070", "V"), "g070": ("070", "G"),
    "mode3a": ("070", "MODE3A"), "track": ("161", "TRN"),
}
_FIELDS_021_V2 = {
    "sac": ("010", "SAC"), "sic": ("010", "SIC"), "t071": ("071", None),
    "t073": ("073", None), "t077": ("077", None), "address": ("080", None),
    "lat131": ("131", "LAT"), "lon131": ("131", "LON"), "lat130": ("130", "LAT"),
    "lon130": ("130", "LON"), "geo": ("140", None), "fl": ("145", None),
    "nucp": ("090", "NUCPNIC"), "nacp": ("090", "NACP"), "vn": ("210", "VN"),
    "mode3a": ("070", "MODE3A"),
}
_FIELDS_021_V0 = {
    "sac": ("010", "SAC"), "sic": ("010", "SIC"), "t030": ("030", None),
    "address": ("080", None), "lat130": ("130", "LAT"), "lon130": ("130", "LON"),
    "geo": ("140", None), "fl": ("145", None),
}
#: I021/070 of edition 0.26 (0.23 to 0.25 have none): V, G, L bits then the code.
_FIELDS_021_V0_070 = {"v070": ("070", "V"), "g070": ("070", "G"), "mode3a": ("070", "MODE3A")}
_FIELDS_034 = {
    "sac": ("010", "SAC"), "sic": ("010", "SIC"), "type": ("000", None),
    "tod": ("030", None), "hgt": ("120", "HGT"), "lat": ("120", "LAT"), "lon": ("120", "LON"),
}
_FIELDS_BY_CATEGORY = {48: _FIELDS_048, 34: _FIELDS_034}
#: CAT021 columns checked for a plausible block, by edition family (2.x: True).
_TIME_COLUMNS_021 = {True: ("t071", "t073", "t077"), False: ("t030",)}
_POSITION_COLUMNS_021 = {True: (("lat131", "lon131"), ("lat130", "lon130")),
                         False: (("lat130", "lon130"),)}
#: CAT021 height columns checked, with their ranges (both families).
_HEIGHT_COLUMNS_021 = (("geo", GEO_HEIGHT_RANGE_FT), ("fl", FLIGHT_LEVEL_RANGE_FL))


def _fields_of(spec: Any) -> dict[str, tuple[str, str | None]]:
    """Columns read of an edition: column -> (item, subfield)."""
    category = int(spec.cv_category)
    if category == 21:
        if spec.cv_edition[0] >= 2:
            return _FIELDS_021_V2
        if "070" in spec.cv_record.cv_items_dict:
            return {**_FIELDS_021_V0, **_FIELDS_021_V0_070}
        return _FIELDS_021_V0
    return _FIELDS_BY_CATEGORY[category]


@dataclass(frozen=True)
class _Compiled:
    """A record layout prepared for :func:`_walk_records`."""

    spec: Any
    #: ``tables[k][b]``: FSPEC positions flagged by byte value ``b`` at FSPEC byte ``k``.
    tables: tuple[tuple[tuple[int, ...], ...], ...]
    #: Layout at each position (an int: fixed size [bytes]).
    items: tuple[Any, ...]
    #: Offset slot of each position (-1: not read).
    slots: tuple[int, ...]
    #: Item name of each slot.
    slot_items: tuple[str, ...]
    #: Field layouts by column name.
    fields: dict[str, FieldLayout]
    #: Part sizes of the extended items read, by item name.
    parts: dict[str, tuple[int, ...]]
    #: The edition's name (``"2.6"``).
    edition: str


def _compile(spec: Any) -> _Compiled:
    record = record_layout(spec)
    fields = {name: locate(spec, item, sub)
              for name, (item, sub) in _fields_of(spec).items()}
    slot_items = tuple(dict.fromkeys(f.item for f in fields.values()))
    slots = tuple(slot_items.index(name) if name in slot_items else -1
                  for name in record.names)
    n_items = len(record.items)
    tables = tuple(
        tuple(tuple(7 * k + j for j in range(7) if value & (0x80 >> j) and 7 * k + j < n_items)
              + ((n_items,) if any(value & (0x80 >> j) and 7 * k + j >= n_items
                                   for j in range(7)) else ())
              for value in range(256))
        for k in range(record.max_fspec))
    parts = {item: record.items[record.position(item)].sizes for item in slot_items
             if isinstance(record.items[record.position(item)], ExtendedLayout)}
    return _Compiled(spec, tables, record.items, slots, slot_items, fields, parts,
                     edition_name(spec))


_COMPILED: dict[Any, _Compiled] = {}


def _compiled(spec: Any) -> _Compiled:
    if spec not in _COMPILED:
        _COMPILED[spec] = _compile(spec)
    return _COMPILED[spec]


def _skip(layout: Any, data: bytes, pos: int, end: int) -> int:
    """Position after a variable-size item starting at ``pos``; < 0 when it does not parse."""
    kind = layout.__class__
    if kind is ExtendedLayout:
        sizes, fx = layout.sizes, layout.fx
        last = len(sizes) - 1
        for k, size in enumerate(sizes):
            pos += size
            if pos > end:
                return _BAD_RECORD
            if not fx[k] or not data[pos - 1] & 1:
                return pos
            if k == last:  # the last FX must be 0
                return _BAD_RECORD
        return pos
    if kind is RepetitiveLayout:
        element = layout.element
        if layout.rep_bytes == 0:
            while True:
                pos += element
                if pos > end:
                    return _BAD_RECORD
                if not data[pos - 1] & 1:
                    return pos
        count_end = pos + layout.rep_bytes
        if count_end > end:
            return _BAD_RECORD
        pos = count_end + int.from_bytes(data[pos:count_end], "big") * element
        return pos if pos <= end else _BAD_RECORD
    if layout == EXPLICIT:
        if pos >= end or data[pos] == 0:
            return _BAD_RECORD
        pos += data[pos]
        return pos if pos <= end else _BAD_RECORD
    # CompoundLayout: its own FSPEC (strict), then the flagged sub-items.
    items = layout.items
    flagged = []
    k = 0
    while True:
        if pos >= end or k >= layout.max_fspec:
            return _BAD_RECORD
        value = data[pos]
        pos += 1
        flagged.extend(7 * k + j for j in range(7) if value & (0x80 >> j))
        k += 1
        if not value & 1:
            break
    for p in flagged:
        sub = items[p] if p < len(items) else None
        if sub is None:
            return _BAD_RECORD
        pos = pos + sub if sub.__class__ is int else _skip(sub, data, pos, end)
        if pos < 0 or pos > end:
            return _BAD_RECORD
    return pos


def _walk_records(data: bytes, pos: int, end: int, compiled: _Compiled, base: int
                  ) -> list[int] | int:
    """Walk the records of a block body ``data[pos:end]``.

    Returns
    -------
    list of int or int
        For each record, the offset (plus ``base``) of each item read, -1 when
        absent (``len(compiled.slot_items)`` values per record); or
        :data:`_BAD_RECORD` / :data:`_DECODER_FAILURE`.
    """
    tables, items, slots = compiled.tables, compiled.items, compiled.slots
    max_fspec = len(tables)
    n_items = len(items)
    template = [-1] * len(compiled.slot_items)
    out: list[int] = []
    while pos < end:
        row = template[:]
        value = data[pos]
        pos += 1
        flagged = tables[0][value]
        k = 1
        while value & 1:
            if pos >= end or k >= max_fspec:
                return _BAD_RECORD
            value = data[pos]
            pos += 1
            flagged += tables[k][value]
            k += 1
        for p in flagged:
            if p >= n_items:
                return _DECODER_FAILURE
            slot = slots[p]
            if slot >= 0:
                row[slot] = pos + base
            layout = items[p]
            if layout.__class__ is int:
                pos += layout
            elif layout is None:  # a spare position flagged
                return _BAD_RECORD
            else:
                pos = _skip(layout, data, pos, end)
                if pos < 0:
                    return _BAD_RECORD
        if pos > end:
            return _BAD_RECORD
        out += row
    return out


#: Bounds of a field in its item's bytes: (right shift, mask, sign bit (0: unsigned),
#: lowest and highest raw count allowed).
_Bounds = tuple[int, int, int, int, int]


def _bounds(layout: FieldLayout, last_bit: int, low: float | None, high: float | None,
            *, strict_high: bool = False) -> _Bounds:
    """``low <= raw * LSB <= high`` (``< high`` when ``strict_high``) as bounds on the raw
    count of a field ending ``last_bit`` bits into the bytes read; exact (the LSBs are
    binary fractions of small integers, so ``raw * LSB`` is exact in floating point)."""
    assert layout.lsb is not None
    lsb = Fraction(layout.lsb)
    sign = 1 << (layout.bit_size - 1) if layout.signed else 0
    lowest = -sign if sign else 0
    highest = (sign - 1) if sign else (1 << layout.bit_size) - 1
    if low is not None:
        lowest = max(lowest, math.ceil(Fraction(low) / lsb))
    if high is not None:
        bound = Fraction(high) / lsb
        highest = min(highest, math.ceil(bound) - 1 if strict_high else math.floor(bound))
    return (last_bit - layout.bit_offset - layout.bit_size, (1 << layout.bit_size) - 1, sign,
            lowest, highest)


@dataclass(frozen=True)
class _Plan:
    """What :func:`_presence_grade` and :func:`_values_grade` check in the records of a
    CAT021 edition.

    Attributes
    ----------
    address_slot : int
        Offset slot of I080.
    time_slots : tuple of int
        Offset slots of the time items (one must be present).
    items : tuple
        ``(slot, bytes to read, bounds of its fields)`` of every item whose values are
        checked when present (times, positions, heights).
    """

    address_slot: int
    time_slots: tuple[int, ...]
    items: tuple[tuple[int, int, tuple[_Bounds, ...]], ...]


_PLANS: dict[Any, _Plan] = {}


def _plan(compiled: _Compiled) -> _Plan:
    """The :class:`_Plan` of a compiled CAT021 edition (built once)."""
    if compiled.spec in _PLANS:
        return _PLANS[compiled.spec]
    fields = compiled.fields
    family = "t071" in fields
    limits: dict[str, tuple[float | None, float | None, bool]] = {
        name: (None, MAX_TIME_OF_DAY_S, True) for name in _TIME_COLUMNS_021[family]}
    for pair in _POSITION_COLUMNS_021[family]:
        for name, limit in zip(pair, (90.0, 180.0), strict=True):
            limits[name] = (-limit, limit, False)
    for name, (low, high) in _HEIGHT_COLUMNS_021:
        limits[name] = (low, high, False)
    by_item: dict[str, list[str]] = {}
    for name in limits:
        by_item.setdefault(fields[name].item, []).append(name)
    items = []
    for item, names in by_item.items():
        n_bytes = max(fields[n].bit_offset + fields[n].bit_size + 7 for n in names) // 8
        items.append((compiled.slot_items.index(item), n_bytes, tuple(
            _bounds(fields[n], 8 * n_bytes, limits[n][0], limits[n][1],
                    strict_high=limits[n][2]) for n in names)))
    plan = _Plan(compiled.slot_items.index("080"),
                 tuple(compiled.slot_items.index(fields[n].item)
                       for n in _TIME_COLUMNS_021[family]),
                 tuple(items))
    _PLANS[compiled.spec] = plan
    return plan


#: Presence grade of a CAT021 block whose values are still to be checked.
_GRADE_UNCHECKED = GRADE_PLAUSIBLE + 1


def _presence_grade(category: int, walked: list[int], compiled: _Compiled) -> int:
    """The grade of a walked block from the items present: :data:`GRADE_NO_SOURCE`,
    :data:`GRADE_SOURCE`, :data:`GRADE_PLAUSIBLE` (not CAT021), or, for a CAT021 block
    that has every item wanted, :data:`_GRADE_UNCHECKED` (:func:`_values_grade` tells)."""
    width = len(compiled.slot_items)
    if -1 in walked[compiled.slot_items.index("010")::width]:
        return GRADE_NO_SOURCE
    if category != 21:
        return GRADE_PLAUSIBLE
    plan = _plan(compiled)
    if -1 in walked[plan.address_slot::width]:
        return GRADE_SOURCE
    times = [walked[slot::width] for slot in plan.time_slots]
    if min(map(max, *times) if len(times) > 1 else times[0]) < 0:
        return GRADE_SOURCE  # a record without a time of day
    return _GRADE_UNCHECKED


def _values_grade(data: bytes, walked: list[int], compiled: _Compiled, base: int) -> int:
    """:data:`GRADE_PLAUSIBLE` when the times, positions and heights of a CAT021 block
    with every item wanted are within their bounds, else :data:`GRADE_SOURCE`."""
    width = len(compiled.slot_items)
    for slot, n_bytes, bounds in _plan(compiled).items:
        offsets = walked[slot::width]
        if max(offsets) < 0:
            continue  # the item is in no record
        for offset in offsets:
            if offset < 0:
                continue
            offset -= base
            word = int.from_bytes(data[offset:offset + n_bytes], "big")
            for shift, mask, sign, lowest, highest in bounds:
                raw = (word >> shift) & mask
                if raw & sign:
                    raw -= sign << 1
                if not lowest <= raw <= highest:
                    return GRADE_SOURCE
    return GRADE_PLAUSIBLE


# --------------------------------------------------------------------------- field extraction


#: ICAO 6-bit character set (I048/240) as bytes; 0 where the code is not a character.
_ICAO_CHARS = np.zeros(64, dtype=np.uint8)
_ICAO_CHARS[1:27] = np.frombuffer(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ", dtype=np.uint8)
_ICAO_CHARS[0x20] = ord(" ")
_ICAO_CHARS[0x30:0x3A] = np.frombuffer(b"0123456789", dtype=np.uint8)


class _Fields:
    """Raw field values of many records of one edition, from their item offsets."""

    def __init__(self, buffer: np.ndarray, compiled: _Compiled, offsets: np.ndarray) -> None:
        self.buffer = buffer
        self.compiled = compiled
        self.offsets = offsets.reshape(-1, len(compiled.slot_items))
        self._present: dict[tuple[str, int], np.ndarray] = {}

    def _byte(self, index: np.ndarray) -> np.ndarray:
        return self.buffer[np.clip(index, 0, len(self.buffer) - 1)].astype(np.int64)

    def present(self, name: str) -> np.ndarray:
        """Records that carry column ``name``'s field (its item, and its part)."""
        layout = self.compiled.fields[name]
        key = (layout.item, layout.part)
        if key not in self._present:
            offset = self.offsets[:, self.compiled.slot_items.index(layout.item)]
            mask = offset >= 0
            sizes = self.compiled.parts.get(layout.item, ())
            end = offset.copy()
            for part in range(layout.part):
                end = end + sizes[part]
                mask &= (self._byte(end - 1) & 1).astype(bool)
            self._present[key] = mask
        return self._present[key]

    def raw(self, name: str) -> np.ndarray:
        """Column ``name``'s field as integers (two's complement applied); 0 where absent."""
        layout = self.compiled.fields[name]
        offset = self.offsets[:, self.compiled.slot_items.index(layout.item)]
        first = np.where(offset >= 0, offset, 0) + layout.bit_offset // 8
        lead = layout.bit_offset % 8
        n_bytes = (lead + layout.bit_size + 7) // 8
        value = np.zeros(len(offset), dtype=np.uint64)
        for k in range(n_bytes):
            value = (value << np.uint64(8)) | self._byte(first + k).astype(np.uint64)
        value >>= np.uint64(8 * n_bytes - lead - layout.bit_size)
        value &= np.uint64((1 << layout.bit_size) - 1)
        signed = value.astype(np.int64)
        if layout.signed:
            half = 1 << (layout.bit_size - 1)
            signed = np.where(signed >= half, signed - 2 * half, signed)
        return np.where(self.present(name), signed, 0)

    def quantity(self, name: str) -> np.ndarray:
        """Column ``name``'s field as ``signed raw * LSB`` [the item's unit]; NaN where absent."""
        layout = self.compiled.fields[name]
        assert layout.lsb is not None
        return np.where(self.present(name), self.raw(name).astype(float) * layout.lsb, np.nan)

    def uint(self, name: str) -> np.ndarray:
        """Column ``name``'s field as an integer; -1 where absent."""
        return np.where(self.present(name), self.raw(name), -1)

    def icao_text(self, name: str) -> np.ndarray:
        """An ICAO 6-bit string field, blanks removed; ``None`` where absent or empty."""
        present = self.present(name)
        raw = self.raw(name).astype(np.uint64)
        n_chars = self.compiled.fields[name].bit_size // 6
        codes = np.stack([(raw >> np.uint64(6 * (n_chars - 1 - j))) & np.uint64(63)
                          for j in range(n_chars)], axis=1).astype(np.intp)
        text = _ICAO_CHARS[codes].tobytes()
        out = np.empty(len(raw), dtype=object)
        for i, has in enumerate(present.tolist()):
            if has:
                value = text[i * n_chars:(i + 1) * n_chars].replace(b"\0", b"").strip()
                out[i] = value.decode("ascii") or None
            else:
                out[i] = None
        return out


def _mode_3a(f: _Fields) -> np.ndarray:
    """The Mode 3/A code (I070) as its 12-bit integer; -1 where absent, or, when the
    item has validity bits, not validated (V=1) or garbled (G=1)."""
    code = f.uint("mode3a")
    if "v070" not in f.compiled.fields:
        return code
    valid = (f.raw("v070") == 0) & (f.raw("g070") == 0)
    return np.where(valid, code, -1)


def _columns_048(f: _Fields, capture: np.ndarray) -> dict[str, np.ndarray]:
    valid_level = f.present("fl") & (f.raw("v") == 0) & (f.raw("g") == 0)
    return {
        "sac": f.raw("sac"), "sic": f.raw("sic"), "time_of_day_s": f.quantity("tod"),
        "rho_nm": f.quantity("rho"), "theta_deg": f.quantity("theta"),
        "address": f.uint("address"),
        "flight_level": np.where(valid_level, f.quantity("fl"), np.nan),
        "callsign": f.icao_text("callsign"), "capture_s": capture,
        "height_ft": f.quantity("height"), "mode_3a": _mode_3a(f),
        "track_number": f.uint("track"),
    }


def _columns_021(f: _Fields, capture: np.ndarray) -> dict[str, np.ndarray]:
    n = len(capture)
    none_f, none_i = np.full(n, np.nan), np.full(n, -1, dtype=np.int64)
    if "t071" in f.compiled.fields:  # edition 2
        high = f.present("lat131")
        lat = np.where(high, f.quantity("lat131"), f.quantity("lat130"))
        lon = np.where(high, f.quantity("lon131"), f.quantity("lon130"))
        times = f.quantity("t071"), f.quantity("t073"), f.quantity("t077")
        quality = f.uint("nacp"), f.uint("nucp"), f.uint("vn")
    else:
        lat, lon = f.quantity("lat130"), f.quantity("lon130")
        times = f.quantity("t030"), none_f, none_f.copy()
        quality = none_i, none_i.copy(), none_i.copy()
    return {
        "sac": f.raw("sac"), "sic": f.raw("sic"), "time_position_s": times[0],
        "time_reception_s": times[1], "time_report_s": times[2],
        "address": f.uint("address"), "lat_deg": lat, "lon_deg": lon,
        "geo_height_ft": f.quantity("geo"), "nacp": quality[0], "nucp": quality[1],
        "mops_version": quality[2], "capture_s": capture, "flight_level": f.quantity("fl"),
        "mode_3a": _mode_3a(f) if "mode3a" in f.compiled.fields else none_i.copy(),
    }


def _columns_034(f: _Fields, capture: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "sac": f.raw("sac"), "sic": f.raw("sic"), "message_type": f.uint("type"),
        "time_of_day_s": f.quantity("tod"), "lat_deg": f.quantity("lat"),
        "lon_deg": f.quantity("lon"), "height_m": f.quantity("hgt"), "capture_s": capture,
    }


_COLUMN_BUILDERS = {48: _columns_048, 21: _columns_021, 34: _columns_034}


def _choose(parsed: list[tuple[_Compiled, list[int], int]], data: bytes, base: int
            ) -> tuple[_Compiled, list[int], int]:
    """The first edition with the best grade (module docstring), from the editions that
    parsed a block with their presence grades (:func:`_presence_grade`).

    The values of a block are only checked when they can change the choice: a single
    edition with every item wanted, after editions without source only, is chosen
    whether its values are plausible (the best grade) or not (then it is still the first
    with the best grade, "with source").  This is what the usual 2.x block is: the
    0.2x walks fail on it within a record or two."""
    unchecked = [k for k, entry in enumerate(parsed) if entry[2] == _GRADE_UNCHECKED]
    if len(unchecked) == 1 and all(entry[2] == GRADE_NO_SOURCE
                                   for entry in parsed[:unchecked[0]]):
        compiled, walked, _ = parsed[unchecked[0]]
        return compiled, walked, GRADE_SOURCE  # or plausible: the same choice
    graded = [(compiled, walked, _values_grade(data, walked, compiled, base)
               if grade == _GRADE_UNCHECKED else grade)
              for compiled, walked, grade in parsed]
    best = max(grade for _, _, grade in graded)
    return next(entry for entry in graded if entry[2] == best)


class _Collector:
    """Item offsets of the records of accepted blocks, turned into columns at the end."""

    def __init__(self, stats: DecodeStats, specs: dict[int, tuple[Any, ...]] | None = None
                 ) -> None:
        self.stats = stats
        self.specs = SPECS if specs is None else specs
        self.chunks: list[bytes] = []
        self.base = 0
        self.n_reports = 0
        self.order: list[int] = []
        # per specification: offsets (flat), report numbers, capture times
        self.offsets: dict[Any, list[int]] = {}
        self.numbers: dict[Any, list[int]] = {}
        self.captures: dict[Any, list[float]] = {}

    def add_chunk(self, data: bytes) -> int:
        """Keep ``data`` (a payload or file); returns the base offset of its bytes."""
        base = self.base
        self.chunks.append(data)
        self.base += len(data)
        return base

    def block(self, category: int, data: bytes, begin: int, stop: int,
              capture_s: float | None, base: int) -> int:
        """Walk the block ``data[begin:stop]`` (header included); returns its record count."""
        specs = self.specs.get(category)
        if specs is None:
            self.stats.skipped_categories[category] += 1
            return 0
        parsed: list[tuple[_Compiled, list[int], int]] = []
        failed = False
        for spec in specs:
            compiled = _compiled(spec)
            walked = _walk_records(data, begin + HEADER_BYTES, stop, compiled, base)
            if walked == _DECODER_FAILURE:
                failed = True
            elif isinstance(walked, list) and walked:
                parsed.append((compiled, walked, _presence_grade(category, walked, compiled)))
                if parsed[-1][2] == GRADE_PLAUSIBLE:
                    break
        if not parsed:
            self.stats.rejected[REJECT_DECODER if failed else REJECT_RECORDS] += 1
            return 0
        compiled, walked, best = _choose(parsed, data, base)
        if best == GRADE_NO_SOURCE:
            self.stats.rejected[REJECT_NO_SOURCE] += 1
            return 0
        n = len(walked) // len(compiled.slot_items)
        spec = compiled.spec
        self.offsets.setdefault(spec, []).extend(walked)
        self.numbers.setdefault(spec, []).extend(range(self.n_reports, self.n_reports + n))
        self.captures.setdefault(spec, []).extend(
            [math.nan if capture_s is None else capture_s] * n)
        self.order.extend([category] * n)
        self.n_reports += n
        self.stats.blocks_decoded += 1
        self.stats.records[category] += n
        self.stats.editions[category, compiled.edition] += 1
        return n

    def finish(self) -> Decoded:
        """The columns of every record kept, in input order."""
        out = Decoded(stats=self.stats)
        out.order = np.asarray(self.order, dtype=np.int16)
        if not self.n_reports:
            return out
        buffer = np.frombuffer(b"".join(self.chunks), dtype=np.uint8)
        for category, specs in self.specs.items():
            parts, numbers = [], []
            for spec in specs:
                if spec not in self.offsets:
                    continue
                fields = _Fields(buffer, _compiled(spec),
                                 np.asarray(self.offsets[spec], dtype=np.int64))
                capture = np.asarray(self.captures[spec], dtype=float)
                parts.append(_COLUMN_BUILDERS[category](fields, capture))
                numbers.append(np.asarray(self.numbers[spec], dtype=np.int64))
            if not parts:
                continue
            rank = np.argsort(np.concatenate(numbers), kind="stable")
            out.columns[category] = {
                name: np.concatenate([p[name] for p in parts]).astype(
                    empty_columns(category)[name].dtype)[rank]
                for name in COLUMNS[category]}
        return out


def decode_block(category: int, block: bytes, capture_s: float | None,
                 stats: DecodeStats, *, cat021_edition: str = CAT021_AUTO) -> list[Report]:
    """Decode one data block (header included) into reports.

    Parameters
    ----------
    category : int
        The block's CAT byte.
    block : bytes
        The whole block, header included.
    capture_s : float or None
        Capture time of the packet [unix s], copied to each report.
    stats : DecodeStats
        Updated in place.
    cat021_edition : str, optional
        ``"auto"`` (default: chosen per block) or a CAT021 edition to force
        (:data:`CAT021_EDITION_CHOICES`).

    Returns
    -------
    list of report
        Empty for a skipped category or a rejected block.  All reports of a
        block are kept or none: a block with one bad record is rejected.
    """
    collector = _Collector(stats, decoder_specs(cat021_edition))
    base = collector.add_chunk(block)
    collector.block(category, block, 0, len(block), capture_s, base)
    return collector.finish().sequence


def _decode_into(collector: _Collector, data: bytes, capture_s: float | None) -> None:
    """Split ``data`` into blocks and walk them into ``collector``."""
    base = collector.add_chunk(data)
    for category, begin, stop in split_blocks(data, collector.stats):
        collector.block(category, data, begin, stop, capture_s, base)


def decode_payload(data: bytes, capture_s: float | None = None,
                   into: Decoded | None = None, *, cat021_edition: str = CAT021_AUTO
                   ) -> Decoded:
    """Split a UDP payload or raw byte stream into blocks and decode them.

    Parameters
    ----------
    data : bytes
        Concatenated ASTERIX data blocks.
    capture_s : float or None, optional
        Capture time [unix s] given to every report.
    into : Decoded, optional
        Append to this result instead of a new one.
    cat021_edition : str, optional
        ``"auto"`` (default: chosen per block) or a CAT021 edition to force
        (:data:`CAT021_EDITION_CHOICES`).

    Returns
    -------
    Decoded
        ``into`` or a new result.
    """
    collector = _Collector(DecodeStats(), decoder_specs(cat021_edition))
    _decode_into(collector, data, capture_s)
    decoded = collector.finish()
    if into is None:
        return decoded
    into.extend(decoded)
    return into



# --------------------------------------------------------------------------- captures


def detect_format(head: bytes) -> str:
    """``"pcap"``, ``"pcapng"`` or ``"raw"`` from the first bytes of a file."""
    if head[:4] in _PCAP_MAGICS:
        return "pcap"
    if head[:4] == _PCAPNG_MAGIC and head[8:12] in _PCAPNG_BOM:
        return "pcapng"
    return "raw"


def _ipv4_udp_payload(ip: Any, stats: DecodeStats) -> bytes | None:
    """The UDP payload of an IPv4 packet, ``None`` for anything else."""
    if not isinstance(ip, dpkt.ip.IP):
        return None
    if ip.mf or ip.offset:
        stats.rejected[REJECT_FRAGMENT] += 1
        return None
    udp = ip.data
    if not isinstance(udp, dpkt.udp.UDP):
        return None
    return bytes(udp.data)


def _network_layer(linktype: int, frame: bytes) -> Any:
    """The IP layer of a captured frame for the supported link types, else ``None``."""
    if linktype == _DLT_EN10MB:
        return dpkt.ethernet.Ethernet(frame).data
    if linktype == _DLT_LINUX_SLL:
        return dpkt.sll.SLL(frame).data
    if linktype == _DLT_LINUX_SLL2:
        return dpkt.sll2.SLL2(frame).data
    if linktype in (_DLT_RAW, _DLT_IPV4, *_DLT_RAW_ALIASES):
        return dpkt.ip.IP(frame) if frame[:1] and frame[0] >> 4 == 4 else None
    if linktype == _DLT_NULL:
        return dpkt.ip.IP(frame[4:]) if frame[4:5] and frame[4] >> 4 == 4 else None
    return None


def _packets(stream: io.BufferedIOBase, kind: str, stats: DecodeStats
             ) -> Iterator[tuple[float, bytes]]:
    """``(capture time [unix s], UDP payload)`` of each IPv4 UDP packet of a capture."""
    try:
        reader = dpkt.pcap.Reader(stream) if kind == "pcap" else dpkt.pcapng.Reader(stream)
        linktype = reader.datalink()
        packets = iter(reader)
    except Exception as exc:  # noqa: BLE001 - a bad capture header is a bad file
        raise AsterixError(f"cannot read {kind} capture: {exc}") from None
    while True:
        try:
            timestamp, frame = next(packets)
        except StopIteration:
            return
        except Exception:  # noqa: BLE001 - a truncated capture ends the file
            stats.rejected[REJECT_PACKET] += 1
            return
        try:
            payload = _ipv4_udp_payload(_network_layer(linktype, frame), stats)
        except Exception:  # noqa: BLE001 - a malformed frame is skipped
            stats.rejected[REJECT_PACKET] += 1
            continue
        if payload is None:
            continue
        stats.packets += 1
        yield float(timestamp), payload


def decode_bytes(data: bytes, *, progress: Callable[[int, int], None] | None = None,
                 cat021_edition: str = CAT021_AUTO) -> Decoded:
    """Decode a whole recording held in memory (raw blocks, pcap or pcapng).

    Parameters
    ----------
    data : bytes
        The file content; its format comes from its first bytes
        (:func:`detect_format`).
    progress : callable, optional
        Called as ``progress(bytes_done, bytes_total)`` now and then.
    cat021_edition : str, optional
        ``"auto"`` (default: chosen per block) or a CAT021 edition to force
        (:data:`CAT021_EDITION_CHOICES`).

    Returns
    -------
    Decoded
        Reports and counts (``stats.files`` is 1).

    Raises
    ------
    AsterixError
        If a capture's global header cannot be read.
    """
    stats = DecodeStats(files=1)
    collector = _Collector(stats, decoder_specs(cat021_edition))
    total = len(data)
    kind = detect_format(data[:12])
    if kind == "raw":
        step = max(1 << 16, total // 500)
        next_report = step
        base = collector.add_chunk(data)
        for category, begin, stop in split_blocks(data, stats):
            collector.block(category, data, begin, stop, None, base)
            if progress is not None and stop >= next_report:
                progress(stop, total)
                next_report = stop + step
    else:
        stream = io.BytesIO(data)
        for n, (timestamp, payload) in enumerate(_packets(stream, kind, stats)):
            _decode_into(collector, payload, timestamp)
            if progress is not None and n % 200 == 0:
                progress(stream.tell(), total)
    out = collector.finish()
    if progress is not None:
        progress(total, total)
    return out


def decode_file(path: str | Path, *, progress: Callable[[int, int], None] | None = None,
                cat021_edition: str = CAT021_AUTO) -> Decoded:
    """Decode an ASTERIX recording file (raw blocks, pcap or pcapng).

    Parameters
    ----------
    path : str or Path
        The recording.
    progress : callable, optional
        Called as ``progress(bytes_done, bytes_total)``.
    cat021_edition : str, optional
        ``"auto"`` (default: chosen per block) or a CAT021 edition to force
        (:data:`CAT021_EDITION_CHOICES`).

    Returns
    -------
    Decoded
        Reports in file order and the decode counts.

    Raises
    ------
    AsterixError
        If the file is missing, unreadable or empty, or a capture header is invalid.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise AsterixError("file not found", path=path) from None
    except OSError as exc:
        raise AsterixError(f"cannot read: {exc.strerror or exc}", path=path) from None
    if not data:
        raise AsterixError("empty file", path=path)
    try:
        return decode_bytes(data, progress=progress, cat021_edition=cat021_edition)
    except AsterixError as exc:
        raise AsterixError(exc.detail, path=path) from None


def decode_files(paths: Iterable[str | Path], *,
                 progress: Callable[[int, int], None] | None = None,
                 cat021_edition: str = CAT021_AUTO) -> Decoded:
    """Decode several recordings, in the given order, into one result.

    ``progress`` is called as ``progress(bytes_done, bytes_total)`` over all files;
    ``cat021_edition`` as in :func:`decode_file`.
    """
    decoder_specs(cat021_edition)  # an unknown edition fails before any file is read
    paths = [Path(p) for p in paths]
    sizes = [p.stat().st_size if p.is_file() else 0 for p in paths]
    total = sum(sizes)
    out = Decoded()
    done = 0
    for path, size in zip(paths, sizes, strict=True):
        def partial(n: int, _total: int, offset: int = done) -> None:
            if progress is not None:
                progress(offset + n, total)

        out.extend(decode_file(path, progress=partial, cat021_edition=cat021_edition))
        done += size
    return out
