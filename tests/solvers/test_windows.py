"""Biases per time window, chained by random walks (graphcal.solvers.windows): on a simulated
hour with one radar's azimuth drifting and another's range offset stepping, every window's
estimate is within a few sigma of the true mean bias over that window."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from graphcal.data.bias import CONTRACT_KEYS
from graphcal.simulation.scenario import parse_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.windows import windowed_graph
from tests.paths import SCENARIOS

#: Random-walk rates loose enough for the simulated drift and step [SI per sqrt(s)].
RATES = {"azimuth_bias": 1.5e-3 / 60.0, "range_offset": 60.0 / 60.0}


@pytest.fixture(scope="module")
def drifting():
    with open(SCENARIOS / "demo_network.toml", "rb") as f:
        doc = tomllib.load(f)
    doc["scenario"]["duration_s"] = 3600.0
    doc["radar"][0]["drift"] = {"azimuth_bias_mrad_per_h": 1.0, "range_offset_m_per_h": 20.0}
    doc["radar"][1]["step"] = [{"time_s": 2000.0, "range_offset_m": 60.0}]
    scenario = parse_scenario(doc)
    return scenario, simulate(scenario, np.random.default_rng(1))


def test_windows_follow_the_drift_and_the_step(drifting) -> None:
    scenario, sim = drifting
    result = windowed_graph(sim.dataset, 900.0, random_walk_per_sqrt_s=RATES)
    z = []
    for radar in scenario.radars:
        windows = result.series[radar.id]
        assert [w.t_start_s for w in windows] == [0.0, 900.0, 1800.0, 2700.0]
        assert sum(w.n_plots for w in windows) == (sim.dataset.plots["radar_id"]
                                                   == radar.id).sum()
        for w in windows:
            truth = radar.schedule.mean(w.t_start_s, w.t_end_s)
            for name in result.terms[radar.id].free:
                key, factor = CONTRACT_KEYS[name]
                z.append((w.bias.value(name) - truth.value(name)) * factor / w.sigma[key])
    z = np.array(z)
    assert np.max(np.abs(z)) < 3.5, z
    assert 0.5 < np.mean(z**2) < 2.0
    # The drift is followed: NORD's azimuth grows by about 0.75 mrad over the hour.
    first, last = result.series["NORD"][0], result.series["NORD"][-1]
    assert (last.bias.azimuth_bias_rad - first.bias.azimuth_bias_rad) * 1e3 == pytest.approx(
        0.75, abs=0.15)
    assert result.last("SUD") is result.series["SUD"][-1]


def test_tight_random_walks_smooth_a_real_drift_away(drifting) -> None:
    """With the default (tight) rates the chain cannot follow 1 mrad/h: the first and last
    windows' azimuth errors are many sigma (what rate estimation is for)."""
    scenario, sim = drifting
    result = windowed_graph(sim.dataset, 900.0)
    nord = scenario.radars[0]
    first = result.series["NORD"][0]
    truth = nord.schedule.mean(first.t_start_s, first.t_end_s)
    z = (first.bias.azimuth_bias_rad - truth.azimuth_bias_rad) * 1e3 / first.sigma[
        "azimuth_bias_mrad"]
    assert abs(z) > 4.0


def test_pressure_altitudes_are_not_windowed_yet() -> None:
    from graphcal.simulation.scenario import load_scenario

    sim = simulate(load_scenario(SCENARIOS / "demo_pressure.toml"), np.random.default_rng(1))
    with pytest.raises(ValueError, match="pressure altitudes"):
        windowed_graph(sim.dataset, 900.0)
