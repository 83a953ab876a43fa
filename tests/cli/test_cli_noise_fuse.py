"""The ``noise`` and ``fuse`` commands, and calibrating with sigmas left out of sites.toml."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.data.bias import RadarBias
from graphcal.io.folder import load_sites, write_dataset
from tests.synthetic import Track, make_dataset, site_at

runner = CliRunner()

SITES = {
    "RA": dict(east_m=0.0, north_m=0.0, sigma_range_m=40.0, sigma_azimuth_mrad=1.5),
    "RB": dict(east_m=120e3, north_m=-20e3, sigma_range_m=80.0, sigma_azimuth_mrad=1.0,
               sigma_elevation_mrad=2.0),
}
BIASES = {"RA": RadarBias(150.0, 3e-4, 2.0e-3), "RB": RadarBias(-90.0, -2e-4, -1.5e-3, 1.0e-3)}


def _tracks(rng: np.random.Generator) -> list[Track]:
    tracks = []
    for i in range(10):
        start = (rng.uniform(-60e3, 180e3), rng.uniform(-100e3, 100e3), rng.uniform(6e3, 11e3))
        heading = rng.uniform(0, 2 * np.pi)
        tracks.append(Track(f"4ca{i:03x}", start,
                            (220 * np.sin(heading), 220 * np.cos(heading), 0.0), 0.0, 1500.0))
    return tracks


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two radars (2-D and 3-D) with biases, ADS-B, and truth.json."""
    rng = np.random.default_rng(11)
    radars = []
    for rid, kw in SITES.items():
        east, north = kw["east_m"], kw["north_m"]
        sigmas = {k: v for k, v in kw.items() if k.startswith("sigma")}
        radars.append((site_at(rid, east, north, **sigmas), BIASES[rid]))
    ds = make_dataset(rng, radars, _tracks(rng))
    out = tmp_path_factory.mktemp("cli") / "ds"
    write_dataset(ds, out)
    truth = {"method": "truth", "radars": {}}
    for rid, b in BIASES.items():
        truth["radars"][rid] = {
            "range_offset_m": b.range_offset_m, "range_gain": b.range_gain,
            "azimuth_bias_mrad": b.azimuth_bias_rad * 1e3,
            "elevation_bias_mrad": b.elevation_bias_rad * 1e3 if rid == "RB" else None,
        }
    (out / "truth.json").write_text(json.dumps(truth))
    return out


def _true_sigma(rid: str, key: str) -> float | None:
    return SITES[rid].get(key)


@pytest.mark.parametrize("method", ["adsb", "line-fit"])
def test_noise_writes_sites_with_sigmas_within_10_percent(
    folder: Path, tmp_path: Path, method: str
) -> None:
    before = (folder / "sites.toml").read_text()
    out = tmp_path / "sites.toml"
    result = runner.invoke(app, ["noise", str(folder), "--method", method,
                                 "--write-sites", str(out), "--table", str(tmp_path / "t.csv")])
    assert result.exit_code == 0, result.output
    assert method in result.output and "range [m]" in result.output
    sites = load_sites(out)
    for rid, site in sites.items():
        # Independent expectation: the sigmas the data were simulated with.
        assert site.sigma_range_m == pytest.approx(_true_sigma(rid, "sigma_range_m"), rel=0.10)
        assert site.sigma_azimuth_rad * 1e3 == pytest.approx(
            _true_sigma(rid, "sigma_azimuth_mrad"), rel=0.10)
    assert sites["RB"].sigma_elevation_rad * 1e3 == pytest.approx(2.0, rel=0.10)
    assert sites["RA"].sigma_elevation_rad is None
    table = pd.read_csv(tmp_path / "t.csv")
    assert set(table["radar_id"]) == {"RA", "RB"} and table["n_plots"].sum() > 0
    assert (folder / "sites.toml").read_text() == before  # the input is never modified


def test_noise_refuses_to_overwrite_and_rejects_bad_options(folder: Path, tmp_path: Path) -> None:
    existing = tmp_path / "sites.toml"
    existing.write_text("keep me")
    result = runner.invoke(app, ["noise", str(folder), "--write-sites", str(existing)])
    assert result.exit_code == 2 and "--overwrite" in result.output
    assert existing.read_text() == "keep me"
    result = runner.invoke(app, ["noise", str(folder), "--method", "kalman"])
    assert result.exit_code == 2 and "--method" in result.output


def test_calibrate_estimates_sigmas_the_sites_file_leaves_out(folder: Path, tmp_path: Path) -> None:
    data = tmp_path / "nosig"
    data.mkdir()
    for name in ("plots.csv", "adsb.csv"):
        (data / name).write_bytes((folder / name).read_bytes())
    text = "\n".join(line for line in (folder / "sites.toml").read_text().splitlines()
                     if not line.startswith("sigma_"))
    (data / "sites.toml").write_text(text)
    out = tmp_path / "result.json"
    result = runner.invoke(app, ["calibrate", str(data), "--out", str(out)])
    assert result.exit_code == 0, result.output
    doc = json.loads(out.read_text())
    estimated = doc["info"]["estimated_sigmas"]
    assert estimated["RA"]["sigma_range_m"] == pytest.approx(40.0, rel=0.10)
    assert estimated["RB"]["sigma_elevation_mrad"] == pytest.approx(2.0, rel=0.10)
    # RB had no sigma at all: made 3-D from its plots, so its elevation bias is estimated.
    rb = doc["radars"]["RB"]
    three_sigma = 3 * rb["sigma"]["elevation_bias_mrad"]
    assert rb["elevation_bias_mrad"] == pytest.approx(1.0, abs=three_sigma)
    for rid, bias in BIASES.items():
        entry = doc["radars"][rid]
        assert abs(entry["azimuth_bias_mrad"] - bias.azimuth_bias_rad * 1e3) < (
            3 * entry["sigma"]["azimuth_bias_mrad"])
        assert abs(entry["range_offset_m"] - bias.range_offset_m) < 3 * entry["sigma"][
            "range_offset_m"]
    result = runner.invoke(app, ["calibrate", str(data)])
    assert "sites.toml gives no sigma_range_m" in result.output


def test_fuse_scores_tracks_before_and_after_calibration(folder: Path, tmp_path: Path) -> None:
    out = tmp_path / "fused.parquet"
    result = runner.invoke(app, ["fuse", str(folder), "--calibration",
                                 str(folder / "truth.json"), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "fused, covariance weights" in result.output and "RMSE before [m]" in result.output
    tracks = pd.read_parquet(out)
    assert {"time_s", "target_id", "lat_deg", "lon_deg", "alt_m", "sigma_m"} <= set(tracks)
    assert tracks["n_radars"].max() == 2


def test_fuse_numbers_match_the_library(folder: Path) -> None:
    from graphcal.io.folder import load_dataset
    from graphcal.tracking.fusion import FUSED_COV, compare_fusion

    table = compare_fusion(load_dataset(folder), folder / "truth.json")
    # Correcting the true biases (hundreds of metres of shift) must improve the fused track.
    assert table.loc[FUSED_COV, "rmse_after_m"] < 0.8 * table.loc[FUSED_COV, "rmse_before_m"]
    result = runner.invoke(app, ["fuse", str(folder), "--calibration", str(folder / "truth.json")])
    assert f"{table.loc[FUSED_COV, 'rmse_after_m']:.1f}" in result.output


def test_fuse_bad_output_suffix_exits_2(folder: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["fuse", str(folder), "--out", str(tmp_path / "x.txt")])
    assert result.exit_code == 2


def test_estimators_fill_missing_sigmas_when_called_directly(folder: Path) -> None:
    from graphcal.io.folder import load_dataset
    from graphcal.solvers.registry import METHODS

    ds = load_dataset(folder)
    sites = {rid: replace(s, sigma_range_m=float("nan")) for rid, s in ds.sites.items()}
    cal = METHODS["ls"](replace(ds, sites=sites))
    assert set(cal.info["estimated_sigmas"]) == {"RA", "RB"}
    assert np.isfinite(cal.estimate).all()
