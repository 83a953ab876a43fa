"""Tests of long scenarios simulated in chunks (graphcal.simulation.chunks, .stream)."""

from __future__ import annotations

import filecmp
import json
import math

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
import tomli_w
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.core.errors import DatasetError
from graphcal.io.folder import load_dataset
from graphcal.simulation.chunks import chunk_edges, true_span
from graphcal.simulation.scenario import parse_scenario
from graphcal.simulation.simulate import ChunkedSimulation, simulate, write_simulation
from graphcal.simulation.stream import simulate_to_folder

ORIGIN = {"lat_deg": 50.0, "lon_deg": 4.0, "alt_m": 0.0}


def _document() -> dict:
    """Two radars (one with a clock offset, one drifting and stepping), 12 aircraft, 30 min."""
    return {
        "scenario": {"name": "chunks", "duration_s": 1800.0, "origin": dict(ORIGIN)},
        "radar": [
            {"id": "R3D", "lat_deg": 49.8, "lon_deg": 3.8, "alt_m": 100.0,
             "sigma_range_m": 40.0, "sigma_azimuth_mrad": 1.0, "sigma_elevation_mrad": 2.0,
             "scan_period_s": 5.0, "max_range_m": 250_000.0,
             "bias": {"range_offset_m": 80.0, "azimuth_bias_mrad": 1.5,
                      "time_offset_s": 0.7}},
            {"id": "R2D", "lat_deg": 50.2, "lon_deg": 4.3, "alt_m": 50.0,
             "sigma_range_m": 60.0, "sigma_azimuth_mrad": 1.5, "scan_period_s": 8.0,
             "max_range_m": 250_000.0,
             "bias": {"range_offset_m": -50.0, "range_gain": 2e-4, "time_offset_s": -0.4},
             "drift": {"azimuth_bias_mrad_per_h": 0.5},
             "step": [{"time_s": 900.0, "range_offset_m": 30.0}]},
        ],
        "traffic": {"n_aircraft": 12, "radius_m": 150_000.0, "legs": [2, 3],
                    "start_time_s": [-600.0, 1200.0]},
        "adsb": {"enabled": True, "period_s": 1.0, "nacp": 8, "outlier_fraction": 0.01,
                 "equipped_fraction": 0.75},
    }


@pytest.fixture(scope="module")
def scenario():
    return parse_scenario(_document())


# --------------------------------------------------------------------------- chunks


def test_chunk_edges_cover_the_scenario_in_reported_time() -> None:
    assert chunk_edges(1800.0, None) == [-math.inf, math.inf]
    assert chunk_edges(1800.0, 600.0) == [-math.inf, 600.0, 1200.0, math.inf]
    assert chunk_edges(1700.0, 600.0) == [-math.inf, 600.0, 1200.0, math.inf]
    assert chunk_edges(100.0, 600.0) == [-math.inf, math.inf]
    with pytest.raises(ValueError, match="positive duration"):
        chunk_edges(100.0, 0.0)


def test_true_spans_partition_the_scenario_for_a_clock_offset() -> None:
    edges = chunk_edges(1800.0, 600.0)
    spans = [true_span(edges, k, 1800.0, 0.7) for k in range(3)]
    assert [(s.t0_s, s.t1_s, s.closed) for s in spans] == [
        (0.0, 599.3, False), (599.3, 1199.3, False), (1199.3, 1800.0, True)]
    times = np.array([0.0, 599.2, 599.3, 1800.0])
    assert spans[0].keep(times[:2]).tolist() == [0.0, 599.2]
    assert spans[0].keep(times[:3]).tolist() == [0.0, 599.2]
    assert spans[2].keep(times[2:]).tolist() == [599.3, 1800.0]


# --------------------------------------------------------------------------- in memory


def test_one_chunk_is_the_simulation_as_before(scenario) -> None:
    """chunk_s=None draws as simulate always has: a chunk as long as the scenario agrees."""
    whole = simulate(scenario, np.random.default_rng(5))
    long_chunk = simulate(scenario, np.random.default_rng(5), chunk_s=3600.0)
    pd.testing.assert_frame_equal(whole.dataset.plots, long_chunk.dataset.plots)
    pd.testing.assert_frame_equal(whole.dataset.adsb, long_chunk.dataset.adsb)
    assert whole.adsb_equipped == long_chunk.adsb_equipped


def test_chunks_give_the_same_hits_and_statistically_equivalent_noise(scenario) -> None:
    whole = simulate(scenario, np.random.default_rng(5))
    chunked = simulate(scenario, np.random.default_rng(5), chunk_s=600.0)
    # The hits are geometry (the traffic and phases come first from the generator).
    assert chunked.n_candidates == whole.n_candidates
    assert len(chunked.dataset.plots) == len(whole.dataset.plots)  # detection probability 1
    keys = ["time_true_s", "x_m", "y_m", "z_m"]
    a = whole.plot_truth[keys].sort_values("time_true_s", ignore_index=True)
    b = chunked.plot_truth[keys].sort_values("time_true_s", ignore_index=True)
    np.testing.assert_allclose(a.to_numpy(), b.to_numpy(), rtol=0, atol=1e-5)
    # Which aircraft broadcast is drawn after the first chunk's plots: another draw, as many.
    assert len(chunked.adsb_equipped) == len(whole.adsb_equipped) == 9
    # The noise draws differ; their statistics do not.
    differences = []
    for result in (whole, chunked):
        plots = result.dataset.plots
        noise = plots["range_m"].to_numpy() - result.plot_truth["range_true_m"].to_numpy()
        mine = (plots["radar_id"] == "R3D").to_numpy()
        differences.append(noise[mine] - 80.0)
        assert abs(np.mean(noise[mine] - 80.0)) < 4 * 40.0 / math.sqrt(mine.sum())
        assert np.std(noise[mine]) == pytest.approx(40.0, rel=0.1)
    assert not np.array_equal(*differences)


def test_chunked_tables_are_in_time_order_across_clock_offsets(scenario) -> None:
    plots = simulate(scenario, np.random.default_rng(2), chunk_s=600.0).dataset.plots
    assert np.all(np.diff(plots["time_s"].to_numpy()) >= 0)


def test_chunks_can_be_drawn_once(scenario) -> None:
    run = ChunkedSimulation(scenario, np.random.default_rng(0), chunk_s=600.0)
    assert [c.index for c in run.chunks()] == [0, 1, 2]
    with pytest.raises(RuntimeError, match="only once"):
        next(run.chunks())


# --------------------------------------------------------------------------- to a folder


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_streamed_folder_is_the_chunked_simulation_written(scenario, tmp_path, fmt) -> None:
    result = simulate(scenario, np.random.default_rng(7), chunk_s=600.0)
    write_simulation(result, tmp_path / "memory", fmt=fmt)
    streamed = simulate_to_folder(scenario, np.random.default_rng(7), tmp_path / "stream",
                                  fmt=fmt, chunk_s=600.0)
    assert streamed.n_chunks == 3 and streamed.n_plots == result.n_plots()
    assert streamed.n_adsb == len(result.dataset.adsb)
    assert streamed.adsb_equipped == result.adsb_equipped
    names = ["sites.toml", "truth.json"] + ([f"plots.{fmt}", f"adsb.{fmt}"] if fmt == "csv"
                                             else [])
    for name in names:
        assert filecmp.cmp(tmp_path / "memory" / name, tmp_path / "stream" / name,
                           shallow=False), name
    a, b = load_dataset(tmp_path / "memory"), load_dataset(tmp_path / "stream")
    pd.testing.assert_frame_equal(a.plots, b.plots)
    pd.testing.assert_frame_equal(a.adsb, b.adsb)
    truth = json.loads((tmp_path / "stream" / "truth.json").read_text())
    assert truth["radars"]["R2D"]["n_plots"] == streamed.n_plots["R2D"]
    assert "R2D" in truth["drift"]


def test_streamed_parquet_has_a_row_group_per_chunk(scenario, tmp_path) -> None:
    simulate_to_folder(scenario, np.random.default_rng(7), tmp_path / "out", chunk_s=600.0)
    metadata = pq.ParquetFile(tmp_path / "out" / "plots.parquet").metadata
    assert metadata.num_row_groups == 3
    upper = [metadata.row_group(g).column(1).statistics.max for g in range(3)]
    lower = [metadata.row_group(g).column(1).statistics.min for g in range(3)]
    assert upper[0] < 600.0 <= lower[1] and upper[1] < 1200.0 <= lower[2]


def test_streaming_refuses_a_non_empty_folder_and_leaves_nothing_on_failure(
        scenario, tmp_path, monkeypatch) -> None:
    target = tmp_path / "out"
    target.mkdir()
    (target / "keep.txt").write_text("mine")
    with pytest.raises(DatasetError, match="not empty"):
        simulate_to_folder(scenario, np.random.default_rng(0), target, chunk_s=600.0)

    def broken(self, k):
        if k == 1:
            raise OSError("disk full")
        return original(self, k)

    original = ChunkedSimulation._chunk
    monkeypatch.setattr(ChunkedSimulation, "_chunk", broken)
    with pytest.raises(DatasetError, match="not a graphcal dataset"):  # overwrite: datasets only
        simulate_to_folder(scenario, np.random.default_rng(0), target, chunk_s=600.0,
                           overwrite=True)
    (target / "sites.toml").write_text("# an earlier dataset\n")
    with pytest.raises(OSError, match="disk full"):
        simulate_to_folder(scenario, np.random.default_rng(0), target, chunk_s=600.0,
                           overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert sorted(p.name for p in target.iterdir()) == ["keep.txt", "sites.toml"]


def test_cli_simulate_in_chunks(tmp_path) -> None:
    scenario_file = tmp_path / "s.toml"
    scenario_file.write_text(tomli_w.dumps(_document()))
    runner = CliRunner()
    out = tmp_path / "out"
    result = runner.invoke(app, ["simulate", str(scenario_file), "--out", str(out), "--seed",
                                 "7", "--chunk", "10min", "--format", "csv"])
    assert result.exit_code == 0, result.output
    expected = simulate(parse_scenario(_document()), np.random.default_rng(7), chunk_s=600.0)
    assert f"{len(expected.dataset.plots)} plots" in result.output
    bad = runner.invoke(app, ["simulate", str(scenario_file), "--out", str(tmp_path / "x"),
                              "--chunk", "soon"])
    assert bad.exit_code == 2 and "--chunk" in bad.output
