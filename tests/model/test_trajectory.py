"""The trajectory formulation: elimination, derivatives, order, sparse ADS-B."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import graphcal
from graphcal.model.parameters import radar_terms, terms_vector
from graphcal.model.paths import add_motion_prior, band_to_dense, band_zeros
from graphcal.model.robust import RobustKernel
from graphcal.model.trajectory import build_trajectory_block
from graphcal.simulation.scenario import load_scenario
from graphcal.solvers.graph import graph
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def short_demo(demo) -> graphcal.Dataset:
    """The first 10 minutes of the demo network."""
    plots = demo.plots[demo.plots["time_s"] < 600.0].reset_index(drop=True)
    adsb = demo.adsb[demo.adsb["time_s"] < 600.0].reset_index(drop=True)
    return dataclasses.replace(demo, plots=plots, adsb=adsb)


def truth_block(dataset, use_adsb: bool, kernel: str = "none"):
    sim_truth = graphcal.simulate(SCENARIOS / "demo_network.toml", seed=1).biases
    terms = {rid: radar_terms(dataset.sites[rid], {}, False) for rid in dataset.radar_ids}
    keys = {rid: i for i, rid in enumerate(dataset.radar_ids)}
    truth = {rid: terms_vector(sim_truth[rid])[terms[rid].positions] for rid in dataset.radar_ids}
    block = build_trajectory_block(dataset, terms, keys, list(dataset.radar_ids),
                                   RobustKernel(kernel), use_adsb=use_adsb, initial_biases=truth)
    assert block is not None
    return block, block.values_of(truth)


def test_reduced_system_is_the_schur_complement_of_the_joint_system(short_demo) -> None:
    block, values = truth_block(short_demo, use_adsb=True)
    block.settle(values, 5)
    joint = block.normal_equations(values)
    n = block.layout.n_unknowns
    a = joint["information"]
    g = joint["gradient"]
    schur = a[n:, n:] - a[n:, :n] @ np.linalg.solve(a[:n, :n], a[:n, n:])
    reduced_gradient = g[n:] - a[n:, :n] @ np.linalg.solve(a[:n, :n], g[:n])
    block.settle(values, 5)
    _, gradient, information = block.reduced(values, True)
    scale = np.sqrt(np.diag(schur))
    assert np.allclose(information / np.outer(scale, scale), schur / np.outer(scale, scale),
                       atol=1e-6)
    assert np.allclose(gradient / scale, reduced_gradient / scale, atol=1e-6)


def test_reduced_gradient_matches_finite_differences_of_the_reduced_cost(short_demo) -> None:
    block, values = truth_block(short_demo, use_adsb=False)
    block.settle(values, 6)
    _, gradient, information = block.reduced(values, True)
    sigma = np.sqrt(np.diag(np.linalg.inv(information + 1e-12 * np.eye(len(information)))))
    sizes = [len(v) for v in values]
    x0 = np.concatenate(values)

    def cost_at(x: np.ndarray) -> float:
        parts = np.split(x, np.cumsum(sizes)[:-1])
        block.settle(parts, 6)
        cost, _, _ = block.reduced(parts, False)
        return cost

    for i in [0, 1, 2, 6, 9]:
        h = 0.5 * sigma[i]
        step = np.zeros_like(x0)
        step[i] = h
        numeric = (cost_at(x0 + step) - cost_at(x0 - step)) / (2 * h)
        # Scaled by the gradient's noise (sqrt of the information): the reduced cost is
        # the minimum over the paths, so its derivative is the Schur gradient.
        assert numeric * sigma[i] == pytest.approx(gradient[i] * sigma[i], abs=0.05)
    block.settle(values, 6)


def test_height_model_gradient_matches_finite_differences_of_the_reduced_cost() -> None:
    """The reported pressure altitude's derivatives on the height model ``(d, k)``: the
    reduced gradient against central differences of the reduced cost (10 minutes of
    scenarios/demo_pressure.toml, without ADS-B, at the true biases)."""
    scenario = dataclasses.replace(load_scenario(SCENARIOS / "demo_pressure.toml"),
                                   duration_s=600.0)
    sim = graphcal.simulate(scenario, np.random.default_rng(3))
    dataset = sim.dataset
    terms = {rid: radar_terms(dataset.sites[rid], {}, False) for rid in dataset.radar_ids}
    keys = {rid: i for i, rid in enumerate(dataset.radar_ids)}
    truth = {rid: terms_vector(sim.biases[rid])[terms[rid].positions]
             for rid in dataset.radar_ids}
    block = build_trajectory_block(dataset, terms, keys, list(dataset.radar_ids),
                                   RobustKernel("none"), use_adsb=False, initial_biases=truth,
                                   height_key=len(keys))
    assert block is not None and block.pressure
    truth[""] = scenario.height_model.as_vector()
    values = block.values_of(truth)
    block.settle(values, 6)
    _, gradient, information = block.reduced(values, True)
    sigma = np.sqrt(np.diag(np.linalg.inv(information)))
    sizes = [len(v) for v in values]
    x0 = np.concatenate(values)

    def cost_at(x: np.ndarray) -> float:
        block.settle(np.split(x, np.cumsum(sizes)[:-1]), 6)
        cost, _, _ = block.reduced(np.split(x, np.cumsum(sizes)[:-1]), False)
        return cost

    for i in (len(x0) - 2, len(x0) - 1):  # height_offset_m, height_scale
        step = np.zeros_like(x0)
        step[i] = 0.5 * sigma[i]
        numeric = (cost_at(x0 + step) - cost_at(x0 - step)) / (2 * step[i])
        assert numeric * sigma[i] == pytest.approx(gradient[i] * sigma[i], abs=0.05)


@pytest.mark.parametrize("cross", ["trajectory", "pairwise"])
@pytest.mark.parametrize("use_adsb", [True, False])
def test_radar_order_does_not_change_the_answer(short_demo, use_adsb: bool, cross: str) -> None:
    reversed_sites = dict(reversed(list(short_demo.sites.items())))
    backwards = dataclasses.replace(short_demo, sites=reversed_sites)
    a = graph(short_demo, use_adsb=use_adsb, cross=cross)
    b = graph(backwards, use_adsb=use_adsb, cross=cross)
    assert list(b.radar_ids) == list(reversed(a.radar_ids))
    for label, value, sigma in zip(a.labels, a.estimate, np.sqrt(np.diag(a.covariance)),
                                   strict=True):
        other = b.estimate[b.labels.index(label)]
        assert abs(other - value) / sigma < 0.01, label


def test_sparse_adsb_every_5_s_calibrates_within_3_sigma() -> None:
    scenario = load_scenario(SCENARIOS / "demo_network.toml")
    scenario = dataclasses.replace(
        scenario, duration_s=1200.0, adsb=dataclasses.replace(scenario.adsb, period_s=5.0))
    sim = graphcal.simulate(scenario, seed=7)
    cal = graph(sim.dataset)
    estimated_time = [label for label in cal.labels if label[1] == "time_offset"]
    assert len(estimated_time) >= 2  # sparse ADS-B still determines time offsets
    sigma = np.sqrt(np.diag(cal.covariance))
    for (rid, name), value, s in zip(cal.labels, cal.estimate, sigma, strict=True):
        truth = sim.biases[rid].value(name)
        assert abs(value - truth) < 3.0 * s, (rid, name, value, truth, s)
    assert cal.info["target_state"]["formulation"] == "trajectory"


@pytest.mark.parametrize("refraction", ["none", "exponential"])
def test_measurement_jacobians_match_finite_differences(demo, refraction: str) -> None:
    """RadarMeasurementModel.measure: d h / d enu and d h / d every bias term (eccentricity
    included) against central differences, straight and refracted rays."""
    from graphcal.model.measurement import measurement_model
    from graphcal.model.parameters import TERM_NAMES

    site = dataclasses.replace(demo.sites["EST3D"], refraction=refraction)
    model = measurement_model(site)
    rng = np.random.default_rng(2)
    enu = np.column_stack([rng.uniform(-150e3, 150e3, 20), rng.uniform(-150e3, 150e3, 20),
                           rng.uniform(3e3, 11e3, 20)])
    terms = np.array([120.0, 4.5e-4, 2.6e-3, 1.8e-3, 0.0, 0.4e-3, -0.3e-3])
    free = tuple(name for name in TERM_NAMES if name != "time_offset")
    predicted, d_enu, d_terms = model.measure(enu, terms, free)
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = 1.0
        plus, _, _ = model.measure(enu + step, terms, free)
        minus, _, _ = model.measure(enu - step, terms, free)
        assert np.allclose((plus - minus) / 2.0, d_enu[:, :, axis], rtol=1e-5, atol=1e-9)
    for k, name in enumerate(free):
        h = 1e-3 * max(abs(terms[TERM_NAMES.index(name)]), 1e-3)
        shifted = terms.copy()
        shifted[TERM_NAMES.index(name)] += h
        plus, _, _ = model.measure(enu, shifted, free)
        shifted[TERM_NAMES.index(name)] -= 2 * h
        minus, _, _ = model.measure(enu, shifted, free)
        assert np.allclose((plus - minus) / (2 * h), d_terms[:, :, k], rtol=1e-6, atol=1e-9), name


def test_residual_dof_of_the_paths_add_up_to_the_datas_share(short_demo) -> None:
    """``residual_fit``'s paths' shares of the degrees of freedom, estimated from random
    draws, sum to the data's exact share ``n - tr(A^-1 P)`` (``P`` the motion prior, ``A``
    the paths' normal matrix from the dense joint system): every measurement's
    ``tr(A^-1 D)`` adds up with the prior's to ``tr(I) = n``."""
    block, values = truth_block(short_demo, use_adsb=False)
    block.settle(values, 5)
    block.reduced(values, True)
    n = block.layout.n_unknowns
    a = block.normal_equations(values)["information"][:n, :n]
    prior = band_zeros(n)
    add_motion_prior(prior, block.layout, block.phase_scale, block.vertical_scale)
    exact = n - float(np.trace(np.linalg.solve(a, band_to_dense(prior))))
    fit = block.residual_fit(values, n_probes=64)
    estimated = sum(e["paths_dof"] for by in fit.values() for e in by.values())
    # The estimate's standard deviation is at most sqrt(2 tr / draws) (the docstring).
    assert estimated == pytest.approx(exact, abs=4.0 * np.sqrt(2.0 * exact / 64))
    assert 0.0 < exact < n
    again = block.residual_fit(values, n_probes=64)
    assert again == fit  # seeded: the same figures on every run
    plots = sum(len(r.rows) for r in block.radars)
    assert sum(by["range"]["n"] for by in fit.values()) == plots
