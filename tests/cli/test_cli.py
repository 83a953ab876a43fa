"""The command line: calibrate on contract datasets, errors and exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.data.bias import RadarBias
from graphcal.solvers.registry import METHODS
from tests.synthetic import Track, make_dataset, site_at

runner = CliRunner()

BIAS_A = RadarBias(60.0, 2e-4, 1.5e-3)
BIAS_B = RadarBias(-40.0, -1e-4, -1e-3, 0.8e-3)


def _write_outside_tool_dataset(folder: Path, fmt: str = "csv") -> None:
    """A dataset written the way an outside tool would: plain text and pandas, no graphcal."""
    rng = np.random.default_rng(4)
    site_a = site_at("RA", 0.0, 0.0)
    site_b = site_at("RB", 110e3, -15e3, sigma_range_m=60.0, sigma_elevation_mrad=2.0)
    tracks = []
    for i in range(8):
        start = (rng.uniform(-60e3, 170e3), rng.uniform(-100e3, 100e3), rng.uniform(7e3, 11e3))
        heading = rng.uniform(0, 2 * np.pi)
        tracks.append(Track(f"4ca{i:03x}", start,
                            (210 * np.sin(heading), 210 * np.cos(heading), 0.0), 0.0, 800.0))
    ds = make_dataset(rng, [(site_a, BIAS_A), (site_b, BIAS_B)], tracks)
    folder.mkdir()
    lines = []
    for site in (site_a, site_b):
        lines += [
            "[[radar]]",
            f'id = "{site.id}"',
            f"lat_deg = {float(np.rad2deg(site.lat_rad))!r}",
            f"lon_deg = {float(np.rad2deg(site.lon_rad))!r}",
            f"alt_m = {float(site.alt_m)!r}",
            f"sigma_range_m = {site.sigma_range_m}",
            f"sigma_azimuth_mrad = {site.sigma_azimuth_rad * 1e3}",
        ]
        if site.is_3d:
            lines.append(f"sigma_elevation_mrad = {site.sigma_elevation_rad * 1e3}")
        lines.append("scan_period_s = 4.0\n")
    (folder / "sites.toml").write_text("\n".join(lines))
    if fmt == "csv":
        ds.plots.to_csv(folder / "plots.csv", index=False)
        ds.adsb.drop(columns=["sigma_m"]).to_csv(folder / "adsb.csv", index=False)
    else:
        ds.plots.to_parquet(folder / "plots.parquet", index=False)
        ds.adsb.to_parquet(folder / "adsb.parquet", index=False)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_outside_tool_dataset_calibrates_with_every_method(tmp_path: Path, method: str) -> None:
    data = tmp_path / "ds"
    _write_outside_tool_dataset(data, fmt="parquet" if method == "wls" else "csv")
    out = tmp_path / "result.json"
    result = runner.invoke(app, ["calibrate", str(data), "--method", method, "--out", str(out)])
    assert result.exit_code == 0, result.output
    doc = json.loads(out.read_text())
    assert doc["method"] == method
    assert set(doc["radars"]) == {"RA", "RB"}
    assert doc["radars"]["RA"]["elevation_bias_mrad"] is None
    if method in ("ls", "fl-ls", "wls", "wls-pruned"):
        est = doc["radars"]["RA"]["azimuth_bias_mrad"]
        sigma = doc["radars"]["RA"]["sigma"]["azimuth_bias_mrad"]
        assert abs(est - 1.5) < 4 * sigma
    assert sorted(p.name for p in data.iterdir()) == sorted(
        ["sites.toml", "plots.parquet" if method == "wls" else "plots.csv",
         "adsb.parquet" if method == "wls" else "adsb.csv"]
    )


def test_calibrate_prints_value_plus_minus_sigma_table(tmp_path: Path) -> None:
    data = tmp_path / "ds"
    _write_outside_tool_dataset(data)
    result = runner.invoke(app, ["calibrate", str(data), "--method", "ls"])
    assert result.exit_code == 0, result.output
    assert "±" in result.output
    assert "azimuth_bias_mrad" in result.output
    assert "observability degree" in result.output


def test_model_checks_are_recorded_and_can_be_turned_off(tmp_path: Path) -> None:
    data = tmp_path / "ds"
    _write_outside_tool_dataset(data)
    for flag, expected in (([], True), (["--no-model-checks"], False)):
        out = tmp_path / f"result{len(flag)}.json"
        result = runner.invoke(app, ["calibrate", str(data), "--method", "ls", "--out", str(out),
                                     *flag])
        assert result.exit_code == 0, result.output
        info = json.loads(out.read_text())["info"]
        assert ("model_checks" in info) is expected
    checks = json.loads((tmp_path / "result0.json").read_text())["info"]["model_checks"]
    assert checks["reference"] == "adsb" and set(checks["radars"]) == {"RA", "RB"}


def test_default_method_is_graph(tmp_path: Path) -> None:
    data = tmp_path / "ds"
    _write_outside_tool_dataset(data)
    result = runner.invoke(app, ["calibrate", str(data)])
    assert result.exit_code == 0, result.output
    assert "method graph" in result.output


def test_bad_input_exits_2_with_file_row_and_field(tmp_path: Path) -> None:
    data = tmp_path / "ds"
    _write_outside_tool_dataset(data)
    plots = (data / "plots.csv").read_text().splitlines()
    fields = plots[3].split(",")
    fields[3] = "361.5"  # azimuth_deg out of range in data row 3
    plots[3] = ",".join(fields)
    (data / "plots.csv").write_text("\n".join(plots) + "\n")
    before = sorted(p.name for p in data.iterdir())
    result = runner.invoke(app, ["calibrate", str(data), "--method", "ls"])
    assert result.exit_code == 2
    message = result.output.strip()
    assert "plots.csv" in message and "row 3" in message and "azimuth_deg" in message
    assert len(message.splitlines()) == 1
    assert sorted(p.name for p in data.iterdir()) == before


def test_missing_folder_and_unknown_method_exit_2(tmp_path: Path) -> None:
    result = runner.invoke(app, ["calibrate", str(tmp_path / "nope")])
    assert result.exit_code == 2
    data = tmp_path / "ds"
    _write_outside_tool_dataset(data)
    result = runner.invoke(app, ["calibrate", str(data), "--method", "magic"])
    assert result.exit_code == 2
    assert "unknown method" in result.output


def test_method_needing_adsb_exits_3_without_it(tmp_path: Path) -> None:
    data = tmp_path / "ds"
    _write_outside_tool_dataset(data)
    (data / "adsb.csv").unlink()
    result = runner.invoke(app, ["calibrate", str(data), "--method", "ls"])
    assert result.exit_code == 3
    assert "ADS-B" in result.output


def test_help_lists_every_command() -> None:
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("simulate", "calibrate", "methods"):
        assert command in result.output
