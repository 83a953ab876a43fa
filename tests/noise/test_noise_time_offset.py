"""The ADS-B noise method removes a radar's time-stamping bias before its sigmas: a 2 s
offset at 250 m/s would otherwise read as hundreds of metres of range noise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from graphcal.noise.adsb import TIME_OFFSET_MIN_S, estimate_noise_adsb
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate


@pytest.fixture(scope="module")
def demo():
    return simulate(load_scenario("scenarios/demo_network.toml"),
                    np.random.default_rng(1)).dataset


def _late(dataset, radar: str, offset_s: float):
    """The radar's plots stamped ``offset_s`` late: time_reported = time_true + offset."""
    plots = dataset.plots.copy()
    plots.loc[plots["radar_id"] == radar, "time_s"] += offset_s
    return dataclasses.replace(dataset, plots=plots)


def test_a_2_s_offset_is_found_and_removed(demo) -> None:
    clean = estimate_noise_adsb(demo, "NORD")
    late = estimate_noise_adsb(_late(demo, "NORD", 2.0), "NORD")
    tau, sigma = late.details["time_offset_s"], late.details["time_offset_sigma_s"]
    assert tau == pytest.approx(2.0, abs=max(5 * sigma, 0.01))
    # the simulation's truth: NORD's sigmas are 30 m and 1.2 mrad (demo_network.toml)
    assert late.sigma_range_m == pytest.approx(30.0, rel=0.1)
    assert late.sigma_azimuth_mrad == pytest.approx(1.2, rel=0.1)
    assert late.sigma_range_m == pytest.approx(clean.sigma_range_m, rel=0.02)


def test_no_offset_is_removed_from_clean_data(demo) -> None:
    for radar in ("NORD", "EST3D", "APP"):
        assert "time_offset_s" not in estimate_noise_adsb(demo, radar).details
    assert TIME_OFFSET_MIN_S == 0.05
