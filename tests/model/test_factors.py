"""Every factor of the graph calibrator: analytic Jacobians against numerical derivatives,
robust kernels against GTSAM's own M-estimators, motion factors against their definition."""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
import pytest

from graphcal.data.align import align_adsb, pair_plots
from graphcal.data.bias import RadarBias
from graphcal.model.factors import adsb_factor, pairwise_factor
from graphcal.model.measurement import reference_polar_covariance
from graphcal.model.parameters import RadarTerms
from graphcal.model.robust import RobustKernel, default_threshold
from graphcal.solvers.target_state import build_target_state, motion_blocks
from tests.jacobians import numerical_jacobian
from tests.synthetic import Track, make_dataset, site_at

BIAS_2D = RadarBias(120.0, 0.002, 0.004)
BIAS_3D = RadarBias(-80.0, -0.001, -0.003, 0.002)


@pytest.fixture(scope="module")
def dataset():
    rng = np.random.default_rng(7)
    radars = [
        (site_at("A", -40e3, 0.0), BIAS_2D),
        (site_at("B", 40e3, 10e3, sigma_elevation_mrad=2.0), BIAS_3D),
    ]
    tracks = [
        Track("aa0001", (-60e3, 50e3, 8000.0), (180.0, -20.0, 0.0), 0.0, 120.0),
        Track("aa0002", (30e3, -70e3, 5000.0), (-30.0, 200.0, 3.0), 0.0, 120.0),
    ]
    return make_dataset(rng, radars, tracks)


BIAS_STEPS = np.array([1.0, 1e-5, 1e-5, 1e-5])


def _terms(site, names=None) -> RadarTerms:
    free = tuple(names or (
        ("range_offset", "range_gain", "azimuth_bias", "elevation_bias") if site.is_3d
        else ("range_offset", "range_gain", "azimuth_bias")
    ))
    return RadarTerms(site.id, free)


@pytest.mark.parametrize("radar", ["A", "B"])
def test_adsb_factor_jacobian_matches_numerical(dataset, radar: str) -> None:
    site = dataset.sites[radar]
    al = align_adsb(dataset, radar)
    terms = _terms(site)
    f = adsb_factor(site, terms, 0, al.plots, al.reference_polar, reference_polar_covariance(al),
                    RobustKernel("none"))
    x = np.array([50.0, 0.001, 0.002, 0.001])[: len(terms.free)]
    _, (jac,) = f.whitened([x])
    numeric = numerical_jacobian(lambda v: f.whitened([v])[0], x, BIAS_STEPS[: len(x)])
    np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-8)


def test_adsb_factor_residual_is_zero_at_truth_without_noise() -> None:
    rng = np.random.default_rng(3)
    site = site_at("C", 0.0, 0.0, sigma_elevation_mrad=1.0)
    ds = make_dataset(rng, [(site, BIAS_3D)],
                      [Track("cc0001", (20e3, 60e3, 9000.0), (150.0, 0.0, 0.0), 0.0, 60.0)],
                      noise=False)
    al = align_adsb(ds, "C")
    f = adsb_factor(site, _terms(site), 0, al.plots, al.reference_polar,
                    reference_polar_covariance(al), RobustKernel("none"))
    e, _ = f.whitened([BIAS_3D.as_vector()])
    # ADS-B interpolated linearly along a straight track: exact up to float rounding.
    assert np.max(np.abs(e)) < 1e-4


def test_pairwise_factor_jacobians_match_numerical(dataset) -> None:
    pairs = pair_plots(dataset, "A", "B")
    sa, sb = dataset.sites["A"], dataset.sites["B"]
    ta, tb = _terms(sa), _terms(sb)
    f = pairwise_factor(sa, sb, ta, tb, 0, 1, pairs.a_plots, pairs.b_plots, pairs.a_index0,
                        pairs.weight, pairs.b_index, RobustKernel("none"))
    assert f is not None and len(f) > 50
    xa = np.array([100.0, 0.0015, 0.003])
    xb = np.array([-60.0, -0.0008, -0.002, 0.0015])
    _, (ja, jb) = f.whitened([xa, xb])
    na = numerical_jacobian(lambda v: f.whitened([v, xb])[0], xa, BIAS_STEPS[:3])
    nb = numerical_jacobian(lambda v: f.whitened([xa, v])[0], xb, BIAS_STEPS)
    np.testing.assert_allclose(ja, na, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(jb, nb, rtol=1e-5, atol=1e-7)


def test_pairwise_factor_vanishes_at_true_biases_without_noise() -> None:
    rng = np.random.default_rng(4)
    sa = site_at("A", -30e3, 0.0, sigma_elevation_mrad=1.0)
    sb = site_at("B", 30e3, 0.0, sigma_elevation_mrad=1.0)
    ds = make_dataset(rng, [(sa, BIAS_3D), (sb, RadarBias(40.0, 0.001, 0.002, -0.001))],
                      [Track("bb0001", (0.0, 50e3, 7000.0), (200.0, 0.0, 0.0), 0.0, 200.0)],
                      noise=False)
    pairs = pair_plots(ds, "A", "B")
    f = pairwise_factor(sa, sb, _terms(sa), _terms(sb), 0, 1, pairs.a_plots, pairs.b_plots,
                        pairs.a_index0, pairs.weight, pairs.b_index, RobustKernel("none"))
    res, _, _ = f.residual(BIAS_3D.as_vector(), np.array([40.0, 0.001, 0.002, -0.001]))
    # Straight, constant-speed flight: interpolating radar A's plots is exact.
    assert np.max(np.abs(res)) < 1e-3


ECCENTRIC = ("range_offset", "range_gain", "azimuth_bias", "azimuth_sin", "azimuth_cos")


@pytest.mark.parametrize("radar", ["A", "B"])
def test_adsb_factor_jacobian_with_eccentricity_matches_numerical(dataset, radar: str) -> None:
    site = dataset.sites[radar]
    al = align_adsb(dataset, radar)
    terms = RadarTerms(site.id, ECCENTRIC)
    f = adsb_factor(site, terms, 0, al.plots, al.reference_polar, reference_polar_covariance(al),
                    RobustKernel("none"))
    x = np.array([50.0, 0.001, 0.002, 0.0015, -0.0007])
    _, (jac,) = f.whitened([x])
    numeric = numerical_jacobian(lambda v: f.whitened([v])[0], x,
                                 np.array([1.0, 1e-5, 1e-5, 1e-5, 1e-5]))
    np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-8)


def test_pairwise_factor_jacobians_with_eccentricity_match_numerical(dataset) -> None:
    pairs = pair_plots(dataset, "A", "B")
    sa, sb = dataset.sites["A"], dataset.sites["B"]
    ta = RadarTerms("A", ECCENTRIC)
    tb = RadarTerms("B", (*ECCENTRIC, "elevation_bias"))
    f = pairwise_factor(sa, sb, ta, tb, 0, 1, pairs.a_plots, pairs.b_plots, pairs.a_index0,
                        pairs.weight, pairs.b_index, RobustKernel("none"))
    xa = np.array([100.0, 0.0015, 0.003, 0.002, -0.001])
    xb = np.array([-60.0, -0.0008, -0.002, -0.0012, 0.0009, 0.0015])
    _, (ja, jb) = f.whitened([xa, xb])
    steps = np.array([1.0, 1e-5, 1e-5, 1e-5, 1e-5, 1e-5])
    na = numerical_jacobian(lambda v: f.whitened([v, xb])[0], xa, steps[:5])
    nb = numerical_jacobian(lambda v: f.whitened([xa, v])[0], xb, steps)
    np.testing.assert_allclose(ja, na, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(jb, nb, rtol=1e-5, atol=1e-7)


def test_factors_vanish_at_a_true_eccentricity_without_noise() -> None:
    """Noise-free plots made with an eccentricity (tests.synthetic, its own implementation):
    the ADS-B and pairwise residuals vanish at the true terms and not without them."""
    rng = np.random.default_rng(8)
    sa = site_at("A", -30e3, 0.0, sigma_elevation_mrad=1.0)
    sb = site_at("B", 30e3, 0.0, sigma_elevation_mrad=1.0)
    bias_a = RadarBias(20.0, 1e-4, 1e-3, -1e-3, azimuth_sin_rad=2e-3, azimuth_cos_rad=-1.5e-3)
    bias_b = RadarBias(40.0, 0.001, 0.002, -0.001)
    ds = make_dataset(rng, [(sa, bias_a), (sb, bias_b)],
                      [Track("bb0001", (-40e3, 50e3, 7000.0), (200.0, -60.0, 0.0), 0.0, 300.0)],
                      noise=False)
    terms = RadarTerms("A", (*ECCENTRIC, "elevation_bias"))
    truth = np.array([20.0, 1e-4, 1e-3, 2e-3, -1.5e-3, -1e-3])
    al = align_adsb(ds, "A")
    f = adsb_factor(sa, terms, 0, al.plots, al.reference_polar, reference_polar_covariance(al),
                    RobustKernel("none"))
    assert np.max(np.abs(f.whitened([truth])[0])) < 1e-4
    assert np.max(np.abs(f.whitened([truth * [1, 1, 1, 0, 0, 1]])[0])) > 1.0
    pairs = pair_plots(ds, "A", "B")
    g = pairwise_factor(sa, sb, terms, _terms(sb), 0, 1, pairs.a_plots, pairs.b_plots,
                        pairs.a_index0, pairs.weight, pairs.b_index, RobustKernel("none"))
    res, _, _ = g.residual(bias_a.as_vector(), bias_b.as_vector(), ecc_a=(2e-3, -1.5e-3))
    assert np.max(np.abs(res)) < 1e-3
    res, _, _ = g.residual(bias_a.as_vector(), bias_b.as_vector())
    assert np.max(np.abs(res)) > 10.0


def test_fixed_terms_are_left_out_of_the_jacobian(dataset) -> None:
    site = dataset.sites["B"]
    al = align_adsb(dataset, "B")
    terms = RadarTerms("B", ("range_offset", "azimuth_bias"), {"range_gain": -0.001})
    f = adsb_factor(site, terms, 0, al.plots, al.reference_polar, reference_polar_covariance(al),
                    RobustKernel("none"))
    x = np.array([-80.0, -0.003])
    _, (jac,) = f.whitened([x])
    assert jac.shape[-1] == 2
    np.testing.assert_allclose(terms.full(x), [-80.0, -0.001, -0.003, 0.0])
    numeric = numerical_jacobian(lambda v: f.whitened([v])[0], x, np.array([1.0, 1e-5]))
    np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-8)


@pytest.fixture(scope="module")
def target_state(dataset):
    terms = {rid: _terms(site) for rid, site in dataset.sites.items()}
    keys = {"A": 0, "B": 1}
    return build_target_state(dataset, terms, keys, RobustKernel("none"), use_adsb=True,
                              adsb_max_gap_s=10.0)


@pytest.mark.parametrize("which", [0, -1])
def test_plot_factor_jacobians_match_numerical(target_state, which: int) -> None:
    # The first factor is one radar's, the last the other's (2-D with height, 3-D).
    factors = sorted(target_state.plot_factors, key=lambda f: f.terms.radar_id)
    f = factors[which]
    rng = np.random.default_rng(1)
    k = len(f.terms.free)
    bias = np.array([30.0, 0.001, 0.002, 0.001])[:k]
    index = {int(key): i for i, key in enumerate(target_state.state_keys)}
    states = [target_state.initial_states[index[key]] + rng.normal(0, [50, 50, 50, 5, 5, 1])
              for key in f.state_keys]
    e, d_bias, d_state = f.whitened(bias, states)
    numeric = numerical_jacobian(lambda v: f.whitened(v, states)[0], bias, BIAS_STEPS[:k])
    np.testing.assert_allclose(d_bias, numeric, rtol=1e-6, atol=1e-8)
    # Per state: the rows of the plots that use it.
    flat, blocks = f.error([bias, *states], True, True)
    for j in range(len(states)):
        def moved(v, j=j):
            s = list(states)
            s[j] = v
            return f.error([bias, *s], False, True)[0]

        numeric = numerical_jacobian(moved, states[j], np.array([1.0, 1.0, 1.0, 0.1, 0.1, 0.1]))
        np.testing.assert_allclose(blocks[1 + j], numeric, rtol=1e-5, atol=1e-7)


def test_adsb_track_factor_jacobian_matches_numerical(target_state) -> None:
    g = target_state.adsb_factors[0]
    index = {int(key): i for i, key in enumerate(target_state.state_keys)}
    states = [target_state.initial_states[index[key]] for key in g.state_keys]
    _, blocks = g.error(states, True)
    for j in range(len(states)):
        def moved(v, j=j):
            s = list(states)
            s[j] = v
            return g.error(s, False)[0]

        numeric = numerical_jacobian(moved, states[j], np.ones(6))
        np.testing.assert_allclose(blocks[j], numeric, rtol=1e-6, atol=1e-9)


def test_motion_factor_is_the_constant_velocity_model() -> None:
    dt, q = 3.0, 4.0
    a1, a2 = motion_blocks(dt, q)
    rng = np.random.default_rng(0)
    x1, x2 = rng.normal(size=6) * 100, rng.normal(size=6) * 100
    innovation = np.r_[x2[:3] - x1[:3] - dt * x1[3:], x2[3:] - x1[3:]]
    cov = q * np.block([[dt**3 / 3 * np.eye(3), dt**2 / 2 * np.eye(3)],
                        [dt**2 / 2 * np.eye(3), dt * np.eye(3)]])
    whitened = a1 @ x1 + a2 @ x2
    # Same Mahalanobis norm as the innovation under Q.
    assert whitened @ whitened == pytest.approx(innovation @ np.linalg.solve(cov, innovation))


@pytest.mark.parametrize("name, gtsam_kernel", [
    ("huber", gtsam.noiseModel.mEstimator.Huber),
    ("cauchy", gtsam.noiseModel.mEstimator.Cauchy),
])
def test_robust_kernels_match_gtsam_m_estimators(name: str, gtsam_kernel) -> None:
    kernel = RobustKernel(name)
    k = kernel.threshold(3)
    assert k == pytest.approx(default_threshold(3))
    reference = gtsam_kernel.Create(k)
    s = np.array([0.1, 1.0, 2.0, 3.5, 10.0, 100.0])
    np.testing.assert_allclose(kernel.weight(s, 3), [reference.weight(v) for v in s], rtol=1e-12)
    np.testing.assert_allclose(kernel.loss(s, 3), [reference.loss(v) for v in s], rtol=1e-12)


@pytest.mark.parametrize("name", ["huber", "cauchy", "none"])
def test_robust_error_gives_the_kernel_cost_and_irls_linearisation(name: str) -> None:
    kernel = RobustKernel(name)
    rng = np.random.default_rng(2)
    r = rng.normal(size=(200, 3)) * np.r_[np.ones(190), np.full(10, 30.0)][:, None]
    s = np.linalg.norm(r, axis=1)
    e, _ = kernel.apply(r, None)
    assert 0.5 * np.sum(e**2) == pytest.approx(np.sum(kernel.loss(s, 3)))
    jac = rng.normal(size=(200, 3, 2))
    e_lin, (j_lin,) = kernel.apply(r, [jac])
    w = kernel.weight(s, 3)
    # Gradient of the cost: sum w J^T r (IRLS), identical in both forms.
    np.testing.assert_allclose(np.einsum("nip,ni->p", j_lin, e_lin),
                               np.einsum("n,nip,ni->p", w, jac, r))
    # Weight is rho'(s) / s.
    ds = 1e-6
    derivative = (kernel.loss(s + ds, 3) - kernel.loss(s - ds, 3)) / (2 * ds)
    np.testing.assert_allclose(w, derivative / s, rtol=1e-5)
    # Weight below 0.5: s > 2k for Huber, s > k for Cauchy; the 10 outliers for Huber.
    k = kernel.threshold(3)
    expected = {"huber": s > 2 * k, "cauchy": s > k, "none": np.zeros_like(s, bool)}[name]
    np.testing.assert_array_equal(kernel.downweighted(r), expected)
    if name == "huber":
        assert expected.sum() == 10


def test_unknown_kernel_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown robust kernel 'tukey'"):
        RobustKernel("tukey")


@dataclass(frozen=True)
class TurningTrack:
    """An aircraft on a circle at constant speed and height (``tests.synthetic.Track``'s
    interface): ``(cx + R sin wt, cy + R cos wt, h)``."""

    target_id: str
    centre_m: tuple[float, float]
    radius_m: float
    rate_rad_s: float
    height_m: float
    t0_s: float
    duration_s: float

    def enu(self, t: np.ndarray) -> np.ndarray:
        angle = self.rate_rad_s * (t - self.t0_s)
        return np.column_stack([self.centre_m[0] + self.radius_m * np.sin(angle),
                                self.centre_m[1] + self.radius_m * np.cos(angle),
                                np.full(len(t), self.height_m)])


def _turning_pairs():
    rng = np.random.default_rng(5)
    sa = site_at("A", -30e3, 0.0, sigma_elevation_mrad=1.0, scan_period_s=8.0)
    sb = site_at("B", 30e3, 0.0, sigma_elevation_mrad=1.0, scan_period_s=5.0)
    bias_b = RadarBias(40.0, 0.001, 0.002, -0.001)
    turn = TurningTrack("tt0001", (0.0, 50e3), 6000.0, np.deg2rad(2.0), 8000.0, 0.0, 300.0)
    ds = make_dataset(rng, [(sa, BIAS_3D), (sb, bias_b)], [turn], noise=False)
    return sa, sb, bias_b, pair_plots(ds, "A", "B")


def test_quadratic_pairs_follow_a_turn_the_chord_cuts() -> None:
    """A noise-free aircraft turning at 2 deg/s (7 m/s²), radar A scanning every 8 s: the
    straight chord between A's plots misses by up to a dt² / 8 = 56 m; through a third plot
    the miss is the cubic term, at most v w² max|(t - t0)(t - t1)(t - t2)| / 6 = 8 m."""
    sa, sb, bias_b, pairs = _turning_pairs()
    args = (sa, sb, _terms(sa), _terms(sb), 0, 1, pairs.a_plots, pairs.b_plots,
            pairs.a_index0, pairs.weight, pairs.b_index, RobustKernel("none"))
    linear = pairwise_factor(*args)
    quadratic = pairwise_factor(*args, i2=pairs.a_index2,
                                quadratic_weights=pairs.quadratic_weights)
    truth = (BIAS_3D.as_vector(), bias_b.as_vector())
    miss_linear = np.linalg.norm(linear.residual(*truth)[0], axis=1)
    miss_quadratic = np.linalg.norm(quadratic.residual(*truth)[0], axis=1)
    assert 50.0 < miss_linear.max() < 60.0
    assert miss_quadratic.max() < 8.5 and np.median(miss_quadratic) < 0.15 * np.median(
        miss_linear)
    # The noise of the interpolated position grows by the weights, but only a little.
    trace = np.trace(np.linalg.inv(quadratic.whitening @ np.swapaxes(quadratic.whitening, 1, 2)),
                     axis1=1, axis2=2)
    trace_linear = np.trace(np.linalg.inv(linear.whitening @ np.swapaxes(linear.whitening, 1, 2)),
                            axis1=1, axis2=2)
    assert 1.0 <= np.median(trace / trace_linear) < 1.2


def test_quadratic_pairwise_factor_jacobians_match_numerical() -> None:
    sa, sb, _, pairs = _turning_pairs()
    f = pairwise_factor(sa, sb, _terms(sa), _terms(sb), 0, 1, pairs.a_plots, pairs.b_plots,
                        pairs.a_index0, pairs.weight, pairs.b_index, RobustKernel("none"),
                        i2=pairs.a_index2, quadratic_weights=pairs.quadratic_weights)
    xa = np.array([100.0, 0.0015, 0.003, 0.001])
    xb = np.array([-60.0, -0.0008, -0.002, 0.0015])
    _, (ja, jb) = f.whitened([xa, xb])
    np.testing.assert_allclose(
        ja, numerical_jacobian(lambda v: f.whitened([v, xb])[0], xa, BIAS_STEPS),
        rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(
        jb, numerical_jacobian(lambda v: f.whitened([xa, v])[0], xb, BIAS_STEPS),
        rtol=1e-5, atol=1e-7)
    positions, coefficients = f.plot_noise()
    assert positions.shape == coefficients.shape == (len(f), 4)
    np.testing.assert_allclose(coefficients.sum(axis=1), 0.0, atol=1e-12)


def test_kernel_thresholds_are_the_chi_quantiles() -> None:
    """scipy.special's chi-square quantile gives scipy.stats' chi 95 % points."""
    from scipy import stats

    for dimension in [1, 2, 3, 4, 7, 9]:
        assert default_threshold(dimension) == pytest.approx(
            float(np.sqrt(stats.chi2.ppf(0.95, dimension))), rel=1e-12)


def test_shared_corrections_give_the_same_residuals_with_one_conversion_per_radar(
        monkeypatch) -> None:
    import graphcal.model.cross_radar as cross_radar
    from graphcal.model.factors import share_corrections

    rng = np.random.default_rng(11)
    radars = [
        (site_at("A", -40e3, 0.0), BIAS_2D),
        (site_at("B", 40e3, 10e3, sigma_elevation_mrad=2.0), BIAS_3D),
        (site_at("C", 0.0, -50e3), RadarBias(30.0, 0.0005, -0.002)),
    ]
    tracks = [
        Track("aa0001", (-60e3, 50e3, 8000.0), (180.0, -20.0, 0.0), 0.0, 120.0),
        Track("aa0002", (30e3, -70e3, 5000.0), (-30.0, 200.0, 3.0), 0.0, 120.0),
    ]
    ds = make_dataset(rng, radars, tracks)
    keys = {"A": 0, "B": 1, "C": 2}

    def factors():
        out = []
        for a, b in (("A", "B"), ("A", "C"), ("B", "C")):
            pairs = pair_plots(ds, a, b)
            sa, sb = ds.sites[a], ds.sites[b]
            out.append(pairwise_factor(sa, sb, _terms(sa), _terms(sb), keys[a], keys[b],
                                       pairs.a_plots, pairs.b_plots, pairs.a_index0,
                                       pairs.weight, pairs.b_index, RobustKernel("none")))
        assert all(f is not None and len(f) > 20 for f in out)
        return out

    plain, shared = factors(), factors()
    share_corrections(shared)
    assert all(f.a_shared is not None and f.b_shared is not None for f in shared)
    assert shared[0].a_shared is shared[1].a_shared  # A's one cache
    values = {"A": np.array([100.0, 0.0015, 0.003]),
              "B": np.array([-60.0, -0.0008, -0.002, 0.0015]),
              "C": np.array([20.0, 0.0004, -0.001])}
    calls = []
    real = cross_radar.corrected_ecef
    monkeypatch.setattr(cross_radar, "corrected_ecef",
                        lambda *a, **k: calls.append(a[0].id) or real(*a, **k))
    for f_plain, f_shared in zip(plain, shared, strict=True):
        ids = (f_plain.terms_a.radar_id, f_plain.terms_b.radar_id)
        e0, j0 = f_plain.whitened([values[ids[0]], values[ids[1]]])
        e1, j1 = f_shared.whitened([values[ids[0]], values[ids[1]]])
        np.testing.assert_array_equal(e1, e0)
        for a, b in zip(j1, j0, strict=True):
            np.testing.assert_array_equal(a, b)
    assert sorted(calls) == ["A", "B", "C"]  # each radar converted once for three pairs


# --------------------------------------------------------------------------- the one bias model
def _polar_points(rng: np.random.Generator, n: int = 40) -> np.ndarray:
    return np.column_stack([rng.uniform(5e3, 250e3, n), rng.uniform(0.0, 2 * np.pi, n),
                            rng.uniform(-0.01, 0.3, n)])


#: Terms of TERM_NAMES with a non-zero eccentricity (time offset unused by the model).
ECCENTRIC_TERMS = np.array([40.0, 1.5e-3, 2e-3, -1e-3, 0.7, 1.2e-3, -0.8e-3])
TERM_STEPS = np.array([1.0, 1e-6, 1e-6, 1e-6, 1e-3, 1e-6, 1e-6])


@pytest.mark.parametrize("terms", [ECCENTRIC_TERMS, ECCENTRIC_TERMS * [1, 1, 1, 1, 1, 0, 0]])
def test_biased_polar_jacobians_match_numerical(terms: np.ndarray) -> None:
    """slope: the diagonal of d h / d true polar; d_terms: d h / d every term; both against
    central differences of h, and d_terms's structure as TERM_ROWS and ADDITIVE_TERMS say."""
    from graphcal.model.measurement import ADDITIVE_TERMS, TERM_ROWS, biased_polar
    from graphcal.model.parameters import TERM_NAMES

    polar = _polar_points(np.random.default_rng(12))
    predicted, slope, d_terms = biased_polar(polar, terms, TERM_NAMES)
    r, az, el = polar.T
    s, c = terms[5:]
    np.testing.assert_allclose(predicted, np.column_stack([
        (1 + terms[1]) * r + terms[0], az + terms[2] + s * np.sin(az) + c * np.cos(az),
        el + terms[3]]), rtol=1e-15, atol=1e-9)
    numeric = numerical_jacobian(lambda p: biased_polar(p, terms)[0], polar,
                                 np.array([1.0, 1e-6, 1e-6]))
    np.testing.assert_allclose(numeric, np.einsum("ni,ij->nij", slope, np.eye(3)),
                               rtol=1e-7, atol=1e-9)
    numeric = numerical_jacobian(lambda t: biased_polar(polar, t)[0].T, terms, TERM_STEPS)
    np.testing.assert_allclose(d_terms, np.moveaxis(numeric, 1, 0), rtol=1e-7, atol=1e-9)
    for k, name in enumerate(TERM_NAMES):
        row = TERM_ROWS[name]
        others = [i for i in range(3) if i != row]
        assert not np.any(d_terms[:, others, k]), name
        if name in ADDITIVE_TERMS:
            assert np.all(d_terms[:, row, k] == 1.0), name


def test_measure_is_the_polar_jacobian_and_biased_polar(dataset) -> None:
    """RadarMeasurementModel.measure = the polar coordinates of ENU points, their
    Jacobian, and biased_polar on top."""
    from graphcal.model.measurement import biased_polar, measurement_model
    from graphcal.model.parameters import TERM_NAMES

    model = measurement_model(dataset.sites["B"])
    rng = np.random.default_rng(13)
    enu = rng.uniform([-1e5, -1e5, 2e3], [1e5, 1e5, 1.2e4], size=(30, 3))
    free = ("range_gain", "azimuth_cos", "range_offset", "elevation_bias", "time_offset")
    predicted, d_enu, d_terms = model.measure(enu, ECCENTRIC_TERMS, free)
    polar, jac = model.enu_jacobian(enu)
    expected, slope, expected_terms = biased_polar(polar, ECCENTRIC_TERMS, free)
    np.testing.assert_array_equal(predicted, expected)
    np.testing.assert_array_equal(d_enu, slope[:, :, None] * jac)
    np.testing.assert_array_equal(d_terms, expected_terms)
    assert not np.any(d_terms[:, :, free.index("time_offset")])
    # The order of the columns is free's.
    _, _, every = biased_polar(polar, ECCENTRIC_TERMS, TERM_NAMES)
    np.testing.assert_array_equal(d_terms, every[:, :, [TERM_NAMES.index(n) for n in free]])


@pytest.mark.parametrize("radar", ["A", "B"])
def test_adsb_factor_jacobian_is_minus_w_d_terms(dataset, radar: str) -> None:
    """The ADS-B factor's whitened Jacobian is -W d_terms of biased_polar at the reference
    moved to the time offset, its time column W (slope * rate), and both equal central
    differences of the whitened residual: every term free, eccentricity and time offset
    non-zero."""
    from graphcal.model.measurement import biased_polar
    from graphcal.model.parameters import TERM_NAMES

    site = dataset.sites[radar]
    al = align_adsb(dataset, radar)
    rng = np.random.default_rng(14)
    n = len(al)
    rate = np.column_stack([rng.normal(0, 200.0, n), rng.normal(0, 2e-3, n),
                            rng.normal(0, 1e-3, n)])
    free = tuple(name for name in TERM_NAMES if site.is_3d or name != "elevation_bias")
    f = adsb_factor(site, RadarTerms(radar, free), 0, al.plots, al.reference_polar,
                    reference_polar_covariance(al), RobustKernel("none"), rate, 0.3)
    terms = ECCENTRIC_TERMS if site.is_3d else ECCENTRIC_TERMS * [1, 1, 1, 0, 1, 1, 1]
    x = terms[[TERM_NAMES.index(name) for name in free]]
    e, (jac,) = f.whitened([x])
    m = f.rows
    reference = al.reference_polar + rate * (0.3 - terms[4])
    predicted, slope, d_terms = biased_polar(reference, terms, free)
    w = f.whitening
    measured = np.column_stack([al.plots.range_m, al.plots.azimuth_rad, al.plots.elevation_rad])
    residual = measured[:, :m] - predicted[:, :m]
    residual[:, 1] = np.mod(residual[:, 1] + np.pi, 2 * np.pi) - np.pi
    np.testing.assert_allclose(e, np.einsum("nij,nj->ni", w, residual), rtol=1e-12, atol=1e-9)
    expected = -w @ d_terms[:, :m, :]
    expected[:, :, free.index("time_offset")] = np.einsum("nij,nj->ni", w, (slope * rate)[:, :m])
    np.testing.assert_allclose(jac, expected, rtol=1e-12, atol=1e-12)
    numeric = numerical_jacobian(lambda v: f.whitened([v])[0], x,
                                 TERM_STEPS[[TERM_NAMES.index(name) for name in free]])
    np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-7)
    # residual(): the same columns, unwhitened, over every term.
    res, jac_all = f.residual(terms[:4], terms[4], (terms[5], terms[6]))
    np.testing.assert_allclose(np.einsum("nij,nj->ni", w, res), e, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(w @ jac_all[:, :, [TERM_NAMES.index(n) for n in free]], jac,
                               rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("refraction", ["none", "exponential"])
def test_polar_noise_variances_are_the_noise_covariances_diagonal(dataset, refraction) -> None:
    """A radar's plus the ADS-B's variances, coordinate by coordinate, formed alone and
    after the ADS-B covariance has been computed: the diagonal of ``covar + J C J^T``."""
    import dataclasses

    from graphcal.model.measurement import measurement_model, polar_noise_variances

    for radar in ("A", "B"):
        site = dataclasses.replace(dataset.sites[radar], refraction=refraction)
        data = dataclasses.replace(dataset, sites={**dataset.sites, radar: site})
        al = align_adsb(data, radar)
        alone = polar_noise_variances(al, site)
        full = measurement_model(site).covar(len(al)) + reference_polar_covariance(al, site)
        expected = np.diagonal(full, axis1=1, axis2=2)
        assert np.abs(alone - expected).max() <= 1e-15 * np.abs(expected).max()
        assert np.array_equal(polar_noise_variances(al, site), expected)  # computed now
        reference = np.diagonal(reference_polar_covariance(al, site), axis1=1, axis2=2)
        assert np.array_equal(alone[:, 2] == reference[:, 2], np.full(len(al), not site.is_3d))
