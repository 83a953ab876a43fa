"""The report's time axes read the dataset's epoch (``[dataset] epoch_utc``): a dataset
whose 0 s is 08:00 UTC shows 08:xx on the binned time axis, the map's zoom panel and the
model checks' time panels; without an epoch, 0 s stays 00:00 UTC."""

from __future__ import annotations

import re
from dataclasses import replace
from datetime import UTC, datetime

import numpy as np
import pytest

from graphcal.data.correct import correct_dataset
from graphcal.reporting.display import clock_text
from graphcal.reporting.report_figures import binned_figure, map_figure, model_checks_figure
from graphcal.reporting.report_residuals import residual_views
from graphcal.solvers.registry import METHODS
from tests.reporting.test_report import BIASES, TRACKS
from tests.synthetic import make_dataset, site_at

EIGHT = datetime(2021, 10, 7, 8, 0, tzinfo=UTC)
CLOCK = re.compile(r"^\d\d:\d\d$")


@pytest.fixture(scope="module")
def scenario():
    sites = [site_at("RA", -20e3, 0.0), site_at("RB", 30e3, 5e3, sigma_elevation_mrad=2.0)]
    dataset = make_dataset(np.random.default_rng(3), [(s, BIASES[s.id]) for s in sites], TRACKS)
    return replace(dataset, epoch_utc=EIGHT), METHODS["graph"](dataset)


def _time_labels(fig) -> list[str]:
    """The tick labels, within the axis limits, of every axis labelled as a time."""
    fig.canvas.draw()
    labels = []
    for ax in fig.axes:
        if ax.get_xlabel().startswith("time"):
            lo, hi = sorted(ax.get_xlim())
            labels += [t.get_text() for t in ax.get_xticklabels()
                       if t.get_text() and lo <= t.get_position()[0] <= hi]
    return labels


def test_clock_text_with_an_epoch() -> None:
    assert clock_text(600.0, EIGHT) == "08:10:00"
    assert clock_text(16 * 3600 + 60.0, EIGHT) == "00:01:00 +1d"
    assert clock_text(600.0) == "00:10:00"


def test_binned_time_axis_is_utc_from_the_epoch(scenario) -> None:
    dataset, cal = scenario
    view = residual_views(dataset, cal)["RA"]
    labels = _time_labels(binned_figure(view, dataset.epoch_utc))
    assert labels and all(CLOCK.match(t) and t.startswith("08:") for t in labels), labels
    fig = binned_figure(view, dataset.epoch_utc)
    assert any("2021-10-07" in ax.get_xlabel() for ax in fig.axes)
    undated = _time_labels(binned_figure(view))
    assert undated and all(t.startswith("00:") for t in undated), undated


def test_ticks_fall_on_round_clock_times_for_an_odd_epoch(scenario) -> None:
    dataset, cal = scenario
    view = residual_views(dataset, cal)["RA"]
    odd = datetime(2021, 10, 7, 8, 7, 13, tzinfo=UTC)
    labels = _time_labels(binned_figure(view, odd))
    assert labels and all(int(t[3:]) % 2 == 0 for t in labels), labels  # 2-min steps


def test_map_zoom_title_is_utc_from_the_epoch(scenario) -> None:
    dataset, cal = scenario
    corrected = correct_dataset(dataset, {r: cal.bias(r) for r in cal.radar_ids})
    fig = map_figure(dataset, corrected, cal.radar_ids, np.random.default_rng(0))
    title = fig.axes[1].get_title()
    assert re.search(r"around 08:\d\d:\d\d UTC", title), title


def test_model_checks_time_panel_is_utc_from_the_epoch() -> None:
    bins = {"centre_s": [100.0, 300.0, 500.0], "lower_s": [0.0, 200.0, 400.0],
            "upper_s": [200.0, 400.0, 600.0], "mean_m": [1.0, -1.0, 0.5],
            "sigma_m": [1.0, 1.0, 1.0], "absorbed_m": [0.0, 0.0, 0.0]}
    entry = {"tests": [{"residual": "range_m", "against": "time_s", "bins": bins, "chi2": 2.0,
                        "dof": 3.0, "p_value": 0.5, "fired": False}]}
    labels = _time_labels(model_checks_figure("RA", entry, EIGHT))
    assert labels and all(t.startswith("08:") for t in labels), labels
