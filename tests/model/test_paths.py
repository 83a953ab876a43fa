"""The B-spline paths and their banded normal equations, against dense oracles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate

from graphcal.model.paths import (
    HALF_BANDWIDTH,
    SECOND_DERIVATIVE_GRAM,
    BandFactor,
    PathLayout,
    add_measurement_blocks,
    add_motion_prior,
    band_matvec,
    band_to_dense,
    band_zeros,
    basis,
    basis_derivative,
    motion_prior_energy,
    scatter_columns,
    scatter_vectors,
)


def test_basis_is_a_partition_of_unity_and_reproduces_lines() -> None:
    u = np.linspace(0.0, 1.0, 11)
    b = basis(u)
    assert np.allclose(b.sum(axis=1), 1.0)
    # Coefficients on a line k -> 2k + 1 give the line 2 (k + 1 + u) + 1 (uniform cubic
    # B-splines reproduce linear functions; the curve at interval 0 is centred on k = 1).
    c = 2.0 * np.arange(4) + 1.0
    assert np.allclose(b @ c, 2.0 * (1.0 + u) + 1.0)


def test_basis_derivative_matches_finite_differences() -> None:
    u = np.linspace(0.05, 0.95, 7)
    h = 1e-6
    numeric = (basis(u + h) - basis(u - h)) / (2 * h)
    assert np.allclose(basis_derivative(u), numeric, atol=1e-8)


def test_second_derivative_gram_matches_quadrature() -> None:
    def second(u: float) -> np.ndarray:
        h = 1e-4
        return (basis(np.array([u + h]))[0] - 2 * basis(np.array([u]))[0]
                + basis(np.array([u - h]))[0]) / h**2

    for a in range(4):
        for b in range(4):
            value, _ = integrate.quad(lambda u, a=a, b=b: second(u)[a] * second(u)[b], 0, 1)
            assert SECOND_DERIVATIVE_GRAM[a, b] == pytest.approx(value, abs=1e-4)


def make_layout() -> PathLayout:
    return PathLayout.build(np.array([0.0, 100.0]), np.array([55.0, 130.0]), 10.0, 20.0)


def test_layout_counts_and_locate() -> None:
    layout = make_layout()
    assert list(layout.n_intervals) == [6, 3]
    assert list(layout.first_coefficient) == [0, 9, 15]
    first, u = layout.locate(np.array([0, 0, 1]), np.array([0.0, 25.0, 129.0]))
    assert list(first) == [0, 2, 9 + 2]
    assert np.allclose(u, [0.0, 0.5, 0.9])
    assert layout.n_phases == 3 + 1
    assert len(layout.unknown_phase()) == layout.n_unknowns


def test_banded_assembly_matches_dense_assembly() -> None:
    rng = np.random.default_rng(3)
    layout = make_layout()
    n = layout.n_unknowns
    path = rng.integers(0, 2, 40)
    t = np.where(path == 0, rng.uniform(0, 55, 40), rng.uniform(100, 130, 40))
    first, u = layout.locate(path, t)
    w = basis(u)
    h = rng.normal(size=(40, 2, 3))
    info = np.swapaxes(h, 1, 2) @ h
    band = band_zeros(n)
    add_measurement_blocks(band, first, w, info)
    scale = rng.uniform(0.5, 2.0, (layout.n_phases, 3))  # 1 / q per phase and axis
    add_motion_prior(band, layout, scale)
    dense = np.zeros((n, n))
    for i in range(40):
        rows = np.arange(3 * first[i], 3 * first[i] + 12)
        dense[np.ix_(rows, rows)] += np.kron(np.outer(w[i], w[i]), info[i])
    interval_first = layout.interval_first_coefficient()
    for k, f in enumerate(interval_first):
        rows = np.arange(3 * f, 3 * f + 12)
        dense[np.ix_(rows, rows)] += np.kron(
            SECOND_DERIVATIVE_GRAM / layout.spacing_s**3, np.diag(scale[layout.phase[k]]))
    assert np.allclose(band_to_dense(band), dense)
    x = rng.normal(size=n)
    assert np.allclose(band_matvec(band, x), dense @ x)
    # Vectors and columns.
    v = rng.normal(size=(40, 3))
    expected = np.zeros(n)
    for i in range(40):
        expected[3 * first[i]:3 * first[i] + 12] += np.kron(w[i], v[i])
    assert np.allclose(scatter_vectors(first, w, v, n), expected)
    k = rng.normal(size=(40, 3, 2))
    out = np.zeros((n, 5))
    scatter_columns(first, w, k, np.array([1, 3]), out)
    expected = np.zeros((n, 5))
    for i in range(40):
        expected[3 * first[i]:3 * first[i] + 12][:, [1, 3]] += np.kron(w[i][:, None], k[i])
    assert np.allclose(out, expected)


def test_motion_prior_energy_is_the_quadratic_form() -> None:
    rng = np.random.default_rng(4)
    layout = make_layout()
    c = rng.normal(size=(layout.n_coefficients, 3))
    band = band_zeros(layout.n_unknowns)
    add_motion_prior(band, layout, np.ones(layout.n_phases))
    assert motion_prior_energy(c, layout).sum() == pytest.approx(
        float(c.ravel() @ band_matvec(band, c.ravel())))
    # Per axis: each axis's share is the quadratic form of that axis's prior alone.
    per_axis = motion_prior_energy(c, layout, per_axis=True)
    for axis in range(3):
        only = np.zeros((layout.n_phases, 3))
        only[:, axis] = 1.0
        band = band_zeros(layout.n_unknowns)
        add_motion_prior(band, layout, only)
        assert per_axis[:, axis].sum() == pytest.approx(
            float(c.ravel() @ band_matvec(band, c.ravel())))


def test_band_factor_solves_like_numpy() -> None:
    rng = np.random.default_rng(5)
    n = 60
    band = band_zeros(n)
    band[0] = 5.0 + rng.uniform(size=n)
    band[1:] = 0.1 * rng.normal(size=(HALF_BANDWIDTH, n))
    dense = band_to_dense(band)
    factor = BandFactor.of(band)
    rhs = rng.normal(size=(n, 3))
    assert np.allclose(factor.solve(rhs), np.linalg.solve(dense, rhs))
    z = factor.forward(rhs)
    assert np.allclose(z.T @ z, rhs.T @ np.linalg.solve(dense, rhs))
    assert 2 * factor.log_diagonal().sum() == pytest.approx(np.linalg.slogdet(dense)[1])
