"""CSV table files: pyarrow's parser where it can, pandas' where it must, the same rows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from graphcal.data.dataset import ADSB_COLUMNS, PLOT_COLUMNS
from graphcal.io import table_files
from graphcal.io.table_files import read_rows


def _plots(rng: np.random.Generator, n: int) -> pd.DataFrame:
    return pd.DataFrame({
        "radar_id": rng.choice(["R1", "R2", "R3"], n),
        "time_s": np.sort(rng.uniform(0.0, 3600.0, n)),
        "range_m": rng.uniform(1e3, 3e5, n),
        "azimuth_deg": rng.uniform(0.0, 360.0, n),
        "elevation_deg": np.where(rng.random(n) < 0.3, np.nan, rng.uniform(0.0, 20.0, n)),
        "target_id": rng.choice(["4ca7b3", "", "3c6444"], n),
        "altitude_m": rng.uniform(0.0, 12e3, n),
    })


def _read(path: Path, chunk_rows: int | None, usecols: list[str] | None = None
          ) -> tuple[pd.DataFrame, np.ndarray, list[int]]:
    chunks = list(read_rows(path, ("time_s",), chunk_rows=chunk_rows, usecols=usecols))
    frame = pd.concat([c.frame for c in chunks], ignore_index=True)
    rows = np.concatenate([c.rows for c in chunks])
    return frame, rows, [len(c.frame) for c in chunks]


@pytest.fixture
def no_pandas_parser(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail if pandas parses more than a header: the rows must come from pyarrow."""
    original = pd.read_csv

    def header_only(*args, **kwargs):
        if kwargs.get("nrows") != 0:
            raise AssertionError("pandas parsed the rows")
        return original(*args, **kwargs)

    monkeypatch.setattr(table_files.pd, "read_csv", header_only)


@pytest.mark.parametrize("chunk_rows", [None, 1, 7, 100, 10_000])
def test_contract_file_parsed_by_pyarrow_exactly(tmp_path: Path, no_pandas_parser: None,
                                                 arrow_block_bytes: int,
                                                 chunk_rows: int | None) -> None:
    truth = _plots(np.random.default_rng(1), 1000)
    path = tmp_path / "plots.csv"
    truth.to_csv(path, index=False)
    frame, rows, sizes = _read(path, chunk_rows)
    # Floats written at full precision come back to the bit; text stays text ("" too).
    for column in truth.columns:
        if column in ("radar_id", "target_id"):
            assert frame[column].astype(str).tolist() == truth[column].tolist()
        else:
            np.testing.assert_array_equal(frame[column].to_numpy(dtype=float),
                                          truth[column].to_numpy())
    np.testing.assert_array_equal(rows, np.arange(1, 1001))
    step = chunk_rows or 1000
    assert sizes == [min(step, 1000 - start) for start in range(0, 1000, step)]


def test_only_asked_columns_in_file_order(tmp_path: Path, no_pandas_parser: None) -> None:
    truth = _plots(np.random.default_rng(2), 50)
    path = tmp_path / "plots.csv"
    truth.to_csv(path, index=False)
    frame, _, _ = _read(path, 20, usecols=["elevation_deg", "radar_id"])
    assert list(frame.columns) == ["radar_id", "elevation_deg"]


@pytest.fixture(params=[256, table_files.ARROW_BLOCK_BYTES], ids=["small-blocks", "default"])
def arrow_block_bytes(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> int:
    """pyarrow's block: small ones let it yield chunks before it stops at a bad line."""
    monkeypatch.setattr(table_files, "ARROW_BLOCK_BYTES", request.param)
    return request.param


def test_blank_and_empty_lines_keep_their_numbers(tmp_path: Path, arrow_block_bytes: int
                                                  ) -> None:
    # Rows 1-5, a blank line (row 6), rows 7-9, a line of empty cells (row 10), row 11.
    truth = _plots(np.random.default_rng(3), 9)
    lines = truth.to_csv(index=False).splitlines()
    text = "\n".join(lines[:6] + [""] + lines[6:9] + [",,,,,,"] + lines[9:]) + "\n"
    path = tmp_path / "plots.csv"
    path.write_text(text)
    for chunk_rows in (None, 2, 3, 4, 100):
        frame, rows, _ = _read(path, chunk_rows)
        np.testing.assert_array_equal(rows, [1, 2, 3, 4, 5, 7, 8, 9, 11])
        np.testing.assert_array_equal(frame["range_m"].to_numpy(dtype=float),
                                      truth["range_m"].to_numpy())


def test_pandas_takes_over_at_the_chunk_of_a_bad_cell(tmp_path: Path, arrow_block_bytes: int
                                                      ) -> None:
    truth = _plots(np.random.default_rng(4), 40)
    text = truth.assign(range_m=truth["range_m"].map(repr)).to_csv(index=False)
    lines = text.splitlines()
    fields = lines[31].split(",")  # data row 31
    fields[2] = "1,5"
    lines[31] = ",".join(fields[:2] + ['"1,5"'] + fields[3:])
    path = tmp_path / "plots.csv"
    path.write_text("\n".join(lines) + "\n")
    chunks = list(read_rows(path, PLOT_COLUMNS, chunk_rows=8))
    assert [len(c.frame) for c in chunks] == [8, 8, 8, 8, 8]
    np.testing.assert_array_equal(np.concatenate([c.rows for c in chunks]), np.arange(1, 41))
    bad = chunks[3]
    assert bad.frame["range_m"].iloc[30 - 24] == "1,5"
    assert bad.rows[30 - 24] == 31


def test_extra_columns_keep_pandas_types(tmp_path: Path) -> None:
    truth = pd.DataFrame({"time_s": [1.0, 2.0], "target_id": ["a", "b"], "lat_deg": [1.0, 2.0],
                          "lon_deg": [3.0, 4.0], "alt_m": [5.0, 6.0], "squawk": [1200, 7000]})
    path = tmp_path / "adsb.csv"
    truth.to_csv(path, index=False)
    frame, _, _ = _read(path, 1)
    assert frame["squawk"].tolist() == [1200, 7000]
    assert pd.api.types.is_integer_dtype(frame["squawk"])
    assert set(ADSB_COLUMNS) <= set(frame.columns)


def test_byte_order_mark_read_as_pandas_reads_it(tmp_path: Path, no_pandas_parser: None
                                                  ) -> None:
    truth = _plots(np.random.default_rng(5), 5)
    path = tmp_path / "plots.csv"
    path.write_bytes(b"\xef\xbb\xbf" + truth.to_csv(index=False).encode())
    frame, rows, _ = _read(path, 2)
    assert list(frame.columns) == list(truth.columns)
    np.testing.assert_array_equal(rows, np.arange(1, 6))
