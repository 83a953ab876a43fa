"""The height model's observations (pressure altitudes): Jacobians against numerical
derivatives, the noise-free residuals at the truth, the ADS-B segment means and the plots
that stay placeable."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

from graphcal.data.align import ADSB_VERTICAL_SIGMA_RATIO, pair_plots, plot_arrays
from graphcal.data.bias import RadarBias
from graphcal.data.height import HeightModel
from graphcal.model.cross_radar import corrected_ecef
from graphcal.model.factors import pairwise_factor
from graphcal.model.height import (
    BARO_QUANTUM_M,
    CORRELATED_SIGMA_M,
    AdsbHeightFactor,
    adsb_height_segments,
    placeable_over_prior,
)
from graphcal.model.parameters import RadarTerms
from graphcal.model.robust import RobustKernel
from tests.jacobians import numerical_jacobian
from tests.synthetic import Track, make_dataset, site_at

TRUE_HEIGHT = HeightModel(180.0, 0.025)
BIAS_A = RadarBias(120.0, 0.002, 0.004)
BIAS_B = RadarBias(-80.0, -0.001, -0.003, 0.002)
BIAS_C = RadarBias(40.0, 0.001, -0.002)
STEPS = np.array([1.0, 1e-5, 1e-5, 1e-5, 1e-3])
HEIGHT_STEPS = np.array([1.0, 1e-5])


def _pressure(dataset):
    """The dataset with its plots' heights turned into pressure altitudes (TRUE_HEIGHT)."""
    plots = dataset.plots.copy()
    plots["altitude_m"] = TRUE_HEIGHT.pressure(plots["altitude_m"].to_numpy())
    return dataclasses.replace(dataset, plots=plots, plot_altitude="pressure")


def pressure_network(noise: bool, seed: int = 7):
    rng = np.random.default_rng(seed)
    radars = [
        (site_at("A", -40e3, 0.0), BIAS_A),
        (site_at("B", 40e3, 10e3, sigma_elevation_mrad=2.0), BIAS_B),
        (site_at("C", 5e3, -50e3), BIAS_C),
    ]
    tracks = [Track("aa0001", (-60e3, 50e3, 8000.0), (180.0, -20.0, 0.0), 0.0, 160.0),
              Track("aa0002", (30e3, -70e3, 5000.0), (-30.0, 200.0, 3.0), 0.0, 160.0)]
    return _pressure(make_dataset(rng, radars, tracks, noise=noise))


def _terms(site, time_offset: bool = False) -> RadarTerms:
    names = ("range_offset", "range_gain", "azimuth_bias")
    if site.is_3d:
        names = (*names, "elevation_bias")
    return RadarTerms(site.id, (*names, "time_offset") if time_offset else names)


def _factor(dataset, a: str, b: str, time_offset: bool = False, tau0=(0.0, 0.0)):
    pairs = pair_plots(dataset, a, b, shift_s=tau0[0] - tau0[1])
    sa, sb = dataset.sites[a], dataset.sites[b]
    return pairwise_factor(sa, sb, _terms(sa, time_offset), _terms(sb, time_offset), 0, 1,
                           pairs.a_plots, pairs.b_plots, pairs.a_index0, pairs.weight,
                           pairs.b_index, RobustKernel("none"), *tau0, height_key=2)


@pytest.mark.parametrize(("a", "b"), [("A", "B"), ("B", "A"), ("A", "C")])
def test_pairwise_height_jacobians_match_numerical(a: str, b: str) -> None:
    dataset = pressure_network(noise=True)
    f = _factor(dataset, a, b)
    assert f is not None and len(f) > 50 and f.keys == [0, 1, 2]
    xa = np.array([100.0, 0.0015, 0.003, 0.001])[: len(f.terms_a.free)]
    xb = np.array([-60.0, -0.0008, -0.002, 0.0015])[: len(f.terms_b.free)]
    xh = np.array([150.0, 0.02])
    _, (ja, jb, jh) = f.whitened([xa, xb, xh])
    na = numerical_jacobian(lambda v: f.whitened([v, xb, xh])[0], xa, STEPS[: len(xa)])
    nb = numerical_jacobian(lambda v: f.whitened([xa, v, xh])[0], xb, STEPS[: len(xb)])
    nh = numerical_jacobian(lambda v: f.whitened([xa, xb, v])[0], xh, HEIGHT_STEPS)
    for analytic, numeric in ((ja, na), (jb, nb), (jh, nh)):
        np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-6 * np.abs(numeric).max())
    assert np.abs(jh).max() > 1e-3  # a 2-D radar's plots do depend on the height model


def test_pairwise_height_jacobian_with_a_time_offset_shift() -> None:
    """The time-offset term moves radar a's interpolated position, its height part included."""
    dataset = pressure_network(noise=True)
    f = _factor(dataset, "A", "C", time_offset=True, tau0=(0.3, -0.2))
    xa = np.array([100.0, 0.0015, 0.003, 0.6])  # tau_a - tau_b != tau0_a - tau0_b
    xc = np.array([-60.0, -0.0008, -0.002, -0.1])
    xh = np.array([150.0, 0.02])
    _, (ja, jc, jh) = f.whitened([xa, xc, xh])
    nh = numerical_jacobian(lambda v: f.whitened([xa, xc, v])[0], xh, HEIGHT_STEPS)
    na = numerical_jacobian(lambda v: f.whitened([v, xc, xh])[0], xa, STEPS[[0, 1, 2, 4]])
    np.testing.assert_allclose(jh, nh, rtol=1e-5, atol=1e-6 * np.abs(nh).max())
    np.testing.assert_allclose(ja, na, rtol=1e-5, atol=1e-6 * np.abs(na).max())


def test_pairwise_residual_vanishes_only_with_the_true_height_model() -> None:
    """Noise-free straight flights: the pressure altitudes placed by the true height model
    give residuals of the 2-D placement's spherical-earth approximation (below 1 m); taking
    them as heights (the model at zero) leaves the 180 m offset's metres in them."""
    dataset = pressure_network(noise=False)
    for a, b, bias_a, bias_b in (("A", "B", BIAS_A, BIAS_B), ("A", "C", BIAS_A, BIAS_C)):
        f = _factor(dataset, a, b)
        truth = (TRUE_HEIGHT.height_offset_m, TRUE_HEIGHT.height_scale)
        res, _, _ = f.residual(bias_a.as_vector(), bias_b.as_vector(), height=truth)
        assert np.max(np.abs(res)) < 1.0
        res, _, _ = f.residual(bias_a.as_vector(), bias_b.as_vector(), height=(0.0, 0.0))
        assert np.max(np.abs(res)) > 20.0


@pytest.mark.parametrize("rid", ["A", "B"])
def test_corrected_ecef_height_columns(rid: str) -> None:
    dataset = pressure_network(noise=True)
    site, plots = dataset.sites[rid], plot_arrays(dataset, rid)
    bias = np.array([30.0, 1e-4, 1e-3, 1e-3 if site.is_3d else 0.0])
    _, jac, _ = corrected_ecef(site, plots, bias, (0.0, 0.0), (150.0, 0.02))
    assert jac.shape == (len(plots), 3, 8)
    numeric = numerical_jacobian(
        lambda v: corrected_ecef(site, plots, bias, (0.0, 0.0), tuple(v))[0],
        np.array([150.0, 0.02]), HEIGHT_STEPS)
    np.testing.assert_allclose(jac[:, :, 6:], numeric, rtol=1e-6, atol=1e-6)
    if site.is_3d:
        assert not np.any(jac[:, :, 6:])  # a 3-D radar measures its elevation


# --------------------------------------------------------------------------- ADS-B
def _adsb_table() -> pd.DataFrame:
    """Three aircraft at 1 Hz, heights of the true model plus noise: one level (150
    reports), one climbing (45) and one descending (130)."""
    rng = np.random.default_rng(11)
    rows = []
    for target, n, start, p0, climb in (("aa0001", 150, 10.0, 9000.0, 0.0),
                                        ("aa0002", 45, 30.0, 3000.0, 8.0),
                                        ("aa0003", 130, 0.0, 5000.0, -6.0)):
        t = start + np.arange(n)
        p = p0 + climb * (t - start)
        h = TRUE_HEIGHT.geometric(p) + rng.normal(0.0, 15.0, n)
        rows.append(pd.DataFrame({"time_s": t, "target_id": target, "lat_deg": 48.8,
                                  "lon_deg": 2.4, "alt_m": h, "sigma_m": 10.0,
                                  "baro_alt_m": p}))
    table = pd.concat(rows, ignore_index=True)
    table.loc[5, "baro_alt_m"] = np.nan  # a report without a pressure altitude
    return table


def test_segments_are_means_with_the_documented_sigma() -> None:
    table = _adsb_table()
    seg = adsb_height_segments(table)
    # aa0001 level: one segment of its 149 reports with baro_alt_m, however long;
    # aa0002 climbing: 0-44 s; aa0003 descending: 0-59, 60-119, 120-129 s.
    assert seg.n_reports.tolist() == [149, 45, 60, 60, 10]
    assert seg.target_id.tolist() == ["aa0001", "aa0002"] + ["aa0003"] * 3
    first = table.iloc[[i for i in range(150) if i != 5]]
    assert seg.geometric_m[0] == pytest.approx(first["alt_m"].mean())
    assert seg.pressure_m[0] == pytest.approx(first["baro_alt_m"].mean())
    assert seg.time_s[0] == pytest.approx(first["time_s"].mean())
    sigma_v = ADSB_VERTICAL_SIGMA_RATIO * 10.0
    expected = np.sqrt(sigma_v**2 / seg.n_reports + BARO_QUANTUM_M**2 / 12.0
                       + CORRELATED_SIGMA_M**2)
    np.testing.assert_allclose(seg.sigma_m, expected)
    assert len(adsb_height_segments(table.drop(columns="baro_alt_m"))) == 0
    assert len(adsb_height_segments(None)) == 0


def test_adsb_height_factor_jacobian_and_truth() -> None:
    table = _adsb_table()
    table["alt_m"] = TRUE_HEIGHT.geometric(table["baro_alt_m"])  # noise-free
    f = AdsbHeightFactor(3, adsb_height_segments(table), RobustKernel("none"))
    assert f.keys == [3] and f.dimension == 5
    truth = TRUE_HEIGHT.as_vector()
    assert np.max(np.abs(f.whitened([truth])[0])) < 1e-9
    x = np.array([100.0, 0.01])
    _, (jac,) = f.whitened([x])
    numeric = numerical_jacobian(lambda v: f.whitened([v])[0], x, HEIGHT_STEPS)
    np.testing.assert_allclose(jac, numeric, rtol=1e-7)
    e, (flat,) = f.error([x], True)
    assert e.shape == (5,) and flat.shape == (5, 2)


# --------------------------------------------------------------------------- placeable
def test_plots_near_the_zenith_are_not_placeable() -> None:
    site = site_at("A", 0.0, 0.0)
    plots = plot_arrays(make_dataset(np.random.default_rng(1), [(site, RadarBias())], [
        Track("aa0001", (-20e3, 3e3, 9000.0), (200.0, 0.0, 0.0), 0.0, 200.0),
    ], adsb=False), "A")
    ok = placeable_over_prior(site, plots)
    ground = np.hypot(plots.range_m, 0.0)
    # Far plots (elevation well below 70 deg at every height of the prior's span) are kept;
    # the plots passing near overhead (3 km from the radar at 9 km) are not.
    assert ok[ground > 40e3].all()
    assert not ok[ground < 10e3].any()
    three_d = site_at("B", 0.0, 0.0, sigma_elevation_mrad=1.0)
    assert placeable_over_prior(three_d, plots).all()


def test_height_jacobians_along_refracted_rays() -> None:
    """A 2-D radar with refraction (contract v2) places its plots at their modelled height
    along the refracted ray: the height columns follow, checked numerically."""
    dataset = pressure_network(noise=True)
    sites = {rid: dataclasses.replace(site, refraction="exponential")
             for rid, site in dataset.sites.items()}
    refracted = dataclasses.replace(dataset, sites=sites)
    site, plots = sites["A"], plot_arrays(refracted, "A")
    assert site.atmosphere is not None
    bias = np.array([30.0, 1e-4, 1e-3, 0.0])
    _, jac, _ = corrected_ecef(site, plots, bias, (0.0, 0.0), (150.0, 0.02))
    numeric = numerical_jacobian(
        lambda v: corrected_ecef(site, plots, bias, (0.0, 0.0), tuple(v))[0],
        np.array([150.0, 0.02]), HEIGHT_STEPS)
    np.testing.assert_allclose(jac[:, :, 6:], numeric, rtol=1e-5, atol=1e-5)
    f = _factor(refracted, "A", "B")
    xa, xb, xh = np.array([100.0, 0.0015, 0.003]), np.array([-60.0, -8e-4, -2e-3, 1.5e-3]), \
        np.array([150.0, 0.02])
    _, (_, _, jh) = f.whitened([xa, xb, xh])
    nh = numerical_jacobian(lambda v: f.whitened([xa, xb, v])[0], xh, HEIGHT_STEPS)
    np.testing.assert_allclose(jh, nh, rtol=1e-5, atol=1e-6 * np.abs(nh).max())
