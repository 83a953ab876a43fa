"""import-asterix's sites template, missing positions and 3-D check; calibrate --cat063 codes."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.io.asterix.encode import encode_dataset
from graphcal.io.folder import write_dataset, write_sites
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.io.test_asterix_read import CAT034, CAT048, block, plot_record, site_record
from tests.paths import SCENARIOS

runner = CliRunner()


def _recording(folder: Path) -> Path:
    """Radars SIC 1 (3 plots), 2 (2 plots, CAT034 position) and 3 (1 plot)."""
    data = b"".join(block(CAT048, [plot_record(100.0 + i, sic=sic) for i in range(n)])
                    for sic, n in ((1, 3), (2, 2), (3, 1)))
    data += block(CAT034, [site_record(sic=2, lat=47.5, lon=8.25, height=500.0)])
    path = folder / "rec.raw"
    path.write_bytes(data)
    return path


def test_missing_positions_named_in_one_error_then_template_filled_in(tmp_path: Path) -> None:
    rec = _recording(tmp_path)
    out = tmp_path / "ds"
    result = runner.invoke(app, ["import-asterix", str(rec), "--out", str(out)])
    assert result.exit_code == 2
    message = result.output
    assert "2 radars" in message and "SIC 1 " in message and "SIC 3 " in message
    assert "--write-sites-template" in message and "Traceback" not in message
    assert not out.exists()

    template = tmp_path / "sites.toml"
    result = runner.invoke(app, ["import-asterix", str(rec), "--out", str(out),
                                 "--write-sites-template", str(template)])
    assert result.exit_code == 0, result.output
    assert not out.exists()  # no dataset written
    text = template.read_text()
    radars = tomllib.loads(text)["radar"]
    assert [(r["id"], r["sac"], r["sic"]) for r in radars] == [
        ("SAC025_SIC001", 25, 1), ("SAC025_SIC002", 25, 2), ("SAC025_SIC003", 25, 3)]
    assert "# 3 CAT048 reports" in text and "# 1 CAT048 reports" in text
    assert np.isnan(radars[0]["lat_deg"]) and np.isnan(radars[2]["alt_m"])
    assert (radars[1]["lat_deg"], radars[1]["lon_deg"], radars[1]["alt_m"]) == \
        pytest.approx((47.5, 8.25, 500.0), abs=1e-4)  # CAT034 I120 LSBs

    again = runner.invoke(app, ["import-asterix", str(rec), "--write-sites-template",
                                str(template)])
    assert again.exit_code == 2 and "--overwrite" in again.output
    unfilled = runner.invoke(app, ["import-asterix", str(rec), "--sites", str(template),
                                   "--out", str(out)])
    assert unfilled.exit_code == 2 and "lat_deg" in unfilled.output
    template.write_text(text.replace("= nan", "= 46.0"))
    result = runner.invoke(app, ["import-asterix", str(rec), "--sites", str(template),
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    sites = tomllib.loads((out / "sites.toml").read_text())["radar"]
    assert sorted((r["sac"], r["sic"]) for r in sites) == [(25, 1), (25, 2), (25, 3)]
    overwrite = runner.invoke(app, ["import-asterix", str(rec), "--write-sites-template",
                                    str(template), "--overwrite"])
    assert overwrite.exit_code == 0 and "= nan" in template.read_text()


def test_3d_sites_for_2d_records_refused_before_writing(tmp_path: Path) -> None:
    rec = _recording(tmp_path)
    sites = tmp_path / "sites.toml"
    sites.write_text("".join(
        f'[[radar]]\nid = "R{sic}"\nsac = 25\nsic = {sic}\nlat_deg = 46.0\nlon_deg = 8.0\n'
        "alt_m = 400.0\nsigma_range_m = 50.0\nsigma_azimuth_mrad = 1.0\n"
        + ("sigma_elevation_mrad = 2.0\n" if sic == 3 else "") for sic in (1, 2, 3)))
    out = tmp_path / "ds"
    result = runner.invoke(app, ["import-asterix", str(rec), "--sites", str(sites),
                                 "--out", str(out)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "radar R3 " in lines[0] and "3-D in the sites.toml" in lines[0]
    assert not out.exists()


@pytest.fixture(scope="module")
def dataset_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Paper 003's 2-D radar R2D (an id without a SAC/SIC) with ADS-B."""
    run = simulate(load_scenario(SCENARIOS / "paper003_adsb_2d.toml"), np.random.default_rng(3))
    folder = tmp_path_factory.mktemp("cat063") / "ds"
    write_dataset(run.dataset, folder)
    return folder


def test_cat063_without_a_code_fails_before_the_estimation(dataset_folder: Path,
                                                            tmp_path: Path) -> None:
    export = tmp_path / "biases.json"
    result = runner.invoke(app, ["calibrate", str(dataset_folder), "--cat063", str(export)])
    assert result.exit_code == 2
    assert "R2D" in result.output and "--sac-sic" in result.output
    assert "observability" not in result.output  # no estimate was printed
    assert not export.exists()
    for bad in ("R2D=25", "R2D=25/999", "R2D:25/201"):
        result = runner.invoke(app, ["calibrate", str(dataset_folder), "--cat063",
                                     str(export), "--sac-sic", bad])
        assert result.exit_code == 2 and "--sac-sic" in result.output, bad
    result = runner.invoke(app, ["calibrate", str(dataset_folder), "--cat063", str(export),
                                 "--sac-sic", "NOPE=1/2"])
    assert result.exit_code == 2 and "NOPE" in result.output
    result = runner.invoke(app, ["calibrate", str(dataset_folder), "--sac-sic", "R2D=1/2"])
    assert result.exit_code == 2 and "--cat063" in result.output


def test_cat063_with_sac_sic_option_and_from_sites(dataset_folder: Path,
                                                    tmp_path: Path) -> None:
    export = tmp_path / "biases.json"
    result = runner.invoke(app, ["calibrate", str(dataset_folder), "--cat063", str(export),
                                 "--sac-sic", "R2D=25/201"])
    assert result.exit_code == 0, result.output
    (record,) = json.loads(export.read_text())["records"]
    assert (record["sac"], record["sic"]) == (25, 201)
    for entry in record["fields"].values():
        if entry["value"] is not None:
            assert entry["value"] == entry["count"] * entry["lsb"]
    # The same code from the dataset's sites.toml (sac/sic keys).
    folder = tmp_path / "with_codes"
    folder.mkdir()
    for name in ("plots.csv", "adsb.csv"):
        (folder / name).write_bytes((dataset_folder / name).read_bytes())
    text = (dataset_folder / "sites.toml").read_text()
    (folder / "sites.toml").write_text(text.replace('id = "R2D"', 'id = "R2D"\nsac = 7\nsic = 9'))
    result = runner.invoke(app, ["calibrate", str(folder), "--cat063", str(export),
                                 "--overwrite"])
    assert result.exit_code == 0, result.output
    (record,) = json.loads(export.read_text())["records"]
    assert (record["sac"], record["sic"]) == (7, 9)


def test_encoded_3d_network_imports_as_3d(tmp_path: Path) -> None:
    """A 3-D radar's I048/110 heights become elevations the loader accepts as 3-D."""
    run = simulate(load_scenario(SCENARIOS / "paper002_three_radars.toml"),
                   np.random.default_rng(5))
    ds = run.dataset
    near = ds.plots[ds.plots["range_m"] < 250.0 * 1852.0]
    ds.plots = near.groupby("radar_id").head(40).reset_index(drop=True)
    codes = {rid: (25, 10 + k) for k, rid in enumerate(ds.sites)}
    rec = tmp_path / "rec.ast"
    rec.write_bytes(encode_dataset(ds, codes))
    sites = tmp_path / "sites.toml"
    write_sites(ds.sites, sites)
    text = sites.read_text()
    for rid, (sac, sic) in codes.items():
        text = text.replace(f'id = "{rid}"', f'id = "{rid}"\nsac = {sac}\nsic = {sic}')
    sites.write_text(text)
    out = tmp_path / "ds"
    result = runner.invoke(app, ["import-asterix", str(rec), "--sites", str(sites),
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    from graphcal.io.folder import load_dataset

    back = load_dataset(out)
    with_plots = set(back.plots["radar_id"])
    assert with_plots and all(back.sites[rid].is_3d for rid in with_plots)
    assert np.isfinite(back.plots["elevation_deg"]).all()
