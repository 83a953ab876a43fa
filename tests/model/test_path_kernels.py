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
    expected_basis = basis(np.random.default_rng(3).uniform(-0.2, 1.2, 500))
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
    u = np.random.default_rng(3).uniform(-0.2, 1.2, 500)  # extrapolated a little too
    assert np.allclose(basis(u), expected_basis, rtol=0, atol=1e-15)
    assert np.allclose(basis(u).sum(axis=1), 1.0, rtol=0, atol=1e-15)
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


def time_offset_block(dataset):
    """The demo's paths with every radar's time offset free too, off the truth."""
    from graphcal.model.parameters import radar_terms
    from graphcal.model.robust import RobustKernel
    from graphcal.model.trajectory import build_trajectory_block

    terms = {rid: radar_terms(dataset.sites[rid], {}, True) for rid in dataset.radar_ids}
    keys = {rid: i for i, rid in enumerate(dataset.radar_ids)}
    start = {rid: np.full(len(terms[rid].free), 1e-4) for rid in dataset.radar_ids}
    block = build_trajectory_block(dataset, terms, keys, list(dataset.radar_ids),
                                   RobustKernel("huber"), use_adsb=True, initial_biases=start)
    assert block is not None
    return block, {rid: start[rid] * 3.0 for rid in dataset.radar_ids}


def test_compiled_plot_linearisation_equals_numpys(short_demo, monkeypatch) -> None:  # noqa: F811
    """Each radar's plots on the paths (2-D and 3-D, time offsets free): the whitened
    residuals, both Jacobians, the positions and velocities, formed plot by plot
    against the measurement model's NumPy form."""
    from graphcal.model.paths import basis, basis_derivative
    from graphcal.model.trajectory import (
        compiled_plot_model,
        plots_on_paths,
        plots_on_paths_compiled,
    )

    compiled_sums(monkeypatch)
    block, named = time_offset_block(short_demo)
    c = block.coefficients
    kinds = set()
    for radar in block.radars:
        full = radar.terms.full_terms(named[radar.radar_id])
        assert compiled_plot_model(radar, full)
        first, u = block.layout.locate(radar.path, radar.time_s - full[4])
        rates = basis_derivative(u) / block.layout.spacing_s
        expected = plots_on_paths(radar, c, first, basis(u), rates, full)
        got = plots_on_paths_compiled(radar, c, first, basis(u), rates, full)
        for name, a, b in zip(("e", "hx", "hb", "position", "velocity"), expected, got,
                              strict=True):
            assert a.shape == b.shape, name
            assert np.abs(a - b).max() <= 1e-10 * max(np.abs(a).max(), 1.0), name
        assert np.abs(expected[2][:, :, -1]).max() > 0  # the time offset's column
        kinds.add(radar.ndim)
        without = plots_on_paths_compiled(radar, c, first, basis(u), None, full)
        assert without[4] is None
        assert np.array_equal(without[0], got[0])
    assert kinds == {2, 3}


def test_radars_the_compiled_plots_leave_to_numpy(short_demo, monkeypatch) -> None:  # noqa: F811
    """Refraction and azimuth eccentricity are left to the measurement model's NumPy
    form; a plot at a radar's zenith is refused as it is there."""
    import dataclasses

    from graphcal.model.paths import basis
    from graphcal.model.trajectory import compiled_plot_model, plots_on_paths_compiled

    compiled_sums(monkeypatch)
    block, named = time_offset_block(short_demo)
    radar = block.radars[0]
    full = radar.terms.full_terms(named[radar.radar_id])
    assert compiled_plot_model(radar, full)
    eccentric = full.copy()
    eccentric[5] = 1e-4
    assert not compiled_plot_model(radar, eccentric)
    refracted = dataclasses.replace(
        radar, site=dataclasses.replace(radar.site, refraction="exponential"))
    assert not compiled_plot_model(refracted, full)
    # A path straight above the radar: its azimuth has no derivative.
    above = dataclasses.replace(radar, map_a=np.zeros((3, 3)), map_c=np.array([0.0, 0.0, 9e3]))
    first, u = block.layout.locate(radar.path, radar.time_s)
    with pytest.raises(ValueError, match="zenith"):
        plots_on_paths_compiled(above, block.coefficients, first, basis(u), None, full)


def test_compiled_heights_equal_numpys(monkeypatch) -> None:
    """Ellipsoidal heights and verticals of points in a network frame, against
    :func:`graphcal.core.frames.ecef_to_height_and_normal` (checked against pymap3d in
    the frames' tests)."""
    from graphcal.core import frames
    from graphcal.model.trajectory import NetworkFrame

    frame = NetworkFrame(np.deg2rad(48.5), np.deg2rad(2.3))
    rng = np.random.default_rng(9)
    enu = rng.uniform(-400e3, 400e3, (5000, 3))
    enu[:, 2] = rng.uniform(-500.0, 15e3, 5000)
    height, normal = frames.ecef_to_height_and_normal(frame.to_ecef(enu))
    up = frames.rotate(normal, frame.rotation)
    compiled_sums(monkeypatch)
    got_height, got_up = frame.heights_and_up(enu)
    assert np.abs(got_height - height).max() <= 1e-7  # metres
    assert np.abs(got_up - up).max() <= 1e-14
    assert np.allclose(np.linalg.norm(got_up, axis=1), 1.0, rtol=0, atol=1e-14)


def test_compiled_band_product_equals_numpys(numpy_sums, monkeypatch) -> None:
    """``A x`` of a symmetric band (half-bandwidth 11) against NumPy's diagonal-by-diagonal
    sums and the dense product."""
    from graphcal.model.paths import band_matvec

    first, weights, info, vectors, _ = random_measurements(500, 80, seed=8)
    band = band_zeros(240)
    add_measurement_blocks(band, first, weights, info)
    x = np.random.default_rng(8).normal(size=240)
    expected = band_matvec(band, x)
    dense = np.zeros((240, 240))
    for d in range(band.shape[0]):
        dense += np.diag(band[d, : 240 - d], -d) + (np.diag(band[d, : 240 - d], d) if d else 0)
    assert np.allclose(dense @ x, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    compiled_sums(monkeypatch)
    got = band_matvec(band, x)
    assert np.abs(got - expected).max() <= 1e-13 * np.abs(expected).max()
    assert np.array_equal(band_matvec(band, np.stack([x, x], axis=1))[:, 1], expected)


def test_compiled_first_fit_equals_numpys(short_demo, numpy_sums, monkeypatch) -> None:  # noqa: F811
    """The first fit's plots (converted at the initial biases, 2-D at their heights) in
    its normal equations, summed with isotropic blocks in one compiled pass."""
    from graphcal.model.trajectory import initial_plot_system

    block, values = truth_block(short_demo, use_adsb=True)
    named = block._split([v + 1e-4 for v in values])
    expected_band, expected_rhs = initial_plot_system(block, named)
    compiled_sums(monkeypatch)
    band, rhs = initial_plot_system(block, named)
    assert np.abs(band - expected_band).max() <= 1e-13 * np.abs(expected_band).max()
    assert np.abs(rhs - expected_rhs).max() <= 1e-12 * np.abs(expected_rhs).max()
