"""The shared numerical-Jacobian helper against Jacobians known in closed form."""

from __future__ import annotations

import numpy as np

from tests.jacobians import numerical_jacobian


def test_linear_map_is_exact() -> None:
    a = np.array([[1.0, -2.0, 0.5], [3.0, 0.0, 4.0]])
    jac = numerical_jacobian(lambda x: x @ a.T, np.array([0.3, -1.0, 2.0]), np.ones(3))
    np.testing.assert_allclose(jac, a, rtol=0, atol=1e-12)


def test_batched_points_with_their_own_steps() -> None:
    """d(x0 x1, x0^2) / d(x0, x1) = [[x1, x0], [2 x0, 0]]; central differences of a
    quadratic are exact up to rounding."""
    x = np.array([[1.0, 2.0], [-3.0, 0.5], [10.0, -4.0]])
    steps = np.array([[1e-3, 1e-3], [1e-2, 1e-2], [1.0, 1.0]])
    jac = numerical_jacobian(lambda v: (v[..., 0] * v[..., 1], v[..., 0] ** 2), x, steps)
    expected = np.stack([np.stack([x[:, 1], x[:, 0]], -1),
                         np.stack([2 * x[:, 0], np.zeros(3)], -1)], axis=1)
    np.testing.assert_allclose(jac, expected, rtol=0, atol=1e-9)


def test_difference_wraps_an_angle() -> None:
    """An azimuth crossing the 0 / 2 pi seam: plain differences jump by 2 pi, wrapped do not."""
    def azimuth(x: np.ndarray) -> np.ndarray:
        return np.array([np.mod(x[0], 2 * np.pi)])

    def wrapped(plus: np.ndarray, minus: np.ndarray) -> np.ndarray:
        return np.mod(plus - minus + np.pi, 2 * np.pi) - np.pi

    at_seam = np.array([0.0])
    assert abs(numerical_jacobian(azimuth, at_seam, [1e-6])[0, 0]) > 1e5
    np.testing.assert_allclose(
        numerical_jacobian(azimuth, at_seam, [1e-6], difference=wrapped), [[1.0]], atol=1e-9
    )
