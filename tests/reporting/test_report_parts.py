"""Parts of the HTML report: display units, binning, robust limits, the header, the
|z| > 3 flags, the correlation table, radar-versus-radar residuals and the km map."""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np
import pytest

import graphcal
from graphcal.data.bias import RadarBias
from graphcal.data.correct import correct_dataset
from graphcal.reporting.display import clock_text, decimals_for, value_text
from graphcal.reporting.html import build_report, correlation_table
from graphcal.reporting.report_figures import before_after_figure, map_figure
from graphcal.reporting.report_residuals import (
    binned,
    pair_summaries,
    residual_views,
    robust_limits,
)
from graphcal.solvers.registry import METHODS
from tests.reporting.test_report import BIASES, TRACKS
from tests.synthetic import make_dataset, site_at


@pytest.fixture(scope="module")
def scenario():
    sites = [site_at("RA", -20e3, 0.0), site_at("RB", 30e3, 5e3, sigma_elevation_mrad=2.0)]
    dataset = make_dataset(np.random.default_rng(3), [(s, BIASES[s.id]) for s in sites], TRACKS)
    return dataset, METHODS["graph"](dataset)


def _section(page: str, sid: str) -> str:
    return page.split(f'<h2 id="{sid}">')[1].split("<h2 id=")[0]


# -------------------------------------------------------------------- display
def test_decimals_give_two_significant_digits_of_sigma() -> None:
    assert decimals_for(0.0153) == 3  # 0.015
    assert decimals_for(1.2) == 1
    assert decimals_for(26.0) == 0
    assert decimals_for(3400.0) == 0
    assert value_text(-0.0004, 2) == "0.00"  # no negative zero
    assert value_text(21000.0, 0) == "21\u2009000"


def test_clock_text_reads_time_s_from_midnight_utc() -> None:
    assert clock_text(0.0) == "00:00:00"
    assert clock_text(3 * 3600 + 25 * 60 + 7.4) == "03:25:07"
    assert clock_text(86400 + 60) == "00:01:00 +1d"


# -------------------------------------------------------------------- binning
def test_binned_means_and_spreads_match_a_direct_computation() -> None:
    rng = np.random.default_rng(7)
    x = rng.uniform(0.0, 100.0, 6000)
    y = np.where(x < 50.0, 2.0, -1.0) + rng.normal(0.0, 0.5, x.size)
    b = binned(x, y, np.full(x.size, 0.5), n_bins=10)
    assert len(b.centre) == 10
    assert np.all(np.abs(b.count - 600) <= 1)  # equal counts
    edges = np.quantile(x, np.linspace(0, 1, 11))
    for k in range(10):
        inside = (x >= edges[k]) & ((x < edges[k + 1]) if k < 9 else (x <= edges[k + 1]))
        assert b.mean[k] == pytest.approx(np.mean(y[inside]), abs=1e-9)
        assert b.sd[k] == pytest.approx(np.std(y[inside]), abs=1e-9)
    assert np.allclose(b.expected, 0.5)
    # Equal widths (azimuth): 30 deg bins over 0-360.
    az = rng.uniform(0.0, 360.0, 3600)
    w = binned(az, np.sin(np.deg2rad(az)), width=30.0, span=(0.0, 360.0))
    assert len(w.centre) == 12
    assert np.allclose(w.mean, np.sin(np.deg2rad(w.centre)), atol=0.05)


def test_robust_limits_clip_the_tails_and_count_them() -> None:
    rng = np.random.default_rng(1)
    values = np.concatenate([rng.normal(0.0, 1.0, 10_000), [1e4, -1e4, 5e3]])
    lo, hi, outside = robust_limits(values)
    p1, p99 = np.percentile(values, [1, 99])
    assert lo == pytest.approx(p1 - 0.1 * (p99 - p1))
    assert hi == pytest.approx(p99 + 0.1 * (p99 - p1))
    assert outside == int(np.sum((values < lo) | (values > hi)))
    assert 3 <= outside < 200  # the three wild values and a few tail points


# -------------------------------------------------------------------- header
def test_header_names_version_command_dataset_and_utc_span(scenario, tmp_path) -> None:
    dataset, cal = scenario
    located = dataclasses.replace(dataset, path=tmp_path)
    page = build_report(cal, located, crlb=False, command="graphcal report r.json ds")
    header = page.split('<header id="header">')[1].split("</header>")[0]
    assert graphcal.__version__ in header
    assert "graphcal report r.json ds" in header
    assert str(tmp_path.resolve()) in header
    assert re.search(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC", header)
    t = dataset.plots["time_s"]
    assert f"{clock_text(t.min())} – {clock_text(t.max())} UTC" in header


# -------------------------------------------------------------------- flags
def test_estimates_off_the_truth_by_more_than_3_sigma_are_flagged(scenario) -> None:
    dataset, cal = scenario
    sigma = cal.sigma("RA", "range_offset_m")
    # A truth 5 sigma below the estimate for RA's range offset; the rest the estimate itself.
    truth = {rid: cal.bias(rid) for rid in cal.radar_ids}
    truth["RA"] = dataclasses.replace(truth["RA"], range_offset_m=cal.value(
        "RA", "range_offset_m") - 5.0 * sigma)
    page = build_report(cal, dataset, truth=truth, crlb=False)
    estimates = _section(page, "estimates")
    flagged = re.findall(r'<tr class="[^"]*flag[^"]*">(.*?)</tr>', estimates)
    assert len(flagged) == 1 and "range offset" in flagged[0] and "+5.0" in flagged[0]
    assert re.search(r"1 of \d+ estimates are more than 3 σ", estimates)
    clean = build_report(cal, dataset, truth={r: cal.bias(r) for r in cal.radar_ids},
                         crlb=False)
    assert "flag" not in _section(clean, "estimates").replace("flagged", "")
    assert "Every estimate is within 3 σ" in clean


# -------------------------------------------------------------- correlation
def test_correlation_table_shows_two_decimals_of_the_matrix(scenario) -> None:
    _, cal = scenario
    table = correlation_table(cal)
    rho = cal.correlation()
    rows = re.findall(r"<tr(?: class=\"first\")?><th class=\"l\">(.*?)</th>(.*?)</tr>", table)
    assert len(rows) == len(cal.labels)
    for i, (label, cells) in enumerate(rows):
        rid, name = cal.labels[i]
        assert label.startswith(rid)
        values = re.findall(r"<td[^>]*>(.*?)</td>", cells)
        for j in range(i):  # the lower triangle
            expected = "" if abs(rho[i, j]) < 0.005 else f"{rho[i, j]:.2f}".replace("-0.00", "0.00")
            assert values[j] == expected, (i, j)
        assert values[i] == "1"
        assert all(v == "" for v in values[i + 1:])
    assert "e-" not in table  # no scientific notation


# ---------------------------------------------------------- radar versus radar
class _TrueBiases:
    """The part of a Calibration that residual_views reads, holding given biases."""

    def __init__(self, biases: dict[str, RadarBias]) -> None:
        self._biases = biases
        self.radar_ids = list(biases)
        self.atmosphere = None

    def bias(self, radar_id: str) -> RadarBias:
        return self._biases[radar_id]


def test_pairs_without_adsb_shrink_to_zero_after_correction(scenario) -> None:
    """With the true biases as the calibration, each pair's mean difference is within
    3 standard errors of zero after correction, and far from it before."""
    dataset, cal = scenario
    no_adsb = type(dataset)(dataset.sites, dataset.plots, None)
    views = residual_views(no_adsb, _TrueBiases(BIASES))
    assert {v.reference for v in views.values()} == {"cross"}
    summaries = pair_summaries(views)
    assert {(s.radar_id, s.partner) for s in summaries} == {("RA", "RB"), ("RB", "RA")}
    for s in summaries:
        for c in ("range", "azimuth"):
            se = s.sd[("after", c)] / math.sqrt(s.n_after)
            assert abs(s.mean[("after", c)]) < 4.0 * se, (s.radar_id, c)
            assert abs(s.mean[("before", c)]) > 10.0 * se, (s.radar_id, c)


def test_before_and_after_are_separate_panels(scenario) -> None:
    dataset, cal = scenario
    views = residual_views(dataset, cal)
    view = views["RB"]
    fig = before_after_figure(view, np.random.default_rng(0))
    axes = np.array(fig.axes).reshape(-1, 2)
    assert axes.shape == (3, 2)  # range, azimuth, elevation (RB is 3-D) x before, after
    for row, c in enumerate(("range", "azimuth", "elevation")):
        before, after = axes[row]
        yb = before.collections[0].get_offsets()[:, 1]
        ya = after.collections[0].get_offsets()[:, 1]
        # Each panel holds its own stage only: the before panel's mean is the bias's.
        assert np.mean(yb) == pytest.approx(np.mean(view.before.residuals[c]), rel=0.2, abs=0.3)
        assert abs(np.mean(ya)) < 0.2 * abs(np.mean(yb))
        lo, hi, _ = robust_limits(view.after.residuals[c])
        assert after.get_ylim() == pytest.approx((lo, hi))


def test_map_is_in_km_with_equal_aspect_and_range_rings(scenario) -> None:
    from matplotlib.patches import Circle

    dataset, cal = scenario
    corrected = correct_dataset(dataset, {r: cal.bias(r) for r in cal.radar_ids})
    fig = map_figure(dataset, corrected, cal.radar_ids, np.random.default_rng(0))
    ax = fig.axes[0]
    assert ax.get_xlabel() == "east [km]" and ax.get_ylabel() == "north [km]"
    assert ax.get_aspect() == 1.0
    rings = [p for p in ax.patches if isinstance(p, Circle)]
    # The outer (coverage) ring of each radar is its farthest plot, in km.
    radii = sorted(p.radius for p in rings)
    for rid in dataset.sites:
        max_km = dataset.plots_of(rid)["range_m"].max() / 1e3
        assert any(abs(r - max_km) < 1e-9 for r in radii)
        # ... and inside it, rings every round step (10, 20, 25, 50 ... km).
        inner = [r for r in radii if r < max_km - 1e-9 and abs(r / 10.0 - round(r / 10.0)) < 1e-9]
        assert inner, rid
    # Sites are where their east/north offsets put them (site_at: east, north from a common
    # origin), relative to each other.
    ra, rb = (ax.lines[i].get_xydata()[0] for i in range(2))
    assert rb - ra == pytest.approx([50.0, 5.0], abs=0.2)
