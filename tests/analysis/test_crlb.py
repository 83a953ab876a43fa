"""The Cramér-Rao bound (graphcal.analysis.crlb) against hand formulas, a plain loop, and the graph.

Geometry in the expectations goes through pymap3d (as tests/synthetic.py), not
graphcal.core.frames.
"""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest

from graphcal.analysis.crlb import crlb
from graphcal.data.bias import RadarBias
from graphcal.solvers.graph import graph
from tests.synthetic import ORIGIN, Track, make_dataset, site_at

ADSB_SIGMA = 10.0


def _aer(site, track: Track, t: np.ndarray):
    """Azimuth, elevation [rad] and slant range [m] of the track at times t from the site."""
    lat, lon, alt = pymap3d.enu2geodetic(*track.enu(t).T, *ORIGIN)
    az, el, r = pymap3d.geodetic2aer(
        lat, lon, alt, np.rad2deg(site.lat_rad), np.rad2deg(site.lon_rad), site.alt_m
    )
    return np.deg2rad(az), np.deg2rad(el), r


def _interp_factor(t: np.ndarray, t0: float) -> np.ndarray:
    """(1 - w)^2 + w^2 for 1 Hz ADS-B starting at t0: the interpolated variance factor."""
    w = np.mod(t - t0, 1.0)
    return (1.0 - w) ** 2 + w**2


def _single_radar(estimate, sigma_range=30.0, sigma_az_mrad=1.0):
    site = site_at("S", 0.0, 0.0, sigma_range_m=sigma_range, sigma_azimuth_mrad=sigma_az_mrad,
                   estimate=estimate)
    track = Track("abc123", (-40e3, 50e3, 9000.0), (180.0, -20.0, 0.0), 0.0, 400.0)
    ds = make_dataset(np.random.default_rng(3), [(site, RadarBias())], [track],
                      adsb_sigma_m=ADSB_SIGMA, noise=False)
    t = ds.plots["time_s"].to_numpy()
    return site, track, ds, t


def test_range_offset_only_matches_hand_formula() -> None:
    site, track, ds, t = _single_radar(("range_offset",))
    res = crlb(ds)
    assert res.labels == [("S", "range_offset")]
    _, el, _ = _aer(site, track, t)
    # ADS-B ENU covariance s^2 diag(1, 1, 1.5^2) along the line of sight.
    adsb_var = ADSB_SIGMA**2 * _interp_factor(t, track.t0_s) * (
        np.cos(el) ** 2 + 1.5**2 * np.sin(el) ** 2
    )
    expected = 1.0 / np.sum(1.0 / (site.sigma_range_m**2 + adsb_var))
    assert res.covariance[0, 0] == pytest.approx(expected, rel=1e-3)
    # Without ADS-B noise it would be sigma_r^2 / n; the ADS-B term makes it a bit larger.
    assert expected > site.sigma_range_m**2 / len(t)
    assert res.sigma("S", "range_offset_m") == pytest.approx(np.sqrt(expected), rel=1e-3)


def test_azimuth_bias_only_matches_hand_formula() -> None:
    site, track, ds, t = _single_radar(("azimuth_bias",))
    res = crlb(ds)
    _, el, r = _aer(site, track, t)
    ground = r * np.cos(el)
    adsb_var = ADSB_SIGMA**2 * _interp_factor(t, track.t0_s) / ground**2
    expected = 1.0 / np.sum(1.0 / (site.sigma_azimuth_rad**2 + adsb_var))
    assert res.covariance[0, 0] == pytest.approx(expected, rel=1e-3)
    assert res.sigma("S", "azimuth_bias_mrad") == pytest.approx(1e3 * np.sqrt(expected),
                                                                 rel=1e-3)


# --------------------------------------------------------------------------- plain loop
def _network(
    seed: int = 0,
    *,
    adsb: bool = True,
    duration: float = 300.0,
    noise: bool = True,
    time_offsets_s: tuple[float, float] = (0.0, 0.0),
):
    radars = [
        (site_at("A", -30e3, 0.0, sigma_range_m=30.0, sigma_azimuth_mrad=1.0),
         RadarBias(50.0, 0.001, 0.002, time_offset_s=time_offsets_s[0])),
        (site_at("B", 30e3, 10e3, sigma_range_m=20.0, sigma_azimuth_mrad=0.8,
                 sigma_elevation_mrad=2.0),
         RadarBias(-40.0, -0.0005, -0.001, 0.0015, time_offsets_s[1])),
    ]
    tracks = [
        Track("a1", (0.0, -60e3, 8000.0), (0.0, 220.0, 0.0), 0.0, duration),
        Track("a2", (-50e3, 40e3, 10000.0), (200.0, -50.0, 0.0), 0.0, duration),
        Track("a3", (40e3, 60e3, 6000.0), (-150.0, -150.0, 0.0), 0.0, duration),
    ]
    ds = make_dataset(np.random.default_rng(seed), radars, tracks, adsb=adsb,
                      adsb_sigma_m=ADSB_SIGMA, noise=noise)
    return ds, {s.id: b for s, b in radars}


def _polar_pymap3d(site, enu_origin: np.ndarray) -> np.ndarray:
    """(range, azimuth, elevation) of a point given in the ORIGIN's ENU frame, via pymap3d."""
    lat, lon, alt = pymap3d.enu2geodetic(*enu_origin, *ORIGIN)
    az, el, r = pymap3d.geodetic2aer(
        lat, lon, alt, np.rad2deg(site.lat_rad), np.rad2deg(site.lon_rad), site.alt_m
    )
    return np.array([r, np.deg2rad(az), np.deg2rad(el)])


def _measure(site, enu_origin: np.ndarray, beta: np.ndarray) -> np.ndarray:
    r, az, el = _polar_pymap3d(site, enu_origin)
    return np.array([(1 + beta[1]) * r + beta[0], az + beta[2], el + beta[3]])


def _fd(fun, x0: np.ndarray, step: np.ndarray) -> np.ndarray:
    cols = []
    for i in range(len(x0)):
        dx = np.zeros_like(x0)
        dx[i] = step[i]
        cols.append((fun(x0 + dx) - fun(x0 - dx)) / (2 * step[i]))
    return np.stack(cols, axis=-1)


def test_adsb_fisher_equals_plain_loop_of_finite_differences() -> None:
    ds, _ = _network(duration=40.0, noise=False)
    res = crlb(ds)
    adsb = ds.adsb
    fisher = np.zeros((len(res.labels), len(res.labels)))
    for rid, site in ds.sites.items():
        m = 3 if site.is_3d else 2
        cols = [i for i, (r_, _) in enumerate(res.labels) if r_ == rid]
        positions = [("range_offset", "range_gain", "azimuth_bias", "elevation_bias")
                     .index(res.labels[i][1]) for i in cols]
        for _, plot in ds.plots[ds.plots["radar_id"] == rid].iterrows():
            rep = adsb[adsb["target_id"] == plot["target_id"]].sort_values("time_s")
            e, n, u = pymap3d.geodetic2enu(rep["lat_deg"], rep["lon_deg"], rep["alt_m"], *ORIGIN)
            t = plot["time_s"]
            j = np.searchsorted(rep["time_s"].to_numpy(), t, side="right") - 1
            w = (t - rep["time_s"].iloc[j]) / (rep["time_s"].iloc[j + 1] - rep["time_s"].iloc[j])
            pts = np.stack([e, n, u], axis=1)
            x = (1 - w) * pts[j] + w * pts[j + 1]
            jb = _fd(lambda b, x=x, site=site: _measure(site, x, b), np.zeros(4),
                     np.array([1.0, 1e-6, 1e-6, 1e-6]))[:m, positions]
            jx = _fd(lambda y, site=site: _polar_pymap3d(site, y), x, np.full(3, 1.0))[:m]
            # ORIGIN's ENU and the ADS-B ENU frame differ by < 0.1 deg here: s^2 diag(1,1,2.25).
            c_adsb = ADSB_SIGMA**2 * ((1 - w) ** 2 + w**2) * np.diag([1.0, 1.0, 2.25])
            s = jx @ c_adsb @ jx.T + np.diag(site.measurement_sigmas()[:m] ** 2)
            fisher[np.ix_(cols, cols)] += jb.T @ np.linalg.solve(s, jb)
    scale = np.sqrt(np.outer(np.diag(fisher), np.diag(fisher)))
    assert np.max(np.abs(res.fisher - fisher) / scale) < 2e-3


def test_cross_fisher_equals_dense_elimination_loop() -> None:
    """Without ADS-B: the per-event Schur complement equals inverting the full dense
    Fisher matrix of (biases, every event's position and velocity), assembled plot by plot
    with finite-difference Jacobians."""
    ds, _ = _network(duration=40.0, adsb=False, noise=False)
    event_s = 12.0
    res = crlb(ds, event_s=event_s)
    p = len(res.labels)
    plots = ds.plots.copy()
    plots["event"] = list(zip(plots["target_id"], np.floor(plots["time_s"] / event_s),
                              strict=True))
    radars_per_event = plots.groupby("event")["radar_id"].nunique()
    events = [e for e in radars_per_event.index if radars_per_event[e] >= 2]
    assert res.info["n_events"] == len(events)
    dim = p + 6 * len(events)
    full = np.zeros((dim, dim))
    for k, ev in enumerate(events):
        rows = plots[plots["event"] == ev]
        t_mean = rows["time_s"].mean()
        for _, plot in rows.iterrows():
            site = ds.sites[plot["radar_id"]]
            # Position from the noise-free measured polar, via pymap3d.
            el = plot["elevation_deg"]
            if not site.is_3d:
                # A 2-D plot: place it at its reported height (pymap3d search on elevation).
                grid = np.linspace(-0.1, 0.6, 200001)
                e_, n_, u_ = pymap3d.aer2enu(plot["azimuth_deg"], np.rad2deg(grid),
                                             plot["range_m"])
                lat, lon, alt = pymap3d.enu2geodetic(
                    e_, n_, u_, np.rad2deg(site.lat_rad), np.rad2deg(site.lon_rad), site.alt_m)
                el = np.rad2deg(grid[np.argmin(np.abs(alt - plot["altitude_m"]))])
            lat, lon, alt = pymap3d.aer2geodetic(
                plot["azimuth_deg"], el, plot["range_m"],
                np.rad2deg(site.lat_rad), np.rad2deg(site.lon_rad), site.alt_m)
            x = np.array(pymap3d.geodetic2enu(lat, lon, alt, *ORIGIN), dtype=float)
            m = 3 if site.is_3d else 2
            cols = [i for i, (r_, _) in enumerate(res.labels) if r_ == site.id]
            positions = [("range_offset", "range_gain", "azimuth_bias", "elevation_bias")
                         .index(res.labels[i][1]) for i in cols]
            jb = _fd(lambda b, x=x, site=site: _measure(site, x, b), np.zeros(4),
                     np.array([1.0, 1e-6, 1e-6, 1e-6]))[:m, positions]
            jx = _fd(lambda y, site=site: _polar_pymap3d(site, y), x, np.full(3, 1.0))[:m]
            h = np.zeros((m, dim))
            h[:, cols] = jb
            dt = plot["time_s"] - t_mean
            h[:, p + 6 * k: p + 6 * k + 3] = jx
            h[:, p + 6 * k + 3: p + 6 * k + 6] = jx * dt
            weight = np.diag(site.measurement_sigmas()[:m] ** -2.0)
            full += h.T @ weight @ h
            if not site.is_3d:
                # Reported height measures the target's height (ORIGIN's up, < 0.5 deg off).
                hh = np.zeros(dim)
                hh[p + 6 * k + 2] = 1.0
                hh[p + 6 * k + 5] = dt
                full += np.outer(hh, hh) / 30.0**2
    expected = np.linalg.inv(np.linalg.inv(full)[:p, :p])
    scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
    assert np.max(np.abs(res.fisher - expected) / scale) < 0.02


def test_gauge_free_network_is_rank_deficient_not_a_crash() -> None:
    """Two co-located 3-D radars without ADS-B: a common azimuth bias (a rotation about
    the shared vertical) and a common range gain (a homothety about the shared antenna)
    map straight tracks onto straight tracks, so they are not observable; the others are
    (differences, and the common offset and elevation bias bend a straight track)."""
    a = site_at("A", 0.0, 0.0, sigma_elevation_mrad=2.0)
    b = site_at("B", 0.0, 0.0, sigma_elevation_mrad=2.0, sigma_range_m=20.0)
    tracks = [Track("t1", (-40e3, 50e3, 9000.0), (180.0, -20.0, 0.0), 0.0, 200.0),
              Track("t2", (30e3, -40e3, 7000.0), (-100.0, 150.0, 0.0), 0.0, 200.0)]
    ds = make_dataset(np.random.default_rng(0), [(a, RadarBias()), (b, RadarBias())], tracks,
                      adsb=False, noise=False)
    res = crlb(ds)
    assert len(res.labels) == 8
    assert res.rank == 6
    assert res.null_space.shape == (8, 2)
    for name in ("azimuth_bias", "range_gain"):
        common = np.array([float(n == name) for _, n in res.labels])
        d = np.sqrt(np.diag(res.fisher))
        assert np.linalg.norm(res.fisher @ common / d) < 1e-6 * np.linalg.norm(d * common)
    assert ("A", "azimuth_bias") in res.undetermined and ("B", "range_gain") in res.undetermined
    assert res.sigma("A", "azimuth_bias_mrad") == np.inf
    assert np.all(np.isfinite(res.covariance))
    # The graph's weak priors make it full rank.
    with_priors = crlb(ds, priors="graph")
    assert with_priors.rank == 8 and not with_priors.undetermined


# --------------------------------------------------------------------------- against the graph
def test_graph_monte_carlo_rmse_reaches_the_crlb() -> None:
    """The acceptance test: graph's RMSE over seeds is the CRLB.

    200 seeds (0.04 s each, robust="none": the bound is for the Gaussian model; Huber
    gives the same within noise, mean ratio 1.02).  The relative sd of one parameter's
    RMSE over N seeds is ~1/sqrt(2N) = 5 %, so each parameter within 20 % is a 4-sigma
    band; the mean over the 9 parameters (7 biases and 2 time offsets; correlated,
    sd <= 5 %) within 10 %.
    """
    errors, bounds = [], []
    labels = None
    for seed in range(200):
        ds, truth = _network(seed, time_offsets_s=(0.8, -1.2))
        cal = graph(ds, robust="none", time_offset=True)
        res = crlb(ds, time_offset=True)
        assert res.labels == cal.labels
        labels = cal.labels
        errors.append([cal.estimate[i] - truth[rid].value(name)
                       for i, (rid, name) in enumerate(labels)])
        bounds.append(np.diag(res.covariance))
    ratio = np.sqrt(np.mean(np.square(errors), axis=0) / np.mean(bounds, axis=0))
    assert abs(np.mean(ratio) - 1.0) < 0.10, ratio
    assert np.all((ratio > 0.80) & (ratio < 1.20)), ratio


def test_graph_reported_sigma_is_efficient_with_adsb() -> None:
    ds, _ = _network(5)
    cal = graph(ds)
    res = crlb(ds)
    eff = res.efficiency(cal)
    assert len(eff) == 7
    assert all(0.9 <= v <= 1.2 for v in eff.values()), eff
    # The graph's weak priors barely move the bound with ADS-B.
    with_priors = crlb(ds, priors="graph")
    assert np.allclose(np.diag(with_priors.covariance), np.diag(res.covariance), rtol=1e-3)


def test_cross_radar_bound_and_graph_without_adsb() -> None:
    """Without ADS-B the bound is finite here (two radars apart, one 3-D) and the
    graph's pairwise sigma is close to it."""
    ds, _ = _network(7, adsb=False)
    res = crlb(ds, use_adsb=False)
    assert res.rank == len(res.labels) == 7 and res.info["n_events"] > 50
    cal = graph(ds, use_adsb=False)
    eff = res.efficiency(cal)
    assert all(0.8 <= v <= 1.5 for v in eff.values()), eff
