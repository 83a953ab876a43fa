"""Progress off a terminal: plain lines on standard error, and a calibration's imports.

When standard error is a pipe or a file the rich bar is off; long work then prints
``graphcal: <command>: <stage> ..., <seconds> s`` lines, at most one every
``PLAIN_PROGRESS_INTERVAL_S`` (``GRAPHCAL_PROGRESS_S``).  The intervals below are set so
that the outcome does not depend on the machine's speed.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from graphcal.cli.common import progress_bar
from graphcal.data.bias import RadarBias
from graphcal.io.folder import write_dataset
from tests.synthetic import Track, make_dataset, site_at

ROOT = Path(__file__).resolve().parents[2]
LINE = re.compile(r"^graphcal: graph(: [^,]+)?, \d+ s$")


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A two-radar dataset with ADS-B, written as a dataset folder."""
    rng = np.random.default_rng(21)
    sites = [(site_at("RA", 0.0, 0.0), RadarBias(50.0, 1e-4, 1e-3)),
             (site_at("RB", 90e3, 10e3, sigma_elevation_mrad=2.0),
              RadarBias(-30.0, 0.0, -1e-3, 5e-4))]
    tracks = [Track(f"4ca{i:03x}", (rng.uniform(-50e3, 140e3), rng.uniform(-80e3, 80e3), 9e3),
                    (200.0 * np.cos(i), 200.0 * np.sin(i), 0.0), 0.0, 600.0) for i in range(6)]
    out = tmp_path_factory.mktemp("progress") / "data"
    write_dataset(make_dataset(rng, sites, tracks), out)
    return out


def _calibrate(folder: Path, out: Path, interval_s: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "GRAPHCAL_PROGRESS_S": interval_s, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "graphcal", "calibrate", str(folder), "--out", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, check=True, timeout=300,
    )


def test_piped_calibration_prints_plain_progress_lines(folder: Path, tmp_path: Path) -> None:
    done = _calibrate(folder, tmp_path / "result.json", "0.02")
    lines = [line for line in done.stderr.splitlines() if line.startswith("graphcal: graph")]
    assert lines, done.stderr
    assert all(LINE.match(line) for line in lines), lines
    assert "\x1b" not in done.stderr  # plain text: no terminal control sequences
    assert json.loads((tmp_path / "result.json").read_text())["method"] == "graph"


def test_no_progress_line_before_the_interval(folder: Path, tmp_path: Path) -> None:
    done = _calibrate(folder, tmp_path / "result.json", "1000")
    assert not [line for line in done.stderr.splitlines() if line.startswith("graphcal: ")]
    assert done.stderr.strip().endswith("result.json")


def test_plain_progress_reports_the_latest_stage_and_share(monkeypatch, capsys) -> None:
    """In process, off a terminal: the line gives the stage last reported and its share."""
    monkeypatch.setenv("GRAPHCAL_PROGRESS_S", "0.05")
    with progress_bar("work") as callback:
        callback("building factors", 120000, 300000)
        time.sleep(0.4)
    lines = capsys.readouterr().err.splitlines()
    assert lines and lines[0] == "graphcal: work: building factors 40% (120000/300000), 0 s"
    assert len(lines) <= 9  # at most one line per interval


@pytest.mark.parametrize(("extra", "module"), [
    ([], "graphcal.analysis.model_checks"),
    (["--window", "5min"], "graphcal.solvers.drift"),
])
def test_a_default_calibration_imports_no_scipy_stats(folder: Path, tmp_path: Path,
                                                      extra: list[str], module: str) -> None:
    """scipy.stats' import costs a fifth of a small calibration (a second of a 1M-plot
    windowed one); the default path uses scipy.special only (robust thresholds,
    chi-square tails, the step tests)."""
    script = (
        "import json, sys\n"
        "from graphcal.cli.app import app\n"
        f"sys.argv = ['graphcal', 'calibrate', {str(folder)!r}, '--out', "
        f"{str(tmp_path / 'r.json')!r}, *{extra!r}]\n"
        "try:\n    app()\nexcept SystemExit:\n    pass\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True,
                          text=True, check=True, timeout=300)
    modules = set(json.loads(done.stdout.splitlines()[-1]))
    assert module in modules  # the whole run happened
    assert not [m for m in modules if m == "scipy.stats" or m.startswith("scipy.stats.")]
