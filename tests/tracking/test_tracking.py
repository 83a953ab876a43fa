"""Tests of the constant-velocity Kalman filter (graphcal.tracking.kalman)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, linalg, stats

from graphcal.tracking.kalman import (
    PAPER002_R1_M2,
    cv_process_noise,
    cv_transition,
    kalman_filter,
    measurement_noise,
    pad_tracks,
    predict_to,
)

H = np.hstack([np.eye(3), np.zeros((3, 3))])


def _random_spd(rng: np.random.Generator, scale_m: float) -> np.ndarray:
    a = rng.normal(size=(3, 3)) * scale_m
    return a @ a.T + np.eye(3) * scale_m**2


def test_transition_matrix_moves_position_by_velocity() -> None:
    f = cv_transition(2.5)
    x = np.array([1.0, 2.0, 3.0, 10.0, -20.0, 30.0])
    np.testing.assert_allclose(f @ x, [26.0, -48.0, 78.0, 10.0, -20.0, 30.0])
    assert cv_transition(np.array([1.0, 2.0])).shape == (2, 6, 6)


def test_process_noise_equals_integral_of_white_acceleration() -> None:
    """Q(dt) = int_0^dt F(s) G q G^T F(s)^T ds, integrated numerically."""
    q, dt = 3.7, 4.0
    g = np.vstack([np.zeros((3, 3)), np.eye(3)])

    def integrand(s: float) -> np.ndarray:
        f = np.eye(6)
        f[:3, 3:] = s * np.eye(3)
        return (f @ g) @ (q * np.eye(3)) @ (f @ g).T

    expected, _ = integrate.quad_vec(integrand, 0.0, dt)
    np.testing.assert_allclose(cv_process_noise(dt, q), expected, rtol=1e-10, atol=1e-12)
    # Closed form of one axis: q [[dt^3/3, dt^2/2], [dt^2/2, dt]].
    one_axis = cv_process_noise(dt, q)[np.ix_([0, 3], [0, 3])]
    np.testing.assert_allclose(one_axis, q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]]))


def test_process_noise_rejects_negative_values() -> None:
    with pytest.raises(ValueError, match="q_m2_s3"):
        cv_process_noise(1.0, -1.0)
    with pytest.raises(ValueError, match="sorted"):
        cv_process_noise(np.array([1.0, -0.5]), 1.0)


def test_steady_state_covariance_is_the_riccati_solution() -> None:
    """Constant dt and R: the filter's P converges to the DARE solution (scipy)."""
    rng = np.random.default_rng(3)
    dt, q = 2.0, 5.0
    r = _random_spd(rng, 80.0)
    n = 400
    t = np.arange(n) * dt
    est = kalman_filter(t, np.zeros((n, 3)), r, q_m2_s3=q)
    f, qd = cv_transition(dt), cv_process_noise(dt, q)
    # solve_discrete_are solves the predicted-covariance (a priori) Riccati equation
    # for the dual (control) problem: a = F^T, b = H^T.
    p_pred = linalg.solve_discrete_are(f.T, H.T, qd, r)
    s = H @ p_pred @ H.T + r
    p_filt = p_pred - p_pred @ H.T @ np.linalg.solve(s, H @ p_pred)
    np.testing.assert_allclose(est.p[-1], p_filt, rtol=1e-7, atol=1e-9)


def test_nees_is_consistent_over_monte_carlo_runs() -> None:
    """A simulated CV target with process noise: mean NEES within chi-square bounds."""
    rng = np.random.default_rng(11)
    runs, n, q = 300, 80, 2.0
    t = np.cumsum(rng.uniform(0.5, 1.5, n))
    r = _random_spd(rng, 60.0)
    x = np.zeros((runs, n, 6))
    x[:, 0] = np.array([1e6, 2e6, 3e6, 200.0, -150.0, 10.0])
    for k in range(1, n):
        dt = t[k] - t[k - 1]
        w = rng.multivariate_normal(np.zeros(6), cv_process_noise(dt, q), size=runs)
        x[:, k] = x[:, k - 1] @ cv_transition(dt).T + w
    z = x[:, :, :3] + rng.multivariate_normal(np.zeros(3), r, size=(runs, n))
    est = kalman_filter(np.broadcast_to(t, (runs, n)), z, r, q_m2_s3=q)
    err = est.x - x
    nees = np.einsum("rki,rki->rk", err, np.linalg.solve(est.p, err[..., None])[..., 0])
    lo, hi = stats.chi2.ppf([0.005, 0.995], 6 * runs) / runs
    for k in (10, n // 2, n - 1):
        assert lo < nees[:, k].mean() < hi, (k, nees[:, k].mean(), lo, hi)
    # Averaged over time as well (correlated in time, so a looser band).
    assert 5.7 < nees[:, 5:].mean() < 6.3


def test_zero_process_noise_equals_batch_least_squares() -> None:
    """q = 0, straight track, per-plot R: last estimate = weighted line fit at the last time."""
    rng = np.random.default_rng(5)
    n = 40
    t = np.cumsum(rng.uniform(2.0, 6.0, n))
    p0, v = np.array([4e6, -1e5, 4.8e6]), np.array([120.0, -200.0, 5.0])
    r = np.stack([_random_spd(rng, s) for s in rng.uniform(30.0, 300.0, n)])
    truth = p0 + (t - t[0])[:, None] * v
    z = truth + np.stack([rng.multivariate_normal(np.zeros(3), rk) for rk in r])
    est = kalman_filter(t, z, r, q_m2_s3=0.0)
    # Batch GLS: z_k = [I, (t_k - t_n) I] [p_n; v] + e_k, e_k ~ N(0, R_k).
    a = np.zeros((n, 3, 6))
    a[:, :, :3] = np.eye(3)
    a[:, :, 3:] = (t - t[-1])[:, None, None] * np.eye(3)
    w = np.linalg.inv(r)
    normal = np.einsum("kji,kjl,klm->im", a, w, a)
    rhs = np.einsum("kji,kjl,kl->i", a, w, z)
    x_ls = np.linalg.solve(normal, rhs)
    np.testing.assert_allclose(est.x[-1, :3], x_ls[:3], atol=1e-4)
    np.testing.assert_allclose(est.x[-1, 3:], x_ls[3:], atol=1e-7)
    np.testing.assert_allclose(est.p[-1], np.linalg.inv(normal), rtol=1e-6)


def test_two_point_initialisation() -> None:
    t = np.array([10.0, 14.0, 18.0])
    z = np.array([[0.0, 0.0, 0.0], [400.0, -80.0, 8.0], [800.0, -160.0, 16.0]])
    r0, r1 = np.diag([1.0, 2.0, 3.0]), np.diag([4.0, 5.0, 6.0])
    r = np.stack([r0, r1, r1])
    est = kalman_filter(t, z, r, q_m2_s3=0.0)
    assert not est.valid[0] and est.valid[1:].all()
    assert np.isnan(est.x[0]).all()
    np.testing.assert_allclose(est.x[1], [400.0, -80.0, 8.0, 100.0, -20.0, 2.0])
    np.testing.assert_allclose(est.p[1][:3, :3], r1)
    np.testing.assert_allclose(est.p[1][:3, 3:], r1 / 4.0)
    np.testing.assert_allclose(est.p[1][3:, 3:], (r0 + r1) / 16.0)


def test_one_point_initialisation_converges_to_the_two_point_result() -> None:
    rng = np.random.default_rng(2)
    n = 60
    t = np.arange(n) * 4.0
    z = np.outer(t, [100.0, 50.0, 0.0]) + rng.normal(0, 50.0, (n, 3))
    r = np.eye(3) * 50.0**2
    two = kalman_filter(t, z, r, q_m2_s3=1.0)
    one = kalman_filter(t, z, r, q_m2_s3=1.0, init="one-point", velocity_sigma_mps=1e3)
    assert one.valid.all()
    np.testing.assert_allclose(one.x[-1], two.x[-1], atol=1e-3)


def test_padded_batch_equals_separate_filters() -> None:
    rng = np.random.default_rng(8)
    tracks = []
    for n in (12, 7, 20):
        t = np.sort(rng.uniform(0, 100, n))
        z = rng.normal(0, 1e3, (n, 3))
        r = np.stack([_random_spd(rng, 40.0) for _ in range(n)])
        tracks.append((t, z, r))
    tp, mask = pad_tracks([a for a, _, _ in tracks])
    zp, _ = pad_tracks([b for _, b, _ in tracks])
    rp, _ = pad_tracks([c for _, _, c in tracks])
    rp[~mask] = np.eye(3)
    batch = kalman_filter(tp, zp, rp, q_m2_s3=3.0, mask=mask)
    for i, (t, z, r) in enumerate(tracks):
        single = kalman_filter(t, z, r, q_m2_s3=3.0)
        n = len(t)
        np.testing.assert_allclose(batch.x[i, :n], single.x, equal_nan=True)
        np.testing.assert_allclose(batch.p[i, :n], single.p, equal_nan=True)
        assert not batch.valid[i, n:].any()


def test_predict_to_grid_times() -> None:
    t = np.array([0.3, 1.3, 2.3, 3.3])
    z = np.outer(t, [100.0, 0.0, -50.0])
    est = kalman_filter(t, z, np.eye(3) * 100.0, q_m2_s3=2.0)
    grid = np.array([0.0, 1.0, 1.3, 2.0, 3.3, 4.0])
    x, p, ok = predict_to(est, grid)
    np.testing.assert_array_equal(ok, [False, False, True, True, True, False])
    np.testing.assert_allclose(x[2], est.x[1])  # exactly at a plot: the filtered state
    dt = 2.0 - 1.3
    np.testing.assert_allclose(x[3], cv_transition(dt) @ est.x[1])
    f = cv_transition(dt)
    np.testing.assert_allclose(p[3], f @ est.p[1] @ f.T + cv_process_noise(dt, 2.0))
    assert np.isnan(x[0]).all() and np.isnan(x[5]).all()
    _, _, ok_ext = predict_to(est, grid, max_extrapolation_s=1.0)
    assert ok_ext[5]


def test_measurement_noise_modes() -> None:
    cov = np.stack([np.eye(3) * (k + 1.0) for k in range(4)])[None]  # (1, 4, 3, 3)
    np.testing.assert_allclose(measurement_noise("fixed", cov)[0, 2], PAPER002_R1_M2)
    np.testing.assert_allclose(measurement_noise("converted-first", cov)[0, 3], np.eye(3))
    np.testing.assert_allclose(measurement_noise("converted", cov), cov)
    with pytest.raises(ValueError, match="unknown measurement-noise mode"):
        measurement_noise("bogus", cov)


def test_filter_input_errors() -> None:
    t = np.array([0.0, 1.0, 2.0])
    z = np.zeros((3, 3))
    with pytest.raises(ValueError, match="sorted"):
        kalman_filter(t[::-1], z, np.eye(3), q_m2_s3=1.0)
    with pytest.raises(ValueError, match="z_ecef_m"):
        kalman_filter(t, np.zeros((3, 2)), np.eye(3), q_m2_s3=1.0)
    with pytest.raises(ValueError, match="different times"):
        kalman_filter(np.array([0.0, 0.0, 1.0]), z, np.eye(3), q_m2_s3=1.0)
    with pytest.raises(ValueError, match="at least 2"):
        kalman_filter(t[:1], z[:1], np.eye(3), q_m2_s3=1.0)
    with pytest.raises(ValueError, match="unknown init"):
        kalman_filter(t, z, np.eye(3), q_m2_s3=1.0, init="three-point")
