"""The fit verdict: residuals far beyond their sigmas fail, the scenarios pass."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

import graphcal
from graphcal.analysis.fit_verdict import (
    FLOOR,
    MAX_RANGE_GAIN,
    ModelMisfitError,
    chi2_limit,
    verdict_from_sums,
    windows_verdict,
)
from graphcal.core.errors import EstimationError
from graphcal.solvers.window_fit import WindowFit
from tests.paths import SCENARIOS


@pytest.mark.parametrize("dof", [1, 3, 10, 50, 1000, 100_000])
def test_limit_is_the_one_in_a_million_quantile_or_the_floor(dof: int) -> None:
    quantile = stats.chi2.isf(1e-6, dof) / dof
    assert chi2_limit(dof) == pytest.approx(max(FLOOR, quantile), rel=1e-9)
    # a correct model exceeds the limit with probability at most 1e-6
    assert stats.chi2.sf(chi2_limit(dof) * dof, dof) <= 1e-6 * (1 + 1e-9)


@pytest.fixture(scope="module")
def demo() -> graphcal.Dataset:
    return graphcal.simulate(SCENARIOS / "demo_network.toml", seed=2).dataset


def _scaled(ds, radar: str, column: str, scale: float):
    plots = ds.plots.copy()
    rows = plots["radar_id"] == radar
    plots.loc[rows, column] = plots.loc[rows, column] * scale
    return replace(ds, plots=plots)


def test_verdict_from_sums_counts_dof_and_ignores_altitude(demo) -> None:
    cal = graphcal.calibrate(demo, "fl-ls", model_checks=False)
    k = sum(1 for rid, _ in cal.labels if rid == "NORD")
    sums = {"NORD": {"range": (5.0 * (1000 - k), 1000), "azimuth": (900.0, 1000),
                     "altitude": (1e9, 1000)}}
    verdict = verdict_from_sums(cal, "adsb", sums)
    assert verdict.failed == ["NORD"]
    [range_fit, azimuth_fit] = verdict.radars["NORD"].coordinates
    assert range_fit.ratio == pytest.approx(5.0) and range_fit.failed
    assert azimuth_fit.ratio == pytest.approx(900.0 / (1000 - k)) and not azimuth_fit.failed
    assert "NORD: range chi2/dof 5" in verdict.message()


@pytest.mark.parametrize("method", ["graph", "fl-ls", "wls"])
def test_a_correct_dataset_passes(demo, method: str) -> None:
    cal = graphcal.calibrate(demo, method)
    verdict = cal.info["fit_verdict"]
    assert verdict["passed"] and verdict["reference"] == "adsb"
    ratios = [c["chi2_per_dof"] for r in verdict["radars"].values()
              for c in r["coordinates"].values()]
    assert len(ratios) >= 10 and max(ratios) < 1.3


@pytest.mark.parametrize(("method", "use_adsb"), [("graph", True), ("wls", False)])
def test_azimuth_in_radians_fails_naming_the_radar(demo, method: str, use_adsb: bool) -> None:
    broken = _scaled(demo, "NORD", "azimuth_deg", math.pi / 180)
    if not use_adsb:
        broken = replace(broken, adsb=None)
    with pytest.raises(ModelMisfitError) as info:
        graphcal.calibrate(broken, method, model_checks=use_adsb)
    verdict = info.value.verdict
    assert verdict.reference == ("adsb" if use_adsb else "cross")
    assert verdict.failed[0] == "NORD"
    assert isinstance(info.value, EstimationError)
    assert "): NORD: " in str(info.value)
    if use_adsb:  # against ADS-B only the broken radar fails
        assert verdict.failed == ["NORD"]
    assert info.value.calibration.info["fit_verdict"]["failed"] == verdict.failed


def test_range_in_km_fails_on_its_gain(demo) -> None:
    broken = _scaled(demo, "SUD", "range_m", 1e-3)
    with pytest.raises(ModelMisfitError) as info:
        graphcal.calibrate(broken, "graph")
    fit = info.value.verdict.radars["SUD"]
    assert fit.range_gain == pytest.approx(-0.999, abs=1e-4)  # exactly a gain: fits well
    assert fit.gain_implausible and abs(fit.range_gain) > MAX_RANGE_GAIN
    assert info.value.verdict.failed == ["SUD"]


def test_check_fit_off_records_the_verdict_as_a_warning(demo) -> None:
    broken = _scaled(demo, "NORD", "azimuth_deg", math.pi / 180)
    cal = graphcal.calibrate(broken, "fl-ls", check_fit=False, model_checks=False)
    assert cal.info["fit_verdict"]["failed"] == ["NORD"]
    assert any("far beyond their sigmas" in w for w in cal.warnings)
    assert np.isfinite(cal.value("NORD", "azimuth_bias_mrad"))


# --------------------------------------------------------------------------- over windows
def _window_fit(chi2_per_dof: dict[str, float], n: int = 1000, gain: float = 1e-4,
                reference: str = "adsb") -> WindowFit:
    """Fit numbers of a window: each radar's range and azimuth at ``chi2_per_dof`` over
    ``n - 3`` dof (3 terms)."""
    return WindowFit(
        reference,
        sums={rid: {"range": (ratio * (n - 3), n), "azimuth": ((n - 3) * 1.0, n),
                    "altitude": (1e9, n)} for rid, ratio in chi2_per_dof.items()}
        if reference == "adsb" else {},
        n_terms={rid: 3 for rid in chi2_per_dof},
        range_gain={rid: gain for rid in chi2_per_dof},
        negative_ranges={rid: 0 for rid in chi2_per_dof})


def test_over_windows_a_radar_fails_in_the_windows_where_it_fails() -> None:
    windows = [(0.0, 900.0, _window_fit({"A": 1.0, "B": 1.1})),
               (1800.0, 2700.0, _window_fit({"A": 900.0, "B": 1.2})),
               (900.0, 1800.0, _window_fit({"A": 5.0, "B": 3.9}))]
    verdict = windows_verdict(windows)
    assert verdict.failed == ["A"] and verdict.reference == "adsb"
    # the windows in time order, A's worst one as its entry
    assert [w.t_start_s for w in verdict.windows] == [0.0, 900.0, 1800.0]
    assert [w.span for w in verdict.failed_windows("A")] == ["900-1800 s", "1800-2700 s"]
    assert verdict.radars["A"].worst == pytest.approx(900.0)
    assert verdict.radars["B"].worst == pytest.approx(3.9) and not verdict.radars["B"].failed
    text = verdict.message()
    assert "A: in 2 of 3 windows (900-1800 s, 1800-2700 s); worst: range chi2/dof 900" in text
    assert "B:" not in text
    document = verdict.to_dict()
    assert document["failed"] == ["A"] and not document["passed"]
    assert document["radars"]["A"]["window"] == [1800.0, 2700.0]
    assert document["radars"]["A"]["failed_windows"] == [[900.0, 1800.0], [1800.0, 2700.0]]
    assert document["radars"]["B"]["failed_windows"] == []
    assert [w["failed"] for w in document["windows"]] == [[], ["A"], ["A"]]
    assert "altitude" not in document["radars"]["A"]["coordinates"]


def test_over_windows_the_gain_is_judged_without_residuals() -> None:
    """Windows without ADS-B carry no residuals: a range gain of -0.999 (ranges in km)
    still fails, a plausible one passes with reference "none"."""
    km = windows_verdict([(0.0, 600.0, _window_fit({"A": 1.0}, gain=-0.999, reference="none"))])
    assert km.failed == ["A"] and km.reference == "none"
    assert "range gain -0.999" in km.message()
    fine = windows_verdict([(0.0, 600.0, _window_fit({"A": 1.0}, reference="none"))])
    assert fine.passed and fine.radars["A"].coordinates == []


def test_over_windows_few_residuals_get_the_quantile_limit() -> None:
    """A window with 13 residuals (10 dof) of a radar: its limit is the 1e-6 quantile."""
    verdict = windows_verdict([(0.0, 600.0, _window_fit({"A": 4.5}, n=13))])
    [range_fit, _] = verdict.radars["A"].coordinates
    assert range_fit.dof == 10 and range_fit.limit == pytest.approx(chi2_limit(10))
    assert chi2_limit(10) > 4.5 and verdict.passed


@pytest.fixture(scope="module")
def v2_without_adsb() -> graphcal.Calibration:
    """The version-2 demo (refraction, pressure altitudes, an eccentric antenna),
    calibrated without ADS-B by the default formulation."""
    ds = graphcal.simulate(SCENARIOS / "demo_v2.toml", seed=3).dataset
    return graphcal.calibrate(ds, use_adsb=False, model_checks=False)


def test_without_adsb_the_plots_are_judged_on_their_paths(v2_without_adsb) -> None:
    """A correct model with the stated noise has ``E[chi2] = dof``: each coordinate's
    ``chi2 / dof`` on the paths is within its chance spread of 1 (sd below 0.02 at its
    5,000-22,000 dof; 0.1 leaves room for the capped path misfits), once the paths'
    share of the degrees of freedom is counted (without it the 2-D radars' ranges,
    whose plots shape the paths most, would show 0.75-0.8), and no sigma is widened."""
    cal = v2_without_adsb
    verdict = cal.info["fit_verdict"]
    assert verdict["passed"] and verdict["reference"] == "paths"
    ratios = {(rid, c): e["chi2_per_dof"] for rid, r in verdict["radars"].items()
              for c, e in r["coordinates"].items()}
    assert len(ratios) == 12  # five radars' range and azimuth, two elevations
    assert all(0.9 < r < 1.1 for r in ratios.values()), ratios
    fit = cal.info["target_state"]["fit"]
    naive = min(e["chi2"] / e["n"] for by in fit.values() for c, e in by.items()
                if c == "range")
    assert naive < 0.85
    assert not cal.info.get("sigma_inflation")


def test_azimuth_in_radians_without_adsb_fails_on_the_paths(demo) -> None:
    broken = replace(_scaled(demo, "NORD", "azimuth_deg", math.pi / 180), adsb=None)
    with pytest.raises(ModelMisfitError) as info:
        graphcal.calibrate(broken, "graph", model_checks=False)
    verdict = info.value.verdict
    assert verdict.reference == "paths"
    assert verdict.failed[0] == "NORD"
    assert "judged on the aircraft's paths" in str(info.value)


def test_windows_without_adsb_are_judged_on_their_paths(demo) -> None:
    """``--window`` without ADS-B: every window's plots are judged on its paths; a correct
    dataset passes within the chance spread of 1, NORD's azimuths in radians fail in
    every window (before, such windows were judged on range gains alone)."""
    no_adsb = replace(demo, adsb=None)
    cal = graphcal.calibrate(no_adsb, window=900.0, model_checks=False)
    verdict = cal.info["fit_verdict"]
    assert verdict["passed"] and verdict["reference"] == "paths"
    assert {w["reference"] for w in verdict["windows"]} == {"paths"}
    ratios = [c["chi2_per_dof"] for r in verdict["radars"].values()
              for c in r["coordinates"].values()]
    assert len(ratios) == 12 and all(0.9 < r < 1.1 for r in ratios)
    broken = replace(_scaled(demo, "NORD", "azimuth_deg", math.pi / 180), adsb=None)
    with pytest.raises(ModelMisfitError) as info:
        graphcal.calibrate(broken, window=900.0, model_checks=False)
    assert info.value.verdict.failed[0] == "NORD"
    assert "NORD: in 2 of 2 windows" in str(info.value)
