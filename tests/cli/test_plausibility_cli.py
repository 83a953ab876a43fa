"""``--force`` and the fit verdict on the command line: exit 2, then exit 3; the demo passes."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

import graphcal
from graphcal.analysis.fit_verdict import ModelMisfitError
from graphcal.cli.app import app
from graphcal.io.folder import write_dataset
from tests.paths import SCENARIOS

runner = CliRunner()


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("cli-plaus")
    ds = graphcal.simulate(SCENARIOS / "demo_network.toml", seed=5).dataset
    out = {"demo": write_dataset(ds, root / "demo"), "result": root / "result.json"}
    graphcal.calibrate(ds, "fl-ls", model_checks=False).write_json(out["result"])
    for name, column, scale in (("az_rad", "azimuth_deg", math.pi / 180),
                                ("range_km", "range_m", 1e-3)):
        plots = ds.plots.copy()
        rows = plots["radar_id"] == "NORD"
        plots.loc[rows, column] = plots.loc[rows, column] * scale
        out[name] = write_dataset(replace(ds, plots=plots), root / name)
    return out


@pytest.mark.parametrize(("name", "field"), [("az_rad", "azimuth_deg"), ("range_km", "range_m")])
def test_unit_mistake_exits_2_then_3_with_force(folders, tmp_path: Path, name: str,
                                                field: str) -> None:
    stopped = runner.invoke(app, ["calibrate", str(folders[name])])
    assert stopped.exit_code == 2, stopped.output
    line = " ".join(stopped.output.split())
    assert f"plots.csv, field '{field}'" in line and "NORD" in line and "--force" in line
    out = tmp_path / "result.json"
    forced = runner.invoke(app, ["calibrate", str(folders[name]), "--force", "--out", str(out)])
    assert forced.exit_code == 3, forced.output
    text = " ".join(forced.output.split())
    assert "far beyond their sigmas" in text and "NORD:" in text
    assert "SUD:" not in text  # against ADS-B only the broken radar is named
    assert not out.exists()  # no result for a failed verdict


def test_demo_dataset_passes_and_records_the_verdict(folders, tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    result = runner.invoke(app, ["calibrate", str(folders["demo"]), "--out", str(out)])
    assert result.exit_code == 0, result.output
    verdict = json.loads(out.read_text())["info"]["fit_verdict"]
    assert verdict["passed"] and verdict["failed"] == []
    assert set(verdict["radars"]) == {"NORD", "SUD", "EST3D", "OUEST3D", "APP"}


@pytest.mark.parametrize("command", ["noise", "observability", "fuse", "report", "correct"])
def test_other_commands_stop_on_the_mistake(folders, tmp_path: Path, command: str) -> None:
    args = {
        "noise": ["noise", str(folders["az_rad"])],
        "observability": ["observability", str(folders["az_rad"])],
        "fuse": ["fuse", str(folders["az_rad"])],
        "report": ["report", str(folders["result"]), str(folders["az_rad"]), "--out",
                   str(tmp_path / "r.html")],
        "correct": ["correct", str(folders["az_rad"]), str(folders["result"]), "--out",
                    str(tmp_path / "out")],
    }[command]
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    assert "azimuth_deg" in result.output
    assert "--force" in runner.invoke(app, [command, "--help"]).output


# --------------------------------------------------------------------------- over windows
@pytest.fixture(scope="module")
def seed1(tmp_path_factory) -> dict[str, Path]:
    """The tour's demo network (seed 1) and the same with NORD's azimuths in radians."""
    root = tmp_path_factory.mktemp("cli-window-verdict")
    ds = graphcal.simulate(SCENARIOS / "demo_network.toml", seed=1).dataset
    plots = ds.plots.copy()
    rows = plots["radar_id"] == "NORD"
    plots.loc[rows, "azimuth_deg"] = plots.loc[rows, "azimuth_deg"] * (math.pi / 180)
    return {"demo": write_dataset(ds, root / "demo"),
            "az_rad": write_dataset(replace(ds, plots=plots), root / "az_rad")}


@pytest.mark.parametrize(("window", "spans"), [
    ("1h", "in 1 of 1 windows (0-3600 s)"),
    # 10 minutes: the misfit makes steps appear; it is judged before they are located
    ("10min", "in 3 of 3 windows (0-600 s, 600-1200 s, 1200-1800 s)"),
])
def test_with_windows_the_unit_mistake_exits_3(seed1, tmp_path: Path, window: str,
                                               spans: str) -> None:
    out = tmp_path / "result.json"
    forced = runner.invoke(app, ["calibrate", str(seed1["az_rad"]), "--force", "--window",
                                 window, "--out", str(out)])
    assert forced.exit_code == 3, forced.output
    text = " ".join(forced.output.split())
    # (a slow run prints a progress line first)
    assert text[text.index("error: "):].startswith(
        "error: the residuals are far beyond their sigmas")
    assert f"NORD: {spans}; worst: azimuth chi2/dof" in text
    assert "SUD:" not in text and not out.exists()


def test_with_windows_the_demo_passes_and_records_the_verdict(seed1, tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    result = runner.invoke(app, ["calibrate", str(seed1["demo"]), "--window", "15min",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    verdict = json.loads(out.read_text())["info"]["fit_verdict"]
    assert verdict["passed"] and verdict["failed"] == [] and verdict["reference"] == "adsb"
    assert [(w["t_start_s"], w["t_end_s"], w["failed"]) for w in verdict["windows"]] == [
        (0.0, 900.0, []), (900.0, 1800.0, [])]
    assert set(verdict["radars"]) == {"NORD", "SUD", "EST3D", "OUEST3D", "APP"}
    ratios = [c["chi2_per_dof"] for r in verdict["radars"].values()
              for c in r["coordinates"].values()]
    assert len(ratios) == 12 and max(ratios) < 1.2  # each radar's worst window
    assert all(r["failed_windows"] == [] for r in verdict["radars"].values())


def test_with_windows_check_fit_off_records_the_verdict_as_a_warning(seed1) -> None:
    cal = graphcal.calibrate(seed1["az_rad"], window="1h", force=True, check_fit=False)
    assert cal.info["fit_verdict"]["failed"] == ["NORD"]
    assert cal.info["fit_verdict"]["radars"]["NORD"]["failed_windows"] == [[0.0, 3600.0]]
    assert any("far beyond their sigmas" in w and "NORD: in 1 of 1" in w for w in cal.warnings)
    with pytest.raises(ModelMisfitError) as info:
        graphcal.calibrate(seed1["az_rad"], window="1h", force=True)
    assert info.value.calibration.info["fit_verdict"]["failed"] == ["NORD"]
    assert info.value.calibration.series is not None
