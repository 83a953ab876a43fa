"""The calibration history database (graphcal.pipeline.history)."""

from __future__ import annotations

import hashlib
import math
import sqlite3
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd
import pytest

from graphcal.pipeline.history import (
    APPLICATION_ID,
    SCHEMA_VERSION,
    HistoryError,
    append_run,
    default_tolerances,
    flag_tolerances,
    key_unit,
    outside_tolerance,
    radar_ids,
    read_events,
    read_runs,
    read_series,
)

# Values chosen to be exactly representable or not (0.1, 1e-5): both must come back bit
# for bit.
WINDOWED = {
    "method": "graph",
    "radars": {"LAEG": {"range_offset_m": 240.0, "sigma": {"range_offset_m": 3.0}}},
    "series": {
        "window_s": 1800.0,
        "radars": {
            "LAEG": [
                {"t_start_s": 32400.0, "t_end_s": 34200.0, "n_plots": 5120,
                 "range_offset_m": 180.4, "range_gain": -0.00041, "azimuth_bias_mrad": 2.31,
                 "elevation_bias_mrad": None, "time_offset_s": 0.01,
                 "sigma": {"range_offset_m": 1.9, "range_gain": 1.7e-5,
                           "azimuth_bias_mrad": 0.1, "time_offset_s": 0.003}},
                {"t_start_s": 34200.0, "t_end_s": 36000.0, "n_plots": 4870,
                 "range_offset_m": 240.0, "range_gain": -0.00039, "azimuth_bias_mrad": 2.35,
                 "elevation_bias_mrad": None, "time_offset_s": 0.011,
                 "sigma": {"range_offset_m": 3.0, "range_gain": 1.8e-5,
                           "azimuth_bias_mrad": 0.1, "time_offset_s": 0.003}},
            ],
            "DOLE": [
                {"t_start_s": 32400.0, "t_end_s": 34200.0, "n_plots": 3001,
                 "range_offset_m": -12.5, "elevation_bias_mrad": -1.49,
                 "azimuth_sin_mrad": 0.9, "azimuth_cos_mrad": -0.25, "future_key_m": 7.0,
                 "sigma": {"range_offset_m": 2.0, "elevation_bias_mrad": 0.05,
                           "azimuth_sin_mrad": 0.02, "azimuth_cos_mrad": 0.03}},
            ],
        },
    },
    "events": [
        {"radar_id": "LAEG", "time_s": 34200.0, "kind": "step",
         "parameters": ["range_offset_m"], "size": {"range_offset_m": 59.1},
         "sigma": {"range_offset_m": 3.0}},
    ],
}
WINDOWED_PROVENANCE = {
    "dataset": "recordings/day1", "options": {"window": "30min", "method": "graph"},
    "graphcal_version": "0.1.0", "run_time_utc": "2024-05-01T14:00:00Z",
    "epoch_utc": "2024-05-01T00:00:00Z", "sensor_models": {"LAEG": "ssr-mode-s"},
}
SINGLE = {
    "method": "ls",
    "radars": {
        "LAEG": {"range_offset_m": 47.25, "range_gain": 0.000197, "azimuth_bias_mrad": 1.184,
                 "elevation_bias_mrad": None, "fixed": {"elevation_bias_mrad": 0.0},
                 "sigma": {"range_offset_m": 1.23, "range_gain": 1.08e-05,
                           "azimuth_bias_mrad": 0.0151},
                 "n_plots": 7267, "residuals": {"range_m": {"mean": 0.1}}},
    },
    "covariance": {"labels": [], "matrix": []},
}
SINGLE_PROVENANCE = {"dataset": Path("recordings/day2"), "t_start_s": 0.0, "t_end_s": 1800.0,
                     "options": {"out": Path("r.json")}}


@pytest.fixture
def db(tmp_path: Path) -> Path:
    path = tmp_path / "calib.db"
    assert append_run(path, WINDOWED, provenance=WINDOWED_PROVENANCE) == 1
    assert append_run(path, SINGLE, provenance=SINGLE_PROVENANCE) == 2
    return path


def _row(series: pd.DataFrame, run: int, radar: str, start: float, key: str) -> pd.Series:
    hit = series[(series.run_id == run) & (series.radar_id == radar)
                 & (series.t_start_s == start) & (series.key == key)]
    assert len(hit) == 1, (run, radar, start, key)
    return hit.iloc[0]


def test_round_trip_gives_back_every_value_and_sigma_exactly(db: Path) -> None:
    series = read_series(db)
    expected = []
    for rid, windows in WINDOWED["series"]["radars"].items():
        for window in windows:
            for key, value in window.items():
                if key in ("t_start_s", "t_end_s", "n_plots", "sigma") or value is None:
                    continue
                expected.append((1, rid, window["t_start_s"], key, value,
                                 window["sigma"].get(key)))
    for key in ("range_offset_m", "range_gain", "azimuth_bias_mrad"):
        expected.append((2, "LAEG", 0.0, key, SINGLE["radars"]["LAEG"][key],
                         SINGLE["radars"]["LAEG"]["sigma"][key]))
    assert len(series) == len(expected) == 16
    for run, rid, start, key, value, sigma in expected:
        row = _row(series, run, rid, start, key)
        assert row.value == value
        assert (math.isnan(row.sigma) if sigma is None else row.sigma == sigma)


def test_windows_keep_their_span_and_plots_and_a_single_run_spans_its_data(db: Path) -> None:
    series = read_series(db)
    row = _row(series, 1, "LAEG", 34200.0, "range_gain")
    assert (row.t_end_s, row.n_plots, row.sensor_model) == (36000.0, 4870, "ssr-mode-s")
    single = _row(series, 2, "LAEG", 0.0, "range_offset_m")
    assert (single.t_start_s, single.t_end_s, single.n_plots) == (0.0, 1800.0, 7267)
    assert pd.isna(single.sensor_model)
    # null (not estimated) and fixed values are not stored; the last-window copy in
    # "radars" of a windowed run is not stored twice
    assert not ((series.key == "elevation_bias_mrad") & (series.radar_id == "LAEG")).any()
    assert len(series[series.run_id == 1]) == 13


def test_rows_are_sorted_by_radar_time_run_and_contract_key(db: Path) -> None:
    series = read_series(db)
    assert list(series.radar_id.unique()) == ["DOLE", "LAEG"]
    dole = series[series.radar_id == "DOLE"].key.tolist()
    assert dole == ["range_offset_m", "elevation_bias_mrad", "azimuth_sin_mrad",
                    "azimuth_cos_mrad", "future_key_m"]
    laeg = series[series.radar_id == "LAEG"]
    assert laeg[["t_start_s", "run_id"]].drop_duplicates().values.tolist() == [
        [0.0, 2], [32400.0, 1], [34200.0, 1]]


def test_runs_keep_their_provenance(db: Path) -> None:
    runs = read_runs(db)
    assert runs.run_id.tolist() == [1, 2]
    first, second = runs.iloc[0], runs.iloc[1]
    assert first.method == "graph" and second.method == "ls"
    assert first.dataset == "recordings/day1" and second.dataset == "recordings/day2"
    assert first.options == {"window": "30min", "method": "graph"}
    assert second.options == {"out": "r.json"}
    assert (first.t_start_s, first.t_end_s, first.window_s) == (32400.0, 36000.0, 1800.0)
    assert (second.t_start_s, second.t_end_s) == (0.0, 1800.0)
    assert math.isnan(second.window_s)
    assert first.run_time_utc == pd.Timestamp("2024-05-01T14:00:00Z")
    assert first.epoch_utc == pd.Timestamp("2024-05-01T00:00:00Z")
    assert pd.isna(second.epoch_utc)
    assert first.graphcal_version == "0.1.0"
    assert (first.n_radars, second.n_radars) == (2, 1)
    now = datetime.now(UTC)
    assert abs((now - second.run_time_utc.to_pydatetime()).total_seconds()) < 60


def test_events_come_back_with_their_size_and_sigma(db: Path) -> None:
    events = read_events(db)
    assert len(events) == 1
    event = events.iloc[0]
    assert (event.run_id, event.radar_id, event.time_s, event.kind) == (1, "LAEG", 34200.0,
                                                                      "step")
    assert (event["key"], event["size"], event["sigma"]) == ("range_offset_m", 59.1, 3.0)
    assert event.time_utc == pd.Timestamp("2024-05-01T09:30:00Z")


def test_radar_and_since_filters(db: Path) -> None:
    assert radar_ids(db) == ["DOLE", "LAEG"]
    assert set(read_series(db, radar="DOLE").radar_id) == {"DOLE"}
    # windows ending after 34200 s: LAEG's second window of run 1 only
    late = read_series(db, since=34200.0)
    assert set(zip(late.run_id, late.t_start_s, strict=True)) == {(1, 34200.0)}
    assert read_events(db, since=34200.0).empty
    assert len(read_events(db, since=34199.0)) == 1
    # a UTC time keeps only runs with an epoch: run 1 (epoch midnight) after 09:00
    utc = read_series(db, since=datetime(2024, 5, 1, 9, 0, tzinfo=UTC))
    assert set(utc.run_id) == {1} and len(utc) == 13
    assert read_series(db, since=datetime(2024, 5, 1, 9, 30)).t_start_s.unique().tolist() == [
        34200.0]


def test_an_unknown_radar_is_an_error_naming_the_known_ones(db: Path) -> None:
    with pytest.raises(HistoryError, match="no radar 'NOPE'; known: DOLE, LAEG"):
        read_series(db, radar="NOPE")


def test_the_schema_version_and_application_id_are_set(db: Path) -> None:
    con = sqlite3.connect(db)
    try:
        assert con.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION == 1
        assert con.execute("PRAGMA application_id").fetchone()[0] == APPLICATION_ID
    finally:
        con.close()


def test_a_newer_schema_is_refused_for_reading_and_writing(db: Path) -> None:
    con = sqlite3.connect(db)
    con.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    con.close()
    for action in (lambda: read_series(db), lambda: read_runs(db),
                   lambda: append_run(db, SINGLE, provenance=SINGLE_PROVENANCE)):
        with pytest.raises(HistoryError, match="newer graphcal .schema version 2"):
            action()


def test_files_that_are_not_histories_are_refused_untouched(tmp_path: Path) -> None:
    text = tmp_path / "notes.db"
    text.write_text("not a database at all, just some text that is long enough\n" * 20)
    other = tmp_path / "other.db"
    con = sqlite3.connect(other)
    con.execute("CREATE TABLE t (a)")
    con.commit()
    con.close()
    for path in (text, other):
        before = path.read_bytes()
        with pytest.raises(HistoryError, match="not a graphcal history"):
            read_series(path)
        with pytest.raises(HistoryError, match="not a graphcal history"):
            append_run(path, SINGLE, provenance=SINGLE_PROVENANCE)
        assert path.read_bytes() == before
    with pytest.raises(HistoryError, match="no such file"):
        read_runs(tmp_path / "missing.db")
    assert not (tmp_path / "missing.db").exists()
    with pytest.raises(HistoryError, match="does not exist"):
        append_run(tmp_path / "no" / "calib.db", SINGLE, provenance=SINGLE_PROVENANCE)


def test_an_empty_file_becomes_a_history(tmp_path: Path) -> None:
    path = tmp_path / "calib.db"
    path.touch()
    assert append_run(path, SINGLE, provenance=SINGLE_PROVENANCE) == 1
    assert len(read_series(path)) == 3


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_failing_insert_leaves_the_database_unchanged(db: Path) -> None:
    before_bytes, before_series, before_runs = _digest(db), read_series(db), read_runs(db)
    window = {"t_start_s": 0.0, "t_end_s": 60.0, "range_offset_m": 1.0}
    bad = {"radars": {}, "series": {"window_s": 60.0, "radars": {
        "A": [window, {**window, "t_start_s": 60.0, "t_end_s": 120.0}],
        "B": [window, window],  # two windows starting at 0 s: the insert of the second fails
    }}}
    with pytest.raises(HistoryError, match="two windows of radar B start at 0.0 s"):
        append_run(db, bad, provenance={"dataset": "x"})
    assert _digest(db) == before_bytes
    pd.testing.assert_frame_equal(read_series(db), before_series)
    pd.testing.assert_frame_equal(read_runs(db), before_runs)
    assert append_run(db, SINGLE, provenance=SINGLE_PROVENANCE) == 3


def test_a_failing_first_run_leaves_no_file(tmp_path: Path) -> None:
    window = {"t_start_s": 0.0, "t_end_s": 60.0, "range_offset_m": 1.0}
    bad = {"radars": {}, "series": {"window_s": 60.0, "radars": {"B": [window, window]}}}
    with pytest.raises(HistoryError):
        append_run(tmp_path / "calib.db", bad, provenance={"dataset": "x"})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("result", "provenance", "message"), [
    (SINGLE, {"dataset": "x"}, "needs its time span"),
    (SINGLE, {"t_start_s": 0.0, "t_end_s": 1.0}, "provenance.dataset"),
    (SINGLE, {**SINGLE_PROVENANCE, "window": "1h"}, "unknown key.s. window"),
    (SINGLE, {**SINGLE_PROVENANCE, "t_end_s": -1.0}, "before t_start_s"),
    (SINGLE, {**SINGLE_PROVENANCE, "options": {"f": object()}}, "provenance.options"),
    (SINGLE, {**SINGLE_PROVENANCE, "epoch_utc": "yesterday"}, "not an ISO 8601 time"),
    ({"radars": {"A": {"range_offset_m": "12"}}}, SINGLE_PROVENANCE, "radars.A.range_offset_m"),
    ({"radars": {"A": {"range_offset_m": 1.0, "sigma": {"range_offset_m": -1.0}}}},
     SINGLE_PROVENANCE, "negative sigma"),
    ({"radars": {}}, {**SINGLE_PROVENANCE}, None),
    ({"radars": {}, "series": {"window_s": 60.0, "radars": {"A": [
        {"t_start_s": 60.0, "t_end_s": 0.0}]}}}, {"dataset": "x"}, "ends .0.0. before"),
    ({"radars": {}, "events": [{"time_s": 1.0}]}, SINGLE_PROVENANCE, "events.0..radar_id"),
])
def test_malformed_runs_are_refused_with_the_field(tmp_path: Path, result, provenance,
                                                   message) -> None:
    path = tmp_path / "calib.db"
    if message is None:  # a run with no radars is fine: it is recorded, without rows
        assert append_run(path, result, provenance=provenance) == 1
        assert read_series(path).empty
        return
    with pytest.raises(HistoryError, match=message):
        append_run(path, result, provenance=provenance)
    assert not path.exists()


def test_key_units() -> None:
    assert [key_unit(k) for k in ("range_offset_m", "range_gain", "azimuth_bias_mrad",
                                  "time_offset_s", "azimuth_sin_mrad", "lat_deg", "other")] == [
        "m", "fraction", "mrad", "s", "mrad", "deg", ""]


# --------------------------------------------------------------------------- tolerances


def _frame(rows: list[tuple]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["radar_id", "sensor_model", "key", "value", "sigma"])


def test_flags_against_hand_computed_expectations() -> None:
    series = _frame([
        ("A", None, "range_offset_m", 103.0, 1.0),    # 103 - 2 = 101 > 100: outside
        ("A", None, "range_offset_m", 101.0, 1.0),    # 101 > 100, 99 <= 100: possibly
        ("A", None, "range_offset_m", -103.0, 1.0),   # the magnitude counts: outside
        ("A", None, "range_offset_m", 99.0, 5.0),     # 99 <= 100 (band beyond): within
        ("A", None, "range_offset_m", 100.0, 0.0),    # on the tolerance: within
        ("A", None, "range_offset_m", 101.0, math.nan),  # unknown sigma: possibly
        ("A", None, "azimuth_bias_mrad", 2.9, 0.1),   # 2.9 <= 3: within
        ("A", None, "azimuth_bias_mrad", 3.5, 0.2),   # 3.5 - 0.4 = 3.1 > 3: outside
        ("A", None, "future_key_m", 1e9, 1.0),        # no tolerance: unchecked
    ])
    flagged = flag_tolerances(series, {"range_offset_m": 100.0})
    assert flagged.status.tolist() == ["outside", "possibly", "outside", "within", "within",
                                       "possibly", "within", "outside", "unchecked"]
    assert flagged.tolerance.tolist()[:8] == [100.0] * 6 + [3.0] * 2
    assert flagged.tolerance_source.tolist()[:8] == ["given"] * 6 + ["default"] * 2
    outside = outside_tolerance(series, {"range_offset_m": 100.0})
    assert outside.value.tolist() == [103.0, 101.0, -103.0, 101.0, 3.5]


def test_default_tolerances_are_twice_the_sensor_models_typical_bias() -> None:
    # models/ssr-mode-s.toml: typical range offset 50 m, gain 2e-4, azimuth 1.5 mrad,
    # time 0.05 s; air-defence-3d: 150 m, 5e-4, 3 mrad, elevation 3 mrad, 0.1 s
    assert default_tolerances("ssr-mode-s")["range_offset_m"] == 100.0
    assert default_tolerances("ssr-mode-s")["range_gain"] == pytest.approx(4e-4)
    assert default_tolerances("air-defence-3d")["range_offset_m"] == 300.0
    assert default_tolerances("air-defence-3d")["elevation_bias_mrad"] == 6.0
    assert default_tolerances(None) == {
        "range_offset_m": 100.0, "range_gain": 4e-4, "azimuth_bias_mrad": 3.0,
        "elevation_bias_mrad": 6.0, "time_offset_s": 0.1, "azimuth_sin_mrad": 3.0,
        "azimuth_cos_mrad": 3.0,
    }


def test_default_tolerances_follow_each_rows_sensor_model() -> None:
    series = _frame([
        ("S", "ssr-mode-s", "range_offset_m", 150.0, 1.0),      # tolerance 100: outside
        ("D", "air-defence-3d", "range_offset_m", 150.0, 1.0),  # tolerance 300: within
        ("D", "air-defence-3d", "azimuth_bias_mrad", 5.0, 0.1),  # tolerance 6: within
        ("X", "no-such-model", "range_offset_m", 150.0, 1.0),   # fallback 100: outside
        ("D", "air-defence-3d", "azimuth_sin_mrad", 3.5, 0.1),  # model has none: 3
    ])
    flagged = flag_tolerances(series)
    assert flagged.tolerance.tolist() == [100.0, 300.0, 6.0, 100.0, 3.0]
    assert flagged.status.tolist() == ["outside", "within", "within", "outside", "outside"]
    assert flagged.tolerance_source.tolist() == ["ssr-mode-s", "air-defence-3d",
                                                 "air-defence-3d", "default", "default"]
    only = flag_tolerances(series, {"azimuth_bias_mrad": 4.0}, defaults=False)
    assert only.status.tolist() == ["unchecked", "unchecked", "outside", "unchecked",
                                    "unchecked"]


@pytest.mark.parametrize("value", [0.0, -1.0, math.inf, "50"])
def test_a_tolerance_must_be_a_positive_number(value) -> None:
    with pytest.raises(HistoryError, match="tolerance.range_offset_m"):
        flag_tolerances(_frame([]), {"range_offset_m": value})


def test_flags_work_on_what_the_database_gives_back(db: Path) -> None:
    flagged = flag_tolerances(read_series(db), {"range_offset_m": 200.0})
    row = flagged[(flagged.run_id == 1) & (flagged.key == "range_offset_m")
                  & (flagged.radar_id == "LAEG") & (flagged.t_start_s == 34200.0)].iloc[0]
    assert row.status == "outside"  # 240 - 2 * 3 = 234 > 200
    laeg_gain = flagged[(flagged.radar_id == "LAEG") & (flagged.key == "range_gain")]
    # LAEG is an ssr-mode-s in run 1 (4e-4: |-4.1e-4| > 4e-4 by less than 2 sigma), has no
    # model in run 2 (fallback 4e-4)
    assert laeg_gain.status.tolist() == ["within", "possibly", "within"]


def test_a_missing_sensor_model_uses_the_fallback_whatever_marks_it_missing() -> None:
    series = _frame([("A", None, "range_offset_m", 150.0, 1.0),
                     ("B", math.nan, "range_offset_m", 150.0, 1.0),
                     ("C", "", "range_offset_m", 50.0, 1.0)])
    flagged = flag_tolerances(series)
    assert flagged.tolerance.tolist() == [100.0] * 3
    assert flagged.status.tolist() == ["outside", "outside", "within"]
