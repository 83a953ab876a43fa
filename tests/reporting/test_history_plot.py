"""The drift plot of a calibration history (graphcal.reporting.history_plot)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from graphcal.pipeline.history import append_run, flag_tolerances, read_events, read_series
from graphcal.reporting.history_plot import DPI, PANEL_HEIGHT_IN, PANEL_WIDTH_IN, plot_history

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _windows(base: float, sigma: float, step: float, key: str) -> list[dict]:
    out = []
    for k in range(6):
        value = base + (step if k >= 3 else 0.0)
        out.append({"t_start_s": 3600.0 * k, "t_end_s": 3600.0 * (k + 1), "n_plots": 900,
                    key: value, "sigma": {key: sigma}})
    return out


@pytest.fixture(scope="module")
def history(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("history") / "calib.db"
    ra = _windows(40.0, 1.5, 70.0, "range_offset_m")
    for window, azimuth in zip(ra, np.linspace(1.0, 1.6, 6), strict=True):
        window["azimuth_bias_mrad"] = float(azimuth)
        window["sigma"]["azimuth_bias_mrad"] = 0.03
    result = {
        "method": "graph", "radars": {},
        "series": {"window_s": 3600.0, "radars": {
            "RA": ra, "RB": _windows(-0.8, 0.05, 0.0, "elevation_bias_mrad")}},
        "events": [{"radar_id": "RA", "time_s": 10800.0, "kind": "step",
                    "parameters": ["range_offset_m"], "size": {"range_offset_m": 70.0},
                    "sigma": {"range_offset_m": 2.1}}],
    }
    append_run(path, result, provenance={"dataset": "d1",
                                         "sensor_models": {"RA": "ssr-mode-s"}})
    single = {"radars": {"RA": {"range_offset_m": 45.0, "sigma": {"range_offset_m": 1.0}}}}
    append_run(path, single, provenance={"dataset": "d2", "t_start_s": 0.0,
                                         "t_end_s": 7200.0})
    return path


def test_the_plot_is_a_png_with_one_panel_per_radar_and_key(history: Path,
                                                             tmp_path: Path) -> None:
    series = flag_tolerances(read_series(history))
    assert set(series.status) == {"within", "outside"}  # 110 - 3 > 100 after the step
    out = plot_history(series, tmp_path / "drift.png", events=read_events(history),
                       title="calib.db")
    assert out == tmp_path / "drift.png"
    data = out.read_bytes()
    assert data.startswith(PNG_SIGNATURE)
    with Image.open(out) as image:
        width, height = image.size
        pixels = np.asarray(image.convert("RGB"))
    # 2 radars x 3 keys (range offset, azimuth, elevation) of PANEL_* inches at DPI
    assert width == round(3 * PANEL_WIDTH_IN * DPI)
    assert height == round((2 * PANEL_HEIGHT_IN + 0.9) * DPI)
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 50  # drawn, not blank
    assert [p.name for p in tmp_path.iterdir()] == ["drift.png"]  # no temporary file left


@pytest.mark.parametrize("suffix", [".pdf", ".svg"])
def test_other_formats_by_suffix(history: Path, tmp_path: Path, suffix: str) -> None:
    out = plot_history(read_series(history), tmp_path / f"drift{suffix}")
    head = out.read_bytes()[:200]
    assert head.startswith(b"%PDF") if suffix == ".pdf" else b"<svg" in out.read_bytes()


def test_utc_times_when_every_run_has_an_epoch(tmp_path: Path) -> None:
    path = tmp_path / "calib.db"
    result = {"radars": {}, "series": {"window_s": 3600.0, "radars": {
        "RA": _windows(40.0, 1.5, 0.0, "range_offset_m")}}}
    append_run(path, result, provenance={"dataset": "d", "epoch_utc": "2024-05-01T00:00Z"})
    out = plot_history(read_series(path), tmp_path / "drift.svg")
    assert "time (UTC)" in out.read_text()


def test_bad_suffix_and_nothing_to_draw(history: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="suffix"):
        plot_history(read_series(history), tmp_path / "drift.jpg")
    with pytest.raises(ValueError, match="no windows"):
        plot_history(read_series(history).iloc[0:0], tmp_path / "drift.png")
    assert not any(tmp_path.iterdir())


def test_a_frame_without_tolerances_or_events_draws(tmp_path: Path) -> None:
    series = pd.DataFrame({
        "run_id": [1, 1], "radar_id": ["X", "X"], "sensor_model": [None, None],
        "t_start_s": [0.0, 60.0], "t_end_s": [60.0, 120.0], "key": ["range_gain"] * 2,
        "value": [1e-4, 1.2e-4], "sigma": [np.nan, 1e-5],
    })
    assert plot_history(series, tmp_path / "g.png").stat().st_size > 1000
