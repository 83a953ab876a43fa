"""Refraction in the calibration (contract v2): the measurement model follows the refracted
rays the simulator traced, so biases are recovered; left undeclared, they are not."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from graphcal.core.refraction import Atmosphere
from graphcal.data.align import align_adsb, pair_plots
from graphcal.data.dataset import Dataset
from graphcal.model.factors import adsb_factor, pairwise_factor
from graphcal.model.measurement import reference_polar_covariance
from graphcal.model.parameters import RadarTerms
from graphcal.model.robust import RobustKernel
from graphcal.pipeline.calibrate import calibrate
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.jacobians import numerical_jacobian
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def run():
    return simulate(load_scenario(SCENARIOS / "demo_refraction.toml"), np.random.default_rng(5))


def _z(cal, biases) -> dict[tuple[str, str], float]:
    sd = np.sqrt(np.diag(cal.covariance))
    return {(rid, name): (cal.estimate[i] - biases[rid].value(name)) / sd[i]
            for i, (rid, name) in enumerate(cal.labels)}


def test_with_adsb_every_bias_within_3_sigma(run) -> None:
    assert all(s.atmosphere is not None for s in run.dataset.sites.values())
    cal = calibrate(run.dataset)
    z = _z(cal, run.biases)
    assert max(abs(v) for v in z.values()) < 3.0, z
    assert all(0.9 < e < 1.2 for e in cal.info["efficiency"].values())


def test_without_adsb_every_bias_within_3_sigma(run) -> None:
    cal = calibrate(run.dataset, use_adsb=False)
    z = _z(cal, run.biases)
    assert max(abs(v) for v in z.values()) < 3.0, z


def test_undeclared_refraction_gives_elevation_biases_tens_of_sigma_off(run) -> None:
    """The same plots with straight rays assumed: the 3-D radars' elevation biases absorb
    the bending and miss by tens of sigma (the problem contract v2 solves)."""
    straight = {rid: replace(s, refraction="none") for rid, s in run.dataset.sites.items()}
    cal = calibrate(Dataset(straight, run.dataset.plots, run.dataset.adsb), time_offset="off")
    z = _z(cal, run.biases)
    assert abs(z[("EST3D", "elevation_bias")]) > 20 and abs(z[("OUEST3D", "elevation_bias")]) > 20


@pytest.mark.parametrize("radar", ["NORD", "EST3D"])
def test_factor_jacobians_through_refracted_rays_match_numerical(run, radar: str) -> None:
    """ADS-B factor (reference along the refracted ray) and pairwise factor (plots placed
    along refracted rays; a 2-D plot at its reported height): analytic Jacobians in the
    biases against central differences."""
    ds = run.dataset
    site = ds.sites[radar]
    names = ("range_offset", "range_gain", "azimuth_bias") + (
        ("elevation_bias",) if site.is_3d else ())
    terms = RadarTerms(radar, names)
    x = np.array([40.0, 2e-4, 1e-3, 1e-3])[: len(names)]
    steps = np.array([1.0, 1e-5, 1e-5, 1e-5])[: len(names)]
    al = align_adsb(ds, radar)
    f = adsb_factor(site, terms, 0, al.plots.subset(np.arange(200)), al.reference_polar[:200],
                    reference_polar_covariance(al, site)[:200], RobustKernel("none"))
    _, (jac,) = f.whitened([x])
    np.testing.assert_allclose(jac, numerical_jacobian(lambda v: f.whitened([v])[0], x, steps),
                               rtol=1e-6, atol=1e-8)
    other = "SUD" if radar == "NORD" else "OUEST3D"
    pairs = pair_plots(ds, radar, other)
    so = ds.sites[other]
    to = RadarTerms(other, ("range_offset", "azimuth_bias"))
    g = pairwise_factor(site, so, terms, to, 0, 1, pairs.a_plots, pairs.b_plots,
                        pairs.a_index0, pairs.weight, pairs.b_index, RobustKernel("none"))
    assert g is not None and len(g) > 20
    xo = np.array([-30.0, -1e-3])
    _, (ja, _) = g.whitened([x, xo])
    np.testing.assert_allclose(
        ja, numerical_jacobian(lambda v: g.whitened([v, xo])[0], x, steps), rtol=1e-5, atol=1e-6)


def test_no_atmosphere_is_the_straight_model(run) -> None:
    """N_s = 0 declared as "exponential" gives the same estimate as straight rays."""
    zero = {rid: replace(s, refractivity_n_s=0.0) for rid, s in run.dataset.sites.items()}
    none = {rid: replace(s, refraction="none") for rid, s in run.dataset.sites.items()}
    assert Atmosphere(0.0).refracts is False
    a = calibrate(Dataset(zero, run.dataset.plots, run.dataset.adsb), "fl-ls")
    b = calibrate(Dataset(none, run.dataset.plots, run.dataset.adsb), "fl-ls")
    np.testing.assert_allclose(a.estimate, b.estimate, rtol=1e-9, atol=1e-12)
