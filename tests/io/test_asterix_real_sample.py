"""Real CAT048 recordings: every record decoded, Mode 3/A and track number kept.

The recordings are small public samples (``tests/io/data/asterix_real/README.txt`` names their
repositories, commits and licences). The expected values were decoded independently of
graphcal: with Croatia Control's ``asterix-decoder`` 0.7.11 (PyPI) and, for the jASTERIX
record, from the values jASTERIX's own test asserts.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pandas as pd
import pytest

from graphcal.io.asterix.decode import decode_file
from graphcal.io.asterix.tables import build_tables, load_user_sites

DATA = Path(__file__).parent / "data" / "asterix_real"

#: CAT048 records of the pcap excerpt, per datagram, as (SIC, time of day [s], has I040,
#: Mode 3/A code or None, track number); SAC 25 throughout. Every datagram arrives twice
#: (A and B feeds), so the records do too.
PCAP_DATAGRAMS: list[list[tuple[int, float, bool, str | None, int]]] = [
    [(201, 27354.6015625, True, "1000", 3563)],
    [(13, 27355.859375, True, "2303", 482)],
    [(13, 27336.2578125, False, None, 730),  # track only: no I040, no I070
     (13, 27356.046875, True, "2030", 761),
     (13, 27355.9765625, True, "7252", 1435),
     (13, 27356.0234375, True, "4745", 1424)],
    [(201, 27354.671875, True, "2202", 3195)],
    [(204, 27354.6171875, True, "7426", 3779)],
    [(204, 27354.6640625, True, "7000", 3058)],
    [(12, 27355.8984375, True, "6050", 1581),
     (12, 27355.84375, True, "0314", 867),
     (12, 27355.8203125, True, "0301", 780),
     (12, 27355.84375, True, "2076", 1776),  # I070 L = 1 (smoothed code): kept
     (12, 27355.828125, True, "0010", 1173),
     (12, 27355.828125, True, "6502", 364),
     (12, 27355.84375, True, "7001", 1739),
     (12, 27355.8515625, True, "2726", 821),
     (12, 27355.8203125, True, "0005", 1220)],
    [(12, 27356.0390625, True, "0246", 644)],
]

#: CAT048 records of goasterix's sample.ast (SAC 8 / SIC 24), as above; the tenth has an
#: I070 with G = 1 (garbled), whose code graphcal leaves empty.
GOASTERIX_RECORDS: list[tuple[float, str | None, int]] = [
    (30040.8984375, "4606", 804), (30040.8515625, "1000", 1953),
    (30040.84375, "2641", 300), (30040.953125, "1000", 527),
    (30040.8046875, "7051", 546), (30040.8046875, "7057", 1838),
    (30040.8984375, "4605", 1778), (30040.8671875, "2651", 1729),
    (30040.9296875, "1000", 534), (30040.859375, None, 1565),
    (30040.953125, "1230", 774),
]


def _octal(code: int | None) -> str | None:
    return None if code is None else f"{code:04o}"


def _sites(tmp_path: Path, sac: int, sics: list[int]) -> Path:
    path = tmp_path / "sites.toml"
    path.write_text("".join(
        f'[[radar]]\nid = "R{sic}"\nsac = {sac}\nsic = {sic}\n'
        "lat_deg = 45.0\nlon_deg = 15.0\nalt_m = 300.0\n" for sic in sics))
    return path


def _has_code(plots: pd.DataFrame) -> pd.Series:
    """Plots with a Mode 3/A code (the tables hold ``""`` where there is none)."""
    return plots["mode_3a"].fillna("").ne("")


def _shares(plots: pd.DataFrame) -> tuple[float, float]:
    return _has_code(plots).mean(), plots["track_number"].notna().mean()


def test_pcap_excerpt_decodes_every_record() -> None:
    decoded = decode_file(DATA / "cat_034_048_first20.pcap")
    stats = decoded.stats
    assert stats.packets == 20
    assert (stats.blocks, stats.blocks_decoded) == (28, 28)
    assert not stats.rejected and stats.bytes_unsplit == 0
    assert stats.records == Counter({48: 38, 34: 12})
    expected = [record for datagram in PCAP_DATAGRAMS for record in datagram * 2]
    got = [(r.sac, r.sic, r.time_of_day_s, r.rho_nm is not None, _octal(r.mode_3a),
            r.track_number) for r in decoded.cat048]
    assert got == [(25, *record) for record in expected]


def test_pcap_excerpt_plots_keep_mode_3a_and_track_number(tmp_path: Path) -> None:
    decoded = decode_file(DATA / "cat_034_048_first20.pcap")
    sites = load_user_sites(_sites(tmp_path, 25, [12, 13, 201, 204]))
    tables = build_tables(decoded, user_sites=sites)
    plots = tables.dataset.plots
    assert len(plots) == 36
    assert tables.stats.skipped == {"CAT048 without I040 (polar position)": 2}
    assert _shares(plots) == (1.0, 1.0)
    assert plots["mode_3a"].str.fullmatch("[0-7]{4}").all()
    smoothed = plots[plots["track_number"] == 1776]
    assert list(smoothed["mode_3a"]) == ["2076", "2076"]
    # The A and B feeds give every plot twice, as exact duplicates (dropped on loading).
    assert plots.duplicated().sum() == 18


def test_goasterix_sample_skips_other_categories_and_empties_garbled_codes(
        tmp_path: Path) -> None:
    decoded = decode_file(DATA / "goasterix_sample.ast")
    stats = decoded.stats
    assert (stats.blocks, stats.blocks_decoded) == (7, 2)
    assert not stats.rejected and stats.bytes_unsplit == 0
    assert stats.records == Counter({48: 11, 34: 1})
    assert stats.skipped_categories == Counter({30: 1, 1: 1, 2: 1, 255: 1, 32: 1})
    got = [(r.sac, r.sic, r.time_of_day_s, _octal(r.mode_3a), r.track_number)
           for r in decoded.cat048]
    assert got == [(8, 24, *record) for record in GOASTERIX_RECORDS]
    tables = build_tables(decoded, user_sites=load_user_sites(_sites(tmp_path, 8, [24])))
    plots = tables.dataset.plots
    assert len(plots) == 11
    assert _shares(plots) == (pytest.approx(10 / 11), 1.0)
    assert list(plots["mode_3a"])[9] == ""  # the garbled code


def test_jasterix_record_with_four_octet_fspec() -> None:
    decoded = decode_file(DATA / "jasterix_cat048ed1.23.bin")
    assert decoded.stats.records == Counter({48: 1}) and not decoded.stats.rejected
    (report,) = decoded.cat048
    assert (report.sac, report.sic) == (0, 1)
    assert report.time_of_day_s == 33499.8359375
    assert (report.rho_nm, report.theta_deg) == (255.99609375, 89.67041015625)
    assert report.flight_level == 370.0
    assert report.address == 11226301 and report.callsign == "RYR5XW"
    assert _octal(report.mode_3a) == "0470"  # L = 1, validated: kept
    assert report.track_number == 919


def test_real_samples_meet_the_share_target(tmp_path: Path) -> None:
    """Over both multi-plot samples, > 90 % of the plots keep mode_3a and track_number."""
    plots: list[pd.DataFrame] = []
    for name, sac, sics in (("cat_034_048_first20.pcap", 25, [12, 13, 201, 204]),
                            ("goasterix_sample.ast", 8, [24])):
        folder = tmp_path / name
        folder.mkdir()
        sites = load_user_sites(_sites(folder, sac, sics))
        plots.append(build_tables(decode_file(DATA / name), user_sites=sites).dataset.plots)
    mode_3a = sum(int(_has_code(p).sum()) for p in plots)
    track = sum(int(p["track_number"].notna().sum()) for p in plots)
    total = sum(len(p) for p in plots)
    assert (total, mode_3a, track) == (47, 46, 47)
    assert mode_3a / total > 0.9 and track / total > 0.9
