"""What each window carries for the fit verdict (graphcal.solvers.window_fit): the model
checks' normalised residual sums against ADS-B, from the window's own fit, cheaply."""

from __future__ import annotations

import tomllib
from dataclasses import replace

import numpy as np
import pytest

from graphcal.analysis.model_checks import calibrated_residuals, normalised_sums
from graphcal.data.windows import split_windows
from graphcal.model.problem import build_problem
from graphcal.simulation.scenario import parse_scenario
from graphcal.simulation.simulate import simulate
from graphcal.solvers.graph import graph
from graphcal.solvers.window_fit import FIRST_ORDER_MAX_S, NEGLIGIBLE_TIME_OFFSET_S, window_fit
from graphcal.solvers.windows import WindowOptions, summarise_window
from tests.paths import SCENARIOS


@pytest.fixture(scope="module")
def window():
    """The demo network's first 15 minutes, NORD's clock 0.8 s late (aligned again), SUD's
    60 ms (the reference moved to first order)."""
    with open(SCENARIOS / "demo_network.toml", "rb") as f:
        doc = tomllib.load(f)
    doc["radar"][0]["bias"]["time_offset_s"] = 0.8
    doc["radar"][1]["bias"]["time_offset_s"] = 0.06
    sim = simulate(parse_scenario(doc), np.random.default_rng(3))
    return next(iter(split_windows(sim.dataset, 900.0)))


def test_the_sums_are_the_model_checks_sums(window) -> None:
    """Against the model checks' residuals (ADS-B aligned again at each radar's estimated
    time offset): the same counts and chi2/dof within 0.5 % (2 % for SUD, whose reference
    is moved to first order); NORD's 0.8 s, left out, would misfit."""
    dataset = window.dataset
    problem = build_problem(dataset)
    cal = graph(problem, time_offset=None)
    fit = window_fit(problem, cal, use_adsb=True, max_gap_s=WindowOptions().adsb_max_gap_s)
    assert cal.value("NORD", "time_offset_s") == pytest.approx(0.8, abs=0.02)
    assert FIRST_ORDER_MAX_S > cal.value("SUD", "time_offset_s") > NEGLIGIBLE_TIME_OFFSET_S
    reference, residuals, _ = calibrated_residuals(dataset, cal)
    assert fit.reference == reference == "adsb"
    assert set(fit.sums) == set(residuals) == set(cal.radar_ids)
    for rid, res in residuals.items():
        expected = normalised_sums(res)
        assert set(fit.sums[rid]) == set(expected) - {"altitude"}
        for coordinate, (chi2, n) in fit.sums[rid].items():
            assert abs(n - expected[coordinate][1]) <= 0.002 * n, (rid, coordinate)
            # moved to first order: the ADS-B rate's noise, up to 2 % (FIRST_ORDER_MAX_S)
            tolerance = 2e-2 if rid == "SUD" else 5e-3
            assert chi2 / n == pytest.approx(expected[coordinate][0] / expected[coordinate][1],
                                             rel=tolerance), (rid, coordinate)
            assert 0.85 < chi2 / n < 1.15
        assert fit.n_terms[rid] == sum(1 for r, _ in cal.labels if r == rid)
        assert fit.range_gain[rid] == cal.value(rid, "range_gain")
        assert fit.negative_ranges[rid] == 0
    # Without moving the reference by the time offset, NORD would misfit.
    late = replace(cal.bias("NORD"), time_offset_s=0.0)
    _, unmoved, _ = calibrated_residuals(dataset, {"NORD": late})
    chi2, n = normalised_sums(unmoved["NORD"])["range"]
    assert chi2 / n > 5.0


def test_the_summary_carries_its_window_fit(window) -> None:
    summary = summarise_window(window)
    problem = build_problem(window.dataset)
    cal = graph(problem, time_offset=None)
    fit = window_fit(problem, cal, use_adsb=True, max_gap_s=WindowOptions().adsb_max_gap_s)
    assert summary.fit == fit  # the same fit, plain numbers
    assert summarise_window(window, judge=False).fit is None
    # Without ADS-B: the plots on the window's paths.  The time offsets are not estimated,
    # so NORD's 0.8 s (200 m along track) shows, beyond the verdict's floor of 4, and
    # bends the paths the others are judged on less; with the pairs, no residuals.
    on_paths = summarise_window(window, WindowOptions(use_adsb=False)).fit
    assert on_paths.reference == "paths"
    ratios = {(rid, c): chi2 / dof for rid, by in on_paths.sums.items()
              for c, (chi2, dof) in by.items() if c != "altitude"}
    worst = max(ratios, key=ratios.get)
    assert worst == ("NORD", "range") and ratios[worst] > 4.0
    assert max(r for (rid, _), r in ratios.items() if rid != "NORD") < 0.5 * ratios[worst]
    pairs = WindowOptions(use_adsb=False, cross="pairwise")
    assert summarise_window(window, pairs).fit.reference == "none"


def test_negative_ranges_and_the_gain_are_counted_without_residuals(window) -> None:
    """Ranges in km: the window's own fit is a gain of -0.999; no plot goes negative."""
    plots = window.dataset.plots.copy()
    sud = plots["radar_id"] == "SUD"
    plots.loc[sud, "range_m"] *= 1e-3
    dataset = replace(window.dataset, plots=plots)
    problem = build_problem(dataset)
    cal = graph(problem, time_offset=None)
    fit = window_fit(problem, cal, use_adsb=False, max_gap_s=10.0)
    assert fit.reference == "none" and fit.sums == {}
    assert fit.range_gain["SUD"] == pytest.approx(-0.999, abs=1e-3)
