"""Plots without an address associated by gating (graphcal.tracking.association) and the
calibration that associates, solves and associates again (graphcal.pipeline.associate),
scored against the simulator's truth: which aircraft each plot came from, or clutter."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

import graphcal
from graphcal.data.align import plot_arrays
from graphcal.tracking.association import (
    ASSOCIATED,
    associate,
    coarse_bias,
    reference_tracks,
    unaddressed_radars,
)
from tests.paths import SCENARIOS

PRIMARY = ["EST3D", "OUEST3D"]
CLUTTER_PER_SCAN = 8.0


@pytest.fixture(scope="module")
def network():
    """The demo network (seed 1) with the 3-D radars' addresses removed and 8 false plots a
    scan added to EST3D; the plots' true aircraft ("clutter" for the false ones)."""
    sim = graphcal.simulate(SCENARIOS / "demo_network.toml", seed=1)
    ds = sim.dataset
    plots = ds.plots.copy()
    truth = plots["target_id"].astype(str).copy()
    plots.loc[plots["radar_id"].isin(PRIMARY), "target_id"] = ""
    rng = np.random.default_rng(7)
    period = ds.sites["EST3D"].scan_period_s
    t0, t1 = plots["time_s"].min(), plots["time_s"].max()
    n = rng.poisson(CLUTTER_PER_SCAN * (t1 - t0) / period)
    clutter = pd.DataFrame({
        "radar_id": "EST3D", "time_s": rng.uniform(t0, t1, n), "target_id": "",
        "range_m": rng.uniform(5e3, 250e3, n), "azimuth_deg": rng.uniform(0.0, 360.0, n),
        "elevation_deg": rng.uniform(0.5, 10.0, n)})
    plots = pd.concat([plots, clutter.reindex(columns=plots.columns)], ignore_index=True)
    truth = pd.concat([truth, pd.Series(["clutter"] * n)], ignore_index=True)
    return sim, ds, replace(ds, plots=plots), truth, n


def test_the_radars_without_addresses_are_found(network) -> None:
    _, ds, blank, _, _ = network
    assert unaddressed_radars(ds) == []
    assert sorted(unaddressed_radars(blank)) == sorted(PRIMARY)


def test_the_coarse_search_finds_the_biases_to_within_the_first_gate(network) -> None:
    """From zero, the vote lands within a few sigma of the first gate's widths (300 m,
    2 mrad) of the truth, with range gains of a few 1e-4 folded into the offset."""
    sim, _, blank, _, _ = network
    refs = reference_tracks(blank, {})
    for rid in PRIMARY:
        plots = plot_arrays(blank, rid)
        plots = plots.subset(plots.target_id.astype(str) == "")
        found = coarse_bias(blank.sites[rid], refs, plots)
        true = sim.truth[rid]
        mean_range = float(np.nanmean(plots.range_m))
        assert found.range_offset_m == pytest.approx(
            true.range_offset_m + true.range_gain * mean_range, abs=300.0)
        assert found.azimuth_bias_rad == pytest.approx(true.azimuth_bias_rad, abs=1e-3)
        assert found.elevation_bias_rad == pytest.approx(true.elevation_bias_rad, abs=1e-3)


def test_association_at_the_true_biases_against_the_truth(network) -> None:
    """At the true biases: no plot given to the wrong aircraft, no clutter associated, at
    least 99 % of the plots of aircraft with a reference associated, and the false-plot
    rate near the 8 a scan added (Poisson: within 5 %)."""
    sim, _, blank, truth, n_clutter = network
    cov = {rid: np.diag([1.0, 1e-10, 1e-10, 1e-10]) for rid in PRIMARY}
    result = associate(blank, {rid: sim.truth[rid] for rid in sim.truth}, cov)
    given = result.target_id[result.status == ASSOCIATED]
    true = truth.loc[given.index]
    assert (true.to_numpy() == "clutter").sum() == 0
    assert (true.to_numpy() != given.to_numpy()).sum() == 0
    real = truth.loc[result.status.index] != "clutter"
    assert (result.status[real] == ASSOCIATED).mean() > 0.99
    est = result.radars["EST3D"]
    assert est.false_plots_per_scan == pytest.approx(CLUTTER_PER_SCAN, rel=0.05)
    assert est.n_left_out >= n_clutter


@pytest.mark.parametrize("use_adsb", [True, False])
def test_calibrating_without_addresses_matches_the_addressed_run(network, use_adsb) -> None:
    """Every radar calibrated; the 3-D radars' estimates within 0.3 sigma of the addressed
    run's and their sigmas within 1 % of it (the clutter left out, the same plots used)."""
    _, ds, blank, _, _ = network
    cal = graphcal.calibrate(blank, use_adsb=use_adsb, model_checks=False, check_fit=False,
                             bound=False)
    ref = graphcal.calibrate(ds, use_adsb=use_adsb, model_checks=False, check_fit=False,
                             bound=False)
    assert set(cal.radar_ids) == set(ref.radar_ids)
    figures = cal.info["association"]["radars"]
    assert set(figures) == set(PRIMARY)
    for rid in PRIMARY:
        for key in ("range_offset_m", "range_gain", "azimuth_bias_mrad", "elevation_bias_mrad"):
            assert abs(cal.value(rid, key) - ref.value(rid, key)) < 0.3 * ref.sigma(rid, key)
            assert cal.sigma(rid, key) == pytest.approx(ref.sigma(rid, key), rel=0.01)


def test_with_windows_the_radars_without_addresses_are_calibrated(network) -> None:
    """Window by window (--window): each window associated before its calibration; every
    radar calibrated, the 3-D radars' smoothed biases within 3 sigma of the truth."""
    sim, _, blank, _, _ = network
    cal = graphcal.calibrate(blank, window="15min", check_fit=False)
    assert set(PRIMARY) <= set(cal.radar_ids)
    figures = cal.info["association"]
    assert figures["windows"] == 2 and set(figures["radars"]) == set(PRIMARY)
    est = figures["radars"]["EST3D"]
    assert est["associated"] + est["ambiguous"] + est["left_out"] == est["plots"]
    assert est["false_plots_per_scan"] == pytest.approx(CLUTTER_PER_SCAN, rel=0.1)
    for rid in PRIMARY:
        true = sim.truth[rid]
        for key, value in (("range_offset_m", true.range_offset_m),
                           ("azimuth_bias_mrad", true.azimuth_bias_rad * 1e3),
                           ("elevation_bias_mrad", true.elevation_bias_rad * 1e3)):
            assert abs(cal.value(rid, key) - value) < 3.0 * cal.sigma(rid, key), (rid, key)


def test_the_associated_plots_fit_their_aircraft_as_chi_square_says(network) -> None:
    """At the true biases the share of associated plots beyond the chi-square's 99.9 % point
    is the 0.1 % the distribution gives (binomial over 5,000 plots: within 0.02-0.25 %),
    and no warning; with EST3D's range offset 1.5 sigma off, that share passes 1 % and the
    radar is warned about."""
    from dataclasses import replace as changed

    sim, _, blank, _, _ = network
    cov = {rid: np.diag([1.0, 1e-10, 1e-10, 1e-10]) for rid in PRIMARY}
    truth = {rid: sim.truth[rid] for rid in sim.truth}
    result = associate(blank, truth, cov)
    for rid in PRIMARY:
        assert 0.0002 < result.radars[rid].tail_fraction < 0.0025
        assert result.radars[rid].warning() is None
    off = dict(truth)
    off["EST3D"] = changed(truth["EST3D"], range_offset_m=truth["EST3D"].range_offset_m + 150.0)
    result = associate(blank, off, cov)
    assert result.radars["EST3D"].tail_fraction > 0.01
    assert "EST3D: " in result.radars["EST3D"].warning()
    assert result.radars["OUEST3D"].warning() is None


def test_the_command_line_says_what_was_associated() -> None:
    from graphcal.cli.calibrate import association_line

    line = association_line({
        "EST3D": {"plots": 6691, "associated": 5298, "false_plots_per_scan": 7.74},
        "SUD": {"plots": 7112, "associated": 7100, "false_plots_per_scan": None}})
    assert line == ("plots without an address associated: EST3D 5298 of 6691 (7.7 left out a "
                    "scan), SUD 7100 of 7112")


def test_plots_that_lost_their_address_at_a_mode_s_radar_are_associated(network) -> None:
    """A Mode S radar (NORD) whose recording lost the address of a quarter of its plots
    (contract v3: ``info.association`` when any plot lacks one): those plots are associated,
    at least 99 % of them with the aircraft that made them and none with another, and the
    radar's estimate stays within 0.3 sigma of the run with every address, its sigma within
    2 % (the same plots used)."""
    _, ds, _, _, _ = network
    plots = ds.plots.copy()
    nord = np.flatnonzero(plots["radar_id"].to_numpy() == "NORD")
    lost = np.random.default_rng(11).choice(nord, size=len(nord) // 4, replace=False)
    truth = plots["target_id"].astype(str).iloc[lost]
    plots.iloc[lost, plots.columns.get_loc("target_id")] = ""
    options = dict(model_checks=False, check_fit=False, bound=False)
    cal = graphcal.calibrate(replace(ds, plots=plots), **options)
    ref = graphcal.calibrate(ds, **options)
    figures = cal.info["association"]["radars"]
    assert set(figures) == {"NORD"} and figures["NORD"]["plots"] == len(lost)
    assert figures["NORD"]["associated"] >= 0.99 * len(lost)
    association = associate(replace(ds, plots=plots), {r: cal.bias(r) for r in cal.radar_ids})
    given = association.target_id.loc[truth.index]
    associated = association.status.loc[truth.index] == ASSOCIATED
    assert (given[associated] == truth[associated]).all()
    for key in ("range_offset_m", "range_gain", "azimuth_bias_mrad"):
        assert abs(cal.value("NORD", key) - ref.value("NORD", key)) < 0.3 * ref.sigma("NORD", key)
        assert cal.sigma("NORD", key) == pytest.approx(ref.sigma("NORD", key), rel=0.02)


@pytest.mark.parametrize("shrink", [2.5, 5.0])
def test_a_misfit_of_an_associated_radar_names_association(network, shrink) -> None:
    """EST3D's declared range and azimuth sigmas ``shrink`` times smaller than its noise:
    its associated plots fit worse than the chi-square says (the tail warning), and the fit
    verdict's warning (at 2.5: sigmas widened; at 5: chi2/dof beyond the floor of 4, the
    verdict failed) names the association by gating as a possible cause."""
    _, _, blank, _, _ = network
    site = blank.sites["EST3D"]
    sites = dict(blank.sites)
    sites["EST3D"] = replace(site, sigma_range_m=site.sigma_range_m / shrink,
                             sigma_azimuth_rad=site.sigma_azimuth_rad / shrink)
    cal = graphcal.calibrate(replace(blank, sites=sites), check_fit=False, bound=False)
    verdict = cal.info["fit_verdict"]
    assert "EST3D" in verdict["associated"]
    assert cal.info["association"]["radars"]["EST3D"]["tail_fraction"] > 0.01
    text = " ".join(w for w in cal.warnings if w.startswith(("radar EST3D", "the residuals")))
    assert "associated by gating" in text
    assert ("EST3D" in verdict["failed"]) == (shrink > 3.0)


def test_the_calibrator_associates_with_summarise_associated(network) -> None:
    """Windows as they arrive (``Calibrator``): with ``summarise_associated`` the primary
    radars are calibrated, within 3 sigma of the truth; with the default summary they are
    not, and the calibrator counts the plots it could not use."""
    from graphcal.pipeline.windowed import summarise_associated
    from graphcal.solvers.incremental import Calibrator

    sim, _, blank, _, _ = network
    associated = Calibrator(blank.sites, 900.0, summarise=summarise_associated)
    plain = Calibrator(blank.sites, 900.0)
    for calibrator in (associated, plain):
        for start in (0.0, 900.0):
            block = blank.plots["time_s"].between(start, start + 900.0, inclusive="left")
            calibrator.add(replace(blank, plots=blank.plots[block]))
        calibrator.flush()
    assert associated.unaddressed_plots == 0
    n_blank = int((blank.plots["target_id"].astype(str) == "").sum())
    assert plain.unaddressed_plots == n_blank
    current = associated.current()
    assert set(PRIMARY) <= set(current) and not set(PRIMARY) & set(plain.current())
    for rid in PRIMARY:
        true, est = sim.truth[rid], current[rid]
        assert abs(est.bias.range_offset_m - true.range_offset_m) < 3.0 * est.sigma[
            "range_offset_m"], rid
        assert abs(est.bias.azimuth_bias_rad - true.azimuth_bias_rad) * 1e3 < 3.0 * est.sigma[
            "azimuth_bias_mrad"], rid
