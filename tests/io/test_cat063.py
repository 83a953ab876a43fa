"""Export of a calibration in CAT063 terms: units, counts, signs, files and binary."""

from __future__ import annotations

import json
import math
from pathlib import Path

import asterix.generated as gen
import pandas as pd
import pytest
from asterix.base import Bits, RawDatablock

from graphcal.data.calibration import Calibration
from graphcal.io.asterix.cat063 import (
    cat063_records,
    encode_cat063,
    write_cat063_csv,
    write_cat063_json,
)
from graphcal.io.asterix.encode import AsterixEncodeError

DEG_PER_MRAD = 180.0 / math.pi / 1000.0

RESULT = {
    "method": "graph",
    "radars": {
        "SAC025_SIC201": {
            "range_offset_m": -93.7, "range_gain": 0.000694, "azimuth_bias_mrad": -3.10,
            "elevation_bias_mrad": None, "time_offset_s": 0.125,
            "sigma": {"range_offset_m": 0.9, "range_gain": 7.5e-6, "azimuth_bias_mrad": 0.02,
                      "time_offset_s": 0.004},
            "n_plots": 100,
        },
        "DOLE": {
            "range_offset_m": 250.0, "range_gain": -0.0012, "azimuth_bias_mrad": 5.5,
            "elevation_bias_mrad": -1.2,
            "sigma": {"range_offset_m": 2.0, "range_gain": 1e-5, "azimuth_bias_mrad": 0.05,
                      "elevation_bias_mrad": 0.1},
            "n_plots": 50,
        },
    },
    "covariance": {
        "labels": [
            "SAC025_SIC201.range_offset_m", "SAC025_SIC201.range_gain",
            "SAC025_SIC201.azimuth_bias_mrad", "SAC025_SIC201.time_offset_s",
            "DOLE.range_offset_m", "DOLE.range_gain", "DOLE.azimuth_bias_mrad",
            "DOLE.elevation_bias_mrad",
        ],
        "matrix": [[0.0] * 8 for _ in range(8)],
    },
}
for i, s in enumerate([0.9, 7.5e-6, 0.02, 0.004, 2.0, 1e-5, 0.05, 0.1]):
    RESULT["covariance"]["matrix"][i][i] = s * s

CODES = {"DOLE": (7, 42)}
KINDS = {"DOLE": "psr"}


def by_radar(records: list[dict]) -> dict[str, dict]:
    return {r["radar_id"]: r for r in records}


@pytest.mark.parametrize("source", ["calibration", "dict"])
def test_counts_times_lsb_reproduce_the_values_with_the_contract_sign(source: str) -> None:
    calibration = Calibration.from_dict(RESULT) if source == "calibration" else RESULT
    records = by_radar(cat063_records(calibration, CODES, KINDS))
    ssr, psr = records["SAC025_SIC201"], records["DOLE"]
    assert (ssr["sac"], ssr["sic"], ssr["kind"]) == (25, 201, "ssr")
    assert (psr["sac"], psr["sic"], psr["kind"]) == (7, 42, "psr")

    expected = {
        "SAC025_SIC201": {
            "range_bias": ("I063/080", "SRB", -93.7 / 1852.0, 0.9 / 1852.0),
            "range_gain": ("I063/080", "SRG", 0.000694, 7.5e-6),
            "azimuth_bias": ("I063/081", None, -3.10 * DEG_PER_MRAD, 0.02 * DEG_PER_MRAD),
            "time_stamping_bias": ("I063/070", None, 125.0, 4.0),
        },
        "DOLE": {
            "range_bias": ("I063/090", "PRB", 250.0 / 1852.0, 2.0 / 1852.0),
            "range_gain": ("I063/090", "PRG", -0.0012, 1e-5),
            "azimuth_bias": ("I063/091", None, 5.5 * DEG_PER_MRAD, 0.05 * DEG_PER_MRAD),
            "elevation_bias": ("I063/092", None, -1.2 * DEG_PER_MRAD, 0.1 * DEG_PER_MRAD),
        },
    }
    for rid, fields in expected.items():
        for name, (item, subfield, value, sigma) in fields.items():
            entry = records[rid]["fields"][name]
            assert (entry["item"], entry["subfield"]) == (item, subfield)
            # quantised: the value is the count's, within half an LSB of the contract's
            assert entry["value"] == entry["count"] * entry["lsb"]
            assert abs(entry["value"] - value) <= 0.5 * entry["lsb"] + 1e-15
            assert entry["sigma"] == pytest.approx(sigma, rel=1e-9)
            # same sign as the contract value (measured minus true)
            assert math.copysign(1.0, entry["count"]) == math.copysign(1.0, value)
            assert abs(entry["count"] * entry["lsb"] - value) <= 0.5 * entry["lsb"] + 1e-15
            assert entry["in_range"] is True
    lsbs = {name: f["lsb"] for name, f in psr["fields"].items()}
    assert lsbs == {"time_stamping_bias": 1.0, "range_gain": 1e-5, "range_bias": 1 / 128,
                    "azimuth_bias": 360 / 65536, "elevation_bias": 360 / 65536}
    assert psr["fields"]["range_bias"]["unit"] == "NM"
    # not estimated: null
    for name in ("elevation_bias",):
        entry = ssr["fields"][name]
        assert entry["value"] is None and entry["count"] is None and entry["sigma"] is None
    assert psr["fields"]["time_stamping_bias"]["count"] is None


def test_out_of_range_is_flagged_not_wrapped() -> None:
    result = json.loads(json.dumps(RESULT))
    result["radars"]["DOLE"]["range_offset_m"] = 600000.0  # 324 NM > 255.99 NM
    result["radars"]["DOLE"]["range_gain"] = 0.5  # > 0.32767
    entry = by_radar(cat063_records(result, CODES, KINDS))["DOLE"]["fields"]
    assert entry["range_bias"]["in_range"] is False
    assert entry["range_bias"]["count"] == round(600000.0 / 1852.0 * 128)
    assert entry["range_gain"]["in_range"] is False
    with pytest.raises(AsterixEncodeError, match="DOLE range_bias"):
        encode_cat063(result, CODES, KINDS)


def test_radar_codes_are_needed_for_other_names() -> None:
    with pytest.raises(AsterixEncodeError, match=r"'DOLE'.*radar_codes"):
        cat063_records(RESULT)
    with pytest.raises(ValueError, match="kind"):
        cat063_records(RESULT, CODES, {"DOLE": "mlat"})


def decode(data: bytes) -> list:
    blocks = RawDatablock.parse(Bits.from_bytes(data))
    assert not isinstance(blocks, ValueError) and len(blocks) == 1
    assert blocks[0].get_category() == 63
    records = gen.Cat_063_1_7.cv_uap.parse(blocks[0].get_raw_records())
    assert not isinstance(records, ValueError)
    return records


def signed(raw: int) -> int:
    return raw - 65536 if raw >= 32768 else raw


def test_binary_cat063_decodes_to_the_same_counts() -> None:
    calibration = Calibration.from_dict(RESULT)
    records = by_radar(cat063_records(calibration, CODES, KINDS))
    data = encode_cat063(calibration, CODES, KINDS, source=(9, 99), service_id=3,
                         time_s=86400.0 + 3600.5)
    decoded = decode(data)
    assert len(decoded) == 2
    for record in decoded:
        i010 = record.get_item("010").variation
        assert (i010.get_item("SAC").as_uint(), i010.get_item("SIC").as_uint()) == (9, 99)
        assert record.get_item("015").as_uint() == 3
        assert record.get_item("030").variation.content.as_quantity() == 3600.5
        i050 = record.get_item("050").variation
        code = (i050.get_item("SAC").as_uint(), i050.get_item("SIC").as_uint())
        rid = {(25, 201): "SAC025_SIC201", (7, 42): "DOLE"}[code]
        fields = records[rid]["fields"]
        for entry in fields.values():
            item = entry["item"].removeprefix("I063/")
            got = record.get_item(item)
            if entry["count"] is None:
                if entry["subfield"] is None:
                    assert got is None
                continue
            if entry["subfield"] is None:
                element = got.variation
            else:
                element = got.variation.get_item(entry["subfield"]).variation
            assert signed(element.as_uint()) == entry["count"]
            assert element.content.as_quantity() == pytest.approx(entry["count"] * entry["lsb"])
        if rid == "DOLE":
            assert record.get_item("080") is None and record.get_item("081") is None
            assert record.get_item("070") is None
        else:
            assert record.get_item("090") is None and record.get_item("092") is None


def test_json_and_csv_files_are_written_atomically_and_read_back(tmp_path: Path) -> None:
    calibration = Calibration.from_dict(RESULT)
    json_path = tmp_path / "cat063.json"
    records = write_cat063_json(json_path, calibration, CODES, KINDS)
    document = json.loads(json_path.read_text(encoding="utf-8"))
    assert document["standard"].startswith("ASTERIX CAT063")
    assert "measured minus true" in document["convention"]
    assert document["records"] == json.loads(json.dumps(records))
    assert document["records"][0]["fields"]["elevation_bias"]["value"] is None

    csv_path = tmp_path / "cat063.csv"
    write_cat063_csv(csv_path, calibration, CODES, KINDS)
    table = pd.read_csv(csv_path)
    assert len(table) == 10
    row = table[(table.radar_id == "DOLE") & (table.field == "range_bias")].iloc[0]
    assert (row["item"], row["subfield"], row["unit"], int(row["sac"])) == \
        ("I063/090", "PRB", "NM", 7)
    assert row["count"] == records[1]["fields"]["range_bias"]["count"]
    lsb = 1.0 / 128.0
    assert row["value"] == round(250.0 / 1852.0 / lsb) * lsb  # quantised to the LSB
    missing = table[(table.radar_id == "SAC025_SIC201") & (table.field == "elevation_bias")]
    assert missing["value"].isna().all() and missing["count"].isna().all()
    # nothing but the two files (no temporary leftovers)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cat063.csv", "cat063.json"]


def test_values_are_whole_lsbs_and_the_binary_gives_them_back_exactly() -> None:
    """value / lsb is an integer (the count) and libasterix decodes the binary item to
    exactly the JSON value."""
    calibration = Calibration.from_dict(RESULT)
    records = by_radar(cat063_records(calibration, CODES, KINDS))
    for record in decode(encode_cat063(calibration, CODES, KINDS)):
        i050 = record.get_item("050").variation
        code = (i050.get_item("SAC").as_uint(), i050.get_item("SIC").as_uint())
        rid = {(25, 201): "SAC025_SIC201", (7, 42): "DOLE"}[code]
        for entry in records[rid]["fields"].values():
            if entry["value"] is None:
                continue
            ratio = entry["value"] / entry["lsb"]
            assert abs(ratio - round(ratio)) < 1e-9 and round(ratio) == entry["count"]
            got = record.get_item(entry["item"].removeprefix("I063/")).variation
            if entry["subfield"] is not None:
                got = got.get_item(entry["subfield"]).variation
            assert got.content.as_quantity() == entry["value"]


def test_radar_codes_for_names_every_radar_without_a_code() -> None:
    from graphcal.io.asterix.cat063 import radar_codes_for

    with pytest.raises(AsterixEncodeError, match=r"2 radars .*: DOLE, NORD; .*--sac-sic"):
        radar_codes_for(["SAC025_SIC201", "DOLE", "NORD"])
    codes = radar_codes_for(["SAC025_SIC201", "DOLE", "NORD"], {"DOLE": (7, 42)},
                            {"NORD": (7, 43), "DOLE": (7, 44)})
    assert codes == {"SAC025_SIC201": (25, 201), "DOLE": (7, 44), "NORD": (7, 43)}
    with pytest.raises(AsterixEncodeError, match="not in the dataset: SUD"):
        radar_codes_for(["DOLE"], given={"SUD": (1, 2)})
    with pytest.raises(AsterixEncodeError, match="same SAC/SIC"):
        radar_codes_for(["DOLE", "NORD"], {"DOLE": (7, 42), "NORD": (7, 42)})
