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
    """With the default (tight) rates and no rate estimation the chain cannot follow
    1 mrad/h: the first window's azimuth error is many sigma (what rate estimation is for)."""
    scenario, sim = drifting
    result = windowed_graph(sim.dataset, 900.0, estimate_rates=False)
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


@pytest.mark.parametrize("q_true", [0.5, 2.0])
def test_random_walk_rate_recovers_the_simulated_rate(q_true) -> None:
    """Chains of 40 windows: a random walk of rate q seen through noise of 10 units; the
    median over 40 chains of the maximum-likelihood rate is within 15 % of q."""
    from graphcal.solvers.windows import random_walk_rate

    rng = np.random.default_rng(0)
    t = np.arange(40) * 900.0
    rates = []
    for _ in range(40):
        x = np.cumsum(np.r_[0.0, rng.normal(0.0, q_true * np.sqrt(900.0), 39)])
        rates.append(random_walk_rate(t, x + rng.normal(0.0, 10.0, 40), np.full(40, 100.0)))
    assert np.median(rates) == pytest.approx(q_true, rel=0.15)


def test_random_walk_rate_of_a_constant_is_mostly_zero() -> None:
    from graphcal.solvers.windows import random_walk_rate

    rng = np.random.default_rng(1)
    t = np.arange(40) * 900.0
    rates = [random_walk_rate(t, rng.normal(5.0, 10.0, 40), np.full(40, 100.0))
             for _ in range(40)]
    assert np.mean(np.array(rates) == 0.0) > 0.5
    assert np.max(rates) < 0.2  # far below what 10 units of noise per window could hide


def test_estimated_rates_follow_the_drift(drifting) -> None:
    scenario, sim = drifting
    result = windowed_graph(sim.dataset, 900.0)
    assert result.rates["NORD"]["azimuth_bias"] > 1e-7  # 1 mrad/h drift found
    for w in result.series["NORD"]:
        truth = scenario.radars[0].schedule.mean(w.t_start_s, w.t_end_s)
        z = (w.bias.azimuth_bias_rad - truth.azimuth_bias_rad) * 1e3 / w.sigma[
            "azimuth_bias_mrad"]
        assert abs(z) < 3.0
