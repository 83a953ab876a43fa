"""A simulated dataset written to ASTERIX and read back is the same within ASTERIX resolution.

The encoder (:mod:`graphcal.io.asterix.encode`) and the reader (:mod:`graphcal.io.asterix.decode`,
:mod:`graphcal.io.asterix.tables`) are separate code; both use libasterix's item definitions.
Resolutions (half an LSB bounds the error): time 1/128 s, RHO 1/256 NM, THETA 360/2^16 deg,
flight level 1/4 FL, CAT021 latitude/longitude 180/2^30 deg, geometric height 6.25 ft.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.data.dataset import Dataset
from graphcal.io.asterix.decode import decode_file
from graphcal.io.asterix.encode import write_asterix, write_pcap
from graphcal.io.asterix.tables import build_tables, load_user_sites
from graphcal.io.folder import write_sites
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.graph import graph
from tests.paths import SCENARIOS

NM = 1852.0
FOOT = 0.3048
#: 2021-10-07 12:00 UTC: the simulated time 0 [unix s].
EPOCH_UNIX_S = 1633608000.0
SECONDS_AFTER_MIDNIGHT = 43200.0


@pytest.fixture(scope="module")
def simulated():
    """Paper 003's 2-D radar and ADS-B (CAT048 has no elevation angle, so 2-D only)."""
    scenario = load_scenario(SCENARIOS / "paper003_adsb_2d.toml")
    run = simulate(scenario, np.random.default_rng(3))
    ds = run.dataset
    # Mode S addresses as the contract wants them (6 hex digits).
    plots = ds.plots.copy()
    adsb = ds.adsb.copy()
    return run, Dataset(ds.sites, plots, adsb)


def _sites_file(ds: Dataset, folder: Path) -> Path:
    path = folder / "sites.toml"
    write_sites(ds.sites, path)
    text = path.read_text().replace('id = "R2D"', 'id = "R2D"\nsac = 25\nsic = 201')
    path.write_text(text)
    return path


@pytest.mark.parametrize("container", ["raw", "pcap"])
def test_roundtrip_within_resolution(simulated, tmp_path: Path, container: str) -> None:
    run, ds = simulated
    codes = {"R2D": (25, 201)}
    path = tmp_path / f"recording.{container}"
    if container == "raw":
        write_asterix(ds, path, codes)
    else:
        # Time of day counts from midnight, which is simulated time -43200 s.
        write_pcap(ds, path, codes, epoch_s=EPOCH_UNIX_S, day_start_s=-SECONDS_AFTER_MIDNIGHT)
    tables = build_tables(
        decode_file(path), user_sites=load_user_sites(_sites_file(ds, tmp_path)),
        epoch_unix_s=EPOCH_UNIX_S - SECONDS_AFTER_MIDNIGHT if container == "raw" else None,
    )
    back = tables.dataset
    assert list(back.sites) == ["R2D"]
    shift = SECONDS_AFTER_MIDNIGHT if container == "pcap" else 0.0
    a = ds.plots.sort_values("time_s").reset_index(drop=True)
    b = back.plots.sort_values("time_s").reset_index(drop=True)
    assert len(a) == len(b) == len(ds.plots)
    assert np.max(np.abs(b.time_s - shift - a.time_s)) <= 0.5 / 128 + 1e-9
    assert np.max(np.abs(b.range_m - a.range_m)) <= 0.5 * NM / 256 + 1e-6
    daz = (b.azimuth_deg - a.azimuth_deg + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(daz)) <= 0.5 * 360.0 / 2**16 + 1e-9
    assert np.max(np.abs(b.altitude_m - a.altitude_m)) <= 0.5 * 25.0 * FOOT + 1e-6
    assert (b.target_id == a.target_id).all()
    assert b.elevation_deg.isna().all()
    # ADS-B
    a = ds.adsb.sort_values("time_s").reset_index(drop=True)
    b = back.adsb.sort_values("time_s").reset_index(drop=True)
    assert len(a) == len(b)
    assert np.max(np.abs(b.time_s - shift - a.time_s)) <= 0.5 / 128 + 1e-9
    for column in ("lat_deg", "lon_deg"):
        assert np.max(np.abs(b[column] - a[column])) <= 0.5 * 180.0 / 2**30 + 1e-12
    assert np.max(np.abs(b.alt_m - a.alt_m)) <= 0.5 * 6.25 * FOOT + 1e-6
    assert (b.target_id == a.target_id).all()
    if "nacp" in a:
        assert (pd.to_numeric(b.nacp) == pd.to_numeric(a.nacp)).all()


def test_calibration_survives_the_roundtrip(simulated, tmp_path: Path) -> None:
    """The biases from the re-imported recording equal the original ones within 0.1 sigma."""
    run, ds = simulated
    path = tmp_path / "recording.pcap"
    write_pcap(ds, path, {"R2D": (25, 201)}, epoch_s=EPOCH_UNIX_S,
               day_start_s=-SECONDS_AFTER_MIDNIGHT)
    back = build_tables(
        decode_file(path), user_sites=load_user_sites(_sites_file(ds, tmp_path))
    ).dataset
    before = graph(ds)
    after = graph(dataclasses.replace(back))
    for key in ("range_offset_m", "azimuth_bias_mrad"):
        sigma = before.sigma("R2D", key)
        assert abs(after.value("R2D", key) - before.value("R2D", key)) < 0.1 * sigma, key
        true = {"range_offset_m": 297.0, "azimuth_bias_mrad": 161.7}[key]
        assert abs(after.value("R2D", key) - true) < 3 * after.sigma("R2D", key)


def test_import_then_calibrate_with_cat063_export(simulated, tmp_path: Path) -> None:
    """The engineer's path: import-asterix, calibrate --cat063; SAC/SIC kept in sites.toml."""
    import json

    from typer.testing import CliRunner

    from graphcal.cli.app import app

    _, ds = simulated
    recording = tmp_path / "recording.pcap"
    write_pcap(ds, recording, {"R2D": (25, 201)}, epoch_s=EPOCH_UNIX_S,
               day_start_s=-SECONDS_AFTER_MIDNIGHT)
    runner = CliRunner()
    folder = tmp_path / "ds"
    sites = _sites_file(ds, tmp_path)
    result = runner.invoke(app, ["import-asterix", str(recording), "--out", str(folder),
                                 "--sites", str(sites)])
    assert result.exit_code == 0, result.output
    assert "sac = 25" in (folder / "sites.toml").read_text()
    export = tmp_path / "biases.json"
    result = runner.invoke(app, ["calibrate", str(folder), "--cat063", str(export)])
    assert result.exit_code == 0, result.output
    record = json.loads(export.read_text())
    records = record["records"] if isinstance(record, dict) else record
    assert (records[0]["sac"], records[0]["sic"]) == (25, 201)
    binary = tmp_path / "biases.ast"
    result = runner.invoke(app, ["calibrate", str(folder), "--cat063", str(binary)])
    assert result.exit_code == 0, result.output
    assert binary.read_bytes()[0] == 63
