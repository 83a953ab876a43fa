"""Tests of graphcal.io.window_reader and .dataset_span: a dataset read window by window."""

from __future__ import annotations

import shutil
import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.core.errors import DatasetError, RowsOutOfOrderError
from graphcal.data.windows import split_windows
from graphcal.io.dataset_span import dataset_span, end_times_span, scan_times
from graphcal.io.folder import load_dataset
from graphcal.io.window_reader import iter_windows
from graphcal.simulation.scenario import parse_scenario
from graphcal.simulation.simulate import simulate, write_simulation

WINDOW_S = 600.0


def _document() -> dict:
    """Three radars, 14 aircraft for an hour, ADS-B with outliers: six 10-minute windows."""
    radar = {"alt_m": 100.0, "sigma_range_m": 40.0, "sigma_azimuth_mrad": 1.0,
             "scan_period_s": 6.0, "max_range_m": 220_000.0}
    return {
        "scenario": {"name": "windows", "duration_s": 3600.0,
                     "origin": {"lat_deg": 50.0, "lon_deg": 4.0}},
        "radar": [
            {**radar, "id": "N", "lat_deg": 50.6, "lon_deg": 4.1, "sigma_elevation_mrad": 2.0,
             "bias": {"range_offset_m": 50.0, "time_offset_s": 0.2}},
            {**radar, "id": "S", "lat_deg": 49.5, "lon_deg": 3.9,
             "bias": {"azimuth_bias_mrad": -1.0}},
            {**radar, "id": "E", "lat_deg": 50.0, "lon_deg": 4.8,
             "bias": {"range_gain": 1e-4}},
        ],
        "traffic": {"n_aircraft": 14, "radius_m": 150_000.0, "legs": [2, 3],
                    "start_time_s": [-900.0, 3000.0]},
        "adsb": {"enabled": True, "period_s": 1.0, "nacp": 8, "outlier_fraction": 0.003},
    }


def _with_defects(plots: pd.DataFrame, adsb: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Defects cleaning judges row by row: duplicate plots and reports, stale reports."""
    rng = np.random.default_rng(0)
    duplicates = np.sort(rng.choice(len(plots), 40, replace=False))
    plots = pd.concat([plots, plots.iloc[duplicates]]).sort_index(kind="stable")
    stale = adsb.iloc[np.sort(rng.choice(len(adsb) - 1, 30, replace=False))].copy()
    stale["time_s"] += 0.5  # the same position again, half a second later
    adsb = pd.concat([adsb, adsb.iloc[:25], stale]).sort_values("time_s", kind="stable")
    return plots.reset_index(drop=True), adsb.reset_index(drop=True)


@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict[str, Path]:
    """The simulated dataset, with defects, as CSV and as Parquet."""
    result = simulate(parse_scenario(_document()), np.random.default_rng(4))
    dataset = result.dataset
    dataset.plots, dataset.adsb = _with_defects(dataset.plots, dataset.adsb)
    root = tmp_path_factory.mktemp("windows")
    out = {}
    for fmt in ("csv", "parquet"):
        write_simulation(result, root / fmt, fmt=fmt)
        out[fmt] = root / fmt
    return out


def assert_same_windows(expected, got) -> None:
    """Same windows: index, span, sites, plots and ADS-B rows in the same order."""
    assert [(w.index, w.t_start_s, w.t_end_s) for w in got] == \
        [(w.index, w.t_start_s, w.t_end_s) for w in expected]
    for a, b in zip(expected, got, strict=True):
        assert b.dataset.sites == a.dataset.sites
        assert b.dataset.plot_altitude == a.dataset.plot_altitude
        pd.testing.assert_frame_equal(b.dataset.plots, a.dataset.plots.reset_index(drop=True))
        if a.dataset.adsb is None:
            assert b.dataset.adsb is None
        else:
            pd.testing.assert_frame_equal(b.dataset.adsb,
                                          a.dataset.adsb.reset_index(drop=True))


# --------------------------------------------------------------------------- the same windows


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_windows_are_those_of_the_loaded_and_cleaned_dataset(folders, fmt) -> None:
    folder = folders[fmt]
    whole = load_dataset(folder)
    assert whole.cleaning.counts["plots_duplicate"] == 40
    assert whole.cleaning.counts["adsb_duplicate"] == 25
    assert whole.cleaning.counts["adsb_stale"] >= 30
    expected = list(split_windows(whole, WINDOW_S))
    got = list(iter_windows(folder, WINDOW_S, chunk_rows=4000))
    assert len(got) == 6
    assert_same_windows(expected, got)
    removed = sum(w.dataset.cleaning.counts["plots_duplicate"] for w in got)
    assert removed == 40


@pytest.mark.parametrize("order", ["auto", "sorted", "any"])
def test_windows_without_cleaning_in_every_order_mode(folders, order, tmp_path) -> None:
    folder = folders["parquet"]
    expected = list(split_windows(load_dataset(folder, clean=False), WINDOW_S,
                                  adsb_margin_s=45.0))
    got = list(iter_windows(folder, WINDOW_S, adsb_margin_s=45.0, clean=False, order=order,
                            chunk_rows=3000, spill_dir=tmp_path))
    assert_same_windows(expected, got)
    assert list(tmp_path.iterdir()) == []  # the temporary folder is gone


def test_rows_out_of_order_are_sorted_by_window_through_a_temporary_folder(
        folders, tmp_path) -> None:
    folder = tmp_path / "shuffled"
    shutil.copytree(folders["csv"], folder)
    plots = pd.read_csv(folder / "plots.csv", dtype={"target_id": str})
    plots.sample(frac=1.0, random_state=1).to_csv(folder / "plots.csv", index=False)
    span = scan_times([folder / "plots.csv"], ("time_s",), max_lateness_s=60.0)
    assert not span.files_in_order and span.files[0].late_row is not None
    expected = list(split_windows(load_dataset(folder), WINDOW_S))
    spill = tmp_path / "spill"
    spill.mkdir()
    got = list(iter_windows(folder, WINDOW_S, chunk_rows=2000, spill_rows=5000,
                            spill_dir=spill))
    assert_same_windows(expected, got)
    assert list(spill.iterdir()) == []


def test_the_time_overlap_is_checked_here_or_left_to_the_caller(folders, tmp_path) -> None:
    """ADS-B on another time base (UNIX time against seconds of the day)."""
    from graphcal.data.plausibility import ImplausibleDataError
    from graphcal.io.window_reader import check_span_overlap

    folder = tmp_path / "unix"
    shutil.copytree(folders["csv"], folder)
    adsb = pd.read_csv(folder / "adsb.csv", dtype={"target_id": str})
    adsb["time_s"] += 1.6e9
    adsb.to_csv(folder / "adsb.csv", index=False)
    for order in ("auto", "sorted"):
        with pytest.raises(ImplausibleDataError, match="do not overlap"):
            next(iter_windows(folder, WINDOW_S, order=order))
        window = next(iter_windows(folder, WINDOW_S, order=order, time_overlap=False))
        assert window.index == 0 and len(window.dataset.adsb) == 0
    with pytest.raises(ImplausibleDataError, match="UNIX time"):
        check_span_overlap(dataset_span(folder))
    check_span_overlap(dataset_span(folders["csv"]))


def test_parts_that_overlap_in_time_are_read_side_by_side(folders, tmp_path) -> None:
    """One Parquet part per radar (each in time order), ADS-B in hourly CSV parts."""
    folder = tmp_path / "parts"
    shutil.copytree(folders["parquet"], folder)
    plots = pd.read_parquet(folder / "plots.parquet")
    (folder / "plots.parquet").unlink()
    (folder / "plots").mkdir()
    for i, (radar_id, rows) in enumerate(plots.groupby("radar_id", sort=False)):
        rows.to_parquet(folder / "plots" / f"{i}-{radar_id}.parquet", index=False,
                        row_group_size=500)
    (folder / "plots" / "_SUCCESS").write_text("")  # other writers' markers are ignored
    adsb = pd.read_parquet(folder / "adsb.parquet")
    (folder / "adsb.parquet").unlink()
    (folder / "adsb").mkdir()
    for half, rows in adsb.groupby(adsb["time_s"] >= 1800.0):
        rows.to_csv(folder / "adsb" / f"part-{int(half)}.csv", index=False)
    whole = load_dataset(folder)
    assert len(whole.plots) == len(plots) - 40
    expected = list(split_windows(whole, WINDOW_S))
    assert_same_windows(expected, list(iter_windows(folder, WINDOW_S, chunk_rows=700)))
    assert_same_windows(expected, list(iter_windows(folder, WINDOW_S, chunk_rows=700,
                                                    order="sorted")))


def test_the_span_from_the_ends_of_csv_files(folders, tmp_path) -> None:
    """In time order, a CSV table's first and last rows give the span every row gives;
    the rows are not counted; a Parquet table has no such ends (``None``)."""
    folder = folders["csv"]
    quick, full = end_times_span(folder), dataset_span(folder)
    assert quick is not None and quick.radar_ids == full.radar_ids
    assert (quick.t_start_s, quick.t_end_s) == (full.t_start_s, full.t_end_s)
    assert quick.adsb is not None and full.adsb is not None
    assert (quick.adsb.t_min_s, quick.adsb.t_max_s) == (full.adsb.t_min_s, full.adsb.t_max_s)
    assert quick.n_plots is None and full.n_plots == len(pd.read_csv(folder / "plots.csv"))
    shuffled = tmp_path / "shuffled"
    shutil.copytree(folder, shuffled)
    plots = pd.read_csv(shuffled / "plots.csv", dtype={"target_id": str})
    first_last = plots.iloc[[len(plots) // 2, len(plots) // 2 + 1]]
    rest = plots.drop(index=first_last.index)
    pd.concat([first_last.iloc[:1], rest, first_last.iloc[1:]]).to_csv(
        shuffled / "plots.csv", index=False)
    ends = end_times_span(shuffled)
    assert ends is not None  # the ends of a file out of order: not its span
    assert ends.t_start_s == first_last["time_s"].min() > full.t_start_s
    assert end_times_span(folders["parquet"]) is None


def test_stopping_early_removes_the_temporary_folder(folders, tmp_path) -> None:
    windows = iter_windows(folders["parquet"], WINDOW_S, order="any", spill_dir=tmp_path)
    first = next(windows)
    assert first.index == 0 and len(list(tmp_path.iterdir())) == 2  # plots and ADS-B
    windows.close()
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------- bad input


def test_a_row_out_of_order_names_the_file_and_row(folders, tmp_path) -> None:
    folder = tmp_path / "late"
    shutil.copytree(folders["csv"], folder)
    lines = (folder / "plots.csv").read_text().splitlines(keepends=True)
    moved = lines.pop(100)  # data row 99, 0-600 s, moved to be data row 2000
    lines.insert(2000, moved)
    (folder / "plots.csv").write_text("".join(lines))
    with pytest.raises(DatasetError) as info:
        list(iter_windows(folder, WINDOW_S, order="sorted", chunk_rows=700))
    error = info.value
    assert isinstance(error, RowsOutOfOrderError)  # a caller may read again, sorting first
    assert error.path == folder / "plots.csv" and error.row == 2000 and error.field == "time_s"
    assert "time order" in str(error) and "sort it by time_s" in str(error)
    assert "(line 2001)" in str(error)
    assert len(list(iter_windows(folder, WINDOW_S))) == 6  # auto: sorted by window


@pytest.mark.parametrize(("fmt", "column", "value"), [
    ("csv", "azimuth_deg", "12,5"), ("csv", "radar_id", "X"), ("parquet", "range_m", -5.0)])
def test_a_bad_cell_deep_in_a_file_gives_the_error_load_dataset_gives(
        folders, tmp_path, fmt, column, value) -> None:
    folder = tmp_path / "bad"
    shutil.copytree(folders[fmt], folder)
    path = folder / f"plots.{fmt}"
    if fmt == "csv":
        lines = path.read_text().splitlines(keepends=True)
        header = lines[0].strip().split(",")
        cells = lines[2345].rstrip("\n").split(",")
        cells[header.index(column)] = f'"{value}"'
        lines[2345] = ",".join(cells) + "\n"
        path.write_text("".join(lines))
    else:
        table = pd.read_parquet(path)
        table.loc[2344, column] = value
        table.to_parquet(path, index=False, row_group_size=1000)
    with pytest.raises(DatasetError) as whole:
        load_dataset(folder)
    with pytest.raises(DatasetError) as windowed:
        list(iter_windows(folder, WINDOW_S, chunk_rows=1000))
    assert str(windowed.value) == str(whole.value)
    assert windowed.value.row == 2345 and windowed.value.field == column


def test_bad_arguments_and_folders(folders, tmp_path) -> None:
    folder = folders["csv"]
    with pytest.raises(ValueError, match="positive duration"):
        next(iter_windows(folder, 0.0))
    with pytest.raises(ValueError, match="adsb_margin_s"):
        next(iter_windows(folder, WINDOW_S, adsb_margin_s=-1.0))
    with pytest.raises(ValueError, match="order"):
        next(iter_windows(folder, WINDOW_S, order="random"))
    with pytest.raises(DatasetError, match="not found"):
        next(iter_windows(tmp_path / "nowhere", WINDOW_S))
    both = tmp_path / "both"
    shutil.copytree(folder, both)
    (both / "plots").mkdir()
    with pytest.raises(DatasetError, match=r"plots\.csv and plots/"):
        next(iter_windows(both, WINDOW_S))
    (both / "plots.csv").unlink()
    with pytest.raises(DatasetError, match="no .csv or .parquet part"):
        load_dataset(both)


def test_sites_without_sigmas_become_3d_from_their_plots(folders, tmp_path) -> None:
    folder = tmp_path / "nosigma"
    shutil.copytree(folders["parquet"], folder)
    text = (folder / "sites.toml").read_text()
    kept = [line for line in text.splitlines() if not line.startswith("sigma_")]
    (folder / "sites.toml").write_text("\n".join(kept) + "\n")
    whole = load_dataset(folder)
    assert whole.sites["N"].is_3d and not whole.sites["S"].is_3d
    first = next(iter_windows(folder, WINDOW_S))
    assert first.dataset.sites == whole.sites


# --------------------------------------------------------------------------- span


def test_dataset_span_from_statistics_and_from_the_time_column(folders, tmp_path) -> None:
    whole = load_dataset(folders["csv"], clean=False)
    times = whole.plots["time_s"]
    for folder in (folders["csv"], folders["parquet"]):
        span = dataset_span(folder)
        assert span.radar_ids == ("N", "S", "E")
        assert (span.t_start_s, span.t_end_s) == (times.min(), times.max())
        assert (span.n_plots, span.n_adsb) == (len(whole.plots), len(whole.adsb))
        assert list(span.window_indices(WINDOW_S)) == list(range(6))
    no_statistics = tmp_path / "nostats"
    shutil.copytree(folders["parquet"], no_statistics)
    table = pd.read_parquet(no_statistics / "plots.parquet")
    table.to_parquet(no_statistics / "plots.parquet", index=False, write_statistics=False)
    assert dataset_span(no_statistics).t_end_s == times.max()


def test_csv_end_times_are_the_first_and_last_rows_times(folders, tmp_path) -> None:
    from graphcal.io.dataset_span import csv_end_times

    rows = pd.read_csv(folders["csv"] / "plots.csv")
    assert csv_end_times(folders["csv"] / "plots.csv") == (
        rows["time_s"].iloc[0], rows["time_s"].iloc[-1])
    assert csv_end_times(folders["parquet"] / "plots.parquet") is None
    blank_last = tmp_path / "plots.csv"
    blank_last.write_text("radar_id,time_s\nN,5.5\nN,nan\n\n")
    assert csv_end_times(blank_last) is None  # a last time that is not a number
    blank_last.write_text("radar_id,time_s\nN,5.5\nS,7200.25\n\n")
    assert csv_end_times(blank_last) == (5.5, 7200.25)


def test_a_changed_table_is_measured_again(folders, tmp_path) -> None:
    folder = tmp_path / "changing"
    shutil.copytree(folders["csv"], folder)
    before = dataset_span(folder)
    rows = pd.read_csv(folder / "plots.csv")
    rows = rows[rows["time_s"] < rows["time_s"].median()]
    rows.to_csv(folder / "plots.csv", index=False)
    after = dataset_span(folder)
    assert after.n_plots == len(rows) < before.n_plots
    assert dataset_span(folder) is after  # unchanged: remembered


# --------------------------------------------------------------------------- memory


def _write_long_table(folder: Path, n_windows: int, rows_per_window: int = 1500) -> None:
    """Plots of two radars, ``n_windows`` one-minute windows, Parquet row groups of 1000."""
    folder.mkdir()
    (folder / "sites.toml").write_text(
        '[[radar]]\nid = "A"\nlat_deg = 50.0\nlon_deg = 4.0\nalt_m = 0.0\n'
        "sigma_range_m = 30.0\nsigma_azimuth_mrad = 1.0\n\n"
        '[[radar]]\nid = "B"\nlat_deg = 50.5\nlon_deg = 4.5\nalt_m = 0.0\n'
        "sigma_range_m = 30.0\nsigma_azimuth_mrad = 1.0\n")
    rng = np.random.default_rng(1)
    n = n_windows * rows_per_window
    plots = pd.DataFrame({
        "radar_id": rng.choice(["A", "B"], n),
        "time_s": np.sort(rng.uniform(0.0, 60.0 * n_windows, n)),
        "range_m": rng.uniform(1e3, 2e5, n),
        "azimuth_deg": rng.uniform(0.0, 360.0, n),
        "elevation_deg": np.full(n, np.nan),
        "target_id": rng.choice([f"{i:06x}" for i in range(50)], n),
        "altitude_m": rng.uniform(1e3, 1e4, n),
    })
    plots.to_parquet(folder / "plots.parquet", index=False, row_group_size=1000)


def _peak_bytes(folder: Path) -> tuple[int, int]:
    """Peak traced memory [bytes] of reading every window, and the number of windows."""
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        count = sum(1 for _ in iter_windows(folder, 60.0, clean=False, chunk_rows=1000))
        return tracemalloc.get_traced_memory()[1] - base, count
    finally:
        tracemalloc.stop()


def test_memory_does_not_grow_with_the_number_of_windows(tmp_path) -> None:
    _write_long_table(tmp_path / "short", 6)
    _write_long_table(tmp_path / "long", 30)
    short, n_short = _peak_bytes(tmp_path / "short")
    long, n_long = _peak_bytes(tmp_path / "long")
    assert (n_short, n_long) == (6, 30)
    assert long < 1.3 * short
    whole = load_dataset(tmp_path / "long", clean=False).plots
    assert long < 0.25 * whole.memory_usage(deep=True).sum()
