"""A calibration in the terms of ASTERIX CAT063 (Sensor Status Messages), ed. 1.7.

CAT063 carries, per sensor (I063/050 Sensor Identifier, SAC/SIC), the
registration biases an SDPS has estimated.  The items, as defined in the
edition's specification (``asterix.generated.Cat_063_1_7`` of ``libasterix``,
and the CAT063 definition of the asterix-specs project, items I063/070..092):

==========  =====  ==================================  ======  ============  ======
item        field  meaning                             bits    LSB           unit
==========  =====  ==================================  ======  ============  ======
I063/070    -      time stamping bias                  16 s    1             ms
I063/080    SRG    SSR / Mode S range gain             16 s    1e-5          (none)
I063/080    SRB    SSR / Mode S range bias             16 s    1/128         NM
I063/081    -      SSR / Mode S azimuth bias           16 s    360/2^16      deg
I063/090    PRG    PSR range gain                      16 s    1e-5          (none)
I063/090    PRB    PSR range bias                      16 s    1/128         NM
I063/091    -      PSR azimuth bias                    16 s    360/2^16      deg
I063/092    -      PSR elevation bias                  16 s    360/2^16      deg
==========  =====  ==================================  ======  ============  ======

("16 s": 16-bit two's complement; "-": the item is one element.)  Ranges: time
bias +-32.767 s, gains +-0.32767, range biases -256 .. +255.99 NM, angles -180 .. +179.995 deg.

Sign convention
---------------
The specification's notes give the correction each item is meant for:

* I063/080 and I063/090: ``rho_corrected = (rho_measured - range_bias) / (1 + range_gain)``,
  i.e. ``rho_measured = (1 + range_gain) * rho_true + range_bias``;
* I063/081 and I063/091: ``theta_corrected = theta_measured - azimuth_bias``.

This is graphcal's bias model (CONTRACT.md, "measured minus true") term for
term, so the CAT063 values are the contract values in the standard's units,
with the same sign:

* range bias [NM] = ``range_offset_m / 1852``;
* range gain = ``range_gain`` (a plain fraction in both: 1e-5 is 10 ppm);
* azimuth bias [deg] = ``azimuth_bias_mrad * 1e-3 * 180 / pi``;
* elevation bias [deg] (I063/092) = ``elevation_bias_mrad * 1e-3 * 180 / pi``;
* time stamping bias [ms] = ``time_offset_s * 1000``.

The specification gives no formula for I063/070 and I063/092; they are taken
with the same convention as the other biases (value = measured or reported
minus true; corrected = measured minus bias), which matches the contract's
``time_reported = time_true + time_offset_s`` and elevation model.

Which items a radar uses depends on its kind: ``"ssr"`` (default) gives
I063/080 and I063/081, ``"psr"`` I063/090 and I063/091.  The elevation bias
of a 3-D radar always goes to I063/092, the only elevation item.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import asterix.generated as gen
import pandas as pd

from graphcal.core.atomic import atomic_write_table, atomic_write_text
from graphcal.data.calibration import Calibration
from graphcal.io.asterix.encode import AsterixEncodeError, resolve_radar_codes, time_of_day_count

#: CAT063 edition used: Sensor Status Messages, ed. 1.7.
CAT063 = gen.Cat_063_1_7
#: Name of the standard and edition, as written to files.
STANDARD = "ASTERIX CAT063 ed. 1.7"

RadarKind = Literal["ssr", "psr"]
_DEG_PER_MRAD = 1e-3 * 180.0 / math.pi


@dataclass(frozen=True)
class Cat063Field:
    """One CAT063 quantity and how it maps from a contract key.

    Attributes
    ----------
    name : str
        Field name in the records (``time_stamping_bias``, ``range_gain``,
        ``range_bias``, ``azimuth_bias``, ``elevation_bias``).
    item : str
        Data item, e.g. ``I063/080``.
    subfield : str or None
        Subfield of a group item (``SRG``, ``SRB``, ``PRG``, ``PRB``), else ``None``.
    contract_key : str
        Contract key of the value (``range_offset_m``, ...).
    unit : str
        Unit of the standard (``ms``, ``NM``, ``deg``, ``""`` for a fraction).
    lsb : float
        Value of one count, in ``unit``.
    scale : float
        Factor from the contract unit to ``unit``.
    bits : int
        Width of the two's-complement field.
    """

    name: str
    item: str
    subfield: str | None
    contract_key: str
    unit: str
    lsb: float
    scale: float
    bits: int = 16

    @property
    def count_range(self) -> tuple[int, int]:
        """Smallest and largest count of the signed field."""
        half = 1 << (self.bits - 1)
        return -half, half - 1


_ANGLE_LSB = 360.0 / 2**16
_RANGE_BIAS_LSB = 1.0 / 128.0
_GAIN_LSB = 1e-5

_TIME = Cat063Field("time_stamping_bias", "I063/070", None, "time_offset_s", "ms", 1.0, 1e3)
_ELEVATION = Cat063Field("elevation_bias", "I063/092", None, "elevation_bias_mrad", "deg",
                         _ANGLE_LSB, _DEG_PER_MRAD)

#: The CAT063 fields of each radar kind, in record order.
FIELDS: dict[str, tuple[Cat063Field, ...]] = {
    "ssr": (
        _TIME,
        Cat063Field("range_gain", "I063/080", "SRG", "range_gain", "", _GAIN_LSB, 1.0),
        Cat063Field("range_bias", "I063/080", "SRB", "range_offset_m", "NM", _RANGE_BIAS_LSB,
                    1.0 / 1852.0),
        Cat063Field("azimuth_bias", "I063/081", None, "azimuth_bias_mrad", "deg", _ANGLE_LSB,
                    _DEG_PER_MRAD),
        _ELEVATION,
    ),
    "psr": (
        _TIME,
        Cat063Field("range_gain", "I063/090", "PRG", "range_gain", "", _GAIN_LSB, 1.0),
        Cat063Field("range_bias", "I063/090", "PRB", "range_offset_m", "NM", _RANGE_BIAS_LSB,
                    1.0 / 1852.0),
        Cat063Field("azimuth_bias", "I063/091", None, "azimuth_bias_mrad", "deg", _ANGLE_LSB,
                    _DEG_PER_MRAD),
        _ELEVATION,
    ),
}

#: Plain-language statement of the sign convention, written to the JSON file.
CONVENTION = (
    "CAT063 biases are measured minus true, as in graphcal's contract: "
    "rho_corrected = (rho_measured - range_bias) / (1 + range_gain) (I063/080, I063/090), "
    "theta_corrected = theta_measured - azimuth_bias (I063/081, I063/091); the time "
    "stamping bias (I063/070) is reported minus true time and the elevation bias (I063/092) "
    "measured minus true elevation. value = count * lsb, in unit."
)

_CSV_COLUMNS = (
    "radar_id", "sac", "sic", "kind", "field", "item", "subfield", "unit", "lsb", "value",
    "count", "sigma", "in_range", "contract_key", "contract_value", "contract_sigma",
)


def _finite(value: Any) -> float | None:
    """A finite float, else ``None``."""
    if value is None or isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


def _contract_values(
    calibration: Calibration | Mapping[str, Any],
) -> dict[str, dict[str, tuple[float | None, float | None]]]:
    """``radar -> contract key -> (value, sigma)`` from a Calibration or a result dict."""
    keys = {f.contract_key for f in FIELDS["ssr"]}
    out: dict[str, dict[str, tuple[float | None, float | None]]] = {}
    if isinstance(calibration, Calibration):
        for rid in calibration.radar_ids:
            out[rid] = {key: (_finite(calibration.value(rid, key)),
                              _finite(calibration.sigma(rid, key))) for key in keys}
        return out
    radars = calibration.get("radars") if isinstance(calibration, Mapping) else None
    if not isinstance(radars, Mapping):
        raise ValueError("not a calibration: expected a Calibration or a result dict with "
                         "a 'radars' object")
    for rid, entry in radars.items():
        entry = entry if isinstance(entry, Mapping) else {}
        fixed = entry.get("fixed") if isinstance(entry.get("fixed"), Mapping) else {}
        sigma = entry.get("sigma") if isinstance(entry.get("sigma"), Mapping) else {}
        values = {}
        for key in keys:
            value = _finite(entry.get(key))
            if value is None:
                value = _finite(fixed.get(key))
            values[key] = (value, _finite(sigma.get(key)))
        out[str(rid)] = values
    return out


def _field_entry(spec: Cat063Field, value: float | None, sigma: float | None) -> dict[str, Any]:
    """One field of a record: value, count, LSB, sigma and the range flag."""
    entry: dict[str, Any] = {
        "item": spec.item,
        "subfield": spec.subfield,
        "unit": spec.unit,
        "lsb": spec.lsb,
        "value": None,
        "count": None,
        "sigma": None if sigma is None else sigma * spec.scale,
        "in_range": None,
        "contract_key": spec.contract_key,
        "contract_value": value,
        "contract_sigma": sigma,
    }
    if value is not None:
        count = round(value * spec.scale / spec.lsb)
        low, high = spec.count_range
        # The value the item carries: exactly count x LSB (what a receiver decodes).
        entry.update(value=count * spec.lsb, count=count, in_range=bool(low <= count <= high))
    return entry


def cat063_records(
    calibration: Calibration | Mapping[str, Any],
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    radar_kinds: Mapping[str, RadarKind] | None = None,
) -> list[dict[str, Any]]:
    """One CAT063 sensor record per radar, in the standard's units and counts.

    Parameters
    ----------
    calibration : Calibration or mapping
        A calibration, or a parsed result JSON (``calibrate --out``, or a
        simulation's ``truth.json``: values and ``sigma`` in contract units).
    radar_codes : mapping, optional
        ``radar_id -> (SAC, SIC)``; radars missing here must be named like
        ``SAC025_SIC201``.
    radar_kinds : mapping, optional
        ``radar_id -> "ssr" | "psr"``: selects I063/080-081 or I063/090-091.
        Default ``"ssr"``.

    Returns
    -------
    list of dict
        Per radar: ``radar_id``, ``sac``, ``sic``, ``kind`` and ``fields``, a
        dict by field name (``time_stamping_bias``, ``range_gain``,
        ``range_bias``, ``azimuth_bias``, ``elevation_bias``) of: ``item``,
        ``subfield``, ``unit``, ``lsb``, ``value`` (standard units, sign as
        in the module docstring, quantised: exactly ``count * lsb``, the value
        the binary item carries), ``count`` (the contract value in the standard's
        unit divided by ``lsb``, rounded; not wrapped), ``sigma`` (1-sigma in
        the same unit, not quantised), ``in_range`` (whether ``count`` fits
        the item), and the contract's ``contract_key``, ``contract_value``,
        ``contract_sigma``.  A quantity the calibration
        does not give has ``value``, ``count``, ``sigma`` and ``in_range``
        ``None``.

    Raises
    ------
    AsterixEncodeError
        A radar without SAC/SIC (the message says how to give it).
    ValueError
        An unknown radar kind, or a kind for an unknown radar.
    """
    values = _contract_values(calibration)
    codes = resolve_radar_codes(values, radar_codes)
    kinds = dict(radar_kinds or {})
    unknown = sorted(set(kinds) - set(values))
    if unknown:
        raise ValueError(f"radar_kinds names radars not in the calibration: {', '.join(unknown)}")
    records = []
    for rid, radar_values in values.items():
        kind = kinds.get(rid, "ssr")
        if kind not in FIELDS:
            raise ValueError(f"radar {rid!r}: kind must be 'ssr' or 'psr', not {kind!r}")
        sac, sic = codes[rid]
        fields = {spec.name: _field_entry(spec, *radar_values[spec.contract_key])
                  for spec in FIELDS[kind]}
        records.append({"radar_id": rid, "sac": sac, "sic": sic, "kind": kind, "fields": fields})
    return records


def out_of_range(records: Sequence[Mapping[str, Any]]) -> list[str]:
    """``"RADAR field"`` for every field whose count does not fit its item."""
    return [f"{r['radar_id']} {name}" for r in records for name, f in r["fields"].items()
            if f["in_range"] is False]


def cat063_table(records: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """The records as a table, one row per radar and field (the CSV layout)."""
    rows = []
    for record in records:
        for name, entry in record["fields"].items():
            rows.append({
                "radar_id": record["radar_id"], "sac": record["sac"], "sic": record["sic"],
                "kind": record["kind"], "field": name,
                **{key: entry[key] for key in _CSV_COLUMNS if key in entry},
            })
    table = pd.DataFrame(rows, columns=list(_CSV_COLUMNS))
    table["count"] = table["count"].astype("Int64")
    table["in_range"] = table["in_range"].astype("boolean")
    return table


def write_cat063_json(
    path: str | Path,
    calibration: Calibration | Mapping[str, Any],
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    radar_kinds: Mapping[str, RadarKind] | None = None,
) -> list[dict[str, Any]]:
    """Write :func:`cat063_records` as JSON, atomically.

    The file is ``{"standard", "convention", "records"}``; missing values
    are ``null``.

    Returns
    -------
    list of dict
        The records written.
    """
    records = cat063_records(calibration, radar_codes, radar_kinds)
    document = {"standard": STANDARD, "convention": CONVENTION, "records": records}
    atomic_write_text(path, json.dumps(document, indent=2, allow_nan=False) + "\n")
    return records


def write_cat063_csv(
    path: str | Path,
    calibration: Calibration | Mapping[str, Any],
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    radar_kinds: Mapping[str, RadarKind] | None = None,
) -> list[dict[str, Any]]:
    """Write :func:`cat063_records` as CSV (:func:`cat063_table`), atomically.

    Empty cells are missing values.

    Returns
    -------
    list of dict
        The records written.
    """
    path = Path(path)
    if path.suffix != ".csv":
        raise ValueError(f"{path}: expected a .csv file name")
    records = cat063_records(calibration, radar_codes, radar_kinds)
    atomic_write_table(cat063_table(records), path)
    return records


def _raw(count: int | None, bits: int = 16) -> int:
    """A signed count as the raw bits of a two's-complement field (``None`` -> 0)."""
    return 0 if count is None else count & ((1 << bits) - 1)


def encode_cat063(
    calibration: Calibration | Mapping[str, Any],
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    radar_kinds: Mapping[str, RadarKind] | None = None,
    *,
    source: tuple[int, int] = (0, 0),
    service_id: int = 1,
    time_s: float = 0.0,
    day_start_s: float = 0.0,
) -> bytes:
    """Encode the calibration as one CAT063 data block (one record per radar).

    Each record has I063/010 (``source``, the calibration service), I063/015
    (``service_id``), I063/030 (time of message, LSB 1/128 s), I063/050 (the
    radar's SAC/SIC) and the bias items it has values for (module docstring).
    In a group item (I063/080, I063/090) a missing gain or bias is sent as 0;
    the item is left out when both are missing.

    Parameters
    ----------
    calibration, radar_codes, radar_kinds
        As for :func:`cat063_records`.
    source : tuple of int, optional
        SAC/SIC of the calibration service.
    service_id : int, optional
        Service identification, 0..255.
    time_s : float, optional
        Time of the message on the dataset's time base [s].
    day_start_s : float, optional
        Value of ``time_s`` at the midnight that starts the day [s].

    Returns
    -------
    bytes
        The data block.

    Raises
    ------
    AsterixEncodeError
        Missing SAC/SIC, a bad ``source``/``service_id``, or a value outside
        its item's range (named; nothing is wrapped).
    """
    records = cat063_records(calibration, radar_codes, radar_kinds)
    bad = out_of_range(records)
    if bad:
        raise AsterixEncodeError(f"values outside the range of their CAT063 item: {', '.join(bad)}")
    sac, sic = (int(v) for v in source)
    if not (0 <= sac <= 255 and 0 <= sic <= 255 and 0 <= int(service_id) <= 255):
        raise AsterixEncodeError("source SAC/SIC and service_id must be within 0..255")
    tod = time_of_day_count(time_s, day_start_s)
    out = []
    for record in records:
        items: dict[str, Any] = {
            "010": (("SAC", sac), ("SIC", sic)),
            "015": int(service_id),
            "030": tod,
            "050": (("SAC", record["sac"]), ("SIC", record["sic"])),
        }
        groups: dict[str, dict[str, int | None]] = {}
        for entry in record["fields"].values():
            item = entry["item"].removeprefix("I063/")
            if entry["subfield"] is not None:
                groups.setdefault(item, {})[entry["subfield"]] = entry["count"]
            elif entry["count"] is not None:
                items[item] = _raw(entry["count"])
        for item, parts in groups.items():
            if any(count is not None for count in parts.values()):
                items[item] = tuple((name, _raw(count)) for name, count in parts.items())
        out.append(CAT063.cv_record.create(items))
    return CAT063.create(out).unparse().to_bytes()


#: ``write_cat063`` file suffixes: JSON, CSV, or a binary CAT063 data block.
CAT063_SUFFIXES: tuple[str, ...] = (".json", ".csv", ".ast", ".bin")


def radar_codes_for(
    radar_ids: Iterable[str],
    site_codes: Mapping[str, Sequence[int]] | None = None,
    given: Mapping[str, Sequence[int]] | None = None,
) -> dict[str, tuple[int, int]]:
    """SAC/SIC of every radar for a CAT063 export, or an error naming all that lack one.

    Parameters
    ----------
    radar_ids : iterable of str
        Radars to export.
    site_codes : mapping, optional
        ``radar_id -> (SAC, SIC)`` from ``sites.toml`` (``sac``/``sic`` keys).
    given : mapping, optional
        ``radar_id -> (SAC, SIC)`` given explicitly (``--sac-sic``); wins over
        ``site_codes``.  Radars in neither must be named like ``SAC025_SIC201``.

    Returns
    -------
    dict
        ``radar_id -> (SAC, SIC)``.

    Raises
    ------
    AsterixEncodeError
        Radars without a code (all named), a code outside 0..255, two radars with
        the same code, or ``given`` naming an unknown radar.
    """
    from graphcal.io.asterix.encode import radar_sac_sic

    radar_ids = list(radar_ids)
    given = dict(given or {})
    unknown = sorted(set(given) - set(radar_ids))
    if unknown:
        raise AsterixEncodeError(f"SAC/SIC given for radars not in the dataset: "
                                 f"{', '.join(unknown)} (radars: {', '.join(radar_ids)})")
    codes = {**dict(site_codes or {}), **given}
    missing = [rid for rid in radar_ids if rid not in codes and radar_sac_sic(rid) is None]
    if missing:
        raise AsterixEncodeError(
            f"{len(missing)} radar{'s' if len(missing) > 1 else ''} without a SAC/SIC for the "
            f"CAT063 export: {', '.join(missing)}; give sac and sic in their sites.toml "
            f"tables or --sac-sic RADAR=SAC/SIC (e.g. --sac-sic {missing[0]}=25/201)")
    return resolve_radar_codes(radar_ids, {rid: codes[rid] for rid in radar_ids if rid in codes})


def radar_kinds_from_sites(sites: Mapping[str, Any]) -> dict[str, RadarKind]:
    """``"psr"`` for a radar whose sensor model is a primary radar (``psr-*``) or which is
    3-D, else ``"ssr"`` (``sites``: :class:`graphcal.data.dataset.Site` by radar id)."""
    kinds: dict[str, RadarKind] = {}
    for rid, site in sites.items():
        model = str(getattr(site, "model", "") or "")
        primary = model.startswith("psr") or bool(getattr(site, "is_3d", False))
        kinds[rid] = "psr" if primary else "ssr"
    return kinds


def write_cat063(
    path: str | Path,
    calibration: Calibration | Mapping[str, Any],
    radar_codes: Mapping[str, Sequence[int]] | None = None,
    radar_kinds: Mapping[str, RadarKind] | None = None,
) -> None:
    """Write the CAT063 export in the format its suffix names (:data:`CAT063_SUFFIXES`).

    ``.json`` and ``.csv``: :func:`write_cat063_json`, :func:`write_cat063_csv`;
    ``.ast`` or ``.bin``: one binary CAT063 data block (:func:`encode_cat063`).
    Written atomically.
    """
    from graphcal.core.atomic import atomic_write_stream

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CAT063_SUFFIXES:
        raise ValueError(
            f"{path}: a CAT063 export must end in {', '.join(CAT063_SUFFIXES)}"
        )
    if suffix == ".json":
        write_cat063_json(path, calibration, radar_codes, radar_kinds)
    elif suffix == ".csv":
        write_cat063_csv(path, calibration, radar_codes, radar_kinds)
    else:
        data = encode_cat063(calibration, radar_codes, radar_kinds)
        atomic_write_stream(path, lambda stream: stream.write(data))
