"""Tests of graphcal.core.covariance: measurement-covariance conversion (paper 002).

Independent expectations: explicit loops, pymap3d (numerical Jacobians of its
conversions), central finite differences, Gauss-Hermite quadrature, closed
forms derived by hand, and seeded Monte Carlo with tolerances from its
sampling error.  Angles are radians unless a name says ``_deg``.  Azimuth is
clockwise from north, so paper 002's formulas appear with ``sin(az)`` and
``cos(az)`` swapped.
"""

from __future__ import annotations

import itertools

import numpy as np
import pymap3d
import pytest
from numpy.polynomial.hermite_e import hermegauss

from graphcal.core import frames
from graphcal.core.covariance import (
    convert_covariance,
    ecef_to_enu_covariance,
    ecef_to_polar_covariance,
    enu_to_ecef_covariance,
    enu_to_enu_covariance,
    mean_square_error,
    polar_covariance,
    polar_to_ecef_covariance,
    polar_to_enu_covariance,
    polar_to_enu_hessian,
    polar_to_enu_mean_shift,
    second_order_covariance_term,
    second_order_mean,
    second_order_relative_size,
)
from tests.jacobians import numerical_jacobian

DEG = np.pi / 180.0
#: Radar site (lat_rad, lon_rad, alt_m) of the Monte-Carlo experiments (Changsha).
SITE = (28.2 * DEG, 112.9 * DEG, 50.0)
#: Sites for the linear conversions: mid-latitude, equator/antimeridian, south, near pole.
SITES = [
    (48.7 * DEG, 9.2 * DEG, 420.0),
    (0.0, np.pi, 0.0),
    (-33.9 * DEG, -70.7 * DEG, -35.0),
    (89.5 * DEG, -120.0 * DEG, 2800.0),
]


def random_spd(rng: np.random.Generator, shape: tuple[int, ...], n: int) -> np.ndarray:
    """Random symmetric positive-definite matrices ``(*shape, n, n)``, entries of order 1e4."""
    a = rng.normal(0.0, 100.0, (*shape, n, n))
    return a @ np.swapaxes(a, -1, -2) + 10.0 * np.eye(n)


def trace(m: np.ndarray) -> np.ndarray:
    return np.trace(m, axis1=-2, axis2=-1)


# ---------------------------------------------------------------------------
# General rule J R J^T and the linear conversions (paper 002 eq. 2-6)
# ---------------------------------------------------------------------------


def test_convert_covariance_matches_explicit_loops_non_square_and_broadcast():
    """J (5, 4, 2, 3) with R (4, 3, 3): sum_ab J_ia R_ab J_jb by loops; rtol 1e-12 (rounding)."""
    rng = np.random.default_rng(1)
    jac = rng.normal(size=(5, 4, 2, 3))
    cov = random_spd(rng, (4,), 3)
    out = convert_covariance(cov, jac)
    assert out.shape == (5, 4, 2, 2)
    expected = np.zeros((5, 4, 2, 2))
    for p, q, i, j, a, b in itertools.product(
        range(5), range(4), range(2), range(2), range(3), range(3)
    ):
        expected[p, q, i, j] += jac[p, q, i, a] * cov[q, a, b] * jac[p, q, j, b]
    np.testing.assert_allclose(out, expected, rtol=1e-12)
    np.testing.assert_allclose(
        out, np.einsum("...ia,...ab,...jb->...ij", jac, cov[None], jac), rtol=1e-12
    )


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: convert_covariance(np.eye(3)[:2], np.eye(3)), "square"),
        (lambda: convert_covariance(np.eye(3), np.eye(2)), "columns"),
        (lambda: convert_covariance(np.ones(3), np.eye(3)), "shape"),
        (lambda: convert_covariance(-np.eye(3), np.eye(3)), "negative variance"),
        (lambda: polar_covariance(-1.0, 0.1), "sigma_range_m"),
        (lambda: polar_covariance(1.0, 0.1, -0.1), "sigma_elevation_rad"),
        (lambda: enu_to_ecef_covariance(np.eye(2), 0.1, 0.2), r"\(\.\.\., 3, 3\)"),
        (lambda: polar_to_enu_covariance(-1.0, 0.0, 0.0, np.eye(3)), "range"),
        (lambda: polar_to_enu_covariance(1.0, 0.0, 0.0, np.eye(3), order=3), "order"),
        (lambda: polar_to_enu_covariance(1.0, 0.0, 0.0, np.ones((3, 3)), order="exact"), "diag"),
        (lambda: second_order_covariance_term(np.zeros((3, 2, 2)), np.eye(3)), "hessian"),
        (lambda: mean_square_error(np.eye(3), np.zeros(2)), "mean_shift"),
    ],
)
def test_bad_inputs_raise_value_error(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_polar_covariance_diagonal_and_two_d_radar():
    """Squares of the sigmas on the diagonal; no elevation -> zero variance (exact)."""
    cov = polar_covariance([50.0, 100.0], 0.1 * DEG, 0.2 * DEG)
    assert cov.shape == (2, 3, 3)
    np.testing.assert_array_equal(cov[1], np.diag([1e4, (0.1 * DEG) ** 2, (0.2 * DEG) ** 2]))
    cov_2d = polar_covariance(50.0, 0.1 * DEG)
    np.testing.assert_array_equal(cov_2d, np.diag([2500.0, (0.1 * DEG) ** 2, 0.0]))


@pytest.mark.parametrize("site", SITES)
def test_enu_ecef_round_trip_and_trace_invariance(site):
    """ENU -> ECEF -> ENU returns the input and keeps trace and eigenvalues (rotation);
    rtol 1e-12 of the largest entry (rounding of 3x3 products)."""
    rng = np.random.default_rng(2)
    cov = random_spd(rng, (6,), 3)
    lat, lon, _ = site
    ecef = enu_to_ecef_covariance(cov, lat, lon)
    back = ecef_to_enu_covariance(ecef, lat, lon)
    scale = np.abs(cov).max()
    np.testing.assert_allclose(back, cov, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(trace(ecef), trace(cov), rtol=1e-12)
    np.testing.assert_allclose(
        np.linalg.eigvalsh(ecef), np.linalg.eigvalsh(cov), rtol=0, atol=1e-12 * scale
    )


def test_linear_conversion_broadcasts_latitude_arrays():
    """Arrays of sites broadcast with the covariance's leading axis; each row equals the
    scalar call (bit-for-bit up to rtol 1e-15)."""
    rng = np.random.default_rng(3)
    cov = random_spd(rng, (4,), 3)
    lat = np.array([s[0] for s in SITES])
    lon = np.array([s[1] for s in SITES])
    out = enu_to_ecef_covariance(cov, lat, lon)
    for k in range(4):
        np.testing.assert_allclose(out[k], enu_to_ecef_covariance(cov[k], lat[k], lon[k]), 1e-15)


@pytest.mark.parametrize("site", SITES)
def test_enu_to_ecef_covariance_matches_pymap3d(site):
    """J = numerical Jacobian of pymap3d.enu2ecef (linear, so central differences are exact
    up to rounding: 1e-9 m / 10 m steps); compare J R J^T, atol 1e-8 of the scale."""
    lat, lon, alt = site
    rng = np.random.default_rng(4)
    cov = random_spd(rng, (), 3)

    def enu2ecef(e, n, u):
        return pymap3d.enu2ecef(e, n, u, lat, lon, alt, deg=False)

    jac = numerical_jacobian(lambda x: enu2ecef(*x), np.array([3e4, -2e4, 5e3]), np.full(3, 10.0))
    np.testing.assert_allclose(
        enu_to_ecef_covariance(cov, lat, lon), jac @ cov @ jac.T, rtol=0, atol=1e-8 * cov.max()
    )


@pytest.mark.parametrize("site", SITES)
@pytest.mark.parametrize(
    "polar", [(1e4, 60.0 * DEG, 60.0 * DEG), (2.5e5, 200.0 * DEG, 1.0 * DEG), (5e4, 0.3, -0.2)]
)
def test_polar_to_ecef_chain_matches_pymap3d(site, polar):
    """Paper 002 eq. 19: polar -> ENU -> ECEF equals J R J^T with J the numerical Jacobian
    of pymap3d.aer2ecef (radians).  Steps 1 m / 1e-6 rad: truncation ~1e-12, rounding of
    ECEF (~1e-9 m) / (1e-6 rad * 1e4 m) ~ 1e-7 relative -> rtol 1e-5 of the largest entry."""
    lat, lon, alt = site
    r, az, el = polar
    cov_polar = polar_covariance(50.0, 0.2 * DEG, 0.3 * DEG)

    def aer2ecef(rng_m, az_rad, el_rad):
        return pymap3d.aer2ecef(az_rad, el_rad, rng_m, lat, lon, alt, deg=False)

    jac = numerical_jacobian(
        lambda x: aer2ecef(*x), np.array([r, az, el]), np.array([1.0, 1e-6, 1e-6])
    )
    expected = jac @ cov_polar @ jac.T
    got = polar_to_ecef_covariance(r, az, el, cov_polar, lat, lon)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5 * np.abs(expected).max())


def test_enu_to_enu_and_ecef_to_polar_chains():
    """Radar A's ENU -> radar B's ENU equals the chain through ECEF (rtol 1e-12); ECEF ->
    radar polar at the target inverts polar -> ECEF to first order (J^-1 J = I):
    recovers the diagonal polar covariance, rtol 1e-9 (conditioning of r * angles)."""
    rng = np.random.default_rng(5)
    cov = random_spd(rng, (3,), 3)
    (lat_a, lon_a, _), (lat_b, lon_b, _) = SITES[0], SITES[2]
    direct = enu_to_enu_covariance(cov, lat_a, lon_a, lat_b, lon_b)
    chain = ecef_to_enu_covariance(enu_to_ecef_covariance(cov, lat_a, lon_a), lat_b, lon_b)
    np.testing.assert_allclose(direct, chain, rtol=0, atol=1e-12 * np.abs(cov).max())

    lat, lon, alt = SITES[0]
    r, az, el = 8e4, 130.0 * DEG, 4.0 * DEG
    cov_polar = polar_covariance(60.0, 0.15 * DEG, 0.25 * DEG)
    cov_ecef = polar_to_ecef_covariance(r, az, el, cov_polar, lat, lon)
    target = frames.polar_to_ecef(r, az, el, lat, lon, alt)
    back = ecef_to_polar_covariance(cov_ecef, target, lat, lon, alt)
    np.testing.assert_allclose(np.diag(back), np.diag(cov_polar), rtol=1e-9)
    np.testing.assert_allclose(
        back / np.sqrt(np.outer(np.diag(back), np.diag(back))), np.eye(3), atol=1e-9
    )


# ---------------------------------------------------------------------------
# Jacobian, Hessian and the closed forms of paper 002 eq. 23-25
# ---------------------------------------------------------------------------

POLAR_POINTS = np.array(
    [
        [1e4, 60.0 * DEG, 60.0 * DEG],
        [2e5, 215.0 * DEG, 2.0 * DEG],
        [3e3, 350.0 * DEG, -10.0 * DEG],
        [5e4, 95.0 * DEG, 85.0 * DEG],
    ]
)


@pytest.mark.parametrize("point", POLAR_POINTS)
def test_first_order_jacobian_matches_finite_differences(point):
    """frames.polar_to_enu_jacobian vs central differences of frames.polar_to_enu
    (steps 1e-3 m, 1e-7 rad: truncation ~1e-14 r, rounding ~1e-16 r / 1e-7): rtol 1e-6."""
    jac_fd = numerical_jacobian(
        lambda x: frames.polar_to_enu(*x), np.asarray(point), np.array([1e-3, 1e-7, 1e-7])
    )
    jac = frames.polar_to_enu_jacobian(*point)
    np.testing.assert_allclose(jac, jac_fd, rtol=0, atol=1e-6 * np.abs(jac).max())


def test_hessian_matches_central_finite_differences():
    """H_ijk vs the four-point central second difference of frames.polar_to_enu
    (steps 1 m, 1e-4 rad): truncation ~h^2 ~1e-8 relative, rounding ~eps r / h^2 ~ 1e-4 m
    against entries ~r -> atol 1e-6 of the largest entry (range column: 1e-6 of 1)."""
    steps = np.array([1.0, 1e-4, 1e-4])
    hess = polar_to_enu_hessian(POLAR_POINTS[:, 0], POLAR_POINTS[:, 1], POLAR_POINTS[:, 2])
    assert hess.shape == (4, 3, 3, 3)
    for p, x0 in enumerate(POLAR_POINTS):
        fd = np.zeros((3, 3, 3))
        for j, k in itertools.product(range(3), range(3)):
            dj = np.zeros(3)
            dk = np.zeros(3)
            dj[j] = steps[j]
            dk[k] = steps[k]
            f = [frames.polar_to_enu(*(x0 + sj * dj + sk * dk)) for sj, sk in
                 ((1, 1), (1, -1), (-1, 1), (-1, -1))]
            fd[:, j, k] = (f[0] - f[1] - f[2] + f[3]) / (4.0 * steps[j] * steps[k])
        # Range-range entries are exactly zero and range-angle entries are of order 1.
        scale = np.array([1.0, x0[0], x0[0]])
        atol = 1e-6 * np.sqrt(scale[:, None] * scale[None, :])
        for i in range(3):
            np.testing.assert_array_less(np.abs(hess[p, i] - fd[i]), atol)


@pytest.mark.parametrize("point", POLAR_POINTS)
def test_first_order_matches_paper_eq_24_25(point):
    """Eq. 24 (azimuth from north: sin and cos of az swapped) and eq. 25's sum
    sigma_r^2 + sigma_a^2 r^2 cos^2 e + sigma_e^2 r^2; rtol 1e-12."""
    r, a, e = point
    sr, sa, se = 500.0, 0.7 * DEG, 0.4 * DEG
    cov = polar_to_enu_covariance(r, a, e, polar_covariance(sr, sa, se))
    var_e = sr**2 * (np.sin(a) * np.cos(e)) ** 2 + sa**2 * (r * np.cos(a) * np.cos(e)) ** 2
    var_e += se**2 * (r * np.sin(a) * np.sin(e)) ** 2
    var_n = sr**2 * (np.cos(a) * np.cos(e)) ** 2 + sa**2 * (r * np.sin(a) * np.cos(e)) ** 2
    var_n += se**2 * (r * np.cos(a) * np.sin(e)) ** 2
    var_u = sr**2 * np.sin(e) ** 2 + se**2 * (r * np.cos(e)) ** 2
    np.testing.assert_allclose(np.diag(cov), [var_e, var_n, var_u], rtol=1e-12)
    eq25 = sr**2 + sa**2 * r**2 * np.cos(e) ** 2 + se**2 * r**2
    np.testing.assert_allclose(trace(cov), eq25, rtol=1e-12)


# ---------------------------------------------------------------------------
# Second order and the exact conversion
# ---------------------------------------------------------------------------


def gauss_hermite_moments(func, cov: np.ndarray, points: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of ``func(d)`` for ``d ~ N(0, cov)`` by tensor Gauss-Hermite
    quadrature (exact for polynomials of degree < 2 * points in each variable)."""
    nodes, weights = hermegauss(points)
    weights = weights / weights.sum()
    chol = np.linalg.cholesky(cov)
    grid = np.array(list(itertools.product(nodes, repeat=cov.shape[0])))
    w = np.prod(np.array(list(itertools.product(weights, repeat=cov.shape[0]))), axis=1)
    values = func(grid @ chol.T)  # (points^n, m)
    mean = w @ values
    centred = values - mean
    return mean, (centred * w[:, None]).T @ centred


def test_second_order_terms_exact_for_a_quadratic_map():
    """For y = J d + 1/2 d^T H d with Gaussian d, the second-order mean and covariance are
    exact; reference: 3-point Gauss-Hermite (exact up to degree 5 per variable, here
    degree 4) -> agreement to rounding, rtol 1e-10."""
    rng = np.random.default_rng(6)
    jac = rng.normal(size=(2, 3))
    hess = rng.normal(size=(2, 3, 3))
    hess = hess + np.swapaxes(hess, -1, -2)
    cov = random_spd(rng, (), 3) / 1e4

    def quadratic(d):
        return d @ jac.T + 0.5 * np.einsum("pa,iab,pb->pi", d, hess, d)

    mean, cov_y = gauss_hermite_moments(quadratic, cov, 3)
    np.testing.assert_allclose(second_order_mean(hess, cov), mean, rtol=1e-10)
    expected = convert_covariance(cov, jac) + second_order_covariance_term(hess, cov)
    np.testing.assert_allclose(expected, cov_y, rtol=1e-10)


def test_exact_order_matches_gauss_hermite_quadrature():
    """order='exact' (covariance and mean shift) vs 60-point Gauss-Hermite quadrature of
    frames.polar_to_enu at large sigmas (10 deg, 25 deg); the integrand is smooth, so
    quadrature converges to rounding: rtol 1e-9 of the largest entry."""
    r, a, e = 1e4, 40.0 * DEG, 30.0 * DEG
    cov_polar = polar_covariance(500.0, 10.0 * DEG, 25.0 * DEG)
    truth = frames.polar_to_enu(r, a, e)

    def convert(d):
        return frames.polar_to_enu(r + d[:, 0], a + d[:, 1], e + d[:, 2])

    mean, cov = gauss_hermite_moments(convert, cov_polar, 60)
    got = polar_to_enu_covariance(r, a, e, cov_polar, order="exact")
    np.testing.assert_allclose(got, cov, rtol=0, atol=1e-9 * np.abs(cov).max())
    shift = polar_to_enu_mean_shift(r, a, e, cov_polar, order="exact")
    np.testing.assert_allclose(shift, mean - truth, rtol=0, atol=1e-9 * r)


def test_exact_order_matches_monte_carlo_at_large_sigmas():
    """order='exact' vs 10^6 seeded samples at sigma_a = sigma_e = 10 deg: each entry
    within 5 sampling standard deviations sqrt((S_ii S_jj + S_ij^2) / n); first order
    misses by far more (its trace is > 2 % off here, ~50 standard deviations)."""
    rng = np.random.default_rng(7)
    n = 1_000_000
    r, a, e = 1e4, 40.0 * DEG, 30.0 * DEG
    sr, sa, se = 500.0, 10.0 * DEG, 10.0 * DEG
    cov_polar = polar_covariance(sr, sa, se)
    samples = frames.polar_to_enu(
        r + sr * rng.standard_normal(n), a + sa * rng.standard_normal(n),
        e + se * rng.standard_normal(n),
    )
    mc = np.cov(samples.T)
    exact = polar_to_enu_covariance(r, a, e, cov_polar, order="exact")
    d = np.diag(exact)
    sd = np.sqrt((np.outer(d, d) + exact**2) / n)
    np.testing.assert_array_less(np.abs(mc - exact), 5.0 * sd)
    first = polar_to_enu_covariance(r, a, e, cov_polar)
    assert abs(trace(first) / trace(mc) - 1.0) > 0.02


def test_order_two_is_not_uniformly_better():
    """Azimuth noise s only, el = 0, trace over east and north (closed forms):
    exact r^2 (1 - exp(-s^2)) = r^2 (s^2 - s^4/2 + ...); first order r^2 s^2 (error
    +s^4/2), with the Hessian term r^2 (s^2 + s^4/2) (error +s^4); the dropped
    third-derivative cross term 2 E[(J d)(T d^3)/6] = -r^2 s^4 restores the exact s^4
    coefficient.  Mean square about the truth 2 r^2 (1 - exp(-s^2/2)): errors +s^4/4
    (first order) and +s^4 (Hessian term plus b b^T).  Coefficients to O(s^2) = 8e-3 at
    5 deg -> tolerance 1e-2."""
    r, a = 1e4, 0.3
    for s_deg in (1.0, 2.0, 5.0):
        s = s_deg * DEG
        cov_polar = polar_covariance(0.0, s, 0.0)
        covs = {
            o: polar_to_enu_covariance(r, a, 0.0, cov_polar, order=o) for o in (1, 2, "exact")
        }
        tr = {o: trace(c[:2, :2]) for o, c in covs.items()}
        exact = r**2 * -np.expm1(-(s**2))
        np.testing.assert_allclose(tr["exact"], exact, rtol=1e-12)
        unit = r**2 * s**4
        assert (tr[1] - exact) / unit == pytest.approx(0.5, abs=1e-2)
        assert (tr[2] - exact) / unit == pytest.approx(1.0, abs=1e-2)
        # Third-derivative cross term: d^3 east/da^3 = -r cos(a), d^3 north/da^3 = r sin(a).
        jac_a = np.array([r * np.cos(a), -r * np.sin(a)])
        third = np.array([-r * np.cos(a), r * np.sin(a)])
        cross = 2.0 * np.sum(jac_a * third) * 3.0 * s**4 / 6.0
        assert cross == pytest.approx(-unit, rel=1e-12)
        assert (tr[2] + cross - exact) / unit == pytest.approx(0.0, abs=1e-2)

        mse_exact = 2.0 * r**2 * -np.expm1(-(s**2) / 2.0)
        shift = {o: polar_to_enu_mean_shift(r, a, 0.0, cov_polar, order=o) for o in (2, "exact")}
        mse = {o: trace(mean_square_error(covs[o], shift[o])[:2, :2]) for o in (2, "exact")}
        np.testing.assert_allclose(mse["exact"], mse_exact, rtol=1e-12)
        assert (tr[1] - mse_exact) / unit == pytest.approx(0.25, abs=1e-2)
        assert (mse[2] - mse_exact) / unit == pytest.approx(1.0, abs=1e-2)


def test_order_two_wins_at_large_sigma_by_monte_carlo():
    """The same statement without closed forms: 10^6 samples at s = 20 deg (azimuth only,
    el = 0).  Trace sampling error ~sqrt(2/n) = 0.14 %; first order is ~6 % high, with the
    Hessian term ~12 % high, exact within 1 %."""
    rng = np.random.default_rng(8)
    n = 1_000_000
    r, a, s = 1e4, 0.3, 20.0 * DEG
    samples = frames.polar_to_enu(r, a + s * rng.standard_normal(n), 0.0)
    mc = np.sum(np.var(samples[:, :2], axis=0))
    cov_polar = polar_covariance(0.0, s, 0.0)
    err = {
        o: trace(polar_to_enu_covariance(r, a, 0.0, cov_polar, order=o)[:2, :2]) / mc - 1.0
        for o in (1, 2, "exact")
    }
    assert abs(err["exact"]) < 0.01
    assert 0.04 < err[1] < 0.08
    assert 0.10 < err[2] < 0.14


def test_hessian_term_is_exact_leading_term_where_first_order_vanishes():
    """At el = 90 deg the first-order rows of up (elevation noise) and of east at az = 0
    vanish; the Hessian term gives the exact leading sigma^4 term:
    var(up) = r^2 (1 - exp(-s_e^2))^2 / 2 ~ r^2 s_e^4 / 2,
    var(east) = r^2 (1 - exp(-2 s_e^2))(1 - exp(-2 s_a^2)) / 4 ~ r^2 s_a^2 s_e^2.
    Relative differences O(s^2) ~ 3e-4 at 1 deg -> rtol 2e-3; first order ~1e-29 r^2."""
    r = 1e4
    sa, se = 0.5 * DEG, 1.0 * DEG
    cov_polar = polar_covariance(0.0, sa, se)
    el = 90.0 * DEG
    var_up = r**2 * np.expm1(-(se**2)) ** 2 / 2.0
    var_east = r**2 * np.expm1(-2 * se**2) * np.expm1(-2 * sa**2) / 4.0
    second = polar_to_enu_covariance(r, 0.0, el, cov_polar, order=2)
    exact = polar_to_enu_covariance(r, 0.0, el, cov_polar, order="exact")
    first = polar_to_enu_covariance(r, 0.0, el, cov_polar, order=1)
    np.testing.assert_allclose([second[2, 2], second[0, 0]], [var_up, var_east], rtol=2e-3)
    np.testing.assert_allclose([exact[2, 2], exact[0, 0]], [var_up, var_east], rtol=1e-9)
    assert first[0, 0] < 1e-12 * var_east and first[2, 2] < 1e-12 * var_up


def test_relative_size_against_paper_eq_29():
    """sigma_r = 0, sigma_a = sigma_e = s = 1 deg.  Derived: tr(S) / (tr(J R J^T) + tr(S)) =
    s^2 (2 + sin^2 e) / (2 (2 - sin^2 e) + s^2 (2 + sin^2 e)), i.e. s^2 / (2 + s^2) at
    e = 0: about twice paper eq. 29's s^2 / (4 + s^2) (its eq. 26 keeps only squared halves
    of the diagonal Hessian entries), both ~1e-4 << 1.  rtol 1e-10."""
    s = 1.0 * DEG
    r, a = 1e4, 60.0 * DEG
    el = np.array([0.0, 30.0, 60.0, 90.0]) * DEG
    cov_polar = polar_covariance(0.0, s, s)
    ratio = second_order_relative_size(
        frames.polar_to_enu_jacobian(r, a, el), polar_to_enu_hessian(r, a, el), cov_polar
    )
    s2e = np.sin(el) ** 2
    np.testing.assert_allclose(
        ratio, s**2 * (2 + s2e) / (2 * (2 - s2e) + s**2 * (2 + s2e)), rtol=1e-10
    )
    paper = s**2 / (4 + s**2)
    assert paper == pytest.approx(7.6e-5, rel=1e-2)
    assert ratio[0] / paper == pytest.approx(2.0, rel=1e-3)
    assert ratio.max() < 5e-4  # 3 s^2 / 2 = 4.6e-4 at the zenith
    # Range-angle Hessian entries: the share grows with sigma_r (eq. 28 says it falls).
    at = (1e4, 60.0 * DEG, 60.0 * DEG)
    shares = [
        second_order_relative_size(
            frames.polar_to_enu_jacobian(*at), polar_to_enu_hessian(*at), polar_covariance(sr, s, s)
        )
        for sr in (0.0, 500.0)
    ]
    assert shares[0] == pytest.approx(3.35e-4, rel=1e-3)
    assert shares[1] == pytest.approx(3.746e-4, rel=1e-3)


# ---------------------------------------------------------------------------
# Monte Carlo of paper 002 section 3
# ---------------------------------------------------------------------------


def monte_carlo_relative_error(
    range_m, azimuth_rad, elevation_rad, sigma_r, sigma_a, sigma_e, n, rng, runs=100
):
    """Per-cell mean relative error of the converted covariance sum, paper 002 section 3.

    For each cell (a true target ``(r, az, el)`` and sigmas; arrays broadcast to cells):

    1. ``n`` noisy polar measurements ``(r + sigma_r z1, az + sigma_a z2, el + sigma_e z3)``
       with standard normals ``z`` are converted to ECEF (radar at :data:`SITE`), and the
       statistical covariance sum is eq. 30, ``e = mean |x'_k - x|^2`` about the true
       ECEF point ``x``;
    2. ``runs`` further noisy measurements (the paper's 100 Monte-Carlo runs) each give the
       converted covariance sum ``T_k = tr(polar_to_ecef_covariance(...))`` evaluated at
       the measured point (eq. 19/25), since the truth is unknown in practice;
    3. the cell's relative error is ``mean_k |T_k - e| / e``.

    Sampling noise: ``e`` has relative standard deviation ``sqrt(2 sum lambda^2) /
    sum lambda / sqrt(n)`` (``lambda`` the eigenvalues of the ECEF covariance, Gaussian
    approximation), and ``T_k`` varies with the measured range and elevation by
    ``|grad T|_R / T``; see :func:`predicted_mean_relative_error`.  ECEF positions are
    assembled component-wise (same values as frames.polar_to_ecef, less memory).

    Returns ``(e, relative_error)``, both of the broadcast cell shape.
    """
    arrays = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (range_m, azimuth_rad, elevation_rad,
                                               sigma_r, sigma_a, sigma_e))
    )
    shape = arrays[0].shape
    r, az, el, sr, sa, se = (v.ravel()[:, None] for v in arrays)
    lat, lon, alt = SITE
    rot = frames.ecef_to_enu_rotation(lat, lon)  # rows: east, north, up in ECEF
    origin = frames.geodetic_to_ecef(lat, lon, alt)
    truth = frames.polar_to_ecef(r[:, 0], az[:, 0], el[:, 0], lat, lon, alt)
    stat = np.empty(r.shape[0])
    rel = np.empty(r.shape[0])
    step = max(1, 2_000_000 // (n + runs))  # bounds memory to ~50 MB per array
    for start in range(0, r.shape[0], step):
        cells = slice(start, start + step)
        z = rng.standard_normal((3, stat[cells].size, n + runs))
        rr = r[cells] + sr[cells] * z[0]
        aa = az[cells] + sa[cells] * z[1]
        ee = el[cells] + se[cells] * z[2]
        ground = rr * np.cos(ee)
        enu = (ground * np.sin(aa), ground * np.cos(aa), rr * np.sin(ee))
        d2 = np.zeros(rr.shape)
        for c in range(3):
            x = origin[c] + enu[0] * rot[0, c] + enu[1] * rot[1, c] + enu[2] * rot[2, c]
            d2 += (x - truth[cells, c][:, None]) ** 2
        stat[cells] = d2[:, :n].mean(axis=1)
        cov_polar = polar_covariance(sr[cells, 0], sa[cells, 0], se[cells, 0])[:, None]
        converted = trace(
            polar_to_ecef_covariance(rr[:, n:], aa[:, n:], ee[:, n:], cov_polar, lat, lon)
        )
        rel[cells] = np.mean(np.abs(converted - stat[cells, None]), axis=1) / stat[cells]
    return stat.reshape(shape), rel.reshape(shape)


def predicted_mean_relative_error(
    range_m, elevation_rad, sigma_r, sigma_a, sigma_e, n
):
    """Expected relative error of :func:`monte_carlo_relative_error` if the conversion
    itself were exact (it is to ~1e-4 here): ``T_k / T - 1 ~ N(0, s_A^2)`` and
    ``e / T - 1 ~ N(0, s_B^2)``, so ``E|T_k - e| / e ~ sqrt(2/pi) sqrt(s_A^2 + s_B^2)``.

    ``T = sigma_r^2 + sigma_a^2 r^2 cos^2 e + sigma_e^2 r^2`` (eq. 25), so
    ``s_A^2 = ((dT/dr sigma_r)^2 + (dT/de sigma_e)^2) / T^2`` with
    ``dT/dr = 2 r (sigma_a^2 cos^2 e + sigma_e^2)``, ``dT/de = -2 sigma_a^2 r^2 cos e sin e``;
    ``s_B = sqrt(2 tr(S^2)) / tr(S) / sqrt(n)`` for the (first-order) covariance ``S``.
    """
    r, e, sr, sa, se = np.broadcast_arrays(
        *(np.asarray(v, dtype=float) for v in (range_m, elevation_rad, sigma_r, sigma_a,
                                               sigma_e))
    )
    cov = polar_to_enu_covariance(r, 0.0, e, polar_covariance(sr, sa, se))
    total = trace(cov)
    s_b = np.sqrt(2.0 * np.sum(cov**2, axis=(-2, -1))) / total / np.sqrt(n)
    d_r = 2.0 * r * (sa**2 * np.cos(e) ** 2 + se**2)
    d_e = -2.0 * sa**2 * r**2 * np.cos(e) * np.sin(e)
    s_a = np.hypot(d_r * sr, d_e * se) / total
    return np.sqrt(2.0 / np.pi) * np.hypot(s_a, s_b)


#: Noisy samples per cell in section 3.1: the statistical sum's relative standard deviation
#: is at most sqrt(2)/sqrt(n) = 0.45 % (one dominant eigenvalue), so the largest of 100
#: cells (~2.6 sd = 1.2 %) plus the evaluation-point spread (mean ~1 %) stays well inside 4 %.
N_SECTION_31 = 100_000
#: Noisy samples per cell in section 3.2; with it the mean relative error at 10 km is
#: ~0.0115, the paper's figure (at larger n it tends to ~0.0098, the evaluation-point part).
N_SECTION_32 = 20_000


def test_paper_section_3_1_accuracy_grid():
    """(10 km, 60 deg, 60 deg), sigma_r = 500 m, sigma_a and sigma_e on a 10 x 10 grid over
    0.1..1 deg: every cell's mean relative error is below the paper's 4 %, and the grid
    mean agrees with the sampling-noise prediction within 15 % (that mean is known to ~3 %
    from 100 cells)."""
    rng = np.random.default_rng(31)
    sig = np.linspace(0.1, 1.0, 10) * DEG
    sa, se = np.meshgrid(sig, sig, indexing="ij")
    stat, rel = monte_carlo_relative_error(
        1e4, 60.0 * DEG, 60.0 * DEG, 500.0, sa, se, N_SECTION_31, rng
    )
    # The statistical sum itself is eq. 25 within its sampling error (5 sd of 1.4/sqrt(n)).
    eq25 = 500.0**2 + sa**2 * 1e8 * np.cos(60.0 * DEG) ** 2 + se**2 * 1e8
    np.testing.assert_array_less(np.abs(stat / eq25 - 1.0), 5.0 * np.sqrt(2.0 / N_SECTION_31))
    assert rel.max() < 0.04
    predicted = predicted_mean_relative_error(1e4, 60.0 * DEG, 500.0, sa, se, N_SECTION_31)
    assert rel.mean() == pytest.approx(predicted.mean(), rel=0.15)


def test_paper_section_3_2_position_grid():
    """r = 10 km, sigma_r = 50 m, sigma_a = sigma_e = 1 deg on the 36 x 36 grid az 0..360,
    el -180..180 deg, n = N_SECTION_32: the mean relative error is sampling noise (the
    second-order share is ~1e-4): it agrees with the prediction within 15 % (the grid mean
    is known to ~2 % from 1296 cells) and, with this n, with the paper's 0.0115 within 15 %.
    At r = 100 km every cell is below the paper's 5 %: there the evaluation-point spread
    is ~0.1 % and the statistical sum's sd at most sqrt(2/n) = 1 %, max over cells ~3.5 %."""
    rng = np.random.default_rng(32)
    az, el = np.meshgrid(
        np.linspace(0.0, 360.0, 36) * DEG, np.linspace(-180.0, 180.0, 36) * DEG, indexing="ij"
    )
    sigmas = (50.0, 1.0 * DEG, 1.0 * DEG)
    share = second_order_relative_size(
        frames.polar_to_enu_jacobian(1e4, az, el),
        polar_to_enu_hessian(1e4, az, el),
        polar_covariance(*sigmas),
        include_bias=True,
    )
    assert share.max() < 1e-3  # 5.1e-4 with the squared bias, at el = +-90 deg
    _, rel = monte_carlo_relative_error(1e4, az, el, *sigmas, N_SECTION_32, rng)
    predicted = predicted_mean_relative_error(1e4, el, *sigmas, N_SECTION_32)
    assert rel.mean() == pytest.approx(predicted.mean(), rel=0.15)
    assert rel.mean() == pytest.approx(0.0115, rel=0.15)
    _, rel_far = monte_carlo_relative_error(1e5, az, el, *sigmas, N_SECTION_32, rng)
    assert rel_far.max() < 0.05
