"""Corrupted raw ASTERIX recordings: the splitter loses the damaged blocks, not the file.

A simulated network (``scenarios/demo_network.toml``) is encoded as raw blocks; single
corrupted ``LEN`` bytes and random bytes must cost a few blocks each, the import summary
must state the bytes left out, and corrupted times of day must not become negative
``time_s`` (``graphcal.io.asterix.decode.split_blocks``, ``tables.build_tables``).
"""

from __future__ import annotations

import dataclasses
import random
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.io.asterix.decode import (
    REJECT_UNCONFIRMED,
    DecodeStats,
    decode_bytes,
    decode_payload,
    split_blocks,
)
from graphcal.io.asterix.encode import encode_dataset
from graphcal.io.asterix.tables import (
    SKIP_BEFORE_DAY_0_021,
    SKIP_BEFORE_DAY_0_048,
    SKIP_TOD_021,
    SKIP_TOD_048,
    adsb_frame,
    build_tables,
    plots_frame,
    records_time_of_day,
    unwrap_time_array,
)
from graphcal.io.folder import write_sites
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.io.test_asterix_read import (
    CAT021,
    CAT034,
    CAT048,
    MIDNIGHT,
    adsb_record,
    block,
    capture,
    plot_record,
    site_record,
)
from tests.paths import SCENARIOS

runner = CliRunner()


@pytest.fixture(scope="module")
def recording() -> tuple[bytes, dict[str, tuple[int, int]], object]:
    """The demo network's first 600 s as raw blocks, its radar codes and its dataset."""
    scenario = dataclasses.replace(load_scenario(SCENARIOS / "demo_network.toml"),
                                   duration_s=600.0)
    ds = simulate(scenario, np.random.default_rng(1)).dataset
    codes = {rid: (25, 10 + k) for k, rid in enumerate(ds.sites)}
    return encode_dataset(ds, codes), codes, ds


def _len_only(data: bytes) -> list[tuple[int, int, int]]:
    """The blocks of a valid stream, by LEN alone."""
    out, pos = [], 0
    while pos < len(data):
        length = (data[pos + 1] << 8) | data[pos + 2]
        out.append((data[pos], pos, pos + length))
        pos += length
    assert pos == len(data)
    return out


def _blocks(data: bytes) -> list[tuple[int, int, int]]:
    return list(split_blocks(data, DecodeStats()))


def test_a_valid_stream_splits_as_by_len_alone(recording) -> None:
    data, _, _ = recording
    assert len(_len_only(data)) > 5000
    stats = DecodeStats()
    assert list(split_blocks(data, stats)) == _len_only(data)
    assert stats.bytes_unsplit == 0 and not stats.rejected
    # Categories appearing one after the other at the start, one ASTERIX does not define
    # between known ones, big blocks, and a stream of a single such category.
    plots = block(CAT048, [plot_record(float(t)) for t in range(300)])
    boundary = next(e for _, _, e in _len_only(data) if e >= 5000)
    stop = next(e for _, _, e in _len_only(data) if e >= 20000)
    streams = [
        block(CAT021, [adsb_record(1.0)]) + block(CAT034, [site_record()])
        + block(CAT048, [plot_record(2.0)]) + block(CAT021, [adsb_record(3.0)]),
        block(CAT048, [plot_record(1.0)]) * 3 + bytes([200, 0, 5, 1, 2])
        + block(CAT048, [plot_record(2.0)]) * 3,
        plots + block(CAT021, [adsb_record(4.0)]) + plots * 2,
        bytes([200, 0, 4, 9]) * 5,
        data[:boundary] + block(CAT034, [site_record()]) + data[boundary:stop],
    ]
    for stream in streams:
        assert _blocks(stream) == _len_only(stream)


@pytest.mark.parametrize(("index", "offset", "value"), [
    (0.5, 1, 0xF0), (0.25, 1, 0x7F), (0.75, 2, 0x00), (0.9, 1, 0x03), (0.1, 2, 0xFF)])
def test_one_corrupted_len_loses_a_few_blocks(recording, index: float, offset: int,
                                              value: int) -> None:
    data, _, _ = recording
    clean = _len_only(data)
    _, begin, _ = clean[int(index * len(clean))]
    corrupted = bytearray(data)
    corrupted[begin + offset] = value if value != data[begin + offset] else value ^ 0x40
    decoded = decode_bytes(bytes(corrupted))
    reference = decode_bytes(data)
    kept = set(_blocks(bytes(corrupted)))
    assert sum(1 for b in clean if b not in kept) <= 3
    assert decoded.count(48) >= 0.99 * reference.count(48)
    assert decoded.count(21) >= 0.99 * reference.count(21)
    assert decoded.stats.bytes_unsplit <= 3 * max(e - b for _, b, e in clean)


def test_twenty_random_bytes_lose_a_small_share(recording) -> None:
    data, _, _ = recording
    reference = decode_bytes(data)
    for seed in range(3):
        rng = random.Random(seed)
        corrupted = bytearray(data)
        for _ in range(20):
            corrupted[rng.randrange(len(data))] = rng.randrange(256)
        decoded = decode_bytes(bytes(corrupted))
        assert decoded.count(48) >= 0.99 * reference.count(48), seed
        assert decoded.count(21) >= 0.99 * reference.count(21), seed
        assert decoded.stats.bytes_unsplit < 0.005 * len(data), seed


def test_a_len_pointing_into_records_is_rejected_not_walked() -> None:
    blocks = [block(CAT048, [plot_record(float(t)) for t in range(k, k + 3)])
              for k in range(0, 300, 3)]
    data = bytearray(b"".join(blocks))
    data[1] = 0x0F  # the first block's LEN now ends inside the records of a later block
    decoded = decode_payload(bytes(data))
    assert decoded.count(48) == 297
    assert decoded.stats.rejected[REJECT_UNCONFIRMED] == 1
    assert decoded.stats.bytes_unsplit == len(blocks[0])
    assert not decoded.stats.skipped_categories


def _sites(ds, codes: dict[str, tuple[int, int]], path: Path) -> Path:
    write_sites(ds.sites, path)
    text = path.read_text()
    for rid, (sac, sic) in codes.items():
        text = text.replace(f'id = "{rid}"', f'id = "{rid}"\nsac = {sac}\nsic = {sic}')
    path.write_text(text)
    return path


def test_summary_states_the_bytes_left_out(recording, tmp_path: Path) -> None:
    data, codes, ds = recording
    sites = _sites(ds, codes, tmp_path / "sites.toml")
    clean = _len_only(data)
    corrupted = bytearray(data)
    corrupted[clean[len(clean) // 2][1] + 1] = 0xF0
    path = tmp_path / "a_len1.ast"
    path.write_bytes(bytes(corrupted))
    result = runner.invoke(app, ["import-asterix", str(path), "--out", str(tmp_path / "imp"),
                                 "--sites", str(sites)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    _, begin, stop = clean[len(clean) // 2]
    n = stop - begin
    assert f"{n:,} bytes (" in text and "of a_len1.ast could not be split into blocks" in text
    assert "warning:" not in text and "skipped categories" not in text
    # More than 1 % of the input lost: a warning.
    junk = bytes(random.Random(5).randrange(256) for _ in range(len(data) // 20))
    path = tmp_path / "junk.ast"
    path.write_bytes(data[:clean[100][1]] + junk + data[clean[100][1]:])
    result = runner.invoke(app, ["import-asterix", str(path), "--out", str(tmp_path / "imp2"),
                                 "--sites", str(sites)])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert f"{len(junk):,} bytes (4.8 %) of junk.ast could not be split" in text
    assert "warning: 4.8 % of the ASTERIX bytes could not be split" in text


def test_times_of_day_out_of_range_or_before_day_0_are_skipped() -> None:
    tods = [100.0, 101.0, 53904.0, 102.0, 120000.0, 103.0]
    data = b"".join(block(CAT048, [plot_record(t)]) for t in tods)
    data += b"".join(block(CAT021, [adsb_record(t + 0.5)]) for t in tods)
    data += block(CAT034, [site_record()])
    tables = build_tables(decode_payload(data))
    assert tables.dataset.plots["time_s"].tolist() == [100.0, 101.0, 102.0, 103.0]
    assert tables.dataset.adsb["time_s"].tolist() == [100.5, 101.5, 102.5, 103.5]
    skipped = tables.stats.skipped
    assert skipped[SKIP_TOD_048] == 1 and skipped[SKIP_BEFORE_DAY_0_048] == 1
    assert skipped[SKIP_TOD_021] == 1 and skipped[SKIP_BEFORE_DAY_0_021] == 1
    # With capture times, a time of day far from its packet's is put on the day before.
    packets = [(MIDNIGHT + t, block(CAT048, [plot_record(t)])) for t in (100.0, 101.0)]
    packets += [(MIDNIGHT + 102.0, block(CAT048, [plot_record(53904.0)])),
                (MIDNIGHT + 103.0, block(CAT034, [site_record()]))]
    tables = build_tables(decode_bytes(capture(packets)))
    assert tables.dataset.plots["time_s"].tolist() == [100.0, 101.0]
    assert tables.stats.skipped[SKIP_BEFORE_DAY_0_048] == 1


def test_no_negative_time_after_random_corruption(recording) -> None:
    data, codes, ds = recording
    for seed in range(3):
        rng = random.Random(100 + seed)
        corrupted = bytearray(data)
        for _ in range(100):
            corrupted[rng.randrange(len(data))] = rng.randrange(256)
        decoded = decode_bytes(bytes(corrupted))
        # The table builder's steps, without the sites (a corrupted SAC/SIC is a radar
        # without a position, which build_tables refuses).
        tod, capture_s = records_time_of_day(decoded)
        times, _ = unwrap_time_array(tod, capture_s)
        columns = decoded.columns[48]
        ids = {(s, c): f"SAC{s}_SIC{c}" for s, c in zip(
            columns["sac"].tolist(), columns["sic"].tolist(), strict=True)}
        plots = plots_frame(columns, times[decoded.order == 48], ids, Counter())
        adsb = adsb_frame(decoded.columns[21], times[decoded.order == 21], Counter())
        assert (plots["time_s"] >= 0.0).all() and (adsb["time_s"] >= 0.0).all()
        assert len(plots) > 0.95 * len(ds.plots) and len(adsb) > 0.95 * len(ds.adsb)
