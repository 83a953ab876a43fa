"""CAT021 reports without a geometric height (I021/140), as old ground stations send them.

An edition 0.23 ground station (a 2016 recording at Barcelona LEBL, for one) often sends
the flight level (I021/145) but no geometric height.  ``import-asterix`` keeps such reports
with ``alt_m`` empty and ``baro_alt_m`` from the flight level; loading the dataset leaves
them out of a calibration with a warning, and a dataset none of whose reports has a height
is calibrated as without ADS-B (``fl-ls``, which needs ADS-B, stops with exit status 3).

The records are encoded with libasterix (``Cat_021_0_23`` and ``Cat_021_2_6`` without
I140); the radars' plots and the reports with I140 with graphcal's own encoder.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

import asterix.generated as gen
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.core.errors import DatasetError
from graphcal.data.cleaning import clean_dataset, drop_non_finite_adsb
from graphcal.data.dataset import Dataset
from graphcal.io.asterix.decode import decode_payload
from graphcal.io.asterix.encode import encode_dataset
from graphcal.io.asterix.tables import FOOT_M, adsb_frame, build_tables
from graphcal.io.folder import load_dataset, write_dataset, write_sites
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.io.test_asterix_cat021_editions import old_record
from tests.io.test_asterix_read import CAT021, block

runner = CliRunner()

#: LEBL (Barcelona), where the ADS-B station of the recordings stands [deg].
LEBL_LAT_DEG, LEBL_LON_DEG = 41.2971, 2.0785
#: SAC/SIC of the ADS-B ground station, and of the two radars.
STATION = (20, 129)
RADAR_CODES = {"R1": (20, 1), "R2": (20, 2)}
#: Pressure altitude minus geometric height of the simulated aircraft [m] (any offset).
BARO_MINUS_GEO_M = -80.0

SCENARIO = f"""
[scenario]
name = "lebl_two_ssr"
description = "Two 2-D SSRs near Barcelona, 12 aircraft, ADS-B"
duration_s = 600.0
origin = {{ lat_deg = {LEBL_LAT_DEG}, lon_deg = {LEBL_LON_DEG}, alt_m = 0.0 }}

[[radar]]
id = "R1"
lat_deg = {LEBL_LAT_DEG}
lon_deg = {LEBL_LON_DEG}
alt_m = 40.0
sigma_range_m = 40.0
sigma_azimuth_mrad = 1.0
scan_period_s = 4.0

[radar.bias]
range_offset_m = 80.0
range_gain = 0.0002
azimuth_bias_mrad = 1.5

[[radar]]
id = "R2"
lat_deg = 41.70
lon_deg = 2.50
alt_m = 300.0
sigma_range_m = 40.0
sigma_azimuth_mrad = 1.0
scan_period_s = 5.0

[radar.bias]
range_offset_m = -60.0
range_gain = -0.0001
azimuth_bias_mrad = -2.0

[traffic]
n_aircraft = 12
radius_m = 120000.0
altitude_m = [3000.0, 11000.0]
speed_mps = [150.0, 240.0]
legs = [2, 4]
turn_rate_deg_s = [1.5, 3.0]
vertical_rate_mps = [5.0, 10.0]
level_probability = 0.5
start_time_s = [0.0, 60.0]

[adsb]
enabled = true
period_s = 1.0
nacp = 8
"""


def _words(text: str) -> str:
    """``text`` with every run of blanks and line breaks one space (messages may be wrapped)."""
    return " ".join(text.split())


def _flight_level(alt_m):
    """The flight level an aircraft at ``alt_m`` [m] reports (pressure altitude / 100 ft)."""
    return (alt_m + BARO_MINUS_GEO_M) / FOOT_M / 100.0


def _no_height_records(adsb: pd.DataFrame, edition: str) -> list:
    """CAT021 records without I140 (with I145) of the rows of ``adsb``."""
    records = []
    for row in adsb.itertuples(index=False):
        fl = _flight_level(row.alt_m)
        if edition == "0.23":
            records.append(old_record(gen.Cat_021_0_23, tod=row.time_s, lat=row.lat_deg,
                                      lon=row.lon_deg, address=int(row.target_id, 16),
                                      height_ft=None, fl=fl, sac=STATION[0], sic=STATION[1]))
        else:
            records.append(CAT021.cv_record.create({
                "010": (("SAC", STATION[0]), ("SIC", STATION[1])), "071": (row.time_s, "s"),
                "080": int(row.target_id, 16),
                "131": (("LAT", (row.lat_deg, "°")), ("LON", (row.lon_deg, "°"))),
                "145": (fl, "FL")}))
    return records


def _blocks(spec, records: list, size: int = 20) -> bytes:
    return b"".join(block(spec, records[i:i + size]) for i in range(0, len(records), size))


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Dataset:
    path = tmp_path_factory.mktemp("lebl") / "lebl.toml"
    path.write_text(SCENARIO)
    return simulate(load_scenario(path), np.random.default_rng(1)).dataset


def _sites_file(dataset: Dataset, path: Path) -> Path:
    write_sites(dataset.sites, path)
    text = path.read_text()
    for rid, (sac, sic) in RADAR_CODES.items():
        text = text.replace(f'id = "{rid}"', f'id = "{rid}"\nsac = {sac}\nsic = {sic}')
    path.write_text(text)
    return path


def _no_height_blocks(without_height: pd.DataFrame) -> bytes:
    """``without_height`` as CAT021 without I140: its first half as edition 0.23 blocks, the
    rest as 2.x blocks."""
    half = len(without_height) // 2
    return (_blocks(gen.Cat_021_0_23, _no_height_records(without_height.iloc[:half], "0.23"))
            + _blocks(CAT021, _no_height_records(without_height.iloc[half:], "2.x")))


@pytest.fixture(scope="module")
def imported(simulated: Dataset, tmp_path_factory: pytest.TempPathFactory
             ) -> dict[str, tuple[Path, pd.DataFrame, str]]:
    """Two imported folders: ``none`` (no ADS-B report has I140: every 4th report of the
    simulation, without I140) and ``mixed`` (the same, and every 2nd report with I140).

    The radars' plots and the reports with I140 (CAT021 2.x) come from graphcal's
    encoder, the reports without I140 from libasterix's."""
    base = tmp_path_factory.mktemp("cat021_no_height")
    sites = _sites_file(simulated, base / "sites.toml")
    adsb = simulated.adsb.reset_index(drop=True)
    with_height = adsb.iloc[::2].reset_index(drop=True)
    without = adsb.iloc[1::4].reset_index(drop=True)
    no_height = _no_height_blocks(without)
    out = {}
    for name, height in (("none", None), ("mixed", with_height)):
        rec = base / f"{name}.ast"
        rec.write_bytes(encode_dataset(
            Dataset(sites=simulated.sites, plots=simulated.plots, adsb=height),
            RADAR_CODES, adsb_code=STATION) + no_height)
        folder = base / name
        result = runner.invoke(app, ["import-asterix", str(rec), "--sites", str(sites),
                                     "--out", str(folder)])
        assert result.exit_code == 0, result.output
        out[name] = (folder, without, result.output)
    return out


# --------------------------------------------------------------------------- import


def test_reports_without_i140_are_kept_with_alt_m_empty(imported) -> None:
    folder, without, output = imported["none"]
    adsb = pd.read_csv(folder / "adsb.csv", dtype={"target_id": str})
    assert len(adsb) == len(without)
    assert adsb["alt_m"].isna().all()
    # The positions: around the station (the aircraft fly within 120 km of LEBL), and
    # those sent, within the LSB of 0.23's I130 (180/2^23 deg) and of 2.x's I131.
    lat0, lon0 = math.radians(LEBL_LAT_DEG), math.radians(LEBL_LON_DEG)
    lat, lon = np.radians(adsb["lat_deg"]), np.radians(adsb["lon_deg"])
    hav = (np.sin((lat - lat0) / 2) ** 2
           + np.cos(lat) * math.cos(lat0) * np.sin((lon - lon0) / 2) ** 2)
    assert (2 * 6_371_000.0 * np.arcsin(np.sqrt(hav))).max() < 200_000.0
    sent = without.sort_values(["time_s", "target_id"], kind="stable").reset_index(drop=True)
    got = adsb.sort_values(["time_s", "target_id"], kind="stable").reset_index(drop=True)
    assert list(got["target_id"]) == list(sent["target_id"])
    assert got["time_s"].to_numpy() == pytest.approx(sent["time_s"].to_numpy(), abs=1 / 128)
    lsb = 180 / 2**23
    assert got["lat_deg"].to_numpy() == pytest.approx(sent["lat_deg"].to_numpy(), abs=lsb)
    assert got["lon_deg"].to_numpy() == pytest.approx(sent["lon_deg"].to_numpy(), abs=lsb)
    # baro_alt_m = FL * 100 ft in metres, FL to its LSB (1/4 FL).
    fl = np.round(_flight_level(sent["alt_m"].to_numpy()) * 4) / 4
    assert got["baro_alt_m"].to_numpy() == pytest.approx(fl * 100 * FOOT_M, abs=1e-6)
    # The summary says how many and what that means.
    words = _words(output)
    half = len(without) // 2
    assert "CAT021 editions: 0.23 (" in words and "2.6 (" in words
    assert (f"ADS-B without geometric height (I021/140): {len(without)} reports "
            f"({len(without)} with a flight level, I021/145, as baro_alt_m) kept with alt_m "
            "empty: their positions can be inspected, but a calibration cannot use them "
            "without a geometric height") in words
    assert f"ADS-B: {len(without)} reports" in words and half > 0


def test_mixed_import_keeps_both_kinds(imported) -> None:
    folder, without, output = imported["mixed"]
    adsb = pd.read_csv(folder / "adsb.csv", dtype={"target_id": str})
    missing = adsb["alt_m"].isna()
    assert int(missing.sum()) == len(without)
    assert np.isfinite(adsb.loc[~missing, "alt_m"]).all() and (~missing).sum() > 0
    assert adsb.loc[missing, "baro_alt_m"].notna().all()
    assert f"ADS-B without geometric height (I021/140): {len(without)} reports" in _words(output)


def test_a_report_with_neither_height_nor_flight_level_is_skipped_and_counted() -> None:
    spec = gen.Cat_021_0_23
    records = [old_record(spec, tod=100.0, lat=41.3, lon=2.1, address=0x340001,
                          height_ft=None, fl=350.0),
               old_record(spec, tod=101.0, lat=41.3, lon=2.1, address=0x340002,
                          height_ft=None, fl=None),
               old_record(spec, tod=102.0, lat=41.3, lon=2.1, address=0x340003,
                          height_ft=20000.0, fl=None)]
    decoded = decode_payload(block(spec, records))
    assert decoded.stats.editions == {(21, "0.23"): 1}
    skipped: Counter[str] = Counter()
    times = decoded.columns[21]["time_position_s"]
    frame = adsb_frame(decoded.columns[21], times, skipped)
    assert list(frame["target_id"]) == ["340001", "340003"]
    assert np.isnan(frame["alt_m"].iloc[0]) and frame["alt_m"].iloc[1] == 20000.0 * FOOT_M
    assert frame["baro_alt_m"].iloc[0] == pytest.approx(35000.0 * FOOT_M)
    assert np.isnan(frame["baro_alt_m"].iloc[1])
    assert skipped == {"CAT021 without geometric height (I140) or flight level (I145)": 1}


def test_build_tables_counts_reports_without_height() -> None:
    from tests.io.test_asterix_read import CAT034, CAT048, plot_record, site_record

    spec = gen.Cat_021_0_23
    data = block(CAT034, [site_record(lat=LEBL_LAT_DEG, lon=LEBL_LON_DEG)])
    data += block(CAT048, [plot_record(100.0 + k) for k in range(3)])
    data += block(spec, [old_record(spec, tod=100.0 + k, lat=41.3, lon=2.1,
                                    address=0x340000 + k, height_ft=None,
                                    fl=None if k == 2 else 300.0) for k in range(4)])
    tables = build_tables(decode_payload(data))
    assert tables.stats.adsb_reports == 3
    assert tables.stats.adsb_without_height == 3 and tables.stats.adsb_without_height_baro == 3
    assert tables.dataset.adsb is not None and tables.dataset.adsb["alt_m"].isna().all()


# --------------------------------------------------------------------------- loading


def test_loading_drops_reports_without_alt_m_with_a_warning(imported) -> None:
    folder, without, _ = imported["mixed"]
    raw = load_dataset(folder, clean=False)  # the positions can be inspected
    assert raw.adsb is not None and int(raw.adsb["alt_m"].isna().sum()) == len(without)
    ds = load_dataset(folder)
    assert ds.adsb is not None and np.isfinite(ds.adsb["alt_m"]).all()
    report = ds.cleaning
    assert report is not None and report.counts["adsb_no_height"] == len(without)
    assert report.counts["adsb_non_finite"] == 0
    (warning,) = [w for w in report.warnings if "geometric height" in w]
    assert warning.startswith(f"{len(without)} ADS-B reports without a geometric height "
                              "(alt_m) not used: ")
    assert warning.endswith(f"; {len(without)} of them carry baro_alt_m")
    assert f"{len(without)} ADS-B reports without a geometric height (alt_m) not used" in (
        report.summary())


def test_a_table_without_any_alt_m_leaves_the_calibration_without_adsb(imported) -> None:
    folder, without, _ = imported["none"]
    ds = load_dataset(folder)
    assert ds.adsb is None
    assert ds.cleaning is not None and ds.cleaning.counts["adsb_no_height"] == len(without)
    note = ("no ADS-B report has a geometric height (alt_m): the calibration proceeds as "
            "without ADS-B")
    assert any(w.startswith(note) for w in ds.cleaning.warnings)
    assert any(line.startswith(note) for line in ds.cleaning.summary())


def test_empty_alt_m_is_accepted_infinite_is_not(tmp_path: Path, simulated: Dataset) -> None:
    adsb = simulated.adsb.iloc[:50].copy()
    adsb["alt_m"] = adsb["alt_m"].astype(float)
    adsb.loc[3, "alt_m"] = np.nan
    ds = Dataset(sites=simulated.sites, plots=simulated.plots.iloc[:50], adsb=adsb)
    write_dataset(ds, tmp_path / "ok")
    loaded = load_dataset(tmp_path / "ok", clean=False, force=True)
    assert loaded.adsb is not None and np.isnan(loaded.adsb["alt_m"].iloc[3])
    text = (tmp_path / "ok" / "adsb.csv").read_text().splitlines()
    cells = text[5].split(",")
    header = text[0].split(",")
    cells[header.index("alt_m")] = "inf"
    text[5] = ",".join(cells)
    (tmp_path / "ok" / "adsb.csv").write_text("\n".join(text) + "\n")
    with pytest.raises(DatasetError, match=r"adsb\.csv, row 5, field 'alt_m'"):
        load_dataset(tmp_path / "ok", force=True)


def test_cleaning_counts_missing_height_apart_from_other_defects(simulated: Dataset) -> None:
    adsb = simulated.adsb.iloc[:40].copy().reset_index(drop=True)
    adsb["baro_alt_m"] = adsb["alt_m"] + BARO_MINUS_GEO_M
    adsb.loc[[1, 2, 3], "alt_m"] = np.nan
    adsb.loc[3, "lat_deg"] = np.nan  # missing a position as well: a non-finite report
    adsb.loc[2, "baro_alt_m"] = np.nan
    adsb.loc[5, "alt_m"] = np.inf
    kept, report = drop_non_finite_adsb(adsb)
    assert len(kept) == 36
    assert report.counts["adsb_no_height"] == 2 and report.counts["adsb_non_finite"] == 2
    assert report.warnings == [
        "2 ADS-B reports without a geometric height (alt_m) not used: a calibration needs the "
        "height above the ellipsoid to place a report (a source such as CAT021 without "
        "I021/140 gives none, and a pressure altitude is not one); 1 of them carry baro_alt_m"]
    # In memory as from a folder: the whole table without alt_m leaves no ADS-B.
    adsb["alt_m"] = np.nan
    cleaned, report = clean_dataset(Dataset(sites=simulated.sites, plots=simulated.plots,
                                            adsb=adsb))
    assert cleaned.adsb is None and report.counts["adsb_no_height"] == 39
    assert any("proceeds as without ADS-B" in w for w in report.warnings)


# --------------------------------------------------------------------------- calibrate


def test_calibrate_without_any_geometric_height(imported, tmp_path: Path) -> None:
    folder, without, _ = imported["none"]
    result = runner.invoke(app, ["calibrate", str(folder), "--out", str(tmp_path / "r.json")])
    assert result.exit_code == 0, result.output
    words = _words(result.output)
    assert "Traceback" not in result.output
    assert (f"{len(without)} ADS-B reports without a geometric height (alt_m) not used"
            in words)
    assert ("no ADS-B report has a geometric height (alt_m): the calibration proceeds as "
            "without ADS-B") in words
    cal = json.loads((tmp_path / "r.json").read_text())
    assert set(cal["radars"]) == {"R1", "R2"}
    assert cal["info"]["cleaning"]["counts"]["adsb_no_height"] == len(without)

    fl_ls = runner.invoke(app, ["calibrate", str(folder), "--method", "fl-ls"])
    assert fl_ls.exit_code == 3, fl_ls.output
    assert "Traceback" not in fl_ls.output
    words = _words(fl_ls.output)
    assert "error: this method needs ADS-B reports" in words
    assert "no ADS-B report has a geometric height (alt_m)" in words


def test_calibrate_with_some_geometric_heights(imported, tmp_path: Path) -> None:
    folder, without, _ = imported["mixed"]
    out = tmp_path / "r.json"
    result = runner.invoke(app, ["calibrate", str(folder), "--out", str(out)])
    assert result.exit_code == 0, result.output
    words = _words(result.output)
    assert (f"{len(without)} ADS-B reports without a geometric height (alt_m) not used: "
            in words)
    assert f"{len(without)} of them carry baro_alt_m" in words
    assert "proceeds as without ADS-B" not in words
    cal = json.loads(out.read_text())
    assert cal["info"]["cleaning"]["counts"]["adsb_no_height"] == len(without)

    fl_ls = runner.invoke(app, ["calibrate", str(folder), "--method", "fl-ls"])
    assert fl_ls.exit_code == 0, fl_ls.output
    assert f"{len(without)} ADS-B reports without a geometric height" in _words(fl_ls.output)


@pytest.mark.parametrize("options", [["--no-clean"], ["--window", "300s"]])
def test_calibrate_without_cleaning_or_by_windows(imported, options: list[str]) -> None:
    folder, _, _ = imported["none"]
    result = runner.invoke(app, ["calibrate", str(folder), *options])
    assert result.exit_code == 0, result.output
    fl_ls = runner.invoke(app, ["calibrate", str(folder), "--method", "fl-ls", "--no-clean"])
    assert fl_ls.exit_code == 3, fl_ls.output
