"""Stacks of small matrices (graphcal.core.batched) against numpy's one-matrix-at-a-time forms."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.core.batched import (
    cholesky_inverse,
    congruent_diagonal,
    congruent_diagonal_variances,
    sum_of_products,
)


@pytest.mark.parametrize("m", [1, 2, 3, 4])
def test_cholesky_inverse_is_numpys(m: int) -> None:
    """Covariances scaled as a radar's are (m^2 beside rad^2), correlations up to 0.9."""
    rng = np.random.default_rng(m)
    a = rng.normal(size=(500, m, m))
    correlation = a @ np.swapaxes(a, 1, 2) + m * np.eye(m)
    d = np.sqrt(np.diagonal(correlation, axis1=1, axis2=2))
    correlation /= d[:, :, None] * d[:, None, :]
    scale = 10.0 ** rng.uniform(-4, 3, (500, m))
    cov = correlation * scale[:, :, None] * scale[:, None, :]
    expected = np.linalg.inv(np.linalg.cholesky(cov))
    got = cholesky_inverse(cov)
    # L^-1 = L_R^-1 D^-1: element (i, j) scales as 1 / scale_j.
    np.testing.assert_allclose(got * scale[:, None, :], expected * scale[:, None, :],
                               rtol=0, atol=1e-12)
    if m <= 3:
        assert np.all(np.triu(got, 1) == 0.0)


def test_cholesky_inverse_rejects_a_matrix_that_is_not_positive_definite() -> None:
    cov = np.tile(np.eye(3), (4, 1, 1))
    cov[2, 1, 1] = -1.0
    with pytest.raises(np.linalg.LinAlgError):
        cholesky_inverse(cov)


def test_sum_of_products_is_the_einsum() -> None:
    rng = np.random.default_rng(0)
    a, middle, b = rng.normal(size=(300, 3, 4)), rng.normal(size=(300, 3, 2)), rng.normal(
        size=(300, 2, 5))
    np.testing.assert_allclose(sum_of_products(a, middle, b),
                               np.einsum("nip,nij,njq->pq", a, middle, b), rtol=1e-12)
    np.testing.assert_allclose(sum_of_products(a, None, a), np.einsum("nip,niq->pq", a, a),
                               rtol=1e-12)


@pytest.mark.parametrize("shape", [(50, 3, 3), (50, 2, 3), (4, 5, 3, 2)])
def test_congruent_diagonal_is_the_matrix_product(shape) -> None:
    rng = np.random.default_rng(len(shape) + shape[-2])
    jac = rng.normal(size=shape)
    diagonal = rng.uniform(0.5, 2.0, size=shape[:-2] + shape[-1:])
    expected = (jac * diagonal[..., None, :]) @ np.swapaxes(jac, -1, -2)
    got = congruent_diagonal(jac, diagonal)
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13)
    assert np.array_equal(got, np.swapaxes(got, -1, -2))
    assert np.array_equal(congruent_diagonal_variances(jac, diagonal),
                          np.diagonal(got, axis1=-2, axis2=-1))
    # One diagonal for the whole stack.
    one = diagonal.reshape(-1, shape[-1])[0]
    np.testing.assert_allclose(congruent_diagonal(jac, one),
                               (jac * one) @ np.swapaxes(jac, -1, -2), rtol=1e-13, atol=1e-13)
