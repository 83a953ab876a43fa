"""Read ASTERIX recordings: split byte streams into data blocks and decode records.

Inputs are either *raw* files (ASTERIX data blocks written back to back, as
recorded by most ATC tools) or packet captures (pcap or pcapng) of the UDP
datagrams that carry them.  Each data block is ``CAT`` (1 byte), ``LEN``
(2 bytes, big-endian, the length of the whole block in bytes) and the records.
A UDP payload may hold several data blocks.

Categories decoded (item definitions from ``libasterix``, import name ``asterix``):

- CAT048 (monoradar target reports), edition 1.32,
- CAT021 (ADS-B target reports), edition 2.6 (a block that does not parse with
  it is tried with edition 0.26, still found in older recordings),
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

Robustness: a block is rejected as a whole when its header is inconsistent with
the bytes that follow, when its records do not parse, or when the decoder
raises anything.  The rest of the input is kept; :class:`DecodeStats` counts
what was rejected and why.  After a block whose ``LEN`` cannot be right, the
splitter looks for the next offset where a plausible chain of block headers
starts (see :func:`split_blocks`), so one corrupted byte does not lose a whole
raw file.  Nothing raises on arbitrary input bytes except :class:`AsterixError`
for a file that cannot be read at all.
"""

from __future__ import annotations

import io
import math
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
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


#: Decoder specifications by category (the first that parses a block wins).
SPECS: dict[int, tuple[Any, ...]] = {
    48: (gen.Cat_048_1_32,),
    21: (gen.Cat_021_2_6, gen.Cat_021_0_26),
    34: (gen.Cat_034_1_29,),
}
#: Categories that are decoded; others are counted in ``DecodeStats.skipped_categories``.
DECODED_CATEGORIES: tuple[int, ...] = tuple(SPECS)

#: Size of a data block header (CAT + LEN) [bytes].
HEADER_BYTES = 3

# Rejection reasons (keys of DecodeStats.rejected).
#: Fewer than 3 bytes left where a block header should start.
REJECT_SHORT_HEADER = "short header"
#: ``LEN`` smaller than the 3-byte header.
REJECT_BAD_LENGTH = "LEN < 3"
#: ``LEN`` runs past the end of the payload or file (truncated block).
REJECT_TRUNCATED = "truncated (LEN past end)"
#: Bytes skipped while looking for the next plausible block header.
REJECT_RESYNC = "bytes skipped to resync"
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
    flight_level : float or None
        Barometric (pressure) altitude (I021/145) [FL, 100 ft], resolution 1/4 FL.
    nacp : int or None
        Navigation Accuracy Category for position (I021/090 second extension, v2).
    nucp : int or None
        NUCp or NIC (I021/090 first part, v2), used when NACp is absent.
    mops_version : int or None
        ADS-B version number VN (I021/210): 0 DO-260 (the NUCp field is a
        NUCp), 1 DO-260A, 2 DO-260B (it is a NIC).
    capture_s : float or None
        Capture time of the packet [unix s].
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
    """

    files: int = 0
    packets: int = 0
    bytes_read: int = 0
    blocks: int = 0
    blocks_decoded: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    records: Counter[int] = field(default_factory=Counter)
    skipped_categories: Counter[int] = field(default_factory=Counter)

    @property
    def n_rejected(self) -> int:
        """Rejections of every reason, resync bytes excluded."""
        return sum(n for reason, n in self.rejected.items() if reason != REJECT_RESYNC)

    def merge(self, other: DecodeStats) -> None:
        """Add the counts of ``other`` to this one."""
        self.files += other.files
        self.packets += other.packets
        self.bytes_read += other.bytes_read
        self.blocks += other.blocks
        self.blocks_decoded += other.blocks_decoded
        self.rejected.update(other.rejected)
        self.records.update(other.records)
        self.skipped_categories.update(other.skipped_categories)


#: Column kinds of each category: float (NaN for ``None``), int (-1 for ``None``), str.
_FLOAT, _INT, _STR = "float", "int", "str"
#: The columns of each category, in the order of its report's fields.
COLUMNS: dict[int, dict[str, str]] = {
    48: {"sac": _INT, "sic": _INT, "time_of_day_s": _FLOAT, "rho_nm": _FLOAT,
         "theta_deg": _FLOAT, "address": _INT, "flight_level": _FLOAT, "callsign": _STR,
         "capture_s": _FLOAT, "height_ft": _FLOAT},
    21: {"sac": _INT, "sic": _INT, "time_position_s": _FLOAT, "time_reception_s": _FLOAT,
         "time_report_s": _FLOAT, "address": _INT, "lat_deg": _FLOAT, "lon_deg": _FLOAT,
         "geo_height_ft": _FLOAT, "nacp": _INT, "nucp": _INT, "mops_version": _INT,
         "capture_s": _FLOAT, "flight_level": _FLOAT},
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


def _plausible_header(data: bytes, pos: int, end: int) -> bool:
    """True when a block header at ``pos`` fits in ``[pos, end)`` and is followed by
    the end or by another header that fits."""
    if pos + HEADER_BYTES > end:
        return False
    length = (data[pos + 1] << 8) | data[pos + 2]
    if length < HEADER_BYTES or pos + length > end:
        return False
    nxt = pos + length
    if nxt == end:
        return True
    if nxt + HEADER_BYTES > end:
        return False
    next_length = (data[nxt + 1] << 8) | data[nxt + 2]
    return HEADER_BYTES <= next_length <= end - nxt


def split_blocks(
    data: bytes, stats: DecodeStats, *, start: int = 0, end: int | None = None
) -> Iterator[tuple[int, int, int]]:
    """Split bytes into ASTERIX data blocks.

    Parameters
    ----------
    data : bytes
        A UDP payload or a whole raw file.
    stats : DecodeStats
        Updated in place: ``blocks``, ``bytes_read`` and ``rejected``.
    start, end : int, optional
        Byte range of ``data`` to split (default: all of it).

    Yields
    ------
    (category, begin, stop) : tuple of int
        Category and byte range of each block with a consistent header
        (``data[begin:stop]`` includes the 3-byte header).

    Notes
    -----
    A header whose ``LEN`` is below 3 or runs past ``end`` is rejected.  The
    splitter then skips forward to the next offset where a header fits and
    is followed by the end or by another header that fits, counting the bytes
    skipped under :data:`REJECT_RESYNC`.  Fewer than 3 bytes at the end are
    rejected as :data:`REJECT_SHORT_HEADER`.  The work is linear in the input size.
    """
    end = len(data) if end is None else end
    stats.bytes_read += max(0, end - start)
    pos = start
    while pos < end:
        if end - pos < HEADER_BYTES:
            stats.rejected[REJECT_SHORT_HEADER] += 1
            return
        length = (data[pos + 1] << 8) | data[pos + 2]
        if HEADER_BYTES <= length <= end - pos:
            stats.blocks += 1
            yield data[pos], pos, pos + length
            pos += length
            continue
        stats.rejected[REJECT_BAD_LENGTH if length < HEADER_BYTES else REJECT_TRUNCATED] += 1
        resync = pos + 1
        while resync < end and not _plausible_header(data, resync, end):
            resync += 1
        if resync < end:
            stats.rejected[REJECT_RESYNC] += resync - pos
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
    "height": ("110", "3DH"),
}
_FIELDS_021_V2 = {
    "sac": ("010", "SAC"), "sic": ("010", "SIC"), "t071": ("071", None),
    "t073": ("073", None), "t077": ("077", None), "address": ("080", None),
    "lat131": ("131", "LAT"), "lon131": ("131", "LON"), "lat130": ("130", "LAT"),
    "lon130": ("130", "LON"), "geo": ("140", None), "fl": ("145", None),
    "nucp": ("090", "NUCPNIC"), "nacp": ("090", "NACP"), "vn": ("210", "VN"),
}
_FIELDS_021_V0 = {
    "sac": ("010", "SAC"), "sic": ("010", "SIC"), "t030": ("030", None),
    "address": ("080", None), "lat130": ("130", "LAT"), "lon130": ("130", "LON"),
    "geo": ("140", None), "fl": ("145", None),
}
_FIELDS_034 = {
    "sac": ("010", "SAC"), "sic": ("010", "SIC"), "type": ("000", None),
    "tod": ("030", None), "hgt": ("120", "HGT"), "lat": ("120", "LAT"), "lon": ("120", "LON"),
}
_FIELDS_BY_SPEC: dict[Any, dict[str, tuple[str, str | None]]] = {
    gen.Cat_048_1_32: _FIELDS_048, gen.Cat_021_2_6: _FIELDS_021_V2,
    gen.Cat_021_0_26: _FIELDS_021_V0, gen.Cat_034_1_29: _FIELDS_034,
}


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


def _compile(spec: Any) -> _Compiled:
    record = record_layout(spec)
    fields = {name: locate(spec, item, sub)
              for name, (item, sub) in _FIELDS_BY_SPEC[spec].items()}
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
    return _Compiled(spec, tables, record.items, slots, slot_items, fields, parts)


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


def _columns_048(f: _Fields, capture: np.ndarray) -> dict[str, np.ndarray]:
    valid_level = f.present("fl") & (f.raw("v") == 0) & (f.raw("g") == 0)
    return {
        "sac": f.raw("sac"), "sic": f.raw("sic"), "time_of_day_s": f.quantity("tod"),
        "rho_nm": f.quantity("rho"), "theta_deg": f.quantity("theta"),
        "address": f.uint("address"),
        "flight_level": np.where(valid_level, f.quantity("fl"), np.nan),
        "callsign": f.icao_text("callsign"), "capture_s": capture,
        "height_ft": f.quantity("height"),
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
    }


def _columns_034(f: _Fields, capture: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "sac": f.raw("sac"), "sic": f.raw("sic"), "message_type": f.uint("type"),
        "time_of_day_s": f.quantity("tod"), "lat_deg": f.quantity("lat"),
        "lon_deg": f.quantity("lon"), "height_m": f.quantity("hgt"), "capture_s": capture,
    }


_COLUMN_BUILDERS = {48: _columns_048, 21: _columns_021, 34: _columns_034}


class _Collector:
    """Item offsets of the records of accepted blocks, turned into columns at the end."""

    def __init__(self, stats: DecodeStats) -> None:
        self.stats = stats
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
        if category not in SPECS:
            self.stats.skipped_categories[category] += 1
            return 0
        walked: list[int] | int = _BAD_RECORD
        compiled = None
        for spec in SPECS[category]:
            compiled = _compiled(spec)
            walked = _walk_records(data, begin + HEADER_BYTES, stop, compiled, base)
            if walked == _DECODER_FAILURE:
                self.stats.rejected[REJECT_DECODER] += 1
                return 0
            if isinstance(walked, list) and walked:
                break
        if not isinstance(walked, list) or not walked:
            self.stats.rejected[REJECT_RECORDS] += 1
            return 0
        assert compiled is not None
        width = len(compiled.slot_items)
        if -1 in walked[compiled.slot_items.index("010")::width]:
            self.stats.rejected[REJECT_NO_SOURCE] += 1
            return 0
        n = len(walked) // width
        spec = compiled.spec
        self.offsets.setdefault(spec, []).extend(walked)
        self.numbers.setdefault(spec, []).extend(range(self.n_reports, self.n_reports + n))
        self.captures.setdefault(spec, []).extend(
            [math.nan if capture_s is None else capture_s] * n)
        self.order.extend([category] * n)
        self.n_reports += n
        self.stats.blocks_decoded += 1
        self.stats.records[category] += n
        return n

    def finish(self) -> Decoded:
        """The columns of every record kept, in input order."""
        out = Decoded(stats=self.stats)
        out.order = np.asarray(self.order, dtype=np.int16)
        if not self.n_reports:
            return out
        buffer = np.frombuffer(b"".join(self.chunks), dtype=np.uint8)
        for category, specs in SPECS.items():
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
                 stats: DecodeStats) -> list[Report]:
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

    Returns
    -------
    list of report
        Empty for a skipped category or a rejected block.  All reports of a
        block are kept or none: a block with one bad record is rejected.
    """
    collector = _Collector(stats)
    base = collector.add_chunk(block)
    collector.block(category, block, 0, len(block), capture_s, base)
    return collector.finish().sequence


def _decode_into(collector: _Collector, data: bytes, capture_s: float | None) -> None:
    """Split ``data`` into blocks and walk them into ``collector``."""
    base = collector.add_chunk(data)
    for category, begin, stop in split_blocks(data, collector.stats):
        collector.block(category, data, begin, stop, capture_s, base)


def decode_payload(data: bytes, capture_s: float | None = None,
                   into: Decoded | None = None) -> Decoded:
    """Split a UDP payload or raw byte stream into blocks and decode them.

    Parameters
    ----------
    data : bytes
        Concatenated ASTERIX data blocks.
    capture_s : float or None, optional
        Capture time [unix s] given to every report.
    into : Decoded, optional
        Append to this result instead of a new one.

    Returns
    -------
    Decoded
        ``into`` or a new result.
    """
    collector = _Collector(DecodeStats())
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


def decode_bytes(data: bytes, *, progress: Callable[[int, int], None] | None = None
                 ) -> Decoded:
    """Decode a whole recording held in memory (raw blocks, pcap or pcapng).

    Parameters
    ----------
    data : bytes
        The file content; its format comes from its first bytes
        (:func:`detect_format`).
    progress : callable, optional
        Called as ``progress(bytes_done, bytes_total)`` now and then.

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
    collector = _Collector(stats)
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


def decode_file(path: str | Path, *, progress: Callable[[int, int], None] | None = None
                ) -> Decoded:
    """Decode an ASTERIX recording file (raw blocks, pcap or pcapng).

    Parameters
    ----------
    path : str or Path
        The recording.
    progress : callable, optional
        Called as ``progress(bytes_done, bytes_total)``.

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
        return decode_bytes(data, progress=progress)
    except AsterixError as exc:
        raise AsterixError(exc.detail, path=path) from None


def decode_files(paths: Iterable[str | Path], *,
                 progress: Callable[[int, int], None] | None = None) -> Decoded:
    """Decode several recordings, in the given order, into one result.

    ``progress`` is called as ``progress(bytes_done, bytes_total)`` over all files.
    """
    paths = [Path(p) for p in paths]
    sizes = [p.stat().st_size if p.is_file() else 0 for p in paths]
    total = sum(sizes)
    out = Decoded()
    done = 0
    for path, size in zip(paths, sizes, strict=True):
        def partial(n: int, _total: int, offset: int = done) -> None:
            if progress is not None:
                progress(offset + n, total)

        out.extend(decode_file(path, progress=partial))
        done += size
    return out
