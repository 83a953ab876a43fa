"""OpenSky-style tables to the contract ADS-B table."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.core.errors import DatasetError
from graphcal.io.opensky import (
    DROP_BAD_ADDRESS,
    DROP_NO_HEIGHT,
    DROP_NO_POSITION,
    DROP_ON_GROUND,
    DROP_STALE,
    FOOT_M,
    read_opensky_adsb,
    squawk_codes,
)
from tests.paths import SHARED_DATA

SHARED = SHARED_DATA
PARIS = SHARED / "opensky_paris_2021-10-07.parquet"
#: 2021-10-07 00:00:00 UTC.
MIDNIGHT = 1633564800.0


def _table() -> pd.DataFrame:
    t0 = MIDNIGHT + 12 * 3600.0
    return pd.DataFrame({
        "timestamp": [t0, t0 + 1, t0 + 2, t0 + 3, t0 + 4, t0 + 5, t0 + 1, t0 + 2],
        "icao24": ["4CA1B2", "4ca1b2", "4ca1b2", "4ca1b2", "4ca1b2", "4ca1b2", "zz", "3c660c"],
        "latitude": [48.0, 48.01, 48.01, np.nan, 48.03, 48.04, 48.0, 49.0],
        "longitude": [2.0, 2.01, 2.01, 2.02, 2.03, 2.04, 2.0, 2.5],
        "altitude": [10000.0, 10025.0, 10050.0, 10075.0, np.nan, 10125.0, 1.0, 0.0],
        "onground": [False, False, False, False, False, False, False, True],
    })


def test_cleaning_counts_units_and_time_base(tmp_path: Path) -> None:
    path = tmp_path / "states.csv"
    _table().to_csv(path, index=False)
    adsb = read_opensky_adsb(path)
    assert adsb.attrs["epoch_unix_s"] == MIDNIGHT
    assert adsb.attrs["height_source"] == "altitude (barometric)"
    assert adsb["time_s"].tolist() == [43200.0, 43201.0, 43205.0]
    assert adsb["target_id"].unique().tolist() == ["4ca1b2"]
    assert adsb["alt_m"].tolist() == pytest.approx(np.array([10000.0, 10025.0, 10125.0]) * FOOT_M)
    dropped = adsb.attrs["dropped"]
    assert dropped[DROP_NO_POSITION] == 1 and dropped[DROP_BAD_ADDRESS] == 1
    assert dropped[DROP_STALE] == 1 and dropped[DROP_ON_GROUND] == 1
    assert dropped[DROP_NO_HEIGHT] == 1
    assert list(adsb.columns) == ["time_s", "target_id", "lat_deg", "lon_deg", "alt_m"]


def test_datetimes_geoaltitude_lastposupdate_and_epoch(tmp_path: Path) -> None:
    table = _table().drop(columns=["onground"])
    table["lastposupdate"] = table["timestamp"] - 0.5
    table.loc[2, "lastposupdate"] = table.loc[1, "lastposupdate"]  # position not updated
    table.loc[5, ["latitude", "longitude"]] = table.loc[4, ["latitude", "longitude"]].to_numpy()
    table["timestamp"] = pd.to_datetime(table["timestamp"], unit="s", utc=True)
    table["geoaltitude"] = table["altitude"] * FOOT_M + 50.0
    path = tmp_path / "states.parquet"
    table.to_parquet(path)
    adsb = read_opensky_adsb(path, epoch_unix_s=MIDNIGHT - 86400.0)
    assert adsb.attrs["height_source"] == "geoaltitude"
    # lastposupdate is the time; row 5 repeats row 4's position but its update advanced.
    assert adsb["time_s"].tolist() == [129599.5, 129600.5, 129601.5, 129604.5]
    assert adsb.attrs["dropped"][DROP_STALE] == 1


def test_bad_tables(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="file not found"):
        read_opensky_adsb(tmp_path / "missing.csv")
    path = tmp_path / "bad.csv"
    pd.DataFrame({"timestamp": [1.0], "icao24": ["abcdef"], "latitude": [1.0]}).to_csv(path)
    with pytest.raises(DatasetError, match="longitude, geoaltitude or altitude"):
        read_opensky_adsb(path)
    pd.DataFrame({"timestamp": [1.0], "icao24": ["abcdef"], "latitude": [np.nan],
                  "longitude": [1.0], "altitude": [1.0]}).to_csv(path)
    with pytest.raises(DatasetError, match="no usable ADS-B row"):
        read_opensky_adsb(path)


def _squawk_table() -> pd.DataFrame:
    t0 = MIDNIGHT + 3600.0
    return pd.DataFrame({
        "timestamp": t0 + np.arange(6.0),
        "icao24": [f"4ca1b{k}" for k in range(6)],
        "latitude": 48.0, "longitude": 2.0, "geoaltitude": 9000.0,
    })


def test_squawk_becomes_mode_3a_zero_padded(tmp_path: Path) -> None:
    # In a CSV file: text, kept as text even when it looks like a number.
    path = tmp_path / "states.csv"
    table = _squawk_table()
    table["squawk"] = ["413", "0413", "7000", "", "8000", "12345"]
    table.to_csv(path, index=False)
    adsb = read_opensky_adsb(path)
    assert adsb["mode_3a"].tolist() == ["0413", "0413", "7000", "", "", ""]
    assert list(adsb.columns)[-1] == "mode_3a"
    # In a Parquet file: numbers (the digits are the code's octal digits) or text.
    for values in ([413.0, 7000.0, np.nan, 0.0, 7777.0, 413.5],
                   pd.array([413, 7000, None, 0, 7777, 99], dtype="Int64"),
                   ["413", "7000", None, "0", "7777", "0x1a"]):
        table["squawk"] = values
        table.to_parquet(tmp_path / "states.parquet")
        adsb = read_opensky_adsb(tmp_path / "states.parquet")
        assert adsb["mode_3a"].tolist() == ["0413", "7000", "", "0000", "7777", ""]


def test_without_squawk_no_mode_3a_column(tmp_path: Path) -> None:
    path = tmp_path / "states.csv"
    _squawk_table().to_csv(path, index=False)
    assert "mode_3a" not in read_opensky_adsb(path).columns


def test_squawk_codes_of_every_kind() -> None:
    assert squawk_codes(pd.Series([413, 7000, 8, 77])).tolist() == ["0413", "7000", "", "0077"]
    assert squawk_codes(pd.Series(["413.0", " 7700 ", "-413", "7 00"])).tolist() == \
        ["0413", "7700", "", ""]
    assert squawk_codes(pd.Series([True, False])).tolist() == ["", ""]
    assert squawk_codes(pd.Series([], dtype=float)).tolist() == []


@pytest.mark.skipif(not PARIS.exists(), reason="shared OpenSky table not available")
def test_shared_paris_table() -> None:
    adsb = read_opensky_adsb(PARIS)
    rows = adsb.attrs["rows_read"]
    dropped = adsb.attrs["dropped"]
    assert rows == 284505
    assert 0.15 < dropped[DROP_STALE] / rows < 0.25  # about a fifth only repeat a position
    assert adsb.attrs["epoch_unix_s"] == MIDNIGHT
    assert adsb["time_s"].between(12 * 3600.0, 15 * 3600.0).all()
    assert adsb["alt_m"].between(-500.0, 20000.0).all()
    assert adsb["alt_m"].median() == pytest.approx(2900.0, rel=0.1)  # ft converted to m
    assert adsb["target_id"].str.fullmatch("[0-9a-f]{6}").all()
    assert not adsb.duplicated(["target_id", "time_s"]).any()
    # Its squawks are text, some of 2 or 3 digits (leading zeros lost upstream): padded.
    codes = adsb["mode_3a"]
    assert (codes.str.fullmatch("[0-7]{4}") | codes.eq("")).all()
    assert codes.str.startswith("0").any() and codes.eq("").mean() < 0.01
