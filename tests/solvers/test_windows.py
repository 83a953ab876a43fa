"""Biases per time window, chained by random walks (graphcal.solvers.windows): on a simulated
hour with one radar's azimuth drifting and another's range offset stepping, every window's
estimate is within a few sigma of the true mean bias over that window."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from graphcal.data.bias import CONTRACT_KEYS
from graphcal.data.windows import split_windows
from graphcal.simulation.scenario import parse_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.graph import graph
from graphcal.solvers.windows import (
    WindowOptions,
    declared_cuts,
    smooth_windows,
    summarise_window,
    windowed_graph,
)
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
    result = windowed_graph(sim.dataset, 900.0, random_walk_per_sqrt_s=RATES,
                            detect_steps=False)
    z = []
    for radar in scenario.radars:
        windows = result.series[radar.id]
        assert [w.t_start_s for w in windows] == [0.0, 900.0, 1800.0, 2700.0]
        assert sum(w.n_plots for w in windows) <= (sim.dataset.plots["radar_id"]
                                                   == radar.id).sum()
        for w in windows:
            truth = radar.schedule.mean(w.t_start_s, w.t_end_s)
            for name in result.terms[radar.id].free:
                key, factor = CONTRACT_KEYS[name]
                z.append((w.bias.value(name) - truth.value(name)) * factor / w.sigma[key])
    z = np.array(z)
    # APP's range offset is 3.4 sigma off in this seed with one batch of the whole hour
    # too (graph(), no windows): a property of the data, not of the windows.
    assert np.max(np.abs(z)) < 3.6, z
    assert 0.5 < np.mean(z**2) < 2.0
    # The drift is followed: NORD's azimuth grows by about 0.75 mrad over the hour.
    first, last = result.series["NORD"][0], result.series["NORD"][-1]
    assert (last.bias.azimuth_bias_rad - first.bias.azimuth_bias_rad) * 1e3 == pytest.approx(
        0.75, abs=0.15)
    assert result.last("SUD") is result.series["SUD"][-1]


def test_the_step_is_found_in_its_window(drifting) -> None:
    """SUD's range offset steps by 60 m at 2000 s: one event, in the window holding it,
    its size within 3 sigma; the constant radars have none."""
    _, sim = drifting
    result = windowed_graph(sim.dataset, 900.0)
    sud = [e for e in result.events if e.radar_id == "SUD"]
    assert len(sud) == 1
    assert sud[0].kind == "step" and sud[0].parameters == ["range_offset_m"]
    assert 1800.0 <= sud[0].time_s <= 2700.0
    assert abs(sud[0].size["range_offset_m"] - 60.0) < 3 * sud[0].sigma["range_offset_m"]
    assert not [e for e in result.events if e.radar_id in ("EST3D", "OUEST3D", "APP")]


def test_a_declared_break_cuts_the_chain(drifting) -> None:
    _, sim = drifting
    result = windowed_graph(sim.dataset, 900.0, breaks={"SUD": [1800.0]}, detect_steps=False)
    (event,) = [e for e in result.events if e.radar_id == "SUD"]
    assert event.kind == "break" and event.time_s == 1800.0


def test_declared_cuts_on_a_boundary_and_inside_a_window() -> None:
    starts = np.array([0.0, 900.0, 1800.0, 2700.0])
    ends, middles = starts + 900.0, starts + 450.0
    assert declared_cuts(middles, starts, ends, [1800.0]) == [1]
    assert declared_cuts(middles, starts, ends, [2000.0]) == [1, 2]
    assert declared_cuts(middles, starts, ends, [0.0, 5000.0]) == []


def test_one_window_is_the_graph_estimate_itself(drifting) -> None:
    """One window: the chain adds nothing; the result is that window's own estimate
    and covariance (the weak prior counted once)."""
    _, sim = drifting
    (window,) = [w for w in split_windows(sim.dataset, 900.0) if w.index == 1]
    summary = summarise_window(window)
    result = smooth_windows([summary], sim.dataset.sites, 900.0)
    assert result.last_labels == summary.labels
    np.testing.assert_allclose(result.last_estimate, summary.estimate, rtol=1e-6,
                               atol=1e-9 * np.abs(summary.estimate).max())
    np.testing.assert_allclose(result.last_covariance, summary.covariance, rtol=1e-5)


def test_a_constant_chain_pools_the_windows_like_one_batch() -> None:
    """Constant biases and a tight walk: the last window's estimate is the whole
    recording's, so it agrees with one batch of all the plots (graph()) within a
    fraction of a sigma, and its sigma is about the batch's."""
    from graphcal.simulation.scenario import load_scenario

    scenario = load_scenario(SCENARIOS / "demo_network.toml")
    sim = simulate(scenario, np.random.default_rng(3))
    tight = {name: 1e-9 for name in ("range_offset", "range_gain", "azimuth_bias",
                                     "elevation_bias", "time_offset")}
    result = windowed_graph(sim.dataset, 1800.0, random_walk_per_sqrt_s=tight,
                            detect_steps=False)
    batch = graph(sim.dataset, time_offset=True)
    for i, label in enumerate(result.last_labels):
        j = batch.labels.index(label)
        sd = np.sqrt(batch.covariance[j, j])
        assert abs(result.last_estimate[i] - batch.estimate[j]) < 0.3 * sd, label
        assert np.sqrt(result.last_covariance[i, i]) == pytest.approx(sd, rel=0.25), label


def test_tight_random_walks_smooth_a_real_drift_away(drifting) -> None:
    """With the default (tight) rates and no rate estimation the chain cannot follow
    1 mrad/h: the first window's azimuth error is many sigma (what rate estimation is for)."""
    scenario, sim = drifting
    result = windowed_graph(sim.dataset, 900.0, estimate_rates=False, detect_steps=False)
    nord = scenario.radars[0]
    first = result.series["NORD"][0]
    truth = nord.schedule.mean(first.t_start_s, first.t_end_s)
    z = (first.bias.azimuth_bias_rad - truth.azimuth_bias_rad) * 1e3 / first.sigma[
        "azimuth_bias_mrad"]
    assert abs(z) > 4.0


def test_pressure_altitudes_get_a_height_model_per_window() -> None:
    from graphcal.simulation.scenario import load_scenario

    sim = simulate(load_scenario(SCENARIOS / "demo_pressure.toml"), np.random.default_rng(1))
    result = windowed_graph(sim.dataset, 1800.0, options=WindowOptions(), detect_steps=False)
    assert all(s.atmosphere is not None for s in result.summaries)
    assert result.series



@pytest.mark.parametrize("cross", ["pairwise", "trajectory"])
def test_estimated_rates_follow_the_drift(drifting, cross: str) -> None:
    """1 mrad/h over four 15-min windows: a drift (pairwise) or, as four windows cannot
    tell a steady drift from steps at the decision's margin, steps (trajectory, whose
    window sigmas are a few per cent smaller); either way every window follows it."""
    scenario, sim = drifting
    result = windowed_graph(sim.dataset, 900.0, options=WindowOptions(cross=cross))
    found = (result.rates["NORD"]["azimuth_bias"] > 1e-7  # 1 mrad/h drift found
             or any(e.radar_id == "NORD" and "azimuth_bias_mrad" in e.parameters
                    for e in result.events))
    assert found
    if cross == "pairwise":
        assert result.rates["NORD"]["azimuth_bias"] > 1e-7
    for w in result.series["NORD"]:
        truth = scenario.radars[0].schedule.mean(w.t_start_s, w.t_end_s)
        z = (w.bias.azimuth_bias_rad - truth.azimuth_bias_rad) * 1e3 / w.sigma[
            "azimuth_bias_mrad"]
        assert abs(z) < 3.0


def test_two_windows_with_floored_rates_are_solved_as_one_batch() -> None:
    """Two windows say nothing about the rates: each falls to its floor, so stiff that
    GTSAM's Cholesky once failed (indeterminate system).  The chain is solved in units
    of a window's sigma with a bounded stiffness; being all but rigid, its last window
    agrees with one batch of both windows' plots within a fraction of a sigma."""
    from graphcal.data.bias import RadarBias
    from tests.synthetic import Track, make_dataset, site_at

    rng = np.random.default_rng(21)
    sites = [(site_at("RA", 0.0, 0.0), RadarBias(50.0, 1e-4, 1e-3)),
             (site_at("RB", 90e3, 10e3, sigma_elevation_mrad=2.0),
              RadarBias(-30.0, 0.0, -1e-3, 5e-4))]
    tracks = [Track(f"4ca{i:03x}", (rng.uniform(-50e3, 140e3), rng.uniform(-80e3, 80e3), 9e3),
                    (200.0 * np.cos(i), 200.0 * np.sin(i), 0.0), 0.0, 600.0)
              for i in range(6)]
    dataset = make_dataset(rng, sites, tracks)
    result = windowed_graph(dataset, 300.0)
    assert {rid: len(s) for rid, s in result.series.items()} == {"RA": 2, "RB": 2}
    batch = graph(dataset, time_offset=True)
    for i, label in enumerate(result.last_labels):
        j = batch.labels.index(label)
        sd = np.sqrt(batch.covariance[j, j])
        assert abs(result.last_estimate[i] - batch.estimate[j]) < 0.5 * sd, label
        assert np.sqrt(result.last_covariance[i, i]) == pytest.approx(sd, rel=0.3), label


def test_constant_biases_from_windows_agree_with_one_batch(demo) -> None:
    """The demo's three 10-minute windows combined with no random walk: within 0.3 sigma
    of the batch over the same data, sigmas within 15 % (each window's paths end at its
    edges, and the summaries are linearised at their own windows' estimates)."""
    from graphcal.solvers.windows import constant_biases, summarise_window

    summaries = [s for s in (summarise_window(w, judge=False)
                             for w in split_windows(demo, 600.0)) if s is not None]
    assert len(summaries) == 3
    combined = constant_biases(summaries, demo.sites)
    batch = graph(demo)
    assert set(combined.labels) <= set(batch.labels)
    sigma = np.sqrt(np.diag(combined.covariance))
    for i, label in enumerate(combined.labels):
        j = batch.labels.index(label)
        batch_sigma = np.sqrt(batch.covariance[j, j])
        assert abs(combined.estimate[i] - batch.estimate[j]) < 0.3 * batch_sigma, label
        assert sigma[i] == pytest.approx(batch_sigma, rel=0.15), label
    assert sum(combined.n_plots.values()) > 0.95 * sum(batch.n_plots.values())
