"""ASTERIX encoding of a dataset, checked by decoding with libasterix's own parser."""

from __future__ import annotations

import math
from pathlib import Path

import asterix.generated as gen
import dpkt
import numpy as np
import pandas as pd
import pytest
from asterix.base import Bits, RawDatablock

from graphcal.data.dataset import Dataset, Site
from graphcal.io.asterix.encode import (
    AsterixEncodeError,
    EncodeSummary,
    encode_dataset,
    resolve_radar_codes,
    write_asterix,
    write_pcap,
)

SPECS = {48: gen.Cat_048_1_32, 21: gen.Cat_021_2_7, 34: gen.Cat_034_1_29}
HALF_TIME = 0.5 / 128
HALF_RHO_M = 0.5 / 256 * 1852.0
HALF_THETA_DEG = 0.5 * 360.0 / 2**16
HALF_FL = 0.125
HALF_LATLON = 0.5 * 180.0 / 2**30
HALF_HEIGHT_FT = 0.5 * 6.25
HALF_SITE_LATLON = 0.5 * 180.0 / 2**23


def site(radar_id: str, lat: float, lon: float, alt: float, *, three_d: bool = False) -> Site:
    return Site(id=radar_id, lat_rad=math.radians(lat), lon_rad=math.radians(lon), alt_m=alt,
                sigma_range_m=30.0, sigma_azimuth_rad=1e-3,
                sigma_elevation_rad=2e-3 if three_d else None)


def small_dataset() -> Dataset:
    sites = {
        "SAC025_SIC201": site("SAC025_SIC201", 47.4817, 8.3967, 866.0),
        "DOLE": site("DOLE", 46.9, -1.5, 430.4, three_d=True),
    }
    plots = pd.DataFrame({
        "radar_id": ["SAC025_SIC201", "SAC025_SIC201", "DOLE", "DOLE", "SAC025_SIC201"],
        "time_s": [100.0, 104.3, 86399.999, 86400.0 + 12.34, 200.5],
        "range_m": [12345.6, 250000.0, 80000.0, 474000.0, 1.0],
        "azimuth_deg": [0.0, 123.456, 359.9999, 270.0, 45.0],
        "elevation_deg": [np.nan, np.nan, 1.5, 2.0, np.nan],
        "target_id": ["abc123", "", "4b1801", "xyz", "00ff00"],
        "altitude_m": [10668.0, np.nan, 3000.0, np.nan, -300.0],
        "callsign": ["swr12", None, "EZY1234", "", np.nan],
    })
    adsb = pd.DataFrame({
        "time_s": [100.25, 100.75, 86500.0],
        "target_id": ["abc123", "4b1801", "abc123"],
        "lat_deg": [47.5, -33.25, 47.6],
        "lon_deg": [8.5, -179.99, 180.0],
        "alt_m": [10900.0, -20.0, 11000.0],
        "sigma_m": [10.0, 10.0, 10.0],
        "nacp": pd.array([9, None, 11], dtype="Int64"),
    })
    return Dataset(sites=sites, plots=plots, adsb=adsb)


CODES = {"DOLE": (7, 42)}


def decode(data: bytes) -> list[tuple[int, object]]:
    """(category, record) of every record, with libasterix's low-level parser."""
    blocks = RawDatablock.parse(Bits.from_bytes(data))
    assert not isinstance(blocks, ValueError)
    out = []
    for block in blocks:
        category = block.get_category()
        records = SPECS[category].cv_uap.parse(block.get_raw_records())
        assert not isinstance(records, ValueError)
        out += [(category, record) for record in records]
    return out


def sub(record, item: str, name: str):
    return record.get_item(item).variation.get_item(name)


def quantity(record, item: str, name: str | None = None) -> float:
    if name is None:
        return record.get_item(item).variation.content.as_quantity()
    return sub(record, item, name).variation.content.as_quantity()


def tod_close(decoded: float, time_s: float) -> bool:
    expected = time_s % 86400.0
    diff = (decoded - expected + 43200.0) % 86400.0 - 43200.0
    return abs(diff) <= HALF_TIME + 1e-12


def test_plots_adsb_and_sites_round_trip_within_half_an_lsb() -> None:
    dataset = small_dataset()
    summary = EncodeSummary()
    data = encode_dataset(dataset, CODES, summary=summary)
    records = decode(data)
    assert summary.n_records == {48: 5, 21: 3, 34: 2}
    assert summary.n_bytes == len(data)

    cat48 = [r for c, r in records if c == 48]
    assert len(cat48) == 5
    codes = resolve_radar_codes(dataset.radar_ids, CODES)
    # records come in time order; match them to plot rows by time
    plots = dataset.plots.sort_values("time_s", kind="stable").reset_index(drop=True)
    for record, (_, row) in zip(cat48, plots.iterrows(), strict=True):
        assert (sub(record, "010", "SAC").as_uint(), sub(record, "010", "SIC").as_uint()) == \
            codes[row.radar_id]
        assert tod_close(quantity(record, "140"), row.time_s)
        assert abs(quantity(record, "040", "RHO") * 1852.0 - row.range_m) <= HALF_RHO_M
        dtheta = (quantity(record, "040", "THETA") - row.azimuth_deg + 180.0) % 360.0 - 180.0
        assert abs(dtheta) <= HALF_THETA_DEG
        address = record.get_item("220")
        typ = sub(record, "020", "TYP").as_uint()
        if len(row.target_id) == 6 and all(c in "0123456789abcdef" for c in row.target_id):
            assert address is not None and address.as_uint() == int(row.target_id, 16)
            assert typ == 5
        else:
            assert address is None
            assert typ in (1, 2)
        flight_level = record.get_item("090")
        if np.isfinite(row.altitude_m):
            fl = quantity(record, "090", "FL")
            assert abs(fl - row.altitude_m / 0.3048 / 100.0) <= HALF_FL
        else:
            assert flight_level is None
        callsign = record.get_item("240")
        if isinstance(row.callsign, str) and row.callsign:
            assert callsign.variation.content.as_string().rstrip() == row.callsign.upper()
        else:
            assert callsign is None
    # the 3-D radar's plot without address or altitude is a PSR plot
    assert sub(cat48[4], "020", "TYP").as_uint() == 1

    cat21 = [r for c, r in records if c == 21]
    for record, (_, row) in zip(cat21, dataset.adsb.iterrows(), strict=True):
        assert (sub(record, "010", "SAC").as_uint(), sub(record, "010", "SIC").as_uint()) == (0, 0)
        assert record.get_item("080").as_uint() == int(row.target_id, 16)
        assert tod_close(quantity(record, "071"), row.time_s)
        assert abs(quantity(record, "131", "LAT") - row.lat_deg) <= HALF_LATLON
        assert abs(quantity(record, "131", "LON") - row.lon_deg) <= HALF_LATLON
        assert abs(quantity(record, "140") - row.alt_m / 0.3048) <= HALF_HEIGHT_FT
        assert sub(record, "040", "ATP").as_uint() == 0
        assert record.get_item("161") is not None
        nacp = record.get_item("090")
        if pd.isna(row.nacp):
            assert nacp is None
        else:
            assert nacp.variation.get_item("NACP").as_uint() == row.nacp
    # one track number per aircraft
    tracks = [sub(r, "161", "TRNUM").as_uint() for r in cat21]
    assert tracks[0] == tracks[2] != tracks[1]

    cat34 = {(sub(r, "010", "SAC").as_uint(), sub(r, "010", "SIC").as_uint()): r
             for c, r in records if c == 34}
    assert set(cat34) == {(25, 201), (7, 42)}
    for rid, radar in dataset.sites.items():
        record = cat34[codes[rid]]
        assert record.get_item("000").as_uint() == 1
        assert abs(quantity(record, "120", "LAT") - math.degrees(radar.lat_rad)) <= \
            HALF_SITE_LATLON
        assert abs(quantity(record, "120", "LON") - math.degrees(radar.lon_rad)) <= \
            HALF_SITE_LATLON
        assert abs(quantity(record, "120", "HGT") - radar.alt_m) <= 0.5
        first = dataset.plots.loc[dataset.plots.radar_id == rid, "time_s"].min()
        assert tod_close(quantity(record, "030"), first)


def test_time_of_day_wraps_at_midnight() -> None:
    dataset = small_dataset()
    data = encode_dataset(dataset, CODES, day_start_s=-86400.0)
    times = sorted(quantity(r, "140") for c, r in decode(data) if c == 48)
    # 86399.999 s rounds to midnight -> 0; 86412.34 s -> 12.34 s
    assert times[0] == 0.0
    assert abs(times[1] - 12.34) <= HALF_TIME
    assert max(times) < 86400.0
    shifted = encode_dataset(dataset, CODES, day_start_s=50.0)
    times = sorted(quantity(r, "140") for c, r in decode(shifted) if c == 48)
    assert abs(times[0] - 50.0) <= HALF_TIME  # 100 s - 50 s


def test_blocks_stay_below_the_limit_and_split() -> None:
    n = 4000
    sites = {"SAC001_SIC002": site("SAC001_SIC002", 45.0, 5.0, 100.0)}
    rng = np.random.default_rng(1)
    plots = pd.DataFrame({
        "radar_id": ["SAC001_SIC002"] * n,
        "time_s": np.arange(n) * 0.01,
        "range_m": rng.uniform(1e3, 4e5, n),
        "azimuth_deg": rng.uniform(0.0, 360.0, n),
        "elevation_deg": np.nan,
        "target_id": [f"{i:06x}" for i in range(n)],
        "altitude_m": rng.uniform(0.0, 12000.0, n),
    })
    data = encode_dataset(Dataset(sites=sites, plots=plots))
    assert len(data) > 65535
    blocks = RawDatablock.parse(Bits.from_bytes(data))
    assert not isinstance(blocks, ValueError)
    lengths = [len(b.unparse().to_bytes()) for b in blocks]
    assert all(length <= 65535 for length in lengths)
    assert [b.get_category() for b in blocks] == [34, 48, 48]
    assert sum(lengths) == len(data)
    assert len(decode(data)) == n + 1
    small = encode_dataset(Dataset(sites=sites, plots=plots.iloc[:50]), max_block_bytes=200)
    small_blocks = RawDatablock.parse(Bits.from_bytes(small))
    assert all(len(b.unparse().to_bytes()) <= 200 for b in small_blocks)
    assert len(decode(small)) == 51


def test_out_of_range_values_raise_naming_the_row_or_are_skipped() -> None:
    dataset = small_dataset()
    dataset.plots.loc[3, "range_m"] = 600000.0  # beyond 256 NM
    with pytest.raises(AsterixEncodeError, match=r"plots row 4: .*range_m"):
        encode_dataset(dataset, CODES)
    summary = EncodeSummary()
    data = encode_dataset(dataset, CODES, on_range_error="skip", summary=summary)
    assert summary.n_records[48] == 4
    assert len(summary.skipped) == 1 and "plots row 4" in summary.skipped[0]
    assert sum(1 for c, _ in decode(data) if c == 48) == 4

    dataset = small_dataset()
    dataset.plots.loc[0, "altitude_m"] = 70000.0  # FL 2297 > 2047.75
    with pytest.raises(AsterixEncodeError, match="plots row 1:"):
        encode_dataset(dataset, CODES)
    dataset = small_dataset()
    dataset.adsb.loc[1, "target_id"] = "unknown"
    with pytest.raises(AsterixEncodeError, match="adsb row 2: .*ICAO"):
        encode_dataset(dataset, CODES)


def test_radar_codes_are_required_for_other_names() -> None:
    with pytest.raises(AsterixEncodeError, match=r"'DOLE'.*radar_codes"):
        encode_dataset(small_dataset())
    with pytest.raises(AsterixEncodeError, match="same SAC/SIC"):
        encode_dataset(small_dataset(), {"DOLE": (25, 201)})
    assert resolve_radar_codes(["sac1_sic2"]) == {"sac1_sic2": (1, 2)}


def test_write_asterix_and_pcap(tmp_path: Path) -> None:
    dataset = small_dataset()
    path = tmp_path / "out.ast"
    summary = write_asterix(dataset, path, CODES)
    assert path.read_bytes() == encode_dataset(dataset, CODES)
    assert summary.n_bytes == path.stat().st_size
    assert list(tmp_path.iterdir()) == [path]

    pcap = tmp_path / "out.pcap"
    summary = write_pcap(dataset, pcap, CODES, epoch_s=1.7e9)
    with pcap.open("rb") as stream:
        packets = list(dpkt.pcap.Reader(stream))
    assert len(packets) == 10 == summary.n_blocks
    times = [ts for ts, _ in packets]
    assert times == sorted(times)
    payload = b""
    for ts, frame in packets:
        udp = dpkt.ethernet.Ethernet(frame).data.data
        records = decode(udp.data)
        assert len(records) == 1
        category, record = records[0]
        item = {48: "140", 21: "071", 34: "030"}[category]
        assert tod_close(quantity(record, item), ts - 1.7e9)
        payload += udp.data
    assert len(decode(payload)) == 10
