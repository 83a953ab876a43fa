"""Reading windows ahead of their calibration (graphcal.pipeline.schedulers.read_ahead)."""

from __future__ import annotations

import pytest


def test_read_ahead_keeps_the_order_and_raises_where_the_producer_stopped() -> None:
    from graphcal.pipeline.schedulers import read_ahead

    assert list(read_ahead(iter(range(50)))) == list(range(50))

    def broken():
        yield from range(3)
        raise ValueError("row 7 of plots.csv")

    seen = []
    with pytest.raises(ValueError, match="row 7"):
        for item in read_ahead(broken()):
            seen.append(item)
    assert seen == [0, 1, 2]


def test_read_ahead_stops_its_producer_when_abandoned() -> None:
    """At most depth + 1 items are taken from the source beyond those consumed."""
    import threading

    from graphcal.pipeline.schedulers import read_ahead

    taken = []

    def source():
        for i in range(1000):
            taken.append(i)
            yield i

    reader = read_ahead(source(), depth=1)
    assert [next(reader) for _ in range(3)] == [0, 1, 2]
    reader.close()
    assert not [t for t in threading.enumerate() if t.name == "graphcal-read-ahead"]
    assert len(taken) <= 3 + 2


def _numbers_then_trouble(n: int, fail_at: int | None, warn_at: int | None):
    """A producer for the child-process tests (module level: the child runs it)."""
    import warnings

    from graphcal.core.errors import DatasetError

    for i in range(n):
        if i == warn_at:
            warnings.warn(f"odd row {i}", UserWarning, stacklevel=1)
        if i == fail_at:
            raise DatasetError("not a number", path="plots.csv", row=i + 2, field="range_m")
        yield {"i": i, "square": i * i}


needs_fork = pytest.mark.skipif(
    not __import__("graphcal.pipeline.schedulers", fromlist=["x"]).child_reading_available(),
    reason="reading in a child process needs fork (Linux)")


@needs_fork
def test_read_in_child_keeps_the_order_warnings_and_the_error_of_the_producer() -> None:
    from graphcal.core.errors import DatasetError
    from graphcal.pipeline.schedulers import read_in_child

    expected = [{"i": i, "square": i * i} for i in range(40)]
    assert list(read_in_child(_numbers_then_trouble, (40, None, None))) == expected
    seen = []
    with pytest.warns(UserWarning, match="odd row 2"), \
            pytest.raises(DatasetError) as caught:
        for item in read_in_child(_numbers_then_trouble, (40, 5, 2)):
            seen.append(item["i"])
    assert seen == [0, 1, 2, 3, 4]
    # The error arrives whole: its file, row and field, as the command line prints them.
    assert (caught.value.row, caught.value.field, str(caught.value.path)) == (
        7, "range_m", "plots.csv")


@needs_fork
def test_read_in_child_stops_the_child_when_abandoned() -> None:
    import multiprocessing

    from graphcal.pipeline.schedulers import read_in_child

    reader = read_in_child(_numbers_then_trouble, (10_000, None, None))
    assert [next(reader)["i"] for _ in range(3)] == [0, 1, 2]
    assert [p.name for p in multiprocessing.active_children()] == ["graphcal-reader"]
    reader.close()
    assert not multiprocessing.active_children()


def _large_items_marked(n: int, size_bytes: int, folder: str):
    """A producer of large items that leaves a file named after each item it made."""
    from pathlib import Path

    for i in range(n):
        item = bytes([i % 256]) * size_bytes
        (Path(folder) / f"made-{i}").touch()
        yield item


def _made(folder, i: int, wait_s: float) -> bool:
    import time

    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        if (folder / f"made-{i}").exists():
            return True
        time.sleep(0.01)
    return (folder / f"made-{i}").exists()


@needs_fork
@pytest.mark.parametrize("budget_bytes", [None, 1])
def test_read_in_child_runs_ahead_within_its_byte_budget(tmp_path, monkeypatch,
                                                          budget_bytes) -> None:
    """Items larger than the pipe: the child goes on producing while this process holds
    the first one, as far as CHILD_AHEAD_BYTES allows and no further."""
    from graphcal.pipeline import schedulers

    if budget_bytes is not None:
        monkeypatch.setattr(schedulers, "CHILD_AHEAD_BYTES", budget_bytes)
    size = 3 << 20  # three times the widened pipe
    reader = schedulers.read_in_child(_large_items_marked, (30, size, str(tmp_path)))
    try:
        first = next(reader)
        assert len(first) == size and first[0] == 0
        if budget_bytes is None:  # 64 MiB: some twenty items fit
            assert _made(tmp_path, 8, 20.0)
        else:
            # One item in the pipe, one held, one being produced that waits to be held.
            assert _made(tmp_path, 2, 20.0)
            assert not _made(tmp_path, 3, 0.5)
        rest = list(reader)
        assert [item[0] for item in rest] == list(range(1, 30))
        assert all(len(item) == size for item in rest)
    finally:
        reader.close()


def _square_then_trouble(item: int, fail_at: int | None, warn_at: int | None) -> dict:
    """A window function for the forked-map tests: squares, warns, fails, and says which
    process did it."""
    import os
    import warnings

    from graphcal.core.errors import DatasetError

    if item == warn_at:
        warnings.warn(f"odd window {item}", UserWarning, stacklevel=1)
    if item == fail_at:
        raise DatasetError("not a number", path="plots.csv", row=item + 2, field="range_m")
    return {"square": item * item, "pid": os.getpid()}


@needs_fork
def test_map_forked_keeps_the_order_and_shares_the_items_between_two_processes() -> None:
    import os

    from graphcal.pipeline.schedulers import map_forked

    prepared = []
    results = list(map_forked(_square_then_trouble, range(9), args=(None, None),
                              prepare=prepared.append))
    assert [r["square"] for r in results] == [i * i for i in range(9)]
    # The copy takes the first two items (it is kept two ahead); prepare runs where
    # the item is done.
    here = [i for i, r in enumerate(results) if r["pid"] == os.getpid()]
    assert {r["pid"] for r in results[:2]} - {os.getpid()}
    assert len({r["pid"] for r in results} - {os.getpid()}) == 1
    assert here and sorted(prepared) == here


def _slow_in_the_copy(item: int, parent_pid: int) -> int:
    """Instant here, 0.3 s in the forked copy."""
    import os
    import time

    if os.getpid() != parent_pid:
        time.sleep(0.3)
    return os.getpid()


@needs_fork
def test_map_forked_gives_the_free_process_the_next_item_and_steals_at_the_end() -> None:
    """A slow copy holds two items at most: this process takes the others, and at the end
    takes back the one the copy has not started (lock-step would give each four)."""
    import os

    from graphcal.pipeline.schedulers import map_forked

    pids = list(map_forked(_slow_in_the_copy, range(8), args=(os.getpid(),)))
    here = [i for i, pid in enumerate(pids) if pid == os.getpid()]
    assert here == list(range(1, 8))  # item 1 stolen back; the copy did item 0 only


@needs_fork
def test_map_forked_raises_the_copys_warnings_and_errors_here_and_stops_it() -> None:
    import multiprocessing

    from graphcal.core.errors import DatasetError
    from graphcal.pipeline.schedulers import map_forked

    seen = []
    with pytest.warns(UserWarning, match="odd window 3"), pytest.raises(DatasetError) as caught:
        for result in map_forked(_square_then_trouble, range(20), args=(5, 3)):
            seen.append(result["square"])
    assert seen == [0, 1, 4, 9, 16]
    assert (caught.value.row, caught.value.field) == (7, "range_m")
    assert not [p for p in multiprocessing.active_children() if p.name == "graphcal-helper"]


def _warn_every_time(item: int, parent_pid: int) -> int:
    """Warns each time; slow here, so that the forked copy takes most items."""
    import os
    import time
    import warnings

    if os.getpid() == parent_pid:
        time.sleep(0.2)
    warnings.warn("the same every window", UserWarning, stacklevel=1)
    return item


@needs_fork
def test_map_forked_shows_a_repeated_warning_once_per_process_under_the_default_filter(
) -> None:
    """Both processes' windows raise it: under the default filter it is shown at most
    once for each process, not once per window."""
    import os
    import warnings

    from graphcal.pipeline.schedulers import map_forked

    shown = []
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        original = warnings.showwarning
        warnings.showwarning = lambda message, *args, **kwargs: shown.append(str(message))
        try:
            assert list(map_forked(_warn_every_time, range(8),
                                   args=(os.getpid(),))) == list(range(8))
        finally:
            warnings.showwarning = original
    assert 1 <= len(shown) <= 2 and set(shown) == {"the same every window"}
