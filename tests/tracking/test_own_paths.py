"""Tracks formed from one radar's plots (graphcal.tracking.track_formation) and paths of
their own for the aircraft no reference covers (graphcal.tracking.own_paths), scored
against the simulator's truth: which aircraft made each plot, or clutter.

The network is ``scenarios/demo_identity.toml`` (seed 1) without its two Mode S radars and
with ADS-B kept for 40 % of the aircraft: the other aircraft are seen only by the Mode A/C
SSR (SUD) and the two primary 3-D radars (EST3D with 8 false plots a scan), so that without
paths of their own their plots cannot enter the fit.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

import graphcal
from graphcal.data.align import plot_arrays
from graphcal.simulation.simulate import CLUTTER
from graphcal.tracking.association import ASSOCIATED, associate
from graphcal.tracking.own_paths import OWN_PATH_PREFIX
from graphcal.tracking.track_formation import form_tracks
from tests.paths import SCENARIOS

NO_IDENTITY = ["SUD", "EST3D", "OUEST3D"]
KEYS = ("range_offset_m", "range_gain", "azimuth_bias_mrad", "elevation_bias_mrad",
        "time_offset_s")


@pytest.fixture(scope="module")
def uncovered():
    """The network (module docstring), each plot's true aircraft, and the true biases."""
    sim = graphcal.simulate(SCENARIOS / "demo_identity.toml", seed=1)
    ds = sim.dataset
    truth = pd.Series(sim.plot_truth["truth_target_id"].to_numpy(), index=ds.plots.index)
    keep_plots = ds.plots["radar_id"].isin(NO_IDENTITY)
    aircraft = np.array(sorted(pd.unique(ds.adsb["target_id"].astype(str))))
    rng = np.random.default_rng(3)
    with_adsb = set(aircraft[rng.random(len(aircraft)) < 0.4])
    adsb = ds.adsb[ds.adsb["target_id"].astype(str).isin(with_adsb)]
    sites = {rid: site for rid, site in ds.sites.items() if rid in NO_IDENTITY}
    network = replace(ds, sites=sites, plots=ds.plots.loc[keep_plots], adsb=adsb)
    return network, truth.loc[keep_plots], sim.biases, with_adsb


def test_tracks_follow_one_aircraft_and_clutter_forms_none(uncovered) -> None:
    """On the measured plots of every radar, clutter included: at least 99 % of the plots in
    a track are of the track's aircraft, at most 0.5 % of the false plots are in a track (one
    joins only when it falls in the gate of a track whose aircraft was missed), and
    at least 85 % of the real plots are (the detection probability is 0.9-0.98, so some
    tracks end before their aircraft leaves)."""
    network, truth, _, _ = uncovered
    for rid in NO_IDENTITY:
        plots = plot_arrays(network, rid)
        label = form_tracks(network.sites[rid], plots)
        true = truth.reindex(plots.index).to_numpy()
        frame = pd.DataFrame({"track": label, "truth": true})
        tracked = frame[frame["track"] >= 0]
        major = tracked.groupby("track")["truth"].agg(lambda s: s.value_counts().iloc[0])
        assert major.sum() / len(tracked) >= 0.99, rid
        clutter = true == CLUTTER
        if clutter.any():
            assert np.mean(label[clutter] >= 0) <= 5e-3, rid
        assert np.mean(label[~clutter] >= 0) >= 0.85, rid


def test_aircraft_no_reference_covers_get_paths_of_their_own(uncovered) -> None:
    """At the true biases: without paths of their own the aircraft without ADS-B are left
    out (but for a plot in a thousand taken by a near aircraft with ADS-B); with them, at
    least 80 % of their plots are on a path of their own, at least 99.5 % of those of one
    aircraft per path, no false plot on any, and the plots associated with ADS-B are as
    before."""
    network, truth, biases, with_adsb = uncovered
    cov = {rid: np.diag([5.0**2, 1e-5**2, 1e-4**2, 1e-4**2]) for rid in NO_IDENTITY}
    without = associate(network, biases, cov, own_paths=False)
    found = associate(network, biases, cov)
    true = truth.reindex(found.target_id.index)
    uncovered_plots = (true != CLUTTER) & ~true.isin(with_adsb)
    assert ((without.status == ASSOCIATED) & uncovered_plots).sum() <= 1e-3 * uncovered_plots.sum()
    own = (found.status == ASSOCIATED) & found.target_id.astype(str).str.startswith(
        OWN_PATH_PREFIX)
    assert own.sum() >= 0.8 * uncovered_plots.sum()
    assert not (own & (true == CLUTTER)).any()
    frame = pd.DataFrame({"path": found.target_id[own], "truth": true[own]})
    pure = frame.groupby("path")["truth"].agg(lambda s: s.value_counts().iloc[0]).sum()
    assert pure >= 0.995 * own.sum()
    referenced = (without.status == ASSOCIATED)
    assert (found.target_id[referenced] == without.target_id[referenced]).all()
    per_radar = {rid: r.n_own_paths for rid, r in found.radars.items()}
    assert sum(per_radar.values()) == own.sum() and min(per_radar.values()) > 0


def test_paths_of_their_own_do_not_depend_on_the_radars_order(uncovered) -> None:
    network, _, biases, _ = uncovered
    cov = {rid: np.diag([5.0**2, 1e-5**2, 1e-4**2, 1e-4**2]) for rid in NO_IDENTITY}
    reordered = replace(network, sites=dict(reversed(list(network.sites.items()))))
    a = associate(network, biases, cov)
    b = associate(reordered, biases, cov)
    assert a.target_id.sort_index().equals(b.target_id.sort_index())


def test_calibrated_with_paths_of_their_own_as_with_addresses(uncovered) -> None:
    """The whole calibration: every bias and time offset within 3 sigma of the truth, and
    every sigma within 15 % of the same data's with every plot's address known (clutter
    dropped).  Without paths of their own the primary radars' sigmas were up to 1.7 times
    the addressed run's (measured on this network)."""
    network, truth, biases, _ = uncovered
    options = dict(model_checks=False, check_fit=False, bound=False)
    cal = graphcal.calibrate(network, **options)
    plots = network.plots.copy()
    plots["target_id"] = truth.reindex(plots.index).to_numpy()
    addressed = graphcal.calibrate(replace(network, plots=plots[plots["target_id"] != CLUTTER]),
                                   **options)
    ratios = []
    for rid in NO_IDENTITY:
        est, ref = cal.to_dict()["radars"][rid], addressed.to_dict()["radars"][rid]
        true = biases[rid]
        truth_of = {"range_offset_m": true.range_offset_m, "range_gain": true.range_gain,
                    "azimuth_bias_mrad": true.azimuth_bias_rad * 1e3,
                    "elevation_bias_mrad": true.elevation_bias_rad * 1e3,
                    "time_offset_s": true.time_offset_s}
        for key in KEYS:
            if est.get(key) is None:
                continue
            assert abs(est[key] - truth_of[key]) <= 3.0 * est["sigma"][key], (rid, key)
            ratios.append(est["sigma"][key] / ref["sigma"][key])
    assert max(ratios) <= 1.15
    assert cal.info["association"]["radars"]["EST3D"]["own_paths"] > 0


def test_without_any_reference_the_radars_calibrate_on_paths_of_their_own(uncovered) -> None:
    """No ADS-B and no Mode S radar (``use_adsb=False``): the coarse search has nothing to
    vote against, and every aircraft is a path of its own.  Every radar is still calibrated,
    each estimate within 1 sigma of the same data's with every address known (clutter
    dropped; the same cross-radar model: with a fraction f of the plots kept the two differ
    by about sigma sqrt(1/f - 1), 0.3 sigma at f = 0.92, so 1 sigma is 3 of those) and each
    sigma within 15 % of it."""
    network, truth, _, _ = uncovered
    options = dict(use_adsb=False, model_checks=False, check_fit=False, bound=False)
    cal = graphcal.calibrate(network, **options)
    plots = network.plots.copy()
    plots["target_id"] = truth.reindex(plots.index).to_numpy()
    addressed = graphcal.calibrate(replace(network, plots=plots[plots["target_id"] != CLUTTER]),
                                   **options)
    figures = cal.info["association"]["radars"]
    assert set(cal.radar_ids) == set(NO_IDENTITY)
    for rid in NO_IDENTITY:
        assert figures[rid]["own_paths"] == figures[rid]["associated"] > 0
        est, ref = cal.to_dict()["radars"][rid], addressed.to_dict()["radars"][rid]
        for key, sigma in ref["sigma"].items():
            assert abs(est[key] - ref[key]) <= 1.0 * sigma, (rid, key)
            assert est["sigma"][key] <= 1.15 * sigma, (rid, key)
