"""The reference ASTERIX record decoder: ``libasterix``'s generic parser, item by item.

This is how graphcal decoded records before :mod:`graphcal.io.asterix.decode`
walked them with compiled byte layouts and extracted fields with numpy.  It is
slow (about 2,000 CAT048 records per second) and kept as a second, independent
reading of the same bytes: the tests decode random and mutated recordings with
both and require the same reports and the same rejection counts, and
``benchmarks/bench_asterix.py`` times both.

Only raw byte streams (data blocks back to back) are read here; block splitting
and the report types are those of :mod:`graphcal.io.asterix.decode`.  The CAT021
edition of a block is chosen by the same rule (that module's docstring, "Choosing
the CAT021 edition"), here judged on the items ``libasterix`` parsed.
"""

from __future__ import annotations

import math
from typing import Any

from asterix.base import Bits

from graphcal.io.asterix.decode import (
    CAT021_AUTO,
    FLIGHT_LEVEL_RANGE_FL,
    GEO_HEIGHT_RANGE_FT,
    GRADE_NO_SOURCE,
    GRADE_PLAUSIBLE,
    GRADE_SOURCE,
    HEADER_BYTES,
    MAX_TIME_OF_DAY_S,
    REJECT_DECODER,
    REJECT_NO_SOURCE,
    REJECT_RECORDS,
    Cat021Report,
    Cat034Message,
    Cat048Report,
    DecodeStats,
    Report,
    decoder_specs,
    edition_name,
    split_blocks,
)


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


def _height(record: Any) -> float | None:
    """I048/110 3-D height [ft], or ``None``."""
    item = record.get_item("110")
    return None if item is None else float(_sub(item, "3DH").as_quantity("ft"))


def _mode_3a(record: Any) -> int | None:
    """The Mode 3/A code of I070 as its 12-bit integer, or ``None`` when absent or, when
    the item has validity bits, not validated (V=1) or garbled (G=1)."""
    item = record.get_item("070")
    if item is None:
        return None
    names = {entry.cv_non_spare.cv_name for entry, _ in item.variation.cv_items_list
             if hasattr(entry, "cv_non_spare")}
    if any(int(_sub(item, bit).as_uint()) for bit in ("V", "G") if bit in names):
        return None
    return int(_sub(item, "MODE3A").as_uint())


def _track_number(record: Any) -> int | None:
    """I048/161 track number, or ``None`` when absent."""
    item = record.get_item("161")
    return None if item is None else int(_sub(item, "TRN").as_uint())


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
        height_ft=_height(record),
        mode_3a=_mode_3a(record),
        track_number=_track_number(record),
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
        mode_3a=_mode_3a(record),
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


def _plausible_021(record: Any, edition: tuple[int, int]) -> bool:
    """A CAT021 record with a target address and a time of day, all its times below
    86401 s, its positions within +-90 / +-180 deg and its heights within the ranges
    of the specification (I010 is checked by the caller)."""
    if record.get_item("080") is None:
        return False
    names = ("071", "073", "077") if edition[0] >= 2 else ("030",)
    times = [record.get_item(name) for name in names]
    times = [float(t.variation.content.as_quantity("s")) for t in times if t is not None]
    if not times or not all(t < MAX_TIME_OF_DAY_S for t in times):
        return False
    for name in ("131", "130") if edition[0] >= 2 else ("130",):
        item = record.get_item(name)
        if item is not None and not (
                abs(float(_sub(item, "LAT").as_quantity("°"))) <= 90.0
                and abs(float(_sub(item, "LON").as_quantity("°"))) <= 180.0):
            return False
    for name, unit, (low, high) in (("140", "ft", GEO_HEIGHT_RANGE_FT),
                                    ("145", "FL", FLIGHT_LEVEL_RANGE_FL)):
        item = record.get_item(name)
        if item is not None and not low <= float(item.variation.content.as_quantity(unit)) <= high:
            return False
    return True


def _grade(category: int, spec: Any, records: list[Any]) -> int:
    """How plausible a block's records are under ``spec`` (``GRADE_*``)."""
    if any(record.get_item("010") is None for record in records):
        return GRADE_NO_SOURCE
    if category == 21 and not all(_plausible_021(r, spec.cv_edition) for r in records):
        return GRADE_SOURCE
    return GRADE_PLAUSIBLE


def _parse_records(category: int, body: bytes, specs: tuple[Any, ...]
                   ) -> tuple[Any, list[Any], int] | None:
    """Parse the records of a block body with each specification in turn; the first
    that accepts all of it with the best grade, and that grade.

    Returns ``None`` when none accepts it.

    Raises
    ------
    Exception
        The last ``libasterix`` failure when none accepts it and one failed.
    """
    bits = Bits.from_bytes(body)
    best: tuple[Any, list[Any], int] | None = None
    failure: Exception | None = None
    for spec in specs:
        try:
            records = spec.cv_uap.parse(bits)
        except Exception as exc:  # noqa: BLE001 - another edition may parse it
            failure = exc
            continue
        if isinstance(records, ValueError) or not records:
            continue
        grade = _grade(category, spec, records)
        if best is None or grade > best[2]:
            best = spec, records, grade
            if grade == GRADE_PLAUSIBLE:
                break
    if best is None and failure is not None:
        raise failure
    return best


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
        ``"auto"`` (default) or a CAT021 edition to force.

    Returns
    -------
    list of report
        Empty for a skipped category or a rejected block.  All reports of a
        block are kept or none: a block with one bad record is rejected.
    """
    specs = decoder_specs(cat021_edition).get(category)
    if specs is None:
        stats.skipped_categories[category] += 1
        return []
    try:
        parsed = _parse_records(category, block[HEADER_BYTES:], specs)
        if parsed is None:
            stats.rejected[REJECT_RECORDS] += 1
            return []
        spec, records, _grade_of_block = parsed
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
    stats.editions[category, edition_name(spec)] += 1
    return reports


def decode_payload(data: bytes, capture_s: float | None = None, *,
                   cat021_edition: str = CAT021_AUTO) -> tuple[list[Report], DecodeStats]:
    """Split a raw byte stream into blocks and decode them with ``libasterix``.

    Parameters
    ----------
    data : bytes
        Concatenated ASTERIX data blocks.
    capture_s : float or None, optional
        Capture time [unix s] given to every report.
    cat021_edition : str, optional
        ``"auto"`` (default) or a CAT021 edition to force.

    Returns
    -------
    reports : list of report
        In input order.
    stats : DecodeStats
        The counts, as :func:`graphcal.io.asterix.decode.decode_payload` gives them.
    """
    stats = DecodeStats()
    reports: list[Report] = []
    for category, begin, stop in split_blocks(data, stats):
        reports += decode_block(category, data[begin:stop], capture_s, stats,
                                cat021_edition=cat021_edition)
    return reports, stats
