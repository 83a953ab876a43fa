"""Estimators on the simulated demo network (mixed 2-D/3-D, random traffic, antenna sweep).

Truth comes from the simulator; the estimators must recover it within 4 of
their own reported sigmas, over several seeds, where their model holds
(``fl`` is left out: the demo radars have range gains, which FL does not model).
"""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.data.bias import RadarBias
from graphcal.data.calibration import Calibration
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.registry import calibrate
from tests.paths import SCENARIOS


def _max_abs_z(cal: Calibration, biases: dict[str, RadarBias]) -> float:
    sd = np.sqrt(np.diag(cal.covariance))
    z = [
        (cal.estimate[i] - biases[rid].value(name)) / sd[i]
        for i, (rid, name) in enumerate(cal.labels)
    ]
    return float(np.max(np.abs(z)))


@pytest.fixture(scope="module")
def demo_runs():
    scenario = load_scenario(SCENARIOS / "demo_network.toml")
    return [simulate(scenario, np.random.default_rng(seed)) for seed in (1, 2, 3)]


@pytest.mark.parametrize("method", ["ls", "fl-ls", "wls"])
def test_demo_network_recovered_within_reported_sigma(demo_runs, method: str) -> None:
    for run in demo_runs:
        cal = calibrate(run.dataset, method)
        assert set(cal.radar_ids) == set(run.biases)
        assert _max_abs_z(cal, run.biases) < 4.0, method


def test_wls_sigma_agrees_with_the_spread_over_seeds(demo_runs) -> None:
    """Normalised errors over 3 seeds x 16 parameters have a variance in [0.5, 2.5].

    Measured 2.05 on these seeds with the shared-plot sandwich covariance and the pairs
    oriented by scan period (1.48 over seeds 1-8; 1.38 with the pairs in file order);
    with the paper's plain ``A^-1`` it is 6.1 (sigmas over-confident by ~2.5x), which
    fails.
    """
    z = []
    for run in demo_runs:
        cal = calibrate(run.dataset, "wls")
        sd = np.sqrt(np.diag(cal.covariance))
        z += [
            (cal.estimate[i] - run.biases[rid].value(name)) / sd[i]
            for i, (rid, name) in enumerate(cal.labels)
        ]
    assert 0.5 < np.mean(np.square(z)) < 2.5
