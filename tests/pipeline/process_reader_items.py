"""Module-level producers for the process-reader tests (a spawned child imports them)."""

from __future__ import annotations

from collections.abc import Iterator


def numbers(n: int) -> Iterator[int]:
    """0 .. n-1."""
    yield from range(n)


def broken(n: int) -> Iterator[int]:
    """0 .. n-1, then a ValueError naming a row."""
    yield from range(n)
    raise ValueError("row 7 of plots.csv")
