"""``calibrate``: options the chosen method (or the missing ``--select``, ``--window``) leaves
unused are refused with exit status 2 and a line saying why, before any data is read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli import calibrate_options as options
from graphcal.cli.app import app
from graphcal.data.bias import RadarBias
from graphcal.io.folder import write_dataset
from tests.synthetic import Track, make_dataset, site_at

runner = CliRunner()


@pytest.mark.parametrize(("argv", "why"), [
    (["--method", "ls", "--no-adsb"], "ls estimates each radar against ADS-B and needs it"),
    (["--method", "fl-ls", "--no-adsb"], "needs it"),
    (["--method", "wls", "--adsb"], "uses only the radars' common observations"),
    (["--method", "wls-pruned", "--no-adsb"], "never ADS-B"),
    (["--budget", "100"], "--budget applies to a selection"),
    (["--select-unit", "track"], "--select-unit applies to a selection"),
    (["--select", "greedy", "--select-seed", "3"], "--select greedy draws nothing"),
    (["--select", "random", "--select-unit", "track", "--segment-s", "30"],
     "--segment-s applies to --select-unit segment"),
    (["--method", "wls-pruned", "--select", "greedy"], "would prune twice"),
    (["--method", "wls", "--robust", "huber"], "--robust applies to graph; wls does not use it"),
    (["--method", "ls", "--cross", "none"], "--cross applies to graph"),
    (["--method", "fl", "--fix", "RA.range_gain=0"], "--fix applies to graph"),
    (["--method", "ls", "--time-offset", "on"], "--time-offset applies to graph"),
    (["--method", "graph", "--iterations", "2"], "--iterations applies to wls and wls-pruned"),
    (["--method", "ls", "--linearise", "neighbours"], "--linearise applies to wls"),
    (["--robust", "none", "--robust-scale", "2"], "with --robust none there is none"),
    (["--drift", "range_offset_m=1"], "--drift applies to calibrations over time"),
    (["--no-steps"], "applies to calibrations over time"),
    (["--window", "10min", "--method", "wls"], "--window calibrates with the graph method"),
    (["--window", "10min", "--select", "random"], "each window uses all its data"),
    (["--window", "10min", "--init", "ls"], "--init does not apply with --window"),
    (["--window", "10min", "--model-checks"], "not run per window"),
    (["--window", "10min", "--report", "r.html"], "run 'graphcal report' on it"),
    (["--out", "r.json", "--truth", "t.json"], "with --out alone it is not used"),
    (["--method", "magic"], "unknown method 'magic'"),
    (["--cross", "everything"],
     "--cross: unknown cross-radar mode 'everything'; use one of: trajectory, pairwise, "
     "target-state, none"),
    (["--select", "best"], "--select: unknown selection method 'best'; use one of: greedy, "
     "e-optimal, d-optimal, random"),
])
def test_unused_or_unknown_options_are_refused(tmp_path: Path, argv: list[str],
                                               why: str) -> None:
    """The folder does not exist: the refusal comes before anything is read."""
    result = runner.invoke(app, ["calibrate", str(tmp_path / "not-read"), *argv])
    assert result.exit_code == 2, result.output
    assert result.output.startswith("error: ") and result.output.count("\n") == 1
    assert why in result.output


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rng = np.random.default_rng(8)
    tracks = [Track(f"4ca{i:03x}", (rng.uniform(-40e3, 120e3), rng.uniform(-60e3, 60e3), 9e3),
                    (210.0 * np.cos(i), 210.0 * np.sin(i), 0.0), 0.0, 600.0) for i in range(6)]
    ds = make_dataset(rng, [(site_at("RA", 0.0, 0.0), RadarBias(40.0, 1e-4, 1e-3)),
                            (site_at("RB", 90e3, 0.0), RadarBias(-30.0, 0.0, -1e-3))], tracks)
    return write_dataset(ds, tmp_path_factory.mktemp("options") / "ds")


@pytest.mark.parametrize("argv", [
    ["--method", "ls", "--adsb"],               # what ls does anyway
    ["--method", "wls", "--iterations", "2", "--linearise", "neighbours"],
    ["--select", "random", "--budget", "200", "--select-seed", "1", "--method", "ls"],
])
def test_options_that_apply_run(folder: Path, tmp_path: Path, argv: list[str]) -> None:
    result = runner.invoke(app, ["calibrate", str(folder), *argv,
                                 "--out", str(tmp_path / "r.json")])
    assert result.exit_code == 0, result.output


def test_choices_match_the_modules_that_own_them() -> None:
    from graphcal.analysis.selection import SELECTION_METHODS, SELECTION_UNITS
    from graphcal.model.cross_radar import LINEARISE_CHOICES
    from graphcal.model.factor_set import CROSS_MODES
    from graphcal.model.robust import KERNELS
    from graphcal.pipeline.calibrate import TIME_OFFSET_CHOICES
    from graphcal.solvers.registry import METHODS

    assert set(options.METHOD_CHOICES) == set(METHODS)
    assert set(options.INIT_CHOICES) == {"auto", "zero", *METHODS} - {"graph"}
    assert set(options.CROSS_CHOICES) == set(CROSS_MODES)
    assert set(options.ROBUST_CHOICES) == set(KERNELS)
    assert set(options.TIME_OFFSET_CHOICES) == set(TIME_OFFSET_CHOICES)
    assert set(options.LINEARISE_CHOICES) == set(LINEARISE_CHOICES)
    assert set(options.SELECT_CHOICES) == set(SELECTION_METHODS)
    assert set(options.SELECT_UNIT_CHOICES) == set(SELECTION_UNITS)
