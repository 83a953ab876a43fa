"""Tests of graphcal.io.table_writer and graphcal.io.folder.DatasetWriter: tables in pieces."""

from __future__ import annotations

import filecmp
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from graphcal.core.atomic import write_table
from graphcal.io.folder import DatasetWriter, load_dataset, load_sites
from graphcal.io.table_writer import TableWriter
from tests.io.test_dataset import SITES


def _table(n: int, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    return pd.DataFrame({
        "radar_id": rng.choice(["A", "B"], n).astype(object),
        "time_s": np.sort(rng.uniform(0.0, 1e4, n)),
        "range_m": rng.uniform(1e3, 2e5, n),
        "azimuth_deg": rng.uniform(0.0, 360.0, n),
        "elevation_deg": np.where(rng.uniform(size=n) < 0.5, np.nan, 1.5),
        "target_id": rng.choice(["4b1805", "", "abc123"], n).astype(object),
        "altitude_m": rng.uniform(1e3, 1e4, n),
    })


def _pieces(frame: pd.DataFrame, cuts: list[int]) -> list[pd.DataFrame]:
    return [frame.iloc[a:b] for a, b in zip([0, *cuts], [*cuts, len(frame)], strict=True)]


def test_csv_pieces_give_the_file_of_the_whole_table(tmp_path: Path) -> None:
    frame = _table(1000)
    write_table(frame, tmp_path / "whole.csv")
    with TableWriter(tmp_path / "pieces.csv") as writer:
        for piece in _pieces(frame, [0, 10, 400, 400, 999]):
            writer.write(piece)
    assert writer.n_rows == 1000
    assert filecmp.cmp(tmp_path / "whole.csv", tmp_path / "pieces.csv", shallow=False)


def test_parquet_pieces_become_bounded_row_groups(tmp_path: Path) -> None:
    frame = _table(1000)
    with TableWriter(tmp_path / "t.parquet", row_group_rows=300) as writer:
        for piece in _pieces(frame, [0, 100, 700]):
            writer.write(piece)
    metadata = pq.ParquetFile(tmp_path / "t.parquet").metadata
    assert [metadata.row_group(g).num_rows for g in range(metadata.num_row_groups)] == \
        [100, 300, 300, 300]
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "t.parquet"), frame)


def test_an_empty_first_piece_does_not_fix_the_types(tmp_path: Path) -> None:
    frame = _table(50)
    empty = pd.DataFrame({c: pd.Series([], dtype=object) for c in frame.columns})
    with TableWriter(tmp_path / "t.parquet") as writer:
        writer.write(empty)
        writer.write(frame)
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "t.parquet"), frame)
    with TableWriter(tmp_path / "none.parquet") as writer:
        writer.write(frame.iloc[:0])
    assert len(pd.read_parquet(tmp_path / "none.parquet").columns) == 7
    with TableWriter(tmp_path / "nothing.csv"):
        pass
    assert not (tmp_path / "nothing.csv").exists()


def test_a_failure_leaves_the_previous_file(tmp_path: Path) -> None:
    target = tmp_path / "t.parquet"
    _table(5).to_parquet(target, index=False)
    before = target.read_bytes()
    with pytest.raises(RuntimeError, match="stop"):
        with TableWriter(target) as writer:
            writer.write(_table(100))
            raise RuntimeError("stop")
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["t.parquet"]


def test_bad_use(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="suffix"):
        TableWriter(tmp_path / "t.json")
    writer = TableWriter(tmp_path / "t.csv")
    writer.write(_table(3))
    with pytest.raises(ValueError, match="columns"):
        writer.write(_table(3).drop(columns="altitude_m"))
    writer.close()
    with pytest.raises(ValueError, match="closed"):
        writer.write(_table(3))


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_dataset_writer_writes_a_folder_in_pieces(tmp_path: Path, fmt: str) -> None:
    (tmp_path / "sites.toml").write_text(SITES)
    sites = load_sites(tmp_path / "sites.toml")
    plots = _table(200)
    plots["elevation_deg"] = np.where(plots["radar_id"] == "B", 2.0, np.nan)
    with DatasetWriter(sites, tmp_path / "ds", fmt=fmt) as writer:
        for piece in _pieces(plots, [50, 120]):
            writer.write_plots(piece)
        writer.write_text("note.txt", "hello\n")
        assert not (tmp_path / "ds").exists()  # in place only once complete
    assert writer.rows_written("plots") == 200 and writer.rows_written("adsb") == 0
    assert sorted(p.name for p in (tmp_path / "ds").iterdir()) == \
        ["note.txt", f"plots.{fmt}", "sites.toml"]
    loaded = load_dataset(tmp_path / "ds", clean=False)
    np.testing.assert_array_equal(loaded.plots["time_s"], plots["time_s"])
    assert loaded.adsb is None and loaded.sites == sites


def test_dataset_writer_abort_leaves_nothing(tmp_path: Path) -> None:
    (tmp_path / "sites.toml").write_text(SITES)
    sites = load_sites(tmp_path / "sites.toml")
    with pytest.raises(KeyError):
        with DatasetWriter(sites, tmp_path / "out" / "ds") as writer:
            writer.write_plots(_table(10))
            raise KeyError("stop")
    assert list((tmp_path / "out").iterdir()) == []
