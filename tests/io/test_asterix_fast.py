"""The column decoder against libasterix's item-by-item decoder, and 3-D radars in ASTERIX.

:mod:`graphcal.io.asterix.decode` walks FSPECs with compiled item sizes and extracts fields
with numpy; :mod:`graphcal.io.asterix.reference` parses every item with libasterix.  On
valid, mutated and random bytes both must give the same reports (values identical, not
close) and the same rejection counts.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from graphcal.data.dataset import Dataset
from graphcal.io.asterix import reference
from graphcal.io.asterix.decode import AsterixError, decode_payload
from graphcal.io.asterix.encode import encode_dataset
from graphcal.io.asterix.tables import build_tables, load_user_sites, radar_inventory
from graphcal.io.folder import write_sites
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.io.test_asterix_read import (
    CAT021,
    CAT034,
    CAT048,
    adsb_record,
    block,
    plot_record,
    samples,  # noqa: F401, F811 - the fixture
    site_record,
)
from tests.paths import SCENARIOS

FOOT = 0.3048
NM = 1852.0


def assert_same_as_reference(data: bytes) -> None:
    """The column decoder gives the reports and counts of libasterix's item-by-item one."""
    fast = decode_payload(data)
    reports, stats = reference.decode_payload(data)
    assert fast.sequence == reports
    assert fast.stats.rejected == stats.rejected
    assert fast.stats.records == stats.records
    assert fast.stats.blocks_decoded == stats.blocks_decoded
    assert fast.stats.skipped_categories == stats.skipped_categories


def _valid_blocks(rng: np.random.Generator) -> list[bytes]:
    blocks = []
    for _ in range(3):
        tod = float(rng.uniform(0.0, 86399.0))
        blocks.append(block(CAT048, [
            plot_record(tod, float(rng.uniform(1, 250)), float(rng.uniform(0, 359.9)),
                        address=int(rng.integers(1 << 24)),
                        fl=None if rng.random() < 0.3 else float(rng.uniform(-10, 450)))
            for _ in range(int(rng.integers(1, 5)))]))
        blocks.append(block(CAT021, [adsb_record(
            tod, lat=float(rng.uniform(-80, 80)), lon=float(rng.uniform(-170, 170)),
            height_ft=float(rng.uniform(-1000, 40000)), address=int(rng.integers(1 << 24)),
            nacp=None if rng.random() < 0.3 else int(rng.integers(0, 12)),
            position=rng.random() > 0.1)]))
        blocks.append(block(CAT034, [site_record(lat=float(rng.uniform(-80, 80)),
                                                 height=float(rng.uniform(-100, 3000)))]))
    return blocks


def _mutate(rng: np.random.Generator, data: bytes) -> bytes:
    out = bytearray(data)
    for _ in range(int(rng.integers(1, 6))):
        if not out:
            break
        pos = int(rng.integers(len(out)))
        kind = int(rng.integers(4))
        if kind == 0:
            out[pos] ^= 1 << int(rng.integers(8))
        elif kind == 1:
            del out[pos:]
        elif kind == 2:
            out[pos:pos] = rng.bytes(int(rng.integers(1, 8)))
        else:
            del out[pos:pos + int(rng.integers(1, 8))]
    return bytes(out)


def test_same_reports_and_counts_as_libasterix_on_valid_mutated_and_random_bytes() -> None:
    rng = np.random.default_rng(17)
    pool = _valid_blocks(rng)
    assert_same_as_reference(b"".join(pool))
    for _ in range(400):
        picked = [pool[i] for i in rng.integers(len(pool), size=int(rng.integers(1, 5)))]
        assert_same_as_reference(_mutate(rng, b"".join(picked)))
    for _ in range(100):
        assert_same_as_reference(rng.bytes(int(rng.integers(1, 300))))
    # Bit flips inside the FSPEC and items of each category, one at a time.
    for data in pool:
        for pos in range(3, len(data)):
            for bit in (0, 7):
                flipped = bytearray(data)
                flipped[pos] ^= 1 << bit
                assert_same_as_reference(bytes(flipped))


def test_real_samples_decode_identically(samples: Path) -> None:  # noqa: F811
    for name in ("cat048.raw", "cat034.raw"):
        assert_same_as_reference((samples / name).read_bytes())


def test_full_mode_s_records_and_cat021_edition_0_26() -> None:
    """Items the decoder only skips (I020, I200, I170, I250 ...), the Mode-3/A code and
    track number (I070, I161) and the older CAT021 edition."""
    import asterix.generated as gen

    record = CAT048.cv_record.create({
        "010": (("SAC", 25), ("SIC", 201)), "140": (1000.5, "s"),
        "020": ((("TYP", 5), 0, 0, 0, 0, None),),
        "040": (("RHO", (100.0, "NM")), ("THETA", (12.0, "°"))),
        "070": (0, 0, 0, 0, ("MODE3A", "1000")), "090": (0, 1, ("FL", (330.0, "FL"))),
        "220": 0xABC123, "240": "DLH65A", "161": (0, ("TRN", 3563)),
        "200": (("GSP", (0.12, "NM/s")), ("HDG", (124.0, "°"))),
        "170": ((0, 0, 2, 0, 0, 0, 0, 0, None),),
        "110": (0, ("3DH", (12000.0, "ft"))),
    })
    old = gen.Cat_021_0_26
    adsb = old.cv_record.create({
        "010": (("SAC", 1), ("SIC", 2)), "030": (2000.0, "s"), "080": 0x123456,
        "130": (("LAT", (48.5, "°")), ("LON", (2.25, "°"))), "140": (30000.0, "ft"),
        "145": (300.25, "FL"),
    })
    data = block(CAT048, [record]) + old.create([adsb]).unparse().to_bytes()
    assert_same_as_reference(data)
    decoded = decode_payload(data)
    (plot,) = decoded.cat048
    assert plot.flight_level is None  # garbled (G=1)
    assert plot.height_ft == 12000.0 and plot.callsign == "DLH65A"
    assert plot.mode_3a == 0o1000 and plot.track_number == 3563
    (report,) = decoded.cat021
    assert report.flight_level == 300.25 and report.time_position_s == 2000.0


@pytest.fixture(scope="module")
def three_d():
    """Paper 002's three 3-D radars (elevation measured), a few minutes of plots."""
    scenario = load_scenario(SCENARIOS / "paper002_three_radars.toml")
    run = simulate(scenario, np.random.default_rng(5))
    ds = run.dataset
    near = ds.plots[ds.plots["range_m"] < 250.0 * NM]  # CAT048 RHO stops at 256 NM
    ds.plots = near.groupby("radar_id").head(80).reset_index(drop=True)
    return ds


def _codes(ds) -> dict[str, tuple[int, int]]:
    return {rid: (25, 10 + k) for k, rid in enumerate(ds.sites)}


def _user_sites(ds, folder: Path, codes, *, drop_elevation: str | None = None) -> Path:
    path = folder / "sites.toml"
    write_sites(ds.sites, path)
    text = path.read_text()
    for rid, (sac, sic) in codes.items():
        text = text.replace(f'id = "{rid}"', f'id = "{rid}"\nsac = {sac}\nsic = {sic}')
    if drop_elevation is not None:
        head, _, tail = text.partition(f'id = "{drop_elevation}"')
        lines = tail.split("\n")
        first = next(i for i, line in enumerate(lines) if line.startswith("sigma_elevation"))
        tail = "\n".join(lines[:first] + lines[first + 1:])
        text = head + f'id = "{drop_elevation}"' + tail
    path.write_text(text)
    return path


def test_3d_radars_round_trip_through_the_3d_height(three_d, tmp_path: Path) -> None:
    """Elevation -> I048/110 height (25 ft) -> elevation: back within 12.5 ft / range."""
    ds = three_d
    codes = _codes(ds)
    data = encode_dataset(ds, codes)
    decoded = decode_payload(data)
    assert all(r.is_3d for r in radar_inventory(decoded))
    tables = build_tables(decoded, user_sites=load_user_sites(_user_sites(ds, tmp_path, codes)))
    back = tables.dataset.plots.sort_values(["radar_id", "time_s"], kind="stable")
    a = ds.plots.sort_values(["radar_id", "time_s"], kind="stable")
    assert len(back) == len(a)
    # Height error at most half an LSB (12.5 ft); d(el) = dh cos(el)... bounded by dh / r,
    # plus the range quantisation (1/512 NM) through the same formula (a few urad).
    bound = 0.5 * 25.0 * FOOT / a["range_m"].to_numpy() + 2e-5
    error = np.radians(back["elevation_deg"].to_numpy() - a["elevation_deg"].to_numpy())
    assert np.all(np.abs(error) <= bound)


def test_3d_sites_for_2d_records_and_the_reverse_are_refused(three_d, tmp_path: Path) -> None:
    ds = three_d
    codes = _codes(ds)
    first = str(ds.plots["radar_id"].iloc[0])
    decoded = decode_payload(encode_dataset(ds, codes))
    sites = load_user_sites(_user_sites(ds, tmp_path, codes, drop_elevation=first))
    with pytest.raises(AsterixError, match=rf"radar {first} .* 2-D in the sites.toml"):
        build_tables(decoded, user_sites=sites)
    # The same radars as 2-D records (no I048/110): sites.toml says 3-D.
    flat = ds.plots.copy()
    flat["elevation_deg"] = np.nan
    two_d = Dataset({rid: dataclasses.replace(s, sigma_elevation_rad=None, estimate=())
                     for rid, s in ds.sites.items()}, flat, None)
    decoded = decode_payload(encode_dataset(two_d, codes))
    assert not any(r.is_3d for r in radar_inventory(decoded))
    sites = load_user_sites(_user_sites(ds, tmp_path, codes))
    with pytest.raises(AsterixError, match=r"is 3-D in the sites.toml .* 0 of its"):
        build_tables(decoded, user_sites=sites)


def test_every_radar_without_a_position_is_named_at_once() -> None:
    data = b"".join(block(CAT048, [plot_record(100.0 + i, sic=sic) for i in range(2)])
                    for sic in (1, 2, 3)) + block(CAT034, [site_record(sic=2)])
    with pytest.raises(AsterixError) as error:
        build_tables(decode_payload(data))
    message = str(error.value)
    assert "2 radars" in message
    assert "SAC 25 / SIC 1 " in message and "SAC 25 / SIC 3 " in message
    assert "SIC 2 " not in message


def test_cat021_flight_level_becomes_baro_alt_m() -> None:
    record = CAT021.cv_record.create({
        "010": (("SAC", 1), ("SIC", 2)), "071": (100.0, "s"), "080": 0xABCDEF,
        "131": (("LAT", (48.5, "°")), ("LON", (2.25, "°"))), "140": (35000.0, "ft"),
        "145": (347.5, "FL"),
    })
    data = (block(CAT048, [plot_record(100.0)]) + block(CAT021, [record])
            + block(CAT034, [site_record()]))
    adsb = build_tables(decode_payload(data)).dataset.adsb
    assert adsb["baro_alt_m"].iloc[0] == pytest.approx(347.5 * 100.0 * FOOT, abs=1e-9)
    assert adsb["alt_m"].iloc[0] == pytest.approx(35000.0 * FOOT, abs=1e-9)
