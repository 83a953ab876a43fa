"""ASTERIX reading: block splitting, decoding, tables, time base, robustness."""

from __future__ import annotations

import io
import math
import os
import subprocess
import sys
import tarfile
import time
from collections import Counter
from datetime import timedelta
from pathlib import Path

import asterix.generated as gen
import dpkt
import pytest
import typer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from graphcal.cli.import_asterix import import_asterix_command
from graphcal.core.errors import GraphcalInputError
from graphcal.io.asterix.decode import (
    REJECT_BAD_LENGTH,
    REJECT_RECORDS,
    REJECT_SHORT_HEADER,
    REJECT_TRUNCATED,
    AsterixError,
    DecodeStats,
    decode_bytes,
    decode_file,
    decode_files,
    decode_payload,
    split_blocks,
)
from graphcal.io.asterix.tables import (
    DAY_S,
    FOOT_M,
    NM_M,
    build_tables,
    default_radar_id,
    load_user_sites,
    unwrap_times,
)
from graphcal.io.folder import load_dataset, write_dataset

CAT048 = gen.Cat_048_1_32
CAT021 = gen.Cat_021_2_6
CAT034 = gen.Cat_034_1_29
SAMPLE_VERSION = "0.7.11"
SAMPLE_FILES = ("cat048.raw", "cat034.raw", "cat_034_048.pcap")


# --------------------------------------------------------------------------- encoders


def plot_record(tod: float, rho: float = 100.0, theta: float = 45.0, *, sac: int = 25,
                sic: int = 201, address: int | None = 0x3C660C, fl: float | None = 330.0):
    items = {
        "010": (("SAC", sac), ("SIC", sic)),
        "140": (tod, "s"),
        "040": (("RHO", (rho, "NM")), ("THETA", (theta, "°"))),
    }
    if fl is not None:
        items["090"] = (0, 0, ("FL", (fl, "FL")))
    if address is not None:
        items["220"] = address
    return CAT048.cv_record.create(items)


def adsb_record(tod: float, *, lat: float = 48.5, lon: float = 2.25, height_ft: float = 35000.0,
                address: int = 0xABCDEF, nacp: int | None = 9, position: bool = True):
    items = {"010": (("SAC", 1), ("SIC", 2)), "071": (tod, "s"), "080": address,
             "140": (height_ft, "ft")}
    if position:
        items["131"] = (("LAT", (lat, "°")), ("LON", (lon, "°")))
    if nacp is not None:
        items["090"] = ((0, 7, None), (0, 0, nacp, None))
    return CAT021.cv_record.create(items)


def site_record(*, sac: int = 25, sic: int = 201, lat: float = 48.5, lon: float = 2.25,
                height: float = 120.0, tod: float = 3600.0):
    return CAT034.cv_record.create({
        "000": 1, "010": (("SAC", sac), ("SIC", sic)), "030": (tod, "s"),
        "120": (("HGT", (height, "m")), ("LAT", (lat, "°")), ("LON", (lon, "°"))),
    })


def block(spec, records) -> bytes:
    return spec.create(list(records)).unparse().to_bytes()


def udp_frame(payload: bytes) -> bytes:
    udp = dpkt.udp.UDP(sport=5000, dport=8600, data=payload)
    udp.ulen = len(udp)
    ip = dpkt.ip.IP(src=b"\x0a\x00\x00\x01", dst=b"\xef\x00\x00\x01", p=dpkt.ip.IP_PROTO_UDP,
                    data=udp)
    ip.len = len(ip)
    return bytes(dpkt.ethernet.Ethernet(src=b"\x00" * 6, dst=b"\x01" * 6,
                                         type=dpkt.ethernet.ETH_TYPE_IP, data=ip))


def capture(packets: list[tuple[float, bytes]], *, ng: bool = False) -> bytes:
    stream = io.BytesIO()
    writer = dpkt.pcapng.Writer(stream) if ng else dpkt.pcap.Writer(stream)
    for ts, payload in packets:
        writer.writepkt(udp_frame(payload), ts=ts)
    return stream.getvalue()


#: 2021-10-07 00:00:00 UTC.
MIDNIGHT = 1633564800.0


# --------------------------------------------------------------------------- real samples


def _sample_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "graphcal-test"
    target = cache / f"asterix-decoder-{SAMPLE_VERSION}"
    if all((target / name).is_file() for name in SAMPLE_FILES):
        return target
    download = tmp_path_factory.mktemp("sdist")
    try:
        subprocess.run(
            [sys.executable, "-m", "pip", "download", f"asterix-decoder=={SAMPLE_VERSION}",
             "--no-deps", "--no-binary", ":all:", "-d", str(download), "-q"],
            check=True, timeout=180, capture_output=True)
        (archive,) = download.glob("asterix_decoder-*.tar.gz")
        target.mkdir(parents=True, exist_ok=True)
        with tarfile.open(archive) as tar:
            for name in SAMPLE_FILES:
                member = tar.extractfile(
                    f"asterix_decoder-{SAMPLE_VERSION}/asterix/sample_data/{name}")
                assert member is not None
                (target / name).write_bytes(member.read())
    except (OSError, ValueError, subprocess.SubprocessError, tarfile.TarError,
            KeyError, AssertionError) as exc:
        pytest.skip(f"asterix-decoder sample recordings not available (offline?): {exc}")
    return target


@pytest.fixture(scope="session")
def samples(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _sample_dir(tmp_path_factory)


def test_sample_cat048_raw_gives_the_reference_plot(samples: Path, tmp_path: Path) -> None:
    decoded = decode_file(samples / "cat048.raw")
    assert decoded.stats.records == {48: 1} and not decoded.stats.rejected
    (report,) = decoded.cat048
    assert (report.sac, report.sic, report.callsign) == (25, 201, "DLH65A")
    sites = tmp_path / "sites.toml"
    sites.write_text('[[radar]]\nid = "R201"\nsac = 25\nsic = 201\n'
                     "lat_deg = 45.0\nlon_deg = 15.0\nalt_m = 300.0\n")
    tables = build_tables(decoded, user_sites=load_user_sites(sites))
    row = tables.dataset.plots.iloc[0]
    assert row["radar_id"] == "R201"
    assert row["time_s"] == 27354.6015625
    assert row["range_m"] == 197.68359375 * 1852.0
    assert row["azimuth_deg"] == 340.13671875
    assert math.isnan(row["elevation_deg"])
    assert row["target_id"] == "3c660c"
    assert row["altitude_m"] == pytest.approx(330 * 100 * 0.3048)
    assert row["callsign"] == "DLH65A"
    assert tables.time_base.epoch_unix_s is None


def _independent_block_count(path: Path) -> tuple[int, Counter[int]]:
    """Packets and blocks per CAT byte, counted without graphcal's splitter."""
    counts: Counter[int] = Counter()
    packets = 0
    with path.open("rb") as handle:
        for _, frame in dpkt.pcap.Reader(handle):
            payload = bytes(dpkt.ethernet.Ethernet(frame).data.data.data)
            packets += 1
            pos = 0
            while pos < len(payload):
                counts[payload[pos]] += 1
                pos += int.from_bytes(payload[pos + 1:pos + 3], "big")
    return packets, counts


def test_sample_pcap_counts_and_cat034_identity(samples: Path, tmp_path: Path) -> None:
    path = samples / "cat_034_048.pcap"
    decoded = decode_file(path)
    packets, blocks = _independent_block_count(path)
    assert (packets, blocks) == (100, Counter({48: 86, 34: 34}))
    stats = decoded.stats
    assert stats.packets == packets and stats.blocks == sum(blocks.values())
    assert stats.blocks_decoded == stats.blocks and not stats.rejected
    assert stats.records == {48: 128, 34: 34}
    assert all(r.capture_s is not None for r in decoded.sequence)
    radars = {(r.sac, r.sic) for r in decoded.cat048}
    assert radars == {(r.sac, r.sic) for r in decoded.cat034}
    assert radars == {(25, s) for s in (11, 12, 13, 14, 201, 204, 205)}
    with pytest.raises(AsterixError, match=r"SAC 25 / SIC \d+ .*--sites"):
        build_tables(decoded)
    # With positions for every radar: plots on the capture day's time base.
    site = tmp_path / "sites.toml"
    site.write_text("".join(
        f'[[radar]]\nid = "R{sic}"\nsac = 25\nsic = {sic}\nlat_deg = 45.0\nlon_deg = 15.0\n'
        "alt_m = 300.0\n" for _, sic in sorted(radars)))
    tables = build_tables(decoded, user_sites=load_user_sites(site))
    assert tables.time_base.date == "2016-05-05"
    assert len(tables.dataset.plots) == 128 - 2  # two reports have no I040
    assert tables.stats.skipped == {"CAT048 without I040 (polar position)": 2}


# --------------------------------------------------------------------------- tables


def test_plots_adsb_and_cat034_site(tmp_path: Path) -> None:
    data = (block(CAT034, [site_record()])
            + block(CAT048, [plot_record(1000.0, 10.0, 90.0), plot_record(1001.0, address=None,
                                                                          fl=None)])
            + block(CAT021, [adsb_record(1000.5), adsb_record(1000.6, position=False),
                             adsb_record(1000.7, nacp=None, lat=48.6)]))
    tables = build_tables(decode_payload(data))
    plots, adsb = tables.dataset.plots, tables.dataset.adsb
    radar = default_radar_id(25, 201)
    assert radar == "SAC025_SIC201" and list(tables.dataset.sites) == [radar]
    site = tables.dataset.sites[radar]
    assert math.degrees(site.lat_rad) == pytest.approx(48.5, abs=1e-5)
    assert site.alt_m == 120.0 and site.missing_sigmas
    assert plots["range_m"].tolist() == [10.0 * NM_M, 100.0 * NM_M]
    assert plots["target_id"].tolist() == ["3c660c", ""]
    assert math.isnan(plots["altitude_m"].iloc[1])
    assert adsb is not None and len(adsb) == 2
    assert adsb["alt_m"].iloc[0] == pytest.approx(35000.0 * FOOT_M)
    assert adsb["target_id"].iloc[0] == "abcdef"
    assert adsb["nacp"].iloc[0] == 9 and adsb["nacp"].isna().iloc[1]
    assert tables.stats.skipped == {"CAT021 without position": 1}
    write_dataset(tables.dataset, tmp_path / "ds", fmt="parquet")
    loaded = load_dataset(tmp_path / "ds")
    assert len(loaded.plots) == 2 and loaded.adsb is not None and len(loaded.adsb) == 2


def test_raw_midnight_wrap_and_out_of_order_reports() -> None:
    tods = [86390.0, 86399.5, 0.25, 86399.875, 5.0, 10.0]
    data = b"".join(block(CAT048, [plot_record(t)]) for t in tods)
    data += block(CAT021, [adsb_record(7.5)]) + block(CAT034, [site_record(tod=11.0)])
    tables = build_tables(decode_payload(data))
    assert tables.dataset.plots["time_s"].tolist() == [
        86390.0, 86399.5, 86400.25, 86399.875, 86405.0, 86410.0]
    assert tables.dataset.adsb["time_s"].tolist() == [86407.5]
    assert tables.time_base.wrapped == 5


def test_capture_times_put_reports_on_the_right_day() -> None:
    packets = [
        (MIDNIGHT - 1.0, block(CAT048, [plot_record(86398.875)])),
        # stamped just before midnight, captured just after
        (MIDNIGHT + 0.3, block(CAT048, [plot_record(86399.875)])),
        # stamped just after midnight, captured just before (capture clock late)
        (MIDNIGHT - 0.2, block(CAT048, [plot_record(0.125)])),
        (MIDNIGHT + 3600.0, block(CAT021, [adsb_record(3599.5)])),
        (MIDNIGHT + 3600.0, block(CAT034, [site_record()])),
    ]
    tables = build_tables(decode_bytes(capture(packets)))
    epoch = MIDNIGHT - DAY_S
    assert tables.time_base.epoch_unix_s == epoch and tables.time_base.date == "2021-10-06"
    assert tables.dataset.plots["time_s"].tolist() == [86398.875, 86399.875, 86400.125]
    assert tables.dataset.adsb["time_s"].tolist() == [DAY_S + 3599.5]


def test_unwrap_without_any_time_keeps_none() -> None:
    times, base = unwrap_times([])
    assert times == [] and base.epoch_unix_s is None and base.date is None


def test_sites_toml_wins_and_is_validated(tmp_path: Path) -> None:
    data = block(CAT034, [site_record()]) + block(CAT048, [plot_record(10.0)])
    sites = tmp_path / "sites.toml"
    sites.write_text('[[radar]]\nid = "PAR"\nsac = 25\nsic = 201\nlat_deg = 49.0\n'
                     "lon_deg = 2.5\nalt_m = 90.0\nsigma_range_m = 40.0\n"
                     "sigma_azimuth_mrad = 1.0\n")
    tables = build_tables(decode_payload(data), user_sites=load_user_sites(sites))
    assert list(tables.dataset.sites) == ["PAR"] and tables.stats.site_origin == {
        "PAR": "sites.toml"}
    assert tables.dataset.sites["PAR"].sigma_range_m == 40.0
    sites.write_text('[[radar]]\nid = "PAR"\nsac = 25\nlat_deg = 49.0\nlon_deg = 2.5\n'
                     "alt_m = 90.0\n")
    with pytest.raises(GraphcalInputError, match="give both sac and sic"):
        load_user_sites(sites)
    sites.write_text('[[radar]]\nid = "PAR"\nsac = 300\nsic = 1\nlat_deg = 49.0\n'
                     "lon_deg = 2.5\nalt_m = 90.0\n")
    with pytest.raises(GraphcalInputError, match="0..255"):
        load_user_sites(sites)


# --------------------------------------------------------------------------- robustness


def test_corrupted_truncated_and_unknown_blocks() -> None:
    good1 = block(CAT048, [plot_record(1.0), plot_record(2.0)])
    good2 = block(CAT048, [plot_record(3.0)])
    bad_records = bytes([48, 0, 8]) + b"\xff\xff\xff\xff\xff"  # FSPEC runs off the end
    unknown = bytes([62, 0, 5, 0, 0])
    stats_cases = [
        (good1 + bad_records + good2, {REJECT_RECORDS: 1}, 3),
        (good1 + bytes([48, 0, 1]) + good2, {REJECT_BAD_LENGTH: 1}, 3),
        (good1 + good2[:-4], {REJECT_TRUNCATED: 1}, 2),
        (good1 + good2 + b"\x00\x01", {REJECT_SHORT_HEADER: 1}, 3),
        (good1 + good2 + b"\x30\x00\x05\x80", {REJECT_TRUNCATED: 1}, 3),
    ]
    for data, rejected, n_records in stats_cases:
        decoded = decode_payload(data)
        counted = {k: v for k, v in decoded.stats.rejected.items() if "resync" not in k}
        assert counted == rejected, data.hex()
        assert len(decoded.cat048) == n_records
    decoded = decode_payload(good1 + unknown + good2)
    assert decoded.stats.skipped_categories == {62: 1} and len(decoded.cat048) == 3
    assert not decoded.stats.rejected


def test_resync_after_bad_length_keeps_the_following_blocks() -> None:
    blocks = [block(CAT048, [plot_record(float(t))]) for t in range(5)]
    data = blocks[0] + b"\x30\xff\xff" + b"".join(blocks[1:])
    decoded = decode_payload(data)
    assert len(decoded.cat048) == 5
    assert decoded.stats.rejected[REJECT_TRUNCATED] == 1


def test_pcapng_linux_cooked_and_raw_ip(tmp_path: Path) -> None:
    payload = block(CAT048, [plot_record(100.0)]) + block(CAT034, [site_record()])
    path = tmp_path / "rec.pcapng"
    path.write_bytes(capture([(MIDNIGHT + 100.0, payload)] * 3, ng=True))
    decoded = decode_file(path)
    assert decoded.stats.packets == 3 and decoded.stats.records == {48: 3, 34: 3}
    assert decoded.cat048[0].capture_s == pytest.approx(MIDNIGHT + 100.0)
    ip = dpkt.ethernet.Ethernet(udp_frame(payload)).data
    for linktype, frame in ((dpkt.pcap.DLT_RAW, bytes(ip)),
                            (dpkt.pcap.DLT_LINUX_SLL,
                             bytes(dpkt.sll.SLL(type=3, ethtype=0x0800, data=ip)))):
        stream = io.BytesIO()
        writer = dpkt.pcap.Writer(stream, linktype=linktype)
        writer.writepkt(frame, ts=MIDNIGHT)
        decoded = decode_bytes(stream.getvalue())
        assert decoded.stats.records == {48: 1, 34: 1}, linktype


def test_truncated_capture_keeps_complete_packets() -> None:
    payload = block(CAT048, [plot_record(100.0)])
    data = capture([(MIDNIGHT, payload)] * 4)
    decoded = decode_bytes(data[:-10])
    assert decoded.stats.records == {48: 3}


def test_empty_missing_and_useless_files(tmp_path: Path) -> None:
    empty = tmp_path / "empty.raw"
    empty.write_bytes(b"")
    with pytest.raises(AsterixError, match="empty file"):
        decode_file(empty)
    with pytest.raises(AsterixError, match="file not found"):
        decode_file(tmp_path / "missing.raw")
    only_sites = tmp_path / "sites.raw"
    only_sites.write_bytes(block(CAT034, [site_record()]))
    with pytest.raises(AsterixError, match="no CAT048"):
        build_tables(decode_files([only_sites]))


# --------------------------------------------------------------------------- command


def _cli() -> typer.Typer:
    app = typer.Typer()
    app.command("import-asterix")(import_asterix_command)
    app.command("noop")(lambda: None)
    return app


def test_import_command_writes_dataset_and_reports(tmp_path: Path) -> None:
    rec = tmp_path / "rec.pcap"
    rec.write_bytes(capture([
        (MIDNIGHT + 10.0, block(CAT034, [site_record()])),
        (MIDNIGHT + 11.0, block(CAT048, [plot_record(11.0), plot_record(11.5)])),
        (MIDNIGHT + 12.0, block(CAT021, [adsb_record(11.9)]) + b"\x30\x00"),
    ]))
    runner = CliRunner()
    out = tmp_path / "ds"
    result = runner.invoke(_cli(), ["import-asterix", str(rec), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "SAC025_SIC201" in result.output and "CAT034" in result.output
    assert "short header 1" in result.output and "2021-10-07" in result.output
    dataset = load_dataset(out)
    assert len(dataset.plots) == 2 and dataset.adsb is not None and len(dataset.adsb) == 1
    again = runner.invoke(_cli(), ["import-asterix", str(rec), "--out", str(out)])
    assert again.exit_code == 2 and "not empty" in again.output
    bad = runner.invoke(_cli(), ["import-asterix", str(tmp_path / "nope.raw"), "--out",
                                 str(tmp_path / "x")])
    assert bad.exit_code == 2 and "no such file" in bad.output
    no_site = tmp_path / "nosite.raw"
    no_site.write_bytes(block(CAT048, [plot_record(1.0, sic=7)]))
    missing = runner.invoke(_cli(), ["import-asterix", str(no_site), "--out", str(tmp_path / "y")])
    assert missing.exit_code == 2 and "SAC 25 / SIC 7" in missing.output


# --------------------------------------------------------------------------- fuzz


_VALID = [
    block(CAT048, [plot_record(100.0), plot_record(86399.0, 5.0, 359.9)]),
    block(CAT021, [adsb_record(50.0)]),
    block(CAT034, [site_record()]),
    block(CAT048, [plot_record(3.0)]) + block(CAT021, [adsb_record(2.0)]),
]


def _exercise(data: bytes) -> None:
    started = time.perf_counter()
    for decoded in (decode_payload(data), decode_bytes(data)):
        stats: DecodeStats = decoded.stats
        assert stats.blocks >= stats.blocks_decoded
        try:
            build_tables(decoded)
        except AsterixError:
            pass
    assert time.perf_counter() - started < 2.0


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    data = bytearray(draw(st.sampled_from(_VALID)))
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(["flip", "truncate", "length", "insert"]))
        if not data:
            break
        pos = draw(st.integers(0, len(data) - 1))
        if kind == "flip":
            data[pos] ^= 1 << draw(st.integers(0, 7))
        elif kind == "truncate":
            del data[pos:]
        elif kind == "length" and len(data) >= 3:
            data[1:3] = draw(st.integers(0, 0xFFFF)).to_bytes(2, "big")
        else:
            data[pos:pos] = draw(st.binary(max_size=4))
    return bytes(data)


@settings(max_examples=1000, deadline=timedelta(seconds=5),
          suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(st.binary(max_size=200), mutated(),
                 mutated().map(lambda b: capture([(MIDNIGHT, b)]))))
def test_fuzz_never_crashes(data: bytes) -> None:
    try:
        _exercise(data)
    except AsterixError:
        pass


def test_split_blocks_is_linear_on_garbage() -> None:
    data = bytes([48, 0xFF, 0xFF]) * 20000
    started = time.perf_counter()
    stats = DecodeStats()
    blocks = list(split_blocks(data, stats))
    assert time.perf_counter() - started < 2.0
    assert sum(stop - begin for _, begin, stop in blocks) <= len(data)
    assert stats.rejected[REJECT_TRUNCATED] >= 1
