"""Contract v3 in ASTERIX: I048/070 (Mode-3/A code), I048/161 (track number) and I021/070
(Mode 3/A code) encoded, decoded and imported into ``mode_3a`` / ``track_number``.

The expected bytes are worked out by hand from the EUROCONTROL specifications (CAT048
ed. 1.32, CAT021 ed. 2.6/2.7), not taken from the encoder:

* I048/070, 2 octets: bit 16 V (1: code not validated), bit 15 G (1: garbled code),
  bit 14 L (1: code not extracted during the last scan), bit 13 spare, bits 12-1 the
  code A4 A2 A1 B4 B2 B1 C4 C2 C1 D4 D2 D1, i.e. the four octal digits as 3-bit groups:
  code 7000 -> 111 000 000 000 -> 0x0E 0x00; code 0413 -> 000 100 001 011 -> 0x01 0x0B.
* I048/161, 2 octets: 4 spare bits, then the 12-bit track number: 17 -> 0x00 0x11,
  4095 -> 0x0F 0xFF.
* I021/070 (ed. 2.x), 2 octets: 4 spare bits, then the 12-bit code as in I048/070.
* CAT048 UAP: FRN 1 I010, 2 I140, 3 I020, 4 I040, 5 I070, 6 I090, 7 I130, FX,
  8 I220, 9 I240, 10 I250, 11 I161.  CAT021 ed. 2.6/2.7 UAP: FRN 1 I010, 2 I040,
  3 I161, 4 I015, 5 I071, 6 I130, 7 I131, FX, 8 I072, 9 I150, 10 I151, 11 I080,
  12 I073, 13 I074, 14 I075, FX, 15 I076, 16 I140, 17 I090, 18 I210, 19 I070.
"""

from __future__ import annotations

import math
from pathlib import Path

import asterix.generated as gen
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.data.dataset import Dataset, Site
from graphcal.io.asterix.decode import decode_file, decode_payload
from graphcal.io.asterix.encode import AsterixEncodeError, encode_dataset, write_asterix
from graphcal.io.asterix.tables import build_tables, mode_3a_text
from graphcal.io.folder import load_dataset, write_dataset
from tests.io.test_asterix_fast import assert_same_as_reference
from tests.io.test_asterix_read import CAT034, CAT048, block, site_record

RADAR = "SAC001_SIC002"


def _site() -> Site:
    return Site(id=RADAR, lat_rad=math.radians(47.5), lon_rad=math.radians(8.5), alt_m=500.0,
                sigma_range_m=40.0, sigma_azimuth_rad=1e-3)


def _dataset(codes: list[str], tracks: list[int | None], adsb_codes: list[str] | None = None,
             ) -> Dataset:
    """A 2-D radar's plots (1 s apart, no address, no altitude) with the v3 columns."""
    n = len(codes)
    plots = pd.DataFrame({
        "radar_id": [RADAR] * n, "time_s": 100.0 + np.arange(n), "range_m": 50_000.0,
        "azimuth_deg": 30.0, "elevation_deg": np.nan, "target_id": "", "altitude_m": np.nan,
        "mode_3a": codes, "track_number": pd.array(tracks, dtype="Int64"),
    })
    adsb = None
    if adsb_codes is not None:
        m = len(adsb_codes)
        adsb = pd.DataFrame({
            "time_s": 100.5 + np.arange(m), "target_id": [f"4b18{k:02x}" for k in range(m)],
            "lat_deg": 47.8, "lon_deg": 8.6, "alt_m": 10_000.0, "mode_3a": adsb_codes,
        })
    return Dataset(sites={RADAR: _site()}, plots=plots, adsb=adsb)


def _blocks(data: bytes, category: int) -> list[bytes]:
    """The data blocks of ``category`` (whole blocks, header included)."""
    out, pos = [], 0
    while pos < len(data):
        length = int.from_bytes(data[pos + 1:pos + 3], "big")
        if data[pos] == category:
            out.append(data[pos:pos + length])
        pos += length
    return out


# --------------------------------------------------------------------------- encoding


def test_cat048_items_have_the_bytes_of_the_specification() -> None:
    data = encode_dataset(_dataset(["7000", "0413"], [17, 4095]))
    (cat048,) = _blocks(data, 48)
    body = cat048[3:]
    assert len(body) == 2 * 16  # two records of 16 octets
    first, second = body[:16], body[16:]
    for record in (first, second):
        # FSPEC: FRN 1-5 and FX (0xF9), then FRN 11 (I161) alone (0x10).
        assert record[0:2] == b"\xf9\x10"
        assert record[2:4] == b"\x01\x02"  # I010 SAC 1, SIC 2
        assert record[7] == 0x40  # I020: TYP 2 (SSR: a Mode 3/A code), FX 0
    assert first[4:7] == (100 * 128).to_bytes(3, "big")  # I140, 1/128 s
    assert first[12:14] == b"\x0e\x00"  # I070: V G L 0, code 7000
    assert first[14:16] == b"\x00\x11"  # I161: track 17
    assert second[12:14] == b"\x01\x0b"  # code 0413
    assert second[14:16] == b"\x0f\xff"  # track 4095


def test_plot_without_code_or_track_carries_neither_item() -> None:
    data = encode_dataset(_dataset([""], [None]))
    (cat048,) = _blocks(data, 48)
    # FRN 1-4 only (0xF0), no FX: no I070, no I161; a 2-D radar's plot stays SSR.
    assert cat048[3] == 0xF0
    assert len(cat048) == 3 + 1 + 2 + 3 + 1 + 4


def test_cat021_item_070_has_the_bytes_of_the_specification() -> None:
    data = encode_dataset(_dataset(["7000"], [1], ["0413"]))
    (cat021,) = _blocks(data, 21)
    record = cat021[3:]
    # FSPEC: FRN 1 2 3 5 7 + FX (0xEB); FRN 11 + FX (0x11); FRN 16 and 19 (0x48).
    assert record[:3] == b"\xeb\x11\x48"
    # I010 2, I040 1, I161 2, I071 3, I131 8, I080 3, I140 2, then I070 last.
    assert len(record) == 3 + 2 + 1 + 2 + 3 + 8 + 3 + 2 + 2
    assert record[-2:] == b"\x01\x0b"


@pytest.mark.parametrize(("column", "value", "text"), [
    ("mode_3a", "8000", "not 4 octal digits"),
    ("mode_3a", "413", "not 4 octal digits"),
    ("track_number", 4096, "0..4095"),
])
def test_values_items_cannot_carry_are_refused_or_skipped(column: str, value: object,
                                                          text: str) -> None:
    dataset = _dataset(["7000", "0413"], [1, 2])
    if column == "track_number":
        dataset.plots[column] = pd.array([1, value], dtype="Int64")
    else:
        dataset.plots[column] = ["7000", value]
    with pytest.raises(AsterixEncodeError) as error:
        encode_dataset(dataset)
    assert "plots row 2" in str(error.value) and text in str(error.value)
    assert error.value.row == 2
    data = encode_dataset(dataset, on_range_error="skip")
    assert len(decode_payload(data).cat048) == 1


# --------------------------------------------------------------------------- decoding


def _plot_070_161(v: int, g: int, l_bit: int, code: int, track: int) -> bytes:
    """A CAT048 record by hand: I010, I140, I040, I070 and I161."""
    fspec = bytes([0x80 | 0x40 | 0x10 | 0x08 | 0x01, 0x10])  # FRN 1 2 4 5, FX; FRN 11
    i010 = bytes([25, 201])
    i140 = (1000 * 128).to_bytes(3, "big")
    i040 = (100 * 256).to_bytes(2, "big") + (1 << 13).to_bytes(2, "big")  # 100 NM, 45 deg
    i070 = ((v << 15) | (g << 14) | (l_bit << 13) | code).to_bytes(2, "big")
    i161 = track.to_bytes(2, "big")
    return fspec + i010 + i140 + i040 + i070 + i161


def _header(category: int, body: bytes) -> bytes:
    return bytes([category]) + (3 + len(body)).to_bytes(2, "big") + body


def test_decoded_codes_follow_the_validity_bits() -> None:
    records = [
        _plot_070_161(0, 0, 0, 0o7000, 17),    # validated
        _plot_070_161(0, 0, 1, 0o413, 4095),   # L: kept from an earlier scan: kept
        _plot_070_161(1, 0, 0, 0o1234, 0),     # V: not validated: left out
        _plot_070_161(0, 1, 0, 0o1234, 1),     # G: garbled: left out
    ]
    data = _header(48, b"".join(records)) + block(CAT034, [site_record()])
    assert_same_as_reference(data)  # the column decoder and libasterix agree
    reports = decode_payload(data).cat048
    assert [r.mode_3a for r in reports] == [0o7000, 0o413, None, None]
    assert [r.track_number for r in reports] == [17, 4095, 0, 1]
    plots = build_tables(decode_payload(data)).dataset.plots
    assert plots["mode_3a"].tolist() == ["7000", "0413", "", ""]
    assert plots["track_number"].tolist() == [17, 4095, 0, 1]
    assert plots["track_number"].dtype == "Int64"
    assert plots.columns.tolist()[-3:] == ["mode_3a", "track_number", "callsign"]


def test_plots_without_the_items_have_empty_columns() -> None:
    fspec = bytes([0x80 | 0x40 | 0x10])  # I010, I140, I040
    record = fspec + bytes([25, 201]) + (1000 * 128).to_bytes(3, "big") + bytes(4)
    data = _header(48, record) + block(CAT034, [site_record()])
    plots = build_tables(decode_payload(data)).dataset.plots
    assert plots["mode_3a"].tolist() == [""]
    assert plots["track_number"].isna().tolist() == [True]


def test_cat021_070_by_hand_and_in_edition_0_26() -> None:
    # Edition 2.x: I010, I071, I131, I080, I140, I070 (FRN 1 5 7, 11, 16 19).
    fspec = bytes([0x80 | 0x08 | 0x02 | 0x01, 0x10 | 0x01, 0x40 | 0x08])
    lat = round(47.5 / (180.0 / 2**30)).to_bytes(4, "big", signed=True)
    lon = round(8.5 / (180.0 / 2**30)).to_bytes(4, "big", signed=True)
    record = (fspec + bytes([1, 2]) + (1000 * 128).to_bytes(3, "big") + lat + lon
              + (0xABCDEF).to_bytes(3, "big") + (5600).to_bytes(2, "big") + b"\x01\x0b")
    old = gen.Cat_021_0_26
    not_validated = old.cv_record.create({
        "010": (("SAC", 1), ("SIC", 2)), "030": (1001.0, "s"), "080": 0x123456,
        "130": (("LAT", (47.6, "°")), ("LON", (8.6, "°"))), "140": (30000.0, "ft"),
        "070": (("V", 1), ("G", 0), ("L", 0), 0, ("MODE3A", 0o7000)),
    })
    validated = old.cv_record.create({
        "010": (("SAC", 1), ("SIC", 2)), "030": (1002.0, "s"), "080": 0x123457,
        "130": (("LAT", (47.6, "°")), ("LON", (8.6, "°"))), "140": (30000.0, "ft"),
        "070": (("V", 0), ("G", 0), ("L", 1), 0, ("MODE3A", 0o7000)),
    })
    data = (_header(48, _plot_070_161(0, 0, 0, 0o7000, 1)) + _header(21, record)
            + old.create([not_validated, validated]).unparse().to_bytes()
            + block(CAT034, [site_record()]))
    assert_same_as_reference(data)
    decoded = decode_payload(data)
    assert [r.mode_3a for r in decoded.cat021] == [0o413, None, 0o7000]
    adsb = build_tables(decoded).dataset.adsb
    assert adsb is not None
    assert adsb["mode_3a"].tolist() == ["0413", "", "7000"]


def test_column_decoder_agrees_with_libasterix_on_random_and_flipped_records() -> None:
    rng = np.random.default_rng(5)
    records = []
    for _ in range(40):
        bits = rng.integers(0, 2, 3)
        items = {
            "010": (("SAC", 25), ("SIC", 201)), "140": (float(rng.uniform(0, 86000)), "s"),
            "040": (("RHO", (float(rng.uniform(1, 200)), "NM")), ("THETA", (10.0, "°"))),
            "070": (("V", int(bits[0])), ("G", int(bits[1])), ("L", int(bits[2])), 0,
                    ("MODE3A", int(rng.integers(0, 4096)))),
        }
        if rng.random() < 0.7:
            items["161"] = (0, ("TRN", int(rng.integers(0, 4096))))
        records.append(CAT048.cv_record.create(items))
    data = block(CAT048, records)
    assert_same_as_reference(data)
    reports = decode_payload(data).cat048
    assert any(r.mode_3a is None for r in reports) and any(r.mode_3a for r in reports)
    for pos in range(3, 60):
        flipped = bytearray(data)
        flipped[pos] ^= 0x80
        assert_same_as_reference(bytes(flipped))


def test_mode_3a_text() -> None:
    codes = np.array([0o7000, 0o413, 0, 0o7777, -1])
    assert mode_3a_text(codes).tolist() == ["7000", "0413", "0000", "7777", ""]


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_encode_import_write_read_keeps_codes_and_track_numbers(tmp_path: Path,
                                                                fmt: str) -> None:
    codes, tracks = ["0413", "7000", "", "0000", "7777"], [17, 4095, None, 0, 3]
    original = _dataset(codes, tracks, ["0413", "", "1200"])
    recording = tmp_path / "rec.ast"
    write_asterix(original, recording)
    tables = build_tables(decode_file(recording))
    plots, adsb = tables.dataset.plots, tables.dataset.adsb
    assert plots["mode_3a"].tolist() == codes
    assert plots["track_number"].astype(object).where(plots["track_number"].notna(),
                                                      None).tolist() == tracks
    assert adsb is not None and adsb["mode_3a"].tolist() == ["0413", "", "1200"]
    loaded = load_dataset(write_dataset(tables.dataset, tmp_path / "ds", fmt=fmt), force=True)
    pd.testing.assert_series_equal(loaded.plots["mode_3a"], plots["mode_3a"])
    pd.testing.assert_series_equal(loaded.plots["track_number"], plots["track_number"])
    assert loaded.adsb is not None
    assert loaded.adsb["mode_3a"].tolist() == ["0413", "", "1200"]


def test_import_asterix_command_writes_the_columns(tmp_path: Path) -> None:
    recording = tmp_path / "rec.ast"
    write_asterix(_dataset(["0413", ""], [7, None], ["0413"]), recording)
    opensky = tmp_path / "states.csv"
    opensky.write_text("timestamp,icao24,latitude,longitude,geoaltitude,squawk\n"
                       "100,4b1805,47.8,8.6,10000,413\n"
                       "101,4b1806,47.9,8.7,10000,\n")
    out = tmp_path / "ds"
    result = CliRunner().invoke(app, ["import-asterix", str(recording), "--out", str(out),
                                      "--adsb", str(opensky), "--adsb-format", "opensky"])
    assert result.exit_code == 0, result.output
    lines = (out / "plots.csv").read_text().splitlines()
    header = lines[0].split(",")
    assert header.index("mode_3a") == 7 and header.index("track_number") == 8
    assert [line.split(",")[7:9] for line in lines[1:]] == [["0413", "7"], ["", ""]]
    adsb = (out / "adsb.csv").read_text().splitlines()
    column = adsb[0].split(",").index("mode_3a")
    assert [line.split(",")[column] for line in adsb[1:]] == ["0413", ""]
    loaded = load_dataset(out, force=True)
    assert loaded.plots["mode_3a"].tolist() == ["0413", ""]
