"""What the sigmas are (``info["sigma"]`` of the paper methods): a footnote under the
calibrate table and a note in the report's estimates section; and a radar without any
model-check test (a small dataset) gets a line, not a crash."""

from __future__ import annotations

import copy
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.data.calibration import Calibration
from graphcal.io.folder import write_dataset
from graphcal.reporting.html import build_report
from graphcal.reporting.tables import sigma_footnote
from graphcal.solvers.adsb_reference import FL_SIGMA_NOTE, LS_SIGMA_NOTE
from graphcal.solvers.registry import METHODS
from graphcal.solvers.wls import WLS_SIGMA_NOTE
from tests.paths import SCENARIOS
from tests.reporting.test_report import BIASES, TRACKS
from tests.synthetic import make_dataset, site_at

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def dataset():
    sites = [site_at("RA", -20e3, 0.0), site_at("RB", 30e3, 5e3, sigma_elevation_mrad=2.0)]
    return make_dataset(np.random.default_rng(3), [(s, BIASES[s.id]) for s in sites], TRACKS)


def _section(page: str, sid: str) -> str:
    return page.split(f'<h2 id="{sid}">')[1].split("<h2 id=")[0]


def test_footnote_text(dataset) -> None:
    cal = METHODS["ls"](dataset)
    assert cal.info["sigma"] == LS_SIGMA_NOTE
    assert sigma_footnote(cal) == f"σ: {LS_SIGMA_NOTE}"
    graph = copy.copy(cal)
    graph.info = {k: v for k, v in cal.info.items() if k != "sigma"}
    assert sigma_footnote(graph) is None
    for note in (FL_SIGMA_NOTE, WLS_SIGMA_NOTE):
        assert note.startswith("formal (paper 00")


@pytest.mark.parametrize("method", ["ls", "wls"])
def test_report_estimates_say_what_the_sigmas_are(dataset, method: str) -> None:
    cal = METHODS[method](dataset)
    estimates = _section(build_report(cal, dataset, crlb=False), "estimates")
    assert '<p class="note sigma">σ: formal (paper 00' in estimates
    graph = _section(build_report(METHODS["graph"](dataset), dataset, crlb=False), "estimates")
    assert "note sigma" not in graph


def test_json_round_trip_keeps_the_note(dataset, tmp_path: Path) -> None:
    cal = METHODS["wls"](dataset)
    cal.write_json(tmp_path / "r.json")
    assert sigma_footnote(Calibration.read_json(tmp_path / "r.json")) == f"σ: {WLS_SIGMA_NOTE}"


def test_calibrate_prints_the_footnote_under_the_table(dataset, tmp_path: Path) -> None:
    folder = tmp_path / "ds"
    write_dataset(dataset, folder)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "80", "NO_COLOR": "1"}
    done = subprocess.run([sys.executable, "-m", "graphcal", "calibrate", str(folder),
                           "--method", "wls"], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("σ: formal (paper 001"))
    following = [line for line in lines[start + 1:] if line.startswith("  ")]
    assert " ".join([lines[start], *following]).split() == f"σ: {WLS_SIGMA_NOTE}".split()
    assert lines[start + 1 + len(following)].startswith("observability degree")
    assert max(len(line) for line in lines) <= 80
    graph = CliRunner().invoke(app, ["calibrate", str(folder)])
    assert graph.exit_code == 0, graph.output
    assert "σ:" not in graph.output


def test_model_checks_without_tests_say_so(dataset) -> None:
    """A radar whose residuals are too few for any test: a line instead of a figure."""
    from graphcal.analysis.model_checks import model_checks

    cal = METHODS["graph"](dataset)
    checks = model_checks(dataset, cal).to_dict()
    checks["radars"]["RB"]["tests"] = []
    checks["radars"]["RB"]["n_tests"] = 0
    checked = copy.copy(cal)
    checked.info = {**cal.info, "model_checks": checks}
    section = _section(build_report(checked, dataset, crlb=False), "model-checks")
    assert "No test: too few residuals to bin" in section
    assert section.count("<img") == 1  # RA only


#: Scenarios small enough to simulate and calibrate in a test (seconds each).
SMALL_SCENARIOS = ["paper002_three_radars.toml", "paper003_adsb_2d.toml"]


@pytest.mark.parametrize("scenario", SMALL_SCENARIOS)
def test_calibrate_report_on_small_scenarios(scenario: str, tmp_path: Path) -> None:
    """``calibrate --report`` writes the report on the bundled small scenarios (it used to
    crash drawing the model checks of radars with no test)."""
    runner = CliRunner()
    folder = tmp_path / "ds"
    done = runner.invoke(app, ["simulate", str(SCENARIOS / scenario), "--out", str(folder),
                               "--seed", "1"])
    assert done.exit_code == 0, done.output
    report = tmp_path / "r.html"
    done = runner.invoke(app, ["calibrate", str(folder), "--report", str(report)])
    assert done.exit_code == 0, done.output
    page = report.read_text(encoding="utf-8")
    assert '<h2 id="model-checks">' in page and page.rstrip().endswith("</html>")
