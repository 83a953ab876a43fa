"""rows_where (graphcal.io.table_stream): a chunk's rows on one side of a time."""

from __future__ import annotations

import numpy as np
import pandas as pd
from pandas.testing import assert_frame_equal

from graphcal.io.table_stream import rows_where


def _chunk() -> tuple[pd.DataFrame, np.ndarray]:
    times = np.array([0.0, 1.0, 2.0, 1.5, 4.0, 5.0])
    frame = pd.DataFrame({"time_s": times, "target_id": pd.Series(list("abcdef"), dtype="str")},
                         index=pd.RangeIndex(10, 16))
    return frame, times


def test_rows_of_one_run_are_a_slice_with_the_rows_loc_gives() -> None:
    frame, times = _chunk()
    for mask in (times >= 2.0, times < 2.0, times >= 4.0, np.ones(6, dtype=bool)):
        rows, kept = rows_where(frame, times, mask)
        assert_frame_equal(rows, frame.loc[mask], check_exact=True)
        np.testing.assert_array_equal(kept, times[mask])


def test_rows_in_several_runs_or_none() -> None:
    """A row late within the tolerance breaks the run: rows taken as loc takes them."""
    frame, times = _chunk()
    for mask in (times >= 1.6, times < 1.2, np.zeros(6, dtype=bool)):
        rows, kept = rows_where(frame, times, mask)
        assert_frame_equal(rows, frame.loc[mask], check_exact=True)
        np.testing.assert_array_equal(kept, times[mask])
