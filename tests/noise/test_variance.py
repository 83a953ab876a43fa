"""Paper 000's formulas (eq. 1-10): error propagation, IRLS lines, residual sigmas.

Each number is checked against an independent expectation: a finite-difference
Jacobian of pymap3d, a linear-programming least-absolute-deviation fit and the
half-normal moments of Gaussian residuals.  The estimation of sigmas from radar
data is tested in tests/test_noise.py.
"""

from __future__ import annotations

import math

import numpy as np
import pymap3d
import pytest
from scipy.optimize import linprog

from graphcal.noise.variance import (
    fit_line_irls,
    printed_eq9_sigma,
    propagate_sigmas,
    residual_sigma,
    robust_residual_sigma,
)
from tests.jacobians import numerical_jacobian

# --------------------------------------------------------------------------- eq. 1-2


def _fd_jacobian_pymap3d(r: float, az: float, el: float) -> np.ndarray:
    """d(e, n, u) / d(r, az, el) by central differences of pymap3d.aer2enu."""
    return numerical_jacobian(
        lambda x: pymap3d.aer2enu(np.rad2deg(x[1]), np.rad2deg(x[2]), x[0]),
        np.array([r, az, el]), np.array([1.0, 1e-7, 1e-7]),
    )


def test_propagation_matches_pymap3d_finite_differences() -> None:
    rng = np.random.default_rng(0)
    s_r, s_a, s_e = 40.0, 1.2e-3, 2.5e-3
    r = rng.uniform(5e3, 300e3, 20)
    az = rng.uniform(0, 2 * np.pi, 20)
    el = rng.uniform(-0.02, 0.6, 20)
    got = propagate_sigmas(r, az, el, s_r, s_a, s_e)
    for i in range(20):
        jac = _fd_jacobian_pymap3d(r[i], az[i], el[i])
        cov = jac @ np.diag([s_r**2, s_a**2, s_e**2]) @ jac.T
        expected = np.sqrt(np.diag(cov))
        assert got.sigma_x_m[i] == pytest.approx(expected[0], rel=1e-5)
        assert got.sigma_y_m[i] == pytest.approx(expected[1], rel=1e-5)
        assert got.sigma_z_m[i] == pytest.approx(expected[2], rel=1e-5)
        # eq. 2: RMS of the three components.
        assert got.sigma_p_m[i] == pytest.approx(np.sqrt(np.trace(cov) / 3), rel=1e-5)


def test_propagation_hand_formula_and_2d() -> None:
    """Paper 000 eq. 1 (corrected) written out; a 2-D radar has no elevation term."""
    r, az, el = 150e3, np.deg2rad(30.0), np.deg2rad(3.0)
    s_r, s_a, s_e = 30.0, 1e-3, 2e-3
    sx = math.sqrt((math.cos(el) * math.sin(az) * s_r) ** 2
                   + (r * math.cos(el) * math.cos(az) * s_a) ** 2
                   + (r * math.sin(el) * math.sin(az) * s_e) ** 2)
    sy = math.sqrt((math.cos(el) * math.cos(az) * s_r) ** 2
                   + (r * math.cos(el) * math.sin(az) * s_a) ** 2
                   + (r * math.sin(el) * math.cos(az) * s_e) ** 2)
    sz = math.sqrt((math.sin(el) * s_r) ** 2 + (r * math.cos(el) * s_e) ** 2)
    got = propagate_sigmas(r, az, el, s_r, s_a, s_e)
    assert float(got.sigma_x_m) == pytest.approx(sx, rel=1e-12)
    assert float(got.sigma_y_m) == pytest.approx(sy, rel=1e-12)
    assert float(got.sigma_z_m) == pytest.approx(sz, rel=1e-12)
    two_d = propagate_sigmas(r, az, el, s_r, s_a, None)
    assert float(two_d.sigma_z_m) == pytest.approx(math.sin(el) * s_r, rel=1e-12)
    # The paper's example: 1 deg of azimuth at 50 km is 873 m across.
    assert float(propagate_sigmas(50e3, 0.0, 0.0, 0.0, np.deg2rad(1.0)).sigma_x_m) == (
        pytest.approx(872.7, abs=0.1))


# --------------------------------------------------------------------------- eq. 3-9


def _lad_linprog(t: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Least-absolute-deviation line by linear programming: (slope, intercept, L1 norm)."""
    n = t.size
    # variables: a, b, u (n), v (n) >= 0 with a + b t + u - v = y
    c = np.concatenate([[0.0, 0.0], np.ones(2 * n)])
    a_eq = np.hstack([np.ones((n, 1)), t[:, None], np.eye(n), -np.eye(n)])
    bounds = [(None, None), (None, None)] + [(0, None)] * (2 * n)
    sol = linprog(c, A_eq=a_eq, b_eq=y, bounds=bounds, method="highs")
    return float(sol.x[1]), float(sol.x[0]), float(sol.fun)


def test_irls_recovers_line_with_outliers() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 204.0, 4.0)
    y = 1000.0 + 200.0 * t + rng.normal(0.0, 30.0, t.size)
    y[[3, 17, 30, 44, 48]] += 3000.0
    fit = fit_line_irls(t, y)
    ols_slope = np.polyfit(t, y, 1)[0]
    # L1 slope sd ~ sqrt(pi/2) 30 / sqrt(sum (t - mean)^2) = 0.09 m/s; OLS is pulled off.
    assert fit.slope == pytest.approx(200.0, abs=0.4)
    assert abs(ols_slope - 200.0) > 3 * abs(fit.slope - 200.0) + 0.5
    # Independent LAD solution by linear programming: same minimum L1 norm.
    _, _, l1 = _lad_linprog(t, y)
    assert fit.l1_norm == pytest.approx(l1, rel=1e-4)
    assert fit.weights.sum() == pytest.approx(1.0)
    assert np.all(fit.weights[[3, 17, 30, 44, 48]] < np.median(fit.weights))


def test_printed_eq9_underestimates_by_sqrt_1_minus_2_over_pi() -> None:
    """Gaussian residuals: eq. 9 as printed gives sqrt(1 - 2/pi) = 0.6028 sigma."""
    rng = np.random.default_rng(2)
    residuals = rng.normal(0.0, 50.0, 400_000)
    ratio = printed_eq9_sigma(residuals) / residual_sigma(residuals)
    # sd of the ratio ~ 0.001 at this size.
    assert ratio == pytest.approx(math.sqrt(1.0 - 2.0 / math.pi), abs=0.005)
    assert residual_sigma(residuals) == pytest.approx(50.0, rel=0.005)
    assert robust_residual_sigma(residuals) == pytest.approx(50.0, rel=0.01)


def test_dof_correction_of_short_line_fits() -> None:
    """Residuals of 10-point line fits: sum l^2 / (n - 2) is unbiased, sum l^2 / n is 20 % low."""
    rng = np.random.default_rng(3)
    t = np.arange(10.0)
    var_dof, var_naive = [], []
    for _ in range(4000):
        y = 5.0 + 2.0 * t + rng.normal(0.0, 1.0, t.size)
        res = y - np.polyval(np.polyfit(t, y, 1), t)
        var_dof.append(residual_sigma(res) ** 2)
        var_naive.append(np.mean(res**2))
    assert np.mean(var_dof) == pytest.approx(1.0, abs=0.03)
    assert np.mean(var_naive) == pytest.approx(0.8, abs=0.03)


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="two distinct"):
        fit_line_irls([1.0, 1.0, 1.0], [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="more than 2"):
        residual_sigma([1.0, 2.0])


def test_mad_constants_are_the_gaussian_ones() -> None:
    """sigma = 1.4826 MAD for Gaussian data, and the MAD sigma's standard error factor
    sqrt(1 / (16 phi(q)^2 q^2)), q = Phi^-1(3/4): the literals are scipy's values."""
    from scipy import stats

    from graphcal.noise.result import MAD_SE_FACTOR
    from graphcal.noise.variance import MAD_TO_SIGMA

    q = stats.norm.ppf(0.75)
    assert MAD_TO_SIGMA == 1.0 / q
    assert MAD_SE_FACTOR == math.sqrt(0.25 / (2.0 * stats.norm.pdf(q)) ** 2 / q**2)
