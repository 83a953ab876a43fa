"""``graphcal history``: tables at 80 columns, CSV, the plot, and bad input."""

from __future__ import annotations

import io
import sqlite3
from pathlib import Path

import pandas as pd
import pytest
from rich.console import Console
from typer.testing import CliRunner

import graphcal.cli.history as history_cli
from graphcal.cli.app import app
from graphcal.cli.history import CSV_COLUMNS, parse_since, parse_tolerances
from graphcal.pipeline.history import SCHEMA_VERSION, append_run

runner = CliRunner()

#: Two windows of a 3-D radar with a long id and a step; UTC times (the widest column).
LONG_ID = "CHAMPAGNE-3D-SOUTH"
WINDOWED = {
    "method": "graph",
    "radars": {},
    "series": {"window_s": 1800.0, "radars": {LONG_ID: [
        {"t_start_s": 32400.0, "t_end_s": 34200.0, "n_plots": 5120,
         "range_offset_m": 180.41, "range_gain": -0.0004123, "azimuth_bias_mrad": 2.31,
         "elevation_bias_mrad": -1.49, "azimuth_sin_mrad": 0.894,
         "sigma": {"range_offset_m": 1.9, "range_gain": 1.234e-5, "azimuth_bias_mrad": 0.1,
                   "elevation_bias_mrad": 0.05, "azimuth_sin_mrad": 0.0115}},
        {"t_start_s": 34200.0, "t_end_s": 36000.0, "n_plots": 4870,
         "range_offset_m": 302.0, "range_gain": -0.000998, "azimuth_bias_mrad": 2.35,
         "elevation_bias_mrad": -1.52, "azimuth_sin_mrad": 0.9,
         "sigma": {"range_offset_m": 0.5, "range_gain": 1.3e-5, "azimuth_bias_mrad": 0.1,
                   "elevation_bias_mrad": 0.05, "azimuth_sin_mrad": 0.0115}},
    ]}},
    "events": [{"radar_id": LONG_ID, "time_s": 34200.0, "kind": "step",
                "parameters": ["range_offset_m"], "size": {"range_offset_m": 121.6},
                "sigma": {"range_offset_m": 2.0}}],
}
SINGLE = {"method": "ls", "radars": {"NORD": {
    "range_offset_m": 44.89, "range_gain": 0.0001975, "azimuth_bias_mrad": 1.184,
    "time_offset_s": 0.0001,
    "sigma": {"range_offset_m": 1.23, "range_gain": 1.081e-5, "azimuth_bias_mrad": 0.0151,
              "time_offset_s": 0.0032},
    "n_plots": 7267}}}


@pytest.fixture
def db(tmp_path: Path) -> Path:
    path = tmp_path / "calib.db"
    append_run(path, WINDOWED, provenance={
        "dataset": "recordings/2024-05-01", "epoch_utc": "2024-05-01T00:00:00Z",
        "run_time_utc": "2024-05-01T14:00:00Z", "sensor_models": {LONG_ID: "air-defence-3d"}})
    append_run(path, SINGLE, provenance={"dataset": "demo-out", "t_start_s": 0.0,
                                         "t_end_s": 1800.0})
    return path


def _output_at_80_columns(monkeypatch: pytest.MonkeyPatch, args: list[str]) -> str:
    """The command's standard output on a console of COLUMNS=80."""
    monkeypatch.setenv("COLUMNS", "80")
    buffer = io.StringIO()
    monkeypatch.setattr(history_cli, "console", Console(file=buffer))
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    return buffer.getvalue()


def test_the_table_fits_80_columns_without_cutting_ids_or_numbers(
        db: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(db.parent)  # the header names the file as given: a short path
    text = _output_at_80_columns(monkeypatch, ["history", db.name])
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80
    assert "…" not in text
    for expected in (
        f"{LONG_ID} (air-defence-3d)", "NORD", "from [s]", "span [s]", "from (UTC)",
        "recordings/2024-05-01", "32400-36000", "1800 s",  # the runs
        "2024-05-01 09:00:00", "2024-05-01 09:30:00",  # the windows' UTC starts
        "180.41 ± 3.80", "-4.123e-04 ± 2.468e-05", "302.00 ± 1.00", "-9.980e-04 ± 2.600e-05",
        "0.894 ± 0.023", "-1.490 ± 0.100",  # eccentricity and elevation, 2 sigma
        "44.89 ± 2.46", "1.975e-04 ± 2.162e-05", "0.000 ± 0.006",
        "step at 2024-05-01 09:30:00 (run 1): range_offset_m 121.60 ± 4.00 m",
    ):
        assert expected in text, expected
    # 302 - 1 > 300 (air-defence-3d: twice 150 m): OUT; |-9.98e-4| - 2.6e-5 < 1e-3: within
    flagged = [line for line in lines if line.rstrip().endswith(("OUT", "out?"))]
    assert len(flagged) == 1 and "302.00" in flagged[0] and flagged[0].rstrip().endswith("OUT")
    assert "1 OUT" in text and "0 out?" in text


def test_a_given_tolerance_changes_the_flags(db: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    text = _output_at_80_columns(monkeypatch, ["history", str(db), "--radar", "NORD",
                                               "--tolerance", "range_offset_m=44",
                                               "--tolerance", "azimuth_bias_mrad=1.2"])
    assert LONG_ID not in text
    # 44.89 > 44 but 44.89 - 2.46 < 44: out?; 1.184 <= 1.2: within
    assert "1 run" in text and "0 OUT" in text and "1 out?" in text


def test_csv_gives_every_window_exactly(db: Path) -> None:
    result = runner.invoke(app, ["history", str(db), "--csv"])
    assert result.exit_code == 0, result.output
    frame = pd.read_csv(io.StringIO(result.stdout), keep_default_na=False, na_values=[""])
    assert tuple(frame.columns) == CSV_COLUMNS
    assert len(frame) == 5 * 2 + 4
    row = frame[(frame.radar_id == LONG_ID) & (frame.key == "range_gain")
                & (frame.t_start_s == 32400.0)].iloc[0]
    assert (row.value, row.sigma, row.tolerance) == (-0.0004123, 1.234e-5, 0.001)
    assert row.t_start_utc == "2024-05-01T09:00:00.000000Z"
    assert set(frame[frame.radar_id == "NORD"].t_start_utc.isna()) == {True}
    assert frame.status.value_counts().to_dict() == {"within": 13, "outside": 1}


def test_since_in_seconds_and_in_utc(db: Path) -> None:
    seconds = runner.invoke(app, ["history", str(db), "--csv", "--since", "34200"])
    frame = pd.read_csv(io.StringIO(seconds.stdout))
    assert sorted(set(frame.t_start_s)) == [34200.0]
    utc = runner.invoke(app, ["history", str(db), "--csv", "--since", "2024-05-01T09:15Z"])
    assert utc.exit_code == 0
    frame = pd.read_csv(io.StringIO(utc.stdout))
    assert set(frame.radar_id) == {LONG_ID} and sorted(set(frame.t_start_s)) == [32400.0,
                                                                               34200.0]
    assert "leaves out the runs without a UTC epoch (2)" in utc.stderr


def test_nothing_since_is_said_plainly(db: Path) -> None:
    result = runner.invoke(app, ["history", str(db), "--since", "99999"])
    assert result.exit_code == 0
    assert "no windows after 99999" in result.stdout


def test_the_plot_is_written(db: Path, tmp_path: Path) -> None:
    out = tmp_path / "drift.png"
    result = runner.invoke(app, ["history", str(db), "--plot", str(out), "--csv"])
    assert result.exit_code == 0, result.output
    assert out.read_bytes().startswith(b"\x89PNG")
    assert f"wrote {out}" in " ".join(result.stderr.split())


def _not_a_history(tmp_path: Path) -> Path:
    path = tmp_path / "plots.csv"
    path.write_text("radar_id,time_s\nA,1.0\n")
    return path


def _newer(tmp_path: Path) -> Path:
    path = tmp_path / "new.db"
    append_run(path, SINGLE, provenance={"dataset": "d", "t_start_s": 0.0, "t_end_s": 1.0})
    con = sqlite3.connect(path)
    con.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    con.close()
    return path


@pytest.mark.parametrize(("make", "extra", "message"), [
    (lambda d, t: t / "missing.db", [], "missing.db: no such file"),
    (lambda d, t: t, [], "not a file"),
    (lambda d, t: _not_a_history(t), [], "not a graphcal history database"),
    (lambda d, t: _newer(t), [], "newer graphcal"),
    (lambda d, t: d, ["--radar", "SUD"], "no radar 'SUD'; known: CHAMPAGNE-3D-SOUTH, NORD"),
    (lambda d, t: d, ["--tolerance", "range_bias=5"], "--tolerance range_bias: unknown key"),
    (lambda d, t: d, ["--tolerance", "range_offset_m"], "expected KEY=VALUE"),
    (lambda d, t: d, ["--tolerance", "range_offset_m=-5"], "expected KEY=VALUE"),
    (lambda d, t: d, ["--since", "yesterday"], "--since yesterday: expected seconds"),
    (lambda d, t: d, ["--since", "nan"], "not a finite number"),
    (lambda d, t: d, ["--plot", "drift.jpg"], "use a .png, .pdf, .svg suffix"),
    (lambda d, t: d, ["--plot", "no/such/drift.png"], "does not exist"),
    (lambda d, t: d, ["--since", "1e9", "--plot", "drift.png"], "no windows to draw"),
])
def test_bad_input_is_one_line_and_exit_status_2(db: Path, tmp_path: Path, make, extra,
                                                  message, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["history", str(make(db, tmp_path)), *extra])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output and result.exception is None or isinstance(
        result.exception, SystemExit)
    errors = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith("error: "), result.stderr
    assert message in errors[0]


def test_option_parsers() -> None:
    assert parse_tolerances(["range_offset_m=50", "range_gain=4e-4"]) == {
        "range_offset_m": 50.0, "range_gain": 4e-4}
    assert parse_since("32400") == 32400.0
    assert parse_since("2024-05-01T09:00").isoformat() == "2024-05-01T09:00:00+00:00"
    assert parse_since("2024-05-01T11:00+02:00").utcoffset().total_seconds() == 7200


def test_calibrate_history_records_the_datasets_epoch(tmp_path: Path) -> None:
    """``calibrate --history`` passes ``[dataset] epoch_utc`` as the run's provenance, with
    and without windows; a dataset without one records none. The history then shows UTC."""
    import numpy as np

    from graphcal.data.bias import RadarBias
    from graphcal.io.folder import write_dataset
    from graphcal.pipeline.history import read_runs, read_series
    from tests.synthetic import Track, make_dataset, site_at

    tracks = [Track(f"4ca{i:03x}", (-30e3 + 20e3 * i, 10e3, 9e3), (200.0, 40.0, 0.0), 0.0, 600.0)
              for i in range(3)]
    dataset = make_dataset(np.random.default_rng(2), [
        (site_at("RA", 0.0, 0.0), RadarBias(50.0, 1e-4, 1e-3)),
        (site_at("RB", 60e3, 0.0), RadarBias(-30.0, 0.0, -1e-3))], tracks)
    plain = write_dataset(dataset, tmp_path / "plain")
    dated = tmp_path / "dated"
    dated.mkdir()
    for name in ("plots.csv", "adsb.csv"):
        (dated / name).write_bytes((plain / name).read_bytes())
    (dated / "sites.toml").write_text('[dataset]\nepoch_utc = "2021-10-07T09:00:00Z"\n\n'
                                      + (plain / "sites.toml").read_text())
    path = tmp_path / "calib.db"
    for folder, options in ((dated, ["--method", "ls"]), (dated, ["--window", "5min"]),
                            (plain, ["--method", "ls"])):
        result = runner.invoke(app, ["calibrate", str(folder), *options, "--history",
                                     str(path)])
        assert result.exit_code == 0, result.output
    runs = read_runs(path)
    epoch = pd.Timestamp("2021-10-07T09:00:00Z")
    assert runs["epoch_utc"].tolist()[:2] == [epoch, epoch] and pd.isna(runs["epoch_utc"][2])
    series = read_series(path, radar="RA")
    first = series[series["run_id"] == 1].iloc[0]
    assert first["t_start_utc"] == epoch + pd.to_timedelta(first["t_start_s"], unit="s")
    shown = runner.invoke(app, ["history", str(path), "--radar", "RA", "--since",
                                "2021-10-07T09:00:00Z"])
    assert shown.exit_code == 0 and "2021-10-07" in shown.output
