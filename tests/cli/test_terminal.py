"""The terminal: the calibrate table at 80 columns, choices in the help, ``--version``,
warnings also with ``--out``, and progress lines on the commands that take seconds."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal import __version__
from graphcal.cli.app import app
from graphcal.data.bias import RadarBias
from graphcal.io.folder import write_dataset
from graphcal.reporting.tables import format_value
from tests.synthetic import Track, make_dataset, site_at

ROOT = Path(__file__).resolve().parents[2]
runner = CliRunner()
LONG_ID = "LONGRANGE_NORTH_RADAR_01"
BIASES = {LONG_ID: RadarBias(-1234.5, -3.2e-4, 2.5e-3), "RB": RadarBias(-30.0, 1e-4, -1e-3)}


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two radars, one with a long id, ADS-B and a truth.json (its table: 4 value columns)."""
    rng = np.random.default_rng(5)
    tracks = [Track(f"4ca{i:03x}", (rng.uniform(-40e3, 120e3), rng.uniform(-60e3, 60e3), 9e3),
                    (210.0 * np.cos(i), 210.0 * np.sin(i), 0.0), 0.0, 600.0) for i in range(6)]
    ds = make_dataset(rng, [(site_at(LONG_ID, 0.0, 0.0), BIASES[LONG_ID]),
                            (site_at("RB", 90e3, 0.0), BIASES["RB"])], tracks)
    out = write_dataset(ds, tmp_path_factory.mktemp("terminal") / "ds")
    truth = {"method": "truth", "radars": {
        rid: {"range_offset_m": b.range_offset_m, "range_gain": b.range_gain,
              "azimuth_bias_mrad": b.azimuth_bias_rad * 1e3, "elevation_bias_mrad": None}
        for rid, b in BIASES.items()}}
    (out / "truth.json").write_text(json.dumps(truth))
    return out


def _graphcal(*argv: str, columns: int | None = None, **env: str) -> subprocess.CompletedProcess:
    environment = {**os.environ, "PYTHONPATH": str(ROOT), **env}
    environment.pop("COLUMNS", None)
    if columns is not None:
        environment["COLUMNS"] = str(columns)
    return subprocess.run([sys.executable, "-m", "graphcal", *argv], cwd=ROOT,
                          env=environment, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("columns", [40, 60, 80, 100])
def test_calibrate_table_fits_the_width_and_cuts_nothing(folder: Path, tmp_path: Path,
                                                         columns: int) -> None:
    """Piped with ``COLUMNS``: no line wider than the terminal, no ellipsis, and every id
    and every ``value ± sigma`` of the same run's result JSON printed whole."""
    out = tmp_path / "r.json"
    assert _graphcal("calibrate", str(folder), "--method", "ls", "--out", str(out)).returncode == 0
    shown = _graphcal("calibrate", str(folder), "--method", "ls", columns=columns)
    assert shown.returncode == 0, shown.stderr
    lines = shown.stdout.splitlines()
    assert max(len(line) for line in lines) <= columns
    assert "…" not in shown.stdout
    doc = json.loads(out.read_text())
    text = shown.stdout
    for rid, entry in doc["radars"].items():
        assert re.search(rf"(^|\s){rid}\b", text, re.MULTILINE), rid
        for key, sigma in entry["sigma"].items():
            assert format_value(key, entry[key], sigma) in text, (rid, key)
    assert format_value("range_offset_m", BIASES[LONG_ID].range_offset_m) in text  # truth


def test_wide_terminal_keeps_one_table(folder: Path) -> None:
    shown = _graphcal("calibrate", str(folder), "--method", "ls", columns=200)
    assert shown.stdout.count("graphcal calibration, method ls") == 1
    assert max(len(line) for line in shown.stdout.splitlines()) <= 200


@pytest.mark.parametrize(("command", "choices"), [
    ("calibrate", ["graph|ls|fl|fl-ls|wls|wls-pruned", "pairwise|target-state|none",
                   "huber|cauchy|none", "auto|on|off", "plots|neighbours",
                   "segment|track|observation"]),
    ("simulate", ["csv|parquet"]),
    ("noise", ["auto|adsb|line-fit"]),
    ("observability", ["graph|wls", "observation|segment|track"]),
    ("import-asterix", ["csv|parquet", "asterix|opensky"]),
])
def test_choices_are_listed_in_the_help(command: str, choices: list[str]) -> None:
    result = runner.invoke(app, [command, "--help"], env={"COLUMNS": "250"})
    assert result.exit_code == 0
    text = "".join(result.output.split())
    for choice in choices:
        assert choice in text, choice
    assert "<str>" not in result.output


def test_version() -> None:
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0
    assert result.output.strip() == f"graphcal {__version__}"


def test_warnings_are_printed_with_out(folder: Path, tmp_path: Path) -> None:
    """sites.toml without sigmas: the estimator's warnings, with and without --out."""
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("plots.csv", "adsb.csv"):
        (bare / name).write_bytes((folder / name).read_bytes())
    (bare / "sites.toml").write_text("\n".join(
        line for line in (folder / "sites.toml").read_text().splitlines()
        if not line.startswith("sigma_")))
    printed = runner.invoke(app, ["calibrate", str(bare), "--method", "ls"])
    written = runner.invoke(app, ["calibrate", str(bare), "--method", "ls",
                                  "--out", str(tmp_path / "r.json")])
    assert printed.exit_code == 0 and written.exit_code == 0
    warnings = [line for line in printed.output.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 2  # one per radar: its sigmas were estimated
    assert warnings == [line for line in written.output.splitlines()
                        if line.startswith("warning:")]


@pytest.mark.parametrize(("argv", "label"), [
    (["noise", "{ds}"], "graphcal: estimating the noise"),
    (["report", "{result}", "{ds}", "--out", "{tmp}/r.html"], "graphcal: writing the report"),
    (["correct", "{ds}", "{result}", "--out", "{tmp}/corrected"], "graphcal: correcting"),
    (["observability", "{ds}", "--budget", "100"], "graphcal: selections of 100 observations"),
])
def test_slow_commands_print_progress_when_piped(folder: Path, tmp_path: Path,
                                                 argv: list[str], label: str) -> None:
    result = tmp_path / "truth-result.json"
    done = _graphcal("calibrate", str(folder), "--method", "ls", "--out", str(result))
    assert done.returncode == 0, done.stderr
    names = {"ds": str(folder), "result": str(result), "tmp": str(tmp_path)}
    done = _graphcal(*(a.format(**names) for a in argv), GRAPHCAL_PROGRESS_S="0.001")
    assert done.returncode == 0, done.stderr
    assert label in done.stderr
    assert "\x1b" not in done.stderr
