"""Calibration over time windows through the pipeline and the command line: the result
JSON's series and events (contract v2), the options, and the schedulers."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.data.calibration import Calibration
from graphcal.io.folder import write_dataset
from graphcal.pipeline.calibrate import calibrate
from graphcal.pipeline.windowed import parse_drift
from graphcal.simulation.scenario import parse_scenario
from graphcal.simulation.simulate import simulate
from tests.paths import SCENARIOS

runner = CliRunner()


#: The tests of how a folder is read (order, child process, late rows) compare runs of
#: one formulation; the pairwise one is the quicker.
READING_CROSS = "pairwise"


def assert_same_series(expected: Calibration, got: Calibration, within_sigma: float) -> None:
    """Every window's every bias of ``got`` within ``within_sigma`` of ``expected``'s sigma."""
    for rid, entries in expected.series["radars"].items():
        for mine, theirs in zip(entries, got.series["radars"][rid], strict=True):
            for key, sigma in mine["sigma"].items():
                assert abs(mine[key] - theirs[key]) <= within_sigma * sigma, (rid, key)


@pytest.fixture(scope="module")
def stepping():
    """The demo network for one hour, SUD's range offset stepping 60 m at 2000 s."""
    with open(SCENARIOS / "demo_network.toml", "rb") as f:
        doc = tomllib.load(f)
    doc["scenario"]["duration_s"] = 3600.0
    doc["traffic"]["start_time_s"] = [0.0, 1800.0]
    doc["radar"][1]["step"] = [{"time_s": 2000.0, "range_offset_m": 60.0}]
    scenario = parse_scenario(doc)
    return scenario, simulate(scenario, np.random.default_rng(5))


@pytest.fixture(scope="module")
def windowed(stepping):
    _, sim = stepping
    return calibrate(sim.dataset, window="15min")


def test_the_result_is_the_last_window_with_series_and_events(stepping, windowed) -> None:
    scenario, sim = stepping
    cal = windowed
    document = cal.to_dict()
    assert document["series"]["window_s"] == 900.0
    for rid, entries in document["series"]["radars"].items():
        assert [e["t_start_s"] for e in entries] == sorted(e["t_start_s"] for e in entries)
        last = entries[-1]
        assert document["radars"][rid]["range_offset_m"] == pytest.approx(
            last["range_offset_m"], rel=1e-9)
        assert document["radars"][rid]["sigma"]["range_offset_m"] == pytest.approx(
            last["sigma"]["range_offset_m"], rel=1e-6)
        assert set(last) >= {"t_start_s", "t_end_s", "n_plots", "range_offset_m",
                             "range_gain", "azimuth_bias_mrad", "elevation_bias_mrad",
                             "sigma"}
    # SUD's step: one event of kind "step" in range offset, in the window holding 2000 s.
    (event,) = [e for e in document["events"] if e["radar_id"] == "SUD"]
    assert event["kind"] == "step" and "range_offset_m" in event["parameters"]
    assert 900.0 <= event["time_s"] <= 2700.0
    # Located inside its window from SUD's own plots against ADS-B (to about 30 s).
    assert abs(event["time_s"] - 2000.0) < 60.0
    assert abs(event["size"]["range_offset_m"] - 60.0) < 3 * event["sigma"]["range_offset_m"]
    # The fit verdict judged every window's own fit, the one holding the step in its parts.
    verdict = document["info"]["fit_verdict"]
    assert verdict["passed"] and verdict["reference"] == "adsb"
    spans = [(w["t_start_s"], w["t_end_s"]) for w in verdict["windows"]]
    assert spans[0] == (0.0, 900.0) and spans[-1][1] == 3600.0
    assert any(t0 < event["time_s"] == t1 for t0, t1 in spans)  # cut at the step
    # The last window's SUD range offset is the stepped one.
    truth = scenario.radars[1].schedule.mean(2700.0, 3600.0)
    assert document["radars"]["SUD"]["range_offset_m"] == pytest.approx(
        truth.range_offset_m, abs=4 * document["radars"]["SUD"]["sigma"]["range_offset_m"])


def test_series_and_events_survive_the_json_round_trip(windowed) -> None:
    text = windowed.to_json()
    again = Calibration.from_dict(json.loads(text))
    assert again.series == json.loads(text)["series"]
    assert again.events == json.loads(text)["events"]
    back = again.to_dict()
    assert back["series"] == json.loads(text)["series"]
    for rid, entry in json.loads(text)["radars"].items():
        for key, sigma in entry["sigma"].items():
            assert back["radars"][rid][key] == pytest.approx(entry[key], rel=1e-9, abs=1e-12)
            assert back["radars"][rid]["sigma"][key] == pytest.approx(sigma, rel=1e-9)


def test_a_result_without_windows_has_neither_key(stepping) -> None:
    _, sim = stepping
    document = calibrate(sim.dataset, model_checks=False, bound=False).to_dict()
    assert "series" not in document and "events" not in document


def test_drift_rates_are_read_per_square_root_of_an_hour() -> None:
    rates = parse_drift({"azimuth_bias_mrad": 0.6, "range_offset_m": 3.0})
    assert rates["azimuth_bias"] == pytest.approx(0.6e-3 / 60.0)
    assert rates["range_offset"] == pytest.approx(3.0 / 60.0)
    with pytest.raises(ValueError, match="unknown bias key"):
        parse_drift({"azimuth_mrad": 1.0})
    with pytest.raises(ValueError, match=">= 0"):
        parse_drift({"range_offset_m": -1.0})


@pytest.mark.parametrize(("options", "message"), [
    ({"method": "wls", "window": "15min"}, "graph method"),
    ({"drift": {"range_offset_m": 1.0}}, "give window"),
    ({"window": "15min", "breaks": {"NOPE": [100.0]}}, "unknown radar"),
    ({"window": "fortnight"}, "not a duration"),
    ({"window": "15min", "scheduler": "somewhere"}, "unknown scheduler"),
    ({"window": "15min", "select": "greedy"}, "select is not available"),
])
def test_bad_window_options_are_refused(stepping, options, message) -> None:
    _, sim = stepping
    with pytest.raises(ValueError, match=message):
        calibrate(sim.dataset, **options)


def test_processes_give_the_same_series_as_this_process(stepping, windowed) -> None:
    """The window map on a Dask LocalCluster of worker processes: the same series
    (within 0.01 sigma) as in this process."""
    pytest.importorskip("distributed")
    _, sim = stepping
    other = calibrate(sim.dataset, window="15min", scheduler="processes")
    assert_same_series(windowed, other, within_sigma=0.01)
    assert other.info["windows"]["scheduler"] == "processes"


def test_forked_copy_gives_the_same_series_as_this_process(stepping, windowed) -> None:
    """The window map in this process and a forked copy of it (the default for a large
    folder; both with the compiled loops, loaded before the fork): the same series
    (within 0.001 sigma) as in this process alone, with NumPy's sums."""
    from graphcal.pipeline.schedulers import child_reading_available

    if not child_reading_available():
        pytest.skip("the forked map needs fork (Linux)")
    _, sim = stepping
    other = calibrate(sim.dataset, window="15min", scheduler="forked")
    assert_same_series(windowed, other, within_sigma=0.001)
    assert other.info["windows"]["scheduler"] == "forked"
    assert windowed.info["windows"]["scheduler"] == "synchronous"


def test_command_line_window_drift_and_break(stepping, tmp_path: Path) -> None:
    _, sim = stepping
    folder = tmp_path / "ds"
    write_dataset(sim.dataset, folder)
    out = tmp_path / "result.json"
    result = runner.invoke(app, ["calibrate", str(folder), "--window", "15min",
                                 "--drift", "azimuth_bias_mrad=0.1", "--break", "SUD@1800",
                                 "--no-steps", "--out", str(out)])
    assert result.exit_code == 0, result.output
    document = json.loads(out.read_text())
    assert document["info"]["windows"]["random_walk_per_sqrt_h"]["NORD"][
        "azimuth_bias_mrad"] == pytest.approx(0.1)
    (event,) = document["events"]
    assert event["radar_id"] == "SUD" and event["kind"] == "break"
    assert event["time_s"] == 1800.0
    db = tmp_path / "calib.db"
    result = runner.invoke(app, ["calibrate", str(folder), "--window", "15min", "--no-steps",
                                 "--history", str(db), "--out", str(tmp_path / "r2.json")])
    assert result.exit_code == 0, result.output
    from graphcal.pipeline.history import read_runs, read_series

    (run,) = read_runs(db).itertuples()
    assert run.window_s == 900.0
    series = read_series(db, radar="SUD")
    stored = series[series["key"] == "range_offset_m"].sort_values("t_start_s")
    written = json.loads((tmp_path / "r2.json").read_text())["series"]["radars"]["SUD"]
    assert stored["value"].tolist() == pytest.approx([w["range_offset_m"] for w in written])
    missing = runner.invoke(app, ["calibrate", str(folder), "--history",
                                  str(tmp_path / "nowhere" / "c.db")])
    assert missing.exit_code == 2 and "does not exist" in missing.output
    bad = runner.invoke(app, ["calibrate", str(folder), "--drift", "range_offset_m=1"])
    assert bad.exit_code == 2 and "--window" in bad.output
    bad = runner.invoke(app, ["calibrate", str(folder), "--window", "15min",
                              "--break", "SUD1800"])
    assert bad.exit_code == 2 and "RADAR@TIME" in bad.output


def test_a_folder_is_read_window_by_window_with_the_same_result(stepping, windowed,
                                                                 tmp_path: Path) -> None:
    """calibrate(folder, window=...) streams the folder (io.window_reader) instead of
    loading it: the same series as the dataset in memory (within 0.01 sigma)."""
    _, sim = stepping
    folder = tmp_path / "ds"
    write_dataset(sim.dataset, folder, fmt="parquet")
    streamed = calibrate(folder, window="15min")
    assert streamed.info["windows"]["streamed"] is True
    assert_same_series(windowed, streamed, within_sigma=0.01)


def test_a_folder_read_in_a_child_process_gives_the_same_series(stepping, tmp_path: Path,
                                                                monkeypatch) -> None:
    """Large folders are read and cleaned by a forked child (schedulers.read_in_child),
    small ones by a thread: the same windows, so the same series to the last bit."""
    import graphcal.pipeline.window_feed as window_feed
    from graphcal.pipeline.schedulers import child_reading_available

    if not child_reading_available():
        pytest.skip("reading in a child process needs fork (Linux)")
    _, sim = stepping
    folder = tmp_path / "ds"
    write_dataset(sim.dataset, folder)
    results = {}
    for name, threshold in (("child", 0), ("thread", 1 << 60), ("started", 0)):
        monkeypatch.setattr(window_feed, "CHILD_READER_MIN_BYTES", threshold)
        if name == "started":  # as the command line does, before importing the solvers
            assert window_feed.start_reading(folder, "15min")
            assert len(window_feed._STARTED) == 1
        results[name] = calibrate(folder, window="15min", cross=READING_CROSS)
        assert not window_feed._STARTED  # taken
    for name in ("child", "started"):
        assert results[name].series == results["thread"].series
        assert results[name].events == results["thread"].events
    assert len(results["child"].events) == 1  # the step, re-read in this process


def test_a_head_start_is_only_a_head_start(stepping, tmp_path: Path, monkeypatch) -> None:
    """start_reading starts nothing for a bad folder or duration (the calibration then
    reports it), and a reader started for other options is not taken, and stopped."""
    import multiprocessing

    import graphcal.pipeline.window_feed as window_feed
    from graphcal.pipeline.schedulers import child_reading_available

    if not child_reading_available():
        pytest.skip("reading in a child process needs fork (Linux)")
    monkeypatch.setattr(window_feed, "CHILD_READER_MIN_BYTES", 0)
    assert not window_feed.start_reading(tmp_path / "missing", "1h")
    _, sim = stepping
    folder = tmp_path / "ds"
    write_dataset(sim.dataset, folder)
    assert not window_feed.start_reading(folder, "1 fortnight")
    assert not window_feed._STARTED and not multiprocessing.active_children()
    assert window_feed.start_reading(folder, "1h", clean=False)
    stream, in_child, _ = window_feed.open_folder_windows(folder, 3600.0, True, False)
    assert in_child and len(window_feed._STARTED) == 1  # other options: a reader of its own
    stream.close()
    window_feed.stop_started()
    assert not window_feed._STARTED and not multiprocessing.active_children()


def _assert_series_as_ordered(sim, tmp_path: Path, got: Calibration) -> None:
    """``got`` has the events and series of the simulation's folder written in time
    order: the same plots per window, the values to 1e-6 of their sigmas."""
    ordered = tmp_path / "ordered"
    write_dataset(sim.dataset, ordered)
    expected = calibrate(ordered, window="15min", cross=READING_CROSS)
    # The same events; the step statistic (a chi-square of some 1,000) to 1e-6 of itself:
    # the order of the rows changes the order of floating-point sums.
    assert len(got.events) == len(expected.events)
    for mine, theirs in zip(got.events, expected.events, strict=True):
        assert {k: v for k, v in mine.items() if k != "statistic"} == {
            k: v for k, v in theirs.items() if k != "statistic"}
        assert mine.get("statistic") == pytest.approx(theirs.get("statistic"), rel=1e-6)
    for rid, entries in expected.series["radars"].items():
        for mine, theirs in zip(entries, got.series["radars"][rid], strict=True):
            assert mine["n_plots"] == theirs["n_plots"]
            for key, sigma in mine["sigma"].items():
                assert abs(mine[key] - theirs[key]) <= 1e-6 * sigma, (rid, key)


def _written_csv(sim, folder: Path, monkeypatch, threshold: int):
    """The simulation's dataset written to ``folder`` (CSV), read by a forked child when
    its tables reach ``threshold`` bytes, and its plots table as written."""
    import pandas as pd

    import graphcal.pipeline.window_feed as window_feed

    monkeypatch.setattr(window_feed, "CHILD_READER_MIN_BYTES", threshold)
    write_dataset(sim.dataset, folder)
    assert window_feed.reading_order(folder) == "sorted"
    return pd.read_csv(folder / "plots.csv", dtype={"target_id": str, "radar_id": str})


def _row_moved(frame, row, position: int):
    """``frame`` with the row labelled ``row`` moved to ``position`` among the others."""
    import pandas as pd

    rest = frame.drop(index=row)
    return pd.concat([rest.iloc[:position], frame.loc[[row]], rest.iloc[position:]])


@pytest.mark.parametrize("threshold", [0, 1 << 60], ids=["child", "here"])
def test_a_csv_folder_out_of_time_order_is_read_sorted_by_window(stepping, tmp_path: Path,
                                                                 monkeypatch, threshold) -> None:
    """A CSV folder is read as if in time order while its spans are measured; a file
    found out of order sends the reader back to sorting by window: the same series."""
    _, sim = stepping
    shuffled = tmp_path / "shuffled"
    plots = _written_csv(sim, shuffled, monkeypatch, threshold)
    plots.sample(frac=1.0, random_state=2).to_csv(shuffled / "plots.csv", index=False)
    _assert_series_as_ordered(sim, tmp_path,
                              calibrate(shuffled, window="15min", cross=READING_CROSS))


@pytest.mark.parametrize("threshold", [0, 1 << 60], ids=["child", "here"])
def test_a_late_row_deep_in_a_csv_table_sends_the_reading_back(stepping, tmp_path: Path,
                                                              monkeypatch, threshold) -> None:
    """A table in time order but for one row of the first window written near its end:
    read as if in order, the first windows are calibrated before the late row is met.
    They are dropped and the folder read again sorted by window: the first window counts
    that row, and the series is the ordered folder's."""
    _, sim = stepping
    late = tmp_path / "late"
    plots = _written_csv(sim, late, monkeypatch, threshold)
    moved = plots.index[plots["time_s"] < 600.0][5]
    _row_moved(plots, moved, len(plots) - 51).to_csv(late / "plots.csv", index=False)
    _assert_series_as_ordered(sim, tmp_path,
                              calibrate(late, window="15min", cross=READING_CROSS))


@pytest.mark.parametrize("threshold", [0, 1 << 60], ids=["child", "here"])
def test_the_ends_of_tables_out_of_order_do_not_refuse_them(stepping, tmp_path: Path,
                                                           monkeypatch, threshold) -> None:
    """Plots whose first and last rows are from the first minutes and ADS-B whose first
    and last rows are from the last: their ends (the span of tables in time order) do
    not overlap in time, their rows do.  The full span decides (no refusal), the reader
    finds the rows out of order and reads again: the ordered folder's series."""
    import pandas as pd

    from graphcal.io.dataset_span import end_times_span

    _, sim = stepping
    folder = tmp_path / "ends"
    plots = _written_csv(sim, folder, monkeypatch, threshold)
    early = plots.index[plots["time_s"] < 300.0][5]
    _row_moved(plots, early, len(plots) - 1).to_csv(folder / "plots.csv", index=False)
    adsb = pd.read_csv(folder / "adsb.csv", dtype={"target_id": str})
    late = adsb.index[adsb["time_s"] > adsb["time_s"].max() - 300.0][5]
    _row_moved(adsb, late, 0).to_csv(folder / "adsb.csv", index=False)
    ends = end_times_span(folder)
    assert ends is not None and ends.adsb is not None
    assert ends.adsb.t_min_s > ends.t_end_s + 600.0  # the ends do not overlap
    _assert_series_as_ordered(sim, tmp_path,
                              calibrate(folder, window="15min", cross=READING_CROSS))


@pytest.mark.parametrize("threshold", [0, 1 << 60], ids=["child", "here"])
def test_adsb_on_another_time_base_is_refused_before_anything_else(
        stepping, tmp_path: Path, monkeypatch, threshold) -> None:
    """ADS-B two days after the plots: the time-overlap finding, measured beside the
    reading, is what the calibration raises (not what the windows without ADS-B give)."""
    import pandas as pd

    import graphcal.pipeline.window_feed as window_feed
    from graphcal.core.errors import ImplausibleDataError

    monkeypatch.setattr(window_feed, "CHILD_READER_MIN_BYTES", threshold)
    _, sim = stepping
    folder = tmp_path / "shifted"
    write_dataset(sim.dataset, folder)
    adsb = pd.read_csv(folder / "adsb.csv", dtype={"target_id": str})
    adsb["time_s"] += 2 * 86400.0
    adsb.to_csv(folder / "adsb.csv", index=False)
    with pytest.raises(ImplausibleDataError, match="do not overlap"):
        calibrate(folder, window="15min")


def test_a_long_recording_is_calibrated_for_constant_biases_window_by_window(
        demo, demo_dir, monkeypatch) -> None:
    """Beyond CONSTANT_BATCH_MIN_SPAN_S a folder is not loaded whole: its windows'
    summaries give the constant biases (here the 30-minute demo against a 15-minute
    limit, in 10-minute windows), close to the batch's, and the result says how."""
    import graphcal.pipeline.calibrate as pipeline
    from graphcal.solvers.graph import graph

    monkeypatch.setattr(pipeline, "CONSTANT_BATCH_MIN_SPAN_S", 900.0)
    monkeypatch.setattr(pipeline, "CONSTANT_BATCH_WINDOW_S", 600.0)
    cal = calibrate(demo_dir)
    assert cal.info["windows"] == pytest.approx(
        {**cal.info["windows"], "window_s": 600.0, "n_windows": 3, "constant": True})
    assert cal.series is None and not cal.events
    assert any("constant biases from 3 windows" in w for w in cal.warnings)
    batch = graph(demo)
    for i, label in enumerate(cal.labels):
        j = batch.labels.index(label)
        sigma = np.sqrt(batch.covariance[j, j])
        assert abs(cal.estimate[i] - batch.estimate[j]) < 0.5 * sigma, label


def test_the_command_does_not_load_a_long_recording_whole(demo_dir, monkeypatch,
                                                          tmp_path: Path) -> None:
    """``graphcal calibrate`` on a long recording (here the demo against a 15-minute
    limit) passes the folder to the pipeline, which reads it window by window."""
    import json

    from typer.testing import CliRunner

    import graphcal.cli.calibrate as command
    import graphcal.io.folder as folder
    import graphcal.pipeline.calibrate as pipeline
    from graphcal.cli.app import app

    monkeypatch.setattr(pipeline, "CONSTANT_BATCH_MIN_SPAN_S", 900.0)
    monkeypatch.setattr(pipeline, "CONSTANT_BATCH_WINDOW_S", 600.0)

    def no_whole_load(*args, **kwargs):
        raise AssertionError("loaded whole")

    monkeypatch.setattr(folder, "load_dataset", no_whole_load)
    del command
    out = tmp_path / "r.json"
    result = CliRunner().invoke(app, ["calibrate", str(demo_dir), "--out", str(out)])
    assert result.exit_code == 0, result.output
    info = json.loads(out.read_text())["info"]
    assert info["windows"]["constant"] is True and info["windows"]["n_windows"] == 3


@pytest.mark.parametrize(("seconds_per_window", "loads"), [(0.1, False), (0.4, True)])
def test_compiled_loops_load_after_three_windows_that_were_slow_enough(
        monkeypatch, seconds_per_window: float, loads: bool) -> None:
    import types

    import graphcal.pipeline.windowed as windowed

    clock = [0.0]
    monkeypatch.setattr(windowed, "time", types.SimpleNamespace(perf_counter=lambda: clock[0]))
    monkeypatch.setattr(windowed.path_kernels, "enabled", lambda: False)
    loaded = []
    monkeypatch.setattr(windowed.path_kernels, "enable", lambda: loaded.append(clock[0]))
    prepare = windowed._CompiledLoopsWhenWorthIt()
    for number in range(7):
        prepare(number)
        # The first window also loads the solvers: it is not counted.
        clock[0] += 2.0 if number == 0 else seconds_per_window
    # Asked at the fifth window (after three timed ones), when they pay: then at every
    # later one too here, since `enabled` is held at False.
    assert bool(loaded) == loads
    if loads:
        assert loaded[0] == pytest.approx(2.0 + 3 * seconds_per_window)
