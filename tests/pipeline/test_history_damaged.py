"""A history database changed outside graphcal (a bad cell) is refused with one line
naming the file and the field, never a traceback."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from graphcal.pipeline.history import HistoryError, read_events, read_runs, read_series
from tests.pipeline.test_history import (
    SINGLE,
    SINGLE_PROVENANCE,
    WINDOWED,
    WINDOWED_PROVENANCE,
)


@pytest.fixture
def db(tmp_path: Path) -> Path:
    from graphcal.pipeline.history import append_run

    path = tmp_path / "calib.db"
    append_run(path, WINDOWED, provenance=WINDOWED_PROVENANCE)
    append_run(path, SINGLE, provenance=SINGLE_PROVENANCE)
    return path


def _edit(path: Path, sql: str) -> None:
    with sqlite3.connect(path) as con:
        con.execute(sql)


@pytest.mark.parametrize(("sql", "reader", "field"), [
    ("UPDATE estimates SET value = 'abc' WHERE rowid = 1", read_series, "value"),
    ("UPDATE estimates SET sigma = -1 WHERE rowid = 1", read_series, "sigma"),
    ("UPDATE estimates SET value = 1e999 WHERE rowid = 1", read_series, "value"),
    ("UPDATE runs SET epoch_utc = 'not-a-date'", read_series, "epoch_utc"),
    ("UPDATE runs SET epoch_utc = 'not-a-date'", read_runs, "epoch_utc"),
    ("UPDATE runs SET options_json = '{not json'", read_runs, "options_json"),
    ("UPDATE runs SET window_s = -5 WHERE window_s IS NOT NULL", read_runs, "window_s"),
    ("UPDATE events SET time_s = 'soon'", read_events, "time_s"),
])
def test_a_bad_cell_is_named(db: Path, sql: str, reader, field: str) -> None:
    _edit(db, sql)
    with pytest.raises(HistoryError) as caught:
        reader(db)
    assert caught.value.field == field
    assert str(db) in str(caught.value)
    assert "changed outside graphcal" in str(caught.value)


def test_an_intact_database_reads_as_before(db: Path) -> None:
    series = read_series(db)
    assert series["value"].dtype == float and series["sigma"].dtype == float
    assert str(series["n_plots"].dtype) == "Int64"
    assert len(read_runs(db)) == 2
