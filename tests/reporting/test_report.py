"""The HTML report (graphcal.reporting.html) and the ``report`` command."""

from __future__ import annotations

import base64
import io
import math
import re

import numpy as np
import pytest
import typer
from PIL import Image
from typer.testing import CliRunner

from graphcal.cli.report import report_command
from graphcal.data.bias import RadarBias
from graphcal.io.folder import load_dataset, write_dataset
from graphcal.reporting.html import SECTIONS, build_report, write_report, write_report_for
from graphcal.solvers.registry import METHODS
from tests.synthetic import Track, make_dataset, site_at

BIASES = {
    "RA": RadarBias(range_offset_m=90.0, range_gain=3e-4, azimuth_bias_rad=2e-3),
    "RB": RadarBias(range_offset_m=-60.0, range_gain=-2e-4, azimuth_bias_rad=-3e-3,
                    elevation_bias_rad=1e-3),
}
TRACKS = [
    Track("aa0001", (-60e3, 10e3, 9000.0), (220.0, 10.0, 0.0), 0.0, 600.0),
    Track("aa0002", (20e3, -50e3, 7000.0), (-30.0, 200.0, 0.0), 0.0, 600.0),
    Track("aa0003", (-40e3, 45e3, 6000.0), (150.0, -120.0, 0.0), 0.0, 600.0),
]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def scenario():
    sites = [site_at("RA", -20e3, 0.0), site_at("RB", 30e3, 5e3, sigma_elevation_mrad=2.0)]
    dataset = make_dataset(np.random.default_rng(3), [(s, BIASES[s.id]) for s in sites], TRACKS)
    cal = METHODS["graph"](dataset)
    return dataset, cal


@pytest.fixture(scope="module")
def page(scenario):
    dataset, cal = scenario
    return build_report(cal, dataset, truth=BIASES, crlb=False)


def _images(text: str) -> list[bytes]:
    return [base64.b64decode(m, validate=True)
            for m in re.findall(r'<img src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)]


def test_report_has_every_section(page) -> None:
    assert page.startswith("<!DOCTYPE html>")
    for sid, _ in SECTIONS:
        assert re.search(rf'<h2 id="{sid}">', page), sid
    for sid in ("estimates", "residuals", "histograms", "map", "correlation", "observability",
                "data"):
        assert f'id="{sid}"' in page


def test_report_images_are_valid_embedded_pngs(page) -> None:
    images = _images(page)
    # before/after, binned and histograms per radar, the map (the correlation is a table)
    assert len(images) == 3 * 2 + 1
    assert page.count("<img") == len(images)
    for png in images:
        assert png.startswith(PNG_SIGNATURE)
        assert len(png) > 5000
        with Image.open(io.BytesIO(png)) as image:
            image.load()
            assert image.size[0] > 200 and image.size[1] > 150
    # Self-contained: no external resources.
    assert not re.search(r'(src|href)="(https?:|//|file:)', page)


def test_report_estimates_show_each_radar_with_truth(page, scenario) -> None:
    _, cal = scenario
    estimates = page.split('<h2 id="estimates">')[1].split("<h2 ")[0]
    for rid in ("RA", "RB"):
        assert f'<td class="l">{rid}</td>' in estimates
    assert "azimuth bias" in estimates and "elevation bias" in estimates
    assert "truth" in estimates and "error / σ" in estimates
    # Display units: the gain in ppm, decimals from its sigma (2 significant digits).
    gain_ppm = cal.value("RA", "range_gain") * 1e6
    sigma_ppm = cal.sigma("RA", "range_gain") * 1e6
    decimals = max(0, 1 - math.floor(math.log10(sigma_ppm)))
    row = next(r for r in re.findall(r"<tr[^>]*>(.*?)</tr>", estimates)
               if "range gain" in r and ">ppm<" in r)
    assert f">{gain_ppm:.{decimals}f}<" in row
    assert "0.000" not in row  # not the fraction


def test_report_without_adsb_still_builds(scenario) -> None:
    dataset, cal = scenario
    no_adsb = type(dataset)(dataset.sites, dataset.plots, None)
    text = build_report(cal, no_adsb, crlb=False)
    for sid, _ in SECTIONS:
        assert f'<h2 id="{sid}">' in text
    # Without ADS-B the residuals are radar versus radar.
    assert "the other radars' corrected plots" in text
    pairs = text.split('<h2 id="pairs">')[1].split("<h2 id=")[0]
    assert "<table" in pairs and "minus partner" in pairs


def test_write_report_and_pdf(tmp_path, scenario) -> None:
    dataset, cal = scenario
    out = write_report(tmp_path / "r.html", cal, dataset, crlb=False, pdf=tmp_path / "r.pdf")
    assert out.read_text(encoding="utf-8").startswith("<!DOCTYPE html>")
    assert (tmp_path / "r.pdf").read_bytes().startswith(b"%PDF")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.html", "r.pdf"]  # no temporaries


@pytest.fixture()
def runner_app():
    app = typer.Typer()
    app.command(name="report")(report_command)
    app.command(name="noop")(lambda: None)  # keeps 'report' a named sub-command
    return app


def test_report_command(tmp_path, scenario, runner_app) -> None:
    dataset, cal = scenario
    folder = tmp_path / "ds"
    write_dataset(dataset, folder)
    cal.write_json(tmp_path / "result.json")
    out = tmp_path / "report.html"
    result = CliRunner().invoke(
        runner_app, ["report", str(tmp_path / "result.json"), str(folder), "--out", str(out)]
    )
    assert result.exit_code == 0, result.output
    text = out.read_text(encoding="utf-8")
    assert all(f'<h2 id="{sid}">' in text for sid, _ in SECTIONS)
    assert "RA" in text and "RB" in text


def test_report_command_bad_result_exits_2(tmp_path, scenario, runner_app) -> None:
    dataset, _ = scenario
    folder = tmp_path / "ds"
    write_dataset(dataset, folder)
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    out = tmp_path / "report.html"
    result = CliRunner().invoke(runner_app, ["report", str(bad), str(folder), "--out", str(out)])
    assert result.exit_code == 2
    assert not out.exists()


def test_write_report_for_picks_up_truth_json(tmp_path, scenario) -> None:
    dataset, cal = scenario
    folder = tmp_path / "ds"
    write_dataset(dataset, folder)
    (folder / "truth.json").write_text(
        '{"radars": {"RA": {"range_offset_m": 90.0}, "RB": {"range_offset_m": -60.0}}}'
    )
    loaded = load_dataset(folder)
    path = write_report_for(cal, loaded, tmp_path / "x.html")
    assert "error / σ" in path.read_text(encoding="utf-8")


def test_model_checks_section(scenario) -> None:
    """One figure per checked radar, the tests that fired marked, the warnings listed;
    without recorded checks, a note."""
    import copy

    from graphcal.analysis.model_checks import model_checks

    dataset, cal = scenario
    plots = dataset.plots.copy()
    rows = plots["radar_id"] == "RA"
    az = np.deg2rad(plots.loc[rows, "azimuth_deg"].to_numpy())
    plots.loc[rows, "azimuth_deg"] = np.mod(np.rad2deg(az + 3e-3 * np.sin(az)), 360.0)
    eccentric = type(dataset)(dataset.sites, plots, dataset.adsb)
    checked = copy.copy(cal)
    checked.info = {**cal.info, "model_checks": model_checks(eccentric, cal).to_dict()}
    text = build_report(checked, eccentric, crlb=False)
    section = text.split('<h2 id="model-checks">')[1].split("<h2 id=")[0]
    assert len(_images(section)) == 2  # RA and RB
    assert section.count('<span class="warn">fired</span>') >= 1
    assert "RA: unmodelled azimuth residual sinusoidal in azimuth" in section
    assert "antenna eccentricity" in section
    bare = build_report(cal, dataset, crlb=False)
    note = bare.split('<h2 id="model-checks">')[1].split("<h2 id=")[0]
    assert "No model checks recorded" in note and not _images(note)


@pytest.mark.parametrize("determined", [True, False])
def test_report_estimates_show_the_height_model(tmp_path, scenario, determined) -> None:
    """A result with an ``atmosphere`` block (contract v2): its two parameters are rows of
    the estimates table, with the truth of a truth.json and their z-scores."""
    import dataclasses
    import json

    from graphcal.data.height import HeightModelEstimate

    dataset, cal = scenario
    estimate = HeightModelEstimate(190.0, 0.021, np.diag([4.0**2, 1e-3**2]),
                                   np.array([500.0, 0.05]), determined=determined)
    with_height = dataclasses.replace(cal, atmosphere=estimate)
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"radars": {}, "atmosphere": {
        "height_offset_m": 184.0, "height_scale": 0.02, "sigma": {}}}))
    page = build_report(with_height, dataset, truth=truth, crlb=False)
    estimates = page.split('<h2 id="estimates">')[1].split("<h2 ")[0]
    rows = re.findall(r"<tr[^>]*>(.*?)</tr>", estimates, flags=re.S)
    offset = next(r for r in rows if ">height offset<" in r)
    scale = next(r for r in rows if ">height scale<" in r)
    assert "atmosphere" in offset
    if determined:
        # sigma 4 m: one decimal; the scale in ppm (sigma 1000 ppm: no decimal)
        assert ">190.0<" in offset and ">4.0<" in offset and ">184.0<" in offset
        assert ">+1.5<" in offset  # (190 - 184) / 4
        assert ">21000<" in scale.replace("\u2009", "") and ">+1.0<" in scale
    else:
        assert "not determined" in offset and "not determined" in scale


def _recording_row(page: str) -> str:
    return re.search(r"<td>recording</td><td>([^<]*)</td>", page).group(1)


def test_the_header_dates_the_recording_by_its_epoch(scenario, page) -> None:
    """With ``[dataset] epoch_utc`` the header gives the UTC date and time span; across
    midnight the end has its own date; without an epoch, times of day as before."""
    from dataclasses import replace
    from datetime import UTC, datetime, timedelta

    dataset, cal = scenario
    t0, t1 = float(dataset.plots["time_s"].min()), float(dataset.plots["time_s"].max())
    assert 0.0 <= t0 < 10.0 and 590.0 < t1 <= 600.0  # the tracks fly 0-600 s
    epoch = datetime(2021, 10, 7, 8, 0, tzinfo=UTC)
    start, end = (epoch + timedelta(seconds=round(t)) for t in (t0, t1))
    dated = _recording_row(build_report(cal, replace(dataset, epoch_utc=epoch), crlb=False))
    assert dated.startswith(f"2021-10-07 {start:%H:%M:%S} – {end:%H:%M:%S} UTC (")
    assert dated.endswith("counted from epoch_utc 2021-10-07T08:00:00Z)")
    late = datetime(2021, 10, 7, 23, 55, tzinfo=UTC)
    start, end = (late + timedelta(seconds=round(t)) for t in (t0, t1))
    across = _recording_row(build_report(cal, replace(dataset, epoch_utc=late), crlb=False))
    assert across.startswith(f"2021-10-07 {start:%H:%M:%S} – 2021-10-08 {end:%H:%M:%S} UTC")
    # the data section's spans are dated too
    assert f"2021-10-07 {start:%H:%M:%S} – 2021-10-08" in build_report(
        cal, replace(dataset, epoch_utc=late), crlb=False).split('<h2 id="data">')[1]
    undated = _recording_row(page)
    assert undated.startswith("00:00:0") and "2021" not in undated
    assert undated.endswith("counted from 00:00 UTC of the recording's first day)")
