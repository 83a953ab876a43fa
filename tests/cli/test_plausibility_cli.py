"""``--force`` and the fit verdict on the command line: exit 2, then exit 3; the demo passes."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

import graphcal
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
