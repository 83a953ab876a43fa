"""A radar's random-error sigmas estimated from its data: line-fit and ADS-B estimates.

Each number is checked against an independent expectation: the sigmas the data
were simulated with (tests/synthetic.py, geometry by pymap3d, and the scenario
simulator) and paper 000's error propagation (eq. 1-2, tested against pymap3d in
tests/test_variance.py).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from graphcal.core import frames
from graphcal.data.bias import RadarBias
from graphcal.noise import (
    LineFitOptions,
    NoiseEstimate,
    estimate_noise,
    estimate_noise_adsb,
    estimate_noise_line_fit,
    line_fit_residuals,
    sites_with_estimated_sigmas,
    variance_table,
)
from graphcal.noise.variance import propagate_sigmas
from graphcal.simulation.scenario import load_scenario
from graphcal.simulation.simulate import simulate
from tests.synthetic import Track, make_dataset, site_at

#: Accepted relative error of an estimated sigma against the simulated one.
TOLERANCE = 0.10


# --------------------------------------------------------------------------- simulated data


def _straight_tracks(rng: np.random.Generator, n: int = 24) -> list[Track]:
    tracks = []
    for i in range(n):
        start = (rng.uniform(-150e3, 150e3), rng.uniform(-150e3, 150e3), rng.uniform(3e3, 11e3))
        heading = rng.uniform(0, 2 * np.pi)
        speed = rng.uniform(150, 250)
        velocity = (speed * np.sin(heading), speed * np.cos(heading), 0.0)
        tracks.append(Track(f"b{i:05x}", start, velocity, 0.0, 1200.0))
    return tracks


@pytest.fixture(scope="module")
def straight():
    """A 2-D radar A and a 3-D radar B, straight level tracks, biased, with ADS-B (10 m)."""
    rng = np.random.default_rng(11)
    a = site_at("A", 0.0, 0.0, sigma_range_m=30.0, sigma_azimuth_mrad=1.0)
    b = site_at("B", 120e3, 20e3, sigma_range_m=60.0, sigma_azimuth_mrad=1.5,
                sigma_elevation_mrad=2.0)
    radars = [(a, RadarBias(80.0, 3e-4, 2e-3)), (b, RadarBias(-50.0, -2e-4, -1.5e-3, 1e-3))]
    return make_dataset(rng, radars, _straight_tracks(rng))


@pytest.fixture(scope="module")
def demo():
    return simulate(load_scenario("scenarios/demo_network.toml"), np.random.default_rng(1)).dataset


def _check(dataset, estimates, method: str) -> None:
    for rid, est in estimates.items():
        site = dataset.sites[rid]
        assert est.estimated and est.method == method, (rid, est.reason)
        assert est.sigma_range_m == pytest.approx(site.sigma_range_m, rel=TOLERANCE), rid
        assert est.sigma_azimuth_rad == pytest.approx(site.sigma_azimuth_rad, rel=TOLERANCE), rid
        if site.is_3d:
            assert est.sigma_elevation_rad == pytest.approx(
                site.sigma_elevation_rad, rel=TOLERANCE), rid
        else:
            assert est.sigma_elevation_mrad is None
        # Own standard errors: a few percent, and the truth within 4 of them.
        assert 0 < est.se_range_m < 0.05 * site.sigma_range_m
        assert abs(est.sigma_range_m - site.sigma_range_m) < 4 * est.se_range_m, rid
        assert abs(est.sigma_azimuth_mrad - site.sigma_azimuth_rad * 1e3) < (
            4 * est.se_azimuth_mrad), rid


@pytest.mark.parametrize("use_adsb,method", [(False, "line-fit"), (True, "adsb")])
def test_straight_tracks_both_methods(straight, use_adsb, method) -> None:
    estimates = estimate_noise(straight, use_adsb=use_adsb)
    _check(straight, estimates, method)
    if method == "line-fit":
        assert all(e.n_legs > 50 for e in estimates.values())


@pytest.mark.parametrize("use_adsb,method", [(False, "line-fit"), (True, "adsb")])
def test_demo_network_both_methods(demo, use_adsb, method) -> None:
    """Turns, climbs, 2-D and 3-D radars, missed detections, Mode C heights, NACp 8 ADS-B."""
    _check(demo, estimate_noise(demo, use_adsb=use_adsb), method)


def test_auto_uses_adsb_when_present_and_line_fit_without(demo) -> None:
    with_adsb = estimate_noise(demo, use_adsb="auto", radar_ids=["NORD"])
    assert with_adsb["NORD"].method == "adsb"
    no_adsb = dataclasses.replace(demo, adsb=None)
    estimates = estimate_noise(no_adsb, use_adsb="auto")
    assert {e.method for e in estimates.values()} == {"line-fit"}
    _check(no_adsb, estimates, "line-fit")


def test_line_fit_is_robust_to_outlying_plots(demo) -> None:
    """2 % of the plots of a radar moved 3 km in range: the robust estimate holds."""
    rng = np.random.default_rng(5)
    plots = demo.plots.copy()
    rows = np.flatnonzero(plots["radar_id"].to_numpy() == "SUD")
    bad = rng.choice(rows, size=len(rows) // 50, replace=False)
    plots.loc[bad, "range_m"] += 3000.0
    dataset = dataclasses.replace(demo, plots=plots, adsb=None)
    est = estimate_noise_line_fit(dataset, "SUD")
    assert est.sigma_range_m == pytest.approx(30.0, rel=TOLERANCE)
    assert est.sigma_azimuth_mrad == pytest.approx(1.2, rel=TOLERANCE)


def test_residual_variance_model_is_unbiased(straight) -> None:
    """sum e^2 equals sum of the predicted E[e^2] with the true sigmas (method of moments)."""
    lf = line_fit_residuals(straight, "B")
    site = straight.sites["B"]
    true = np.array([site.sigma_range_m, site.sigma_azimuth_rad, site.sigma_elevation_rad])
    predicted = np.einsum("ikm,m->k", lf.coef, true**2)
    observed = np.sum(lf.polar_residual**2, axis=0)
    # 3-sigma of a chi-square with ~len(lf) dof is ~3 sqrt(2/n): < 10 %.
    np.testing.assert_allclose(observed / predicted, 1.0, atol=3 * math.sqrt(2 / len(lf)))
    # The dof correction: sum (1 - h_ii) = n_plots - 2 n_windows.
    assert np.sum(1 - lf.leverage) == pytest.approx(len(lf) - 2 * lf.n_windows)


# --------------------------------------------------------------------------- lookup table


@pytest.fixture(scope="module")
def surrounded():
    """Radars A (2-D) and B (3-D) inside 60 straight level tracks, no bias, no ADS-B."""
    rng = np.random.default_rng(12)
    tracks = []
    for i in range(60):
        start = (rng.uniform(-150e3, 150e3), rng.uniform(-150e3, 150e3), rng.uniform(3e3, 11e3))
        heading, speed = rng.uniform(0, 2 * np.pi), rng.uniform(150, 250)
        velocity = (speed * np.sin(heading), speed * np.cos(heading), 0.0)
        tracks.append(Track(f"c{i:05x}", start, velocity, 0.0, 900.0))
    a = site_at("A", 0.0, 0.0, sigma_range_m=30.0, sigma_azimuth_mrad=1.0)
    b = site_at("B", 30e3, 20e3, sigma_range_m=60.0, sigma_azimuth_mrad=1.5,
                sigma_elevation_mrad=2.0)
    return make_dataset(rng, [(a, RadarBias()), (b, RadarBias())], tracks, adsb=False)


def test_variance_table_matches_error_propagation(surrounded) -> None:
    """Default bins (50 km x 45 deg), RMS per bin, against eq. 1-2 with the true sigmas."""
    for rid in ("A", "B"):
        site = surrounded.sites[rid]
        table = variance_table(surrounded, rid, robust=False)
        est = estimate_noise_line_fit(surrounded, rid, robust=False)
        expected_cols = {"radar_id", "range_min_m", "range_max_m", "azimuth_min_deg",
                         "azimuth_max_deg", "n_plots", "n_legs", "sigma_x_m", "sigma_y_m",
                         "sigma_p_m", "sigma_range_m", "sigma_azimuth_mrad"}
        if site.is_3d:
            expected_cols |= {"sigma_z_m", "sigma_elevation_mrad"}
        assert set(table.columns) == expected_cols
        assert table["n_plots"].sum() == est.n_plots_used
        assert not table.duplicated(["range_min_m", "azimuth_min_deg"]).any()
        assert np.all(table["range_max_m"] - table["range_min_m"] == 50e3)
        assert np.all(table["azimuth_max_deg"] - table["azimuth_min_deg"] == 45.0)
        full = table[(table["n_plots"] >= 200) & (table["range_min_m"] >= 50e3)]
        assert len(full) >= 15
        # Polar sigmas per bin: the simulated ones (RMS over >= 200 plots: sd <= 5 %).
        np.testing.assert_allclose(full["sigma_range_m"], site.sigma_range_m, rtol=0.2)
        np.testing.assert_allclose(full["sigma_azimuth_mrad"], site.sigma_azimuth_rad * 1e3,
                                   rtol=0.2)
        # sigma_p (eq. 10, horizontal) does not depend on azimuth: eq. 1 at the bin centre,
        # at the elevation of a target at 7 km (the tracks fly at 3-11 km).  Within the
        # 50-100 km bins the range is +-33 % about the centre, hence 20 %.
        r_c = 0.5 * (full["range_min_m"] + full["range_max_m"]).to_numpy()
        az_c = np.deg2rad(0.5 * (full["azimuth_min_deg"] + full["azimuth_max_deg"])).to_numpy()
        el_c = frames.elevation_from_height(r_c, 7000.0, site.lat_rad, site.alt_m)
        prop = propagate_sigmas(r_c, az_c, el_c, site.sigma_range_m, site.sigma_azimuth_rad,
                                site.sigma_elevation_rad)
        np.testing.assert_allclose(
            full["sigma_p_m"], np.sqrt((prop.sigma_x_m**2 + prop.sigma_y_m**2) / 2), rtol=0.2)
        # sigma_x, sigma_y vary across a 45 deg bin (they vanish along some azimuths):
        # compare with the RMS of eq. 1 over the plots the table used in the bin.
        plots = surrounded.plots.loc[line_fit_residuals(surrounded, rid).plot_index]
        r = plots["range_m"].to_numpy()
        az = np.deg2rad(plots["azimuth_deg"].to_numpy())
        if site.is_3d:
            el = np.deg2rad(plots["elevation_deg"].to_numpy())
        else:
            el = frames.elevation_from_height(r, plots["altitude_m"].to_numpy(), site.lat_rad,
                                              site.alt_m)
        per_plot = propagate_sigmas(r, az, el, site.sigma_range_m, site.sigma_azimuth_rad,
                                    site.sigma_elevation_rad)
        for _, row in full.iterrows():
            inside = ((r >= row["range_min_m"]) & (r < row["range_max_m"])
                      & (np.rad2deg(az) >= row["azimuth_min_deg"])
                      & (np.rad2deg(az) < row["azimuth_max_deg"]))
            for comp in ("x", "y", "z") if site.is_3d else ("x", "y"):
                var = getattr(per_plot, f"sigma_{comp}_m")[inside] ** 2
                expected = np.sqrt(np.mean(var))
                # Relative sd of an RMS of independent N(0, var_i): sqrt(2 sum var^2) / (2 sum var).
                rel_sd = np.sqrt(2 * np.sum(var**2)) / (2 * np.sum(var))
                assert row[f"sigma_{comp}_m"] == pytest.approx(expected, rel=4 * rel_sd), (
                    rid, comp, dict(row))


# --------------------------------------------------------------------------- bad input, sites


def test_too_few_plots_gives_a_flagged_estimate(straight) -> None:
    plots = straight.plots
    keep = (plots["radar_id"] != "A") | (plots.index.to_numpy() % 200 == 0)
    sparse = dataclasses.replace(straight, plots=plots[keep])
    est = estimate_noise(sparse, use_adsb=False)
    assert not est["A"].estimated and math.isnan(est["A"].sigma_range_m)
    assert "straight windows" in est["A"].reason
    assert est["B"].estimated
    few = estimate_noise_adsb(sparse, "A", min_plots=10_000)
    assert not few.estimated and "matched to ADS-B" in few.reason
    # The site keeps its own sigmas; a table cannot be made.
    sites = sites_with_estimated_sigmas(sparse.sites, est, only_missing=False)
    assert sites["A"] is sparse.sites["A"]
    with pytest.raises(ValueError, match="straight windows"):
        variance_table(sparse, "A")


def test_bad_arguments(straight) -> None:
    with pytest.raises(ValueError, match="no ADS-B"):
        estimate_noise(dataclasses.replace(straight, adsb=None), use_adsb=True)
    with pytest.raises(ValueError, match="unknown radar"):
        estimate_noise(straight, radar_ids=["ZZ"])
    with pytest.raises(ValueError, match="use_adsb"):
        estimate_noise(straight, use_adsb="yes")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="window_plots"):
        LineFitOptions(window_plots=3)


def test_sites_with_estimated_sigmas() -> None:
    a = site_at("A", 0.0, 0.0)
    b = site_at("B", 1e4, 0.0, sigma_elevation_mrad=2.0)
    a_missing = dataclasses.replace(a, sigma_range_m=math.nan)
    est = {
        "A": NoiseEstimate("A", 41.0, 1.3, None, 1000, 50, "line-fit"),
        "B": NoiseEstimate("B", 61.0, 1.6, 2.2, 1000, 50, "adsb"),
    }
    only = sites_with_estimated_sigmas({"A": a_missing, "B": b}, est)
    assert only["A"].sigma_range_m == 41.0
    assert only["A"].sigma_azimuth_rad == a.sigma_azimuth_rad
    assert only["B"] is b
    everything = sites_with_estimated_sigmas({"A": a, "B": b}, est, only_missing=False)
    assert everything["A"].sigma_range_m == 41.0
    assert everything["A"].sigma_azimuth_rad == pytest.approx(1.3e-3)
    assert everything["A"].sigma_elevation_rad is None
    assert everything["B"].sigma_elevation_rad == pytest.approx(2.2e-3)
    assert everything["B"].lat_rad == b.lat_rad and everything["B"].estimate == b.estimate
