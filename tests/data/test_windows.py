"""Time windows of a dataset (graphcal.data.windows)."""

from __future__ import annotations

import numpy as np
import pytest

from graphcal.data.bias import RadarBias
from graphcal.data.windows import split_windows, window_index
from tests.synthetic import Track, make_dataset, site_at


@pytest.fixture(scope="module")
def dataset():
    a = site_at("A", -20e3, 0.0)
    b = site_at("B", 20e3, 0.0, sigma_elevation_mrad=1.0, scan_period_s=5.0)
    tracks = [Track("aa0001", (0.0, 40e3, 8000.0), (200.0, 0.0, 0.0), 100.0, 1500.0),
              Track("aa0002", (-30e3, -30e3, 6000.0), (0.0, 150.0, 0.0), 2500.0, 500.0)]
    return make_dataset(np.random.default_rng(2), [(a, RadarBias()), (b, RadarBias())], tracks)


def test_windows_partition_the_plots_on_aligned_edges(dataset) -> None:
    windows = list(split_windows(dataset, 600.0))
    # Plots from 100 s to 1600 s and 2500 s to 3000 s: windows 0, 1, 2, then 4 (3 is empty).
    assert [w.index for w in windows] == [0, 1, 2, 4]
    assert [(w.t_start_s, w.t_end_s) for w in windows][:2] == [(0.0, 600.0), (600.0, 1200.0)]
    rows = np.concatenate([w.dataset.plots.index.to_numpy() for w in windows])
    assert sorted(rows.tolist()) == sorted(dataset.plots.index.tolist())
    for w in windows:
        t = w.dataset.plots["time_s"].to_numpy()
        assert np.all((t >= w.t_start_s) & (t < w.t_end_s)) and w.n_plots == len(t)
        assert np.all(np.diff(w.dataset.plots.index.to_numpy()) > 0)  # original order kept
        assert w.dataset.sites is dataset.sites


def test_windows_keep_adsb_beyond_their_ends(dataset) -> None:
    w = next(w for w in split_windows(dataset, 600.0, adsb_margin_s=20.0) if w.index == 1)
    t = w.dataset.adsb["time_s"].to_numpy()
    assert t.min() == pytest.approx(580.0, abs=1.0) and t.max() == pytest.approx(1219.0, abs=1.0)


def test_window_index_and_bad_windows() -> None:
    np.testing.assert_array_equal(window_index(np.array([0.0, 599.9, 600.0, -1.0]), 600.0),
                                  [0, 0, 1, -1])
    with pytest.raises(ValueError, match="positive duration"):
        window_index(np.zeros(2), 0.0)
