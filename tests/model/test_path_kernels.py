"""The paths' compiled loops against NumPy's sums (a second implementation of each)."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.model import path_kernels
from graphcal.model.paths import (
    add_measurement_blocks,
    band_zeros,
    basis,
    evaluate_paths,
    scatter_vectors,
    weighted_squares,
)
from tests.model.test_trajectory import short_demo, truth_block  # noqa: F401 - fixture

pytest.importorskip("numba")


@pytest.fixture
def numpy_sums(monkeypatch):
    """NumPy's sums in this test, whatever the process uses."""
    monkeypatch.setenv(path_kernels.KERNELS_ENV, "numpy")
    monkeypatch.setitem(path_kernels._state, "enabled", False)


def compiled_sums(monkeypatch) -> None:
    monkeypatch.delenv(path_kernels.KERNELS_ENV, raising=False)
    assert path_kernels.enable()
    assert path_kernels.enabled()


def random_measurements(n: int, n_coefficients: int, seed: int):
    rng = np.random.default_rng(seed)
    first = np.sort(rng.integers(0, n_coefficients - 3, n))
    weights = basis(rng.random(n))
    root = rng.normal(size=(n, 3, 3))
    info = root @ np.swapaxes(root, 1, 2)
    return first, weights, info, rng.normal(size=(n, 3)), rng.normal(size=(n_coefficients, 3))


def test_compiled_sums_equal_numpys(numpy_sums, monkeypatch) -> None:
    first, weights, info, vectors, coefficients = random_measurements(2000, 300, seed=3)
    expected_band = band_zeros(900)
    add_measurement_blocks(expected_band, first, weights, info)
    expected_vector = scatter_vectors(first, weights, vectors, 900)
    expected_paths = evaluate_paths(coefficients, first, weights)
    expected_squares = weighted_squares(coefficients, first, weights, vectors, info)
    residual = expected_paths - vectors  # a third way: one measurement at a time
    assert np.isclose(expected_squares[5], residual[5] @ info[5] @ residual[5])
    compiled_sums(monkeypatch)
    band = band_zeros(900)
    add_measurement_blocks(band, first, weights, info)
    scale = np.abs(expected_band).max()
    assert np.abs(band - expected_band).max() <= 1e-13 * scale
    assert np.allclose(scatter_vectors(first, weights, vectors, 900), expected_vector,
                       rtol=0, atol=1e-12)
    assert np.allclose(evaluate_paths(coefficients, first, weights), expected_paths,
                       rtol=0, atol=1e-12)
    assert np.allclose(weighted_squares(coefficients, first, weights, vectors, info),
                       expected_squares, rtol=1e-12, atol=0)


def test_compiled_linearisation_equals_numpys(short_demo, numpy_sums, monkeypatch) -> None:  # noqa: F811
    """The whole linearisation (band, gradient, bias columns, bias information and
    gradient, cost) of the demo's plots, robust weights included."""
    block, values = truth_block(short_demo, use_adsb=True, kernel="huber")
    values = [v + 0.1 * np.abs(v) for v in values]  # off the truth: robust weights < 1
    named = block._split(values)
    expected = block._linearise_data(named, True, block.coefficients)
    compiled_sums(monkeypatch)
    got = block._linearise_data(named, True, block.coefficients)
    for name in ("band", "gradient", "cross", "bias_information", "bias_gradient",
                 "phase_cost"):
        a, b = getattr(expected, name), getattr(got, name)
        assert np.abs(a - b).max() <= 1e-10 * max(np.abs(a).max(), 1.0), name
    assert got.cost == pytest.approx(expected.cost, rel=1e-12)


def test_numpy_is_kept_when_asked(monkeypatch) -> None:
    monkeypatch.setenv(path_kernels.KERNELS_ENV, "numpy")
    assert not path_kernels.available()
    assert not path_kernels.enable()


def test_compiled_adsb_sums_equal_numpys(short_demo, numpy_sums, monkeypatch) -> None:  # noqa: F811
    """The ADS-B reports in the network frame, their information and their share of the
    paths' normal equations, built both ways."""
    expected, _ = truth_block(short_demo, use_adsb=True)
    compiled_sums(monkeypatch)
    got, _ = truth_block(short_demo, use_adsb=True)
    a, b = expected.adsb, got.adsb
    assert np.abs(a.position - b.position).max() <= 1e-6  # metres, over hundreds of km
    assert np.abs(a.information - b.information).max() <= 1e-12 * np.abs(a.information).max()
    assert np.abs(a.band - b.band).max() <= 1e-12 * np.abs(a.band).max()
    assert np.abs(a.rhs - b.rhs).max() <= 1e-10 * np.abs(a.rhs).max()
    assert b.constant == pytest.approx(a.constant, rel=1e-12)
    assert np.abs(expected.coefficients - got.coefficients).max() <= 1e-6


def test_compiled_motion_prior_equals_numpys(numpy_sums, monkeypatch) -> None:
    from graphcal.model.paths import PathLayout, add_motion_prior

    layout = PathLayout.build(np.array([0.0, 100.0]), np.array([400.0, 1300.0]), 10.0, 300.0)
    scale = np.random.default_rng(5).uniform(0.1, 10.0, (layout.n_phases, 3))  # per axis
    expected = band_zeros(layout.n_unknowns)
    add_motion_prior(expected, layout, scale)
    compiled_sums(monkeypatch)
    got = band_zeros(layout.n_unknowns)
    add_motion_prior(got, layout, scale)
    assert np.abs(got - expected).max() <= 1e-14 * np.abs(expected).max()



@pytest.mark.parametrize("width", [11, 3, 5])
def test_compiled_cholesky_equals_lapacks(width, monkeypatch) -> None:
    """The compiled banded Cholesky against LAPACK's ``dpbtrf``, for the unrolled
    half-bandwidths (11, 3) and another, over the full band and its last columns."""
    import scipy.linalg

    from graphcal.model.paths import BandFactor

    rng = np.random.default_rng(width)
    n = 400
    root = rng.normal(size=(n + width, n)) * (np.abs(
        np.arange(n + width)[:, None] - np.arange(n)[None, :]) <= width // 2)
    dense = root.T @ root + np.diag(rng.random(n))  # positive definite, banded
    band = np.zeros((width + 1, n), order="F")
    for d in range(width + 1):
        band[d, : n - d] = np.diagonal(dense, -d)
    expected = scipy.linalg.cholesky_banded(band, lower=True)
    compiled_sums(monkeypatch)
    factor = BandFactor.of(band)
    assert np.abs(factor.lower - expected).max() <= 1e-12 * np.abs(expected).max()
    assert np.array_equal(band[0], np.diagonal(dense))  # not overwritten unless asked
    singular = band.copy(order="F")
    singular[0, 7] = -1.0
    with pytest.raises(np.linalg.LinAlgError, match="8-th leading minor"):
        BandFactor.of(singular)


def test_compiled_likelihood_terms_equal_lapacks(numpy_sums, monkeypatch) -> None:
    """The process-noise grid's terms by phase (band, ridge, factor, forward solve, sums)
    in one compiled pass against LAPACK's factor and solve and NumPy's sums."""
    from graphcal.model.trajectory import noise_likelihood_terms

    first, weights, info, vectors, _ = random_measurements(600, 100, seed=5)
    data = band_zeros(300)
    add_measurement_blocks(data, first, weights, info)
    prior = band_zeros(300)
    add_measurement_blocks(prior, first[::3], weights[::3], info[::3])
    rng = np.random.default_rng(6)
    g_data, g_prior = rng.normal(size=300), rng.normal(size=300)
    phase = np.repeat(np.arange(6), 50)
    expected = noise_likelihood_terms(data, g_data, prior, g_prior, 0.3, phase, 6)
    compiled_sums(monkeypatch)
    reduction, log_det = noise_likelihood_terms(data, g_data, prior, g_prior, 0.3, phase, 6)
    assert np.allclose(reduction, expected[0], rtol=1e-10, atol=0)
    assert np.allclose(log_det, expected[1], rtol=1e-12, atol=1e-12)
