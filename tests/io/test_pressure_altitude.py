"""Pressure altitudes (contract v2) on input: ``[dataset] plot_altitude``, ADS-B ``baro_alt_m``.

Covers the dataset folder (read, validate, write back, version-1 files unchanged), the
OpenSky import and the ASTERIX CAT021 I145 round trip.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.core.errors import DatasetError
from graphcal.data.dataset import Dataset
from graphcal.io.asterix.decode import decode_bytes
from graphcal.io.asterix.encode import encode_dataset
from graphcal.io.asterix.tables import build_tables, load_user_sites
from graphcal.io.folder import (
    load_dataset,
    load_plot_altitude,
    load_sites,
    write_dataset,
    write_sites,
)
from graphcal.io.opensky import FOOT_M, read_opensky_adsb
from tests.io.test_dataset import ADSB_HEADER, ADSB_ROWS, SITES, make_dataset

PRESSURE_SITES = '[dataset]\nplot_altitude = "pressure"\n\n' + SITES


# --------------------------------------------------------------------------- sites.toml
def test_plot_altitude_defaults_to_geometric(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "ds"))
    assert dataset.plot_altitude == "geometric" and not dataset.pressure_altitudes


def test_plot_altitude_pressure_is_read(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "ds", sites=PRESSURE_SITES))
    assert dataset.plot_altitude == "pressure" and dataset.pressure_altitudes
    assert list(dataset.sites) == ["A", "B"]  # the radars are read as before


@pytest.mark.parametrize(("table", "field", "words"), [
    ('[dataset]\nplot_altitude = "baro"\n', "dataset.plot_altitude", '"pressure"'),
    ("[dataset]\nplot_altitude = 1\n", "dataset.plot_altitude", "got 1"),
    ('[dataset]\nplot_height = "pressure"\n', "dataset.plot_height", "unknown key"),
    ('dataset = "pressure"\n', "dataset", "must be a table"),
])
def test_bad_dataset_table_names_file_table_and_field(
    tmp_path: Path, table: str, field: str, words: str
) -> None:
    folder = make_dataset(tmp_path / "ds", sites=table + "\n" + SITES)
    with pytest.raises(DatasetError) as info:
        load_dataset(folder)
    message = str(info.value)
    assert "sites.toml" in message and "[dataset]" in message and words in message
    assert info.value.field == field


def test_write_sites_round_trips_and_keeps_version_1_files(tmp_path: Path) -> None:
    folder = make_dataset(tmp_path / "ds")
    sites = load_sites(folder / "sites.toml")
    write_sites(sites, tmp_path / "v1.toml")
    text = (tmp_path / "v1.toml").read_text()
    assert "[dataset]" not in text and "plot_altitude" not in text
    write_sites(sites, tmp_path / "v2.toml", plot_altitude="pressure")
    assert load_plot_altitude(tmp_path / "v2.toml") == "pressure"
    assert load_sites(tmp_path / "v2.toml") == sites
    with pytest.raises(ValueError, match="plot_altitude"):
        write_sites(sites, tmp_path / "bad.toml", plot_altitude="baro")


def test_write_dataset_keeps_plot_altitude(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "ds", sites=PRESSURE_SITES))
    back = load_dataset(write_dataset(dataset, tmp_path / "out"))
    assert back.plot_altitude == "pressure"
    geometric = load_dataset(make_dataset(tmp_path / "ds1"))
    out = write_dataset(geometric, tmp_path / "out1")
    assert "[dataset]" not in (out / "sites.toml").read_text()


# --------------------------------------------------------------------------- ADS-B column
def test_baro_alt_m_is_read_with_nan_allowed(tmp_path: Path) -> None:
    rows = [row + f",{value}" for row, value in zip(ADSB_ROWS, ["9800.5", "", "nan"],
                                                      strict=True)]
    folder = make_dataset(tmp_path / "ds")
    (folder / "adsb.csv").write_text("\n".join([ADSB_HEADER + ",baro_alt_m", *rows]) + "\n")
    adsb = load_dataset(folder).adsb
    assert adsb is not None and adsb["baro_alt_m"].dtype == np.float64
    assert adsb["baro_alt_m"].iloc[0] == 9800.5
    assert adsb["baro_alt_m"].iloc[1:].isna().all()


@pytest.mark.parametrize(("value", "words"), [("inf", "not finite"), ("FL350", "not a number")])
def test_bad_baro_alt_m_names_row_and_column(tmp_path: Path, value: str, words: str) -> None:
    rows = [row + "," + ("9800" if i != 1 else value) for i, row in enumerate(ADSB_ROWS)]
    folder = make_dataset(tmp_path / "ds")
    (folder / "adsb.csv").write_text("\n".join([ADSB_HEADER + ",baro_alt_m", *rows]) + "\n")
    with pytest.raises(DatasetError) as info:
        load_dataset(folder)
    assert "adsb.csv" in str(info.value) and words in str(info.value)
    assert info.value.row == 2 and info.value.field == "baro_alt_m"


# --------------------------------------------------------------------------- OpenSky
def _states(**heights: list[float]) -> pd.DataFrame:
    t0 = 1633608000.0
    return pd.DataFrame({
        "timestamp": [t0, t0 + 1.0, t0 + 2.0],
        "icao24": ["4ca1b2"] * 3,
        "latitude": [48.0, 48.01, 48.02],
        "longitude": [2.0, 2.01, 2.02],
        **heights,
    })


def test_opensky_baroaltitude_beside_geoaltitude(tmp_path: Path) -> None:
    path = tmp_path / "states.csv"
    _states(geoaltitude=[10300.0, 10310.0, 10320.0], baroaltitude=[10100.0, np.nan, 10120.0],
            altitude=[1.0, 2.0, 3.0]).to_csv(path, index=False)
    adsb = read_opensky_adsb(path)
    assert adsb["alt_m"].tolist() == [10300.0, 10310.0, 10320.0]
    # baroaltitude [m] is preferred to altitude [ft]; a missing one stays NaN.
    assert adsb["baro_alt_m"].iloc[[0, 2]].tolist() == [10100.0, 10120.0]
    assert np.isnan(adsb["baro_alt_m"].iloc[1])
    assert adsb.attrs["baro_source"] == "baroaltitude"


def test_opensky_altitude_in_feet_beside_geoaltitude(tmp_path: Path) -> None:
    path = tmp_path / "states.csv"
    _states(geoaltitude=[10300.0, 10310.0, 10320.0],
            altitude=[33000.0, 33025.0, 33050.0]).to_csv(path, index=False)
    adsb = read_opensky_adsb(path)
    expected = np.array([33000.0, 33025.0, 33050.0]) * FOOT_M
    assert adsb["baro_alt_m"].to_numpy() == pytest.approx(expected)
    assert adsb.attrs["baro_source"] == "altitude"


@pytest.mark.parametrize("column", ["altitude", "baroaltitude"])
def test_opensky_barometric_height_alone_gives_no_baro_column(
    tmp_path: Path, column: str
) -> None:
    path = tmp_path / "states.csv"
    _states(**{column: [10000.0, 10010.0, 10020.0]}).to_csv(path, index=False)
    adsb = read_opensky_adsb(path)
    # alt_m already is the barometric altitude: a baro_alt_m beside it would be the same
    # number and would "determine" a height model of zero.
    assert "baro_alt_m" not in adsb and adsb.attrs["baro_source"] is None
    scale = FOOT_M if column == "altitude" else 1.0
    assert adsb["alt_m"].tolist() == pytest.approx([10000.0 * scale, 10010.0 * scale,
                                                    10020.0 * scale])
    assert adsb.attrs["height_source"] == f"{column} (barometric)"


# --------------------------------------------------------------------------- ASTERIX
def test_asterix_cat021_i145_round_trip(tmp_path: Path) -> None:
    folder = make_dataset(tmp_path / "ds")
    dataset = load_dataset(folder)
    adsb = dataset.adsb.copy()
    adsb["baro_alt_m"] = [9800.0, np.nan, 9811.7]
    sites = {rid: s for rid, s in dataset.sites.items() if not s.is_3d}
    plots = dataset.plots[dataset.plots["radar_id"].isin(list(sites))]
    data = encode_dataset(Dataset(sites, plots, adsb), {"A": (25, 201)})
    tables = build_tables(decode_bytes(data))
    back = tables.dataset.adsb.sort_values("time_s").reset_index(drop=True)
    lsb_m = 0.25 * 100.0 * FOOT_M  # I021/145: 1/4 FL
    assert abs(back["baro_alt_m"].iloc[0] - 9800.0) <= 0.5 * lsb_m
    assert np.isnan(back["baro_alt_m"].iloc[1])
    assert abs(back["baro_alt_m"].iloc[2] - 9811.7) <= 0.5 * lsb_m
    # The geometric height (I021/140) is carried on beside it.
    assert back["alt_m"].tolist() == pytest.approx(adsb["alt_m"].tolist(), abs=3.125 * FOOT_M)


def test_asterix_import_takes_plot_altitude_from_the_user_sites(tmp_path: Path) -> None:
    """CAT048 I090 is a pressure altitude: a user sites.toml that says so is carried on."""
    dataset = load_dataset(make_dataset(tmp_path / "ds"))
    sites = {rid: s for rid, s in dataset.sites.items() if not s.is_3d}
    plots = dataset.plots[dataset.plots["radar_id"].isin(list(sites))]
    data = encode_dataset(Dataset(sites, plots, dataset.adsb), {"A": (25, 201)})
    user = tmp_path / "user.toml"
    user.write_text(PRESSURE_SITES.replace('id = "A"', 'id = "A"\nsac = 25\nsic = 201'))
    tables = build_tables(decode_bytes(data), user_sites=load_user_sites(user))
    assert tables.dataset.plot_altitude == "pressure"
    out = write_dataset(tables.dataset, tmp_path / "imported")
    assert load_dataset(out).plot_altitude == "pressure"
    assert build_tables(decode_bytes(data)).dataset.plot_altitude == "geometric"
