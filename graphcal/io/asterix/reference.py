"""Read ASTERIX recordings: split byte streams into data blocks and decode records.

Inputs are either *raw* files (ASTERIX data blocks written back to back, as
recorded by most ATC tools) or packet captures (pcap or pcapng) of the UDP
datagrams that carry them.  Each data block is ``CAT`` (1 byte), ``LEN``
(2 bytes, big-endian, the length of the whole block in bytes) and the records.
A UDP payload may hold several data blocks.

Categories decoded (with the pure-Python decoder ``libasterix``, import name
``asterix``):

- CAT048 (monoradar target reports), edition 1.32,
- CAT021 (ADS-B target reports), edition 2.6 (a block that does not parse with
  it is tried with edition 0.26, still found in older recordings),
- CAT034 (monoradar service messages), edition 1.29.

Every other category is counted and skipped.  Only the items graphcal needs are
kept (:class:`Cat048Report`, :class:`Cat021Report`, :class:`Cat034Message`), in
the units of the ASTERIX specification; :mod:`graphcal.io.asterix.tables` turns
them into contract tables.

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
from asterix import generated as gen
from asterix.base import Bits

from graphcal.core.errors import GraphcalInputError


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


@dataclass
class Decoded:
    """Decoded reports, in input order, and the decode counts."""

    cat048: list[Cat048Report] = field(default_factory=list)
    cat021: list[Cat021Report] = field(default_factory=list)
    cat034: list[Cat034Message] = field(default_factory=list)
    #: Every report in input order (the time base is built from this sequence).
    sequence: list[Report] = field(default_factory=list)
    stats: DecodeStats = field(default_factory=DecodeStats)

    def add(self, report: Report) -> None:
        """Append one report to its category list and to :attr:`sequence`."""
        if isinstance(report, Cat048Report):
            self.cat048.append(report)
        elif isinstance(report, Cat021Report):
            self.cat021.append(report)
        else:
            self.cat034.append(report)
        self.sequence.append(report)

    def extend(self, other: Decoded) -> None:
        """Append the reports and counts of ``other``."""
        for report in other.sequence:
            self.add(report)
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


# --------------------------------------------------------------------------- item access


def _sub(item: Any, name: str) -> Any:
    """Subitem ``name`` of a group/extended item's variation, or ``None``."""
    sub = item.variation.get_item(name)
    return None if sub is None else sub.variation.content


def _quantity(record: Any, name: str, unit: str) -> float | None:
    """Physical value of an element item in ``unit``, or ``None`` when absent."""
    item = record.get_item(name)
    if item is None:
        return None
    value = float(item.variation.content.as_quantity(unit))
    return value if math.isfinite(value) else None


def _uint(record: Any, name: str) -> int | None:
    """Raw unsigned value of an element item, or ``None`` when absent."""
    item = record.get_item(name)
    return None if item is None else int(item.variation.content.as_uint())


def _source(record: Any) -> tuple[int, int] | None:
    """``(SAC, SIC)`` of I010, or ``None`` when absent."""
    item = record.get_item("010")
    if item is None:
        return None
    return int(_sub(item, "SAC").as_uint()), int(_sub(item, "SIC").as_uint())


def _text(record: Any, name: str) -> str | None:
    """A string item with blanks removed; ``None`` when absent or empty."""
    item = record.get_item(name)
    if item is None:
        return None
    text = item.variation.content.as_string().strip()
    return text or None


def _cat048(record: Any, capture_s: float | None) -> Cat048Report | None:
    source = _source(record)
    if source is None:
        return None
    rho = theta = None
    i040 = record.get_item("040")
    if i040 is not None:
        rho = float(_sub(i040, "RHO").as_quantity("NM"))
        theta = float(_sub(i040, "THETA").as_quantity("°"))
    flight_level = None
    i090 = record.get_item("090")
    if i090 is not None and _sub(i090, "V").as_uint() == 0 and _sub(i090, "G").as_uint() == 0:
        flight_level = float(_sub(i090, "FL").as_quantity("FL"))
    return Cat048Report(
        sac=source[0], sic=source[1],
        time_of_day_s=_quantity(record, "140", "s"),
        rho_nm=rho, theta_deg=theta,
        address=_uint(record, "220"),
        flight_level=flight_level,
        callsign=_text(record, "240"),
        capture_s=capture_s,
    )


def _cat021_quality(record: Any) -> tuple[int | None, int | None]:
    """``(NACp, NUCp/NIC)`` from I021/090 of edition 2 (``None`` where absent)."""
    item = record.get_item("090")
    if item is None or not hasattr(item.variation, "get_item"):
        return None, None
    variation = item.variation
    nucp = variation.get_item("NUCPNIC")
    nacp = variation.get_item("NACP")
    return (
        None if nacp is None else int(nacp.variation.content.as_uint()),
        None if nucp is None else int(nucp.variation.content.as_uint()),
    )


def _cat021(record: Any, edition: tuple[int, int], capture_s: float | None
            ) -> Cat021Report | None:
    source = _source(record)
    if source is None:
        return None
    lat = lon = None
    position = record.get_item("131") if edition[0] >= 2 else None
    if position is None:
        position = record.get_item("130")
    if position is not None:
        lat = float(_sub(position, "LAT").as_quantity("°"))
        lon = float(_sub(position, "LON").as_quantity("°"))
    if edition[0] >= 2:
        t_position = _quantity(record, "071", "s")
        t_reception = _quantity(record, "073", "s")
        t_report = _quantity(record, "077", "s")
        nacp, nucp = _cat021_quality(record)
        i210 = record.get_item("210")
        version = None if i210 is None else int(_sub(i210, "VN").as_uint())
    else:
        t_position, t_reception, t_report = _quantity(record, "030", "s"), None, None
        nacp = nucp = version = None
    return Cat021Report(
        sac=source[0], sic=source[1],
        time_position_s=t_position, time_reception_s=t_reception, time_report_s=t_report,
        address=_uint(record, "080"),
        lat_deg=lat, lon_deg=lon,
        geo_height_ft=_quantity(record, "140", "ft"),
        nacp=nacp, nucp=nucp, mops_version=version,
        capture_s=capture_s,
        flight_level=_quantity(record, "145", "FL"),
    )


def _cat034(record: Any, capture_s: float | None) -> Cat034Message | None:
    source = _source(record)
    if source is None:
        return None
    lat = lon = height = None
    i120 = record.get_item("120")
    if i120 is not None:
        height = float(_sub(i120, "HGT").as_quantity("m"))
        lat = float(_sub(i120, "LAT").as_quantity("°"))
        lon = float(_sub(i120, "LON").as_quantity("°"))
    return Cat034Message(
        sac=source[0], sic=source[1],
        message_type=_uint(record, "000"),
        time_of_day_s=_quantity(record, "030", "s"),
        lat_deg=lat, lon_deg=lon, height_m=height,
        capture_s=capture_s,
    )


def _parse_records(category: int, body: bytes) -> tuple[Any, list[Any]] | None:
    """Parse the records of a block body with the first specification that accepts
    all of it; ``None`` when none does."""
    bits = Bits.from_bytes(body)
    for spec in SPECS[category]:
        records = spec.cv_uap.parse(bits)
        if not isinstance(records, ValueError) and records:
            return spec, records
    return None


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
    if category not in SPECS:
        stats.skipped_categories[category] += 1
        return []
    try:
        parsed = _parse_records(category, block[HEADER_BYTES:])
        if parsed is None:
            stats.rejected[REJECT_RECORDS] += 1
            return []
        spec, records = parsed
        reports: list[Report] = []
        for record in records:
            if category == 48:
                report: Report | None = _cat048(record, capture_s)
            elif category == 21:
                report = _cat021(record, spec.cv_edition, capture_s)
            else:
                report = _cat034(record, capture_s)
            if report is None:
                stats.rejected[REJECT_NO_SOURCE] += 1
                return []
            reports.append(report)
    except Exception:  # noqa: BLE001 - any decoder failure rejects the block, never the run
        stats.rejected[REJECT_DECODER] += 1
        return []
    stats.blocks_decoded += 1
    stats.records[category] += len(reports)
    return reports


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
    out = Decoded() if into is None else into
    for category, begin, stop in split_blocks(data, out.stats):
        for report in decode_block(category, data[begin:stop], capture_s, out.stats):
            out.add(report)
    return out


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
    out = Decoded()
    out.stats.files = 1
    total = len(data)
    kind = detect_format(data[:12])
    if kind == "raw":
        step = max(1 << 16, total // 500)
        next_report = step
        for category, begin, stop in split_blocks(data, out.stats):
            for report in decode_block(category, data[begin:stop], None, out.stats):
                out.add(report)
            if progress is not None and stop >= next_report:
                progress(stop, total)
                next_report = stop + step
    else:
        stream = io.BytesIO(data)
        for n, (timestamp, payload) in enumerate(_packets(stream, kind, out.stats)):
            decode_payload(payload, timestamp, into=out)
            if progress is not None and n % 200 == 0:
                progress(stream.tell(), total)
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
