"""Observability figures: against the graph's own covariance, a gauge-free case, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.analysis.observability import analyse, degree_curve, observation_blocks
from graphcal.cli.app import app
from graphcal.data.bias import RadarBias
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate, write_simulation
from graphcal.solvers.graph import graph
from tests.paths import SCENARIOS
from tests.synthetic import Track, make_dataset, site_at


def _network(seed: int = 0, adsb: bool = True):
    radars = [
        (site_at("A", -30e3, 0.0), RadarBias(50.0, 0.001, 0.002)),
        (site_at("B", 30e3, 10e3, sigma_elevation_mrad=2.0), RadarBias(-40.0, 0.0, -0.001, 0.001)),
    ]
    tracks = [
        Track("a1", (0.0, -60e3, 8000.0), (0.0, 220.0, 0.0), 0.0, 300.0),
        Track("a2", (-50e3, 40e3, 10000.0), (200.0, -50.0, 0.0), 0.0, 300.0),
        Track("a3", (40e3, 60e3, 6000.0), (-150.0, -150.0, 0.0), 0.0, 300.0),
    ]
    return make_dataset(np.random.default_rng(seed), radars, tracks, adsb=adsb)


def test_joint_sigma_is_the_graph_posterior_without_priors() -> None:
    """Same factors, two computations: einsum + pseudo-inverse here, GTSAM marginals there
    (whose weak priors change the sigmas by far less than 1 % with ADS-B)."""
    ds = _network()
    report = analyse(observation_blocks(ds))
    cal = graph(ds, robust="none", time_offset=False, cross="pairwise")
    assert report.labels == cal.labels
    assert np.allclose(report.sigma_joint, np.sqrt(np.diag(cal.covariance)), rtol=0.01)
    assert report.rank == len(report.labels)
    assert np.all(report.sigma_alone <= report.sigma_joint * (1 + 1e-9))
    assert report.degree == pytest.approx(1.0 / report.condition)


def test_co_located_radars_without_adsb_name_their_undetermined_directions() -> None:
    """Two radars on one site, no ADS-B: paper 001's differences of the two radars' plots
    cancel every bias the radars share, so the 4 common directions (offset, gain, azimuth,
    elevation) are undetermined and only the 4 differences are."""
    a = site_at("A", 0.0, 0.0, sigma_elevation_mrad=2.0)
    b = site_at("B", 0.0, 0.0, sigma_elevation_mrad=2.0, sigma_range_m=20.0)
    tracks = [Track("t1", (-40e3, 50e3, 9000.0), (180.0, -20.0, 0.0), 0.0, 200.0),
              Track("t2", (30e3, -40e3, 7000.0), (-100.0, 150.0, 0.0), 0.0, 200.0)]
    ds = make_dataset(np.random.default_rng(0), [(a, RadarBias()), (b, RadarBias())], tracks,
                      adsb=False, noise=False)  # Jacobians at exact plots: exactly singular
    report = analyse(observation_blocks(ds, "wls"))
    assert report.rank == 4
    assert report.condition == np.inf and report.degree == 0.0
    # Each null direction pairs a term of A with the same term of B, with equal weights.
    null = report.directions[:, report.eigenvalues < 1e-9 * report.eigenvalues[-1]]
    assert null.shape[1] == 4
    for k in range(4):
        pair = np.zeros(8)
        pair[[k, k + 4]] = 1.0
        projection = np.linalg.norm(null.T @ (pair / np.sqrt(2)))
        assert projection == pytest.approx(1.0, abs=1e-6)
    text = " ".join(report.weak_directions(limit=4))
    assert "A azimuth bias" in text and "B azimuth bias" in text and "cannot be told apart" in text
    assert np.all(np.isinf(report.sigma_joint))


def test_paper001_path2_is_weak_and_the_curve_saturates() -> None:
    run = simulate(load_scenario(SCENARIOS / "paper001_path2.toml"), np.random.default_rng(1))
    blocks = observation_blocks(run.dataset, "wls")
    report = analyse(blocks)
    assert report.degree < 1e-4 and report.confounded()
    _, n_obs, degree = degree_curve(blocks, points=40)
    assert n_obs[-1] == report.n_observations
    assert degree[-1] == pytest.approx(report.degree, rel=1e-6)
    # More data is not always more observability: the curve is not monotonic.
    assert np.any(np.diff(degree) < 0)


def test_cli_table_json_and_plot(tmp_path: Path) -> None:
    run = simulate(load_scenario(SCENARIOS / "paper003_adsb_2d.toml"), np.random.default_rng(0))
    data = tmp_path / "ds"
    write_simulation(run, data)
    out, png = tmp_path / "obs.json", tmp_path / "deg.png"
    result = CliRunner().invoke(app, ["observability", str(data), "--out", str(out),
                                      "--plot", str(png)])
    assert result.exit_code == 0, result.output
    assert "Deg" in result.output
    figures = json.loads(out.read_text())
    assert figures["rank"] == 2 and set(figures["parameters"]) == {
        "R2D.range_offset_m", "R2D.azimuth_bias_mrad"}
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bad = CliRunner().invoke(app, ["observability", str(data), "--method", "magic"])
    assert bad.exit_code == 2 and "graph, wls" in bad.output
