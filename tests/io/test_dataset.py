"""Tests of graphcal.io.folder: reading, validating and writing dataset folders."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.core.atomic import atomic_write_text
from graphcal.core.errors import DatasetError
from graphcal.core.refraction import Atmosphere
from graphcal.data.dataset import ADSB_DEFAULT_SIGMA_M, Dataset, Site
from graphcal.data.sensor_models import load_sensor_model
from graphcal.io.folder import load_dataset, load_sites, write_dataset, write_sites

# Radar "A" is 2-D, radar "B" is 3-D.
SITES = """\
[[radar]]
id = "A"
lat_deg = 47.4817
lon_deg = 8.3967
alt_m = 866.0
sigma_range_m = 40.0
sigma_azimuth_mrad = 1.0
scan_period_s = 4.0

[[radar]]
id = "B"
lat_deg = 46.9
lon_deg = 7.5
alt_m = 950
sigma_range_m = 100.0
sigma_azimuth_mrad = 2.0
sigma_elevation_mrad = 3.0
"""

PLOT_HEADER = "radar_id,time_s,range_m,azimuth_deg,elevation_deg,target_id,altitude_m"
PLOT_ROWS = [
    "A,10.0,52000.5,12.25,,4B1805,10058.4",
    "B,11.5,81234.0,200.0,5.5,4b1805,",
    "A,14.0,51800.0,12.5,,,",
]
ADSB_HEADER = "time_s,target_id,lat_deg,lon_deg,alt_m,sigma_m,nacp"
ADSB_ROWS = [
    "10.0, 4B1805 ,47.8,8.6,10100.0,,9",
    "10.5,4b1805,47.81,8.61,10105.0,7.5,",
    "11.0,4b1805,47.82,8.62,10110.0,,",
]


def csv_text(header: str, rows: list[str]) -> str:
    """A CSV file's text from its header and data lines."""
    return "\n".join([header, *rows]) + "\n"


def make_dataset(
    folder: Path,
    *,
    sites: str = SITES,
    plots: list[str] | None = None,
    adsb: list[str] | None = None,
    with_adsb: bool = True,
) -> Path:
    """Write a small valid dataset (CSV) into ``folder``, with optional replacements."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sites.toml").write_text(sites)
    (folder / "plots.csv").write_text(csv_text(PLOT_HEADER, PLOT_ROWS if plots is None else plots))
    if with_adsb:
        (folder / "adsb.csv").write_text(csv_text(ADSB_HEADER, ADSB_ROWS if adsb is None else adsb))
    return folder


def replace_cell(rows: list[str], row: int, column: int, value: str) -> list[str]:
    """``rows`` with the cell of data row ``row`` (1-based) and ``column`` replaced."""
    out = list(rows)
    cells = out[row - 1].split(",")
    cells[column] = value
    out[row - 1] = ",".join(cells)
    return out


def listing(folder: Path) -> dict[str, tuple[int, int]]:
    """Every entry below ``folder`` with its size and modification time."""
    return {
        str(path.relative_to(folder)): (path.stat().st_size, path.stat().st_mtime_ns)
        for path in sorted(folder.rglob("*"))
    }


def assert_error(folder: Path, file_name: str, row: int | None, field: str | None) -> str:
    """Load ``folder``, expect a DatasetError naming file, row and field; return its text."""
    with pytest.raises(DatasetError) as info:
        load_dataset(folder)
    message = str(info.value)
    assert file_name in message
    if row is not None:
        assert f"row {row}" in message
        assert info.value.row == row
    if field is not None:
        assert field in message
        assert info.value.field == field
    return message


# --------------------------------------------------------------------------- reading


def test_load_valid_dataset_normalises_the_tables(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "ds"))
    assert dataset.radar_ids == ["A", "B"]
    assert dataset.path == tmp_path / "ds"
    plots = dataset.plots
    assert list(plots.columns) == [
        "radar_id", "time_s", "range_m", "azimuth_deg", "elevation_deg", "target_id", "altitude_m",
    ]
    assert plots["target_id"].tolist() == ["4b1805", "4b1805", ""]
    assert plots["range_m"].tolist() == [52000.5, 81234.0, 51800.0]
    assert np.isnan(plots["elevation_deg"].iloc[0]) and plots["elevation_deg"].iloc[1] == 5.5
    assert plots["altitude_m"].iloc[0] == 10058.4 and np.isnan(plots["altitude_m"].iloc[1])
    for column in ("time_s", "range_m", "azimuth_deg", "elevation_deg", "altitude_m"):
        assert plots[column].dtype == np.float64
    adsb = dataset.adsb
    assert adsb is not None
    assert adsb["target_id"].tolist() == ["4b1805"] * 3
    assert str(adsb["nacp"].dtype) == "Int64"
    assert adsb["nacp"].iloc[0] == 9 and adsb["nacp"].isna().iloc[1]


def test_sites_are_converted_to_radians(tmp_path: Path) -> None:
    sites = load_dataset(make_dataset(tmp_path / "ds")).sites
    a, b = sites["A"], sites["B"]
    assert a.lat_rad == pytest.approx(math.radians(47.4817))
    assert a.sigma_azimuth_rad == pytest.approx(1e-3)
    assert a.scan_period_s == 4.0
    assert not a.is_3d and a.estimate == ("range_offset", "range_gain", "azimuth_bias")
    assert b.is_3d and b.sigma_elevation_rad == pytest.approx(3e-3)
    assert b.alt_m == 950.0 and b.scan_period_s is None and b.model is None


def test_adsb_sigma_from_value_then_nacp_then_default(tmp_path: Path) -> None:
    adsb = load_dataset(make_dataset(tmp_path / "ds")).adsb
    assert adsb is not None
    sigma = adsb["sigma_m"].to_numpy()
    assert sigma[0] == pytest.approx(30.0 / 2.4477)  # NACp 9
    assert sigma[1] == 7.5  # given
    assert sigma[2] == ADSB_DEFAULT_SIGMA_M == 30.0  # neither


def test_given_sigma_wins_over_nacp(tmp_path: Path) -> None:
    rows = replace_cell(ADSB_ROWS, 1, 5, "4.0")
    adsb = load_dataset(make_dataset(tmp_path / "ds", adsb=rows)).adsb
    assert adsb is not None and adsb["sigma_m"].iloc[0] == 4.0


def test_adsb_without_optional_columns(tmp_path: Path) -> None:
    folder = make_dataset(tmp_path / "ds", with_adsb=False)
    rows = [",".join(r.split(",")[:5]) for r in ADSB_ROWS]
    (folder / "adsb.csv").write_text(csv_text("time_s,target_id,lat_deg,lon_deg,alt_m", rows))
    adsb = load_dataset(folder).adsb
    assert adsb is not None
    assert "nacp" not in adsb.columns
    assert (adsb["sigma_m"] == ADSB_DEFAULT_SIGMA_M).all()


def test_adsb_is_optional(tmp_path: Path) -> None:
    assert load_dataset(make_dataset(tmp_path / "ds", with_adsb=False)).adsb is None


def test_missing_altitude_column_is_added_as_nan(tmp_path: Path) -> None:
    folder = make_dataset(tmp_path / "ds")
    rows = [",".join(r.split(",")[:6]) for r in PLOT_ROWS]
    header = ",".join(PLOT_HEADER.split(",")[:6])
    (folder / "plots.csv").write_text(csv_text(header, rows))
    plots = load_dataset(folder).plots
    assert plots["altitude_m"].isna().all()


def test_ids_stay_text(tmp_path: Path) -> None:
    sites = SITES.replace('id = "A"', 'id = "007"')
    plots = [r.replace("A,", "007,", 1) if r.startswith("A,") else r for r in PLOT_ROWS]
    plots = replace_cell(plots, 2, 5, "000123")
    dataset = load_dataset(make_dataset(tmp_path / "ds", sites=sites, plots=plots))
    assert dataset.plots["radar_id"].tolist() == ["007", "B", "007"]
    assert dataset.plots["target_id"].iloc[1] == "000123"


def test_2d_radar_elevation_is_kept(tmp_path: Path) -> None:
    plots = replace_cell(PLOT_ROWS, 1, 4, "1.25")
    dataset = load_dataset(make_dataset(tmp_path / "ds", plots=plots))
    assert dataset.plots["elevation_deg"].iloc[0] == 1.25


def test_extra_columns_are_kept_after_the_contract_columns(tmp_path: Path) -> None:
    folder = make_dataset(tmp_path / "ds")
    rows = [f"{r},{i}" for i, r in enumerate(PLOT_ROWS)]
    (folder / "plots.csv").write_text(csv_text(PLOT_HEADER + ",snr_db", rows))
    plots = load_dataset(folder).plots
    assert list(plots.columns)[-1] == "snr_db"
    assert plots["snr_db"].tolist() == [0, 1, 2]


def test_blank_lines_are_skipped_and_keep_line_numbers(tmp_path: Path) -> None:
    plots = [PLOT_ROWS[0], "", replace_cell(PLOT_ROWS, 2, 3, "400")[1]]
    folder = make_dataset(tmp_path / "ds", plots=plots)
    message = assert_error(folder, "plots.csv", 3, "azimuth_deg")
    assert "line 4" in message
    ok = make_dataset(tmp_path / "ok", plots=[PLOT_ROWS[0], "", PLOT_ROWS[1], ""])
    assert len(load_dataset(ok).plots) == 2


def test_load_dataset_writes_nothing(tmp_path: Path) -> None:
    csv_folder = make_dataset(tmp_path / "csv")
    parquet_folder = write_dataset(load_dataset(csv_folder), tmp_path / "pq", fmt="parquet")
    for folder in (csv_folder, parquet_folder):
        before = listing(folder)
        parent_before = sorted(os.listdir(folder.parent))
        load_dataset(folder)
        assert listing(folder) == before
        assert sorted(os.listdir(folder.parent)) == parent_before


def test_parquet_input_is_validated_too(tmp_path: Path) -> None:
    folder = write_dataset(load_dataset(make_dataset(tmp_path / "src")), tmp_path / "pq",
                           fmt="parquet")
    plots = pd.read_parquet(folder / "plots.parquet")
    plots.loc[1, "azimuth_deg"] = 360.0
    plots.to_parquet(folder / "plots.parquet", index=False)
    assert_error(folder, "plots.parquet", 2, "azimuth_deg")


def test_parquet_text_in_numeric_column(tmp_path: Path) -> None:
    folder = write_dataset(load_dataset(make_dataset(tmp_path / "src")), tmp_path / "pq",
                           fmt="parquet")
    plots = pd.read_parquet(folder / "plots.parquet")
    plots["range_m"] = ["1000", "12 km", "2000"]
    plots.to_parquet(folder / "plots.parquet", index=False)
    message = assert_error(folder, "plots.parquet", 2, "range_m")
    assert "12 km" in message


# --------------------------------------------------------------------------- bad input


PLOT_CASES = [
    # (data row, column index, bad value, field, text in the message)
    (2, 0, "ZZ", "radar_id", "unknown radar"),
    (2, 0, "", "radar_id", "missing radar id"),
    (2, 1, "", "time_s", "missing"),
    (3, 1, "inf", "time_s", "not finite"),
    (2, 2, "-1.0", "range_m", "negative"),
    (2, 2, "abc", "range_m", "not a number"),
    (1, 2, "nan", "range_m", "missing"),
    (2, 3, "360", "azimuth_deg", "outside"),
    (3, 3, "-0.5", "azimuth_deg", "outside"),
    (2, 4, "", "elevation_deg", "3-D radar"),
    (2, 4, "90.5", "elevation_deg", "outside"),
    (1, 4, "-91", "elevation_deg", "outside"),
    (2, 4, "x", "elevation_deg", "not a number"),
    (2, 6, "-inf", "altitude_m", "not finite"),
]


@pytest.mark.parametrize(("row", "column", "value", "field", "text"), PLOT_CASES)
def test_bad_plot_cell(
    tmp_path: Path, row: int, column: int, value: str, field: str, text: str
) -> None:
    plots = replace_cell(PLOT_ROWS, row, column, value)
    message = assert_error(make_dataset(tmp_path / "ds", plots=plots), "plots.csv", row, field)
    assert text in message
    assert f"line {row + 1}" in message


ADSB_CASES = [
    (2, 0, "soon", "time_s", "not a number"),
    (3, 1, " ", "target_id", "missing target id"),
    (2, 2, "90.5", "lat_deg", "outside"),
    (1, 3, "-180.5", "lon_deg", "outside"),
    (3, 4, "inf", "alt_m", "not finite"),  # empty is allowed: no geometric height
    (2, 5, "0", "sigma_m", "positive"),
    (3, 5, "-3", "sigma_m", "positive"),
    (3, 5, "inf", "sigma_m", "not finite"),
    (2, 6, "12", "nacp", "0..11"),
    (3, 6, "8.5", "nacp", "0..11"),
]


@pytest.mark.parametrize(("row", "column", "value", "field", "text"), ADSB_CASES)
def test_bad_adsb_cell(
    tmp_path: Path, row: int, column: int, value: str, field: str, text: str
) -> None:
    adsb = replace_cell(ADSB_ROWS, row, column, value)
    message = assert_error(make_dataset(tmp_path / "ds", adsb=adsb), "adsb.csv", row, field)
    assert text in message


def test_row_with_too_many_fields(tmp_path: Path) -> None:
    plots = replace_cell(PLOT_ROWS, 2, 3, "12,5")  # a decimal comma adds a field
    message = assert_error(make_dataset(tmp_path / "ds", plots=plots), "plots.csv", 2, None)
    assert "8 fields" in message and "line 3" in message


def test_first_offending_row_is_reported(tmp_path: Path) -> None:
    # Row 3 fails in an early column, row 2 in a late one: row 2 comes first in the file.
    plots = replace_cell(PLOT_ROWS, 3, 0, "ZZ")
    plots = replace_cell(plots, 2, 3, "999")
    assert_error(make_dataset(tmp_path / "ds", plots=plots), "plots.csv", 2, "azimuth_deg")


SITE_CASES = [
    # (old text, new text, row, field)
    ('id = "B"', 'id = "A"', 2, "id"),
    ('id = "B"', 'id = "  "', 2, "id"),
    ('id = "B"\n', "", 2, "id"),
    ("lat_deg = 47.4817", "lat_deg = 90.5", 1, "lat_deg"),
    ("lon_deg = 7.5", "lon_deg = -180.1", 2, "lon_deg"),
    ("lat_deg = 46.9\n", "", 2, "lat_deg"),
    ("alt_m = 950", 'alt_m = "high"', 2, "alt_m"),
    ("sigma_range_m = 40.0", "sigma_range_m = 0.0", 1, "sigma_range_m"),
    ("sigma_azimuth_mrad = 2.0", "sigma_azimuth_mrad = -1.0", 2, "sigma_azimuth_mrad"),
    ("sigma_elevation_mrad = 3.0", "sigma_elevation_mrad = 0", 2, "sigma_elevation_mrad"),
    ("scan_period_s = 4.0", "scan_period_s = 0.0", 1, "scan_period_s"),
    ("scan_period_s = 4.0", "scan_period_s = 4.0\nmodel = 'no-such-radar'", 1, "model"),
    ("scan_period_s = 4.0", "scan_period_s = 4.0\nestimate = ['elevation_bias']", 1, "estimate"),
    ("scan_period_s = 4.0", "scan_period_s = 4.0\nestimate = ['range_bias']", 1, "estimate"),
    ("scan_period_s = 4.0", "scan_period_s = 4.0\nestimate = []", 1, "estimate"),
    ("scan_period_s = 4.0", "scan_period_s = 4.0\nsigma_elevaton_mrad = 2.0", 1,
     "sigma_elevaton_mrad"),
    # Contract v2, refraction.
    ("alt_m = 950", 'alt_m = 950\nrefraction = "ray-trace"', 2, "refraction"),
    ("alt_m = 950", "alt_m = 950\nrefraction = 1", 2, "refraction"),
    ("alt_m = 950", 'alt_m = 950\nrefraction = "exponential"\nrefractivity_n_s = 501.0', 2,
     "refractivity_n_s"),
    ("alt_m = 950", "alt_m = 950\nrefractivity_n_s = -1", 2, "refractivity_n_s"),
    ("alt_m = 950", 'alt_m = 950\nrefractivity_n_s = "320"', 2, "refractivity_n_s"),
    ("alt_m = 950", "alt_m = 950\nrefractivity_scale_height_m = 0", 2,
     "refractivity_scale_height_m"),
    ("alt_m = 866.0", 'alt_m = 866.0\nrefraction = "exponential"\n'
     "refractivity_n_s = 400\nrefractivity_scale_height_m = 4000", 1,
     "refractivity_scale_height_m"),
]


@pytest.mark.parametrize(("old", "new", "row", "field"), SITE_CASES)
def test_bad_site(tmp_path: Path, old: str, new: str, row: int, field: str) -> None:
    assert old in SITES
    folder = make_dataset(tmp_path / "ds", sites=SITES.replace(old, new, 1))
    assert_error(folder, "sites.toml", row, field)


def test_bad_refraction_messages(tmp_path: Path) -> None:
    text = SITES.replace("alt_m = 950", 'alt_m = 950\nrefraction = "ray-trace"')
    message = assert_error(make_dataset(tmp_path / "a", sites=text), "sites.toml", 2,
                           "refraction")
    assert "radar 'B'" in message and '"none", "exponential"' in message
    text = SITES.replace("alt_m = 950", "alt_m = 950\nrefractivity_n_s = 600")
    message = assert_error(make_dataset(tmp_path / "b", sites=text), "sites.toml", 2,
                           "refractivity_n_s")
    assert "outside [0, 500]" in message
    text = SITES.replace("alt_m = 950", 'alt_m = 950\nrefraction = "exponential"\n'
                         "refractivity_scale_height_m = 3000")
    message = assert_error(make_dataset(tmp_path / "c", sites=text), "sites.toml", 2,
                           "refractivity_scale_height_m")
    assert "104 N-units/km" in message


def test_refraction_keys(tmp_path: Path) -> None:
    """Contract v2: the keys are read per radar; absent, the radar's rays are straight."""
    text = SITES.replace("alt_m = 950", 'alt_m = 950\nrefraction = "exponential"\n'
                         "refractivity_n_s = 320\nrefractivity_scale_height_m = 7500")
    sites = load_dataset(make_dataset(tmp_path / "ds", sites=text)).sites
    assert sites["A"].refraction == "none" and sites["A"].atmosphere is None
    assert (sites["A"].refractivity_n_s, sites["A"].refractivity_scale_height_m) == (313.0, 7000.0)
    b = sites["B"]
    assert (b.refraction, b.refractivity_n_s, b.refractivity_scale_height_m) == (
        "exponential", 320.0, 7500.0)
    assert b.atmosphere == Atmosphere(320.0, 7500.0)
    # Defaults for the values not given.
    text = SITES.replace("alt_m = 950", 'alt_m = 950\nrefraction = "exponential"')
    b = load_dataset(make_dataset(tmp_path / "ds2", sites=text)).sites["B"]
    assert b.atmosphere == Atmosphere(313.0, 7000.0)


def test_site_refraction_model_is_checked() -> None:
    with pytest.raises(ValueError, match="refraction"):
        Site("X", 0.0, 0.0, 0.0, 10.0, 1e-3, refraction="standard")


def test_refraction_keys_are_written_only_when_on(tmp_path: Path) -> None:
    straight = Site("A", 0.8, 0.1, 100.0, 30.0, 1e-3)
    bent = Site("B", 0.8, 0.1, 100.0, 30.0, 1e-3, refraction="exponential",
                refractivity_n_s=320.0, refractivity_scale_height_m=7000.0)
    write_sites({"A": straight}, tmp_path / "v1.toml")
    assert "refract" not in (tmp_path / "v1.toml").read_text()
    write_sites({"A": straight, "B": bent}, tmp_path / "v2.toml")
    text = (tmp_path / "v2.toml").read_text()
    assert text.count("refraction = ") == 1
    assert 'refraction = "exponential"' in text and "refractivity_n_s = 320.0" in text
    assert "refractivity_scale_height_m = 7000.0" in text
    assert load_sites(tmp_path / "v2.toml") == {"A": straight, "B": bent}


def test_sites_without_sigmas_load_as_missing(tmp_path: Path) -> None:
    # A: range sigma only; B: no sigma at all, and every plot of B has an elevation.
    text = SITES.replace("sigma_azimuth_mrad = 1.0\n", "").replace(
        "sigma_range_m = 100.0\nsigma_azimuth_mrad = 2.0\nsigma_elevation_mrad = 3.0\n", "")
    dataset = load_dataset(make_dataset(tmp_path / "ds", sites=text))
    a, b = dataset.sites["A"], dataset.sites["B"]
    assert a.missing_sigmas == ("sigma_azimuth_mrad",)
    assert a.sigma_range_m == 40.0 and not a.is_3d
    assert b.missing_sigmas == ("sigma_range_m", "sigma_azimuth_mrad", "sigma_elevation_mrad")
    assert b.is_3d and "elevation_bias" in b.estimate
    write_sites(dataset.sites, tmp_path / "out.toml")
    written = (tmp_path / "out.toml").read_text()
    assert "nan" not in written and written.count("sigma_") == 1
    assert load_sites(tmp_path / "out.toml")["A"].missing_sigmas == ("sigma_azimuth_mrad",)


def test_site_without_sigmas_stays_2d_when_a_plot_lacks_elevation(tmp_path: Path) -> None:
    text = SITES.replace("sigma_range_m = 40.0\nsigma_azimuth_mrad = 1.0\n", "")
    dataset = load_dataset(make_dataset(tmp_path / "ds", sites=text))
    assert not dataset.sites["A"].is_3d
    assert dataset.sites["A"].missing_sigmas == ("sigma_range_m", "sigma_azimuth_mrad")


def test_sites_file_that_is_not_toml(tmp_path: Path) -> None:
    folder = make_dataset(tmp_path / "ds", sites="[[radar]\nid = 'A'\n")
    assert "cannot read TOML" in assert_error(folder, "sites.toml", None, None)


def test_sites_file_without_radars(tmp_path: Path) -> None:
    assert_error(make_dataset(tmp_path / "ds", sites="title = 'x'\n"), "sites.toml", None, "radar")


def test_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="not found") as info:
        load_dataset(tmp_path / "nowhere")
    assert "nowhere" in str(info.value)


@pytest.mark.parametrize("name", ["sites.toml", "plots.csv"])
def test_missing_required_file(tmp_path: Path, name: str) -> None:
    folder = make_dataset(tmp_path / "ds")
    (folder / name).unlink()
    stem = name.split(".")[0]
    assert stem in assert_error(folder, stem, None, None)


def test_both_csv_and_parquet_is_an_error(tmp_path: Path) -> None:
    folder = make_dataset(tmp_path / "ds")
    pd.read_csv(folder / "plots.csv").to_parquet(folder / "plots.parquet")
    message = assert_error(folder, "plots.parquet", None, "plots")
    assert "plots.csv" in message


@pytest.mark.parametrize(
    ("file_name", "header"), [("plots.csv", PLOT_HEADER), ("adsb.csv", ADSB_HEADER)]
)
def test_empty_table(tmp_path: Path, file_name: str, header: str) -> None:
    folder = make_dataset(tmp_path / "ds")
    (folder / file_name).write_text(header + "\n")
    assert "no data rows" in assert_error(folder, file_name, None, None)


def test_empty_file(tmp_path: Path) -> None:
    folder = make_dataset(tmp_path / "ds")
    (folder / "adsb.csv").write_text("")
    assert "empty" in assert_error(folder, "adsb.csv", None, None)


@pytest.mark.parametrize(
    ("file_name", "header", "rows", "column"),
    [
        ("plots.csv", PLOT_HEADER, PLOT_ROWS, "azimuth_deg"),
        ("plots.csv", PLOT_HEADER, PLOT_ROWS, "elevation_deg"),
        ("adsb.csv", ADSB_HEADER, ADSB_ROWS, "lat_deg"),
    ],
)
def test_missing_required_column(
    tmp_path: Path, file_name: str, header: str, rows: list[str], column: str
) -> None:
    index = header.split(",").index(column)

    def drop(line: str) -> str:
        cells = line.split(",")
        return ",".join(cells[:index] + cells[index + 1:])

    folder = make_dataset(tmp_path / "ds")
    (folder / file_name).write_text(csv_text(drop(header), [drop(r) for r in rows]))
    message = assert_error(folder, file_name, None, column)
    assert "missing required column" in message


# --------------------------------------------------------------------------- sensor models


def test_site_naming_a_model_gets_its_defaults(tmp_path: Path) -> None:
    path = tmp_path / "sites.toml"
    path.write_text(
        '[[radar]]\nid = "S"\nlat_deg = 45.0\nlon_deg = 5.0\nalt_m = 300.0\n'
        'model = "ssr-mode-s"\n'
        '[[radar]]\nid = "D"\nlat_deg = 45.5\nlon_deg = 5.5\nalt_m = 400.0\n'
        'model = "air-defence-3d"\nsigma_range_m = 80.0\n'
    )
    sites = load_sites(path)
    ssr, defence = load_sensor_model("ssr-mode-s"), load_sensor_model("air-defence-3d")
    s, d = sites["S"], sites["D"]
    assert s.model == "ssr-mode-s"
    assert s.sigma_range_m == ssr.sigma_range_m == 30.0
    assert s.sigma_azimuth_rad == pytest.approx(1.2e-3)
    assert s.sigma_elevation_rad is None and not s.is_3d
    assert s.scan_period_s == 4.0
    assert s.estimate == ssr.estimate
    assert d.is_3d and d.sigma_elevation_rad == pytest.approx(defence.sigma_elevation_rad)
    assert d.sigma_range_m == 80.0  # the site's own value wins
    assert d.sigma_azimuth_rad == pytest.approx(2e-3)
    assert d.estimate == defence.estimate


def test_site_estimate_wins_over_the_model(tmp_path: Path) -> None:
    path = tmp_path / "sites.toml"
    path.write_text(
        '[[radar]]\nid = "P"\nlat_deg = 45.0\nlon_deg = 5.0\nalt_m = 300.0\n'
        'model = "psr-approach"\nestimate = ["range_offset", "range_gain", "azimuth_bias"]\n'
    )
    site = load_sites(path)["P"]
    assert site.estimate == ("range_offset", "range_gain", "azimuth_bias")
    assert site.sigma_range_m == 50.0


# --------------------------------------------------------------------------- writing


def test_sites_round_trip(tmp_path: Path) -> None:
    sites = {
        "A": Site("A", math.radians(47.4817), math.radians(8.3967), 866.0, 40.0, 1e-3),
        "B": Site("B", math.radians(-33.9), math.radians(151.2), 12.5, 100.0, 2e-3, 3e-3,
                  scan_period_s=10.0, estimate=("range_offset", "elevation_bias")),
        "C": Site("C", 0.1, -0.2, 0.0, 30.0, 1.2e-3, scan_period_s=4.0, model="ssr-mode-s",
                  estimate=("range_offset", "range_gain", "azimuth_bias")),
    }
    path = tmp_path / "sites.toml"
    write_sites(sites, path)
    loaded = load_sites(path)
    assert list(loaded) == ["A", "B", "C"]
    assert loaded == sites  # exact: written angles convert back to the same radians
    assert [p.name for p in tmp_path.iterdir()] == ["sites.toml"]


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_dataset_round_trip(tmp_path: Path, fmt: str) -> None:
    original = load_dataset(make_dataset(tmp_path / "src"))
    folder = write_dataset(original, tmp_path / "out", fmt=fmt)
    assert sorted(p.name for p in folder.iterdir()) == sorted(
        ["sites.toml", f"plots.{fmt}", f"adsb.{fmt}"])
    loaded = load_dataset(folder)
    pd.testing.assert_frame_equal(loaded.plots, original.plots, check_exact=True)
    assert loaded.adsb is not None and original.adsb is not None
    pd.testing.assert_frame_equal(loaded.adsb, original.adsb, check_exact=True)
    assert loaded.sites == original.sites


def test_csv_and_parquet_give_identical_tables(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    n = 200
    plots = pd.DataFrame({
        "radar_id": rng.choice(["A", "B"], n),
        "time_s": np.sort(rng.uniform(0, 3600, n)),
        "range_m": rng.uniform(1e3, 4e5, n),
        "azimuth_deg": rng.uniform(0, 360, n),
        "elevation_deg": rng.uniform(-1, 30, n),
        "target_id": rng.choice(["4b1805", "", "3c6444"], n),
        "altitude_m": np.where(rng.random(n) < 0.3, np.nan, rng.uniform(0, 12e3, n)),
    })
    plots.loc[plots["radar_id"] == "A", "elevation_deg"] = np.nan
    base = load_dataset(make_dataset(tmp_path / "src"))
    dataset = Dataset(sites=base.sites, plots=plots, adsb=base.adsb)
    from_csv = load_dataset(write_dataset(dataset, tmp_path / "csv", fmt="csv"))
    from_parquet = load_dataset(write_dataset(dataset, tmp_path / "pq", fmt="parquet"))
    pd.testing.assert_frame_equal(from_csv.plots, from_parquet.plots, check_exact=True)
    pd.testing.assert_frame_equal(from_csv.adsb, from_parquet.adsb, check_exact=True)
    np.testing.assert_array_equal(from_csv.plots["range_m"], plots["range_m"])


def test_write_refuses_a_non_empty_folder_without_overwrite(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "src"))
    target = tmp_path / "out"
    target.mkdir()
    (target / "notes.txt").write_text("keep me")
    with pytest.raises(DatasetError, match="overwrite"):
        write_dataset(dataset, target)
    assert [p.name for p in target.iterdir()] == ["notes.txt"]


def test_write_into_an_empty_folder(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "src"))
    target = tmp_path / "out"
    target.mkdir()
    write_dataset(dataset, target)
    assert (target / "plots.csv").is_file()


def test_write_with_overwrite_replaces_the_folder(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "src"))
    target = tmp_path / "out"
    write_dataset(dataset, target, fmt="parquet")
    (target / "stale.txt").write_text("old")
    write_dataset(dataset, target, fmt="csv", overwrite=True)
    assert sorted(p.name for p in target.iterdir()) == ["adsb.csv", "plots.csv", "sites.toml"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "src"]  # no backup left


def test_write_refuses_a_file_target(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "src"))
    (tmp_path / "out").write_text("a file")
    with pytest.raises(DatasetError, match="not a folder"):
        write_dataset(dataset, tmp_path / "out", overwrite=True)


def test_write_rejects_unknown_format(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "src"))
    with pytest.raises(ValueError, match="fmt"):
        write_dataset(dataset, tmp_path / "out", fmt="xlsx")


def _failing_to_parquet(self: pd.DataFrame, *args: object, **kwargs: object) -> None:
    raise OSError("disk full")


def test_failed_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "src"))
    parent = tmp_path / "results"
    parent.mkdir()
    monkeypatch.setattr(pd.DataFrame, "to_parquet", _failing_to_parquet)
    with pytest.raises(OSError, match="disk full"):
        write_dataset(dataset, parent / "out", fmt="parquet")
    assert list(parent.iterdir()) == []


def test_failed_overwrite_keeps_the_old_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "src"))
    target = write_dataset(dataset, tmp_path / "results" / "out", fmt="csv")
    before = listing(target)
    monkeypatch.setattr(pd.DataFrame, "to_parquet", _failing_to_parquet)
    with pytest.raises(OSError):
        write_dataset(dataset, target, fmt="parquet", overwrite=True)
    assert listing(target) == before
    assert [p.name for p in target.parent.iterdir()] == ["out"]


def test_atomic_write_text(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "truth.json"
    atomic_write_text(path, '{"a": 1}\n')
    atomic_write_text(path, '{"a": 2}\n')
    assert path.read_text() == '{"a": 2}\n'

    def fail(src: object, dst: object) -> None:
        raise OSError("no")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError):
        atomic_write_text(path, '{"a": 3}\n')
    assert path.read_text() == '{"a": 2}\n'
    assert [p.name for p in tmp_path.iterdir()] == ["truth.json"]
