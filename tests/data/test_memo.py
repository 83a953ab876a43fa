"""Work shared within one calibration (graphcal.data.memo)."""

from __future__ import annotations

import numpy as np

from graphcal.data.memo import active, remember, shared, sharing


def test_values_are_computed_once_per_key_and_source_inside_a_block() -> None:
    calls: list[str] = []
    table, other = np.zeros(3), np.zeros(3)

    def compute(tag: str) -> list[str]:
        calls.append(tag)
        return [tag]

    with sharing():
        first = remember(("x",), (table,), lambda: compute("a"))
        again = remember(("x",), (table,), lambda: compute("b"))
        elsewhere = remember(("x",), (other,), lambda: compute("c"))
        renamed = remember(("y",), (table,), lambda: compute("d"))
    assert first is again
    assert elsewhere == ["c"] and renamed == ["d"]
    assert calls == ["a", "c", "d"]


def test_outside_a_block_nothing_is_kept() -> None:
    table = np.zeros(3)
    assert not active()
    values = [remember(("x",), (table,), lambda: [1]) for _ in range(2)]
    assert values[0] is not values[1]
    with sharing():
        kept = remember(("x",), (table,), lambda: [2])
    with sharing():  # a new block starts empty
        assert remember(("x",), (table,), lambda: [3]) == [3] != kept


def test_nested_blocks_and_the_decorator_join_the_outer_block() -> None:
    table = np.zeros(3)

    @shared
    def inner() -> list[int]:
        assert active()
        return remember(("x",), (table,), lambda: [4])

    with sharing():
        outer = remember(("x",), (table,), lambda: [5])
        with sharing():
            assert remember(("x",), (table,), lambda: [6]) is outer
        assert inner() is outer
    assert not active()
    assert inner() == [4]


def test_a_value_is_dropped_with_its_source() -> None:
    """A loop over many tables (time windows) does not keep every table's values."""
    import gc
    import weakref

    class Value(list):
        pass

    with sharing():
        table = np.zeros(3)
        value = remember(("x",), (table,), lambda: Value([1]))
        kept = weakref.ref(value)
        del value, table
        gc.collect()
        assert kept() is None
