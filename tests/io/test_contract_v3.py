"""Contract v3 columns in dataset folders: plots ``mode_3a`` and ``track_number``, ADS-B
``mode_3a``; read, validated, kept and written, whole and window by window."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from graphcal.cli.app import app
from graphcal.core.errors import DatasetError
from graphcal.data.dataset import Dataset
from graphcal.data.windows import split_windows
from graphcal.io.folder import DatasetWriter, load_dataset, write_dataset
from graphcal.io.window_reader import iter_windows
from tests.io.test_dataset import (
    ADSB_HEADER,
    ADSB_ROWS,
    PLOT_HEADER,
    assert_error,
    csv_text,
    make_dataset,
    replace_cell,
)

V3_PLOT_HEADER = PLOT_HEADER + ",mode_3a,track_number"
V3_PLOT_ROWS = [
    "A,10.0,52000.5,12.25,,4B1805,10058.4,0413,17",
    "B,11.5,81234.0,200.0,5.5,4b1805,,7000,4095",
    "A,14.0,51800.0,12.5,,,,,",
]
V3_ADSB_HEADER = ADSB_HEADER + ",mode_3a"
V3_ADSB_ROWS = [row + "," + code for row, code in zip(ADSB_ROWS, ["0413", "", "0000"],
                                                      strict=True)]


def make_v3(folder: Path, plots: list[str] | None = None,
            adsb: list[str] | None = None) -> Path:
    """The small dataset of test_dataset.py with the v3 columns."""
    make_dataset(folder)
    (folder / "plots.csv").write_text(
        csv_text(V3_PLOT_HEADER, V3_PLOT_ROWS if plots is None else plots))
    (folder / "adsb.csv").write_text(
        csv_text(V3_ADSB_HEADER, V3_ADSB_ROWS if adsb is None else adsb))
    return folder


def assert_v3_values(dataset: Dataset) -> None:
    """The codes keep their leading zeros; the track numbers are nullable integers."""
    plots, adsb = dataset.plots, dataset.adsb
    assert plots["mode_3a"].tolist() == ["0413", "7000", ""]
    assert plots["track_number"].dtype == "Int64"
    assert plots["track_number"].tolist()[:2] == [17, 4095]
    assert plots["track_number"].isna().tolist() == [False, False, True]
    assert adsb is not None
    assert adsb["mode_3a"].tolist() == ["0413", "", "0000"]


# --------------------------------------------------------------------------- reading, writing


def test_v3_columns_are_read_with_their_types(tmp_path: Path) -> None:
    dataset = load_dataset(make_v3(tmp_path / "ds"))
    assert_v3_values(dataset)
    columns = dataset.plots.columns.tolist()
    assert columns[6:] == ["altitude_m", "mode_3a", "track_number"]


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_round_trip_keeps_leading_zeros_and_track_numbers(tmp_path: Path, fmt: str) -> None:
    original = load_dataset(make_v3(tmp_path / "src"))
    folder = write_dataset(original, tmp_path / "out", fmt=fmt)
    loaded = load_dataset(folder)
    assert_v3_values(loaded)
    pd.testing.assert_frame_equal(loaded.plots, original.plots, check_exact=True)
    pd.testing.assert_frame_equal(loaded.adsb, original.adsb, check_exact=True)
    if fmt == "csv":
        text = (folder / "plots.csv").read_text().splitlines()
        assert text[1].endswith(",0413,17") and text[3].endswith(",,")
        assert (folder / "adsb.csv").read_text().splitlines()[3].endswith(",0000")
    else:
        schema = pq.read_schema(folder / "plots.parquet")
        assert pa.types.is_string(schema.field("mode_3a").type) or \
            pa.types.is_large_string(schema.field("mode_3a").type)
        assert pa.types.is_integer(schema.field("track_number").type)


def test_written_piece_by_piece(tmp_path: Path) -> None:
    original = load_dataset(make_v3(tmp_path / "src"))
    with DatasetWriter(original.sites, tmp_path / "out", fmt="parquet") as writer:
        writer.write_plots(original.plots.iloc[:1])
        writer.write_plots(original.plots.iloc[1:])
        writer.write_adsb(original.adsb)
    loaded = load_dataset(tmp_path / "out")
    assert_v3_values(loaded)


def test_parquet_nulls_are_missing_values(tmp_path: Path) -> None:
    folder = make_v3(tmp_path / "ds")
    plots = pd.read_csv(folder / "plots.csv", dtype={"mode_3a": str, "target_id": str})
    plots["mode_3a"] = pd.array(["0413", None, None], dtype=object)
    plots["track_number"] = pd.array([3, None, 0], dtype="Int64")
    (folder / "plots.csv").unlink()
    plots.to_parquet(folder / "plots.parquet", index=False)
    loaded = load_dataset(folder)
    assert loaded.plots["mode_3a"].tolist() == ["0413", "", ""]
    assert loaded.plots["track_number"].isna().tolist() == [False, True, False]
    assert loaded.plots["track_number"].iloc[2] == 0


def test_v2_folder_without_the_columns_reads_as_before(tmp_path: Path) -> None:
    dataset = load_dataset(make_dataset(tmp_path / "ds"))
    assert dataset.plots.columns.tolist() == PLOT_HEADER.split(",")
    assert dataset.adsb is not None
    assert dataset.adsb.columns.tolist() == ADSB_HEADER.split(",")
    assert "mode_3a" not in dataset.adsb and "track_number" not in dataset.plots
    out = write_dataset(dataset, tmp_path / "out")
    assert (out / "plots.csv").read_text().splitlines()[0] == PLOT_HEADER
    assert (out / "plots.csv").read_text() == csv_text(PLOT_HEADER, [
        "A,10.0,52000.5,12.25,,4b1805,10058.4",
        "B,11.5,81234.0,200.0,5.5,4b1805,",
        "A,14.0,51800.0,12.5,,,",
    ])


def test_empty_cells_and_missing_text_are_no_code(tmp_path: Path) -> None:
    rows = replace_cell(replace_cell(V3_PLOT_ROWS, 1, 7, " "), 2, 7, "NA")
    dataset = load_dataset(make_v3(tmp_path / "ds", plots=rows))
    assert dataset.plots["mode_3a"].tolist() == ["", "", ""]


def test_codes_in_a_file_read_by_pandas_keep_leading_zeros(tmp_path: Path) -> None:
    # An extra column sends the file to pandas' parser instead of pyarrow's.
    folder = make_v3(tmp_path / "ds")
    text = (folder / "plots.csv").read_text().splitlines()
    lines = [text[0] + ",note"] + [line + ",x" for line in text[1:]]
    (folder / "plots.csv").write_text("\n".join(lines) + "\n")
    dataset = load_dataset(folder)
    assert dataset.plots["mode_3a"].tolist() == ["0413", "7000", ""]
    assert dataset.plots["track_number"].dtype == "Int64"
    assert dataset.plots.columns.tolist()[-1] == "note"


# --------------------------------------------------------------------------- bad values


PLOT_CASES = [
    # (data row, column index, bad value, field, text in the message)
    (2, 7, "8000", "mode_3a", "not a Mode 3/A code"),
    (1, 7, "413", "mode_3a", "4 octal digits"),
    (2, 7, "04130", "mode_3a", "4 octal digits"),
    (3, 7, "7a00", "mode_3a", "'7a00'"),
    (2, 8, "-1", "track_number", "not a non-negative integer"),
    (3, 8, "2.5", "track_number", "not a non-negative integer"),
    (1, 8, "abc", "track_number", "not a number"),
    (2, 8, "1e30", "track_number", "too large"),
]


@pytest.mark.parametrize(("row", "column", "value", "field", "text"), PLOT_CASES)
def test_bad_v3_plot_cell(tmp_path: Path, row: int, column: int, value: str, field: str,
                          text: str) -> None:
    rows = replace_cell(V3_PLOT_ROWS, row, column, value)
    message = assert_error(make_v3(tmp_path / "ds", plots=rows), "plots.csv", row, field)
    assert text in message
    assert f"line {row + 1}" in message


def test_bad_adsb_code(tmp_path: Path) -> None:
    rows = replace_cell(V3_ADSB_ROWS, 3, 7, "0009")
    message = assert_error(make_v3(tmp_path / "ds", adsb=rows), "adsb.csv", 3, "mode_3a")
    assert "'0009' is not a Mode 3/A code" in message


def test_numeric_parquet_code_column_is_refused(tmp_path: Path) -> None:
    folder = make_v3(tmp_path / "ds")
    adsb = pd.read_csv(folder / "adsb.csv", dtype={"target_id": str})
    adsb["mode_3a"] = [413, np.nan, 0]  # leading zeros lost: refused, not guessed
    (folder / "adsb.csv").unlink()
    adsb.to_parquet(folder / "adsb.parquet", index=False)
    message = assert_error(folder, "adsb.parquet", 1, "mode_3a")
    assert "as text" in message


def test_bad_code_deep_in_a_file_read_window_by_window(tmp_path: Path) -> None:
    rows = replace_cell(V3_PLOT_ROWS, 3, 7, "9999")
    folder = make_v3(tmp_path / "ds", plots=rows)
    with pytest.raises(DatasetError) as info:
        list(iter_windows(folder, 600.0, chunk_rows=1, force=True))
    assert (info.value.row, info.value.field) == (3, "mode_3a")
    assert "plots.csv" in str(info.value)


def test_bad_code_exits_with_status_2_naming_file_row_and_field(tmp_path: Path) -> None:
    rows = replace_cell(V3_PLOT_ROWS, 2, 7, "1238")
    folder = make_v3(tmp_path / "ds", plots=rows)
    result = CliRunner().invoke(app, ["calibrate", str(folder)])
    assert result.exit_code == 2, result.output
    assert "plots.csv" in result.output and "row 2" in result.output
    assert "mode_3a" in result.output and "Traceback" not in result.output


# --------------------------------------------------------------------------- windows


@pytest.fixture(scope="module")
def v3_folders(demo: Dataset, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The demo network with codes and track numbers, as CSV and as Parquet."""
    rng = np.random.default_rng(3)
    plots = demo.plots.copy()
    codes = np.array([f"{code:04o}" for code in rng.integers(0, 4096, len(plots))],
                     dtype=object)
    codes[rng.random(len(plots)) < 0.2] = ""
    plots["mode_3a"] = codes
    plots["track_number"] = pd.array(rng.integers(0, 5000, len(plots)), dtype="Int64")
    plots.loc[rng.random(len(plots)) < 0.1, "track_number"] = pd.NA
    adsb = demo.adsb.copy()
    adsb["mode_3a"] = np.where(rng.random(len(adsb)) < 0.5, "0413", "")
    dataset = Dataset(sites=demo.sites, plots=plots, adsb=adsb)
    root = tmp_path_factory.mktemp("v3")
    return {fmt: write_dataset(dataset, root / fmt, fmt=fmt) for fmt in ("csv", "parquet")}


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_windows_keep_the_v3_columns(v3_folders: dict[str, Path], fmt: str,
                                     tmp_path: Path) -> None:
    folder = v3_folders[fmt]
    whole = load_dataset(folder, clean=False)
    assert whole.plots["mode_3a"].str.startswith("0").any()
    expected = list(split_windows(whole, 600.0, adsb_margin_s=45.0))
    for order in ("auto", "any"):
        got = list(iter_windows(folder, 600.0, adsb_margin_s=45.0, clean=False, order=order,
                                chunk_rows=5000, spill_dir=tmp_path))
        assert len(got) == len(expected) == 3
        for a, b in zip(expected, got, strict=True):
            pd.testing.assert_frame_equal(b.dataset.plots,
                                          a.dataset.plots.reset_index(drop=True))
            pd.testing.assert_frame_equal(b.dataset.adsb, a.dataset.adsb.reset_index(drop=True))
            assert b.dataset.plots["track_number"].dtype == "Int64"


def test_cleaned_windows_keep_the_v3_columns(v3_folders: dict[str, Path]) -> None:
    folder = v3_folders["parquet"]
    expected = list(split_windows(load_dataset(folder), 600.0))
    got = list(iter_windows(folder, 600.0, chunk_rows=7000))
    for a, b in zip(expected, got, strict=True):
        pd.testing.assert_frame_equal(b.dataset.plots, a.dataset.plots.reset_index(drop=True))
        assert {"mode_3a", "track_number"} <= set(b.dataset.plots.columns)
        assert "mode_3a" in b.dataset.adsb
