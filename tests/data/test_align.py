"""Association and time alignment (paper 003 eq. 6-7 corrected)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from graphcal.data.align import (
    align_adsb,
    bracket,
    overlapping_pairs,
    pair_max_gap_s,
    pair_plots,
    quadratic_third,
)
from graphcal.data.bias import RadarBias
from tests.synthetic import Track, make_dataset, site_at


def test_bracket_interpolates_between_the_right_samples() -> None:
    """x = x_j + v (t - t_j): the weight is measured from the earlier sample."""
    t = np.array([0.0, 1.0, 2.0, 10.0])
    j, w, ok = bracket(t, np.array([0.25, 1.5, 2.0, 6.0, -1.0, 11.0]), max_gap_s=5.0)
    assert list(j[:3]) == [0, 1, 2] or list(j[:3]) == [0, 1, 1]
    assert w[0] == pytest.approx(0.25)
    assert w[1] == pytest.approx(0.5)
    assert list(ok) == [True, True, True, False, False, False]  # 2->10 gap is 8 s > 5 s


def test_paper003_eq6_misprint_is_corrected() -> None:
    """Interpolating a constant-velocity ADS-B track is exact at the plot time.

    The printed eq. 6 uses (t_{j+1} - t_R), which would place the point
    mirrored inside the interval; the test would then miss by up to v * dt.
    """
    rng = np.random.default_rng(0)
    site = site_at("A", 0, 0)
    track = Track("abc123", (30e3, 40e3, 9e3), (220.0, -130.0, 5.0), 0.0, 300.0)
    ds = make_dataset(rng, [(site, RadarBias())], [track], noise=False)
    al = align_adsb(ds, "A")
    assert len(al) > 50
    r, az, _ = site.polar_from_ecef(al.reference_ecef_m)
    # Noise-free plots with zero bias are the truth itself.
    assert np.max(np.abs(r - al.plots.range_m)) < 0.05
    assert np.max(np.abs(az - al.plots.azimuth_rad)) < 1e-6


def test_adsb_gaps_longer_than_the_limit_are_not_bridged() -> None:
    rng = np.random.default_rng(1)
    site = site_at("A", 0, 0)
    track = Track("abc123", (30e3, 40e3, 9e3), (220.0, -130.0, 0.0), 0.0, 400.0)
    ds = make_dataset(rng, [(site, RadarBias())], [track], noise=False)
    adsb = ds.adsb
    ds.adsb = adsb[(adsb["time_s"] < 100) | (adsb["time_s"] > 160)].reset_index(drop=True)
    al = align_adsb(ds, "A", max_gap_s=10.0)
    assert not np.any((al.plots.time_s > 100) & (al.plots.time_s < 160))
    assert al.n_unmatched == pytest.approx(60 / 4, abs=2)
    al_wide = align_adsb(ds, "A", max_gap_s=100.0)
    assert len(al_wide) == len(ds.plots)


def test_plots_without_matching_adsb_identity_are_unmatched() -> None:
    rng = np.random.default_rng(2)
    site = site_at("A", 0, 0)
    tracks = [
        Track("aaaaaa", (30e3, 40e3, 9e3), (200.0, 0.0, 0.0), 0.0, 200.0),
        Track("bbbbbb", (-30e3, 40e3, 9e3), (0.0, 200.0, 0.0), 0.0, 200.0),
    ]
    ds = make_dataset(rng, [(site, RadarBias())], tracks)
    ds.adsb = ds.adsb[ds.adsb["target_id"] == "aaaaaa"]
    al = align_adsb(ds, "A")
    assert set(al.plots.target_id) == {"aaaaaa"}
    assert al.n_unmatched == int((ds.plots["target_id"] == "bbbbbb").sum())


def test_cross_radar_pairs_match_target_and_time() -> None:
    """Each pair brackets the other radar's plot time, same target, weight in [0, 1]."""
    rng = np.random.default_rng(3)
    a, b = site_at("A", 0, 0), site_at("B", 100e3, 0, scan_period_s=5.0)
    tracks = [
        Track("aaaaaa", (30e3, 40e3, 9e3), (200.0, 0.0, 0.0), 0.0, 300.0),
        Track("bbbbbb", (60e3, -40e3, 9e3), (0.0, 200.0, 0.0), 50.0, 300.0),
    ]
    ds = make_dataset(rng, [(a, RadarBias()), (b, RadarBias())], tracks, adsb=False)
    ds.plots.loc[ds.plots.index[:5], "target_id"] = ""  # unknown identity: never paired
    pairs = pair_plots(ds, "A", "B")
    assert len(pairs) > 100
    ta = pairs.a_plots.time_s
    tb = pairs.b_plots.time_s[pairs.b_index]
    assert np.all(ta[pairs.a_index0] <= tb) and np.all(tb <= ta[pairs.a_index0 + 1])
    same = pairs.a_plots.target_id[pairs.a_index0] == pairs.b_plots.target_id[pairs.b_index]
    assert np.all(same)
    next_target = pairs.a_plots.target_id[pairs.a_index0 + 1]
    assert np.all(next_target == pairs.a_plots.target_id[pairs.a_index0])
    assert np.all((pairs.weight >= 0) & (pairs.weight <= 1))
    assert not np.any(pairs.b_plots.target_id[pairs.b_index] == "")
    assert isinstance(ds.plots, pd.DataFrame)


def test_quadratic_third_reproduces_a_parabola_and_picks_the_nearer_side() -> None:
    """Lagrange weights through three samples reproduce any quadratic of time exactly; the
    third sample is on the side nearer the query, and without one the weights are linear."""
    from graphcal.data.align import quadratic_third

    t = np.array([0.0, 4.0, 8.5, 12.0, 16.5, 40.0])
    value = 3.0 - 2.0 * t + 0.7 * t**2
    query = np.array([1.0, 7.0, 9.0, 15.0, 0.0])
    j, w, ok = bracket(t, query, max_gap_s=10.0)
    assert ok.all()
    third, weights = quadratic_third(t, query, j, w, max_gap_s=10.0)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0)
    # 1 s: no sample before 0 s, so 8.5 s; 7 s: 12 s (nearer than 0 s); 9 s: 4 s (nearer
    # than 16.5 s); 15 s: 8.5 s (40 s is beyond the gap limit).
    assert third.tolist() == [2, 3, 1, 2, 2]
    estimate = (weights[:, 0] * value[j] + weights[:, 1] * value[j + 1]
                + weights[:, 2] * value[np.maximum(third, 0)])
    np.testing.assert_allclose(estimate, 3.0 - 2.0 * query + 0.7 * query**2, rtol=1e-12)
    # At a sample the weights select it alone.
    np.testing.assert_allclose(weights[4], [1.0, 0.0, 0.0], atol=1e-12)
    # With a 3 s limit neither 8.5 s (3.5 s before 12 s) nor 40 s qualifies: linear.
    j, w, _ = bracket(t, np.array([14.0]), max_gap_s=10.0)
    third, weights = quadratic_third(t, np.array([14.0]), j, w, max_gap_s=3.0)
    assert third.tolist() == [-1]
    np.testing.assert_allclose(weights[0], [1.0 - w[0], w[0], 0.0])


def test_cross_radar_pairs_carry_the_quadratic_third_plot() -> None:
    from graphcal.data.align import quadratic_third

    rng = np.random.default_rng(8)
    a, b = site_at("A", -30e3, 0.0), site_at("B", 30e3, 0.0, scan_period_s=5.0)
    ds = make_dataset(rng, [(a, RadarBias()), (b, RadarBias())],
                      [Track("ab0001", (0.0, 40e3, 8000.0), (180.0, 30.0, 0.0), 0.0, 300.0)])
    pairs = pair_plots(ds, "A", "B")
    assert pairs.a_index2 is not None and pairs.quadratic_weights is not None
    assert len(pairs) > 40 and np.all(pairs.a_index2 >= 0)
    np.testing.assert_allclose(pairs.quadratic_weights.sum(axis=1), 1.0)
    query = pairs.b_plots.time_s[pairs.b_index]
    third, weights = quadratic_third(pairs.a_plots.time_s, query, pairs.a_index0, pairs.weight,
                                     pair_max_gap_s(a))
    np.testing.assert_array_equal(third, pairs.a_index2)
    np.testing.assert_allclose(weights, pairs.quadratic_weights)


def test_blocked_bracketing_equals_bracketing_each_track_alone() -> None:
    """One search over all tracks gives bracket()'s answer on each track alone, including
    repeated times, one-sample tracks, queries on samples and outside the tracks."""
    from graphcal.data.align import bracket_in_blocks, quadratic_third_in_blocks

    rng = np.random.default_rng(3)
    tracks = [np.sort(np.round(rng.uniform(0, 100, size), 0)) for size in (1, 2, 5, 40, 3)]
    tracks.append(np.array([5.0, 5.0, 6.0, 30.0]))
    time_s = np.concatenate(tracks)
    start = np.cumsum([0] + [len(t) for t in tracks])
    block = np.repeat(np.arange(len(tracks)), [len(t) for t in tracks])
    code = rng.integers(0, len(tracks), 500)
    query = np.round(rng.uniform(-10, 110, 500), 1)
    on = rng.integers(0, len(time_s), 50)
    query[:50] = time_s[on]  # on a sample of the query's own track
    code[:50] = block[on]
    lo, hi = start[code], start[code + 1]
    j, w, ok = bracket_in_blocks(time_s, block + 1j * time_s, code, lo, hi, query, 12.0)
    third, weights = quadratic_third_in_blocks(time_s, query[ok], j[ok], w[ok], lo[ok], hi[ok],
                                               12.0)
    k = 0
    for i in range(len(query)):
        track = tracks[code[i]]
        with np.errstate(divide="ignore", invalid="ignore"):  # repeated times
            jj, ww, good = bracket(track, query[i : i + 1], 12.0)
        assert ok[i] == good[0]
        if good[0]:
            assert j[i] - lo[i] == jj[0] and w[i] == ww[0]
            t3, w3 = quadratic_third(track, query[i : i + 1], jj, ww, 12.0)
            assert (third[k] - lo[i] if third[k] >= 0 else -1) == t3[0]
            np.testing.assert_array_equal(weights[k], w3[0])
            k += 1
    assert 0 < ok.sum() < len(query)


def test_only_radars_that_saw_a_common_aircraft_are_paired() -> None:
    """Four radars: A and B share an aircraft, C and A another, D's aircraft is its own,
    and a thousand more radars have no plot at all.  The pairs are (A, B) and (A, C),
    each oriented by pairing_order (scan period, then id; here no periods: by id),
    whatever the order of the radar list; unlabelled plots pair nothing."""
    from dataclasses import replace

    plots = pd.DataFrame({
        "radar_id": ["A", "B", "A", "C", "D", "B", "C"],
        "time_s": [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
        "range_m": 1e4, "azimuth_deg": 10.0, "elevation_deg": np.nan,
        "target_id": ["x", "x", "y", "y", "z", "", ""],
    })
    rng = np.random.default_rng(0)
    track = Track("4ca001", (1e4, 0.0, 9e3), (200.0, 0.0, 0.0), 0.0, 60.0)
    base = make_dataset(rng, [(site_at("A", 0.0, 0.0), RadarBias(0.0, 0.0, 0.0))], [track])
    sites = {rid: site_at(rid, 0.0, 0.0)
             for rid in ["A", "B", "C", "D", *(f"R{i:04d}" for i in range(1000))]}
    dataset = replace(base, plots=plots, sites=sites)
    order = ["D", "C", "B", "A", *(f"R{i:04d}" for i in range(1000))]
    assert overlapping_pairs(dataset, order) == [("A", "B"), ("A", "C")]
    assert overlapping_pairs(dataset, order[::-1]) == [("A", "B"), ("A", "C")]
    # A shorter scan period goes first (its track is the one interpolated).
    fast = {**sites, "C": replace(sites["C"], scan_period_s=4.0),
            "A": replace(sites["A"], scan_period_s=10.0),
            "B": replace(sites["B"], scan_period_s=12.0)}
    assert overlapping_pairs(replace(dataset, sites=fast), order) == [("C", "A"), ("A", "B")]
    assert overlapping_pairs(replace(dataset, plots=plots.iloc[:0])) == []


def test_thinned_alignment_equals_aligning_the_thinned_plots_afresh() -> None:
    from dataclasses import fields, replace

    from graphcal.data.align import align_adsb_thinned
    from graphcal.model.problem import build_problem

    rng = np.random.default_rng(5)
    site = site_at("A", 0, 0)
    tracks = [
        Track("aaaaaa", (30e3, 40e3, 9e3), (200.0, 0.0, 0.0), 0.0, 300.0),
        Track("bbbbbb", (-30e3, 40e3, 9e3), (0.0, 200.0, 0.0), 0.0, 300.0),
        Track("cccccc", (10e3, -50e3, 7e3), (-150.0, 100.0, 0.0), 0.0, 300.0),
    ]
    ds = make_dataset(rng, [(site, RadarBias()), (site_at("B", 20e3, 0), RadarBias())], tracks)
    ds.adsb = ds.adsb[ds.adsb["target_id"] != "cccccc"]  # some plots stay unmatched
    ds.plots.index = 1000 + 3 * np.arange(len(ds.plots))  # labels that are not positions
    keep = rng.uniform(size=len(ds.plots)) < 0.4
    thinned = replace(ds, plots=ds.plots.loc[keep].reset_index(drop=True))
    problem = build_problem(ds)
    for rid in ("A", "B"):
        full = problem.alignment(rid)
        cut = align_adsb_thinned(full, ds, keep, problem.plots(rid))
        afresh = align_adsb(thinned, rid)
        assert 0 < len(cut) < len(full)
        assert cut.n_unmatched == afresh.n_unmatched > 0
        # The thinned problem holds the cut alignment, not one aligned again.
        held = problem.thinned(keep).alignment(rid)
        for one in (cut, held):
            for field in fields(afresh.plots):
                np.testing.assert_array_equal(getattr(one.plots, field.name),
                                              getattr(afresh.plots, field.name))
            for field in fields(afresh):
                if field.name not in ("plots", "derived"):
                    np.testing.assert_array_equal(getattr(one, field.name),
                                                  getattr(afresh, field.name),
                                                  err_msg=field.name)
