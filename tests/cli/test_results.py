"""Result JSON checked on read (``marginals``, ``report``), ``correct`` refusing a result for
none of the radars and reporting its cleaning, ``simulate`` renaming a complete folder."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.data.bias import RadarBias
from graphcal.io import folder as folder_module
from graphcal.io.folder import write_dataset
from tests.paths import SCENARIOS
from tests.synthetic import Track, make_dataset, site_at

runner = CliRunner()


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """A two-radar dataset and its ls result (a valid covariance)."""
    rng = np.random.default_rng(12)
    tracks = [Track(f"4ca{i:03x}", (rng.uniform(-40e3, 120e3), rng.uniform(-60e3, 60e3), 9e3),
                    (210.0 * np.cos(i), 210.0 * np.sin(i), 0.0), 0.0, 600.0) for i in range(6)]
    ds = make_dataset(rng, [(site_at("RA", 0.0, 0.0), RadarBias(40.0, 1e-4, 1e-3)),
                            (site_at("RB", 90e3, 0.0), RadarBias(-30.0, 0.0, -1e-3))], tracks)
    root = tmp_path_factory.mktemp("results")
    folder = write_dataset(ds, root / "ds")
    out = root / "result.json"
    result = runner.invoke(app, ["calibrate", str(folder), "--method", "ls", "--out", str(out)])
    assert result.exit_code == 0, result.output
    return folder, json.loads(out.read_text())


def _broken(doc: dict, how: str) -> str:
    """The result's text with its covariance broken in one way."""
    bad = copy.deepcopy(doc)
    matrix = bad["covariance"]["matrix"]
    if how == "negative variance":
        matrix[0][0] = -matrix[0][0]
    elif how == "asymmetric":
        matrix[0][1] = matrix[1][0] + 10.0 * math.sqrt(matrix[0][0] * matrix[1][1])
    elif how == "correlation 10":
        value = 10.0 * math.sqrt(matrix[0][0] * matrix[2][2])
        matrix[0][2] = matrix[2][0] = value
    elif how == "NaN":
        matrix[1][1] = float("nan")
    return json.dumps(bad)


@pytest.mark.parametrize(("how", "message"), [
    ("negative variance", "negative variance"),
    ("asymmetric", "not symmetric"),
    ("correlation 10", "not positive semi-definite"),
    ("NaN", "not a finite number"),
])
@pytest.mark.parametrize("command", ["marginals", "report"])
def test_bad_covariance_is_refused(data, tmp_path: Path, how: str, message: str,
                                   command: str) -> None:
    folder, doc = data
    path = tmp_path / "bad.json"
    path.write_text(_broken(doc, how))
    argv = ["marginals", str(path), "--correlation"] if command == "marginals" else [
        "report", str(path), str(folder), "--out", str(tmp_path / "r.html")]
    result = runner.invoke(app, argv)
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: {path}, field 'covariance.matrix': ")
    assert message in result.output
    assert not (tmp_path / "r.html").exists()


def test_valid_result_is_read(data, tmp_path: Path) -> None:
    _, doc = data
    path = tmp_path / "ok.json"
    path.write_text(json.dumps(doc))
    result = runner.invoke(app, ["marginals", str(path), "--correlation"])
    assert result.exit_code == 0, result.output


def test_correct_refuses_a_result_for_none_of_the_radars(data, tmp_path: Path) -> None:
    folder, doc = data
    other = copy.deepcopy(doc)
    other["radars"] = {f"X{rid}": entry for rid, entry in doc["radars"].items()}
    other["covariance"]["labels"] = [f"X{label}" for label in doc["covariance"]["labels"]]
    path = tmp_path / "other.json"
    path.write_text(json.dumps(other))
    result = runner.invoke(app, ["correct", str(folder), str(path),
                                 "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "none of the radars" in result.output and "XRA" in result.output
    assert not (tmp_path / "out").exists()


def test_correct_reports_what_cleaning_dropped(data, tmp_path: Path) -> None:
    """Three plots written twice: the corrected folder has them once, and says so."""
    folder, doc = data
    dirty = tmp_path / "dirty"
    dirty.mkdir()
    for name in ("sites.toml", "adsb.csv"):
        (dirty / name).write_bytes((folder / name).read_bytes())
    plots = pd.read_csv(folder / "plots.csv")
    pd.concat([plots, plots.iloc[[5, 50, 500]]]).to_csv(dirty / "plots.csv", index=False)
    result_path = tmp_path / "r.json"
    result_path.write_text(json.dumps(doc))
    partial = copy.deepcopy(doc)
    partial["radars"].pop("RB")
    partial["covariance"]["labels"], partial["covariance"]["matrix"] = [], []
    partial_path = tmp_path / "partial.json"
    partial_path.write_text(json.dumps(partial))
    result = runner.invoke(app, ["correct", str(dirty), str(partial_path),
                                 "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert "cleaning: 3 exact duplicate plots dropped (not written)" in result.output
    assert "has no biases for RB" in result.output
    assert len(pd.read_csv(tmp_path / "out" / "plots.csv")) == len(plots)


def test_simulate_renames_a_folder_that_holds_truth(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """At the rename that makes the folder appear, truth.json is already in it."""
    seen: list[list[str]] = []
    real = folder_module._move_into_place

    def spy(staging: Path, target: Path, overwrite: bool) -> None:
        seen.append(sorted(p.name for p in staging.iterdir()))
        real(staging, target, overwrite)

    monkeypatch.setattr(folder_module, "_move_into_place", spy)
    result = runner.invoke(app, ["simulate", str(SCENARIOS / "paper003_adsb_2d.toml"),
                                 "--out", str(tmp_path / "ds")])
    assert result.exit_code == 0, result.output
    assert seen == [["adsb.csv", "plots.csv", "sites.toml", "truth.json"]]
