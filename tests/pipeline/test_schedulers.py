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
