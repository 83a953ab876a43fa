"""Labels that never cover data: the map's site labels (two radars 2 km apart) and the
drift plot's tolerance notes and event labels, checked on the Agg renderer's text boxes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.data.bias import RadarBias
from graphcal.data.correct import correct_dataset
from graphcal.reporting.report_figures import map_figure
from graphcal.solvers.registry import METHODS
from tests.reporting.test_report import TRACKS
from tests.synthetic import make_dataset, site_at


def _site_boxes(ax, renderer, half_px: float):
    from matplotlib.transforms import Bbox

    boxes = []
    for line in ax.lines:
        if line.get_marker() == "^":
            for x, y in line.get_xydata():
                px, py = ax.transData.transform((x, y))
                boxes.append(Bbox([[px - half_px, py - half_px], [px + half_px, py + half_px]]))
    return boxes


@pytest.mark.parametrize("n_close", [2, 4])
def test_map_labels_of_nearby_radars_do_not_overlap(n_close: int) -> None:
    """Radars 2 km apart (four: a square of 2 km): each label is clear of the others and of
    every site marker, and inside the axes."""
    offsets = [(0.0, 0.0), (2e3, 0.0), (0.0, 2e3), (2e3, 2e3)][:n_close]
    sites = [site_at(f"R{k}", 10e3 + dx, dy) for k, (dx, dy) in enumerate(offsets)]
    sites.append(site_at("FAR", -60e3, 30e3))
    biases = {s.id: RadarBias(10.0, 0.0, 1e-3) for s in sites}
    dataset = make_dataset(np.random.default_rng(1), [(s, biases[s.id]) for s in sites],
                           TRACKS)
    cal = METHODS["ls"](dataset)
    corrected = correct_dataset(dataset, {r: cal.bias(r) for r in cal.radar_ids})
    fig = map_figure(dataset, corrected, cal.radar_ids, np.random.default_rng(0))
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    ax = fig.axes[0]
    labels = [t for t in ax.texts if t.get_text() in {s.id for s in sites}]
    assert sorted(t.get_text() for t in labels) == sorted(s.id for s in sites)
    from matplotlib.text import Text

    # the text's own box (an annotation's extent includes its leader line to the marker)
    boxes = {t.get_text(): Text.get_window_extent(t, renderer) for t in labels}
    markers = _site_boxes(ax, renderer, half_px=4.0 * fig.dpi / 72.0)
    assert len(markers) == len(sites)
    names = list(boxes)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not boxes[a].overlaps(boxes[b]), (a, b)
        for marker in markers:
            assert not boxes[a].overlaps(marker), a
        assert ax.get_window_extent(renderer).contains(*boxes[a].p0), a
    legend = ax.get_legend().get_window_extent(renderer)
    assert not any(box.overlaps(legend) for box in boxes.values())


def _history_rows(values: list[float], sigma: float, tolerance: float, key: str) -> pd.DataFrame:
    t = np.arange(len(values)) * 1800.0
    return pd.DataFrame({
        "run_id": 1, "radar_id": "SUD", "sensor_model": "ssr-mode-s", "t_start_s": t,
        "t_end_s": t + 1800.0, "t_start_utc": pd.NaT, "t_end_utc": pd.NaT, "n_plots": 5000,
        "key": key, "value": values, "sigma": sigma, "tolerance": tolerance,
        "tolerance_source": "model", "status": "within"})


def test_drift_plot_notes_and_event_labels_cover_no_window(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """A far tolerance's note and a step's label lie clear of every window's 2σ band (the
    windows spread over the panel's whole height, the step in its middle)."""
    import matplotlib.figure

    from graphcal.reporting import history_plot

    series = pd.concat([
        _history_rows([-70.0, -70.2, -10.5, -10.1], 1.0, 100.0, "range_offset_m"),
        _history_rows([-1.5e-4, -1.48e-4, -1.46e-4, -1.5e-4], 5e-6, 4e-4, "range_gain"),
    ], ignore_index=True)
    events = pd.DataFrame({"event_id": [1], "run_id": [1], "radar_id": ["SUD"],
                           "time_s": [3700.0], "time_utc": [pd.NaT], "kind": ["step"],
                           "key": ["range_offset_m"], "size": [59.6], "sigma": [0.9]})
    kept: list[matplotlib.figure.Figure] = []
    real_close = history_plot._pyplot().close
    monkeypatch.setattr(history_plot._pyplot(), "close", lambda fig: kept.append(fig))
    try:
        history_plot.plot_history(series, tmp_path / "drift.png", events=events)
    finally:
        monkeypatch.setattr(history_plot._pyplot(), "close", real_close)
    (fig,) = kept
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for ax, key in zip(fig.axes, ("range_offset_m", "range_gain"), strict=True):
        rows = series[series["key"] == key]
        scale = 1e6 if key == "range_gain" else 1.0
        windows = []
        for row in rows.itertuples():
            (x0, y0), (x1, y1) = ax.transData.transform(
                [(row.t_start_s / 3600.0, (row.value - 2 * row.sigma) * scale),
                 (row.t_end_s / 3600.0, (row.value + 2 * row.sigma) * scale)])
            windows.append((min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)))
        texts = [t for t in [*ax.texts, ax.title, ax._right_title] if t.get_text()]
        notes = [t for t in texts if "tolerance" in t.get_text()]
        assert notes, key  # the tolerance is off scale in both panels
        if key == "range_offset_m":
            assert any(t.get_text().startswith("step +59.6 m") for t in texts)
        for text in texts:
            box = text.get_window_extent(renderer)
            for x0, y0, x1, y1 in windows:
                overlap = box.x0 < x1 and x0 < box.x1 and box.y0 < y1 and y0 < box.y1
                assert not overlap, (key, text.get_text())
        plt = history_plot._pyplot()
    plt.close(fig)


def test_residual_panel_notes_lie_above_their_panels() -> None:
    """The mean / sd / count note of each residual panel is above the panel, over no point;
    the stage names above the top row cover no note."""
    from matplotlib.text import Text

    from graphcal.reporting.report_figures import before_after_figure
    from graphcal.reporting.report_residuals import residual_views
    from tests.reporting.test_report import BIASES

    sites = [site_at("RA", -20e3, 0.0), site_at("RB", 30e3, 5e3, sigma_elevation_mrad=2.0)]
    dataset = make_dataset(np.random.default_rng(3), [(s, BIASES[s.id]) for s in sites],
                           TRACKS)
    view = residual_views(dataset, METHODS["graph"](dataset))["RA"]
    fig = before_after_figure(view, np.random.default_rng(0))
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    notes, stages = [], []
    for ax in fig.axes:
        panel = ax.get_window_extent(renderer)
        note = ax._left_title
        assert note.get_text().startswith("mean "), note.get_text()
        box = Text.get_window_extent(note, renderer)
        assert box.y0 >= panel.y1 - 0.5, note.get_text()  # above the panel
        notes.append(box)
        stages += [Text.get_window_extent(t, renderer) for t in ax.texts
                   if "correction" in t.get_text()]
    assert len(stages) == 2
    assert not any(s.overlaps(n) for s in stages for n in notes)
