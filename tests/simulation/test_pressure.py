"""Simulated pressure altitudes (contract v2): scenario keys, plots, ADS-B and truth.json."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.core import frames
from graphcal.core.errors import ScenarioError
from graphcal.io.folder import load_dataset
from graphcal.simulation.scenario import FOOT_M, load_scenario, parse_scenario
from graphcal.simulation.simulate import simulate, truth_document, write_simulation
from tests.paths import SCENARIOS

QUANTUM_M = 25.0 * FOOT_M


def small_scenario(**tables) -> dict:
    """One 2-D radar, one level aircraft, ten minutes; ``tables`` added at the top level."""
    return {
        "scenario": {"name": "unit", "duration_s": 600.0,
                     "origin": {"lat_deg": 48.85, "lon_deg": 2.35, "alt_m": 0.0}},
        "radar": [{"id": "A", "lat_deg": 48.9, "lon_deg": 2.3, "alt_m": 100.0,
                   "sigma_range_m": 50.0, "sigma_azimuth_mrad": 1.5, "scan_period_s": 4.0}],
        "aircraft": [{"id": "abc123", "east_m": -40_000.0, "north_m": 10_000.0,
                      "alt_m": 7000.0, "speed_mps": 220.0, "heading_deg": 80.0}],
        **tables,
    }


@pytest.fixture(scope="module")
def demo_pair():
    """The demo network and demo_pressure (the same network on a non-standard day), seed 1."""
    plain = simulate(load_scenario(SCENARIOS / "demo_network.toml"), np.random.default_rng(1))
    pressure = simulate(load_scenario(SCENARIOS / "demo_pressure.toml"),
                        np.random.default_rng(1))
    return plain, pressure


def test_scenario_keys_are_read_and_checked() -> None:
    scenario = parse_scenario(small_scenario(
        dataset={"plot_altitude": "pressure"},
        atmosphere={"height_offset_m": 210.0, "height_scale": 0.025},
    ))
    assert scenario.plot_altitude == "pressure"
    assert scenario.height_model.height_offset_m == 210.0
    assert scenario.height_model.height_scale == 0.025
    assert scenario.adsb_baro is True  # the default once the scenario has pressure altitudes
    plain = parse_scenario(small_scenario())
    assert plain.plot_altitude == "geometric" and plain.true_height_model is None
    assert not plain.has_pressure and plain.adsb_baro is False
    for changes, field in [
        ({"dataset": {"plot_altitude": "baro"}}, "dataset.plot_altitude"),
        ({"dataset": {"altitude": "pressure"}}, "dataset.altitude"),
        ({"atmosphere": {"height_scale": 2.0}}, "atmosphere.height_scale"),
        ({"atmosphere": {"offset_m": 2.0}}, "atmosphere.offset_m"),
        ({"adsb": {"baro_altitude": "yes"}}, "adsb.baro_altitude"),
    ]:
        with pytest.raises(ScenarioError) as info:
            parse_scenario(small_scenario(**changes))
        assert info.value.field == field


def test_same_random_stream_only_the_heights_change(demo_pair) -> None:
    """demo_pressure is demo_network plus pressure altitudes: every other value is identical."""
    plain, pressure = demo_pair
    a, b = plain.dataset.plots, pressure.dataset.plots
    pd.testing.assert_frame_equal(a.drop(columns="altitude_m"), b.drop(columns="altitude_m"))
    pd.testing.assert_frame_equal(plain.dataset.adsb,
                                  pressure.dataset.adsb.drop(columns="baro_alt_m"))
    pd.testing.assert_frame_equal(plain.plot_truth, pressure.plot_truth)
    assert plain.dataset.plot_altitude == "geometric"
    assert pressure.dataset.plot_altitude == "pressure"


def test_plot_altitudes_are_pressure_altitudes(demo_pair) -> None:
    plain, pressure = demo_pair
    model = pressure.scenario.height_model
    h = pressure.plot_truth["height_true_m"].to_numpy()
    # Reported = (h - d) / (1 + k) + noise (10 m), quantised to 25 ft: mean 0, that spread.
    error = pressure.dataset.plots["altitude_m"].to_numpy() - (h - 185.0) / 1.02
    assert model.height_offset_m == 185.0 and model.height_scale == 0.02
    assert abs(np.mean(error)) < 0.2
    assert np.std(error) == pytest.approx(np.hypot(10.0, QUANTUM_M / np.sqrt(12.0)), rel=0.02)
    # The same noise draws as the geometric heights of demo_network.
    geometric = plain.dataset.plots["altitude_m"].to_numpy()
    assert np.max(np.abs(1.02 * pressure.dataset.plots["altitude_m"] + 185.0 - geometric)) < (
        1.02 * QUANTUM_M / 2 + QUANTUM_M / 2 + 0.02 * 60.0)


def test_adsb_baro_altitude_is_the_quantised_pressure_altitude(demo_pair) -> None:
    _, pressure = demo_pair
    truth = pressure.adsb_truth
    h = frames.ecef_to_geodetic(truth[["x_m", "y_m", "z_m"]].to_numpy())[2]
    expected = np.round((h - 185.0) / 1.02 / QUANTUM_M) * QUANTUM_M
    np.testing.assert_allclose(pressure.dataset.adsb["baro_alt_m"], expected, atol=1e-6)


def test_truth_json_and_folder(demo_pair, tmp_path: Path) -> None:
    plain, pressure = demo_pair
    assert "atmosphere" not in truth_document(plain)
    block = truth_document(pressure)["atmosphere"]
    assert block == {"height_offset_m": 185.0, "height_scale": 0.02, "sigma": {}}
    folder = write_simulation(pressure, tmp_path / "run")
    assert json.loads((folder / "truth.json").read_text())["atmosphere"] == block
    back = load_dataset(folder)
    assert back.plot_altitude == "pressure" and "baro_alt_m" in back.adsb
    plain_folder = write_simulation(plain, tmp_path / "plain")
    assert "[dataset]" not in (plain_folder / "sites.toml").read_text()
    assert "baro_alt_m" not in (plain_folder / "adsb.csv").read_text().splitlines()[0]


def test_baro_altitude_can_be_switched_off() -> None:
    scenario = parse_scenario(small_scenario(
        dataset={"plot_altitude": "pressure"}, atmosphere={"height_offset_m": 150.0},
        adsb={"enabled": True, "baro_altitude": False},
    ))
    result = simulate(scenario, np.random.default_rng(2))
    assert result.dataset.adsb is not None and "baro_alt_m" not in result.dataset.adsb
