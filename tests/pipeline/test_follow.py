"""Following a folder written as parts: each new part validated and fed to a Calibrator;
the same windows as giving it the whole dataset at once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graphcal.core.errors import DatasetError
from graphcal.io.folder import write_sites
from graphcal.pipeline.follow import follow_folder
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.incremental import Calibrator
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def demo():
    return simulate(load_scenario(SCENARIOS / "demo_network.toml"), np.random.default_rng(1))


def _write_parts(ds, folder: Path, block_s: float = 600.0) -> None:
    (folder / "plots").mkdir(parents=True)
    (folder / "adsb").mkdir()
    write_sites(ds.sites, folder / "sites.toml")
    for k, start in enumerate(np.arange(0.0, 1800.0, block_s)):
        for stem, table in (("plots", ds.plots), ("adsb", ds.adsb)):
            rows = table[(table["time_s"] >= start) & (table["time_s"] < start + block_s)]
            rows.to_csv(folder / stem / f"{k:03d}-{stem}.csv", index=False)


def test_parts_are_fed_as_they_come_and_give_the_same_windows(demo, tmp_path: Path) -> None:
    ds = demo.dataset
    folder = tmp_path / "rec"
    _write_parts(ds, folder)
    looks = list(follow_folder(folder, window_s=900.0, poll_s=0.0, settle_s=0.0,
                               idle_stop_s=0.0, sleep=lambda _: None))
    calibrator = looks[-1][0]
    whole = Calibrator(ds.sites, 900.0)
    whole.add(ds)
    whole.flush()
    assert [s.t_start_s for s in calibrator.summaries] == [s.t_start_s for s in whole.summaries]
    mine, theirs = calibrator.current(), whole.current()
    for rid, estimate in theirs.items():
        for key, sigma in estimate.sigma.items():
            assert abs(mine[rid].sigma[key] - sigma) <= 0.05 * sigma


def test_a_bad_part_names_its_file_and_row(demo, tmp_path: Path) -> None:
    folder = tmp_path / "rec"
    _write_parts(demo.dataset, folder)
    bad = folder / "plots" / "001-plots.csv"
    lines = bad.read_text().splitlines()
    cells = lines[3].split(",")
    cells[1] = "NOWHERE"
    lines[3] = ",".join(cells)
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="001-plots.csv"):
        list(follow_folder(folder, window_s=900.0, poll_s=0.0, settle_s=0.0, idle_stop_s=0.0,
                           sleep=lambda _: None))
